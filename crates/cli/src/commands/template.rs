//! `drivebus template check FILE...` and `template list`, and the `--template FILE` option
//! that adds a drive kind to any command taking `--drive` (docs/templates.md).

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Subcommand;
use drivebus_drive::template::{self, Template};

use super::target::{fail, EXIT_USAGE};

/// `drivebus template ...`.
#[derive(Subcommand, Debug)]
pub enum TemplateCmd {
    /// Check template files: every error with its line (exit 3), or what each describes.
    Check {
        /// The template files.
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// List the drive kinds templates add: the shipped ones and those given with --template.
    List,
}

/// Runs `drivebus template ...`.
pub fn run(cmd: &TemplateCmd) -> Result<u8> {
    match cmd {
        TemplateCmd::Check { files } => {
            let mut bad = 0;
            for file in files {
                match Template::load(file) {
                    Ok(t) => println!("{}", describe(&t)),
                    Err(e) => {
                        bad += 1;
                        for line in e.to_string().lines() {
                            eprintln!("drivebus: {line}");
                        }
                    }
                }
            }
            Ok(if bad == 0 { 0 } else { EXIT_USAGE })
        }
        TemplateCmd::List => {
            for family in template::registered() {
                if let Some(t) = family.template() {
                    println!("{}", describe(t));
                }
            }
            Ok(0)
        }
    }
}

/// What a template describes, in one line.
fn describe(t: &Template) -> String {
    let protocols: Vec<&str> = t.protocols.iter().map(|p| p.name()).collect();
    let status: Vec<&str> = t.status.values().map(|(n, _)| n).collect();
    format!(
        "{}: kind {} ({} {}), {}, status {}, {}{}, {} parameters, {} fault codes; source: {}; checked against the {} {}",
        t.file,
        t.kind,
        t.maker,
        t.model,
        protocols.join(" or "),
        status.join(" "),
        if t.command.is_some() { "command" } else { "no command" },
        if t.setpoint.is_some() { ", setpoint" } else { ", no setpoint" },
        t.params.len(),
        t.faults.len(),
        t.source,
        t.checked.as_str(),
        if t.checked == template::Checked::Simulator { "only" } else { "" },
    )
    .trim_end()
    .to_string()
}

/// Adds the kinds of the `--template` files: each file's errors on stderr, one line each, and
/// a usage failure if any file does not check.
pub fn load(files: &[String]) -> Result<()> {
    let mut bad = Vec::new();
    for file in files {
        let result = Template::load(Path::new(file)).map_err(|e| e.to_string()).and_then(template::register);
        if let Err(e) = result {
            for line in e.lines() {
                eprintln!("drivebus: --template {line}");
            }
            bad.push(file.as_str());
        }
    }
    if bad.is_empty() {
        Ok(())
    } else {
        Err(fail(
            EXIT_USAGE,
            format!("--template {}: fix the errors above (drivebus template check)", bad.join(", ")),
        ))
    }
}
