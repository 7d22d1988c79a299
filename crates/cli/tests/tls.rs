//! TLS as `drivebus` runs it: `config check` on the broker TLS keys, and `serve` refusing a
//! broker whose certificate fails the check with a log line that says why (Mosquitto).

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::mpsc;

#[path = "support/lines.rs"]
mod lines;
#[path = "../../gateway/tests/mqtt_support/mod.rs"]
mod mqtt_support;
#[path = "../../gateway/tests/tls_support/mod.rs"]
mod tls_support;
#[path = "../../../tests/interop/witness.rs"]
mod witness;

use lines::Killed;
use mqtt_support::{free_port, mosquitto_binary, wait_listening, Mosquitto, PATIENCE};
use tls_support::TestPki;

const BUS: &str = "[[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
                   [[bus.drive]]\nname = \"d1\"\nfamily = \"generic\"\naddress = 1\n";

fn config_check(file: &Path) -> (Option<i32>, String) {
    let out =
        Command::new(env!("CARGO_BIN_EXE_drivebus")).args(["config", "check"]).arg(file).output().unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn config_check_names_a_broker_tls_file_it_cannot_use_in_one_line() {
    let pki = TestPki::new("cli-check", &["broker.plant"]);
    let file = pki.dir.join("plant.toml");
    for (keys, says) in [
        (
            "ca_file = \"/nonexistent/ca.pem\"\n".to_string(),
            "plant.toml:3: field `mqtt.ca_file`: ca_file /nonexistent/ca.pem: cannot read it",
        ),
        (
            format!("client_key = \"{}\"\n", TestPki::toml(&pki.client_key)),
            "plant.toml:3: field `mqtt.client_key`: client_key needs client_cert",
        ),
    ] {
        std::fs::write(&file, format!("[mqtt]\nurl = \"mqtts://broker.plant\"\n{keys}{BUS}")).unwrap();
        let (code, err) = config_check(&file);
        assert_eq!(code, Some(3), "{err}");
        assert!(err.contains(says), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
    }
    std::fs::write(&file, format!("[sparkplug]\nurls = [\"mqtt://10.0.0.9\"]\ncommands = true\n{BUS}"))
        .unwrap();
    let (code, err) = config_check(&file);
    assert_eq!(code, Some(3), "{err}");
    assert!(
        err.contains("field `sparkplug.urls`: motor commands would cross the network to 10.0.0.9 in clear: use mqtts://10.0.0.9, or set [sparkplug] allow_plaintext = true"),
        "{err}"
    );
    let ok = format!(
        "[mqtt]\nurl = \"mqtts://broker.plant\"\nca_file = \"{}\"\nclient_cert = \"{}\"\nclient_key = \"{}\"\n{BUS}",
        TestPki::toml(&pki.ca),
        TestPki::toml(&pki.client_cert),
        TestPki::toml(&pki.client_key)
    );
    std::fs::write(&file, ok).unwrap();
    let (code, err) = config_check(&file);
    assert_eq!(code, Some(0), "{err}");
}

/// `serve` with a broker whose certificate another CA signed: it keeps running and its log
/// says the certificate is not trusted and what to do.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto (.ci/install-witnesses.sh)"]
async fn serve_says_why_a_broker_certificate_is_refused() {
    let bin = mosquitto_binary();
    if !witness::witness("mosquitto", bin.is_some(), "apt-get install mosquitto") {
        return;
    }
    let pki = TestPki::new("cli-serve", &["localhost"]);
    let tls_port = free_port();
    let extra = format!(
        "allow_anonymous true\nlistener {tls_port} 127.0.0.1\ncertfile {}\nkeyfile {}\n",
        pki.server_cert.display(),
        pki.server_key.display()
    );
    let _broker = Mosquitto::start_with(&bin.unwrap(), free_port(), &extra).await;
    wait_listening(format!("127.0.0.1:{tls_port}").parse().unwrap()).await;
    let file = pki.dir.join("plant.toml");
    std::fs::write(
        &file,
        format!(
            "[mqtt]\nurl = \"mqtts://localhost:{tls_port}\"\nca_file = \"{}\"\n{BUS}",
            TestPki::toml(&pki.other_ca)
        ),
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["serve", "--no-opcua", "--no-store", "--config"])
        .arg(&file)
        .args(["--http", &format!("127.0.0.1:{}", free_port())])
        .args(["--modbus", &format!("127.0.0.1:{}", free_port())])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start drivebus serve");
    let stderr = child.stderr.take().unwrap();
    let _child = Killed(child);
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let mut seen = Vec::new();
    let line = loop {
        match rx.recv_timeout(PATIENCE) {
            Ok(l) if l.contains("MQTT: broker") => break l,
            Ok(l) => seen.push(l),
            Err(_) => panic!("no line about the broker; stderr: {seen:#?}"),
        }
    };
    assert!(line.contains(&format!("MQTT: broker localhost:{tls_port}:")), "{line}");
    assert!(
        line.contains("the broker's certificate is not signed by a CA trusted here: give the CA that signed it in ca_file"),
        "{line}"
    );
}

const WRITE_TOKEN: &str = "[[token]]\nname = \"scada\"\ntoken = \"0123456789abcdef-w\"\nrole = \"write\"\n";

/// `--http` on the command line opens the listener to the network: with a write token and no
/// TLS, `serve` refuses to start and says what to do.
#[test]
fn serve_refuses_write_tokens_over_plain_http_off_loopback() {
    let pki = TestPki::new("cli-plain", &["localhost"]);
    let file = pki.dir.join("plant.toml");
    std::fs::write(&file, format!("{WRITE_TOKEN}{BUS}")).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["serve", "--no-opcua", "--no-store", "--config"])
        .arg(&file)
        .args(["--http", &format!("0.0.0.0:{}", free_port())])
        .args(["--modbus", &format!("127.0.0.1:{}", free_port())])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("write tokens would cross the network in clear on http://0.0.0.0:"), "{err}");
    assert!(err.contains("give [http] tls_cert and tls_key (HTTPS)"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
}

/// With `tls_cert` and `tls_key`, `serve` listens with HTTPS (and says so), a write token on
/// every address allowed.
#[test]
fn serve_with_a_certificate_serves_https() {
    let pki = TestPki::new("cli-https", &["localhost"]);
    let file = pki.dir.join("plant.toml");
    let port = free_port();
    std::fs::write(
        &file,
        format!(
            "[http]\nlisten = \"0.0.0.0:{port}\"\ntls_cert = \"{}\"\ntls_key = \"{}\"\n{WRITE_TOKEN}{BUS}",
            TestPki::toml(&pki.server_cert),
            TestPki::toml(&pki.server_key)
        ),
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["serve", "--no-opcua", "--no-store", "--config"])
        .arg(&file)
        .args(["--modbus", &format!("127.0.0.1:{}", free_port())])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let found = lines::wait_for_lines(&mut child, "drivebus serve", &["dashboard", "HTTP API"]);
    let _child = Killed(child);
    assert_eq!(found[0], format!("https://0.0.0.0:{port}/"));
    assert_eq!(found[1], format!("https://0.0.0.0:{port}/api/drives"));
}
