//! Toshiba VF-AS1 on the TOSHIBA Inverter Protocol (ASCII and binary mode on one line), driven
//! through a real `VirtualLine` on simulated time. Frames from protocols.md section 5.2/5.3
//! (`seeds/002_43d8a4399c8be05f.txt` and the public VF-AS1/VF-S11 manuals).

mod support;

use std::time::Duration;

use drivebus_proto::checksum::sum8;
use drivebus_proto::session::{MasterEvent, MasterSession};
use drivebus_proto::toshiba::ascii::{AsciiAddress, AsciiRequest};
use drivebus_proto::toshiba::{default_timing, CommNo, Tip, TipRequest};
use drivebus_proto::Instant;
use drivebus_sim::bus::{Device, VirtualLine};
use drivebus_sim::family::toshiba::{ToshibaDrive, ToshibaProtocol, TRIP_E, TRIP_ERR5_COMMUNICATION};
use drivebus_sim::model::Trip;
use support::{exchange, model, params, toshiba_line, wait};

fn line_with(addresses: &[u8]) -> VirtualLine {
    toshiba_line(ToshibaProtocol::Tip, addresses)
}

/// A binary frame: `body` and its SUM.
fn bin(body: &[u8]) -> Vec<u8> {
    let mut f = body.to_vec();
    f.push(sum8(body));
    f
}

#[test]
fn ta4_ta5_read_output_current() {
    let mut line = line_with(&[0]);
    // protocols.md TA4: "(RFE03)" CR; stopped, the current is 0.
    assert_eq!(exchange(&mut line, b"(RFE03)\r"), b"(RFE030000)\r");
    // Running at 60 Hz: FE03 is 0.01 % of the rated current FE70 (17.5 A).
    exchange(&mut line, b"(PFA011770)\r");
    exchange(&mut line, b"(PFA00C400)\r");
    wait(&mut line, Duration::from_secs(10));
    let amps = model(&mut line, 1).current_a();
    assert!(amps > 0.0);
    let expect = format!("(RFE03{:04X})\r", (amps / 17.5 * 10000.0).round() as u16);
    assert_eq!(exchange(&mut line, b"(RFE03)\r"), expect.as_bytes());
    assert_eq!(exchange(&mut line, b"(RFE70)\r"), b"(RFE7000AF)\r", "17.5 A in 0.1 A");
}

#[test]
fn ta7_w_writes_eeprom_p_writes_ram() {
    let mut line = line_with(&[0]);
    // manual VF-AS1 p.17: W 0010 = 0064 writes 10.0 s; the reply echoes it.
    assert_eq!(exchange(&mut line, b"(W00100064)\r"), b"(W00100064)\r");
    assert_eq!(params(&mut line, 1).eeprom_writes(0x0010u32), Some(1));
    // P writes RAM only: the value changes, the EEPROM count does not.
    assert_eq!(exchange(&mut line, b"(P00100032)\r"), b"(P00100032)\r");
    assert_eq!(params(&mut line, 1).get(0x0010u32), Some(0x32));
    assert_eq!(params(&mut line, 1).eeprom_writes(0x0010u32), Some(1));
    assert_eq!(model(&mut line, 1).settings().decel, Duration::from_secs(5), "dEC re-derived");
    // Fewer than 4 data digits are echoed as 4 (project decision).
    assert_eq!(exchange(&mut line, b"(P001064)\r"), b"(P00100064)\r");
    // W to FA01 is RAM only: no EEPROM write.
    assert_eq!(exchange(&mut line, b"(WFA011770)\r"), b"(WFA011770)\r");
    assert_eq!(params(&mut line, 1).eeprom_writes(0xFA01u32), Some(0));
    assert_eq!(params(&mut line, 1).total_eeprom_writes(), 1);
    // With &SUM the reply carries one too.
    let mut req = b"(R0010&".to_vec();
    req.extend(format!("{:02X})\r", sum8(&req)).bytes());
    let mut expect = b"(R00100064&".to_vec();
    expect.extend(format!("{:02X})\r", sum8(&expect)).bytes());
    assert_eq!(exchange(&mut line, &req), expect);
}

#[test]
fn tb1_tb2_binary_read_and_write_echo() {
    let mut line = line_with(&[0]);
    // manual VF-AS1 p.10: "2F 52 00 00 81" reads 0000 (AU1 = 0).
    assert_eq!(
        exchange(&mut line, &[0x2F, 0x52, 0x00, 0x00, 0x81]),
        [0x2F, 0x52, 0x00, 0x00, 0x00, 0x00, 0x81]
    );
    // manual VF-AS1 p.17: "2F 57 00 10 00 64 FA"; the reply is identical.
    let tb2 = [0x2F, 0x57, 0x00, 0x10, 0x00, 0x64, 0xFA];
    assert_eq!(exchange(&mut line, &tb2), tb2);
    assert_eq!(params(&mut line, 1).eeprom_writes(0x0010u32), Some(1));
    // P (50H) in binary mode: RAM only.
    let p = bin(&[0x2F, 0x50, 0x00, 0x10, 0x00, 0x32]);
    assert_eq!(exchange(&mut line, &p), p);
    assert_eq!(params(&mut line, 1).eeprom_writes(0x0010u32), Some(1));
    // G (47H) reads with dummy data.
    let g = bin(&[0x2F, 0x47, 0x00, 0x10, 0x00, 0x00]);
    assert_eq!(exchange(&mut line, &g), bin(&[0x2F, 0x47, 0x00, 0x10, 0x00, 0x32]));
    // With INV-NO.
    let r = bin(&[0x2F, 0x00, 0x52, 0xFE, 0x70]);
    assert_eq!(exchange(&mut line, &r), bin(&[0x2F, 0x00, 0x52, 0xFE, 0x70, 0x00, 0xAF]));
}

#[test]
fn tb14_block_communication() {
    let mut line = line_with(&[0]);
    // manual VF-AS1 p.16: the SUM D8 is wrong (D9 is right): checksum error 0004.
    let tb14 = [0x2F, 0x58, 0x02, 0x05, 0xC4, 0x00, 0x17, 0x70, 0xD8];
    assert_eq!(exchange(&mut line, &tb14), [0x2F, 0x4E, 0x00, 0x04, 0x81]);
    assert!(!model(&mut line, 1).is_running());
    // With D9: FA00 = C400 (run forward, both priorities), FA01 = 60.00 Hz; 5 read items
    // FD01, FD00, FE03, FC90, FE05 (f875-f879 defaults).
    let good = [0x2F, 0x58, 0x02, 0x05, 0xC4, 0x00, 0x17, 0x70, 0xD9];
    let reply = exchange(&mut line, &good);
    assert!(model(&mut line, 1).is_running());
    assert_eq!(reply.len(), 3 + 2 * 5 + 1);
    assert_eq!(&reply[..3], [0x2F, 0x59, 0x05]);
    assert_eq!(*reply.last().unwrap(), sum8(&reply[..reply.len() - 1]));
    let fd01 = u16::from_be_bytes([reply[3], reply[4]]);
    assert_ne!(fd01 & 0x0400, 0, "FD01 bit 10 running");
    assert_eq!(&reply[9..11], [0x00, 0x00], "FC90: no trip");
    // ACC 10.0 s from 0 to FH 80 Hz: 60 Hz after 7.5 s.
    wait(&mut line, Duration::from_secs(8));
    let reply = exchange(&mut line, &bin(&[0x2F, 0x58, 0x00, 0x05]));
    assert_eq!(&reply[5..7], [0x17, 0x70], "FD00 = 60.00 Hz");
    // nR over 5: a reply with no read groups; the write is still done.
    let stop = bin(&[0x2F, 0x58, 0x01, 0x06, 0xC0, 0x00]);
    assert_eq!(exchange(&mut line, &stop), bin(&[0x2F, 0x59, 0x00]));
    assert_eq!(params(&mut line, 1).get(0xFA00u32), Some(0xC000));
    // nW over 2: format error, no reply, nothing done.
    let bad = bin(&[0x2F, 0x58, 0x03, 0x01, 0xC4, 0x00, 0x17, 0x70, 0x00, 0x00]);
    assert_eq!(exchange(&mut line, &bad), b"");
    assert_eq!(params(&mut line, 1).get(0xFA00u32), Some(0xC000));
    // The write targets follow f870/f871: swap them.
    exchange(&mut line, b"(P08700003)\r");
    exchange(&mut line, b"(P08710001)\r");
    let swapped = bin(&[0x2F, 0x58, 0x02, 0x00, 0x0B, 0xB8, 0xC4, 0x00]);
    assert_eq!(exchange(&mut line, &swapped), bin(&[0x2F, 0x59, 0x00]));
    assert_eq!(params(&mut line, 1).get(0xFA01u32), Some(3000));
    assert_eq!(params(&mut line, 1).get(0xFA00u32), Some(0xC400));
}

#[test]
fn ta13_ascii_wildcard_smallest_number_answers() {
    let mut line = line_with(&[2, 12, 22, 3]);
    // manual VF-S11 p.9: "(*2R0000)CR -> (02R00000000)CR", from inverter 02 only.
    assert_eq!(exchange(&mut line, b"(*2R0000)\r"), b"(02R00000000)\r");
    // Every matching drive acts, only 02 answers; 03 does not match.
    assert_eq!(exchange(&mut line, b"(*2PFA011770)\r"), b"(02PFA011770)\r");
    for port in 1..=3 {
        assert_eq!(params(&mut line, port).get(0xFA01u32), Some(0x1770), "port {port}");
    }
    assert_eq!(params(&mut line, 4).get(0xFA01u32), Some(0));
    // A pattern whose smallest number is not on the line: all act, none answers.
    assert_eq!(exchange(&mut line, b"(1*PFA010BB8)\r"), b"");
    assert_eq!(params(&mut line, 2).get(0xFA01u32), Some(0x0BB8));
    // Another number: silence.
    assert_eq!(exchange(&mut line, b"(05RFD00)\r"), b"");
    assert_eq!(exchange(&mut line, b"(12RFA01)\r"), b"(12RFA010BB8)\r");
}

#[test]
fn binary_broadcast_only_inverter_00_answers() {
    let mut line = line_with(&[0, 1]);
    let read = bin(&[0x2F, 0xFF, 0x52, 0xFE, 0x70]);
    assert_eq!(exchange(&mut line, &read), bin(&[0x2F, 0x00, 0x52, 0xFE, 0x70, 0x00, 0xAF]));
    // A broadcast write acts on both.
    let write = bin(&[0x2F, 0xFF, 0x50, 0xFA, 0x01, 0x17, 0x70]);
    assert_eq!(exchange(&mut line, &write), bin(&[0x2F, 0x00, 0x50, 0xFA, 0x01, 0x17, 0x70]));
    assert_eq!(params(&mut line, 1).get(0xFA01u32), Some(0x1770));
    assert_eq!(params(&mut line, 2).get(0xFA01u32), Some(0x1770));
    // Without inverter 00 a broadcast is executed and never answered.
    let mut line = line_with(&[1, 2]);
    assert_eq!(exchange(&mut line, &write), b"");
    assert_eq!(params(&mut line, 1).get(0xFA01u32), Some(0x1770));
    assert_eq!(params(&mut line, 2).get(0xFA01u32), Some(0x1770));
    // Another number: silence.
    assert_eq!(exchange(&mut line, &bin(&[0x2F, 0x05, 0x52, 0xFD, 0x00])), b"");
}

/// Starts the motor at `hz_hex` and lets it reach speed.
fn run_at(line: &mut VirtualLine, hz_hex: &str) {
    exchange(line, format!("(PFA01{hz_hex})\r").as_bytes());
    exchange(line, b"(PFA00C400)\r");
    wait(line, Duration::from_secs(10));
}

#[test]
fn every_ascii_error_code() {
    let mut line = line_with(&[0]);
    run_at(&mut line, "1770");
    // 0000 impossible to execute: FH (0011) cannot change while running.
    assert_eq!(exchange(&mut line, b"(W00111F40)\r"), b"(N0000)\r");
    // ... nor can a monitor be written.
    assert_eq!(exchange(&mut line, b"(PFD001234)\r"), b"(N0000)\r");
    // 0001 data error: dEC is 0.1..6000.0 s.
    assert_eq!(exchange(&mut line, b"(W00100000)\r"), b"(N0001)\r");
    // ... and UL above FH.
    assert_eq!(exchange(&mut line, b"(W00121F41)\r"), b"(N0001)\r");
    // 0002 no such communication number.
    assert_eq!(exchange(&mut line, b"(RFFFF)\r"), b"(N0002)\r");
    assert_eq!(exchange(&mut line, b"(00R1234)\r"), b"(00N0002)\r");
    // 0003 command error (ASCII mode answers it).
    assert_eq!(exchange(&mut line, b"(X0000)\r"), b"(N0003)\r");
    // 0004 checksum error: (R0000&60) is right, &61 is not; the reply carries a SUM.
    assert_eq!(exchange(&mut line, b"(R0000&60)\r"), b"(R00000000&20)\r");
    assert_eq!(exchange(&mut line, b"(R0000&61)\r"), b"(N0004&60)\r");
    // Format errors: no reply (one-digit INV-NO, "(R11)" CR, a wrong stop code).
    assert_eq!(exchange(&mut line, b"(0R0000)\r"), b"");
    assert_eq!(exchange(&mut line, b"(R11)\r"), b"");
    assert_eq!(exchange(&mut line, b"(R0000]\r"), b"");
    // Refused writes changed nothing, counted nothing.
    assert_eq!(params(&mut line, 1).get(0x0011u32), Some(8000));
    assert_eq!(params(&mut line, 1).total_eeprom_writes(), 0);
}

#[test]
fn every_binary_error_code() {
    let mut line = line_with(&[0]);
    run_at(&mut line, "1770");
    // protocols.md TB9: 0000 impossible to execute.
    assert_eq!(
        exchange(&mut line, &bin(&[0x2F, 0x57, 0x00, 0x11, 0x1F, 0x40])),
        [0x2F, 0x4E, 0x00, 0x00, 0x7D]
    );
    // TB10: 0001 data error.
    assert_eq!(
        exchange(&mut line, &bin(&[0x2F, 0x57, 0x00, 0x10, 0x00, 0x00])),
        [0x2F, 0x4E, 0x00, 0x01, 0x7E]
    );
    // TB11: 0002 no such communication number.
    assert_eq!(exchange(&mut line, &bin(&[0x2F, 0x52, 0xFF, 0xFF])), [0x2F, 0x4E, 0x00, 0x02, 0x7F]);
    // 0003 command error: binary mode does not answer it.
    assert_eq!(exchange(&mut line, &bin(&[0x2F, 0x51, 0x00, 0x10])), b"");
    // TB12: 0004 checksum error.
    assert_eq!(exchange(&mut line, &[0x2F, 0x52, 0x00, 0x00, 0x80]), [0x2F, 0x4E, 0x00, 0x04, 0x81]);
    // With INV-NO the error reply carries it.
    assert_eq!(
        exchange(&mut line, &bin(&[0x2F, 0x00, 0x52, 0xFF, 0xFF])),
        bin(&[0x2F, 0x00, 0x4E, 0x00, 0x02])
    );
    // The drive still answers normally afterwards.
    assert_eq!(
        exchange(&mut line, &[0x2F, 0x52, 0x00, 0x00, 0x81]),
        [0x2F, 0x52, 0x00, 0x00, 0x00, 0x00, 0x81]
    );
}

#[test]
fn lower_case_while_tripped() {
    let mut line = line_with(&[0]);
    run_at(&mut line, "1770");
    // FA00 bit 12, emergency stop (with bit 15): the drive trips E; the reply is already lower case.
    assert_eq!(exchange(&mut line, b"(PFA009000)\r"), b"(pFA009000)\r");
    assert_eq!(model(&mut line, 1).trip(), Some(Trip::External));
    assert_eq!(model(&mut line, 1).output_hz(), 0.0);
    assert_eq!(exchange(&mut line, b"(RFC90)\r"), format!("(rFC90{TRIP_E:04X})\r").as_bytes());
    assert_eq!(exchange(&mut line, b"(RFD01)\r"), b"(rFD011003)\r", "emergency-stopped, tripped, FL");
    assert_eq!(exchange(&mut line, b"(RFFFF)\r"), b"(n0002)\r");
    assert_eq!(exchange(&mut line, b"(W00100064)\r"), b"(w00100064)\r");
    // Binary mode: CMD + 20H.
    assert_eq!(
        exchange(&mut line, &bin(&[0x2F, 0x52, 0xFD, 0x00])),
        bin(&[0x2F, 0x72, 0xFD, 0x00, 0x00, 0x00])
    );
    assert_eq!(exchange(&mut line, &bin(&[0x2F, 0x52, 0xFF, 0xFF])), [0x2F, 0x6E, 0x00, 0x02, 0x9F]);
    assert_eq!(exchange(&mut line, &[0x2F, 0x52, 0x00, 0x00, 0x80]), [0x2F, 0x6E, 0x00, 0x04, 0xA1]);
    let block = exchange(&mut line, &bin(&[0x2F, 0x58, 0x00, 0x04]));
    assert_eq!(&block[..3], [0x2F, 0x79, 0x04], "y");
    assert_eq!(&block[9..11], [0x00, TRIP_E as u8], "FC90 in the block");
    // Running is refused while tripped.
    exchange(&mut line, b"(PFA00C400)\r");
    assert!(!model(&mut line, 1).is_running());
    // Fault reset (bit 13): the reply after it is upper case again; the trip is in the past-trip log.
    assert_eq!(exchange(&mut line, b"(PFA00A000)\r"), b"(PFA00A000)\r");
    assert_eq!(exchange(&mut line, b"(RFC90)\r"), b"(RFC900000)\r");
    assert_eq!(exchange(&mut line, b"(RFE10)\r"), format!("(RFE10{TRIP_E:04X})\r").as_bytes());
    assert_eq!(exchange(&mut line, b"(RFE00)\r"), b"(RFE001770)\r", "output frequency at the trip");
}

#[test]
fn run_ramps_on_simulated_time_and_stops() {
    let mut line = line_with(&[7]);
    exchange(&mut line, b"(07PFA011770)\r");
    // The command acts when its last byte (CR) arrives.
    let frame = b"(07PFA00C400)\r";
    let sent_at = line.now();
    let arrives = sent_at + line.char_time() * frame.len() as u32;
    line.master_write(sent_at, frame);
    line.advance_to(arrives + Duration::from_millis(3750));
    // ACC 10.0 s from 0 to FH 80.00 Hz: 8 Hz/s, 30 Hz at 3.75 s.
    let mhz = model(&mut line, 1).output_mhz();
    assert!((29_990..=30_000).contains(&mhz), "{mhz} mHz");
    while let Some(t) = line.next_deadline() {
        line.advance_to(t);
    }
    let mut echo = Vec::new();
    line.master_read(&mut echo);
    assert_eq!(echo, frame);
    wait(&mut line, Duration::from_secs(5));
    assert_eq!(exchange(&mut line, b"(07RFD00)\r"), b"(07RFD001770)\r");
    assert_eq!(exchange(&mut line, b"(07RFE02)\r"), b"(07RFE021770)\r");
    let status = exchange(&mut line, b"(07RFD01)\r");
    assert_eq!(status, b"(07RFD016400)\r", "standby, ST on, running");
    // Reverse (C600): ramps through zero to the other side.
    exchange(&mut line, b"(07PFA00C600)\r");
    wait(&mut line, Duration::from_secs(20));
    assert_eq!(model(&mut line, 1).output_rotation(), drivebus_sim::model::Rotation::Reverse);
    assert_eq!(exchange(&mut line, b"(07RFD01)\r"), b"(07RFD016600)\r");
    // Upper limit UL clamps the command: 50 Hz.
    exchange(&mut line, b"(07P00121388)\r");
    exchange(&mut line, b"(07PFA011F40)\r");
    wait(&mut line, Duration::from_secs(10));
    assert_eq!(exchange(&mut line, b"(07RFD00)\r"), b"(07RFD001388)\r");
    // Stop (C000): DEC 10.0 s from FH, 50 Hz -> 0 in 6.25 s.
    exchange(&mut line, b"(07PFA00C000)\r");
    wait(&mut line, Duration::from_secs(7));
    assert!(!model(&mut line, 1).is_running());
    assert_eq!(exchange(&mut line, b"(07RFD00)\r"), b"(07RFD000000)\r");
}

#[test]
fn command_needs_priority_and_frequency_needs_bit_14() {
    let mut line = line_with(&[0]);
    exchange(&mut line, b"(PFA011770)\r");
    // Run without command priority (bit 15): ignored.
    exchange(&mut line, b"(PFA004400)\r");
    wait(&mut line, Duration::from_secs(1));
    assert!(!model(&mut line, 1).is_running());
    assert!(line.drive(1).unwrap().control_source().starts_with("CMOd (0003) = 0"));
    // 8400: command priority, run, panel frequency (0.00 Hz by default; then 20 Hz).
    exchange(&mut line, b"(PFA008400)\r");
    assert!(model(&mut line, 1).is_running());
    assert_eq!(model(&mut line, 1).setpoint_hz(), 0.0);
    assert!(line.drive(1).unwrap().control_source().starts_with("communication"));
    // C400: FA01 is used.
    exchange(&mut line, b"(PFA00C400)\r");
    assert_eq!(model(&mut line, 1).setpoint_hz(), 60.0);
    // Releasing command priority stops the motor (the terminal board gives no run signal).
    exchange(&mut line, b"(PFA000000)\r");
    assert_eq!(model(&mut line, 1).state(), drivebus_sim::model::RunState::Stopping);
    wait(&mut line, Duration::from_secs(1));
    assert_eq!(model(&mut line, 1).state(), drivebus_sim::model::RunState::Stopped);
    // Coast stop (bit 11) and jog (bit 8).
    exchange(&mut line, b"(PFA00C400)\r");
    wait(&mut line, Duration::from_secs(2));
    exchange(&mut line, b"(PFA00C800)\r");
    assert_eq!(model(&mut line, 1).output_hz(), 0.0);
    assert_eq!(exchange(&mut line, b"(RFD01)\r"), b"(RFD016800)\r", "coast-stopped");
    exchange(&mut line, b"(PFA00C500)\r");
    wait(&mut line, Duration::from_secs(2));
    assert_eq!(model(&mut line, 1).output_hz(), 5.0, "jog frequency");
    assert_eq!(exchange(&mut line, b"(RFD01)\r"), b"(RFD016500)\r");
}

#[test]
fn parameter_writes_are_checked() {
    let mut line = line_with(&[0]);
    // ACC 5.0 s (0032H) by W: counted; the model follows.
    assert_eq!(exchange(&mut line, b"(W00090032)\r"), b"(W00090032)\r");
    assert_eq!(model(&mut line, 1).settings().accel, Duration::from_secs(5));
    // FH may change while stopped; the model's maximum follows.
    assert_eq!(exchange(&mut line, b"(W00111770)\r"), b"(W00111770)\r");
    assert_eq!(model(&mut line, 1).settings().max_hz, 60.0);
    // f803 range 0..100 s.
    assert_eq!(exchange(&mut line, b"(W08030065)\r"), b"(N0001)\r");
    // LL above UL: data error.
    assert_eq!(exchange(&mut line, b"(W00131771)\r"), b"(N0001)\r");
    // Read-only catalog entry (FE70 rated current).
    assert_eq!(exchange(&mut line, b"(WFE700001)\r"), b"(N0000)\r");
    let p = params(&mut line, 1);
    assert_eq!(p.eeprom_writes(0x0009u32), Some(1));
    assert_eq!(p.eeprom_writes(0x0011u32), Some(1));
    assert_eq!(p.total_eeprom_writes(), 2);
    // Every catalog parameter reads back its value.
    assert_eq!(exchange(&mut line, b"(R0829)\r"), b"(R08290000)\r");
    assert_eq!(exchange(&mut line, b"(R0802)\r"), b"(R08020000)\r");
    assert_eq!(exchange(&mut line, b"(R0870)\r"), b"(R08700001)\r");
}

#[test]
fn comm_timeout_trips_err5() {
    let mut line = line_with(&[0]);
    run_at(&mut line, "1770");
    // f804 = 1 (trip), f803 = 2 s.
    exchange(&mut line, b"(P08040001)\r");
    exchange(&mut line, b"(P08030002)\r");
    // Telegrams keep it alive.
    for _ in 0..3 {
        wait(&mut line, Duration::from_millis(1500));
        assert_eq!(exchange(&mut line, b"(RFC90)\r"), b"(RFC900000)\r");
    }
    // The last valid telegram ended when its CR arrived; the trip comes 2 s later, exactly.
    let last_sent = line.now();
    exchange(&mut line, b"(RFC90)\r");
    let last_comm = last_sent + line.char_time() * 8;
    wait(&mut line, Duration::from_millis(2100));
    assert_eq!(model(&mut line, 1).trip(), Some(Trip::CommunicationTimeout));
    let record = *model(&mut line, 1).recent_trips().next().unwrap();
    assert_eq!(record.at, last_comm + Duration::from_secs(2));
    assert_eq!(record.output_mhz, 60_000);
    assert_eq!(model(&mut line, 1).output_hz(), 0.0);
    assert_eq!(
        exchange(&mut line, b"(RFC90)\r"),
        format!("(rFC90{TRIP_ERR5_COMMUNICATION:04X})\r").as_bytes()
    );
    assert_eq!(
        exchange(&mut line, &bin(&[0x2F, 0x52, 0xFC, 0x90])),
        bin(&[0x2F, 0x72, 0xFC, 0x90, 0x00, 0x18])
    );
    // Fault reset over the line.
    assert_eq!(exchange(&mut line, b"(PFA00A000)\r"), b"(PFA00A000)\r");
    assert_eq!(model(&mut line, 1).trip(), None);
    // f804 = 0, alarm only: FD01 bit 2 after the time-out, the motor keeps running.
    exchange(&mut line, b"(P08040000)\r");
    exchange(&mut line, b"(PFA00C400)\r");
    wait(&mut line, Duration::from_secs(3));
    assert_eq!(model(&mut line, 1).trip(), None);
    assert!(model(&mut line, 1).is_running());
    assert_eq!(exchange(&mut line, b"(RFD01)\r"), b"(RFD016404)\r");
}

#[test]
fn comm_timeout_with_deceleration_stop() {
    let mut line = line_with(&[0]);
    run_at(&mut line, "1770");
    // f804 = 2: trip after a deceleration stop; f803 = 1 s.
    exchange(&mut line, b"(P08040002)\r");
    exchange(&mut line, b"(P08030001)\r");
    // DEC 10.0 s from FH 80 Hz: 60 Hz -> 0 in 7.5 s, then Err5.
    wait(&mut line, Duration::from_secs(5));
    let m = model(&mut line, 1);
    assert_eq!(m.trip(), None);
    assert!(m.output_hz() > 20.0 && m.output_hz() < 40.0, "{}", m.output_hz());
    wait(&mut line, Duration::from_secs(4));
    assert_eq!(model(&mut line, 1).trip(), Some(Trip::CommunicationTimeout));
    assert_eq!(model(&mut line, 1).recent_trips().next().unwrap().output_mhz, 0);
    assert_eq!(exchange(&mut line, b"(RFC90)\r"), b"(rFC900018)\r");
}

#[test]
fn f829_takes_effect_at_power_cycle() {
    let t0 = Instant::from_millis(100);
    let mut drive = ToshibaDrive::new(3, ToshibaProtocol::Tip, t0).unwrap();
    let ask = |drive: &mut ToshibaDrive, now: Instant, bytes: &[u8]| {
        drive.receive(now, bytes);
        drive.silence(now + Duration::from_millis(2));
        let at = now + Duration::from_millis(50);
        drive.advance_to(at);
        drive.poll_transmit(at).unwrap_or_default()
    };
    // W f829 = 1 (Modbus) and P dEC = 5.0 s: the drive still speaks TIP.
    assert_eq!(ask(&mut drive, t0, b"(03W08290001)\r"), b"(03W08290001)\r");
    assert_eq!(ask(&mut drive, t0 + Duration::from_millis(100), b"(03P00100032)\r"), b"(03P00100032)\r");
    assert_eq!(drive.protocol_in_force(), ToshibaProtocol::Tip);
    assert_eq!(drivebus_sim::drive::VirtualDrive::protocol(&drive), "toshiba-ascii+toshiba-binary");
    // Power cycle: Modbus-RTU from now on, after 2 s without communication; the P value is gone.
    let t1 = Instant::from_millis(1000);
    drive.power_cycle(t1);
    assert_eq!(drive.protocol_in_force(), ToshibaProtocol::ModbusRtu);
    let core = drivebus_sim::drive::VirtualDrive::core(&drive);
    assert_eq!(core.params.get(0x0010u32), Some(100), "EEPROM value back");
    assert_eq!(core.params.eeprom_writes(0x0829u32), Some(1));
    let read = [0x03, 0x03, 0x08, 0x29, 0x00, 0x01];
    let read = rtu(&read);
    assert_eq!(ask(&mut drive, t1 + Duration::from_secs(1), &read), b"", "starting up");
    let t2 = t1 + Duration::from_secs(3);
    assert_eq!(ask(&mut drive, t2, &read), rtu(&[0x03, 0x03, 0x02, 0x00, 0x01]));
    assert_eq!(ask(&mut drive, t2 + Duration::from_millis(100), b"(03R0829)\r"), b"");
    // Back to TIP with 06 f829 = 0 and another power cycle.
    let write = rtu(&[0x03, 0x06, 0x08, 0x29, 0x00, 0x00]);
    assert_eq!(ask(&mut drive, t2 + Duration::from_millis(200), &write), write);
    let t3 = t2 + Duration::from_secs(1);
    drive.power_cycle(t3);
    assert_eq!(ask(&mut drive, t3 + Duration::from_secs(3), b"(03R0829)\r"), b"(03R08290000)\r");
}

fn rtu(body: &[u8]) -> Vec<u8> {
    let mut f = body.to_vec();
    f.extend(drivebus_proto::checksum::crc16_modbus(body).to_le_bytes());
    f
}

#[test]
fn master_session_reads_through_the_line() {
    let mut line = line_with(&[4]);
    let mut master = MasterSession::new(Tip::default(), default_timing());
    let req = TipRequest::Ascii(AsciiRequest::read(AsciiAddress::Unit(4), CommNo::RATED_CURRENT));
    master.send(line.now(), &req).unwrap();
    let event = support::master_outcome(&mut line, &mut master, |e| e);
    let MasterEvent::Reply(reply) = event else { panic!("{event:?}") };
    assert_eq!(reply.data(), Some(175));
    assert_eq!(reply.error(), None);
    assert!(!reply.tripped());
}

#[test]
fn random_bytes_never_panic_in_either_protocol() {
    for protocol in [ToshibaProtocol::Tip, ToshibaProtocol::ModbusRtu] {
        let mut drive = ToshibaDrive::new(1, protocol, Instant::ZERO).unwrap();
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut now = Instant::ZERO;
        let alphabet = b"()&*/0123456789ABCDEFRWPGXNrwp\r\x2F\x01\x03\x06\x2B\x0E\xFF\x00";
        for i in 0..20_000u32 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let b = if x % 3 == 0 { (x >> 24) as u8 } else { alphabet[(x >> 32) as usize % alphabet.len()] };
            now = now + Duration::from_micros(600);
            drive.receive(now, &[b]);
            if i % 7 == 0 {
                drive.silence(now);
            }
            let _ = drive.poll_transmit(now + Duration::from_millis(10));
        }
    }
}
