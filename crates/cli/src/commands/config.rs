//! `drivebus config check FILE`: reads a gateway configuration as `serve` would, opens nothing
//! (no port, no listener, no store), and says what it would run.

use drivebus_gateway::text::count;
use std::path::PathBuf;

use anyhow::Result;
use clap::Subcommand;
use drivebus_gateway::config::{Port, Role};
use drivebus_gateway::GatewayConfig;

/// `drivebus config ...`.
#[derive(Subcommand, Debug)]
pub enum ConfigCmd {
    /// Check a gateway configuration (every error with file, line and field; exit 3) and say
    /// what `serve --config FILE` would run: buses, drives, front ends, listeners. Opens nothing.
    Check {
        /// The configuration file.
        file: PathBuf,
    },
}

/// Runs `drivebus config ...`.
pub fn run(cmd: &ConfigCmd) -> Result<u8> {
    match cmd {
        ConfigCmd::Check { file } => {
            let config = super::serve::read_config(file)?;
            print!("{}", describe(&config));
            println!("{}: the configuration is valid", file.display());
            Ok(0)
        }
    }
}

/// What a configuration runs, in the words `serve` prints at start.
pub fn describe(c: &GatewayConfig) -> String {
    let mut out = String::new();
    let drives: usize = c.buses.iter().map(|b| b.drives.len()).sum();
    out += &format!(
        "gateway {:?}: {}, {}\n",
        c.name,
        count(c.buses.len(), "bus", "buses"),
        count(drives, "drive", "drives")
    );
    for t in &c.templates {
        out += &format!("  template {}\n", t.display());
    }
    for b in &c.buses {
        let port = match &b.port {
            Port::Virtual => "virtual (simulated drives)".to_string(),
            p => p.to_string(),
        };
        out += &format!("  bus {}: {port}, {} at {} {}\n", b.name, b.protocol_name(), b.baud, b.format);
        for d in &b.drives {
            let unit = if d.unit_id == 0 {
                "no Modbus TCP unit".to_string()
            } else {
                format!("unit id {}", d.unit_id)
            };
            out += &format!(
                "    drive {}: {} at address {}, {unit}, polled every {} ms{}\n",
                d.name,
                d.family,
                d.address,
                d.poll.as_millis(),
                if d.locked { ", locked" } else { "" }
            );
        }
    }
    for l in &c.linkage {
        out +=
            &format!("  linkage: {} follows {} x {} + {} Hz\n", l.follower, l.leader, l.ratio, l.offset_hz);
    }
    out += &format!(
        "  HTTP        {}://{}/ (anonymous reads {})\n",
        if c.http.tls.is_some() { "https" } else { "http" },
        c.http.listen,
        if c.http.anonymous_read { "on" } else { "off" }
    );
    out += &format!(
        "  Modbus TCP  {} ({})\n",
        c.modbus.listen,
        if c.modbus.read_only {
            "read-only".to_string()
        } else if c.modbus.allow.is_empty() {
            "writes from nobody".to_string()
        } else {
            format!(
                "writes from {}",
                c.modbus.allow.iter().map(|a| a.to_string()).collect::<Vec<_>>().join(", ")
            )
        }
    );
    if let Some(m) = &c.mqtt {
        out += &format!("  MQTT        {}\n", m.url);
    }
    match &c.store {
        Some(p) => out += &format!("  event store {}\n", p.display()),
        None => out += "  event store off\n",
    }
    let writers = c.tokens.iter().filter(|t| t.role == Role::Write).count();
    out += &format!("  tokens      {} ({writers} may write)\n", c.tokens.len());
    out
}
