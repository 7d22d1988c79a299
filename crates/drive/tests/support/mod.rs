//! Shared by the profile tests: simulated drives on a paced virtual line, and a plan run to its
//! end against them as a bus owner would, on simulated time.
#![allow(dead_code)]

use std::time::Duration;

use drivebus_drive::profile::{
    run_blocking, DriveError, DriveStatus, Exchange, Operation, Outcome, Plan, Profile,
};
use drivebus_drive::Storage;
use drivebus_proto::deframe::Scanner;
use drivebus_proto::line::CharFormat;
use drivebus_proto::{Codec, Direction, Instant};
use drivebus_sim::bus::{Device, VirtualLine};
use drivebus_sim::drive::VirtualDrive;
use drivebus_sim::master::LineMaster;
use drivebus_sim::model::DriveModel;

/// The most exchanges a plan may take before the test calls it endless.
pub const MAX_EXCHANGES: usize = 32;

/// A line at `baud` and `format` with one drive per address that `new` builds; ports 1, 2, ...
/// in that order.
pub fn line_with<D: Device + Send + 'static>(
    baud: u32,
    format: CharFormat,
    addresses: &[u8],
    new: impl Fn(u8, Instant) -> Result<D, String>,
) -> VirtualLine {
    let mut line = VirtualLine::new(baud, format, Instant::ZERO);
    for &a in addresses {
        match new(a, Instant::ZERO) {
            Ok(d) => {
                line.add_device(Box::new(d));
            }
            Err(e) => panic!("drive {a}: {e}"),
        }
    }
    line
}

/// How long [`transact`] waits for a reply.
pub const RESPONSE_TIMEOUT: Duration = Duration::from_millis(500);
/// How long [`transact`] waits after a broadcast.
pub const TURNAROUND: Duration = Duration::from_millis(100);

/// Puts one request on the line after `gap` of silence and waits until codec `C`'s deframer
/// has a whole reply; `None` after a broadcast or when nothing came in time.
pub fn transact<C: Codec>(line: &mut VirtualLine, x: &Exchange, gap: Duration) -> Option<Vec<u8>> {
    let master = LineMaster {
        gap_before: gap,
        gap_after: Duration::ZERO,
        timeout: RESPONSE_TIMEOUT,
        turnaround: TURNAROUND,
    };
    master.transact(line, C::scanner(Some(Direction::Drive)), &x.request, x.expect_reply)
}

/// Runs `plan` to its end, `transact` putting each request on the line and giving the reply;
/// the outcome and the requests sent.
pub fn execute(
    mut plan: Box<dyn Plan>,
    mut transact: impl FnMut(&Exchange) -> Option<Vec<u8>>,
) -> (Result<Outcome, DriveError>, Vec<Vec<u8>>) {
    let mut sent = Vec::new();
    let outcome = run_blocking(&mut *plan, |x| {
        assert!(sent.len() < MAX_EXCHANGES, "a plan that does not end");
        let reply = transact(&x);
        sent.push(x.request);
        Ok::<_, DriveError>(reply)
    });
    (outcome, sent)
}

/// Writes `request` at once and runs the line until `scanner` has a whole reply (or `timeout`
/// passed), then `chars_after` characters of silence; a request without a reply waits
/// `turnaround`.
pub fn transact_frame<S: Scanner>(
    line: &mut VirtualLine,
    scanner: S,
    request: &[u8],
    expect_reply: bool,
    (chars_after, timeout, turnaround): (u32, Duration, Duration),
) -> Option<Vec<u8>> {
    let master = LineMaster {
        gap_before: Duration::ZERO,
        gap_after: line.char_time() * chars_after,
        timeout,
        turnaround,
    };
    master.transact(line, scanner, request, expect_reply)
}

/// Plans `op` on `profile` and runs the plan with `execute`, expecting success; the outcome and
/// what `execute` tells of the requests sent.
pub fn run_ok<T>(
    profile: &dyn Profile,
    op: Operation,
    execute: impl FnOnce(Box<dyn Plan>) -> (Result<Outcome, DriveError>, T),
) -> (Outcome, T) {
    let plan = profile.plan(&op).unwrap_or_else(|e| panic!("{op:?}: {e}"));
    match execute(plan) {
        (Ok(outcome), sent) => (outcome, sent),
        (Err(e), _) => panic!("{op:?}: {e}"),
    }
}

/// That an operation (`what`) ended done; panics on anything else.
pub fn done(what: &str, r: Result<Outcome, DriveError>) {
    match r {
        Ok(Outcome::Done) => {}
        other => panic!("{what}: {other:?}"),
    }
}

/// The drive's state a Status (`what`) ended with; panics on anything else.
pub fn status_of(what: &str, r: Result<Outcome, DriveError>) -> DriveStatus {
    match r {
        Ok(Outcome::Status(s)) => s,
        other => panic!("{what}: a status, not {other:?}"),
    }
}

/// The raw value a ReadParam (`what`) ended with; panics on anything else.
pub fn param_of(what: &str, r: Result<Outcome, DriveError>) -> i64 {
    match r {
        Ok(Outcome::Param(raw)) => raw,
        other => panic!("{what}: a value, not {other:?}"),
    }
}

/// The motor model of the drive on `port`.
pub fn model(line: &mut VirtualLine, port: usize) -> &DriveModel {
    &drive(line, port).core().model
}

/// The motor model of the drive on `port`, mutable.
pub fn model_mut(line: &mut VirtualLine, port: usize) -> &mut DriveModel {
    &mut drive_mut(line, port).core_mut().model
}

/// Lets `d` of simulated time pass on the line.
pub fn wait(line: &mut VirtualLine, d: Duration) {
    let end = line.now() + d;
    line.run_until(end);
}

/// The drive on `port`.
pub fn drive(line: &mut VirtualLine, port: usize) -> &dyn VirtualDrive {
    line.drive(port).unwrap_or_else(|| panic!("port {port} holds a drive"))
}

/// The drive on `port`, mutable.
pub fn drive_mut(line: &mut VirtualLine, port: usize) -> &mut dyn VirtualDrive {
    line.drive_mut(port).unwrap_or_else(|| panic!("port {port} holds a drive"))
}

/// WriteParam `name` = `raw` into `storage`.
pub fn write(name: &str, raw: i64, storage: Storage) -> Operation {
    Operation::WriteParam { name: name.into(), raw, storage }
}

/// The code and meaning of a refusal; panics on anything else.
pub fn refusal(r: Result<Outcome, DriveError>) -> (u32, String) {
    match r {
        Err(DriveError::Refused { code, meaning, .. }) => (code, meaning),
        other => panic!("expected a refusal, got {other:?}"),
    }
}
