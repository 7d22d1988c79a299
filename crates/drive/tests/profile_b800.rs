//! The B800 profile against the simulated B800 drive on a paced virtual line, on simulated
//! time: every operation run to completion, the seed's error codes as refusals, range checks,
//! the global address.

mod support;

use std::time::Duration;

use drivebus_drive::profile::b800::B800Profile;
use drivebus_drive::profile::{
    CodeSpace, DriveError, DriveStatus, Fault, Operation, Outcome, Plan, Profile, Step,
};
use drivebus_drive::{Family, Storage};
use drivebus_proto::b800::FrameScanner;
use drivebus_proto::line::CharFormat;
use drivebus_proto::Direction;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::family::b800::B800Drive;
use drivebus_sim::model::{Rotation, RunState, Trip};
use support::{model, model_mut, wait};

/// The master's response timeout (project decision: 100 ms).
const TIMEOUT: Duration = Duration::from_millis(100);

/// A 9600 bps 8N1 line with one B800 per address; ports 1, 2, ... in that order.
fn line_with(addresses: &[u8]) -> VirtualLine {
    support::line_with(9600, CharFormat::NONE_8N1, addresses, B800Drive::new)
}

/// Writes `request` and runs the line until a whole frame has come back (or the timeout); one
/// character of silence after it. No reply to a global frame: a response time's wait.
fn transact(line: &mut VirtualLine, request: &[u8], expect_reply: bool) -> Option<Vec<u8>> {
    let scanner = FrameScanner::new(Some(Direction::Drive));
    support::transact_frame(line, scanner, request, expect_reply, (1, TIMEOUT, TIMEOUT))
}

/// Runs a plan to its end; the outcome and the frames sent, as text.
fn execute(line: &mut VirtualLine, plan: Box<dyn Plan>) -> (Result<Outcome, DriveError>, Vec<String>) {
    let (outcome, sent) = support::execute(plan, |x| transact(line, &x.request, x.expect_reply));
    let text = sent.iter().map(|r| String::from_utf8_lossy(&r[1..r.len() - 1]).into_owned()).collect();
    (outcome, text)
}

/// The command letters of frames to drive 1 (DA 81): "81540D" -> 'T'.
fn letters(frames: &[String]) -> String {
    frames.iter().map(|f| u8::from_str_radix(&f[2..4], 16).map_or('?', char::from)).collect()
}

/// Runs `op`, expecting success; the outcome and the command letters sent.
fn run(line: &mut VirtualLine, profile: &B800Profile, op: Operation) -> (Outcome, String) {
    let (outcome, sent) = support::run_ok(profile, op, |plan| execute(line, plan));
    (outcome, letters(&sent))
}

/// Runs `op`, expecting an error; the error and the command letters sent.
fn fail(line: &mut VirtualLine, profile: &B800Profile, op: Operation) -> (DriveError, String) {
    let plan = profile.plan(&op).unwrap_or_else(|e| panic!("{op:?}: {e}"));
    match execute(line, plan) {
        (Err(e), sent) => (e, letters(&sent)),
        (Ok(outcome), _) => panic!("{op:?}: {outcome:?}"),
    }
}

fn status(line: &mut VirtualLine, profile: &B800Profile) -> DriveStatus {
    support::status_of("Status", Ok(run(line, profile, Operation::Status).0))
}

fn set_f12(line: &mut VirtualLine, port: usize, value: i64) {
    let params = &mut line.drive_mut(port).expect("a drive").core_mut().params;
    params.set("F-12", value, Storage::Ram, false).expect("F-12 takes 0..2");
}

fn refused(code: u32, meaning: &str) -> DriveError {
    DriveError::Refused { code, space: CodeSpace::B800Error, meaning: meaning.to_string() }
}

#[test]
fn set_speed_then_run_ramps_and_status_shows_it() {
    let mut line = line_with(&[1]);
    let b = B800Profile::new(1).expect("profile");
    assert_eq!(
        (b.family(), b.protocol(), b.address()),
        (Family::B800, drivebus_proto::protocol::WireProtocol::B800, 1)
    );

    // P: 40 Hz as 60 x Hz = 0960; the stopped drive takes the keypad setpoint.
    assert_eq!(run(&mut line, &b, Operation::SetSpeed(40.0)), (Outcome::Done, "P".into()));
    assert!((model(&mut line, 1).setpoint_hz() - 40.0).abs() < 0.02);
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
    // A stopped drive's status is one T: the output is off.
    assert_eq!(
        run(&mut line, &b, Operation::Status),
        (
            Outcome::Status(DriveStatus {
                address: 1,
                running: false,
                direction: None,
                output_hz: Some(0.0),
                setpoint_hz: Some(40.0),
                current_a: Some(0.0),
                fault: None,
                values: Vec::new()
            }),
            "T".into()
        )
    );

    // Run: T, then R.
    assert_eq!(run(&mut line, &b, Operation::Run), (Outcome::Done, "TR".into()));
    // F-03 = 5.0 s from 0 to F-01 = 50 Hz: 10 Hz a second.
    wait(&mut line, Duration::from_secs(1));
    let (outcome, sent) = run(&mut line, &b, Operation::Status);
    assert_eq!(sent, "TZA");
    let Outcome::Status(s) = outcome else { panic!("{outcome:?}") };
    assert!(s.running && s.fault.is_none(), "{s:?}");
    let early = s.output_hz.expect("output");
    assert!((8.0..13.0).contains(&early), "{early} Hz after 1 s");
    assert!(s.current_a.expect("current") > 0.0, "{s:?}");
    wait(&mut line, Duration::from_secs(1));
    let later = status(&mut line, &b).output_hz.expect("output");
    assert!(later > early + 5.0, "{early} -> {later}: the output ramps");
    wait(&mut line, Duration::from_secs(3));
    assert!((status(&mut line, &b).output_hz.expect("output") - 40.0).abs() < 0.02);

    // Run to a running drive sends no R.
    assert_eq!(run(&mut line, &b, Operation::Run), (Outcome::Done, "T".into()));
    // Stop: S; the drive ramps down; a second stop gets e 02 (standby), which is success.
    assert_eq!(run(&mut line, &b, Operation::Stop), (Outcome::Done, "S".into()));
    wait(&mut line, Duration::from_secs(5));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
    assert_eq!(run(&mut line, &b, Operation::Stop), (Outcome::Done, "S".into()));
}

#[test]
fn run_while_tripped_is_refused_and_reset_clears_the_trip() {
    let mut line = line_with(&[1]);
    let b = B800Profile::new(1).expect("profile");
    run(&mut line, &b, Operation::SetSpeed(20.0));
    run(&mut line, &b, Operation::Run);
    wait(&mut line, Duration::from_secs(1));
    model_mut(&mut line, 1).trip_now(Trip::OverCurrent);

    let s = status(&mut line, &b);
    assert!(!s.running);
    assert_eq!(s.fault, Some(Fault { code: 1, text: "over-current".into() }));
    assert_eq!((s.output_hz, s.current_a), (Some(0.0), Some(0.0)));

    assert_eq!(fail(&mut line, &b, Operation::Run), (refused(0x9A, "tripped"), "TR".into()));
    // Reset: T, then S to the tripped drive; a healthy drive gets no S.
    assert_eq!(run(&mut line, &b, Operation::Reset), (Outcome::Done, "TS".into()));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
    assert_eq!(run(&mut line, &b, Operation::Reset), (Outcome::Done, "T".into()));
    assert_eq!(run(&mut line, &b, Operation::Run), (Outcome::Done, "TR".into()));
    assert_eq!(model(&mut line, 1).state(), RunState::Running);
}

#[test]
fn a_persisting_trip_refuses_the_reset() {
    let mut line = line_with(&[1]);
    let b = B800Profile::new(1).expect("profile");
    let m = model_mut(&mut line, 1);
    m.set_supply(0.5);
    m.trip_now(Trip::UnderVoltage);
    assert_eq!(
        fail(&mut line, &b, Operation::Reset),
        (refused(0x9A, "tripped: the trip is still in force after S, its cause persists"), "TS".into())
    );
    assert_eq!(status(&mut line, &b).fault, Some(Fault { code: 3, text: "under-voltage".into() }));
}

#[test]
fn hardware_enable_missing() {
    let mut line = line_with(&[1]);
    let b = B800Profile::new(1).expect("profile");
    model_mut(&mut line, 1).set_hardware_enable(false);
    assert_eq!(
        fail(&mut line, &b, Operation::Run),
        (refused(0x99, "hardware enable not present"), "TR".into())
    );
    let s = status(&mut line, &b);
    assert_eq!(s.fault, Some(Fault { code: 0x99, text: "hardware enable missing".into() }));
}

#[test]
fn reverse_needs_f12_host_run_stop_and_a_running_drive() {
    let mut line = line_with(&[1]);
    let b = B800Profile::new(1).expect("profile");
    // Stopped: no R is sent (it would start the drive).
    let (e, sent) = fail(&mut line, &b, Operation::Reverse);
    assert!(matches!(e, DriveError::Unsupported(ref s) if s.contains("only a running drive")), "{e}");
    assert_eq!(sent, "T");

    // Keypad mode (F-12 = 1, the default): the drive answers e 93.
    run(&mut line, &b, Operation::SetSpeed(20.0));
    run(&mut line, &b, Operation::Run);
    let (e, sent) = fail(&mut line, &b, Operation::Reverse);
    assert!(
        matches!(e, DriveError::Refused { code: 0x93, ref meaning, .. } if meaning.contains("F-12 = 2")),
        "{e}"
    );
    assert_eq!(sent, "TR");
    assert_eq!(model(&mut line, 1).rotation(), Rotation::Forward);

    // F-12 = 2: R to the running drive reverses it; Run to it sends no R (no reversal).
    set_f12(&mut line, 1, 2);
    assert_eq!(run(&mut line, &b, Operation::Reverse), (Outcome::Done, "TR".into()));
    assert_eq!(model(&mut line, 1).rotation(), Rotation::Reverse);
    assert_eq!(run(&mut line, &b, Operation::Run), (Outcome::Done, "T".into()));
    assert_eq!(model(&mut line, 1).rotation(), Rotation::Reverse);
    // P in host run/stop mode: e 91.
    assert_eq!(
        fail(&mut line, &b, Operation::SetSpeed(30.0)),
        (refused(0x91, "not in keypad mode"), "P".into())
    );
}

#[test]
fn terminal_mode_refuses_commands_with_91() {
    let mut line = line_with(&[1]);
    let b = B800Profile::new(1).expect("profile");
    set_f12(&mut line, 1, 0);
    assert_eq!(fail(&mut line, &b, Operation::Run), (refused(0x91, "not in keypad mode"), "TR".into()));
    assert_eq!(fail(&mut line, &b, Operation::Stop), (refused(0x91, "not in keypad mode"), "S".into()));
    assert_eq!(
        fail(&mut line, &b, Operation::SetSpeed(10.0)),
        (refused(0x91, "not in keypad mode"), "P".into())
    );
    // Status still works: T, Z and A are not keypad commands.
    assert!(!status(&mut line, &b).running);
}

#[test]
fn set_speed_out_of_range_is_refused_before_anything_is_sent() {
    let mut line = line_with(&[1]);
    let b = B800Profile::new(1).expect("profile");
    assert_eq!(b.frequency_limits(), (0.0, 50.0));
    for (hz, message) in [
        (-0.5, "-0.5 Hz is below 0 Hz: the B800 protocol has no signed speed"),
        (50.5, "50.5 Hz is above the maximum frequency F-01 = 50.0 Hz"),
        (f64::INFINITY, "inf is not a speed"),
    ] {
        assert_eq!(b.plan(&Operation::SetSpeed(hz)).err(), Some(DriveError::OutOfRange(message.into())));
    }
    // Told the drive's F-01 = 60 Hz and F-02 = 5 Hz.
    let b = b.with_frequency_limits(5.0, 60.0).expect("limits");
    assert!(b.plan(&Operation::SetSpeed(55.0)).is_ok());
    assert_eq!(
        b.plan(&Operation::SetSpeed(4.0)).err(),
        Some(DriveError::OutOfRange("4 Hz is below the minimum frequency F-02 = 5.0 Hz".into()))
    );
    assert_eq!(
        B800Profile::new(1).expect("profile").with_frequency_limits(0.0, 500.0).err(),
        Some(DriveError::OutOfRange("F-01 is 10.0..400.0 Hz, 500 is out of range".into()))
    );
    assert_eq!(line.stats().master_bytes, 0);
    wait(&mut line, Duration::from_millis(1));
}

#[test]
fn no_jog_and_no_parameter_access() {
    let b = B800Profile::new(1).expect("profile");
    assert!(matches!(b.plan(&Operation::Jog), Err(DriveError::Unsupported(s)) if s.contains("no jog")));
    assert_eq!(
        b.plan(&Operation::ReadParam("F-12".into())).err(),
        Some(DriveError::Unsupported(
            "the B800 protocol has no parameter access (its commands are R S A Z M T V P I L): \
             set F-12 Control source on the drive's keypad"
                .into()
        ))
    );
    let write = Operation::WriteParam { name: "F-01".into(), raw: 600, storage: Storage::Ram };
    assert!(matches!(b.plan(&write), Err(DriveError::Unsupported(_))));
    assert_eq!(
        b.plan(&Operation::ReadParam("F-99".into())).err(),
        Some(DriveError::Unsupported("the B800 catalog has no parameter \"F-99\"".into()))
    );
    assert_eq!(b.param("f12").map(|p| p.name.as_str()), Ok("F-12"));
}

#[test]
fn global_address_reaches_every_drive_and_gets_no_reply() {
    let mut line = line_with(&[1, 2]);
    let all = B800Profile::new(0).expect("profile");
    assert_eq!(all.address(), 0);
    for op in [Operation::Status, Operation::Reset, Operation::Jog] {
        assert!(matches!(all.plan(&op), Err(DriveError::Unsupported(_))), "{op:?}");
    }
    // seed 000: "start all drives" is 7E 34 37 35 32 32 44 7F.
    let mut plan = all.plan(&Operation::Run).expect("plan");
    let Ok(Step::Send(x)) = plan.step(None) else { panic!("a frame") };
    assert_eq!((x.request.as_slice(), x.expect_reply), (&b"\x7E47522D\x7F"[..], false));
    transact(&mut line, &x.request, false);
    assert_eq!(plan.step(None), Ok(Step::Done(Outcome::Done)));
    assert_eq!(line.stats().device_bytes, 0);

    let (outcome, sent) = execute(&mut line, all.plan(&Operation::SetSpeed(25.0)).expect("plan"));
    assert_eq!((outcome, sent), (Ok(Outcome::Done), vec!["475005DC43".to_string()]));
    wait(&mut line, Duration::from_secs(4));
    for port in [1, 2] {
        let m = model(&mut line, port);
        assert_eq!(m.state(), RunState::Running);
        assert!((m.output_hz() - 25.0).abs() < 0.02, "{}", m.output_hz());
    }
    // seed 000: "stop all drives" is 7E 34 37 35 33 32 43 7F.
    let (outcome, sent) = execute(&mut line, all.plan(&Operation::Stop).expect("plan"));
    assert_eq!((outcome, sent), (Ok(Outcome::Done), vec!["47532C".to_string()]));
    wait(&mut line, Duration::from_secs(4));
    assert_eq!(model(&mut line, 1).state(), RunState::Stopped);
    assert_eq!(model(&mut line, 2).state(), RunState::Stopped);
    assert_eq!(line.stats().device_bytes, 0);
}

#[test]
fn addresses_and_malformed_replies() {
    assert_eq!(
        B800Profile::new(64).err(),
        Some(DriveError::OutOfRange(
            "a B800 drive address is 1 to 63 (0 for the global address G), not 64".into()
        ))
    );
    let b = B800Profile::new(1).expect("profile");
    let first = |op: &Operation| {
        let mut plan = b.plan(op).expect("plan");
        let Ok(Step::Send(_)) = plan.step(None) else { panic!("a frame") };
        plan
    };
    // Not a frame.
    assert!(matches!(first(&Operation::Stop).step(Some(b"\x7E01")), Err(DriveError::Protocol(_))));
    // No reply.
    assert_eq!(
        first(&Operation::Stop).step(None),
        Err(DriveError::Protocol("drive 1 did not answer".into()))
    );
    // seed 000's reply from drive 05, 'p', to a stop for drive 1.
    assert_eq!(
        first(&Operation::Stop).step(Some(b"\x7E057033\x7F")),
        Err(DriveError::Protocol("the reply comes from drive 5, the request went to drive 1".into()))
    );
    // seed 000's 'r' from drive 01, answering a stop.
    assert_eq!(
        first(&Operation::Stop).step(Some(b"\x7E017235\x7F")),
        Err(DriveError::Protocol("S (stop command) was answered with 'r' (run command executed)".into()))
    );
}
