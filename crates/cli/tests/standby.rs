//! Two `drivebus serve` processes on one simulated line of 8 drives (`drivebus simulate` with two
//! ptys, one per gateway): the standby serves what it hears, takes the line within 1.5 s of a
//! `kill -9` of the master, and the old master restarted stays standby; two started at once end
//! with one master, and after that the other sends nothing and none of its frames is garbled (a
//! frame of the master's garbled with a drive's late reply on a loaded machine must come with a
//! reply the master missed; the counts are printed).
//!
//! A gateway that hears another master (`drivebus monitor` on the other pty) yields and takes the
//! line back when that one falls silent; a standby that takes over polls at the intervals it
//! learnt from the master, not at its own `poll_ms`.
//!
//! `DRIVEBUS_STANDBY_KILLS=20` runs twenty kills (three by default) and prints the takeover
//! times.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::Value;

#[path = "support/http.rs"]
mod http;
#[path = "support/sim.rs"]
mod sim;
use http::free_port;
use sim::Killed;

const DRIVES: u8 = 8;
/// The write token of the test's gateways (made up for the test).
const TOKEN: &str = "standby-test-token-0123456789abcdef";

/// `drivebus simulate` with 8 generic Modbus RTU drives and two ptys; its control address.
fn simulate(dir: &Path) -> (Killed, [PathBuf; 2], SocketAddr) {
    let ptys = [dir.join("pty-a"), dir.join("pty-b")];
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.arg("simulate");
    for a in 1..=DRIVES {
        cmd.args(["--drive", &format!("generic@{a}:modbus-rtu")]);
    }
    cmd.arg("--pty").arg(&ptys[0]).arg("--pty").arg(&ptys[1]).args(["--control", "127.0.0.1:0"]);
    let mut child = cmd.stdout(Stdio::piped()).spawn().expect("start simulate");
    let mut out = BufReader::new(child.stdout.take().unwrap()).lines();
    let (mut ready, mut control) = (0, None);
    while ready < 2 {
        let l = out.next().expect("simulate's lines").unwrap();
        if let Some(c) = l.strip_prefix("control http://") {
            control = Some(c.trim_end_matches("/drives").parse().unwrap());
        }
        ready += usize::from(l.starts_with("listening on "));
    }
    std::thread::spawn(move || for _ in out {});
    (Killed(child), ptys, control.expect("control"))
}

/// The configuration of a gateway on `pty`: the 8 drives, each polled every 500 ms.
fn config(dir: &Path, name: &str, pty: &Path, role: &str) -> PathBuf {
    config_polling(dir, name, pty, role, &[500; DRIVES as usize])
}

/// The configuration of a gateway on `pty`: drive `d{a}` at address `a` polled every
/// `poll_ms[a - 1]` ms, for each of `poll_ms`.
fn config_polling(dir: &Path, name: &str, pty: &Path, role: &str, poll_ms: &[u64]) -> PathBuf {
    let mut text = format!(
        "name = \"{name}\"\n[[token]]\nname = \"ops\"\ntoken = \"{TOKEN}\"\nrole = \"write\"\n\
         [http]\nanonymous_read = true\n[standby]\nrole = \"{role}\"\nsilence_ms = 500\n\
         [[bus]]\nname = \"line\"\nport = \"{}\"\nprotocol = \"modbus-rtu\"\n",
        pty.display()
    );
    for (a, poll) in (1..).zip(poll_ms) {
        text.push_str(&format!(
            "[[bus.drive]]\nname = \"d{a}\"\nfamily = \"generic\"\naddress = {a}\npoll_ms = {poll}\n"
        ));
    }
    let file = dir.join(format!("{name}.toml"));
    std::fs::write(&file, text).unwrap();
    file
}

/// A `drivebus serve` process.
struct Gateway {
    child: Option<Killed>,
    http: SocketAddr,
    /// Its log (stderr), line by line as it comes.
    log: Arc<Mutex<Vec<String>>>,
}

impl Gateway {
    fn start(config: &Path, standby: bool) -> Gateway {
        let http: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
        let modbus = format!("127.0.0.1:{}", free_port());
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
        cmd.args(["serve", "--no-opcua", "--http", &http.to_string(), "--modbus", &modbus, "--config"])
            .arg(config)
            .arg("--db")
            .arg(config.with_extension("db"));
        if standby {
            cmd.arg("--standby");
        }
        let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("start serve");
        let log = Arc::new(Mutex::new(Vec::new()));
        let (err, kept) = (BufReader::new(child.stderr.take().unwrap()), log.clone());
        std::thread::spawn(move || {
            for l in err.lines().map_while(Result::ok) {
                kept.lock().unwrap().push(l);
            }
        });
        let out = BufReader::new(child.stdout.take().unwrap());
        let mut lines = out.lines();
        // The listeners are bound when the banner's HTTP line is out.
        for l in lines.by_ref() {
            if l.unwrap().contains("HTTP API") {
                break;
            }
        }
        std::thread::spawn(move || for _ in lines {});
        Gateway { child: Some(Killed(child)), http, log }
    }

    fn get(&self, path: &str) -> Value {
        match http::http_json(self.http, "GET", path, None) {
            Ok((200, v)) => v,
            other => panic!("GET {path}: {other:?}"),
        }
    }

    fn role(&self) -> String {
        self.get("/api/buses")[0]["role"].as_str().unwrap_or_default().to_string()
    }

    fn transactions(&self) -> u64 {
        self.get("/api/buses")[0]["transactions"].as_u64().unwrap_or(0)
    }

    /// The value of the metric `name` of the bus `line` in `/metrics`.
    fn bus_metric(&self, name: &str) -> f64 {
        let (status, text) = http::request(self.http, "GET", "/metrics", None, None);
        assert_eq!(status, 200, "{text}");
        let series = format!("{name}{{bus=\"line\"}} ");
        let line = text.lines().find_map(|l| l.strip_prefix(series.as_str()));
        line.unwrap_or_else(|| panic!("no {series}in /metrics:\n{text}")).trim().parse().unwrap()
    }

    /// The events of `kind` on the bus `line`.
    fn bus_events(&self, kind: &str) -> Vec<Value> {
        let v = self.get(&format!("/api/events?kind={kind}"));
        v.as_array().unwrap().iter().filter(|e| e["bus"] == "line").cloned().collect()
    }

    /// Each drive's status polls so far (`/api/drives`' `polls`), by name.
    fn polls(&self) -> std::collections::HashMap<String, u64> {
        let v = self.get("/api/drives");
        v.as_array()
            .unwrap()
            .iter()
            .map(|d| (d["id"].as_str().unwrap().to_string(), d["polls"].as_u64().unwrap()))
            .collect()
    }

    /// `kill -9`.
    fn kill9(&mut self) {
        if let Some(mut k) = self.child.take() {
            let _ = k.0.kill();
            let _ = k.0.wait();
        }
    }
}

/// Waits (generously) until `done`.
fn wait(what: &str, done: impl Fn() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(60);
    while !done() {
        assert!(Instant::now() < deadline, "{what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Every drive's data age as the gateway reports it, ms (`None`: no value yet).
fn ages(g: &Gateway) -> Vec<Option<u64>> {
    g.get("/api/drives").as_array().unwrap().iter().map(|d| d["age_ms"].as_u64()).collect()
}

/// What the simulated line has carried (`GET /stats`).
fn stats(control: SocketAddr) -> Value {
    http::http_json(control, "GET", "/stats", None).unwrap().1
}

fn garbled(control: SocketAddr) -> u64 {
    stats(control)["garbled_frames"].as_u64().unwrap()
}

#[test]
fn the_standby_takes_over_a_killed_master_and_the_old_one_stays_standby() {
    let dir = tempfile::tempdir().unwrap();
    let (_sim, ptys, control) = simulate(dir.path());
    let configs = [config(dir.path(), "a", &ptys[0], "active"), config(dir.path(), "b", &ptys[1], "active")];
    let mut gw = [Gateway::start(&configs[0], false), Gateway::start(&configs[1], true)];
    wait("a masters the line", || gw[0].role() == "master");
    wait("b serves every drive from what it hears", || {
        gw[1].role() == "standby" && ages(&gw[1]).iter().all(|a| a.is_some_and(|a| a < 2500))
    });
    assert_eq!(gw[1].transactions(), 0, "a standby sends nothing");
    // A command to the standby is refused with the reason, and sent nowhere.
    let (status, text) =
        http::request(gw[1].http, "POST", "/api/drives/d1/speed", Some(TOKEN), Some(r#"{"hz": 30}"#));
    assert_eq!(status, 503, "{text}");
    let v: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["error"]["kind"], "standby", "{v}");
    assert!(v["error"]["message"].as_str().unwrap().contains("standby"), "{v}");
    assert_eq!(gw[1].transactions(), 0);
    let events = gw[1].get("/api/events?kind=command");
    assert!(events.to_string().contains("standby"), "the refusal is audited: {events}");
    let kills: usize = std::env::var("DRIVEBUS_STANDBY_KILLS").ok().and_then(|v| v.parse().ok()).unwrap_or(3);
    let mut took = Vec::new();
    let mut worsts = Vec::new();
    let mut master = 0;
    for kill in 0..kills {
        let standby = 1 - master;
        let sent = gw[standby].transactions();
        gw[master].kill9();
        let killed = Instant::now();
        // The standby polls within 1.5 s, and no drive's age goes over 2.5 s meanwhile.
        let mut worst = 0;
        loop {
            worst = worst.max(ages(&gw[standby]).iter().map(|a| a.unwrap_or(u64::MAX)).max().unwrap());
            if gw[standby].role() == "master" && gw[standby].transactions() > sent {
                break;
            }
            assert!(killed.elapsed() < Duration::from_secs(10), "kill {kill}: no takeover");
            std::thread::sleep(Duration::from_millis(10));
        }
        took.push(killed.elapsed());
        wait("the takeover is an event", || {
            let v = gw[standby].get("/api/events?kind=takeover");
            v.as_array().is_some_and(|a| a.iter().any(|e| e["bus"] == "line"))
        });
        worsts.push(worst);
        assert!(worst <= 2500, "kill {kill}: a drive's data was {worst} ms old");
        // The old master restarted (as configured: active) hears the new one and stays standby.
        gw[master] = Gateway::start(&configs[master], false);
        let restarted = Instant::now();
        wait("the restarted one serves values", || {
            ages(&gw[master]).iter().all(|a| a.is_some_and(|a| a < 2500))
        });
        while restarted.elapsed() < Duration::from_secs(1) {
            std::thread::sleep(Duration::from_millis(50));
        }
        assert_eq!(gw[master].role(), "standby", "kill {kill}: the restarted one stays standby");
        assert_eq!(gw[standby].role(), "master");
        master = standby;
    }
    took.sort();
    println!("the oldest data age the standby showed until it polled, per kill (ms): {worsts:?}");
    println!(
        "takeover over {} kills: min {:?}, median {:?}, max {:?}; garbled frames on the line: {}",
        took.len(),
        took[0],
        took[took.len() / 2],
        took[took.len() - 1],
        garbled(control)
    );
    assert!(took.iter().all(|t| *t <= Duration::from_millis(1500)), "{took:?}");
}

#[test]
fn two_gateways_started_at_once_end_with_one_master_and_a_quiet_line() {
    let dir = tempfile::tempdir().unwrap();
    let (_sim, ptys, control) = simulate(dir.path());
    let configs = [config(dir.path(), "a", &ptys[0], "active"), config(dir.path(), "b", &ptys[1], "active")];
    let (c0, c1) = (configs[0].clone(), configs[1].clone());
    let t0 = std::thread::spawn(move || Gateway::start(&c0, false));
    let g1 = Gateway::start(&c1, false);
    let g0 = t0.join().unwrap();
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(50));
    }
    wait("one master", || {
        let roles = [g0.role(), g1.role()];
        roles.iter().filter(|r| *r == "master").count() == 1
    });
    // From here one gateway sends and the other only listens. Proved strictly: the standby
    // sends nothing and none of its frames is garbled, so no two masters talk at once. The
    // master alone may still garble a frame with a drive's reply when a process is starved
    // under load (the line's time is the wall clock; a simulated drive answers within a few ms,
    // so a timeout on this line is a starved process): it gives up on a reply the simulator
    // has not delivered yet and sends again while that reply is on the line. So each garbled
    // frame of the master's must come with a reply it did not get (a timeout or a damaged reply,
    // counted by the master itself); one without fails the test.
    let master = usize::from(g1.role() == "master");
    let g = [&g0, &g1];
    let bus0 = g.map(|g| g.get("/api/buses")[0].clone());
    let line0 = stats(control);
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(3) {
        let roles = [g0.role(), g1.role()];
        assert_eq!(roles.iter().filter(|r| *r == "master").count(), 1, "{roles:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
    let line1 = stats(control);
    // What a frame garbled at the end did to the master's exchange is counted once it is over.
    let sent = g[master].transactions();
    wait("the master's exchanges go on", || g[master].transactions() >= sent + 2);
    let bus1 = g.map(|g| g.get("/api/buses")[0].clone());
    let grown = |v0: &Value, v1: &Value, key: &str| v1[key].as_u64().unwrap() - v0[key].as_u64().unwrap();
    let by_master = |v: &Value, m: usize| v["garbled_frames_by_master"][m].as_u64().unwrap();
    let standby = 1 - master;
    let seen = format!("line {line0} -> {line1}; master {} -> {}", bus0[master], bus1[master]);
    assert_eq!(grown(&bus0[standby], &bus1[standby], "transactions"), 0, "the standby sent nothing: {seen}");
    assert_eq!(by_master(&line1, standby), by_master(&line0, standby), "{seen}");
    let master_garbled = by_master(&line1, master) - by_master(&line0, master);
    let missed = grown(&bus0[master], &bus1[master], "timeouts")
        + grown(&bus0[master], &bus1[master], "checksum_errors");
    assert!(master_garbled <= missed, "a garbled frame of the master's without a reply it missed: {seen}");
    let before = line0["garbled_frames"].as_u64().unwrap();
    println!(
        "after settling: the standby sent nothing; {master_garbled} frames of the master garbled, {} in all, \
         with {missed} replies it missed (timeouts and damaged replies of a loaded machine)",
        grown(&line0, &line1, "garbled_frames")
    );
    println!("garbled frames at the common start: {before}");
}

/// `drivebus monitor` polling drive 1 every 100 ms on `pty`: another master on the line. The
/// count of its refreshes that got the drive's answer goes up as it prints them.
fn monitor(pty: &Path) -> (Killed, Arc<Mutex<u64>>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .arg("--port")
        .arg(pty)
        .args(["--drive", "generic", "--protocol", "modbus-rtu", "--address", "1"])
        .args(["monitor", "--plain", "--interval", "100"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start monitor");
    let answered = Arc::new(Mutex::new(0));
    let (out, count) = (BufReader::new(child.stdout.take().unwrap()), answered.clone());
    std::thread::spawn(move || {
        for l in out.lines().map_while(Result::ok) {
            if l.contains("online=yes") && !l.contains(" error=") {
                *count.lock().unwrap() += 1;
            }
        }
    });
    (Killed(child), answered)
}

#[test]
fn a_master_that_hears_another_master_yields_and_takes_the_line_back_when_it_falls_silent() {
    let dir = tempfile::tempdir().unwrap();
    let (_sim, ptys, _control) = simulate(dir.path());
    let gw = Gateway::start(&config(dir.path(), "a", &ptys[0], "active"), false);
    wait("the gateway masters the line and polls", || gw.role() == "master" && gw.transactions() > 0);
    assert_eq!(gw.bus_metric("drivebus_bus_role"), 1.0);
    assert_eq!(gw.bus_metric("drivebus_bus_yields_total"), 0.0);
    // Another master (a commissioning tool on the other port) polls drive 1 every 100 ms.
    let (other, answered) = monitor(&ptys[1]);
    let heard = Instant::now();
    wait("the gateway yields: role standby, counted, an event", || {
        gw.role() == "standby"
            && gw.bus_metric("drivebus_bus_yields_total") >= 1.0
            && !gw.bus_events("yield").is_empty()
    });
    let yielded = heard.elapsed();
    assert_eq!(gw.bus_metric("drivebus_bus_role"), 0.0);
    let e = &gw.bus_events("yield")[0];
    assert_eq!(e["detail"]["role"], "standby", "{e}");
    assert!(e["result"].as_str().unwrap().contains("stopped sending"), "{e}");
    wait("the yield is in the log", || {
        gw.log.lock().unwrap().iter().any(|l| l.contains(" yield line") && l.contains("stopped sending"))
    });
    // It sends nothing while the other master polls: its requests stay as many while the
    // other gets 10 answers more (a takeover in between, the other starved of CPU for longer
    // than the silence, would be counted, and then it yields again).
    let (sent, took) = (gw.transactions(), gw.bus_metric("drivebus_bus_takeovers_total"));
    let got = *answered.lock().unwrap();
    wait("the other master polls on", || *answered.lock().unwrap() >= got + 10);
    if gw.bus_metric("drivebus_bus_takeovers_total") == took {
        assert_eq!(gw.transactions(), sent, "a gateway that yielded sent requests");
    }
    // Its view of the drive the other polls stays warm from what it hears meanwhile.
    wait("it serves d1's values from what it hears", || ages(&gw)[0].is_some_and(|a| a < 2500));
    // The other falls silent: the gateway takes the line back and polls again.
    drop(other);
    let silent = Instant::now();
    let sent = gw.transactions();
    wait("the gateway takes the line back and polls", || gw.role() == "master" && gw.transactions() > sent);
    let back = silent.elapsed();
    assert_eq!(gw.bus_metric("drivebus_bus_role"), 1.0);
    assert!(gw.bus_metric("drivebus_bus_takeovers_total") >= 1.0);
    wait("the takeover is an event", || !gw.bus_events("takeover").is_empty());
    println!(
        "yielded {yielded:?} after the other master began; took the line back {back:?} after it stopped"
    );
}

#[test]
fn a_standby_that_takes_over_polls_each_drive_at_the_interval_it_learnt() {
    let dir = tempfile::tempdir().unwrap();
    let (_sim, ptys, _control) = simulate(dir.path());
    // Two of the line's drives: the master polls d1 every 100 ms and d2 every 500 ms (about
    // half the line's time at 9600 baud); the standby's own configuration says 500 ms for both.
    let a = config_polling(dir.path(), "a", &ptys[0], "active", &[100, 500]);
    let b = config_polling(dir.path(), "b", &ptys[1], "standby", &[500, 500]);
    let mut gw = [Gateway::start(&a, false), Gateway::start(&b, true)];
    wait("a masters the line", || gw[0].role() == "master");
    wait("b serves every drive from what it hears", || {
        gw[1].role() == "standby" && ages(&gw[1]).iter().all(|a| a.is_some_and(|a| a < 2500))
    });
    // Long enough for b to have learnt d2's interval: the median of the latest gaps, three
    // sendings heard.
    let p = gw[0].polls();
    wait("a polls on", || gw[0].polls()["d2"] >= p["d2"] + 3);
    gw[0].kill9();
    wait("b takes over", || gw[1].role() == "master" && gw[1].transactions() > 0);
    // From the takeover on, b polls d1 at the 100 ms it learnt and d2 at its own 500 ms:
    // counted over the same stretch, about five polls of d1 to one of d2 (one to one if b
    // polled at its own poll_ms). Counts, not times: a loaded machine slows both alike.
    let p0 = gw[1].polls();
    wait("b polls d2 ten times", || gw[1].polls()["d2"] >= p0["d2"] + 10);
    let p1 = gw[1].polls();
    let (d1, d2) = (p1["d1"] - p0["d1"], p1["d2"] - p0["d2"]);
    println!("after the takeover: {d1} polls of d1 (learnt 100 ms), {d2} of d2 (500 ms)");
    assert!(d1 >= 2 * d2 + 5, "d1 polled {d1} times while d2 was {d2} times: not at the learnt interval");
}

#[test]
fn a_standby_whose_line_idles_longer_than_the_silence_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("slow.toml");
    std::fs::write(
        &file,
        "[[bus]]\nname = \"l\"\nport = \"/dev/ttyUSB9\"\nprotocol = \"modbus-rtu\"\n\
         [[bus.drive]]\nname = \"d\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 1000\n",
    )
    .unwrap();
    let o = sim::output(
        Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["serve", "--standby", "--no-store", "--no-opcua", "--config"])
            .arg(&file),
    );
    assert_eq!(o.code, 3, "{}{}", o.stdout, o.stderr);
    assert!(o.stderr.contains("poll_ms 1000") && o.stderr.contains("silence_ms"), "{}", o.stderr);
    assert_eq!(o.stderr.trim().lines().count(), 1, "{}", o.stderr);
}
