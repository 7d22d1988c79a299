//! The dashboard in a real browser: `drivebus serve --demo` with headless Chromium driven through
//! WebDriver (chromedriver). The page must show a tile for every demo drive, ask for the token
//! when a command is first sent, say clearly when a token is not accepted, show a locked drive's
//! refusal, run `mixer-1` (state running, output frequency above 0), and fit a 360 px wide screen.
//! Then a second gateway, on a configuration of its own, shows a tripped drive (a `drivebus
//! simulate` process tripped through its control interface while the page watches) with its
//! fault code and text and the trip in the event log with the values before it, and a
//! drive whose port does not exist as offline. Screenshots go to `target/artifacts/dashboard.png`,
//! `dashboard-faults.png` and `dashboard-phone.png`.
//!
//! Both tests need the browser, so `cargo test` lists them as ignored; `cargo test -- --ignored`
//! runs them. `.ci/run` installs Debian's chromium and chromium-driver and sets
//! `DRIVEBUS_REQUIRE_INTEROP=1`, so in CI a missing browser is a failure.
//!
//! The WebDriver client is a few lines over `std::net::TcpStream` (JSON with serde_json): the
//! protocol is plain HTTP/1.1 on loopback, and no crate is needed for it.

use std::io::Write;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

/// How long anything may take before the test gives up (a generous bound, not a speed claim).
const PATIENCE: Duration = Duration::from_secs(90);

#[path = "support/http.rs"]
mod http;
use http::{free_port, http_json};
#[path = "support/lines.rs"]
mod lines;
use lines::{wait_for_lines, Killed};
#[path = "support/values_template.rs"]
mod values_template;
#[path = "../../../tests/interop/witness.rs"]
mod witness;
use witness::witness;

const DEMO_DRIVES: [&str; 10] = [
    "conveyor-1",
    "conveyor-2",
    "fan-1",
    "pump-1",
    "pump-2",
    "pump-3",
    "ahu-1",
    "ahu-2",
    "mixer-1",
    "mixer-2",
];

/// Chromium and chromedriver, or `None` when one is missing (said on stderr; a failure with
/// `DRIVEBUS_REQUIRE_INTEROP=1`).
fn browser_programs() -> Option<(PathBuf, PathBuf)> {
    let chromium = find_program(&["chromium", "chromium-browser"]);
    let chromedriver = find_program(&["chromedriver"]);
    let here = chromium.is_some() && chromedriver.is_some();
    if !witness("chromium and chromedriver", here, "apt-get install chromium chromium-driver") {
        return None;
    }
    chromium.zip(chromedriver)
}

fn find_program(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    for dir in std::env::split_paths(&path) {
        for n in names {
            let p = dir.join(n);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    None
}

/// Four minutes of mixer-2 at 12.5 Hz, from 5 to 1 minute ago: what a trend can only show when
/// the page reads the store's history (the live stream starts when the page opens).
fn seed_history(db: &Path) {
    let now_ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0);
    let store = drivebus_store::Store::open(db).expect("a store file in the temp dir");
    for i in 0..240 {
        store.sample(drivebus_store::Sample {
            time_ms: now_ms - 300_000 + i * 1000,
            drive: "mixer-2".into(),
            output_hz: Some(12.5),
            current_a: Some(1.5),
            setpoint_hz: Some(12.5),
        });
    }
    store.flush().expect("the samples are written");
}

/// `drivebus serve --demo` on free loopback ports: its HTTP address and the demo write token.
fn start_serve() -> (Killed, SocketAddr, String) {
    // A store of its own, so the page's event log and trends also come from it.
    let db =
        std::env::temp_dir().join(format!("drivebus-dashboard-{}-{}.db", std::process::id(), free_port()));
    seed_history(&db);
    let mut proc = Killed(
        Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args([
                "serve",
                "--demo",
                "--http",
                "127.0.0.1:0",
                "--modbus",
                "127.0.0.1:0",
                "--no-opcua",
                "--db",
            ])
            .arg(&db)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start drivebus serve --demo"),
    );
    // Wait for the lines that say where it listens and the token (events, not sleeps).
    let said = wait_for_lines(&mut proc.0, "drivebus serve --demo", &["dashboard", "demo write token:"]);
    (proc, dashboard_address(&said[0]), said[1].clone())
}

/// The HTTP address in the dashboard URL `serve` prints (`http://127.0.0.1:PORT/`).
fn dashboard_address(url: &str) -> SocketAddr {
    let addr = url.trim_start_matches("http://").trim_end_matches('/');
    addr.parse().unwrap_or_else(|e| panic!("dashboard URL {url:?}: {e}"))
}

/// A plant with trouble: a generic drive on a `drivebus simulate` process over TCP, to be tripped
/// through the simulator's control interface, and a drive on a serial port that does not exist.
/// Returns the processes, the gateway's HTTP address and the simulator's control address.
fn start_faulted_plant(dir: &Path) -> (Killed, Killed, SocketAddr, SocketAddr) {
    let mut sim = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["simulate", "--drive", "generic@1:modbus-rtu", "--baud", "19200", "--serial", "8N1"])
        .args(["--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start drivebus simulate");
    let at = wait_for_lines(&mut sim, "drivebus simulate", &["listening on tcp", "control http://"]);
    let sim = Killed(sim);
    let control: SocketAddr = at[1].trim_end_matches("/drives").parse().expect("the control address");

    let config = dir.join("faulted.toml");
    std::fs::write(
        &config,
        format!(
            "name = \"faulted\"\n[http]\nanonymous_read = true\n[store]\ndisabled = true\n\
             [[bus]]\nname = \"line-a\"\nport = \"tcp://{}\"\nprotocol = \"modbus-rtu\"\nbaud = 19200\nserial = \"8N1\"\n\
             [[bus.drive]]\nname = \"press-1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 200\n\
             [[bus]]\nname = \"line-b\"\nport = \"{}\"\nprotocol = \"modbus-rtu\"\nbaud = 19200\nserial = \"8N1\"\n\
             [[bus.drive]]\nname = \"press-2\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 200\n",
            at[0],
            dir.join("ttyUSB-unplugged").display()
        ),
    )
    .expect("write the configuration");
    let (serve, http) = serve_config(&config, &[]);
    (sim, serve, http, control)
}

/// `drivebus serve --config <config> <extra>` on ports of the system's choosing; its HTTP
/// address once it says where its dashboard is.
fn serve_config(config: &Path, extra: &[&str]) -> (Killed, SocketAddr) {
    let mut serve = Killed(
        Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["serve", "--no-opcua", "--config"])
            .arg(config)
            .args(extra)
            .args(["--http", "127.0.0.1:0", "--modbus", "127.0.0.1:0"])
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start drivebus serve --config"),
    );
    let url = wait_for_lines(&mut serve.0, "drivebus serve --config", &["dashboard"]);
    let http = dashboard_address(&url[0]);
    (serve, http)
}

fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return None,
        } as u32)
    };
    let mut out = Vec::with_capacity(s.len() * 3 / 4);
    let (mut acc, mut bits) = (0u32, 0);
    for v in s.bytes().filter_map(val) {
        acc = (acc << 6) | v;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    out
}

/// A WebDriver session, deleted (and chromedriver stopped) on drop.
struct Browser {
    driver: SocketAddr,
    session: String,
    _chromedriver: Killed,
}

const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

impl Browser {
    fn start(chromium: &Path, chromedriver: &Path) -> Browser {
        let mut last = String::new();
        // A free port can be taken between our look and chromedriver's bind: try a few.
        for _ in 0..3 {
            let port = free_port();
            let child = Command::new(chromedriver)
                .arg(format!("--port={port}"))
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("start chromedriver");
            let mut proc = Killed(child);
            let driver: SocketAddr = ([127, 0, 0, 1], port).into();
            let deadline = Instant::now() + PATIENCE;
            let ready = loop {
                if let Ok(Some(status)) = proc.0.try_wait() {
                    last = format!("chromedriver --port={port} exited: {status}");
                    break false;
                }
                match http_json(driver, "GET", "/status", None) {
                    Ok((200, v)) if v["value"]["ready"] == json!(true) => break true,
                    Ok((_, v)) => last = v.to_string(),
                    Err(e) => last = e,
                }
                if Instant::now() > deadline {
                    break false;
                }
                std::thread::sleep(Duration::from_millis(100));
            };
            if !ready {
                continue;
            }
            let caps = json!({ "capabilities": { "alwaysMatch": {
                "browserName": "chrome",
                "goog:chromeOptions": {
                    "binary": chromium.to_string_lossy(),
                    "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                             "--window-size=1280,2300", "--no-first-run", "--no-default-browser-check"]
                }
            }}});
            let (status, v) = http_json(driver, "POST", "/session", Some(&caps)).expect("POST /session");
            assert_eq!(status, 200, "chromedriver could not start Chromium: {v}");
            let session = v["value"]["sessionId"].as_str().expect("a session id").to_string();
            return Browser { driver, session, _chromedriver: proc };
        }
        panic!("chromedriver did not become ready: {last}");
    }

    fn call(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let full = format!("/session/{}{path}", self.session);
        let (status, v) = http_json(self.driver, method, &full, body.as_ref())
            .unwrap_or_else(|e| panic!("WebDriver {method} {path}: {e}"));
        assert_eq!(status, 200, "WebDriver {method} {path}: {v}");
        v["value"].clone()
    }

    fn goto(&self, url: &str) {
        self.call("POST", "/url", Some(json!({ "url": url })));
    }

    /// Runs `script` in the page (a function body; `return` gives the value).
    fn js(&self, script: &str) -> Value {
        self.call("POST", "/execute/sync", Some(json!({ "script": script, "args": [] })))
    }

    fn element(&self, css: &str) -> String {
        let v = self.call("POST", "/element", Some(json!({ "using": "css selector", "value": css })));
        v[ELEMENT].as_str().unwrap_or_else(|| panic!("no element {css}: {v}")).to_string()
    }

    /// A click as a user makes it (WebDriver element click: scrolled into view, must be visible).
    fn click(&self, css: &str) {
        let e = self.element(css);
        self.call("POST", &format!("/element/{e}/click"), Some(json!({})));
    }

    /// Types `text` into the field `css` after clearing it.
    fn type_into(&self, css: &str, text: &str) {
        let e = self.element(css);
        self.call("POST", &format!("/element/{e}/clear"), Some(json!({})));
        self.call("POST", &format!("/element/{e}/value"), Some(json!({ "text": text })));
    }

    fn text(&self, css: &str) -> String {
        let sel = q(css);
        self.js(&format!("const e = document.querySelector({sel}); return e ? e.textContent.trim() : null;"))
            .as_str()
            .unwrap_or("")
            .to_string()
    }

    /// Waits until `script` returns true; on timeout fails with `what` and the value of `show`.
    fn wait_for(&self, what: &str, script: &str, show: &str) {
        let deadline = Instant::now() + PATIENCE;
        while Instant::now() < deadline {
            if self.js(script) == json!(true) {
                return;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        panic!("timed out waiting for {what}; the page shows: {}", self.js(show));
    }

    fn screenshot(&self, path: &Path) {
        let b64 = self.call("GET", "/screenshot", None);
        let png = base64_decode(b64.as_str().expect("base64 screenshot"));
        assert!(png.starts_with(b"\x89PNG"), "the screenshot is not a PNG");
        std::fs::write(path, png).unwrap_or_else(|e| panic!("write {}: {e}", path.display()));
        let _ = writeln!(std::io::stderr(), "dashboard screenshot: {}", path.display());
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = http_json(self.driver, "DELETE", &format!("/session/{}", self.session), None);
    }
}

fn artifacts_dir() -> PathBuf {
    // target/<profile>/drivebus -> target/artifacts
    let bin = Path::new(env!("CARGO_BIN_EXE_drivebus"));
    let target = bin.parent().and_then(Path::parent).expect("the binary is in target/<profile>/");
    let dir = target.join("artifacts");
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("create {}: {e}", dir.display()));
    dir
}

/// `css` as a JavaScript string literal.
fn q(css: &str) -> String {
    serde_json::to_string(css).expect("a string")
}

fn tile(id: &str, rest: &str) -> String {
    format!("[data-drive=\"{id}\"] {rest}")
}

#[test]
#[ignore = "needs chromium (.ci/install-witnesses.sh)"]
fn the_dashboard_runs_a_drive_in_a_real_browser() {
    let Some((chromium, chromedriver)) = browser_programs() else { return };
    let (_serve, http, token) = start_serve();
    let browser = Browser::start(&chromium, &chromedriver);
    browser.goto(&format!("http://{http}/"));

    // A tile for every demo drive, grouped by the four demo buses, each polled.
    browser.wait_for(
        "a polled tile for each of the 10 demo drives",
        "const t = [...document.querySelectorAll('[data-drive]')];
         return t.length === 10 && t.every(e => e.querySelector('[data-field=state]').textContent !== 'unknown');",
        "return [...document.querySelectorAll('[data-drive]')].map(e => e.dataset.drive + ':' + e.querySelector('[data-field=state]').textContent);",
    );
    let mut ids: Vec<String> = serde_json::from_value(
        browser.js("return [...document.querySelectorAll('[data-drive]')].map(e => e.dataset.drive);"),
    )
    .unwrap();
    ids.sort();
    let mut want: Vec<String> = DEMO_DRIVES.iter().map(|s| s.to_string()).collect();
    want.sort();
    assert_eq!(ids, want);
    assert_eq!(browser.js("return document.querySelectorAll('[data-bus]').length;"), json!(4));
    assert_eq!(browser.text(&tile("mixer-1", "[data-field=state]")), "stopped");
    // The bus statistics come from GET /api/buses and the stream.
    browser.wait_for(
        "bus statistics with transactions counted",
        "const d = document.querySelector('[data-bus=\"line-b800\"] [data-field=transactions]');
         return !!d && Number(d.textContent) > 0;",
        "return document.querySelector('[data-bus=\"line-b800\"]').innerText;",
    );
    assert!(browser.js("return document.getElementById('token-dialog').hidden;") == json!(true));

    // First command: the page asks for the token. A wrong one is refused clearly (401).
    browser.type_into(&tile("mixer-1", "[data-field=speed]"), "30");
    browser.click(&tile("mixer-1", "[data-action=speed]"));
    browser.wait_for(
        "the token prompt",
        "return !document.getElementById('token-dialog').hidden;",
        "return document.body.innerText.slice(0, 500);",
    );
    browser.type_into("#token-input", "not-the-token");
    browser.click("#token-save");
    let msg = q(&tile("mixer-1", "[data-field=message]"));
    browser.wait_for(
        "the 401 message and the prompt again",
        &format!(
            "const m = document.querySelector({msg});
             return m.dataset.kind === 'error' && m.textContent.includes('401')
                 && !document.getElementById('token-dialog').hidden;"
        ),
        &format!("return document.querySelector({msg}).textContent;"),
    );
    // The right token: the pending command is sent and the drive's answer shown.
    browser.type_into("#token-input", &token);
    browser.click("#token-save");
    browser.wait_for(
        "the speed command's answer",
        &format!("return document.querySelector({msg}).dataset.kind === 'ok';"),
        &format!("return document.querySelector({msg}).textContent;"),
    );

    // Run: the state becomes running and the output frequency rises above 0.
    browser.click(&tile("mixer-1", "[data-action=run]"));
    let state = q(&tile("mixer-1", "[data-field=state]"));
    let hz = q(&tile("mixer-1", "[data-field=output_hz]"));
    browser.wait_for(
        "mixer-1 running with its output frequency above 0",
        &format!(
            "return document.querySelector({state}).textContent === 'running'
                 && Number(document.querySelector({hz}).dataset.value) > 0;"
        ),
        "return document.querySelector('[data-drive=\"mixer-1\"]').innerText;",
    );
    assert!(browser.js("return document.getElementById('token-dialog').hidden;") == json!(true));

    // B800: the gateway knows the speed it set, and the tile shows it; the protocol reports no
    // direction, and the tile says so.
    assert_eq!(browser.text(&tile("mixer-1", "[data-field=setpoint_hz]")), "30.00");
    assert_eq!(
        browser.text(&tile("mixer-1", "[data-field=direction]")),
        "direction not reported (B800 protocol)"
    );
    // Danfoss: a direction, or a dash while the drive has not told it.
    let ahu = browser.text(&tile("ahu-1", "[data-field=direction]"));
    assert!(["forward", "reverse", "direction –"].contains(&ahu.as_str()), "{ahu}");

    // A locked drive's command controls are disabled and say why; its Trend button is not.
    let locked = browser.js(&format!(
        "const t = document.querySelector({});
         return [...t.querySelectorAll('.controls button, .controls input')].map(b => [b.dataset.action || 'speed-field', b.disabled, b.title]);",
        q("[data-drive=\"pump-3\"]")
    ));
    for control in locked.as_array().expect("a list") {
        let (name, disabled, title) = (&control[0], &control[1], control[2].as_str().unwrap_or(""));
        if name == "trend" {
            assert_eq!(disabled, &json!(false), "{control}");
        } else {
            assert_eq!(disabled, &json!(true), "{control}");
            assert!(title.starts_with("locked:"), "{control}");
        }
    }
    assert!(browser.text(&tile("pump-3", "[data-field=locked-why]")).contains("locked = true"));
    // An unlocked drive's are live.
    assert_eq!(
        browser.js(&format!(
            "return document.querySelector({}).disabled;",
            q(&tile("pump-2", "[data-action=run]"))
        )),
        json!(false)
    );

    // The live trend opens with points from the stream, under a time axis; the tiles beside it
    // keep their height.
    let height = |id: &str| {
        browser.js(&format!(
            "return document.querySelector({}).getBoundingClientRect().height;",
            q(&format!("[data-drive=\"{id}\"]"))
        ))
    };
    let neighbour_before = height("mixer-2");
    browser.click(&tile("mixer-1", "[data-action=trend]"));
    browser.wait_for(
        "mixer-1's trend with points",
        "const p = document.querySelector('[data-drive=\"mixer-1\"] .trend-hz').getAttribute('points');
         return p.trim().split(' ').length >= 2;",
        "return document.querySelector('[data-drive=\"mixer-1\"] [data-field=trend]').outerHTML;",
    );
    assert_eq!(height("mixer-2"), neighbour_before, "opening mixer-1's trend stretched mixer-2");
    let axis: Vec<String> = serde_json::from_value(browser.js(
        "return [...document.querySelectorAll('[data-drive=\"mixer-1\"] .trend-axis span')].map(s => s.textContent);",
    ))
    .unwrap();
    assert_eq!(axis.len(), 5, "{axis:?}");
    assert!(
        axis.iter().all(|t| t.len() == 8 && t.as_bytes()[2] == b':' && t.as_bytes()[5] == b':'),
        "clock times: {axis:?}"
    );
    assert!(axis.first() < axis.last(), "{axis:?}");

    // mixer-2's trend opens with the store's history: 200 points or more within 15 s of opening
    // it, the first at the window's left edge. Live points alone come one per poll from when the
    // page opened, so past those 15 s the condition can no longer become true.
    browser.js("window.__trendOpened = Date.now(); return true;");
    browser.click(&tile("mixer-2", "[data-action=trend]"));
    browser.wait_for(
        "mixer-2's trend starting with the stored history",
        "const p = document.querySelector('[data-drive=\"mixer-2\"] .trend-hz').getAttribute('points').trim();
         if (!p || Date.now() - window.__trendOpened > 15000) return false;
         const pts = p.split(' ');
         return pts.length >= 200 && parseFloat(pts[0].split(',')[0]) < 20;",
        "return document.querySelector('[data-drive=\"mixer-2\"] .trend-hz').getAttribute('points').slice(0, 200);",
    );

    // The event log shows the commands (stored or live).
    browser.wait_for(
        "the run command in the event log",
        "return [...document.querySelectorAll('#event-rows tr')].some(r => r.dataset.kind === 'command' && r.textContent.includes('mixer-1') && r.textContent.includes('run'));",
        "return document.getElementById('event-rows').innerText;",
    );

    let dir_artifacts = artifacts_dir();
    browser.screenshot(&dir_artifacts.join("dashboard.png"));

    // After a reload the command is still in the event log: read back from the store.
    browser.call("POST", "/refresh", Some(json!({})));
    browser.wait_for(
        "the run command in the stored event log after a reload",
        "return [...document.querySelectorAll('#event-rows tr')].some(r => r.dataset.kind === 'command' && r.textContent.includes('mixer-1') && r.textContent.includes('run'));",
        "return document.getElementById('event-rows').innerText;",
    );

    // The Kind filter: only commands, then everything again (the gateway's start is back).
    browser.js(
        "const s = document.getElementById('event-kind'); s.value = 'command'; s.dispatchEvent(new Event('change')); return true;",
    );
    browser.wait_for(
        "only commands in the event log",
        "const rows = [...document.querySelectorAll('#event-rows tr')]; return rows.length > 0 && rows.every(r => r.dataset.kind === 'command');",
        "return document.getElementById('event-rows').innerText;",
    );
    browser.js(
        "const s = document.getElementById('event-kind'); s.value = ''; s.dispatchEvent(new Event('change')); return true;",
    );
    browser.wait_for(
        "every kind in the event log again",
        "const rows = [...document.querySelectorAll('#event-rows tr')]; return rows.some(r => r.dataset.kind === 'started') && rows.some(r => r.dataset.kind === 'command');",
        "return document.getElementById('event-rows').innerText;",
    );

    // A tripped drive and a drive that cannot be reached, as a second gateway shows them.
    let dir = std::env::temp_dir().join(format!("drivebus-dashboard-faults-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temp dir");
    let (_sim, _faulted, faulted_http, control) = start_faulted_plant(&dir);
    browser.goto(&format!("http://{faulted_http}/"));
    // Tripped while the gateway polls it and the page follows the live events: the trip's row
    // in the event log shows the values the drive had just before it.
    browser.wait_for(
        "press-1 polled, stopped",
        "const t = document.querySelector('[data-drive=\"press-1\"]'); return !!t && t.dataset.state === 'stopped';",
        "const t = document.querySelector('[data-drive=\"press-1\"]'); return t ? t.innerText : document.body.innerText.slice(0, 300);",
    );
    let (status, answer) =
        http_json(control, "POST", "/drives/1", Some(&json!({ "trip": "over-current" }))).expect("trip");
    assert_eq!(status, 200, "tripping the simulated drive: {answer}");
    browser.wait_for(
        "the trip in the event log with the values before it",
        "return [...document.querySelectorAll('#event-rows tr')].some(r => r.dataset.kind === 'trip' && r.textContent.includes('press-1') && r.textContent.includes('before: stopped 0.00 Hz'));",
        "return document.getElementById('event-rows').innerText;",
    );
    let fault = q(&tile("press-1", "[data-field=fault]"));
    browser.wait_for(
        "press-1 tripped, with the fault's code and text",
        &format!(
            "const t = document.querySelector('[data-drive=\"press-1\"]'); const f = document.querySelector({fault});
             return !!t && t.dataset.state === 'tripped' && !f.hidden && /^fault \\d+: \\S/.test(f.textContent);"
        ),
        "const t = document.querySelector('[data-drive=\"press-1\"]'); return t ? t.innerText : document.body.innerText.slice(0, 300);",
    );
    let fault_text = browser.text(&tile("press-1", "[data-field=fault]"));
    assert!(
        fault_text.to_lowercase().contains("over"),
        "the over-current trip by its manual text: {fault_text}"
    );
    browser.wait_for(
        "press-2 and its bus offline",
        "const t = document.querySelector('[data-drive=\"press-2\"]');
         const b = document.querySelector('[data-bus=\"line-b\"] [data-field=online]');
         return !!t && t.dataset.state === 'offline' && !!b && b.dataset.state === 'offline';",
        "const t = document.querySelector('[data-drive=\"press-2\"]'); return t ? t.innerText : document.body.innerText.slice(0, 300);",
    );
    // The drive on the live line stays online: one dead port takes nothing else down.
    assert_eq!(browser.text(&tile("press-1", "[data-field=state]")), "tripped");
    // Nothing left through the missing port, and no line is busier than the time that passed.
    let bus_field = |bus: &str, f: &str| browser.text(&format!("[data-bus=\"{bus}\"] [data-field={f}]"));
    assert_eq!(bus_field("line-b", "transactions"), "0");
    assert_eq!(bus_field("line-b", "utilization"), "0.0 %");
    let busy = bus_field("line-a", "utilization");
    let pct: f64 = busy.trim_end_matches('%').trim().parse().unwrap_or(f64::NAN);
    assert!((0.0..=100.0).contains(&pct), "line-a utilization {busy}");
    // This gateway's configuration says [store] disabled = true: the event log says that, not
    // to drop a command-line flag it was not given.
    browser.wait_for(
        "the event log saying why there are no stored events",
        "return document.getElementById('event-status').textContent.includes('disabled = true');",
        "return document.getElementById('event-status').textContent;",
    );
    browser.screenshot(&dir_artifacts.join("dashboard-faults.png"));
    let _ = std::fs::remove_dir_all(&dir);

    // A phone: 360 CSS px wide, nothing wider than the screen.
    browser.call("POST", "/window/rect", Some(json!({ "width": 360, "height": 800 })));
    browser.wait_for(
        "a 360 px wide viewport",
        "return window.innerWidth <= 400;",
        "return window.innerWidth;",
    );
    let overflow = browser.js("return document.documentElement.scrollWidth - window.innerWidth;");
    assert!(
        overflow.as_i64().is_some_and(|o| o <= 0),
        "the page is wider than a phone screen by {overflow} px"
    );
    browser.screenshot(&dir_artifacts.join("dashboard-phone.png"));
}

/// The bench's plant (bench/gateway_load.sh): 1000 simulated generic drives on 32 virtual buses.
fn start_plant_of_1000(dir: &Path) -> (Killed, SocketAddr) {
    let mut toml = String::from("name = \"plant\"\n[http]\nanonymous_read = true\n");
    let mut n = 0;
    for b in 1..=32 {
        let per = if b <= 8 { 32 } else { 31 };
        toml += &format!(
            "[[bus]]\nname = \"line-{b}\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 115200\n"
        );
        for a in 1..=per {
            n += 1;
            toml += &format!("[[bus.drive]]\nname = \"vfd-{n}\"\nfamily = \"generic\"\naddress = {a}\n");
        }
    }
    assert_eq!(n, 1000);
    let config = dir.join("plant.toml");
    std::fs::write(&config, toml).expect("write the configuration");
    serve_config(&config, &["--no-store"])
}

/// A hall's worth of drives: the page opens on the table (drive, bus, state, output and set Hz,
/// current, fault, age), sorts it, filters it by bus and state and searches it by name; the
/// cards, when chosen, fill the width of a wide window. The times the page took are printed.
#[test]
#[ignore = "needs chromium (.ci/install-witnesses.sh)"]
fn the_table_view_holds_a_plant_of_1000_drives() {
    let Some((chromium, chromedriver)) = browser_programs() else { return };
    let dir = tempfile::tempdir().expect("a temp dir");
    let (_serve, http) = start_plant_of_1000(dir.path());
    let browser = Browser::start(&chromium, &chromedriver);
    browser.call("POST", "/window/rect", Some(json!({ "width": 1900, "height": 1200 })));
    browser.goto(&format!("http://{http}/"));
    browser.wait_for(
        "the table with every drive polled",
        "const rows = document.querySelectorAll('#dense-rows tr');
         return !document.getElementById('dense').hidden && rows.length === 1000
             && [...rows].every(r => r.cells[2].textContent !== 'unknown');",
        "return [document.getElementById('dense-count').textContent, document.querySelectorAll('#dense-rows tr').length];",
    );
    assert_eq!(browser.text("#dense-count"), "1000 of 1000 drives");
    assert_eq!(
        browser.js("return document.querySelectorAll('[data-drive]').length;"),
        json!(0),
        "no cards made"
    );
    let names = |n: usize| -> Vec<String> {
        serde_json::from_value(browser.js(&format!(
            "return [...document.querySelectorAll('#dense-rows tr')].slice(0, {n}).map(r => r.cells[0].textContent);"
        )))
        .unwrap()
    };
    assert_eq!(names(3), ["vfd-1", "vfd-2", "vfd-3"], "sorted by name, numbers as numbers");
    let timed = |script: &str| -> f64 {
        browser
            .js(&format!("const t0 = performance.now(); {script}; return performance.now() - t0;"))
            .as_f64()
            .unwrap_or(f64::NAN)
    };
    let sort_ms = timed("document.querySelector('#dense-table th[data-sort=id]').click()");
    assert_eq!(names(2), ["vfd-1000", "vfd-999"], "the second click sorts the other way");
    let by_bus_ms = timed("const s = document.getElementById('dense-bus'); s.value = 'line-3'; s.dispatchEvent(new Event('change'))");
    let buses: Vec<String> = serde_json::from_value(
        browser
            .js("return [...document.querySelectorAll('#dense-rows tr')].map(r => r.cells[1].textContent);"),
    )
    .unwrap();
    assert_eq!(buses.len(), 32);
    assert!(buses.iter().all(|b| b == "line-3"), "{buses:?}");
    browser.js("const s = document.getElementById('dense-bus'); s.value = ''; s.dispatchEvent(new Event('change')); return true;");
    browser.js("const s = document.getElementById('dense-state'); s.value = 'running'; s.dispatchEvent(new Event('change')); return true;");
    assert_eq!(browser.text("#dense-count"), "0 of 1000 drives");
    browser.js("const s = document.getElementById('dense-state'); s.value = 'stopped'; s.dispatchEvent(new Event('change')); return true;");
    assert_eq!(browser.text("#dense-count"), "1000 of 1000 drives");
    browser.js("const s = document.getElementById('dense-state'); s.value = ''; s.dispatchEvent(new Event('change')); return true;");
    browser.click("#dense-table th[data-sort=id]");
    browser.type_into("#dense-search", "vfd-10");
    let mut found = names(20);
    found.sort();
    let mut want: Vec<String> = ["vfd-10", "vfd-1000"].iter().map(|s| s.to_string()).collect();
    want.extend((100..=109).map(|n| format!("vfd-{n}")));
    want.sort();
    assert_eq!(found, want);
    // The sort by output frequency puts every drive in order (the stopped ones all at 0.00 Hz,
    // then by name).
    browser.type_into("#dense-search", "");
    browser.click("#dense-table th[data-sort=output_hz]");
    assert_eq!(
        browser.js("return document.querySelector('#dense-table th[data-sort=output_hz]').getAttribute('aria-sort');"),
        json!("ascending")
    );
    browser.screenshot(&artifacts_dir().join("dashboard-table.png"));

    // The cards, chosen: a tile per drive, as many to a row as the window holds.
    let cards_ms = timed("document.querySelector('[data-view=cards]').click()");
    assert_eq!(browser.js("return document.querySelectorAll('[data-drive]').length;"), json!(1000));
    let per_row = browser
        .js("const t = [...document.querySelectorAll('[data-bus=\"line-1\"] [data-drive]')];
         return t.filter(e => e.offsetTop === t[0].offsetTop).length;");
    assert!(per_row.as_i64().is_some_and(|n| n >= 5), "{per_row} cards to a row in a 1900 px window");
    let _ = writeln!(
        std::io::stderr(),
        "dashboard with 1000 drives: sort {sort_ms:.1} ms, filter by bus {by_bus_ms:.1} ms, \
         switch to 1000 cards {cards_ms:.1} ms; {per_row} cards to a row at 1900 px"
    );
}

/// The commissioning pages against `serve --demo`: back up fan-1, change P0.02 on its parameter
/// page (confirmed old → new), see the diff against the backup show exactly that parameter,
/// restore it, see no difference; a write the drive refuses shows the drive's reason; a scan of
/// the generic demo bus finds its three drives while conveyor-1's data stays fresh (within four
/// of its 250 ms poll intervals). Screenshots: `workbench-params.png`, `workbench-diff.png`,
/// `workbench-scan.png` under target/artifacts.
#[test]
#[ignore = "needs chromium (.ci/install-witnesses.sh)"]
fn the_commissioning_pages_back_up_edit_restore_and_scan_in_a_real_browser() {
    let Some((chromium, chromedriver)) = browser_programs() else { return };
    let (_serve, http, token) = start_serve();
    let browser = Browser::start(&chromium, &chromedriver);
    let artifacts = artifacts_dir();
    browser.goto(&format!("http://{http}/"));
    browser.js(&format!("sessionStorage.setItem('drivebus.token', {}); return true;", q(&token)));
    browser.goto(&format!("http://{http}/#drive/fan-1"));
    let p002 = |rest: &str| q(&format!("#wb-param-rows tr[data-param=\"P0.02\"] {rest}"));
    browser.wait_for(
        "fan-1's first group read, P0.02 at its default",
        &format!(
            "const v = document.querySelector({}); return !!v && v.textContent === '50.00 Hz'
               && document.getElementById('wb-read').disabled === false;",
            p002("[data-field=value]")
        ),
        "return document.getElementById('workbench').innerText.slice(0, 800);",
    );
    assert_eq!(browser.text("#wb-title"), "fan-1");
    assert!(browser.text("#wb-read-status").starts_with("read "), "{}", browser.text("#wb-read-status"));
    browser.screenshot(&artifacts.join("workbench-params.png"));

    // The backup, as the page downloads it.
    browser.click("[data-tab=backup]");
    browser.click("#wb-download");
    browser.wait_for(
        "the backup downloaded",
        "return document.getElementById('wb-backup-status').textContent.includes('downloaded');",
        "return document.getElementById('wb-backup-status').textContent;",
    );
    let backup = browser.js("return window.drivebusWorkbench.lastBackup();").as_str().unwrap().to_string();
    let parsed: Value = serde_json::from_str(&backup).expect("the backup is JSON");
    assert_eq!(parsed["params"]["P0.02"]["raw"], 5000);

    // Change P0.02: the confirmation shows old → new; the row shows the new value, marked.
    browser.click("[data-tab=params]");
    browser.type_into("#wb-param-rows tr[data-param=\"P0.02\"] [data-field=new]", "42.5");
    browser.click("#wb-param-rows tr[data-param=\"P0.02\"] [data-action=edit]");
    browser.wait_for(
        "the confirmation",
        "return !document.getElementById('wb-confirm').hidden;",
        "return document.getElementById('wb-confirm').outerHTML;",
    );
    let confirm = browser.text("#wb-confirm-text");
    assert!(confirm.contains("50.00 Hz → 42.5 Hz"), "{confirm}");
    browser.click("#wb-confirm-yes");
    browser.wait_for(
        "P0.02 written and read back",
        &format!(
            "const v = document.querySelector({}); return !!v && v.textContent === '42.50 Hz';",
            p002("[data-field=value]")
        ),
        &format!("return document.querySelector({}).parentElement.innerText;", p002("td")),
    );
    assert_eq!(
        browser.js(&format!(
            "return document.querySelector({}).classList.contains('differs');",
            q("#wb-param-rows tr[data-param=\"P0.02\"]")
        )),
        json!(true)
    );

    // Upload the backup: the diff is exactly P0.02, drive 42.50 Hz, file 50.00 Hz.
    browser.click("[data-tab=backup]");
    let file = std::env::temp_dir().join(format!("drivebus-fan-1-{}.json", std::process::id()));
    std::fs::write(&file, &backup).expect("write the backup file");
    let input = browser.element("#wb-file");
    browser.call("POST", &format!("/element/{input}/value"), Some(json!({ "text": file.to_string_lossy() })));
    browser.wait_for(
        "the diff",
        "return document.querySelectorAll('#wb-diff-rows tr').length > 0
             || document.getElementById('wb-backup-status').dataset.kind === 'error';",
        "return document.getElementById('wb-backup').innerText;",
    );
    let diff = browser.js(
        "return [...document.querySelectorAll('#wb-diff-rows tr')].map(tr => [tr.dataset.param, tr.cells[3].textContent, tr.cells[4].textContent, tr.querySelector('input').checked]);",
    );
    assert_eq!(diff, json!([["P0.02", "42.50 Hz", "50.00 Hz", true]]));
    browser.screenshot(&artifacts.join("workbench-diff.png"));
    browser.click("#wb-apply");
    browser.wait_for(
        "the row restored",
        "const r = document.querySelector('#wb-diff-rows [data-field=result]'); return !!r && r.textContent === 'ok';",
        "return document.getElementById('wb-backup').innerText;",
    );
    assert_eq!(browser.text("#wb-apply-status"), "1 of 1 written");
    browser.js(&format!("window.drivebusWorkbench.restoreText({}); return true;", q(&backup)));
    browser.wait_for(
        "no difference left",
        "return document.getElementById('wb-backup-status').textContent.startsWith('No difference');",
        "return document.getElementById('wb-backup-status').textContent;",
    );
    let _ = std::fs::remove_file(&file);

    // A write the drive refuses (the maximum frequency while the motor runs) shows its reason.
    browser.js(
        "window.__ran = null; window.drivebus.api('POST', '/api/drives/fan-1/run')
           .then(() => { window.__ran = true; }, (e) => { window.__ran = String(e.message); }); return true;",
    );
    browser.wait_for("fan-1 running", "return window.__ran === true;", "return window.__ran;");
    browser.click("[data-tab=params]");
    browser.type_into("#wb-param-rows tr[data-param=\"P0.04\"] [data-field=new]", "60");
    browser.click("#wb-param-rows tr[data-param=\"P0.04\"] [data-action=edit]");
    browser.click("#wb-confirm-yes");
    let msg = q("#wb-param-rows tr[data-param=\"P0.04\"] [data-field=message]");
    browser.wait_for(
        "the drive's refusal",
        &format!("const m = document.querySelector({msg}); return !!m && m.dataset.kind === 'error';"),
        &format!("return document.querySelector({msg}).textContent;"),
    );
    let refusal = browser.js(&format!("return document.querySelector({msg}).textContent;"));
    let refusal = refusal.as_str().unwrap_or_default();
    assert!(refusal.contains("409 refused") && refusal.contains("the drive refused: code"), "{refusal}");

    // Find drives on the generic bus while conveyor-1 (polled every 250 ms) keeps fresh data.
    browser.goto(&format!("http://{http}/#bus/line-generic"));
    browser.wait_for(
        "the bus page",
        "return !document.getElementById('wb-bus').hidden;",
        "return location.hash;",
    );
    browser.type_into("#wb-addresses", "1-8");
    browser.click("#wb-scan");
    let mut worst_age = 0u64;
    let deadline = Instant::now() + PATIENCE;
    loop {
        let (status, d) = http_json(http, "GET", "/api/drives/conveyor-1", None).expect("GET conveyor-1");
        assert_eq!(status, 200, "{d}");
        worst_age = worst_age.max(d["age_ms"].as_u64().unwrap_or(u64::MAX));
        if browser.text("#wb-scan-status").starts_with("done") {
            break;
        }
        assert!(Instant::now() < deadline, "the scan did not end: {}", browser.text("#wb-scan-status"));
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(worst_age <= 4 * 250, "conveyor-1's data was {worst_age} ms old during the scan");
    let found = browser.js(
        "return [...document.querySelectorAll('#wb-found-rows tr')].map(tr => [Number(tr.dataset.address), tr.cells[1].textContent, tr.cells[4].textContent]);",
    );
    assert_eq!(
        found,
        json!([[1, "generic", "conveyor-1"], [2, "generic", "conveyor-2"], [3, "generic", "fan-1"]])
    );
    assert!(browser.text("#wb-config").contains("[[bus.drive]]"), "{}", browser.text("#wb-config"));
    let _ =
        writeln!(std::io::stderr(), "scan of line-generic 1-8: conveyor-1's worst data age {worst_age} ms");
    browser.screenshot(&artifacts.join("workbench-scan.png"));
}

/// Issue 27: a gateway that is a standby on its line (another gateway masters it) shows the
/// bus's role `standby`, a `standby` badge on the drive's tile, and the tile's command
/// controls off with the reason.
#[test]
#[ignore = "needs chromium (.ci/install-witnesses.sh)"]
fn a_standby_shows_its_role_and_its_drives_controls_are_off() {
    let Some((chromium, chromedriver)) = browser_programs() else { return };
    let dir = tempfile::tempdir().unwrap();
    let mut sim = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["simulate", "--drive", "generic@1:modbus-rtu", "--baud", "19200", "--serial", "8N1"])
        .args(["--tcp", "127.0.0.1:0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start drivebus simulate");
    let at = wait_for_lines(&mut sim, "drivebus simulate", &["listening on tcp"]);
    let _sim = Killed(sim);
    // Nobody else masters the line: a standby listens twice 60 s before it takes it.
    let config = dir.path().join("standby.toml");
    std::fs::write(
        &config,
        format!(
            "name = \"standby\"\n[http]\nanonymous_read = true\n[store]\ndisabled = true\n\
             [standby]\nrole = \"standby\"\nsilence_ms = 60000\n\
             [[bus]]\nname = \"line-a\"\nport = \"tcp://{}\"\nprotocol = \"modbus-rtu\"\nbaud = 19200\nserial = \"8N1\"\n\
             [[bus.drive]]\nname = \"press-1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 200\n",
            at[0]
        ),
    )
    .unwrap();
    let (_serve, http) = serve_config(&config, &[]);
    let browser = Browser::start(&chromium, &chromedriver);
    browser.goto(&format!("http://{http}/"));
    browser.wait_for(
        "the bus's role standby and the drive's standby badge",
        "const role = document.querySelector('[data-bus] [data-field=role]');
         const badge = document.querySelector('[data-drive=\"press-1\"] [data-field=source]');
         return role !== null && role.textContent === 'standby' && badge !== null && !badge.hidden;",
        "return [document.querySelector('[data-bus] [data-field=role]')?.textContent,
                 document.querySelector('[data-drive=\"press-1\"] [data-field=source]')?.hidden];",
    );
    let run = browser.js(&format!(
        "const b = document.querySelector({}); return [b.disabled, b.title];",
        q(&tile("press-1", "[data-action=run]"))
    ));
    assert_eq!(run[0], json!(true), "{run}");
    assert!(run[1].as_str().unwrap().starts_with("standby:"), "{run}");
    assert!(browser
        .text(&tile("press-1", "[data-field=locked-why]"))
        .contains("another gateway masters the line"));
}

/// A templated drive's named values (its template's `[values]`) on its tile: a line each with
/// the template's name and the value in its unit; a built-in drive's tile has no such list.
#[test]
#[ignore = "needs chromium (.ci/install-witnesses.sh)"]
fn a_templated_drives_tile_lists_its_named_values_with_their_units() {
    let Some((chromium, chromedriver)) = browser_programs() else { return };
    let dir = tempfile::tempdir().unwrap();
    values_template::write(dir.path());
    let config = dir.path().join("plant.toml");
    std::fs::write(
        &config,
        format!(
            "name = \"values\"\ntemplates = [\"tpl.toml\"]\n[http]\nanonymous_read = true\n[store]\ndisabled = true\n\
             [[bus]]\nname = \"line-v\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 115200\n\
             [[bus.drive]]\nname = \"tpl-1\"\nfamily = \"{}\"\naddress = 1\npoll_ms = 200\n\
             [[bus.drive]]\nname = \"plain-1\"\nfamily = \"generic\"\naddress = 2\npoll_ms = 200\n",
            values_template::KIND
        ),
    )
    .unwrap();
    let (_serve, http) = serve_config(&config, &[]);
    let browser = Browser::start(&chromium, &chromedriver);
    browser.goto(&format!("http://{http}/"));
    let values = tile("tpl-1", "[data-field=values]");
    browser.wait_for(
        "tpl-1's named values on its tile",
        &format!(
            "const l = document.querySelector({}); return l !== null && !l.hidden && \
             /^\\d+(\\.\\d+)? V$/.test(l.querySelector('dd[data-value=dc_bus_v]')?.textContent ?? '');",
            q(&values)
        ),
        &format!("return document.querySelector({})?.outerHTML;", q(&values)),
    );
    let names = browser.js(&format!(
        "return [...document.querySelectorAll({})].map((e) => e.textContent);",
        q(&tile("tpl-1", "[data-field=values] dt"))
    ));
    assert_eq!(names, json!(["dc_bus_v", "power_kw"]));
    let dc = browser.text(&tile("tpl-1", "[data-field=values] dd[data-value=dc_bus_v]"));
    let volts: f64 = dc.trim_end_matches(" V").parse().unwrap();
    assert!((400.0..700.0).contains(&volts), "the simulated DC bus: {dc}");
    let kw = browser.text(&tile("tpl-1", "[data-field=values] dd[data-value=power_kw]"));
    assert!(kw.ends_with(" kW"), "{kw}");
    // A built-in drive's tile shows no list.
    let plain = browser.js(&format!(
        "return document.querySelector({}).hidden;",
        q(&tile("plain-1", "[data-field=values]"))
    ));
    assert_eq!(plain, json!(true));
    browser.screenshot(&artifacts_dir().join("dashboard-values.png"));
}
