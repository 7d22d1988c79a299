//! OPC UA with a client nobody here wrote: Python asyncua (PyPI) against `drivebus serve` on the
//! demo's buses plus a drive on a `drivebus simulate` process (tripped during the test) and one
//! on a serial port that does not exist. tests/interop/opcua_client.py does the client's side:
//! browse, reads with status and source timestamps, a subscription while a drive ramps after
//! SetSpeed and Run as user demo, refusals (anonymous call, wrong password, wrong type, read-only,
//! out of range), a trip event, and a Basic256Sha256 SignAndEncrypt session. This side checks the
//! audit trail's OPC UA actor.
//!
//! A plain `cargo test` lists the test as ignored (`cargo test -- --ignored` runs it).
//! `.ci/install-witnesses.sh` installs asyncua and CI sets `DRIVEBUS_REQUIRE_INTEROP=1`, so there
//! a missing witness is a failure.

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "support/http.rs"]
mod http;
#[path = "support/opcua_plant.rs"]
mod plant;
#[path = "support/values_template.rs"]
mod values_template;
#[path = "../../../tests/interop/witness.rs"]
mod witness;
use plant::{Plant, Serve};
use witness::witness;

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/interop/opcua_client.py")
}

/// Runs the asyncua client with `args`; asserts it said ALL OK.
fn client(args: &[&str]) {
    let out = Command::new("python3").arg(script()).args(args).output().unwrap();
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && said.contains("ALL OK"),
        "the asyncua client ({}): {said}\n{}",
        args[0],
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("{said}");
}

/// Makes the asyncua client's certificate and key in `dir` (`client.der` is the certificate).
fn mkcert(dir: &Path) {
    let out = Command::new("python3").arg(script()).arg("mkcert").arg(dir).output().unwrap();
    assert!(out.status.success(), "mkcert: {}", String::from_utf8_lossy(&out.stderr));
}

#[test]
#[ignore = "needs asyncua (.ci/install-witnesses.sh)"]
fn asyncua_browses_reads_subscribes_commands_and_is_refused_where_it_should_be() {
    if !witness("Python asyncua", witness::python_has("asyncua"), "pip install asyncua") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("drivebus-opcua-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();

    // The client's certificate, trusted by the gateway's configuration.
    mkcert(&dir.join("client"));

    let plant = Plant::start_with(&dir, &dir.join("client/client.der"), "insecure_writes = true\n");
    let (url, http, token) = (&plant.url, plant.http, plant::TOKEN);
    let certs = dir.join("client").display().to_string();
    client(&["check", url, token, plant::DRIVES, plant::OFFLINE, plant::SIMULATED, &plant.control, &certs]);

    // pump-1 has been running for a while: its history is the HTTP trend's.
    client(&["history", url, &format!("http://{http}"), "pump-1"]);

    // Every command is in the audit trail with its OPC UA actor.
    let (status, body) =
        http::request(http, "GET", "/api/events?kind=command&drive=pump-1", Some(token), None);
    assert_eq!(status, 200, "{body}");
    let events: serde_json::Value = serde_json::from_str(&body).unwrap();
    let actors: Vec<&str> = events.as_array().unwrap().iter().filter_map(|e| e["actor"].as_str()).collect();
    assert!(
        actors.iter().any(|a| a.starts_with("opcua:demo@")),
        "no command by opcua:demo@... in {actors:?}"
    );
    assert!(
        actors.iter().any(|a| a.starts_with("opcua:anonymous@")),
        "the refused anonymous call: {actors:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// What a plant's integrator checks before trusting the server, with asyncua: the endpoints
/// advertise the machine's name (the gateway listens on every address) and encrypt passwords on
/// every endpoint (None included: asyncua sends none in clear); writes and calls are refused
/// over None and taken over Sign and SignAndEncrypt; anonymous and read-role writes are refused
/// before their value's type is looked at; a user's sessions are capped. Every refusal is in the
/// audit trail.
#[test]
#[ignore = "needs asyncua (.ci/install-witnesses.sh)"]
fn asyncua_finds_passwords_encrypted_writes_signed_and_sessions_capped() {
    if !witness("Python asyncua", witness::python_has("asyncua"), "pip install asyncua") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    mkcert(&dir.path().join("client"));
    let (write, read) = ("opcua-trust-write-0123456789", "opcua-trust-read-0123456789");
    let config = format!(
        "[http]\nanonymous_read = true\n[store]\npath = \"{}\"\n\
         [[token]]\nname = \"ops-w\"\ntoken = \"{write}\"\nrole = \"write\"\n\
         [[token]]\nname = \"ops-r\"\ntoken = \"{read}\"\nrole = \"read\"\n\
         [opcua]\ntrusted_clients = [\"{}\"]\nmax_sessions_per_user = 3\n\
         [[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
         [[bus.drive]]\nname = \"pump-1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 200\n",
        dir.path().join("store.db").display(),
        dir.path().join("client/client.der").display(),
    );
    let file = dir.path().join("plant.toml");
    std::fs::write(&file, config).unwrap();
    let serve = Serve::start(&file, "0.0.0.0:0", &[]);
    let (http, url) = (serve.http, &serve.url);
    // Listening on every address, it advertises the machine's name, never 0.0.0.0.
    let (host, port) = url.trim_start_matches("opc.tcp://").rsplit_once(':').unwrap();
    let machine = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap();
    assert_eq!(host, machine.trim(), "{url}");

    let client_dir = dir.path().join("client").display().to_string();
    client(&["trust", &format!("opc.tcp://127.0.0.1:{port}"), write, read, &client_dir, "3", host]);

    // Each kind of refusal is in the audit trail, with who and why.
    let (status, body) = http::request(http, "GET", "/api/events?kind=command", None, None);
    assert_eq!(status, 200, "{body}");
    let events: serde_json::Value = serde_json::from_str(&body).unwrap();
    let seen: Vec<(String, String)> = events
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (e["actor"].as_str().unwrap_or("").to_string(), e["result"].as_str().unwrap_or("").to_string())
        })
        .collect();
    for (actor, result) in [
        ("opcua:ops-w@", "insecure: writes and method calls need a Sign or SignAndEncrypt session"),
        ("opcua:anonymous@", "forbidden: log in with a write token"),
        ("opcua:ops-r@", "forbidden: this user's token has role read"),
        ("opcua:ops-r", "too_many_sessions: user ops-r holds 3 sessions"),
    ] {
        assert!(
            seen.iter().any(|(a, r)| a.starts_with(actor) && r.starts_with(result)),
            "no refusal of {actor} with {result:?} in {seen:?}"
        );
    }
}

/// A hall of 1000 drives (32 virtual buses): every drive is listed, and a drive's parameter
/// nodes, made only when asked for, browse and read from the drive.
#[test]
#[ignore = "needs asyncua (.ci/install-witnesses.sh)"]
fn asyncua_browses_and_reads_a_parameter_on_a_1000_drive_plant() {
    if !witness("Python asyncua", witness::python_has("asyncua"), "pip install asyncua") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut config = format!(
        "[http]\nanonymous_read = true\n[opcua]\npki_dir = \"{}\"\n",
        dir.path().join("pki").display()
    );
    let mut n = 0;
    for b in 1..=32 {
        config += &format!(
            "[[bus]]\nname = \"line-{b}\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 115200\n"
        );
        for a in 1..=(if b <= 8 { 32 } else { 31 }) {
            n += 1;
            config += &format!("[[bus.drive]]\nname = \"vfd-{n}\"\nfamily = \"generic\"\naddress = {a}\n");
        }
    }
    assert_eq!(n, 1000);
    let file = dir.path().join("plant.toml");
    std::fs::write(&file, config).unwrap();
    let serve = Serve::start(&file, "127.0.0.1:0", &["--no-store"]);
    client(&["big", &serve.url, "1000"]);
}

/// Method calls pipelined on one session (sent one after another without waiting for the
/// answers) are carried out in the order they were sent: the audit trail lists them so, and the
/// drive ends in the last commanded state. The OPC UA server library runs each request in a task
/// of its own; Write and Call requests of one channel wait for each other (the third `drivebus:`
/// change, vendor/async-opcua-server/DRIVEBUS.md).
#[test]
#[ignore = "needs asyncua (.ci/install-witnesses.sh)"]
fn asyncua_pipelined_calls_to_one_drive_are_carried_out_in_the_order_sent() {
    if !witness("Python asyncua", witness::python_has("asyncua"), "pip install asyncua") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let token = "opcua-order-token-0123456789";
    let config = format!(
        "[http]\nanonymous_read = true\n[store]\npath = \"{}\"\n\
         [[token]]\nname = \"demo\"\ntoken = \"{token}\"\nrole = \"write\"\n\
         [opcua]\ninsecure_writes = true\n\
         [[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 115200\n\
         [[bus.drive]]\nname = \"pump-1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 200\n",
        dir.path().join("store.db").display(),
    );
    let file = dir.path().join("plant.toml");
    std::fs::write(&file, config).unwrap();
    let serve = Serve::start(&file, "127.0.0.1:0", &[]);
    let http = format!("http://{}", serve.http);
    client(&["order", &serve.url, &http, token, "pump-1", "120"]);
}

/// A templated drive (the shipped `generic-2000h` map, with `[values]` added) in OPC UA: browsed,
/// OutputFrequency read, its named values read (with their units) and subscribed to, SetSpeed
/// and Run called, a parameter read by the template's name; then its trend in the store is what
/// OPC UA's history read gives (the `history` check), as for a built-in drive.
#[test]
#[ignore = "needs asyncua (.ci/install-witnesses.sh)"]
fn asyncua_browses_reads_and_commands_a_templated_drive_and_reads_its_history() {
    if !witness("Python asyncua", witness::python_has("asyncua"), "pip install asyncua") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let token = "opcua-template-token-0123456789";
    // The shipped map under a kind of the user's, with two named values.
    values_template::write(dir.path());
    let config = format!(
        "templates = [\"tpl.toml\"]\n[http]\nanonymous_read = true\n[store]\npath = \"{}\"\n\
         [[token]]\nname = \"demo\"\ntoken = \"{token}\"\nrole = \"write\"\n\
         [opcua]\ninsecure_writes = true\n\
         [[bus]]\nname = \"line-t\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 115200\n\
         [[bus.drive]]\nname = \"tpl-1\"\nfamily = \"{}\"\naddress = 1\npoll_ms = 200\n",
        dir.path().join("store.db").display(),
        values_template::KIND,
    );
    let file = dir.path().join("plant.toml");
    std::fs::write(&file, config).unwrap();
    let serve = Serve::start(&file, "127.0.0.1:0", &[]);
    client(&["template", &serve.url, token, "tpl-1"]);
    client(&["history", &serve.url, &format!("http://{}", serve.http), "tpl-1"]);
}

/// Issue 27: a gateway that is a standby on a line (another gateway masters it) serves the
/// drive's values marked as heard (`Source`, the bus's `Role`) and refuses writes and calls with
/// Bad_InvalidState; the refusal is in the audit trail.
#[test]
#[ignore = "needs asyncua (.ci/install-witnesses.sh)"]
fn asyncua_sees_a_standby_marked_and_its_commands_refused_with_bad_invalid_state() {
    if !witness("Python asyncua", witness::python_has("asyncua"), "pip install asyncua") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut sim = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["simulate", "--drive", "generic@1:modbus-rtu", "--baud", "19200", "--serial", "8N1"])
        .args(["--tcp", "127.0.0.1:0"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let at = plant::lines::wait_for_lines(&mut sim, "drivebus simulate", &["listening on tcp"]);
    let _sim = plant::lines::Killed(sim);
    // Nobody else masters the line: a standby listens twice 60 s before it takes it.
    let config = format!(
        "name = \"standby\"\n[http]\nanonymous_read = true\n[[token]]\nname = \"demo\"\ntoken = \"{}\"\nrole = \"write\"\n\
         [opcua]\ninsecure_writes = true\n[store]\npath = \"{}\"\n[standby]\nrole = \"standby\"\nsilence_ms = 60000\n\
         [[bus]]\nname = \"line-a\"\nport = \"tcp://{}\"\nprotocol = \"modbus-rtu\"\nbaud = 19200\nserial = \"8N1\"\n\
         [[bus.drive]]\nname = \"press-1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 200\n",
        plant::TOKEN,
        dir.path().join("store.db").display(),
        at[0]
    );
    let file = dir.path().join("standby.toml");
    std::fs::write(&file, config).unwrap();
    let serve = Serve::start(&file, "127.0.0.1:0", &[]);
    client(&["standby", &serve.url, plant::TOKEN, "press-1", "line-a"]);

    let (status, body) =
        http::request(serve.http, "GET", "/api/events?kind=command&drive=press-1", None, None);
    assert_eq!(status, 200, "{body}");
    let events: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert!(
        events
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["actor"].as_str().is_some_and(|a| a.starts_with("opcua:demo@"))
                && e["result"].as_str().is_some_and(|r| r.starts_with("standby: "))),
        "the refusal audited: {events}"
    );
}

/// The OPC UA server forgets a client's monitored items however its subscription ends
/// (`drivebus_opcua_monitored_items` in /metrics, issue 25): deleted by the client, deleted
/// with its session (CloseSession), or expired after the client vanished without closing
/// anything. The library kept every data item of a deleted subscription, and every item of an
/// expired one, for as long as the server ran (the eighth `drivebus:` change,
/// vendor/async-opcua-server/DRIVEBUS.md).
#[test]
#[ignore = "needs asyncua (.ci/install-witnesses.sh)"]
fn asyncua_monitored_items_are_forgotten_when_subscriptions_end() {
    if !witness("Python asyncua", witness::python_has("asyncua"), "pip install asyncua") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = "[http]\nanonymous_read = true\n\
         [[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 115200\n\
         [[bus.drive]]\nname = \"pump-1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 100\n\
         [[bus.drive]]\nname = \"pump-2\"\nfamily = \"generic\"\naddress = 2\npoll_ms = 100\n";
    let file = dir.path().join("plant.toml");
    std::fs::write(&file, config).unwrap();
    let serve = Serve::start(&file, "127.0.0.1:0", &["--no-store"]);
    client(&["items", &serve.url, &format!("http://{}", serve.http), "pump-1,pump-2"]);
}
