//! `drivebus panel` end to end over a simulator's pty: the display as the drive shows it, key
//! presses, the Toshiba panel's LEDs set by communication (FA10, FA11, FA12), and bad usage.

use std::process::Command;

use serde_json::Value;

/// `drivebus simulate` on a pty with a control interface, killed on drop.
struct Sim {
    proc: Proc,
}

impl Sim {
    fn start(drives: &[&str], pty: &str) -> Sim {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
        cmd.arg("simulate");
        for d in drives {
            cmd.args(["--drive", d]);
        }
        cmd.args(["--pty", pty, "--control", "127.0.0.1:0"]);
        Sim { proc: Proc::start(cmd, "listening on ") }
    }

    /// `GET /drives/{n}` of the control interface.
    fn drive(&self, n: usize) -> Value {
        http_json(self.proc.control(), "GET", &format!("/drives/{n}"), None).expect("drive JSON").1
    }
}

#[path = "support/http.rs"]
mod http;
#[path = "support/sim.rs"]
mod sim;
use http::http_json;
use sim::{output, Out, Proc};

fn panel(pty: &str, drive: &[&str], args: &[&str]) -> Out {
    output(
        Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["panel", "--port", pty, "--timeout", "300"])
            .args(drive)
            .args(args),
    )
}

fn json(o: &Out) -> Value {
    assert_eq!(o.code, 0, "{}{}", o.stdout, o.stderr);
    serde_json::from_str(o.stdout.trim()).expect("one JSON object")
}

const TOSHIBA: &[&str] = &["--drive", "toshiba", "--address", "1"];
const GENERIC: &[&str] = &["--drive", "generic", "--protocol", "modbus-rtu", "--address", "2"];

#[test]
fn the_panel_over_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let pty = dir.path().join("bus0");
    let pty = pty.to_str().unwrap();
    let sim = Sim::start(&["toshiba@1", "generic@2:modbus-rtu"], pty);

    // A stopped Toshiba drive shows its setpoint, 0.0; "up" twice is 0.2 Hz, "run" starts it.
    let v = json(&panel(pty, TOSHIBA, &["--json"]));
    assert_eq!((v["display"].as_str(), v["running"].as_bool()), (Some("0.0"), Some(false)), "{v}");
    let v = json(&panel(pty, TOSHIBA, &["--key", "up", "--key", "up", "--key", "run", "--json"]));
    assert_eq!(v["setpoint_hz"], 0.2, "{v}");
    assert_eq!(v["running"], true, "{v}");
    assert_eq!(sim.drive(1)["state"], "running");

    // LED setting by communication: the drive's panel shows what was written.
    let v = json(&panel(pty, TOSHIBA, &["--show", "HELO", "--json"]));
    assert_eq!((v["display"].as_str(), v["led_by_communication"].as_bool()), (Some("HELO"), Some(true)));
    assert_eq!(sim.drive(1)["display"], "HELO");
    let o = panel(pty, TOSHIBA, &["--release", "--key", "stop"]);
    assert_eq!(o.code, 0, "{}{}", o.stdout, o.stderr);
    assert!(o.stdout.contains("pressed    stop"), "{}", o.stdout);
    assert_ne!(sim.drive(1)["display"], "HELO");

    // The generic drive's remote keypad: 2000H and 2001H through the line.
    let v = json(&panel(pty, GENERIC, &["--key", "run", "--key", "up", "--step", "40", "--json"]));
    assert_eq!(v["setpoint_hz"], 40.0, "{v}");
    assert_eq!(sim.drive(2)["state"], "running");
    let o = panel(pty, GENERIC, &[]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(o.stdout.contains("generic drive 2") && o.stdout.contains("running"), "{}", o.stdout);
}

#[test]
fn bad_panel_usage_exits_3_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let pty = dir.path().join("bus0");
    let pty = pty.to_str().unwrap();
    let _sim = Sim::start(&["generic@2:modbus-rtu"], pty);
    for (args, needle) in [
        (vec!["--key", "fly"], "unknown key \"fly\""),
        (vec!["--step", "0"], "--step 0"),
        (vec!["--show", "TOO LONG"], "up to 4"),
        (vec!["--show", "AB"], "Toshiba panel"),
    ] {
        let o = panel(pty, GENERIC, &args);
        assert_eq!(o.code, 3, "{args:?}: {}{}", o.stdout, o.stderr);
        assert_eq!(o.stderr.lines().count(), 1, "{args:?}: {}", o.stderr);
        assert!(o.stderr.contains(needle), "{args:?}: {}", o.stderr);
    }
}
