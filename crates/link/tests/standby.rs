//! Two bus owners on one virtual line, on tokio's paused clock: a standby answers its polls from
//! what it hears of the master's, refuses commands, takes the line when the master falls
//! silent; the old master restarted stays listening. The line counts no garbled frame.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_drive::profile::{for_drive, DriveStatus, Exchange};
use drivebus_drive::Family;
use drivebus_link::drive::Drive;
use drivebus_link::link::Link;
use drivebus_link::role::{Role, RoleConfig};
use drivebus_link::{Bus, BusConfig, BusError, Priority, SimLink};
use drivebus_proto::checksum::crc16_modbus;
use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::Instant;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::config::DriveSpec;

fn rtu(frame: &[u8]) -> Vec<u8> {
    let mut v = frame.to_vec();
    v.extend_from_slice(&crc16_modbus(frame).to_le_bytes());
    v
}

fn read(addr: u8, reg: u16) -> Exchange {
    Exchange { request: rtu(&[addr, 0x03, (reg >> 8) as u8, reg as u8, 0, 1]), expect_reply: true }
}

/// Each poll's drive and result.
type Answers = Arc<Mutex<Vec<(u8, Result<Option<Vec<u8>>, BusError>)>>>;

const SILENCE: Duration = Duration::from_millis(500);

fn config(role: Option<bool>) -> BusConfig {
    let mut cfg = BusConfig::new(WireProtocol::ModbusRtu, 19200, CharFormat::NONE_8N2);
    cfg.response_timeout = Some(Duration::from_millis(50));
    cfg.role = role.map(|standby| RoleConfig { standby, silence: SILENCE });
    cfg
}

/// Bus owners on `line`'s two masters' ports, on one clock: `a` active, `b` a standby when
/// `b_standby`.
fn masters(line: &Arc<Mutex<VirtualLine>>, b_standby: bool) -> (Bus, Bus) {
    let a_link = SimLink::new(line.clone(), "a");
    let clock = a_link.clock();
    let a = Bus::spawn(a_link, config(Some(false))).unwrap();
    let b = Bus::spawn(SimLink::for_master(line.clone(), "b", 1, clock), config(Some(b_standby))).unwrap();
    (a, b)
}

/// A line of generic RTU drives 1 and 2 with two masters' ports.
fn line() -> Arc<Mutex<VirtualLine>> {
    let mut line = VirtualLine::new(19200, CharFormat::NONE_8N2, Instant::ZERO);
    for a in [1, 2] {
        let spec = DriveSpec {
            family: Family::Generic,
            address: a,
            protocol: Some(WireProtocol::ModbusRtu),
            response: Duration::from_millis(3),
            load: 0.5,
            params: Vec::new(),
        };
        line.add_device(drivebus_sim::family::build(&spec, Instant::ZERO).unwrap());
    }
    assert_eq!(line.add_master(), 1);
    Arc::new(Mutex::new(line))
}

/// Polls drives 1 and 2 (setpoint 2102H) in turn every 20 ms until aborted; counts answers.
fn poller(bus: Bus, answers: Answers) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        loop {
            for a in [1u8, 2] {
                let r = bus.transact(a, read(a, 0x2102), Priority::Poll, None).await;
                answers.lock().unwrap().push((a, r));
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }
    })
}

/// Waits on the paused clock until `done`, at most `limit`.
async fn wait_for(limit: Duration, what: &str, done: impl Fn() -> bool) -> Duration {
    let start = tokio::time::Instant::now();
    while !done() {
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    start.elapsed()
}

#[tokio::test(start_paused = true)]
async fn a_standby_listens_refuses_commands_takes_over_and_the_old_master_stays_standby() {
    let line = line();
    let a_link = SimLink::new(line.clone(), "a");
    let clock = a_link.clock();
    let a = Bus::spawn(a_link, config(Some(false))).unwrap();
    let b = Bus::spawn(SimLink::for_master(line.clone(), "b", 1, clock), config(Some(true))).unwrap();
    let (a_answers, b_answers): (Answers, Answers) = Default::default();
    let a_poll = poller(a.clone(), a_answers.clone());
    let b_poll = poller(b.clone(), b_answers.clone());

    // The active one takes the line after its silence; the standby stays listening.
    wait_for(Duration::from_secs(2), "a masters", || a.role().is_some_and(|r| r.role == Role::Master)).await;
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(b.role().unwrap().role, Role::Standby);
    assert_eq!(b.stats().transactions, 0, "a standby sends nothing");
    // Its polls are answered from what it heard, the same replies the master got.
    let heard: Vec<_> =
        b_answers.lock().unwrap().iter().filter(|(_, r)| matches!(r, Ok(Some(_)))).cloned().collect();
    assert!(heard.len() >= 10, "{:?}", b_answers.lock().unwrap());
    let got: Vec<Vec<u8>> =
        a_answers.lock().unwrap().iter().filter_map(|(_, r)| r.as_ref().ok().cloned().flatten()).collect();
    for (addr, r) in &heard {
        let reply = r.as_ref().unwrap().as_ref().unwrap();
        assert_eq!(reply[0], *addr, "the reply of the drive asked");
        assert!(got.contains(reply), "a reply the master got: {reply:02X?}");
    }
    // Commands are refused, with the reason.
    let e = b.transact(1, read(1, 0x2102), Priority::Command, None).await.unwrap_err();
    assert!(matches!(e, BusError::Standby(_)), "{e}");
    assert!(e.to_string().contains("standby"), "{e}");

    // The master dies: the standby polls within 1.5 s.
    a_poll.abort();
    drop(a);
    let killed = tokio::time::Instant::now();
    let sent_before = b.stats().transactions;
    wait_for(Duration::from_millis(1500), "the standby takes over", || {
        b.role().is_some_and(|r| r.role == Role::Master) && b.stats().transactions > sent_before
    })
    .await;
    let took = killed.elapsed();
    let status = b.role().unwrap();
    assert_eq!((status.takeovers, status.yields), (1, 0), "{status:?}");
    assert!(took >= SILENCE, "not before the silence: {took:?}");

    // The old master restarted (active) hears the new one and stays standby.
    let a2_link = SimLink::for_master(line.clone(), "a again", 0, clock);
    let a2 = Bus::spawn(a2_link, config(Some(false))).unwrap();
    let a2_answers: Answers = Default::default();
    let a2_poll = poller(a2.clone(), a2_answers.clone());
    tokio::time::sleep(Duration::from_secs(5)).await;
    assert_eq!(a2.role().unwrap().role, Role::Standby);
    assert_eq!(a2.stats().transactions, 0);
    assert_eq!(b.role().unwrap().role, Role::Master);
    assert_eq!(line.lock().unwrap().stats().garbled_frames, 0, "no two masters ever talked at once");
    a2_poll.abort();
    b_poll.abort();
}

#[tokio::test(start_paused = true)]
async fn two_active_owners_started_together_end_with_one_master() {
    for round in 0..5 {
        let line = line();
        let (a, b) = masters(&line, false);
        let (x, y): (Answers, Answers) = Default::default();
        let pa = poller(a.clone(), x);
        let pb = poller(b.clone(), y);
        tokio::time::sleep(Duration::from_secs(3)).await;
        let masters =
            [&a, &b].iter().filter(|bus| bus.role().is_some_and(|r| r.role == Role::Master)).count();
        assert_eq!(masters, 1, "round {round}: {:?} {:?}", a.role(), b.role());
        let garbled = line.lock().unwrap().stats().garbled_frames;
        tokio::time::sleep(Duration::from_secs(3)).await;
        assert_eq!(line.lock().unwrap().stats().garbled_frames, garbled, "round {round}: none after 3 s");
        pa.abort();
        pb.abort();
    }
}

#[tokio::test(start_paused = true)]
async fn twenty_kills_each_hand_the_line_over_within_one_and_a_half_seconds() {
    let mut took = Vec::new();
    for kill in 0..20 {
        let line = line();
        let (a, b) = masters(&line, true);
        let (x, y): (Answers, Answers) = Default::default();
        let pa = poller(a.clone(), x);
        let pb = poller(b.clone(), y);
        wait_for(Duration::from_secs(2), "a masters", || a.role().is_some_and(|r| r.role == Role::Master))
            .await;
        // Killed at a different point of its polling cycle each time.
        tokio::time::sleep(Duration::from_millis(1000 + 7 * kill)).await;
        pa.abort();
        drop(a);
        let killed = tokio::time::Instant::now();
        let sent = b.stats().transactions;
        wait_for(Duration::from_millis(1500), "the standby polls", || {
            b.role().is_some_and(|r| r.role == Role::Master) && b.stats().transactions > sent
        })
        .await;
        took.push(killed.elapsed());
        assert_eq!(line.lock().unwrap().stats().garbled_frames, 0, "kill {kill}");
        pb.abort();
    }
    took.sort();
    println!("takeover over 20 kills: min {:?}, median {:?}, max {:?}", took[0], took[10], took[19]);
    assert!(took[0] >= SILENCE && took[19] <= Duration::from_millis(1500), "{took:?}");
}

/// Each status read's drive, when it ended and its result.
type Statuses = Arc<Mutex<Vec<(u8, tokio::time::Instant, Result<DriveStatus, String>)>>>;

#[tokio::test(start_paused = true)]
async fn a_standby_poll_the_master_has_not_answered_yet_holds_up_no_other_drives() {
    let line = line();
    let (a, b) = masters(&line, true);
    // The master polls drive 2 every 50 ms and drive 1 every 1.6 s, slower than the silence
    // (500 ms): a value of drive 1 older than that answers no poll of the standby.
    let master = a.clone();
    let a_poll = tokio::spawn(async move {
        for n in 0u64.. {
            if n % 32 == 0 {
                let _ = master.transact(1, read(1, 0x2102), Priority::Poll, None).await;
            }
            let _ = master.transact(2, read(2, 0x2102), Priority::Poll, None).await;
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    });
    wait_for(Duration::from_secs(2), "a masters", || a.role().is_some_and(|r| r.role == Role::Master)).await;
    // The standby polls both at once, as the gateway's scheduler does on a standby bus: drive
    // 1's poll waits for the master's next read of it two thirds of the time.
    let answers: Arc<Mutex<Vec<(u8, tokio::time::Instant, bool)>>> = Default::default();
    let pollers: Vec<_> = [1u8, 2]
        .into_iter()
        .map(|addr| {
            let (bus, answers) = (b.clone(), answers.clone());
            tokio::spawn(async move {
                loop {
                    let r = bus.transact(addr, read(addr, 0x2102), Priority::Poll, None).await;
                    answers.lock().unwrap().push((addr, tokio::time::Instant::now(), r.is_ok()));
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
            })
        })
        .collect();
    tokio::time::sleep(Duration::from_secs(2)).await;
    let from = answers.lock().unwrap().len();
    tokio::time::sleep(Duration::from_secs(4)).await;
    let got: Vec<_> = answers.lock().unwrap()[from..].to_vec();
    assert!(got.iter().all(|(_, _, ok)| *ok), "{got:?}");
    assert!(got.iter().any(|(a, _, _)| *a == 1), "drive 1 is answered too: {got:?}");
    // Drive 2's polls are answered from the master's reads of it every 50 ms, also while drive
    // 1's poll waits for up to 1.1 s: each poll waits apart.
    let two: Vec<_> = got.iter().filter(|(a, _, _)| *a == 2).map(|(_, t, _)| *t).collect();
    let longest = two.windows(2).map(|w| w[1] - w[0]).max().unwrap_or(Duration::MAX);
    assert!(longest < Duration::from_millis(200), "drive 2 waited {longest:?} for an answer: {got:?}");
    assert_eq!(b.role().unwrap().role, Role::Standby);
    assert_eq!(b.stats().transactions, 0, "a standby sends nothing");
    a_poll.abort();
    for p in pollers {
        p.abort();
    }
}

/// Reads `quantity` registers from `start` of drive `addr`.
fn read_span(addr: u8, start: u16, quantity: u16) -> Exchange {
    Exchange {
        request: rtu(&[addr, 0x03, (start >> 8) as u8, start as u8, (quantity >> 8) as u8, quantity as u8]),
        expect_reply: true,
    }
}

#[tokio::test(start_paused = true)]
async fn a_standby_learns_values_health_and_schedule_from_a_master_that_polls_otherwise() {
    let line = line();
    let (a, b) = masters(&line, true);
    // The master polls every 150 ms with its own spans and order: 2102H..2104H first, then
    // 2100H..2101H (a profile's status reads 2100H..2103H, then 2104H), and drive 3, which is
    // not on the line.
    let master = a.clone();
    let a_poll = tokio::spawn(async move {
        loop {
            for addr in [1u8, 2, 3] {
                let _ = master.transact(addr, read_span(addr, 0x2102, 3), Priority::Poll, None).await;
                let _ = master.transact(addr, read_span(addr, 0x2100, 2), Priority::Poll, None).await;
            }
            tokio::time::sleep(Duration::from_millis(150)).await;
        }
    });
    wait_for(Duration::from_secs(2), "a masters", || a.role().is_some_and(|r| r.role == Role::Master)).await;
    // It runs drive 1 at 40 Hz and drive 2 at 25 Hz.
    for (addr, hz) in [(1u8, 40.0), (2, 25.0)] {
        let d = Drive::new(a.clone(), for_drive(Family::Generic, WireProtocol::ModbusRtu, addr).unwrap());
        d.set_speed(hz).await.unwrap();
        d.run().await.unwrap();
    }
    // The standby reads each drive's status with the profile, as the gateway polls, at its own
    // 40 ms.
    let statuses: Statuses = Default::default();
    let (standby, seen) = (b.clone(), statuses.clone());
    let b_poll = tokio::spawn(async move {
        let drives: Vec<Drive> = [1u8, 2, 3]
            .into_iter()
            .map(|a| {
                let p = for_drive(Family::Generic, WireProtocol::ModbusRtu, a).unwrap();
                Drive::new(standby.clone(), p).polling()
            })
            .collect();
        loop {
            for (a, d) in (1u8..).zip(&drives) {
                let r = d.status().await.map_err(|e| e.to_string());
                seen.lock().unwrap().push((a, tokio::time::Instant::now(), r));
                tokio::time::sleep(Duration::from_millis(40)).await;
            }
        }
    });
    // Let the drives reach their speed.
    tokio::time::sleep(Duration::from_secs(15)).await;
    let since = tokio::time::Instant::now();
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(b.role().unwrap().role, Role::Standby);
    assert_eq!(b.stats().transactions, 0, "a standby sends nothing");
    // Every answer shows the drive's true state.
    let seen: Vec<_> = statuses.lock().unwrap().iter().filter(|(_, t, _)| *t >= since).cloned().collect();
    for (addr, hz) in [(1u8, 40.0), (2, 25.0)] {
        let mine: Vec<_> = seen.iter().filter(|(a, _, _)| *a == addr).collect();
        assert!(mine.len() >= 5, "drive {addr}: {seen:?}");
        for (_, _, r) in mine {
            let s = r.as_ref().unwrap_or_else(|e| panic!("drive {addr}: {e}"));
            assert!(s.running, "drive {addr}: {s:?}");
            assert_eq!((s.setpoint_hz, s.output_hz), (Some(hz), Some(hz)), "drive {addr}: {s:?}");
        }
    }
    // Drive 3 never answers the master: the standby's polls fail and it is offline, as a
    // polled one would be.
    let three: Vec<_> = seen.iter().filter(|(a, _, _)| *a == 3).collect();
    assert!(!three.is_empty(), "{seen:?}");
    for (_, _, r) in three {
        let e = r.as_ref().unwrap_err();
        assert!(e.contains("no answer from drive 3") || e.contains("drive 3 is offline"), "{e}");
    }
    let health = b.health();
    assert!(!health[&3].online && health[&1].online && health[&2].online, "{health:?}");

    // The schedule it learnt: drives 1 and 2 polled every cycle, 150 ms plus the cycle's
    // exchanges (drive 3 only probed after its backoff).
    let learnt = b.learnt_schedule();
    for addr in [1u8, 2] {
        let every = learnt.get(&addr).copied().unwrap_or_default();
        assert!(
            every >= Duration::from_millis(150) && every < Duration::from_millis(400),
            "drive {addr}: {every:?}"
        );
    }
    a_poll.abort();
    b_poll.abort();
}

#[tokio::test(start_paused = true)]
async fn a_standby_that_polls_seldom_still_times_what_it_hears_as_it_came() {
    let line = line();
    let (a, b) = masters(&line, true);
    let master = a.clone();
    let a_poll = tokio::spawn(async move {
        loop {
            let _ = master.transact(1, read(1, 0x2102), Priority::Poll, None).await;
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    });
    wait_for(Duration::from_secs(2), "a masters", || a.role().is_some_and(|r| r.role == Role::Master)).await;
    // The standby has no poll for a while; then the master dies, and 300 ms later the standby
    // polls: what it heard is at least 300 ms old, older than the master's interval, so it
    // answers no poll; the poll is answered once the standby has taken the line and asked the
    // drive itself.
    tokio::time::sleep(Duration::from_secs(3)).await;
    a_poll.abort();
    drop(a);
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(b.stats().transactions, 0);
    let reply = b.transact(1, read(1, 0x2102), Priority::Poll, None).await.unwrap();
    assert!(reply.is_some());
    assert_eq!(b.role().unwrap().role, Role::Master);
    assert!(b.stats().transactions >= 1, "answered by its own exchange, not by what it heard before");
}
