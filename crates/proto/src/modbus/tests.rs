//! Test vectors of protocols.md 5.4 (TM1–TM8) and 5.6 (M1–M16), the seed-004 examples of
//! protocols.md 3.5 with their diagnoses, scanners, and sessions on a virtual clock.

extern crate std;

use std::format;
use std::string::{String, ToString};
use std::vec;
use std::vec::Vec;

use core::time::Duration;

use super::ascii::{self, AsciiScanner, ModbusAscii};
use super::pdu::{function, DeviceObject, ExceptionCode, ReadDeviceIdCode, MAX_PDU};
use super::rtu::{self, Accept, ModbusRtu, RtuScanner};
use super::*;
use crate::codec::Codec;
use crate::deframe::{Deframer, Event, Scan, Scanner};
use crate::describe::{Describe, Direction, Target};
use crate::error::{EmitError, FrameError, MismatchHint};
use crate::line::CharFormat;
use crate::session::{Incoming, MasterEvent, MasterSession, SlaveSession};
use crate::time::Instant;

/// "01 03 FD 00" -> bytes.
fn h(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
}

/// An ASCII frame with CR LF appended.
fn a(s: &str) -> Vec<u8> {
    let mut v = s.as_bytes().to_vec();
    v.extend_from_slice(b"\r\n");
    v
}

#[derive(Debug, PartialEq)]
enum Ev {
    Frame(Vec<u8>),
    Rejected(Vec<u8>, String),
}

fn deframe<S: Scanner>(scanner: S, chunks: &[&[u8]], finish: bool) -> Vec<Ev> {
    let mut d = Deframer::new(scanner);
    let mut out = Vec::new();
    let mut on = |e: Event<'_>| match e {
        Event::Frame { bytes, .. } => out.push(Ev::Frame(bytes.to_vec())),
        Event::Rejected { bytes, error, .. } => out.push(Ev::Rejected(bytes.to_vec(), error.to_string())),
    };
    for c in chunks {
        d.push(c, &mut on);
    }
    if finish {
        d.finish(&mut on);
    }
    out
}

/// The events up to and including the first rejection. `Deframer::silence` (called by
/// `finish`) reports the unscanned tail of a candidate that already failed its CRC once more;
/// the lead is asked to make it silent, and these tests do not depend on either behaviour.
fn first(mut evs: Vec<Ev>) -> Vec<Ev> {
    if let Some(i) = evs.iter().position(|e| matches!(e, Ev::Rejected(..))) {
        evs.truncate(i + 1);
    }
    evs
}

fn fields<D: Describe>(d: &D) -> Vec<String> {
    let mut v = Vec::new();
    d.fields(&mut |f| v.push(f.to_string()));
    v
}

fn rtu_req(bytes: &[u8]) -> Request<'_> {
    Request::parse_rtu(bytes).unwrap()
}

fn rtu_rep(bytes: &[u8]) -> Reply<'_> {
    Reply::parse_rtu(bytes).unwrap()
}

/// The bytes `emit` (RTU or ASCII, request or reply) writes for `frame`.
fn emitted<T>(frame: &T, emit: fn(&T, &mut [u8]) -> Result<usize, EmitError>) -> Vec<u8> {
    let mut buf = [0u8; 513];
    let n = emit(frame, &mut buf).unwrap();
    buf[..n].to_vec()
}

fn err<T: core::fmt::Debug>(r: Result<T, FrameError>) -> String {
    r.unwrap_err().to_string()
}

// ---------------------------------------------------------------------------------------------
// protocols.md 5.4: Toshiba Modbus-RTU (seed 002 and the VF-S15 manual)

#[test]
fn tm1_read_fd00() {
    // 01     inverter number 1
    // 03     read command
    // FD 00  communication number FD00 (output frequency)
    // 00 01  number of data groups: 1 (fixed on VF-AS1)
    // B5 A6  CRC, low byte first
    let f = h("01 03 FD 00 00 01 B5 A6");
    let r = rtu_req(&f);
    assert_eq!(
        r,
        Request {
            unit: UnitId(1),
            pdu: RequestPdu::ReadHoldingRegisters { start: RegisterAddress(0xFD00), quantity: 1 }
        }
    );
    assert_eq!(emitted(&r, Request::emit_rtu), f);
    assert_eq!(r.command().to_string(), "03 read holding registers");
    assert_eq!(r.target(), Target::Unit(1));
    assert_eq!(fields(&r), ["starting address FD00 (output frequency (Toshiba))", "quantity 1"]);
    assert_eq!(r.pending(), Some(Pending { unit: UnitId(1), function: 0x03 }));
}

#[test]
fn tm2_reply_60_hz() {
    // 01     inverter number 1
    // 03     read command
    // 02     number of data bytes: 2
    // 17 70  read data 0x1770 = 6000 = 60.00 Hz (FD00 is in 0.01 Hz)
    // B6 50  CRC
    let f = h("01 03 02 17 70 B6 50");
    let r = rtu_rep(&f);
    let ReplyPdu::ReadHoldingRegisters { values } = r.pdu else { panic!("{r:?}") };
    assert_eq!(values.iter().collect::<Vec<_>>(), [0x1770]);
    assert_eq!(emitted(&r, Reply::emit_rtu), f);
    assert_eq!(fields(&r), ["byte count 2", "register value 1770"]);
    assert!(Pending { unit: UnitId(1), function: 3 }.matches(&r));
    assert!(!Pending { unit: UnitId(2), function: 3 }.matches(&r));
    assert!(!Pending { unit: UnitId(1), function: 6 }.matches(&r));
}

#[test]
fn tm3_read_two_words() {
    // 01 03 FD00, number of data groups 00 02 (not allowed on VF-AS1, fine for the codec), CRC F5 A7
    let f = h("01 03 FD 00 00 02 F5 A7");
    let r = rtu_req(&f);
    assert_eq!(r.pdu, RequestPdu::ReadHoldingRegisters { start: RegisterAddress(0xFD00), quantity: 2 });
    assert_eq!(emitted(&r, Request::emit_rtu), f);
}

#[test]
fn tm4_exception_03() {
    // 01     inverter number 1
    // 83     03 + 80: read command error
    // 03     error code 03: illegal data value (the count 2 of TM3)
    // 01 31  CRC
    let f = h("01 83 03 01 31");
    let r = rtu_rep(&f);
    assert_eq!(r.pdu, ReplyPdu::Exception { function: 0x03, code: ExceptionCode::ILLEGAL_DATA_VALUE });
    assert!(r.is_refusal());
    assert_eq!(r.command().to_string(), "83 exception to read holding registers");
    assert_eq!(fields(&r), ["exception code 03 (illegal data value)"]);
    assert!(Pending { unit: UnitId(1), function: 3 }.matches(&r));
    assert_eq!(emitted(&Reply::exception(UnitId(1), 0x03, ExceptionCode(3)), Reply::emit_rtu), f);
    // A request scanner does not take it; a reply scanner and a monitor do.
    assert_eq!(
        ModbusRtu::parse(&f, Some(Direction::Master)).unwrap_err(),
        FrameError::Malformed("a function code with the 0x80 bit set is an exception reply, not a request")
    );
    assert!(matches!(ModbusRtu::parse(&f, None), Ok(Frame::Reply(_))));
}

#[test]
fn tm5_write_fa01_echoed() {
    // 01     inverter number 1
    // 06     write command
    // FA 01  communication number FA01 (frequency command from communication, 0.01 Hz)
    // 17 70  data 6000 = 60.00 Hz
    // E6 C6  CRC; the reply is identical
    let f = h("01 06 FA 01 17 70 E6 C6");
    let q = rtu_req(&f);
    assert_eq!(q.pdu, RequestPdu::WriteSingleRegister { address: RegisterAddress(0xFA01), value: 0x1770 });
    let r = rtu_rep(&f);
    assert_eq!(r.pdu, ReplyPdu::WriteSingleRegister { address: RegisterAddress(0xFA01), value: 0x1770 });
    assert_eq!(emitted(&q, Request::emit_rtu), f);
    assert_eq!(emitted(&r, Reply::emit_rtu), f);
    assert_eq!(
        fields(&q),
        [
            "register address FA01 (frequency command from communication (Toshiba))",
            "register value 1770 = 60.00 Hz"
        ]
    );
}

#[test]
fn tm6_write_missing_comm_no() {
    // 01 06 FFFF 0000 CRC 89 EE: write to communication number FFFF, which does not exist
    // 01 86 02 C3 A1: 06 + 80, error code 02 illegal data address
    let q = h("01 06 FF FF 00 00 89 EE");
    let r = h("01 86 02 C3 A1");
    assert_eq!(
        rtu_req(&q).pdu,
        RequestPdu::WriteSingleRegister { address: RegisterAddress(0xFFFF), value: 0 }
    );
    let rep = rtu_rep(&r);
    assert_eq!(rep.pdu, ReplyPdu::Exception { function: 0x06, code: ExceptionCode::ILLEGAL_DATA_ADDRESS });
    assert_eq!(fields(&rep), ["exception code 02 (illegal data address)"]);
    assert!(rtu_req(&q).pending().unwrap().matches(&rep));
}

const TM8: &str = "01 2B 0E 01 01 00 00 03 00 07 54 4F 53 48 49 42 41 01 0C 56 46 53 31 35 2D 32 30 33 37 50 4D 02 04 30 31 30 30 13 45";

#[test]
fn tm7_read_device_identification() {
    // 01     inverter number 1
    // 2B     encapsulated interface transport
    // 0E     MEI type: read device identification
    // 01     read device ID code: basic (stream)
    // 00     object id 00 (VendorName), the first to read
    // 70 77  CRC
    let f = h("01 2B 0E 01 00 70 77");
    let r = rtu_req(&f);
    assert_eq!(r.pdu, RequestPdu::ReadDeviceIdentification { code: ReadDeviceIdCode::BASIC, object_id: 0 });
    assert_eq!(emitted(&r, Request::emit_rtu), f);
    assert_eq!(r.command().to_string(), "2B read device identification");
    assert_eq!(
        fields(&r),
        [
            "MEI type 0E (read device identification)",
            "read device ID code 01 (basic device identification (stream))",
            "object ID 00 (VendorName)"
        ]
    );
}

#[test]
fn tm8_device_identification_reply() {
    // 01 2B 0E        unit 1, function 2B, MEI type 0E
    // 01              read device ID code: basic
    // 01              conformity level 01: basic, stream only
    // 00              more follows: no
    // 00              next object id
    // 03              number of objects
    // 00 07 "TOSHIBA"          object 00 VendorName, 7 bytes
    // 01 0C "VFS15-2037PM"     object 01 ProductCode, 12 bytes
    // 02 04 "0100"             object 02 MajorMinorRevision, 4 bytes
    // 13 45           CRC
    let f = h(TM8);
    let r = rtu_rep(&f);
    let ReplyPdu::ReadDeviceIdentification(id) = r.pdu else { panic!("{r:?}") };
    assert_eq!(id.code, ReadDeviceIdCode::BASIC);
    assert_eq!(id.conformity_level, 1);
    assert!(!id.more_follows);
    assert_eq!(id.next_object_id, 0);
    let objs: Vec<(u8, Vec<u8>)> = id.objects.iter().map(|o| (o.id, o.value.iter().collect())).collect();
    assert_eq!(objs, [(0, b"TOSHIBA".to_vec()), (1, b"VFS15-2037PM".to_vec()), (2, b"0100".to_vec())]);
    assert_eq!(emitted(&r, Reply::emit_rtu), f);
    // Built from a list, it is the same frame.
    let list = [
        DeviceObject::new(0, b"TOSHIBA"),
        DeviceObject::new(1, b"VFS15-2037PM"),
        DeviceObject::new(2, b"0100"),
    ];
    let built = Reply {
        unit: UnitId(1),
        pdu: ReplyPdu::ReadDeviceIdentification(DeviceIdReply {
            code: ReadDeviceIdCode::BASIC,
            conformity_level: 1,
            more_follows: false,
            next_object_id: 0,
            objects: DeviceObjects::from_list(&list),
        }),
    };
    assert_eq!(emitted(&built, Reply::emit_rtu), f);
    assert_eq!(built, r);
    let fs = fields(&r);
    assert_eq!(fs[2], "conformity level 01 (basic identification, stream access only)");
    assert_eq!(fs[6], "object ID 00 (VendorName)");
    assert_eq!(fs[8], "object value \"TOSHIBA\"");
    assert_eq!(fs[11], "object value \"VFS15-2037PM\"");
    assert_eq!(fs[14], "object value \"0100\"");
    // The reply scanner walks the object list to find its end.
    assert_eq!(RtuScanner::replies().scan(&f, 0), Scan::Frame { len: f.len() });
    assert_eq!(RtuScanner::either().scan(&f, 0), Scan::Frame { len: f.len() });
    for cut in 2..f.len() {
        assert_eq!(RtuScanner::replies().scan(&f[..cut], 0), Scan::Incomplete { checked: 0 }, "cut {cut}");
    }
}

#[test]
fn tm8_object_list_errors() {
    // Three objects announced, the last one cut: truncated, counted in frame bytes.
    let mut body = h(TM8);
    body.truncate(body.len() - 2);
    let cut = &body[..body.len() - 1];
    let mut f = cut.to_vec();
    f.extend_from_slice(&crate::checksum::crc16_modbus(cut).to_le_bytes());
    assert_eq!(err(Reply::parse_rtu(&f)), "truncated frame: 2B/0E reply needs 39 bytes, got 38");
    // more follows must be 00 or FF
    let mut g = h(TM8);
    g[4 + 1] = 0x12;
    let n = g.len() - 2;
    let crc = crate::checksum::crc16_modbus(&g[..n]).to_le_bytes();
    g[n..].copy_from_slice(&crc);
    assert_eq!(err(Reply::parse_rtu(&g)), "more follows must be 00 or FF");
}

// ---------------------------------------------------------------------------------------------
// protocols.md 5.6: generic Modbus and seed 004

#[test]
fn m1_spec_example() {
    // 11     slave 17
    // 03     read holding registers
    // 00 6B  starting address 006B
    // 00 03  quantity 3
    // 76 87  CRC
    let f = h("11 03 00 6B 00 03 76 87");
    let r = rtu_req(&f);
    assert_eq!(r.unit, UnitId(17));
    assert_eq!(r.pdu, RequestPdu::ReadHoldingRegisters { start: RegisterAddress(0x006B), quantity: 3 });
    assert_eq!(emitted(&r, Request::emit_rtu), f);
}

#[test]
fn m3_ascii_write() {
    // :        start
    // 01       address 1
    // 06       write single register
    // 0405     register 0405
    // 1234     value 1234
    // AA       LRC: -(01+06+04+05+12+34) = -0x56 = AA
    // CR LF
    let f = a(":010604051234AA");
    let r = Request::parse_ascii(&f).unwrap();
    assert_eq!(r.unit, UnitId(1));
    assert_eq!(r.pdu, RequestPdu::WriteSingleRegister { address: RegisterAddress(0x0405), value: 0x1234 });
    assert_eq!(emitted(&r, Request::emit_ascii), f);
    assert_eq!(AsciiScanner.scan(&f, 0), Scan::Frame { len: f.len() });
}

#[test]
fn m4_ascii_read_two_from_2102() {
    // : 01 03 | 2102 starting address (set frequency) | 0002 quantity | D7 LRC (sum 0x29) | CR LF
    let f = a(":010321020002D7");
    let r = Request::parse_ascii(&f).unwrap();
    assert_eq!(r.pdu, RequestPdu::ReadHoldingRegisters { start: RegisterAddress(0x2102), quantity: 2 });
    assert_eq!(emitted(&r, Request::emit_ascii), f);
    assert_eq!(fields(&r), ["starting address 2102 (set frequency (generic VFD))", "quantity 2"]);
}

#[test]
fn m5_ascii_read_one_from_0401() {
    // : 01 03 | 0401 | 0001 | F6 LRC | CR LF
    let f = a(":010304010001F6");
    let r = Request::parse_ascii(&f).unwrap();
    assert_eq!(r.pdu, RequestPdu::ReadHoldingRegisters { start: RegisterAddress(0x0401), quantity: 1 });
    assert_eq!(emitted(&r, Request::emit_ascii), f);
}

#[test]
fn m8_seed_rtu_read_crc_over_four_bytes() {
    // seed 004 prints the read of 2104H as 01 03 21 04 00 (..) E8 4B.
    // 01 03 21 04 00 E8 4B: seven bytes where a 03 request is eight, and E8 4B is the CRC of
    // 01 03 21 04 only. The stream ends (or the line goes silent) after it.
    let f = h("01 03 21 04 00 E8 4B");
    let want =
        "truncated frame: 03 request, whose CRC is that of its first 4 bytes only, needs 8 bytes, got 7";
    let evs = deframe(RtuScanner::requests(), &[&f], true);
    assert_eq!(evs, [Ev::Rejected(f.clone(), want.into())]);
    // The monitor says the same.
    let evs = deframe(RtuScanner::either(), &[&f], true);
    assert_eq!(evs, [Ev::Rejected(f.clone(), want.into())]);
    assert_eq!(RtuScanner::requests().truncated(&f).to_string(), want);
    // With the missing quantity byte 01 the frame is eight bytes and the CRC still wrong.
    let f8 = h("01 03 21 04 00 01 E8 4B");
    let evs = first(deframe(RtuScanner::requests(), &[&f8], true));
    assert_eq!(
        evs,
        [Ev::Rejected(
            f8.clone(),
            "CRC mismatch: frame carries E8 4B, computed CF F7 (the carried CRC is that of the first 4 bytes only)"
                .into()
        )]
    );
    assert_eq!(
        rtu::mismatch(&f8),
        FrameError::ChecksumMismatch {
            kind: crate::error::ChecksumKind::Crc16,
            carried: 0x4BE8,
            computed: 0xF7CF,
            hint: Some(MismatchHint::PrefixOnly { len: 4 }),
        }
    );
    // The correct frame.
    let good = h("01 03 21 04 00 01 CF F7");
    assert_eq!(
        rtu_req(&good).pdu,
        RequestPdu::ReadHoldingRegisters { start: RegisterAddress(0x2104), quantity: 1 }
    );
    assert_eq!(fields(&rtu_req(&good))[0], "starting address 2104 (output current (generic VFD))");
}

#[test]
fn m9_seed_rtu_read_reply_is_the_request_echoed() {
    // 01 03 21 04 00 00 0E 37: the CRC is right for these six bytes.
    let f = h("01 03 21 04 00 00 0E 37");
    // From the master: a 03 request for quantity 0.
    assert_eq!(err(ModbusRtu::parse(&f, Some(Direction::Master))), "quantity 0 is not allowed (1..125)");
    assert_eq!(deframe(RtuScanner::requests(), &[&f], false), [Ev::Frame(f.clone())]);
    // From the drive: a reply reading wants byte count 0x21 = 33 bytes of data, so the
    // scanner waits; the silence after it (or the end of the stream) makes it a whole frame,
    // which is not a 03 reply.
    let want = "not a valid 03 reply: it has the layout of a 03 request (starting address, quantity) \
                where a reply has a byte count and register values";
    assert_eq!(err(ModbusRtu::parse(&f, Some(Direction::Drive))), want);
    assert_eq!(deframe(RtuScanner::replies(), &[&f], false), []);
    assert_eq!(deframe(RtuScanner::replies(), &[&f], true), [Ev::Frame(f.clone())]);
    // A monitor takes it as a request (8 bytes) and reports the request reading's error.
    assert_eq!(deframe(RtuScanner::either(), &[&f], false), [Ev::Frame(f.clone())]);
    assert_eq!(err(ModbusRtu::parse(&f, None)), "quantity 0 is not allowed (1..125)");
    // A correct reply for value 0000.
    let good = h("01 03 02 00 00 B8 44");
    assert_eq!(rtu_rep(&good).pdu, ReplyPdu::ReadHoldingRegisters { values: Registers::from_values(&[0]) });
}

#[test]
fn m12_seed_rtu_write_p0_02() {
    // 01     address 1
    // 06     write single register
    // 00 02  register 0002 = parameter P0.02
    // 13 88  5000 = 50.00 Hz (0.01 Hz)
    // 25 5C  CRC; the reply is identical
    let f = h("01 06 00 02 13 88 25 5C");
    let q = rtu_req(&f);
    assert_eq!(q.pdu, RequestPdu::WriteSingleRegister { address: RegisterAddress(2), value: 5000 });
    assert_eq!(rtu_rep(&f).pdu, ReplyPdu::WriteSingleRegister { address: RegisterAddress(2), value: 5000 });
    assert_eq!(emitted(&q, Request::emit_rtu), f);
    // The seed prints the request with address 00H: the CRC 25 5C is that of address 01.
    let seed = h("00 06 00 02 13 88 25 5C");
    let want = "CRC mismatch: frame carries 25 5C, computed 24 8D \
                (the carried CRC is right for the same frame sent to address 1)";
    assert_eq!(deframe(RtuScanner::requests(), &[&seed], false), [Ev::Rejected(seed.clone(), want.into())]);
    assert_eq!(
        first(deframe(RtuScanner::either(), &[&seed], true)),
        [Ev::Rejected(seed.clone(), want.into())]
    );
    assert_eq!(err(Request::parse_rtu(&seed)), want);
    // With address 00 and its own CRC it is a broadcast: executed, never answered.
    let bc = h("00 06 00 02 13 88 24 8D");
    let r = rtu_req(&bc);
    assert_eq!(r.target(), Target::Broadcast);
    assert_eq!(r.pending(), None);
    assert_eq!(r.disposition(1), crate::session::Disposition::Broadcast { reply: false });
}

#[test]
fn m14_seed_ascii_write_p0_02() {
    // : 01 06 | 0002 register P0.02 | 1388 = 5000 = 50.00 Hz | 5C LRC | CR LF, both directions
    let f = a(":0106000213885C");
    let q = Request::parse_ascii(&f).unwrap();
    assert_eq!(q.pdu, RequestPdu::WriteSingleRegister { address: RegisterAddress(2), value: 5000 });
    let r = Reply::parse_ascii(&f).unwrap();
    assert_eq!(r.pdu, ReplyPdu::WriteSingleRegister { address: RegisterAddress(2), value: 5000 });
    assert_eq!(emitted(&q, Request::emit_ascii), f);
    assert_eq!(emitted(&r, Reply::emit_ascii), f);
}

#[test]
fn m15_seed_rtu_loop_back() {
    // 01     address 1
    // 08     diagnostics (seed 004: communication loop test)
    // 01 02  sub-function 0102 (not standard; the drive echoes any)
    // 03 04  data
    // 41 04  CRC; the reply is identical
    let f = h("01 08 01 02 03 04 41 04");
    let q = rtu_req(&f);
    assert_eq!(q.pdu, RequestPdu::Diagnostics { sub_function: 0x0102, data: Data::binary(&[3, 4]) });
    let r = rtu_rep(&f);
    assert_eq!(r.pdu, ReplyPdu::Diagnostics { sub_function: 0x0102, data: Data::binary(&[3, 4]) });
    assert_eq!(emitted(&q, Request::emit_rtu), f);
    assert_eq!(emitted(&r, Reply::emit_rtu), f);
    assert_eq!(
        fields(&q),
        [
            "sub-function 0102 (not a standard sub-function (seed 004's loop-back test echoes any))",
            "data 03 04"
        ]
    );
    assert!(q.pending().unwrap().matches(&r));
}

#[test]
fn m16_seed_ascii_loop_back() {
    // : 01 08 | 0102 sub-function | 0304 data | ED LRC | CR LF, both directions
    let f = a(":010801020304ED");
    let q = Request::parse_ascii(&f).unwrap();
    assert_eq!(q.pdu, RequestPdu::Diagnostics { sub_function: 0x0102, data: Data::binary(&[3, 4]) });
    assert_eq!(emitted(&q, Request::emit_ascii), f);
    assert_eq!(fields(&q)[1], "data 03 04");
    let r = Reply::parse_ascii(&f).unwrap();
    assert_eq!(emitted(&r, Reply::emit_ascii), f);
}

#[test]
fn seed_ascii_read_2104() {
    // seed 004 prints the ASCII read of 2104H as ": 01 03 2104 00 D7" CR LF (a digit pair is
    // lost): five bytes where a 03 request is six; the LRC D7 fits 01 03 21 04 00 00, that is
    // quantity 0000, which is not allowed.
    let f = a(":0103210400D7");
    assert_eq!(AsciiScanner.scan(&f, 0), Scan::Frame { len: f.len() });
    let want =
        "truncated frame: 03 request (the LRC would match quantity 0000, but quantity 0 is not allowed) \
                needs 6 bytes, got 5";
    assert_eq!(err(ModbusAscii::parse(&f, Some(Direction::Master))), want);
    assert_eq!(err(ModbusAscii::parse(&f, None)), want);
    // The seed's reply is the same text: not a valid 03 reply.
    assert_eq!(
        err(ModbusAscii::parse(&f, Some(Direction::Drive))),
        "byte count 33 does not match the frame, which implies 2"
    );
    // With quantity 0000 the LRC matches, and quantity 0 is refused.
    assert_eq!(err(Request::parse_ascii(&a(":010321040000D7"))), "quantity 0 is not allowed (1..125)");
    // For quantity 0001 the LRC is D6; the correct reply for value 0000 is :0103020000FA.
    let good_f = a(":010321040001D6");
    let good = Request::parse_ascii(&good_f).unwrap();
    assert_eq!(good.pdu, RequestPdu::ReadHoldingRegisters { start: RegisterAddress(0x2104), quantity: 1 });
    let rep_f = a(":0103020000FA");
    let rep = Reply::parse_ascii(&rep_f).unwrap();
    assert_eq!(rep.pdu, ReplyPdu::ReadHoldingRegisters { values: Registers::from_values(&[0]) });
}

#[test]
fn seed_examples_through_the_codecs() {
    // Every seed-004 example of protocols.md 3.5 as `drivebus decode` sees it: a deframer for
    // the direction, the stream ended after the frame, then the codec's parse.
    fn decode<C: Codec>(bytes: &[u8], from: Direction) -> String {
        let mut d = Deframer::new(C::scanner(Some(from)));
        let mut out = String::new();
        let mut on = |e: Event<'_>| match e {
            // Only the first report (see `first`).
            _ if !out.is_empty() => {}
            Event::Frame { bytes, .. } => match C::parse(bytes, Some(from)) {
                Ok(f) => out.push_str(&format!("ok {}", f.command())),
                Err(e) => out.push_str(&format!("error {e}")),
            },
            Event::Rejected { error, .. } => out.push_str(&format!("rejected {error}")),
        };
        d.push(bytes, &mut on);
        d.finish(&mut on);
        out
    }
    use Direction::{Drive, Master};
    let cases: &[(&str, bool, Direction, &str)] = &[
        (":0103210400D7", true, Master, "error truncated frame: 03 request (the LRC would match quantity 0000, but quantity 0 is not allowed) needs 6 bytes, got 5"),
        (":0103210400D7", true, Drive, "error byte count 33 does not match the frame, which implies 2"),
        ("01 03 21 04 00 E8 4B", false, Master, "rejected truncated frame: 03 request, whose CRC is that of its first 4 bytes only, needs 8 bytes, got 7"),
        ("01 03 21 04 00 00 0E 37", false, Master, "error quantity 0 is not allowed (1..125)"),
        ("01 03 21 04 00 00 0E 37", false, Drive, "error not a valid 03 reply: it has the layout of a 03 request (starting address, quantity) where a reply has a byte count and register values"),
        (":0106000213885C", true, Master, "ok 06 write single register"),
        (":0106000213885C", true, Drive, "ok 06 write single register"),
        ("00 06 00 02 13 88 25 5C", false, Master, "rejected CRC mismatch: frame carries 25 5C, computed 24 8D (the carried CRC is right for the same frame sent to address 1)"),
        ("01 06 00 02 13 88 25 5C", false, Drive, "ok 06 write single register"),
        (":010801020304ED", true, Master, "ok 08 diagnostics"),
        (":010801020304ED", true, Drive, "ok 08 diagnostics"),
        ("01 08 01 02 03 04 41 04", false, Master, "ok 08 diagnostics"),
        ("01 08 01 02 03 04 41 04", false, Drive, "ok 08 diagnostics"),
    ];
    for &(frame, is_ascii, from, want) in cases {
        let got = if is_ascii {
            decode::<ModbusAscii>(&a(frame), from)
        } else {
            decode::<ModbusRtu>(&h(frame), from)
        };
        assert_eq!(got, want, "{frame} from {from:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// PDU validation

#[test]
fn quantity_limits() {
    let req = |q: u16| {
        let mut f = vec![1, 3, 0, 0];
        f.extend_from_slice(&q.to_be_bytes());
        let crc = crate::checksum::crc16_modbus(&f).to_le_bytes();
        f.extend_from_slice(&crc);
        f
    };
    assert_eq!(err(Request::parse_rtu(&req(0))), "quantity 0 is not allowed (1..125)");
    assert_eq!(err(Request::parse_rtu(&req(126))), "quantity 126 is not allowed (1..125)");
    assert!(Request::parse_rtu(&req(125)).is_ok());
    assert!(Request::parse_rtu(&req(1)).is_ok());
    // Emitting refuses them too.
    let r = Request {
        unit: UnitId(1),
        pdu: RequestPdu::ReadInputRegisters { start: RegisterAddress(0), quantity: 0 },
    };
    assert_eq!(
        r.emit_rtu(&mut [0; 16]),
        Err(EmitError::OutOfRange { field: "quantity", value: 0, min: 1, max: 125 })
    );
}

#[test]
fn write_multiple_registers() {
    // 01 10 | 2000 start | 0002 quantity | 04 byte count | 0001 0BB8 values | CRC
    let values = [0x0001, 0x0BB8];
    let q = Request {
        unit: UnitId(1),
        pdu: RequestPdu::WriteMultipleRegisters {
            start: RegisterAddress(0x2000),
            values: Registers::from_values(&values),
        },
    };
    let f = emitted(&q, Request::emit_rtu);
    assert_eq!(&f[..11], &h("01 10 20 00 00 02 04 00 01 0B B8")[..]);
    assert_eq!(rtu_req(&f), q);
    assert_eq!(RtuScanner::requests().scan(&f, 0), Scan::Frame { len: 13 });
    assert_eq!(
        fields(&q),
        [
            "starting address 2000 (command (generic VFD: 1 run, 2 fwd, 3 rev, 4 jog, 7 decel stop, 8 e-stop, A reset))",
            "quantity 2",
            "byte count 4",
            "register value 0001",
            "register value 0BB8 = 30.00 Hz",
        ]
    );
    let rep = Reply {
        unit: UnitId(1),
        pdu: ReplyPdu::WriteMultipleRegisters { start: RegisterAddress(0x2000), quantity: 2 },
    };
    let rf = emitted(&rep, Reply::emit_rtu);
    assert_eq!(rf.len(), 8);
    assert_eq!(rtu_rep(&rf), rep);
    assert!(q.pending().unwrap().matches(&rep));
    // byte count must be twice the quantity
    let mut bad = f[..11].to_vec();
    bad[6] = 3;
    bad.truncate(10);
    let crc = crate::checksum::crc16_modbus(&bad).to_le_bytes();
    bad.extend_from_slice(&crc);
    assert_eq!(err(Request::parse_rtu(&bad)), "byte count 3 does not match the frame, which implies 4");
    // quantity 1..123
    let pdu = [0x10, 0, 0, 0, 124, 248];
    assert_eq!(err(RequestPdu::parse(&pdu)), "quantity 124 is not allowed (1..123)");
    let too_many = [0u16; 124];
    let big = Request {
        unit: UnitId(1),
        pdu: RequestPdu::WriteMultipleRegisters {
            start: RegisterAddress(0),
            values: Registers::from_values(&too_many),
        },
    };
    assert!(big.emit_rtu(&mut [0; 300]).is_err());
}

#[test]
fn read_reply_validation() {
    // byte count odd
    assert_eq!(err(ReplyPdu::parse(&[0x03, 3, 1, 2, 3])), "odd byte count: a register is 2 bytes");
    // byte count against the data
    assert_eq!(
        err(ReplyPdu::parse(&[0x03, 4, 1, 2])),
        "byte count 4 does not match the frame, which implies 2"
    );
    // byte count 0
    assert_eq!(err(ReplyPdu::parse(&[0x04, 0])), "byte count 0 is not allowed (2..250)");
    assert_eq!(
        ReplyPdu::parse(&[0x04, 2, 0x12, 0x34]).unwrap(),
        ReplyPdu::ReadInputRegisters { values: Registers::from_be_bytes(&[0x12, 0x34]) }
    );
}

#[test]
fn exception_codes_have_meanings() {
    let want = [
        (0x01, "illegal function"),
        (0x02, "illegal data address"),
        (0x03, "illegal data value"),
        (0x04, "server device failure"),
        (0x05, "acknowledge"),
        (0x06, "server device busy"),
        (0x08, "memory parity error"),
        (0x0A, "gateway path unavailable"),
        (0x0B, "gateway target device failed to respond"),
    ];
    for (code, meaning) in want {
        assert_eq!(ExceptionCode(code).meaning(), Some(meaning));
        let f = emitted(&Reply::exception(UnitId(5), 0x06, ExceptionCode(code)), Reply::emit_rtu);
        let r = rtu_rep(&f);
        assert_eq!(fields(&r), [format!("exception code {code:02X} ({meaning})")]);
    }
    // 07 has a meaning but no constant.
    assert_eq!(ExceptionCode(0x07).meaning(), Some("negative acknowledge"));
    assert_eq!(ExceptionCode(0x42).meaning(), None);
    assert_eq!(
        (ExceptionCode::ILLEGAL_FUNCTION, ExceptionCode::GATEWAY_TARGET_FAILED),
        (ExceptionCode(1), ExceptionCode(0x0B))
    );
    assert_eq!(
        ExceptionCode::for_error(&FrameError::Unknown { field: "function code", value: 0x41 }),
        ExceptionCode::ILLEGAL_FUNCTION
    );
    assert_eq!(
        ExceptionCode::for_error(&FrameError::OutOfRange { field: "quantity", value: 0, min: 1, max: 125 }),
        ExceptionCode::ILLEGAL_DATA_VALUE
    );
}

#[test]
fn other_function_codes_are_framed() {
    // 01 read coils: 8-byte request, reply with a byte count; parsed as Other.
    let q = emitted(
        &Request {
            unit: UnitId(1),
            pdu: RequestPdu::Other { function: 0x01, data: Data::binary(&[0, 0x13, 0, 0x25]) },
        },
        Request::emit_rtu,
    );
    assert_eq!(RtuScanner::requests().scan(&q, 0), Scan::Frame { len: 8 });
    assert_eq!(rtu_req(&q).pdu, RequestPdu::Other { function: 1, data: Data::binary(&[0, 0x13, 0, 0x25]) });
    assert_eq!(rtu_req(&q).command().to_string(), "01 read coils");
    let r = emitted(
        &Reply {
            unit: UnitId(1),
            pdu: ReplyPdu::Other { function: 0x01, data: Data::binary(&[3, 0xCD, 0x6B, 0x05]) },
        },
        Reply::emit_rtu,
    );
    assert_eq!(RtuScanner::replies().scan(&r, 0), Scan::Frame { len: 8 });
    // Unknown codes are rejected at once, one byte skipped.
    let junk = h("01 41 00 00 00 00 00 00");
    match RtuScanner::requests().scan(&junk, 0) {
        Scan::Invalid { len: 2, skip: 1, error } => {
            assert_eq!(error.to_string(), "unknown function code 0x41")
        }
        s => panic!("{s:?}"),
    }
    match RtuScanner::either().scan(&junk, 0) {
        Scan::Invalid { skip: 1, error, .. } => assert_eq!(error.to_string(), "unknown function code 0x41"),
        s => panic!("{s:?}"),
    }
    assert_eq!(err(RequestPdu::parse(&[0x2B, 0x0D, 0])), "unknown MEI type 0x0D");
}

// ---------------------------------------------------------------------------------------------
// RTU scanner

#[test]
fn rtu_monitor_hears_both_directions() {
    let stream: Vec<Vec<u8>> = [
        "01 03 FD 00 00 01 B5 A6",
        "01 03 02 17 70 B6 50",
        "01 03 FD 00 00 02 F5 A7",
        "01 83 03 01 31",
        "01 06 FA 01 17 70 E6 C6",
        "01 06 FA 01 17 70 E6 C6",
        "01 06 FF FF 00 00 89 EE",
        "01 86 02 C3 A1",
        "01 2B 0E 01 00 70 77",
        TM8,
        "01 08 01 02 03 04 41 04",
        "01 08 01 02 03 04 41 04",
        "11 03 00 6B 00 03 76 87",
    ]
    .iter()
    .map(|s| h(s))
    .collect();
    let all: Vec<u8> = stream.concat();
    let want: Vec<Ev> = stream.iter().map(|f| Ev::Frame(f.clone())).collect();
    assert_eq!(deframe(RtuScanner::either(), &[&all], true), want);
    // Any split gives the same frames.
    for i in 0..all.len() {
        assert_eq!(deframe(RtuScanner::either(), &[&all[..i], &all[i..]], true), want, "split at {i}");
    }
    let chunks: Vec<&[u8]> = all.chunks(1).collect();
    assert_eq!(deframe(RtuScanner::either(), &chunks, true), want);
}

#[test]
fn rtu_resync_after_garbage_and_bad_crc() {
    let good = h("01 03 FD 00 00 01 B5 A6");
    let mut bad = good.clone();
    bad[7] ^= 0xFF;
    let mut s = h("FF 00 FF");
    s.extend_from_slice(&bad);
    s.extend_from_slice(&good);
    let evs = deframe(RtuScanner::requests(), &[&s], true);
    assert_eq!(evs.last(), Some(&Ev::Frame(good.clone())));
    assert_eq!(evs.iter().filter(|e| matches!(e, Ev::Frame(_))).count(), 1);
    let mut d = Deframer::new(RtuScanner::requests());
    d.push(&s, &mut |_| {});
    assert_eq!(d.stats().frames, 1);
    assert!(d.stats().checksum_failures >= 1);
}

#[test]
fn rtu_silence_accepts_any_length_with_a_good_crc() {
    // An 08 return-query-data with 6 data bytes: longer than the 8 bytes predicted, whole by silence.
    let q = Request {
        unit: UnitId(3),
        pdu: RequestPdu::Diagnostics { sub_function: 0, data: Data::binary(&[1, 2, 3, 4, 5, 6]) },
    };
    let f = emitted(&q, Request::emit_rtu);
    assert_eq!(RtuScanner::requests().silence(&f), Scan::Frame { len: f.len() });
    assert_eq!(rtu_req(&f), q);
    // Bytes cut short of a reply: say how many are missing.
    let tm2 = h("01 03 02 17 70 B6 50");
    match RtuScanner::replies().silence(&tm2[..5]) {
        Scan::Invalid { len: 5, skip: 5, error } => {
            assert_eq!(error.to_string(), "truncated frame: 03 reply needs 7 bytes, got 5")
        }
        s => panic!("{s:?}"),
    }
    match RtuScanner::replies().silence(&tm2[..1]) {
        Scan::Invalid { error, .. } => {
            assert_eq!(error.to_string(), "truncated frame: Modbus RTU frame needs 4 bytes, got 1")
        }
        s => panic!("{s:?}"),
    }
}

#[test]
fn crc_rewind_finds_the_other_address() {
    let body = h("00 06 00 02 13 88");
    for addr in [1u8, 7, 0xF7, 0xFE] {
        let mut other = body.clone();
        other[0] = addr;
        let carried = crate::checksum::crc16_modbus(&other);
        assert_eq!(rtu::mismatch_hint(&body, carried), Some(MismatchHint::OtherAddress { address: addr }));
    }
    // A CRC that fits nothing: no hint.
    let f = h("01 03 FD 00 00 01 00 00");
    match rtu::mismatch(&f) {
        FrameError::ChecksumMismatch { hint, .. } => {
            assert!(hint.is_none() || matches!(hint, Some(MismatchHint::OtherAddress { .. })))
        }
        e => panic!("{e:?}"),
    }
}

#[test]
fn rtu_reply_too_long_is_rejected_quickly() {
    // A reply reading of 01 03 FD ..: byte count 253 announces 258 bytes.
    match RtuScanner::replies().scan(&h("01 03 FD 00"), 0) {
        Scan::Invalid { skip: 1, error, .. } => {
            assert_eq!(
                error.to_string(),
                "frame too long: Modbus RTU frame allows at most 256 bytes, got 258"
            )
        }
        s => panic!("{s:?}"),
    }
}

// ---------------------------------------------------------------------------------------------
// ASCII scanner

/// A non-hex byte ends a frame; a new ':' restarts one. The bad part is rejected, the frame
/// after it found.
#[test]
fn ascii_bad_starts_are_rejected_and_the_next_frame_found() {
    let cases: [(&[u8], &[u8], &str, &str); 2] = [
        (b":01\x01", b":01\x01", "non-hex byte 0x01 at offset 3 ends the frame", ":010604051234AA"),
        (b"xx:0103", b":0103", "a new ':' started another frame before this one's CR LF", ":010304010001F6"),
    ];
    for (junk, rejected, error, frame) in cases {
        let mut s = junk.to_vec();
        s.extend_from_slice(&a(frame));
        let want = [Ev::Rejected(rejected.to_vec(), error.into()), Ev::Frame(a(frame))];
        assert_eq!(deframe(AsciiScanner, &[&s], true), want);
    }
}

#[test]
fn ascii_lower_case_and_errors() {
    let f = a(":010604051234aa");
    assert_eq!(AsciiScanner.scan(&f, 0), Scan::Frame { len: f.len() });
    let r = Request::parse_ascii(&f).unwrap();
    assert_eq!(r.pdu, RequestPdu::WriteSingleRegister { address: RegisterAddress(0x0405), value: 0x1234 });
    // Sent in upper case.
    assert_eq!(emitted(&r, Request::emit_ascii), a(":010604051234AA"));
    // LRC
    let bad = a(":010604051234AB");
    assert_eq!(
        deframe(AsciiScanner, &[&bad], true),
        [Ev::Rejected(bad.clone(), "LRC mismatch: frame carries AB, computed AA".into())]
    );
    // Odd digit count, too few bytes, CR without LF, a stream cut short.
    assert_eq!(
        err(Request::parse_ascii(&a(":010604051234A"))),
        "odd number of hex digits (13): a byte is two digits"
    );
    assert_eq!(
        err(Request::parse_ascii(&a(":01FF"))),
        "truncated frame: Modbus ASCII frame (address, function code, LRC) needs 3 bytes, got 2"
    );
    let evs = deframe(AsciiScanner, &[b":0106\r:010304010001F6\r\n"], true);
    assert_eq!(
        evs[0],
        Ev::Rejected(
            b":0106\r".to_vec(),
            "CR not followed by LF: a Modbus ASCII frame ends with CR LF".into()
        )
    );
    assert_eq!(evs[1], Ev::Frame(a(":010304010001F6")));
    let evs = deframe(AsciiScanner, &[b":010304"], true);
    assert_eq!(evs, [Ev::Rejected(b":010304".to_vec(), "the stream ended before the frame's CR LF".into())]);
}

#[test]
fn ascii_longest_frame() {
    // 10 with 123 registers: 1 + 2 * (1 + 6 + 246 + 1) + 2 = 511 characters.
    let values = [0xABCDu16; 123];
    let q = Request {
        unit: UnitId(1),
        pdu: RequestPdu::WriteMultipleRegisters {
            start: RegisterAddress(0),
            values: Registers::from_values(&values),
        },
    };
    let f = emitted(&q, Request::emit_ascii);
    assert_eq!(f.len(), 511);
    assert_eq!(deframe(AsciiScanner, &[&f], true), [Ev::Frame(f.clone())]);
    assert_eq!(Request::parse_ascii(&f).unwrap(), q);
    // The longest PDU (253 bytes) is 513 characters.
    let data = [0x55u8; MAX_PDU - 3];
    let d = Request {
        unit: UnitId(1),
        pdu: RequestPdu::Diagnostics { sub_function: 0, data: Data::binary(&data) },
    };
    let f = emitted(&d, Request::emit_ascii);
    assert_eq!(f.len(), 513);
    assert_eq!(deframe(AsciiScanner, &[&f], true), [Ev::Frame(f.clone())]);
    // One digit pair more does not fit.
    let mut long = f[..511].to_vec();
    long.extend_from_slice(b"00\r\n");
    let evs = deframe(AsciiScanner, &[&long], true);
    assert!(matches!(&evs[0], Ev::Rejected(_, e) if e.starts_with("frame too long")), "{evs:?}");
}

#[test]
fn ascii_data_views_decode_hex() {
    // : 01 03 | 04 byte count | 0102 ABCD | 7D LRC = -(01+03+04+01+02+AB+CD) | CR LF
    let f = a(":0103040102ABCD7D");
    let r = Reply::parse_ascii(&f).unwrap();
    let ReplyPdu::ReadHoldingRegisters { values } = r.pdu else { panic!() };
    assert_eq!(values.iter().collect::<Vec<_>>(), [0x0102, 0xABCD]);
    assert_eq!(emitted(&r, Reply::emit_ascii), f);
    // The same reply over RTU compares equal.
    let rtu_f = emitted(&r, Reply::emit_rtu);
    assert_eq!(rtu_rep(&rtu_f), r);
}

// ---------------------------------------------------------------------------------------------
// Timing

#[test]
fn timings() {
    let t = rtu::timing(9600, CharFormat::EVEN_8E1);
    assert_eq!(t.min_gap.as_micros(), 4010);
    assert_eq!(t.response_timeout, Duration::from_millis(100));
    assert_eq!(rtu::timing(115200, CharFormat::EVEN_8E1).min_gap.as_micros(), 1750);
    assert_eq!(rtu::timing_generic_vfd(19200, CharFormat::NONE_8N2).min_gap, Duration::from_millis(10));
    let t = ascii::timing(9600, CharFormat::NONE_7N2);
    assert_eq!(t.inter_char_timeout, Duration::from_secs(1));
    assert_eq!(t.response_timeout, Duration::from_millis(100));
}

// ---------------------------------------------------------------------------------------------
// Sessions on a virtual clock

fn drive_handler(
) -> impl FnMut(Instant, Incoming<'_, Request<'_>>, &mut crate::session::Responder<'_, ModbusRtu>) {
    |_now, incoming, resp| match incoming {
        Incoming::Request { request, .. } => {
            let unit = request.unit;
            match request.pdu {
                RequestPdu::ReadHoldingRegisters { start: RegisterAddress(0xFD00), quantity: 1 } => {
                    let values = [0x1770u16];
                    resp.reply(&Reply {
                        unit,
                        pdu: ReplyPdu::ReadHoldingRegisters { values: Registers::from_values(&values) },
                    })
                    .unwrap();
                }
                RequestPdu::ReadHoldingRegisters { .. } => {
                    resp.reply(&Reply::exception(unit, 3, ExceptionCode::ILLEGAL_DATA_VALUE)).unwrap();
                }
                RequestPdu::WriteSingleRegister { address, value } => {
                    resp.reply(&Reply { unit, pdu: ReplyPdu::WriteSingleRegister { address, value } })
                        .unwrap();
                }
                RequestPdu::Other { function, .. } => {
                    resp.reply(&Reply::exception(unit, function, ExceptionCode::ILLEGAL_FUNCTION)).unwrap();
                }
                _ => {}
            }
        }
        Incoming::Rejected { bytes, error } => {
            let unit = UnitId(bytes[0]);
            resp.reply(&Reply::exception(unit, bytes[1], ExceptionCode::for_error(&error))).unwrap();
        }
    }
}

/// TM1: read FD00 (output frequency), one register, from drive 1.
const READ_FD00: Request<'static> = Request {
    unit: UnitId(1),
    pdu: RequestPdu::ReadHoldingRegisters { start: RegisterAddress(0xFD00), quantity: 1 },
};

/// TM5: write 6000 (60.00 Hz) into FA01 of drive 1.
const WRITE_FA01: Request<'static> = Request {
    unit: UnitId(1),
    pdu: RequestPdu::WriteSingleRegister { address: RegisterAddress(0xFA01), value: 6000 },
};

/// A Modbus RTU master at `baud`, 8E1.
fn rtu_master(baud: u32) -> MasterSession<ModbusRtu> {
    MasterSession::new(ModbusRtu, rtu::timing(baud, CharFormat::EVEN_8E1))
}

/// Drive `unit` on Modbus RTU, answering 2 ms after a request.
fn rtu_slave(unit: u8) -> SlaveSession<ModbusRtu> {
    SlaveSession::new(ModbusRtu, unit, Duration::from_millis(2))
}

#[test]
fn session_request_and_reply() {
    let mut master = rtu_master(19200);
    let mut slave = rtu_slave(1);
    let mut handler = drive_handler();
    let t0 = Instant::from_millis(10);
    let req = READ_FD00;
    master.send(t0, &req).unwrap();
    let wire = master.poll_transmit(t0).unwrap().to_vec();
    assert_eq!(wire, h("01 03 FD 00 00 01 B5 A6"));
    let t1 = t0 + Duration::from_millis(5);
    slave.handle_input(t1, &wire, &mut handler);
    assert_eq!(slave.poll_transmit(t1), None);
    let t2 = t1 + Duration::from_millis(2);
    let reply = slave.poll_transmit(t2).unwrap().to_vec();
    assert_eq!(reply, h("01 03 02 17 70 B6 50"));
    master.handle_input(t2 + Duration::from_millis(4), &reply);
    match master.poll_event() {
        Some(MasterEvent::Reply(r)) => {
            assert_eq!(r.pdu, ReplyPdu::ReadHoldingRegisters { values: Registers::from_values(&[0x1770]) })
        }
        e => panic!("{e:?}"),
    }
    assert_eq!(master.stats().replies, 1);
    assert_eq!(slave.stats().replies, 1);
}

#[test]
fn session_min_gap_is_respected() {
    let mut master = rtu_master(9600);
    let t0 = Instant::from_millis(0);
    let req = WRITE_FA01;
    master.send(t0, &req).unwrap();
    master.poll_transmit(t0).unwrap();
    let echo = h("01 06 FA 01 17 70 E6 C6");
    let t_rx = Instant::from_millis(30);
    master.handle_input(t_rx, &echo);
    assert!(matches!(master.poll_event(), Some(MasterEvent::Reply(_))));
    master.send(t_rx, &req).unwrap();
    // t3.5 at 9600 baud is 4.010 ms after the last byte received.
    assert_eq!(master.poll_transmit(t_rx + Duration::from_micros(4000)), None);
    assert_eq!(master.poll_timeout(), Some(t_rx + Duration::from_nanos(4_010_417)));
    assert!(master.poll_transmit(t_rx + Duration::from_nanos(4_010_417)).is_some());
}

/// A pty or a TCP server can bring the reply sooner than the request's own wire time: the
/// next request waits for the gap after the reply, not for the request's computed end.
#[test]
fn session_reply_sooner_than_the_wire_time_allows_the_next_request_after_the_gap() {
    let mut timing = rtu::timing(9600, CharFormat::EVEN_8E1);
    timing.min_gap = Duration::ZERO;
    let mut master = MasterSession::new(ModbusRtu, timing);
    let t0 = Instant::from_millis(0);
    let req = WRITE_FA01;
    master.send(t0, &req).unwrap();
    master.poll_transmit(t0).unwrap();
    // 8 characters at 9600 8E1 take 9.2 ms; the echo is here after 50 us.
    let t_rx = t0 + Duration::from_micros(50);
    master.handle_input(t_rx, &h("01 06 FA 01 17 70 E6 C6"));
    assert!(matches!(master.poll_event(), Some(MasterEvent::Reply(_))));
    master.send(t_rx, &req).unwrap();
    assert_eq!(master.poll_timeout(), Some(t_rx));
    assert!(master.poll_transmit(t_rx).is_some());
}

#[test]
fn session_broadcast_gets_no_reply() {
    let mut master = rtu_master(19200);
    let mut slave = rtu_slave(1);
    let mut seen = Vec::new();
    let mut handler = |_: Instant,
                       inc: Incoming<'_, Request<'_>>,
                       resp: &mut crate::session::Responder<'_, ModbusRtu>| {
        if let Incoming::Request { request, broadcast } = inc {
            seen.push((request.pdu.function(), broadcast, resp.may_reply()));
            if let RequestPdu::WriteSingleRegister { address, value } = request.pdu {
                resp.reply(&Reply { unit: UnitId(1), pdu: ReplyPdu::WriteSingleRegister { address, value } })
                    .unwrap();
            }
        }
    };
    let t0 = Instant::from_millis(0);
    let req = Request {
        unit: UnitId::BROADCAST,
        pdu: RequestPdu::WriteSingleRegister { address: RegisterAddress(2), value: 5000 },
    };
    master.send(t0, &req).unwrap();
    let wire = master.poll_transmit(t0).unwrap().to_vec();
    assert_eq!(wire, h("00 06 00 02 13 88 24 8D"));
    slave.handle_input(t0 + Duration::from_millis(5), &wire, &mut handler);
    assert_eq!(seen.len(), 1);
    assert!(seen[0].1, "broadcast");
    assert!(!seen[0].2, "no reply allowed");
    assert_eq!(slave.poll_transmit(t0 + Duration::from_secs(1)), None);
    let until = master.poll_timeout().unwrap();
    master.handle_timeout(until);
    assert_eq!(master.poll_event(), Some(MasterEvent::BroadcastDone));
}

#[test]
fn session_timeout_and_other_addresses() {
    let mut master = rtu_master(19200);
    let mut slave = rtu_slave(2);
    let mut handler = drive_handler();
    let t0 = Instant::from_millis(0);
    let req = READ_FD00;
    master.send(t0, &req).unwrap();
    let wire = master.poll_transmit(t0).unwrap().to_vec();
    slave.handle_input(t0, &wire, &mut handler);
    assert_eq!(slave.poll_transmit(t0 + Duration::from_secs(1)), None);
    assert_eq!(slave.stats().ignored, 1);
    let deadline = master.poll_timeout().unwrap();
    master.handle_timeout(Instant(deadline.0 - 1));
    assert_eq!(master.poll_event(), None);
    master.handle_timeout(deadline);
    assert_eq!(master.poll_event(), Some(MasterEvent::Timeout));
}

#[test]
fn session_corrupt_reply() {
    let mut master = rtu_master(19200);
    let t0 = Instant::from_millis(0);
    let req = READ_FD00;
    master.send(t0, &req).unwrap();
    master.poll_transmit(t0).unwrap();
    master.handle_input(t0 + Duration::from_millis(10), &h("01 03 02 17 70 B6 51"));
    match master.poll_event() {
        Some(MasterEvent::Corrupt(FrameError::ChecksumMismatch { .. })) => {}
        e => panic!("{e:?}"),
    }
}

#[test]
fn session_exception_for_a_bad_request() {
    // The seed's 01 03 21 04 00 00 0E 37 has a good CRC and quantity 0: the drive answers
    // exception 03; a frame with a bad CRC gets no answer.
    let mut slave = SlaveSession::new(ModbusRtu, 1, Duration::ZERO);
    let mut handler = drive_handler();
    let t = Instant::from_millis(1);
    slave.handle_input(t, &h("01 03 21 04 00 00 0E 37"), &mut handler);
    assert_eq!(slave.poll_transmit(t).unwrap(), &h("01 83 03 01 31")[..]);
    slave.handle_input(t, &h("01 03 21 04 00 01 E8 4B"), &mut handler);
    assert_eq!(slave.poll_transmit(t), None);
    // An unsupported but known function: exception 01.
    slave.handle_input(
        t,
        &emitted(
            &Request {
                unit: UnitId(1),
                pdu: RequestPdu::Other { function: 0x05, data: Data::binary(&[0, 1, 0xFF, 0]) },
            },
            Request::emit_rtu,
        ),
        &mut handler,
    );
    let rep = slave.poll_transmit(t).unwrap().to_vec();
    assert_eq!(
        rtu_rep(&rep).pdu,
        ReplyPdu::Exception { function: 0x05, code: ExceptionCode::ILLEGAL_FUNCTION }
    );
}

#[test]
fn ascii_session_exchange() {
    let timing = ascii::timing(9600, CharFormat::NONE_7N2);
    let mut master = MasterSession::new(ModbusAscii, timing);
    let mut slave = SlaveSession::new(ModbusAscii, 1, Duration::from_millis(1));
    let mut handler = |_: Instant,
                       inc: Incoming<'_, Request<'_>>,
                       resp: &mut crate::session::Responder<'_, ModbusAscii>| {
        if let Incoming::Request { request, .. } = inc {
            if let RequestPdu::Diagnostics { sub_function, data } = request.pdu {
                resp.reply(&Reply { unit: request.unit, pdu: ReplyPdu::Diagnostics { sub_function, data } })
                    .unwrap();
            }
        }
    };
    let t0 = Instant::from_millis(0);
    let req = Request {
        unit: UnitId(1),
        pdu: RequestPdu::Diagnostics { sub_function: 0x0102, data: Data::binary(&[3, 4]) },
    };
    master.send(t0, &req).unwrap();
    let wire = master.poll_transmit(t0).unwrap().to_vec();
    assert_eq!(wire, a(":010801020304ED"));
    // Byte by byte, the way a slow line delivers it.
    for (i, b) in wire.iter().enumerate() {
        slave.handle_input(t0 + Duration::from_millis(i as u64), core::slice::from_ref(b), &mut handler);
    }
    let t1 = t0 + Duration::from_millis(40);
    let reply = slave.poll_transmit(t1).unwrap().to_vec();
    assert_eq!(reply, a(":010801020304ED"));
    // The reply arrives slowly: 500 ms between characters is still one frame.
    let mut t = t1;
    for (i, b) in reply.iter().enumerate() {
        if i > 0 {
            t = t + Duration::from_millis(500);
        }
        master.handle_timeout(t);
        master.handle_input(t, core::slice::from_ref(b));
    }
    assert!(matches!(master.poll_event(), Some(MasterEvent::Reply(_))));
}

#[test]
fn codec_names_and_scanners() {
    assert_eq!(<ModbusRtu as Codec>::NAME, "modbus-rtu");
    assert_eq!(<ModbusAscii as Codec>::NAME, "modbus-ascii");
    assert_eq!(ModbusRtu::scanner(Some(Direction::Master)).accept(), Accept::Requests);
    assert_eq!(ModbusRtu::scanner(Some(Direction::Drive)).accept(), Accept::Replies);
    assert_eq!(ModbusRtu::scanner(None).accept(), Accept::Either);
    let f = h("01 03 02 17 70 B6 50");
    // A monitor's parse prefers the request reading and falls back to the reply.
    let frame = ModbusRtu::parse(&f, None).unwrap();
    assert_eq!(frame.direction(), Direction::Drive);
    assert_eq!(frame.command().code, function::READ_HOLDING_REGISTERS);
}

#[test]
fn register_units_and_constructors() {
    let fa01 = register_info(RegisterAddress(0xFA01)).unwrap();
    assert_eq!(fa01.quantity(0x1770), Some(60.0));
    assert_eq!(fa01.raw(60.0), Some(0x1770));
    let p = register_info(RegisterAddress(0x2104)).unwrap();
    assert_eq!(p.raw(5.24), Some(52));
    assert_eq!(p.raw(-1.0), None);
    assert_eq!(register_info(RegisterAddress(0x2000)).unwrap().quantity(1), None);
    assert_eq!(register_info(RegisterAddress(0x0002)), None);
    // The constructors build the vectors.
    assert_eq!(
        emitted(&Request::read_holding_registers(UnitId(1), 0xFD00, 1), Request::emit_rtu),
        h("01 03 FD 00 00 01 B5 A6")
    );
    assert_eq!(
        emitted(&Request::write_single_register(UnitId(1), 0xFA01, 6000), Request::emit_rtu),
        h("01 06 FA 01 17 70 E6 C6")
    );
    assert_eq!(
        emitted(&Request::diagnostics(UnitId(1), 0x0102, &[3, 4]), Request::emit_rtu),
        h("01 08 01 02 03 04 41 04")
    );
    assert_eq!(
        emitted(
            &Request::read_device_identification(UnitId(1), ReadDeviceIdCode::BASIC, 0),
            Request::emit_rtu
        ),
        h("01 2B 0E 01 00 70 77")
    );
    assert_eq!(
        emitted(&Request::read_holding_registers(UnitId(1), 0x2102, 2), Request::emit_ascii),
        a(":010321020002D7")
    );
    assert_eq!(
        Request::read_input_registers(UnitId(2), 5, 1).pdu,
        RequestPdu::ReadInputRegisters { start: RegisterAddress(5), quantity: 1 }
    );
    let v = [1u16, 2];
    assert_eq!(Request::write_multiple_registers(UnitId(1), 0x2000, &v).pdu.wire_len(), 10);
}

#[test]
fn monitor_diagnoses_at_silence() {
    // A monitor waits for the longer reply reading; at silence it explains the reading as
    // long as the frame.
    let f8 = h("01 03 21 04 00 01 E8 4B");
    assert_eq!(deframe(RtuScanner::either(), &[&f8], false), []);
    assert_eq!(
        first(deframe(RtuScanner::either(), &[&f8], true)),
        [Ev::Rejected(
            f8.clone(),
            "CRC mismatch: frame carries E8 4B, computed CF F7 (the carried CRC is that of the first 4 bytes only)"
                .into()
        )]
    );
}

/// Modbus RTU's t1.5 where it is asked for: a silence longer than 1.5 characters inside a reply
/// makes it incomplete; shorter gaps, or the rule off (the default), keep the frame.
#[test]
fn session_t15_inside_a_reply_declares_it_incomplete_when_enforced() {
    let req = WRITE_FA01;
    let reply = h("01 06 FA 01 17 70 E6 C6");
    let (t15, _) = crate::line::modbus_t15_t35(9600);
    let run = |enforce: bool, gap: Duration| {
        let mut timing = rtu::timing(9600, CharFormat::EVEN_8E1);
        timing.max_char_gap = enforce.then_some(t15);
        let mut master = MasterSession::new(ModbusRtu, timing);
        let t0 = Instant::from_millis(0);
        master.send(t0, &req).unwrap();
        master.poll_transmit(t0).unwrap();
        let t1 = Instant::from_millis(20);
        master.handle_input(t1, &reply[..3]);
        master.handle_input(t1 + gap, &reply[3..]);
        match master.poll_event() {
            Some(MasterEvent::Reply(_)) => "reply".to_string(),
            Some(MasterEvent::Corrupt(e)) => format!("incomplete: {e}"),
            other => format!("{other:?}"),
        }
    };
    // 1.5 characters of 11 bits at 9600 baud: 1.719 ms.
    assert_eq!(run(true, Duration::from_micros(1500)), "reply");
    let cut = run(true, Duration::from_micros(2000));
    assert!(cut.starts_with("incomplete: "), "{cut}");
    assert_eq!(run(false, Duration::from_millis(5)), "reply");
}

#[test]
fn read_write_multiple_registers_round_trips_and_is_checked() {
    // Modbus Application Protocol 6.17: read 6 from 0003, write 3 from 000E.
    let wire =
        [0x17, 0x00, 0x03, 0x00, 0x06, 0x00, 0x0E, 0x00, 0x03, 0x06, 0x00, 0xFF, 0x00, 0xFF, 0x00, 0xFF];
    let req = RequestPdu::parse(&wire).expect("a valid 17 request");
    let RequestPdu::ReadWriteMultipleRegisters { read_start, read_quantity, write_start, values } = req
    else {
        panic!("{req:?}")
    };
    assert_eq!((read_start.0, read_quantity, write_start.0, values.len()), (3, 6, 14, 3));
    assert_eq!(values.iter().collect::<std::vec::Vec<_>>(), [0xFF, 0xFF, 0xFF]);
    let mut out = [0u8; 32];
    assert_eq!(req.emit(&mut out), Ok(wire.len()));
    assert_eq!(&out[..wire.len()], &wire);
    // The byte count must be twice the quantity to write; quantities have their limits.
    let mut bad = wire;
    bad[9] = 4;
    assert!(RequestPdu::parse(&bad).is_err());
    let mut bad = wire;
    bad[4] = 0;
    assert!(RequestPdu::parse(&bad).is_err(), "read quantity 0");
    // The reply carries the registers read, like 03.
    let reply = [0x17, 0x04, 0x00, 0xFE, 0x0A, 0xCD];
    let rep = ReplyPdu::parse(&reply).expect("a valid 17 reply");
    assert!(matches!(rep, ReplyPdu::ReadWriteMultipleRegisters { values } if values.len() == 2));
    assert_eq!(rep.emit(&mut out), Ok(reply.len()));
    assert_eq!(&out[..reply.len()], &reply);
}

#[test]
fn length_messages_name_the_function() {
    use super::pdu::{reply_what, request_what};
    for (fc, req, rep) in [
        (0x01, "01 request", "01 reply"),
        (0x0B, "0B request", "0B reply"),
        (0x0F, "0F request", "0F reply"),
        (0x18, "18 request", "18 reply"),
        (0x2B, "2B/0E request", "2B/0E reply"),
        (0x09, "request", "reply"),
        (0x83, "request", "exception reply"),
    ] {
        assert_eq!((request_what(fc), reply_what(fc)), (req, rep), "{fc:02X}");
    }
    assert_eq!(err(ReplyPdu::parse(&h("10 00 01"))), "truncated frame: 10 reply needs 5 bytes, got 3");
}
