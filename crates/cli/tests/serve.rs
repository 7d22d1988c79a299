//! `drivebus serve --demo` end to end: the real binary on free loopback ports, driven over HTTP
//! with curl (or a plain HTTP/1.1 request when curl is not installed) using the demo token it
//! prints.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

#[path = "support/http.rs"]
mod http;
#[path = "support/lines.rs"]
mod lines;
use http::{free_port, request as raw};
use lines::{serve_command, stdout_until, wait_for_lines, Killed};

/// A `drivebus serve --demo` process, killed on drop.
struct Serve {
    child: Child,
    http: SocketAddr,
    token: String,
    dir: PathBuf,
}

impl Serve {
    fn start() -> Serve {
        let dir = std::env::temp_dir().join(format!("drivebus-serve-{}-{}", std::process::id(), free_port()));
        std::fs::create_dir_all(&dir).unwrap();
        Serve::start_in(dir)
    }

    /// Starts on the store in `dir` (kept from an earlier run).
    fn start_in(dir: PathBuf) -> Serve {
        let http: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
        let modbus = format!("127.0.0.1:{}", free_port());
        let mut child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["serve", "--demo", "--no-opcua", "--http", &http.to_string(), "--modbus", &modbus, "--db"])
            .arg(dir.join("x.db"))
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start drivebus serve");
        let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
        let mut token = None;
        let mut said = Vec::new();
        // The token line comes once every listener is bound: an event, not a sleep.
        for line in lines.by_ref() {
            let line = line.unwrap();
            said.push(line.clone());
            if let Some(t) = line.trim().strip_prefix("demo write token: ") {
                token = Some(t.to_string());
                break;
            }
        }
        let token = token.unwrap_or_else(|| panic!("drivebus serve printed no demo token: {said:?}"));
        std::thread::spawn(move || for _ in lines {});
        Serve { child, http, token, dir }
    }

    /// `method path` with an optional token and JSON body: (status, JSON answer).
    fn call(&self, method: &str, path: &str, token: Option<&str>, body: Option<&str>) -> (u16, Value) {
        let (status, text) = if has_curl() {
            curl(self.http, method, path, token, body)
        } else {
            raw(self.http, method, path, token, body)
        };
        let json =
            serde_json::from_str(&text).unwrap_or_else(|e| panic!("{method} {path}: {status} {text:?}: {e}"));
        (status, json)
    }
}

impl Serve {
    /// SIGKILL (`kill -9`): no flush, no goodbye; the store directory stays.
    fn kill9(mut self) -> PathBuf {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let dir = std::mem::take(&mut self.dir);
        std::mem::forget(self);
        dir
    }
}

impl Drop for Serve {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn has_curl() -> bool {
    Command::new("curl").arg("--version").output().is_ok_and(|o| o.status.success())
}

fn curl(
    http: SocketAddr,
    method: &str,
    path: &str,
    token: Option<&str>,
    body: Option<&str>,
) -> (u16, String) {
    let mut cmd = Command::new("curl");
    cmd.args(["-sS", "--max-time", "30", "-X", method, "-w", "\n%{http_code}"]);
    if let Some(t) = token {
        cmd.arg("-H").arg(format!("Authorization: Bearer {t}"));
    }
    if let Some(b) = body {
        cmd.args(["-H", "Content-Type: application/json", "--data", b]);
    }
    let out = cmd.arg(format!("http://{http}{path}")).output().expect("run curl");
    assert!(out.status.success(), "curl {method} {path}: {}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let (body, code) = text.rsplit_once('\n').unwrap();
    (code.trim().parse().unwrap(), body.to_string())
}

#[test]
fn serve_demo_runs_a_drive_over_http_and_audits_it_through_kill_9() {
    let s = Serve::start();
    if !has_curl() {
        eprintln!("curl is not installed: plain HTTP/1.1 requests from the test instead");
    }
    // Without the token, a write is refused and nothing moves.
    let (status, answer) = s.call("POST", "/api/drives/pump-1/run", None, None);
    assert_eq!(status, 401, "{answer}");
    assert_eq!(answer["error"]["kind"], "unauthorized");
    let t = Some(s.token.as_str());
    let (status, answer) = s.call("POST", "/api/drives/pump-1/speed", t, Some(r#"{"hz": 40}"#));
    assert_eq!(status, 200, "{answer}");
    let (status, answer) = s.call("POST", "/api/drives/pump-1/run", t, None);
    assert_eq!(status, 200, "{answer}");
    // The simulated drive ramps in its own (real) time: poll, generously.
    let deadline = Instant::now() + Duration::from_secs(120);
    let last = loop {
        let (status, v) = s.call("GET", "/api/drives/pump-1", None, None);
        assert_eq!(status, 200, "{v}");
        if v["output_hz"].as_f64().is_some_and(|hz| (hz - 40.0).abs() <= 0.1) {
            break v;
        }
        assert!(Instant::now() < deadline, "pump-1 never reached 40 Hz: {v}");
        std::thread::sleep(Duration::from_millis(250));
    };
    assert_eq!(last["running"], true, "{last}");
    // The audit trail has both commands with the caller (needs the real event store).
    let (status, events) = s.call("GET", "/api/events?drive=pump-1&kind=command&since=0", None, None);
    assert_eq!(status, 200, "{events}");
    let commands: Vec<(String, String, String)> = events
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            let f = |k: &str| e[k].as_str().unwrap_or_default().to_string();
            (f("action"), f("actor"), f("result"))
        })
        .collect();
    for action in ["speed 40 Hz", "run"] {
        assert!(
            commands.iter().any(|(a, who, r)| a == action && who == "http:demo@127.0.0.1" && r == "ok"),
            "{action} by http:demo@127.0.0.1 is not in the events: {commands:?}"
        );
    }
    // kill -9 and a restart on the same store: the audit trail is still there.
    let dir = s.kill9();
    let s = Serve::start_in(dir);
    let (status, events) = s.call("GET", "/api/events?drive=pump-1&kind=command&since=0", None, None);
    assert_eq!(status, 200, "{events}");
    let after: Vec<String> = events
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["action"].as_str().unwrap_or_default().to_string())
        .collect();
    for action in ["speed 40 Hz", "run"] {
        assert!(after.iter().any(|a| a == action), "{action} lost after kill -9: {after:?}");
    }
}

/// `serve --config` with a file of `tokens`: its stderr up to the line that says the listeners
/// are bound (the process is killed there).
fn serve_config_stderr(dir: &std::path::Path, tokens: &str) -> String {
    let cfg = dir.join("plant.toml");
    std::fs::write(
        &cfg,
        format!(
            "name = \"t\"\n[store]\ndisabled = true\n{tokens}\n[[bus]]\nname = \"l\"\nport = \"virtual\"\n\
             protocol = \"modbus-rtu\"\n[[bus.drive]]\nname = \"d\"\nfamily = \"generic\"\naddress = 1\n"
        ),
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["serve", "--no-opcua", "--config"])
        .arg(&cfg)
        .args([
            "--http",
            &format!("127.0.0.1:{}", free_port()),
            "--modbus",
            &format!("127.0.0.1:{}", free_port()),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start drivebus serve");
    // The listeners line on stdout comes after every startup warning on stderr.
    let said = stdout_until(&mut child, "Modbus TCP");
    let _ = child.kill();
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    let _ = child.wait();
    assert!(said.iter().any(|l| l.contains("drivebus serve: 1 bus, 1 drive")), "{said:?} {err}");
    err
}

#[test]
fn serve_warns_when_no_token_can_read_or_write() {
    let dir = tempfile::tempdir().unwrap();
    let err = serve_config_stderr(dir.path(), "");
    assert!(err.contains("no [[token]] and anonymous_read = false") && err.contains("401"), "{err}");
    let read_only = "[[token]]\nname = \"hmi\"\ntoken = \"a-read-token-of-16-chars\"\nrole = \"read\"\n";
    let err = serve_config_stderr(dir.path(), read_only);
    assert!(err.contains("no [[token]] with role = \"write\"") && err.contains("403"), "{err}");
    let write = "[[token]]\nname = \"scada\"\ntoken = \"a-write-token-of-16-chars\"\nrole = \"write\"\n";
    let err = serve_config_stderr(dir.path(), write);
    assert!(!err.contains("warning") && !err.contains("note:"), "{err}");
}

/// `drivebus serve --demo --no-store --no-opcua` on free loopback ports, to be given more flags.
fn serve_demo_without_store() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.args(["serve", "--demo", "--no-store", "--no-opcua"])
        .args(["--http", &format!("127.0.0.1:{}", free_port())])
        .args(["--modbus", &format!("127.0.0.1:{}", free_port())]);
    cmd
}

#[test]
fn serve_bridge_flag_passes_modbus_tcp_to_the_bus_and_bad_flags_are_one_line() {
    let bridge: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    let mut child = serve_demo_without_store()
        .args(["--bridge", &format!("line-generic={bridge}")])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start drivebus serve");
    let said = stdout_until(&mut child, "demo write token");
    assert!(
        said.iter().any(|l| l.contains(&format!("bridge      {bridge} -> bus line-generic"))),
        "{said:?}"
    );
    // 03 of 210BH (version) from drive 1 of line-generic, through the bridge.
    let mut s = TcpStream::connect(bridge).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.write_all(&[0, 1, 0, 0, 0, 6, 1, 0x03, 0x21, 0x0B, 0, 1]).unwrap();
    let mut answer = [0u8; 11];
    s.read_exact(&mut answer).unwrap();
    assert_eq!(answer, [0, 1, 0, 0, 0, 5, 1, 0x03, 2, 0x01, 0x00], "version 1.00");
    let _ = child.kill();
    let _ = child.wait();

    for (args, code, needle) in [
        (vec!["--bridge", "nope=127.0.0.1:1"], 3, "no bus \"nope\""),
        (vec!["--bridge", "line-toshiba=127.0.0.1:1"], 3, "needs a modbus-rtu or modbus-ascii bus"),
        (vec!["--bridge", "line-generic"], 3, "BUS=HOST:PORT"),
    ] {
        let out = serve_demo_without_store().args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{args:?}: {err}");
        let last = err.lines().last().unwrap_or_default();
        assert!(last.starts_with("drivebus: ") && last.contains(needle), "{args:?}: {err}");
    }
}

/// A Modbus RTU slave whose port is missing does not stop `serve` (a bus's port does not
/// either): the gateway serves, `/readyz` names the slave's port, and the log line says so in
/// the log's format (JSON here).
#[test]
fn serve_starts_with_a_missing_rtu_slave_port_and_readyz_names_it() {
    let http: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["serve", "--demo", "--no-store", "--no-opcua", "--log-format", "json"])
        .args(["--http", &http.to_string(), "--modbus", &format!("127.0.0.1:{}", free_port())])
        .args(["--modbus-rtu", "/nonexistent/ttyS9"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start drivebus serve");
    let said = stdout_until(&mut child, "demo write token");
    assert!(said.iter().any(|l| l.contains("Modbus RTU  slave on /nonexistent/ttyS9")), "{said:?}");
    let deadline = Instant::now() + Duration::from_secs(60);
    let answer = loop {
        let (status, body) = http::http_json(http, "GET", "/readyz", None).unwrap();
        if status == 503 {
            break body;
        }
        assert!(Instant::now() < deadline, "/readyz: {status} {body}");
        std::thread::sleep(Duration::from_millis(50));
    };
    let reasons = answer["reasons"].as_array().unwrap();
    assert!(
        reasons
            .iter()
            .any(|r| r.as_str().unwrap().starts_with("Modbus RTU slave on /nonexistent/ttyS9 is down")),
        "{answer}"
    );
    let (_, metrics) = raw(http, "GET", "/metrics", None, None);
    assert!(metrics.contains("drivebus_modbus_rtu_up{port=\"/nonexistent/ttyS9\"} 0"), "{metrics}");
    let _ = child.kill();
    let _ = child.wait();
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    let line = err.lines().find(|l| l.contains("/nonexistent/ttyS9")).unwrap_or_else(|| panic!("{err}"));
    let v: Value = serde_json::from_str(line).unwrap_or_else(|e| panic!("not JSON ({e}): {line}"));
    assert_eq!(v["level"], "warn", "{v}");
    assert!(v["message"].as_str().unwrap().contains("Modbus RTU slave"), "{v}");
}

/// `serve --demo` run in a folder writes nothing there: its store and the OPC UA server's key
/// go to the state folder (~/.local/state/drivebus here, `HOME` a temporary folder), and the
/// banner says where the key is, and that the demo (on loopback) takes OPC UA writes over None.
#[test]
fn the_demo_writes_nothing_in_the_working_directory_and_says_where_the_key_is() {
    let cwd = tempfile::tempdir().unwrap();
    let home = tempfile::tempdir().unwrap();
    let mut child = serve_command("127.0.0.1:0")
        .arg("--demo")
        .current_dir(cwd.path())
        .env("HOME", home.path())
        .env_remove("XDG_STATE_HOME")
        .env_remove("STATE_DIRECTORY")
        .spawn()
        .expect("start drivebus serve");
    let said = wait_for_lines(
        &mut child,
        "drivebus serve --demo",
        &["OPC UA key", "event store", "OPC UA      writes and calls"],
    );
    let _child = Killed(child);
    let state = home.path().join(".local/state/drivebus");
    let key = state.join("pki/private/private.pem");
    assert_eq!(said[0], key.display().to_string());
    assert!(key.exists(), "no key at {}", key.display());
    assert_eq!(said[1], state.join("drivebus-demo.db").display().to_string());
    assert_eq!(said[2], "also over the unsigned None endpoint (the demo, on loopback)");
    let left: Vec<_> = std::fs::read_dir(cwd.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(left.is_empty(), "serve --demo wrote {left:?} in its working directory");
}

/// `serve --config` whose file names no `[store] path` keeps its store, drivebus.db, in the state
/// folder ($XDG_STATE_HOME/drivebus here) and writes nothing in its working directory.
#[test]
fn a_config_without_a_store_path_writes_the_store_in_the_state_folder_not_the_working_directory() {
    let cwd = tempfile::tempdir().unwrap();
    let conf = tempfile::tempdir().unwrap();
    let state = tempfile::tempdir().unwrap();
    let cfg = conf.path().join("plant.toml");
    std::fs::write(
        &cfg,
        "name = \"t\"\n[[bus]]\nname = \"l\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\n\
         [[bus.drive]]\nname = \"d\"\nfamily = \"generic\"\naddress = 1\n",
    )
    .unwrap();
    let mut child = serve_command("127.0.0.1:0")
        .arg("--config")
        .arg(&cfg)
        .current_dir(cwd.path())
        .env("XDG_STATE_HOME", state.path())
        .env_remove("STATE_DIRECTORY")
        .spawn()
        .expect("start drivebus serve");
    let said = wait_for_lines(&mut child, "drivebus serve", &["event store"]);
    let _child = Killed(child);
    let db = state.path().join("drivebus/drivebus.db");
    assert_eq!(said[0], db.display().to_string());
    assert!(db.exists(), "no store at {}", db.display());
    let left: Vec<_> = std::fs::read_dir(cwd.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(left.is_empty(), "serve wrote {left:?} in its working directory");
}
