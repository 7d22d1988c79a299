//! Each command's help lists its own options only, and an option given before a command it
//! does not apply to is bad usage; options before and after the command are the same.

use std::process::Command;

#[path = "support/output.rs"]
mod output;

fn drivebus(args: &[&str]) -> (i32, String, String) {
    let out = output::output(Command::new(env!("CARGO_BIN_EXE_drivebus")).args(args));
    (out.code, out.stdout, out.stderr)
}

fn help(command: &[&str]) -> String {
    let mut args = command.to_vec();
    args.push("--help");
    let (code, out, err) = drivebus(&args);
    assert_eq!(code, 0, "{command:?}: {err}");
    out
}

const LINK: [&str; 12] = [
    "--port",
    "--drive",
    "--address",
    "--protocol",
    "--baud",
    "--serial",
    "--timeout",
    "--retries",
    "--gap",
    "--rs485",
    "--strict-t15",
    "--echo",
];

#[test]
fn each_command_shows_its_own_options() {
    let serve = help(&["serve"]);
    for flag in LINK.iter().chain(&["--json"]) {
        assert!(!serve.contains(flag), "serve --help lists {flag}:\n{serve}");
    }
    assert!(serve.contains("--config") && serve.contains("--demo"), "{serve}");
    for command in [
        &["status"][..],
        &["run"],
        &["speed"],
        &["param", "get"],
        &["params", "restore"],
        &["raw"],
        &["monitor"],
    ] {
        let text = help(command);
        for flag in LINK.iter().chain(&["--json"]) {
            assert!(text.contains(flag), "{command:?} --help misses {flag}:\n{text}");
        }
    }
    let decode = help(&["decode"]);
    for flag in ["--port", "--address", "--baud", "--retries", "--rs485"] {
        assert!(!decode.contains(flag), "decode --help lists {flag}:\n{decode}");
    }
    assert!(
        decode.contains("--protocol") && decode.contains("--from") && decode.contains("--json"),
        "{decode}"
    );
    let simulate = help(&["simulate"]);
    assert!(
        simulate.contains("KIND@ADDR") && simulate.contains("--baud") && !simulate.contains("--port"),
        "{simulate}"
    );
    let events = help(&["events"]);
    assert!(
        events.contains("--drive <ID>") && !events.contains("--port") && !events.contains("--retries"),
        "{events}"
    );
    let scan = help(&["scan"]);
    assert!(scan.contains("--port") && scan.contains("--formats") && !scan.contains("--retries"), "{scan}");
}

#[test]
fn an_option_before_a_command_it_does_not_apply_to_is_bad_usage() {
    let (code, _, err) = drivebus(&["--port", "/dev/null", "serve", "--demo"]);
    assert_eq!(code, 3, "{err}");
    assert_eq!(err.trim(), "drivebus: --port does not apply to drivebus serve (see drivebus serve --help)");
    let (code, _, err) = drivebus(&["--retries", "1", "decode", "-p", "b800", "7E 38 31 35 32 32 46 7F"]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("--retries does not apply to drivebus decode"), "{err}");
    // After the command, an option the command lacks is clap's unknown argument.
    let (code, _, err) = drivebus(&["serve", "--port", "/dev/null"]);
    assert_eq!(code, 3, "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}

#[test]
fn options_go_before_or_after_the_command() {
    let bytes = "7E 38 31 35 32 32 46 7F";
    let before = drivebus(&["--json", "-p", "b800", "decode", bytes]);
    let after = drivebus(&["decode", "--json", "-p", "b800", bytes]);
    let mixed = drivebus(&["-p", "b800", "decode", "--json", bytes]);
    assert_eq!(before.0, 0, "{}", before.2);
    assert!(before.1.starts_with('{'), "{}", before.1);
    assert_eq!(before, after);
    assert_eq!(before, mixed);
    // Given at both places, the value after the command counts.
    let (code, out, err) = drivebus(&["-p", "modbus-rtu", "decode", "--json", "-p", "b800", bytes]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("\"protocol\":\"b800\""), "{out}");
}

#[test]
fn no_command_is_one_line_saying_so() {
    let (code, out, err) = drivebus(&[]);
    assert_eq!(code, 3);
    assert!(out.is_empty(), "{out}");
    assert_eq!(err.trim(), "drivebus: say which command: drivebus <COMMAND> (see drivebus --help)");
    let (code, _, err) = drivebus(&["params"]);
    assert_eq!(code, 3);
    assert_eq!(
        err.trim(),
        "drivebus: say which command: drivebus params <COMMAND> (see drivebus params --help)"
    );
}
