//! A line where a drive acts as bus master (seed 004 9.2.2 (2)): the gateway hears broadcasts
//! it did not send and shows the bus as a drive-master line, in the bus view (HTTP API) and
//! the metrics. Real time: the line is a pseudo-terminal served by the simulator.

use std::time::{Duration, Instant};

use drivebus_gateway::{Gateway, GatewayConfig};
use drivebus_sim::config::BusSpec;
use drivebus_sim::runtime::{Endpoint, Simulator};

async fn wait_for(what: &str, limit: Duration, mut ok: impl FnMut() -> bool) {
    let start = Instant::now();
    while !ok() {
        assert!(start.elapsed() < limit, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_drive_master_line_is_shown() {
    let dir = std::env::temp_dir().join(format!("drivebus-drive-master-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let pty = dir.join("ttyV0");
    let sim = Simulator::new(&BusSpec::from_toml("line.toml", LINE).unwrap()).unwrap();
    let path = pty.clone();
    let served = tokio::spawn(async move {
        let _ = sim.serve(Endpoint::Pty(path), false, |_| {}).await;
    });
    wait_for("the pty", Duration::from_secs(10), || pty.exists()).await;

    // Polls far apart: on a half-duplex line the master drive talks blindly, and a gateway
    // that kept the line busy would garble most of its broadcasts.
    let text = format!(
        "[store]\ndisabled = true\n\
         [[bus]]\nname = \"line\"\nport = \"{}\"\nprotocol = \"modbus-rtu\"\nbaud = 9600\nserial = \"8N2\"\ntimeout_ms = 200\n\
         [[bus.drive]]\nname = \"follower\"\nfamily = \"generic\"\naddress = 2\npoll_ms = 500\n",
        pty.display()
    );
    let gw = Gateway::start(GatewayConfig::from_toml("t.toml", &text).unwrap(), None).unwrap();
    let bus = || gw.bus_view(&gw.buses()[0]);
    wait_for("the drive-master line", Duration::from_secs(20), || bus().drive_master).await;
    assert!(bus().foreign_broadcasts > 0);
    let json = serde_json::to_value(bus()).unwrap();
    assert_eq!(json["drive_master"], true, "{json}");

    let metrics = drivebus_gateway::metrics::render(&gw).unwrap();
    assert!(metrics.contains("drivebus_bus_drive_master{bus=\"line\"} 1"), "{metrics}");
    assert!(metrics.contains("drivebus_bus_foreign_broadcasts_total{bus=\"line\"}"), "{metrics}");
    served.abort();
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_line_without_a_drive_master_is_not_one() {
    let dir = std::env::temp_dir().join(format!("drivebus-no-drive-master-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let pty = dir.join("ttyV0");
    let plain = LINE.replace("role = \"master\"\ncycle_ms = 100\n", "");
    assert!(!plain.contains("master"), "{plain}");
    let sim = Simulator::new(&BusSpec::from_toml("line.toml", &plain).unwrap()).unwrap();
    let path = pty.clone();
    let served = tokio::spawn(async move {
        let _ = sim.serve(Endpoint::Pty(path), false, |_| {}).await;
    });
    wait_for("the pty", Duration::from_secs(10), || pty.exists()).await;
    let text = format!(
        "[store]\ndisabled = true\n\
         [[bus]]\nname = \"line\"\nport = \"{}\"\nprotocol = \"modbus-rtu\"\nbaud = 9600\nserial = \"8N2\"\ntimeout_ms = 200\n\
         [[bus.drive]]\nname = \"follower\"\nfamily = \"generic\"\naddress = 2\npoll_ms = 100\n",
        pty.display()
    );
    let gw = Gateway::start(GatewayConfig::from_toml("t.toml", &text).unwrap(), None).unwrap();
    let bus = || gw.bus_view(&gw.buses()[0]);
    wait_for("ten replies", Duration::from_secs(20), || bus().replies >= 10).await;
    assert!(!bus().drive_master);
    assert_eq!(bus().foreign_broadcasts, 0);
    served.abort();
    let _ = std::fs::remove_dir_all(&dir);
}
