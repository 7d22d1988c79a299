//! Binary mode against the manuals' examples.

use super::*;
use crate::checksum::sum8;
use crate::deframe::{Deframer, Event};
use crate::describe::{Describe, Target};
use crate::toshiba::ErrorCode;
use std::string::{String, ToString};
use std::vec::Vec;

fn emit(f: &BinaryFrame) -> Vec<u8> {
    let mut b = [0u8; 32];
    let n = f.emit(&mut b).unwrap();
    b[..n].to_vec()
}

fn describe(f: &BinaryFrame) -> String {
    let mut s = String::new();
    f.fields(&mut |fl| {
        if !s.is_empty() {
            s.push_str(", ");
        }
        s.push_str(&fl.to_string());
    });
    s
}

type Rejections = Vec<(Vec<u8>, FrameError)>;

fn run(from: Option<Direction>, chunks: &[&[u8]]) -> (Vec<Vec<u8>>, Rejections) {
    let mut d = Deframer::new(BinaryScanner { from });
    let (mut good, mut bad) = (Vec::new(), Vec::new());
    for c in chunks {
        d.push(c, &mut |e| match e {
            Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
            Event::Rejected { bytes, error, .. } => bad.push((bytes.to_vec(), error)),
        });
    }
    (good, bad)
}

/// TB1: `2F 52 00 00 81`, R comm-no 0000 (manual VF-AS1 p.10).
#[test]
fn tb1_read() {
    let wire = [
        0x2F, // start code
        0x52, // 'R' (INV-NO omitted: 52H > 3FH is a command)
        0x00, 0x00, // COMNO 0000
        0x81, // SUM = 2F + 52 + 00 + 00
    ];
    let req = BinaryRequest::read(BinaryAddress::Omitted, CommNo(0));
    assert_eq!(emit(&BinaryFrame::Request(req)), wire);
    assert_eq!(BinaryRequest::parse(&wire), Ok(req));
    let f = BinaryCodec::parse(&wire, Some(Direction::Drive)).unwrap();
    assert_eq!(f, BinaryFrame::Request(req), "5-byte R is a request whatever `from` says");
    assert_eq!(f.command().to_string(), "R read");
    assert_eq!(f.target(), Target::Implicit);
    assert_eq!(describe(&f), "communication number 0000, SUM 81");
    for from in [None, Some(Direction::Master)] {
        assert_eq!(run(from, &[&wire]).0, [wire.to_vec()], "{from:?}");
    }
    // A master's reply scanner waits for the 7 bytes of a reply before it takes a request.
    assert!(run(Some(Direction::Drive), &[&wire]).0.is_empty());
    let two: Vec<u8> = wire.iter().chain(&wire).copied().collect();
    assert_eq!(run(Some(Direction::Drive), &[&two]).0, [wire.to_vec()]);
}

/// TB2: `2F 57 00 10 00 64 FA`, W deceleration time = 100 (10.0 s); the reply is identical.
#[test]
fn tb2_write_echo() {
    let wire = [
        0x2F, // start code
        0x57, // 'W' write RAM and EEPROM
        0x00, 0x10, // COMNO 0010 deceleration time
        0x00, 0x64, // DATA 100 = 10.0 s
        0xFA, // SUM
    ];
    let req = BinaryRequest::write(BinaryAddress::Omitted, CommNo::DECELERATION_TIME, 100);
    assert_eq!(emit(&BinaryFrame::Request(req)), wire);
    assert_eq!(BinaryCodec::parse(&wire, None), Ok(BinaryFrame::Request(req)));
    let rep = req.reply(0, false, 100).unwrap();
    assert_eq!(emit(&BinaryFrame::Reply(rep)), wire);
    assert_eq!(BinaryReply::parse(&wire), Ok(rep));
    assert_eq!(rep.value(), Some(10.0));
    assert_eq!(
        describe(&BinaryFrame::Reply(rep)),
        "tripped 0, communication number 0010 (deceleration time), data 0064 = 10.0 s, SUM FA"
    );
    assert!(TipBinary::default().pending(&req).unwrap().matches(&rep));
}

/// TB9–TB12: the manual's error replies (VF-S11 p.15).
#[test]
fn tb9_to_tb12_error_replies() {
    for (wire, code, name) in [
        ([0x2F, 0x4E, 0x00, 0x00, 0x7D], 0, "impossible to execute"), // TB9
        ([0x2F, 0x4E, 0x00, 0x01, 0x7E], 1, "data error"),            // TB10
        ([0x2F, 0x4E, 0x00, 0x02, 0x7F], 2, "communication number error"), // TB11
        ([0x2F, 0x4E, 0x00, 0x04, 0x81], 4, "checksum error"),        // TB12
    ] {
        // 2F start, 4E 'N' error, 2-byte error code, SUM.
        let rep = BinaryReply { inv_no: None, tripped: false, body: BinaryReplyBody::Error(ErrorCode(code)) };
        assert_eq!(emit(&BinaryFrame::Reply(rep)), wire);
        let f = BinaryCodec::parse(&wire, None).unwrap();
        assert_eq!(f, BinaryFrame::Reply(rep));
        assert!(f.is_refusal());
        assert_eq!(
            describe(&f),
            std::format!("tripped 0, error code 000{code} ({name}), SUM {:02X}", wire[4])
        );
        assert_eq!(run(Some(Direction::Drive), &[&wire]).0, [wire.to_vec()]);
    }
    // Tripped: 6E.
    let rep = BinaryReply::parse(&[0x2F, 0x6E, 0x00, 0x00, 0x9D]).unwrap();
    assert!(rep.tripped);
    assert_eq!(rep.error(), Some(ErrorCode::IMPOSSIBLE_TO_EXECUTE));
}

/// TB14: block write with a wrong SUM (D8, the correct one is D9): the drive answers
/// `2F 4E 00 04 81` (manual VF-AS1 p.16).
#[test]
fn tb14_block_checksum_error() {
    let wire = [
        0x2F, // start code
        0x58, // 'X' block communication
        0x02, // nW: 2 write groups
        0x05, // nR: 5 read groups
        0xC4, 0x00, // WDATA1 -> FA00: command priority, frequency priority, run
        0x17, 0x70, // WDATA2 -> FA01: 6000 = 60.00 Hz
        0xD8, // SUM as printed; 2F+58+02+05+C4+00+17+70 = 2D9 -> D9
    ];
    let (good, bad) = run(Some(Direction::Master), &[&wire]);
    assert!(good.is_empty());
    assert_eq!(bad[0].0, wire);
    assert_eq!(bad[0].1.to_string(), "SUM mismatch: frame carries D8, computed D9");
    assert_eq!(TipBinary::default().rejected_disposition(&wire, 0), Disposition::Mine);
    let rep = rejection_reply(&wire, 0, false).unwrap();
    assert_eq!(emit(&BinaryFrame::Reply(rep)), [0x2F, 0x4E, 0x00, 0x04, 0x81]);

    let mut fixed = wire;
    fixed[8] = 0xD9;
    let req = BinaryRequest::parse(&fixed).unwrap();
    let block = BlockRequest::new(&[0xC400, 0x1770], 5).unwrap();
    assert_eq!(req, BinaryRequest::block(BinaryAddress::Omitted, block));
    assert_eq!(emit(&BinaryFrame::Request(req)), fixed);
    assert_eq!(
        describe(&BinaryFrame::Request(req)),
        "nW 2, nR 5, WDATA1 C400, command priority 1, frequency priority 1, run 1, WDATA2 1770 = 60.00 Hz, SUM D9"
    );
    assert_eq!(BinaryFrame::Request(req).command().to_string(), "X block communication");
}

#[test]
fn block_reply() {
    let req = BinaryRequest::block(BinaryAddress::Unit(1), BlockRequest::new(&[], 5).unwrap());
    let rep = req.block_reply(1, false, &[0x0400, 0x1770, 0x077B, 0x0000, 0x2710]).unwrap();
    let bytes = emit(&BinaryFrame::Reply(rep));
    // 2F, INV-NO 01, 'Y', nR 5, five words, SUM.
    assert_eq!(bytes[..4], [0x2F, 0x01, 0x59, 0x05]);
    assert_eq!(bytes.len(), 15);
    assert_eq!(bytes.len(), MAX_FRAME);
    assert_eq!(BinaryReply::parse(&bytes), Ok(rep));
    assert!(TipBinary::default().pending(&req).unwrap().matches(&rep));
    assert_eq!(
        describe(&BinaryFrame::Reply(rep)),
        std::format!(
            "INV-NO 01, tripped 0, nR 5, RDATA1 0400, running 1, RDATA2 1770 = 60.00 Hz, \
             RDATA3 077B = 19.15 %, RDATA4 0000, RDATA5 2710 = 100.00 %, SUM {:02X}",
            bytes[14]
        )
    );
    assert_eq!(run(Some(Direction::Drive), &[&bytes]).0, [&bytes[..]]);
    // nR over 5: the reply carries no read groups.
    let req = BinaryRequest::block(BinaryAddress::Omitted, BlockRequest::new(&[0xC400], 6).unwrap());
    let rep = req.block_reply(0, true, &[1, 2, 3]).unwrap();
    let bytes = emit(&BinaryFrame::Reply(rep));
    assert_eq!(bytes, [0x2F, 0x79, 0x00, 0xA8]);
    assert_eq!(BinaryReply::parse(&bytes), Ok(rep));
    // nW over 2 is a format error: no reply.
    let mut bad = [0x2F, 0x58, 0x03, 0x00, 0, 0, 0, 0, 0, 0, 0];
    let n = bad.len();
    bad[n - 1] = sum8(&bad[..n - 1]);
    let err = BinaryRequest::parse(&bad).unwrap_err();
    assert_eq!(err.to_string(), "nW (number of write data groups) 3 is not allowed (0..2)");
    assert_eq!(rejection_reply(&bad, 0, false), None);
    let (good, rejected) = run(Some(Direction::Master), &[&bad]);
    assert!(good.is_empty());
    assert_eq!(rejected[0].1, err);
}

#[test]
fn inv_no_and_broadcast() {
    let req = BinaryRequest::read(BinaryAddress::Unit(0x3F), CommNo::OUTPUT_FREQUENCY);
    let bytes = emit(&BinaryFrame::Request(req));
    assert_eq!(bytes, [0x2F, 0x3F, 0x52, 0xFD, 0x00, 0xBD]);
    assert_eq!(BinaryRequest::parse(&bytes), Ok(req));
    let bc = BinaryRequest::write_ram(BinaryAddress::Broadcast, CommNo::FREQUENCY_COMMAND, 0x1770);
    let bytes = emit(&BinaryFrame::Request(bc));
    assert_eq!(bytes[..3], [0x2F, 0xFF, 0x50]);
    assert_eq!(BinaryRequest::parse(&bytes), Ok(bc));
    assert_eq!(BinaryFrame::Request(bc).target(), Target::Broadcast);
    assert_eq!(bc.inv_no.disposition(0), Disposition::Broadcast { reply: true });
    assert_eq!(bc.inv_no.disposition(5), Disposition::Broadcast { reply: false });
    assert_eq!(req.inv_no.disposition(0x3F), Disposition::Mine);
    assert_eq!(req.inv_no.disposition(1), Disposition::NotMine);
    // Inverter 00 answers with its own number.
    let rep = bc.reply(0, false, 0x1770).unwrap();
    assert_eq!(rep.inv_no, Some(0));
    assert!(TipBinary::default().pending(&bc).unwrap().matches(&rep));
    assert_eq!(TipBinary { broadcast_reply: false }.pending(&bc), None);
    // A reply never carries FF.
    let mut fake = [0x2F, 0xFF, 0x72, 0xFD, 0x00, 0x17, 0x70, 0];
    fake[7] = sum8(&fake[..7]);
    assert_eq!(
        BinaryReply::parse(&fake),
        Err(FrameError::Malformed("a reply carries the inverter's own number, never the broadcast FF"))
    );
    let mut b = [0u8; 16];
    assert_eq!(
        BinaryRequest::read(BinaryAddress::Unit(0x40), CommNo(0)).emit(&mut b),
        Err(EmitError::OutOfRange { field: "INV-NO", value: 0x40, min: 0, max: 0x3F })
    );
}

#[test]
fn tripped_and_g() {
    let req = BinaryRequest::read_dummy(BinaryAddress::Unit(2), CommNo::OUTPUT_FREQUENCY);
    let bytes = emit(&BinaryFrame::Request(req));
    assert_eq!(bytes[..7], [0x2F, 0x02, 0x47, 0xFD, 0x00, 0x00, 0x00]);
    assert_eq!(BinaryRequest::parse(&bytes), Ok(req));
    let rep = req.reply(2, true, 0x1770).unwrap();
    let bytes = emit(&BinaryFrame::Reply(rep));
    assert_eq!(bytes[2], 0x67, "g: G + 20H while tripped");
    let f = BinaryCodec::parse(&bytes, None).unwrap();
    assert_eq!(f, BinaryFrame::Reply(rep), "lower case is a drive's whatever `from` says");
    assert_eq!(BinaryReply::parse(&bytes).unwrap().hz(), Some(60.0));
    assert_eq!(f.command().to_string(), "g read (dummy data)");
    // r: a tripped R reply.
    let rep = BinaryRequest::read(BinaryAddress::Omitted, CommNo::TRIP_CODE).reply(0, true, 0x18).unwrap();
    let bytes = emit(&BinaryFrame::Reply(rep));
    assert_eq!(bytes[..6], [0x2F, 0x72, 0xFC, 0x90, 0x00, 0x18]);
    assert_eq!(
        BinaryRequest::parse(&bytes),
        Err(FrameError::Malformed("a reply from a tripped drive (lower-case CMD), not a request"))
    );
}

#[test]
fn unknown_command_gets_no_reply() {
    let wire = [0x2F, 0x41, 0x00, 0x00, 0x70];
    let err = BinaryRequest::parse(&wire).unwrap_err();
    assert_eq!(err.to_string(), "unknown binary-mode CMD 0x41");
    assert_eq!(rejection_reply(&wire, 0, false), None);
    assert_eq!(TipBinary::default().rejected_disposition(&wire, 0), Disposition::NotMine);
    let (good, bad) = run(Some(Direction::Master), &[&wire]);
    assert!(good.is_empty());
    assert_eq!(bad.len(), 1);
}

#[test]
fn r_lengths_by_direction() {
    let request = [0x2F, 0x52, 0xFD, 0x00, 0x7E];
    let reply = [0x2F, 0x52, 0xFD, 0x00, 0x17, 0x70, 0x05];
    assert_eq!(sum8(&request[..4]), 0x7E);
    assert_eq!(sum8(&reply[..6]), 0x05);
    assert!(BinaryReply::parse(&request).is_err());
    assert_eq!(BinaryReply::parse(&reply).unwrap().hz(), Some(60.0));
    assert_eq!(
        BinaryRequest::parse(&reply),
        Err(FrameError::Malformed("a drive's reply to R (7 bytes without INV-NO), not a request"))
    );
    // A monitor hears both, back to back.
    let stream: Vec<u8> = request.iter().chain(&reply).copied().collect();
    assert_eq!(run(None, &[&stream]).0, [request.to_vec(), reply.to_vec()]);
    // A drive on a 2-wire line hears the other drive's reply as a whole frame.
    assert_eq!(run(Some(Direction::Master), &[&stream]).0, [request.to_vec(), reply.to_vec()]);
    assert_eq!(run(Some(Direction::Drive), &[&reply]).0, [reply.to_vec()]);
    // Odd lengths.
    assert_eq!(
        BinaryFrame::parse(&reply[..6], None).unwrap_err().to_string(),
        "truncated frame: an R frame needs 7 bytes, got 6"
    );
}

#[test]
fn last_start_code_counts() {
    // A stray 2F before a frame: 2F 2F reads as INV-NO 2F, whose SUM fails; the second
    // 2F starts a frame that checks out, and nothing is reported for the stray byte.
    let stream = [0x2F, 0x2F, 0x52, 0x00, 0x00, 0x81];
    let (good, bad) = run(Some(Direction::Master), &[&stream]);
    assert_eq!(good, [stream[1..].to_vec()]);
    assert!(bad.is_empty());
    // A cut-off frame (X, needs 9 bytes) followed by a whole R: the R is found at once.
    let stream = [0x2F, 0x58, 0x02, 0x2F, 0x52, 0x00, 0x00, 0x81];
    let (good, bad) = run(Some(Direction::Master), &[&stream]);
    assert_eq!(good, [stream[3..].to_vec()]);
    assert!(bad.is_empty());
    // 2F as data is kept: W 002F = 002F.
    let req = BinaryRequest::write(BinaryAddress::Omitted, CommNo(0x2F), 0x2F2F);
    let bytes = emit(&BinaryFrame::Request(req));
    assert_eq!(run(Some(Direction::Master), &[&bytes]).0, [&bytes[..]]);
    for i in 0..bytes.len() {
        assert_eq!(run(Some(Direction::Master), &[&bytes[..i], &bytes[i..]]).0, [&bytes[..]], "split {i}");
    }
}

#[test]
fn garbage_then_frames() {
    let a = [0x2F, 0x52, 0x00, 0x00, 0x81];
    let b = [0x2F, 0x57, 0x00, 0x10, 0x00, 0x64, 0xFA];
    let mut stream = Vec::new();
    stream.extend_from_slice(&[0x00, 0x13, 0x2F, 0x52, 0x00, 0x00, 0x80]); // bad SUM
    stream.extend_from_slice(&a);
    stream.extend_from_slice(&[0x99]);
    stream.extend_from_slice(&b);
    let (good, bad) = run(Some(Direction::Master), &[&stream]);
    assert_eq!(good, [a.to_vec(), b.to_vec()]);
    assert_eq!(bad.len(), 1);
    assert_eq!(bad[0].1.to_string(), "SUM mismatch: frame carries 80, computed 81");
    for i in 0..stream.len() {
        for j in i..stream.len() {
            let (g, _) = run(Some(Direction::Master), &[&stream[..i], &stream[i..j], &stream[j..]]);
            assert_eq!(g, good, "split {i} {j}");
        }
    }
}

#[test]
fn truncated_message() {
    let mut d = Deframer::new(BinaryScanner { from: Some(Direction::Master) });
    d.push(&[0x2F, 0x57, 0x00], &mut |_| {});
    let mut err = None;
    d.finish(&mut |e| {
        if let Event::Rejected { error, .. } = e {
            err = Some(error)
        }
    });
    assert_eq!(err.unwrap().to_string(), "truncated frame: a binary-mode frame needs 7 bytes, got 3");
}
