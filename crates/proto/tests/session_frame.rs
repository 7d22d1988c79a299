//! A request encoded elsewhere (a drive profile) goes on the wire as it is: the master session
//! sends its bytes, and what the reply must match comes from a look at the frame.

use drivebus_proto::b800::{self, B800};
use drivebus_proto::checksum::{self, crc16_modbus};
use drivebus_proto::error::{EmitError, FrameError, SessionError};
use drivebus_proto::fc::Fc;
use drivebus_proto::modbus::rtu::{self, ModbusRtu};
use drivebus_proto::session::{MasterEvent, MasterSession, Protocol};
use drivebus_proto::toshiba::ascii::TipAscii;
use drivebus_proto::toshiba::binary::TipBinary;
use drivebus_proto::toshiba::Tip;
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

/// Whether `reply` answers the request frame `request` by the header look, checked against
/// the whole parse wherever the reply parses.
fn header_look<P: Protocol>(proto: &P, request: &[u8], reply: &[u8]) -> Result<bool, FrameError> {
    let pending = proto.pending_of_frame(request).expect("a request").expect("a reply is due");
    let header = proto.reply_matches(&pending, reply);
    if let Ok(rep) = proto.parse_reply(reply) {
        assert_eq!(header, Ok(proto.matches(&pending, &rep)), "{reply:02X?}");
    }
    header
}

/// A binary-mode TIP frame: `body` and its SUM.
fn tip_binary(body: &[u8]) -> Vec<u8> {
    let mut f = body.to_vec();
    f.push(checksum::sum8(body));
    f
}

/// An FC telegram: `body` and its BCC.
fn fc_telegram(body: &[u8]) -> Vec<u8> {
    let mut f = body.to_vec();
    f.push(checksum::xor8(body));
    f
}

/// A B800 frame: FG1, the hex `digits`, CS and FG2.
fn b800_frame(digits: &str) -> Vec<u8> {
    let mut f = vec![b800::FG1];
    f.extend_from_slice(digits.as_bytes());
    f.extend_from_slice(&drivebus_proto::hex::byte_digits(checksum::not_sum8(digits.as_bytes())));
    f.push(b800::FG2);
    f
}

#[test]
fn the_header_look_at_a_tip_ascii_reply_agrees_with_the_whole_parse() {
    let proto = TipAscii::default();
    // protocols.md 5.2 TA4/TA5: read FE03 (output current), the reply carries 077B.
    let (read, reply) = (b"(RFE03)\r", b"(RFE03077B)\r");
    assert_eq!(header_look(&proto, read, reply), Ok(true));
    assert_eq!(header_look(&proto, read, b"(rFE03077B)\r"), Ok(true), "tripped");
    assert_eq!(header_look(&proto, read, b"(N0004)\r"), Ok(true), "an error reply answers");
    assert_eq!(header_look(&proto, read, b"(RFE04077B)\r"), Ok(false), "another COMNO");
    assert_eq!(header_look(&proto, read, b"(WFE030064)\r"), Ok(false), "another command");
    assert_eq!(header_look(&proto, read, b"(02RFE03077B)\r"), Ok(false), "an INV-NO to a request without");
    // TA13: (*2R0000) is answered by inverter 02 alone, as (02R00000000).
    let wildcard = b"(*2R0000)\r";
    assert_eq!(header_look(&proto, wildcard, b"(02R00000000)\r"), Ok(true));
    assert_eq!(header_look(&proto, wildcard, b"(12R00000000)\r"), Ok(false), "another inverter");
    // The request heard as an echo is no reply; nor is a frame too short for COMNO.
    assert!(header_look(&proto, read, read).is_err());
    assert!(header_look(&proto, read, b"(R)\r").is_err());
    // A DATA digit changed into no hex digit on a line without SUM: an error, as the parse says.
    assert!(header_look(&proto, read, b"(RFE03077G)\r").is_err());
}

#[test]
fn the_header_look_at_a_tip_binary_reply_agrees_with_the_whole_parse() {
    let proto = TipBinary::default();
    // protocols.md 5.3 TB1: R comm-no 0000; its reply carries DATA.
    let read = [0x2F, 0x52, 0x00, 0x00, 0x81];
    assert_eq!(header_look(&proto, &read, &tip_binary(&[0x2F, 0x52, 0x00, 0x00, 0x17, 0x70])), Ok(true));
    assert_eq!(header_look(&proto, &read, &tip_binary(&[0x2F, 0x72, 0x00, 0x00, 0x17, 0x70])), Ok(true));
    // TB9, TB12: an error reply answers any request.
    assert_eq!(header_look(&proto, &read, &[0x2F, 0x4E, 0x00, 0x00, 0x7D]), Ok(true));
    assert_eq!(header_look(&proto, &read, &[0x2F, 0x4E, 0x00, 0x04, 0x81]), Ok(true));
    let other_comm_no = tip_binary(&[0x2F, 0x52, 0x00, 0x01, 0x17, 0x70]);
    assert_eq!(header_look(&proto, &read, &other_comm_no), Ok(false));
    let other_inverter = tip_binary(&[0x2F, 0x03, 0x52, 0x00, 0x00, 0x17, 0x70]);
    assert_eq!(header_look(&proto, &read, &other_inverter), Ok(false));
    // TB2: W decel time, the reply is identical; a P reply does not answer it.
    let write = [0x2F, 0x57, 0x00, 0x10, 0x00, 0x64, 0xFA];
    assert_eq!(header_look(&proto, &write, &write), Ok(true));
    assert_eq!(header_look(&proto, &write, &tip_binary(&[0x2F, 0x50, 0x00, 0x10, 0x00, 0x64])), Ok(false));
    // The R request heard as an echo is no reply; two bytes hold no header.
    assert!(header_look(&proto, &read, &read).is_err());
    assert!(header_look(&proto, &read, &[0x2F, 0x52]).is_err());
}

#[test]
fn the_header_look_on_a_line_with_both_tip_modes_keeps_to_the_request_mode() {
    let proto = Tip::default();
    assert_eq!(header_look(&proto, b"(RFE03)\r", b"(RFE03077B)\r"), Ok(true));
    assert_eq!(header_look(&proto, b"(RFE03)\r", &[0x2F, 0x4E, 0x00, 0x00, 0x7D]), Ok(false));
    assert_eq!(header_look(&proto, &[0x2F, 0x52, 0x00, 0x00, 0x81], b"(N0004)\r"), Ok(false));
    assert_eq!(
        header_look(&proto, &[0x2F, 0x52, 0x00, 0x00, 0x81], &[0x2F, 0x4E, 0x00, 0x00, 0x7D]),
        Ok(true)
    );
}

#[test]
fn the_header_look_at_an_fc_reply_agrees_with_the_whole_parse() {
    let proto = Fc::default();
    // protocols.md 5.5 D1/D2: a process telegram to address 4 and its reply.
    let process = [0x02, 0x06, 0x04, 0x04, 0x7C, 0x20, 0x00, 0x58];
    let process_reply = [0x02, 0x06, 0x04, 0x06, 0x07, 0x00, 0x00, 0x01];
    assert_eq!(header_look(&proto, &process, &process_reply), Ok(true));
    // D3/D4: read parameter 520 (PNU 208) at address 1, the reply with AK 2.
    let read = [0x02, 0x0E, 0x01, 0x12, 0x08, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x17];
    let reply = [0x02, 0x0E, 0x01, 0x22, 0x08, 0, 0, 0, 0, 0x02, 0x0C, 0x06, 0x07, 0, 0, 0x28];
    assert_eq!(header_look(&proto, &read, &reply), Ok(true));
    assert_eq!(header_look(&proto, &process, &reply), Ok(false), "another ADR, a parameter block");
    assert_eq!(header_look(&proto, &read, &process_reply), Ok(false), "a process block");
    let mut other_adr = reply[..15].to_vec();
    other_adr[2] = 0x02;
    assert_eq!(header_look(&proto, &read, &fc_telegram(&other_adr)), Ok(false));
    let mut other_pnu = reply[..15].to_vec();
    other_pnu[4] = 0x09;
    assert_eq!(header_look(&proto, &read, &fc_telegram(&other_pnu)), Ok(false));
    // AK 7 "cannot be performed" answers whatever PNU it carries.
    let mut refusal = other_pnu.clone();
    refusal[3] = 0x72;
    assert_eq!(header_look(&proto, &read, &fc_telegram(&refusal)), Ok(true));
    // AK 4 is no response: no reply, whatever its header says.
    let mut unknown_ak = reply[..15].to_vec();
    unknown_ak[3] = 0x42;
    assert!(header_look(&proto, &read, &fc_telegram(&unknown_ak)).is_err());
    assert!(header_look(&proto, &read, &[0x02, 0x0E, 0x01]).is_err(), "too short");
}

#[test]
fn the_header_look_at_a_b800_reply_agrees_with_the_whole_parse() {
    let proto = B800;
    // protocols.md 5.1 B1/B5: run drive 1, drive 1's 'r'.
    let (run_1, r_from_1) = (b800_frame("8152"), b800_frame("0172"));
    assert_eq!(run_1, b"\x7E81522F\x7F");
    assert_eq!(r_from_1, b"\x7E017235\x7F");
    assert_eq!(header_look(&proto, &run_1, &r_from_1), Ok(true));
    // B2/B6: drive 5, P 40.0 Hz, and its 'p'.
    let (set_5, p_from_5) = (b800_frame("85500960"), b800_frame("0570"));
    assert_eq!(header_look(&proto, &set_5, &p_from_5), Ok(true));
    assert_eq!(header_look(&proto, &run_1, &p_from_5), Ok(false), "another drive");
    assert_eq!(header_look(&proto, &set_5, &b800_frame("0572")), Ok(false), "another letter");
    assert_eq!(header_look(&proto, &set_5, &b800_frame("056597")), Ok(true), "an 'e' answers");
    // The request heard as an echo is no reply (its DA is a master's); FG1 FG2 hold no header.
    assert!(header_look(&proto, &run_1, &run_1).is_err());
    assert!(header_look(&proto, &run_1, &[b800::FG1, b800::FG2]).is_err());
    // The header answers; DATA that 'r' does not carry is for the reply's reader to report.
    let r_with_data = b800_frame("01721234");
    assert!(proto.parse_reply(&r_with_data).is_err());
    assert_eq!(header_look(&proto, &run_1, &r_with_data), Ok(true));
}
