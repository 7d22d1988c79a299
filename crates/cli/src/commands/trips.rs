//! `drivebus trips`: a drive's trip history, as far as its protocol gives it
//! (`drivebus_drive::profile::trips`).

use anyhow::Result;
use drivebus_drive::profile::trips::{history_json, history_of, history_reads};

use super::drive::{classify, connect, runtime};
use super::target::Target;

/// `trips`: the trip in force and the logged trips, newest first.
pub fn run(t: &Target) -> Result<u8> {
    runtime()?.block_on(async {
        let (drive, label) = connect(t).await?;
        let family = drive.profile().family();
        let status = drive.status().await.map_err(|e| classify(e, &label))?;
        let mut raws = Vec::new();
        for name in history_reads(family) {
            let (raw, _) = drive.read_param(&name).await.map_err(|e| classify(e, &label))?;
            raws.push(raw);
        }
        let h = history_of(family, &status, &raws);
        if t.json {
            println!("{}", history_json(status.address, family, &h));
            return Ok(0);
        }
        println!("{label}");
        match &h.current {
            Some(f) => println!("  in force  {} ({})", f.code, f.text),
            None => println!("  in force  none"),
        }
        println!("  from      {}", h.source);
        if h.entries.is_empty() {
            println!("  no trips logged");
            return Ok(0);
        }
        let width = h.entries.iter().map(|e| e.text.len()).max().unwrap_or(4).max(4);
        println!("  {:>2}  {:>4}  {:<width$}  {:>10}  {:>8}", "#", "code", "text", "output", "current");
        let cell =
            |v: Option<f64>, unit: &str, d: usize| v.map_or("-".to_string(), |x| format!("{x:.d$} {unit}"));
        for e in &h.entries {
            println!(
                "  {:>2}  {:>4}  {:<width$}  {:>10}  {:>8}",
                e.index,
                e.code,
                e.text,
                cell(e.output_hz, "Hz", 2),
                cell(e.current_a, "A", 1)
            );
        }
        Ok(0)
    })
}
