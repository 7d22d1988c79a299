//! The generic Chinese VFD (`seeds/004_e8ea1998fe1a671e.txt`) on a virtual line, on simulated
//! time: the seed's own frames, every exception with its bytes, broadcast and addressing,
//! ramps, commands, parameters and EEPROM counts.

use std::time::Duration;

use drivebus_proto::checksum::{crc16_modbus, lrc};
use drivebus_proto::modbus::rtu::{self, ModbusRtu};
use drivebus_proto::modbus::{Reply, ReplyPdu, Request, UnitId};
use drivebus_proto::session::{MasterEvent, MasterSession};
use drivebus_proto::Instant;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::drive::VirtualDrive;
use drivebus_sim::family::generic::{reg, status, GenericDrive, GenericProtocol};
use drivebus_sim::model::{RunState, Trip};

const BAUD: u32 = 9600;

/// A line at 9600 baud in the protocol's default format with drives at `addresses`.
fn line_with(protocol: GenericProtocol, addresses: &[u8]) -> VirtualLine {
    let mut line =
        VirtualLine::new(BAUD, drivebus_sim::family::generic::char_format(protocol), Instant::ZERO);
    for &a in addresses {
        let drive = GenericDrive::new(a, protocol, Instant::ZERO).expect("a valid address");
        line.add_device(Box::new(drive));
    }
    line
}

fn rtu_line() -> VirtualLine {
    line_with(GenericProtocol::Rtu, &[1])
}

fn ascii_line() -> VirtualLine {
    line_with(GenericProtocol::Ascii, &[1])
}

/// Runs the line until nothing is pending.
fn settle(line: &mut VirtualLine) {
    while let Some(t) = line.next_deadline() {
        line.advance_to(t);
    }
}

/// Writes `request` now, lets the line settle, and returns what reached the master.
fn exchange(line: &mut VirtualLine, request: &[u8]) -> Vec<u8> {
    let now = line.now();
    line.master_write(now, request);
    settle(line);
    let mut got = Vec::new();
    line.master_read(&mut got);
    got
}

/// `body` + its CRC, low byte first.
fn rtu(body: &[u8]) -> Vec<u8> {
    let mut v = body.to_vec();
    v.extend_from_slice(&crc16_modbus(body).to_le_bytes());
    v
}

/// `:` + hex digits of `body` and its LRC + CR LF.
fn ascii(body: &[u8]) -> Vec<u8> {
    let mut s = String::from(":");
    for b in body.iter().chain(std::iter::once(&lrc(body))) {
        s.push_str(&format!("{b:02X}"));
    }
    s.push_str("\r\n");
    s.into_bytes()
}

fn read_req(unit: u8, start: u16, quantity: u16) -> Vec<u8> {
    let [a, b] = start.to_be_bytes();
    let [c, d] = quantity.to_be_bytes();
    rtu(&[unit, 0x03, a, b, c, d])
}

fn write_req(unit: u8, register: u16, value: u16) -> Vec<u8> {
    let [a, b] = register.to_be_bytes();
    let [c, d] = value.to_be_bytes();
    rtu(&[unit, 0x06, a, b, c, d])
}

/// Reads one register of drive 1 over RTU and returns its value.
fn read1(line: &mut VirtualLine, register: u16) -> u16 {
    let reply = exchange(line, &read_req(1, register, 1));
    assert_eq!(reply.len(), 7, "a one-register reply, got {reply:02X?}");
    assert_eq!(reply, rtu(&reply[..5]));
    u16::from_be_bytes([reply[3], reply[4]])
}

/// Writes one register of drive 1 over RTU and asserts the echo.
fn write1(line: &mut VirtualLine, register: u16, value: u16) {
    let request = write_req(1, register, value);
    assert_eq!(exchange(line, &request), request, "06 echo for {register:04X}H = {value}");
}

fn drive(line: &mut VirtualLine) -> &dyn VirtualDrive {
    line.drive(1).expect("port 1 holds a virtual drive")
}

fn drive_mut(line: &mut VirtualLine) -> &mut dyn VirtualDrive {
    line.drive_mut(1).expect("port 1 holds a virtual drive")
}

/// Advances the line's simulated time by `d`.
fn wait(line: &mut VirtualLine, d: Duration) {
    let t = line.now() + d;
    line.advance_to(t);
}

// ------------------------------------------------------------------------------------------
// The seed's own examples
// ------------------------------------------------------------------------------------------

#[test]
fn seed_ascii_write_p0_02_is_echoed_and_stored() {
    // seed 004, 06H example: ":0106000213885C" both ways (P0.02 = 50.00 Hz).
    let mut line = ascii_line();
    let request = b":0106000213885C\r\n";
    assert_eq!(exchange(&mut line, request), request.to_vec());
    let params = &drive(&mut line).core().params;
    assert_eq!(params.get("P0.02"), Some(5000));
    assert_eq!(params.eeprom_writes("P0.02"), Some(1));
}

#[test]
fn seed_rtu_write_is_echoed() {
    // seed 004 (with address 01H, as its CRC 25 5C says): the reply is identical.
    let mut line = rtu_line();
    let request = [0x01, 0x06, 0x00, 0x02, 0x13, 0x88, 0x25, 0x5C];
    assert_eq!(exchange(&mut line, &request), request);
    assert_eq!(drive(&mut line).core().params.get("P0.02"), Some(5000));
}

#[test]
fn seed_loop_back_is_echoed_in_rtu_and_ascii() {
    // "变频器将收到的资料原封不动送给主控设备": sub-function 0102H, data 0304H, echoed.
    let mut line = rtu_line();
    let request = [0x01, 0x08, 0x01, 0x02, 0x03, 0x04, 0x41, 0x04];
    assert_eq!(exchange(&mut line, &request), request);

    let mut line = ascii_line();
    let request = b":010801020304ED\r\n";
    assert_eq!(exchange(&mut line, request), request.to_vec());
    // Sub-function 0000 (return query data) is echoed as well.
    let request = ascii(&[0x01, 0x08, 0x00, 0x00, 0xA5, 0x37]);
    assert_eq!(exchange(&mut line, &request), request);
}

#[test]
fn seed_broadcast_write_is_executed_by_every_drive_and_answered_by_none() {
    // The seed's RTU request with address 00H: CRC 24 8D for address 0 (protocols.md 3.5).
    let mut line = line_with(GenericProtocol::Rtu, &[1, 2]);
    let request = [0x00, 0x06, 0x00, 0x02, 0x13, 0x88, 0x24, 0x8D];
    assert_eq!(request.to_vec(), rtu(&request[..6]));
    assert!(exchange(&mut line, &request).is_empty());
    // The broadcast 2001H = 40.00 Hz: the setpoint changes, nothing on the line.
    assert!(exchange(&mut line, &[0x00, 0x06, 0x20, 0x01, 0x0F, 0xA0, 0xD7, 0x93]).is_empty());
    assert_eq!(line.stats().device_bytes, 0);
    for port in [1, 2] {
        let d = line.drive(port).expect("a drive");
        assert_eq!(d.core().params.get("P0.02"), Some(5000));
        assert_eq!(d.core().params.get("2001H"), Some(4000));
        assert_eq!(d.snapshot().setpoint_hz, 40.0);
    }
    // A broadcast run starts both; reads are not answered either.
    assert!(exchange(&mut line, &write_req(0, reg::COMMAND, 2)).is_empty());
    assert!(exchange(&mut line, &read_req(0, reg::OUTPUT_FREQUENCY, 1)).is_empty());
    assert_eq!(line.stats().device_bytes, 0);
    for port in [1, 2] {
        assert_eq!(line.drive(port).map(|d| d.core().model.state()), Some(RunState::Running));
    }
}

#[test]
fn ascii_broadcast_is_silent() {
    let mut line = line_with(GenericProtocol::Ascii, &[1, 3]);
    assert!(exchange(&mut line, &ascii(&[0x00, 0x06, 0x20, 0x01, 0x0F, 0xA0])).is_empty());
    assert_eq!(line.stats().device_bytes, 0);
    assert_eq!(line.drive(2).map(|d| d.snapshot().setpoint_hz), Some(40.0));
}

// ------------------------------------------------------------------------------------------
// Addressing and damaged frames
// ------------------------------------------------------------------------------------------

#[test]
fn a_drive_answers_only_its_own_address() {
    let mut line = line_with(GenericProtocol::Rtu, &[2]);
    assert!(exchange(&mut line, &read_req(1, reg::STATUS, 1)).is_empty());
    assert!(exchange(&mut line, &write_req(1, reg::FREQUENCY, 1000)).is_empty());
    assert_eq!(line.drive(1).map(|d| d.snapshot().setpoint_hz), Some(0.0), "not executed");
    assert_eq!(line.stats().device_bytes, 0);
    // Its own address: 2101H = run from comms, frequency from comms.
    let status_bits = status::RUN_FROM_COMM | status::FREQUENCY_FROM_COMM;
    let [hi, lo] = status_bits.to_be_bytes();
    assert_eq!(exchange(&mut line, &read_req(2, reg::STATUS, 1)), rtu(&[0x02, 0x03, 0x02, hi, lo]));

    let mut line = line_with(GenericProtocol::Ascii, &[2]);
    assert!(exchange(&mut line, b":0106000213885C\r\n").is_empty());
    assert_eq!(line.stats().device_bytes, 0);
}

#[test]
fn the_highest_address_254_works_and_bad_addresses_are_refused() {
    let mut line = line_with(GenericProtocol::Rtu, &[254]);
    let reply = exchange(&mut line, &read_req(254, reg::VERSION, 1));
    assert_eq!(reply, rtu(&[0xFE, 0x03, 0x02, 0x01, 0x00]), "version 1.00 in BCD");
    for bad in [0, 255] {
        let e = GenericDrive::new(bad, GenericProtocol::Rtu, Instant::ZERO).err();
        assert_eq!(
            e.as_deref(),
            Some(
                format!("a generic drive's address is 1..254 (0 is the broadcast address), not {bad}")
                    .as_str()
            )
        );
    }
    assert_eq!("modbus-ascii".parse::<GenericProtocol>(), Ok(GenericProtocol::Ascii));
    assert_eq!("Modbus-RTU".parse::<GenericProtocol>(), Ok(GenericProtocol::Rtu));
    assert_eq!(
        "tcp".parse::<GenericProtocol>().map_err(|e| e.to_string()),
        Err("the generic drive speaks modbus-rtu or modbus-ascii, not \"tcp\"".to_string())
    );
}

#[test]
fn bad_crc_and_bad_lrc_are_discarded_without_a_word() {
    // "如果两值不同则接收消息有错误 丢弃该消息帧,并不作任何回应".
    let mut line = rtu_line();
    let mut request = write_req(1, reg::FREQUENCY, 1000);
    request[7] ^= 0x01;
    assert!(exchange(&mut line, &request).is_empty());
    assert_eq!(drive(&mut line).snapshot().setpoint_hz, 0.0);
    // The next good frame is answered.
    assert_eq!(read1(&mut line, reg::FREQUENCY), 0);

    let mut line = ascii_line();
    assert!(exchange(&mut line, b":0106000213885D\r\n").is_empty());
    assert_eq!(drive(&mut line).core().params.get("P0.02"), Some(5000), "the default, unchanged");
    assert_eq!(drive(&mut line).core().params.eeprom_writes("P0.02"), Some(0));
    assert_eq!(line.stats().device_bytes, 0);
}

// ------------------------------------------------------------------------------------------
// Exceptions 01, 02, 03 with their bytes
// ------------------------------------------------------------------------------------------

#[test]
fn exception_01_for_every_function_but_03_06_08() {
    // "功能码错误。变频器能够辩识功能码: 03H 06H 08H".
    let mut line = rtu_line();
    // 04 read input registers.
    let reply = exchange(&mut line, &rtu(&[0x01, 0x04, 0x21, 0x03, 0x00, 0x01]));
    assert_eq!(reply, [0x01, 0x84, 0x01, 0x82, 0xC0]);
    assert_eq!(reply, rtu(&[0x01, 0x84, 0x01]));
    // 10 write multiple registers: refused, not executed.
    let reply = exchange(&mut line, &rtu(&[0x01, 0x10, 0x20, 0x01, 0x00, 0x01, 0x02, 0x03, 0xE8]));
    assert_eq!(reply, [0x01, 0x90, 0x01, 0x8D, 0xC0]);
    assert_eq!(drive(&mut line).snapshot().setpoint_hz, 0.0);
    // 01 read coils, 05 write coil, 2B/0E device identification.
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x01, 0x00, 0x00, 0x00, 0x08])), rtu(&[0x01, 0x81, 0x01]));
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x05, 0x00, 0x00, 0xFF, 0x00])), rtu(&[0x01, 0x85, 0x01]));
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x2B, 0x0E, 0x01, 0x00])), rtu(&[0x01, 0xAB, 0x01]));
    // 07 and 11 (serial-line diagnostics), and function codes whose length no Modbus layout
    // gives (41H; 2BH with MEI type 0DH): the drive frames them by silence and answers 01.
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x07])), [0x01, 0x87, 0x01, 0x82, 0x30]);
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x11])), [0x01, 0x91, 0x01, 0x8C, 0x50]);
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x41, 0x00, 0x00])), [0x01, 0xC1, 0x01, 0xB0, 0x50]);
    assert_eq!(exchange(&mut line, &rtu(&[0x01, 0x2B, 0x0D, 0x01, 0x00])), rtu(&[0x01, 0xAB, 0x01]));
    // ... but not when addressed to another drive or broadcast, nor with a bad CRC.
    assert!(exchange(&mut line, &rtu(&[0x02, 0x41, 0x00, 0x00])).is_empty());
    assert!(exchange(&mut line, &rtu(&[0x00, 0x41, 0x00, 0x00])).is_empty());
    assert!(exchange(&mut line, &[0x01, 0x41, 0x00, 0x00, 0xB0, 0x51]).is_empty());
    // A 10 request the codec refuses (byte count 3 for 1 register) is still function 01.
    let reply = exchange(&mut line, &rtu(&[0x01, 0x10, 0x20, 0x01, 0x00, 0x01, 0x03, 0x03, 0xE8, 0x00]));
    assert_eq!(reply, [0x01, 0x90, 0x01, 0x8D, 0xC0]);
    // The drive still answers the next good request.
    assert_eq!(read1(&mut line, reg::FAULT_CODE), 0);

    let mut line = ascii_line();
    // 04 and a function code no Modbus layout knows (41H).
    assert_eq!(exchange(&mut line, &ascii(&[0x01, 0x04, 0x21, 0x03, 0x00, 0x01])), b":0184017A\r\n");
    assert_eq!(exchange(&mut line, &ascii(&[0x01, 0x41, 0x00, 0x00])), b":01C1013D\r\n");
    // A function code with the exception bit is no function the drive knows either.
    assert_eq!(exchange(&mut line, &ascii(&[0x01, 0x83, 0x00, 0x00])), ascii(&[0x01, 0x83, 0x01]));
}

#[test]
fn exception_02_for_unknown_and_read_only_addresses() {
    // "资料地址错误。资料地址变频器无法辩识".
    let mut line = rtu_line();
    assert_eq!(exchange(&mut line, &read_req(1, 0x3000, 1)), [0x01, 0x83, 0x02, 0xC0, 0xF1]);
    assert_eq!(exchange(&mut line, &read_req(1, 0x210C, 1)), rtu(&[0x01, 0x83, 0x02]));
    // A read that runs past the end of the map: 210AH..210DH.
    assert_eq!(exchange(&mut line, &read_req(1, 0x210A, 4)), rtu(&[0x01, 0x83, 0x02]));
    assert_eq!(exchange(&mut line, &read_req(1, 0xFFFF, 2)), rtu(&[0x01, 0x83, 0x02]));
    // P0.16 does not exist.
    assert_eq!(exchange(&mut line, &write_req(1, 0x0016, 1)), rtu(&[0x01, 0x86, 0x02]));
    // The monitors and the fault records are read-only: 02.
    assert_eq!(
        exchange(&mut line, &write_req(1, reg::OUTPUT_FREQUENCY, 100)),
        [0x01, 0x86, 0x02, 0xC3, 0xA1]
    );
    assert_eq!(exchange(&mut line, &write_req(1, reg::FAULT_CODE, 0)), rtu(&[0x01, 0x86, 0x02]));
    assert_eq!(exchange(&mut line, &write_req(1, 0x0400, 0)), rtu(&[0x01, 0x86, 0x02]));

    let mut line = ascii_line();
    assert_eq!(exchange(&mut line, &ascii(&[0x01, 0x03, 0x30, 0x00, 0x00, 0x01])), b":0183027A\r\n");
    assert_eq!(exchange(&mut line, &ascii(&[0x01, 0x06, 0x21, 0x03, 0x00, 0x01])), b":01860277\r\n");
}

#[test]
fn exception_03_for_values_out_of_range_and_reads_over_8_bytes() {
    // "资料内容错误。资料内容超限"; "N<=8, 最大 8 个字节".
    let mut line = rtu_line();
    assert_eq!(exchange(&mut line, &read_req(1, 0x2100, 5)), [0x01, 0x83, 0x03, 0x01, 0x31]);
    // Quantity 0 is not a read either.
    assert_eq!(exchange(&mut line, &read_req(1, 0x2100, 0)), rtu(&[0x01, 0x83, 0x03]));
    // 2001H above the maximum frequency P0.04 (50.00 Hz).
    assert_eq!(exchange(&mut line, &write_req(1, reg::FREQUENCY, 5001)), [0x01, 0x86, 0x03, 0x02, 0x61]);
    // 2000H commands are 1..0AH.
    assert_eq!(exchange(&mut line, &write_req(1, reg::COMMAND, 0)), rtu(&[0x01, 0x86, 0x03]));
    assert_eq!(exchange(&mut line, &write_req(1, reg::COMMAND, 11)), rtu(&[0x01, 0x86, 0x03]));
    // P0.07 acceleration time is 0.1..3600.0 s.
    assert_eq!(exchange(&mut line, &write_req(1, 0x0007, 0)), rtu(&[0x01, 0x86, 0x03]));
    // P0.02 above P0.04.
    assert_eq!(exchange(&mut line, &write_req(1, 0x0002, 6000)), rtu(&[0x01, 0x86, 0x03]));
    let params = &drive(&mut line).core().params;
    assert_eq!((params.get("P0.07"), params.get("P0.02")), (Some(100), Some(5000)));
    assert_eq!(params.total_eeprom_writes(), 0, "refused writes never reach the EEPROM");

    let mut line = ascii_line();
    assert_eq!(exchange(&mut line, &ascii(&[0x01, 0x03, 0x21, 0x00, 0x00, 0x05])), b":01830379\r\n");
    assert_eq!(exchange(&mut line, &ascii(&[0x01, 0x06, 0x20, 0x01, 0x13, 0x89])), b":01860376\r\n");
}

// ------------------------------------------------------------------------------------------
// Running: ramps on simulated time, status bits, commands
// ------------------------------------------------------------------------------------------

#[test]
fn run_at_40_hz_ramps_the_output_frequency() {
    let mut line = rtu_line();
    // 2001H = 4000 (40.00 Hz), then 2000H = 2 (forward run).
    assert_eq!(
        exchange(&mut line, &[0x01, 0x06, 0x20, 0x01, 0x0F, 0xA0, 0xD6, 0x42]),
        [0x01, 0x06, 0x20, 0x01, 0x0F, 0xA0, 0xD6, 0x42]
    );
    assert_eq!(read1(&mut line, reg::SET_FREQUENCY), 4000);
    assert_eq!(read1(&mut line, reg::OUTPUT_FREQUENCY), 0);
    // The run starts when the request's last byte (8 characters) has arrived.
    let started = line.now() + line.char_time() * 8;
    write1(&mut line, reg::COMMAND, 2);
    // P0.07 = 10.0 s from 0 to P0.04 = 50 Hz: 5 Hz/s, so 5 mHz per millisecond.
    let expected_mhz = |now: Instant| (now.saturating_since(started).as_micros() * 5 / 1000) as i64;
    wait(&mut line, Duration::from_secs(4));
    let f = read1(&mut line, reg::OUTPUT_FREQUENCY);
    // Read at the end of this request (4 s + the reply + 8 characters): about 20.1 Hz.
    assert!((2000..2020).contains(&f), "about 20.00 Hz 4 s into the ramp, got {f}");
    let now = line.now();
    let out = drive(&mut line).core().model.output_mhz();
    assert!((expected_mhz(now) - 2..=expected_mhz(now)).contains(&out), "{out} mHz at {now:?}");
    // Reaches 40.00 Hz at 8 s and stays.
    line.advance_to(started + Duration::from_millis(7980));
    assert!(read1(&mut line, reg::OUTPUT_FREQUENCY) < 4000);
    wait(&mut line, Duration::from_secs(2));
    // 2100H..2103H in one read: no fault, status, set and output frequency.
    let reply = exchange(&mut line, &read_req(1, 0x2100, 4));
    let bits = status::RUN | status::NORMAL_RUN | status::FREQUENCY_FROM_COMM | status::RUN_FROM_COMM;
    let [sh, sl] = bits.to_be_bytes();
    assert_eq!(reply, rtu(&[0x01, 0x03, 0x08, 0x00, 0x00, sh, sl, 0x0F, 0xA0, 0x0F, 0xA0]));
    // Current, DC bus, output voltage, rpm.
    let current = read1(&mut line, reg::OUTPUT_CURRENT);
    assert_eq!(current, 24, "3.7 A rated at half load: 3.7 x (0.3 + 0.35) = 2.4 A");
    let dc = read1(&mut line, reg::DC_BUS_VOLTAGE);
    assert!((5000..5200).contains(&dc), "about 1.35 x 380 V, got {dc}");
    assert_eq!(read1(&mut line, reg::OUTPUT_VOLTAGE), 304, "V/f: 380 V x 40/50");
    let rpm = read1(&mut line, reg::MOTOR_SPEED);
    assert!((1140..1200).contains(&rpm), "{rpm}");
    assert!(read1(&mut line, reg::MODULE_TEMPERATURE) >= 250);

    // 7: decelerate to stop (10 s from 50 Hz: 8 s from 40 Hz).
    write1(&mut line, reg::COMMAND, 7);
    wait(&mut line, Duration::from_secs(4));
    let f = read1(&mut line, reg::OUTPUT_FREQUENCY);
    assert!((1970..=2000).contains(&f), "about 20.00 Hz 4 s into the deceleration, got {f}");
    assert_eq!(read1(&mut line, reg::STATUS) & status::RUN, status::RUN, "still running down");
    wait(&mut line, Duration::from_secs(5));
    assert_eq!(read1(&mut line, reg::OUTPUT_FREQUENCY), 0);
    assert_eq!(read1(&mut line, reg::STATUS) & status::RUN, 0);
}

#[test]
fn reverse_jog_and_emergency_stop() {
    let mut line = rtu_line();
    write1(&mut line, reg::FREQUENCY, 2000);
    write1(&mut line, reg::COMMAND, 3);
    wait(&mut line, Duration::from_secs(5));
    let bits = read1(&mut line, reg::STATUS);
    assert_eq!(bits & (status::RUN | status::REVERSE), status::RUN | status::REVERSE);
    assert_eq!(read1(&mut line, reg::OUTPUT_FREQUENCY), 2000);
    // 8: emergency stop coasts: output off at once.
    write1(&mut line, reg::COMMAND, 8);
    assert_eq!(read1(&mut line, reg::OUTPUT_FREQUENCY), 0);
    assert_eq!(read1(&mut line, reg::STATUS) & status::RUN, 0);
    // 5: jog forward at P1.05 = 5.00 Hz; 1 s at 5 Hz/s.
    write1(&mut line, reg::COMMAND, 5);
    wait(&mut line, Duration::from_secs(2));
    let bits = read1(&mut line, reg::STATUS);
    assert_eq!(
        bits & (status::RUN | status::JOG | status::REVERSE | status::NORMAL_RUN),
        status::RUN | status::JOG
    );
    assert_eq!(read1(&mut line, reg::OUTPUT_FREQUENCY), 500);
    // 9: jog stop.
    write1(&mut line, reg::COMMAND, 9);
    wait(&mut line, Duration::from_secs(2));
    assert_eq!(read1(&mut line, reg::STATUS) & (status::RUN | status::JOG), 0);
    // 1: run keeps the commanded direction (forward since the jog).
    write1(&mut line, reg::COMMAND, 1);
    assert_eq!(read1(&mut line, reg::STATUS) & (status::RUN | status::REVERSE), status::RUN);
    assert_eq!(read1(&mut line, reg::COMMAND), 1, "2000H reads back the last command");
}

#[test]
fn p0_03_sets_the_direction_of_a_plain_run() {
    let mut line = rtu_line();
    write1(&mut line, 0x0003, 1);
    write1(&mut line, reg::COMMAND, 1);
    assert_eq!(
        read1(&mut line, reg::STATUS) & (status::RUN | status::REVERSE),
        status::RUN | status::REVERSE
    );
}

#[test]
fn reverse_prohibited_by_p0_03_is_refused() {
    let mut line = rtu_line();
    write1(&mut line, 0x0003, 2);
    assert_eq!(exchange(&mut line, &write_req(1, reg::COMMAND, 3)), rtu(&[0x01, 0x86, 0x03]));
    assert_eq!(exchange(&mut line, &write_req(1, reg::COMMAND, 6)), rtu(&[0x01, 0x86, 0x03]));
    assert_eq!(drive(&mut line).core().model.state(), RunState::Stopped);
    write1(&mut line, reg::COMMAND, 2);
    assert_eq!(drive(&mut line).core().model.state(), RunState::Running);
}

#[test]
fn run_commands_need_p0_01_communication() {
    let mut line = rtu_line();
    assert_eq!(drive(&mut line).control_source(), "P0.01 = 2 communication");
    // P0.01 = 0: keypad. Run and stop from the line are refused with 03.
    write1(&mut line, 0x0001, 0);
    assert_eq!(drive(&mut line).control_source(), "P0.01 = 0 keypad");
    assert_eq!(read1(&mut line, reg::STATUS) & status::RUN_FROM_COMM, 0);
    for command in [1, 2, 4, 7, 8] {
        assert_eq!(exchange(&mut line, &write_req(1, reg::COMMAND, command)), rtu(&[0x01, 0x86, 0x03]));
    }
    assert_eq!(drive(&mut line).core().model.state(), RunState::Stopped);
    // A fault reset is accepted from any control source.
    drive_mut(&mut line).core_mut().model.trip_now(Trip::External);
    write1(&mut line, reg::COMMAND, 0x0A);
    assert_eq!(drive(&mut line).core().model.trip(), None);
    // Back to communication: the drive runs.
    write1(&mut line, 0x0001, 2);
    write1(&mut line, reg::COMMAND, 1);
    assert_eq!(drive(&mut line).core().model.state(), RunState::Running);
    // Terminal control refuses a stop from the line too.
    write1(&mut line, 0x0001, 1);
    assert_eq!(exchange(&mut line, &write_req(1, reg::COMMAND, 7)), rtu(&[0x01, 0x86, 0x03]));
    assert_eq!(drive(&mut line).core().model.state(), RunState::Running);
    assert_eq!(drive(&mut line).core().params.eeprom_writes("P0.01"), Some(3));
}

#[test]
fn trips_show_in_2100h_refuse_run_and_reset_with_0a() {
    let mut line = rtu_line();
    write1(&mut line, reg::FREQUENCY, 3000);
    write1(&mut line, reg::COMMAND, 2);
    wait(&mut line, Duration::from_secs(6));
    // Overload: over-current.
    drive_mut(&mut line).core_mut().model.set_load(4.0);
    wait(&mut line, Duration::from_millis(10));
    assert_eq!(read1(&mut line, reg::FAULT_CODE), Trip::OverCurrent.code());
    assert_eq!(read1(&mut line, reg::FAULT_CODE), 1);
    assert_eq!(read1(&mut line, reg::STATUS) & status::RUN, 0);
    // The fault records: P4.00 last fault, P4.02 output frequency at the fault.
    assert_eq!(read1(&mut line, 0x0400), 1);
    assert_eq!(read1(&mut line, 0x0402), 3000);
    assert!(read1(&mut line, 0x0403) > 0, "current at the fault");
    // Run while tripped: 03, and nothing runs.
    assert_eq!(exchange(&mut line, &write_req(1, reg::COMMAND, 2)), rtu(&[0x01, 0x86, 0x03]));
    // 0AH: fault reset.
    drive_mut(&mut line).core_mut().model.set_load(0.5);
    write1(&mut line, reg::COMMAND, 0x0A);
    assert_eq!(read1(&mut line, reg::FAULT_CODE), 0);
    write1(&mut line, reg::COMMAND, 2);
    assert_eq!(drive(&mut line).core().model.state(), RunState::Running);
    // A second fault moves the first to P4.01.
    drive_mut(&mut line).core_mut().model.trip_now(Trip::External);
    assert_eq!(read1(&mut line, reg::FAULT_CODE), 5);
    assert_eq!((read1(&mut line, 0x0400), read1(&mut line, 0x0401)), (5, 1));
    // An under-voltage that persists cannot be reset: 03.
    write1(&mut line, reg::COMMAND, 0x0A);
    drive_mut(&mut line).core_mut().model.set_supply(0.5);
    write1(&mut line, reg::COMMAND, 2);
    wait(&mut line, Duration::from_millis(10));
    assert_eq!(read1(&mut line, reg::FAULT_CODE), 3);
    assert_eq!(read1(&mut line, reg::STATUS) & status::UNDERVOLTAGE, status::UNDERVOLTAGE);
    assert_eq!(exchange(&mut line, &write_req(1, reg::COMMAND, 0x0A)), rtu(&[0x01, 0x86, 0x03]));
    // P0.14 = 2 clears the fault records.
    write1(&mut line, 0x0014, 2);
    assert_eq!((read1(&mut line, 0x0400), read1(&mut line, 0x0401), read1(&mut line, 0x0014)), (0, 0, 0));
}

#[test]
fn communication_timeout_trips_with_code_6() {
    let mut line = rtu_line();
    write1(&mut line, 0x0313, 20); // P3.13 = 2.0 s
    write1(&mut line, reg::FREQUENCY, 1000);
    write1(&mut line, reg::COMMAND, 2);
    // Polling keeps it alive.
    for _ in 0..5 {
        wait(&mut line, Duration::from_millis(1500));
        assert_eq!(read1(&mut line, reg::FAULT_CODE), 0);
    }
    wait(&mut line, Duration::from_millis(2100));
    assert_eq!(drive(&mut line).core().model.trip(), Some(Trip::CommunicationTimeout));
    assert_eq!(read1(&mut line, reg::FAULT_CODE), 6);
    // P3.14 = 0: alarm only, no trip.
    write1(&mut line, reg::COMMAND, 0x0A);
    write1(&mut line, 0x0314, 0);
    wait(&mut line, Duration::from_secs(10));
    assert_eq!(read1(&mut line, reg::FAULT_CODE), 0);
}

// ------------------------------------------------------------------------------------------
// Parameters
// ------------------------------------------------------------------------------------------

#[test]
fn parameter_writes_check_range_read_only_running_and_count_eeprom() {
    let mut line = rtu_line();
    // P0.02 keypad frequency: EEPROM, counted per write.
    for v in [1000, 2000, 3000] {
        write1(&mut line, 0x0002, v);
    }
    assert_eq!(read1(&mut line, 0x0002), 3000);
    // 2001H lives in RAM: never counted.
    for v in [1000, 2000, 3000, 4000] {
        write1(&mut line, reg::FREQUENCY, v);
    }
    let params = &drive(&mut line).core().params;
    assert_eq!(params.eeprom_writes("P0.02"), Some(3));
    assert_eq!(params.eeprom_writes("2001H"), Some(0));
    assert_eq!(params.total_eeprom_writes(), 3);
    assert_eq!(drive(&mut line).snapshot().eeprom_writes, 3);
    // The starting values the simulator forces cost nothing and read back.
    assert_eq!(read1(&mut line, 0x0000), 4, "P0.00 = 4 communication");
    assert_eq!(read1(&mut line, 0x0001), 2, "P0.01 = 2 communication");
    assert_eq!(read1(&mut line, 0x0310), 3, "P3.10 = 3 RTU 1-8-2");
    assert_eq!(read1(&mut line, 0x0311), 1, "P3.11 = the address");
    // Four parameters in one read: P0.04..P0.07.
    let reply = exchange(&mut line, &read_req(1, 0x0004, 4));
    assert_eq!(reply, rtu(&[0x01, 0x03, 0x08, 0x13, 0x88, 0x13, 0x88, 0x00, 0x00, 0x00, 0x64]));

    // P0.00 = 0: the keypad frequency P0.02 is the setpoint; status bit 9 clears.
    write1(&mut line, 0x0000, 0);
    assert_eq!(read1(&mut line, reg::SET_FREQUENCY), 3000);
    assert_eq!(read1(&mut line, reg::STATUS) & status::FREQUENCY_FROM_COMM, 0);
    write1(&mut line, 0x0000, 4);
    assert_eq!(read1(&mut line, reg::SET_FREQUENCY), 4000);

    // While running: P0.04 (maximum frequency) is refused with 03, P0.07 is accepted.
    write1(&mut line, reg::COMMAND, 2);
    assert_eq!(exchange(&mut line, &write_req(1, 0x0004, 6000)), rtu(&[0x01, 0x86, 0x03]));
    write1(&mut line, 0x0007, 50); // 5.0 s
    assert_eq!(drive(&mut line).core().model.settings().accel, Duration::from_secs(5));
    write1(&mut line, reg::COMMAND, 8);
    // Stopped: P0.04 = 60.00 Hz takes, 2001H may now go to 60 Hz, the ramp reference changes.
    write1(&mut line, 0x0004, 6000);
    assert_eq!(drive(&mut line).core().model.settings().max_hz, 60.0);
    write1(&mut line, 0x0005, 6000);
    write1(&mut line, reg::FREQUENCY, 6000);
    assert_eq!(drive(&mut line).snapshot().setpoint_hz, 60.0);
    // The upper limit P0.05 limits the setpoint.
    write1(&mut line, 0x0005, 4500);
    assert_eq!(read1(&mut line, reg::SET_FREQUENCY), 4500);
    // A lower limit above the upper limit: 03.
    assert_eq!(exchange(&mut line, &write_req(1, 0x0006, 4600)), rtu(&[0x01, 0x86, 0x03]));
    // Read-only P4.04 (run hours): 02.
    assert_eq!(exchange(&mut line, &write_req(1, 0x0404, 1)), rtu(&[0x01, 0x86, 0x02]));
}

#[test]
fn parameter_lock_p0_15() {
    let mut line = rtu_line();
    write1(&mut line, 0x0015, 1);
    assert_eq!(read1(&mut line, reg::STATUS) & status::PROTECTED, status::PROTECTED);
    write1(&mut line, 0x0002, 2500); // P0.02 stays writable
    assert_eq!(exchange(&mut line, &write_req(1, 0x0007, 50)), rtu(&[0x01, 0x86, 0x03]));
    write1(&mut line, reg::FREQUENCY, 1000); // 2000H/2001H are not parameters
    write1(&mut line, 0x0015, 2);
    assert_eq!(exchange(&mut line, &write_req(1, 0x0002, 2600)), rtu(&[0x01, 0x86, 0x03]));
    write1(&mut line, 0x0015, 0);
    write1(&mut line, 0x0007, 50);
}

#[test]
fn factory_reset_keeps_communication_and_address_change_takes_effect_after_the_reply() {
    let mut line = rtu_line();
    write1(&mut line, 0x0007, 300);
    write1(&mut line, 0x0001, 0);
    write1(&mut line, 0x0312, 20); // P3.12 response delay 20 ms
    write1(&mut line, 0x0014, 1);
    assert_eq!(read1(&mut line, 0x0007), 100, "P0.07 back to its default");
    assert_eq!(read1(&mut line, 0x0001), 2, "P0.01 back to the simulator's starting value");
    assert_eq!(read1(&mut line, 0x0312), 20, "P3.12 kept");
    assert_eq!(drive(&mut line).core().model.settings().accel, Duration::from_secs(10));

    // P3.12 = 20 ms: the reply starts 20 ms after the request.
    let t0 = line.now();
    let before = line.stats().device_bytes;
    line.master_write(t0, &read_req(1, reg::STATUS, 1));
    let request_end = t0 + line.char_time() * 8;
    line.advance_to(request_end + Duration::from_millis(19));
    assert_eq!(line.stats().device_bytes, before, "nothing before 20 ms");
    settle(&mut line);
    let mut got = Vec::new();
    line.master_read(&mut got);
    assert_eq!(got.len(), 7);
    write1(&mut line, 0x0312, 0);

    // P3.11 = 7: the reply still comes from 1, then the drive answers at 7 only.
    write1(&mut line, 0x0311, 7);
    assert!(exchange(&mut line, &read_req(1, reg::STATUS, 1)).is_empty());
    let reply = exchange(&mut line, &read_req(7, 0x0311, 1));
    assert_eq!(reply, rtu(&[0x07, 0x03, 0x02, 0x00, 0x07]));
    assert_eq!(drive(&mut line).snapshot().address, 7);
}

#[test]
fn ascii_reads_and_writes_the_same_map() {
    let mut line = ascii_line();
    assert_eq!(exchange(&mut line, &ascii(&[0x01, 0x06, 0x20, 0x01, 0x0F, 0xA0])), b":010620010FA029\r\n");
    assert_eq!(
        exchange(&mut line, &ascii(&[0x01, 0x03, 0x21, 0x02, 0x00, 0x01])),
        ascii(&[0x01, 0x03, 0x02, 0x0F, 0xA0])
    );
    assert_eq!(exchange(&mut line, &ascii(&[0x01, 0x03, 0x21, 0x02, 0x00, 0x01])), b":0103020FA04B\r\n");
    // Lower-case hex digits are accepted; the reply is upper case.
    assert_eq!(exchange(&mut line, b":010321020001d8\r\n"), b":0103020FA04B\r\n");
    assert_eq!(read_ascii_p3_10(&mut line), 0, "P3.10 = 0 ASCII 1-7-2");
    assert_eq!(drive(&mut line).protocol(), "modbus-ascii");
}

fn read_ascii_p3_10(line: &mut VirtualLine) -> u16 {
    let reply = exchange(line, &ascii(&[0x01, 0x03, 0x03, 0x10, 0x00, 0x01]));
    let text = std::str::from_utf8(&reply).expect("ASCII");
    u16::from_str_radix(&text[7..11], 16).expect("hex digits")
}

// ------------------------------------------------------------------------------------------
// Through a master session
// ------------------------------------------------------------------------------------------

/// Runs one transaction of `master` on `line` to its end.
fn transact(
    line: &mut VirtualLine,
    master: &mut MasterSession<ModbusRtu>,
    request: &Request<'_>,
) -> Option<Vec<u16>> {
    master.send(line.now(), request).expect("idle");
    loop {
        let now = line.now();
        if let Some(bytes) = master.poll_transmit(now) {
            let bytes = bytes.to_vec();
            line.master_write(now, &bytes);
        }
        if let Some(event) = master.poll_event() {
            return match event {
                MasterEvent::Reply(Reply { pdu: ReplyPdu::ReadHoldingRegisters { values }, .. }) => {
                    Some(values.iter().collect())
                }
                MasterEvent::Reply(Reply { pdu: ReplyPdu::WriteSingleRegister { value, .. }, .. }) => {
                    Some(vec![value])
                }
                MasterEvent::BroadcastDone => None,
                other => panic!("unexpected {other:?}"),
            };
        }
        let next = [line.next_deadline(), master.poll_timeout()].into_iter().flatten().min();
        let t = next.expect("something pending").max(now);
        line.advance_to(t);
        let mut got = Vec::new();
        line.master_read(&mut got);
        master.handle_input(t, &got);
        master.handle_timeout(t);
    }
}

#[test]
fn a_master_session_runs_the_drive() {
    let mut line = rtu_line();
    let mut master = MasterSession::new(
        ModbusRtu,
        rtu::timing_generic_vfd(BAUD, drivebus_sim::family::generic::char_format(GenericProtocol::Rtu)),
    );
    let unit = UnitId(1);
    let set = Request::write_single_register(unit, reg::FREQUENCY, 4000);
    assert_eq!(transact(&mut line, &mut master, &set), Some(vec![4000]));
    let run = Request::write_single_register(unit, reg::COMMAND, 2);
    assert_eq!(transact(&mut line, &mut master, &run), Some(vec![2]));
    let started = line.now();
    let read = Request::read_holding_registers(unit, reg::OUTPUT_FREQUENCY, 1);
    let mut last = 0;
    while line.now() < started + Duration::from_secs(9) {
        let f = transact(&mut line, &mut master, &read).expect("a reply")[0];
        assert!(f >= last, "the output only rises: {last} then {f}");
        last = f;
        wait(&mut line, Duration::from_millis(250));
    }
    assert_eq!(last, 4000);
    // A broadcast stop through the session: no reply, the drive stops.
    let stop = Request::write_single_register(UnitId::BROADCAST, reg::COMMAND, 8);
    assert_eq!(transact(&mut line, &mut master, &stop), None);
    assert_eq!(drive(&mut line).core().model.output_hz(), 0.0);
    // The forced starting values cost no EEPROM write.
    assert_eq!(drive(&mut line).core().params.total_eeprom_writes(), 0);
}

#[test]
fn registers_read_directly_and_describe_the_drive() {
    let mut d = GenericDrive::new(5, GenericProtocol::Ascii, Instant::ZERO).expect("address 5");
    assert_eq!(d.register(reg::VERSION), Some(0x0100));
    assert_eq!(d.register(reg::VI_INPUT), Some(0));
    assert_eq!(d.register(0x0311), Some(5));
    assert_eq!(d.register(0x3000), None);
    assert_eq!(d.protocol_kind(), GenericProtocol::Ascii);
    let snap = d.snapshot();
    assert_eq!((snap.family.as_str(), snap.protocol.as_str(), snap.address), ("generic", "modbus-ascii", 5));
    assert_eq!(snap.control_source, "P0.01 = 2 communication");
    assert_eq!(snap.state, "stopped");
}
