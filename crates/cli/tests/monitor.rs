//! `drivebus monitor` end to end against `drivebus simulate`: with stdout not a terminal it
//! prints one line per drive per refresh, and `--count` stops it.

use std::process::Command;

use serde_json::Value;

#[path = "support/sim.rs"]
mod sim;
use sim::{output, Proc};

/// `drivebus simulate` of `drives` on TCP (killed on drop), and its address as `--port` takes it.
fn start(drives: &[&str]) -> (Proc, String) {
    let args: Vec<&str> =
        drives.iter().flat_map(|d| ["--drive", d]).chain(["--tcp", "127.0.0.1:0"]).collect();
    let proc = sim::simulate_with(&args);
    let port = proc.tcp_port();
    (proc, port)
}

fn drivebus(port: &str, args: &[&str]) -> (i32, String, String) {
    let out = output(
        Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["--port", port, "--drive", "generic", "--protocol", "modbus-rtu"])
            .args(args),
    );
    (out.code, out.stdout, out.stderr)
}

#[test]
fn plain_lines_per_drive_per_refresh() {
    let (_sim, port) = start(&["generic@1:modbus-rtu", "generic@2:modbus-rtu"]);
    let (code, out, err) = drivebus(&port, &["--address", "1", "speed", "30"]);
    assert_eq!(code, 0, "{out}{err}");
    let (code, out, err) = drivebus(&port, &["--address", "1", "run"]);
    assert_eq!(code, 0, "{out}{err}");
    // Drive 9 is not there: it goes offline after 3 failed refreshes (no retries).
    let (code, out, err) = drivebus(
        &port,
        &[
            "monitor",
            "--address",
            "1",
            "--address",
            "2",
            "--address",
            "9",
            "--interval",
            "50",
            "--count",
            "3",
            "--timeout",
            "100",
            "--retries",
            "0",
        ],
    );
    assert_eq!(code, 0, "{out}{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 9, "3 drives x 3 refreshes: {out}");
    for (i, l) in lines.iter().enumerate() {
        let address = [1, 2, 9][i % 3];
        assert!(l.contains(&format!(" drive={address} ")), "{l}");
    }
    assert!(lines[0].contains("state=running") && lines[0].contains("setpoint_hz=30.00"), "{out}");
    assert!(lines[0].contains("online=yes") && lines[0].contains("fault=\"none\""), "{out}");
    assert!(lines[1].contains("state=stopped") && lines[1].contains("output_hz=0.00"), "{out}");
    assert!(lines[2].contains("state=no data") && lines[2].contains("online=yes"), "{out}");
    assert!(lines[2].contains("error=\"no answer from drive 9"), "{out}");
    assert!(lines[8].contains("online=no"), "offline after 3 failures: {out}");
}

#[test]
fn plain_json_and_errors() {
    let (_sim, port) = start(&["generic@4:modbus-rtu"]);
    let (code, out, err) =
        drivebus(&port, &["monitor", "--address", "4", "--count", "2", "--interval", "20", "--json"]);
    assert_eq!(code, 0, "{out}{err}");
    let rows: Vec<Value> = out.lines().map(|l| serde_json::from_str(l).expect("JSON line")).collect();
    assert_eq!(rows.len(), 2);
    assert_eq!(rows[1]["address"], 4);
    assert_eq!(rows[1]["running"], false);
    assert_eq!(rows[1]["online"], true);
    assert!(rows[1]["t"].as_f64().unwrap() >= rows[0]["t"].as_f64().unwrap());

    // Nobody answers: exit 2, one line naming the port.
    let (code, out, err) =
        drivebus(&port, &["monitor", "--address", "5", "--count", "1", "--timeout", "50", "--retries", "0"]);
    assert_eq!(code, 2, "{out}{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("no answer from any drive") && err.contains(&port), "{err}");

    // Bad usage: exit 3.
    let (code, _, err) = drivebus(&port, &["monitor", "--count", "1"]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("--address"), "{err}");
    let (code, _, err) = drivebus(&port, &["monitor", "--address", "4", "--interval", "0"]);
    assert_eq!(code, 3, "{err}");
    // Other commands still want exactly one drive.
    let (code, _, err) = drivebus(&port, &["--address", "4", "--address", "5", "status"]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("give one --address"), "{err}");
}
