//! Interop with programs nobody here wrote, over a pseudo-terminal: pymodbus (PyPI) and mbpoll
//! (Debian) talk to `drivebus simulate`.
//!
//! A plain `cargo test` lists these tests as ignored (`cargo test -- --ignored` runs them).
//! `.ci/run` installs both and sets `DRIVEBUS_REQUIRE_INTEROP=1`, so in CI a missing witness is
//! a failure.

use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};

#[path = "support/sim.rs"]
mod sim;
#[path = "../../../tests/interop/witness.rs"]
mod witness;
use sim::{pymodbus_client, Proc};
use witness::witness;

static NEXT: AtomicUsize = AtomicUsize::new(0);

/// A `drivebus simulate` process with a pty, killed on drop.
struct Sim {
    _proc: Proc,
    pty: PathBuf,
}

impl Sim {
    fn start(drives: &[&str]) -> Sim {
        Sim::start_with(drives, &[])
    }

    fn start_with(drives: &[&str], extra: &[&str]) -> Sim {
        let pty = std::env::temp_dir().join(format!(
            "drivebus-interop-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::SeqCst)
        ));
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
        cmd.arg("simulate").arg("--pty").arg(&pty);
        for d in drives {
            cmd.arg("--drive").arg(d);
        }
        cmd.args(extra);
        // Ready once it says where it listens (an event, not a sleep).
        Sim { _proc: Proc::start(cmd, "listening on"), pty }
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.pty);
    }
}

fn has_mbpoll() -> bool {
    witness::runs("mbpoll", &["-V"], false)
}

fn pymodbus(family: &str, drive: &str, extra: &[&str]) {
    if !witness("pymodbus", witness::python_has("pymodbus"), "pip install pymodbus pyserial") {
        return;
    }
    let sim = Sim::start_with(&[drive], extra);
    let out = Command::new("python3")
        .arg(pymodbus_client())
        .arg(family)
        .arg(&sim.pty)
        .output()
        .expect("run python3");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "pymodbus against {drive}: {stdout}{stderr}");
    assert!(stdout.contains("ramps"), "{stdout}");
}

#[test]
#[ignore = "needs pymodbus (.ci/install-witnesses.sh)"]
fn pymodbus_runs_a_generic_drive_and_sees_2103h_ramp() {
    pymodbus("generic", "generic@1:modbus-rtu", &[]);
}

#[test]
#[ignore = "needs pymodbus (.ci/install-witnesses.sh)"]
fn pymodbus_runs_a_toshiba_drive_and_sees_fd00_ramp() {
    // 8N1: see the note in pymodbus_client.py (pyserial, exclusive lock, even parity, pty).
    pymodbus("toshiba", "toshiba@1:modbus-rtu", &["--serial", "8N1"]);
}

fn mbpoll(sim: &Sim, args: &[&str]) -> String {
    let out = Command::new("mbpoll").args(args).arg(&sim.pty).output().expect("run mbpoll");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "mbpoll {args:?}: {text}");
    text
}

#[test]
#[ignore = "needs mbpoll (.ci/install-witnesses.sh)"]
fn mbpoll_reads_the_generic_and_toshiba_registers() {
    if !witness("mbpoll", has_mbpoll(), "apt-get install mbpoll") {
        return;
    }
    // Generic drive, RTU 9600 8N2: 2103H output frequency (0-based reference 8451) and
    // 210BH software version.
    let sim = Sim::start(&["generic@1:modbus-rtu"]);
    let common = [
        "-m", "rtu", "-a", "1", "-b", "9600", "-d", "8", "-P", "none", "-s", "2", "-t", "4", "-0", "-1",
        "-o", "1",
    ];
    let text = mbpoll(&sim, &[&common[..], &["-r", "8451", "-c", "1"]].concat());
    assert!(
        text.contains("[8451]: \t0") || text.contains("[8451]:\t0") || text.contains("[8451]: 0"),
        "{text}"
    );
    let text = mbpoll(&sim, &[&common[..], &["-r", "8448", "-c", "4"]].concat());
    assert!(text.contains("[8451]"), "four registers from 2100H: {text}");
    drop(sim);
    // Toshiba drive on Modbus-RTU, 19200 8E1: FD00 output frequency (64768), one word only.
    let sim = Sim::start(&["toshiba@1:modbus-rtu"]);
    let text = mbpoll(
        &sim,
        &[
            "-m", "rtu", "-a", "1", "-b", "19200", "-d", "8", "-P", "even", "-s", "1", "-t", "4", "-0", "-1",
            "-o", "1", "-r", "64768", "-c", "1",
        ],
    );
    assert!(text.contains("[64768]"), "{text}");
}
