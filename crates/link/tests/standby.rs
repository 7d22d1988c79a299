//! Two bus owners on one virtual line, on tokio's paused clock: a standby answers its polls from
//! what it hears of the master's, refuses commands, takes the line when the master falls
//! silent; the old master restarted stays listening. The line counts no garbled frame.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_drive::profile::{for_drive, DriveStatus, Exchange, Profile};
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

/// A line of `family` drives at `addresses` speaking `protocol`, with two masters' ports.
fn line_of(
    protocol: WireProtocol,
    family: Family,
    format: CharFormat,
    addresses: &[u8],
) -> Arc<Mutex<VirtualLine>> {
    let mut line = VirtualLine::new(19200, format, Instant::ZERO);
    for &address in addresses {
        let spec = DriveSpec {
            family,
            address,
            protocol: Some(protocol),
            response: Duration::from_millis(3),
            load: 0.5,
            params: Vec::new(),
        };
        line.add_device(drivebus_sim::family::build(&spec, Instant::ZERO).unwrap());
    }
    assert_eq!(line.add_master(), 1);
    Arc::new(Mutex::new(line))
}

/// An active bus owner and a standby on `line`'s two masters' ports, speaking `protocol`.
/// A bus of `protocol` on a line with another master: the active one, or a standby.
fn shared_cfg(protocol: WireProtocol, format: CharFormat, standby: bool) -> BusConfig {
    let mut cfg = BusConfig::new(protocol, 19200, format);
    cfg.response_timeout = Some(Duration::from_millis(50));
    cfg.role = Some(RoleConfig { standby, silence: SILENCE });
    cfg
}

/// Once `a` masters the line, each drive of `speeds` set to its speed and run through its
/// profile: the master's drives, in `speeds` order.
async fn run_through(a: &Bus, profile: impl Fn(u8) -> Box<dyn Profile>, speeds: &[(u8, f64)]) -> Vec<Drive> {
    let masters: Vec<Drive> = speeds.iter().map(|&(addr, _)| Drive::new(a.clone(), profile(addr))).collect();
    // The active one takes the line at its first poll after its silence.
    let start = tokio::time::Instant::now();
    while masters[0].polling_twin().status().await.is_err() {
        assert!(start.elapsed() < Duration::from_secs(2), "a masters: {:?}", a.role());
    }
    for (d, &(_, hz)) in masters.iter().zip(speeds) {
        d.set_speed(hz).await.unwrap();
        d.run().await.unwrap();
    }
    masters
}

/// Master `a` polls each of `drives` every 150 ms with the requests `polls` makes, each of
/// which must be answered.
fn poll_otherwise(a: &Bus, drives: Vec<u8>, polls: fn(u8) -> Vec<Vec<u8>>) -> tokio::task::JoinHandle<()> {
    let master = a.clone();
    tokio::spawn(async move {
        loop {
            for &addr in &drives {
                for request in polls(addr) {
                    let ex = Exchange { request, expect_reply: true };
                    let reply = master.transact(addr, ex, Priority::Poll, None).await;
                    assert!(matches!(reply, Ok(Some(_))), "drive {addr}: {reply:?}");
                }
            }
            tokio::time::sleep(Duration::from_millis(150)).await;
        }
    })
}

/// Standby `b` reads each of `drives`' status through its profile, one every 40 ms: what each
/// read gave, and when.
fn read_statuses(
    b: &Bus,
    drives: &[u8],
    profile: impl Fn(u8) -> Box<dyn Profile>,
) -> (Statuses, tokio::task::JoinHandle<()>) {
    let statuses: Statuses = Default::default();
    let seen = statuses.clone();
    let drives: Vec<(u8, Drive)> =
        drives.iter().map(|&a| (a, Drive::new(b.clone(), profile(a)).polling())).collect();
    let task = tokio::spawn(async move {
        loop {
            for (a, d) in &drives {
                let r = d.status().await.map_err(|e| e.to_string());
                seen.lock().unwrap().push((*a, tokio::time::Instant::now(), r));
                tokio::time::sleep(Duration::from_millis(40)).await;
            }
        }
    });
    (statuses, task)
}

fn pair_on(line: &Arc<Mutex<VirtualLine>>, protocol: WireProtocol, format: CharFormat) -> (Bus, Bus) {
    let cfg = |standby| shared_cfg(protocol, format, standby);
    let a_link = SimLink::new(line.clone(), "a");
    let clock = a_link.clock();
    let a = Bus::spawn(a_link, cfg(false)).unwrap();
    let b = Bus::spawn(SimLink::for_master(line.clone(), "b", 1, clock), cfg(true)).unwrap();
    (a, b)
}

/// A master on a line of `family` drives that runs each of `speeds` through the profile and
/// then polls each drive every 150 ms with the requests `polls` makes (each answered), never
/// as the profile would; a standby beside it reads each drive's status through the profile
/// every 40 ms. Checks that the standby sent nothing and that each of its status reads after
/// the drives settled was answered with what the master's profile reads: running, output
/// and current.
async fn a_standby_reads_what_a_master_polls_otherwise(
    protocol: WireProtocol,
    family: Family,
    format: CharFormat,
    speeds: &[(u8, f64)],
    polls: fn(u8) -> Vec<Vec<u8>>,
) {
    let addresses: Vec<u8> = speeds.iter().map(|(a, _)| *a).collect();
    let line = line_of(protocol, family, format, &addresses);
    let (a, b) = pair_on(&line, protocol, format);
    let profile = move |addr| for_drive(family, protocol, addr).unwrap();
    let masters = run_through(&a, profile, speeds).await;
    let a_poll = poll_otherwise(&a, addresses.clone(), polls);
    let (statuses, b_poll) = read_statuses(&b, &addresses, profile);
    // Let the drives reach their speed.
    tokio::time::sleep(Duration::from_secs(15)).await;
    let since = tokio::time::Instant::now();
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert!(!a_poll.is_finished(), "the master's polls are all answered");
    assert_eq!(b.role().unwrap().role, Role::Standby);
    assert_eq!(b.stats().transactions, 0, "a standby sends nothing");
    let seen: Vec<_> = statuses.lock().unwrap().iter().filter(|(_, t, _)| *t >= since).cloned().collect();
    for (d, &(addr, hz)) in masters.iter().zip(speeds) {
        let truth = d.status().await.unwrap();
        assert!(truth.running && truth.output_hz.is_some_and(|f| (f - hz).abs() < 0.1), "{truth:?}");
        let mine: Vec<_> = seen.iter().filter(|(a, _, _)| *a == addr).collect();
        assert!(mine.len() >= 5, "drive {addr}: {seen:?}");
        for (_, _, r) in mine {
            let s = r.as_ref().unwrap_or_else(|e| panic!("drive {addr}: {e}"));
            assert_eq!(
                (s.running, s.output_hz, s.current_a, &s.fault),
                (truth.running, truth.output_hz, truth.current_a, &truth.fault),
                "drive {addr}: {s:?}"
            );
        }
    }
    a_poll.abort();
    b_poll.abort();
}

#[tokio::test(start_paused = true)]
async fn a_toshiba_ascii_standby_learns_by_communication_number() {
    use drivebus_proto::toshiba::ascii::{AsciiAddress, AsciiRequest};
    use drivebus_proto::toshiba::CommNo;
    // The master reads the numbers a Status needs in its own order, without `&` SUM (the
    // profile sends them with it, FD01 first).
    fn polls(addr: u8) -> Vec<Vec<u8>> {
        [0xFE70, 0xFE03, 0xFE02, 0xFD00, 0xFD01]
            .into_iter()
            .map(|n| {
                let mut out = [0u8; 32];
                let len = AsciiRequest::read(AsciiAddress::Unit(addr), CommNo(n)).emit(&mut out).unwrap();
                out[..len].to_vec()
            })
            .collect()
    }
    let format = CharFormat::EVEN_8E1;
    a_standby_reads_what_a_master_polls_otherwise(
        WireProtocol::ToshibaAscii,
        Family::Toshiba,
        format,
        &[(1, 40.0), (2, 25.0)],
        polls,
    )
    .await;
}

#[tokio::test(start_paused = true)]
async fn a_toshiba_binary_standby_answers_its_block_read_from_single_reads() {
    use drivebus_proto::toshiba::binary::{BinaryAddress, BinaryRequest};
    use drivebus_proto::toshiba::CommNo;
    // The master reads each number alone with `G` (dummy data), the block read selections
    // f875–f879 among them; the standby's profile reads them with `R`, and its status with one
    // `X` block read.
    fn polls(addr: u8) -> Vec<Vec<u8>> {
        [0x0875, 0x0876, 0x0877, 0x0878, 0x0879, 0xFE70, 0xFE02, 0xFE03, 0xFD00, 0xFD01]
            .into_iter()
            .map(|n| {
                let mut out = [0u8; 16];
                let len =
                    BinaryRequest::read_dummy(BinaryAddress::Unit(addr), CommNo(n)).emit(&mut out).unwrap();
                out[..len].to_vec()
            })
            .collect()
    }
    a_standby_reads_what_a_master_polls_otherwise(
        WireProtocol::ToshibaBinary,
        Family::Toshiba,
        CharFormat::EVEN_8E1,
        &[(1, 40.0), (2, 25.0)],
        polls,
    )
    .await;
}

#[tokio::test(start_paused = true)]
async fn a_danfoss_standby_learns_parameters_and_every_telegrams_status_word() {
    use drivebus_proto::fc::{AddressFormat, Adr, ParameterNumber, Request, MAX_TELEGRAM};
    // The master reads the parameters a Status needs in its own order with PCD1 = 0000, and
    // sends a process block for the status word and MAV; the profile's telegrams carry its
    // own control word and reference.
    fn polls(addr: u8) -> Vec<Vec<u8>> {
        let adr = Adr::new(addr, AddressFormat::OneTo126).unwrap();
        let mut out = Vec::new();
        for pnu in [1614, 1602, 303, 302, 300] {
            let mut buf = [0u8; MAX_TELEGRAM];
            let n = Request::read(adr, ParameterNumber::new(pnu).unwrap(), 0).emit(&mut buf).unwrap();
            out.push(buf[..n].to_vec());
        }
        let mut buf = [0u8; MAX_TELEGRAM];
        let process =
            Request::process(adr, drivebus_proto::fc::ControlWord(0), drivebus_proto::fc::Reference(0));
        let n = process.emit(&mut buf).unwrap();
        out.push(buf[..n].to_vec());
        out
    }
    a_standby_reads_what_a_master_polls_otherwise(
        WireProtocol::DanfossFc,
        Family::Danfoss,
        CharFormat::EVEN_8E1,
        &[(1, 40.0), (2, 25.0)],
        polls,
    )
    .await;
}

#[tokio::test(start_paused = true)]
async fn a_b800_standby_learns_by_command_from_a_master_that_writes_lower_case_hex() {
    // The master asks `A`, `Z` and `T` in that order, its hex digits in lower case (drive 10
    // is DA `8a`, `Z` is `5a`); the profile writes upper case, `T` first.
    fn polls(addr: u8) -> Vec<Vec<u8>> {
        [b'A', b'Z', b'T']
            .into_iter()
            .map(|cmd| {
                let digits = format!("{:02x}{:02x}", addr + 128, cmd);
                let sum = digits.bytes().fold(0u8, |s, c| s.wrapping_add(c));
                let mut frame = vec![0x7E];
                frame.extend_from_slice(digits.as_bytes());
                frame.extend_from_slice(format!("{:02x}", !sum).as_bytes());
                frame.push(0x7F);
                frame
            })
            .collect()
    }
    a_standby_reads_what_a_master_polls_otherwise(
        WireProtocol::B800,
        Family::B800,
        CharFormat::NONE_8N1,
        &[(10, 40.0), (11, 25.0)],
        polls,
    )
    .await;
}

#[tokio::test(start_paused = true)]
async fn a_modbus_standby_learns_a_register_from_the_writes_its_drive_acknowledged() {
    let format = CharFormat::NONE_8N2;
    let line = line_of(WireProtocol::ModbusRtu, Family::Generic, format, &[1, 2]);
    let (a, b) = pair_on(&line, WireProtocol::ModbusRtu, format);
    // The master writes each drive's keypad frequency P0.02 (0002H) every 100 ms with 06, and
    // never reads it: drive 1 30.00 Hz, drive 2 35.00 Hz.
    let raw = |addr: u8| 2500 + 500 * u16::from(addr);
    let master = a.clone();
    let acknowledged = Arc::new(Mutex::new(0u32));
    let acks = acknowledged.clone();
    let a_poll = tokio::spawn(async move {
        loop {
            for addr in [1u8, 2] {
                let [hi, lo] = raw(addr).to_be_bytes();
                let write = rtu(&[addr, 0x06, 0x00, 0x02, hi, lo]);
                let ex = Exchange { request: write.clone(), expect_reply: true };
                if master.transact(addr, ex, Priority::Poll, None).await == Ok(Some(write)) {
                    *acks.lock().unwrap() += 1;
                }
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    });
    wait_for(Duration::from_secs(2), "a masters", || a.role().is_some_and(|r| r.role == Role::Master)).await;
    // The standby reads P0.02 through the profile (03 of 0002H) every 40 ms.
    let standby = b.clone();
    let reads = Arc::new(Mutex::new(Vec::new()));
    let seen = reads.clone();
    let b_poll = tokio::spawn(async move {
        let drives: Vec<(u8, Drive)> = [1u8, 2]
            .into_iter()
            .map(|a| {
                let p = for_drive(Family::Generic, WireProtocol::ModbusRtu, a).unwrap();
                (a, Drive::new(standby.clone(), p).polling())
            })
            .collect();
        loop {
            for (a, d) in &drives {
                let r = d.read_param("P0.02").await.map(|(v, _)| v).map_err(|e| e.to_string());
                seen.lock().unwrap().push((*a, r));
                tokio::time::sleep(Duration::from_millis(40)).await;
            }
        }
    });
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(b.role().unwrap().role, Role::Standby);
    assert_eq!(b.stats().transactions, 0, "a standby sends nothing");
    assert!(*acknowledged.lock().unwrap() >= 20, "the drives acknowledged the master's writes");
    let reads = reads.lock().unwrap().clone();
    for addr in [1u8, 2] {
        let mine: Vec<_> = reads.iter().filter(|(a, _)| *a == addr).map(|(_, r)| r.clone()).collect();
        assert!(mine.len() >= 10, "drive {addr}: {reads:?}");
        for r in &mine {
            assert_eq!(r, &Ok(i64::from(raw(addr))), "drive {addr}: {reads:?}");
        }
    }
    a_poll.abort();
    b_poll.abort();
}

#[tokio::test(start_paused = true)]
async fn a_standby_poll_of_what_the_master_never_reads_fails_after_its_wait_and_holds_no_other_up() {
    let line = line();
    let (a, b) = masters(&line, true);
    let a_poll = poller(a.clone(), Default::default());
    wait_for(Duration::from_secs(2), "a masters", || a.role().is_some_and(|r| r.role == Role::Master)).await;
    // The master polls 2102H only: a read of 2105H is never answered by what the standby
    // hears. It fails after the standby's wait (5 s), though the master keeps talking.
    let start = tokio::time::Instant::now();
    let never =
        tokio::time::timeout(Duration::from_secs(30), b.transact(1, read(1, 0x2105), Priority::Poll, None));
    let e = never.await.expect("the poll ends").unwrap_err();
    assert!(matches!(e, BusError::Standby(_)), "{e}");
    let waited = start.elapsed();
    assert!(waited >= Duration::from_secs(5) && waited < Duration::from_secs(6), "{waited:?}");
    // The bus goes on: a poll the master's traffic answers is answered.
    let heard =
        tokio::time::timeout(Duration::from_secs(2), b.transact(1, read(1, 0x2102), Priority::Poll, None));
    assert!(matches!(heard.await, Ok(Ok(Some(_)))));
    assert_eq!((b.role().unwrap().role, b.stats().transactions), (Role::Standby, 0));
    a_poll.abort();
}

/// The second master's port of `line`, opened now: it hears nothing the line carried before
/// (the virtual line keeps every master's bytes from its start).
fn late_port(line: &Arc<Mutex<VirtualLine>>, clock: drivebus_link::Clock) -> SimLink {
    let mut history = Vec::new();
    let mut l = line.lock().unwrap();
    l.advance_to(clock.now());
    l.master_read_to(1, &mut history);
    drop(l);
    SimLink::for_master(line.clone(), "b", 1, clock)
}

/// A drivebus master on a line of `family` drives runs each of `speeds` and polls their status
/// through the profile every 150 ms, as the gateway does; a standby started `late` after it
/// (when the master has read the drives' set-up values once already) reads each status through
/// the profile every 40 ms. Each drive's status is served within the set-up refresh (30 s)
/// plus one failed wait of the standby (5 s), and from then on every status read is answered
/// with the master's view: running, output, current, fault. Returns the standby.
async fn a_late_standby_serves_every_status_within_the_setup_refresh(
    protocol: WireProtocol,
    family: Family,
    format: CharFormat,
    speeds: &[(u8, f64)],
    late: Duration,
) -> Bus {
    let addresses: Vec<u8> = speeds.iter().map(|(a, _)| *a).collect();
    let line = line_of(protocol, family, format, &addresses);
    let cfg = |standby| shared_cfg(protocol, format, standby);
    let a_link = SimLink::new(line.clone(), "a");
    let clock = a_link.clock();
    let a = Bus::spawn(a_link, cfg(false)).unwrap();
    let profile = move |addr| for_drive(family, protocol, addr).unwrap();
    let masters = run_through(&a, profile, speeds).await;
    // The drives are at their speed by then.
    let steady = tokio::time::Instant::now() + Duration::from_secs(12);
    let polls: Vec<Drive> = masters.iter().map(Drive::polling_twin).collect();
    let a_poll = tokio::spawn(async move {
        loop {
            for d in &polls {
                let _ = d.status().await;
            }
            tokio::time::sleep(Duration::from_millis(150)).await;
        }
    });
    tokio::time::sleep(late).await;
    let b = Bus::spawn(late_port(&line, clock), cfg(true)).unwrap();
    let started = tokio::time::Instant::now();
    let (statuses, b_poll) = read_statuses(&b, &addresses, profile);
    // Whole: with the values the set-up scales (until then they are unknown, not guessed).
    let whole = |s: &DriveStatus| s.output_hz.is_some() && s.current_a.is_some() && s.setpoint_hz.is_some();
    let served =
        |addr: u8| statuses.lock().unwrap().iter().any(|(a, _, r)| *a == addr && r.as_ref().is_ok_and(whole));
    let took =
        wait_for(Duration::from_secs(40), "every drive's whole status served by the late standby", || {
            addresses.iter().all(|&a| served(a))
        })
        .await;
    println!("{protocol}: a standby started {late:?} after the master served every status after {took:?}");
    let first = statuses.lock().unwrap().iter().find(|(_, _, r)| r.is_ok()).map(|(_, t, _)| *t - started);
    println!("{protocol}: its first status (what it could show) after {first:?}");
    assert!(took < Duration::from_secs(36), "{took:?}");
    // From then on every status read is answered, as the master sees the drive.
    let since = tokio::time::Instant::now();
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(b.role().unwrap().role, Role::Standby);
    assert_eq!(b.stats().transactions, 0, "a standby sends nothing");
    let all: Vec<_> = statuses.lock().unwrap().clone();
    let seen: Vec<_> = all.iter().filter(|(_, t, _)| *t >= since).cloned().collect();
    for (d, &(addr, hz)) in masters.iter().zip(speeds) {
        let truth = d.status().await.unwrap();
        assert!(truth.running && truth.output_hz.is_some_and(|f| (f - hz).abs() < 0.1), "{truth:?}");
        // Before (the drives at their speed): each value the master's or unknown, never another.
        for (_, _, r) in all.iter().filter(|(a, t, _)| *a == addr && *t >= steady) {
            if let Ok(s) = r {
                let fits = |mine: Option<f64>, master: Option<f64>| mine.is_none() || mine == master;
                assert!(
                    s.running == truth.running
                        && s.fault == truth.fault
                        && fits(s.output_hz, truth.output_hz)
                        && fits(s.current_a, truth.current_a)
                        && fits(s.setpoint_hz, truth.setpoint_hz),
                    "drive {addr}: {s:?} against {truth:?}"
                );
            }
        }
        let mine: Vec<_> = seen.iter().filter(|(a, _, _)| *a == addr).collect();
        assert!(mine.len() >= 5, "drive {addr}: {seen:?}");
        for (_, _, r) in mine {
            let s = r.as_ref().unwrap_or_else(|e| panic!("drive {addr}: {e}"));
            assert_eq!(
                (s.running, s.output_hz, s.setpoint_hz, s.current_a, &s.fault),
                (truth.running, truth.output_hz, truth.setpoint_hz, truth.current_a, &truth.fault),
                "drive {addr}: {s:?}"
            );
        }
    }
    // The master sets drive 1 to a new speed: the standby's status shows the new setpoint
    // within two set-up refreshes (its own, which reads the setpoint again where the profile
    // reads it once, and the master's), and never a setpoint other than the two (or unknown,
    // while the standby knows the master commanded one and has not heard which).
    let (addr, old) = speeds[0];
    let new = old - 10.0;
    masters[0].set_speed(new).await.unwrap();
    let changed = tokio::time::Instant::now();
    let latest = |addr: u8| {
        let seen = statuses.lock().unwrap();
        let after = |(a, t, _): &&(u8, tokio::time::Instant, _)| *a == addr && *t > changed;
        seen.iter().rev().filter(after).find_map(|(_, _, r)| r.as_ref().ok().map(|s| s.setpoint_hz))
    };
    let took =
        wait_for(Duration::from_secs(70), "the new setpoint served", || latest(addr) == Some(Some(new)))
            .await;
    println!("{protocol}: the standby showed a setpoint the master commanded after {took:?}");
    for (a, t, r) in statuses.lock().unwrap().iter() {
        if let (true, Ok(s)) = (*a == addr && *t >= since, r) {
            assert!(
                [Some(old), Some(new), None].contains(&s.setpoint_hz) && s.running,
                "drive {addr}: {s:?}"
            );
        }
    }
    a_poll.abort();
    b_poll.abort();
    b
}

#[tokio::test(start_paused = true)]
async fn a_toshiba_ascii_standby_started_late_serves_status_and_learns_inverter_0s_schedule() {
    let b = a_late_standby_serves_every_status_within_the_setup_refresh(
        WireProtocol::ToshibaAscii,
        Family::Toshiba,
        CharFormat::EVEN_8E1,
        &[(0, 40.0), (1, 25.0)],
        Duration::from_secs(3),
    )
    .await;
    // Inverter 0 is a drive of TIP, not a broadcast: its polls are learnt as its schedule.
    let learnt = b.learnt_schedule();
    for addr in [0u8, 1] {
        let every = learnt.get(&addr).copied().unwrap_or_default();
        assert!(
            every >= Duration::from_millis(150) && every < Duration::from_millis(400),
            "drive {addr}: {learnt:?}"
        );
    }
}

#[tokio::test(start_paused = true)]
async fn a_toshiba_binary_standby_started_late_serves_the_block_status() {
    a_late_standby_serves_every_status_within_the_setup_refresh(
        WireProtocol::ToshibaBinary,
        Family::Toshiba,
        CharFormat::EVEN_8E1,
        &[(1, 40.0), (2, 25.0)],
        Duration::from_secs(3),
    )
    .await;
}

#[tokio::test(start_paused = true)]
async fn a_danfoss_standby_started_late_serves_status_and_setpoint() {
    a_late_standby_serves_every_status_within_the_setup_refresh(
        WireProtocol::DanfossFc,
        Family::Danfoss,
        CharFormat::EVEN_8E1,
        &[(1, 40.0), (2, 25.0)],
        Duration::from_secs(3),
    )
    .await;
}

/// A master that is not drivebus polls each drive every 150 ms with `polls`, which never read
/// the set-up values the standby's profile reads once (it was set up otherwise); a standby
/// beside it reads each status through the profile every 40 ms. From its first second on,
/// every status read is answered: what the status word and the process values say as the
/// master's profile sees it, and what needs the set-up unknown (`blank` makes the expected
/// status of the master's).
async fn a_standby_beside_a_master_that_never_reads_the_set_up_shows_what_it_can(
    protocol: WireProtocol,
    family: Family,
    format: CharFormat,
    speeds: &[(u8, f64)],
    polls: fn(u8) -> Vec<Vec<u8>>,
    blank: fn(DriveStatus) -> DriveStatus,
) {
    let addresses: Vec<u8> = speeds.iter().map(|(a, _)| *a).collect();
    let line = line_of(protocol, family, format, &addresses);
    let cfg = |standby| shared_cfg(protocol, format, standby);
    let a_link = SimLink::new(line.clone(), "a");
    let clock = a_link.clock();
    let a = Bus::spawn(a_link, cfg(false)).unwrap();
    let profile = move |addr| for_drive(family, protocol, addr).unwrap();
    // Set up and run through the profile (reading the set-up once, before the standby starts).
    let masters = run_through(&a, profile, speeds).await;
    tokio::time::sleep(Duration::from_secs(15)).await;
    let mut truths = Vec::new();
    for d in &masters {
        truths.push(blank(d.status().await.unwrap()));
    }
    // From now on the master polls only `polls`, and the standby starts.
    let b = Bus::spawn(late_port(&line, clock), cfg(true)).unwrap();
    let a_poll = poll_otherwise(&a, addresses.clone(), polls);
    let (statuses, b_poll) = read_statuses(&b, &addresses, profile);
    let since = tokio::time::Instant::now() + Duration::from_secs(1);
    // Past a set-up refresh of the standby's profiles too.
    tokio::time::sleep(Duration::from_secs(40)).await;
    assert!(!a_poll.is_finished(), "the master's polls are all answered");
    assert_eq!(b.role().unwrap().role, Role::Standby);
    assert_eq!(b.stats().transactions, 0, "a standby sends nothing");
    let seen: Vec<_> = statuses.lock().unwrap().iter().filter(|(_, t, _)| *t >= since).cloned().collect();
    for (&addr, truth) in addresses.iter().zip(&truths) {
        let mine: Vec<_> = seen.iter().filter(|(a, _, _)| *a == addr).collect();
        assert!(mine.len() >= 100, "drive {addr}: {} status reads in 39 s", mine.len());
        for (_, _, r) in mine {
            let s = r.as_ref().unwrap_or_else(|e| panic!("drive {addr}: {e}"));
            assert_eq!(
                (s.running, s.output_hz, s.setpoint_hz, s.current_a, &s.fault),
                (truth.running, truth.output_hz, truth.setpoint_hz, truth.current_a, &truth.fault),
                "drive {addr}: {s:?}"
            );
        }
    }
    a_poll.abort();
    b_poll.abort();
}

#[tokio::test(start_paused = true)]
async fn a_danfoss_standby_beside_a_master_that_never_reads_the_scale_shows_state_and_current() {
    use drivebus_proto::fc::{
        AddressFormat, Adr, ControlWord, ParameterNumber, Reference, Request, MAX_TELEGRAM,
    };
    // 16-14 and a process block: never 3-00, 3-02, 3-03 or 16-02.
    fn polls(addr: u8) -> Vec<Vec<u8>> {
        let adr = Adr::new(addr, AddressFormat::OneTo126).unwrap();
        let mut buf = [0u8; MAX_TELEGRAM];
        let n = Request::read(adr, ParameterNumber::new(1614).unwrap(), 0).emit(&mut buf).unwrap();
        let mut out = vec![buf[..n].to_vec()];
        let n = Request::process(adr, ControlWord(0), Reference(0)).emit(&mut buf).unwrap();
        out.push(buf[..n].to_vec());
        out
    }
    // MAV and 16-02 need the reference scaling: output and setpoint unknown.
    fn blank(s: DriveStatus) -> DriveStatus {
        DriveStatus { output_hz: None, setpoint_hz: None, direction: None, ..s }
    }
    a_standby_beside_a_master_that_never_reads_the_set_up_shows_what_it_can(
        WireProtocol::DanfossFc,
        Family::Danfoss,
        CharFormat::EVEN_8E1,
        &[(1, 40.0), (2, 25.0)],
        polls,
        blank,
    )
    .await;
}

#[tokio::test(start_paused = true)]
async fn a_toshiba_standby_beside_a_master_that_never_reads_fe70_shows_all_but_the_current() {
    use drivebus_proto::toshiba::ascii::{AsciiAddress, AsciiRequest};
    use drivebus_proto::toshiba::CommNo;
    // FD01, FD00, FE02, FE03: never FE70.
    fn polls(addr: u8) -> Vec<Vec<u8>> {
        [0xFD01, 0xFD00, 0xFE02, 0xFE03]
            .into_iter()
            .map(|n| {
                let mut out = [0u8; 32];
                let len = AsciiRequest::read(AsciiAddress::Unit(addr), CommNo(n)).emit(&mut out).unwrap();
                out[..len].to_vec()
            })
            .collect()
    }
    // FE03 is a share of FE70: the current unknown.
    fn blank(s: DriveStatus) -> DriveStatus {
        DriveStatus { current_a: None, ..s }
    }
    a_standby_beside_a_master_that_never_reads_the_set_up_shows_what_it_can(
        WireProtocol::ToshibaAscii,
        Family::Toshiba,
        CharFormat::EVEN_8E1,
        &[(1, 40.0), (2, 25.0)],
        polls,
        blank,
    )
    .await;
}

#[tokio::test(start_paused = true)]
async fn a_standby_learns_the_masters_interval_through_a_burst_and_an_extra_poll() {
    let start = tokio::time::Instant::now();
    let line = line();
    let (a, b) = masters(&line, true);
    let master = a.clone();
    // Drive 1 polled every 400 ms (plus the exchange), but twice within 120 ms at first (a
    // master's first poll held up by its start-up listening, the next one soon after), and once
    // more 120 ms after drive 2 in its fourth round (a retry the standby cannot tell from a poll:
    // another request came between).
    let a_poll = tokio::spawn(async move {
        let poll = |d: u8| master.transact(d, read(d, 0x2102), Priority::Poll, None);
        let _ = poll(1).await;
        tokio::time::sleep(Duration::from_millis(120)).await;
        for round in 0.. {
            let _ = poll(1).await;
            if round == 3 {
                let _ = poll(2).await;
                tokio::time::sleep(Duration::from_millis(120)).await;
                let _ = poll(1).await;
            }
            tokio::time::sleep(Duration::from_millis(400)).await;
        }
    });
    // The first poll goes after a's start-up listening (500 ms), the burst's second at about
    // 620 ms, the rounds about every 400 ms after it: the third at about 1430 ms, the extra
    // poll at about 1970 ms.
    for (at, after) in [(1500, "after the burst"), (2100, "after the extra poll"), (3500, "later")] {
        tokio::time::sleep_until(start + Duration::from_millis(at)).await;
        assert_eq!(a.role().unwrap().role, Role::Master);
        let every = b.learnt_schedule().get(&1).copied();
        assert!(
            every.is_some_and(|e| e >= Duration::from_millis(400) && e < Duration::from_millis(430)),
            "{after}: drive 1 learnt at {every:?}, polled every 400 ms and its exchange"
        );
    }
    a_poll.abort();
}
