//! Toshiba's outputs and model code (FA50–FA52, FB05) and every family's trip history
//! (`drivebus trips`), end to end against `drivebus simulate` on a pty.

use serde_json::Value;

#[path = "support/sim.rs"]
mod sim;

use sim::{drivebus, ok, pty_path, simulate};

fn get(port: &str, protocol: &str, name: &str) -> Value {
    let o = drivebus(port, "toshiba", Some(protocol), 1, &["param", "get", name, "--json"]);
    ok(&o, &format!("param get {name}"));
    serde_json::from_str(o.stdout.trim()).expect("param JSON")
}

/// FA50–FA52 take what the master writes (RAM) and read it back; FB05 names the model and
/// refuses writes; in TIP (ASCII and binary) and in Modbus-RTU.
#[test]
fn toshiba_outputs_and_model_code_in_every_protocol() {
    for (drive, protocols) in
        [("toshiba@1", &["toshiba-binary", "toshiba-ascii"][..]), ("toshiba@1:modbus-rtu", &["modbus-rtu"][..])]
    {
        let pty = pty_path("toshiba-outputs");
        let _sim = simulate(drive, &["--pty", &pty]);
        for (k, &protocol) in protocols.iter().enumerate() {
            let model = get(&pty, protocol, "FB05");
            assert_eq!(model["raw"], 0x2037, "{protocol}: {model}");
            assert!(model["text"].as_str().unwrap_or("").contains("VFAS1-2037PM"), "{model}");
            let o = drivebus(&pty, "toshiba", Some(protocol), 1, &["param", "get", "FB05"]);
            ok(&o, "FB05 as text");
            assert!(o.stdout.contains("Inverter model (capacity) code") && o.stdout.contains("VFAS1-2037PM"), "{}", o.stdout);
            let bits = format!("{}", 5 + k);
            ok(&drivebus(&pty, "toshiba", Some(protocol), 1, &["param", "set", "FA50", &bits]), "set FA50");
            assert_eq!(get(&pty, protocol, "FA50")["raw"], 5 + k as i64, "{protocol}");
            ok(&drivebus(&pty, "toshiba", Some(protocol), 1, &["param", "set", "FA51", "42.5"]), "set FA51");
            assert_eq!(get(&pty, protocol, "FA51")["raw"], 425, "{protocol}");
            ok(&drivebus(&pty, "toshiba", Some(protocol), 1, &["param", "set", "FA52", "100"]), "set FA52");
            assert_eq!(get(&pty, protocol, "FA52")["raw"], 1000, "{protocol}");
            let o = drivebus(&pty, "toshiba", Some(protocol), 1, &["param", "set", "FA51", "100.1"]);
            assert_eq!(o.code, 3, "{protocol}: out of range: {}{}", o.stdout, o.stderr);
            let o = drivebus(&pty, "toshiba", Some(protocol), 1, &["param", "set", "FB05", "1"]);
            assert_ne!(o.code, 0, "{protocol}: FB05 is read-only: {}{}", o.stdout, o.stderr);
            assert_eq!(o.stderr.lines().count(), 1, "{}", o.stderr);
        }
    }
}
