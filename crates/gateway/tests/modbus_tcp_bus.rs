//! A bus with `protocol = "modbus-tcp"`: the gateway polls and commands simulated drives behind
//! a Modbus TCP endpoint (the simulator's `--modbus-tcp`), one unit id per drive, and opens the
//! connection again when the endpoint goes away and comes back. Real time: the endpoint is a
//! TCP port.

mod support;

use std::net::SocketAddr;
use std::time::Duration;

use drivebus_gateway::core::Command;
use drivebus_gateway::{Gateway, GatewayConfig};
use drivebus_sim::config::BusSpec;
use drivebus_sim::runtime::{Endpoint, Simulator};
use support::wait_for;
use tokio::task::JoinHandle;

/// A generic drive at 1 and a Toshiba drive at 2, both on Modbus RTU behind a Modbus TCP
/// endpoint at `addr`; the endpoint's address once it listens.
async fn endpoint(addr: SocketAddr) -> (SocketAddr, JoinHandle<()>) {
    let drives = vec!["generic@1:modbus-rtu".parse().unwrap(), "toshiba@2:modbus-rtu".parse().unwrap()];
    let bus = BusSpec::new(drives, Some(19200), Some("8E1".parse().unwrap())).unwrap();
    let sim = Simulator::new(&bus).unwrap();
    let (tx, rx) = tokio::sync::oneshot::channel();
    let task = tokio::spawn(async move {
        let _ = sim
            .serve(Endpoint::ModbusTcp(addr), false, move |at| {
                let _ = tx.send(at);
            })
            .await;
    });
    let at = rx.await.expect("the endpoint listens");
    (at.trim_start_matches("modbus-tcp ").parse().unwrap(), task)
}

fn config(addr: SocketAddr) -> GatewayConfig {
    let text = format!(
        "[store]\ndisabled = true\n\
         [[bus]]\nname = \"eth\"\nport = \"tcp://{addr}\"\nprotocol = \"modbus-tcp\"\ntimeout_ms = 500\nretries = 0\n\
         [[bus.drive]]\nname = \"fan\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 50\n\
         [[bus.drive]]\nname = \"pump\"\nfamily = \"toshiba\"\naddress = 2\npoll_ms = 50\n"
    );
    GatewayConfig::from_toml("t.toml", &text).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_gateway_polls_and_commands_drives_over_modbus_tcp_and_reconnects() {
    let (addr, sim) = endpoint("127.0.0.1:0".parse().unwrap()).await;
    let gw = Gateway::start(config(addr), None).unwrap();
    let view = |id: &str| gw.drive_view(&gw.drive(id).unwrap());
    wait_for("both drives online", Duration::from_secs(20), || {
        view("fan").online == Some(true) && view("pump").online == Some(true)
    })
    .await;
    assert_eq!(view("fan").protocol, "modbus-tcp");
    assert_eq!(gw.bus_view(&gw.buses()[0]).protocol, "modbus-tcp");

    gw.command("fan", Command::Speed(20.0), "test").await.expect("speed");
    gw.command("fan", Command::Run, "test").await.expect("run");
    wait_for("fan at 20 Hz", Duration::from_secs(60), || {
        view("fan").output_hz.is_some_and(|hz| (hz - 20.0).abs() < 0.01)
    })
    .await;
    assert_eq!(view("pump").running, Some(false), "the other unit id is another drive");

    // The endpoint goes away: offline. It comes back at the same address: the connection is
    // opened again with the bus's backoff and the drives are polled again.
    sim.abort();
    let _ = sim.await;
    wait_for("fan offline", Duration::from_secs(20), || view("fan").online == Some(false)).await;
    let (_, sim) = endpoint(addr).await;
    wait_for("fan online again", Duration::from_secs(30), || view("fan").online == Some(true)).await;
    sim.abort();
}

#[test]
fn a_modbus_tcp_bus_is_checked() {
    let bad = |text: &str, want: &str| {
        let e = GatewayConfig::from_toml("t.toml", text).expect_err(text).to_string();
        assert!(e.contains(want), "{e}");
    };
    bad(
        "[[bus]]\nname = \"a\"\nport = \"/dev/ttyUSB0\"\nprotocol = \"modbus-tcp\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"generic\"\naddress = 1\n",
        "t.toml:3: field `bus.port`: a modbus-tcp bus is reached over TCP: give tcp://HOST[:PORT]",
    );
    bad(
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-tcp\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"danfoss\"\naddress = 1\n",
        "field `bus.protocol`: drive \"x\": a danfoss drive does not speak Modbus, so not modbus-tcp",
    );
    bad(
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus\"\n",
        "unknown protocol: use modbus-rtu, modbus-ascii, toshiba-ascii, toshiba-binary, danfoss-fc or b800 or modbus-tcp",
    );
    bad(
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-tcp\"\nmax_in_flight = 4\n",
        "t.toml:5: field `bus.max_in_flight`: 4: this version sends one request at a time on a Modbus TCP bus: use 1",
    );
    bad(
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-rtu\"\nmax_in_flight = 1\n",
        "field `bus.max_in_flight`: only a modbus-tcp bus",
    );
    let c = GatewayConfig::from_toml(
        "t.toml",
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5\"\nprotocol = \"modbus-tcp\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"generic\"\naddress = 1\n",
    )
    .unwrap();
    assert_eq!(c.buses[0].port, drivebus_gateway::config::Port::ModbusTcp("10.0.0.5:502".into()));
    assert_eq!(c.buses[0].protocol_name(), "modbus-tcp");
}
