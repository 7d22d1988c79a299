//! MQTT and Sparkplug B over TLS (`mqtts://`) against Mosquitto (Debian's `mosquitto`), with a
//! CA, a server certificate and a client certificate made at test time: the gateway verifies
//! the broker and shows its own certificate; a broker signed by another CA, or whose
//! certificate is for another name, is refused with an error that says so.

mod mqtt_support;
mod tls_support;
#[path = "../../../tests/interop/witness.rs"]
mod witness;

use std::net::SocketAddr;
use std::path::PathBuf;

use drivebus_gateway::config::mqtt::parse_url;
use drivebus_gateway::config::tls::{broker_transport, explain};
use drivebus_gateway::config::{BrokerTls, MqttConfig, SparkplugConfig};
use drivebus_gateway::{Gateway, GatewayConfig};
use mqtt_support::*;
use tls_support::TestPki;
use witness::witness;

/// The broker's program, or None (said on stderr, a failure where witnesses are required).
fn mosquitto() -> Option<PathBuf> {
    let bin = mosquitto_binary();
    witness("mosquitto", bin.is_some(), "apt-get install mosquitto");
    bin
}

/// Mosquitto with a plain loopback listener (for the test's own clients) and a TLS one that
/// asks for a client certificate signed by the test CA; `(plain, tls port)`.
async fn tls_broker(bin: &std::path::Path, pki: &TestPki) -> (Mosquitto, u16) {
    let tls_port = free_port();
    let extra = format!(
        "allow_anonymous true\nlistener {tls_port} 127.0.0.1\ncafile {}\ncertfile {}\nkeyfile {}\n\
         require_certificate true\n",
        pki.ca.display(),
        pki.server_cert.display(),
        pki.server_key.display()
    );
    let broker = Mosquitto::start_with(bin, free_port(), &extra).await;
    wait_listening(format!("127.0.0.1:{tls_port}").parse::<SocketAddr>().unwrap()).await;
    (broker, tls_port)
}

fn client_tls(pki: &TestPki, ca: &std::path::Path) -> BrokerTls {
    BrokerTls {
        ca_file: Some(ca.to_path_buf()),
        client_cert: Some(pki.client_cert.clone()),
        client_key: Some(pki.client_key.clone()),
        allow_plaintext: false,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto (.ci/install-witnesses.sh)"]
async fn mqtt_and_sparkplug_over_tls_verify_the_broker_and_show_a_client_certificate() {
    let Some(bin) = mosquitto() else { return };
    let pki = TestPki::new("mqtts", &["localhost"]);
    let (broker, tls_port) = tls_broker(&bin, &pki).await;
    let mut config = GatewayConfig::demo();
    config.name = "hall-tls".into();
    config.store = None;
    let gw = Gateway::start(config, None).unwrap();
    let mqtt = MqttConfig {
        url: format!("mqtts://localhost:{tls_port}"),
        topic_prefix: None,
        discovery: false,
        allow_commands: vec!["*/*/*".into()],
        client_id: None,
        credentials: None,
        tls: client_tls(&pki, &pki.ca),
    };
    drivebus_gateway::mqtt::spawn(gw.clone(), &mqtt).unwrap();
    let mut sp = SparkplugConfig::new(&format!("mqtts://localhost:{tls_port}"));
    sp.tls = client_tls(&pki, &pki.ca);
    sp.commands = true;
    drivebus_gateway::sparkplug::spawn(gw.clone(), &sp).unwrap();

    // What the gateway published over TLS, seen on the plain listener.
    let p = "drivebus/hall-tls";
    let live = Subscriber::start(broker.addr, "live", "#").await;
    let status = format!("{p}/status");
    live.wait("the gateway online", |log| {
        log.iter().any(|m| m.topic == status && m.text == "online").then_some(())
    })
    .await;
    live.wait("the Sparkplug NBIRTH", |log| {
        log.iter().any(|m| m.topic == "spBv1.0/drivebus/NBIRTH/hall-tls").then_some(())
    })
    .await;
    // A command comes back to it over TLS and is carried out.
    live.publish(&format!("{p}/line-toshiba/pump-1/set/speed"), "30", false).await;
    live.wait_json(&format!("{p}/line-toshiba/pump-1/result"), |r| {
        r["command"] == "speed" && r["ok"] == true
    })
    .await;
}

/// Connects a client with the gateway's own transport for `url` and `tls`; the connection's
/// error as the gateway would log it.
async fn refusal(url: &str, tls: &BrokerTls) -> String {
    let b = parse_url(url).unwrap();
    let transport = broker_transport("mqtt", &b, tls, false, false).unwrap();
    let mut opts = rumqttc::MqttOptions::new("probe", b.host.clone(), b.port);
    opts.set_transport(transport);
    let (_client, mut eventloop) = rumqttc::AsyncClient::new(opts, 10);
    let e = tokio::time::timeout(PATIENCE, async {
        loop {
            match eventloop.poll().await {
                Ok(rumqttc::Event::Incoming(rumqttc::Packet::ConnAck(_))) => panic!("{url}: connected"),
                Ok(_) => {}
                Err(e) => return e,
            }
        }
    })
    .await
    .expect("an answer from the broker");
    explain(&b.host, &e.to_string())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto (.ci/install-witnesses.sh)"]
async fn a_broker_of_another_ca_or_another_name_is_refused_with_a_clear_error() {
    let Some(bin) = mosquitto() else { return };
    let pki = TestPki::new("mqtts-refused", &["localhost"]);
    let (_broker, tls_port) = tls_broker(&bin, &pki).await;

    let e = refusal(&format!("mqtts://localhost:{tls_port}"), &client_tls(&pki, &pki.other_ca)).await;
    assert!(e.contains("not signed by a CA trusted here: give the CA that signed it in ca_file"), "{e}");
    // The certificate is for localhost, not for the address.
    let e = refusal(&format!("mqtts://127.0.0.1:{tls_port}"), &client_tls(&pki, &pki.ca)).await;
    assert!(e.contains("the broker's certificate is not made for \"127.0.0.1\""), "{e}");
    // Without the system's roots knowing the test CA, the default trust refuses it too.
    let none = BrokerTls { ca_file: None, ..client_tls(&pki, &pki.ca) };
    let e = refusal(&format!("mqtts://localhost:{tls_port}"), &none).await;
    assert!(e.contains("not signed by a CA trusted here"), "{e}");
}
