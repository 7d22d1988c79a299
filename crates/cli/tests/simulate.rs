//! `drivebus simulate` end to end over TCP: drives answer as their manuals say, and the
//! control interface silences, trips, injects noise and reports state at run time.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Command, Stdio};
use std::time::Duration;

use serde_json::Value;

#[path = "support/http.rs"]
mod http;
#[path = "support/sim.rs"]
mod sim;
use http::request;
use sim::Proc;

/// `drivebus simulate <args>` on TCP with a control interface, killed on drop.
struct Sim {
    proc: Proc,
    bus: String,
}

impl Sim {
    fn start(args: &[&str]) -> Sim {
        let proc =
            sim::simulate_with(&[args, &["--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"]].concat());
        Sim { bus: proc.ready.trim_start_matches("tcp ").to_string(), proc }
    }

    /// `method path` with a JSON body to the control interface: the status and the JSON answer
    /// (null when the answer is not JSON).
    fn http(&self, method: &str, path: &str, body: &str) -> (u16, Value) {
        let (status, text) = request(self.proc.control(), method, path, None, Some(body));
        (status, serde_json::from_str(&text).unwrap_or(Value::Null))
    }
}

/// Sends `req` and collects what comes back until `until` bytes arrived or the line is quiet.
fn exchange(bus: &mut TcpStream, req: &[u8], until: usize) -> Vec<u8> {
    bus.write_all(req).unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 256];
    bus.set_read_timeout(Some(Duration::from_millis(400))).unwrap();
    while got.len() < until {
        match bus.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => got.extend_from_slice(&buf[..n]),
        }
    }
    got
}

fn b800(frame: &str) -> Vec<u8> {
    let digits: Vec<u8> = frame.bytes().collect();
    let cs = !digits.iter().fold(0u8, |a, &b| a.wrapping_add(b));
    let mut v = vec![0x7E];
    v.extend_from_slice(&digits);
    v.extend_from_slice(format!("{cs:02X}").as_bytes());
    v.push(0x7F);
    v
}

#[test]
fn b800_drive_over_tcp_with_control_interface() {
    let sim = Sim::start(&["--drive", "b800@5", "--drive", "b800@6"]);
    let mut bus = TcpStream::connect(&sim.bus).expect("connect bus");
    // The seed's example: P 40.0 Hz to drive 5, answered 'p'.
    assert_eq!(exchange(&mut bus, &b800("85500960"), 8), b"\x7E0570\x33\x33\x7F");
    // R runs it; the control interface sees it running with its setpoint.
    assert_eq!(exchange(&mut bus, &b800("8552"), 8), b800("0572"));
    let (code, d) = sim.http("GET", "/drives/1", "");
    assert_eq!(code, 200);
    assert_eq!(d["state"], "running");
    assert_eq!(d["setpoint_hz"], 40.0);
    assert_eq!(d["address"], 5);

    // Silenced, it hears but does not answer.
    let (code, _) = sim.http("POST", "/drives/1", r#"{"silent": true}"#);
    assert_eq!(code, 200);
    assert!(exchange(&mut bus, &b800("8554"), 1).is_empty());
    sim.http("POST", "/drives/1", r#"{"silent": false}"#);

    // Tripped, a run command gets e 9A.
    sim.http("POST", "/drives/2", r#"{"trip": "over-current"}"#);
    let reply = exchange(&mut bus, &b800("8652"), 10);
    assert_eq!(&reply[..5], b"\x7E0665", "{reply:?}");
    assert_eq!(&reply[5..7], b"9A");
    let (_, d) = sim.http("GET", "/drives/2", "");
    assert_eq!(d["trip"], "over-current");
    assert_eq!(d["trip_log"].as_array().map(|a| a.len()), Some(1));

    // Noise on every byte: the drive sees a bad frame and does not answer as usual.
    let (code, f) = sim.http("PUT", "/faults", r#"{"corrupt_rate": 1.0}"#);
    assert_eq!((code, f["corrupt_rate"].as_f64()), (200, Some(1.0)));
    let reply = exchange(&mut bus, &b800("8554"), 8);
    assert_ne!(reply, b800("0574"));
    sim.http("PUT", "/faults", r#"{"corrupt_rate": 0.0}"#);

    // Parameters as on the keypad: F-12 = 0 (terminals) makes R an error 91.
    let (code, _) = sim.http("POST", "/drives/1", r#"{"params": {"F-12": 0}}"#);
    assert_eq!(code, 200);
    let reply = exchange(&mut bus, &b800("8552"), 10);
    assert_eq!(&reply[..7], b"\x7E056591", "{reply:?}");
    let (code, e) = sim.http("POST", "/drives/1", r#"{"params": {"F-12": 7}}"#);
    assert_eq!(code, 422);
    assert!(e["error"].as_str().unwrap().contains("F-12"), "{e}");
    // A power cycle stops the motor.
    let (code, d) = sim.http("POST", "/drives/1", r#"{"power_cycle": true}"#);
    assert_eq!((code, d["state"].as_str()), (200, Some("stopped")));

    // Bad requests get a 4xx with a sentence.
    let (code, e) = sim.http("POST", "/drives/9", r#"{"load": 1}"#);
    assert_eq!(code, 404);
    assert!(e["error"].as_str().unwrap().contains("numbered 1..2"));
    let (code, e) = sim.http("POST", "/drives/1", r#"{"load": 9}"#);
    assert_eq!(code, 422);
    assert!(e["error"].as_str().unwrap().contains("0..5"));
    let (code, _) = sim.http("POST", "/drives/1", "{not json");
    assert_eq!(code, 400);
    let (code, e) = sim.http("PUT", "/faults", r#"{"drop_rate": 2}"#);
    assert_eq!(code, 422);
    assert!(e["error"].as_str().unwrap().contains("probability"));
}

/// A simulator's process (killed on drop), its `listening on` lines in order (one per master),
/// its control address and the lines it prints after them.
type Masters = (sim::Killed, Vec<String>, std::net::SocketAddr, std::sync::mpsc::Receiver<String>);

/// `drivebus simulate <args>` with a control interface.
fn start_masters(args: &[&str], masters: usize) -> Masters {
    let mut child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .arg("simulate")
        .args(args)
        .args(["--control", "127.0.0.1:0"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let (mut ready, mut control) = (Vec::new(), None);
    while ready.len() < masters {
        let line = lines.next().expect("a ready line").unwrap();
        if let Some(c) = line.strip_prefix("control http://") {
            control = Some(c.trim_end_matches("/drives").parse().unwrap());
        }
        if let Some(at) = line.strip_prefix("listening on ") {
            ready.push(at.to_string());
        }
    }
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in lines.map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    (sim::Killed(child), ready, control.expect("a control line"), rx)
}

/// Waits (generously) for a printed line containing `what`.
fn wait_line(rx: &std::sync::mpsc::Receiver<String>, what: &str) -> String {
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        match rx.recv_timeout(left) {
            Ok(l) if l.contains(what) => return l,
            Ok(_) => {}
            Err(_) => panic!("no line with {what:?}"),
        }
    }
}

/// Reads from `bus` until `want` bytes came, with a generous deadline.
fn read_n(bus: &mut TcpStream, want: usize) -> Vec<u8> {
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    let mut got = Vec::new();
    let mut buf = [0u8; 256];
    bus.set_read_timeout(Some(Duration::from_millis(200))).unwrap();
    while got.len() < want && std::time::Instant::now() < deadline {
        if let Ok(n) = bus.read(&mut buf) {
            assert!(n > 0, "the simulator closed the port");
            got.extend_from_slice(&buf[..n]);
        }
    }
    got
}

#[test]
fn several_masters_share_one_line_hear_each_other_and_garble_when_they_talk_at_once() {
    let (_sim, ready, control, printed) = start_masters(
        &["-v", "--drive", "b800@5", "--tcp", "127.0.0.1:0", "--tcp", "127.0.0.1:0", "--tcp", "127.0.0.1:0"],
        3,
    );
    assert!(ready[0].ends_with("(master 0)") && ready[2].ends_with("(master 2)"), "{ready:?}");
    let addr = |i: usize| ready[i].trim_start_matches("tcp ").split(' ').next().unwrap().to_string();
    let mut a = TcpStream::connect(addr(0)).unwrap();
    let mut b = TcpStream::connect(addr(1)).unwrap();
    let mut c = TcpStream::connect(addr(2)).unwrap();
    let stats = || {
        let (status, text) = request(control, "GET", "/stats", None, None);
        assert_eq!(status, 200);
        serde_json::from_str::<Value>(&text).unwrap()
    };
    assert_eq!(stats()["masters"], 3);
    // A asks; A gets the answer, B and C hear the request and then the answer.
    let (req, reply) = (b800("85500960"), b"\x7E0570\x33\x33\x7F".to_vec());
    assert_eq!(exchange(&mut a, &req, reply.len()), reply);
    let heard = [req.clone(), reply.clone()].concat();
    assert_eq!(read_n(&mut b, heard.len()), heard);
    assert_eq!(read_n(&mut c, heard.len()), heard);
    // B asks: the drive answers B, and A hears both.
    let run = b800("8552");
    assert_eq!(exchange(&mut b, &run, 8), b800("0572"));
    assert_eq!(read_n(&mut a, run.len() + 8), [run.clone(), b800("0572")].concat());
    assert_eq!(read_n(&mut c, run.len() + 8), [run.clone(), b800("0572")].concat());
    // -v prints every frame once, each request with the master that sent it.
    wait_line(&printed, "[master 0] b800 master to drive 5");
    let b_request = wait_line(&printed, "[master 1] b800 master to drive 5");
    let answer = wait_line(&printed, "b800 drive 5 to master");
    assert!(!answer.contains("[master"), "{b_request} / {answer}");
    let s = stats();
    assert_eq!((s["collisions"].as_u64(), s["garbled_frames"].as_u64()), (Some(0), Some(0)), "{s}");
    // A and B at once: 60 characters each (69 ms on the wire at 9600 baud) overlap, and the line
    // counts both frames as garbled.
    let long = vec![b'0'; 60];
    a.write_all(&long).unwrap();
    b.write_all(&long).unwrap();
    let heard = read_n(&mut c, 120);
    assert_eq!(heard.len(), 120, "C hears both frames' characters");
    assert_ne!(heard, [long.clone(), long.clone()].concat(), "garbled, not as sent");
    let s = stats();
    assert_eq!(s["garbled_frames"].as_u64(), Some(2), "{s}");
    assert!(s["collisions"].as_u64() > Some(0), "{s}");
    assert_eq!(s["garbled_frames_by_master"], serde_json::json!([1, 1, 0]), "A's frame and B's: {s}");
}

#[test]
fn the_same_pty_path_twice_is_refused() {
    let path = sim::pty_path("twice");
    let o = sim::output(
        Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["simulate", "--drive", "b800@5", "--pty", &path, "--pty", &path]),
    );
    assert_eq!(o.code, 3, "{}{}", o.stdout, o.stderr);
    assert!(o.stderr.contains("given twice"), "{}", o.stderr);
}

#[test]
fn bad_options_exit_3_with_one_line() {
    for args in [
        vec!["simulate", "--drive", "b800@64", "--tcp", "127.0.0.1:0"],
        vec!["simulate", "--drive", "pump@1", "--tcp", "127.0.0.1:0"],
        vec!["simulate", "--drive", "b800@1"],
        vec!["simulate", "--drive", "generic@1", "--serial", "9Z1", "--tcp", "127.0.0.1:0"],
        vec!["simulate", "--config", "/nonexistent/bus.toml", "--tcp", "127.0.0.1:0"],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_drivebus")).args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(3), "{args:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{args:?}: one line: {err}");
    }
}

/// Stopped by SIGTERM (as `kill` or a service manager stops it) or SIGINT (Ctrl-C), the
/// simulator removes its pty symlink.
#[test]
fn a_stopped_simulator_removes_its_pty_link() {
    for signal in ["-TERM", "-INT"] {
        let link = std::env::temp_dir().join(format!("drivebus-sim-signal{signal}-{}", std::process::id()));
        let mut child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["simulate", "--drive", "generic@1:modbus-rtu", "--pty"])
            .arg(&link)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start drivebus simulate");
        let mut lines = BufReader::new(child.stdout.take().expect("stdout")).lines();
        while !lines.next().expect("a ready line").expect("utf-8").starts_with("listening on pty") {}
        assert!(link.symlink_metadata().is_ok(), "the link is there while it runs");
        let sent = Command::new("kill").args([signal, &child.id().to_string()]).status().expect("kill");
        assert!(sent.success());
        let status = child.wait().expect("wait");
        assert!(status.success(), "{signal}: {status}");
        assert!(link.symlink_metadata().is_err(), "{signal}: {} is left behind", link.display());
    }
}

#[test]
fn the_tap_carries_both_directions_of_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let tap_path = dir.path().join("tap");
    let tap_arg = tap_path.to_str().unwrap();
    let sim = Sim::start(&["--drive", "b800@5", "--tap", tap_arg]);
    let mut tap = std::fs::File::open(&tap_path).expect("open the tap");
    let mut bus = TcpStream::connect(&sim.bus).expect("connect bus");
    let request = b800("85500960");
    let reply = exchange(&mut bus, &request, 8);
    assert_eq!(reply, b"\x7E0570\x33\x33\x7F");
    // The tap hears the request, then the reply, whatever it held before is of no matter.
    let mut want = request.clone();
    want.extend_from_slice(&reply);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut got = Vec::new();
        let mut buf = [0u8; 256];
        while let Ok(n) = tap.read(&mut buf) {
            got.extend_from_slice(&buf[..n]);
            if tx.send(got.clone()).is_err() {
                break;
            }
        }
    });
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    let mut seen = Vec::new();
    while !seen.windows(want.len()).any(|w| w == want.as_slice()) {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        seen = rx.recv_timeout(left).unwrap_or_else(|_| panic!("the tap carried {seen:02X?}"));
    }
    // Writing to the tap does not reach the line: a listener never talks.
    let mut tap_w = std::fs::OpenOptions::new().write(true).open(&tap_path).unwrap();
    tap_w.write_all(&b800("8552")).unwrap();
    let (_, d) = sim.http("GET", "/drives/1", "");
    assert_eq!(d["state"], "stopped", "a run written to the tap must not reach the drive");
}

/// Polls `GET /drives/{n}` until `ok` holds for its JSON, for at most 30 s.
fn wait_drive(sim: &Sim, n: usize, what: &str, ok: impl Fn(&Value) -> bool) -> Value {
    let start = std::time::Instant::now();
    loop {
        let (_, d) = sim.http("GET", &format!("/drives/{n}"), "");
        if ok(&d) {
            return d;
        }
        assert!(start.elapsed() < Duration::from_secs(30), "drive {n}: timed out waiting for {what}: {d}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_generic_master_drive_runs_its_followers_through_the_control_interface() {
    let dir = tempfile::tempdir().unwrap();
    let bus = dir.path().join("bus.toml");
    // Short ramps (0.5 s to 50 Hz) so the test waits little.
    std::fs::write(
        &bus,
        r#"
[[drive]]
kind = "generic"
address = 1
protocol = "modbus-rtu"
role = "master"
keypad_hz = 40
params = { "P0.07" = "0.5", "P0.08" = "0.5" }

[[drive]]
kind = "generic"
address = 2
protocol = "modbus-rtu"
params = { "P0.07" = "0.5", "P0.08" = "0.5" }

[[drive]]
kind = "generic"
address = 3
protocol = "modbus-rtu"
params = { "P0.07" = "0.5", "P0.08" = "0.5" }
"#,
    )
    .unwrap();
    let sim = Sim::start(&["--config", bus.to_str().unwrap()]);
    let (status, master) = sim.http("POST", "/drives/1", r#"{"run": true}"#);
    assert_eq!(status, 200, "{master}");
    assert_eq!(master["role"], "master");
    for n in 1..=3 {
        wait_drive(&sim, n, "40 Hz", |d| d["state"] == "running" && d["output_hz"] == 40.0);
    }
    sim.http("POST", "/drives/1", r#"{"run": false}"#);
    for n in 2..=3 {
        wait_drive(&sim, n, "a stop", |d| d["state"] == "stopped");
    }
    // A follower's keypad RUN is refused: its run commands come from communication.
    let (status, err) = sim.http("POST", "/drives/2", r#"{"run": true}"#);
    assert_eq!(status, 409, "{err}");
    assert!(err["error"].as_str().unwrap_or_default().contains("P0.01 = 0"), "{err}");
}

#[test]
fn a_toshiba_master_drive_its_proportional_follower_and_f806_when_it_fails() {
    let dir = tempfile::tempdir().unwrap();
    let bus = dir.path().join("bus.toml");
    let ramps = r#""0009" = "0.1 s", "0010" = "0.1 s", "0012" = "80 Hz""#;
    std::fs::write(
        &bus,
        format!(
            r#"
[[drive]]
kind = "toshiba"
address = 10
role = "master"
params = {{ f806 = 3, {ramps} }}

[[drive]]
kind = "toshiba"
address = 1
params = {{ f806 = 2, f803 = 1, f810 = 1, f813 = 100, f814 = "40 Hz", {ramps} }}
"#
        ),
    )
    .unwrap();
    let sim = Sim::start(&["--config", bus.to_str().unwrap()]);
    let (status, m) = sim.http("POST", "/drives/1", r#"{"keypad_hz": 80, "run": true}"#);
    assert_eq!(status, 200, "{m}");
    wait_drive(&sim, 2, "40 Hz (80 Hz = 100 % of the master's FH)", |d| d["output_hz"] == 40.0);
    // The master fails: after f803 = 1 s the follower trips (f806 = 2: emergency stop).
    sim.http("POST", "/drives/1", r#"{"silent": true}"#);
    let d = wait_drive(&sim, 2, "the trip", |d| d["state"] == "tripped");
    assert_eq!(d["trip"], "external trip");
}
