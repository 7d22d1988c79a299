//! A bus whose port disappears is reported offline and reopened when it returns; the other
//! buses keep polling. A bus's `rs485` setting is applied to its serial port. Real time: the
//! port is a pseudo-terminal served by the simulator.

mod support;

use std::path::PathBuf;
use std::time::Duration;

use drivebus_gateway::{Gateway, GatewayConfig};
use drivebus_sim::config::BusSpec;
use drivebus_sim::runtime::{Endpoint, Simulator};
use support::wait_for;
use tokio::task::JoinHandle;

fn serve_pty(path: PathBuf) -> JoinHandle<()> {
    let bus = BusSpec::new(vec!["b800@1".parse().unwrap()], Some(9600), None).unwrap();
    let sim = Simulator::new(&bus).unwrap();
    tokio::spawn(async move {
        let _ = sim.serve(Endpoint::Pty(path), false, |_| {}).await;
    })
}

/// A B800 served on a pty in a directory of its own (`drivebus-<tag>-<pid>`), once the pty is
/// there: the directory, the pty's path and the server.
async fn served_pty(tag: &str) -> (PathBuf, PathBuf, JoinHandle<()>) {
    let dir = std::env::temp_dir().join(format!("drivebus-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let pty = dir.join("ttyV0");
    let sim = serve_pty(pty.clone());
    wait_for("the pty", Duration::from_secs(10), || pty.exists()).await;
    (dir, pty, sim)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_port_goes_offline_and_comes_back() {
    let (dir, pty, sim) = served_pty("port-loss").await;

    let text = format!(
        "[store]\ndisabled = true\n\
         [[bus]]\nname = \"real\"\nport = \"{}\"\nprotocol = \"b800\"\nbaud = 9600\ntimeout_ms = 100\nretries = 0\n\
         [[bus.drive]]\nname = \"m1\"\nfamily = \"b800\"\naddress = 1\npoll_ms = 50\n\
         [[bus]]\nname = \"sim\"\nport = \"virtual\"\nprotocol = \"b800\"\nbaud = 9600\n\
         [[bus.drive]]\nname = \"m2\"\nfamily = \"b800\"\naddress = 1\npoll_ms = 50\n",
        pty.display()
    );
    let gw = Gateway::start(GatewayConfig::from_toml("t.toml", &text).unwrap(), None).unwrap();
    let m1 = || gw.drive_view(&gw.drive("m1").unwrap());
    let m2_polls = || gw.drive_view(&gw.drive("m2").unwrap()).polls;
    wait_for("m1 online", Duration::from_secs(10), || m1().online == Some(true)).await;

    // The port goes away.
    let mut changes = gw.subscribe();
    sim.abort();
    let _ = sim.await;
    wait_for("m1 offline", Duration::from_secs(10), || m1().online == Some(false)).await;
    let before = m2_polls();
    wait_for("the other bus to keep polling", Duration::from_secs(30), || m2_polls() > before + 3).await;
    let m1_polls = m1().polls;
    wait_for("m1's polls to keep counting while its port is gone", Duration::from_secs(30), || {
        m1().polls > m1_polls + 3
    })
    .await;
    let err = m1().last_error.unwrap_or_default();
    assert!(!err.is_empty());
    let mut kinds = Vec::new();
    while let Ok(c) = changes.try_recv() {
        if let drivebus_gateway::core::Change::Event(e) = c {
            kinds.push((e.kind, e.bus, e.drive));
        }
    }
    eprintln!("m1 error while the port is gone: {err}; events {kinds:?}");
    assert!(
        kinds.iter().any(|(k, b, d)| *k == drivebus_store::EventKind::Offline
            && b.as_deref() == Some("real")
            && d.as_deref() == Some("m1")),
        "{kinds:?}"
    );

    // It comes back at the same path.
    let sim = serve_pty(pty.clone());
    wait_for("m1 online again", Duration::from_secs(20), || m1().online == Some(true)).await;
    let bus = gw.bus_view(&gw.buses()[0]);
    assert!(bus.online, "{bus:?}");
    sim.abort();
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_port_missing_at_start_is_an_offline_bus_not_a_failure() {
    let text = "[store]\ndisabled = true\n\
         [[bus]]\nname = \"gone\"\nport = \"/dev/drivebus-no-such-port\"\nprotocol = \"b800\"\ntimeout_ms = 50\n\
         [[bus.drive]]\nname = \"m1\"\nfamily = \"b800\"\naddress = 1\npoll_ms = 50\n\
         [[bus]]\nname = \"sim\"\nport = \"virtual\"\nprotocol = \"b800\"\n\
         [[bus.drive]]\nname = \"m2\"\nfamily = \"b800\"\naddress = 1\npoll_ms = 50\n";
    let gw = Gateway::start(GatewayConfig::from_toml("t.toml", text).unwrap(), None).unwrap();
    wait_for("m1 offline", Duration::from_secs(10), || {
        gw.drive_view(&gw.drive("m1").unwrap()).online == Some(false)
    })
    .await;
    wait_for("m2 online", Duration::from_secs(10), || {
        gw.drive_view(&gw.drive("m2").unwrap()).online == Some(true)
    })
    .await;
    let bus = gw.bus_view(&gw.buses()[0]);
    assert!(!bus.online, "{bus:?}");
    let err = gw.drive_view(&gw.drive("m1").unwrap()).last_error.unwrap();
    assert!(err.contains("/dev/drivebus-no-such-port"), "{err}");
    // The offline drive is still polled: its counter keeps rising (issue 13, defect 10).
    let polls = || gw.drive_view(&gw.drive("m1").unwrap()).polls;
    let before = polls();
    wait_for("m1's polls to keep counting while offline", Duration::from_secs(30), || polls() > before + 3)
        .await;
}

/// A configuration of one b800 drive on the pty `pty`, whose port has RS-485 mode `rs485`.
fn rs485_config(pty: &std::path::Path, rs485: &str) -> GatewayConfig {
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
    let (dir, pty, sim) = served_pty("rs485").await;

    // A pty has no kernel RS-485 mode: asked for, the port does not open, and says why.
    let gw = Gateway::start(rs485_config(&pty, "kernel"), None).unwrap();
    let m1 = || gw.drive_view(&gw.drive("m1").unwrap());
    wait_for("m1 offline", Duration::from_secs(10), || m1().online == Some(false)).await;
    let err = m1().last_error.unwrap_or_default();
    assert!(err.contains("no kernel RS-485 mode"), "{err}");

    // `auto` falls back to RTS toggling, which a pty skips: the bus is opened again with it
    // (a changed setting reopens the bus) and the drive answers.
    let reload = gw.reload(rs485_config(&pty, "auto"), "test").await.unwrap();
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
