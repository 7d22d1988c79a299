//! The commissioning commands end to end against `drivebus simulate`: every family and
//! protocol, over TCP and over a pty; and the generic profile against a pymodbus server.

use std::process::Command;

use serde_json::{json, Value};

#[path = "support/http.rs"]
mod http;

#[path = "support/sim.rs"]
mod sim;

use sim::{drivebus, ok, simulate, status, wait_status, Proc};

#[path = "../../../tests/interop/witness.rs"]
mod witness;
use witness::witness;

/// speed, run, status shows it running and ramping, stop; out-of-range speed refused with 3
/// before anything is sent; a missing drive is exit 2.
fn commission(port: &str, family: &str, protocol: Option<&str>, address: u8) {
    let s = status(port, family, protocol, address);
    assert_eq!(s["running"], false, "{family}: {s}");
    assert_eq!(s["address"], address);
    ok(&drivebus(port, family, protocol, address, &["speed", "30"]), "speed 30");
    ok(&drivebus(port, family, protocol, address, &["run"]), "run");
    let mut last = -1.0;
    let mut rising = 0;
    for _ in 0..40 {
        let s = status(port, family, protocol, address);
        assert_eq!(s["running"], true, "{family}: {s}");
        let hz = s["output_hz"].as_f64().unwrap_or(0.0);
        if hz > last && last >= 0.0 {
            rising += 1;
        }
        last = hz;
        if rising >= 2 {
            break;
        }
    }
    assert!(rising >= 2, "{family}: the output ramps");
    let o = drivebus(port, family, protocol, address, &["reverse"]);
    if family == "b800" {
        // Keypad mode (F-12 = 1): the drive answers e 93, a refusal with what to change.
        assert_eq!(o.code, 1, "b800 reverse: {}{}", o.stdout, o.stderr);
        assert!(o.stderr.contains("0x93") && o.stderr.contains("F-12 = 2"), "{}", o.stderr);
    } else {
        ok(&o, "reverse");
    }
    let o = drivebus(port, family, protocol, address, &["jog"]);
    if family == "b800" {
        assert_eq!(o.code, 3, "the B800 protocol has no jog: {}{}", o.stdout, o.stderr);
        assert!(o.stderr.contains("no jog"), "{}", o.stderr);
    } else {
        ok(&o, "jog");
    }
    ok(&drivebus(port, family, protocol, address, &["reset"]), "reset");
    ok(&drivebus(port, family, protocol, address, &["stop"]), "stop");
    let o = drivebus(port, family, protocol, address, &["speed", "5000"]);
    assert_eq!(o.code, 3, "{family}: out of range: {}{}", o.stdout, o.stderr);
    assert_eq!(o.stderr.lines().count(), 1, "{}", o.stderr);
    let o = drivebus(
        port,
        family,
        protocol,
        if family == "toshiba" && protocol != Some("modbus-rtu") { 33 } else { 9 },
        &["status"],
    );
    assert_eq!(o.code, 2, "{family}: no drive there: {}{}", o.stdout, o.stderr);
    assert!(o.stderr.contains("no answer"), "{}", o.stderr);
}

#[test]
fn generic_over_tcp_and_pty() {
    let sim = simulate("generic@1:modbus-rtu", &["--tcp", "127.0.0.1:0"]);
    let port = sim.tcp_port();
    commission(&port, "generic", Some("modbus-rtu"), 1);
    // Parameters by the manual's names, RAM and EEPROM.
    ok(&drivebus(&port, "generic", Some("modbus-rtu"), 1, &["param", "set", "P0.02", "45"]), "param set");
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["param", "get", "P0.02", "--json"]);
    ok(&o, "param get");
    let v: Value = serde_json::from_str(o.stdout.trim()).unwrap();
    assert_eq!(v["raw"], 4500);
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["param", "set", "P0.02", "46", "--eeprom"]);
    ok(&o, "param set --eeprom");
    assert!(o.stderr.contains("EEPROM"), "warns about EEPROM wear: {}", o.stderr);
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["param", "get", "Q9.99"]);
    assert_eq!(o.code, 3, "{}", o.stderr);
    drop(sim);

    let pty = std::env::temp_dir().join(format!("drivebus-commission-{}", std::process::id()));
    let pty_s = pty.to_string_lossy().to_string();
    let sim = simulate("generic@2:modbus-rtu", &["--pty", &pty_s]);
    commission(&pty_s, "generic", Some("modbus-rtu"), 2);
    drop(sim);
}

#[test]
fn every_other_family_and_protocol_over_a_pty() {
    for (drive, family, protocol, address) in [
        ("generic@3:modbus-ascii", "generic", Some("modbus-ascii"), 3),
        ("toshiba@1", "toshiba", Some("toshiba-binary"), 1),
        ("toshiba@1", "toshiba", Some("toshiba-ascii"), 1),
        ("toshiba@1:modbus-rtu", "toshiba", Some("modbus-rtu"), 1),
        ("danfoss@3", "danfoss", None, 3),
        ("b800@5", "b800", None, 5),
    ] {
        let pty = std::env::temp_dir().join(format!("drivebus-commission-{family}-{}", std::process::id()));
        let pty_s = pty.to_string_lossy().to_string();
        let sim = simulate(drive, &["--pty", &pty_s]);
        commission(&pty_s, family, protocol, address);
        drop(sim);
    }
}

#[test]
fn generic_ascii_over_tcp() {
    let sim = simulate("generic@3:modbus-ascii", &["--tcp", "127.0.0.1:0"]);
    let port = sim.tcp_port();
    commission(&port, "generic", Some("modbus-ascii"), 3);
}

#[test]
fn toshiba_in_every_protocol() {
    for (drive, protocol) in [
        ("toshiba@1", "toshiba-binary"),
        ("toshiba@1", "toshiba-ascii"),
        ("toshiba@1:modbus-rtu", "modbus-rtu"),
    ] {
        let sim = simulate(drive, &["--tcp", "127.0.0.1:0"]);
        let port = sim.tcp_port();
        commission(&port, "toshiba", Some(protocol), 1);
    }
}

#[test]
fn danfoss_over_tcp() {
    let sim = simulate("danfoss@3", &["--tcp", "127.0.0.1:0"]);
    let port = sim.tcp_port();
    commission(&port, "danfoss", None, 3);
    // A read-only parameter cannot be written: the drive says no (AK 7), exit 1.
    let o = drivebus(&port, "danfoss", None, 3, &["param", "set", "16-13", "1"]);
    assert!(o.code == 1 || o.code == 3, "{}{}", o.stdout, o.stderr);
}

#[test]
fn b800_over_tcp() {
    let sim = simulate("b800@5", &["--tcp", "127.0.0.1:0"]);
    let port = sim.tcp_port();
    commission(&port, "b800", None, 5);
}

#[test]
fn params_backup_restore_diff_between_two_drives() {
    let sim = simulate("generic@1:modbus-rtu", &["--tcp", "127.0.0.1:0"]);
    let port = sim.tcp_port();
    let dir = std::env::temp_dir().join(format!("drivebus-params-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("drive1.json");
    let f = file.to_string_lossy().to_string();
    ok(&drivebus(&port, "generic", Some("modbus-rtu"), 1, &["params", "backup", &f]), "backup");
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["params", "diff", &f]);
    ok(&o, "diff equal");
    assert!(o.stdout.contains("no differences"), "{}", o.stdout);
    ok(&drivebus(&port, "generic", Some("modbus-rtu"), 1, &["param", "set", "P0.02", "12.5"]), "change");
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["params", "diff", &f]);
    assert_eq!(o.code, 1, "{}", o.stdout);
    assert!(o.stdout.contains("P0.02"), "{}", o.stdout);
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["params", "restore", &f, "--dry-run"]);
    ok(&o, "dry run");
    assert!(o.stdout.contains("P0.02") && o.stdout.contains("dry run"), "{}", o.stdout);
    ok(&drivebus(&port, "generic", Some("modbus-rtu"), 1, &["params", "restore", &f]), "restore");
    ok(&drivebus(&port, "generic", Some("modbus-rtu"), 1, &["params", "diff", &f]), "equal again");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
#[ignore = "needs pymodbus (.ci/install-witnesses.sh)"]
fn the_generic_profile_drives_a_pymodbus_server() {
    if !witness("pymodbus", witness::python_has("pymodbus"), "pip install pymodbus") {
        return;
    }
    let port_no = 20000 + (std::process::id() % 20000) as u16;
    let script =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/interop/pymodbus_server.py");
    let mut cmd = Command::new("python3");
    cmd.arg(script).arg(port_no.to_string());
    let _server = Proc::start(cmd, "listening on ");
    let port = format!("tcp://127.0.0.1:{port_no}");
    // The server starts listening just after it prints; retry the first exchange briefly.
    let mut s = None;
    for _ in 0..50 {
        let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["status", "--json"]);
        if o.code == 0 {
            s = Some(serde_json::from_str::<Value>(o.stdout.trim()).unwrap());
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    let s = s.expect("status from the pymodbus server");
    assert_eq!(s["running"], true, "{s}");
    assert_eq!(s["output_hz"], 40.0, "{s}");
    assert_eq!(s["current_a"], 5.2, "{s}");
    ok(&drivebus(&port, "generic", Some("modbus-rtu"), 1, &["speed", "25"]), "speed");
    ok(&drivebus(&port, "generic", Some("modbus-rtu"), 1, &["stop"]), "stop");
    // Read back what drivebus wrote, with raw: 2001H = 2500 (0x09C4), 2000H = 7 (decel stop).
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["raw", "01 03 20 00 00 02 CF CB", "--json"]);
    ok(&o, "raw");
    let v: Value = serde_json::from_str(o.stdout.lines().next().unwrap_or("{}")).unwrap();
    let text = v.to_string();
    assert!(text.contains("2500") || text.contains("09C4"), "{text}");
}

/// `raw` with bytes that are not one valid request is bad usage (exit 3) that names what is
/// wrong, checksum included: nothing is sent (the session would send its own encoding).
#[test]
fn raw_refuses_a_request_that_is_not_a_valid_frame() {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.args(["simulate", "--drive", "generic@1:modbus-rtu", "--tcp", "127.0.0.1:0"]);
    let sim = Proc::start(cmd, "listening on ");
    let port = sim.tcp_port();
    // The right CRC of this read is CF CB.
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["raw", "01 03 20 00 00 02 00 00"]);
    assert_eq!(o.code, 3, "{}{}", o.stdout, o.stderr);
    assert_eq!(o.stderr.trim().lines().count(), 1, "{}", o.stderr);
    assert!(
        o.stderr.contains("not a valid modbus-rtu request") && o.stderr.contains("CF CB"),
        "{}",
        o.stderr
    );
    // Two requests at once, or bytes beyond one, are not one request either.
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["raw", "01 03 20 00 00 02 CF CB 01"]);
    assert_eq!(o.code, 3, "{}{}", o.stdout, o.stderr);
    assert!(o.stderr.contains("not one modbus-rtu request"), "{}", o.stderr);
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["raw", "01 03 20 00 00 02 CF CB"]);
    ok(&o, "raw with the right CRC");
    // The reply is decoded as the answer to the request: 2103H is the output frequency, 0002H
    // P0.02, each in Hz.
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["raw", "01 03 21 03 00 01 7E 36"]);
    ok(&o, "raw read of 2103H");
    assert!(o.stdout.contains("drive 1 to master") && o.stdout.contains(" Hz"), "{}", o.stdout);
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 1, &["raw", "01 03 00 02 00 01 25 CA"]);
    ok(&o, "raw read of P0.02");
    assert!(o.stdout.contains(" Hz"), "{}", o.stdout);
}

#[test]
fn scan_finds_the_drives_on_a_mixed_line() {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.args(["simulate", "--drive", "generic@3:modbus-rtu", "--drive", "b800@5", "--tcp", "127.0.0.1:0"]);
    let sim = Proc::start(cmd, "listening on ");
    let port = sim.tcp_port();
    let out = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["scan", "--port", &port, "--drive", "auto", "--addresses", "1-6", "--json"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let found: Value = serde_json::from_slice(&out.stdout).unwrap();
    let list = found.as_array().unwrap();
    assert!(
        list.iter().any(|f| f["family"] == "generic" && f["address"] == 3 && f["protocol"] == "modbus-rtu"),
        "{found}"
    );
    assert!(list.iter().any(|f| f["family"] == "b800" && f["address"] == 5), "{found}");
    assert!(!list.iter().any(|f| f["address"] == 1 || f["address"] == 2), "{found}");
    // The generic drive refuses the Toshiba map's status read: that is not a Toshiba drive.
    assert!(!list.iter().any(|f| f["family"] == "toshiba"), "{found}");
    // Every character format listed is tried (a pty or TCP line carries any of them).
    let out = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["scan", "--port", &port, "--drive", "generic", "--protocol", "modbus-rtu", "--addresses", "3"])
        .args(["--formats", "8N1,8E1", "--json"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let found: Value = serde_json::from_slice(&out.stdout).unwrap();
    let formats: Vec<&str> = found.as_array().unwrap().iter().filter_map(|f| f["serial"].as_str()).collect();
    assert_eq!(formats, ["8N1", "8E1"], "{found}");
    let out = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["scan", "--port", &port, "--drive", "generic", "--formats", "8X1"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(3), "a bad format is a usage error");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("8X1") && err.lines().count() == 1, "{err}");
    // --first stops at the first; nothing at 10-12 is exit 2.
    let out = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["scan", "--port", &port, "--drive", "b800", "--addresses", "10-12"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
}

/// On a pty the port is closed before it is opened with the next protocol, baud rate or
/// format (its exclusive lock is drivebus's own); every family and format is tried.
#[test]
fn scan_over_a_pty_tries_every_family_and_format() {
    let pty = std::env::temp_dir().join(format!("drivebus-scan-{}", std::process::id()));
    let pty_s = pty.to_string_lossy().to_string();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.args(["simulate", "--drive", "generic@3:modbus-rtu", "--drive", "b800@5", "--pty", &pty_s]);
    let _sim = Proc::start(cmd, "listening on ");
    let out = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["--port", &pty_s, "--drive", "auto", "scan", "--addresses", "1-6", "--formats", "7N2,8N2"])
        .args(["--timeout", "100", "--json"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let found: Value = serde_json::from_slice(&out.stdout).unwrap();
    let mut seen: Vec<(String, u64, String)> = found
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            (
                f["family"].as_str().unwrap().to_string(),
                f["address"].as_u64().unwrap(),
                f["serial"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    seen.sort();
    let want: Vec<(String, u64, String)> =
        [("b800", 5, "7N2"), ("b800", 5, "8N2"), ("generic", 3, "7N2"), ("generic", 3, "8N2")]
            .iter()
            .map(|(f, a, s)| (f.to_string(), *a, s.to_string()))
            .collect();
    assert_eq!(seen, want, "{found}");
}

/// A backup of drive 1 restored onto drive 2 on the same pty line: drive 2 takes drive 1's
/// settings but keeps its own address (communication settings only with --include-comm), the
/// restore says whose backup it is, and both drives still answer at their own addresses.
#[test]
fn a_backup_restored_onto_another_drive_keeps_its_address() {
    let pty = std::env::temp_dir().join(format!("drivebus-restore-{}", std::process::id()));
    let pty_s = pty.to_string_lossy().to_string();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.args([
        "simulate",
        "--drive",
        "generic@1:modbus-rtu",
        "--drive",
        "generic@2:modbus-rtu",
        "--pty",
        &pty_s,
    ]);
    let _sim = Proc::start(cmd, "listening on ");
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("d1.json");
    let f = file.to_string_lossy().to_string();
    let rtu = Some("modbus-rtu");
    ok(&drivebus(&pty_s, "generic", rtu, 1, &["param", "set", "P0.02", "12.5"]), "change drive 1");
    ok(&drivebus(&pty_s, "generic", rtu, 1, &["params", "backup", &f]), "backup drive 1");
    let saved: Value = serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    assert_eq!(saved["family"], "generic", "{saved}");
    assert_eq!(saved["address"], 1, "{saved}");
    assert!(saved["model"].as_str().is_some_and(|m| !m.is_empty()), "{saved}");
    // Asked for, the communication settings would be written: shown, not sent.
    let o = drivebus(&pty_s, "generic", rtu, 2, &["params", "restore", &f, "--include-comm", "--dry-run"]);
    ok(&o, "dry run with --include-comm");
    assert!(o.stdout.contains("P3.11: 2 -> 1 (dry run)"), "{}", o.stdout);
    let o = drivebus(&pty_s, "generic", rtu, 2, &["params", "restore", &f]);
    ok(&o, "restore onto drive 2");
    assert!(
        o.stdout.contains("backup of generic drive 1") && o.stdout.contains("onto drive 2"),
        "{}",
        o.stdout
    );
    assert!(o.stdout.contains("P0.02:"), "{}", o.stdout);
    assert!(!o.stdout.contains("P3.11:"), "the address is not restored: {}", o.stdout);
    assert!(o.stdout.contains("kept as they are: P3.11"), "{}", o.stdout);
    for address in [1, 2] {
        let s = status(&pty_s, "generic", rtu, address);
        assert_eq!(s["address"], address, "{s}");
    }
    let o = drivebus(&pty_s, "generic", rtu, 2, &["param", "get", "P0.02", "--json"]);
    ok(&o, "P0.02 on drive 2");
    let v: Value = serde_json::from_str(o.stdout.trim()).unwrap();
    assert_eq!(v["raw"], 1250, "{v}");
    let o = drivebus(&pty_s, "generic", rtu, 2, &["param", "get", "P3.11", "--json"]);
    ok(&o, "P3.11 on drive 2");
    let v: Value = serde_json::from_str(o.stdout.trim()).unwrap();
    assert_eq!(v["raw"], 2, "{v}");
}

/// The B800 protocol has no parameter access: a backup says so and fails (no empty file), and
/// `param set` says only that, with where to set it, without an EEPROM-wear note first.
#[test]
fn b800_parameters_are_refused_with_what_to_do() {
    let sim = simulate("b800@5", &["--tcp", "127.0.0.1:0"]);
    let port = sim.tcp_port();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("b800.json");
    let o = drivebus(&port, "b800", None, 5, &["params", "backup", &file.to_string_lossy()]);
    assert_eq!(o.code, 3, "{}{}", o.stdout, o.stderr);
    assert_eq!(o.stderr.trim().lines().count(), 1, "{}", o.stderr);
    assert!(o.stderr.contains("nothing to back up") && o.stderr.contains("keypad"), "{}", o.stderr);
    assert!(!file.exists(), "no empty backup is written");
    let o = drivebus(&port, "b800", None, 5, &["param", "set", "F-12", "2"]);
    assert_eq!(o.code, 3, "{}{}", o.stdout, o.stderr);
    assert_eq!(o.stderr.trim().lines().count(), 1, "{}", o.stderr);
    assert!(o.stderr.contains("no parameter access") && o.stderr.contains("keypad"), "{}", o.stderr);
    assert!(!o.stderr.contains("EEPROM"), "{}", o.stderr);
    // The link line counts in plain plurals.
    let o = drivebus(&port, "b800", None, 5, &["status"]);
    ok(&o, "status");
    assert!(o.stdout.contains("1 transaction,") && !o.stdout.contains("(s)"), "{}", o.stdout);
}

/// Danfoss, each command a separate process: `speed 30; run; stop; run` reaches 30 Hz (every
/// telegram carries the drive's reference, read from it, not 0); `run` to a tripped drive that
/// still holds a start is refused with exit 1 and the alarm.
#[test]
fn danfoss_commands_from_separate_processes() {
    let sim = simulate("danfoss@3", &["--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"]);
    let port = sim.tcp_port();
    for cmd in [&["speed", "30"][..], &["run"], &["stop"]] {
        ok(&drivebus(&port, "danfoss", None, 3, cmd), cmd[0]);
    }
    wait_status(&port, "danfoss", None, 3, "stopped", |s| s["running"] == false);
    ok(&drivebus(&port, "danfoss", None, 3, &["run"]), "run again");
    let s = wait_status(&port, "danfoss", None, 3, "30 Hz", |s| {
        s["output_hz"].as_f64().is_some_and(|hz| (hz - 30.0).abs() < 0.1)
    });
    assert_eq!(s["running"], true, "{s}");

    let (code, v) =
        http::http_json(sim.control(), "POST", "/drives/1", Some(&json!({"trip": "over-current"})))
            .expect("trip");
    assert_eq!(code, 200, "{v}");
    let o = drivebus(&port, "danfoss", None, 3, &["run"]);
    assert_eq!(o.code, 1, "run while tripped: {}{}", o.stdout, o.stderr);
    assert!(o.stderr.contains("tripped") && o.stderr.contains("over current"), "{}", o.stderr);
    assert!(!o.stdout.contains("done"), "{}", o.stdout);
}

/// A command to address 0 reaches every drive and nobody confirms it: it says so instead of
/// "done".
#[test]
fn a_broadcast_says_it_is_unconfirmed() {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.args(["simulate", "--drive", "generic@1:modbus-rtu", "--drive", "generic@2:modbus-rtu"]);
    cmd.args(["--tcp", "127.0.0.1:0"]);
    let sim = Proc::start(cmd, "listening on ");
    let port = sim.tcp_port();
    let o = drivebus(&port, "generic", Some("modbus-rtu"), 0, &["run"]);
    ok(&o, "broadcast run");
    assert!(o.stdout.contains("run sent to all drives (broadcast: no confirmation)"), "{}", o.stdout);
    assert!(!o.stdout.contains("done"), "{}", o.stdout);
    for address in [1, 2] {
        wait_status(&port, "generic", Some("modbus-rtu"), address, "running after the broadcast", |s| {
            s["running"] == true
        });
    }
}
