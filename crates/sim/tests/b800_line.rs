//! B800 virtual drives on a paced virtual line (9600 bps 8N1), on simulated time: the seed's
//! examples (`seeds/000_04b515f0e0c1734e.txt`) byte for byte, every error code with its reply
//! bytes, global commands, reversing, ramps and parameters.

mod support;

use std::time::Duration;

use drivebus_drive::{Storage, WriteError};
use drivebus_proto::b800::{
    self, Address, DriveState, MasterCommand, Request, SlaveReply, Speed, Version, B800,
};
use drivebus_proto::session::{MasterEvent, MasterSession};
use drivebus_proto::Instant;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::drive::VirtualDrive;
use drivebus_sim::family::b800::{trip_code, B800Drive};
use drivebus_sim::model::{Rotation, RunState, Trip};

/// `"7E 38 31"` as bytes.
fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|h| u8::from_str_radix(h, 16).expect("test hex")).collect()
}

/// A line at the seed's 9600 bps 8N1 with one B800 per address; ports in the same order.
fn line_with(addresses: &[u8]) -> VirtualLine {
    let mut line = VirtualLine::new(b800::BAUD, b800::FORMAT, Instant::ZERO);
    for &a in addresses {
        line.add_device(Box::new(B800Drive::new(a, Instant::ZERO).expect("valid address")));
    }
    line
}

fn run_until_idle(line: &mut VirtualLine) {
    let mut guard = 0;
    while let Some(t) = line.next_deadline() {
        line.advance_to(t);
        guard += 1;
        assert!(guard < 10_000, "the line never went idle");
    }
}

/// Writes `request` (hex text) at the line's time, runs the line until it is idle, and
/// returns every byte that reached the master.
fn exchange(line: &mut VirtualLine, request: &str) -> Vec<u8> {
    let now = line.now();
    line.master_write(now, &hex(request));
    run_until_idle(line);
    // Leave a gap of a few characters before the next request.
    let later = line.now() + Duration::from_millis(5);
    line.advance_to(later);
    let mut got = Vec::new();
    line.master_read(&mut got);
    got
}

/// Asserts that `request` is answered with exactly `reply` (both hex text).
#[track_caller]
fn assert_reply(line: &mut VirtualLine, request: &str, reply: &str) {
    let got = exchange(line, request);
    assert_eq!(got, hex(reply), "reply to {request}");
}

/// Asserts that `request` gets no answer at all.
#[track_caller]
fn assert_silent(line: &mut VirtualLine, request: &str) {
    let got = exchange(line, request);
    assert!(got.is_empty(), "no reply expected to {request}, got {got:02X?}");
}

/// Lets `d` of simulated time pass.
fn wait(line: &mut VirtualLine, d: Duration) {
    let t = line.now() + d;
    line.advance_to(t);
}

fn drive(line: &mut VirtualLine, port: usize) -> &mut dyn VirtualDrive {
    line.drive_mut(port).expect("a B800 drive on this port")
}

fn set(line: &mut VirtualLine, port: usize, name: &str, raw: i64) {
    drive(line, port).core_mut().params.set(name, raw, Storage::Eeprom, false).expect("a valid write");
}

fn state(line: &mut VirtualLine, port: usize) -> RunState {
    drive(line, port).core().model.state()
}

fn output_mhz(line: &mut VirtualLine, port: usize) -> i64 {
    drive(line, port).core().model.output_mhz()
}

// Frames for drive 1 (DA 81 from the master, 01 in the reply), checksums worked out by hand
// from the seed's rule "~(DA + CMD + ([DATA]))" over the ASCII characters.
const R1: &str = "7E 38 31 35 32 32 46 7F";
const S1: &str = "7E 38 31 35 33 32 45 7F";
const A1: &str = "7E 38 31 34 31 33 31 7F";
const Z1: &str = "7E 38 31 35 41 32 30 7F";
const M1: &str = "7E 38 31 34 44 31 45 7F";
const T1: &str = "7E 38 31 35 34 32 44 7F";
const V1: &str = "7E 38 31 35 36 32 42 7F";
const I1: &str = "7E 38 31 34 39 32 39 7F";
const L1: &str = "7E 38 31 34 43 31 46 7F";
/// P 40.0 Hz (0x0960) to drive 1.
const P1_40: &str = "7E 38 31 35 30 30 39 36 30 36 32 7F";
/// P 60.0 Hz (0x0E10) to drive 1.
const P1_60: &str = "7E 38 31 35 30 30 45 31 30 35 42 7F";

const R1_OK: &str = "7E 30 31 37 32 33 35 7F";
const S1_OK: &str = "7E 30 31 37 33 33 34 7F";
const P1_OK: &str = "7E 30 31 37 30 33 37 7F";
const I1_OK: &str = "7E 30 31 36 39 32 46 7F";
const L1_OK: &str = "7E 30 31 36 43 32 35 7F";

/// The `e` replies of drive 1: `7E 30 31 36 35 [code] [CS] 7F`.
const E02: &str = "7E 30 31 36 35 30 32 44 31 7F";
const E91: &str = "7E 30 31 36 35 39 31 43 39 7F";
const E92: &str = "7E 30 31 36 35 39 32 43 38 7F";
const E93: &str = "7E 30 31 36 35 39 33 43 37 7F";
const E94: &str = "7E 30 31 36 35 39 34 43 36 7F";
const E95: &str = "7E 30 31 36 35 39 35 43 35 7F";
const E97: &str = "7E 30 31 36 35 39 37 43 33 7F";
const E98: &str = "7E 30 31 36 35 39 38 43 32 7F";
const E99: &str = "7E 30 31 36 35 39 39 43 31 7F";
const E9A: &str = "7E 30 31 36 35 39 41 42 39 7F";

/// Global run and stop (seed 000, "Further examples" 1 and 3).
const G_RUN: &str = "7E 34 37 35 32 32 44 7F";
const G_STOP: &str = "7E 34 37 35 33 32 43 7F";

// ------------------------------------------------------------------------------------------
// The seed's examples
// ------------------------------------------------------------------------------------------

#[test]
fn seed_run_command_to_drive_1() {
    let mut line = line_with(&[1]);
    // seed 000: "Send Run Command to Drive number 01" -> "Run Command to Drive number 01
    // carried out": 7E 30 31 37 32 33 35 7F.
    assert_reply(&mut line, "7E 38 31 35 32 32 46 7F", "7E 30 31 37 32 33 35 7F");
    assert_eq!(state(&mut line, 1), RunState::Running);
    let snap = drive(&mut line, 1).snapshot();
    assert_eq!(
        (snap.family.as_str(), snap.protocol.as_str(), snap.state.as_str()),
        ("b800", "b800", "running")
    );
    assert_eq!(snap.control_source, "F-12 = 1 keypad");
}

#[test]
fn seed_new_speed_40_hz_to_drive_5_ramps_there_on_simulated_time() {
    let mut line = line_with(&[5]);
    assert_reply(&mut line, "7E 38 35 35 32 32 42 7F", "7E 30 35 37 32 33 31 7F");
    // seed 000: "Send new target speed of 40.0Hz from intelligent host to drive 05 in keypad
    // mode" -> "New target speed of 40.0Hz set in drive 05": 7E 30 35 37 30 33 33 7F.
    assert_reply(&mut line, "7E 38 35 35 30 30 39 36 30 35 45 7F", "7E 30 35 37 30 33 33 7F");
    // The ramp starts when the P arrives, some 20 ms before `started`.
    let started = line.now();
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 40.0);
    // F-03 = 5.0 s from 0 to F-01 = 50.0 Hz: 10 Hz/s, so 40 Hz is reached 4 s after the run.
    let before = started + Duration::from_millis(3_900);
    line.advance_to(before);
    assert!(output_mhz(&mut line, 1) < 40_000, "{} mHz at 3.9 s", output_mhz(&mut line, 1));
    line.advance_to(started + Duration::from_secs(4));
    assert_eq!(output_mhz(&mut line, 1), 40_000);
    // Read back with Z: 40.0 Hz x 60 = 2400 = 0x0960.
    assert_reply(&mut line, "7E 38 35 35 41 31 43 7F", "7E 30 35 37 41 30 39 36 30 35 33 7F");
}

#[test]
fn seed_speed_40_hz_before_run_is_held_and_used_at_the_run() {
    let mut line = line_with(&[1]);
    assert_reply(&mut line, P1_40, P1_OK);
    assert_eq!(output_mhz(&mut line, 1), 0, "a stopped drive only loads the speed");
    assert_reply(&mut line, R1, R1_OK);
    wait(&mut line, Duration::from_secs(2));
    // Half way: 20.0 Hz = 1200 = 0x04B0, read a few milliseconds after the 2 s.
    let z = exchange(&mut line, Z1);
    let rep = b800::Reply::parse(&z).expect("a z reply");
    let SlaveReply::SpeedHz(s) = rep.reply else { panic!("{rep:?}") };
    assert!((1200..1240).contains(&s.raw()), "{}", s.raw());
    wait(&mut line, Duration::from_secs(3));
    assert_reply(&mut line, Z1, "7E 30 31 37 41 30 39 36 30 35 37 7F");
}

#[test]
fn global_run_and_stop_on_a_line_of_three_drives_act_without_a_reply() {
    let mut line = line_with(&[1, 2, 3]);
    // seed 000: "Start all drives" 7E 34 37 35 32 32 44 7F; "There is no reply from the
    // B800s to a global command."
    assert_silent(&mut line, G_RUN);
    assert_eq!(line.stats().device_bytes, 0, "nothing from any drive on the line");
    for port in 1..=3 {
        assert_eq!(state(&mut line, port), RunState::Running, "drive on port {port}");
    }
    // P to everyone: every drive loads 40 Hz, none answers.
    assert_silent(&mut line, "7E 34 37 35 30 30 39 36 30 36 30 7F");
    wait(&mut line, Duration::from_secs(5));
    for port in 1..=3 {
        assert_eq!(output_mhz(&mut line, port), 40_000, "drive on port {port}");
    }
    // seed 000: "Stop all drives" 7E 34 37 35 33 32 43 7F.
    assert_silent(&mut line, G_STOP);
    for port in 1..=3 {
        assert_eq!(state(&mut line, port), RunState::Stopping, "drive on port {port}");
    }
    wait(&mut line, Duration::from_secs(5));
    for port in 1..=3 {
        assert_eq!(state(&mut line, port), RunState::Stopped, "drive on port {port}");
    }
    assert_eq!(line.stats().device_bytes, 0);
    // Each drive still answers its own address.
    assert_reply(&mut line, "7E 38 32 35 41 31 46 7F", "7E 30 32 37 41 30 30 30 30 36 35 7F");
}

#[test]
fn other_addresses_are_silent_and_do_not_act() {
    let mut line = line_with(&[1]);
    // R to drive 2, 3 and 63: drive 1 neither acts nor answers.
    assert_silent(&mut line, "7E 38 32 35 32 32 45 7F");
    assert_silent(&mut line, "7E 38 33 35 32 32 44 7F");
    assert_eq!(state(&mut line, 1), RunState::Stopped);
    // Unknown command and bad checksum for drive 2: not drive 1's business either.
    assert_silent(&mut line, "7E 38 32 35 38 32 38 7F");
    assert_silent(&mut line, "7E 38 32 35 32 32 46 7F");
    // A drive's reply heard on the line (DA 01) is not a request.
    assert_silent(&mut line, R1_OK);
    assert_eq!(line.stats().device_bytes, 0);
}

#[test]
fn a_line_of_drives_answers_each_address_once() {
    let mut line = line_with(&[1, 2, 3]);
    assert_reply(&mut line, "7E 38 32 35 32 32 45 7F", "7E 30 32 37 32 33 34 7F");
    assert_eq!(state(&mut line, 1), RunState::Stopped);
    assert_eq!(state(&mut line, 2), RunState::Running);
    assert_eq!(state(&mut line, 3), RunState::Stopped);
}

// ------------------------------------------------------------------------------------------
// Reversing with F-12 = 2
// ------------------------------------------------------------------------------------------

#[test]
fn run_to_a_running_drive_reverses_it_with_f12_2() {
    let mut line = line_with(&[1]);
    set(&mut line, 1, "F-12", 2);
    drive(&mut line, 1).core_mut().model.set_setpoint_hz(20.0);
    assert_eq!(drive(&mut line, 1).control_source(), "F-12 = 2 host run/stop");
    assert_reply(&mut line, R1, R1_OK);
    wait(&mut line, Duration::from_secs(3));
    assert_eq!(output_mhz(&mut line, 1), 20_000);
    // seed 000: "Sending a run command to an already running drive reverses direction if
    // F-12 = 2".
    assert_reply(&mut line, R1, R1_OK);
    let t0 = line.now();
    let m = &drive(&mut line, 1).core().model;
    assert_eq!((m.rotation(), m.output_rotation()), (Rotation::Reverse, Rotation::Forward));
    // Down through zero (2 s at 10 Hz/s) and up again on the other side.
    line.advance_to(t0 + Duration::from_secs(1));
    assert!(output_mhz(&mut line, 1) < 20_000);
    // One step across the zero crossing: the time after it is not lost.
    line.advance_to(t0 + Duration::from_secs(5));
    let m = &drive(&mut line, 1).core().model;
    assert_eq!((m.output_mhz(), m.output_rotation()), (20_000, Rotation::Reverse));
    assert_eq!(drive(&mut line, 1).snapshot().direction, "reverse");
    // And back.
    assert_reply(&mut line, R1, R1_OK);
    assert_eq!(drive(&mut line, 1).core().model.rotation(), Rotation::Forward);
}

#[test]
fn global_run_reverses_every_running_drive_with_f12_2() {
    let mut line = line_with(&[1, 2, 3]);
    for port in 1..=3 {
        set(&mut line, port, "F-12", 2);
    }
    // seed 000: "Reverse direction of all drives (F-12 = 2)" is the same frame as "Start all
    // drives": the first starts them, the second reverses them.
    assert_silent(&mut line, G_RUN);
    wait(&mut line, Duration::from_secs(1));
    assert_silent(&mut line, G_RUN);
    for port in 1..=3 {
        let m = &drive(&mut line, port).core().model;
        assert_eq!((m.state(), m.rotation()), (RunState::Running, Rotation::Reverse), "port {port}");
    }
}

// ------------------------------------------------------------------------------------------
// Every error code with its reply bytes
// ------------------------------------------------------------------------------------------

#[test]
fn error_91_not_in_keypad_mode() {
    let mut line = line_with(&[1]);
    // F-12 = 0 (terminals): the host may not run, stop or set the speed.
    set(&mut line, 1, "F-12", 0);
    for req in [R1, S1, P1_40, I1, L1] {
        assert_reply(&mut line, req, E91);
    }
    assert_eq!(state(&mut line, 1), RunState::Stopped);
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 0.0);
    // Requests still work.
    assert_reply(&mut line, T1, "7E 30 31 37 34 30 30 30 32 37 31 7F");
    // F-12 = 2 (host run/stop): run and stop work, P/I/L do not (seed 000: "Keypad mode only
    // (F-12 = 1)").
    set(&mut line, 1, "F-12", 2);
    assert_reply(&mut line, R1, R1_OK);
    for req in [P1_40, I1, L1] {
        assert_reply(&mut line, req, E91);
    }
    assert_reply(&mut line, S1, S1_OK);
}

#[test]
fn error_92_rpm_not_available_with_f10_0() {
    let mut line = line_with(&[1]);
    assert_reply(&mut line, P1_40, P1_OK);
    assert_reply(&mut line, R1, R1_OK);
    wait(&mut line, Duration::from_secs(5));
    // F-10 = 1 (default): 40 Hz x F-09 1420 rpm / F-06 50 Hz = 1136 rpm = 0x0470.
    assert_reply(&mut line, M1, "7E 30 31 36 44 30 34 37 30 35 39 7F");
    // seed 000: "0x92 B800 speed in RPM not available (F-10 = 0)".
    set(&mut line, 1, "F-10", 0);
    assert_reply(&mut line, M1, E92);
}

#[test]
fn error_93_run_to_a_running_drive_in_keypad_mode() {
    let mut line = line_with(&[1]);
    assert_reply(&mut line, R1, R1_OK);
    assert_reply(&mut line, R1, E93);
    assert_eq!(drive(&mut line, 1).core().model.rotation(), Rotation::Forward, "no reversal with F-12 = 1");
    // While ramping down after S the drive may be started again.
    assert_reply(&mut line, S1, S1_OK);
    assert_reply(&mut line, R1, R1_OK);
}

#[test]
fn error_94_increase_or_reduce_to_a_stopped_drive() {
    let mut line = line_with(&[1]);
    assert_reply(&mut line, I1, E94);
    assert_reply(&mut line, L1, E94);
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 0.0);
}

#[test]
fn error_95_bad_checksum_for_this_drive_only() {
    let mut line = line_with(&[1, 2]);
    // R to drive 1 with CS 2E instead of 2F.
    assert_reply(&mut line, "7E 38 31 35 32 32 45 7F", E95);
    assert_eq!(state(&mut line, 1), RunState::Stopped, "a damaged frame is not acted on");
    // P to drive 1 with a damaged DATA digit (0961 instead of 0960, CS unchanged).
    assert_reply(&mut line, "7E 38 31 35 30 30 39 36 31 36 32 7F", E95);
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 0.0);
    // A global frame with a bad checksum: nobody may answer.
    assert_silent(&mut line, "7E 34 37 35 32 32 45 7F");
    assert_eq!(state(&mut line, 2), RunState::Stopped);
}

#[test]
fn error_97_unknown_command() {
    let mut line = line_with(&[1, 2]);
    // 'X' (0x58) to drive 1; drive 2 stays silent, so exactly one reply is on the line.
    assert_reply(&mut line, "7E 38 31 35 38 32 39 7F", E97);
    // 'Q' (0x51) too.
    assert_reply(&mut line, "7E 38 31 35 31 33 30 7F", E97);
    // Global unknown command: no reply.
    assert_silent(&mut line, "7E 34 37 35 38 32 37 7F");
}

#[test]
fn error_98_parameters_locked() {
    let mut line = line_with(&[1]);
    assert_reply(&mut line, R1, R1_OK);
    set(&mut line, 1, "F-14", 1);
    for req in [P1_40, I1, L1] {
        assert_reply(&mut line, req, E98);
    }
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 0.0);
    // Run, stop and requests are not parameter changes.
    assert_reply(&mut line, S1, S1_OK);
    set(&mut line, 1, "F-14", 0);
    assert_reply(&mut line, P1_40, P1_OK);
}

#[test]
fn error_99_hardware_enable_missing() {
    let mut line = line_with(&[1]);
    drive(&mut line, 1).core_mut().model.set_hardware_enable(false);
    assert_reply(&mut line, R1, E99);
    assert_eq!(state(&mut line, 1), RunState::Stopped);
    // Status low byte 0x99.
    assert_reply(&mut line, T1, "7E 30 31 37 34 30 30 39 39 36 31 7F");
    drive(&mut line, 1).core_mut().model.set_hardware_enable(true);
    assert_reply(&mut line, R1, R1_OK);
    // Status low byte 0x93 while running.
    assert_reply(&mut line, T1, "7E 30 31 37 34 30 30 39 33 36 37 7F");
}

#[test]
fn error_9a_tripped_and_stop_resets() {
    let mut line = line_with(&[1]);
    assert_reply(&mut line, R1, R1_OK);
    drive(&mut line, 1).core_mut().model.trip_now(Trip::External);
    assert_reply(&mut line, R1, E9A);
    assert_reply(&mut line, I1, E9A);
    assert_reply(&mut line, L1, E9A);
    // Status: low byte 0x9A, high byte the trip code (external trip 06).
    assert_eq!(trip_code(Trip::External), 0x06);
    assert_reply(&mut line, T1, "7E 30 31 37 34 30 36 39 41 35 33 7F");
    assert_eq!(drive(&mut line, 1).core().params.values("F-13"), Some(&[6, 0, 0, 0][..]));
    // S resets the trip; the drive is in standby again.
    assert_reply(&mut line, S1, S1_OK);
    assert_reply(&mut line, T1, "7E 30 31 37 34 30 30 30 32 37 31 7F");
    assert_reply(&mut line, R1, R1_OK);
}

#[test]
fn error_9a_when_the_trip_cause_persists() {
    let mut line = line_with(&[1]);
    assert_reply(&mut line, R1, R1_OK);
    drive(&mut line, 1).core_mut().model.set_supply(0.5);
    wait(&mut line, Duration::from_millis(10));
    assert_eq!(drive(&mut line, 1).core().model.trip(), Some(Trip::UnderVoltage));
    // The supply is still low: S cannot reset.
    assert_reply(&mut line, S1, E9A);
    drive(&mut line, 1).core_mut().model.set_supply(1.0);
    assert_reply(&mut line, S1, S1_OK);
}

#[test]
fn error_02_stop_to_a_drive_in_standby() {
    let mut line = line_with(&[1]);
    // seed 000: "0x02 Drive in Standby (status information)".
    assert_reply(&mut line, S1, E02);
    assert_reply(&mut line, R1, R1_OK);
    assert_reply(&mut line, S1, S1_OK);
    wait(&mut line, Duration::from_secs(1));
    assert_eq!(state(&mut line, 1), RunState::Stopped);
    assert_reply(&mut line, S1, E02);
}

// ------------------------------------------------------------------------------------------
// Requests and keypad speed
// ------------------------------------------------------------------------------------------

#[test]
fn version_status_current_and_rpm() {
    let mut line = line_with(&[1]);
    // V: 1.00 as BCD, 0x0100.
    assert_reply(&mut line, V1, "7E 30 31 37 36 30 31 30 30 37 30 7F");
    // T: standby 0x0002.
    assert_reply(&mut line, T1, "7E 30 31 37 34 30 30 30 32 37 31 7F");
    // A: no current while stopped.
    assert_reply(&mut line, A1, "7E 30 31 36 31 30 30 30 30 37 37 7F");
    // At 50 Hz: M = 1420 rpm (F-09) = 0x058C; A = 4.1 A x (0.3 + 0.7 x 0.5 load) = 2.7 A = 0x001B.
    drive(&mut line, 1).core_mut().model.set_setpoint_hz(50.0);
    assert_reply(&mut line, R1, R1_OK);
    wait(&mut line, Duration::from_secs(6));
    assert_reply(&mut line, M1, "7E 30 31 36 44 30 35 38 43 34 34 7F");
    assert_reply(&mut line, A1, "7E 30 31 36 31 30 30 31 42 36 34 7F");
}

#[test]
fn increase_and_reduce_step_the_keypad_setpoint_within_the_limits() {
    let mut line = line_with(&[1]);
    assert_reply(&mut line, P1_40, P1_OK);
    assert_reply(&mut line, R1, R1_OK);
    // One step is F-19 = 0.5 Hz.
    assert_reply(&mut line, I1, I1_OK);
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 40.5);
    wait(&mut line, Duration::from_secs(5));
    assert_reply(&mut line, Z1, "7E 30 31 37 41 30 39 37 45 34 31 7F");
    assert_reply(&mut line, L1, L1_OK);
    assert_reply(&mut line, L1, L1_OK);
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 39.5);
    // Up to F-01 = 50.0 Hz and no further.
    for _ in 0..25 {
        assert_reply(&mut line, I1, I1_OK);
    }
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 50.0);
    // Down to F-02 (set to 10.0 Hz here) and no further.
    set(&mut line, 1, "F-02", 100);
    set(&mut line, 1, "F-19", 100);
    for _ in 0..6 {
        assert_reply(&mut line, L1, L1_OK);
    }
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 10.0);
}

#[test]
fn set_speed_is_held_within_the_frequency_limits() {
    let mut line = line_with(&[1]);
    // 60 Hz (0x0E10) is above F-01 = 50.0 Hz.
    assert_reply(&mut line, P1_60, P1_OK);
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 50.0);
    set(&mut line, 1, "F-02", 450);
    assert_reply(&mut line, P1_40, P1_OK);
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 45.0);
}

#[test]
fn lower_case_hex_digits_are_accepted() {
    let mut line = line_with(&[1]);
    // Z as "5a", CS over the characters as sent: 38 31 35 61 -> ~0xFF = 00.
    assert_reply(&mut line, "7E 38 31 35 61 30 30 7F", "7E 30 31 37 41 30 30 30 30 36 36 7F");
}

#[test]
fn a_master_session_talks_to_the_drive() {
    let mut line = line_with(&[7]);
    let mut master = MasterSession::new(B800, b800::default_timing());
    let seven = Address::new(7).expect("7 is an address");
    let to7 = |cmd: MasterCommand| Request::to_drive(seven, cmd);
    let rep = ask(&mut line, &mut master, to7(MasterCommand::SetSpeed(Speed::from_hz(25.0).expect("25 Hz"))));
    assert_eq!(rep, MasterEvent::Reply(b800::Reply::new(seven, SlaveReply::SetSpeed)));
    let rep = ask(&mut line, &mut master, to7(MasterCommand::Run));
    assert_eq!(rep, MasterEvent::Reply(b800::Reply::new(seven, SlaveReply::Run)));
    wait(&mut line, Duration::from_secs(3));
    let rep = ask(&mut line, &mut master, to7(MasterCommand::SpeedHz));
    assert_eq!(rep, MasterEvent::Reply(b800::Reply::new(seven, SlaveReply::SpeedHz(Speed::from_raw(1500)))));
    let rep = ask(&mut line, &mut master, to7(MasterCommand::Status));
    let MasterEvent::Reply(b800::Reply { reply: SlaveReply::Status(s), .. }) = rep else { panic!("{rep:?}") };
    assert_eq!(s.state(), DriveState::Running);
    let rep = ask(&mut line, &mut master, to7(MasterCommand::Version));
    assert_eq!(
        rep,
        MasterEvent::Reply(b800::Reply::new(seven, SlaveReply::Version(Version::new(1, 0).expect("1.00"))))
    );
    // A global stop: the session waits out the turnaround, no reply.
    master.send(line.now(), &Request::global(MasterCommand::Stop)).expect("idle");
    assert_eq!(drive_session(&mut line, &mut master), MasterEvent::BroadcastDone);
    assert_eq!(state(&mut line, 1), RunState::Stopping);
    // A request to a drive that is not there times out.
    let eight = Address::new(8).expect("8 is an address");
    let rep = ask(&mut line, &mut master, Request::to_drive(eight, MasterCommand::Status));
    assert_eq!(rep, MasterEvent::Timeout);
}

/// Sends `req` through the master session over the line; returns the outcome.
fn ask(line: &mut VirtualLine, master: &mut MasterSession<B800>, req: Request) -> MasterEvent<b800::Reply> {
    master.send(line.now(), &req).expect("the session is idle");
    drive_session(line, master)
}

/// Runs the master session and the line until the session has an outcome.
fn drive_session(line: &mut VirtualLine, master: &mut MasterSession<B800>) -> MasterEvent<b800::Reply> {
    support::master_outcome(line, master, |event| event)
}

// ------------------------------------------------------------------------------------------
// Parameters
// ------------------------------------------------------------------------------------------

#[test]
fn parameter_writes_are_checked_and_counted() {
    let mut line = line_with(&[1]);
    let params = &mut drive(&mut line, 1).core_mut().params;
    // Range: F-12 is 0..2.
    assert!(matches!(params.set("F-12", 3, Storage::Eeprom, false), Err(WriteError::OutOfRange(_))));
    // Read-only: the trip log.
    assert!(matches!(params.set("F-13", 1, Storage::Eeprom, false), Err(WriteError::ReadOnly { .. })));
    // Not while running: maximum frequency and motor data.
    assert!(matches!(
        params.set("F-01", 600, Storage::Eeprom, true),
        Err(WriteError::NotWhileRunning { .. })
    ));
    assert_eq!(params.total_eeprom_writes(), 0, "refused writes never reach the EEPROM");
    params.set("F-03", 100, Storage::Eeprom, false).expect("10.0 s");
    params.set("F-03", 100, Storage::Eeprom, false).expect("10.0 s");
    params.set("F-04", 20, Storage::Ram, false).expect("2.0 s");
    assert_eq!(params.eeprom_writes("F-03"), Some(2));
    assert_eq!(params.eeprom_writes("F-04"), Some(0), "a RAM write is not an EEPROM write");
    assert_eq!(drive(&mut line, 1).snapshot().eeprom_writes, 2);
}

#[test]
fn parameter_changes_reach_the_model_at_the_next_step() {
    let mut line = line_with(&[1]);
    // F-03 = 10.0 s and F-01 = 80.0 Hz: 8 Hz/s, so 40 Hz takes 5 s.
    set(&mut line, 1, "F-03", 100);
    set(&mut line, 1, "F-01", 800);
    assert_reply(&mut line, P1_60, P1_OK);
    assert_eq!(drive(&mut line, 1).core().model.setpoint_hz(), 60.0, "F-01 = 80 Hz allows 60 Hz");
    assert_reply(&mut line, P1_40, P1_OK);
    assert_reply(&mut line, R1, R1_OK);
    let t0 = line.now();
    line.advance_to(t0 + Duration::from_millis(4_900));
    assert!(output_mhz(&mut line, 1) < 40_000);
    line.advance_to(t0 + Duration::from_millis(5_100));
    assert_eq!(output_mhz(&mut line, 1), 40_000);
    // F-05 = 1: S coasts at once.
    set(&mut line, 1, "F-05", 1);
    assert_reply(&mut line, S1, S1_OK);
    assert_eq!((state(&mut line, 1), output_mhz(&mut line, 1)), (RunState::Stopped, 0));
}

#[test]
fn f32_and_the_core_address_move_the_drive() {
    let mut line = line_with(&[1]);
    set(&mut line, 1, "F-32", 2);
    wait(&mut line, Duration::from_millis(1));
    assert_silent(&mut line, R1);
    assert_reply(&mut line, "7E 38 32 35 32 32 45 7F", "7E 30 32 37 32 33 34 7F");
    drive(&mut line, 1).core_mut().address = 1;
    wait(&mut line, Duration::from_millis(1));
    assert_eq!(drive(&mut line, 1).core().params.get("F-32"), Some(1));
    assert_reply(&mut line, S1, S1_OK);
}

// ------------------------------------------------------------------------------------------
// Communication loss, trip log, robustness
// ------------------------------------------------------------------------------------------

#[test]
fn communication_loss_trips_with_f34_0() {
    let mut line = line_with(&[1]);
    set(&mut line, 1, "F-33", 20);
    assert_reply(&mut line, R1, R1_OK);
    // Telegrams every second keep it alive; a global one counts too.
    for _ in 0..3 {
        wait(&mut line, Duration::from_secs(1));
        assert_reply(&mut line, T1, "7E 30 31 37 34 30 30 39 33 36 37 7F");
    }
    wait(&mut line, Duration::from_secs(1));
    assert_silent(&mut line, "7E 34 37 35 30 30 39 36 30 36 30 7F");
    wait(&mut line, Duration::from_millis(1_900));
    assert_eq!(drive(&mut line, 1).core().model.trip(), None);
    wait(&mut line, Duration::from_millis(200));
    assert_eq!(drive(&mut line, 1).core().model.trip(), Some(Trip::CommunicationTimeout));
    // Status: trip code 05 in the high byte.
    assert_reply(&mut line, T1, "7E 30 31 37 34 30 35 39 41 35 34 7F");
}

#[test]
fn communication_loss_ramps_to_a_stop_with_f34_1() {
    let mut line = line_with(&[1]);
    set(&mut line, 1, "F-33", 20);
    set(&mut line, 1, "F-34", 1);
    assert_reply(&mut line, P1_40, P1_OK);
    assert_reply(&mut line, R1, R1_OK);
    let t0 = line.now();
    // t0 is about 22 ms after the R arrived (the reply and a gap).
    line.advance_to(t0 + Duration::from_millis(1_950));
    assert_eq!(state(&mut line, 1), RunState::Running);
    line.advance_to(t0 + Duration::from_millis(2_500));
    // Lost 2.0 s after the R at 20 Hz, then about 0.52 s of ramping down at 10 Hz/s.
    assert_eq!(state(&mut line, 1), RunState::Stopping);
    assert!((14_000..15_000).contains(&output_mhz(&mut line, 1)), "{}", output_mhz(&mut line, 1));
    assert_eq!(drive(&mut line, 1).core().model.trip(), None);
    wait(&mut line, Duration::from_secs(2));
    assert_eq!(state(&mut line, 1), RunState::Stopped);
}

#[test]
fn trip_log_keeps_the_last_four_codes_newest_first() {
    let mut line = line_with(&[1]);
    let trips =
        [Trip::External, Trip::OverCurrent, Trip::OverVoltage, Trip::UnderVoltage, Trip::OverTemperature];
    for trip in trips {
        drive(&mut line, 1).core_mut().model.trip_now(trip);
        assert_reply(&mut line, S1, S1_OK);
    }
    assert_eq!(drive(&mut line, 1).core().params.values("F-13"), Some(&[4, 3, 2, 1][..]));
}

#[test]
fn noise_and_broken_frames_never_panic_and_the_drive_still_answers() {
    let mut line = line_with(&[1]);
    let mut x: u32 = 0x1234_5678;
    for round in 0..200 {
        let mut bytes = Vec::new();
        for _ in 0..(round % 13 + 1) {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            // Mostly flags and hex digits, so the scanner gets deep into frames.
            let pool = b"\x7E\x7F0123456789ABCDEFabcdef8155GZ\x00\xFF";
            bytes.push(pool[(x as usize) % pool.len()]);
        }
        let now = line.now();
        line.master_write(now, &bytes);
        run_until_idle(&mut line);
    }
    let mut junk = Vec::new();
    line.master_read(&mut junk);
    // A stray 7E left a frame open: the next 7E starts a new one.
    assert_reply(&mut line, V1, "7E 30 31 37 36 30 31 30 30 37 30 7F");
}
