//! Master and slave sessions wired together on a virtual clock, in both modes.

use core::time::Duration;
use std::vec::Vec;

use super::ascii::{AsciiAddress, AsciiRequest, TipAscii};
use super::binary::{BinaryAddress, BinaryRequest, BlockRequest, TipBinary};
use super::*;
use crate::error::FrameError;
use crate::session::{Incoming, MasterEvent, MasterSession, Protocol, Responder, SlaveSession};
use crate::time::Instant;

const DELAY: Duration = Duration::from_millis(2);

/// A simulated drive's memory: FD00 = 60.00 Hz, FE03 = 19.15 %; other numbers do not exist.
fn read(comm_no: CommNo) -> Option<u16> {
    match comm_no {
        CommNo::OUTPUT_FREQUENCY => Some(0x1770),
        CommNo::OUTPUT_CURRENT => Some(0x077B),
        CommNo(0) => Some(0),
        _ => None,
    }
}

/// A drive numbered `me` that answers both modes.
fn tip_drive(
    me: u8,
    inc: Incoming<'_, TipRequest>,
    resp: &mut Responder<'_, Tip>,
    log: &mut Vec<TipRequest>,
) {
    match inc {
        Incoming::Request { request, .. } => {
            log.push(request);
            let reply = match request {
                TipRequest::Binary(b) if matches!(b.body, binary::BinaryRequestBody::Block(_)) => {
                    b.block_reply(me, false, &[0x0400, 0x1770, 0x077B, 0, 0x2710]).map(TipReply::Binary)
                }
                _ => match request.cmd() {
                    Some(Cmd::R | Cmd::G) => {
                        let comm_no = match request {
                            TipRequest::Ascii(r) => r.comm_no,
                            TipRequest::Binary(r) => r.body.comm_no().unwrap_or(CommNo(0)),
                        };
                        Some(match read(comm_no) {
                            Some(v) => request.reply(me, false, v).unwrap_or(request.error_reply(
                                me,
                                false,
                                ErrorCode(0),
                            )),
                            None => request.error_reply(me, false, ErrorCode::COMM_NO_ERROR),
                        })
                    }
                    _ => {
                        let data = match request {
                            TipRequest::Ascii(r) => r.value().unwrap_or(0),
                            TipRequest::Binary(r) => match r.body {
                                binary::BinaryRequestBody::Write { data, .. }
                                | binary::BinaryRequestBody::WriteRam { data, .. } => data,
                                _ => 0,
                            },
                        };
                        request.reply(me, false, data)
                    }
                },
            };
            if let Some(r) = reply {
                resp.reply(&r).unwrap();
            }
        }
        Incoming::Rejected { bytes, .. } => {
            if let Some(r) = Tip::rejection_reply(bytes, me, false) {
                resp.reply(&r).unwrap();
            }
        }
    }
}

/// A master and one drive; returns the master's event and the bytes each side sent.
fn exchange(req: TipRequest, me: u8) -> (MasterEvent<TipReply>, Vec<u8>, Vec<u8>) {
    let mut m = MasterSession::new(Tip::default(), default_timing());
    let mut s = SlaveSession::new(Tip::default(), me, DELAY);
    let mut log = Vec::new();
    let mut now = Instant::from_millis(10);
    m.send(now, &req).unwrap();
    let sent = m.poll_transmit(now).unwrap().to_vec();
    s.handle_input(now, &sent, &mut |_, inc, resp| tip_drive(me, inc, resp, &mut log));
    now = now + DELAY;
    let answer = s.poll_transmit(now).map(|b| b.to_vec()).unwrap_or_default();
    if answer.is_empty() {
        now = now + Duration::from_millis(200);
        m.handle_timeout(now);
    } else {
        m.handle_input(now, &answer);
    }
    (m.poll_event().unwrap(), sent, answer)
}

#[test]
fn ascii_read_exchange() {
    let req = AsciiRequest::read(AsciiAddress::Unit(3), CommNo::OUTPUT_FREQUENCY);
    let (ev, sent, answer) = exchange(TipRequest::Ascii(req), 3);
    assert_eq!(sent, b"(03RFD00)\r");
    assert_eq!(answer, b"(03RFD001770)\r");
    let MasterEvent::Reply(rep) = ev else { panic!("{ev:?}") };
    assert_eq!(rep.hz(), Some(60.0));
}

#[test]
fn ascii_with_sum_and_error_reply() {
    let req = AsciiRequest::read(AsciiAddress::Omitted, CommNo(0x1234)).with_sum();
    let (ev, _, answer) = exchange(TipRequest::Ascii(req), 7);
    assert_eq!(answer, b"(N0002&5E)\r");
    let MasterEvent::Reply(rep) = ev else { panic!("{ev:?}") };
    assert_eq!(rep.error(), Some(ErrorCode::COMM_NO_ERROR));
}

#[test]
fn binary_write_echo() {
    // TB2 over the sessions: the echo is identical.
    let req = BinaryRequest::write(BinaryAddress::Omitted, CommNo::DECELERATION_TIME, 100);
    let (ev, sent, answer) = exchange(TipRequest::Binary(req), 0);
    assert_eq!(sent, [0x2F, 0x57, 0x00, 0x10, 0x00, 0x64, 0xFA]);
    assert_eq!(answer, sent);
    let MasterEvent::Reply(rep) = ev else { panic!("{ev:?}") };
    assert_eq!(rep.data(), Some(100));
}

#[test]
fn binary_block_exchange() {
    let block = BlockRequest::new(&[0xC400, 0x1770], 5).unwrap();
    let req = BinaryRequest::block(BinaryAddress::Unit(1), block);
    let (ev, sent, answer) = exchange(TipRequest::Binary(req), 1);
    assert_eq!(sent, [0x2F, 0x01, 0x58, 0x02, 0x05, 0xC4, 0x00, 0x17, 0x70, 0xDA]);
    assert_eq!(answer.len(), 15);
    let MasterEvent::Reply(TipReply::Binary(rep)) = ev else { panic!("{ev:?}") };
    let binary::BinaryReplyBody::Block(b) = rep.body else { panic!() };
    assert_eq!(b.rdata(), [0x0400, 0x1770, 0x077B, 0, 0x2710]);
}

#[test]
fn one_drive_answers_both_modes() {
    let mut m = MasterSession::new(Tip::default(), default_timing());
    let mut s = SlaveSession::new(Tip::default(), 2, DELAY);
    let mut log = Vec::new();
    let mut now = Instant::ZERO;
    for req in [
        TipRequest::Ascii(AsciiRequest::read(AsciiAddress::Unit(2), CommNo::OUTPUT_CURRENT)),
        TipRequest::Binary(BinaryRequest::read(BinaryAddress::Unit(2), CommNo::OUTPUT_CURRENT)),
    ] {
        now = m.ready_at().max(now);
        m.send(now, &req).unwrap();
        let sent = m.poll_transmit(now).unwrap().to_vec();
        s.handle_input(now, &sent, &mut |_, inc, resp| tip_drive(2, inc, resp, &mut log));
        now = now + DELAY;
        let answer = s.poll_transmit(now).unwrap().to_vec();
        m.handle_input(now, &answer);
        let Some(MasterEvent::Reply(rep)) = m.poll_event() else { panic!() };
        assert_eq!(rep.data(), Some(0x077B));
        assert_eq!(core::mem::discriminant(&rep), core::mem::discriminant(&req.reply(2, false, 0).unwrap()));
    }
    assert_eq!(log.len(), 2);
}

#[test]
fn wildcard_only_smallest_answers() {
    // TA13: (*2R0000) -> inverters 02, 12 and 22 act, 02 answers.
    let req = TipRequest::Ascii(AsciiRequest::read(
        AsciiAddress::Wildcard { tens: None, units: Some(2) },
        CommNo(0),
    ));
    let mut m = MasterSession::new(Tip::default(), default_timing());
    let mut slaves: Vec<_> =
        [2u8, 12, 22, 3].iter().map(|&n| SlaveSession::new(Tip::default(), n, DELAY)).collect();
    let now = Instant::ZERO;
    m.send(now, &req).unwrap();
    let sent = m.poll_transmit(now).unwrap().to_vec();
    assert_eq!(sent, b"(*2R0000)\r");
    let mut acted = Vec::new();
    let mut answers = Vec::new();
    for s in &mut slaves {
        let me = s.address();
        let mut log = Vec::new();
        s.handle_input(now, &sent, &mut |_, inc, resp| tip_drive(me, inc, resp, &mut log));
        if !log.is_empty() {
            acted.push(me);
        }
        if let Some(b) = s.poll_transmit(now + DELAY) {
            answers.push(b.to_vec());
        }
    }
    assert_eq!(acted, [2, 12, 22]);
    assert_eq!(answers, [b"(02R00000000)\r".to_vec()]);
    m.handle_input(now + DELAY, &answers[0]);
    assert!(matches!(m.poll_event(), Some(MasterEvent::Reply(_))));
}

#[test]
fn broadcast_without_reply_is_done_after_turnaround() {
    let proto = TipBinary { broadcast_reply: false };
    let mut m = MasterSession::new(proto, default_timing());
    let mut s = SlaveSession::new(TipBinary::default(), 5, DELAY);
    let now = Instant::ZERO;
    let req = BinaryRequest::write_ram(BinaryAddress::Broadcast, CommNo::FREQUENCY_COMMAND, 0x1770);
    m.send(now, &req).unwrap();
    let sent = m.poll_transmit(now).unwrap().to_vec();
    let mut seen = None;
    s.handle_input(now, &sent, &mut |_, inc, resp| {
        if let Incoming::Request { request, broadcast } = inc {
            seen = Some(broadcast);
            assert!(!resp.may_reply(), "only inverter 00 answers FF");
            resp.reply(&request.reply(5, false, 0x1770).unwrap()).unwrap();
        }
    });
    assert_eq!(seen, Some(true));
    assert_eq!(s.poll_transmit(now + DELAY), None, "nothing sent");
    let due = m.poll_timeout().unwrap();
    m.handle_timeout(due);
    assert_eq!(m.poll_event(), Some(MasterEvent::BroadcastDone));

    // ASCII `**` likewise, with broadcast_reply off.
    let proto = TipAscii { broadcast_reply: false };
    let mut m = MasterSession::new(proto, default_timing());
    m.send(now, &AsciiRequest::write_ram(AsciiAddress::ALL, CommNo::FREQUENCY_COMMAND, 0x1770)).unwrap();
    assert_eq!(m.poll_transmit(now).unwrap(), b"(**PFA011770)\r");
    let due = m.poll_timeout().unwrap();
    m.handle_timeout(due);
    assert_eq!(m.poll_event(), Some(MasterEvent::BroadcastDone));
}

#[test]
fn timeout_when_nobody_answers() {
    let req = TipRequest::Ascii(AsciiRequest::read(AsciiAddress::Unit(9), CommNo::OUTPUT_FREQUENCY));
    let (ev, _, answer) = exchange(req, 4);
    assert!(answer.is_empty());
    assert_eq!(ev, MasterEvent::Timeout);
}

#[test]
fn corrupt_reply() {
    for (req, bad) in [
        (
            TipRequest::Ascii(AsciiRequest::read(AsciiAddress::Unit(3), CommNo::OUTPUT_FREQUENCY).with_sum()),
            b"(03RFD001770&00)\r".to_vec(),
        ),
        (
            TipRequest::Binary(BinaryRequest::read(BinaryAddress::Unit(3), CommNo::OUTPUT_FREQUENCY)),
            [0x2F, 0x03, 0x52, 0xFD, 0x00, 0x17, 0x70, 0x00].to_vec(),
        ),
    ] {
        let mut m = MasterSession::new(Tip::default(), default_timing());
        let mut s = SlaveSession::new(Tip::default(), 3, DELAY);
        let now = Instant::ZERO;
        m.send(now, &req).unwrap();
        let sent = m.poll_transmit(now).unwrap().to_vec();
        s.handle_input(now, &sent, &mut |_, _, resp| resp.reply_raw(&bad).unwrap());
        let answer = s.poll_transmit(now + DELAY).unwrap().to_vec();
        m.handle_input(now + DELAY, &answer);
        match m.poll_event() {
            Some(MasterEvent::Corrupt(FrameError::ChecksumMismatch { .. })) => {}
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn min_gap_is_respected() {
    let t = default_timing();
    let mut m = MasterSession::new(TipAscii::default(), t);
    let now = Instant::from_millis(5);
    let req = AsciiRequest::read(AsciiAddress::Omitted, CommNo::OUTPUT_FREQUENCY);
    m.send(now, &req).unwrap();
    let n = m.poll_transmit(now).unwrap().len();
    let reply_at = now + Duration::from_millis(20);
    m.handle_input(reply_at, b"(RFD001770)\r");
    assert!(matches!(m.poll_event(), Some(MasterEvent::Reply(_))));
    assert!(n > 0);
    assert_eq!(m.ready_at(), reply_at + t.min_gap);
    m.send(reply_at, &req).unwrap();
    assert_eq!(m.poll_transmit(reply_at), None, "too soon after the reply");
    assert_eq!(m.poll_timeout(), Some(reply_at + t.min_gap));
    assert!(m.poll_transmit(reply_at + t.min_gap).is_some());
}

#[test]
fn drive_answers_checksum_errors_addressed_to_it() {
    let mut log = Vec::new();
    // TB14: block write with SUM D8 -> 2F 4E 00 04 81.
    let tb14 = [0x2F, 0x58, 0x02, 0x05, 0xC4, 0x00, 0x17, 0x70, 0xD8];
    let mut s = SlaveSession::new(Tip::default(), 0, DELAY);
    s.handle_input(Instant::ZERO, &tb14, &mut |_, inc, resp| tip_drive(0, inc, resp, &mut log));
    assert_eq!(s.poll_transmit(Instant::ZERO + DELAY).unwrap(), [0x2F, 0x4E, 0x00, 0x04, 0x81]);
    // ASCII: (R0000&61) -> (N0004&60).
    s.handle_input(Instant::ZERO, b"(R0000&61)\r", &mut |_, inc, resp| tip_drive(0, inc, resp, &mut log));
    assert_eq!(s.poll_transmit(Instant::ZERO + DELAY).unwrap(), b"(N0004&60)\r");
    // To another inverter: silence.
    s.handle_input(Instant::ZERO, b"(05R0000&61)\r", &mut |_, inc, resp| tip_drive(0, inc, resp, &mut log));
    assert_eq!(s.poll_transmit(Instant::ZERO + DELAY), None);
    // A format error: silence.
    s.handle_input(Instant::ZERO, b"(R11)\r", &mut |_, inc, resp| tip_drive(0, inc, resp, &mut log));
    assert_eq!(s.poll_transmit(Instant::ZERO + DELAY), None);
    // A command error: ASCII answers 0003, binary does not.
    s.handle_input(Instant::ZERO, b"(XFD00)\r", &mut |_, inc, resp| tip_drive(0, inc, resp, &mut log));
    assert_eq!(s.poll_transmit(Instant::ZERO + DELAY).unwrap(), b"(N0003)\r");
    s.handle_input(Instant::ZERO, &[0x2F, 0x41, 0x00, 0x00, 0x70], &mut |_, inc, resp| {
        tip_drive(0, inc, resp, &mut log)
    });
    assert_eq!(s.poll_transmit(Instant::ZERO + DELAY), None);
    assert!(log.is_empty());
}

#[test]
fn other_drives_replies_are_ignored() {
    // On a 2-wire line a drive hears the other drives' replies: they are not requests.
    let mut s = SlaveSession::new(Tip::default(), 1, DELAY);
    let mut log = Vec::new();
    for frame in [
        &b"(02R00000000)\r"[..],
        b"(02rFD001770)\r",
        b"(N0001)\r",
        &[0x2F, 0x02, 0x52, 0xFD, 0x00, 0x17, 0x70, 0x07],
    ] {
        s.handle_input(Instant::ZERO, frame, &mut |_, inc, resp| tip_drive(1, inc, resp, &mut log));
        assert_eq!(s.poll_transmit(Instant::ZERO + DELAY), None);
    }
    assert!(log.is_empty());
    assert_eq!(
        Tip::default()
            .disposition(&TipRequest::Ascii(AsciiRequest::read(AsciiAddress::Unit(2), CommNo(0))), 1),
        crate::session::Disposition::NotMine
    );
}
