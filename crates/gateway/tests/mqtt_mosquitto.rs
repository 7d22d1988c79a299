//! MQTT against Mosquitto (Debian's `mosquitto`), started by the test on a free loopback port
//! with a minimal configuration: retained statuses, a command by topic, a refused one, and a
//! real broker restart (kill, start again empty) after which the gateway republishes.
//!
//! A plain `cargo test` lists these tests as ignored (`cargo test -- --ignored` runs them).
//! `.ci/install-witnesses.sh` installs Mosquitto and `.ci/run` sets `DRIVEBUS_REQUIRE_INTEROP=1`,
//! so in CI a missing broker is a failure.

mod mqtt_support;
mod support;
#[path = "../../../tests/interop/witness.rs"]
mod witness;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::Command;

use mqtt_support::*;
use support::wait_for;
use witness::witness;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto (.ci/install-witnesses.sh)"]
async fn mosquitto_statuses_commands_and_restart() {
    let Some(bin) = mosquitto() else {
        return;
    };
    let port = free_port();
    let mut broker = Mosquitto::start(&bin, port).await;
    let gw = demo_gateway("hall-m", broker.addr, &["line-toshiba/pump-1/*"], false);
    let p = "drivebus/hall-m";

    let live = Subscriber::start(broker.addr, "live", &format!("{p}/#")).await;
    live.wait_json(&format!("{p}/line-b800/mixer-2/status"), |v| v["online"] == true).await;
    wait_all_statuses(&Subscriber::start(broker.addr, "late", &format!("{p}/#")).await, p).await;

    live.publish(&format!("{p}/line-toshiba/pump-1/set/speed"), "30", false).await;
    live.wait_json(&format!("{p}/line-toshiba/pump-1/result"), |r| {
        r["command"] == "speed" && r["ok"] == true
    })
    .await;
    live.publish(&format!("{p}/line-toshiba/pump-1/set/run"), "1", false).await;
    live.wait_json(&format!("{p}/line-toshiba/pump-1/status"), |v| v["running"] == true).await;
    live.publish(&format!("{p}/line-toshiba/pump-2/set/run"), "1", false).await;
    let r = live.wait_json(&format!("{p}/line-toshiba/pump-2/result"), |r| r["command"] == "run").await;
    assert_eq!(r["error"]["kind"], "forbidden", "{r}");
    assert_eq!(gw.drive_view(&gw.drive("pump-2").unwrap()).running, Some(false));

    // A real restart: the broker goes away and comes back empty on the same port.
    broker.stop();
    let broker = Mosquitto::start(&bin, port).await;
    let again = Subscriber::start(broker.addr, "again", &format!("{p}/#")).await;
    wait_every_status(&again, p, "every drive's status after the restart").await;
    wait_all_statuses(&Subscriber::start(broker.addr, "after", &format!("{p}/#")).await, p).await;
    let pump = again.wait_json(&format!("{p}/line-toshiba/pump-1/status"), |v| v["running"] == true).await;
    assert_eq!(pump["setpoint_hz"], 30.0);
}

/// A broker that asks for a user name and password: the gateway logs in with the configured
/// credentials; with a wrong password it is refused and connects never.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto (.ci/install-witnesses.sh)"]
async fn mosquitto_with_a_password() {
    let (Some(bin), Some(passwd)) = (mosquitto_binary(), which("mosquitto_passwd")) else {
        witness("mosquitto and mosquitto_passwd", false, "apt-get install mosquitto");
        return;
    };
    let port = free_port();
    let dir = std::env::temp_dir().join(format!("drivebus-mosquitto-auth-{}-{port}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("passwords");
    let made = Command::new(&passwd)
        .args(["-b", "-c"])
        .arg(&file)
        .args(["plant", "s3cret-Passw0rd"])
        .status()
        .expect("run mosquitto_passwd");
    assert!(made.success());
    // The broker's log, where it says whom it refused (writable for the user it runs as).
    let log = dir.join("broker.log");
    std::fs::write(&log, "").unwrap();
    std::fs::set_permissions(&log, std::os::unix::fs::PermissionsExt::from_mode(0o666)).unwrap();
    let _broker = Mosquitto::start_with(
        &bin,
        port,
        &format!(
            "allow_anonymous false\npassword_file {}\nlog_dest file {}\nlog_type all\n",
            file.display(),
            log.display()
        ),
    )
    .await;
    let addr: SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
    let good = demo_gateway_with("hall-auth", addr, &[], false, Some(("plant", "s3cret-Passw0rd")));
    let bad = demo_gateway_with("hall-bad", addr, &[], false, Some(("plant", "wrong")));
    wait_for("the gateway to log in", PATIENCE, || {
        drivebus_gateway::metrics::front_ends(&good).mqtt_connections() > 0
    })
    .await;
    // Once the broker has refused the wrong password (it logs the client as <unknown>, having
    // refused it before it had a name), it is still not connected.
    let refusals = || {
        std::fs::read_to_string(&log)
            .unwrap_or_default()
            .lines()
            .filter(|l| l.contains("disconnected, not authorised"))
            .count()
    };
    wait_for("the broker to refuse the wrong password", PATIENCE, || refusals() >= 1).await;
    assert_eq!(
        drivebus_gateway::metrics::front_ends(&bad).mqtt_connections(),
        0,
        "a wrong password was accepted"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The broker's program, or None (said on stderr, a failure in CI) when it is not installed.
fn mosquitto() -> Option<PathBuf> {
    let bin = mosquitto_binary();
    witness("mosquitto", bin.is_some(), "apt-get install mosquitto");
    bin
}

fn which(name: &str) -> Option<PathBuf> {
    let mut dirs: Vec<PathBuf> =
        std::env::var_os("PATH").map(|p| std::env::split_paths(&p).collect()).unwrap_or_default();
    dirs.extend(["/usr/bin", "/usr/sbin"].map(PathBuf::from));
    dirs.into_iter().map(|d| d.join(name)).find(|p| p.is_file())
}

/// Oversize and retained command messages (issue 13, defects 3 and 7): a retained 100 KiB
/// `set/stop` waiting on the broker, a retained `set/run` published while the gateway is
/// connected, and a retained 2 MiB one. None is carried out, the first two get a result and an
/// audit record, the third is dropped by the broker (above the gateway's Maximum Packet Size),
/// and the gateway never loses its connection: one connection from start to end.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mosquitto (.ci/install-witnesses.sh)"]
async fn oversize_and_retained_commands_are_refused_without_a_reconnection() {
    let Some(bin) = mosquitto() else {
        return;
    };
    let broker = Mosquitto::start(&bin, free_port()).await;
    let p = "drivebus/hall-o";
    let big = Subscriber::start_with_max(broker.addr, "big", &format!("{p}/+/+/result"), 4 << 20).await;
    big.publish(&format!("{p}/line-toshiba/pump-1/set/stop"), &"x".repeat(100 * 1024), true).await;
    let gw = demo_gateway("hall-o", broker.addr, &["line-toshiba/pump-1/*"], false);
    let events = collect_events(&gw);
    let result = format!("{p}/line-toshiba/pump-1/result");
    let r = big.wait_json(&result, |r| r["command"] == "stop").await;
    assert_eq!(r["ok"], false, "{r}");
    assert_eq!(r["error"]["kind"], "too_large", "{r}");

    // Published retained while the gateway is subscribed: its first delivery is refused too.
    big.publish(&format!("{p}/line-toshiba/pump-1/set/run"), "1", true).await;
    let r = big.wait_json(&result, |r| r["command"] == "run").await;
    assert_eq!(r["error"]["kind"], "retained", "{r}");
    big.publish(&format!("{p}/line-toshiba/pump-1/set/speed"), &"9".repeat(2 << 20), true).await;

    // The connection carries on: a good command after them is carried out.
    big.publish(&format!("{p}/line-toshiba/pump-1/set/speed"), "31", false).await;
    let r = big.wait_json(&result, |r| r["command"] == "speed").await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(gw.drive_view(&gw.drive("pump-1").unwrap()).running, Some(false));
    let audited = |needle: &str| {
        let needle = needle.to_string();
        let events = events.clone();
        async move {
            let deadline = std::time::Instant::now() + PATIENCE;
            loop {
                let found = events.lock().unwrap().iter().any(|e: &drivebus_store::Event| {
                    e.actor.as_deref() == Some("mqtt:drivebus-hall-o")
                        && e.result.as_deref().is_some_and(|r| r.starts_with(&needle))
                });
                if found {
                    return;
                }
                assert!(std::time::Instant::now() < deadline, "no audit record {needle:?}");
                tokio::time::sleep(std::time::Duration::from_millis(50)).await;
            }
        }
    };
    audited("too_large: ").await;
    audited("retained: ").await;
    assert_eq!(drivebus_gateway::metrics::front_ends(&gw).mqtt_connections(), 1, "the gateway reconnected");
}
