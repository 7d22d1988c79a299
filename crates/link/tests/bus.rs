//! The bus owner against virtual drives, on tokio's paused clock (simulated time: fast and
//! deterministic): exchanges, broadcasts, noise, a dead drive among live ones.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_drive::profile::Exchange;
use drivebus_drive::Family;
use drivebus_link::{Bus, BusConfig, BusError, Priority, SimLink};
use drivebus_proto::checksum::crc16_modbus;
use drivebus_proto::line::CharFormat;
use drivebus_proto::Instant;
use drivebus_sim::bus::{Faults, VirtualLine};
use drivebus_sim::config::DriveSpec;

fn rtu(frame: &[u8]) -> Vec<u8> {
    let mut v = frame.to_vec();
    v.extend_from_slice(&crc16_modbus(frame).to_le_bytes());
    v
}

fn read(addr: u8, reg: u16) -> Exchange {
    Exchange { request: rtu(&[addr, 0x03, (reg >> 8) as u8, reg as u8, 0, 1]), expect_reply: addr != 0 }
}

/// A line of generic RTU drives at 19200 8N2 and a bus owner on it.
fn bus_of(addresses: &[u8], faults: Faults) -> (Bus, Arc<Mutex<VirtualLine>>) {
    let mut line = VirtualLine::new(19200, CharFormat::NONE_8N2, Instant::ZERO);
    for &a in addresses {
        let spec = DriveSpec {
            family: Family::Generic,
            address: a,
            protocol: Some(drivebus_proto::protocol::WireProtocol::ModbusRtu),
            response: Duration::from_millis(3),
            load: 0.5,
            params: Vec::new(),
        };
        line.add_device(drivebus_sim::family::build(&spec, Instant::ZERO).unwrap());
    }
    line.set_faults(faults);
    line.seed(7);
    let line = Arc::new(Mutex::new(line));
    let mut cfg =
        BusConfig::new(drivebus_proto::protocol::WireProtocol::ModbusRtu, 19200, CharFormat::NONE_8N2);
    cfg.response_timeout = Some(Duration::from_millis(50));
    let bus = Bus::spawn(SimLink::new(line.clone(), "virtual"), cfg).unwrap();
    (bus, line)
}

fn value(reply: &[u8]) -> u16 {
    u16::from_be_bytes([reply[3], reply[4]])
}

#[tokio::test(start_paused = true)]
async fn reads_a_register_and_broadcasts_without_waiting_for_a_reply() {
    let (bus, _line) = bus_of(&[1, 2], Faults::default());
    let r = bus.transact(1, read(1, 0x210B), Priority::Command, None).await.unwrap().unwrap();
    assert_eq!(value(&r), 0x0100, "210BH is the version 1.00");
    // A broadcast write of 2001H: executed by both, answered by none.
    let w = Exchange { request: rtu(&[0, 0x06, 0x20, 0x01, 0x0F, 0xA0]), expect_reply: false };
    assert_eq!(bus.transact(0, w, Priority::Command, None).await.unwrap(), None);
    for a in [1, 2] {
        let r = bus.transact(a, read(a, 0x2102), Priority::Command, None).await.unwrap().unwrap();
        assert_eq!(value(&r), 4000, "drive {a} took the broadcast setpoint");
    }
    let s = bus.stats();
    assert_eq!((s.broadcasts, s.timeouts, s.checksum_errors), (1, 0, 0));
    assert!(s.utilization() > 0.0);
}

#[tokio::test(start_paused = true)]
async fn one_percent_noise_never_gives_a_wrong_value() {
    let (bus, _line) = bus_of(&[1], Faults { corrupt_rate: 0.01, ..Faults::default() });
    let (mut ok, mut failed) = (0, 0);
    for _ in 0..1000 {
        match bus.transact(1, read(1, 0x210B), Priority::Poll, None).await {
            Ok(Some(r)) => {
                assert_eq!(value(&r), 0x0100, "a reply that passed its CRC carries the true value");
                ok += 1;
            }
            Ok(None) => panic!("a reply is due"),
            Err(_) => failed += 1,
        }
    }
    let s = bus.stats();
    // 1 % of ~15 bytes per exchange: about one exchange in seven is hit, and retried.
    assert!(s.checksum_errors + s.timeouts > 50, "damage is detected: {s:?}");
    // Every damaged attempt is retried, except the last of a transaction that failed them all.
    assert_eq!(
        s.retries,
        s.checksum_errors + s.timeouts - failed as u64,
        "every damaged exchange is retried: {s:?}"
    );
    assert_eq!(s.transactions, 1000 + s.retries);
    assert!(ok >= 995, "retries recover almost everything: {ok} ok, {failed} failed, {s:?}");
}

#[tokio::test(start_paused = true)]
async fn a_dead_drive_costs_the_others_at_most_one_timeout_per_cycle() {
    let addresses = [1, 2, 3, 4, 5, 6, 7, 8];
    let (bus, line) = bus_of(&addresses, Faults::default());
    // A healthy cycle first.
    let start = tokio::time::Instant::now();
    for &a in &addresses {
        bus.transact(a, read(a, 0x2103), Priority::Poll, None).await.unwrap();
    }
    let healthy = start.elapsed();
    // Drive 5 goes silent.
    line.lock().unwrap().set_silent(5, true);
    let mut cycles = Vec::new();
    for _ in 0..20 {
        let t = tokio::time::Instant::now();
        for &a in &addresses {
            let r = bus.transact(a, read(a, 0x2103), Priority::Poll, None).await;
            if a == 5 {
                assert!(matches!(r, Err(BusError::Timeout { .. }) | Err(BusError::Offline { .. })), "{r:?}");
            } else {
                assert!(r.is_ok(), "drive {a}: {r:?}");
            }
        }
        cycles.push(t.elapsed());
    }
    let timeout = Duration::from_millis(50);
    // Once offline (after 3 failed transactions), a cycle costs at most one timeout more.
    for (i, c) in cycles.iter().enumerate().skip(3) {
        assert!(
            *c <= healthy + timeout + Duration::from_millis(5),
            "cycle {i}: {c:?} vs healthy {healthy:?}"
        );
    }
    let health = bus.health();
    assert!(!health[&5].online);
    assert!(health[&1].online);
}

#[tokio::test(start_paused = true)]
async fn commands_go_first_then_bridged_requests_then_polls() {
    let (bus, _line) = bus_of(&[1], Faults::default());
    let bus = Arc::new(bus);
    let order = Arc::new(Mutex::new(Vec::new()));
    let job = |what: &'static str, priority: Priority| {
        let (bus, order) = (bus.clone(), order.clone());
        tokio::spawn(async move {
            bus.transact(1, read(1, 0x2103), priority, None).await.unwrap();
            order.lock().unwrap().push(what);
        })
    };
    // The first keeps the line busy while the other three queue up, the lowest first.
    let first = job("first", Priority::Poll);
    for _ in 0..10 {
        tokio::task::yield_now().await;
    }
    let jobs =
        [job("poll", Priority::Poll), job("bridge", Priority::Bridge), job("command", Priority::Command)];
    first.await.unwrap();
    for j in jobs {
        j.await.unwrap();
    }
    assert_eq!(*order.lock().unwrap(), ["first", "command", "bridge", "poll"]);
}
