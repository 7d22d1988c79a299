//! The Toshiba VF-AS1 profile (`seeds/002_43d8a4399c8be05f.txt`) run to completion against the
//! simulated VF-AS1 on a paced `VirtualLine`, on simulated time, in Modbus-RTU, TIP ASCII and
//! TIP binary.

mod support;

use std::time::Duration;

use drivebus_drive::profile::toshiba::{ToshibaProfile, ToshibaProtocol, TIP_BROADCAST};
use drivebus_drive::profile::{DriveError, DriveStatus, Exchange, Operation, Outcome, Profile, Step};
use drivebus_drive::Storage;
use drivebus_proto::line::CharFormat;
use drivebus_proto::modbus::rtu::ModbusRtu;
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::toshiba::ascii::AsciiCodec;
use drivebus_proto::toshiba::binary::{BinaryAddress, BinaryCodec, BinaryRequest};
use drivebus_proto::toshiba::{CommNo, ErrorCode};
use drivebus_proto::Codec;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::drive::VirtualDrive;
use drivebus_sim::family::toshiba as sim;
use drivebus_sim::model::{Rotation, Trip};
use support::{refusal, write};

const ALL: [WireProtocol; 3] =
    [WireProtocol::ModbusRtu, WireProtocol::ToshibaAscii, WireProtocol::ToshibaBinary];
/// Silence left before each request (the drive needs none in TIP; Modbus t3.5 is 1.75 ms).
const GAP: Duration = Duration::from_millis(5);

/// A line at the VF-AS1's default 19200 8E1 and a bus owner that counts its exchanges.
struct Bus {
    line: VirtualLine,
    protocol: WireProtocol,
    exchanges: usize,
}

impl Bus {
    /// Drives numbered `addresses`, speaking `protocol` (f829 set to match).
    fn new(protocol: WireProtocol, addresses: &[u8]) -> Bus {
        let kind = ToshibaProtocol::of(protocol).unwrap_or_else(|| panic!("the VF-AS1 speaks no {protocol}"));
        let line = support::line_with(19200, CharFormat::EVEN_8E1, addresses, |a, now| {
            sim::ToshibaDrive::new(a, kind, now)
        });
        Bus { line, protocol, exchanges: 0 }
    }

    fn transact(&mut self, x: &Exchange) -> Option<Vec<u8>> {
        self.exchanges += 1;
        match self.protocol {
            WireProtocol::ModbusRtu => transact::<ModbusRtu>(&mut self.line, x),
            WireProtocol::ToshibaAscii => transact::<AsciiCodec>(&mut self.line, x),
            WireProtocol::ToshibaBinary => transact::<BinaryCodec>(&mut self.line, x),
            other => panic!("the VF-AS1 speaks no {other}"),
        }
    }

    /// Runs `op` to completion, as a bus owner would.
    fn run(&mut self, p: &dyn Profile, op: Operation) -> Result<Outcome, DriveError> {
        support::execute(p.plan(&op)?, |x| self.transact(x)).0
    }

    fn ok(&mut self, p: &ToshibaProfile, op: Operation) {
        let what = format!("{op:?} in {}", self.protocol);
        support::done(&what, self.run(p, op));
    }

    fn status(&mut self, p: &ToshibaProfile) -> DriveStatus {
        let what = format!("Status in {}", self.protocol);
        support::status_of(&what, self.run(p, Operation::Status))
    }

    fn read(&mut self, p: &ToshibaProfile, name: &str) -> i64 {
        let what = format!("ReadParam {name} in {}", self.protocol);
        support::param_of(&what, self.run(p, Operation::ReadParam(name.into())))
    }

    fn wait(&mut self, d: Duration) {
        support::wait(&mut self.line, d);
    }

    fn drive(&mut self, port: usize) -> &dyn VirtualDrive {
        support::drive(&mut self.line, port)
    }

    fn drive_mut(&mut self, port: usize) -> &mut dyn VirtualDrive {
        support::drive_mut(&mut self.line, port)
    }

    fn master_bytes(&self) -> u64 {
        self.line.stats().master_bytes
    }
}

/// Puts one request on the line (after the minimum gap) and waits for a whole reply.
fn transact<C: Codec>(line: &mut VirtualLine, x: &Exchange) -> Option<Vec<u8>> {
    support::transact::<C>(line, x, GAP)
}

/// Inverter 1 (Modbus numbers start at 1; TIP has 0 too).
fn profile(protocol: WireProtocol) -> ToshibaProfile {
    ToshibaProfile::new(1, protocol).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn run_and_set_speed_show_running_and_the_output_ramping_in_every_protocol() {
    for protocol in ALL {
        let mut bus = Bus::new(protocol, &[1]);
        let p = profile(protocol);
        assert_eq!(p.protocol(), protocol);
        let s = bus.status(&p);
        assert_eq!(s.address, 1);
        assert!(!s.running, "{protocol}");
        assert_eq!(s.fault, None);
        assert_eq!(s.current_a, Some(0.0));
        // FD01, FD00, FE02, FE03 and, the first time, FE70; in binary mode f875-f879 (once),
        // the X block, FE02 and FE70.
        let first = if protocol == WireProtocol::ToshibaBinary { 8 } else { 5 };
        assert_eq!(bus.exchanges, first, "{protocol}");

        bus.ok(&p, Operation::SetSpeed(40.0));
        bus.ok(&p, Operation::Run);
        bus.wait(Duration::from_secs(2));
        let before = bus.exchanges;
        let s = bus.status(&p);
        let each = if protocol == WireProtocol::ToshibaBinary { 2 } else { 4 };
        assert_eq!(bus.exchanges - before, each, "FE70 and f875-f879 are read once per profile ({protocol})");
        assert!(s.running, "{protocol}");
        assert_eq!(s.direction.as_deref(), Some("forward"));
        assert_eq!(s.setpoint_hz, Some(40.0));
        // ACC = 10.0 s from 0 to FH = 80 Hz: about 16 Hz after 2 s.
        let early = s.output_hz.unwrap_or(0.0);
        assert!(early > 10.0 && early < 22.0, "ramping: {early} Hz ({protocol})");
        let amps = s.current_a.unwrap_or(0.0);
        let model = bus.drive(1).core().model.current_a();
        assert!(amps > 0.0 && (amps - model).abs() < 0.01, "{amps} A against {model} A ({protocol})");
        let fa00 = bus.drive(1).core().params.get("FA00");
        assert_eq!(fa00, Some(0xC400), "command and frequency priority, run ({protocol})");

        bus.wait(Duration::from_secs(10));
        assert_eq!(bus.status(&p).output_hz, Some(40.0));
        bus.ok(&p, Operation::Stop);
        assert_eq!(bus.drive(1).core().params.get("FA00"), Some(0xC000));
        bus.wait(Duration::from_secs(10));
        let s = bus.status(&p);
        assert!(!s.running, "{protocol}");
        assert_eq!(s.output_hz, Some(0.0));
    }
}

/// Binary mode reads status with block communication by default: f875-f879 once, then the X
/// block of the first 3 read groups and FE02 per status (the single reads' result, in 31
/// bytes instead of 56).
#[test]
fn binary_block_status_reads_in_two_exchanges() {
    let mut bus = Bus::new(WireProtocol::ToshibaBinary, &[1]);
    let plain = profile(WireProtocol::ToshibaBinary).with_block_status(false);
    let block = profile(WireProtocol::ToshibaBinary);
    bus.ok(&plain, Operation::SetSpeed(30.0));
    bus.ok(&plain, Operation::Run);
    bus.wait(Duration::from_secs(10));
    let before = bus.exchanges;
    let a = bus.status(&plain);
    assert_eq!(bus.exchanges - before, 5, "FD01, FD00, FE02, FE03, FE70 one by one");
    bus.status(&block); // learns FE70 and f875-f879
    let (before, bytes) = (bus.exchanges, bus.master_bytes());
    let b = bus.status(&block);
    assert_eq!(bus.exchanges - before, 2, "X block read and FE02");
    assert_eq!(bus.master_bytes() - bytes, 6 + 6, "X (6 bytes) and R FE02 (6 bytes) from the master");
    assert_eq!(a, b);
    assert_eq!(b.output_hz, Some(30.0));
    // The block asks for 3 groups (FD01, FD00, FE03): FC90, the 4th item, is read on its own
    // when FD01 says tripped.
    bus.drive_mut(1).core_mut().model.trip_now(Trip::OverCurrent);
    let before = bus.exchanges;
    let f = bus.status(&block).fault.unwrap_or_else(|| panic!("a fault"));
    assert_eq!(bus.exchanges - before, 3, "X, FE02 and FC90");
    assert_eq!((f.code, f.text.as_str()), (0x03, "OC3: over-current during constant speed operation"));
    // Other protocols ignore the option.
    let mut rtu = Bus::new(WireProtocol::ModbusRtu, &[1]);
    rtu.status(&profile(WireProtocol::ModbusRtu).with_block_status(true));
    assert_eq!(rtu.exchanges, 5);
}

/// A drive whose block read items lack one the status needs is read one number per request;
/// a write of f875-f879 through the profile makes it read them again. Without FC90 in the
/// block, a tripped drive costs one more read.
#[test]
fn block_status_follows_the_drives_read_item_selection() {
    let mut bus = Bus::new(WireProtocol::ToshibaBinary, &[1]);
    let p = profile(WireProtocol::ToshibaBinary);
    // f876 = 4: output voltage instead of output frequency.
    bus.ok(&p, write("f876", 4, Storage::Ram));
    bus.status(&p);
    let before = bus.exchanges;
    let s = bus.status(&p);
    assert_eq!(bus.exchanges - before, 4, "FD01, FD00, FE02, FE03: the block lacks FD00");
    assert_eq!(s.output_hz, Some(0.0));
    // FD00 back, FC90 first: the block again (4 groups, FC90 among them), no FC90 read when
    // tripped.
    bus.ok(&p, write("f876", 2, Storage::Ram));
    bus.ok(&p, write("f875", 13, Storage::Ram));
    bus.ok(&p, write("f878", 1, Storage::Ram));
    let before = bus.exchanges;
    bus.status(&p);
    assert_eq!(bus.exchanges - before, 5 + 2, "f875-f879 read again, then X and FE02");
    bus.drive_mut(1).core_mut().model.trip_now(Trip::OverTemperature);
    let (before, bytes) = (bus.exchanges, bus.master_bytes());
    let f = bus.status(&p).fault.unwrap_or_else(|| panic!("a fault"));
    assert_eq!(bus.exchanges - before, 2, "FC90 comes in the block");
    assert_eq!(bus.master_bytes() - bytes, 12);
    assert_eq!(f.code, 0x10);
}

#[test]
fn run_while_tripped_is_refused_with_the_trip_code_and_reset_clears_it() {
    for protocol in ALL {
        let mut bus = Bus::new(protocol, &[1]);
        let p = profile(protocol);
        bus.drive_mut(1).core_mut().model.trip_now(Trip::External);
        let f = bus.status(&p).fault.unwrap_or_else(|| panic!("a fault"));
        assert_eq!((f.code, f.text.as_str()), (0x11, "E: emergency stop"));

        for op in [Operation::Run, Operation::Jog, Operation::Reverse] {
            let (code, meaning) = refusal(bus.run(&p, op));
            assert_eq!(code, 0x11, "{protocol}");
            assert!(meaning.contains("is tripped (E: emergency stop; FD01 bit 1)"), "{meaning}");
        }
        assert_eq!(bus.drive(1).core().params.get("FA00"), Some(0), "no command went out ({protocol})");

        bus.ok(&p, Operation::Reset);
        assert_eq!(bus.status(&p).fault, None, "{protocol}");
        // The fault reset bit is cleared again, so the next reset is a new edge.
        assert_eq!(bus.drive(1).core().params.get("FA00"), Some(0xC000));
        bus.ok(&p, Operation::Run);
        assert!(bus.status(&p).running);
        // Reset of a drive that is not tripped leaves it running.
        bus.ok(&p, Operation::Reset);
        assert!(bus.drive(1).core().model.is_running(), "{protocol}");

        // Under-voltage while running trips UP1; the reset fails while the supply is low.
        bus.drive_mut(1).core_mut().model.set_supply(0.5);
        bus.wait(Duration::from_millis(50));
        let (code, meaning) = refusal(bus.run(&p, Operation::Reset));
        assert_eq!(code, 0x1E, "{protocol}");
        assert_eq!(meaning, "the trip UP1: main circuit under-voltage persists after the fault reset: its cause is still there");
        bus.drive_mut(1).core_mut().model.set_supply(1.0);
        bus.ok(&p, Operation::Reset);
        assert_eq!(bus.status(&p).fault, None);
    }
}

#[test]
fn reverse_turns_a_running_drive_and_jog_runs_at_5_hz() {
    for protocol in ALL {
        let mut bus = Bus::new(protocol, &[1]);
        let p = profile(protocol);
        let r = bus.run(&p, Operation::Reverse);
        assert!(matches!(r, Err(DriveError::Unsupported(ref s)) if s.contains("stopped")), "{r:?}");
        assert_eq!(bus.drive(1).core().params.get("FA00"), Some(0));

        bus.ok(&p, Operation::SetSpeed(20.0));
        bus.ok(&p, Operation::Run);
        bus.wait(Duration::from_secs(5));
        bus.ok(&p, Operation::Reverse);
        assert_eq!(bus.drive(1).core().params.get("FA00"), Some(0xC600), "{protocol}");
        bus.wait(Duration::from_secs(10));
        assert_eq!(bus.drive(1).core().model.output_rotation(), Rotation::Reverse);
        let s = bus.status(&p);
        assert_eq!(s.direction.as_deref(), Some("reverse"));
        assert_eq!(s.output_hz, Some(20.0));
        // Stop keeps the direction bit; Run follows the drive's direction.
        bus.ok(&p, Operation::Stop);
        assert_eq!(bus.drive(1).core().params.get("FA00"), Some(0xC200));
        bus.wait(Duration::from_secs(10));
        bus.ok(&p, Operation::Run);
        assert_eq!(bus.drive(1).core().params.get("FA00"), Some(0xC600));
        bus.ok(&p, Operation::Reverse);
        assert_eq!(bus.status(&p).direction.as_deref(), Some("forward"));

        bus.ok(&p, Operation::Stop);
        bus.wait(Duration::from_secs(10));
        bus.ok(&p, Operation::Jog);
        assert_eq!(bus.drive(1).core().params.get("FA00"), Some(0xC500));
        bus.wait(Duration::from_secs(2));
        assert!(bus.drive(1).core().model.is_jogging());
        assert_eq!(bus.status(&p).output_hz, Some(sim::JOG_HZ));
        bus.ok(&p, Operation::Reverse);
        assert_eq!(bus.drive(1).core().params.get("FA00"), Some(0xC700), "a jog stays a jog");
        bus.ok(&p, Operation::Stop);
        bus.wait(Duration::from_secs(3));
        assert!(!bus.status(&p).running);
    }
}

#[test]
fn set_speed_out_of_range_is_refused_before_any_byte_is_written() {
    let mut bus = Bus::new(WireProtocol::ToshibaAscii, &[1]);
    let p = profile(WireProtocol::ToshibaAscii);
    let before = bus.master_bytes();
    for (hz, sentence) in [
        (60.01, "60.01 Hz is above the upper limit 0012 = 60.00 Hz"),
        (600.0, "600 Hz is above the upper limit 0012 = 60.00 Hz"),
        (-0.5, "-0.5 Hz is below 0: the setpoint is a frequency without sign; Reverse changes the direction"),
        (f64::NAN, "NaN Hz is not a speed"),
    ] {
        assert_eq!(bus.run(&p, Operation::SetSpeed(hz)), Err(DriveError::OutOfRange(sentence.into())));
    }
    assert_eq!(bus.master_bytes(), before, "nothing was written");
    assert_eq!(bus.exchanges, 0);

    bus.ok(&p, write("UL", 5000, Storage::Ram));
    assert_eq!(p.speed_limits(), (8000, 5000));
    assert_eq!(
        bus.run(&p, Operation::SetSpeed(50.5)),
        Err(DriveError::OutOfRange("50.5 Hz is above the upper limit 0012 = 50.00 Hz".into()))
    );
    // FH below UL: the maximum frequency is the limit.
    p.set_speed_limits(4500, 5000);
    assert_eq!(
        bus.run(&p, Operation::SetSpeed(46.0)),
        Err(DriveError::OutOfRange("46 Hz is above the maximum frequency 0011 = 45.00 Hz".into()))
    );
    // Reading the drive's values puts them back.
    assert_eq!(bus.read(&p, "FH"), 8000);
    bus.ok(&p, Operation::SetSpeed(50.0));
    assert_eq!(bus.read(&p, "FA01"), 5000);
}

#[test]
fn parameters_round_trip_with_ram_and_eeprom_as_the_protocol_allows() {
    // TIP: P writes RAM, W writes RAM and EEPROM.
    for protocol in [WireProtocol::ToshibaAscii, WireProtocol::ToshibaBinary] {
        let mut bus = Bus::new(protocol, &[1]);
        let p = profile(protocol);
        assert_eq!(bus.read(&p, "dEC"), 100);
        bus.ok(&p, write("0010", 50, Storage::Ram));
        assert_eq!(bus.read(&p, "0010"), 50);
        assert_eq!(bus.drive(1).core().params.eeprom_writes("0010"), Some(0), "{protocol}");
        bus.ok(&p, write("dEC", 70, Storage::Eeprom));
        assert_eq!(bus.read(&p, "0010"), 70);
        assert_eq!(bus.drive(1).core().params.eeprom_writes("0010"), Some(1), "{protocol}");
        bus.ok(&p, write("f803", 5, Storage::Eeprom));
        assert_eq!(bus.read(&p, "F803"), 5);
        assert_eq!(bus.read(&p, "FE70"), 175);
    }
    // Modbus-RTU: 06 always stores in EEPROM; a RAM-only write is refused before sending.
    let mut bus = Bus::new(WireProtocol::ModbusRtu, &[1]);
    let p = profile(WireProtocol::ModbusRtu);
    let before = bus.master_bytes();
    match bus.run(&p, write("0010", 50, Storage::Ram)) {
        Err(DriveError::Unsupported(s)) => {
            assert!(s.starts_with("Modbus-RTU has no RAM-only write on the VF-AS1"), "{s}");
            assert!(s.contains("P command (f829 = 0)"), "{s}");
        }
        other => panic!("{other:?}"),
    }
    let fa01 = bus.run(&p, write("FA01", 100, Storage::Eeprom));
    assert!(matches!(fa01, Err(DriveError::Unsupported(ref s)) if s.contains("RAM only")), "{fa01:?}");
    let ro = bus.run(&p, write("FD00", 1, Storage::Ram));
    assert_eq!(ro, Err(DriveError::Unsupported("FD00 (Output frequency) is read-only".into())));
    let range = bus.run(&p, write("f804", 3, Storage::Eeprom));
    assert!(
        matches!(range, Err(DriveError::OutOfRange(ref s)) if s.starts_with("f804 is 0..2")),
        "{range:?}"
    );
    let unknown = bus.run(&p, Operation::ReadParam("f999".into()));
    assert!(matches!(unknown, Err(DriveError::Unsupported(_))), "{unknown:?}");
    assert_eq!(bus.master_bytes(), before);
    bus.ok(&p, write("0010", 50, Storage::Eeprom));
    assert_eq!(bus.read(&p, "0010"), 50);
    assert_eq!(bus.drive(1).core().params.eeprom_writes("0010"), Some(1));
    bus.ok(&p, write("FA01", 1234, Storage::Ram));
    assert_eq!(bus.read(&p, "FA01"), 1234);
    assert_eq!(bus.drive(1).core().params.eeprom_writes("FA01"), Some(0));
}

#[test]
fn the_drives_refusals_carry_the_manuals_codes() {
    for protocol in ALL {
        let mut bus = Bus::new(protocol, &[1]);
        let p = profile(protocol);
        // UL above FH: data error (TIP 0001, Modbus 03).
        let (code, meaning) = refusal(bus.run(&p, write("0012", 9000, Storage::Eeprom)));
        match protocol {
            WireProtocol::ModbusRtu => {
                assert_eq!(code, 3);
                assert!(meaning.starts_with("illegal data value: data error"), "{meaning}");
            }
            _ => {
                assert_eq!(code, 1);
                assert!(meaning.starts_with("data error: invalid data"), "{meaning}");
            }
        }
        assert!(meaning.contains("0012 = 90.00 Hz"), "{meaning}");
        // FH while running: impossible to execute (TIP 0000, Modbus 04).
        bus.ok(&p, Operation::Run);
        let (code, meaning) = refusal(bus.run(&p, write("FH", 7000, Storage::Eeprom)));
        let expected = if protocol == WireProtocol::ModbusRtu { 4 } else { 0 };
        assert_eq!(code, expected, "{protocol}");
        assert!(meaning.contains("impossible to execute"), "{meaning}");
        assert_eq!(p.speed_limits(), (8000, 6000), "a refused write teaches nothing");
    }
}

#[test]
fn a_tip_error_reply_and_garbage_are_told_apart() {
    let p = profile(WireProtocol::ToshibaBinary);
    let mut plan = p.plan(&Operation::ReadParam("0010".into())).unwrap_or_else(|e| panic!("{e}"));
    let Ok(Step::Send(x)) = plan.step(None) else { panic!("a request") };
    assert_eq!(x.request, [0x2F, 0x01, 0x52, 0x00, 0x10, 0x92]);
    // 2F 01 4E 00 02 SUM: communication number error.
    let req = BinaryRequest::read(BinaryAddress::Unit(1), CommNo(0x0010));
    let mut out = [0u8; 16];
    let n =
        req.error_reply(1, false, ErrorCode::COMM_NO_ERROR).emit(&mut out).unwrap_or_else(|e| panic!("{e}"));
    let (code, meaning) = refusal(plan.step(Some(&out[..n])).map(|_| Outcome::Done));
    assert_eq!(code, 2);
    assert_eq!(meaning, "communication number error: there is no such communication number (in reply to the read of 0010: ReadParam 0010)");

    let mut plan = p.plan(&Operation::ReadParam("0010".into())).unwrap_or_else(|e| panic!("{e}"));
    let _ = plan.step(None);
    let r = plan.step(Some(&[0x2F, 0x01, 0x52, 0x00, 0x10, 0x00]));
    assert!(
        matches!(r, Err(DriveError::Protocol(ref s)) if s.contains("is not a valid TOSHIBA binary frame")),
        "{r:?}"
    );
    // Another inverter's reply is not this one's.
    let mut plan = p.plan(&Operation::ReadParam("0010".into())).unwrap_or_else(|e| panic!("{e}"));
    let _ = plan.step(None);
    let other = BinaryRequest::read(BinaryAddress::Unit(2), CommNo(0x0010));
    let n = other.reply(2, false, 100).and_then(|r| r.emit(&mut out).ok()).unwrap_or(0);
    let r = plan.step(Some(&out[..n]));
    assert!(matches!(r, Err(DriveError::Protocol(ref s)) if s.contains("inverter number Some(2)")), "{r:?}");
}

#[test]
fn broadcasts_reach_every_drive_and_wait_for_no_reply() {
    for protocol in ALL {
        let mut bus = Bus::new(protocol, &[1, 2]);
        let address = if protocol == WireProtocol::ModbusRtu { 0 } else { TIP_BROADCAST };
        let all = ToshibaProfile::new(address, protocol).unwrap_or_else(|e| panic!("{e}"));
        assert!(all.is_broadcast());
        bus.ok(&all, Operation::SetSpeed(30.0));
        bus.ok(&all, Operation::Run);
        let storage = if protocol == WireProtocol::ModbusRtu { Storage::Eeprom } else { Storage::Ram };
        bus.ok(&all, write("ACC", 50, storage));
        bus.wait(Duration::from_secs(10));
        for port in [1, 2] {
            let m = &bus.drive(port).core().model;
            assert!(m.is_running(), "drive {port} in {protocol}");
            assert_eq!(m.output_hz(), 30.0);
            assert_eq!(bus.drive(port).core().params.get("0009"), Some(50));
        }
        bus.ok(&all, Operation::Stop);
        bus.wait(Duration::from_secs(10));
        for port in [1, 2] {
            assert!(!bus.drive(port).core().model.is_running(), "drive {port} in {protocol}");
        }
        for op in [
            Operation::Status,
            Operation::Jog,
            Operation::Reverse,
            Operation::Reset,
            Operation::ReadParam("ACC".into()),
        ] {
            assert!(matches!(all.plan(&op), Err(DriveError::Unsupported(_))), "{op:?} in {protocol}");
        }
        assert_eq!(bus.line.stats().collisions, 0);
        // Each drive still answers its own number.
        let two = ToshibaProfile::new(2, protocol).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(bus.read(&two, "ACC"), 50);
    }
}

#[test]
fn inverter_numbers_are_checked_per_protocol() {
    let refused =
        |a: u8, p: WireProtocol| matches!(ToshibaProfile::new(a, p), Err(DriveError::OutOfRange(_)));
    assert!(refused(248, WireProtocol::ModbusRtu));
    assert!(refused(255, WireProtocol::ModbusRtu));
    assert!(refused(100, WireProtocol::ToshibaAscii));
    assert!(refused(64, WireProtocol::ToshibaBinary));
    assert!(!refused(0, WireProtocol::ToshibaBinary));
    assert!(!refused(99, WireProtocol::ToshibaAscii));
    assert!(!refused(247, WireProtocol::ModbusRtu));
    assert_eq!(
        ToshibaProfile::new(64, WireProtocol::ToshibaBinary).err(),
        Some(DriveError::OutOfRange(
            "a VF-AS1 speaking toshiba-binary has inverter number 0..63, or 255 for a broadcast; not 64"
                .into()
        ))
    );
    assert_eq!(
        ToshibaProfile::new(1, WireProtocol::DanfossFc).err(),
        Some(DriveError::Unsupported(
            "the VF-AS1 speaks toshiba-ascii, toshiba-binary or modbus-rtu, not danfoss-fc".into()
        ))
    );
    assert_eq!(ToshibaProtocol::of(WireProtocol::ToshibaBinary), Some(ToshibaProtocol::Tip));
    assert_eq!(ToshibaProtocol::from_f829(1), ToshibaProtocol::ModbusRtu);
    // TIP inverter 0 is a drive, not a broadcast.
    let mut bus = Bus::new(WireProtocol::ToshibaAscii, &[0]);
    let zero = ToshibaProfile::new(0, WireProtocol::ToshibaAscii).unwrap_or_else(|e| panic!("{e}"));
    assert!(!zero.is_broadcast());
    assert_eq!(bus.read(&zero, "FE70"), 175);
}

/// After `refresh_setup` the next status reads FE70 again (and f875–f879 in binary mode with
/// block status), so that a standby listening learns them; the one after is as before. Prints
/// what a refresh adds on the wire (requests and replies).
#[test]
fn a_refresh_reads_the_set_up_values_once_more() {
    for protocol in ALL {
        let mut bus = Bus::new(protocol, &[1]);
        let p = profile(protocol);
        bus.status(&p);
        let plain = |bus: &mut Bus, p: &ToshibaProfile| {
            let (x, bytes) = (bus.exchanges, bus.line.stats().master_bytes + bus.line.stats().device_bytes);
            let s = bus.status(p);
            (s, bus.exchanges - x, bus.line.stats().master_bytes + bus.line.stats().device_bytes - bytes)
        };
        let (before, each, each_bytes) = plain(&mut bus, &p);
        p.refresh_setup();
        let (refreshed, with_refresh, refresh_bytes) = plain(&mut bus, &p);
        let extra = if protocol == WireProtocol::ToshibaBinary { 6 } else { 1 };
        assert_eq!(with_refresh - each, extra, "FE70 (and f875-f879) read again ({protocol})");
        assert_eq!(refreshed, before, "{protocol}");
        assert_eq!(plain(&mut bus, &p).1, each, "once ({protocol})");
        println!("{protocol}: a refresh adds {} bytes on the wire", refresh_bytes - each_bytes);
    }
}
