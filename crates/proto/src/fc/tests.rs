//! The test vectors of protocols.md 5.5, the addressing examples of 2.3, the seed errata,
//! the scanner and the sessions on a virtual clock.

extern crate std;
use std::format;
use std::string::{String, ToString};
use std::vec;
use std::vec::Vec;

use super::*;
use crate::codec::Codec;
use crate::deframe::{Deframer, Event, Scan, Scanner};
use crate::describe::{Describe, Direction, Target};
use crate::error::ChecksumKind;
use crate::session::{Incoming, MasterEvent, MasterSession, SlaveSession};
use crate::time::Instant;
use telegram::MAX_LGE;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
}

fn pnu(s: &str) -> ParameterNumber {
    s.parse().unwrap()
}

fn emit_req(r: &Request<'_>) -> Vec<u8> {
    let mut b = [0u8; MAX_TELEGRAM];
    let n = r.emit(&mut b).unwrap();
    b[..n].to_vec()
}

fn emit_rep(r: &Reply<'_>) -> Vec<u8> {
    let mut b = [0u8; MAX_TELEGRAM];
    let n = r.emit(&mut b).unwrap();
    b[..n].to_vec()
}

/// Every field as `drivebus decode` prints it.
fn show(f: &Frame<'_>) -> Vec<String> {
    let mut v = Vec::new();
    f.fields(&mut |field| v.push(field.to_string()));
    v
}

fn decode(bytes: &[u8], from: Option<Direction>) -> Frame<'_> {
    DanfossFc::parse(bytes, from).unwrap()
}

// ---------------------------------------------------------------------------------------
// protocols.md 5.5, D1–D6
// ---------------------------------------------------------------------------------------

#[test]
fn d1_process_telegram_start_50_percent() {
    let b = hex("02 06 04 04 7C 20 00 58");
    // 02    STX
    // 06    LGE: 4 data bytes + ADR + BCC -> process block, 8 bytes in all
    // 04    ADR: bit 7 = 0 -> address format 1–31, bit 5 = 0, bits 0–4 = address 4
    // 04 7C PCD1 = CTW 047C: bits 2, 3, 4, 5, 6, 10 = start
    // 20 00 PCD2 = MRV 2000 = 50 %
    // 58    BCC = 02^06^04^04^7C^20^00
    assert_eq!(FcScanner.scan(&b, 0), Scan::Frame { len: 8 });
    let r = Request::parse(&b).unwrap();
    assert_eq!(r.adr.byte(), 0x04);
    assert_eq!(r.adr.format(), AddressFormat::OneTo31);
    assert_eq!(r.adr.address(), Some(4));
    assert_eq!(r.block, Block::Process);
    assert_eq!(r.ctw, ControlWord::START);
    assert_eq!(r.reference, Reference(0x2000));
    assert_eq!(r.reference.percent(), 50.0);
    let built = Request::process(
        Adr::new(4, AddressFormat::OneTo31).unwrap(),
        ControlWord::START,
        Reference::from_percent(50.0),
    );
    assert_eq!(emit_req(&built), b);

    let f = decode(&b, None);
    assert_eq!(f.direction(), Direction::Master);
    assert_eq!(f.target(), Target::Unit(4));
    assert_eq!(f.command().name, "process block: start");
    assert_eq!(
        show(&f),
        [
            "LGE 06 (process block)",
            "ADR 04 (address format 1–31)",
            "CTW 047C (start)",
            "CTW bit 02 1 (ramp (no DC brake))",
            "CTW bit 03 1 (no coasting)",
            "CTW bit 04 1 (ramp (no quick stop))",
            "CTW bit 05 1 (use ramp (no hold))",
            "CTW bit 06 1 (start)",
            "CTW bit 10 1 (data valid)",
            "MRV 2000 = 50.00 %",
            "BCC 58",
        ]
    );
}

#[test]
fn d2_process_reply_stw_0607() {
    let b = hex("02 06 04 06 07 00 00 01");
    // 02 STX, 06 LGE, 04 ADR echoed unchanged,
    // 06 07 PCD1 = STW 0607: bits 0, 1, 2, 9, 10
    // 00 00 PCD2 = MAV 0
    // 01 BCC
    let r = Reply::parse(&b).unwrap();
    assert_eq!(r.adr.address(), Some(4));
    assert_eq!(r.stw, StatusWord(0x0607));
    assert!(r.stw.control_ready() && r.stw.drive_ready() && r.stw.enable() && r.stw.bus_control());
    assert!(r.stw.frequency_limit_ok() && !r.stw.in_operation());
    assert_eq!(r.mav, Reference(0));
    assert_eq!(emit_rep(&Reply::process(r.adr, StatusWord(0x0607), Reference(0))), b);
    // A process block carries no AK: the caller says who sent it.
    let f = decode(&b, Some(Direction::Drive));
    assert_eq!(f.direction(), Direction::Drive);
    assert_eq!(f.command().name, "process block: status word and MAV");
    assert_eq!(
        show(&f),
        [
            "LGE 06 (process block)",
            "ADR 04 (address format 1–31)",
            "STW 0607",
            "STW bit 00 1 (control ready)",
            "STW bit 01 1 (drive ready)",
            "STW bit 02 1 (enable)",
            "STW bit 09 1 (bus control)",
            "STW bit 10 1 (frequency limit OK)",
            "MAV 0000 = 0.00 %",
            "BCC 01",
        ]
    );
    // Without `from`, the master's reading is the default.
    assert_eq!(decode(&b, None).direction(), Direction::Master);
}

#[test]
fn d3_vlt5000_read_parameter_520() {
    let b = hex("02 0E 01 12 08 00 00 00 00 00 00 00 00 00 00 17");
    // 02 STX, 0E LGE = 14: parameter block, 16 bytes
    // 01    ADR: format 1–31, address 1
    // 12 08 PKE: AK 1 (read parameter value), PNU 0x208 = 520
    // 00 00 IND
    // 00 00 00 00 PWEhigh PWElow
    // 00 00 PCD1 (CTW 0000: bit 10 = 0, ignored)   00 00 PCD2
    // 17 BCC
    let r = Request::parse(&b).unwrap();
    assert_eq!(r.command(), Some(ParameterCommand::ReadValue));
    let Block::Parameter(p) = r.block else { panic!() };
    assert_eq!(p.pnu.pnu(), 520);
    assert_eq!((p.ind, p.pwe), (0, 0));
    assert_eq!(r.ctw, ControlWord(0));
    assert_eq!(emit_req(&Request::read(Adr::new(1, AddressFormat::OneTo31).unwrap(), pnu("520"), 0)), b);
    let f = decode(&b, None);
    assert_eq!(f.command().code, 1);
    assert_eq!(f.command().to_string(), "01 read parameter value");
    assert_eq!(
        show(&f),
        [
            "LGE 0E (parameter block)",
            "ADR 01 (address format 1–31)",
            "PKE 1208",
            "AK 1 (read parameter value)",
            "PNU 520",
            "parameter \"5-20\"",
            "IND 0000",
            "PWE 00000000",
            "CTW 0000 (data invalid: the control word is ignored)",
            "MRV 0000 = 0.00 %",
            "BCC 17",
        ]
    );
}

#[test]
fn d4_vlt5000_reply_double_word_5_24_a() {
    let b = hex("02 0E 01 22 08 00 00 00 00 02 0C 06 07 00 00 28");
    // 22 08 PKE: AK 2 (value transferred, double word), PNU 520
    // 00 00 IND; 00 00 02 0C PWE = 0x20C = 524 (5.24 A at conversion index -2)
    // 06 07 STW, 00 00 MAV, 28 BCC
    let r = Reply::parse(&b).unwrap();
    assert_eq!(r.response(), Some(ParameterResponse::ValueDoubleWord));
    assert_eq!(r.value(), Some(524));
    assert_eq!(r.stw, StatusWord(0x0607));
    let built =
        Reply::value_double_word(r.adr, pnu("520"), 0, 0x20C).with_process(StatusWord(0x0607), Reference(0));
    assert_eq!(emit_rep(&built), b);
    // AK 2 is in both tables: `from` decides.
    let f = decode(&b, Some(Direction::Drive));
    assert_eq!(f.command().to_string(), "02 parameter value transferred (double word)");
    assert!(!f.is_refusal());
    assert!(show(&f).contains(&"PWE 0000020C".to_string()));
    // A master accepts AK 1 for the same value (project decision).
    let ak1 = emit_rep(&Reply::value_word(r.adr, pnu("520"), 0, 0x20C));
    assert_eq!(Reply::parse(&ak1).unwrap().value(), Some(524));
}

#[test]
fn d5_errata_fc300_request_prints_ak_0() {
    // FC 300 DG p.288 "read 16-14" as printed: PKE 064E, AK 0. The BCC is right.
    let b = hex("02 0E 01 06 4E 00 00 00 00 00 00 00 00 00 00 45");
    // 06 4E PKE: AK 0 (no command), PNU 0x64E = 1614 = 16-14
    assert_eq!(FcScanner.scan(&b, 0), Scan::Frame { len: 16 });
    let r = Request::parse(&b).unwrap();
    assert_eq!(r.command(), Some(ParameterCommand::NoCommand));
    let f = decode(&b, None);
    assert_eq!(f.command().to_string(), "00 no command: nothing is read or written");
    let fields = show(&f);
    assert!(fields.contains(&"AK 0 (no command: nothing is read or written)".to_string()), "{fields:?}");
    assert!(fields.contains(&"parameter \"16-14\"".to_string()));
    // The intended request: AK 1, computed BCC 55.
    let fixed = Request::read(Adr::new(1, AddressFormat::OneTo31).unwrap(), pnu("16-14"), 0);
    assert_eq!(emit_req(&fixed), hex("02 0E 01 16 4E 00 00 00 00 00 00 00 00 00 00 55"));
}

#[test]
fn d6_errata_fc300_reply_prints_ak_0() {
    let b = hex("02 0E 01 06 4E 00 00 00 00 02 0C 06 07 00 00 4A");
    // AK 0 (no response) with PWE 020C, STW 0607: as printed, the BCC is right.
    let r = Reply::parse(&b).unwrap();
    assert_eq!(r.response(), Some(ParameterResponse::NoResponse));
    assert_eq!(r.value(), None);
    let f = decode(&b, Some(Direction::Drive));
    assert_eq!(f.command().to_string(), "00 no response");
    // Read as the master's: "no command".
    assert_eq!(decode(&b, None).command().name, "no command: nothing is read or written");
    // The VLT 5000 version of the same reply, correct: AK 2, BCC 28 (D4).
}

// ---------------------------------------------------------------------------------------
// protocols.md 5.5: description elements and text (full frames, computed BCCs)
// ---------------------------------------------------------------------------------------

#[test]
fn description_element_basic_characteristics() {
    // FC 300 DG p.291: request AK 4, par. 0-01, IND 0001 (basic characteristics).
    let req = hex("02 0E 01 40 01 00 01 00 00 00 00 00 00 00 00 4D");
    let adr = Adr::new(1, AddressFormat::OneTo31).unwrap();
    assert_eq!(emit_req(&Request::read_description(adr, pnu("0-01"), 1)), req);
    let f = decode(&req, Some(Direction::Drive)); // AK 4 is the master's whatever `from` says
    assert_eq!(f.direction(), Direction::Master);
    assert!(show(&f).contains(&"IND 0001 (basic characteristics)".to_string()));
    // Reply (PCD and BCC printed XX; PCD 0, BCC computed): 30 01 PKE AK 3 PNU 1,
    // 00 01 IND, 00 00 04 05 PWE: bit 10 "additional text available" + type 5 (Uint8).
    let rep = hex("02 0E 01 30 01 00 01 00 00 04 05 00 00 00 00 3C");
    assert_eq!(emit_rep(&Reply::description(adr, pnu("0-01"), 1, 0x0405)), rep);
    let f = decode(&rep, Some(Direction::Drive));
    assert_eq!(f.command().to_string(), "03 description element transferred");
    let fields = show(&f);
    for want in [
        "IND 0001 (basic characteristics)",
        "PWE 00000405",
        "data type 5 (Uint8)",
        "additional text available 1",
    ] {
        assert!(fields.contains(&want.to_string()), "{want} in {fields:?}");
    }
}

#[test]
fn description_element_name_is_a_text_block() {
    // FC 300 DG: read name (element 6) of 0-01; the reply carries "LANGUAGE", LGE 0x12 = 10 + 8.
    let adr = Adr::new(1, AddressFormat::OneTo31).unwrap();
    assert_eq!(
        emit_req(&Request::read_description(adr, pnu("0-01"), 6)),
        hex("02 0E 01 40 01 00 06 00 00 00 00 00 00 00 00 4A")
    );
    let rep = hex("02 12 01 30 01 00 06 4C 41 4E 47 55 41 47 45 00 00 00 00 34");
    assert_eq!(FcScanner.scan(&rep, 0), Scan::Frame { len: 20 });
    let r = Reply::parse(&rep).unwrap();
    assert_eq!(r.text_chars(), Some(&b"LANGUAGE"[..]));
    assert_eq!(emit_rep(&Reply::text(adr, ParameterResponse::Description, pnu("0-01"), 6, b"LANGUAGE")), rep);
    let fields = show(&decode(&rep, Some(Direction::Drive)));
    assert!(fields.contains(&"LGE 12 (text block (10 + n characters))".to_string()));
    assert!(fields.contains(&"IND 0006 (name)".to_string()));
    assert!(fields.contains(&"text \"LANGUAGE\"".to_string()));
}

#[test]
fn text_read_english() {
    // FC 300 DG p.295 / VLT 5000: read text of 0-01 value [0]: PKE F001, IND 0001, LGE 0E.
    let adr = Adr::new(1, AddressFormat::OneTo31).unwrap();
    let req = hex("02 0E 01 F0 01 00 01 00 00 00 00 00 00 00 00 FD");
    assert_eq!(emit_req(&Request::read_text(adr, pnu("0-01"), 1)), req);
    let f = decode(&req, None);
    assert_eq!(f.command().to_string(), "0F read/write text");
    assert!(show(&f).contains(&"IND 0001 (text element: parameter value + 1)".to_string()));
    // Reply: 02 11 01 F0 01 00 01 "ENGLISH" PCD1 PCD2 BCC; LGE 0x11 = 17 = 10 + 7.
    let rep = hex("02 11 01 F0 01 00 01 45 4E 47 4C 49 53 48 00 00 00 00 B0");
    let r = Reply::parse(&rep).unwrap();
    assert_eq!(r.response(), Some(ParameterResponse::Text));
    assert_eq!(r.text_chars(), Some(&b"ENGLISH"[..]));
    assert_eq!(emit_rep(&Reply::text(adr, ParameterResponse::Text, pnu("0-01"), 1, b"ENGLISH")), rep);
    let f = decode(&rep, Some(Direction::Drive));
    assert_eq!(f.command().to_string(), "0F text transferred");
    assert!(show(&f).contains(&"text \"ENGLISH\"".to_string()));
}

#[test]
fn text_write_and_four_character_text() {
    let adr = Adr::new(7, AddressFormat::OneTo126).unwrap();
    let w = Request::write_text(adr, pnu("0-37"), 0, b"PUMP 1");
    let b = emit_req(&w);
    assert_eq!(b[1], 10 + 6);
    assert_eq!(&b[3..7], &[0xF0, 37, 0x05, 0x00]);
    assert_eq!(Request::parse(&b).unwrap(), w);
    assert!(show(&decode(&b, None)).contains(&"IND 0500 (write text (high byte 05))".to_string()));
    // 4 characters: LGE 14, the wire form of a parameter block with the text in PWE.
    let b = emit_req(&Request::write_text(adr, pnu("0-37"), 0, b"FANS"));
    assert_eq!(b[1], 14);
    let Block::Parameter(p) = Request::parse(&b).unwrap().block else { panic!() };
    assert_eq!(&p.pwe_bytes(), b"FANS");
    let rep = emit_rep(&Reply::text(adr, ParameterResponse::Text, pnu("0-37"), 0, b"FANS"));
    assert!(show(&decode(&rep, Some(Direction::Drive))).contains(&"text \"FANS\"".to_string()));
    // Short texts (LGE 10..13) and the longest.
    for n in [0usize, 1, 3, 5, 100] {
        let text = vec![b'A'; n];
        let b = emit_req(&Request::write_text(adr, pnu("0-37"), 0, &text));
        assert_eq!(b.len(), 12 + n);
        assert_eq!(FcScanner.scan(&b, 0), Scan::Frame { len: 12 + n });
        assert_eq!(Request::parse(&b).unwrap().block.lge(), 10 + n);
    }
    let long = [b'A'; 101];
    let mut out = [0u8; 200];
    assert_eq!(
        Request::write_text(adr, pnu("0-37"), 0, &long).emit(&mut out),
        Err(EmitError::OutOfRange { field: "text length", value: 101, min: 0, max: 100 })
    );
}

// ---------------------------------------------------------------------------------------
// Addresses (protocols.md 2.3, seed 003 5.4.4)
// ---------------------------------------------------------------------------------------

#[test]
fn address_22_gives_adr_16_and_address_1_gives_adr_81() {
    assert_eq!(Adr::new(22, AddressFormat::OneTo31).unwrap().byte(), 0x16);
    assert_eq!(Adr::new(1, AddressFormat::OneTo126).unwrap().byte(), 0x81);
    assert_eq!(Fc::default().adr(1).unwrap().byte(), 0x81);
    assert_eq!(Fc::new(AddressFormat::OneTo31).adr(22).unwrap().byte(), 0x16);
    assert_eq!(Adr::from_byte(0x16).unwrap().address(), Some(22));
    assert_eq!(Adr::from_byte(0x81).unwrap().address(), Some(1));
    assert_eq!(Adr::from_byte(0xFE).unwrap().address(), Some(126));
    assert_eq!(Adr::from_byte(0x1F).unwrap().address(), Some(31));
    // Bit 6 is unused in format 1–31.
    assert_eq!(Adr::from_byte(0x56).unwrap().address(), Some(22));
    assert_eq!(
        Adr::new(0, AddressFormat::OneTo126),
        Err(EmitError::OutOfRange { field: "FC address", value: 0, min: 1, max: 126 })
    );
    assert_eq!(
        Adr::new(32, AddressFormat::OneTo31),
        Err(EmitError::OutOfRange { field: "FC address", value: 32, min: 1, max: 31 })
    );
    assert_eq!(
        Adr::from_byte(0xFF).unwrap_err().to_string(),
        "ADR address (format 1–126) 127 is not allowed (1..126)"
    );
    assert_eq!(
        Adr::from_byte(0x00).unwrap_err().to_string(),
        "ADR address (format 1–31) 0 is not allowed (1..31)"
    );
}

#[test]
fn broadcast_in_both_formats() {
    assert_eq!(Adr::BROADCAST.byte(), 0x80);
    assert_eq!(Adr::BROADCAST_31.byte(), 0x20);
    assert_eq!(Fc::default().broadcast(), Adr::BROADCAST);
    assert_eq!(Fc::new(AddressFormat::OneTo31).broadcast(), Adr::BROADCAST_31);
    // Format 1–31: bit 5 = 1 is broadcast whatever bits 0–4 say.
    for byte in [0x20, 0x3F, 0x36, 0x60] {
        assert!(Adr::from_byte(byte).unwrap().is_broadcast(), "{byte:02X}");
    }
    let fc = Fc::default();
    for (frame, adr) in [("02 06 80 04 7C 20 00 DC", 0x80), ("02 06 20 04 7C 20 00 7C", 0x20)] {
        let b = hex(frame);
        let r = Request::parse(&b).unwrap();
        assert_eq!(r.adr.byte(), adr);
        assert_eq!(decode(&b, None).target(), Target::Broadcast);
        assert!(show(&decode(&b, None))[1].contains("broadcast"));
        assert_eq!(fc.pending(&r), None);
        assert_eq!(fc.disposition(&r, 4), Disposition::Broadcast { reply: false });
    }
}

#[test]
fn disposition_accepts_own_address_in_either_format() {
    let fc = Fc::default();
    let to = |adr: u8| Request::process(Adr::from_byte(adr).unwrap(), ControlWord::START, Reference(0));
    assert_eq!(fc.disposition(&to(0x96), 22), Disposition::Mine);
    assert_eq!(fc.disposition(&to(0x16), 22), Disposition::Mine);
    assert_eq!(fc.disposition(&to(0x97), 22), Disposition::NotMine);
    assert_eq!(fc.disposition(&to(0x81), 22), Disposition::NotMine);
    // Address 100 cannot be reached in format 1–31.
    assert_eq!(fc.disposition(&to(0x04), 100), Disposition::NotMine);
}

// ---------------------------------------------------------------------------------------
// AK 7 and the other parameter exchanges
// ---------------------------------------------------------------------------------------

#[test]
fn ak7_reply_is_a_refusal_with_fault_code() {
    // Write 4-14 = 1000.0 Hz refused: AK 7, fault 2 "upper or lower limit exceeded".
    let adr = Adr::new(1, AddressFormat::OneTo126).unwrap();
    let req = hex("02 0E 81 E1 9E 00 00 00 00 27 10 00 00 00 00 C5");
    assert_eq!(emit_req(&Request::write_word(adr, pnu("4-14"), 0, 10000, true)), req);
    let rep = hex("02 0E 81 71 9E 00 00 00 00 00 02 06 07 00 00 61");
    // 71 9E PKE: AK 7 (command cannot be performed), PNU 414; PWElow 0002 = fault 2
    let built = Reply::fault(adr, pnu("4-14"), 0, FaultCode::LIMIT_EXCEEDED)
        .with_process(StatusWord(0x0607), Reference(0));
    assert_eq!(emit_rep(&built), rep);
    let r = Reply::parse(&rep).unwrap();
    assert_eq!(r.fault_code(), Some(FaultCode(2)));
    // AK 7 only comes from a drive, whatever `from` says.
    let f = decode(&rep, Some(Direction::Master));
    assert_eq!(f.direction(), Direction::Drive);
    assert!(f.is_refusal());
    assert_eq!(f.command().to_string(), "07 command cannot be performed");
    assert!(show(&f).contains(&"fault code 2 (upper or lower limit exceeded)".to_string()));
    // As a request, AK 7 is not in the master's table.
    assert_eq!(Request::parse(&rep).unwrap_err().to_string(), "unknown AK (parameter command) 0x07");
    assert!(Fc::default().matches(&Fc::default().pending(&Request::parse(&req).unwrap()).unwrap(), &r));
}

#[test]
fn ak7_fault_codes_in_decimal() {
    let adr = Adr::new(22, AddressFormat::OneTo31).unwrap();
    for (code, meaning) in [
        (0, "illegal parameter number"),
        (17, "not while running"),
        (130, "no bus access for this parameter"),
        (255, "no error"),
        (1000, "not in the fault table"),
    ] {
        let b = emit_rep(&Reply::fault(adr, pnu("3-41"), 0, FaultCode(code)));
        let f = decode(&b, None);
        assert!(f.is_refusal());
        assert!(show(&f).contains(&format!("fault code {code} ({meaning})")), "{code}");
    }
    // "not while running" as a drive sends it, STW running at 50 %.
    let b = hex("02 0E 16 71 55 00 00 00 00 00 11 0F 03 20 00 03");
    let r = Reply::parse(&b).unwrap();
    assert_eq!(r.fault_code(), Some(FaultCode::NOT_WHILE_RUNNING));
    assert!(r.stw.in_operation());
    assert_eq!(r.mav.percent(), 50.0);
}

#[test]
fn write_4_14_and_its_reply() {
    // FC 202 DG example: write 4-14 = 100 Hz (1000 at index -1), RAM and EEPROM, word.
    let adr = Adr::new(1, AddressFormat::OneTo126).unwrap();
    let req = Request::write_word(adr, pnu("4-14"), 0, 1000, true);
    assert_eq!(emit_req(&req), hex("02 0E 81 E1 9E 00 00 00 00 03 E8 00 00 00 00 19"));
    let wire = hex("02 0E 81 E1 9E 00 00 00 00 03 E8 00 00 00 00 19");
    let f = decode(&wire, Some(Direction::Drive));
    assert_eq!(f.direction(), Direction::Master, "AK E is the master's");
    assert!(show(&f).contains(&"PWE 000003E8 (value to write)".to_string()));
    let rep = hex("02 0E 81 11 9E 00 00 00 00 03 E8 06 07 00 00 E8");
    let r = Reply::parse(&rep).unwrap();
    assert_eq!(r.value(), Some(1000));
    assert!(Fc::default().matches(&Fc::default().pending(&req).unwrap(), &r));
    // A reply for another parameter does not answer this request.
    let other = Reply::value_word(adr, pnu("4-12"), 0, 0);
    assert!(!Fc::default().matches(&Fc::default().pending(&req).unwrap(), &other));
    // Nor a process block, nor another ADR byte.
    assert!(!Fc::default()
        .matches(&Fc::default().pending(&req).unwrap(), &Reply::process(adr, StatusWord(0), Reference(0))));
    let other_adr = Reply::value_word(Adr::new(1, AddressFormat::OneTo31).unwrap(), pnu("4-14"), 0, 0);
    assert!(!Fc::default().matches(&Fc::default().pending(&req).unwrap(), &other_adr));
    // Double-word writes: AK 3 / D.
    let dw = Request::write_double_word(adr, pnu("3-41"), 0, 1000, false);
    assert_eq!(emit_req(&dw)[3] >> 4, 3);
    assert_eq!(emit_req(&Request::write_double_word(adr, pnu("3-41"), 0, 1000, true))[3] >> 4, 0xD);
    assert_eq!(emit_req(&Request::write_word(adr, pnu("3-41"), 0, 1000, false))[3] >> 4, 2);
}

#[test]
fn array_index_and_pcd_with_parameters() {
    // 15-30 Alarm Log index 1: PKE 15FA, IND 0001, with a start command in PCD1.
    let adr = Adr::new(3, AddressFormat::OneTo126).unwrap();
    let req = Request::read(adr, pnu("15-30"), 1).with_process(ControlWord::START, Reference(0x4000));
    let b = emit_req(&req);
    assert_eq!(&b[3..7], &[0x15, 0xFA, 0x00, 0x01]);
    assert_eq!(&b[11..15], &[0x04, 0x7C, 0x40, 0x00]);
    let fields = show(&decode(&b, None));
    assert!(fields.contains(&"IND 0001 (array index)".to_string()));
    assert!(fields.contains(&"MRV 4000 = 100.00 %".to_string()));
}

// ---------------------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------------------

#[test]
fn error_messages() {
    let e = |s: &str| Request::parse(&hex(s)).unwrap_err().to_string();
    assert_eq!(
        e("02 05 04 04 7C 20 58"),
        "LGE 0x05 is not a telegram length (6 process, 14 parameter, 10+n text)"
    );
    assert_eq!(
        e("02 09 04 04 7C 20 58"),
        "LGE 0x09 is not a telegram length (6 process, 14 parameter, 10+n text)"
    );
    assert_eq!(e("02 C8 04"), "text telegram LGE (10 + at most 100 characters) 200 is not allowed (10..110)");
    assert_eq!(e("02 06 04 04 7C 20 00 59"), "BCC mismatch: frame carries 59, computed 58");
    assert_eq!(
        e("02 06 04 04 7C 20"),
        "truncated frame: the telegram its LGE announces needs 8 bytes, got 6"
    );
    assert_eq!(e("02"), "truncated frame: an FC telegram needs 8 bytes, got 1");
    assert_eq!(e("03 06 04 04 7C 20 00 58"), "unknown start byte (STX is 02) 0x03");
    assert_eq!(e("02 06 04 04 7C 20 00 58 00"), "LGE 6 does not match the frame, which implies 7");
    // AK 5 is in neither table.
    let b = emit_req(&Request::read(Adr::BROADCAST, pnu("1-00"), 0));
    let mut b5 = b.clone();
    b5[3] = 0x50 | (b5[3] & 0x0F);
    b5[15] = crate::checksum::xor8(&b5[..15]);
    assert_eq!(Request::parse(&b5).unwrap_err().to_string(), "unknown AK (parameter command) 0x05");
    assert_eq!(Reply::parse(&b5).unwrap_err().to_string(), "unknown AK (response) 0x05");
    assert!(DanfossFc::parse(&b5, None).is_err());
    // AK 4 / D / E are not responses.
    let mut b4 = b.clone();
    b4[3] = 0x40 | (b4[3] & 0x0F);
    b4[15] = crate::checksum::xor8(&b4[..15]);
    assert_eq!(Reply::parse(&b4).unwrap_err().to_string(), "unknown AK (response) 0x04");
    let mut small = [0u8; 7];
    assert_eq!(
        Request::process(Adr::BROADCAST, ControlWord::START, Reference(0)).emit(&mut small),
        Err(EmitError::BufferTooSmall { needed: 8, capacity: 7 })
    );
}

// ---------------------------------------------------------------------------------------
// Scanner and deframer
// ---------------------------------------------------------------------------------------

#[test]
fn scanner_results() {
    let s = FcScanner;
    assert_eq!(s.scan(&hex("41 42 02 06"), 0), Scan::Noise { len: 2 });
    assert_eq!(s.scan(&hex("41 42"), 0), Scan::Noise { len: 2 });
    assert_eq!(s.scan(&hex("02"), 0), Scan::Incomplete { checked: 0 });
    assert_eq!(s.scan(&hex("02 0E 01 12"), 0), Scan::Incomplete { checked: 0 });
    match s.scan(&hex("02 05 04"), 0) {
        Scan::Invalid { len: 2, skip: 1, error } => {
            assert_eq!(
                error.to_string(),
                "LGE 0x05 is not a telegram length (6 process, 14 parameter, 10+n text)"
            )
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(
        s.scan(&hex("02 06 04 04 7C 20 00 59"), 0),
        Scan::Invalid {
            len: 8,
            skip: 1,
            error: FrameError::ChecksumMismatch {
                kind: ChecksumKind::Bcc,
                carried: 0x59,
                computed: 0x58,
                hint: None
            }
        }
    );
    // The longest accepted LGE never asks for more than the buffer.
    let mut long = vec![0x02, MAX_LGE];
    long.resize(MAX_TELEGRAM - 1, 0);
    assert_eq!(s.scan(&long, 0), Scan::Incomplete { checked: 0 });
    assert_eq!(
        s.truncated(&hex("02 0E 01")).to_string(),
        "truncated frame: the telegram its LGE announces needs 16 bytes, got 3"
    );
    assert_eq!(s.truncated(&hex("02")).to_string(), "truncated frame: an FC telegram needs 8 bytes, got 1");
}

fn frames(chunks: &[&[u8]]) -> (Vec<Vec<u8>>, Vec<String>) {
    let mut d = Deframer::new(FcScanner);
    let mut good = Vec::new();
    let mut bad = Vec::new();
    for c in chunks {
        d.push(c, &mut |e| match e {
            Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
            Event::Rejected { error, .. } => bad.push(error.to_string()),
        });
    }
    (good, bad)
}

#[test]
fn deframer_finds_a_telegram_inside_a_bad_one() {
    // A telegram with a bad BCC whose bytes contain a whole good one: skip 1 finds it.
    let d1 = hex("02 06 04 04 7C 20 00 58");
    let mut stream = hex("02 0E 01");
    stream.extend_from_slice(&d1);
    stream.extend_from_slice(&hex("00 00 00 00 00"));
    stream.extend_from_slice(&hex("02 06 04 06 07 00 00 01"));
    let (good, bad) = frames(&[&stream]);
    assert_eq!(good, [d1.clone(), hex("02 06 04 06 07 00 00 01")]);
    assert_eq!(bad.len(), 1, "{bad:?}");
    assert!(bad[0].starts_with("BCC mismatch"));
    // Every split gives the same frames.
    for i in 0..stream.len() {
        let (g, _) = frames(&[&stream[..i], &stream[i..]]);
        assert_eq!(g, good, "split at {i}");
    }
    let bytes: Vec<&[u8]> = stream.chunks(1).collect();
    assert_eq!(frames(&bytes).0, good);
}

#[test]
fn all_vectors_back_to_back() {
    let all = [
        "02 06 04 04 7C 20 00 58",
        "02 06 04 06 07 00 00 01",
        "02 0E 01 12 08 00 00 00 00 00 00 00 00 00 00 17",
        "02 0E 01 22 08 00 00 00 00 02 0C 06 07 00 00 28",
        "02 0E 01 06 4E 00 00 00 00 00 00 00 00 00 00 45",
        "02 0E 01 06 4E 00 00 00 00 02 0C 06 07 00 00 4A",
        "02 12 01 30 01 00 06 4C 41 4E 47 55 41 47 45 00 00 00 00 34",
        "02 11 01 F0 01 00 01 45 4E 47 4C 49 53 48 00 00 00 00 B0",
    ];
    let stream: Vec<u8> = all.iter().flat_map(|s| hex(s)).collect();
    let (good, bad) = frames(&[&stream]);
    assert!(bad.is_empty());
    assert_eq!(good, all.iter().map(|s| hex(s)).collect::<Vec<_>>());
    for g in &good {
        DanfossFc::parse(g, None).unwrap();
    }
}

// ---------------------------------------------------------------------------------------
// Sessions on a virtual clock
// ---------------------------------------------------------------------------------------

fn at(us: u64) -> Instant {
    Instant::from_micros(us)
}

fn new_master() -> MasterSession<Fc> {
    MasterSession::new(Fc::default(), timing(DEFAULT_BAUD, DEFAULT_FORMAT))
}

fn new_slave(address: u8) -> SlaveSession<Fc> {
    SlaveSession::new(Fc::default(), address, min_response_delay(DEFAULT_BAUD, DEFAULT_FORMAT))
}

#[test]
fn timing_defaults() {
    let t = timing(9600, CharFormat::EVEN_8E1);
    assert_eq!(t.response_timeout, Duration::from_millis(50));
    // 2 characters = 22 bits at 8E1 = 2.29 ms at 9600.
    assert_eq!(t.min_gap.as_micros(), 2291);
    assert_eq!(t.turnaround, Duration::from_millis(20));
    assert_eq!(min_response_delay(9600, CharFormat::EVEN_8E1).as_micros(), 2291);
}

#[test]
fn master_and_slave_exchange_a_parameter_read() {
    let mut m = new_master();
    let mut s = new_slave(4);
    let adr = m.protocol().adr(4).unwrap();
    m.send(at(0), &Request::read(adr, pnu("16-14"), 0)).unwrap();
    let tx = m.poll_transmit(at(0)).unwrap().to_vec();
    assert_eq!(tx, hex("02 0E 84 16 4E 00 00 00 00 00 00 00 00 00 00 D0"));
    // 16 bytes at 9600 8E1 = 18.3 ms on the wire.
    let t1 = at(18_400);
    let mut seen = 0;
    s.handle_input(t1, &tx, &mut |_, inc, resp| {
        let Incoming::Request { request, broadcast } = inc else { panic!("{inc:?}") };
        assert!(!broadcast && resp.may_reply());
        let Block::Parameter(p) = request.block else { panic!() };
        seen += 1;
        resp.reply(
            &Reply::value_word(request.adr, p.pnu, p.ind, 524).with_process(StatusWord(0x0607), Reference(0)),
        )
        .unwrap();
    });
    assert_eq!(seen, 1);
    assert_eq!(s.poll_transmit(t1), None, "the drive waits 2 characters");
    let due = s.poll_timeout().unwrap();
    assert_eq!(due, t1 + min_response_delay(DEFAULT_BAUD, DEFAULT_FORMAT));
    let rx = s.poll_transmit(due).unwrap().to_vec();
    // ADR 84 echoed unchanged; AK 1, PNU 16-14, PWE 020C.
    assert_eq!(&rx[..5], &[0x02, 0x0E, 0x84, 0x16, 0x4E]);
    let t2 = at(40_000);
    m.handle_input(t2, &rx);
    match m.poll_event() {
        Some(MasterEvent::Reply(r)) => {
            assert_eq!(r.value(), Some(524));
            assert_eq!(r.stw, StatusWord(0x0607));
        }
        other => panic!("{other:?}"),
    }
    // The next telegram waits 2 characters after the reply's last byte.
    assert_eq!(m.ready_at(), t2 + Duration::from_nanos(2_291_667));
    m.send(t2, &Request::process(adr, ControlWord::START, Reference(0x2000))).unwrap();
    assert_eq!(m.poll_transmit(at(41_000)), None);
    assert_eq!(m.poll_timeout(), Some(t2 + Duration::from_nanos(2_291_667)));
    assert!(m.poll_transmit(t2 + Duration::from_nanos(2_291_667)).is_some());
}

#[test]
fn slave_answers_its_address_in_format_1_31_too() {
    let mut s = new_slave(22);
    let req = emit_req(&Request::process(
        Adr::new(22, AddressFormat::OneTo31).unwrap(),
        ControlWord::START,
        Reference(0),
    ));
    assert_eq!(req[2], 0x16);
    s.handle_input(at(0), &req, &mut |_, inc, resp| {
        let Incoming::Request { request, .. } = inc else { panic!() };
        resp.reply(&Reply::process(request.adr, StatusWord(0x0F03), Reference(0x2000))).unwrap();
    });
    let rx = s.poll_transmit(at(10_000)).unwrap();
    assert_eq!(rx[2], 0x16, "ADR returned unchanged");
    // Not for us: ignored.
    let other = emit_req(&Request::process(
        Adr::new(23, AddressFormat::OneTo31).unwrap(),
        ControlWord::START,
        Reference(0),
    ));
    s.handle_input(at(20_000), &other, &mut |_, _, _| panic!("not mine"));
    assert_eq!(s.stats().ignored, 1);
}

#[test]
fn broadcast_is_done_without_a_reply() {
    let mut m = new_master();
    let mut s = new_slave(4);
    m.send(at(0), &Request::process(m.protocol().broadcast(), ControlWord::COAST, Reference(0))).unwrap();
    let tx = m.poll_transmit(at(0)).unwrap().to_vec();
    assert_eq!(tx[2], 0x80);
    let mut acted = false;
    s.handle_input(at(9_200), &tx, &mut |_, inc, resp| {
        let Incoming::Request { broadcast, request } = inc else { panic!() };
        assert!(broadcast && !resp.may_reply());
        assert_eq!(request.ctw, ControlWord::COAST);
        resp.reply(&Reply::process(request.adr, StatusWord(0), Reference(0))).unwrap();
        acted = true;
    });
    assert!(acted);
    assert_eq!(s.poll_transmit(at(1_000_000)), None, "a broadcast gets no reply");
    let until = m.poll_timeout().unwrap();
    m.handle_timeout(until);
    assert_eq!(m.poll_event(), Some(MasterEvent::BroadcastDone));
    assert!(m.is_idle());
}

#[test]
fn no_reply_times_out() {
    let mut m = new_master();
    m.send(at(0), &Request::read(m.protocol().adr(9).unwrap(), pnu("4-14"), 0)).unwrap();
    m.poll_transmit(at(0)).unwrap();
    let deadline = m.poll_timeout().unwrap();
    // 16 characters on the wire + 50 ms.
    assert_eq!(deadline, at(0) + DEFAULT_FORMAT.char_time(9600) * 16 + Duration::from_millis(50));
    m.handle_timeout(at(deadline.as_micros() - 1));
    assert_eq!(m.poll_event(), None);
    m.handle_timeout(deadline);
    assert_eq!(m.poll_event(), Some(MasterEvent::Timeout));
}

#[test]
fn corrupt_reply_is_reported() {
    let mut m = new_master();
    let mut s = new_slave(4);
    m.send(at(0), &Request::read(m.protocol().adr(4).unwrap(), pnu("4-14"), 0)).unwrap();
    let tx = m.poll_transmit(at(0)).unwrap().to_vec();
    s.handle_input(at(20_000), &tx, &mut |_, _, resp| {
        let mut bad = hex("02 0E 84 11 9E 00 00 00 00 03 E8 06 07 00 00 00");
        bad[15] = crate::checksum::xor8(&bad[..15]) ^ 0xFF;
        resp.reply_raw(&bad).unwrap();
    });
    let rx = s.poll_transmit(at(30_000)).unwrap().to_vec();
    m.handle_input(at(50_000), &rx);
    match m.poll_event() {
        Some(MasterEvent::Corrupt(FrameError::ChecksumMismatch { kind: ChecksumKind::Bcc, .. })) => {}
        other => panic!("{other:?}"),
    }
}

#[test]
fn refusal_reaches_the_master_as_a_reply() {
    let mut m = new_master();
    let mut s = new_slave(4);
    m.send(at(0), &Request::write_word(m.protocol().adr(4).unwrap(), pnu("4-14"), 0, 10000, false)).unwrap();
    let tx = m.poll_transmit(at(0)).unwrap().to_vec();
    s.handle_input(at(20_000), &tx, &mut |_, inc, resp| {
        let Incoming::Request { request, .. } = inc else { panic!() };
        let Block::Parameter(p) = request.block else { panic!() };
        resp.reply(&Reply::fault(request.adr, p.pnu, p.ind, FaultCode::LIMIT_EXCEEDED)).unwrap();
    });
    let rx = s.poll_transmit(at(30_000)).unwrap().to_vec();
    m.handle_input(at(50_000), &rx);
    match m.poll_event() {
        Some(MasterEvent::Reply(r)) => assert_eq!(r.fault_code(), Some(FaultCode::LIMIT_EXCEEDED)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_late_reply_for_another_parameter_is_not_taken() {
    let mut m = new_master();
    let adr = m.protocol().adr(4).unwrap();
    m.send(at(0), &Request::read(adr, pnu("4-14"), 0)).unwrap();
    m.poll_transmit(at(0)).unwrap();
    let late = emit_rep(&Reply::value_word(adr, pnu("4-12"), 0, 5));
    m.handle_input(at(30_000), &late);
    assert_eq!(m.poll_event(), None);
    assert_eq!(m.stats().unexpected, 1);
    let good = emit_rep(&Reply::value_word(adr, pnu("4-14"), 0, 500));
    m.handle_input(at(40_000), &good);
    assert!(matches!(m.poll_event(), Some(MasterEvent::Reply(r)) if r.value() == Some(500)));
}

#[test]
fn silence_ends_a_telegram_and_the_one_inside_is_found() {
    // A corrupted LGE (0x50) announces 82 bytes and swallows the good telegram after it;
    // the line then goes silent (more than 2 characters): the candidate is cut short, and the
    // deframer searches inside it.
    let mut stream = hex("02 50 04 04 7C");
    stream.extend_from_slice(&hex("02 06 04 06 07 00 00 01"));
    let mut d = Deframer::new(FcScanner);
    let mut good = Vec::new();
    let mut bad = Vec::new();
    let mut on = |e: Event<'_>| match e {
        Event::Frame { bytes, .. } => good.push(bytes.to_vec()),
        Event::Rejected { error, .. } => bad.push(error.to_string()),
    };
    d.push(&stream, &mut on);
    assert_eq!(d.buffered(), 13);
    d.silence(&mut on);
    assert_eq!(d.buffered(), 0);
    assert_eq!(good, [hex("02 06 04 06 07 00 00 01")]);
    assert_eq!(bad, ["truncated frame: the telegram its LGE announces needs 82 bytes, got 13"]);
}

#[test]
fn a_reply_cut_short_is_corrupt_at_the_deadline() {
    let mut m = new_master();
    m.send(at(0), &Request::read(m.protocol().adr(4).unwrap(), pnu("4-14"), 0)).unwrap();
    m.poll_transmit(at(0)).unwrap();
    m.handle_input(at(25_000), &hex("02 0E 84 11 9E 00"));
    let deadline = m.poll_timeout().unwrap();
    m.handle_timeout(deadline);
    match m.poll_event() {
        Some(MasterEvent::Corrupt(FrameError::Truncated { expected: 16, got: 6, .. })) => {}
        other => panic!("{other:?}"),
    }
}

/// Without `from`, a telegram that carries what only a reply can (a value after AK 1, a text
/// after AK F with IND 04xx) is the drive's; the same AK empty is the master's request.
#[test]
fn replies_with_ak_1_or_f_are_told_by_what_they_carry() {
    let adr = Adr::new(1, AddressFormat::OneTo126).unwrap();
    let rep = emit_rep(&Reply::value_word(adr, pnu("4-14"), 0, 650));
    assert_eq!(decode(&rep, None).direction(), Direction::Drive);
    let req = emit_req(&Request::read(adr, pnu("4-14"), 0));
    assert_eq!(decode(&req, None).direction(), Direction::Master);
    let rep = emit_rep(&Reply::text(adr, ParameterResponse::Text, pnu("0-37"), 0x0400, b"PUMP 1"));
    assert_eq!(decode(&rep, None).direction(), Direction::Drive);
    let req = emit_req(&Request::read_text(adr, pnu("0-37"), 0x0400));
    assert_eq!(decode(&req, None).direction(), Direction::Master);
    // A write of text (IND 05xx) is the master's, text and all.
    let req = emit_req(&Request::write_text(adr, pnu("0-37"), 0, b"PUMP 1"));
    assert_eq!(decode(&req, None).direction(), Direction::Master);
    // `from` is taken where the bytes allow either reading.
    assert_eq!(decode(&rep, Some(Direction::Master)).direction(), Direction::Master);
}
