//! Two `drivebus serve` processes on one MQTT broker (an in-process rumqttd): each publishes
//! under its own `--name`, one subscriber sees both side by side, and neither knocks the
//! other off the broker (their client ids differ).

use std::net::SocketAddr;
use std::process::{Command, Stdio};

#[path = "support/lines.rs"]
mod lines;
#[path = "../../gateway/tests/mqtt_support/mod.rs"]
mod mqtt_support;

use lines::Killed;

use mqtt_support::{free_port, rumqttd_both, wait_all_statuses, wait_every_status, Subscriber};

fn serve(name: &str, broker: SocketAddr) -> Killed {
    let child = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["serve", "--demo", "--no-opcua", "--no-store", "--name", name])
        .args(["--http", &format!("127.0.0.1:{}", free_port())])
        .args(["--modbus", &format!("127.0.0.1:{}", free_port())])
        .args(["--mqtt", &format!("mqtt://{broker}")])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start drivebus serve");
    Killed(child)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_gateway_processes_side_by_side_on_one_broker() {
    let (broker, broker5) = rumqttd_both().await;
    let live = Subscriber::start(broker, "live", "drivebus/#").await;
    let _a = serve("hall-a", broker5);
    let _b = serve("hall-b", broker5);

    // Every demo drive of both gateways, as it is published...
    for g in ["hall-a", "hall-b"] {
        wait_every_status(&live, &format!("drivebus/{g}"), "a status of all 20 drives").await;
    }
    // ... and as the broker keeps it for a subscriber that comes later: retained, online.
    let later = Subscriber::start(broker, "later", "drivebus/#").await;
    wait_all_statuses(&later, "drivebus/hall-a").await;
    wait_all_statuses(&later, "drivebus/hall-b").await;
    let log = live.log.lock().unwrap().clone();
    for g in ["hall-a", "hall-b"] {
        let topic = format!("drivebus/{g}/status");
        let seen: Vec<&str> = log.iter().filter(|m| m.topic == topic).map(|m| m.text.as_str()).collect();
        assert!(seen.contains(&"online"), "{g} online: {seen:?}");
        // A second client with the same id would have cut this one off: its will says offline.
        assert!(!seen.contains(&"offline"), "{g} was never knocked off: {seen:?}");
    }
}

#[test]
fn a_name_that_cannot_be_a_topic_level_is_refused() {
    let out = Command::new(env!("CARGO_BIN_EXE_drivebus"))
        .args(["serve", "--demo", "--no-opcua", "--no-store", "--name", "hall/1"])
        .output()
        .expect("run drivebus serve");
    assert_eq!(out.status.code(), Some(3));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--name \"hall/1\"") && err.lines().count() == 1, "{err}");
}
