//! `drivebus events` and `drivebus trend`: read the gateway's store (drivebus-store) from the
//! command line, also while `drivebus serve` is writing it.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use drivebus_store::time::{format_rfc3339, now_ms, parse_time};
use drivebus_store::{EventFilter, EventKind, Resolution, Store, StoreError, TrendQuery};

use crate::commands::target::{link_failure, usage, Target};

/// The store file name these commands look for in the working directory (a `[store] path`
/// written relative, as older configurations did) before the state folder.
const DEFAULT_DB: &str = drivebus_gateway::config::DEFAULT_STORE_FILE;

/// The store to read: `--db`, else drivebus.db here, else the gateway's default store
/// (drivebus.db in the state folder), else the store `drivebus serve --demo` writes
/// (drivebus-demo.db in the state folder). When none exists, the state folder's drivebus.db
/// (the error then names it).
fn store_path(db: Option<&Path>) -> PathBuf {
    if let Some(db) = db {
        return db.to_path_buf();
    }
    let here = PathBuf::from(DEFAULT_DB);
    if here.exists() {
        return here;
    }
    let state = drivebus_gateway::config::state_dir::state_dir().ok().map(|d| d.join(DEFAULT_DB));
    let demo = drivebus_gateway::config::GatewayConfig::demo().store;
    let candidates = [state.clone(), demo];
    if let Some(found) = candidates.into_iter().flatten().find(|p| p.exists()) {
        return found;
    }
    state.unwrap_or(here)
}

/// Arguments of `drivebus events` (with --drive ID and --json from `crate::options`).
#[derive(Args, Debug)]
pub struct EventsArgs {
    /// The store file written by `drivebus serve` (default: drivebus.db here, else drivebus.db
    /// or the demo's drivebus-demo.db in the state folder, the first that exists).
    #[arg(long, value_name = "FILE")]
    pub db: Option<PathBuf>,
    /// Events at or after TIME: RFC 3339 (2026-11-21T10:00:00Z), unix ms, or -10m, -2h, -1d.
    #[arg(long, value_name = "TIME", allow_hyphen_values = true)]
    pub since: Option<String>,
    /// Events before TIME (same forms as --since).
    #[arg(long, value_name = "TIME", allow_hyphen_values = true)]
    pub until: Option<String>,
    /// Only events of KIND: command, trip, fault_reset, online, offline, bus_online,
    /// bus_offline, started, stopped.
    #[arg(long, value_name = "KIND")]
    pub kind: Option<String>,
    /// At most N events, the newest (1 or more).
    #[arg(long, value_name = "N", default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..))]
    pub limit: u64,
}

/// Arguments of `drivebus trend` (with --drive ID, required, and --json from `crate::options`).
#[derive(Args, Debug)]
pub struct TrendArgs {
    /// The store file written by `drivebus serve` (default: drivebus.db here, else drivebus.db
    /// or the demo's drivebus-demo.db in the state folder, the first that exists).
    #[arg(long, value_name = "FILE")]
    pub db: Option<PathBuf>,
    /// Buckets from TIME (default: an hour ago at 1s, a day ago at 1m): RFC 3339, unix ms, or
    /// -10m, -2h, -1d.
    #[arg(long, value_name = "TIME", allow_hyphen_values = true)]
    pub since: Option<String>,
    /// Buckets before TIME (default: now).
    #[arg(long, value_name = "TIME", allow_hyphen_values = true)]
    pub until: Option<String>,
    /// 1s (kept a day) or 1m (kept a year). Default: 1s when --since is within the last day,
    /// else 1m.
    #[arg(long, value_name = "1s|1m")]
    pub resolution: Option<String>,
}

fn open(db: &std::path::Path) -> Result<Store> {
    Store::open_read_only(db).map_err(|e| store_failure(&e))
}

fn store_failure(e: &StoreError) -> anyhow::Error {
    link_failure(e.to_string())
}

fn time_arg(flag: &str, text: Option<&str>, now: i64) -> Result<Option<i64>> {
    text.map(|t| parse_time(t, now).map_err(|e| usage(format!("--{flag}: {e}")))).transpose()
}

fn one_drive(target: &Target) -> Result<Option<String>> {
    match target.drive.as_slice() {
        [] => Ok(None),
        [one] => Ok(Some(one.clone())),
        _ => Err(usage("give one --drive ID (the drive's name in the gateway)")),
    }
}

fn dash(v: Option<&str>) -> &str {
    v.filter(|s| !s.is_empty()).unwrap_or("-")
}

/// Prints rows as columns separated by two spaces, each as wide as its widest cell.
fn print_table(header: &[&str], rows: &[Vec<String>], right_align: &[bool]) {
    let mut widths: Vec<usize> = header.iter().map(|h| h.chars().count()).collect();
    for row in rows {
        for (w, cell) in widths.iter_mut().zip(row) {
            *w = (*w).max(cell.chars().count());
        }
    }
    let line = |cells: &[String]| {
        let mut out = String::new();
        for (i, cell) in cells.iter().enumerate() {
            let w = widths[i];
            let last = i + 1 == cells.len();
            if right_align.get(i).copied().unwrap_or(false) {
                out.push_str(&format!("{cell:>w$}"));
            } else if last {
                out.push_str(cell);
            } else {
                out.push_str(&format!("{cell:<w$}"));
            }
            if !last {
                out.push_str("  ");
            }
        }
        println!("{}", out.trim_end());
    };
    line(&header.iter().map(|h| h.to_string()).collect::<Vec<_>>());
    for row in rows {
        line(row);
    }
}

/// `drivebus events`: the event log, oldest first, as a table or one JSON object per line.
pub fn events(args: &EventsArgs, target: &Target) -> Result<u8> {
    let now = now_ms();
    let since_ms = time_arg("since", args.since.as_deref(), now)?;
    let until_ms = time_arg("until", args.until.as_deref(), now)?;
    if let (Some(s), Some(u)) = (since_ms, until_ms) {
        if s >= u {
            return Err(usage("--since must be before --until"));
        }
    }
    let kind = args
        .kind
        .as_deref()
        .map(|k| k.parse::<EventKind>().map_err(|e| usage(format!("--kind: {e}"))))
        .transpose()?;
    let filter = EventFilter {
        since_ms,
        until_ms,
        after_id: None,
        drive: one_drive(target)?,
        kind,
        limit: usize::try_from(args.limit).unwrap_or(usize::MAX),
    };
    let db = store_path(args.db.as_deref());
    let store = open(&db)?;
    let events = store.events(&filter).map_err(|e| store_failure(&e))?;
    if target.json {
        for e in &events {
            println!("{}", serde_json::to_string(e)?);
        }
        return Ok(0);
    }
    if events.is_empty() {
        eprintln!("no events match in {}", db.display());
        return Ok(0);
    }
    let rows: Vec<Vec<String>> = events
        .iter()
        .map(|e| {
            vec![
                format_rfc3339(e.time_ms),
                e.kind.to_string(),
                dash(e.bus.as_deref()).to_string(),
                dash(e.drive.as_deref()).to_string(),
                dash(e.actor.as_deref()).to_string(),
                dash(e.action.as_deref()).to_string(),
                dash(e.result.as_deref()).to_string(),
            ]
        })
        .collect();
    print_table(&["TIME", "KIND", "BUS", "DRIVE", "ACTOR", "ACTION", "RESULT"], &rows, &[]);
    Ok(0)
}

/// `drivebus trend`: one drive's buckets, oldest first, as a table or one JSON object per line.
pub fn trend(args: &TrendArgs, target: &Target) -> Result<u8> {
    let drive = one_drive(target)?
        .ok_or_else(|| usage("trend needs --drive ID (the drive's name in the gateway)"))?;
    let now = now_ms();
    let since_arg = time_arg("since", args.since.as_deref(), now)?;
    let until_ms = time_arg("until", args.until.as_deref(), now)?.unwrap_or(now);
    let resolution = match args.resolution.as_deref() {
        Some(r) => r.parse::<Resolution>().map_err(|e| usage(format!("--resolution: {e}")))?,
        None => match since_arg {
            Some(s) if s < now - Resolution::Second.retention_ms() => Resolution::Minute,
            _ => Resolution::Second,
        },
    };
    let since_ms = since_arg.unwrap_or(match resolution {
        Resolution::Second => until_ms - 3_600_000,
        Resolution::Minute => until_ms - 86_400_000,
    });
    if since_ms >= until_ms {
        return Err(usage("--since must be before --until"));
    }
    let db = store_path(args.db.as_deref());
    let store = open(&db)?;
    let points = store
        .trend(&TrendQuery { drive: drive.clone(), since_ms, until_ms, resolution })
        .map_err(|e| store_failure(&e))?;
    if target.json {
        for p in &points {
            println!("{}", serde_json::to_string(p)?);
        }
        return Ok(0);
    }
    if points.is_empty() {
        eprintln!(
            "no {resolution} trend for drive {drive} from {} to {} in {}",
            format_rfc3339(since_ms),
            format_rfc3339(until_ms),
            db.display()
        );
        return Ok(0);
    }
    let num = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.2}"));
    let rows: Vec<Vec<String>> = points
        .iter()
        .map(|p| {
            vec![
                format_rfc3339(p.time_ms),
                num(p.output_hz),
                num(p.output_hz_min),
                num(p.output_hz_max),
                num(p.current_a),
                num(p.setpoint_hz),
                p.samples.to_string(),
            ]
        })
        .collect();
    print_table(
        &["TIME", "OUTPUT HZ", "MIN HZ", "MAX HZ", "CURRENT A", "SETPOINT HZ", "SAMPLES"],
        &rows,
        &[false, true, true, true, true, true, true],
    );
    Ok(0)
}
