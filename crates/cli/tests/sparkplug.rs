//! The Sparkplug B edge node against programs nobody here wrote: Debian's Mosquitto as the
//! broker and a Python Sparkplug host (tests/interop/sparkplug_host.py: paho-mqtt and the
//! Sparkplug B schema as pysparkplug ships it) that checks seq continuity, aliases and bdSeq
//! on every message and prints what it received. `drivebus serve` runs as a process, so that
//! it can be killed with SIGKILL.
//!
//! The tests that need them are ignored by a plain `cargo test` (`cargo test -- --ignored` runs
//! them). `.ci/install-witnesses.sh` installs all three and `.ci/run` sets
//! `DRIVEBUS_REQUIRE_INTEROP=1`, so in CI a missing witness is a failure.

use std::io::{BufRead, BufReader, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::{Arc, Mutex};

use serde_json::Value;

#[path = "support/http.rs"]
mod http;
#[path = "../../gateway/tests/mqtt_support/mod.rs"]
mod mqtt_support;

#[path = "support/sim.rs"]
mod sim;
#[path = "../../../tests/interop/witness.rs"]
mod witness;

use mqtt_support::{demo_drives, free_port, mosquitto_binary, Mosquitto, Subscriber, PATIENCE};
use witness::witness;

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/interop/sparkplug_host.py")
}

/// Mosquitto, or `None` (said; a failure with `DRIVEBUS_REQUIRE_INTEROP=1`) when a witness is
/// missing.
fn witnesses() -> Option<PathBuf> {
    let python = witness::python_has("paho.mqtt.client, pysparkplug._protobuf.sparkplug_b_pb2");
    let bin = mosquitto_binary();
    let here = bin.is_some() && python;
    if !witness(
        "mosquitto, paho-mqtt and pysparkplug",
        here,
        "apt-get install mosquitto; pip install paho-mqtt pysparkplug",
    ) {
        return None;
    }
    bin
}

/// The Python host: its JSON lines collected, commands written to its stdin.
struct Host {
    child: Child,
    stdin: ChildStdin,
    log: Arc<Mutex<Vec<Value>>>,
}

impl Host {
    async fn start(broker: SocketAddr, host_id: Option<&str>) -> Host {
        let mut cmd = Command::new("python3");
        cmd.arg(script()).arg(broker.to_string());
        if let Some(id) = host_id {
            cmd.args(["--host-id", id]);
        }
        let mut child = cmd
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start the Python Sparkplug host");
        let stdin = child.stdin.take().unwrap();
        let stdout = child.stdout.take().unwrap();
        let log = Arc::new(Mutex::new(Vec::new()));
        let sink = log.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                let v = serde_json::from_str(&line)
                    .unwrap_or_else(|_| serde_json::json!({"type": "text", "what": line}));
                sink.lock().unwrap().push(v);
            }
        });
        let host = Host { child, stdin, log };
        host.wait("the host subscribed", |log| log.iter().any(|m| m["type"] == "ready").then_some(())).await;
        host
    }

    fn send(&mut self, line: &str) {
        writeln!(self.stdin, "{line}").expect("write to the host");
        self.stdin.flush().unwrap();
    }

    fn len(&self) -> usize {
        self.log.lock().unwrap().len()
    }

    fn log(&self) -> Vec<Value> {
        self.log.lock().unwrap().clone()
    }

    /// Waits until `found` finds something in what the host printed.
    async fn wait<T>(&self, what: &str, found: impl Fn(&[Value]) -> Option<T>) -> T {
        let start = std::time::Instant::now();
        loop {
            if let Some(t) = found(&self.log.lock().unwrap()) {
                return t;
            }
            if start.elapsed() > PATIENCE {
                let log = self.log();
                let tail: Vec<String> = log.iter().rev().take(20).map(|v| v.to_string()).collect();
                panic!("waited {PATIENCE:?} for {what}; the host's last lines:\n{}", tail.join("\n"));
            }
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        }
    }

    fn assert_no_violation(&self) {
        let bad: Vec<Value> =
            self.log().into_iter().filter(|m| m["type"] == "violation" || m["type"] == "error").collect();
        assert!(bad.is_empty(), "the Sparkplug host found: {bad:#?}");
    }
}

impl Drop for Host {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A `drivebus serve --demo` process, killed (SIGKILL) on drop.
struct Serve {
    child: Child,
    http: SocketAddr,
}

impl Serve {
    fn start(name: &str, db: &Path, broker: SocketAddr, extra: &[&str]) -> Serve {
        let http: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
        let child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["serve", "--demo", "--no-opcua", "--name", name, "--db"])
            .arg(db)
            .args(["--http", &http.to_string()])
            .args(["--modbus", &format!("127.0.0.1:{}", free_port())])
            .args(["--sparkplug", &format!("mqtt://{broker}")])
            .args(extra)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start drivebus serve");
        Serve { child, http }
    }

    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// A counter of `/metrics` (0 when absent).
    fn metric(&self, series: &str) -> f64 {
        let (_, body) = http::request(self.http, "GET", "/metrics", None, None);
        body.lines().find_map(|l| l.strip_prefix(series).and_then(|v| v.trim().parse().ok())).unwrap_or(0.0)
    }

    /// The drive's output frequency as the HTTP API shows it.
    fn output_hz(&self, drive: &str) -> f64 {
        let (_, body) = http::request(self.http, "GET", &format!("/api/drives/{drive}"), None, None);
        serde_json::from_str::<Value>(&body).ok().and_then(|v| v["output_hz"].as_f64()).unwrap_or(-1.0)
    }

    /// Waits (polling the API) until `drive` runs at `hz`.
    async fn wait_hz(&self, drive: &str, hz: f64) {
        let start = std::time::Instant::now();
        while (self.output_hz(drive) - hz).abs() > 0.05 {
            assert!(start.elapsed() < PATIENCE, "{drive} never reached {hz} Hz");
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        }
    }
}

impl Drop for Serve {
    fn drop(&mut self) {
        self.kill();
    }
}

fn of<'a>(log: &'a [Value], kind: &str, edge: &str) -> impl Iterator<Item = (usize, &'a Value)> + 'a {
    let (kind, edge) = (kind.to_string(), edge.to_string());
    log.iter().enumerate().filter(move |(_, m)| m["type"] == kind.as_str() && m["edge"] == edge.as_str())
}

fn metric<'a>(m: &'a Value, name: &str) -> Option<&'a Value> {
    m["metrics"].as_array()?.iter().find(|x| x["name"] == name)
}

/// Index of the first NBIRTH of `edge` at or after `from`, once every demo drive's DBIRTH followed.
fn births_from(log: &[Value], edge: &str, from: usize) -> Option<usize> {
    let drives: Vec<String> = demo_drives().into_iter().map(|(_, d)| d).collect();
    births_of(log, edge, from, &drives)
}

/// Index of the first NBIRTH of `edge` at or after `from`, once the DBIRTH of every one of
/// `devices` followed.
fn births_of(log: &[Value], edge: &str, from: usize, devices: &[String]) -> Option<usize> {
    let (at, _) = of(log, "NBIRTH", edge).find(|(i, _)| *i >= from)?;
    let born: Vec<&str> =
        of(log, "DBIRTH", edge).filter(|(i, _)| *i > at).filter_map(|(_, m)| m["device"].as_str()).collect();
    devices.iter().all(|d| born.contains(&d.as_str())).then_some(at)
}

async fn wait_births(host: &Host, edge: &str, from: usize) -> usize {
    host.wait(&format!("NBIRTH and every DBIRTH of {edge}"), |log| births_from(log, edge, from)).await
}

/// The value of `name` in the last DDATA/DBIRTH of `device` from `from` on.
fn latest(log: &[Value], device: &str, name: &str, from: usize) -> Option<Value> {
    log.iter()
        .skip(from)
        .rev()
        .filter(|m| (m["type"] == "DDATA" || m["type"] == "DBIRTH") && m["device"] == device)
        .find_map(|m| metric(m, name).map(|x| x["value"].clone()))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto and pysparkplug (.ci/install-witnesses.sh)"]
async fn a_python_host_sees_births_data_commands_refusals_and_a_rebirth() {
    let Some(bin) = witnesses() else { return };
    let dir = tempfile::tempdir().unwrap();
    let broker = Mosquitto::start(&bin, free_port()).await;
    let mut host = Host::start(broker.addr, None).await;
    let gw = Serve::start("hall-1", &dir.path().join("a.db"), broker.addr, &[]);
    let first = wait_births(&host, "hall-1", 0).await;

    let log = host.log();
    let nbirth = &log[first];
    assert_eq!(nbirth["seq"], 0);
    assert_eq!(nbirth["group"], "drivebus");
    let bd_seq = nbirth["bdSeq"].as_u64().expect("bdSeq in NBIRTH");
    assert!(metric(nbirth, "Buses/line-toshiba/Transactions").is_some(), "{nbirth}");
    let dbirth = of(&log, "DBIRTH", "hall-1").find(|(_, m)| m["device"] == "pump-1").unwrap().1;
    for name in [
        "OutputFrequency",
        "Setpoint",
        "Current",
        "Running",
        "Direction",
        "FaultCode",
        "FaultText",
        "Online",
        "Command/Run",
        "Command/Stop",
        "Command/Reverse",
        "Command/Reset",
    ] {
        assert!(metric(dbirth, name).is_some_and(|m| m["alias"].is_u64()), "{name} in {dbirth}");
    }
    assert!(dbirth["metrics"]
        .as_array()
        .unwrap()
        .iter()
        .any(|m| m["name"].as_str().unwrap().starts_with("Parameters/")));

    // Speed and run by DCMD (by alias, as the host learnt it): DDATA reach the speed.
    let mark = host.len();
    host.send("dcmd hall-1 pump-1 Setpoint double 30");
    host.send("dcmd hall-1 pump-1 Command/Run boolean true");
    host.wait("pump-1 at 30 Hz in DDATA", |log| {
        (latest(log, "pump-1", "OutputFrequency", mark)?.as_f64()? >= 29.95).then_some(())
    })
    .await;

    // Refused without touching a drive, counted by reason; the node keeps running.
    host.send("dcmd hall-1 pump-1 Nonsense double 1");
    host.send("dcmd hall-1 pump-1 Setpoint string fast");
    host.send("dcmd hall-1 pump-1 Setpoint double 9999");
    host.send("dcmd hall-1 no-such-drive Setpoint double 10");
    host.send("raw spBv1.0/drivebus/DCMD/hall-1/pump-2 ffffffff");
    let reasons = ["unknown_metric", "wrong_type", "out_of_range", "unknown_device", "not_sparkplug"];
    for r in reasons {
        wait_metric(&gw, &format!("drivebus_sparkplug_commands_refused_total{{reason=\"{r}\"}}"), 1.0).await;
    }
    assert_eq!(gw.output_hz("pump-2"), 0.0, "a refused command reached pump-2");

    // A rebirth: NBIRTH with the same bdSeq and seq 0, every DBIRTH again, no death first.
    let mark = host.len();
    host.send("ncmd hall-1 rebirth");
    let again = wait_births(&host, "hall-1", mark).await;
    let log = host.log();
    assert_eq!(log[again]["bdSeq"].as_u64(), Some(bd_seq));
    assert_eq!(log[again]["seq"], 0);
    assert!(of(&log, "NDEATH", "hall-1").next().is_none());
    host.assert_no_violation();

    // Every command is in the audit trail under the edge node's name.
    let store = drivebus_store::Store::open_read_only(&dir.path().join("a.db")).unwrap();
    let events = store.events(&drivebus_store::EventFilter { limit: 1000, ..Default::default() }).unwrap();
    let ours: Vec<_> =
        events.iter().filter(|e| e.actor.as_deref() == Some("sparkplug:drivebus/hall-1")).collect();
    assert!(
        ours.iter().any(|e| e.action.as_deref() == Some("speed 30 Hz") && e.result.as_deref() == Some("ok")),
        "{ours:?}"
    );
    assert!(ours.iter().any(|e| e.action.as_deref() == Some("run")), "{ours:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto and pysparkplug (.ci/install-witnesses.sh)"]
async fn kill_9_brings_the_ndeath_and_a_restart_the_next_bd_seq() {
    let Some(bin) = witnesses() else { return };
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("k.db");
    let broker = Mosquitto::start(&bin, free_port()).await;
    let host = Host::start(broker.addr, None).await;
    let mut gw = Serve::start("hall-k", &db, broker.addr, &[]);
    let at = wait_births(&host, "hall-k", 0).await;
    let bd_seq = host.log()[at]["bdSeq"].as_u64().unwrap();
    gw.kill();
    let death =
        host.wait("the NDEATH", |log| of(log, "NDEATH", "hall-k").next().map(|(_, m)| m.clone())).await;
    assert_eq!(death["bdSeq"].as_u64(), Some(bd_seq), "{death}");
    let mark = host.len();
    let _gw = Serve::start("hall-k", &db, broker.addr, &[]);
    let at = wait_births(&host, "hall-k", mark).await;
    assert_eq!(host.log()[at]["bdSeq"].as_u64(), Some((bd_seq + 1) % 256));
    host.assert_no_violation();
}

async fn wait_metric(gw: &Serve, series: &str, at_least: f64) {
    let start = std::time::Instant::now();
    while gw.metric(series) < at_least {
        assert!(start.elapsed() < PATIENCE, "{series} never reached {at_least}");
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
}

/// Waits for live (not historical) DDATA of pump-1 from hall-s after `from`; `what` names the
/// wait in the timeout's message.
async fn wait_live(host: &Host, from: usize, what: &str) {
    host.wait(what, |log| {
        of(log, "DDATA", "hall-s")
            .any(|(i, m)| i > from && m["device"] == "pump-1" && m["metrics"][0]["historical"] == false)
            .then_some(())
    })
    .await
}

/// Waits for historical DDATA of pump-1 (after `from`) that reach `hz`.
async fn wait_kept(host: &Host, from: usize, hz: f64) {
    host.wait(&format!("kept data of pump-1 up to {hz} Hz"), |log| {
        log.iter()
            .skip(from)
            .any(|m| {
                m["type"] == "DDATA"
                    && m["device"] == "pump-1"
                    && metric(m, "OutputFrequency").is_some_and(|x| {
                        x["historical"] == true && x["value"].as_f64().is_some_and(|v| (v - hz).abs() < 0.05)
                    })
            })
            .then_some(())
    })
    .await
}

/// From `from` on: the DDATA of `device` while the host listened again: historical ones first,
/// in time order, rising `OutputFrequency` up to `hz`, then live ones.
fn check_history(log: &[Value], edge: &str, device: &str, from: usize, hz: f64) {
    let ddata: Vec<&Value> =
        of(log, "DDATA", edge).filter(|(i, m)| *i > from && m["device"] == device).map(|(_, m)| m).collect();
    let historical = |m: &Value| m["metrics"].as_array().unwrap().iter().all(|x| x["historical"] == true);
    let split = ddata.iter().position(|m| !historical(m)).unwrap_or(ddata.len());
    assert!(ddata[split..].iter().all(|m| !historical(m)), "historical data after live data");
    let hist = &ddata[..split];
    let times: Vec<u64> = hist.iter().map(|m| m["timestamp"].as_u64().unwrap()).collect();
    assert!(times.windows(2).all(|w| w[0] <= w[1]), "historical data out of order: {times:?}");
    let hzs: Vec<f64> = hist.iter().filter_map(|m| metric(m, "OutputFrequency")?["value"].as_f64()).collect();
    assert!(hzs.len() >= 3, "the ramp while nobody listened: {hzs:?}");
    assert!(hzs.windows(2).all(|w| w[0] <= w[1]), "the ramp in order: {hzs:?}");
    assert!((hzs.last().unwrap() - hz).abs() < 0.05, "the ramp reached {hz}: {hzs:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto and pysparkplug (.ci/install-witnesses.sh)"]
async fn store_and_forward_while_the_primary_host_is_offline_and_while_the_broker_is_gone() {
    let Some(bin) = witnesses() else { return };
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let mut broker = Mosquitto::start(&bin, port).await;
    let mut host = Host::start(broker.addr, Some("scada")).await;
    let gw = Serve::start("hall-s", &dir.path().join("s.db"), broker.addr, &["--sparkplug-primary", "scada"]);
    let first = wait_births(&host, "hall-s", 0).await;
    let first_bd_seq = host.log()[first]["bdSeq"].as_u64().unwrap();

    // The primary host goes offline while pump-1 ramps to 40 Hz.
    host.send("dcmd hall-s pump-1 Setpoint double 40");
    host.send("dcmd hall-s pump-1 Command/Run boolean true");
    host.wait("pump-1 running", |log| (latest(log, "pump-1", "Running", 0)? == true).then_some(())).await;
    let mark = host.len();
    host.send("state offline");
    // The node publishes its NDEATH and starts a new session that waits for the host.
    let death = host
        .wait("the NDEATH", |log| {
            of(log, "NDEATH", "hall-s").find(|(i, _)| *i >= mark).map(|(_, m)| m.clone())
        })
        .await;
    assert_eq!(death["bdSeq"].as_u64(), Some(first_bd_seq), "{death}");
    // Once the gateway keeps data, nothing more is published while the host is away.
    wait_metric(&gw, "drivebus_sparkplug_stored_total", 1.0).await;
    let offline = host.len();
    gw.wait_hz("pump-1", 40.0).await;
    wait_metric(&gw, "drivebus_sparkplug_stored_total", 3.0).await;
    assert!(
        of(&host.log(), "DDATA", "hall-s").all(|(i, _)| i < offline),
        "live DDATA while the host was offline"
    );
    host.send("state online");
    let back = wait_births(&host, "hall-s", offline).await;
    assert_eq!(host.log()[back]["bdSeq"].as_u64(), Some((first_bd_seq + 1) % 256), "the new session's bdSeq");
    wait_kept(&host, back, 40.0).await;
    // Something new, to see live data after the kept.
    host.send("dcmd hall-s pump-1 Setpoint double 35");
    wait_live(&host, back, "the kept ramp and live data").await;
    check_history(&host.log(), "hall-s", "pump-1", back, 40.0);
    host.assert_no_violation();

    // The broker goes away while pump-1 ramps down to 20 Hz, and comes back empty.
    let bd_seq = host.log()[back]["bdSeq"].as_u64().unwrap();
    host.send("dcmd hall-s pump-1 Setpoint double 20");
    host.wait("the new setpoint", |log| {
        (latest(log, "pump-1", "Setpoint", back)?.as_f64()? == 20.0).then_some(())
    })
    .await;
    broker.stop();
    drop(host);
    gw.wait_hz("pump-1", 20.0).await;
    let broker = Mosquitto::start(&bin, port).await;
    let mut host = Host::start(broker.addr, Some("scada")).await;
    let back = wait_births(&host, "hall-s", 0).await;
    assert_ne!(host.log()[back]["bdSeq"].as_u64(), Some(bd_seq), "a new session has a new bdSeq");
    wait_kept(&host, back, 20.0).await;
    host.send("dcmd hall-s pump-1 Setpoint double 25");
    wait_live(&host, back, "the kept ramp down and live data").await;
    let log = host.log();
    let ddata: Vec<&Value> = of(&log, "DDATA", "hall-s")
        .filter(|(i, m)| *i > back && m["device"] == "pump-1")
        .map(|(_, m)| m)
        .collect();
    let hzs: Vec<f64> = ddata
        .iter()
        .take_while(|m| m["metrics"][0]["historical"] == true)
        .filter_map(|m| metric(m, "OutputFrequency")?["value"].as_f64())
        .collect();
    assert!(hzs.len() >= 3 && hzs.windows(2).all(|w| w[0] >= w[1]), "the ramp down, in order: {hzs:?}");
    assert!((hzs.last().unwrap() - 20.0).abs() < 0.05, "{hzs:?}");
    host.assert_no_violation();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto and pysparkplug (.ci/install-witnesses.sh)"]
async fn three_gateways_on_one_broker_one_host_sees_them_all() {
    let Some(bin) = witnesses() else { return };
    let dir = tempfile::tempdir().unwrap();
    let broker = Mosquitto::start(&bin, free_port()).await;
    let host = Host::start(broker.addr, None).await;
    let _gws: Vec<Serve> = ["hall-a", "hall-b", "hall-c"]
        .iter()
        .map(|n| Serve::start(n, &dir.path().join(format!("{n}.db")), broker.addr, &[]))
        .collect();
    for n in ["hall-a", "hall-b", "hall-c"] {
        wait_births(&host, n, 0).await;
    }
    host.wait("DDATA from all three", |log| {
        ["hall-a", "hall-b", "hall-c"].iter().all(|n| of(log, "DDATA", n).next().is_some()).then_some(())
    })
    .await;
    host.assert_no_violation();
}

#[test]
fn bad_sparkplug_flags_are_one_line_errors() {
    for (args, says) in [
        (
            &["--sparkplug", "tcp://127.0.0.1:1883"][..],
            "--sparkplug \"tcp://127.0.0.1:1883\": use mqtt://HOST:PORT",
        ),
        (&["--sparkplug-primary", "scada"][..], "--sparkplug-primary needs a broker"),
        (
            &["--sparkplug", "mqtt://127.0.0.1:1883", "--sparkplug-primary", "a/b"][..],
            "--sparkplug-primary \"a/b\"",
        ),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["serve", "--demo", "--no-opcua", "--no-store"])
            .args(args)
            .output()
            .expect("run drivebus serve");
        assert_eq!(out.status.code(), Some(3), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(says) && err.lines().count() == 1, "{args:?}: {err}");
    }
}

/// A `drivebus serve` of `[standby]` on `pty` (drives d1, d2 of a simulated line), publishing
/// MQTT and Sparkplug B to `broker`, as edge node and MQTT gateway `name`; `more` is added to
/// its configuration (another bus).
fn standby_serve(dir: &Path, name: &str, pty: &Path, broker: SocketAddr, standby: bool, more: &str) -> Serve {
    let mut text = format!(
        "name = \"{name}\"\n[http]\nanonymous_read = true\n[standby]\nrole = \"{}\"\nsilence_ms = 500\n\
         [[bus]]\nname = \"line\"\nport = \"{}\"\nprotocol = \"modbus-rtu\"\n",
        if standby { "standby" } else { "active" },
        pty.display()
    );
    for a in 1..=2 {
        text.push_str(&format!(
            "[[bus.drive]]\nname = \"d{a}\"\nfamily = \"generic\"\naddress = {a}\npoll_ms = 200\n"
        ));
    }
    text.push_str(more);
    let config = dir.join(format!("{name}.toml"));
    std::fs::write(&config, text).unwrap();
    let http: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["serve", "--no-opcua", "--config"])
        .arg(&config)
        .arg("--db")
        .arg(dir.join(format!("{name}.db")))
        .args(["--http", &http.to_string()])
        .args(["--modbus", &format!("127.0.0.1:{}", free_port())])
        .args(["--sparkplug", &format!("mqtt://{broker}"), "--mqtt", &format!("mqtt://{broker}")])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start drivebus serve");
    Serve { child, http }
}

/// Issue 27: "MQTT and Sparkplug B publish from the gateway that is master; a Sparkplug host sees
/// the old node's NDEATH and the new one's NBIRTH". Two gateways on one simulated line: the
/// standby, which hears every answer, publishes no state; `kill -9` of the master brings its
/// NDEATH (its will, its bdSeq), and the standby takes the line and births.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto and pysparkplug (.ci/install-witnesses.sh)"]
async fn the_host_sees_the_killed_masters_ndeath_and_the_standbys_nbirth() {
    let Some(bin) = witnesses() else { return };
    let dir = tempfile::tempdir().unwrap();
    let broker = Mosquitto::start(&bin, free_port()).await;
    let host = Host::start(broker.addr, None).await;
    let watcher = Subscriber::start(broker.addr, "watcher", "drivebus/#").await;
    let (a, b) = (dir.path().join("pty-a"), dir.path().join("pty-b"));
    let _line = sim::simulate_with(&[
        "--drive",
        "generic@1:modbus-rtu",
        "--drive",
        "generic@2:modbus-rtu",
        "--pty",
        a.to_str().unwrap(),
        "--pty",
        b.to_str().unwrap(),
    ]);
    let start = std::time::Instant::now();
    while !(a.exists() && b.exists()) {
        assert!(start.elapsed() < PATIENCE, "the simulator's ptys");
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    let devices = ["d1".to_string(), "d2".to_string()];
    let mut master = standby_serve(dir.path(), "hall-a", &a, broker.addr, false, "");
    let at = host.wait("hall-a's births", |log| births_of(log, "hall-a", 0, &devices)).await;
    let bd_seq = host.log()[at]["bdSeq"].as_u64().expect("bdSeq");
    let standby = standby_serve(dir.path(), "hall-b", &b, broker.addr, true, "");

    // The standby is connected (it says offline) and hears the master's answers...
    watcher
        .wait("hall-b offline", |log| {
            log.iter().any(|m| m.topic == "drivebus/hall-b/status" && m.text == "offline").then_some(())
        })
        .await;
    let heard = |s: &Serve| {
        let (_, body) = http::request(s.http, "GET", "/api/drives", None, None);
        serde_json::from_str::<Value>(&body).ok().is_some_and(|v| {
            v.as_array().is_some_and(|d| {
                d.len() == 2 && d.iter().all(|d| d["source"] == "standby" && d["polls"].as_u64() >= Some(3))
            })
        })
    };
    let start = std::time::Instant::now();
    while !heard(&standby) {
        assert!(start.elapsed() < PATIENCE, "the standby never heard the master's answers");
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    // ... and published none of it, on MQTT or Sparkplug.
    let published: Vec<_> = watcher
        .log
        .lock()
        .unwrap()
        .iter()
        .filter(|m| m.topic.starts_with("drivebus/hall-b/") && m.topic != "drivebus/hall-b/status")
        .map(|m| m.topic.clone())
        .collect();
    assert!(published.is_empty(), "a standby published {published:?}");
    assert!(of(&host.log(), "NBIRTH", "hall-b").next().is_none(), "a standby births nothing");

    // The master dies: its will says NDEATH with its bdSeq; the standby births as master.
    let mark = host.len();
    master.kill();
    let death =
        host.wait("hall-a's NDEATH", |log| of(log, "NDEATH", "hall-a").next().map(|(_, m)| m.clone())).await;
    assert_eq!(death["bdSeq"].as_u64(), Some(bd_seq), "{death}");
    let born = host.wait("hall-b's births", |log| births_of(log, "hall-b", mark, &devices)).await;
    assert!(host.log()[born]["bdSeq"].is_u64());
    watcher
        .wait("hall-b online with d1's status as master", |log| {
            let online = log.iter().any(|m| m.topic == "drivebus/hall-b/status" && m.text == "online");
            let d1 = log.iter().rev().find(|m| m.topic == "drivebus/hall-b/line/d1/status");
            (online && d1.is_some_and(|m| m.text.contains(r#""source":"master""#))).then_some(())
        })
        .await;
    host.assert_no_violation();
}

/// A gateway that masters one of its buses and only hears the other publishes every drive; each
/// device's `Source` metric says whose values they are, and changes when the heard bus is taken.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto and pysparkplug (.ci/install-witnesses.sh)"]
async fn drives_on_a_bus_the_node_only_hears_carry_the_standby_source() {
    let Some(bin) = witnesses() else { return };
    let dir = tempfile::tempdir().unwrap();
    let broker = Mosquitto::start(&bin, free_port()).await;
    let host = Host::start(broker.addr, None).await;
    let (a, b, solo) = (dir.path().join("pty-a"), dir.path().join("pty-b"), dir.path().join("pty-solo"));
    let pty = |p: &Path| p.to_str().unwrap().to_string();
    let drives = ["--drive", "generic@1:modbus-rtu", "--drive", "generic@2:modbus-rtu"];
    let _line = sim::simulate_with(&[&drives[..], &["--pty", &pty(&a), "--pty", &pty(&b)]].concat());
    // A line of its own that nobody else masters: hall-b takes it.
    let _solo = sim::simulate_with(&["--drive", "generic@3:modbus-rtu", "--pty", &pty(&solo)]);
    let mut master = standby_serve(dir.path(), "hall-a", &a, broker.addr, false, "");
    let devices = ["d1".to_string(), "d2".to_string()];
    host.wait("hall-a's births", |log| births_of(log, "hall-a", 0, &devices)).await;
    let more = format!(
        "[[bus]]\nname = \"solo\"\nport = \"{}\"\nprotocol = \"modbus-rtu\"\n\
         [[bus.drive]]\nname = \"d3\"\nfamily = \"generic\"\naddress = 3\npoll_ms = 200\n",
        solo.display()
    );
    let _b = standby_serve(dir.path(), "hall-b", &b, broker.addr, true, &more);
    // hall-b masters "solo" and listens on "line": it births all three drives.
    let all = ["d1".to_string(), "d2".to_string(), "d3".to_string()];
    let born = host.wait("hall-b's births", |log| births_of(log, "hall-b", 0, &all)).await;
    // The Source of `device` in hall-b's first DBIRTH after `from`, and in its last DBIRTH or
    // DDATA that carries it.
    let birth_source = |log: &[Value], device: &str| {
        of(log, "DBIRTH", "hall-b")
            .find(|(i, m)| *i > born && m["device"] == device)
            .and_then(|(_, m)| metric(m, "Source").map(|x| x["value"].clone()))
    };
    let last_source = |log: &[Value], device: &str| {
        log.iter()
            .rev()
            .filter(|m| m["edge"] == "hall-b" && m["device"] == device)
            .filter(|m| m["type"] == "DBIRTH" || m["type"] == "DDATA")
            .find_map(|m| metric(m, "Source").map(|x| x["value"].clone()))
    };
    let log = host.log();
    assert_eq!(birth_source(&log, "d1"), Some(Value::from("standby")), "{log:?}");
    assert_eq!(birth_source(&log, "d2"), Some(Value::from("standby")), "{log:?}");
    assert_eq!(birth_source(&log, "d3"), Some(Value::from("master")), "{log:?}");
    // The master dies: hall-b takes "line" too, and says so in d1's and d2's Source.
    master.kill();
    for d in ["d1", "d2"] {
        host.wait(&format!("{d}'s Source master"), |log| {
            (last_source(log, d) == Some(Value::from("master"))).then_some(())
        })
        .await;
    }
    host.assert_no_violation();
}
