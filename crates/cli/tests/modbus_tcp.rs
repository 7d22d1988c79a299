//! Drives on Modbus TCP end to end: `drivebus simulate --modbus-tcp` serves the virtual drives
//! over MBAP, the commissioning commands reach them with `--protocol modbus-tcp`, and mbpoll
//! (a witness) reads the same registers.

use std::process::Command;

#[path = "support/sim.rs"]
mod sim;
#[path = "../../../tests/interop/witness.rs"]
mod witness;
use sim::{drivebus, ok, simulate, simulate_with, wait_status, Proc};

/// Where a simulator started with `--modbus-tcp` listens, as `--port` takes it.
fn port_of(sim: &Proc) -> String {
    format!("tcp://{}", sim.ready.trim_start_matches("modbus-tcp "))
}

#[test]
fn commissioning_commands_run_a_drive_over_modbus_tcp() {
    let sim = simulate("generic@1", &["--modbus-tcp", "127.0.0.1:0"]);
    let port = port_of(&sim);
    let s = sim::status(&port, "generic", Some("modbus-tcp"), 1);
    assert_eq!(s["running"], false, "{s}");
    ok(&drivebus(&port, "generic", Some("modbus-tcp"), 1, &["speed", "30"]), "speed");
    ok(&drivebus(&port, "generic", Some("modbus-tcp"), 1, &["run"]), "run");
    wait_status(&port, "generic", Some("modbus-tcp"), 1, "ramping to 30 Hz", |s| {
        s["output_hz"].as_f64().is_some_and(|hz| (hz - 30.0).abs() < 0.01)
    });
    // A unit id no drive has: the endpoint answers as a Modbus TCP/RTU gateway does, after its
    // own wait of 1 s (an answer after the 200 ms timeout would be another transaction's).
    let o = drivebus(&port, "generic", Some("modbus-tcp"), 2, &["status", "--timeout", "3000"]);
    assert_eq!(o.code, 1, "{}{}", o.stdout, o.stderr);
    assert!(o.stderr.contains("0x0B") && o.stderr.contains("gateway target"), "{}", o.stderr);
    // A family without Modbus cannot be reached over Modbus TCP.
    let o = drivebus(&port, "danfoss", Some("modbus-tcp"), 1, &["status"]);
    assert_eq!(o.code, 3, "{}", o.stderr);
    assert!(o.stderr.contains("does not speak Modbus, so not modbus-tcp"), "{}", o.stderr);
    // Modbus TCP over a serial device is bad usage, said in one line.
    let o = drivebus("/dev/ttyS99", "generic", Some("modbus-tcp"), 1, &["status"]);
    assert_eq!(o.code, 2, "{}", o.stderr);
    assert!(o.stderr.contains("give tcp://HOST[:PORT]"), "{}", o.stderr);
}

/// `--max-in-flight N` on the commissioning commands: requests pipelined on a modbus-tcp link
/// (status and a speed on one drive, `monitor` on two drives of one server), under the
/// gateway's `max_in_flight` rule: 1..16, and a modbus-tcp link only, refused otherwise in one
/// line with exit 3.
#[test]
fn max_in_flight_pipelines_a_modbus_tcp_link_and_is_refused_elsewhere() {
    let sim = simulate_with(&["--drive", "generic@1", "--drive", "generic@2", "--modbus-tcp", "127.0.0.1:0"]);
    let port = port_of(&sim);
    let run = |address: u8, args: &[&str]| drivebus(&port, "generic", Some("modbus-tcp"), address, args);
    ok(&run(2, &["speed", "15", "--max-in-flight", "4"]), "speed");
    let o = run(2, &["status", "--json", "--max-in-flight", "4"]);
    ok(&o, "status");
    let s: serde_json::Value = serde_json::from_str(o.stdout.trim()).unwrap();
    assert_eq!(s["setpoint_hz"], 15.0, "{s}");
    // monitor of both drives through a proxy that passes nothing on until two requests are
    // waiting: with two in flight both drives answer; one at a time, drive 1's request waits
    // until it timed out (no retry), and drive 1 has not answered.
    let monitor = |extra: &[&str]| {
        let proxy = two_at_once_proxy(port.trim_start_matches("tcp://"));
        let args =
            [&["monitor", "--address", "2", "--count", "1", "--json", "--retries", "0"][..], extra].concat();
        let o = drivebus(&proxy, "generic", Some("modbus-tcp"), 1, &args);
        ok(&o, "monitor");
        let seen: Vec<serde_json::Value> =
            o.stdout.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        let answered = |address: u8| {
            seen.iter().any(|d| d["address"] == address && d["error"].is_null() && d["running"].is_boolean())
        };
        (answered(1), answered(2), o.stdout)
    };
    let (one, two, said) = monitor(&["--max-in-flight", "2"]);
    assert!(one && two, "both drives answer with two requests in flight: {said}");
    let (one, two, said) = monitor(&[]);
    assert!(!one && two, "one at a time, drive 1's request waited for a second one: {said}");

    // The rule and its refusals.
    for (n, want) in
        [("0", "--max-in-flight 0 is outside 1..16"), ("17", "--max-in-flight 17 is outside 1..16")]
    {
        let o = run(1, &["status", "--max-in-flight", n]);
        assert_eq!(o.code, 3, "{}", o.stderr);
        assert_eq!(o.stderr.trim(), format!("drivebus: {want}"), "{}", o.stderr);
    }
    let not_modbus_tcp = [
        drivebus("/dev/ttyS99", "generic", Some("modbus-rtu"), 1, &["status", "--max-in-flight", "2"]),
        drivebus(&port, "generic", None, 1, &["status", "--max-in-flight", "2"]),
    ];
    for o in not_modbus_tcp {
        assert_eq!(o.code, 3, "{}", o.stderr);
        assert!(
            o.stderr.contains("--max-in-flight: only a modbus-tcp bus can have requests in flight together"),
            "{}",
            o.stderr
        );
        assert_eq!(o.stderr.trim().lines().count(), 1, "{}", o.stderr);
    }
}

/// A one-connection proxy to the Modbus TCP server `upstream` that holds what the client sends
/// until two whole MBAP requests are waiting, passes them on together, then everything as it
/// comes; its port as `--port` takes it.
fn two_at_once_proxy(upstream: &str) -> String {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let at = format!("tcp://{}", listener.local_addr().unwrap());
    let upstream = upstream.to_string();
    std::thread::spawn(move || {
        let Ok((mut client, _)) = listener.accept() else { return };
        let mut server = std::net::TcpStream::connect(&upstream).unwrap();
        let (mut answers, mut to_client) = (server.try_clone().unwrap(), client.try_clone().unwrap());
        std::thread::spawn(move || std::io::copy(&mut answers, &mut to_client));
        let (mut held, mut passing) = (Vec::new(), false);
        let mut buf = [0u8; 512];
        while let Ok(n @ 1..) = client.read(&mut buf) {
            if passing {
                let _ = server.write_all(&buf[..n]);
                continue;
            }
            held.extend_from_slice(&buf[..n]);
            let (mut at, mut whole) = (0, 0);
            while held.len() >= at + 6 {
                let end = at + 6 + usize::from(u16::from_be_bytes([held[at + 4], held[at + 5]]));
                if held.len() < end {
                    break;
                }
                (at, whole) = (end, whole + 1);
            }
            if whole >= 2 {
                passing = true;
                let _ = server.write_all(&held);
            }
        }
    });
    at
}

#[test]
fn the_simulator_refuses_a_drive_without_modbus_behind_modbus_tcp() {
    let out = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["simulate", "--drive", "b800@1", "--modbus-tcp", "127.0.0.1:0"])
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("a b800 drive does not speak Modbus"), "{err}");
}

#[test]
#[ignore = "needs mbpoll (.ci/install-witnesses.sh)"]
fn mbpoll_reads_a_drive_from_simulate_modbus_tcp() {
    let present = witness::runs("mbpoll", &["-V"], false);
    if !witness::witness("mbpoll", present, "apt-get install mbpoll") {
        return;
    }
    let sim = simulate("generic@3", &["--modbus-tcp", "127.0.0.1:0"]);
    let port = port_of(&sim);
    ok(&drivebus(&port, "generic", Some("modbus-tcp"), 3, &["speed", "25"]), "speed");
    ok(&drivebus(&port, "generic", Some("modbus-tcp"), 3, &["run"]), "run");
    wait_status(&port, "generic", Some("modbus-tcp"), 3, "ramping to 25 Hz", |s| {
        s["output_hz"].as_f64().is_some_and(|hz| (hz - 25.0).abs() < 0.01)
    });
    let (host, tcp_port) = port.trim_start_matches("tcp://").rsplit_once(':').expect("host:port");
    // 2100H..2103H (0-based references 8448..8451): 2103H is the output frequency in 0.01 Hz.
    let out = Command::new("mbpoll")
        .args(["-m", "tcp", "-p", tcp_port, "-a", "3", "-t", "4", "-0", "-1", "-r", "8448", "-c", "4", host])
        .output()
        .expect("run mbpoll");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{text}");
    let value = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("[8451]:"))
        .map(|v| v.trim().to_string())
        .unwrap_or_else(|| panic!("no 2103H in {text}"));
    assert_eq!(value, "2500", "25.00 Hz as mbpoll read it: {text}");
}

#[test]
#[ignore = "needs pymodbus (.ci/install-witnesses.sh)"]
fn serve_reads_and_commands_a_pymodbus_drive_through_a_templated_modbus_tcp_bus() {
    #[path = "support/http.rs"]
    mod http;
    if !witness::witness("pymodbus", witness::python_has("pymodbus"), "pip install pymodbus") {
        return;
    }
    let interop = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/interop");
    let port = http::free_port();
    let mut server = Command::new("python3");
    server.arg(interop.join("pymodbus_tcp_drive.py")).arg(port.to_string());
    let _server = Proc::start(server, "listening on");

    let dir = std::env::temp_dir().join(format!("drivebus-pymodbus-tcp-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let token = "pymodbus-write-token-0123456789";
    let config = format!(
        "templates = [\"{}\"]\n[store]\ndisabled = true\n[http]\nanonymous_read = true\n\
         [[token]]\nname = \"t\"\ntoken = \"{token}\"\nrole = \"write\"\n\
         [[bus]]\nname = \"eth\"\nport = \"tcp://127.0.0.1:{port}\"\nprotocol = \"modbus-tcp\"\n\
         [[bus.drive]]\nname = \"py\"\nfamily = \"pymodbus-drive\"\naddress = 7\npoll_ms = 100\n",
        interop.join("pymodbus-drive.toml").display()
    );
    std::fs::write(dir.join("plant.toml"), config).unwrap();
    let http_at: std::net::SocketAddr = format!("127.0.0.1:{}", http::free_port()).parse().unwrap();
    let mut serve = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    serve
        .args(["serve", "--no-opcua", "--http", &http_at.to_string(), "--modbus", "127.0.0.1:0", "--config"])
        .arg(dir.join("plant.toml"));
    // Ready once every listener is bound (it says so); killed on drop, also when a check fails.
    let _serve = Proc::start(serve, "  HTTP API");
    let drive = || {
        let (status, text) = http::request(http_at, "GET", "/api/drives", None, None);
        assert_eq!(status, 200, "{text}");
        let all: serde_json::Value = serde_json::from_str(&text).unwrap();
        all.as_array()
            .and_then(|a| a.iter().find(|d| d["id"] == "py").cloned())
            .unwrap_or_else(|| panic!("{text}"))
    };
    let wait = |what: &str, done: &dyn Fn(&serde_json::Value) -> bool| {
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
        loop {
            let d = drive();
            if done(&d) {
                return d;
            }
            assert!(std::time::Instant::now() < deadline, "{what}: {d}");
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
    };
    let d = wait("online", &|d| d["online"] == true);
    assert_eq!(
        (d["family"].as_str(), d["protocol"].as_str()),
        (Some("pymodbus-drive"), Some("modbus-tcp")),
        "{d}"
    );
    assert_eq!(d["running"], false, "{d}");
    let post = |path: &str, body: Option<&str>| {
        let (status, text) = http::request(http_at, "POST", path, Some(token), body);
        assert!(status == 200 || status == 204, "{path}: {status} {text}");
    };
    post("/api/drives/py/speed", Some("{\"hz\": 25.5}"));
    post("/api/drives/py/run", None);
    let d = wait("running at 25.5 Hz", &|d| d["running"] == true && d["output_hz"] == 25.5);
    assert_eq!(d["current_a"], 4.2, "{d}");
    let (status, text) = http::request(http_at, "GET", "/api/drives/py/params/acc", None, None);
    assert_eq!(status, 200, "{text}");
    assert!(text.contains("10.0"), "{text}");
    post("/api/drives/py/stop", None);
    wait("stopped", &|d| d["running"] == false && d["output_hz"] == 0.0);
    let _ = std::fs::remove_dir_all(&dir);
}
