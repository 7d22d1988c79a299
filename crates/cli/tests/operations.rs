//! A gateway in service: `drivebus serve --config` reloaded with SIGHUP (a bus and a drive added,
//! a token removed; then a broken file that changes nothing), `/healthz` and `/readyz` (503 while
//! the store's folder cannot be written or its filesystem has less than `[store] min_free_mb`
//! free), JSON logs, `config check` and `--version`.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::Value;

#[path = "support/http.rs"]
mod http;
use http::free_port;

const OPS_A: &str = "aaaaaaaaaaaaaaaaaaaa";
const OPS_B: &str = "bbbbbbbbbbbbbbbbbbbb";

fn tokens(with_b: bool) -> String {
    let mut t = format!("[[token]]\nname = \"ops-a\"\ntoken = \"{OPS_A}\"\nrole = \"write\"\n");
    if with_b {
        t += &format!("[[token]]\nname = \"ops-b\"\ntoken = \"{OPS_B}\"\nrole = \"write\"\n");
    }
    t
}

fn bus(name: &str, drive: &str) -> String {
    format!(
        "[[bus]]\nname = \"{name}\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
         [[bus.drive]]\nname = \"{drive}\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 100\n"
    )
}

/// A `drivebus serve --config` process with JSON logs, killed on drop.
struct Gateway {
    child: Child,
    http: SocketAddr,
    log: mpsc::Receiver<String>,
    dir: PathBuf,
}

impl Gateway {
    fn start(dir: &Path, config: &Path) -> Gateway {
        let http: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
        let modbus = format!("127.0.0.1:{}", free_port());
        let mut child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args([
                "serve",
                "--no-opcua",
                "--log-format",
                "json",
                "--http",
                &http.to_string(),
                "--modbus",
                &modbus,
                "--config",
            ])
            .arg(config)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start drivebus serve");
        let out = BufReader::new(child.stdout.take().unwrap());
        let (tx, log) = mpsc::channel();
        let err = BufReader::new(child.stderr.take().unwrap());
        std::thread::spawn(move || {
            for line in err.lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        // The listeners are bound when the banner's HTTP line is out: an event, not a sleep.
        let mut said = Vec::new();
        for line in out.lines() {
            let line = line.unwrap();
            said.push(line.clone());
            if line.contains("event store") {
                break;
            }
        }
        assert!(said.iter().any(|l| l.contains("HTTP API")), "serve did not start: {said:?}");
        Gateway { child, http, log, dir: dir.to_path_buf() }
    }

    fn get(&self, path: &str, token: Option<&str>) -> (u16, Value) {
        let (status, text) = http::request(self.http, "GET", path, token, None);
        (status, serde_json::from_str(&text).unwrap_or(Value::String(text)))
    }

    fn hangup(&self) {
        let ok = Command::new("kill").args(["-HUP", &self.child.id().to_string()]).status().unwrap();
        assert!(ok.success());
    }

    /// Waits (generously) for a log line that `pred` accepts, parsed as JSON.
    fn log_line(&self, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let line = self.log.recv_timeout(left).unwrap_or_else(|_| panic!("no log line: {what}"));
            let v: Value = serde_json::from_str(&line).unwrap_or_else(|e| panic!("not JSON ({e}): {line}"));
            assert!(v["time"].is_string() && v["level"].is_string() && v["message"].is_string(), "{v}");
            if pred(&v) {
                return v;
            }
        }
    }

    /// Waits (generously) until `GET path` gives what `pred` accepts.
    fn wait_for(&self, path: &str, what: &str, pred: impl Fn(u16, &Value) -> bool) -> Value {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let (status, v) = self.get(path, None);
            if pred(status, &v) {
                return v;
            }
            assert!(Instant::now() < deadline, "{what}: GET {path} still {status} {v}");
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn polls(g: &Gateway, id: &str) -> u64 {
    let (status, v) = g.get(&format!("/api/drives/{id}"), None);
    assert_eq!(status, 200, "{v}");
    v["polls"].as_u64().unwrap()
}

#[test]
fn sighup_reloads_what_changed_and_a_broken_file_changes_nothing() {
    let dir = std::env::temp_dir().join(format!("drivebus-ops-{}-{}", std::process::id(), free_port()));
    let store = dir.join("state");
    std::fs::create_dir_all(&store).unwrap();
    let file = dir.join("drivebus.toml");
    let head = format!(
        "[http]\nanonymous_read = true\n[store]\npath = \"{}\"\n",
        store.join("drivebus.db").display()
    );
    std::fs::write(&file, format!("{head}{}{}", tokens(true), bus("line-1", "d1"))).unwrap();
    let g = Gateway::start(&dir, &file);

    // Health: the process answers; ready with every listener up and the store writable.
    assert_eq!(g.get("/healthz", None), (200, serde_json::json!({ "status": "ok" })));
    g.wait_for("/readyz", "ready at start", |s, _| s == 200);
    g.wait_for("/api/drives/d1", "d1 polled", |s, v| s == 200 && v["online"] == true);
    assert_eq!(g.get("/api/drives/d2", None).0, 404);
    assert_eq!(http::request(g.http, "POST", "/api/drives/d1/stop", Some(OPS_B), None).0, 200);

    // The file gains a bus with a drive and loses a token.
    std::fs::write(&file, format!("{head}{}{}{}", tokens(false), bus("line-1", "d1"), bus("line-2", "d2")))
        .unwrap();
    let before = polls(&g, "d1");
    g.hangup();
    let v = g.log_line("configuration reloaded", |v| {
        v["message"].as_str().unwrap().contains("configuration reloaded")
    });
    assert_eq!(v["level"], "info");
    let msg = v["message"].as_str().unwrap();
    assert!(msg.contains("bus added line-2") && msg.contains("tokens changed"), "{msg}");
    g.wait_for("/api/drives/d2", "the new drive polled", |s, v| s == 200 && v["online"] == true);
    // line-1 was not restarted: d1's count kept rising (a new bus would start again from 0).
    let after = polls(&g, "d1");
    assert!(after > before, "d1's polls went from {before} to {after}");
    // The removed token is refused; the kept one works.
    let (status, _) = http::request(g.http, "POST", "/api/drives/d1/stop", Some(OPS_B), None);
    assert_eq!(status, 401);
    assert_eq!(http::request(g.http, "POST", "/api/drives/d1/stop", Some(OPS_A), None).0, 200);
    // The reload is in the audit trail, by `signal`, with what changed.
    let events = g.wait_for("/api/events?kind=reload", "the reload event", |s, v| {
        s == 200 && v.as_array().is_some_and(|e| !e.is_empty())
    });
    let e = &events[0];
    assert_eq!((e["actor"].as_str(), e["result"].as_str()), (Some("signal"), Some("ok")), "{e}");
    assert_eq!(e["detail"]["buses_added"], serde_json::json!(["line-2"]), "{e}");

    // A broken file: the running configuration stays, the error is logged and in the metrics.
    std::fs::write(&file, "[[bus]]\nname = \"line-1\"\nbaud = \"fast\"\n").unwrap();
    g.hangup();
    let v = g.log_line("reload refused", |v| v["message"].as_str().unwrap().contains("not reloaded"));
    assert_eq!(v["level"], "warn");
    assert!(v["message"].as_str().unwrap().contains("drivebus.toml:3"), "{v}");
    let metrics = g.wait_for("/metrics", "the failed reload in the metrics", |s, v| {
        s == 200 && v.as_str().is_some_and(|t| t.contains("drivebus_config_reload_failed 1"))
    });
    let text = metrics.as_str().unwrap();
    assert!(text.contains("drivebus_config_reloads_total{result=\"failed\"} 1"), "{text}");
    let d2 = polls(&g, "d2");
    g.wait_for("/api/drives/d2", "d2 still polled", |_, v| v["polls"].as_u64().is_some_and(|p| p > d2));

    // Ready needs a writable store: its folder gone, 503 with the reason; back, ready again.
    let moved = dir.join("state-away");
    std::fs::rename(&store, &moved).unwrap();
    let v = g.wait_for("/readyz", "not ready without the store's folder", |s, _| s == 503);
    assert_eq!(v["ready"], false);
    assert!(v["reasons"][0].as_str().unwrap().starts_with("store: cannot write"), "{v}");
    std::fs::rename(&moved, &store).unwrap();
    g.wait_for("/readyz", "ready again", |s, _| s == 200);
    assert_eq!(g.get("/healthz", None).0, 200);

    // Ready needs [store] min_free_mb free on the store's filesystem (read at each check, so a
    // reload applies it): no disk here has an exabyte free.
    let full = head.replace("[store]\n", "[store]\nmin_free_mb = 1000000000000\n");
    std::fs::write(&file, format!("{full}{}{}{}", tokens(false), bus("line-1", "d1"), bus("line-2", "d2")))
        .unwrap();
    g.hangup();
    let v = g.wait_for("/readyz", "not ready below min_free_mb", |s, _| s == 503);
    let why = v["reasons"][0].as_str().unwrap();
    assert!(
        why.contains("MiB free on the filesystem of") && why.contains("min_free_mb = 1000000000000"),
        "{v}"
    );
}

#[test]
fn config_check_says_what_it_would_run_and_names_the_line_of_an_error() {
    let dir = std::env::temp_dir().join(format!("drivebus-check-{}-{}", std::process::id(), free_port()));
    std::fs::create_dir_all(&dir).unwrap();
    let good = dir.join("good.toml");
    std::fs::write(&good, format!("{}{}", tokens(true), bus("line-1", "d1"))).unwrap();
    let out =
        Command::new(env!("CARGO_BIN_EXE_drivebus")).args(["config", "check"]).arg(&good).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{text}");
    assert!(text.contains("bus line-1: virtual"), "{text}");
    assert!(text.contains("drive d1: generic at address 1, unit id 1, polled every 100 ms"), "{text}");
    assert!(text.contains("Modbus TCP  127.0.0.1:5020"), "{text}");
    assert!(text.contains("the configuration is valid"), "{text}");
    // Nothing was opened: no store file appeared beside it or in the working directory.
    assert!(!dir.join("drivebus.db").exists());

    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        format!("{}{}", tokens(false), bus("line-1", "d1").replace("address = 1", "address = 300")),
    )
    .unwrap();
    let out =
        Command::new(env!("CARGO_BIN_EXE_drivebus")).args(["config", "check"]).arg(&bad).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("bad.toml:13: field `bus.drive.address`"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");

    // Two tokens of one name: the second's name line.
    let twice = dir.join("twice.toml");
    std::fs::write(&twice, format!("{}{}", tokens(true).replace("ops-b", "ops-a"), bus("line-1", "d1")))
        .unwrap();
    let out =
        Command::new(env!("CARGO_BIN_EXE_drivebus")).args(["config", "check"]).arg(&twice).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(
        err.contains("twice.toml:6: field `token.name`: \"ops-a\": two tokens have the same name"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn version_names_the_commit() {
    let out = Command::new(env!("CARGO_BIN_EXE_drivebus")).arg("--version").output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success());
    assert!(text.starts_with(&format!("drivebus {} (commit ", env!("CARGO_PKG_VERSION"))), "{text}");
}
