//! B800 unit tests: the seed's frames (protocols.md 5.1, B1–B6) byte by byte, every command
//! and reply, the receiver state machine, the exact error messages, and sessions on a
//! virtual clock.

extern crate std;

use std::format;
use std::string::ToString;
use std::vec::Vec;

use core::time::Duration;

use super::*;
use crate::deframe::{Deframer, Event, Scan, Scanner, Stats};
use crate::describe::{Describe, Direction, Field, Target};
use crate::error::EmitError;
use crate::error::{ChecksumKind, MismatchHint};
use crate::session::{Incoming, MasterEvent, MasterSession, Responder, SlaveSession};
use crate::time::Instant;

fn a(n: u8) -> Address {
    Address::new(n).unwrap()
}

fn emit_req(r: &Request) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME];
    let n = r.emit(&mut buf).unwrap();
    assert_eq!(n, r.wire_len());
    buf[..n].to_vec()
}

fn emit_rep(r: &Reply) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME];
    let n = r.emit(&mut buf).unwrap();
    assert_eq!(n, r.wire_len());
    buf[..n].to_vec()
}

/// Good frames, rejected candidates with why, and the deframer's counts.
type Deframed = (Vec<Vec<u8>>, Vec<(Vec<u8>, FrameError)>, Stats);

/// Runs `stream` through a deframer in one piece.
fn deframe(from: Option<Direction>, stream: &[u8]) -> Deframed {
    let mut d = Deframer::new(FrameScanner::new(from));
    let mut good = Vec::new();
    let mut bad = Vec::new();
    d.push(stream, &mut |e| match e {
        Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
        Event::Rejected { bytes, error, .. } => bad.push((bytes.to_vec(), error)),
    });
    (good, bad, d.stats())
}

// ---------------------------------------------------------------------------------------
// protocols.md 5.1: B1–B6, the seed's frames
// ---------------------------------------------------------------------------------------

/// B1: run drive 1, the seed's first example.
const B1: [u8; 8] = [
    0x7E, // FG1 start flag
    0x38, 0x31, // DA "81" = 128 + 1
    0x35, 0x32, // CMD "52" = 'R' run
    0x32, 0x46, // CS "2F" = !(38+31+35+32 = D0)
    0x7F, // FG2 stop flag
];

/// B2: drive 5, set speed 40.0 Hz.
const B2: [u8; 12] = [
    0x7E, // FG1
    0x38, 0x35, // DA "85" = 128 + 5
    0x35, 0x30, // CMD "50" = 'P' set new speed in Hz
    0x30, 0x39, 0x36, 0x30, // DATA "0960" = 2400 = 60 x 40.0 Hz, high byte first
    0x35, 0x45, // CS "5E" = !(38+35+35+30+30+39+36+30 = 1A1)
    0x7F, // FG2
];

/// B3: global run (and the seed's "reverse direction of all drives", byte for byte).
const B3: [u8; 8] = [
    0x7E, // FG1
    0x34, 0x37, // DA "47" = 'G' global
    0x35, 0x32, // CMD "52" = 'R'
    0x32, 0x44, // CS "2D" = !(34+37+35+32 = D2)
    0x7F, // FG2
];

/// B4: global stop.
const B4: [u8; 8] = [
    0x7E, // FG1
    0x34, 0x37, // DA "47" = 'G'
    0x35, 0x33, // CMD "53" = 'S'
    0x32, 0x43, // CS "2C" = !(34+37+35+33 = D3)
    0x7F, // FG2
];

/// B5: drive 1 answers run.
const B5: [u8; 8] = [
    0x7E, // FG1
    0x30, 0x31, // DA "01": the plain address, no +128
    0x37, 0x32, // REPLY "72" = 'r' run command executed
    0x33, 0x35, // CS "35" = !(30+31+37+32 = CA)
    0x7F, // FG2
];

/// B6: drive 5 answers set speed.
const B6: [u8; 8] = [
    0x7E, // FG1
    0x30, 0x35, // DA "05"
    0x37, 0x30, // REPLY "70" = 'p' new speed in Hz loaded
    0x33, 0x33, // CS "33" = !(30+35+37+30 = CC)
    0x7F, // FG2
];

/// The seed's "2. Reverse direction of all drives (F-12 = 2)", as printed.
const SEED_REVERSE_ALL: [u8; 8] = [0x7E, 0x34, 0x37, 0x35, 0x32, 0x32, 0x44, 0x7F];

/// protocols.md 4.2's `e` example: drive 01, error 95. Its CS is right: 30+31+36+35+39+35
/// = 13A, !3A = C5, sent as "C5" = 43 35.
const E95: [u8; 10] = [
    0x7E, // FG1
    0x30, 0x31, // DA "01"
    0x36, 0x35, // REPLY "65" = 'e'
    0x39, 0x35, // DATA "95" = invalid data: incorrect checksum
    0x43, 0x35, // CS "C5"
    0x7F, // FG2
];

#[test]
fn b1_run_drive_1() {
    let r = Request::to_drive(a(1), MasterCommand::Run);
    assert_eq!(emit_req(&r), B1);
    assert_eq!(Request::parse(&B1), Ok(r));
    assert_eq!(Packet::parse(&B1), Ok(Packet::Request(r)));
    assert_eq!(r.expected_reply(), Some(Pending { from: a(1), reply: b'r' }));
}

#[test]
fn b2_set_speed_40_hz_drive_5() {
    let speed = Speed::from_hz(40.0).unwrap();
    assert_eq!(speed.raw(), 0x0960);
    assert_eq!(speed.hz(), 40.0);
    let r = Request::to_drive(a(5), MasterCommand::SetSpeed(speed));
    assert_eq!(emit_req(&r), B2);
    assert_eq!(Request::parse(&B2), Ok(r));
    assert_eq!(r.expected_reply(), Some(Pending { from: a(5), reply: b'p' }));
}

#[test]
fn b3_global_run_is_also_reverse_all() {
    let r = Request::global(MasterCommand::Run);
    assert_eq!(emit_req(&r), B3);
    assert_eq!(Request::parse(&B3), Ok(r));
    // seed 000: "Sending a run command to an already running drive reverses direction if
    // F-12 = 2": the seed's "reverse all drives" frame is the global run frame.
    assert_eq!(SEED_REVERSE_ALL, B3);
    // seed 000: "There is no reply from the B800s to a global command."
    assert_eq!(r.expected_reply(), None);
}

#[test]
fn b4_global_stop() {
    let r = Request::global(MasterCommand::Stop);
    assert_eq!(emit_req(&r), B4);
    assert_eq!(Request::parse(&B4), Ok(r));
    assert_eq!(r.expected_reply(), None);
}

#[test]
fn b5_reply_run_from_drive_1() {
    let r = Reply::new(a(1), SlaveReply::Run);
    assert_eq!(emit_rep(&r), B5);
    assert_eq!(Reply::parse(&B5), Ok(r));
    assert_eq!(Packet::parse(&B5), Ok(Packet::Reply(r)));
    assert!(Pending { from: a(1), reply: b'r' }.matches(&r));
    assert!(!Pending { from: a(2), reply: b'r' }.matches(&r));
    assert!(!Pending { from: a(1), reply: b's' }.matches(&r));
}

#[test]
fn b6_reply_set_speed_from_drive_5() {
    let r = Reply::new(a(5), SlaveReply::SetSpeed);
    assert_eq!(emit_rep(&r), B6);
    assert_eq!(Reply::parse(&B6), Ok(r));
}

#[test]
fn error_reply_example_is_right() {
    assert_eq!(crate::checksum::not_sum8(b"016595"), 0xC5);
    let r = Reply::new(a(1), SlaveReply::error(ErrorCode::BAD_CHECKSUM));
    assert_eq!(emit_rep(&r), E95);
    assert_eq!(Reply::parse(&E95), Ok(r));
    assert!(Pending { from: a(1), reply: b'r' }.matches(&r), "an e answers any request");
}

#[test]
fn seed_checksums() {
    // The seed's CS examples (protocols.md 4.1 audit), over the ASCII characters.
    for (chars, cs) in [
        (&b"8152"[..], 0x2F),
        (b"85500960", 0x5E),
        (b"4752", 0x2D),
        (b"4753", 0x2C),
        (b"0172", 0x35),
        (b"0570", 0x33),
        (b"016595", 0xC5),
    ] {
        assert_eq!(crate::checksum::not_sum8(chars), cs, "{chars:?}");
    }
}

// ---------------------------------------------------------------------------------------
// Every command and every reply
// ---------------------------------------------------------------------------------------

#[test]
fn every_master_command_to_drive_1() {
    let cases: [(MasterCommand, &[u8]); 10] = [
        // 7E "81" CMD [DATA] CS 7F
        (MasterCommand::Run, &[0x7E, 0x38, 0x31, 0x35, 0x32, 0x32, 0x46, 0x7F]), // 'R' CS 2F
        (MasterCommand::Stop, &[0x7E, 0x38, 0x31, 0x35, 0x33, 0x32, 0x45, 0x7F]), // 'S' CS 2E
        (MasterCommand::MotorCurrent, &[0x7E, 0x38, 0x31, 0x34, 0x31, 0x33, 0x31, 0x7F]), // 'A' CS 31
        (MasterCommand::SpeedHz, &[0x7E, 0x38, 0x31, 0x35, 0x41, 0x32, 0x30, 0x7F]), // 'Z' CS 20
        (MasterCommand::SpeedRpm, &[0x7E, 0x38, 0x31, 0x34, 0x44, 0x31, 0x45, 0x7F]), // 'M' CS 1E
        (MasterCommand::Status, &[0x7E, 0x38, 0x31, 0x35, 0x34, 0x32, 0x44, 0x7F]), // 'T' CS 2D
        (MasterCommand::Version, &[0x7E, 0x38, 0x31, 0x35, 0x36, 0x32, 0x42, 0x7F]), // 'V' CS 2B
        (
            MasterCommand::SetSpeed(Speed::from_raw(0x0960)), // 'P' "0960" CS 62
            &[0x7E, 0x38, 0x31, 0x35, 0x30, 0x30, 0x39, 0x36, 0x30, 0x36, 0x32, 0x7F],
        ),
        (MasterCommand::Increase, &[0x7E, 0x38, 0x31, 0x34, 0x39, 0x32, 0x39, 0x7F]), // 'I' CS 29
        (MasterCommand::Reduce, &[0x7E, 0x38, 0x31, 0x34, 0x43, 0x31, 0x46, 0x7F]),   // 'L' CS 1F
    ];
    for (cmd, wire) in cases {
        let r = Request::to_drive(a(1), cmd);
        assert_eq!(emit_req(&r), wire, "{cmd:?}");
        assert_eq!(Request::parse(wire), Ok(r), "{cmd:?}");
        assert_eq!(r.expected_reply().unwrap().reply, cmd.letter().to_ascii_lowercase());
        // The same command as a global one.
        let g = Request::global(cmd);
        assert_eq!(Request::parse(&emit_req(&g)), Ok(g));
    }
}

#[test]
fn every_reply_from_drive_1() {
    let cases: [(SlaveReply, &[u8]); 12] = [
        // 7E "01" REPLY [DATA] CS 7F
        (SlaveReply::Run, &[0x7E, 0x30, 0x31, 0x37, 0x32, 0x33, 0x35, 0x7F]), // 'r' CS 35
        (SlaveReply::Stop, &[0x7E, 0x30, 0x31, 0x37, 0x33, 0x33, 0x34, 0x7F]), // 's' CS 34
        (
            SlaveReply::MotorCurrent(Current::from_raw(0x0023)), // 'a' "0023" = 3.5 A, CS 72
            &[0x7E, 0x30, 0x31, 0x36, 0x31, 0x30, 0x30, 0x32, 0x33, 0x37, 0x32, 0x7F],
        ),
        (
            SlaveReply::SpeedHz(Speed::from_raw(0x0960)), // 'z' "0960" = 40.00 Hz, CS 57
            &[0x7E, 0x30, 0x31, 0x37, 0x41, 0x30, 0x39, 0x36, 0x30, 0x35, 0x37, 0x7F],
        ),
        (
            SlaveReply::SpeedRpm(Rpm::from_raw(1500)), // 'm' "05DC" = 1500 rpm, CS 38
            &[0x7E, 0x30, 0x31, 0x36, 0x44, 0x30, 0x35, 0x44, 0x43, 0x33, 0x38, 0x7F],
        ),
        (
            SlaveReply::Status(DriveStatus::tripped(0x03)), // 't' "039A" = tripped, trip 03, CS 56
            &[0x7E, 0x30, 0x31, 0x37, 0x34, 0x30, 0x33, 0x39, 0x41, 0x35, 0x36, 0x7F],
        ),
        (
            SlaveReply::Version(Version::new(1, 0).unwrap()), // 'v' "0100" = 1.00, CS 70
            &[0x7E, 0x30, 0x31, 0x37, 0x36, 0x30, 0x31, 0x30, 0x30, 0x37, 0x30, 0x7F],
        ),
        (SlaveReply::SetSpeed, &[0x7E, 0x30, 0x31, 0x37, 0x30, 0x33, 0x37, 0x7F]), // 'p' CS 37
        (SlaveReply::Increase, &[0x7E, 0x30, 0x31, 0x36, 0x39, 0x32, 0x46, 0x7F]), // 'i' CS 2F
        (SlaveReply::Reduce, &[0x7E, 0x30, 0x31, 0x36, 0x43, 0x32, 0x35, 0x7F]),   // 'l' CS 25
        (SlaveReply::error(ErrorCode::BAD_CHECKSUM), &E95),                        // 'e' "95" CS C5
        (
            SlaveReply::Error { code: ErrorCode::BAD_CHECKSUM, word: true }, // 'e' "0095" CS 65
            &[0x7E, 0x30, 0x31, 0x36, 0x35, 0x30, 0x30, 0x39, 0x35, 0x36, 0x35, 0x7F],
        ),
    ];
    for (reply, wire) in cases {
        let r = Reply::new(a(1), reply);
        assert_eq!(emit_rep(&r), wire, "{reply:?}");
        assert_eq!(Reply::parse(wire), Ok(r), "{reply:?}");
    }
    // Replies and commands pair up by case.
    for (cmd, rep) in [
        (MasterCommand::Run, SlaveReply::Run),
        (MasterCommand::Stop, SlaveReply::Stop),
        (MasterCommand::MotorCurrent, SlaveReply::MotorCurrent(Current::from_raw(0))),
        (MasterCommand::SpeedHz, SlaveReply::SpeedHz(Speed::from_raw(0))),
        (MasterCommand::SpeedRpm, SlaveReply::SpeedRpm(Rpm::from_raw(0))),
        (MasterCommand::Status, SlaveReply::Status(DriveStatus::from_raw(0))),
        (MasterCommand::Version, SlaveReply::Version(Version::from_raw(0))),
        (MasterCommand::SetSpeed(Speed::from_raw(0)), SlaveReply::SetSpeed),
        (MasterCommand::Increase, SlaveReply::Increase),
        (MasterCommand::Reduce, SlaveReply::Reduce),
    ] {
        assert_eq!(cmd.reply_letter(), rep.letter());
    }
}

#[test]
fn every_error_code_of_the_seed() {
    for code in [0x02u8, 0x91, 0x92, 0x93, 0x94, 0x95, 0x97, 0x98, 0x99, 0x9A] {
        let r = Reply::new(a(63), SlaveReply::error(ErrorCode(code)));
        let wire = emit_rep(&r);
        assert_eq!(wire.len(), 10);
        assert_eq!(Reply::parse(&wire), Ok(r));
        assert!(ErrorCode(code).meaning().is_some(), "{code:02X}");
    }
    assert_eq!(ErrorCode(0x96).meaning(), None);
    assert_eq!(ErrorCode::TRIPPED.to_string(), "9A (tripped)");
    assert_eq!(ErrorCode(0x96).to_string(), "96 (not in the seed's list)");
    // A 4-digit word with a high byte is not a byte code.
    let bad = frame_of(b"01651234");
    assert_eq!(Reply::parse(&bad).unwrap_err().to_string(), "error code 4660 is not allowed (0..255)");
}

#[test]
fn values_and_units() {
    assert_eq!(Speed::from_hz(40.0).unwrap().raw(), 0x0960);
    assert_eq!(Speed::from_hz(0.0).unwrap().raw(), 0);
    assert_eq!(Speed::from_hz(50.01).unwrap().raw(), 3001); // 3000.6 rounds to 3001
    assert_eq!(Speed::from_hz(Speed::MAX_HZ).unwrap().raw(), 0xFFFF);
    for bad in [-0.1, 1092.26, 2000.0, f64::NAN, f64::INFINITY] {
        let e = Speed::from_hz(bad).unwrap_err();
        assert_eq!(
            e.to_string(),
            "target speed must be 0 to 1092.25 Hz: the wire carries 60 x Hz in a 16-bit word"
        );
    }
    assert_eq!(Current::from_amps(4.5).unwrap().raw(), 45);
    assert_eq!(Current::from_raw(0x2D).amps(), 4.5);
    assert!(Current::from_amps(-1.0).is_err());
    assert_eq!(Rpm::from_raw(0x05DC).rpm(), 1500);
    let v = Version::from_raw(0x0123);
    assert_eq!((v.major(), v.minor(), v.is_bcd()), (1, 23, true));
    assert_eq!(v.to_string(), "1.23");
    assert_eq!(Version::new(12, 5).unwrap().raw(), 0x1205);
    assert_eq!(Version::from_raw(0x01AB).to_string(), "0x01AB");
    assert_eq!(Version::new(100, 0), None);

    let st = DriveStatus::tripped(0x07);
    assert_eq!(st.raw(), 0x079A);
    assert_eq!((st.state(), st.trip_code()), (DriveState::Tripped, Some(7)));
    let st = DriveStatus::new(DriveState::Running);
    assert_eq!((st.raw(), st.trip_code()), (0x0093, None));
    assert_eq!(DriveStatus::from_raw(0x0002).state(), DriveState::Standby);
    assert_eq!(DriveStatus::from_raw(0x0099).state(), DriveState::HardwareEnableMissing);
    assert_eq!(DriveStatus::from_raw(0x0042).state(), DriveState::Other(0x42));

    assert_eq!(Address::new(0), None);
    assert_eq!(Address::new(64), None);
    assert_eq!(a(63).master_da(), 0xBF);
    assert_eq!(Address::try_new(64).unwrap_err().to_string(), "drive address 64 is out of range (1..63)");
    assert_eq!(Destination::from_da(0x81), Some(Destination::Drive(a(1))));
    assert_eq!(Destination::from_da(b'G'), Some(Destination::Global));
    assert_eq!(Destination::from_da(0x80), None);
    assert_eq!(Destination::from_da(0xC0), None);
    assert_eq!(Destination::from_da(0x01), None);
}

#[test]
fn emit_needs_room() {
    let mut small = [0u8; 11];
    let r = Request::to_drive(a(5), MasterCommand::SetSpeed(Speed::from_raw(0x0960)));
    assert_eq!(r.emit(&mut small), Err(EmitError::BufferTooSmall { needed: 12, capacity: 11 }));
    assert_eq!(r.emit(&mut [0u8; 12]), Ok(12));
}

// ---------------------------------------------------------------------------------------
// Reading frames: case, errors, exact messages
// ---------------------------------------------------------------------------------------

/// 7E, `chars`, their CS as upper-case hex, 7F.
fn frame_of(chars: &[u8]) -> Vec<u8> {
    let mut v = Vec::from([FG1]);
    v.extend_from_slice(chars);
    v.extend_from_slice(&crate::hex::byte_digits(crate::checksum::not_sum8(chars)));
    v.push(FG2);
    v
}

#[test]
fn lower_case_digits_are_accepted() {
    // "bf" "5a": drive 63, 'Z'; the CS is over the lower-case characters as received:
    // 62+66+35+61 = 15E, !5E = A1, here sent as "a1".
    let wire = [0x7E, 0x62, 0x66, 0x35, 0x61, 0x61, 0x31, 0x7F];
    assert_eq!(Request::parse(&wire), Ok(Request::to_drive(a(63), MasterCommand::SpeedHz)));
    let (good, bad, _) = deframe(None, &wire);
    assert_eq!((good.len(), bad.len()), (1, 0));
    // Upper case on the way out: "BF" "5A", CS over those characters = 01.
    assert_eq!(emit_req(&Request::to_drive(a(63), MasterCommand::SpeedHz)), frame_of(b"BF5A"));
    assert_eq!(frame_of(b"BF5A"), [0x7E, 0x42, 0x46, 0x35, 0x41, 0x30, 0x31, 0x7F]);
}

#[test]
fn checksum_mismatch_message() {
    // B1 carrying the CS of "81" 'S' (2E) instead of 2F.
    let wire = [0x7E, 0x38, 0x31, 0x35, 0x32, 0x32, 0x45, 0x7F];
    let e = Request::parse(&wire).unwrap_err();
    assert_eq!(
        e,
        FrameError::ChecksumMismatch { kind: ChecksumKind::Cs, carried: 0x2E, computed: 0x2F, hint: None }
    );
    assert_eq!(e.to_string(), "checksum mismatch: frame carries 2E, computed 2F");
    // The scanner says the same.
    let (good, bad, stats) = deframe(None, &wire);
    assert!(good.is_empty());
    assert_eq!(bad, [(wire.to_vec(), e)]);
    assert_eq!(stats.checksum_failures, 1);
}

#[test]
fn checksum_over_the_plain_address_is_diagnosed() {
    // A master that summed "01" 'R' (CS 37) and then sent DA 81.
    let wire = [0x7E, 0x38, 0x31, 0x35, 0x32, 0x33, 0x37, 0x7F];
    let e = Request::parse(&wire).unwrap_err();
    assert_eq!(
        e,
        FrameError::ChecksumMismatch {
            kind: ChecksumKind::Cs,
            carried: 0x37,
            computed: 0x2F,
            hint: Some(MismatchHint::OtherAddress { address: 1 }),
        }
    );
    assert_eq!(
        e.to_string(),
        "checksum mismatch: frame carries 37, computed 2F \
         (the carried checksum is right for the same frame sent to address 1)"
    );
}

#[test]
fn non_hex_byte_ends_the_frame() {
    // seed 000: "Any non-ASCII byte received other than the START / STOP flags will terminate
    // the data reception and a new sequence must be started."
    let stream = [0x7E, 0x38, 0x31, 0x01, 0x35, 0x32, 0x32, 0x46, 0x7F];
    let (good, bad, stats) = deframe(None, &stream);
    assert!(good.is_empty());
    assert_eq!(bad.len(), 1);
    assert_eq!(bad[0].0, [0x7E, 0x38, 0x31, 0x01]);
    assert_eq!(bad[0].1, FrameError::NonHex { byte: 0x01, offset: 3 });
    assert_eq!(bad[0].1.to_string(), "non-hex byte 0x01 at offset 3 ends the frame");
    assert_eq!(stats.dropped_bytes, stream.len() as u64);
    // An ASCII letter that is not a hex digit ends it too.
    let e = Request::parse(&[0x7E, 0x38, 0x31, 0x35, 0x47, 0x32, 0x46, 0x7F]).unwrap_err();
    assert_eq!(e.to_string(), "non-hex byte 0x47 at offset 4 ends the frame");
}

#[test]
fn start_flag_restarts_a_frame() {
    // 7E "81" 7E then B1 whole: the cut frame is reported, B1 is found.
    let mut stream = Vec::from([0x7E, 0x38, 0x31]);
    stream.extend_from_slice(&B1);
    let (good, bad, _) = deframe(None, &stream);
    assert_eq!(good, [B1.to_vec()]);
    assert_eq!(bad.len(), 1);
    assert_eq!(bad[0].1.to_string(), "a new start flag 7E came before the stop flag 7F");
    // A doubled 7E is just noise.
    let mut stream = Vec::from([0x7E]);
    stream.extend_from_slice(&B1);
    let (good, bad, stats) = deframe(None, &stream);
    assert_eq!((good, bad.len(), stats.dropped_bytes), (Vec::from([B1.to_vec()]), 0, 1));
}

#[test]
fn bytes_outside_frames_are_noise() {
    let mut stream = Vec::from(*b"hello 7F\x7f\x00");
    stream.extend_from_slice(&B5);
    stream.extend_from_slice(b"\x7f junk");
    stream.extend_from_slice(&B6);
    let (good, bad, stats) = deframe(None, &stream);
    assert_eq!(good, [B5.to_vec(), B6.to_vec()]);
    assert!(bad.is_empty());
    assert_eq!(stats.dropped_bytes, (stream.len() - 16) as u64);
}

#[test]
fn digit_count_is_checked() {
    // 7 digits: odd.
    let e = Request::parse(&[0x7E, 0x38, 0x31, 0x35, 0x32, 0x32, 0x46, 0x30, 0x7F]).unwrap_err();
    assert_eq!(e.to_string(), "odd number of hex digits (7): a byte is two digits");
    // 4 digits: DA and CMD without a CS.
    let e = Request::parse(&[0x7E, 0x38, 0x31, 0x35, 0x32, 0x7F]).unwrap_err();
    assert_eq!(e.to_string(), "truncated frame: a B800 frame (FG1 DA CMD CS FG2) needs 8 bytes, got 6");
    let (_, bad, _) = deframe(None, &[0x7E, 0x38, 0x31, 0x35, 0x32, 0x7F]);
    assert_eq!(bad[0].1, e);
    // An empty frame 7E 7F.
    let (_, bad, _) = deframe(None, &[0x7E, 0x7F]);
    assert_eq!(
        bad[0].1.to_string(),
        "truncated frame: a B800 frame (FG1 DA CMD CS FG2) needs 8 bytes, got 2"
    );
    // Missing flags.
    assert_eq!(
        Request::parse(&B1[1..]).unwrap_err().to_string(),
        "a B800 frame starts with the start flag FG1 7E"
    );
    assert_eq!(
        Request::parse(&B1[..7]).unwrap_err().to_string(),
        "a B800 frame ends with the stop flag FG2 7F"
    );
    assert!(matches!(Request::parse(&[]), Err(FrameError::Truncated { .. })));
    assert!(matches!(Request::parse(&[0x7E]), Err(FrameError::Truncated { .. })));
}

#[test]
fn overlong_candidates_are_bounded() {
    let mut stream = Vec::from([0x7E]);
    stream.extend_from_slice(&[b'0'; 40]);
    stream.extend_from_slice(&B1);
    let (good, bad, _) = deframe(None, &stream);
    assert_eq!(good, [B1.to_vec()]);
    assert_eq!(bad.len(), 1);
    assert_eq!(bad[0].0.len(), SCAN_LIMIT);
    assert_eq!(
        bad[0].1.to_string(),
        "frame too long: a B800 frame (no stop flag 7F) allows at most 12 bytes, got 32"
    );
}

#[test]
fn unknown_command_letters() {
    let e = Request::parse(&frame_of(b"8158")).unwrap_err(); // 'X'
    assert_eq!(e, FrameError::Unknown { field: CMD_FIELD, value: 0x58 });
    assert_eq!(e.to_string(), "unknown CMD 0x58");
    // A reply letter in a master frame.
    assert_eq!(Request::parse(&frame_of(b"8172")).unwrap_err().to_string(), "unknown CMD 0x72");
    // A command letter in a drive frame.
    assert_eq!(Reply::parse(&frame_of(b"0152")).unwrap_err().to_string(), "unknown REPLY 0x52");
}

#[test]
fn wrong_data_lengths() {
    // P without its word.
    assert_eq!(
        Request::parse(&frame_of(b"8550")).unwrap_err().to_string(),
        "truncated frame: the DATA of P (set new speed in Hz) needs 2 bytes, got 0"
    );
    // P with one byte.
    assert_eq!(
        Request::parse(&frame_of(b"855009")).unwrap_err().to_string(),
        "truncated frame: the DATA of P (set new speed in Hz) needs 2 bytes, got 1"
    );
    // R with data.
    assert_eq!(
        Request::parse(&frame_of(b"81520000")).unwrap_err().to_string(),
        "frame too long: the DATA of R (run command) allows at most 0 bytes, got 2"
    );
    // a without its word, t with three bytes.
    assert_eq!(
        Reply::parse(&frame_of(b"0161")).unwrap_err().to_string(),
        "truncated frame: the DATA of a (motor current) needs 2 bytes, got 0"
    );
    assert_eq!(
        Reply::parse(&frame_of(b"0174000093")).unwrap_err().to_string(),
        "frame too long: the DATA of t (drive status returned) allows at most 2 bytes, got 3"
    );
    // e without a code, e with three bytes.
    assert_eq!(
        Reply::parse(&frame_of(b"0165")).unwrap_err().to_string(),
        "truncated frame: the DATA of e (error code) needs 1 bytes, got 0"
    );
    assert_eq!(
        Reply::parse(&frame_of(b"0165000095")).unwrap_err().to_string(),
        "frame too long: the DATA of e (error code) allows at most 2 bytes, got 3"
    );
    // The scanner passes them (their CS is good): the parser names the problem.
    let (good, bad, _) = deframe(None, &frame_of(b"81520000"));
    assert_eq!((good.len(), bad.len()), (1, 0));
}

#[test]
fn drive_address_byte() {
    // A master frame must not carry a drive's DA, and the other way round.
    assert_eq!(
        Request::parse(&B5).unwrap_err().to_string(),
        "a DA of 01-3F is a drive's reply: a master sends the drive number + 128 (81-BF) or G"
    );
    assert_eq!(
        Reply::parse(&B1).unwrap_err().to_string(),
        "a DA of 81-BF or G is a master's frame: a drive replies with its plain number 01-3F"
    );
    // DA 80, C0: drive numbers 0 and 64.
    assert_eq!(
        Packet::parse(&frame_of(b"8052")).unwrap_err().to_string(),
        "drive address (DA - 128) 0 is not allowed (1..63)"
    );
    assert_eq!(
        Packet::parse(&frame_of(b"C052")).unwrap_err().to_string(),
        "drive address (DA - 128) 64 is not allowed (1..63)"
    );
    assert_eq!(
        Packet::parse(&frame_of(b"0072")).unwrap_err().to_string(),
        "drive address 0 is not allowed (1..63)"
    );
    assert_eq!(Packet::parse(&frame_of(b"4872")).unwrap_err().to_string(), "unknown DA 0x48");
}

#[test]
fn scanner_direction_filter() {
    let mut stream = B1.to_vec(); // master
    stream.extend_from_slice(&B5); // drive
    stream.extend_from_slice(&B3); // master, global
    stream.extend_from_slice(&B6); // drive
    let (all, _, _) = deframe(None, &stream);
    assert_eq!(all.len(), 4);
    let (from_master, _, s) = deframe(Some(Direction::Master), &stream);
    assert_eq!(from_master, [B1.to_vec(), B3.to_vec()]);
    assert_eq!(s.dropped_bytes, 16);
    let (from_drive, _, _) = deframe(Some(Direction::Drive), &stream);
    assert_eq!(from_drive, [B5.to_vec(), B6.to_vec()]);
    // A damaged frame is reported whichever side it seems to come from.
    let mut bad = B5;
    bad[5] = b'0';
    let (_, rejected, _) = deframe(Some(Direction::Master), &bad);
    assert_eq!(rejected.len(), 1);
}

#[test]
fn scanner_contract_on_every_prefix() {
    let s = FrameScanner::new(None);
    let mut stream = B2.to_vec();
    stream.extend_from_slice(&B1);
    // Every prefix of a frame is Incomplete with checked <= its length; the whole is a Frame.
    let mut checked = 0;
    for n in 1..B2.len() {
        match s.scan(&stream[..n], checked) {
            Scan::Incomplete { checked: c } => {
                assert!(c <= n);
                checked = c;
            }
            other => panic!("prefix {n}: {other:?}"),
        }
    }
    assert_eq!(s.scan(&stream, checked), Scan::Frame { len: 12 });
    assert_eq!(s.scan(&stream, 0), Scan::Frame { len: 12 });
    assert_eq!(s.scan(b"abc\x7e", 0), Scan::Noise { len: 3 });
    assert_eq!(s.scan(b"abc", 0), Scan::Noise { len: 3 });
}

#[test]
fn finish_reports_a_frame_cut_off() {
    let mut d = Deframer::new(FrameScanner::new(None));
    d.push(&B2[..6], &mut |_| panic!("nothing yet"));
    let mut err = None;
    d.finish(&mut |e| {
        if let Event::Rejected { error, .. } = e {
            err = Some(error)
        }
    });
    assert_eq!(
        err.unwrap().to_string(),
        "truncated frame: a B800 frame (no stop flag 7F yet) needs 8 bytes, got 6"
    );
}

#[test]
fn every_split_gives_the_same_frames() {
    let mut stream = Vec::from(*b"\x00xx");
    stream.extend_from_slice(&B2);
    stream.extend_from_slice(&[0x7E, 0x38, 0x31, 0x01]);
    stream.extend_from_slice(&E95);
    stream.extend_from_slice(&[0x7E, 0x38, 0x31, 0x35, 0x32, 0x32, 0x45, 0x7F]); // bad CS
    stream.extend_from_slice(&B1);
    let whole = deframe(None, &stream);
    assert_eq!(whole.0, [B2.to_vec(), E95.to_vec(), B1.to_vec()]);
    assert_eq!(whole.1.len(), 2);
    for i in 0..stream.len() {
        for j in i..stream.len() {
            let mut d = Deframer::new(FrameScanner::new(None));
            let mut good = Vec::new();
            let mut bad = Vec::new();
            for part in [&stream[..i], &stream[i..j], &stream[j..]] {
                d.push(part, &mut |e| match e {
                    Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
                    Event::Rejected { bytes, error, .. } => bad.push((bytes.to_vec(), error)),
                });
            }
            assert_eq!(good, whole.0, "split {i} {j}");
            assert_eq!(bad, whole.1, "split {i} {j}");
            assert_eq!(d.stats(), whole.2, "split {i} {j}");
        }
    }
}

// ---------------------------------------------------------------------------------------
// Codec and Describe
// ---------------------------------------------------------------------------------------

fn fields_of(f: &Frame<'_>) -> Vec<std::string::String> {
    let mut v = Vec::new();
    f.fields(&mut |field: Field<'_>| v.push(field.to_string()));
    v
}

#[test]
fn codec_describes_frames() {
    assert_eq!(<B800 as Codec>::NAME, "b800");
    let f = <B800 as Codec>::parse(&B2, None).unwrap();
    assert_eq!(f.direction(), Direction::Master);
    assert_eq!(f.target(), Target::Unit(5));
    assert_eq!(f.command().to_string(), "P set new speed in Hz");
    assert!(!f.is_refusal());
    assert_eq!(fields_of(&f), ["DA 85 (drive address + 128)", "target speed 0960 = 40.00 Hz", "CS 5E"]);

    // The bytes decide the direction, whatever `from` says.
    let f = <B800 as Codec>::parse(&B3, Some(Direction::Drive)).unwrap();
    assert_eq!((f.direction(), f.target()), (Direction::Master, Target::Broadcast));
    assert_eq!(fields_of(&f), ["DA 47 (global 'G')", "CS 2D"]);

    let f = <B800 as Codec>::parse(&E95, None).unwrap();
    assert_eq!((f.direction(), f.target()), (Direction::Drive, Target::Unit(1)));
    assert_eq!(f.command().to_string(), "e error: command not executed");
    assert!(f.is_refusal());
    assert_eq!(
        fields_of(&f),
        ["DA 01 (drive address)", "error code 95 (invalid data: incorrect checksum)", "CS C5"]
    );

    let cases: [(&[u8], &[&str]); 6] = [
        (b"01610023", &["DA 01 (drive address)", "motor current 0023 = 3.5 A"]),
        (b"017A0960", &["DA 01 (drive address)", "speed in Hz 0960 = 40.00 Hz"]),
        (b"016D05DC", &["DA 01 (drive address)", "speed in RPM 05DC = 1500 rpm"]),
        (b"0174039A", &["DA 01 (drive address)", "drive status 039A", "trip code 03", "state 9A (tripped)"]),
        (b"01740093", &["DA 01 (drive address)", "drive status 0093", "state 93 (running)"]),
        (b"01760100", &["DA 01 (drive address)", "software version 0100 (BCD)"]),
    ];
    for (chars, want) in cases {
        let wire = frame_of(chars);
        let f = <B800 as Codec>::parse(&wire, None).unwrap();
        let got = fields_of(&f);
        assert_eq!(&got[..got.len() - 1], want);
        assert_eq!(got.last().unwrap(), &format!("CS {:02X}", f.cs()));
    }
    // Lower-case digits: CS shows as carried.
    let f = <B800 as Codec>::parse(&[0x7E, 0x62, 0x66, 0x35, 0x61, 0x61, 0x31, 0x7F], None).unwrap();
    assert_eq!(fields_of(&f), ["DA BF (drive address + 128)", "CS A1"]);
    // Codec scanners: both sides, or one.
    assert_eq!(<B800 as Codec>::scanner(None).from(), None);
    assert_eq!(<B800 as Codec>::scanner(Some(Direction::Drive)).from(), Some(Direction::Drive));
}

// ---------------------------------------------------------------------------------------
// Protocol: addressing and the rejected-frame rule
// ---------------------------------------------------------------------------------------

#[test]
fn disposition_by_address() {
    let p = B800;
    let to1 = Request::to_drive(a(1), MasterCommand::Status);
    assert_eq!(p.disposition(&to1, 1), Disposition::Mine);
    assert_eq!(p.disposition(&to1, 2), Disposition::NotMine);
    assert_eq!(
        p.disposition(&Request::global(MasterCommand::Stop), 7),
        Disposition::Broadcast { reply: false }
    );
    assert_eq!(p.pending(&Request::global(MasterCommand::Stop)), None);
    assert_eq!(p.pending(&to1), Some(Pending { from: a(1), reply: b't' }));
}

#[test]
fn bad_checksum_for_this_drive_gets_e95() {
    let p = B800;
    // B1 with a wrong CS, to drive 1.
    let wire = [0x7E, 0x38, 0x31, 0x35, 0x32, 0x32, 0x45, 0x7F];
    let e = Request::parse(&wire).unwrap_err();
    assert_eq!(p.rejected_disposition(&wire, &e, 1), Disposition::Mine);
    assert_eq!(
        p.rejected_reply(&wire, &e, 1),
        Some(Reply::new(a(1), SlaveReply::error(ErrorCode::BAD_CHECKSUM)))
    );
    // For another drive, or global: silence.
    assert_eq!(p.rejected_disposition(&wire, &e, 2), Disposition::NotMine);
    let global = [0x7E, 0x34, 0x37, 0x35, 0x32, 0x32, 0x45, 0x7F];
    let e = Request::parse(&global).unwrap_err();
    assert_eq!(p.rejected_disposition(&global, &e, 1), Disposition::NotMine);
    // A frame cut short by a non-hex byte is not answered (the seed: "a new sequence must
    // be started").
    let cut = [0x7E, 0x38, 0x31, 0x01];
    let e = FrameError::NonHex { byte: 0x01, offset: 3 };
    assert_eq!(p.rejected_disposition(&cut, &e, 1), Disposition::NotMine);
    // An unknown command for this drive gets e 97 (project decision).
    let x = frame_of(b"8158");
    let e = Request::parse(&x).unwrap_err();
    assert_eq!(p.rejected_disposition(&x, &e, 1), Disposition::Mine);
    assert_eq!(p.rejected_reply(&x, &e, 1).unwrap().reply, SlaveReply::error(ErrorCode::UNKNOWN_COMMAND));
    // A wrong DATA length is not answered.
    let r = frame_of(b"81520000");
    let e = Request::parse(&r).unwrap_err();
    assert_eq!(p.rejected_disposition(&r, &e, 1), Disposition::NotMine);
}

#[test]
fn timing_defaults() {
    let t = default_timing();
    assert_eq!(t.response_timeout, Duration::from_millis(100));
    // 10 bits at 9600 bps.
    assert_eq!(t.char_time.as_micros(), 1041);
    assert_eq!(t.min_gap, t.char_time);
    assert_eq!(timing(19200, FORMAT).char_time.as_micros(), 520);
}

// ---------------------------------------------------------------------------------------
// Sessions on a virtual clock
// ---------------------------------------------------------------------------------------

const DRIVE_DELAY: Duration = Duration::from_millis(2);

/// A drive numbered 1 in keypad mode, stopped: answers everything it is asked.
fn drive_1(_now: Instant, incoming: Incoming<'_, Request>, out: &mut Responder<'_, B800>) {
    let reply = match incoming {
        Incoming::Request { request, .. } => match request.cmd {
            MasterCommand::Run => SlaveReply::Run,
            MasterCommand::Stop => SlaveReply::Stop,
            MasterCommand::MotorCurrent => SlaveReply::MotorCurrent(Current::from_raw(45)),
            MasterCommand::SpeedHz => SlaveReply::SpeedHz(Speed::from_raw(0x0960)),
            MasterCommand::SpeedRpm => SlaveReply::SpeedRpm(Rpm::from_raw(1500)),
            MasterCommand::Status => SlaveReply::Status(DriveStatus::new(DriveState::Standby)),
            MasterCommand::Version => SlaveReply::Version(Version::new(1, 0).unwrap()),
            MasterCommand::SetSpeed(_) => SlaveReply::SetSpeed,
            MasterCommand::Increase => SlaveReply::Increase,
            MasterCommand::Reduce => SlaveReply::Reduce,
        },
        Incoming::Rejected { bytes, error } => match B800.rejected_reply(bytes, &error, 1) {
            Some(r) => r.reply,
            None => return,
        },
    };
    out.reply(&Reply::new(a(1), reply)).unwrap();
}

fn pair_up() -> (MasterSession<B800>, SlaveSession<B800>) {
    (MasterSession::new(B800, default_timing()), SlaveSession::new(B800, 1, DRIVE_DELAY))
}

/// Sends `req` at `now`; returns the bytes the master wrote and when they left.
fn transmit(m: &mut MasterSession<B800>, now: Instant, req: &Request) -> (Vec<u8>, Instant) {
    m.send(now, req).unwrap();
    let bytes = m.poll_transmit(now).expect("line is free").to_vec();
    let end = now + default_timing().char_time * bytes.len() as u32;
    (bytes, end)
}

#[test]
fn session_request_and_reply() {
    let (mut m, mut s) = pair_up();
    let t0 = Instant::from_millis(10);
    let req = Request::to_drive(a(1), MasterCommand::SetSpeed(Speed::from_hz(40.0).unwrap()));
    let (wire, t1) = transmit(&mut m, t0, &req);
    assert_eq!(wire, B2_TO_1);
    s.handle_input(t1, &wire, &mut drive_1);
    assert_eq!(s.poll_transmit(t1), None, "the drive waits its response delay");
    assert_eq!(s.poll_timeout(), Some(t1 + DRIVE_DELAY));
    let reply = s.poll_transmit(t1 + DRIVE_DELAY).unwrap().to_vec();
    assert_eq!(reply, frame_of(b"0170"));
    let t2 = t1 + DRIVE_DELAY + Duration::from_millis(8);
    m.handle_input(t2, &reply);
    assert_eq!(m.poll_event(), Some(MasterEvent::Reply(Reply::new(a(1), SlaveReply::SetSpeed))));
    assert!(m.is_idle());
    assert_eq!(m.stats().replies, 1);
    assert_eq!(s.stats().requests, 1);
    assert_eq!(s.stats().replies, 1);

    // Every command gets its reply through the sessions.
    let mut now = t2 + Duration::from_millis(5);
    for cmd in [
        MasterCommand::Run,
        MasterCommand::Stop,
        MasterCommand::MotorCurrent,
        MasterCommand::SpeedHz,
        MasterCommand::SpeedRpm,
        MasterCommand::Status,
        MasterCommand::Version,
        MasterCommand::Increase,
        MasterCommand::Reduce,
    ] {
        let (wire, sent) = transmit(&mut m, now, &Request::to_drive(a(1), cmd));
        s.handle_input(sent, &wire, &mut drive_1);
        let rep = s.poll_transmit(sent + DRIVE_DELAY).unwrap().to_vec();
        now = sent + DRIVE_DELAY + Duration::from_millis(10);
        m.handle_input(now, &rep);
        match m.poll_event() {
            Some(MasterEvent::Reply(r)) => assert_eq!(r.reply.letter(), cmd.reply_letter()),
            other => panic!("{cmd:?}: {other:?}"),
        }
        now = now + Duration::from_millis(5);
    }
}

/// B2's command sent to drive 1: 7E "81" "50" "0960" CS 62 7F.
const B2_TO_1: [u8; 12] = [0x7E, 0x38, 0x31, 0x35, 0x30, 0x30, 0x39, 0x36, 0x30, 0x36, 0x32, 0x7F];

#[test]
fn session_other_drive_ignores_the_request() {
    let (mut m, _) = pair_up();
    let mut s2 = SlaveSession::new(B800, 2, DRIVE_DELAY);
    let (wire, t1) = transmit(&mut m, Instant::ZERO, &Request::to_drive(a(1), MasterCommand::Run));
    let mut called = false;
    s2.handle_input(t1, &wire, &mut |_, _, _: &mut Responder<'_, B800>| called = true);
    assert!(!called);
    assert_eq!(s2.poll_timeout(), None);
    assert_eq!(s2.stats().ignored, 1);
}

#[test]
fn session_drive_hears_other_drives_replies_as_noise() {
    let mut s = SlaveSession::new(B800, 1, DRIVE_DELAY);
    let mut called = false;
    s.handle_input(Instant::ZERO, &B6, &mut |_, _, _: &mut Responder<'_, B800>| called = true);
    assert!(!called);
    assert_eq!(s.stats().invalid, 0);
    assert_eq!(s.stats().deframer.dropped_bytes, 8);
}

#[test]
fn session_global_gets_no_reply() {
    let (mut m, mut s) = pair_up();
    let (wire, t1) = transmit(&mut m, Instant::ZERO, &Request::global(MasterCommand::Run));
    assert_eq!(wire, B3);
    let mut seen = None;
    s.handle_input(t1, &wire, &mut |now, inc, out: &mut Responder<'_, B800>| {
        if let Incoming::Request { request, broadcast } = inc {
            seen = Some((request, broadcast, out.may_reply()));
        }
        drive_1(
            now,
            Incoming::Request { request: Request::global(MasterCommand::Run), broadcast: true },
            out,
        );
    });
    assert_eq!(seen, Some((Request::global(MasterCommand::Run), true, false)));
    assert_eq!(s.poll_transmit(t1 + Duration::from_secs(1)), None, "no reply to a global command");
    let until = m.poll_timeout().unwrap();
    assert_eq!(until, t1 + default_timing().turnaround);
    m.handle_timeout(until);
    assert_eq!(m.poll_event(), Some(MasterEvent::BroadcastDone));
}

#[test]
fn session_timeout() {
    let (mut m, _) = pair_up();
    let (_, t1) = transmit(&mut m, Instant::ZERO, &Request::to_drive(a(9), MasterCommand::Status));
    let deadline = m.poll_timeout().unwrap();
    assert_eq!(deadline, t1 + Duration::from_millis(100));
    m.handle_timeout(Instant(deadline.0 - 1));
    assert_eq!(m.poll_event(), None);
    m.handle_timeout(deadline);
    assert_eq!(m.poll_event(), Some(MasterEvent::Timeout));
    assert_eq!(m.stats().timeouts, 1);
}

#[test]
fn session_corrupt_reply() {
    let (mut m, mut s) = pair_up();
    let (wire, t1) = transmit(&mut m, Instant::ZERO, &Request::to_drive(a(1), MasterCommand::Run));
    s.handle_input(t1, &wire, &mut |_, _, out: &mut Responder<'_, B800>| {
        // B5 with its CS damaged: "34" instead of "35".
        out.reply_raw(&[0x7E, 0x30, 0x31, 0x37, 0x32, 0x33, 0x34, 0x7F]).unwrap();
    });
    let rep = s.poll_transmit(t1 + DRIVE_DELAY).unwrap().to_vec();
    m.handle_input(t1 + Duration::from_millis(10), &rep);
    let ev = m.poll_event().unwrap();
    assert_eq!(
        ev,
        MasterEvent::Corrupt(FrameError::ChecksumMismatch {
            kind: ChecksumKind::Cs,
            carried: 0x34,
            computed: 0x35,
            hint: None
        })
    );
    assert_eq!(m.stats().corrupt, 1);
}

#[test]
fn session_error_reply_is_a_reply() {
    let (mut m, _) = pair_up();
    let (_, t1) = transmit(&mut m, Instant::ZERO, &Request::to_drive(a(1), MasterCommand::SpeedRpm));
    // 01 'e' 92: speed in RPM not available.
    m.handle_input(t1 + Duration::from_millis(5), &frame_of(b"016592"));
    assert_eq!(
        m.poll_event(),
        Some(MasterEvent::Reply(Reply::new(a(1), SlaveReply::error(ErrorCode::RPM_NOT_AVAILABLE))))
    );
}

#[test]
fn session_ignores_replies_that_do_not_match() {
    let (mut m, _) = pair_up();
    let (_, t1) = transmit(&mut m, Instant::ZERO, &Request::to_drive(a(1), MasterCommand::Run));
    // Its own echo (a master frame), drive 5's p, drive 1's s: none answers R to drive 1.
    m.handle_input(t1, &B1);
    m.handle_input(t1 + Duration::from_millis(1), &B6);
    m.handle_input(t1 + Duration::from_millis(2), &frame_of(b"0173"));
    assert_eq!(m.poll_event(), None);
    assert_eq!(m.stats().unexpected, 2);
    m.handle_input(t1 + Duration::from_millis(3), &B5);
    assert_eq!(m.poll_event(), Some(MasterEvent::Reply(Reply::new(a(1), SlaveReply::Run))));
}

#[test]
fn session_bad_checksum_gets_e95_and_unknown_command_e97() {
    let mut s = SlaveSession::new(B800, 1, DRIVE_DELAY);
    // B1 with CS 2E: the drive answers e 95.
    s.handle_input(Instant::ZERO, &[0x7E, 0x38, 0x31, 0x35, 0x32, 0x32, 0x45, 0x7F], &mut drive_1);
    let rep = s.poll_transmit(Instant::ZERO + DRIVE_DELAY).unwrap().to_vec();
    assert_eq!(rep, E95);
    // To drive 2 with a bad CS: nothing.
    s.handle_input(Instant::ZERO, &[0x7E, 0x38, 0x32, 0x35, 0x32, 0x32, 0x45, 0x7F], &mut drive_1);
    assert_eq!(s.poll_timeout(), None);
    // 'X' to drive 1: e 97.
    s.handle_input(Instant::ZERO, &frame_of(b"8158"), &mut drive_1);
    let rep = s.poll_transmit(Instant::ZERO + DRIVE_DELAY).unwrap().to_vec();
    assert_eq!(Reply::parse(&rep), Ok(Reply::new(a(1), SlaveReply::error(ErrorCode::UNKNOWN_COMMAND))));
}

#[test]
fn session_keeps_the_minimum_gap() {
    let (mut m, _) = pair_up();
    let t = default_timing();
    let (_, t1) = transmit(&mut m, Instant::ZERO, &Request::to_drive(a(1), MasterCommand::Run));
    let heard = t1 + Duration::from_millis(5);
    m.handle_input(heard, &B5);
    assert!(matches!(m.poll_event(), Some(MasterEvent::Reply(_))));
    assert_eq!(m.ready_at(), heard + t.min_gap);
    m.send(heard, &Request::to_drive(a(1), MasterCommand::Status)).unwrap();
    assert_eq!(m.poll_transmit(heard), None, "one character of silence first");
    assert_eq!(m.poll_timeout(), Some(heard + t.min_gap));
    assert_eq!(m.poll_transmit(Instant((heard + t.min_gap).0 - 1)), None);
    assert!(m.poll_transmit(heard + t.min_gap).is_some());
}
