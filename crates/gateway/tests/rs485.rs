//! A bus's `rs485` setting is applied to its serial port: `kernel` where the driver has no
//! kernel RS-485 mode (a pseudo-terminal) keeps the bus offline with that reason, `auto` falls
//! back to RTS toggling and polls. Real time: the port is a pseudo-terminal served by the
//! simulator.

use std::time::{Duration, Instant};

use drivebus_gateway::{Gateway, GatewayConfig};
use drivebus_sim::config::BusSpec;
use drivebus_sim::runtime::{Endpoint, Simulator};

fn serve_pty(path: std::path::PathBuf) -> tokio::task::JoinHandle<()> {
    let bus = BusSpec::new(vec!["b800@1".parse().unwrap()], Some(9600), None).unwrap();
    let sim = Simulator::new(&bus).unwrap();
    tokio::spawn(async move {
        let _ = sim.serve(Endpoint::Pty(path), false, |_| {}).await;
    })
}

async fn wait_for(what: &str, limit: Duration, mut ok: impl FnMut() -> bool) {
    let start = Instant::now();
    while !ok() {
        assert!(start.elapsed() < limit, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

fn config(pty: &std::path::Path, rs485: &str) -> GatewayConfig {
    let text = format!(
        "[store]\ndisabled = true\n\
         [[bus]]\nname = \"real\"\nport = \"{}\"\nprotocol = \"b800\"\nbaud = 9600\ntimeout_ms = 100\nretries = 0\nrs485 = \"{rs485}\"\n\
         [[bus.drive]]\nname = \"m1\"\nfamily = \"b800\"\naddress = 1\npoll_ms = 50\n",
        pty.display()
    );
    GatewayConfig::from_toml("t.toml", &text).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bus_opens_its_port_with_its_rs485_setting() {
    let dir = std::env::temp_dir().join(format!("drivebus-rs485-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let pty = dir.join("ttyV0");
    let sim = serve_pty(pty.clone());
    wait_for("the pty", Duration::from_secs(10), || pty.exists()).await;

    // A pty has no kernel RS-485 mode: asked for, the port does not open, and says why.
    let gw = Gateway::start(config(&pty, "kernel"), None).unwrap();
    let m1 = || gw.drive_view(&gw.drive("m1").unwrap());
    wait_for("m1 offline", Duration::from_secs(10), || m1().online == Some(false)).await;
    let err = m1().last_error.unwrap_or_default();
    assert!(err.contains("no kernel RS-485 mode"), "{err}");

    // `auto` falls back to RTS toggling, which a pty skips: the bus is opened again with it
    // (a changed setting reopens the bus) and the drive answers.
    let reload = gw.reload(config(&pty, "auto"), "test").await.unwrap();
    assert!(reload.summary.contains("real"), "{reload:?}");
    let m1 = || gw.drive_view(&gw.drive("m1").unwrap());
    wait_for("m1 online", Duration::from_secs(10), || m1().online == Some(true)).await;

    sim.abort();
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_unknown_rs485_mode_is_refused_with_the_choices() {
    let text = "[[bus]]\nname = \"b\"\nport = \"/dev/ttyUSB0\"\nprotocol = \"b800\"\nrs485 = \"always\"\n";
    let e = GatewayConfig::from_toml("t.toml", text).unwrap_err().to_string();
    assert!(e.contains("bus.rs485") && e.contains("off, auto, kernel or rts"), "{e}");
}
