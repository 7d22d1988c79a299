//! `drivebus sniff` end to end: pymodbus (a Modbus master nobody here wrote) drives a simulated
//! generic drive over the simulator's pty while `drivebus sniff --json --write` listens on the
//! simulator's tap; tshark (nobody here wrote it either) decodes the capture; `--read` replays it.
//!
//! A plain `cargo test` lists the test as ignored (it needs the witnesses; `cargo test --
//! --ignored` runs it). `.ci/run` installs them and sets `DRIVEBUS_REQUIRE_INTEROP=1`, so in CI a
//! missing one is a failure.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::Value;

#[path = "support/sim.rs"]
mod sim;
#[path = "../../../tests/interop/witness.rs"]
mod witness;
use sim::{pymodbus_client, Proc};
use witness::witness;

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_drivebus")
}

/// `drivebus simulate` with a pty `bus` and a tap `tap` in `dir`, killed on drop.
fn simulate(dir: &Path, drive: &str) -> Proc {
    let mut cmd = Command::new(bin());
    cmd.args(["simulate", "--drive", drive, "--pty"]).arg(dir.join("bus")).arg("--tap").arg(dir.join("tap"));
    Proc::start(cmd, "listening on")
}

/// `drivebus sniff` running, its JSON lines arriving on a channel.
struct Sniff {
    child: Child,
    lines: mpsc::Receiver<Value>,
    seen: Vec<Value>,
}

impl Sniff {
    fn start(args: &[&str]) -> Sniff {
        let mut child = Command::new(bin())
            .arg("sniff")
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start drivebus sniff");
        // It says where it listens once the port is open and its old input dropped.
        let mut err = BufReader::new(child.stderr.take().expect("stderr")).lines();
        loop {
            match err.next() {
                Some(Ok(l)) if l.contains("listening on") => break,
                Some(Ok(_)) => continue,
                _ => panic!("drivebus sniff ended before listening"),
            }
        }
        std::thread::spawn(move || {
            for l in err.map_while(Result::ok) {
                eprintln!("sniff: {l}");
            }
        });
        let (tx, rx) = mpsc::channel();
        let out = BufReader::new(child.stdout.take().expect("stdout"));
        std::thread::spawn(move || {
            for l in out.lines().map_while(Result::ok) {
                let v: Value = serde_json::from_str(&l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}"));
                if tx.send(v).is_err() {
                    break;
                }
            }
        });
        Sniff { child, lines: rx, seen: Vec::new() }
    }

    /// Collects lines until `done` holds of them all, within a generous deadline.
    fn wait_for(&mut self, what: &str, done: impl Fn(&[Value]) -> bool) {
        let deadline = Instant::now() + Duration::from_secs(30);
        while !done(&self.seen) {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(v) => self.seen.push(v),
                Err(_) => panic!("sniff never showed {what}: {:#?}", self.seen),
            }
        }
    }

    /// Interrupts it as Ctrl-C does and waits for it to end.
    fn stop(mut self) -> Vec<Value> {
        #[allow(unsafe_code)]
        // SAFETY: kill(2) on our own child's pid with SIGINT has no memory-safety condition.
        unsafe {
            libc::kill(self.child.id() as i32, libc::SIGINT);
        }
        let status = self.child.wait().expect("wait for sniff");
        self.seen.extend(self.lines.iter());
        assert_eq!(status.code(), Some(0), "sniff heard valid frames: {:#?}", self.seen);
        std::mem::take(&mut self.seen)
    }
}

fn has_tshark() -> bool {
    witness::runs("tshark", &["--version"], true)
}

fn masters(v: &[Value]) -> usize {
    v.iter().filter(|f| f["direction"] == "master" && f.get("event").is_none()).count()
}

fn drives(v: &[Value]) -> usize {
    v.iter().filter(|f| f["direction"] == "drive").count()
}

fn register(f: &Value, name: &str) -> Option<u64> {
    f["fields"][name]["raw"].as_u64()
}

#[test]
#[ignore = "needs pymodbus and tshark (.ci/install-witnesses.sh)"]
fn sniff_sees_every_pymodbus_read_and_write_on_the_tap_and_tshark_decodes_the_capture() {
    if !witness("pymodbus", witness::python_has("pymodbus"), "pip install pymodbus pyserial")
        || !witness("tshark", has_tshark(), "apt-get install tshark")
    {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let _sim = simulate(dir.path(), "generic@1:modbus-rtu");
    let pcap = dir.path().join("cap.pcap");
    let tap = dir.path().join("tap");
    let mut sniff =
        Sniff::start(&["--port", tap.to_str().unwrap(), "--json", "--write", pcap.to_str().unwrap()]);
    let out = Command::new("python3")
        .arg(pymodbus_client())
        .arg("generic")
        .arg(dir.path().join("bus"))
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "pymodbus: {text}");
    // pymodbus got every reply, so every one crossed the line: wait until sniff shows them all.
    sniff.wait_for("every request answered", |v| masters(v) >= 5 && masters(v) == drives(v));
    let frames = sniff.stop();

    assert!(frames.iter().all(|f| f["valid"] == true && f["protocol"] == "modbus-rtu"), "{frames:#?}");
    assert!(frames.iter().all(|f| f["address"] == 1 && f["time"].as_f64().is_some()), "{frames:#?}");
    let reqs: Vec<&Value> = frames.iter().filter(|f| f["direction"] == "master").collect();
    // The two writes, with their registers and values.
    let w: Vec<(u64, u64)> = reqs
        .iter()
        .filter(|f| f["function"] == 6)
        .map(|f| (register(f, "register address").unwrap(), register(f, "register value").unwrap()))
        .collect();
    assert_eq!(w, [(0x2001, 4000), (0x2000, 1)], "{reqs:#?}");
    // The reads of 2103H, and the readings rising as the drive ramps.
    let reads = reqs.iter().filter(|f| f["function"] == 3).count();
    assert!(reads >= 3, "{reqs:#?}");
    assert!(reqs
        .iter()
        .filter(|f| f["function"] == 3)
        .all(|f| register(f, "starting address") == Some(0x2103)));
    let readings: Vec<u64> = frames
        .iter()
        .filter(|f| f["direction"] == "drive" && f["function"] == 3)
        .map(|f| register(f, "register value").unwrap())
        .collect();
    assert!(readings.last() > readings.first(), "{readings:?}");
    // Every reply follows its request with a latency: the drive's 5 ms plus wire time.
    for (i, f) in frames.iter().enumerate() {
        let is_reply = f["direction"] == "drive";
        assert_eq!(is_reply, i % 2 == 1, "requests and replies alternate: {frames:#?}");
        if is_reply {
            let l = f["latency_ms"].as_f64().unwrap_or_else(|| panic!("no latency: {f}"));
            assert!(l > 5.0 && l < 1000.0, "{f}");
            assert_eq!(f["function"], frames[i - 1]["function"]);
        } else {
            assert!(f.get("latency_ms").is_none(), "{f}");
        }
    }

    // tshark reads the capture's Modbus RTU frames with its own dissector.
    let t = Command::new("tshark")
        .arg("-r")
        .arg(&pcap)
        .args(["-o", "mbrtu.udp.port:502"])
        .args([
            "-T",
            "fields",
            "-e",
            "frame.packet_flags_direction",
            "-e",
            "mbrtu.unit_id",
            "-e",
            "modbus.func_code",
        ])
        .args(["-e", "modbus.reference_num", "-e", "modbus.regval_uint16", "-e", "modbus.request_frame"])
        .output()
        .expect("run tshark");
    let table = String::from_utf8_lossy(&t.stdout);
    assert!(t.status.success(), "tshark: {}", String::from_utf8_lossy(&t.stderr));
    let rows: Vec<Vec<&str>> = table.lines().map(|l| l.split('\t').collect()).collect();
    assert_eq!(rows.len(), frames.len(), "{table}");
    for (row, f) in rows.iter().zip(&frames) {
        let dir = if f["direction"] == "master" { "0x00000002" } else { "0x00000001" };
        assert_eq!(row[0], dir, "{table}");
        assert_eq!(row[1], "1", "{table}");
        assert_eq!(row[2], f["function"].to_string(), "{table}");
        // Queries with their registers, read responses with their value, and every response
        // tied to its query: tshark tells them apart by the UDP port.
        if f["direction"] == "master" {
            let reg = register(f, "starting address").or_else(|| register(f, "register address")).unwrap();
            assert_eq!(row[3], reg.to_string(), "{table}");
        } else {
            assert!(!row[5].is_empty(), "a response names its request: {table}");
            if f["function"] == 3 {
                assert_eq!(row[4], register(f, "register value").unwrap().to_string(), "{table}");
            }
        }
    }

    // --read replays the capture through the same analysis: the same frames, paired again.
    let r = Command::new(bin()).args(["sniff", "--json", "--read"]).arg(&pcap).output().unwrap();
    assert_eq!(r.status.code(), Some(0), "{}", String::from_utf8_lossy(&r.stderr));
    let again: Vec<Value> =
        String::from_utf8_lossy(&r.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(again.len(), frames.len());
    for (a, b) in again.iter().zip(&frames) {
        for k in ["time", "direction", "address", "function", "fields", "bytes"] {
            assert_eq!(a[k], b[k], "{k}");
        }
        assert_eq!(a.get("latency_ms").is_some(), b.get("latency_ms").is_some());
    }
    let summary = String::from_utf8_lossy(&r.stderr);
    assert!(summary.contains("modbus-rtu") && summary.contains("p99"), "{summary}");
}

/// A hex dump (`line.hex`) in a directory of its own, removed on drop.
struct Dump {
    dir: tempfile::TempDir,
}

impl Dump {
    fn new(text: &str) -> Dump {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("line.hex"), text).unwrap();
        Dump { dir }
    }

    /// `drivebus sniff <args> --read line.hex`, run to its end.
    fn read(&self, args: &[&str]) -> std::process::Output {
        Command::new(bin())
            .arg("sniff")
            .args(args)
            .arg("--read")
            .arg(self.dir.path().join("line.hex"))
            .output()
            .unwrap()
    }
}

#[test]
fn a_hex_dump_is_read_and_its_protocol_found() {
    // B800 (seed 000): P 40.00 Hz to drive 5, its 'p', R to drive 1, its 'r'.
    let dump = Dump::new(
        "# a B800 line\n7E 38 35 35 30 30 39 36 30 35 45 7F\n7E 30 35 37 30 33 33 7F\n7E 38 31 35 32 32 46 7F\n7E 30 31 37 32 33 35 7F\n",
    );
    let r = dump.read(&[]);
    let out = String::from_utf8_lossy(&r.stdout);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(0), "{out}{err}");
    assert!(out.contains("b800") && out.contains("40.00 Hz") && out.contains("→ ok"), "{out}");
    assert!(err.contains("b800") && err.contains("   5 "), "per-address statistics: {err}");
}

#[test]
fn bad_usage_exits_3_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let junk = dir.path().join("junk.hex");
    std::fs::write(&junk, "01 0Z\n").unwrap();
    for args in [
        vec!["sniff"],
        vec!["sniff", "--port", "/dev/null", "--port", "/dev/null", "--port", "/dev/null"],
        vec!["sniff", "--port", "tcp://127.0.0.1:1"],
        vec!["sniff", "--read", junk.to_str().unwrap()],
        vec!["sniff", "--protocol", "profibus", "--read", junk.to_str().unwrap()],
        vec!["sniff", "--count", "0", "--read", junk.to_str().unwrap()],
        vec!["sniff", "--baud", "fast", "--read", junk.to_str().unwrap()],
        vec!["status", "--port", "/dev/null", "--port", "/dev/null", "--drive", "b800", "--address", "1"],
    ] {
        let out = Command::new(bin()).args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(3), "{args:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{args:?}: one line: {err}");
    }
}

#[test]
fn a_drive_masters_broadcasts_are_named() {
    // A generic master drive's cycle, twice: 2001H = 40.00 Hz, then 2000H = 2 (forward run).
    let dump = Dump::new(
        "00 06 20 01 0F A0 D7 93\n00 06 20 00 00 02 02 1A\n00 06 20 01 0F A0 D7 93\n00 06 20 00 00 02 02 1A\n",
    );
    let r = dump.read(&[]);
    let out = String::from_utf8_lossy(&r.stdout);
    assert_eq!(r.status.code(), Some(0), "{out}");
    assert_eq!(out.matches("broadcast as a drive acting as bus master").count(), 4, "{out}");
    let r = dump.read(&["--json"]);
    let frames: Vec<Value> =
        String::from_utf8_lossy(&r.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(frames.len(), 4);
    assert!(frames.iter().all(|f| f["drive_master_broadcast"] == true), "{frames:?}");
}
