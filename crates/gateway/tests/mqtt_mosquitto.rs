//! MQTT against Mosquitto (Debian's `mosquitto`), started by the test on a free loopback port
//! with a minimal configuration: retained statuses, a command by topic, a refused one, and a
//! real broker restart (kill, start again empty) after which the gateway republishes.
//!
//! `.ci/install-witnesses.sh` installs Mosquitto and `.ci/run` sets `DRIVEBUS_REQUIRE_INTEROP=1`,
//! so in CI a missing broker is a failure; locally without it the test says it did not run.

mod mqtt_support;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use mqtt_support::*;

fn mosquitto_binary() -> Option<PathBuf> {
    let mut dirs: Vec<PathBuf> =
        std::env::var_os("PATH").map(|p| std::env::split_paths(&p).collect()).unwrap_or_default();
    dirs.extend(["/usr/sbin", "/usr/local/sbin", "/opt/homebrew/sbin"].map(PathBuf::from));
    dirs.into_iter().map(|d| d.join("mosquitto")).find(|p| p.is_file())
}

/// A Mosquitto process, killed on drop.
struct Mosquitto {
    child: Child,
    addr: SocketAddr,
}

impl Mosquitto {
    async fn start(bin: &Path, port: u16) -> Mosquitto {
        let dir = std::env::temp_dir().join(format!("drivebus-mosquitto-{}-{port}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let conf = dir.join("mosquitto.conf");
        std::fs::write(
            &conf,
            format!("listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\nlog_dest stderr\n"),
        )
        .unwrap();
        let child = Command::new(bin)
            .arg("-c")
            .arg(&conf)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", bin.display()));
        let addr: SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
        wait_listening(addr).await;
        Mosquitto { child, addr }
    }

    fn stop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Mosquitto {
    fn drop(&mut self) {
        self.stop();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mosquitto_statuses_commands_and_restart() {
    let Some(bin) = mosquitto_binary() else {
        assert!(
            std::env::var_os("DRIVEBUS_REQUIRE_INTEROP").is_none(),
            "mosquitto is required in CI but missing: apt-get install mosquitto"
        );
        eprintln!("NOT RUN: mosquitto is not installed (apt-get install mosquitto); .ci/run installs it");
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
    assert_eq!(gw.drive_view(gw.drive("pump-2").unwrap()).running, Some(false));

    // A real restart: the broker goes away and comes back empty on the same port.
    broker.stop();
    let broker = Mosquitto::start(&bin, port).await;
    let again = Subscriber::start(broker.addr, "again", &format!("{p}/#")).await;
    let drives = demo_drives();
    again
        .wait("every drive's status after the restart", |log| {
            drives
                .iter()
                .all(|(b, d)| log.iter().any(|m| m.topic == format!("{p}/{b}/{d}/status")))
                .then_some(())
        })
        .await;
    wait_all_statuses(&Subscriber::start(broker.addr, "after", &format!("{p}/#")).await, p).await;
    let pump = again.wait_json(&format!("{p}/line-toshiba/pump-1/status"), |v| v["running"] == true).await;
    assert_eq!(pump["setpoint_hz"], 30.0);
}
