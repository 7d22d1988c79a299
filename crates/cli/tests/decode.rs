//! `drivebus decode` end to end: the binary run on every example of the seed manuals
//! (protocols.md section 5), the seed examples that are wrong diagnosed, `--json`, exit codes.

use std::process::Command;

use serde_json::Value;

#[cfg(unix)]
#[path = "support/closed_pipe.rs"]
mod closed_pipe;

#[path = "support/output.rs"]
mod output;
use output::{output, Out};

fn decode(args: &[&str]) -> Out {
    output(Command::new(env!("CARGO_BIN_EXE_drivebus")).arg("decode").args(args))
}

fn json(args: &[&str]) -> (i32, Vec<Value>) {
    let mut all = vec!["--json"];
    all.extend_from_slice(args);
    let r = decode(&all);
    let frames =
        r.stdout.lines().map(|l| serde_json::from_str(l).expect("one JSON object per line")).collect();
    (r.code, frames)
}

/// `bytes` as the hex the command reads ("28 52 ...").
fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(" ")
}

/// Asserts a valid frame decodes with `needles` in the text output.
fn valid(args: &[&str], needles: &[&str]) {
    let r = decode(args);
    assert_eq!(r.code, 0, "{args:?}\nstdout: {}\nstderr: {}", r.stdout, r.stderr);
    assert!(!r.stdout.contains("INVALID"), "{args:?}: {}", r.stdout);
    for n in needles {
        assert!(r.stdout.contains(n), "{args:?}: missing {n:?} in\n{}", r.stdout);
    }
}

/// Asserts the input has no valid frame and the diagnosis contains `needle` on stdout and stderr.
fn invalid(args: &[&str], needle: &str) {
    let r = decode(args);
    assert_eq!(r.code, 1, "{args:?}\nstdout: {}\nstderr: {}", r.stdout, r.stderr);
    assert!(r.stdout.contains(needle), "{args:?}: missing {needle:?} in stdout\n{}", r.stdout);
    assert!(r.stderr.contains(needle), "{args:?}: missing {needle:?} in stderr\n{}", r.stderr);
    for line in r.stderr.lines() {
        assert!(line.starts_with("drivebus: "), "one line per error: {line:?}");
    }
}

// ---- B800 (seed 000): B1-B6 ----

#[test]
fn b800_seed_examples() {
    // B1: drive 1 run.
    valid(&["-p", "b800", "7E 38 31 35 32 32 46 7F"], &["master to drive 1", "'R'"]);
    // B2: drive 5 set speed 0960 = 40.00 Hz.
    valid(&["-p", "b800", "7E 38 35 35 30 30 39 36 30 35 45 7F"], &["master to drive 5", "0960 = 40.00 Hz"]);
    // B3/B4: global run and stop.
    valid(&["-p", "b800", "7E 34 37 35 32 32 44 7F"], &["broadcast"]);
    valid(&["-p", "b800", "7E 34 37 35 33 32 43 7F"], &["broadcast"]);
    // B5/B6: replies r and p; the direction comes from the address.
    valid(&["-p", "b800", "7E 30 31 37 32 33 35 7F"], &["drive 1 to master", "'r'"]);
    valid(&["-p", "b800", "7E 30 35 37 30 33 33 7F"], &["drive 5 to master", "'p'"]);
    // Error reply: drive 1, error 95 (bad checksum).
    let r = decode(&["-p", "b800", "7E 30 31 36 35 39 35 43 35 7F"]);
    assert_eq!(r.code, 0);
    assert!(r.stdout.contains("the drive refuses"), "{}", r.stdout);
}

#[test]
fn b800_bad_bytes_are_diagnosed() {
    invalid(&["-p", "b800", "7E 38 31 35 32 32 45 7F"], "checksum mismatch: frame carries 2E, computed 2F");
    invalid(&["-p", "b800", "7E 38 31 01 35 32 32 46 7F"], "non-hex byte 0x01 at offset 3 ends the frame");
}

#[test]
fn b800_json_shape() {
    let (code, frames) =
        json(&["-p", "b800", "7E 38 35 35 30 30 39 36 30 35 45 7F", "7E 34 37 35 33 32 43 7F"]);
    assert_eq!(code, 0);
    assert_eq!(frames.len(), 2);
    let f = &frames[0];
    assert_eq!(f["valid"], true);
    assert_eq!(f["protocol"], "b800");
    assert_eq!(f["direction"], "master");
    assert_eq!(f["address"], 5);
    assert_eq!(f["command"], "P");
    assert!(f["fields"].is_object());
    let speed = f["fields"].as_object().unwrap().values().find(|v| v["unit"] == "Hz").expect("a field in Hz");
    assert_eq!(speed["value"], 40.0);
    assert_eq!(frames[1]["broadcast"], true);
    assert_eq!(frames[1]["address"], 0);
}

// ---- Toshiba TIP (seed 002) ----

#[test]
fn toshiba_ascii_examples() {
    // TA4: read FE03 (output current); TA5: the reply 077B = 19.15 %.
    valid(&["-p", "toshiba-ascii", "28 52 46 45 30 33 29 0D"], &["master to", "FE03"]);
    valid(&["-p", "toshiba-ascii", "28 52 46 45 30 33 30 37 37 42 29 0D"], &["to master", "19.15 %"]);
    // TA7: write decel time 0010 = 0064 (10.0 s).
    valid(&["-p", "toshiba-ascii", "28 57 30 30 31 30 30 30 36 34 29 0D"], &["0010", "10.0 s"]);
    // TA13: the wildcard *2 and the answer from inverter 02.
    valid(&["-p", "toshiba-ascii", "28 2A 32 52 30 30 30 30 29 0D"], &["wildcard"]);
    valid(&["-p", "toshiba-ascii", "--from", "drive", &hex(b"(02R00000000)\r")], &["drive 2 to master"]);
    // With a checksum: (R0000&60)CR.
    valid(&["-p", "toshiba-ascii", "28 52 30 30 30 30 26 36 30 29 0D"], &["SUM"]);
}

#[test]
fn toshiba_ascii_format_error_is_diagnosed() {
    // TA17: (R11)CR is a format error; the drive does not answer.
    let r = decode(&["-p", "toshiba-ascii", "28 52 31 31 29 0D"]);
    assert_eq!(r.code, 1, "{}", r.stdout);
    assert!(r.stdout.contains("INVALID"), "{}", r.stdout);
}

#[test]
fn toshiba_binary_examples() {
    // TB1: R comm-no 0000.
    valid(&["-p", "toshiba-binary", "2F 52 00 00 81"], &["master to"]);
    // TB2: W decel time 0010 = 0064 = 10.0 s.
    valid(&["-p", "toshiba-binary", "2F 57 00 10 00 64 FA"], &["10.0 s"]);
    // TB9-TB12: the error replies.
    for (frame, what) in [
        ("2F 4E 00 00 7D", "0000"),
        ("2F 4E 00 01 7E", "0001"),
        ("2F 4E 00 02 7F", "0002"),
        ("2F 4E 00 04 81", "0004"),
    ] {
        let r = decode(&["-p", "toshiba-binary", frame]);
        assert_eq!(r.code, 0, "{frame}: {}", r.stdout);
        assert!(r.stdout.contains("the drive refuses") && r.stdout.contains(what), "{frame}: {}", r.stdout);
    }
}

#[test]
fn toshiba_binary_block_example_with_wrong_sum() {
    // TB14: the manual's block write carries SUM D8; the right SUM is D9.
    invalid(
        &["-p", "toshiba-binary", "2F 58 02 05 C4 00 17 70 D8"],
        "SUM mismatch: frame carries D8, computed D9",
    );
}

// ---- Modbus (seeds 002 and 004) ----

#[test]
fn modbus_rtu_toshiba_examples() {
    valid(
        &["-p", "modbus-rtu", "--from", "master", "01 03 FD 00 00 01 B5 A6"],
        &["master to drive 1", "FD00"],
    );
    // A reply does not say which register it answers, so its value is shown raw.
    valid(&["-p", "modbus-rtu", "--from", "drive", "01 03 02 17 70 B6 50"], &["drive 1 to master", "1770"]);
    valid(&["-p", "modbus-rtu", "--from", "master", "01 03 FD 00 00 02 F5 A7"], &["quantity"]);
    let r = decode(&["-p", "modbus-rtu", "--from", "drive", "01 83 03 01 31"]);
    assert_eq!(r.code, 0);
    assert!(
        r.stdout.contains("illegal data value") && r.stdout.contains("the drive refuses"),
        "{}",
        r.stdout
    );
    valid(&["-p", "modbus-rtu", "--from", "master", "01 06 FA 01 17 70 E6 C6"], &["60.00 Hz"]);
    valid(&["-p", "modbus-rtu", "--from", "drive", "01 86 02 C3 A1"], &["illegal data address"]);
    valid(&["-p", "modbus-rtu", "--from", "master", "01 2B 0E 01 00 70 77"], &["2B"]);
    valid(
        &[
            "-p",
            "modbus-rtu",
            "--from",
            "drive",
            "01 2B 0E 01 01 00 00 03 00 07 54 4F 53 48 49 42 41 01 0C 56 46 53 31 35 2D 32 30 33 37 50 4D 02 04 30 31 30 30 13 45",
        ],
        &["TOSHIBA", "VFS15-2037PM", "0100"],
    );
}

#[test]
fn modbus_generic_examples() {
    valid(&["-p", "modbus-rtu", "11 03 00 6B 00 03 76 87"], &["master to drive 17"]);
    // Register 0002 is P0.02 on the generic drive but something else on others: shown raw.
    valid(&["-p", "modbus-rtu", "01 06 00 02 13 88 25 5C"], &["0002", "1388"]);
    valid(&["-p", "modbus-rtu", "01 08 01 02 03 04 41 04"], &["08"]);
    valid(
        &["-p", "modbus-ascii", "3A 30 31 30 36 30 34 30 35 31 32 33 34 41 41 0D 0A"],
        &["master to drive 1"],
    );
    valid(&["-p", "modbus-ascii", &hex(b":010321020002D7\r\n")], &["2102"]);
    valid(&["-p", "modbus-ascii", "3A 30 31 30 33 30 34 30 31 30 30 30 31 46 36 0D 0A"], &["0401"]);
    valid(&["-p", "modbus-ascii", "3A 30 31 30 36 30 30 30 32 31 33 38 38 35 43 0D 0A"], &["0002", "1388"]);
    valid(&["-p", "modbus-ascii", "3A 30 31 30 38 30 31 30 32 30 33 30 34 45 44 0D 0A"], &["08"]);
}

#[test]
fn modbus_seed_004_errata_are_explained() {
    // The seed's RTU read: 7 bytes, and E8 4B is the CRC of the first 4 bytes only.
    invalid(&["-p", "modbus-rtu", "--from", "master", "01 03 21 04 00 E8 4B"], "first 4 bytes only");
    invalid(&["-p", "modbus-rtu", "--from", "master", "01 03 21 04 00 E8 4B"], "needs 8 bytes, got 7");
    // With the quantity byte restored the CRC is plainly wrong.
    invalid(
        &["-p", "modbus-rtu", "--from", "master", "01 03 21 04 00 01 E8 4B"],
        "CRC mismatch: frame carries E8 4B, computed CF F7 (the carried CRC is that of the first 4 bytes only)",
    );
    // The seed's RTU "reply" is an echo of a request with quantity 0.
    invalid(
        &["-p", "modbus-rtu", "--from", "master", "01 03 21 04 00 00 0E 37"],
        "quantity 0 is not allowed (1..125)",
    );
    invalid(&["-p", "modbus-rtu", "--from", "drive", "01 03 21 04 00 00 0E 37"], "not a valid 03 reply");
    // The seed's RTU write is sent to address 00 but carries address 01's CRC.
    invalid(
        &["-p", "modbus-rtu", "00 06 00 02 13 88 25 5C"],
        "CRC mismatch: frame carries 25 5C, computed 24 8D (the carried CRC is right for the same frame sent to address 1)",
    );
    // The seed's ASCII read: 5 bytes where a 03 request has 6; LRC D7 would fit quantity 0.
    invalid(
        &["-p", "modbus-ascii", "3A 30 31 30 33 32 31 30 34 30 30 44 37 0D 0A"],
        "quantity 0 is not allowed",
    );
    let r = decode(&["-p", "modbus-ascii", "3A 30 31 30 33 32 31 30 34 30 30 44 37 0D 0A"]);
    assert!(r.stdout.contains("needs 6 bytes, got 5"), "{}", r.stdout);
}

#[test]
fn modbus_json_has_function_and_address() {
    let (code, frames) =
        json(&["-p", "modbus-rtu", "--from", "master", "01 03 FD 00 00 01 B5 A6", "00 06 00 02 13 88 24 8D"]);
    assert_eq!(code, 0);
    assert_eq!(frames.len(), 2);
    assert_eq!(frames[0]["function"], 3);
    assert_eq!(frames[0]["address"], 1);
    assert_eq!(frames[0]["direction"], "master");
    assert_eq!(frames[1]["broadcast"], true);
    assert_eq!(frames[1]["address"], 0);
    let (code, frames) = json(&["-p", "modbus-rtu", "--from", "master", "01 03 21 04 00 01 E8 4B"]);
    assert_eq!(code, 1);
    assert_eq!(frames[0]["valid"], false);
    assert!(frames[0]["error"].as_str().unwrap().starts_with("CRC mismatch"));
}

// ---- Danfoss FC (seed 003) ----

#[test]
fn fc_examples() {
    // D1: process telegram to address 4: CTW 047C (start), reference 2000 (50 %).
    valid(&["-p", "danfoss-fc", "02 06 04 04 7C 20 00 58"], &["047C", "50.00 %"]);
    // D2: the reply: STW 0607, MAV 0.
    valid(&["-p", "danfoss-fc", "--from", "drive", "02 06 04 06 07 00 00 01"], &["0607"]);
    // D3/D4: VLT 5000 read of parameter 520, and the AK=2 reply 0x20C.
    valid(&["-p", "danfoss-fc", "02 0E 01 12 08 00 00 00 00 00 00 00 00 00 00 17"], &["520"]);
    valid(
        &["-p", "danfoss-fc", "--from", "drive", "02 0E 01 22 08 00 00 00 00 02 0C 06 07 00 00 28"],
        &["020C"],
    );
    // D5: the FC 300 guide's misprinted read: AK 0, "no command".
    valid(&["-p", "danfoss-fc", "02 0E 01 06 4E 00 00 00 00 00 00 00 00 00 00 45"], &["no command"]);
}

#[test]
fn fc_bad_bcc_is_diagnosed() {
    invalid(&["-p", "danfoss-fc", "02 06 04 04 7C 20 00 59"], "BCC mismatch: frame carries 59, computed 58");
}

// ---- Streams, noise and usage ----

#[test]
fn frames_in_a_stream_with_garbage_are_all_found() {
    let r = decode(&["-p", "b800", "00 11", "7E 38 31 35 32 32 46 7F", "FF", "7E 30 31 37 32 33 35 7F"]);
    assert_eq!(r.code, 0, "{}", r.stderr);
    assert!(r.stdout.contains("frame 1") && r.stdout.contains("frame 2"), "{}", r.stdout);
    assert!(r.stderr.contains("skipped 2 bytes at byte 0"), "{}", r.stderr);
}

#[test]
fn bad_usage_exits_3_with_one_line() {
    let r = decode(&["-p", "b800", "7E 3G"]);
    assert_eq!(r.code, 3);
    assert_eq!(r.stderr.lines().count(), 1, "{}", r.stderr);
    assert!(r.stderr.contains("'G'"), "{}", r.stderr);
    let r = decode(&["-p", "nope", "00"]);
    assert_eq!(r.code, 3);
    assert_eq!(r.stderr.lines().count(), 1, "{}", r.stderr);
    let r = decode(&["-p", "modbus-rtu", "01 02 03"]);
    assert_eq!(r.code, 1, "no valid frame: {}", r.stdout);
}

/// A reader that stops early (`drivebus decode ... | head -1`) ends the command quietly: no
/// panic from a print to a closed pipe.
#[test]
#[cfg(unix)]
fn a_reader_that_stops_early_ends_the_command_without_a_panic() {
    // 40 000 frames, several MB of output: far more than a pipe holds.
    let chunk = "7E 30 31 37 32 33 35 7F ".repeat(2000);
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_drivebus"));
    cmd.args(["decode", "--protocol", "b800"]);
    for _ in 0..20 {
        cmd.arg(&chunk);
    }
    let first = closed_pipe::first_line_then_close(cmd);
    assert!(first.starts_with("frame 1"), "{first}");
}

// ---- Requests and replies read together; registers named from the catalogs ----

/// A Toshiba Modbus read of FD00 and its reply, without --from: the reply is drive 1's and its
/// value is scaled by the register its request named (17 70 = 60.00 Hz).
#[test]
fn a_reply_is_read_with_its_request() {
    valid(
        &["-p", "modbus-rtu", "01 03 FD 00 00 01 B5 A6", "01 03 02 17 70 B6 50"],
        &[
            "frame 2 at byte 8: drive 1 to master: 03 read holding registers",
            "register value 1770 = 60.00 Hz",
        ],
    );
    let (_, frames) = json(&["-p", "modbus-rtu", "01 03 FD 00 00 01 B5 A6 01 03 02 17 70 B6 50"]);
    assert_eq!(frames[1]["direction"], "drive");
    assert_eq!(frames[1]["fields"]["register value"]["value"], 60.0, "{}", frames[1]);
    assert_eq!(frames[1]["fields"]["register value"]["unit"], "Hz");
    // Alone, the reply's value has no register to be read by.
    let r = decode(&["-p", "modbus-rtu", "--from", "drive", "01 03 02 17 70 B6 50"]);
    assert!(r.stdout.contains("register value 1770\n"), "{}", r.stdout);
}

/// The generic VFD's P0.02 at 0002H in Hz, and the values of its 2000H command named.
#[test]
fn generic_parameters_and_command_values_are_named() {
    valid(
        &["-p", "modbus-rtu", "01 06 00 02 13 88 25 5C"],
        &["register address 0002 (P0.02 ", "(generic)", "register value 1388 = 50.00 Hz"],
    );
    valid(&["-p", "modbus-ascii", "3A 30 31 30 36 30 30 30 32 31 33 38 38 35 43 0D 0A"], &["= 50.00 Hz"]);
    valid(&["-p", "modbus-rtu", "01 06 20 00 00 01 43 CA"], &["register value 0001 (run)"]);
    let (_, frames) = json(&["-p", "modbus-rtu", "01 06 20 00 00 07 C3 C8"]);
    assert_eq!(frames[0]["fields"]["register value"]["meaning"], "decelerate to stop", "{}", frames[0]);
}

/// A register both Modbus families have (generic P0.10 and Toshiba 0010 at 0010H) is named
/// as both until --drive says which; with it, the value is in that parameter's unit.
#[test]
fn a_register_two_families_share_is_named_by_drive() {
    // 01 06 0010 0064: 100 raw.
    let r = decode(&["-p", "modbus-rtu", "01 06 00 10 00 64 89 E4"]);
    assert_eq!(r.code, 0, "{}{}", r.stdout, r.stderr);
    assert!(r.stdout.contains(" or toshiba 0010 ") && r.stdout.contains("--drive FAMILY"), "{}", r.stdout);
    valid(&["-p", "modbus-rtu", "--drive", "toshiba", "01 06 00 10 00 64 89 E4"], &["(0010 ", "= 10.0 s"]);
    let r = decode(&["-p", "modbus-rtu", "--drive", "danfos", "01 06 00 10 00 64 89 E4"]);
    assert_eq!(r.code, 3, "{}", r.stderr);
}

/// A Danfoss reply with AK 1 (a value) or AK F (a text), without --from, is the drive's.
#[test]
fn danfoss_replies_without_from_are_the_drives() {
    // 02 0E 81 | PKE 11CE (AK 1, PNU 462 = 4-14... any) IND 0000 PWE 0000028A | STW 0607 MAV 0000
    let mut t =
        vec![0x02, 0x0E, 0x81, 0x11, 0x9E, 0x00, 0x00, 0x00, 0x00, 0x02, 0x8A, 0x06, 0x07, 0x00, 0x00];
    t.push(t.iter().fold(0, |a, b| a ^ b));
    valid(&["-p", "danfoss-fc", &hex(&t)], &["drive 1 to master: 01 parameter value transferred (word)"]);
}

// ---- A drive acting as bus master (seed 004 9.2.2 (2), Toshiba f806) ----

#[test]
fn a_master_drives_broadcasts_are_named() {
    // A generic master's 06 to address 0, 2001H = 40.00 Hz.
    valid(
        &["--protocol", "modbus-rtu", "--from", "master", "00 06 20 01 0F A0 D7 93"],
        &["master to all drives (broadcast)", "40.00 Hz", "broadcast as a drive acting as bus master"],
    );
    // A Toshiba master's block write to every inverter: run, 100.00 % of its FH.
    let (code, frames) = json(&["--protocol", "toshiba-binary", "2F FF 58 02 00 C4 00 27 10 83"]);
    assert_eq!(code, 0);
    assert_eq!(frames[0]["drive_master_broadcast"], true, "{}", frames[0]);
    // A write to one drive is not one.
    let (_, frames) = json(&["--protocol", "modbus-rtu", "--from", "master", "01 06 20 01 0F A0 D6 42"]);
    assert!(frames[0].get("drive_master_broadcast").is_none(), "{}", frames[0]);
}
