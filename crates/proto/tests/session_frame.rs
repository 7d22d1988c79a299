//! A request encoded elsewhere (a drive profile) goes on the wire as it is: the master session
//! sends its bytes, and what the reply must match comes from a look at the frame.

use drivebus_proto::checksum::crc16_modbus;
use drivebus_proto::error::{EmitError, SessionError};
use drivebus_proto::modbus::rtu::{self, ModbusRtu};
use drivebus_proto::session::{MasterEvent, MasterSession, Protocol};
use drivebus_proto::Instant;

fn rtu_frame(body: &[u8]) -> Vec<u8> {
    let mut f = body.to_vec();
    let crc = crc16_modbus(&f);
    f.extend_from_slice(&crc.to_le_bytes());
    f
}

fn session() -> MasterSession<ModbusRtu> {
    MasterSession::new(ModbusRtu, rtu::timing(9600, "8N1".parse().unwrap()))
}

#[test]
fn an_encoded_request_goes_out_as_it_is_and_its_reply_is_matched() {
    let mut s = session();
    // Read 2 registers at 2100H from drive 1.
    let request = rtu_frame(&[0x01, 0x03, 0x21, 0x00, 0x00, 0x02]);
    let pending = ModbusRtu.pending_of_frame(&request).expect("a request");
    assert!(pending.is_some(), "a reply is due");
    s.send_frame(Instant::ZERO, &request, pending).unwrap();
    assert_eq!(s.send_frame(Instant::ZERO, &request, pending), Err(SessionError::Busy));
    let now = s.ready_at();
    assert_eq!(s.poll_transmit(now), Some(&request[..]));
    // Another drive's reply does not answer it; drive 1's does.
    s.handle_input(now, &rtu_frame(&[0x02, 0x03, 0x04, 0, 1, 0, 2]));
    assert!(s.poll_event().is_none());
    let reply = rtu_frame(&[0x01, 0x03, 0x04, 0, 1, 0, 2]);
    s.handle_input(now, &reply);
    assert!(matches!(s.poll_event(), Some(MasterEvent::Reply(_))));
    assert_eq!(s.reply_bytes(), &reply[..]);
}

#[test]
fn a_broadcast_frame_awaits_no_reply_and_a_bad_frame_is_refused() {
    let mut s = session();
    // Write 2001H = 40.00 Hz to every drive.
    let broadcast = rtu_frame(&[0x00, 0x06, 0x20, 0x01, 0x0F, 0xA0]);
    let pending = ModbusRtu.pending_of_frame(&broadcast).expect("a request");
    assert_eq!(pending, None);
    s.send_frame(Instant::ZERO, &broadcast, pending).unwrap();
    let now = s.ready_at();
    assert_eq!(s.poll_transmit(now), Some(&broadcast[..]));
    let end = s.poll_timeout().expect("the turnaround");
    s.handle_timeout(end);
    assert!(matches!(s.poll_event(), Some(MasterEvent::BroadcastDone)));

    assert!(ModbusRtu.pending_of_frame(&broadcast[..3]).is_err(), "too short to be a request");
    let huge = vec![0x01; 4096];
    match s.send_frame(Instant::ZERO, &huge, None) {
        Err(SessionError::Emit(EmitError::BufferTooSmall { needed: 4096, .. })) => {}
        other => panic!("{other:?}"),
    }
    assert!(s.is_idle(), "nothing was queued");
}

#[test]
fn a_reply_is_handed_on_as_its_frame_for_one_parse_by_whoever_uses_it() {
    let mut s = session();
    let request = rtu_frame(&[0x01, 0x03, 0x21, 0x00, 0x00, 0x02]);
    let pending = ModbusRtu.pending_of_frame(&request).expect("a request");
    s.send_frame(Instant::ZERO, &request, pending).unwrap();
    let now = s.ready_at();
    s.poll_transmit(now).expect("the request");
    // An exception answers the request too (function | 0x80).
    let exception = rtu_frame(&[0x01, 0x83, 0x02]);
    s.handle_input(now, &exception);
    match s.poll_frame_event() {
        Some(MasterEvent::Reply(frame)) => assert_eq!(frame, &exception[..]),
        other => panic!("{other:?}"),
    }
    assert!(s.poll_frame_event().is_none(), "once");
}

#[test]
fn the_header_look_at_a_reply_agrees_with_the_whole_parse() {
    let pending =
        ModbusRtu.pending_of_frame(&rtu_frame(&[0x05, 0x03, 0x21, 0x00, 0x00, 0x01])).unwrap().unwrap();
    let replies = [
        rtu_frame(&[0x05, 0x03, 0x02, 0x12, 0x34]),
        rtu_frame(&[0x05, 0x83, 0x02]),
        rtu_frame(&[0x06, 0x03, 0x02, 0x12, 0x34]),
        rtu_frame(&[0x05, 0x04, 0x02, 0x12, 0x34]),
        rtu_frame(&[0x05, 0x06, 0x21, 0x00, 0x00, 0x01]),
    ];
    for reply in &replies {
        let parsed = ModbusRtu.parse_reply(reply).expect("a reply");
        assert_eq!(
            ModbusRtu.reply_matches(&pending, reply),
            Ok(ModbusRtu.matches(&pending, &parsed)),
            "{reply:02X?}"
        );
    }
    assert!(ModbusRtu.reply_matches(&pending, &[0x05, 0x03]).is_err(), "too short");
}

#[test]
fn the_header_look_at_a_modbus_ascii_reply_agrees_with_the_whole_parse() {
    use drivebus_proto::modbus::ascii::ModbusAscii;
    let lrc = |body: &[u8]| body.iter().fold(0u8, |a, b| a.wrapping_add(*b)).wrapping_neg();
    let frame = |body: &[u8]| {
        let mut f = b":".to_vec();
        for b in body.iter().chain([lrc(body)].iter()) {
            f.extend_from_slice(format!("{b:02X}").as_bytes());
        }
        f.extend_from_slice(b"\r\n");
        f
    };
    let pending =
        ModbusAscii.pending_of_frame(&frame(&[0x05, 0x03, 0x21, 0x00, 0x00, 0x01])).unwrap().unwrap();
    for body in [
        &[0x05, 0x03, 0x02, 0x12, 0x34][..],
        &[0x05, 0x83, 0x02],
        &[0x06, 0x03, 0x02, 0x12, 0x34],
        &[0x05, 0x04, 0x02, 0x12, 0x34],
    ] {
        let reply = frame(body);
        let parsed = ModbusAscii.parse_reply(&reply).expect("a reply");
        assert_eq!(
            ModbusAscii.reply_matches(&pending, &reply),
            Ok(ModbusAscii.matches(&pending, &parsed)),
            "{body:02X?}"
        );
    }
}
