//! Drive templates on the command line: `template check` on every shipped template and on bad
//! files (every error with its line), and `--template FILE` adding a kind `--drive` names.

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "support/sim.rs"]
mod sim;
use sim::{drivebus, ok, output, simulate};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn shipped() -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(repo().join("templates"))
        .expect("templates/")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    files.sort();
    files
}

#[test]
fn template_check_passes_every_shipped_template() {
    let files = shipped();
    assert!(!files.is_empty());
    let o = output(Command::new(env!("CARGO_BIN_EXE_drivebus")).arg("template").arg("check").args(&files));
    ok(&o, "template check");
    assert_eq!(o.stdout.lines().count(), files.len(), "{}", o.stdout);
    for line in o.stdout.lines() {
        assert!(line.contains("source: ") && line.contains("checked against the simulator only"), "{line}");
    }
    // Each shipped file is known without --template.
    let o = output(Command::new(env!("CARGO_BIN_EXE_drivebus")).args(["template", "list"]));
    ok(&o, "template list");
    assert_eq!(o.stdout.lines().count(), files.len(), "{}", o.stdout);
}

#[test]
fn template_check_reports_every_error_with_its_line() {
    let dir = std::env::temp_dir().join(format!("drivebus-template-check-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        "kind = \"x\"\nmaker = \"a\"\nmodel = \"b\"\nsource = \"c\"\nprotocols = [\"modbus-rtu\"]\n\
         [serial]\nbaud = 9600\nformat = \"8N1\"\n[status]\n\
         running = { register = 1, bit = 0 }\nreverse = { register = 1, bit = 0 }\n\
         output_hz = { register = 70000, type = \"u24\", scale = 0.0 }\n\
         fault = { register = 1, mask = 0 }\n\
         current_a = { register = 1, mask = 0x000F }\n",
    )
    .unwrap();
    let o = output(Command::new(env!("CARGO_BIN_EXE_drivebus")).args(["template", "check"]).arg(&bad));
    assert_eq!(o.code, 3, "{}{}", o.stdout, o.stderr);
    let lines: Vec<&str> = o.stderr.lines().collect();
    let at = |n: usize, what: &str| {
        assert!(
            lines.iter().any(|l| l.contains(&format!("bad.toml:{n}: ")) && l.contains(what)),
            "{what}: {}",
            o.stderr
        )
    };
    at(11, "bit 0 overlaps status.running's");
    at(12, "register 70000 is not a Modbus register");
    at(12, "unknown type \"u24\"");
    at(12, "scale of 0");
    at(13, "status.fault: mask 0x0 takes no bit");
    at(14, "status.current_a: mask 0x000F overlaps status.running's (register 1)");
    assert_eq!(lines.len(), 6, "{}", o.stderr);
    // The same file given with --template: the errors, and bad usage.
    let o = drivebus("/dev/null", "x", None, 1, &["status", "--template", bad.to_str().unwrap()]);
    assert_eq!(o.code, 3);
    assert!(o.stderr.contains("--template") && o.stderr.contains("bad.toml:12"), "{}", o.stderr);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_template_given_with_template_is_a_drive_kind() {
    // The shipped generic template under another kind's name, from a file of the user's, with a
    // named value.
    let dir = std::env::temp_dir().join(format!("drivebus-template-kind-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("my-vfd.toml");
    let text = std::fs::read_to_string(repo().join("templates/generic-2000h.toml")).unwrap();
    let text = text.replace("kind = \"generic-2000h\"", "kind = \"my-vfd\"");
    std::fs::write(
        &file,
        format!("{text}\n[values]\ndc_bus_v = {{ register = 0x2105, scale = 0.1, unit = \"V\" }}\n"),
    )
    .unwrap();
    let file = file.to_str().unwrap().to_string();

    let sim = simulate("generic@4", &["--modbus-tcp", "127.0.0.1:0"]);
    let port = format!("tcp://{}", sim.ready.trim_start_matches("modbus-tcp "));
    let run = |args: &[&str]| {
        drivebus(&port, "my-vfd", Some("modbus-tcp"), 4, &[args, &["--template", &file]].concat())
    };
    ok(&run(&["speed", "12.5"]), "speed");
    ok(&run(&["run"]), "run");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    loop {
        let o = run(&["status", "--json"]);
        ok(&o, "status");
        let s: serde_json::Value = serde_json::from_str(o.stdout.trim()).unwrap();
        assert_eq!(s["setpoint_hz"], 12.5, "{s}");
        if s["output_hz"] == 12.5 {
            assert_eq!(s["running"], true);
            break;
        }
        assert!(std::time::Instant::now() < deadline, "{s}");
    }
    let o = run(&["param", "get", "P0.04"]);
    ok(&o, "param get");
    assert!(o.stdout.contains("50.00 Hz"), "{}", o.stdout);
    // The [values] the user's file adds: 2105H, the DC bus in 0.1 V.
    let o = run(&["status", "--json"]);
    ok(&o, "status");
    let s: serde_json::Value = serde_json::from_str(o.stdout.trim()).unwrap();
    assert_eq!(s["values"]["dc_bus_v"]["unit"], "V", "{s}");
    let dc = s["values"]["dc_bus_v"]["value"].as_f64().unwrap_or_default();
    assert!((500.0..520.0).contains(&dc), "about 1.35 x 380 V: {s}");
    let o = run(&["status"]);
    ok(&o, "status");
    assert!(
        o.stdout.lines().any(|l| l.trim_start().starts_with("dc_bus_v") && l.ends_with(" V")),
        "{}",
        o.stdout
    );
    // Without --template the kind is unknown.
    let o = drivebus(&port, "my-vfd", Some("modbus-tcp"), 4, &["status"]);
    assert_eq!(o.code, 3);
    assert!(o.stderr.contains("unknown drive family \"my-vfd\""), "{}", o.stderr);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn simulate_runs_a_templated_drive() {
    let dir = std::env::temp_dir().join(format!("drivebus-template-sim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("sim-vfd.toml");
    let text = std::fs::read_to_string(repo().join("templates/generic-2000h.toml")).unwrap();
    std::fs::write(&file, text.replace("kind = \"generic-2000h\"", "kind = \"sim-vfd\"")).unwrap();
    let file = file.to_str().unwrap();
    let sim = simulate("sim-vfd@3", &["--template", file, "--modbus-tcp", "127.0.0.1:0"]);
    assert!(sim.before.iter().any(|l| l.contains("sim-vfd@3:modbus-rtu")), "{:?}", sim.before);
    let port = format!("tcp://{}", sim.ready.trim_start_matches("modbus-tcp "));
    // The template's map is the generic drive's: the built-in profile reads the simulated drive.
    ok(&drivebus(&port, "generic", Some("modbus-tcp"), 3, &["speed", "20"]), "speed");
    let s = sim::status(&port, "generic", Some("modbus-tcp"), 3);
    assert_eq!(s["setpoint_hz"], 20.0, "{s}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A drive map no built-in family reads: the worked example of docs/templates.md, as the page
/// gives it.
fn fan_b1() -> String {
    let doc =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/templates.md")).unwrap();
    let start = doc.find("```toml\nkind = \"fan-b1\"").expect("the worked example") + "```toml\n".len();
    doc[start..start + doc[start..].find("```").unwrap()].to_string()
}

#[test]
fn scan_auto_tries_the_templates_after_the_built_in_families() {
    let dir = std::env::temp_dir().join(format!("drivebus-template-scan-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("fan-b1.toml");
    std::fs::write(&file, fan_b1()).unwrap();
    let file = file.to_str().unwrap();
    // A templated drive at 3 and a generic one at 2 on the same line.
    let sim = simulate(
        "fan-b1@3",
        &["--template", file, "--drive", "generic@2:modbus-rtu", "--tcp", "127.0.0.1:0"],
    );
    let port = sim.tcp_port();
    let o = output(
        Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["scan", "--port", &port, "--drive", "auto", "--template", file])
            .args(["--addresses", "2-4", "--timeout", "300", "--json"]),
    );
    ok(&o, "scan --drive auto");
    let found: serde_json::Value = serde_json::from_str(o.stdout.trim()).unwrap();
    let at = |address: u64| -> Vec<String> {
        found
            .as_array()
            .unwrap()
            .iter()
            .filter(|f| f["address"] == address)
            .map(|f| f["family"].as_str().unwrap().to_string())
            .collect()
    };
    // The templated drive is found by its kind (the built-in families' refusals there are not
    // listed), and the generic drive as generic only: the shipped generic-2000h template, which
    // repeats its map, is not tried where a built-in family read a status.
    assert_eq!(at(3), ["fan-b1"], "{found}");
    assert_eq!(at(2), ["generic"], "{found}");
    assert!(at(4).is_empty(), "{found}");
    // Without --template the kind is not known, and the drive at 3 is not found by it.
    let o = output(Command::new(env!("CARGO_BIN_EXE_drivebus")).args([
        "scan",
        "--port",
        &port,
        "--drive",
        "auto",
        "--addresses",
        "3",
        "--timeout",
        "300",
        "--json",
    ]));
    assert!(!o.stdout.contains("fan-b1"), "{}", o.stdout);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_shipped_template_needs_no_template_flag_and_shows_its_history() {
    // abb-acs550 is shipped: the simulator and the commands know it without --template.
    let sim = simulate("abb-acs550@2", &["--modbus-tcp", "127.0.0.1:0"]);
    let port = format!("tcp://{}", sim.ready.trim_start_matches("modbus-tcp "));
    let o = drivebus(&port, "abb-acs550", Some("modbus-tcp"), 2, &["status", "--json"]);
    ok(&o, "status");
    let s: serde_json::Value = serde_json::from_str(o.stdout.trim()).unwrap();
    assert_eq!(s["fault"], serde_json::Value::Null, "{s}");
    // No named values: the template leaves out what no public page gave the scale of.
    assert_eq!(s["values"], serde_json::Value::Null, "{s}");
    let o = drivebus(&port, "abb-acs550", Some("modbus-tcp"), 2, &["trips", "--json"]);
    ok(&o, "trips");
    let t: serde_json::Value = serde_json::from_str(o.stdout.trim()).unwrap();
    assert_eq!(t["history"], serde_json::json!([]), "no trip yet: {t}");
    assert!(t["source"].as_str().is_some_and(|s| s.contains("fault_history 0401, 0412, 0413")), "{t}");
}

#[test]
fn the_shipped_v20_template_runs_and_reverses_a_simulated_v20() {
    // siemens-v20 runs by two registers (RUN ENABLE and CMD START) and reverses by a third: the
    // simulator carries out what the commands write, over Modbus TCP as over RS485.
    let sim = simulate("siemens-v20@3", &["--modbus-tcp", "127.0.0.1:0"]);
    let port = format!("tcp://{}", sim.ready.trim_start_matches("modbus-tcp "));
    let tcp = Some("modbus-tcp");
    ok(&drivebus(&port, "siemens-v20", tcp, 3, &["speed", "20"]), "speed");
    ok(&drivebus(&port, "siemens-v20", tcp, 3, &["run"]), "run");
    let s = sim::wait_status(&port, "siemens-v20", tcp, 3, "running forward at 20 Hz", |s| {
        s["running"] == true && s["output_hz"] == 20.0
    });
    assert_eq!(s["direction"], "forward", "{s}");
    ok(&drivebus(&port, "siemens-v20", tcp, 3, &["reverse"]), "reverse");
    let s = sim::wait_status(&port, "siemens-v20", tcp, 3, "running in reverse at 20 Hz", |s| {
        s["direction"] == "reverse" && s["output_hz"] == 20.0
    });
    assert!(s["values"]["dc_bus_v"]["value"].as_f64().is_some_and(|v| v > 100.0), "{s}");
    ok(&drivebus(&port, "siemens-v20", tcp, 3, &["stop"]), "stop");
    sim::wait_status(&port, "siemens-v20", tcp, 3, "stopped", |s| s["running"] == false);
}

#[test]
fn the_shipped_optidrive_e3_template_runs_and_stops_a_simulated_e3() {
    // invertek-optidrive-e3 runs by bit 0 of its control word and takes running and the error
    // code apart from one status word (bit 0, high byte): the simulator fills the word's fields.
    let kind = "invertek-optidrive-e3";
    let sim = simulate(&format!("{kind}@4"), &["--modbus-tcp", "127.0.0.1:0"]);
    let port = format!("tcp://{}", sim.ready.trim_start_matches("modbus-tcp "));
    let tcp = Some("modbus-tcp");
    ok(&drivebus(&port, kind, tcp, 4, &["speed", "30"]), "speed");
    ok(&drivebus(&port, kind, tcp, 4, &["run"]), "run");
    let s = sim::wait_status(&port, kind, tcp, 4, "running at 30 Hz", |s| {
        s["running"] == true && s["output_hz"] == 30.0
    });
    assert_eq!((&s["setpoint_hz"], &s["fault"]), (&serde_json::json!(30.0), &serde_json::Value::Null), "{s}");
    assert!(s["values"]["heatsink_c"]["value"].as_f64().is_some(), "{s}");
    ok(&drivebus(&port, kind, tcp, 4, &["stop"]), "stop");
    sim::wait_status(&port, kind, tcp, 4, "stopped", |s| s["running"] == false && s["output_hz"] == 0.0);
}
