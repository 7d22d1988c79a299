//! `drivebus simulate` in the background and the `drivebus` command against it, for the
//! end-to-end tests.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

use serde_json::Value;

#[path = "lines.rs"]
mod lines;
#[path = "output.rs"]
mod output;
pub use lines::Killed;
pub use output::{output, Out};

/// A background process killed on drop, with the line it printed when ready.
pub struct Proc {
    _child: Killed,
    /// The rest of the ready line.
    pub ready: String,
    /// The lines printed before the ready line.
    pub before: Vec<String>,
}

impl Proc {
    /// Starts `cmd` and waits for the line that starts with `ready_prefix`.
    pub fn start(mut cmd: Command, ready_prefix: &str) -> Proc {
        let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::inherit()).spawn().expect("start");
        let mut lines = BufReader::new(child.stdout.take().expect("stdout")).lines();
        let mut before = Vec::new();
        let ready = loop {
            let line = lines.next().expect("ready line").expect("utf-8");
            if let Some(rest) = line.strip_prefix(ready_prefix) {
                break rest.trim().to_string();
            }
            before.push(line);
        };
        std::thread::spawn(move || for _ in lines {});
        Proc { _child: Killed(child), ready, before }
    }

    /// Where a simulator started with `--tcp` listens, as `--port` takes it (`tcp://HOST:PORT`),
    /// from its ready line (`listening on tcp HOST:PORT`).
    pub fn tcp_port(&self) -> String {
        format!("tcp://{}", self.ready.trim_start_matches("tcp "))
    }

    /// The simulator's control interface (`--control`), from the line it printed.
    pub fn control(&self) -> std::net::SocketAddr {
        let line =
            self.before.iter().find_map(|l| l.strip_prefix("control http://")).expect("a control line");
        line.trim_end_matches("/drives").parse().expect("the control address")
    }
}

/// `drivebus simulate --drive <drive> <endpoint...>`, ready once it listens.
pub fn simulate(drive: &str, endpoint: &[&str]) -> Proc {
    simulate_with(&[&["--drive", drive], endpoint].concat())
}

/// `drivebus simulate <args...>`, ready once it listens.
pub fn simulate_with(args: &[&str]) -> Proc {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.arg("simulate").args(args);
    Proc::start(cmd, "listening on ")
}

/// `drivebus --port <port> --drive <family> --address <address> [--protocol P] <args>`.
pub fn drivebus(port: &str, family: &str, protocol: Option<&str>, address: u8, args: &[&str]) -> Out {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    // A response timeout well above the simulator's answer time even on a loaded machine: a
    // retry sent while the drive still answers collides with its reply on the simulated
    // half-duplex line, and the tests here are about the commands, not the timing.
    cmd.args(["--port", port, "--drive", family, "--address", &address.to_string(), "--timeout", "1000"]);
    if let Some(p) = protocol {
        cmd.args(["--protocol", p]);
    }
    output(cmd.args(args))
}

/// Asserts exit status 0.
pub fn ok(o: &Out, what: &str) {
    assert_eq!(o.code, 0, "{what}: {}{}", o.stdout, o.stderr);
}

/// The Python Modbus master (pymodbus) that drives a simulated line: tests/interop/pymodbus_client.py.
pub fn pymodbus_client() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/interop/pymodbus_client.py")
}

/// A pty path of its own for a test.
pub fn pty_path(what: &str) -> String {
    std::env::temp_dir().join(format!("drivebus-{what}-{}", std::process::id())).to_string_lossy().to_string()
}

/// `status --json` of the drive, parsed.
pub fn status(port: &str, family: &str, protocol: Option<&str>, address: u8) -> Value {
    let o = drivebus(port, family, protocol, address, &["status", "--json"]);
    ok(&o, "status");
    serde_json::from_str(o.stdout.trim()).expect("status JSON")
}

/// Polls `status` until `done` holds for it, with a generous deadline (the ramp's pace is the
/// simulator's, not a speed claim of this test).
pub fn wait_status(
    port: &str,
    family: &str,
    protocol: Option<&str>,
    address: u8,
    what: &str,
    done: impl Fn(&Value) -> bool,
) -> Value {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    loop {
        let s = status(port, family, protocol, address);
        if done(&s) {
            return s;
        }
        assert!(std::time::Instant::now() < deadline, "{what}: {s}");
    }
}
