//! RS-485 direction control on a pty: the kernel's RS-485 ioctl fails there (ENOTTY), so
//! `auto` falls back to RTS toggling, which a pty (no modem lines) must not turn into errors.

use std::sync::Arc;

use drivebus_drive::profile::Exchange;
use drivebus_link::link::Direction;
use drivebus_link::{Bus, BusConfig, Priority, Rs485, SerialLink};
use drivebus_sim::config::BusSpec;
use drivebus_sim::runtime::{Endpoint, Simulator};

async fn pty_simulator(tag: &str) -> String {
    let bus = BusSpec::new(vec!["generic@1:modbus-rtu".parse().unwrap()], None, None).unwrap();
    let sim: Arc<Simulator> = Simulator::new(&bus).unwrap();
    let path = std::env::temp_dir().join(format!("drivebus-rs485-{tag}-{}", std::process::id()));
    let (tx, rx) = tokio::sync::oneshot::channel();
    let p = path.clone();
    tokio::spawn(async move {
        let _ = sim
            .serve(Endpoint::Pty(p), false, |_| {
                let _ = tx.send(());
            })
            .await;
    });
    rx.await.expect("the simulator is listening");
    path.to_string_lossy().into_owned()
}

#[tokio::test]
async fn auto_falls_back_to_rts_on_a_pty_and_transactions_work() {
    let path = pty_simulator("auto").await;
    let format = "8N2".parse().unwrap();
    let link = SerialLink::open_rs485(&path, 9600, format, Rs485::Auto).expect("open");
    assert_eq!(link.direction(), Direction::Rts);
    let bus =
        Bus::spawn(link, BusConfig::new(drivebus_proto::protocol::WireProtocol::ModbusRtu, 9600, format))
            .unwrap();
    // Read 2 registers at 2100H: RTS on, write, drain, RTS off around it.
    let request = vec![0x01, 0x03, 0x21, 0x00, 0x00, 0x02, 0xCE, 0x37];
    let reply = bus
        .transact(1, Exchange { request, expect_reply: true }, Priority::Command, None)
        .await
        .expect("a reply through RTS toggling")
        .expect("a reply is due");
    assert_eq!(&reply[..3], &[0x01, 0x03, 0x04]);
    let _ = std::fs::remove_file(&path);
}

#[tokio::test]
async fn kernel_mode_is_an_error_where_the_driver_lacks_it() {
    let path = pty_simulator("kernel").await;
    let format = "8N2".parse().unwrap();
    let e =
        SerialLink::open_rs485(&path, 9600, format, Rs485::Kernel).err().expect("a pty has no RS-485 mode");
    assert!(e.to_string().contains("no kernel RS-485 mode"), "{e}");
    let off = SerialLink::open_rs485(&path, 9600, format, Rs485::Off).expect("open");
    assert_eq!(off.direction(), Direction::None);
    assert_eq!("rts".parse::<Rs485>(), Ok(Rs485::Rts));
    assert!("half".parse::<Rs485>().is_err());
    let _ = std::fs::remove_file(&path);
}
