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

#[tokio::test(start_paused = true)]
async fn on_demand_floods_share_the_bus_and_polls_keep_their_interval() {
    let (bus, _line) = bus_of(&[1, 2], Faults::default());
    let bus = Arc::new(bus);
    // Two clients each keep 8 reads of drive 2 waiting (the most a client may), with more
    // trying, as fast as they are answered.
    let served = Arc::new(Mutex::new([0u32; 2]));
    for (k, client) in ["10.0.0.2", "10.0.0.3"].into_iter().enumerate() {
        for _ in 0..12 {
            let (bus, served) = (bus.clone(), served.clone());
            tokio::spawn(async move {
                loop {
                    match bus.transact_for(client, 2, read(2, 0x2103), Priority::OnDemand, None).await {
                        Ok(_) => served.lock().unwrap()[k] += 1,
                        Err(BusError::Busy(_)) => tokio::time::sleep(Duration::from_millis(1)).await,
                        Err(e) => panic!("{e}"),
                    }
                }
            });
        }
    }
    // A client over its own bound is refused at once, without waiting.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let refused = bus.transact_for("10.0.0.2", 2, read(2, 0x2103), Priority::OnDemand, None).await;
    assert!(matches!(refused, Err(BusError::Busy(ref m)) if m.contains("at most 8")), "{refused:?}");
    // Drive 1 polled every 100 ms for 10 s: every poll done within its interval.
    let start = tokio::time::Instant::now();
    let mut due = start;
    let mut worst = Duration::ZERO;
    while due - start < Duration::from_secs(10) {
        tokio::time::sleep_until(due).await;
        let poll = bus.transact(1, read(1, 0x2103), Priority::Poll, None);
        tokio::time::timeout(Duration::from_secs(1), poll).await.expect("a poll within 1 s").unwrap();
        worst = worst.max(tokio::time::Instant::now() - due);
        due += Duration::from_millis(100);
    }
    assert!(worst < Duration::from_millis(100), "a poll took {worst:?} to be served");
    let [a, b] = *served.lock().unwrap();
    assert!(a > 100 && b > 100, "on-demand reads were served too: {a} and {b}");
    assert!(a.abs_diff(b) * 10 <= a.max(b), "the clients were served in turn: {a} and {b}");
}

#[tokio::test(start_paused = true)]
async fn scan_probes_wait_behind_everything_and_leave_health_alone() {
    let (bus, _line) = bus_of(&[1], Faults::default());
    let bus = Arc::new(bus);
    let order = Arc::new(Mutex::new(Vec::new()));
    let job = |what: &'static str, address: u8, priority: Priority| {
        let (bus, order) = (bus.clone(), order.clone());
        tokio::spawn(async move {
            let r = bus.transact(address, read(address, 0x2103), priority, None).await;
            order.lock().unwrap().push(what);
            r
        })
    };
    // The first keeps the line busy while the others queue up, the scan's probe first.
    let first = job("first", 1, Priority::Poll);
    for _ in 0..10 {
        tokio::task::yield_now().await;
    }
    let scan = job("scan", 9, Priority::Scan);
    for _ in 0..10 {
        tokio::task::yield_now().await;
    }
    let others = [job("poll", 1, Priority::Poll), job("on-demand", 1, Priority::OnDemand)];
    first.await.unwrap().unwrap();
    for j in others {
        j.await.unwrap().unwrap();
    }
    // An empty address: one attempt (no retries), and no health kept for it.
    let probe = scan.await.unwrap();
    assert!(matches!(probe, Err(BusError::Timeout { attempts: 1, .. })), "{probe:?}");
    assert_eq!(*order.lock().unwrap(), ["first", "poll", "on-demand", "scan"]);
    for _ in 0..5 {
        let r = bus.transact(9, read(9, 0x2103), Priority::Scan, None).await;
        assert!(matches!(r, Err(BusError::Timeout { .. })), "{r:?}");
    }
    assert!(!bus.health().contains_key(&9), "{:?}", bus.health());
    // A drive that is there answers a probe.
    assert!(bus.transact(1, read(1, 0x2103), Priority::Scan, None).await.unwrap().is_some());
}
