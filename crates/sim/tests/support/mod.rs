//! Shared by the line tests: VF-AS1 drives on a 19200 8E1 virtual line, the master's side of
//! an exchange (raw bytes, or a master session of any protocol), and the drives' state, all on
//! simulated time.
#![allow(dead_code)]

use std::time::Duration;

use drivebus_drive::ParamStore;
use drivebus_proto::line::CharFormat;
use drivebus_proto::session::{MasterEvent, MasterSession, Protocol};
use drivebus_proto::Instant;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::family::toshiba::{ToshibaDrive, ToshibaProtocol};
use drivebus_sim::model::DriveModel;

/// A line at the VF-AS1's default 19200 8E1 with one drive set to `protocol` (f829) per
/// address; ports 1, 2, ... in that order.
pub fn toshiba_line(protocol: ToshibaProtocol, addresses: &[u8]) -> VirtualLine {
    let mut line = VirtualLine::new(19200, CharFormat::EVEN_8E1, Instant::ZERO);
    for &a in addresses {
        match ToshibaDrive::new(a, protocol, Instant::ZERO) {
            Ok(d) => {
                line.add_device(Box::new(d));
            }
            Err(e) => panic!("drive {a}: {e}"),
        }
    }
    line
}

/// The master writes `bytes` now; the line runs until nothing is pending; what reached the master.
pub fn exchange(line: &mut VirtualLine, bytes: &[u8]) -> Vec<u8> {
    let now = line.now();
    line.master_write(now, bytes);
    while let Some(t) = line.next_deadline() {
        line.advance_to(t);
    }
    let mut got = Vec::new();
    line.master_read(&mut got);
    got
}

/// Runs `master`, given a request, and the line until the session has an outcome; what `then`
/// makes of it.
pub fn master_outcome<P: Protocol, T>(
    line: &mut VirtualLine,
    master: &mut MasterSession<P>,
    then: impl for<'a> FnOnce(MasterEvent<P::Reply<'a>>) -> T,
) -> T {
    for _ in 0..10_000 {
        let now = line.now();
        if let Some(bytes) = master.poll_transmit(now) {
            let bytes = bytes.to_vec();
            line.master_write(now, &bytes);
        }
        let mut input = Vec::new();
        line.master_read(&mut input);
        master.handle_input(now, &input);
        master.handle_timeout(now);
        if let Some(event) = master.poll_event() {
            return then(event);
        }
        let next = [line.next_deadline(), master.poll_timeout()].into_iter().flatten().min();
        let next = next.expect("something pending").max(now + Duration::from_micros(1));
        line.advance_to(next);
    }
    panic!("the master session never finished");
}

/// Lets `d` of simulated time pass on the line.
pub fn wait(line: &mut VirtualLine, d: Duration) {
    let t = line.now() + d;
    line.advance_to(t);
}

/// The motor model of the drive on `port`.
pub fn model(line: &mut VirtualLine, port: usize) -> &DriveModel {
    &line.drive(port).unwrap_or_else(|| panic!("port {port} holds a drive")).core().model
}

/// The parameter values of the drive on `port`.
pub fn params(line: &mut VirtualLine, port: usize) -> &ParamStore {
    &line.drive(port).unwrap_or_else(|| panic!("port {port} holds a drive")).core().params
}
