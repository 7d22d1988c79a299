//! Toshiba VF-AS1 with f829 = 1 (Modbus-RTU), driven through a real `VirtualLine` on simulated
//! time. Frames from `seeds/002_43d8a4399c8be05f.txt` and protocols.md section 5.4.

mod support;

use std::time::Duration;

use drivebus_proto::checksum::crc16_modbus;
use drivebus_proto::line::CharFormat;
use drivebus_proto::modbus::rtu::{self, ModbusRtu};
use drivebus_proto::modbus::{ReplyPdu, Request, UnitId};
use drivebus_proto::session::{MasterEvent, MasterSession};
use drivebus_proto::Instant;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::family::toshiba::{ToshibaDrive, ToshibaProtocol, TRIP_ERR5_COMMUNICATION};
use drivebus_sim::model::Trip;
use support::{exchange, model, params, toshiba_line, wait};

fn line_with(addresses: &[u8]) -> VirtualLine {
    toshiba_line(ToshibaProtocol::ModbusRtu, addresses)
}

/// `body` and its CRC, low byte first.
fn rtu(body: &[u8]) -> Vec<u8> {
    let mut f = body.to_vec();
    f.extend(crc16_modbus(body).to_le_bytes());
    f
}

/// TM5 and FA00 = C400 to drive 1: run forward at 60.00 Hz.
fn run_60(line: &mut VirtualLine) {
    // manual VF-S15 p.31: "01 06 FA 01 17 70 E6 C6"; the reply is identical.
    let tm5 = [0x01, 0x06, 0xFA, 0x01, 0x17, 0x70, 0xE6, 0xC6];
    assert_eq!(exchange(line, &tm5), tm5);
    let run = rtu(&[0x01, 0x06, 0xFA, 0x00, 0xC4, 0x00]);
    assert_eq!(exchange(line, &run), run);
}

#[test]
fn tm1_tm2_output_frequency_after_the_ramp() {
    let mut line = line_with(&[1]);
    assert_eq!(line.drive(1).unwrap().protocol(), "modbus-rtu");
    let tm1 = [0x01, 0x03, 0xFD, 0x00, 0x00, 0x01, 0xB5, 0xA6];
    assert_eq!(exchange(&mut line, &tm1), rtu(&[0x01, 0x03, 0x02, 0x00, 0x00]));
    run_60(&mut line);
    wait(&mut line, Duration::from_secs(4));
    let half = exchange(&mut line, &tm1);
    let hz = u16::from_be_bytes([half[3], half[4]]);
    assert!((3000..6000).contains(&hz), "ramping: {hz}");
    wait(&mut line, Duration::from_secs(4));
    // seed 002: "Reading output frequency (During 60Hz operation)": 01 03 02 17 70 B6 50.
    assert_eq!(exchange(&mut line, &tm1), [0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50]);
    assert_eq!(model(&mut line, 1).output_hz(), 60.0);
}

#[test]
fn tm3_tm4_two_words_is_a_data_error() {
    let mut line = line_with(&[1]);
    // seed 002: "Example: Data specification error": 01 03 FD 00 00 02 F5 A7 -> 01 83 03 01 31.
    assert_eq!(
        exchange(&mut line, &[0x01, 0x03, 0xFD, 0x00, 0x00, 0x02, 0xF5, 0xA7]),
        [0x01, 0x83, 0x03, 0x01, 0x31]
    );
    // A count of 0 fails to parse; still exception 03.
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x03, 0xFD, 0x00, 0x00, 0x00])), rtu(&[0x01, 0x83, 0x03]));
}

#[test]
fn every_exception() {
    let mut line = line_with(&[1]);
    // 01 illegal function: 04 and 10 are not VF-AS1 functions.
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x04, 0xFD, 0x00, 0x00, 0x01])), rtu(&[0x01, 0x84, 0x01]));
    let w10 = rtu(&[0x01, 0x10, 0xFA, 0x00, 0x00, 0x02, 0x04, 0xC4, 0x00, 0x17, 0x70]);
    assert_eq!(exchange(&mut line, &w10), rtu(&[0x01, 0x90, 0x01]));
    assert_eq!(params(&mut line, 1).get(0xFA00u32), Some(0));
    // 02 illegal data address. manual VF-S15 p.31: 01 06 FF FF 00 00 89 EE -> 01 86 02 C3 A1.
    assert_eq!(
        exchange(&mut line, &[0x01, 0x06, 0xFF, 0xFF, 0x00, 0x00, 0x89, 0xEE]),
        [0x01, 0x86, 0x02, 0xC3, 0xA1]
    );
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x03, 0xFF, 0xFF, 0x00, 0x01])), rtu(&[0x01, 0x83, 0x02]));
    // 03 illegal data value (TIP data error): dEC 0.0 s.
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x06, 0x00, 0x10, 0x00, 0x00])), rtu(&[0x01, 0x86, 0x03]));
    // 04 slave device failure (TIP impossible to execute): FH while running, a monitor.
    run_60(&mut line);
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x06, 0x00, 0x11, 0x1F, 0x40])), rtu(&[0x01, 0x86, 0x04]));
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x06, 0xFD, 0x00, 0x00, 0x00])), rtu(&[0x01, 0x86, 0x04]));
    // A bad CRC: no reply.
    assert_eq!(exchange(&mut line, &[0x01, 0x03, 0xFD, 0x00, 0x00, 0x01, 0xB5, 0xA7]), b"");
    assert_eq!(params(&mut line, 1).get(0x0011u32), Some(8000));
    assert_eq!(params(&mut line, 1).get(0x0010u32), Some(100));
}

#[test]
fn device_identification() {
    let mut line = line_with(&[1]);
    // manual VF-S15 p.38: 01 2B 0E 01 00 70 77; the VF-AS1 answers with its own model name.
    let reply = exchange(&mut line, &[0x01, 0x2B, 0x0E, 0x01, 0x00, 0x70, 0x77]);
    let mut body = vec![0x01, 0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 0x03];
    for (id, text) in [(0u8, "TOSHIBA"), (1, "VFAS1-2037PM"), (2, "0100")] {
        body.push(id);
        body.push(text.len() as u8);
        body.extend(text.bytes());
    }
    assert_eq!(reply, rtu(&body));
    // The same layout as the manual's VF-S15 reply, "VFS15-2037PM" being as long as ours.
    let parsed = drivebus_proto::modbus::Reply::parse_rtu(&reply).unwrap();
    let ReplyPdu::ReadDeviceIdentification(id) = parsed.pdu else { panic!("{parsed:?}") };
    let texts: Vec<Vec<u8>> = id.objects.iter().map(|o| o.value.iter().collect()).collect();
    assert_eq!(texts, [b"TOSHIBA".to_vec(), b"VFAS1-2037PM".to_vec(), b"0100".to_vec()]);
    // Stream from object 02.
    let from2 = exchange(&mut line, &rtu(&[0x01, 0x2B, 0x0E, 0x01, 0x02]));
    assert_eq!(
        from2,
        rtu(&[0x01, 0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 0x01, 0x02, 0x04, b'0', b'1', b'0', b'0'])
    );
    // One specific object (04) needs individual access, which conformity level 01 lacks.
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x2B, 0x0E, 0x04, 0x00])), rtu(&[0x01, 0xAB, 0x03]));
}

#[test]
fn broadcast_executed_without_reply_and_other_numbers_silent() {
    let mut line = line_with(&[1, 2]);
    let bcast = rtu(&[0x00, 0x06, 0xFA, 0x01, 0x17, 0x70]);
    assert_eq!(exchange(&mut line, &bcast), b"");
    assert_eq!(params(&mut line, 1).get(0xFA01u32), Some(0x1770));
    assert_eq!(params(&mut line, 2).get(0xFA01u32), Some(0x1770));
    assert_eq!(exchange(&mut line, &rtu(&[0x00, 0x06, 0xFA, 0x00, 0xC4, 0x00])), b"");
    assert!(model(&mut line, 1).is_running() && model(&mut line, 2).is_running());
    // A broadcast that fails is not answered either.
    assert_eq!(exchange(&mut line, &rtu(&[0x00, 0x06, 0xFF, 0xFF, 0x00, 0x00])), b"");
    // Number 3 is not on the line; number 2 answers alone.
    assert_eq!(exchange(&mut line, &rtu(&[0x03, 0x03, 0xFA, 0x01, 0x00, 0x01])), b"");
    assert_eq!(
        exchange(&mut line, &rtu(&[0x02, 0x03, 0xFA, 0x01, 0x00, 0x01])),
        rtu(&[0x02, 0x03, 0x02, 0x17, 0x70])
    );
    // TIP frames mean nothing to a drive in Modbus mode.
    assert_eq!(exchange(&mut line, b"(02RFA01)\r"), b"");
}

#[test]
fn write_counts_eeprom_except_fa_numbers() {
    let mut line = line_with(&[1]);
    let dec = rtu(&[0x01, 0x06, 0x00, 0x10, 0x00, 0x64]);
    assert_eq!(exchange(&mut line, &dec), dec);
    assert_eq!(params(&mut line, 1).eeprom_writes(0x0010u32), Some(1));
    run_60(&mut line);
    assert_eq!(params(&mut line, 1).total_eeprom_writes(), 1, "FA00/FA01 are RAM only");
    assert_eq!(
        exchange(&mut line, &rtu(&[0x01, 0x03, 0xFA, 0x00, 0x00, 0x01])),
        rtu(&[0x01, 0x03, 0x02, 0xC4, 0x00])
    );
}

#[test]
fn comm_timeout_trips_and_fc90_shows_err5() {
    let mut line = line_with(&[1]);
    run_60(&mut line);
    exchange(&mut line, &rtu(&[0x01, 0x06, 0x08, 0x04, 0x00, 0x01]));
    exchange(&mut line, &rtu(&[0x01, 0x06, 0x08, 0x03, 0x00, 0x01]));
    wait(&mut line, Duration::from_millis(900));
    assert_eq!(model(&mut line, 1).trip(), None);
    wait(&mut line, Duration::from_millis(200));
    assert_eq!(model(&mut line, 1).trip(), Some(Trip::CommunicationTimeout));
    let fc90 = exchange(&mut line, &rtu(&[0x01, 0x03, 0xFC, 0x90, 0x00, 0x01]));
    assert_eq!(fc90, rtu(&[0x01, 0x03, 0x02, 0x00, TRIP_ERR5_COMMUNICATION as u8]));
    // FD01: tripped and FL.
    let fd01 = exchange(&mut line, &rtu(&[0x01, 0x03, 0xFD, 0x01, 0x00, 0x01]));
    assert_eq!(fd01, rtu(&[0x01, 0x03, 0x02, 0x00, 0x03]));
    // Fault reset (FA00 bit 13 with bit 15).
    let reset = rtu(&[0x01, 0x06, 0xFA, 0x00, 0xA0, 0x00]);
    assert_eq!(exchange(&mut line, &reset), reset);
    assert_eq!(model(&mut line, 1).trip(), None);
}

#[test]
fn master_session_over_the_line() {
    let mut line = line_with(&[9]);
    let mut master = MasterSession::new(ModbusRtu, rtu::timing(19200, CharFormat::EVEN_8E1));
    let req = Request::read_holding_registers(UnitId(9), 0xFE70, 1);
    master.send(line.now(), &req).unwrap();
    let value = support::master_outcome(&mut line, &mut master, |e| {
        let MasterEvent::Reply(r) = e else { panic!("{e:?}") };
        let ReplyPdu::ReadHoldingRegisters { values } = r.pdu else { panic!("{r:?}") };
        values.get(0)
    });
    assert_eq!(value, Some(175), "FE70 rated current 17.5 A");
}

#[test]
fn constructor_checks_numbers_and_snapshot_names_the_protocol() {
    let t = Instant::ZERO;
    assert!(ToshibaDrive::new(100, ToshibaProtocol::Tip, t).unwrap_err().contains("0..99"));
    assert!(ToshibaDrive::new(0, ToshibaProtocol::ModbusRtu, t).unwrap_err().contains("1..247"));
    assert!(ToshibaDrive::new(248, ToshibaProtocol::ModbusRtu, t).is_err());
    assert!(ToshibaDrive::new(0, ToshibaProtocol::Tip, t).is_ok());
    assert!(ToshibaDrive::new(247, ToshibaProtocol::ModbusRtu, t).is_ok());
    let mut line = line_with(&[5]);
    let fa01 = rtu(&[0x05, 0x06, 0xFA, 0x01, 0x17, 0x70]);
    assert_eq!(exchange(&mut line, &fa01), fa01);
    let run = rtu(&[0x05, 0x06, 0xFA, 0x00, 0xC4, 0x00]);
    assert_eq!(exchange(&mut line, &run), run);
    wait(&mut line, Duration::from_secs(8));
    let snap = line.drive(1).unwrap().snapshot();
    assert_eq!((snap.family.as_str(), snap.protocol.as_str(), snap.address), ("toshiba", "modbus-rtu", 5));
    assert_eq!(snap.state, "running");
    assert_eq!(snap.output_hz, 60.0);
    assert_eq!(snap.eeprom_writes, 0);
    assert!(snap.control_source.starts_with("communication"), "{}", snap.control_source);
    // f829 = 1 and f802 = 5 were set by the constructor.
    let p = params(&mut line, 1);
    assert_eq!((p.get(0x0829u32), p.get(0x0802u32)), (Some(1), Some(5)));
}
