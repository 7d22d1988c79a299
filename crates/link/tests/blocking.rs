//! The blocking bus and `BlockingDrive` against the simulator, over a pty and over TCP, from a
//! plain thread with no runtime of its own (the simulator runs on a runtime in another thread).

use std::sync::Arc;
use std::time::Duration;

use drivebus_drive::profile::{DriveError, Exchange};
use drivebus_drive::Family;
use drivebus_link::blocking::BlockingBus;
use drivebus_link::drive::{BlockingDrive, Error};
use drivebus_link::{BusConfig, BusError, Priority};
use drivebus_proto::protocol::WireProtocol;
use drivebus_sim::config::BusSpec;
use drivebus_sim::runtime::{Endpoint, Simulator};

/// Starts a simulator of `drives` at `endpoint` on a runtime in its own thread; returns
/// where it listens (the pty's link path, or `tcp://ADDR`).
fn simulator(drives: &[&str], baud: u32, endpoint: Endpoint) -> String {
    let specs = drives.iter().map(|d| d.parse().unwrap()).collect();
    let bus = BusSpec::new(specs, Some(baud), None).unwrap();
    let sim: Arc<Simulator> = Simulator::new(&bus).unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let pty = match &endpoint {
        Endpoint::Pty(p) => Some(p.to_string_lossy().into_owned()),
        Endpoint::Tcp(_) | Endpoint::ModbusTcp(_) => None,
    };
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        rt.block_on(async move {
            let _ = sim
                .serve(endpoint, false, |at| {
                    let _ = tx.send(at);
                })
                .await;
        });
    });
    let at = rx.recv_timeout(Duration::from_secs(10)).expect("the simulator is listening");
    match pty {
        Some(p) => p,
        None => format!("tcp://{}", at.trim_start_matches("tcp ")),
    }
}

fn pty_path(tag: &str) -> Endpoint {
    Endpoint::Pty(std::env::temp_dir().join(format!("drivebus-blocking-{tag}-{}", std::process::id())))
}

#[test]
fn a_generic_drive_over_a_pty_is_set_run_and_read_back() {
    let port = simulator(&["generic@1:modbus-rtu"], 19200, pty_path("generic"));
    let drive = BlockingDrive::open(
        &port,
        Family::Generic,
        WireProtocol::ModbusRtu,
        1,
        19200,
        "8N2".parse().unwrap(),
    )
    .expect("open the pty");
    drive.set_speed(40.0).expect("40 Hz is within the limits");
    drive.run().expect("run");
    // Status reads back to back (each takes its wire time) until the output has moved.
    let mut last = 0.0;
    for _ in 0..1000 {
        let s = drive.status().expect("status");
        assert!(s.running, "{s:?}");
        assert_eq!(s.setpoint_hz, Some(40.0));
        last = s.output_hz.expect("output frequency");
        if last > 0.0 {
            break;
        }
    }
    assert!(last > 0.0 && last <= 40.0, "the output ramps towards 40 Hz: {last}");
    // Out of range: refused before anything is sent.
    let before = drive.stats().transactions;
    match drive.set_speed(1000.0) {
        Err(Error::Drive(DriveError::OutOfRange(_))) => {}
        other => panic!("1000 Hz must be out of range: {other:?}"),
    }
    assert_eq!(drive.stats().transactions, before, "nothing was sent");
    drive.stop().expect("stop");
    let (raw, def) = drive.read_param("P0.04").expect("maximum frequency");
    assert!(raw > 0, "{} = {raw}", def.name);
    let stats = drive.stats();
    assert_eq!(stats.timeouts, 0);
    assert_eq!(stats.replies, stats.transactions);
}

#[test]
fn a_missing_drive_times_out_with_retries_then_goes_offline() {
    let port = simulator(&["generic@1:modbus-rtu"], 115200, pty_path("missing"));
    let mut config = BusConfig::new(WireProtocol::ModbusRtu, 115200, "8N1".parse().unwrap());
    config.response_timeout = Some(Duration::from_millis(30));
    config.retries = 1;
    let mut bus = BlockingBus::open(&port, config).expect("open");
    // Drive 9 is not on the line.
    let mut request = vec![0x09, 0x03, 0x21, 0x00, 0x00, 0x02];
    request.extend_from_slice(&drivebus_proto::checksum::crc16_modbus(&request).to_le_bytes());
    let ex = Exchange { request, expect_reply: true };
    let t0 = std::time::Instant::now();
    match bus.transact(9, &ex, Priority::Command, None) {
        Err(BusError::Timeout { address: 9, attempts: 2, .. }) => {}
        other => panic!("two attempts, then a timeout: {other:?}"),
    }
    // Two response timeouts, not one and not a second: the deadline is kept.
    assert!(t0.elapsed() >= Duration::from_millis(60), "{:?}", t0.elapsed());
    let stats = bus.stats();
    assert_eq!((stats.transactions, stats.timeouts, stats.retries), (2, 2, 1));
    for _ in 0..2 {
        assert!(bus.transact(9, &ex, Priority::Command, None).is_err());
    }
    assert!(!bus.health()[&9].online, "offline after 3 failed transactions");
    match bus.transact(9, &ex, Priority::Poll, None) {
        Err(BusError::Offline { address: 9 }) => {}
        other => panic!("polls to an offline drive are refused at once: {other:?}"),
    }
    // Drive 1 answers on the same bus.
    let ok = Exchange { request: vec![0x01, 0x03, 0x21, 0x00, 0x00, 0x02, 0xCE, 0x37], expect_reply: true };
    let reply = bus.transact(1, &ok, Priority::Poll, None).expect("drive 1 answers").expect("a reply");
    assert_eq!(&reply[..3], &[0x01, 0x03, 0x04]);
}

#[test]
fn b800_and_danfoss_drives_over_tcp() {
    let port = simulator(&["b800@5", "danfoss@3"], 9600, Endpoint::Tcp("127.0.0.1:0".parse().unwrap()));
    // Two protocols on one line is not a real bus; each drive ignores the other's frames, and
    // each BlockingDrive opens its own connection in turn.
    let b800 = BlockingDrive::open(&port, Family::B800, WireProtocol::B800, 5, 9600, "8N1".parse().unwrap())
        .expect("connect");
    b800.set_speed(30.0).expect("speed");
    b800.run().expect("run");
    let s = b800.status().expect("status");
    assert!(s.running, "{s:?}");
    drop(b800);
    let fc =
        BlockingDrive::open(&port, Family::Danfoss, WireProtocol::DanfossFc, 3, 9600, "8E1".parse().unwrap())
            .expect("connect");
    let s = fc.status().expect("status");
    assert!(!s.running, "{s:?}");
}

#[test]
fn a_missing_port_is_a_clear_error() {
    match BlockingBus::open(
        "/dev/drivebus-no-such-port",
        BusConfig::new(WireProtocol::ModbusRtu, 9600, "8E1".parse().unwrap()),
    ) {
        Err(BusError::Link(e)) => assert!(e.contains("/dev/drivebus-no-such-port"), "{e}"),
        Err(e) => panic!("a link error naming the port: {e}"),
        Ok(_) => panic!("no such port"),
    }
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    drop(listener);
    match BlockingBus::open(
        &format!("tcp://{addr}"),
        BusConfig::new(WireProtocol::ModbusRtu, 9600, "8E1".parse().unwrap()),
    ) {
        Err(BusError::Link(e)) => assert!(e.contains(&addr.to_string()), "{e}"),
        Err(e) => panic!("a link error naming the address: {e}"),
        Ok(_) => panic!("nobody listens there"),
    }
    // A protocol is a type: a name that is none of them is refused where it is read.
    let e = "profibus".parse::<drivebus_proto::protocol::WireProtocol>().unwrap_err().to_string();
    assert!(e.contains("modbus-rtu") && e.contains("b800"), "{e}");
}

#[test]
fn rs485_auto_falls_back_to_rts_on_a_pty_and_kernel_mode_is_refused() {
    use drivebus_link::link::Direction;
    use drivebus_link::Rs485;
    let port = simulator(&["generic@1:modbus-rtu"], 9600, pty_path("rs485"));
    let mut config = BusConfig::new(WireProtocol::ModbusRtu, 9600, "8N2".parse().unwrap());
    config.rs485 = Rs485::Kernel;
    match BlockingBus::open(&port, config.clone()) {
        Err(BusError::Link(e)) => assert!(e.contains("no kernel RS-485 mode"), "{e}"),
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("a pty has no kernel RS-485 mode"),
    }
    config.rs485 = Rs485::Auto;
    let mut bus = BlockingBus::open(&port, config).expect("auto opens a pty");
    assert_eq!(bus.direction(), Direction::Rts);
    let ex = Exchange { request: vec![0x01, 0x03, 0x21, 0x00, 0x00, 0x02, 0xCE, 0x37], expect_reply: true };
    let reply = bus.transact(1, &ex, Priority::Command, None).expect("a reply through RTS toggling");
    assert_eq!(&reply.expect("a reply is due")[..3], &[0x01, 0x03, 0x04]);
}

#[test]
fn a_line_that_hangs_up_is_a_link_error_at_once_not_a_timeout() {
    use std::os::fd::AsFd;
    let pair = nix::pty::openpty(None, None).expect("a pty");
    let path = nix::unistd::ttyname(pair.slave.as_fd()).expect("its name");
    let mut config = BusConfig::new(WireProtocol::ModbusRtu, 9600, "8N1".parse().unwrap());
    config.response_timeout = Some(Duration::from_secs(5));
    config.retries = 0;
    let mut bus = BlockingBus::open(&path.to_string_lossy(), config).expect("open the pty");
    drop(pair.master);
    drop(pair.slave);
    let ex = Exchange { request: vec![0x01, 0x03, 0x21, 0x00, 0x00, 0x02, 0xCE, 0x37], expect_reply: true };
    let t0 = std::time::Instant::now();
    match bus.transact(1, &ex, Priority::Command, None) {
        Err(BusError::Link(e)) => assert!(e.contains(&*path.to_string_lossy()), "{e}"),
        other => panic!("a hung-up line is a link error: {other:?}"),
    }
    assert!(t0.elapsed() < Duration::from_secs(2), "not the 5 s response timeout: {:?}", t0.elapsed());
}

#[test]
fn a_virtual_line_is_a_port_of_the_blocking_bus_too() {
    use drivebus_link::port::{Port, VirtualPort};
    use drivebus_proto::line::CharFormat;
    use drivebus_proto::protocol::WireProtocol;
    let mut line =
        drivebus_sim::bus::VirtualLine::new(19200, CharFormat::NONE_8N2, drivebus_proto::Instant::ZERO);
    let spec = "generic@1".parse::<drivebus_sim::config::DriveSpec>().unwrap();
    let spec = drivebus_sim::config::DriveSpec { protocol: Some(WireProtocol::ModbusRtu), ..spec };
    line.add_device(drivebus_sim::family::build(&spec, drivebus_proto::Instant::ZERO).unwrap());
    let port =
        Port::Virtual(VirtualPort { line: Arc::new(std::sync::Mutex::new(line)), name: "virtual:t".into() });
    let mut config = BusConfig::new(WireProtocol::ModbusRtu, 19200, CharFormat::NONE_8N2);
    config.response_timeout = Some(Duration::from_secs(2));
    let mut bus = BlockingBus::open_port(port, config).expect("a virtual line opens");
    assert_eq!(bus.name(), "virtual:t");
    let ex = Exchange { request: vec![0x01, 0x03, 0x21, 0x00, 0x00, 0x02, 0xCE, 0x37], expect_reply: true };
    let reply = bus.transact(1, &ex, Priority::Command, None).expect("a reply");
    assert_eq!(&reply.expect("a reply is due")[..3], &[0x01, 0x03, 0x04]);
    // No drive 2 on the line: its read times out (once, and twice more as retries).
    let ex = Exchange { request: vec![0x02, 0x03, 0x21, 0x00, 0x00, 0x02, 0xCE, 0x04], expect_reply: true };
    match bus.transact(2, &ex, Priority::Command, Some(Duration::from_millis(20))) {
        Err(BusError::Timeout { attempts: 3, .. }) => {}
        other => panic!("{other:?}"),
    }
    assert_eq!(bus.stats().retries, 2);
}
