//! ASCII mode against the manuals' examples.

use super::*;
use crate::checksum::sum8;
use crate::deframe::{Deframer, Event};
use crate::describe::{Describe, Target};
use crate::error::EmitError;
use crate::toshiba::ErrorCode;
use std::format;
use std::string::{String, ToString};
use std::vec::Vec;

fn emit_req(r: &AsciiRequest) -> Vec<u8> {
    let mut b = [0u8; 32];
    let n = r.emit(&mut b).unwrap();
    b[..n].to_vec()
}

fn emit_rep(r: &AsciiReply) -> Vec<u8> {
    let mut b = [0u8; 32];
    let n = r.emit(&mut b).unwrap();
    b[..n].to_vec()
}

fn describe(f: &AsciiFrame) -> String {
    let mut s = String::new();
    f.fields(&mut |fl| {
        if !s.is_empty() {
            s.push_str(", ");
        }
        s.push_str(&fl.to_string());
    });
    s
}

fn frames(stream: &[u8]) -> (Vec<Vec<u8>>, Vec<FrameError>) {
    let mut d = Deframer::new(AsciiScanner);
    let (mut good, mut bad) = (Vec::new(), Vec::new());
    d.push(stream, &mut |e| match e {
        Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
        Event::Rejected { error, .. } => bad.push(error),
    });
    (good, bad)
}

/// TA4: `(RFE03)` CR, read output current (seeds/002_43d8a4399c8be05f.txt TOC: "RFE03CR").
#[test]
fn ta4_read_output_current() {
    let wire = [
        0x28, // '(' start code
        0x52, // 'R' read
        0x46, 0x45, 0x30, 0x33, // "FE03" COMNO: output current
        0x29, // ')' stop code
        0x0D, // CR
    ];
    let req = AsciiRequest::read(AsciiAddress::Omitted, CommNo::OUTPUT_CURRENT);
    assert_eq!(emit_req(&req), wire);
    assert_eq!(AsciiRequest::parse(&wire), Ok(req));
    let f = AsciiCodec::parse(&wire, None).unwrap();
    assert_eq!(f.direction(), Direction::Master);
    assert_eq!(f.target(), Target::Implicit);
    assert_eq!(f.command().to_string(), "R read");
    assert_eq!(describe(&f), "communication number FE03 (output current)");
}

/// TA5: `(RFE03077B)` CR, reply 077B = 19.15 % (seeds/002_43d8a4399c8be05f.txt TOC).
#[test]
fn ta5_reply_output_current() {
    let wire = [
        0x28, // '('
        0x52, // 'R' upper case: not tripped
        0x46, 0x45, 0x30, 0x33, // "FE03"
        0x30, 0x37, 0x37, 0x42, // "077B" DATA = 1915 = 19.15 %
        0x29, 0x0D, // ')' CR
    ];
    let rep = AsciiRequest::read(AsciiAddress::Omitted, CommNo::OUTPUT_CURRENT).reply(0, false, 0x077B);
    assert_eq!(emit_rep(&rep), wire);
    assert_eq!(AsciiReply::parse(&wire), Ok(rep));
    assert_eq!(rep.value(), Some(19.15));
    assert_eq!(rep.hz(), None);
    // R with DATA is a drive's, whatever the caller says.
    let f = AsciiCodec::parse(&wire, Some(Direction::Master)).unwrap();
    assert_eq!(f.direction(), Direction::Drive);
    assert_eq!(describe(&f), "tripped 0, communication number FE03 (output current), data 077B = 19.15 %");
    assert_eq!(
        AsciiRequest::parse(&wire),
        Err(FrameError::Malformed("a drive's reply (R with DATA), not a request"))
    );
}

/// TA7: `(W00100064)` CR writes deceleration time 10.0 s; the reply is the same bytes.
#[test]
fn ta7_write_decel_time_echo() {
    let wire = [
        0x28, // '('
        0x57, // 'W' write RAM and EEPROM
        0x30, 0x30, 0x31, 0x30, // "0010" deceleration time
        0x30, 0x30, 0x36, 0x34, // "0064" = 100 = 10.0 s
        0x29, 0x0D, // ')' CR
    ];
    let req = AsciiRequest::write(AsciiAddress::Omitted, CommNo::DECELERATION_TIME, 0x64);
    assert_eq!(emit_req(&req), wire);
    assert_eq!(AsciiCodec::parse(&wire, None), Ok(AsciiFrame::Request(req)));
    let rep = req.reply(0, false, 0x64);
    assert_eq!(emit_rep(&rep), wire);
    assert_eq!(AsciiCodec::parse(&wire, Some(Direction::Drive)), Ok(AsciiFrame::Reply(rep)));
    assert_eq!(
        describe(&AsciiFrame::Request(req)),
        "communication number 0010 (deceleration time), data 0064 = 10.0 s"
    );
}

/// TA13: `(*2R0000)` CR to every inverter ending in 2; only 02 answers `(02R00000000)` CR.
#[test]
fn ta13_wildcard() {
    let wire = [
        0x28, // '('
        0x2A, 0x32, // "*2" INV-NO wildcard: 02, 12, 22, ...
        0x52, // 'R'
        0x30, 0x30, 0x30, 0x30, // "0000" COMNO
        0x29, 0x0D, // ')' CR
    ];
    let inv_no = AsciiAddress::Wildcard { tens: None, units: Some(2) };
    let req = AsciiRequest::read(inv_no, CommNo(0));
    assert_eq!(emit_req(&req), wire);
    assert_eq!(AsciiRequest::parse(&wire), Ok(req));
    assert_eq!(inv_no.disposition(2), Disposition::Broadcast { reply: true });
    assert_eq!(inv_no.disposition(12), Disposition::Broadcast { reply: false });
    assert_eq!(inv_no.disposition(22), Disposition::Broadcast { reply: false });
    assert_eq!(inv_no.disposition(3), Disposition::NotMine);
    let rep = req.reply(2, false, 0);
    assert_eq!(emit_rep(&rep), b"(02R00000000)\r");
    assert!(TipAscii::default().pending(&req).unwrap().matches(&rep));
    assert_eq!(AsciiFrame::Request(req).target(), Target::Wildcard { tens: None, units: Some(2) });
}

#[test]
fn wildcard_smallest_number() {
    let w = |tens, units| AsciiAddress::Wildcard { tens, units };
    assert_eq!(w(None, Some(2)).reply_inv_no(), Some(2));
    assert_eq!(w(Some(1), None).reply_inv_no(), Some(10));
    assert_eq!(AsciiAddress::ALL.reply_inv_no(), Some(0));
    assert_eq!(w(Some(1), None).disposition(10), Disposition::Broadcast { reply: true });
    assert_eq!(w(Some(1), None).disposition(19), Disposition::Broadcast { reply: false });
    assert_eq!(w(Some(1), None).disposition(20), Disposition::NotMine);
    assert_eq!(AsciiAddress::ALL.disposition(0), Disposition::Broadcast { reply: true });
    assert_eq!(AsciiAddress::ALL.disposition(99), Disposition::Broadcast { reply: false });
    assert_eq!(AsciiAddress::ALL.disposition(100), Disposition::NotMine);
    assert_eq!(
        AsciiFrame::Request(AsciiRequest::read(AsciiAddress::ALL, CommNo(0))).target(),
        Target::Broadcast
    );
    assert_eq!(AsciiRequest::parse(b"(1*RFD00)\r").unwrap().inv_no, w(Some(1), None));
    assert_eq!(AsciiRequest::parse(b"(**RFD00)\r").unwrap().inv_no, AsciiAddress::ALL);
}

/// TA17 (negative): `(R11)` CR is a format error; a drive does not answer.
#[test]
fn ta17_r11_format_error() {
    let wire = b"(R11)\r";
    let err = AsciiRequest::parse(wire).unwrap_err();
    assert_eq!(
        err.to_string(),
        "format error: COMNO needs 4 hex digits before ')'; a drive reads ')' and CR as digits and does not answer"
    );
    assert_eq!(rejection_reply(wire, 0, false), None);
    assert_eq!(TipAscii::default().rejected_disposition(wire, 0), Disposition::NotMine);
    // The scanner frames it (it ends with CR), so the slave sees and ignores it.
    assert_eq!(frames(wire).0.len(), 1);
}

/// `(R0000&60)` CR: 28+52+30+30+30+30+26 = 160H, SUM = 60 (manual's rule).
#[test]
fn sum_example() {
    let wire = [
        0x28, 0x52, // '(' 'R'
        0x30, 0x30, 0x30, 0x30, // "0000"
        0x26, // '&' checksum discrimination code
        0x36, 0x30, // "60" SUM
        0x29, 0x0D, // ')' CR
    ];
    let req = AsciiRequest::read(AsciiAddress::Omitted, CommNo(0)).with_sum();
    assert_eq!(emit_req(&req), wire);
    assert_eq!(AsciiRequest::parse(&wire), Ok(req));
    assert_eq!(describe(&AsciiFrame::Request(req)), "communication number 0000, SUM 60");
    // The reply carries & and SUM because the request did.
    let rep = req.reply(0, false, 0x1234);
    let bytes = emit_rep(&rep);
    assert_eq!(bytes, b"(R00001234&2A)\r");
    assert_eq!(sum8(b"(R00001234&"), 0x2A);
    assert_eq!(AsciiReply::parse(&bytes), Ok(rep));
}

#[test]
fn checksum_mismatch_is_diagnosed_and_answered() {
    let wire = b"(R0000&61)\r";
    let (good, bad) = frames(wire);
    assert!(good.is_empty());
    assert_eq!(bad[0].to_string(), "SUM mismatch: frame carries 61, computed 60");
    // SUM over everything but '&' (a common mistake): 0x160 - 0x26 = 0x13A.
    let err = AsciiRequest::parse(b"(R0000&3A)\r").unwrap_err();
    assert_eq!(
        err.to_string(),
        "SUM mismatch: frame carries 3A, computed 60 (the carried SUM is that of the first 6 bytes only)"
    );
    // A drive answers a checksum error addressed to it: (N0004&..)CR, SUM kept.
    let rep = rejection_reply(wire, 0, false).unwrap();
    assert_eq!(rep.error(), Some(ErrorCode::CHECKSUM_ERROR));
    assert_eq!(emit_rep(&rep), b"(N0004&60)\r");
    assert_eq!(TipAscii::default().rejected_disposition(wire, 7), Disposition::Mine);
    // Addressed to another inverter: silence.
    assert_eq!(TipAscii::default().rejected_disposition(b"(05R0000&61)\r", 7), Disposition::NotMine);
    assert_eq!(TipAscii::default().rejected_disposition(b"(07R0000&61)\r", 7), Disposition::Mine);
    let rep = rejection_reply(b"(07R0000&61)\r", 7, true).unwrap();
    assert_eq!(emit_rep(&rep), b"(07n0004&E7)\r");
}

/// The error replies (N) with every manual code, and the tripped form (n).
#[test]
fn error_replies() {
    for (code, name) in [
        (0, "impossible to execute"),
        (1, "data error"),
        (2, "communication number error"),
        (3, "command error"),
        (4, "checksum error"),
    ] {
        let rep = AsciiReply {
            inv_no: None,
            tripped: false,
            body: AsciiReplyBody::Error(ErrorCode(code)),
            sum: false,
        };
        let bytes = emit_rep(&rep);
        assert_eq!(bytes, format!("(N000{code})\r").as_bytes());
        let f = AsciiCodec::parse(&bytes, Some(Direction::Master)).unwrap();
        assert!(f.is_refusal());
        assert_eq!(f.direction(), Direction::Drive);
        assert_eq!(describe(&f), format!("tripped 0, error code 000{code} ({name})"));
    }
    // protocols.md 1.4 example: (N0001&5D)CR = data error.
    let wire = b"(N0001&5D)\r";
    let rep = AsciiReply::parse(wire).unwrap();
    assert_eq!(rep.error(), Some(ErrorCode::DATA_ERROR));
    assert!(rep.sum);
    let rep = AsciiReply::parse(b"(12n0000)\r").unwrap();
    assert!(rep.tripped);
    assert_eq!(rep.inv_no, Some(12));
    assert_eq!(AsciiCodec::parse(b"(12n0000)\r", None).unwrap().command().to_string(), "n error reply");
    assert_eq!(
        AsciiRequest::parse(b"(N0001)\r"),
        Err(FrameError::Malformed("an error reply (N or n) from a drive, not a request"))
    );
}

#[test]
fn tripped_replies() {
    let req = AsciiRequest::read(AsciiAddress::Unit(3), CommNo::OUTPUT_FREQUENCY);
    let rep = req.reply(3, true, 0x1770);
    let bytes = emit_rep(&rep);
    assert_eq!(bytes, b"(03rFD001770)\r");
    assert_eq!(AsciiReply::parse(&bytes), Ok(rep));
    assert_eq!(rep.hz(), Some(60.0));
    assert!(TipAscii::default().pending(&req).unwrap().matches(&rep));
    // A lower-case W echo is a drive's even when the caller says master.
    let f = AsciiCodec::parse(b"(w00100064)\r", Some(Direction::Master)).unwrap();
    assert_eq!(f.direction(), Direction::Drive);
    assert_eq!(f.command().to_string(), "w write (RAM and EEPROM)");
    assert_eq!(
        AsciiRequest::parse(b"(pFA011770)\r"),
        Err(FrameError::Malformed("a reply from a tripped drive (lower-case CMD), not a request"))
    );
}

#[test]
fn format_errors_get_no_reply() {
    let cases: &[(&[u8], &str)] = &[
        (
            b"(1RFD00)\r",
            "format error: one-digit INV-NO (it is two digits 00-99, or none); a drive does not answer",
        ),
        (b"(RFD00]\r", "format error: the byte before CR is not the stop code ')'; a drive does not answer"),
        (b"(RFD00)X\r", "format error: the byte before CR is not the stop code ')'; a drive does not answer"),
        (b"()\r", "format error: no CMD between '(' and ')'"),
        (b"(12)\r", "format error: no CMD after INV-NO"),
        (
            b"(RF&D00)\r",
            "format error: '&' must be followed by exactly two SUM digits and ')'; a drive does not answer",
        ),
        (b"(RFD00)", "format error: the frame does not end with CR (0D)"),
    ];
    for (wire, msg) in cases {
        let err = AsciiRequest::parse(wire).unwrap_err();
        assert_eq!(err.to_string(), *msg, "{}", String::from_utf8_lossy(wire));
        assert_eq!(rejection_reply(wire, 0, false), None);
    }
}

#[test]
fn answered_errors() {
    // Unknown command: 0003 in ASCII mode (binary mode stays silent).
    let err = AsciiRequest::parse(b"(XFD00)\r").unwrap_err();
    assert_eq!(err.to_string(), "unknown ASCII-mode CMD 0x58");
    assert_eq!(rejection_reply(b"(XFD00)\r", 0, false).unwrap().error(), Some(ErrorCode::COMMAND_ERROR));
    // G is binary-mode only.
    assert_eq!(rejection_reply(b"(GFD000000)\r", 0, false).unwrap().error(), Some(ErrorCode::COMMAND_ERROR));
    // A non-hex COMNO: no such communication number.
    let err = AsciiRequest::parse(b"(RFDX0)\r").unwrap_err();
    assert_eq!(err.to_string(), "non-hex byte 0x58 at offset 4 ends the frame");
    assert_eq!(rejection_reply(b"(RFDX0)\r", 0, false).unwrap().error(), Some(ErrorCode::COMM_NO_ERROR));
    // Too many digits: data error.
    let err = AsciiRequest::parse(b"(WFA0112345)\r").unwrap_err();
    assert_eq!(err.to_string(), "number of DATA digits 5 is not allowed (0..4)");
    assert_eq!(rejection_reply(b"(WFA0112345)\r", 0, false).unwrap().error(), Some(ErrorCode::DATA_ERROR));
    // W without data: data error.
    assert_eq!(rejection_reply(b"(WFA01)\r", 0, false).unwrap().error(), Some(ErrorCode::DATA_ERROR));
    assert_eq!(
        AsciiRequest::parse(b"(WFA01)\r").unwrap_err().to_string(),
        "data error: W and P carry 1 to 4 DATA digits, this one has none"
    );
    // A lower-case command without DATA is neither a reply nor a request: silence.
    assert_eq!(rejection_reply(b"(wFA01)\r", 0, false), None);
    assert_eq!(
        AsciiReply::parse(b"(rFD00)\r").unwrap_err().to_string(),
        "a reply (lower-case CMD) carries 4 DATA digits"
    );
    // Wildcard: the reply carries this inverter's number.
    let rep = rejection_reply(b"(*5XFD00)\r", 5, false).unwrap();
    assert_eq!(emit_rep(&rep), b"(05N0003)\r");
    assert_eq!(
        TipAscii::default().rejected_disposition(b"(*5XFD00)\r", 15),
        Disposition::Broadcast { reply: false }
    );
}

#[test]
fn short_data_and_lower_case_hex() {
    // DATA may be 1-4 digits; drivebus sends 4.
    let req = AsciiRequest::parse(b"(P0010a)\r").unwrap();
    assert_eq!(req.data, Some(AsciiData { value: 0xA, digits: 1 }));
    assert_eq!(emit_req(&req), b"(P0010A)\r");
    assert_eq!(
        describe(&AsciiFrame::Request(req)),
        "communication number 0010 (deceleration time), data A = 1.0 s"
    );
    // A reply with fewer digits is read leniently.
    assert_eq!(AsciiReply::parse(b"(RFD0017)\r").unwrap().data(), Some(0x17));
}

#[test]
fn replies_are_not_requests_and_back() {
    assert!(AsciiReply::parse(b"(RFD00)\r").is_err());
    assert!(AsciiCodec::parse(b"(*2R00001234)\r", None).is_err());
}

#[test]
fn emit_errors() {
    let mut b = [0u8; 32];
    let bad = AsciiRequest::read(AsciiAddress::Unit(100), CommNo(0));
    assert_eq!(bad.emit(&mut b), Err(EmitError::OutOfRange { field: "INV-NO", value: 100, min: 0, max: 99 }));
    let bad = AsciiRequest {
        data: Some(AsciiData { value: 0x100, digits: 2 }),
        ..AsciiRequest::write(AsciiAddress::Omitted, CommNo(0), 0)
    };
    assert!(bad.emit(&mut b).is_err());
    let bad = AsciiRequest { cmd: Cmd::G, ..AsciiRequest::read(AsciiAddress::Omitted, CommNo(0)) };
    assert!(bad.emit(&mut b).is_err());
    let bad = AsciiRequest::read(AsciiAddress::Wildcard { tens: Some(1), units: Some(2) }, CommNo(0));
    assert!(bad.emit(&mut b).is_err());
    let ok = AsciiRequest::read(AsciiAddress::Omitted, CommNo(0));
    assert_eq!(ok.emit(&mut b[..5]), Err(EmitError::BufferTooSmall { needed: 8, capacity: 5 }));
}

#[test]
fn scanner_resyncs() {
    // Garbage, a frame cut short by a new '(', a frame with a control byte, then good frames.
    let stream = b"xx(RFD(RFE03)\r(R\x01D00)\r(W00100064)\r";
    let (good, bad) = frames(stream);
    assert_eq!(good, [b"(RFE03)\r".to_vec(), b"(W00100064)\r".to_vec()]);
    assert_eq!(bad.len(), 2);
    assert_eq!(bad[1].to_string(), "non-hex byte 0x01 at offset 2 ends the frame");
    // No CR within 17 bytes.
    let (good, bad) = frames(b"(RFD000000000000000000(RFD00)\r");
    assert_eq!(good, [b"(RFD00)\r".to_vec()]);
    assert_eq!(bad[0].to_string(), "no CR within 17 bytes: an ASCII-mode frame is at most 17 bytes");
    // Every split gives the same frames.
    let stream = b"(RFE03)\r(RFE03077B)\r(R0000&61)\r(R0000&60)\r";
    let (whole, _) = frames(stream);
    assert_eq!(whole.len(), 3);
    for i in 0..stream.len() {
        let mut d = Deframer::new(AsciiScanner);
        let mut got = Vec::new();
        for part in [&stream[..i], &stream[i..]] {
            d.push(part, &mut |e| {
                if let Event::Frame { bytes, .. } = e {
                    got.push(bytes.to_vec())
                }
            });
        }
        assert_eq!(got, whole, "split at {i}");
    }
}

#[test]
fn longest_frame_fits() {
    let req = AsciiRequest::write(AsciiAddress::Unit(99), CommNo(0xFA01), 0x1770).with_sum();
    let bytes = emit_req(&req);
    assert_eq!(bytes.len(), MAX_FRAME);
    assert_eq!(frames(&bytes).0, [&bytes[..]]);
}
