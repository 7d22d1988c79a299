//! The generic VFD profile (`seeds/004_e8ea1998fe1a671e.txt`) run to completion against the
//! simulated generic drive on a paced `VirtualLine`, on simulated time, in Modbus RTU and ASCII.

mod support;

use std::time::Duration;

use drivebus_drive::profile::generic::{GenericProfile, GenericProtocol};
use drivebus_drive::profile::{DriveError, DriveStatus, Exchange, Operation, Outcome, Profile, Step};
use drivebus_drive::Storage;
use drivebus_proto::modbus::ascii::ModbusAscii;
use drivebus_proto::modbus::rtu::ModbusRtu;
use drivebus_proto::Codec;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::family::generic as sim;
use drivebus_sim::model::{Rotation, RunState, Trip};
use support::{drive, drive_mut, refusal, wait};

const BAUD: u32 = 9600;
/// The silence seed 004 asks for between frames ("保持无输入信号大于等于 10ms").
const GAP: Duration = Duration::from_millis(10);

/// A line in the protocol's default format with simulated drives at `addresses`.
fn line_with(protocol: sim::GenericProtocol, addresses: &[u8]) -> VirtualLine {
    let format = drivebus_drive::Family::Generic.serial_default(protocol.wire()).1;
    support::line_with(BAUD, format, addresses, |a, now| sim::GenericDrive::new(a, protocol, now))
}

fn profile(address: u8, protocol: GenericProtocol) -> GenericProfile {
    GenericProfile::new(address, protocol).unwrap_or_else(|e| panic!("{e}"))
}

/// Puts one request on the line (after the minimum gap) and waits for a whole reply.
fn transact<C: Codec>(line: &mut VirtualLine, x: &Exchange) -> Option<Vec<u8>> {
    support::transact::<C>(line, x, GAP)
}

/// Runs `op` to completion, as a bus owner would.
fn run<C: Codec>(line: &mut VirtualLine, p: &dyn Profile, op: Operation) -> Result<Outcome, DriveError> {
    support::execute(p.plan(&op)?, |x| transact::<C>(line, x)).0
}

fn rtu(line: &mut VirtualLine, p: &GenericProfile, op: Operation) -> Result<Outcome, DriveError> {
    run::<ModbusRtu>(line, p, op)
}

fn ok(line: &mut VirtualLine, p: &GenericProfile, op: Operation) {
    let what = format!("{op:?}");
    support::done(&what, rtu(line, p, op));
}

fn status(line: &mut VirtualLine, p: &GenericProfile) -> DriveStatus {
    support::status_of("Status", rtu(line, p, Operation::Status))
}

fn read(line: &mut VirtualLine, p: &GenericProfile, name: &str) -> i64 {
    support::param_of(&format!("ReadParam {name}"), rtu(line, p, Operation::ReadParam(name.into())))
}

fn write(name: &str, raw: i64) -> Operation {
    support::write(name, raw, Storage::Eeprom)
}

fn refused_code(r: Result<Outcome, DriveError>) -> u32 {
    let (code, meaning) = refusal(r);
    assert!(!meaning.is_empty());
    code
}

#[test]
fn run_and_set_speed_show_running_and_the_output_ramping() {
    let mut line = line_with(sim::GenericProtocol::Rtu, &[1]);
    let p = profile(1, GenericProtocol::Rtu);
    assert_eq!(p.protocol(), drivebus_proto::protocol::WireProtocol::ModbusRtu);
    let s = status(&mut line, &p);
    assert_eq!(s.address, 1);
    assert!(!s.running);
    assert_eq!(s.output_hz, Some(0.0));
    assert_eq!(s.fault, None);

    ok(&mut line, &p, Operation::SetSpeed(40.0));
    ok(&mut line, &p, Operation::Run);
    wait(&mut line, Duration::from_secs(2));
    let s = status(&mut line, &p);
    assert!(s.running);
    assert_eq!(s.direction.as_deref(), Some("forward"));
    assert_eq!(s.setpoint_hz, Some(40.0));
    let early = s.output_hz.unwrap_or(0.0);
    // P0.07 = 10.0 s from 0 to P0.04 = 50 Hz: about 10 Hz after 2 s.
    assert!(early > 5.0 && early < 15.0, "ramping: {early} Hz");
    assert!(s.current_a.unwrap_or(0.0) > 0.0);
    wait(&mut line, Duration::from_secs(10));
    let s = status(&mut line, &p);
    assert_eq!(s.output_hz, Some(40.0));

    ok(&mut line, &p, Operation::Stop);
    wait(&mut line, Duration::from_secs(10));
    let s = status(&mut line, &p);
    assert!(!s.running);
    assert_eq!(s.output_hz, Some(0.0));
}

#[test]
fn modbus_ascii_runs_the_same_operations() {
    let mut line = line_with(sim::GenericProtocol::Ascii, &[7]);
    let p = profile(7, GenericProtocol::Ascii);
    assert_eq!(p.protocol(), drivebus_proto::protocol::WireProtocol::ModbusAscii);
    let go = |line: &mut VirtualLine, op: Operation| run::<ModbusAscii>(line, &p, op);
    assert_eq!(go(&mut line, Operation::SetSpeed(25.5)), Ok(Outcome::Done));
    assert_eq!(go(&mut line, Operation::Run), Ok(Outcome::Done));
    wait(&mut line, Duration::from_secs(10));
    match go(&mut line, Operation::Status) {
        Ok(Outcome::Status(s)) => {
            assert!(s.running);
            assert_eq!(s.address, 7);
            assert_eq!(s.setpoint_hz, Some(25.5));
            assert_eq!(s.output_hz, Some(25.5));
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(go(&mut line, write("P0.08", 55)), Ok(Outcome::Done));
    assert_eq!(go(&mut line, Operation::ReadParam("P0.08".into())), Ok(Outcome::Param(55)));
    assert_eq!(go(&mut line, Operation::ReadParam("2102H".into())), Ok(Outcome::Param(2550)));
    assert_eq!(go(&mut line, Operation::Stop), Ok(Outcome::Done));
    // A run command the drive cannot obey: 03 in ASCII too.
    drive_mut(&mut line, 1).core_mut().model.trip_now(Trip::External);
    assert_eq!(refused_code(go(&mut line, Operation::Run)), 3);
}

#[test]
fn run_while_tripped_is_refused_with_03_and_reset_clears_the_fault() {
    let mut line = line_with(sim::GenericProtocol::Rtu, &[1]);
    let p = profile(1, GenericProtocol::Rtu);
    drive_mut(&mut line, 1).core_mut().model.trip_now(Trip::External);
    let s = status(&mut line, &p);
    let fault = s.fault.unwrap_or_else(|| panic!("a fault"));
    assert_eq!(fault.code, 5);
    assert_eq!(fault.text, "external fault");

    match rtu(&mut line, &p, Operation::Run) {
        Err(DriveError::Refused { code, meaning, .. }) => {
            assert_eq!(code, 3);
            assert!(meaning.starts_with("data content error (资料内容错误。资料内容超限)"), "{meaning}");
            assert!(meaning.contains("06 write of 0001H to 2000H"), "{meaning}");
        }
        other => panic!("{other:?}"),
    }
    assert!(matches!(drive(&mut line, 1).core().model.state(), RunState::Tripped(Trip::External)));
    ok(&mut line, &p, Operation::Reset);
    assert_eq!(status(&mut line, &p).fault, None);
    ok(&mut line, &p, Operation::Run);
    assert!(status(&mut line, &p).running);

    // A fault whose cause persists cannot be reset: 03.
    drive_mut(&mut line, 1).core_mut().model.set_supply(0.5);
    wait(&mut line, Duration::from_millis(50));
    let s = status(&mut line, &p);
    assert_eq!(s.fault.map(|f| (f.code, f.text)), Some((3, "under-voltage".to_string())));
    assert_eq!(refused_code(rtu(&mut line, &p, Operation::Reset)), 3);
}

#[test]
fn reverse_turns_a_running_drive_and_jog_runs_at_the_jog_frequency() {
    let mut line = line_with(sim::GenericProtocol::Rtu, &[1]);
    let p = profile(1, GenericProtocol::Rtu);
    // Stopped: no command sets the direction without starting the motor.
    let before = line.stats().master_bytes;
    match rtu(&mut line, &p, Operation::Reverse) {
        Err(DriveError::Unsupported(s)) => assert!(s.contains("the drive is stopped"), "{s}"),
        other => panic!("{other:?}"),
    }
    // Only the status read went out (8 bytes), no command.
    assert_eq!(line.stats().master_bytes - before, 8);
    assert!(!drive(&mut line, 1).core().model.is_running());

    ok(&mut line, &p, Operation::SetSpeed(20.0));
    ok(&mut line, &p, Operation::Run);
    wait(&mut line, Duration::from_secs(5));
    ok(&mut line, &p, Operation::Reverse);
    assert_eq!(drive(&mut line, 1).core().model.rotation(), Rotation::Reverse);
    let s = status(&mut line, &p);
    assert_eq!(s.direction.as_deref(), Some("reverse"));
    assert!(s.running);
    wait(&mut line, Duration::from_secs(10));
    assert_eq!(drive(&mut line, 1).core().model.output_rotation(), Rotation::Reverse);
    assert_eq!(status(&mut line, &p).output_hz, Some(20.0));
    // And back.
    ok(&mut line, &p, Operation::Reverse);
    assert_eq!(status(&mut line, &p).direction.as_deref(), Some("forward"));

    // Jog: P1.05 = 5.00 Hz, in the commanded direction.
    ok(&mut line, &p, Operation::Stop);
    wait(&mut line, Duration::from_secs(10));
    ok(&mut line, &p, Operation::Jog);
    wait(&mut line, Duration::from_secs(3));
    assert!(drive(&mut line, 1).core().model.is_jogging());
    let s = status(&mut line, &p);
    assert!(s.running);
    assert_eq!(s.output_hz, Some(5.0));
    // Reverse of a jog keeps jogging.
    ok(&mut line, &p, Operation::Reverse);
    assert!(drive(&mut line, 1).core().model.is_jogging());
    assert_eq!(drive(&mut line, 1).core().model.rotation(), Rotation::Reverse);
    ok(&mut line, &p, Operation::Stop);
    wait(&mut line, Duration::from_secs(5));
    assert!(!status(&mut line, &p).running);
}

#[test]
fn set_speed_out_of_range_is_refused_before_any_byte_is_written() {
    let mut line = line_with(sim::GenericProtocol::Rtu, &[1]);
    let p = profile(1, GenericProtocol::Rtu);
    let before = line.stats().master_bytes;
    for (hz, sentence) in [
        (50.01, "50.01 Hz is above the upper limit P0.05 = 50.00 Hz"),
        (500.0, "500 Hz is above the upper limit P0.05 = 50.00 Hz"),
        (-1.0, "-1 Hz is below 0: the setpoint is a frequency without sign; Reverse changes the direction"),
        (f64::INFINITY, "inf Hz is not a speed"),
    ] {
        assert_eq!(rtu(&mut line, &p, Operation::SetSpeed(hz)), Err(DriveError::OutOfRange(sentence.into())));
    }
    assert_eq!(line.stats().master_bytes, before, "nothing was written");

    // The profile learns the limits it reads and writes.
    ok(&mut line, &p, write("P0.05", 4000));
    assert_eq!(p.speed_limits(), (5000, 4000));
    assert_eq!(
        rtu(&mut line, &p, Operation::SetSpeed(40.5)),
        Err(DriveError::OutOfRange("40.5 Hz is above the upper limit P0.05 = 40.00 Hz".into()))
    );
    ok(&mut line, &p, Operation::SetSpeed(40.0));
    // Another master raised P0.04 and P0.05; a read through the profile learns them.
    let params = &mut drive_mut(&mut line, 1).core_mut().params;
    params.force("P0.04", 0, 6000).unwrap_or_else(|e| panic!("{e}"));
    params.force("P0.05", 0, 6000).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(read(&mut line, &p, "P0.04"), 6000);
    assert_eq!(read(&mut line, &p, "P0.05"), 6000);
    ok(&mut line, &p, Operation::SetSpeed(60.0));
    assert_eq!(read(&mut line, &p, "2001H"), 6000);
    assert_eq!(
        rtu(&mut line, &p, Operation::SetSpeed(60.01)),
        Err(DriveError::OutOfRange("60.01 Hz is above the upper limit P0.05 = 60.00 Hz".into()))
    );
}

#[test]
fn parameters_round_trip_by_the_manuals_names() {
    let mut line = line_with(sim::GenericProtocol::Rtu, &[1]);
    let p = profile(1, GenericProtocol::Rtu);
    assert_eq!(read(&mut line, &p, "P0.07"), 100);
    ok(&mut line, &p, write("P0.07", 50));
    assert_eq!(read(&mut line, &p, "p0.07"), 50);
    assert_eq!(drive(&mut line, 1).core().params.eeprom_writes("P0.07"), Some(1));
    assert_eq!(drive(&mut line, 1).core().model.settings().accel, Duration::from_secs(5));
    // 2001H is a RAM register: written with Storage::Ram (the default of WriteParam).
    let op = Operation::WriteParam { name: "2001H".into(), raw: 1234, storage: Storage::Ram };
    ok(&mut line, &p, op);
    assert_eq!(read(&mut line, &p, "0x2001"), 1234);
    assert_eq!(read(&mut line, &p, "2102H"), 1234);
    assert_eq!(p.param("P0.07").map(|d| d.title.as_str()), Ok("Acceleration time 1"));

    // Refused before anything is sent: unknown names, read-only, storage, range.
    let before = line.stats().master_bytes;
    let unknown = rtu(&mut line, &p, Operation::ReadParam("P9.99".into()));
    assert!(matches!(unknown, Err(DriveError::Unsupported(ref s)) if s.contains("\"P9.99\"")), "{unknown:?}");
    let ro = rtu(&mut line, &p, write("2103H", 1));
    assert_eq!(ro, Err(DriveError::Unsupported("2103H (Output frequency) is read-only".into())));
    let ram =
        rtu(&mut line, &p, Operation::WriteParam { name: "P0.07".into(), raw: 70, storage: Storage::Ram });
    assert!(matches!(ram, Err(DriveError::Unsupported(ref s)) if s.contains("no RAM-only write")), "{ram:?}");
    let range = rtu(&mut line, &p, write("P0.03", 3));
    assert_eq!(range, Err(DriveError::OutOfRange("P0.03 is 0..2, 3 is out of range".into())));
    assert_eq!(line.stats().master_bytes, before);

    // Refused by the drive: P0.04 while running, P0.02 above the maximum frequency.
    ok(&mut line, &p, Operation::Run);
    assert_eq!(refused_code(rtu(&mut line, &p, write("P0.04", 6000))), 3);
    assert_eq!(refused_code(rtu(&mut line, &p, write("P0.02", 6000))), 3);
    assert_eq!(read(&mut line, &p, "P0.04"), 5000);
}

#[test]
fn a_broadcast_reaches_every_drive_and_waits_for_no_reply() {
    let mut line = line_with(sim::GenericProtocol::Rtu, &[1, 2]);
    let all = profile(0, GenericProtocol::Rtu);
    assert_eq!(all.address(), 0);
    let mut plan = all.plan(&Operation::Run).unwrap_or_else(|e| panic!("{e}"));
    match plan.step(None) {
        Ok(Step::Send(x)) => assert!(!x.expect_reply),
        other => panic!("{other:?}"),
    }
    assert_eq!(plan.step(None), Ok(Step::Done(Outcome::Done)));

    ok(&mut line, &all, Operation::SetSpeed(30.0));
    ok(&mut line, &all, Operation::Run);
    wait(&mut line, Duration::from_secs(10));
    for port in [1, 2] {
        assert!(drive(&mut line, port).core().model.is_running(), "drive {port}");
        assert_eq!(drive(&mut line, port).core().model.output_hz(), 30.0);
    }
    ok(&mut line, &all, write("P0.08", 20));
    ok(&mut line, &all, Operation::Stop);
    wait(&mut line, Duration::from_secs(5));
    for port in [1, 2] {
        assert!(!drive(&mut line, port).core().model.is_running(), "drive {port}");
        assert_eq!(drive(&mut line, port).core().params.get("P0.08"), Some(20));
    }
    // Nothing that needs an answer goes to address 0.
    for op in [Operation::Status, Operation::Reverse, Operation::ReadParam("P0.08".into())] {
        assert!(matches!(all.plan(&op), Err(DriveError::Unsupported(_))), "{op:?}");
    }
    // Each drive still answers its own address.
    let two = profile(2, GenericProtocol::Rtu);
    assert_eq!(read(&mut line, &two, "P0.08"), 20);
    assert_eq!(line.stats().collisions, 0);
}

#[test]
fn a_silent_drive_is_a_protocol_error_not_a_hang() {
    let mut line = line_with(sim::GenericProtocol::Rtu, &[1]);
    line.set_silent(1, true);
    let p = profile(1, GenericProtocol::Rtu);
    let r = rtu(&mut line, &p, Operation::Status);
    assert_eq!(r, Err(DriveError::Protocol("no reply came to the 03 read of 2100H..2103H".into())));
}
