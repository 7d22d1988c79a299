//! A line where a drive acts as bus master (seed 004 9.2.2 (2)): the gateway hears broadcasts
//! it did not send and shows the bus as a drive-master line, in the bus view (HTTP API) and
//! the metrics. Real time: the line is a pseudo-terminal served by the simulator.

mod support;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use drivebus_gateway::{Gateway, GatewayConfig};
use drivebus_sim::config::BusSpec;
use drivebus_sim::runtime::{Endpoint, Simulator};
use support::wait_for;
use tokio::task::JoinHandle;

const LINE: &str = r#"
[[drive]]
kind = "generic"
address = 1
protocol = "modbus-rtu"
role = "master"
cycle_ms = 100
params = { "P0.02" = "40 Hz" }

[[drive]]
kind = "generic"
address = 2
protocol = "modbus-rtu"
"#;

/// The simulated line `spec` served on a pty in a directory of its own, and a gateway polling
/// its drive 2 every `poll_ms`.
struct Line {
    dir: PathBuf,
    served: JoinHandle<()>,
    gw: Arc<Gateway>,
}

impl Line {
    async fn start(name: &str, spec: &str, poll_ms: u64) -> Line {
        let dir = std::env::temp_dir().join(format!("drivebus-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let pty = dir.join("ttyV0");
        let sim = Simulator::new(&BusSpec::from_toml("line.toml", spec).unwrap()).unwrap();
        let path = pty.clone();
        let served = tokio::spawn(async move {
            let _ = sim.serve(Endpoint::Pty(path), false, |_| {}).await;
        });
        wait_for("the pty", Duration::from_secs(10), || pty.exists()).await;
        let text = format!(
            "[store]\ndisabled = true\n\
             [[bus]]\nname = \"line\"\nport = \"{}\"\nprotocol = \"modbus-rtu\"\nbaud = 9600\nserial = \"8N2\"\ntimeout_ms = 200\n\
             [[bus.drive]]\nname = \"follower\"\nfamily = \"generic\"\naddress = 2\npoll_ms = {poll_ms}\n",
            pty.display()
        );
        let gw = Gateway::start(GatewayConfig::from_toml("t.toml", &text).unwrap(), None).unwrap();
        Line { dir, served, gw }
    }
}

impl Drop for Line {
    fn drop(&mut self) {
        self.served.abort();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_drive_master_line_is_shown() {
    // Polls far apart: on a half-duplex line the master drive talks blindly, and a gateway
    // that kept the line busy would garble most of its broadcasts.
    let line = Line::start("drive-master", LINE, 500).await;
    let gw = &line.gw;
    let bus = || gw.bus_view(&gw.buses()[0]);
    wait_for("the drive-master line", Duration::from_secs(20), || bus().drive_master).await;
    assert!(bus().foreign_broadcasts > 0);
    let json = serde_json::to_value(bus()).unwrap();
    assert_eq!(json["drive_master"], true, "{json}");

    let metrics = drivebus_gateway::metrics::render(gw).unwrap();
    assert!(metrics.contains("drivebus_bus_drive_master{bus=\"line\"} 1"), "{metrics}");
    assert!(metrics.contains("drivebus_bus_foreign_broadcasts_total{bus=\"line\"}"), "{metrics}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_line_without_a_drive_master_is_not_one() {
    let plain = LINE.replace("role = \"master\"\ncycle_ms = 100\n", "");
    assert!(!plain.contains("master"), "{plain}");
    let line = Line::start("no-drive-master", &plain, 100).await;
    let bus = || line.gw.bus_view(&line.gw.buses()[0]);
    wait_for("ten replies", Duration::from_secs(20), || bus().replies >= 10).await;
    assert!(!bus().drive_master);
    assert_eq!(bus().foreign_broadcasts, 0);
}
