//! A drive as bus master (seed 004 9.2.2 (2); the Toshiba manual's inter-drive communication,
//! f806), on simulated time: the master broadcasts its run/stop and frequency every cycle, the
//! other drives follow, and Toshiba followers do what f806 says when the master fails.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_proto::Instant;
use drivebus_sim::bus::{Device, VirtualLine};
use drivebus_sim::config::BusSpec;

/// The line a bus file describes.
fn line(toml: &str) -> VirtualLine {
    BusSpec::from_toml("bus.toml", toml).expect("a valid bus file").build_line().expect("a line")
}

/// Runs the line on simulated time for `d`.
fn run_for(line: &mut VirtualLine, d: Duration) {
    let end = line.now() + d;
    line.run_until(end);
}

fn output_hz(line: &mut VirtualLine, port: usize) -> f64 {
    line.drive(port).expect("a drive").core().model.output_hz()
}

fn state(line: &mut VirtualLine, port: usize) -> String {
    line.drive(port).expect("a drive").snapshot().state
}

/// Records when each burst of bytes arrived and how long it was.
struct Spy(Arc<Mutex<Vec<(Instant, usize)>>>);

impl Device for Spy {
    fn receive(&mut self, now: Instant, bytes: &[u8]) {
        self.0.lock().unwrap().push((now, bytes.len()));
    }
    fn poll_transmit(&mut self, _: Instant) -> Option<Vec<u8>> {
        None
    }
    fn poll_timeout(&self) -> Option<Instant> {
        None
    }
}

const GENERIC: &str = r#"
[[drive]]
kind = "generic"
address = 1
protocol = "modbus-rtu"
role = "master"
params = { "P0.02" = "40 Hz" }

[[drive]]
kind = "generic"
address = 2
protocol = "modbus-rtu"

[[drive]]
kind = "generic"
address = 3
protocol = "modbus-rtu"
"#;

#[test]
fn a_generic_master_at_40_hz_runs_two_followers_at_40_hz() {
    let mut line = line(GENERIC);
    let heard = Arc::new(Mutex::new(Vec::new()));
    line.add_device(Box::new(Spy(heard.clone())));
    assert_eq!(line.drive(1).unwrap().snapshot().role.as_deref(), Some("master"));
    assert_eq!(line.drive(2).unwrap().snapshot().role, None);

    // Stopped master: the followers hear "stop" and stay stopped.
    run_for(&mut line, Duration::from_secs(1));
    assert_eq!(state(&mut line, 2), "stopped");

    // RUN on the master's keypad: 10 s from 0 to 50 Hz, so 40 Hz after 8 s; the followers
    // start at the next cycle (100 ms) and get there as well.
    line.drive_mut(1).unwrap().press_run(true).expect("P0.01 = 0: keypad run");
    run_for(&mut line, Duration::from_secs(10));
    for port in 1..=3 {
        assert_eq!(state(&mut line, port), "running", "drive {port}");
        assert_eq!(output_hz(&mut line, port), 40.0, "drive {port}");
    }
    // Nobody answered a broadcast: every burst on the line came from the master (8 bytes, 06).
    let bursts = heard.lock().unwrap().clone();
    assert!(bursts.len() > 100, "{} bursts", bursts.len());
    assert!(bursts.iter().all(|&(_, n)| n == 8), "only the master's 06 frames: {bursts:?}");
    // Seed 004: at least 10 ms of silence between frames.
    let char_time = line.char_time();
    for w in bursts.windows(2) {
        let (end_1, _) = w[0];
        let (end_2, n) = w[1];
        let start_2 = end_2 - char_time * n as u32;
        assert!(start_2 - end_1 >= Duration::from_millis(10), "{:?} of silence", start_2 - end_1);
    }

    // STOP on the master's keypad: every drive ramps down.
    line.drive_mut(1).unwrap().press_run(false).unwrap();
    run_for(&mut line, Duration::from_secs(10));
    for port in 1..=3 {
        assert_eq!(
            state(&mut line, port),
            "stopped",
            "drive {port}: {:?}",
            line.drive(port).unwrap().snapshot()
        );
    }
}

#[test]
fn the_generic_keypad_run_needs_p0_01_keypad() {
    let mut line = line(GENERIC);
    let e = line.drive_mut(2).unwrap().press_run(true).unwrap_err();
    assert!(e.contains("P0.01 = 2") && e.contains("P0.01 = 0"), "{e}");
}

/// A Toshiba master (f806 = 3) with FH = UL = 80 Hz, and followers numbered 1.. with the
/// manual's proportional control: 100 % (the master's FH) is 40 Hz.
fn toshiba(followers: &[&str]) -> VirtualLine {
    let mut toml = String::from(
        r#"
[[drive]]
kind = "toshiba"
address = 10
role = "master"
keypad_hz = 80
params = { "0012" = "80 Hz" }
"#,
    );
    for (i, extra) in followers.iter().enumerate() {
        toml += &format!(
            "[[drive]]\nkind = \"toshiba\"\naddress = {}\nparams = {{ f810 = 1, f811 = 0, f812 = \"0 Hz\", f813 = 100, f814 = \"40 Hz\", \"0012\" = \"80 Hz\" {extra} }}\n",
            i + 1
        );
    }
    line(&toml)
}

#[test]
fn a_toshiba_master_and_a_proportional_follower_at_the_manuals_ratio() {
    let mut line = toshiba(&[""]);
    line.drive_mut(1).unwrap().press_run(true).unwrap();
    run_for(&mut line, Duration::from_secs(20));
    assert_eq!(output_hz(&mut line, 1), 80.0);
    assert_eq!(output_hz(&mut line, 2), 40.0, "80 Hz = 100 % of the master's FH -> 40 Hz");
    // The master's panel frequency to 60 Hz: 75 % -> 30 Hz.
    line.drive_mut(1).unwrap().set_keypad_hz(60.0).unwrap();
    run_for(&mut line, Duration::from_secs(20));
    assert_eq!(output_hz(&mut line, 1), 60.0);
    assert_eq!(output_hz(&mut line, 2), 30.0);
    line.drive_mut(1).unwrap().press_run(false).unwrap();
    run_for(&mut line, Duration::from_secs(20));
    assert_eq!(state(&mut line, 2), "stopped");
}

#[test]
fn when_the_toshiba_master_fails_each_follower_does_what_f806_says() {
    let mut line = toshiba(&[", f806 = 0, f803 = 1", ", f806 = 1, f803 = 1", ", f806 = 2, f803 = 1"]);
    line.drive_mut(1).unwrap().press_run(true).unwrap();
    run_for(&mut line, Duration::from_secs(20));
    for port in 2..=4 {
        assert_eq!(output_hz(&mut line, port), 40.0, "drive {port}");
    }
    // The master goes silent (a failure, a broken wire): after f803 = 1 s...
    line.set_silent(1, true);
    run_for(&mut line, Duration::from_millis(900));
    for port in 2..=4 {
        assert_eq!(state(&mut line, port), "running", "drive {port}: not before f803");
    }
    run_for(&mut line, Duration::from_secs(20));
    // f806 = 0: the frequency command drops to 0 Hz; the motor ramps down, still in run.
    let zero = line.drive(2).unwrap().snapshot();
    assert_eq!((zero.state.as_str(), zero.setpoint_hz, zero.output_hz), ("running", 0.0, 0.0));
    // f806 = 1: operation continues.
    assert_eq!(output_hz(&mut line, 3), 40.0);
    // f806 = 2: emergency stop trip (E).
    let tripped = line.drive(4).unwrap().snapshot();
    assert_eq!((tripped.state.as_str(), tripped.trip.as_deref()), ("tripped", Some("external trip")));
}

#[test]
fn bus_file_errors_for_the_master_role() {
    let e = |toml: &str| BusSpec::from_toml("bus.toml", toml).unwrap_err().0;
    let msg = e("[[drive]]\nkind = \"generic\"\naddress = 1\nrole = \"boss\"\n");
    assert!(msg.contains("drive 1") && msg.contains("\"master\""), "{msg}");
    let msg = e("[[drive]]\nkind = \"generic\"\naddress = 1\nrole = \"master\"\n[[drive]]\nkind = \"generic\"\naddress = 2\nrole = \"master\"\n");
    assert!(msg.contains("one master"), "{msg}");
    let msg = e("[[drive]]\nkind = \"toshiba\"\naddress = 1\nrole = \"master\"\nparams = { f806 = 1 }\n");
    assert!(msg.contains("f806 = 3"), "{msg}");
    let msg = e("[[drive]]\nkind = \"generic\"\naddress = 1\ncycle_ms = 50\n");
    assert!(msg.contains("role = \"master\""), "{msg}");
    let bus = BusSpec::from_toml("bus.toml", "[[drive]]\nkind = \"b800\"\naddress = 1\nrole = \"master\"\n")
        .unwrap();
    let err = bus.build_line().err().expect("b800 has no master role").0;
    assert!(err.contains("no drive acting as bus master"), "{err}");
    // f806 = 3 alone makes a Toshiba drive the master.
    let bus =
        BusSpec::from_toml("bus.toml", "[[drive]]\nkind = \"toshiba\"\naddress = 1\nparams = { f806 = 3 }\n")
            .unwrap();
    assert_eq!(bus.master.map(|m| m.drive), Some(0));
}

#[test]
fn when_the_generic_master_fails_a_follower_does_what_p3_13_says() {
    // The manual gives generic followers nothing of their own: the communication time-out.
    let toml = GENERIC.replacen(
        "address = 2\nprotocol = \"modbus-rtu\"\n",
        "address = 2\nprotocol = \"modbus-rtu\"\nparams = { \"P3.13\" = \"1.0\", \"P3.14\" = 1 }\n",
        1,
    );
    let mut line = line(&toml);
    line.drive_mut(1).unwrap().press_run(true).unwrap();
    run_for(&mut line, Duration::from_secs(10));
    assert_eq!(output_hz(&mut line, 2), 40.0);
    line.set_silent(1, true);
    run_for(&mut line, Duration::from_secs(2));
    let s = line.drive(2).unwrap().snapshot();
    assert_eq!((s.state.as_str(), s.trip.as_deref()), ("tripped", Some("communication time-out")));
    // Drive 3 has no time-out set: it runs on with the last command.
    assert_eq!(output_hz(&mut line, 3), 40.0);
}
