//! The FC profile against the simulated Danfoss FC drive on a paced virtual line, on simulated
//! time: every operation run to completion, refusals, range checks, parameters, broadcast.

mod support;

use std::time::Duration;

use drivebus_drive::profile::danfoss::{DanfossProfile, ReferenceRange};
use drivebus_drive::profile::{CodeSpace, DriveError, DriveStatus, Operation, Outcome, Plan, Profile, Step};
use drivebus_drive::Storage;
use drivebus_proto::fc::{AddressFormat, ControlWord, FcScanner};
use drivebus_proto::line::CharFormat;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::family::danfoss::DanfossDrive;
use drivebus_sim::model::{Rotation, RunState, Trip};
use support::{model, refusal, wait, write};

/// How long the helper waits for a reply: the FC response timeout, 50 ms.
const TIMEOUT: Duration = Duration::from_millis(50);
/// The wait after a broadcast (protocols.md 2.9 / proto's BROADCAST_TURNAROUND).
const TURNAROUND: Duration = Duration::from_millis(20);

/// A 9600 baud 8E1 line with one FC drive per address; ports 1, 2, ... in that order.
fn line_with(addresses: &[u8]) -> VirtualLine {
    support::line_with(9600, CharFormat::EVEN_8E1, addresses, DanfossDrive::new)
}

/// Writes `request` and runs the line until a whole telegram has come back (or the timeout);
/// two characters of silence after it (protocols.md 2.9).
fn transact(line: &mut VirtualLine, request: &[u8], expect_reply: bool) -> Option<Vec<u8>> {
    support::transact_frame(line, FcScanner, request, expect_reply, (2, TIMEOUT, TURNAROUND))
}

/// Runs a plan to its end; the outcome and the number of telegrams sent.
fn execute(line: &mut VirtualLine, plan: Box<dyn Plan>) -> (Result<Outcome, DriveError>, usize) {
    let (outcome, sent) = support::execute(plan, |x| transact(line, &x.request, x.expect_reply));
    (outcome, sent.len())
}

/// Runs `op` and expects it to succeed; returns the outcome and the telegram count.
fn run(line: &mut VirtualLine, profile: &DanfossProfile, op: Operation) -> (Outcome, usize) {
    support::run_ok(profile, op, |plan| execute(line, plan))
}

fn status(line: &mut VirtualLine, profile: &DanfossProfile) -> DriveStatus {
    support::status_of("Status", Ok(run(line, profile, Operation::Status).0))
}

fn read(line: &mut VirtualLine, profile: &DanfossProfile, name: &str) -> i64 {
    support::param_of(name, Ok(run(line, profile, Operation::ReadParam(name.to_string())).0))
}

#[test]
fn set_speed_then_run_ramps_and_status_shows_it() {
    let mut line = line_with(&[1]);
    let fc = DanfossProfile::new(1).expect("profile");
    assert_eq!(
        (fc.family(), fc.protocol(), fc.address()),
        (drivebus_drive::Family::Danfoss, drivebus_proto::protocol::WireProtocol::DanfossFc, 1)
    );

    // The first set speed reads 3-00, 3-02, 3-03, 4-14, 16-02 (the reference held) and 16-00
    // (0000: never commanded), then sends stop 043C with the reference of 40 Hz: the drive
    // keeps still and holds it.
    let (outcome, sent) = run(&mut line, &fc, Operation::SetSpeed(40.0));
    assert_eq!((outcome, sent), (Outcome::Done, 7));
    assert_eq!(fc.reference_range(), Some(ReferenceRange::catalog_defaults()));
    assert_eq!(fc.last_command().map(|(c, r)| (c.0, r.0)), Some((0x043C, 0x3333)));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
    assert!((model(&mut line, 1).setpoint_hz() - 40.0).abs() < 0.01);

    // Run is one telegram now: 047C with the same reference.
    assert_eq!(run(&mut line, &fc, Operation::Run), (Outcome::Done, 1));
    assert_eq!(model(&mut line, 1).state(), RunState::Running);

    // 3-41 = 3 s from 0 to 50 Hz: about 16.7 Hz after a second. The first status reads 16-14
    // only: the scale is known.
    wait(&mut line, Duration::from_secs(1));
    let (outcome, sent) = run(&mut line, &fc, Operation::Status);
    assert_eq!(sent, 1);
    let Outcome::Status(s) = outcome else { panic!("{outcome:?}") };
    assert!(s.running && s.fault.is_none(), "{s:?}");
    assert_eq!((s.address, s.direction.as_deref(), s.setpoint_hz), (1, Some("forward"), Some(40.0)));
    let early = s.output_hz.expect("output");
    assert!((10.0..25.0).contains(&early), "{early} Hz after 1 s");
    assert!(s.current_a.expect("current") > 0.0);

    wait(&mut line, Duration::from_secs(1));
    let later = status(&mut line, &fc).output_hz.expect("output");
    assert!(later > early + 10.0, "{early} -> {later}: the output ramps");
    wait(&mut line, Duration::from_secs(2));
    let s = status(&mut line, &fc);
    assert!((s.output_hz.expect("output") - 40.0).abs() < 0.01, "{s:?}");

    // A set speed while running repeats the start: the drive keeps running toward 25 Hz.
    assert_eq!(run(&mut line, &fc, Operation::SetSpeed(25.0)), (Outcome::Done, 1));
    assert_eq!(model(&mut line, 1).state(), RunState::Running);
    assert!((model(&mut line, 1).setpoint_hz() - 25.0).abs() < 0.01);

    // Stop ramps down: 25 Hz takes 1.5 s at 3 s per 50 Hz.
    assert_eq!(run(&mut line, &fc, Operation::Stop), (Outcome::Done, 1));
    assert_eq!(fc.last_command().map(|(c, _)| c.0), Some(0x043C));
    wait(&mut line, Duration::from_secs(3));
    let s = status(&mut line, &fc);
    assert!(!s.running && s.output_hz == Some(0.0), "{s:?}");
}

#[test]
fn first_status_reads_the_scale_then_one_telegram() {
    let mut line = line_with(&[7]);
    let fc = DanfossProfile::new(7).expect("profile");
    let (outcome, sent) = run(&mut line, &fc, Operation::Status);
    // 3-00, 3-02, 3-03, 16-02 (nothing commanded yet: the reference the drive holds), 16-14.
    assert_eq!(sent, 5);
    let Outcome::Status(s) = outcome else { panic!("{outcome:?}") };
    assert_eq!(
        s,
        DriveStatus {
            address: 7,
            running: false,
            direction: None,
            output_hz: Some(0.0),
            setpoint_hz: Some(0.0),
            current_a: Some(0.0),
            fault: None,
            values: Vec::new()
        }
    );
    // The setpoint is known now: one telegram per status.
    assert_eq!(run(&mut line, &fc, Operation::Status).1, 1);
    // 4-14 is read before the first set speed only.
    assert_eq!(fc.reference_range(), None);
}

#[test]
fn status_and_parameter_telegrams_do_not_change_the_drive() {
    let mut line = line_with(&[1]);
    let fc = DanfossProfile::new(1).expect("profile");
    run(&mut line, &fc, Operation::SetSpeed(30.0));
    run(&mut line, &fc, Operation::Run);
    // 16-00 shows the control word the drive acted on last: the start, not the reads' words.
    assert_eq!(read(&mut line, &fc, "16-00"), 0x047C);
    status(&mut line, &fc);
    run(&mut line, &fc, write("3-41", 200, Storage::Ram));
    assert_eq!(read(&mut line, &fc, "16-00"), 0x047C);
    assert_eq!(model(&mut line, 1).state(), RunState::Running);
    assert!((model(&mut line, 1).setpoint_hz() - 30.0).abs() < 0.01);
}

#[test]
fn reverse_and_jog() {
    let mut line = line_with(&[3]);
    let fc = DanfossProfile::new(3).expect("profile");
    run(&mut line, &fc, Operation::SetSpeed(20.0));
    run(&mut line, &fc, Operation::Run);
    wait(&mut line, Duration::from_secs(2));
    assert_eq!(run(&mut line, &fc, Operation::Reverse), (Outcome::Done, 1));
    assert_eq!(fc.last_command().map(|(c, _)| c.0), Some(0x847C));
    assert_eq!(model(&mut line, 1).rotation(), Rotation::Reverse);
    // Through zero and up to 20 Hz the other way: 1.2 s down, 1.2 s up.
    wait(&mut line, Duration::from_secs(3));
    let s = status(&mut line, &fc);
    assert_eq!(s.direction.as_deref(), Some("reverse"), "{s:?}");
    assert!((s.output_hz.expect("output") - 20.0).abs() < 0.01, "{s:?}");

    // Stop keeps the direction; Reverse on a stopped drive only turns it for the next run.
    run(&mut line, &fc, Operation::Stop);
    assert_eq!(fc.last_command().map(|(c, _)| c.0), Some(0x843C));
    run(&mut line, &fc, Operation::Reverse);
    assert_eq!(fc.last_command().map(|(c, _)| c.0), Some(0x043C));
    wait(&mut line, Duration::from_secs(2));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);

    // Jog: bit 08, 057C, at 3-19 = 150 rpm = 5 Hz with the 4-pole default motor.
    assert_eq!(run(&mut line, &fc, Operation::Jog), (Outcome::Done, 1));
    assert_eq!(fc.last_command().map(|(c, _)| c.0), Some(0x057C));
    assert!(model(&mut line, 1).is_jogging());
    wait(&mut line, Duration::from_secs(1));
    let s = status(&mut line, &fc);
    assert!(s.running && (s.output_hz.expect("output") - 5.0).abs() < 0.01, "{s:?}");
    run(&mut line, &fc, Operation::Stop);
    wait(&mut line, Duration::from_secs(1));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
}

#[test]
fn a_new_profile_reads_the_drives_control_word_before_commanding() {
    let mut line = line_with(&[2]);
    let first = DanfossProfile::new(2).expect("profile");
    run(&mut line, &first, Operation::SetSpeed(30.0));
    run(&mut line, &first, Operation::Run);
    run(&mut line, &first, Operation::Reverse);
    wait(&mut line, Duration::from_secs(3));

    // Another profile (another program) sets the speed: after the scale it reads 16-02 (the
    // reference held) and 16-00 = 847C, and keeps the drive started in reverse.
    let second = DanfossProfile::new(2).expect("profile");
    assert_eq!(run(&mut line, &second, Operation::SetSpeed(20.0)), (Outcome::Done, 7));
    assert_eq!(second.last_command().map(|(c, _)| c.0), Some(0x847C));
    let m = model(&mut line, 1);
    assert_eq!((m.state(), m.rotation()), (RunState::Running, Rotation::Reverse));
    assert!((m.setpoint_hz() - 20.0).abs() < 0.01);

    // A third one runs: the drive holds a start, so nothing is sent after 16-02 and 16-00 (a
    // start is already in force).
    let third = DanfossProfile::new(2).expect("profile");
    assert_eq!(run(&mut line, &third, Operation::Run), (Outcome::Done, 2));
    assert_eq!(third.last_command(), None);
    assert!((model(&mut line, 1).setpoint_hz() - 20.0).abs() < 0.01);
    // Its reverse keeps the reference the drive holds (read from 16-02) and turns the motor.
    let (result, sent) = execute(&mut line, third.plan(&Operation::Reverse).expect("plan"));
    assert_eq!(result, Ok(Outcome::Done));
    assert_eq!(sent, 3);
    assert_eq!(model(&mut line, 1).rotation(), Rotation::Forward);
    assert!((model(&mut line, 1).setpoint_hz() - 20.0).abs() < 0.01);
    run(&mut line, &third, Operation::Reverse);
    assert_eq!(model(&mut line, 1).rotation(), Rotation::Reverse);

    // Stopped, a fresh profile's reverse turns the direction the drive holds (843C -> 043C).
    run(&mut line, &second, Operation::Stop);
    wait(&mut line, Duration::from_secs(2));
    let fourth = DanfossProfile::new(2).expect("profile");
    assert_eq!(run(&mut line, &fourth, Operation::Reverse), (Outcome::Done, 3));
    assert_eq!(fourth.last_command().map(|(c, _)| c.0), Some(0x043C));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
}

#[test]
fn run_while_tripped_is_refused_with_the_alarm_and_reset_clears_it() {
    let mut line = line_with(&[1]);
    let fc = DanfossProfile::new(1).expect("profile");
    run(&mut line, &fc, Operation::SetSpeed(30.0));
    run(&mut line, &fc, Operation::Run);
    wait(&mut line, Duration::from_secs(1));
    line.drive_mut(1).expect("drive").core_mut().model.trip_now(Trip::OverCurrent);

    // Status: trip bit 03 and alarm 13 from 15-30 [0] (one more telegram).
    let (outcome, sent) = run(&mut line, &fc, Operation::Status);
    assert_eq!(sent, 2);
    let Outcome::Status(s) = outcome else { panic!("{outcome:?}") };
    assert!(!s.running);
    let fault = s.fault.expect("a fault");
    assert_eq!((fault.code, fault.text.as_str()), (13, "over current"));

    // Run: the start telegram, then 15-30 for the alarm number.
    let (result, sent) = execute(&mut line, fc.plan(&Operation::Run).expect("plan"));
    assert_eq!(sent, 2);
    let (code, meaning) = refusal(result);
    assert_eq!(code, 13);
    assert_eq!(meaning, "the drive is tripped: reset it first (alarm 13: over current)");
    let (result, _) = execute(&mut line, fc.plan(&Operation::Jog).expect("plan"));
    assert_eq!(refusal(result).0, 13);

    // Reset: stop 043C, then 04BC (the 0->1 edge of bit 07). The drive is left stopped.
    assert_eq!(run(&mut line, &fc, Operation::Reset), (Outcome::Done, 2));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
    assert_eq!(fc.last_command().map(|(c, _)| c.0), Some(0x043C));
    assert_eq!(status(&mut line, &fc).fault, None);
    run(&mut line, &fc, Operation::Run);
    assert_eq!(model(&mut line, 1).state(), RunState::Running);
}

#[test]
fn a_reset_that_leaves_the_trip_is_refused() {
    let mut line = line_with(&[1]);
    let fc = DanfossProfile::new(1).expect("profile");
    {
        let m = &mut line.drive_mut(1).expect("drive").core_mut().model;
        m.set_supply(0.5);
        m.trip_now(Trip::UnderVoltage);
    }
    // A fresh profile: 16-02 and 16-00 first, then the two reset telegrams and 15-30.
    let (result, sent) = execute(&mut line, fc.plan(&Operation::Reset).expect("plan"));
    assert_eq!(sent, 5);
    let (code, meaning) = refusal(result);
    assert_eq!(code, 8);
    assert!(meaning.contains("DC under voltage"), "{meaning}");
}

#[test]
fn commands_without_bus_control_are_refused() {
    let mut line = line_with(&[1]);
    let fc = DanfossProfile::new(1).expect("profile");
    // 8-01 Control Site = digital only: the drive ignores the control word (status bit 09 = 0).
    run(&mut line, &fc, write("8-01", 1, Storage::Ram));
    let (result, _) = execute(&mut line, fc.plan(&Operation::Run).expect("plan"));
    let (code, meaning) = refusal(result);
    assert_eq!(code & 0x0200, 0);
    assert!(meaning.contains("bit 09"), "{meaning}");
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
    assert_eq!(fc.last_command(), None, "a command the drive ignored is not remembered");
}

#[test]
fn set_speed_out_of_range_is_refused_before_anything_is_sent() {
    let mut line = line_with(&[1]);
    let fc = DanfossProfile::new(1).expect("profile");
    for (hz, message) in [
        (-1.0, "-1 Hz is below 0 Hz: give the direction with Reverse"),
        (600.0, "600 Hz is above 500.0 Hz, the highest 4-14 Motor Speed High Limit an FC drive takes"),
        (f64::NAN, "NaN is not a speed"),
    ] {
        assert_eq!(
            fc.plan(&Operation::SetSpeed(hz)).err(),
            Some(DriveError::OutOfRange(message.to_string()))
        );
    }
    assert_eq!(line.stats().master_bytes, 0);

    // Unknown limits: the reads go out (the scale, 16-02 and 16-00), the command does not.
    let (result, sent) = execute(&mut line, fc.plan(&Operation::SetSpeed(55.0)).expect("plan"));
    assert_eq!(sent, 6);
    assert_eq!(
        result,
        Err(DriveError::OutOfRange("55 Hz is above the maximum reference 3-03 = 50.000 Hz".to_string()))
    );
    assert_eq!(fc.last_command(), None);
    // Known limits: refused before any byte.
    let before = line.stats().master_bytes;
    assert!(matches!(fc.plan(&Operation::SetSpeed(50.5)), Err(DriveError::OutOfRange(_))));
    assert_eq!(line.stats().master_bytes, before);

    // 3-03 = 60 Hz written through the profile: 55 Hz is fine now; 4-14 = 65 Hz still bounds.
    run(&mut line, &fc, write("3-03", 60_000, Storage::Ram));
    // The profile has commanded nothing yet: reads of 16-02 and 16-00 (the reference and the
    // control word the drive holds) first.
    assert_eq!(run(&mut line, &fc, Operation::SetSpeed(55.0)), (Outcome::Done, 3));
    assert!((model(&mut line, 1).setpoint_hz() - 55.0).abs() < 0.01);
    run(&mut line, &fc, write("4-14", 500, Storage::Ram));
    assert_eq!(
        fc.plan(&Operation::SetSpeed(55.0)).err(),
        Some(DriveError::OutOfRange("55 Hz is above the motor speed high limit 4-14 = 50.0 Hz".to_string()))
    );
}

#[test]
fn parameters_round_trip_in_ram_and_eeprom() {
    let mut line = line_with(&[5]);
    let fc = DanfossProfile::new(5).expect("profile");
    let eeprom = |line: &mut VirtualLine, name: &str| {
        line.drive(1).expect("drive").core().params.eeprom_writes(name).expect("known")
    };
    // Double word 3-41 (AK 3 RAM, AK D EEPROM), word 4-14 (AK 2 / E).
    assert_eq!(read(&mut line, &fc, "3-41"), 300);
    assert_eq!(run(&mut line, &fc, write("3-41", 1250, Storage::Ram)), (Outcome::Done, 1));
    assert_eq!(read(&mut line, &fc, "3-41"), 1250);
    assert_eq!(eeprom(&mut line, "3-41"), 0);
    run(&mut line, &fc, write("3-41", 800, Storage::Eeprom));
    assert_eq!(read(&mut line, &fc, "341"), 800);
    assert_eq!(eeprom(&mut line, "3-41"), 1);
    run(&mut line, &fc, write("4-14", 600, Storage::Eeprom));
    assert_eq!(read(&mut line, &fc, "4-14"), 600);
    assert_eq!(eeprom(&mut line, "4-14"), 1);
    // Signed double word: 3-02 = -5.000 Hz.
    run(&mut line, &fc, write("3-02", -5000, Storage::Ram));
    assert_eq!(read(&mut line, &fc, "3-02"), -5000);
    // 15-30 Alarm Log, element 1 of 10.
    line.drive_mut(1).expect("drive").core_mut().model.trip_now(Trip::External);
    assert_eq!(read(&mut line, &fc, "15-30[0]"), 60);
    assert_eq!(read(&mut line, &fc, "15-30[1]"), 0);
    assert_eq!(fc.param("8-32").map(|p| p.title.as_str()), Ok("Baud Rate"));
}

#[test]
fn parameter_refusals() {
    let mut line = line_with(&[1]);
    let fc = DanfossProfile::new(1).expect("profile");
    let plan_err = |op: Operation| fc.plan(&op).err();
    assert_eq!(
        plan_err(Operation::ReadParam("99-99".into())),
        Some(DriveError::Unsupported("the FC catalog has no parameter \"99-99\"".into()))
    );
    assert_eq!(
        plan_err(write("16-14", 1, Storage::Ram)),
        Some(DriveError::Unsupported(
            "16-14 Motor current is read-only: the drive refuses every write".into()
        ))
    );
    assert_eq!(
        plan_err(write("4-14", 6000, Storage::Ram)),
        Some(DriveError::OutOfRange("4-14 is 0.0..500.0 Hz, 600.0 is out of range".into()))
    );
    assert_eq!(
        plan_err(Operation::ReadParam("15-30[10]".into())),
        Some(DriveError::OutOfRange(
            "15-30 Alarm Log: Error Code is an array of 10 (index 0..9): there is no element 10".into()
        ))
    );
    assert!(matches!(plan_err(Operation::ReadParam("4-14[x]".into())), Some(DriveError::Unsupported(_))));
    assert_eq!(line.stats().master_bytes, 0);

    // AK 7 from the drive: 1-23 Motor Frequency cannot change while running (fault 17).
    run(&mut line, &fc, Operation::SetSpeed(10.0));
    run(&mut line, &fc, Operation::Run);
    let (result, _) = execute(&mut line, fc.plan(&write("1-23", 60, Storage::Ram)).expect("plan"));
    assert_eq!(
        result,
        Err(DriveError::Refused { code: 17, space: CodeSpace::FcFault, meaning: "not while running".into() })
    );
    // And fault 2 from the drive's own check: 8-31 above 126 with the FC protocol.
    let (result, _) = execute(&mut line, fc.plan(&write("8-31", 200, Storage::Ram)).expect("plan"));
    assert_eq!(
        result,
        Err(DriveError::Refused {
            code: 2,
            space: CodeSpace::FcFault,
            meaning: "upper or lower limit exceeded".into()
        })
    );
}

#[test]
fn broadcast_commands_reach_every_drive_and_ask_for_no_reply() {
    let mut line = line_with(&[1, 2]);
    let all = DanfossProfile::new(0).expect("profile");
    assert_eq!(all.address(), 0);
    assert_eq!(all.reference_range(), Some(ReferenceRange::catalog_defaults()));
    assert!(matches!(all.plan(&Operation::Status), Err(DriveError::Unsupported(_))));
    assert!(matches!(all.plan(&Operation::ReadParam("4-14".into())), Err(DriveError::Unsupported(_))));
    assert!(matches!(all.plan(&Operation::SetSpeed(10.0)), Err(DriveError::Unsupported(_))));
    assert!(matches!(all.plan(&Operation::Reverse), Err(DriveError::Unsupported(_))));

    let mut plan = all.plan(&Operation::Run).expect("plan");
    let Ok(Step::Send(x)) = plan.step(None) else { panic!("a telegram") };
    assert!(!x.expect_reply);
    assert_eq!(x.request[..7], [0x02, 0x06, 0x80, 0x04, 0x7C, 0x00, 0x00]);
    transact(&mut line, &x.request, false);
    assert_eq!(plan.step(None), Ok(Step::Done(Outcome::Done)));
    assert_eq!(line.stats().device_bytes, 0);
    assert_eq!(model(&mut line, 1).state(), RunState::Running);
    assert_eq!(model(&mut line, 2).state(), RunState::Running);

    // Set speed with the catalog's scale (3-03 = 50 Hz), and a parameter write.
    assert_eq!(run(&mut line, &all, Operation::SetSpeed(25.0)), (Outcome::Done, 1));
    assert_eq!(run(&mut line, &all, write("3-42", 150, Storage::Ram)), (Outcome::Done, 1));
    for port in [1, 2] {
        assert!((model(&mut line, port).setpoint_hz() - 25.0).abs() < 0.01);
        assert_eq!(line.drive(port).expect("drive").core().params.get("3-42"), Some(150));
    }
    run(&mut line, &all, Operation::Stop);
    wait(&mut line, Duration::from_secs(2));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
    assert_eq!(line.stats().device_bytes, 0);
}

#[test]
fn address_format_1_to_31() {
    let mut line = line_with(&[22]);
    let fc = DanfossProfile::with_address_format(22, AddressFormat::OneTo31).expect("profile");
    let mut plan = fc.plan(&Operation::Stop).expect("plan");
    let mut reply = None;
    let mut sent = 0;
    // A fresh profile's stop: 16-02, 16-00, then the stop; every one to ADR 16.
    while let Ok(Step::Send(x)) = plan.step(reply.as_deref()) {
        // protocols.md 2.3: address 22 in format 1-31 is ADR 16.
        assert_eq!(x.request[2], 0x16);
        reply = transact(&mut line, &x.request, true);
        sent += 1;
    }
    assert_eq!(sent, 3);
    assert_eq!(fc.last_command().map(|(c, _)| c.0), Some(0x043C));
    assert!(DanfossProfile::with_address_format(32, AddressFormat::OneTo31).is_err());
    assert_eq!(
        DanfossProfile::new(127).err(),
        Some(DriveError::OutOfRange(
            "an FC drive address is 1 to 126 in address format 1–126 (0 for broadcast), not 127".into()
        ))
    );
}

#[test]
fn malformed_or_missing_replies_are_protocol_errors() {
    let fc = DanfossProfile::new(1).expect("profile");
    let first = |fc: &DanfossProfile, op: &Operation| {
        let mut plan = fc.plan(op).expect("plan");
        let Ok(Step::Send(_)) = plan.step(None) else { panic!("a telegram") };
        plan
    };
    let mut plan = first(&fc, &Operation::Stop);
    assert!(matches!(plan.step(Some(&[0x02, 0x06, 0x81])), Err(DriveError::Protocol(_))));
    let mut plan = first(&fc, &Operation::Stop);
    assert_eq!(plan.step(None), Err(DriveError::Protocol("drive 1 did not answer".into())));
    // A reply from another ADR: 02 06 82 0603 0000 BCC.
    let mut plan = first(&fc, &Operation::Stop);
    let other = [0x02, 0x06, 0x82, 0x06, 0x03, 0x00, 0x00, 0x02 ^ 0x06 ^ 0x82 ^ 0x06 ^ 0x03];
    assert_eq!(
        plan.step(Some(&other)),
        Err(DriveError::Protocol("the reply carries ADR 82, the request 81".into()))
    );
    // A process block answering a parameter read.
    let mut plan = first(&fc, &Operation::ReadParam("4-14".into()));
    let process = [0x02, 0x06, 0x81, 0x06, 0x03, 0x00, 0x00, 0x02 ^ 0x06 ^ 0x81 ^ 0x06 ^ 0x03];
    assert!(matches!(plan.step(Some(&process)), Err(DriveError::Protocol(_))));
    assert_eq!(ControlWord::START.0, 0x047C);
}

/// A profile made after another one set the speed (another `drivebus` run) keeps that speed:
/// it reads the reference the drive holds (16-02) before its first command.
#[test]
fn a_fresh_profile_keeps_the_reference_the_drive_holds() {
    let mut line = line_with(&[4]);
    let first = DanfossProfile::new(4).expect("profile");
    run(&mut line, &first, Operation::SetSpeed(30.0));
    let second = DanfossProfile::new(4).expect("profile");
    run(&mut line, &second, Operation::Run);
    wait(&mut line, Duration::from_secs(20));
    let m = model(&mut line, 1);
    assert_eq!(m.state(), RunState::Running);
    assert!((m.output_hz() - 30.0).abs() < 0.05, "{} Hz", m.output_hz());
}

#[test]
fn a_fresh_profile_reads_the_setpoint_the_drive_holds() {
    let mut line = line_with(&[7]);
    let first = DanfossProfile::new(7).expect("profile");
    assert_eq!(run(&mut line, &first, Operation::SetSpeed(30.0)).0, Outcome::Done);
    // Another program, which has commanded nothing, reads the drive's reference (16-02).
    let fresh = DanfossProfile::new(7).expect("profile");
    let s = status(&mut line, &fresh);
    assert_eq!(s.setpoint_hz, Some(30.0), "{s:?}");
}

/// `speed 30; run; stop; run`, each from a fresh profile (a separate process): every command
/// carries the reference the drive holds, so the last run reaches 30 Hz, not 0 Hz.
#[test]
fn stop_then_run_from_fresh_profiles_keeps_the_speed() {
    let mut line = line_with(&[4]);
    for op in [Operation::SetSpeed(30.0), Operation::Run, Operation::Stop] {
        run(&mut line, &DanfossProfile::new(4).expect("profile"), op);
        wait(&mut line, Duration::from_secs(1));
    }
    assert!((model(&mut line, 1).setpoint_hz() - 30.0).abs() < 0.01, "the stop kept the reference");
    wait(&mut line, Duration::from_secs(20));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
    run(&mut line, &DanfossProfile::new(4).expect("profile"), Operation::Run);
    wait(&mut line, Duration::from_secs(20));
    let m = model(&mut line, 1);
    assert_eq!(m.state(), RunState::Running);
    assert!((m.output_hz() - 30.0).abs() < 0.05, "{} Hz", m.output_hz());
}

/// A fresh profile's run to a tripped drive whose last control word holds a start sends no
/// start (one is in force) and is still refused, with the alarm, as any run to a tripped drive.
#[test]
fn a_fresh_run_to_a_tripped_drive_holding_a_start_is_refused() {
    let mut line = line_with(&[1]);
    let first = DanfossProfile::new(1).expect("profile");
    run(&mut line, &first, Operation::SetSpeed(30.0));
    run(&mut line, &first, Operation::Run);
    wait(&mut line, Duration::from_secs(1));
    line.drive_mut(1).expect("drive").core_mut().model.trip_now(Trip::OverCurrent);
    let fresh = DanfossProfile::new(1).expect("profile");
    let (result, sent) = execute(&mut line, fresh.plan(&Operation::Run).expect("plan"));
    let (code, meaning) = refusal(result);
    assert_eq!(code, 13);
    assert_eq!(meaning, "the drive is tripped: reset it first (alarm 13: over current)");
    // 16-02, 16-00 (its reply's status word shows the trip), 15-30 [0].
    assert_eq!(sent, 3);
}

/// A fresh profile's run to a drive that holds a start but no longer takes the bus control word
/// (8-01 Control Site changed on the panel) is refused, not "done".
#[test]
fn a_fresh_run_to_a_drive_without_bus_control_is_refused() {
    let mut line = line_with(&[1]);
    let first = DanfossProfile::new(1).expect("profile");
    run(&mut line, &first, Operation::SetSpeed(30.0));
    run(&mut line, &first, Operation::Run);
    run(&mut line, &first, write("8-01", 1, Storage::Ram));
    let fresh = DanfossProfile::new(1).expect("profile");
    let (result, _) = execute(&mut line, fresh.plan(&Operation::Run).expect("plan"));
    let (code, meaning) = refusal(result);
    assert_eq!(code & 0x0200, 0);
    assert!(meaning.contains("bit 09"), "{meaning}");
}

/// After `refresh_setup` the next status reads 3-00, 3-02 and 3-03 again, and 16-02 once a
/// setpoint was commanded (for a standby listening: the setpoint stays the commanded one); the
/// one after is one telegram again. Prints what a refresh adds on the wire.
#[test]
fn a_refresh_reads_the_scale_and_the_reference_once_more() {
    let mut line = line_with(&[3]);
    let fc = DanfossProfile::new(3).expect("profile");
    let bytes = |line: &VirtualLine| line.stats().master_bytes + line.stats().device_bytes;
    status(&mut line, &fc);
    // Nothing commanded: the refresh reads the scale, and the setpoint from 16-02 again (set
    // meanwhile by another master).
    let other = DanfossProfile::new(3).expect("profile");
    run(&mut line, &other, Operation::SetSpeed(20.0));
    assert_eq!(status(&mut line, &fc).setpoint_hz, Some(0.0));
    fc.refresh_setup();
    let (Outcome::Status(s), sent) = run(&mut line, &fc, Operation::Status) else { panic!() };
    assert_eq!(sent, 5, "3-00, 3-02, 3-03, 16-02, 16-14");
    assert_eq!(s.setpoint_hz, Some(20.0));
    run(&mut line, &fc, Operation::SetSpeed(30.0));
    run(&mut line, &fc, Operation::Run);
    wait(&mut line, Duration::from_secs(3));
    let at = bytes(&line);
    let (before, sent) = run(&mut line, &fc, Operation::Status);
    let each = bytes(&line) - at;
    assert_eq!(sent, 1);
    fc.refresh_setup();
    let at = bytes(&line);
    let (refreshed, sent) = run(&mut line, &fc, Operation::Status);
    let with_refresh = bytes(&line) - at;
    assert_eq!(sent, 5, "3-00, 3-02, 3-03, 16-02, 16-14");
    assert_eq!(refreshed, before);
    let Outcome::Status(s) = refreshed else { panic!() };
    assert_eq!(s.setpoint_hz, Some(30.0), "the commanded setpoint");
    assert_eq!(run(&mut line, &fc, Operation::Status).1, 1);
    println!("danfoss-fc: a refresh adds {} bytes on the wire", with_refresh - each);
    // A broadcast profile has nothing to read.
    let all = DanfossProfile::new(0).expect("profile");
    all.refresh_setup();
    assert!(all.plan(&Operation::Status).is_err());
}

/// A drive that refuses 16-02 (AK 7) to a refresh of a profile that has commanded a setpoint
/// still gives its status: that read was only for a standby listening.
#[test]
fn a_refresh_whose_reference_read_is_refused_still_gives_the_status() {
    use drivebus_proto::fc::{Adr, FaultCode, ParameterNumber, Reply, Request, MAX_TELEGRAM};
    let mut line = line_with(&[2]);
    let fc = DanfossProfile::new(2).expect("profile");
    run(&mut line, &fc, Operation::SetSpeed(30.0));
    run(&mut line, &fc, Operation::Run);
    wait(&mut line, Duration::from_secs(3));
    let before = status(&mut line, &fc);
    fc.refresh_setup();
    let adr = Adr::new(2, AddressFormat::OneTo126).unwrap();
    let mut refused = 0;
    let (outcome, sent) = support::execute(fc.plan(&Operation::Status).unwrap(), |x| {
        let reads_1602 = matches!(
            Request::parse(&x.request).map(|r| r.block),
            Ok(drivebus_proto::fc::Block::Parameter(q)) if q.pnu.pnu() == 1602
        );
        if !reads_1602 {
            return transact(&mut line, &x.request, x.expect_reply);
        }
        refused += 1;
        let mut out = [0u8; MAX_TELEGRAM];
        let n =
            Reply::fault(adr, ParameterNumber::new(1602).unwrap(), 0, FaultCode(0)).emit(&mut out).unwrap();
        Some(out[..n].to_vec())
    });
    assert_eq!((refused, sent.len()), (1, 5), "3-00, 3-02, 3-03, 16-02 refused, 16-14");
    let Ok(Outcome::Status(s)) = outcome else { panic!("{outcome:?}") };
    assert_eq!((s.running, s.setpoint_hz, s.output_hz), (before.running, Some(30.0), before.output_hz));
}
