//! Toshiba's outputs and model code (FA50–FA52, FB05) and every family's trip history
//! (`drivebus trips`), end to end against `drivebus simulate` on a pty.

use serde_json::Value;

#[path = "support/sim.rs"]
mod sim;

use sim::{drivebus, ok, pty_path, simulate, wait_status};

fn get(port: &str, protocol: &str, name: &str) -> Value {
    let o = drivebus(port, "toshiba", Some(protocol), 1, &["param", "get", name, "--json"]);
    ok(&o, &format!("param get {name}"));
    serde_json::from_str(o.stdout.trim()).expect("param JSON")
}

/// FA50–FA52 take what the master writes (RAM) and read it back; FB05 names the model and
/// refuses writes; in TIP (ASCII and binary) and in Modbus-RTU.
#[test]
fn toshiba_outputs_and_model_code_in_every_protocol() {
    for (drive, protocols) in [
        ("toshiba@1", &["toshiba-binary", "toshiba-ascii"][..]),
        ("toshiba@1:modbus-rtu", &["modbus-rtu"][..]),
    ] {
        let pty = pty_path("toshiba-outputs");
        let _sim = simulate(drive, &["--pty", &pty]);
        for (k, &protocol) in protocols.iter().enumerate() {
            let model = get(&pty, protocol, "FB05");
            assert_eq!(model["raw"], 0x2037, "{protocol}: {model}");
            assert!(model["text"].as_str().unwrap_or("").contains("VFAS1-2037PM"), "{model}");
            let o = drivebus(&pty, "toshiba", Some(protocol), 1, &["param", "get", "FB05"]);
            ok(&o, "FB05 as text");
            assert!(
                o.stdout.contains("Inverter model (capacity) code") && o.stdout.contains("VFAS1-2037PM"),
                "{}",
                o.stdout
            );
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

#[path = "support/http.rs"]
mod http;

fn trips(port: &str, family: &str, protocol: Option<&str>, address: u8) -> Value {
    let o = drivebus(port, family, protocol, address, &["trips", "--json"]);
    ok(&o, &format!("{family} trips"));
    serde_json::from_str(o.stdout.trim()).expect("trips JSON")
}

fn trip(sim: &sim::Proc, what: &str) {
    let (code, v) =
        http::http_json(sim.control(), "POST", "/drives/1", Some(&serde_json::json!({"trip": what})))
            .expect("trip through the control interface");
    assert_eq!(code, 200, "{v}");
}

/// Every family: two trips through the simulator's control interface (the first while running
/// at 20 Hz), reset between them; `trips` shows the trip in force and the log, newest first,
/// with the frequency at the trip where the drive logs it; the human table names them too.
#[test]
fn trips_of_every_family_over_a_pty() {
    for (drive, family, protocol, address, first, second, logged) in [
        (
            "generic@1:modbus-rtu",
            "generic",
            Some("modbus-rtu"),
            1,
            (1, "over-current"),
            (4, "module over-temperature"),
            true,
        ),
        ("toshiba@1", "toshiba", Some("toshiba-binary"), 1, (0x03, "OC3"), (0x10, "OH"), true),
        ("toshiba@1", "toshiba", Some("toshiba-ascii"), 1, (0x03, "OC3"), (0x10, "OH"), true),
        ("danfoss@3", "danfoss", None, 3, (13, "over current"), (29, "heat sink temperature"), true),
        ("b800@5", "b800", None, 5, (1, "over-current"), (4, "over-temperature"), false),
    ] {
        let pty = pty_path(&format!("trips-{family}"));
        let sim = simulate(drive, &["--pty", &pty, "--control", "127.0.0.1:0"]);
        let clean = trips(&pty, family, protocol, address);
        assert!(clean["current"].is_null() && clean["history"] == serde_json::json!([]), "{family}: {clean}");
        ok(&drivebus(&pty, family, protocol, address, &["speed", "20"]), "speed 20");
        ok(&drivebus(&pty, family, protocol, address, &["run"]), "run");
        wait_status(&pty, family, protocol, address, "at 20 Hz", |s| {
            s["output_hz"].as_f64().is_some_and(|hz| (hz - 20.0).abs() < 0.05)
        });
        trip(&sim, "over-current");
        wait_status(&pty, family, protocol, address, "tripped", |s| !s["fault"].is_null());
        let t = trips(&pty, family, protocol, address);
        assert_eq!(t["current"]["code"], first.0, "{family}: {t}");
        if matches!(family, "generic" | "toshiba") {
            // P4.02 / FE00: the output frequency at the last trip.
            assert_eq!(t["history"][0]["output_hz"], 20.0, "{family}: {t}");
        }
        ok(&drivebus(&pty, family, protocol, address, &["stop"]), "stop");
        ok(&drivebus(&pty, family, protocol, address, &["reset"]), "reset");
        trip(&sim, "over-temperature");
        let t = trips(&pty, family, protocol, address);
        assert_eq!(t["family"], family, "{t}");
        assert_eq!(t["current"]["code"], second.0, "{family}: {t}");
        assert!(t["current"]["text"].as_str().unwrap_or("").contains(second.1), "{family}: {t}");
        let history = t["history"].as_array().expect("history");
        if logged {
            assert!(history.len() >= 2, "{family}: {t}");
            assert_eq!(history[0]["index"], 1);
            assert_eq!(history[0]["code"], second.0, "{family}: newest first: {t}");
            assert_eq!(history[1]["code"], first.0, "{family}: {t}");
            assert!(history[1]["text"].as_str().unwrap_or("").contains(first.1), "{family}: {t}");
            if matches!(family, "generic" | "toshiba") {
                // The newest trip came at standstill; the older one's frequency is not logged.
                assert_eq!(history[0]["output_hz"], 0.0, "{family}: {t}");
                assert!(history[1]["output_hz"].is_null(), "{family}: {t}");
            }
        } else {
            assert!(history.is_empty(), "{family}: the protocol gives no log: {t}");
            assert!(t["source"].as_str().unwrap_or("").contains("F-13"), "{t}");
        }
        let o = drivebus(&pty, family, protocol, address, &["trips"]);
        ok(&o, "trips as a table");
        assert!(o.stdout.contains("in force") && o.stdout.contains(second.1), "{family}: {}", o.stdout);
        if logged {
            assert!(o.stdout.contains(first.1), "{family}: {}", o.stdout);
        }
        drop(sim);
    }
}
