//! The virtual Danfoss FC drive on a paced virtual line, driven with raw telegrams and with the
//! proto crate's `MasterSession`, on simulated time.
//!
//! Manual: `seeds/003_26a4c04ca1af5f26.txt` and protocols.md section 2 (examples D1–D6 in 5.5).

use std::time::Duration;

use drivebus_proto::fc::{self, Fc, ParameterNumber, Reply, Request};
use drivebus_proto::line::CharFormat;
use drivebus_proto::session::{MasterEvent, MasterSession};
use drivebus_proto::Instant;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::family::danfoss::DanfossDrive;
use drivebus_sim::model::{Rotation, RunState, Trip};

const BAUD: u32 = 9600;

/// A 9600 baud 8E1 line with one FC drive per address; ports are 1, 2, ... in that order.
fn line_with(addresses: &[u8]) -> VirtualLine {
    let mut line = VirtualLine::new(BAUD, CharFormat::EVEN_8E1, Instant::ZERO);
    for &a in addresses {
        line.add_device(Box::new(DanfossDrive::new(a, Instant::ZERO).unwrap()));
    }
    line
}

/// Runs the line until `end`, event by event.
fn run_until(line: &mut VirtualLine, end: Instant) {
    line.run_until(end);
}

/// Lets `d` of simulated time pass.
fn wait(line: &mut VirtualLine, d: Duration) {
    let end = line.now() + d;
    run_until(line, end);
}

/// Writes `request` now and returns what came back within 100 ms.
fn exchange(line: &mut VirtualLine, request: &[u8]) -> Vec<u8> {
    let now = line.now();
    line.master_write(now, request);
    run_until(line, now + Duration::from_millis(100));
    let mut got = Vec::new();
    line.master_read(&mut got);
    got
}

/// Writes `request` so that its last byte arrives exactly at `at` (the drive acts then), and
/// returns the reply.
fn exchange_arriving_at(line: &mut VirtualLine, at: Instant, request: &[u8]) -> Vec<u8> {
    let start = at - line.char_time() * request.len() as u32;
    run_until(line, start);
    exchange(line, request)
}

/// A telegram from its bytes without the BCC (BCC = XOR of STX .. the last data byte).
fn tg(body: &[u8]) -> Vec<u8> {
    let bcc = body.iter().fold(0, |a, b| a ^ b);
    let mut v = body.to_vec();
    v.push(bcc);
    v
}

/// A process telegram: CTW and reference.
fn process(adr: u8, ctw: u16, reference: u16) -> Vec<u8> {
    let [c0, c1] = ctw.to_be_bytes();
    let [r0, r1] = reference.to_be_bytes();
    tg(&[0x02, 0x06, adr, c0, c1, r0, r1])
}

/// A parameter telegram with CTW 0000 (bit 10 = 0: ignored) and reference 0.
fn param(adr: u8, ak: u8, pnu: u16, ind: u16, pwe: u32) -> Vec<u8> {
    let [k0, k1] = (u16::from(ak) << 12 | pnu).to_be_bytes();
    let [i0, i1] = ind.to_be_bytes();
    let [w0, w1, w2, w3] = pwe.to_be_bytes();
    tg(&[0x02, 0x0E, adr, k0, k1, i0, i1, w0, w1, w2, w3, 0, 0, 0, 0])
}

/// STW and MAV of a reply.
fn stw_mav(reply: &[u8]) -> (u16, u16) {
    let n = reply.len();
    assert!(n >= 8, "no reply: {reply:02X?}");
    (u16::from_be_bytes([reply[n - 5], reply[n - 4]]), u16::from_be_bytes([reply[n - 3], reply[n - 2]]))
}

/// PWE of a parameter-block reply.
fn pwe(reply: &[u8]) -> u32 {
    assert_eq!(reply.len(), 16, "not a parameter block: {reply:02X?}");
    u32::from_be_bytes([reply[7], reply[8], reply[9], reply[10]])
}

fn drive(line: &mut VirtualLine, port: usize) -> &dyn drivebus_sim::drive::VirtualDrive {
    line.drive(port).unwrap()
}

fn ms(t: u64) -> Duration {
    Duration::from_millis(t)
}

const STW_READY: u16 = 0x0603; // control ready, drive ready, bus control, frequency limit OK
const STW_STARTED: u16 = 0x0E07; // + enable, in operation
const STW_AT_SPEED: u16 = 0x0F07; // + speed = reference

#[test]
fn manual_d1_starts_drive_4_at_50_percent_and_mav_ramps() {
    let mut line = line_with(&[4]);
    // protocols.md 5.5 D1: process telegram to address 4 (format 1-31), CTW 047C, REF 2000.
    let reply = exchange(&mut line, &[0x02, 0x06, 0x04, 0x04, 0x7C, 0x20, 0x00, 0x58]);
    // ADR returned unchanged; STW 0E07: control ready, drive ready, enable, bus control,
    // frequency limit OK, in operation; MAV 0: the ramp has just begun.
    assert_eq!(reply, [0x02, 0x06, 0x04, 0x0E, 0x07, 0x00, 0x00, 0x09]);
    let d = drive(&mut line, 1).snapshot();
    assert_eq!((d.state.as_str(), d.setpoint_hz), ("running", 25.0));

    // 3-41 = 3.00 s from 0 to 1-23 = 50 Hz: 16.67 Hz/s, so 5 Hz after 0.3 s.
    let started = Instant::ZERO + line.char_time() * 8;
    run_until(&mut line, started + ms(300));
    let hz = drive(&mut line, 1).core().model.output_hz();
    assert!((hz - 5.0).abs() < 0.002, "{hz} Hz at 0.3 s");

    // MAV follows on simulated time: 10 Hz of 50 Hz is 0x4000 / 5 = 0x0CCD at 0.6 s.
    let poll = process(0x04, 0x047C, 0x2000);
    let (stw, mav) = stw_mav(&exchange_arriving_at(&mut line, started + ms(600), &poll));
    assert_eq!(stw, STW_STARTED);
    assert!((i32::from(mav) - 0x0CCD).abs() <= 1, "MAV {mav:04X} at 0.6 s");
    let (_, later) = stw_mav(&exchange_arriving_at(&mut line, started + ms(1200), &poll));
    assert!((i32::from(later) - 0x199A).abs() <= 1, "MAV {later:04X} at 1.2 s");
    // 25 Hz is reached at 1.5 s (a millisecond later here: the model drops the sub-microsecond
    // part of each step of the nanosecond-paced line): speed = reference, MAV 0x2000.
    let reply = exchange_arriving_at(&mut line, started + ms(1501), &poll);
    assert_eq!(reply, [0x02, 0x06, 0x04, 0x0F, 0x07, 0x20, 0x00, 0x28]);
}

#[test]
fn read_16_14_motor_current_like_manual_d3() {
    let mut line = line_with(&[1]);
    // Stopped: 0.00 A, answered with AK 2 (double word, project decision).
    let read =
        [0x02, 0x0E, 0x01, 0x16, 0x4E, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x55];
    let reply = exchange(&mut line, &read);
    assert_eq!(
        reply,
        [0x02, 0x0E, 0x01, 0x26, 0x4E, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x06, 0x03, 0x00, 0x00, 0x60]
    );
    // Run at 25 Hz with the load that draws the manual's 5.24 A from the 8.40 A motor (1-24).
    let load = (5.24 / 8.4 - 0.3) / 0.7;
    line.drive_mut(1).unwrap().core_mut().model.set_load(load);
    exchange(&mut line, &process(0x01, 0x047C, 0x2000));
    wait(&mut line, ms(2000));
    // protocols.md 5.5 D4: value 0x20C = 5.24 A (16-14, conversion index -2).
    let reply = exchange(&mut line, &read);
    assert_eq!(
        reply,
        [0x02, 0x0E, 0x01, 0x26, 0x4E, 0x00, 0x00, 0x00, 0x00, 0x02, 0x0C, 0x0F, 0x07, 0x20, 0x00, 0x43]
    );
    // 16-13 Frequency in 0.1 Hz, a word: AK 1.
    let reply = exchange(&mut line, &param(0x01, 0x1, 1613, 0, 0));
    assert_eq!((reply[3] >> 4, pwe(&reply)), (1, 250));
}

#[test]
fn master_session_reads_the_current() {
    let mut line = line_with(&[7]);
    exchange(&mut line, &process(0x87, 0x047C, 0x4000));
    wait(&mut line, ms(5000));
    let proto = Fc::default();
    let mut master = MasterSession::new(proto, fc::timing(BAUD, CharFormat::EVEN_8E1));
    let adr = proto.adr(7).unwrap();
    let pnu: ParameterNumber = "16-14".parse().unwrap();
    master.send(line.now(), &Request::read(adr, pnu, 0)).unwrap();
    let mut value = None;
    for _ in 0..10_000 {
        let now = line.now();
        if let Some(bytes) = master.poll_transmit(now) {
            let bytes = bytes.to_vec();
            line.master_write(now, &bytes);
        }
        if let Some(event) = master.poll_event() {
            match event {
                MasterEvent::Reply(r) => value = Some((r.value(), r.stw.in_operation(), r.mav.percent())),
                other => panic!("{other:?}"),
            }
            break;
        }
        let next = [line.next_deadline(), master.poll_timeout()].into_iter().flatten().min().unwrap();
        line.advance_to(next.max(now));
        let mut input = Vec::new();
        line.master_read(&mut input);
        master.handle_input(line.now(), &input);
        master.handle_timeout(line.now());
    }
    // 8.40 A x (0.3 + 0.7 x 0.5 load) = 5.46 A at 50 Hz (100 %).
    assert_eq!(value, Some((Some(546), true, 100.0)));
}

#[test]
fn write_4_14_in_ram_and_in_eeprom() {
    let mut line = line_with(&[1]);
    // AK 2: write 4-14 = 100.0 Hz (1000 = 0x3E8, conversion index -1) in RAM; reply AK 1.
    let reply = exchange(&mut line, &param(0x81, 0x2, 414, 0, 1000));
    assert_eq!(
        reply,
        [0x02, 0x0E, 0x81, 0x11, 0x9E, 0x00, 0x00, 0x00, 0x00, 0x03, 0xE8, 0x06, 0x03, 0x00, 0x00, 0xEC]
    );
    let core = drive(&mut line, 1).core();
    assert_eq!(core.params.get("4-14"), Some(1000));
    assert_eq!(core.params.eeprom_writes("4-14"), Some(0));
    assert_eq!(core.model.settings().max_hz, 100.0);
    // AK E: RAM and EEPROM (the FC 202 example: PKE E19E, PWE 03E8).
    let request =
        [0x02, 0x0E, 0x81, 0xE1, 0x9E, 0x00, 0x00, 0x00, 0x00, 0x03, 0xE8, 0x00, 0x00, 0x00, 0x00, 0x19];
    assert_eq!(request.to_vec(), param(0x81, 0xE, 414, 0, 1000));
    let reply = exchange(&mut line, &request);
    assert_eq!(pwe(&reply), 1000);
    assert_eq!(drive(&mut line, 1).core().params.eeprom_writes("4-14"), Some(1));
    exchange(&mut line, &param(0x81, 0xE, 414, 0, 500));
    let core = drive(&mut line, 1).core();
    assert_eq!((core.params.eeprom_writes("4-14"), core.params.total_eeprom_writes()), (Some(2), 2));
    assert_eq!(core.model.settings().max_hz, 50.0);
    // Read back: AK 1 with PWElow 01F4.
    let reply = exchange(&mut line, &param(0x81, 0x1, 414, 0, 0));
    assert_eq!((reply[3], pwe(&reply)), (0x11, 500));
    // A double word (3-41, AK D) in EEPROM: reply AK 2; the ramp follows.
    let reply = exchange(&mut line, &param(0x81, 0xD, 341, 0, 1000));
    assert_eq!((reply[3], pwe(&reply)), (0x21, 1000));
    assert_eq!(drive(&mut line, 1).core().params.eeprom_writes("3-41"), Some(1));
    // 10.00 s from 0 to 50 Hz (1-23) with 4-14 = 50 Hz.
    assert_eq!(drive(&mut line, 1).core().model.settings().accel, Duration::from_secs(10));
}

/// Every fault code of protocols.md 2.4 the drive produces, with its exact reply (drive 1 in
/// format 1-126, ADR 81, CTW 0000 ignored, STW 0603, MAV 0000).
#[test]
fn every_fault_code_with_its_reply_bytes() {
    let mut line = line_with(&[1]);
    let cases: [(&str, Vec<u8>, [u8; 16]); 11] = [
        (
            "0 illegal parameter number: read PNU 999",
            param(0x81, 0x1, 999, 0, 0),
            [0x02, 0x0E, 0x81, 0x73, 0xE7, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x06, 0x03, 0x00, 0x00, 0x1C],
        ),
        (
            "1 parameter cannot be changed: write 16-14 (read-only)",
            param(0x81, 0xD, 1614, 0, 0),
            [0x02, 0x0E, 0x81, 0x76, 0x4E, 0x00, 0x00, 0x00, 0x00, 0x00, 0x01, 0x06, 0x03, 0x00, 0x00, 0xB1],
        ),
        (
            "2 limit exceeded: 4-14 = 500.1 Hz",
            param(0x81, 0x2, 414, 0, 5001),
            [0x02, 0x0E, 0x81, 0x71, 0x9E, 0x00, 0x00, 0x00, 0x00, 0x00, 0x02, 0x06, 0x03, 0x00, 0x00, 0x65],
        ),
        (
            "3 subindex corrupted: 15-30 has 10 entries, IND 10",
            param(0x81, 0x1, 1530, 10, 0),
            [0x02, 0x0E, 0x81, 0x75, 0xFA, 0x00, 0x0A, 0x00, 0x00, 0x00, 0x03, 0x06, 0x03, 0x00, 0x00, 0x0E],
        ),
        (
            "4 no array: 4-14 with IND 1",
            param(0x81, 0x1, 414, 1, 0),
            [0x02, 0x0E, 0x81, 0x71, 0x9E, 0x00, 0x01, 0x00, 0x00, 0x00, 0x04, 0x06, 0x03, 0x00, 0x00, 0x62],
        ),
        (
            "5 wrong data type: word write (AK 2) to the double word 3-41",
            param(0x81, 0x2, 341, 0, 1000),
            [0x02, 0x0E, 0x81, 0x71, 0x55, 0x00, 0x00, 0x00, 0x00, 0x00, 0x05, 0x06, 0x03, 0x00, 0x00, 0xA9],
        ),
        (
            "5 wrong data type: double-word write (AK 3) to the word 4-14",
            param(0x81, 0x3, 414, 0, 1000),
            [0x02, 0x0E, 0x81, 0x71, 0x9E, 0x00, 0x00, 0x00, 0x00, 0x00, 0x05, 0x06, 0x03, 0x00, 0x00, 0x62],
        ),
        (
            "9 description element not available: AK 4 IND 3",
            param(0x81, 0x4, 414, 3, 0),
            [0x02, 0x0E, 0x81, 0x71, 0x9E, 0x00, 0x03, 0x00, 0x00, 0x00, 0x09, 0x06, 0x03, 0x00, 0x00, 0x6D],
        ),
        (
            "15 no text available: 4-14 has no value texts (AK F IND 0001)",
            param(0x81, 0xF, 414, 1, 0),
            [0x02, 0x0E, 0x81, 0x71, 0x9E, 0x00, 0x01, 0x00, 0x00, 0x00, 0x0F, 0x06, 0x03, 0x00, 0x00, 0x69],
        ),
        (
            "18 other error: AK 5 is not a command",
            param(0x81, 0x5, 414, 0, 0),
            [0x02, 0x0E, 0x81, 0x71, 0x9E, 0x00, 0x00, 0x00, 0x00, 0x00, 0x12, 0x06, 0x03, 0x00, 0x00, 0x75],
        ),
        (
            "5 wrong data type: a text write (AK F IND 0500) to a number",
            param(0x81, 0xF, 414, 0x0500, 0x4142_4344),
            [0x02, 0x0E, 0x81, 0x71, 0x9E, 0x05, 0x00, 0x00, 0x00, 0x00, 0x05, 0x06, 0x03, 0x00, 0x00, 0x67],
        ),
    ];
    for (what, request, expected) in cases {
        let reply = exchange(&mut line, &request);
        assert_eq!(reply, expected, "{what}: {reply:02X?}");
        let parsed = Reply::parse(&reply).unwrap();
        assert_eq!(parsed.fault_code().map(|c| c.0), Some(u16::from(expected[10])), "{what}");
    }
    // Nothing was written.
    let core = drive(&mut line, 1).core();
    assert_eq!((core.params.get("4-14"), core.params.get("3-41")), (Some(650), Some(300)));

    // 17 not while running: 4-19 Max Output Frequency (while_running = false).
    exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    wait(&mut line, ms(2000));
    let reply = exchange(&mut line, &param(0x81, 0xE, 419, 0, 800));
    assert_eq!(
        reply,
        [0x02, 0x0E, 0x81, 0x71, 0xA3, 0x00, 0x00, 0x00, 0x00, 0x00, 0x11, 0x0F, 0x07, 0x20, 0x00, 0x66]
    );
    assert_eq!(drive(&mut line, 1).core().params.get("4-19"), Some(1000));
    // The same write after a stop is accepted.
    exchange(&mut line, &process(0x81, 0x043C, 0x2000));
    wait(&mut line, ms(2000));
    let reply = exchange(&mut line, &param(0x81, 0xE, 419, 0, 800));
    assert_eq!((reply[3] >> 4, pwe(&reply)), (1, 800));
}

#[test]
fn no_command_and_description_elements() {
    let mut line = line_with(&[1]);
    // AK 0 "no command": answered AK 0 "no response", PNU and IND echoed, nothing read.
    let reply = exchange(&mut line, &param(0x81, 0x0, 1614, 0, 0));
    assert_eq!(reply, tg(&[0x02, 0x0E, 0x81, 0x06, 0x4E, 0, 0, 0, 0, 0, 0, 0x06, 0x03, 0, 0]));
    // AK 4 IND 1 on 0-01 Language: AK 3, PWElow 0405 (text available, Uint8) as in the
    // FC 300 example `02 0E 01 30 01 00 01 00 00 04 05`.
    let reply = exchange(&mut line, &param(0x01, 0x4, 1, 1, 0));
    assert_eq!(&reply[..11], [0x02, 0x0E, 0x01, 0x30, 0x01, 0x00, 0x01, 0x00, 0x00, 0x04, 0x05]);
    let describe = |line: &mut VirtualLine, pnu: u16, element: u16| {
        let reply = exchange(line, &param(0x81, 0x4, pnu, element, 0));
        assert_eq!(reply[3] >> 4, 3, "AK 3 for {pnu} element {element}: {reply:02X?}");
        pwe(&reply)
    };
    assert_eq!(describe(&mut line, 1530, 1), 0x4205, "15-30: array, read-only, Uint8");
    assert_eq!(describe(&mut line, 1530, 2), 10);
    assert_eq!(describe(&mut line, 414, 2), 1);
    assert_eq!(describe(&mut line, 414, 4), 0xFF1C, "conversion index -1, unit index 28 (Hz)");
    assert_eq!(describe(&mut line, 414, 7), 0);
    assert_eq!(describe(&mut line, 414, 8), 5000);
    assert_eq!(describe(&mut line, 414, 20), 650);
    assert_eq!(describe(&mut line, 302, 7), (-4_999_000i32) as u32, "Int32 lower limit");
    // Element 6, the name: a text block with AK 3, LGE 10 + 8.
    let reply = exchange(&mut line, &param(0x81, 0x4, 1, 6, 0));
    assert_eq!(
        reply,
        tg(&[
            0x02, 0x12, 0x81, 0x30, 0x01, 0x00, 0x06, b'L', b'a', b'n', b'g', b'u', b'a', b'g', b'e', 0x06,
            0x03, 0, 0
        ])
    );
}

#[test]
fn text_read_returns_the_parameter_name() {
    let mut line = line_with(&[1]);
    // AK F, IND 0400 (read text): the name of 4-14 in a text block, LGE 10 + 27, AK F.
    let reply = exchange(
        &mut line,
        &[0x02, 0x0E, 0x81, 0xF1, 0x9E, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xE6],
    );
    let mut expected = vec![0x02, 0x25, 0x81, 0xF1, 0x9E, 0x04, 0x00];
    expected.extend_from_slice(b"Motor Speed High Limit [Hz]");
    expected.extend_from_slice(&[0x06, 0x03, 0x00, 0x00, 0x8B]);
    assert_eq!(reply, expected);
    let parsed = Reply::parse(&reply).unwrap();
    assert_eq!(parsed.text_chars(), Some(&b"Motor Speed High Limit [Hz]"[..]));
    // The FC 300 example: AK F, IND 0001 on 0-01 reads the text of value 0, LGE 0x11 = 10 + 7.
    let reply = exchange(&mut line, &param(0x81, 0xF, 1, 1, 0));
    assert_eq!(
        reply,
        [
            0x02, 0x11, 0x81, 0xF0, 0x01, 0x00, 0x01, 0x45, 0x6E, 0x67, 0x6C, 0x69, 0x73, 0x68, 0x06, 0x03,
            0x00, 0x00, 0x35
        ]
    );
}

#[test]
fn reset_acts_on_the_rising_edge_of_bit_7_only() {
    let mut line = line_with(&[1]);
    exchange(&mut line, &process(0x81, 0x043C, 0));
    line.drive_mut(1).unwrap().core_mut().model.trip_now(Trip::External);
    // Tripped: trip bit, no ready bits.
    let (stw, _) = stw_mav(&exchange(&mut line, &process(0x81, 0x043C, 0)));
    assert_eq!(stw, 0x0608);
    // 04BC: bit 7 rises: reset.
    let (stw, _) = stw_mav(&exchange(&mut line, &process(0x81, 0x04BC, 0)));
    assert_eq!(stw, STW_READY | 0x0004);
    assert_eq!(drive(&mut line, 1).core().model.trip(), None);
    // Trip again while bit 7 is held: the next 04BC is no edge, so no reset.
    line.drive_mut(1).unwrap().core_mut().model.trip_now(Trip::External);
    let (stw, _) = stw_mav(&exchange(&mut line, &process(0x81, 0x04BC, 0)));
    assert_eq!(stw & 0x0008, 0x0008, "still tripped");
    assert_eq!(drive(&mut line, 1).core().model.trip(), Some(Trip::External));
    // A word with bit 10 = 0 does not count as bit 7 falling either.
    exchange(&mut line, &process(0x81, 0x0000, 0));
    exchange(&mut line, &process(0x81, 0x04BC, 0));
    assert_eq!(drive(&mut line, 1).core().model.trip(), Some(Trip::External));
    // 043C then 04BC: an edge, a reset.
    exchange(&mut line, &process(0x81, 0x043C, 0));
    exchange(&mut line, &process(0x81, 0x04BC, 0));
    assert_eq!(drive(&mut line, 1).core().model.trip(), None);
    // 15-30 Alarm Log, newest first: two external trips (alarm 60), then empty.
    for (index, code) in [(0, 60), (1, 60), (2, 0)] {
        let reply = exchange(&mut line, &param(0x81, 0x1, 1530, index, 0));
        assert_eq!((reply[3], pwe(&reply)), (0x15, code), "15-30[{index}]");
    }
}

#[test]
fn control_word_with_bit_10_clear_is_ignored() {
    let mut line = line_with(&[1]);
    // 047C without bit 10 (007C): nothing starts, the reference is not taken.
    let (stw, _) = stw_mav(&exchange(&mut line, &process(0x81, 0x007C, 0x4000)));
    assert_eq!(stw, STW_READY);
    assert_eq!(drive(&mut line, 1).core().model.state(), RunState::Stopped);
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 0.0);
    exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    wait(&mut line, ms(2000));
    // Ramp stop, coast and a new reference, all without bit 10: the drive keeps running at 25 Hz.
    for ctw in [0x003C, 0x0074, 0x0000, 0x00FC] {
        let reply = exchange(&mut line, &process(0x81, ctw, 0x4000));
        assert_eq!(stw_mav(&reply), (STW_AT_SPEED, 0x2000), "CTW {ctw:04X}");
    }
    // Parameter telegrams carry CTW 0000: they do not stop the drive either.
    exchange(&mut line, &param(0x81, 0x1, 1613, 0, 0));
    let m = &drive(&mut line, 1).core().model;
    assert_eq!((m.state(), m.output_hz(), m.setpoint_hz()), (RunState::Running, 25.0, 25.0));
    // With bit 10: ramp stop (bit 6 = 0), then stopped after 3-42 x 25/50 = 1.5 s.
    let (stw, _) = stw_mav(&exchange(&mut line, &process(0x81, 0x043C, 0x2000)));
    assert_eq!(stw & 0x0100, 0, "no longer at reference");
    wait(&mut line, ms(1600));
    assert_eq!(drive(&mut line, 1).core().model.state(), RunState::Stopped);
}

#[test]
fn coast_and_quick_stop_release_the_motor_at_once() {
    let mut line = line_with(&[1]);
    for (ctw, stw) in [(0x0474, STW_READY), (0x046C, STW_READY | 0x0004), (0x0478, STW_READY | 0x0004)] {
        exchange(&mut line, &process(0x81, 0x047C, 0x2000));
        wait(&mut line, ms(2000));
        assert_eq!(drive(&mut line, 1).core().model.output_hz(), 25.0);
        let reply = exchange(&mut line, &process(0x81, ctw, 0x2000));
        assert_eq!(stw_mav(&reply), (stw, 0), "CTW {ctw:04X}");
        assert_eq!(drive(&mut line, 1).core().model.state(), RunState::Stopped);
    }
}

#[test]
fn jog_runs_at_3_19() {
    let mut line = line_with(&[1]);
    // 057C: bit 8 jog; 3-19 = 150 rpm with 2 pole pairs (1-23 50 Hz, 1-25 1420 rpm) = 5 Hz.
    exchange(&mut line, &process(0x81, 0x057C, 0x2000));
    wait(&mut line, ms(1000));
    let m = &drive(&mut line, 1).core().model;
    assert!(m.is_jogging());
    assert_eq!(m.output_hz(), 5.0);
    let reply = exchange(&mut line, &process(0x81, 0x057C, 0x2000));
    // MAV 5 Hz of 50 Hz = 0x0666; speed = reference.
    assert_eq!(stw_mav(&reply), (STW_AT_SPEED, 0x0666));
    assert!(drive(&mut line, 1).snapshot().jog);
    // 3-19 = 300 rpm: 10 Hz.
    exchange(&mut line, &param(0x81, 0x2, 319, 0, 300));
    wait(&mut line, ms(1000));
    assert_eq!(drive(&mut line, 1).core().model.output_hz(), 10.0);
    // Back to 047C: the reference again.
    exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    wait(&mut line, ms(2000));
    let m = &drive(&mut line, 1).core().model;
    assert_eq!((m.is_jogging(), m.output_hz()), (false, 25.0));
}

#[test]
fn reverse_with_bit_15_and_with_a_negative_reference() {
    let mut line = line_with(&[1]);
    // 847C: start reverse at 50 %: MAV is negative (0xE000 = -50 %).
    exchange(&mut line, &process(0x81, 0x847C, 0x2000));
    wait(&mut line, ms(2000));
    let reply = exchange(&mut line, &process(0x81, 0x847C, 0x2000));
    assert_eq!(stw_mav(&reply), (STW_AT_SPEED, 0xE000));
    assert_eq!(drive(&mut line, 1).core().model.output_rotation(), Rotation::Reverse);
    assert_eq!(drive(&mut line, 1).snapshot().direction, "reverse");
    // Forward again: through zero to +25 Hz (1.5 s down, 1.5 s up).
    exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    wait(&mut line, ms(3100));
    let reply = exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    assert_eq!(stw_mav(&reply), (STW_AT_SPEED, 0x2000));
    // With 3-00 = -max..+max, a negative reference (0xE000 = -50 %) reverses too.
    exchange(&mut line, &param(0x81, 0x2, 300, 0, 1));
    exchange(&mut line, &process(0x81, 0x047C, 0xE000));
    wait(&mut line, ms(3100));
    let reply = exchange(&mut line, &process(0x81, 0x047C, 0xE000));
    assert_eq!(stw_mav(&reply), (STW_AT_SPEED, 0xE000));
    // 4-10 = clockwise only: no reversing (written while stopped: while_running = false).
    exchange(&mut line, &process(0x81, 0x043C, 0x2000));
    wait(&mut line, ms(2000));
    exchange(&mut line, &param(0x81, 0xE, 410, 0, 0));
    exchange(&mut line, &process(0x81, 0x847C, 0xE000));
    wait(&mut line, ms(2000));
    assert_eq!(drive(&mut line, 1).core().model.output_rotation(), Rotation::Forward);
}

#[test]
fn broadcasts_in_both_formats_are_executed_without_reply() {
    let mut line = line_with(&[1, 2, 30]);
    // Format 1-126: ADR 80.
    let reply = exchange(&mut line, &process(0x80, 0x047C, 0x2000));
    assert!(reply.is_empty(), "{reply:02X?}");
    wait(&mut line, ms(2000));
    for port in 1..=3 {
        assert_eq!(drive(&mut line, port).core().model.output_hz(), 25.0, "drive on port {port}");
    }
    // Format 1-31: bit 5 (ADR 20, bits 0-4 ignored: 3F too) stops them all.
    let reply = exchange(&mut line, &process(0x3F, 0x043C, 0x2000));
    assert!(reply.is_empty(), "{reply:02X?}");
    wait(&mut line, ms(2000));
    for port in 1..=3 {
        assert_eq!(drive(&mut line, port).core().model.state(), RunState::Stopped, "port {port}");
    }
    // A broadcast parameter write is executed too (AK E 4-14 = 60.0 Hz), unanswered.
    assert!(exchange(&mut line, &param(0x20, 0xE, 414, 0, 600)).is_empty());
    for port in 1..=3 {
        let core = drive(&mut line, port).core();
        assert_eq!((core.params.get("4-14"), core.params.eeprom_writes("4-14")), (Some(600), Some(1)));
    }
    assert_eq!(line.stats().device_bytes, 0);
}

#[test]
fn other_addresses_bad_bcc_and_cut_telegrams_get_no_reply() {
    let mut line = line_with(&[1]);
    // Drive 5 in both formats, address 33 in format 1-126 (format 1-31 would read it as 1).
    for adr in [0x85, 0x05, 0xA1] {
        assert!(exchange(&mut line, &process(adr, 0x047C, 0x2000)).is_empty(), "ADR {adr:02X}");
    }
    assert_eq!(drive(&mut line, 1).core().model.state(), RunState::Stopped);
    // A bad BCC: silent, and nothing done.
    let mut bad = process(0x81, 0x047C, 0x2000);
    bad[7] ^= 0x01;
    assert!(exchange(&mut line, &bad).is_empty());
    assert_eq!(drive(&mut line, 1).core().model.state(), RunState::Stopped);
    // A telegram cut short: dropped after the silence; the next one is answered.
    let whole = process(0x81, 0x043C, 0);
    assert!(exchange(&mut line, &whole[..5]).is_empty());
    assert_eq!(exchange(&mut line, &whole).len(), 8);
    // Address 1 in both formats; ADR echoed unchanged.
    assert_eq!(exchange(&mut line, &process(0x01, 0x043C, 0))[2], 0x01);
    assert_eq!(exchange(&mut line, &process(0x81, 0x043C, 0))[2], 0x81);
    // Format 1-31 with bit 6 set (unused): still address 1, the byte echoed as sent.
    assert_eq!(exchange(&mut line, &process(0x41, 0x043C, 0))[2], 0x41);
    // Address 40 is reachable in format 1-126 only.
    let mut line = line_with(&[40]);
    assert_eq!(exchange(&mut line, &process(0xA8, 0x043C, 0))[2], 0xA8);
    assert!(exchange(&mut line, &process(0x08, 0x043C, 0)).is_empty());
}

#[test]
fn control_timeout_trips_and_15_30_logs_it() {
    let mut line = line_with(&[1]);
    // 8-03 = 1.0 s (Uint32, AK D), 8-04 = 5 "stop and trip" (AK E).
    assert_eq!(pwe(&exchange(&mut line, &param(0x81, 0xD, 803, 0, 10))), 10);
    assert_eq!(pwe(&exchange(&mut line, &param(0x81, 0xE, 804, 0, 5))), 5);
    exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    let last = line.now();
    // Telegrams every 0.5 s keep it alive.
    for _ in 0..4 {
        wait(&mut line, ms(500));
        exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    }
    assert_ne!(last, line.now());
    assert_eq!(drive(&mut line, 1).core().model.trip(), None);
    // Then silence: the timeout acts 1.0 s after the last telegram's last byte.
    let d = match line.device_mut(1) {
        Some(d) => d.poll_timeout(),
        None => None,
    };
    let deadline = d.unwrap();
    run_until(&mut line, deadline - Duration::from_micros(1));
    assert_eq!(drive(&mut line, 1).core().model.trip(), None);
    run_until(&mut line, deadline);
    let m = &drive(&mut line, 1).core().model;
    assert_eq!(m.trip(), Some(Trip::CommunicationTimeout));
    assert_eq!(m.trip_log().last().map(|r| r.at), Some(deadline));
    // The reply shows the trip; 15-30[0] holds alarm 17 "control word timeout".
    let reply = exchange(&mut line, &param(0x81, 0x1, 1530, 0, 0));
    assert_eq!(
        reply,
        [0x02, 0x0E, 0x81, 0x15, 0xFA, 0x00, 0x00, 0x00, 0x00, 0x00, 0x11, 0x06, 0x08, 0x00, 0x00, 0x7D]
    );
    assert_eq!(drive(&mut line, 1).snapshot().trip.as_deref(), Some("communication time-out"));
    // Reset on the edge of bit 7; start again.
    exchange(&mut line, &process(0x81, 0x043C, 0x2000));
    let (stw, _) = stw_mav(&exchange(&mut line, &process(0x81, 0x04FC, 0x2000)));
    assert_eq!(stw, STW_STARTED);
}

#[test]
fn control_timeout_stop_function_resumes_with_the_next_telegram() {
    let mut line = line_with(&[1]);
    exchange(&mut line, &param(0x81, 0xD, 803, 0, 5));
    exchange(&mut line, &param(0x81, 0xE, 804, 0, 2));
    exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    wait(&mut line, ms(2000));
    let m = &drive(&mut line, 1).core().model;
    assert_eq!((m.trip(), m.state()), (None, RunState::Stopped), "8-04 = 2 stops without a trip");
    exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    assert_eq!(drive(&mut line, 1).core().model.state(), RunState::Running);
}

#[test]
fn address_8_31_and_snapshot() {
    let mut line = line_with(&[1]);
    assert!(DanfossDrive::new(0, Instant::ZERO).is_err());
    assert!(DanfossDrive::new(127, Instant::ZERO).is_err());
    let d = drive(&mut line, 1);
    assert_eq!((d.protocol().as_str(), d.family().as_str()), ("danfoss-fc", "danfoss"));
    assert_eq!(d.core().params.get("8-31"), Some(1));
    assert_eq!(
        d.control_source(),
        "8-02 = FC port (RS485), 8-01 = digital and control word, 8-53 = logic OR"
    );
    // 8-31 = 127: out of the FC range.
    let reply = exchange(&mut line, &param(0x81, 0xE, 831, 0, 127));
    assert_eq!(Reply::parse(&reply).unwrap().fault_code().map(|c| c.0), Some(2));
    // 8-31 = 9: the reply still comes from 1 (ADR echoed), then the drive answers 9 only.
    let reply = exchange(&mut line, &param(0x81, 0xE, 831, 0, 9));
    assert_eq!((reply[2], pwe(&reply)), (0x81, 9));
    assert!(exchange(&mut line, &process(0x81, 0x043C, 0)).is_empty());
    assert_eq!(exchange(&mut line, &process(0x89, 0x043C, 0)).len(), 8);
    assert_eq!(drive(&mut line, 1).snapshot().address, 9);
    // 8-02 = option A: the control word no longer acts, bus control is off.
    exchange(&mut line, &param(0x89, 0xE, 802, 0, 3));
    let (stw, _) = stw_mav(&exchange(&mut line, &process(0x89, 0x047C, 0x2000)));
    assert_eq!(stw & 0x0A00, 0, "no bus control, not in operation");
    // The drive adopts the core's response delay (8-35 = 10 ms by default).
    assert_eq!(drive(&mut line, 1).core().response_delay, ms(10));
}

#[test]
fn reference_range_and_ramp_2_follow_their_parameters() {
    let mut line = line_with(&[1]);
    exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    wait(&mut line, ms(2000));
    // 3-03 Maximum Reference = 40.000 Hz (Int32, AK D): 50 % is now 20 Hz.
    exchange(&mut line, &param(0x81, 0xD, 303, 0, 40_000));
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 20.0);
    wait(&mut line, ms(2000));
    let reply = exchange(&mut line, &process(0x81, 0x047C, 0x2000));
    assert_eq!(stw_mav(&reply), (STW_AT_SPEED, 0x2000));
    // Bit 09 selects ramp 2: 3-51 = 1.00 s from 0 to 50 Hz, so 0 -> 20 Hz takes 0.4 s.
    exchange(&mut line, &param(0x81, 0x3, 351, 0, 100));
    exchange(&mut line, &process(0x81, 0x043C, 0x2000));
    wait(&mut line, ms(2000));
    assert_eq!(drive(&mut line, 1).core().model.state(), RunState::Stopped);
    exchange(&mut line, &process(0x81, 0x067C, 0x2000));
    assert_eq!(drive(&mut line, 1).core().model.settings().accel, ms(1300), "65 Hz / 50 Hz x 1.00 s");
    wait(&mut line, ms(450));
    assert_eq!(drive(&mut line, 1).core().model.output_hz(), 20.0);
    // Bit 05 = 0 holds the output: a new reference is not followed.
    exchange(&mut line, &process(0x81, 0x065C, 0x4000));
    wait(&mut line, ms(1000));
    assert_eq!(drive(&mut line, 1).core().model.output_hz(), 20.0);
}
