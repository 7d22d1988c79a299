//! Drive templates: the shipped generic template against the built-in generic profile on the
//! same simulated drive (the same bytes on the wire, the same status), every shipped template
//! checked, and an error for each kind of bad field, with its line.

mod support;

use std::time::Duration;

use drivebus_drive::profile::generic::{GenericProfile, GenericProtocol};
use drivebus_drive::profile::{DriveError, Operation, Outcome, Profile};
use drivebus_drive::template::{self, Template};
use drivebus_drive::{Family, Storage};
use drivebus_proto::modbus::ascii::ModbusAscii;
use drivebus_proto::modbus::rtu::ModbusRtu;
use drivebus_proto::Codec;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::family::generic as sim;
use drivebus_sim::model::Trip;
use support::{drive_mut, wait};

const GAP: Duration = Duration::from_millis(10);

fn line(protocol: sim::GenericProtocol) -> VirtualLine {
    let format = Family::Generic.serial_default(protocol.wire()).1;
    support::line_with(9600, format, &[1], |a, now| sim::GenericDrive::new(a, protocol, now))
}

fn generic_template() -> Family {
    "generic-2000h".parse().expect("the shipped generic template is a kind")
}

/// Runs `op` through `p` on `line`: the outcome and the requests it sent.
fn run<C: Codec>(
    line: &mut VirtualLine,
    p: &dyn Profile,
    op: &Operation,
) -> (Result<Outcome, DriveError>, Vec<Vec<u8>>) {
    run_counting::<C>(line, p, op, &mut 0)
}

/// [`run`], adding the bytes of the replies to `replied`.
fn run_counting<C: Codec>(
    line: &mut VirtualLine,
    p: &dyn Profile,
    op: &Operation,
    replied: &mut usize,
) -> (Result<Outcome, DriveError>, Vec<Vec<u8>>) {
    match p.plan(op) {
        Ok(plan) => support::execute(plan, |x| {
            let reply = support::transact::<C>(line, x, GAP);
            *replied += reply.as_ref().map_or(0, Vec::len);
            reply
        }),
        Err(e) => (Err(e), Vec::new()),
    }
}

/// The same operations through the built-in profile and the template, each on its own
/// simulated drive started alike: the same requests and the same results, step by step.
fn same_traffic<C: Codec>(built_in: sim::GenericProtocol, protocol: GenericProtocol) -> usize {
    let (mut a, mut b) = (line(built_in), line(built_in));
    let generic = GenericProfile::new(1, protocol).unwrap();
    let templated = drivebus_drive::profile::for_drive(generic_template(), protocol.wire(), 1).unwrap();
    let ops = [
        Operation::Status,
        Operation::Reverse,
        Operation::SetSpeed(30.0),
        Operation::Run,
        Operation::Status,
        Operation::Reverse,
        Operation::Status,
        Operation::ReadParam("P0.04".into()),
        Operation::WriteParam { name: "P0.05".into(), raw: 4000, storage: Storage::Eeprom },
        Operation::SetSpeed(45.0),
        Operation::Jog,
        Operation::Stop,
        Operation::Status,
        Operation::Reset,
        Operation::Run,
        Operation::Status,
    ];
    let mut bytes = 0;
    for (i, op) in ops.iter().enumerate() {
        if i == 13 {
            drive_mut(&mut a, 1).core_mut().model.trip_now(Trip::External);
            drive_mut(&mut b, 1).core_mut().model.trip_now(Trip::External);
            let (sa, _) = run::<C>(&mut a, &generic, &Operation::Status);
            let (sb, _) = run::<C>(&mut b, &*templated, &Operation::Status);
            assert_eq!(sa, sb, "a tripped drive's status");
            assert!(
                matches!(sa, Ok(Outcome::Status(ref s)) if s.fault.as_ref().is_some_and(|f| f.text == "external fault")),
                "{sa:?}"
            );
        }
        let (mut replied_a, mut replied_b) = (0, 0);
        let (ra, xa) = run_counting::<C>(&mut a, &generic, op, &mut replied_a);
        let (rb, xb) = run_counting::<C>(&mut b, &*templated, op, &mut replied_b);
        assert_eq!(xa, xb, "the requests of {op:?}");
        assert_eq!(replied_a, replied_b, "the replies' bytes of {op:?}");
        match (&ra, &rb) {
            // Refusals say the same thing, each in its profile's words.
            (Err(ea), Err(eb)) => {
                assert_eq!(std::mem::discriminant(ea), std::mem::discriminant(eb), "{op:?}: {ea} / {eb}")
            }
            _ => assert_eq!(ra, rb, "the result of {op:?}"),
        }
        if *op == Operation::Status {
            bytes = xa.iter().map(Vec::len).sum();
            eprintln!(
                "status refresh in {}: {} requests, {bytes} bytes out, {replied_a} bytes back (built-in and template alike)",
                C::NAME,
                xa.len()
            );
        }
        wait(&mut a, Duration::from_secs(2));
        wait(&mut b, Duration::from_secs(2));
    }
    bytes
}

#[test]
fn the_generic_template_sends_what_the_built_in_profile_sends_in_rtu() {
    let bytes = same_traffic::<ModbusRtu>(sim::GenericProtocol::Rtu, GenericProtocol::Rtu);
    // 03 read 2100H..2103H and 03 read 2104H: two requests of 8 bytes.
    assert_eq!(bytes, 16);
}

#[test]
fn the_generic_template_sends_what_the_built_in_profile_sends_in_ascii() {
    let bytes = same_traffic::<ModbusAscii>(sim::GenericProtocol::Ascii, GenericProtocol::Ascii);
    assert_eq!(bytes, 34);
}

#[test]
fn every_shipped_template_checks_and_is_a_kind() {
    let kinds = template::shipped().expect("the shipped templates check");
    assert_eq!(kinds.len(), template::kinds::SHIPPED.len());
    for (family, (file, text)) in kinds.iter().zip(template::kinds::SHIPPED) {
        let t = Template::from_toml_str(file, text).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(family.as_str(), t.kind);
        assert_eq!(family.to_string().parse::<Family>(), Ok(*family));
        assert!(!t.source.is_empty(), "{file} names its source");
        assert_eq!(family.template().unwrap().checked, template::Checked::Simulator, "{file}");
    }
}

#[test]
fn the_generic_template_plans_its_status_in_two_reads() {
    let p = template::profile::TemplateProfile::new(
        generic_template(),
        drivebus_proto::protocol::WireProtocol::ModbusRtu,
        1,
    )
    .unwrap();
    let spans: Vec<(u16, u16)> = p.reads().iter().map(|r| (r.start, r.quantity)).collect();
    assert_eq!(spans, [(0x2100, 4), (0x2104, 1)], "merged up to max_read = 4");
}

const GOOD: &str = r#"kind = "test-drive"
maker = "Test"
model = "T1"
source = "a public manual, table 5"
protocols = ["modbus-rtu"]
[serial]
baud = 19200
format = "8E1"
[status]
running = { register = 100, bit = 0 }
reverse = { register = 100, bit = 1 }
output_hz = { register = 101, scale = 0.1 }
current_a = { register = 102, type = "u32", word_order = "low-first", scale = 0.01 }
[command]
register = 200
run = { bit = 0 }
reverse = { bit = 1 }
reset = { bit = 7 }
[setpoint]
register = 201
full_scale = 0x4000
max_hz = 50.0
[[param]]
name = "acc"
title = "acceleration time"
register = 300
unit = "s"
scale = 0.1
range = [0.1, 3600.0]
default = 10.0
"#;

/// The errors of GOOD with `from` replaced by `to`.
fn errors(from: &str, to: &str) -> Vec<(usize, String)> {
    assert!(GOOD.contains(from), "{from}");
    match Template::from_toml_str("t.toml", &GOOD.replacen(from, to, 1)) {
        Ok(_) => panic!("{to:?} was taken"),
        Err(e) => e.errors,
    }
}

#[test]
fn a_good_template_reads_with_its_scalings() {
    let t = Template::from_toml_str("t.toml", GOOD).unwrap_or_else(|e| panic!("{e}"));
    let sp = t.setpoint.as_ref().unwrap();
    assert!((sp.scale - 50.0 / 16384.0).abs() < 1e-12, "0x4000 = 100 % of 50 Hz");
    let cur = t.status.current_a.as_ref().unwrap();
    assert_eq!(cur.value(&[0x86A0, 0x0001]), 1000.0, "low word first: 0x000186A0 x 0.01");
    assert!(t.status.running.as_ref().unwrap().flag(&[0b01]));
    assert!(!t.status.reverse.as_ref().unwrap().flag(&[0b01]));
    assert_eq!(t.params[0].scale, 1);
    assert_eq!((t.params[0].min, t.params[0].max, t.params[0].default), (1, 36000, 100));
}

#[test]
fn each_kind_of_bad_field_is_named_with_its_line() {
    // A register beyond 16 bits, line 10.
    let e = errors("register = 100, bit = 0", "register = 70000, bit = 0");
    assert_eq!(e[0].0, 10);
    assert!(e[0].1.contains("register 70000 is not a Modbus register"), "{e:?}");
    // An unknown type, line 13.
    let e = errors("type = \"u32\"", "type = \"u24\"");
    assert_eq!(
        e[0],
        (13, "status.current_a: unknown type \"u24\": use u16, i16, u32, i32 or f32".to_string())
    );
    // Overlapping bits, line 11: two flags on bit 0 of register 100.
    let e = errors("register = 100, bit = 1", "register = 100, bit = 0");
    assert!(e.iter().any(|(l, m)| *l == 11 && m.contains("overlaps")), "{e:?}");
    // Overlapping command bits, line 18.
    let e = errors("reset = { bit = 7 }", "reset = { bit = 0 }");
    assert!(
        e.iter().any(|(l, m)| *l == 18 && m.contains("command.reset: bit 0 overlaps command.run's")),
        "{e:?}"
    );
    // Two numbers in one register, line 12.
    let e = errors("register = 101, scale = 0.1", "register = 102, scale = 0.1");
    assert!(
        e.iter().any(
            |(l, m)| *l == 13 && m.contains("status.current_a: register 102 overlaps status.output_hz's")
        ),
        "{e:?}"
    );
    // A scale of zero, line 12.
    let e = errors("scale = 0.1 }", "scale = 0.0 }");
    assert_eq!(e[0].0, 12);
    assert!(e[0].1.contains("scale of 0"), "{e:?}");
    // A parameter scale that is not a power of ten, and a default outside the range: both
    // reported, in line order.
    let two =
        GOOD.replacen("scale = 0.1\n", "scale = 0.25\n", 1).replacen("register = 201", "register = -1", 1);
    let e = Template::from_toml_str("t.toml", &two).unwrap_err();
    assert_eq!(e.errors.len(), 2, "{e}");
    assert!(e.errors[0].1.contains("setpoint: register -1"), "{e}");
    assert!(e.errors[1].1.contains("scale 0.25 must be a power of ten"), "{e}");
    assert_eq!(e.to_string().lines().count(), 2, "one line per error: {e}");
    assert!(e.to_string().starts_with("t.toml:20: "), "{e}");
    // An unknown field: toml's own error, with its line.
    let e = errors("max_hz = 50.0", "max_hertz = 50.0");
    assert_eq!(e[0].0, 22);
    assert!(e[0].1.contains("unknown field `max_hertz`"), "{e:?}");
    // A built-in family's name.
    let e = errors("kind = \"test-drive\"", "kind = \"toshiba\"");
    assert!(e[0].1.contains("built-in family"), "{e:?}");
    // modbus-tcp is not the drive's protocol.
    let e = errors("protocols = [\"modbus-rtu\"]", "protocols = [\"modbus-tcp\"]");
    assert!(e[0].1.contains("modbus-tcp is the bus's choice"), "{e:?}");
}

#[test]
fn a_template_kind_works_where_a_family_does() {
    let text = GOOD.replace("test-drive", "kind-test-a");
    let t = Template::from_toml_str("a.toml", &text).unwrap();
    let family = template::register(t.clone()).unwrap();
    assert_eq!(template::register(t).unwrap(), family, "the same file twice is one kind");
    assert_eq!("KIND-TEST-A".parse::<Family>(), Ok(family));
    assert_eq!(family.default_protocol(), drivebus_proto::protocol::WireProtocol::ModbusRtu);
    assert_eq!(family.serial_default(family.default_protocol()), (19200, "8E1".parse().unwrap()));
    assert_eq!(family.model(), "Test T1");
    assert_eq!(serde_json_like(family), "kind-test-a");
    let other = Template::from_toml_str("b.toml", &text.replace("T1", "T2")).unwrap();
    let e = template::register(other).unwrap_err();
    assert!(e.contains("kind \"kind-test-a\" is already given by a.toml"), "{e}");
    let catalog = drivebus_drive::Catalog::load(family).unwrap();
    assert_eq!(catalog.get("acc").unwrap().number, 300);
    assert_eq!(catalog.get("300").unwrap().name, "acc", "by register number too");
}

fn serde_json_like(f: Family) -> String {
    // Family serializes as its name (checked through toml, which the crate already has).
    #[derive(serde::Serialize)]
    struct W {
        f: Family,
    }
    let text = toml::to_string(&W { f }).unwrap();
    text.trim().trim_start_matches("f = ").trim_matches('"').to_string()
}

/// A line with the simulated drive of template kind `family` at `address`.
fn template_line(family: Family, address: u8) -> VirtualLine {
    let protocol = family.default_protocol();
    let format = family.serial_default(protocol).1;
    support::line_with(9600, format, &[address], |a, now| {
        drivebus_sim::family::template::TemplateDrive::new(family, a, protocol, now)
    })
}

/// The operations through `p` on `line`, in the protocol `p` speaks.
fn on(line: &mut VirtualLine, p: &dyn Profile, op: Operation) -> Result<Outcome, DriveError> {
    match p.protocol() {
        drivebus_proto::protocol::WireProtocol::ModbusAscii => run::<ModbusAscii>(line, p, &op).0,
        _ => run::<ModbusRtu>(line, p, &op).0,
    }
}

fn status_on(line: &mut VirtualLine, p: &dyn Profile) -> drivebus_drive::profile::DriveStatus {
    support::status_of("Status", on(line, p, Operation::Status))
}

/// Runs the drive to half its top speed and back, reverses it, trips and resets it: the
/// template's profile against the template's simulated drive.
fn round_trip(family: Family) {
    let t = family.template().unwrap();
    let mut line = template_line(family, 3);
    let p = drivebus_drive::profile::for_drive(family, family.default_protocol(), 3).unwrap();
    let s = status_on(&mut line, &*p);
    assert!(!s.running, "{family}: {s:?}");
    let top = t.setpoint.as_ref().and_then(|s| s.max_hz).unwrap_or(50.0);
    let half = (top / 2.0).round();
    support::done("speed", on(&mut line, &*p, Operation::SetSpeed(half)));
    support::done("run", on(&mut line, &*p, Operation::Run));
    wait(&mut line, Duration::from_secs(30));
    let s = status_on(&mut line, &*p);
    assert!(s.running, "{family}: {s:?}");
    // A template without output_hz: the simulated drive's own output frequency.
    let out = s.output_hz.unwrap_or_else(|| drive_mut(&mut line, 1).core_mut().model.output_hz());
    assert!((out - half).abs() <= 0.05, "{family}: at {half} Hz: {s:?} ({out} Hz)");
    let by_sign = t.setpoint.as_ref().is_some_and(|s| s.reverse_negative);
    if by_sign || t.command.as_ref().is_some_and(|c| c.reverse.is_some()) && t.status.reverse.is_some() {
        support::done("reverse", on(&mut line, &*p, Operation::Reverse));
        wait(&mut line, Duration::from_secs(60));
        let s = status_on(&mut line, &*p);
        assert_eq!(s.direction.as_deref(), Some("reverse"), "{family}: {s:?}");
    }
    if t.status.fault.is_some() {
        drive_mut(&mut line, 1).core_mut().model.trip_now(Trip::External);
        let s = status_on(&mut line, &*p);
        let fault = s.fault.expect("a fault");
        assert_eq!(fault.text, t.fault_text(fault.code), "{family}");
        if t.command.as_ref().is_some_and(|c| c.reset.is_some()) {
            support::done("reset", on(&mut line, &*p, Operation::Reset));
            assert_eq!(status_on(&mut line, &*p).fault, None, "{family}");
        }
    }
    support::done("stop", on(&mut line, &*p, Operation::Stop));
    wait(&mut line, Duration::from_secs(60));
    assert!(!status_on(&mut line, &*p).running, "{family}");
    if let Some(def) = t.params.iter().find(|d| !d.read_only) {
        let raw = support::param_of("read", on(&mut line, &*p, Operation::ReadParam(def.name.clone())));
        assert_eq!(raw, def.default, "{family} {}", def.name);
        let new = if def.max > def.default { def.default + 1 } else { def.default - 1 };
        let write = Operation::WriteParam { name: def.name.clone(), raw: new, storage: def.storage };
        support::done("write", on(&mut line, &*p, write));
        let back = support::param_of("read back", on(&mut line, &*p, Operation::ReadParam(def.name.clone())));
        assert_eq!(back, new, "{family} {}", def.name);
    }
}

#[test]
fn every_shipped_template_round_trips_on_its_simulated_drive() {
    for family in template::shipped().unwrap() {
        round_trip(family);
    }
}

#[test]
fn a_bit_command_word_and_a_full_scale_setpoint_round_trip() {
    // GOOD with a fault code register in the same block and a fault list.
    let text = GOOD
        .replace("test-drive", "bits-test")
        .replace("current_a = {", "fault = { register = 104 }\ncurrent_a = {")
        + "[faults]\n7 = \"external fault\"\n";
    let family =
        template::register(Template::from_toml_str("bits.toml", &text).unwrap_or_else(|e| panic!("{e}")))
            .unwrap();
    round_trip(family);
    // What went on the wire for the setpoint: 25 Hz of 50 Hz = 0x2000 (0x4000 = 100 %).
    let mut line = template_line(family, 3);
    let p = drivebus_drive::profile::for_drive(family, family.default_protocol(), 3).unwrap();
    let (r, sent) = run::<ModbusRtu>(&mut line, &*p, &Operation::SetSpeed(25.0));
    support::done("speed", r);
    assert_eq!(&sent[0][..6], [3, 0x06, 0, 201, 0x20, 0x00], "{sent:02X?}");
    let (r, sent) = run::<ModbusRtu>(&mut line, &*p, &Operation::Run);
    support::done("run", r);
    assert_eq!(&sent[0][..6], [3, 0x06, 0, 200, 0, 1], "run sets bit 0");
    let (r, sent) = run::<ModbusRtu>(&mut line, &*p, &Operation::Status);
    support::status_of("status", r);
    assert_eq!(sent.len(), 1, "registers 100..104 in one read: {sent:02X?}");
    assert_eq!(&sent[0][..6], [3, 0x03, 0, 100, 0, 5]);
}

#[test]
fn the_worked_example_of_the_docs_checks_and_does_what_they_say() {
    let doc =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/templates.md")).unwrap();
    let start = doc.find("```toml\nkind = \"fan-b1\"").expect("the example") + "```toml\n".len();
    let text = &doc[start..start + doc[start..].find("```").unwrap()];
    let t = Template::from_toml_str("docs/templates.md", text).unwrap_or_else(|e| panic!("{e}"));
    let family = template::register(t).unwrap();
    let p =
        template::profile::TemplateProfile::new(family, drivebus_proto::protocol::WireProtocol::ModbusRtu, 3)
            .unwrap();
    let spans: Vec<(u16, u16)> = p.reads().iter().map(|r| (r.start, r.quantity)).collect();
    assert_eq!(spans, [(100, 5)], "one read of registers 100..104");
    round_trip(family);
    let mut line = template_line(family, 3);
    let (_, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::SetSpeed(25.0));
    assert_eq!(&sent[0][..6], [3, 0x06, 0, 201, 0x20, 0x00]);
    let (_, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Run);
    assert_eq!(&sent[0][..6], [3, 0x06, 0, 200, 0, 1]);
}

/// GOOD with a latched fault code, a `tripped` flag, a fault history, and `[values]`.
const WITH_VALUES: &str = r#"kind = "values-test"
maker = "Test"
model = "T2"
source = "a public manual, table 6"
protocols = ["modbus-rtu"]
fault_history = ["last", "previous"]
[serial]
baud = 19200
format = "8E1"
[status]
running = { register = 100, bit = 0 }
tripped = { register = 100, bit = 3 }
output_hz = { register = 101, scale = 0.1 }
fault = { register = 400 }
[values]
dc_bus_v = { register = 106, unit = "V" }
power_kw = { register = 107, type = "f32", word_order = "low-first", unit = "kW" }
[command]
register = 200
run = 1
stop = 2
reset = 4
[setpoint]
register = 201
scale = 0.01
max_hz = 50.0
[[param]]
name = "last"
title = "last fault"
register = 400
range = [0, 100]
default = 0
access = "ro"
[[param]]
name = "previous"
title = "previous fault"
register = 411
range = [0, 100]
default = 0
access = "ro"
[faults]
1 = "over-current"
14 = "external fault"
"#;

#[test]
fn the_new_fields_read_and_their_errors_have_lines() {
    let t = Template::from_toml_str("v.toml", WITH_VALUES).unwrap_or_else(|e| panic!("{e}"));
    let names: Vec<(&str, &str)> =
        t.status.extra.iter().map(|x| (x.name.as_str(), x.unit.as_str())).collect();
    assert_eq!(names, [("dc_bus_v", "V"), ("power_kw", "kW")]);
    assert_eq!(t.fault_history, ["last", "previous"]);
    assert_eq!(t.status.tripped.as_ref().unwrap().bit, Some(3));
    let bad = |from: &str, to: &str| {
        assert!(WITH_VALUES.contains(from), "{from}");
        Template::from_toml_str("v.toml", &WITH_VALUES.replacen(from, to, 1)).unwrap_err().errors
    };
    // A fault history naming no parameter, line 6.
    let e = bad("\"previous\"]", "\"prev\"]");
    assert_eq!(e[0].0, 6, "{e:?}");
    assert!(e[0].1.contains("fault_history: \"prev\" is not one of the template's parameters"), "{e:?}");
    // A value named like a status value, line 16.
    let e = bad("dc_bus_v = {", "output_hz = {");
    assert_eq!(e[0].0, 16, "{e:?}");
    assert!(e[0].1.contains("is a [status] value"), "{e:?}");
    // A bad value name, line 16.
    let e = bad("dc_bus_v = {", "DC-Bus = {");
    assert_eq!(e[0].0, 16, "{e:?}");
    assert!(e[0].1.contains("lower-case letters"), "{e:?}");
    // Two values in one register, line 17 (106..107 overlaps dc_bus_v's 106).
    let e = bad("register = 107, type", "register = 106, type");
    assert!(
        e.iter()
            .any(|(l, m)| *l == 17 && m.contains("values.power_kw: register 106 overlaps values.dc_bus_v's")),
        "{e:?}"
    );
    // A unit on one of the six, line 13.
    let e = bad("scale = 0.1 }", "scale = 0.1, unit = \"Hz\" }");
    assert_eq!(e[0].0, 13, "{e:?}");
    assert!(e[0].1.contains("a unit is for [values]"), "{e:?}");
    // tripped overlapping running's bit, line 12.
    let e = bad("register = 100, bit = 3", "register = 100, bit = 0");
    assert!(
        e.iter().any(|(l, m)| *l == 12 && m.contains("status.tripped: bit 0 overlaps status.running's")),
        "{e:?}"
    );
    // An unknown type on a value, line 17.
    let e = bad("type = \"f32\"", "type = \"f64\"");
    assert_eq!(
        e[0],
        (17, "values.power_kw: unknown type \"f64\": use u16, i16, u32, i32 or f32".to_string())
    );
}

#[test]
fn named_values_a_latched_fault_and_the_fault_history_come_from_the_simulated_drive() {
    let family = template::register(Template::from_toml_str("v.toml", WITH_VALUES).unwrap()).unwrap();
    round_trip(family);
    let mut line = template_line(family, 3);
    let p = drivebus_drive::profile::for_drive(family, family.default_protocol(), 3).unwrap();
    let s = status_on(&mut line, &*p);
    let dc = s.values.iter().find(|v| v.name == "dc_bus_v").expect("dc_bus_v");
    assert_eq!((dc.value, dc.unit.as_str()), (540.0, "V"), "the model's DC bus, stopped: {s:?}");
    assert!(s.values.iter().any(|v| v.name == "power_kw" && v.unit == "kW"), "{s:?}");
    // Two trips, each reset: the fault code register keeps the last one, but the drive is not
    // tripped, so no fault is in force; the history lists both, newest first.
    for trip in [Trip::OverCurrent, Trip::External] {
        drive_mut(&mut line, 1).core_mut().model.trip_now(trip);
        let s = status_on(&mut line, &*p);
        assert!(s.fault.is_some(), "{s:?}");
        support::done("reset", on(&mut line, &*p, Operation::Reset));
    }
    let s = status_on(&mut line, &*p);
    assert_eq!(s.fault, None, "reset: register 400 still holds 14, but tripped is clear: {s:?}");
    let raws: Vec<i64> = drivebus_drive::profile::trips::history_reads(family)
        .into_iter()
        .map(|n| support::param_of("history", on(&mut line, &*p, Operation::ReadParam(n))))
        .collect();
    let h = drivebus_drive::profile::trips::history_of(family, &s, &raws);
    let codes: Vec<(usize, u32, &str)> =
        h.entries.iter().map(|e| (e.index, e.code, e.text.as_str())).collect();
    assert_eq!(codes, [(1, 14, "external fault"), (2, 1, "over-current")]);
    assert!(h.source.contains("fault_history last, previous"), "{}", h.source);
}

#[test]
fn f32_and_low_word_first_parameters_are_read_and_written_in_their_coding() {
    let text = GOOD.replace("test-drive", "wide-test").replacen("[[param]]", "[[param]]\nname = \"flow\"\ntitle = \"flow setpoint\"\nregister = 500\ntype = \"f32\"\nword_order = \"low-first\"\nunit = \"m3/h\"\nscale = 0.01\nrange = [0.0, 1000.0]\ndefault = 12.5\n[[param]]\nname = \"count\"\ntitle = \"a signed counter\"\nregister = 510\ntype = \"i32\"\nword_order = \"low-first\"\nrange = [-100000, 100000]\ndefault = -70000\n[[param]]", 1);
    let t = Template::from_toml_str("w.toml", &text).unwrap_or_else(|e| panic!("{e}"));
    let flow = t.params.iter().find(|d| d.name == "flow").unwrap();
    assert_eq!((flow.default, flow.scale), (1250, 2), "12.5 at 0.01");
    assert_eq!(t.param_words(flow, 2025), [0x0000, 0x41A2], "20.25 as f32 0x41A20000, low word first");
    let count = t.params.iter().find(|d| d.name == "count").unwrap();
    assert_eq!(t.param_words(count, -70000), [0xEE90, 0xFFFE], "0xFFFEEE90, low word first");
    assert_eq!(t.param_raw(count, &[0xEE90, 0xFFFE]), -70000);
    let family = template::register(t).unwrap();
    round_trip(family);
    let mut line = template_line(family, 3);
    let p = drivebus_drive::profile::for_drive(family, family.default_protocol(), 3).unwrap();
    let (r, sent) = run::<ModbusRtu>(
        &mut line,
        &*p,
        &Operation::WriteParam { name: "flow".into(), raw: 2025, storage: Storage::Eeprom },
    );
    support::done("write flow", r);
    assert_eq!(&sent[0][..11], [3, 0x10, 0x01, 0xF4, 0, 2, 4, 0x00, 0x00, 0x41, 0xA2], "{sent:02X?}");
    let back = support::param_of("read flow", on(&mut line, &*p, Operation::ReadParam("flow".into())));
    assert_eq!(back, 2025, "20.25 read back");
    let c = support::param_of("read count", on(&mut line, &*p, Operation::ReadParam("count".into())));
    assert_eq!(c, -70000);
    // word_order on a one-register parameter is an error, with its line.
    let bad = text.replacen("type = \"i32\"\nword_order", "type = \"i16\"\nword_order", 1);
    let e = Template::from_toml_str("w.toml", &bad).unwrap_err();
    assert!(e.to_string().contains("parameter count: word_order is for the 32-bit types"), "{e}");
    assert!(
        e.errors.iter().any(|(l, _)| bad.lines().nth(l - 1).is_some_and(|t| t.starts_with("word_order"))),
        "{e}"
    );
}

#[test]
fn the_acs550_template_reads_its_status_in_three_requests() {
    let family: Family = "abb-acs550".parse().expect("shipped");
    let p =
        template::profile::TemplateProfile::new(family, drivebus_proto::protocol::WireProtocol::ModbusRtu, 1)
            .unwrap();
    let spans: Vec<(u16, u16)> = p.reads().iter().map(|r| (r.start, r.quantity)).collect();
    // 40002 REF1 (its sign is the direction), 40004 status word and 40401 LAST FAULT: the
    // operating data 40103... are left out (their resolutions were not confirmed from a public
    // page).
    assert_eq!(spans, [(1, 1), (3, 1), (400, 1)]);
    let mut line = template_line(family, 1);
    let mut replied = 0;
    let (r, sent) = run_counting::<ModbusRtu>(&mut line, &p, &Operation::Status, &mut replied);
    let s = support::status_of("status", r);
    assert!(s.values.is_empty(), "no named values: {s:?}");
    assert_eq!(s.output_hz, None, "{s:?}");
    let asked: usize = sent.iter().map(Vec::len).sum();
    assert_eq!((asked, replied), (24, 21), "3 x 8 bytes asked; 3 x 7 bytes replied");
}

/// A drive whose commands write several registers (a run enable and a start register, a
/// direction register, a reset pulse, a jog over two adjacent registers) and whose setpoint
/// comes with a run enable in the register after it.
const MULTI: &str = r#"kind = "multi-test"
maker = "Test"
model = "M1"
source = "a public manual, table 7"
protocols = ["modbus-rtu"]
[serial]
baud = 19200
format = "8E1"
[status]
output_hz = { register = 23, type = "i16", scale = 0.01 }
reverse = { register = 4 }
fault = { register = 30 }
[command]
run = [{ register = 3, value = 1 }, { register = 5, value = 1 }]
stop = [{ register = 5, value = 0 }]
forward = [{ register = 4, value = 0 }]
reverse = [{ register = 4, value = 1 }]
reset = [{ register = 6, value = 1 }, { register = 6, value = 0 }]
jog = [{ register = 10, value = 1 }, { register = 11, value = 1 }]
[setpoint]
register = 2
full_scale = 10000
max_hz = 50.0
writes = [{ register = 3, value = 1 }]
[faults]
7 = "external fault"
"#;

#[test]
fn commands_over_several_registers_round_trip_on_the_simulated_drive() {
    let family =
        template::register(Template::from_toml_str("multi.toml", MULTI).unwrap_or_else(|e| panic!("{e}")))
            .unwrap();
    round_trip(family);
    let mut line = template_line(family, 3);
    let p = drivebus_drive::profile::for_drive(family, family.default_protocol(), 3).unwrap();
    // The setpoint and the run enable after it: one 10 write of registers 2..3 (25 Hz of 50 Hz
    // is 5000 of 10000).
    let (r, sent) = run::<ModbusRtu>(&mut line, &*p, &Operation::SetSpeed(25.0));
    support::done("speed", r);
    assert_eq!(sent.len(), 1, "{sent:02X?}");
    assert_eq!(&sent[0][..11], [3, 0x10, 0, 2, 0, 2, 4, 0x13, 0x88, 0, 1], "{sent:02X?}");
    // Run: registers 3 and 5 do not touch: two 06 writes, in order.
    let (r, sent) = run::<ModbusRtu>(&mut line, &*p, &Operation::Run);
    support::done("run", r);
    let heads: Vec<&[u8]> = sent.iter().map(|x| &x[..6]).collect();
    assert_eq!(heads, [&[3, 0x06, 0, 3, 0, 1][..], &[3, 0x06, 0, 5, 0, 1][..]]);
    wait(&mut line, Duration::from_secs(30));
    let s = status_on(&mut line, &*p);
    assert!(s.running, "{s:?}");
    assert_eq!((s.output_hz, s.direction.as_deref()), (Some(25.0), Some("forward")), "{s:?}");
    // Reverse reads the direction register, then writes reverse's register.
    let (r, sent) = run::<ModbusRtu>(&mut line, &*p, &Operation::Reverse);
    support::done("reverse", r);
    assert_eq!(&sent.last().unwrap()[..6], [3, 0x06, 0, 4, 0, 1], "{sent:02X?}");
    wait(&mut line, Duration::from_secs(60));
    // A signed output frequency reads negative in reverse; the view shows it with its direction.
    let (r, _) = run::<ModbusRtu>(&mut line, &*p, &Operation::Status);
    let s = support::status_of("status", r);
    assert_eq!((s.output_hz, s.direction.as_deref()), (Some(25.0), Some("reverse")), "{s:?}");
    let words = drive_mut(&mut line, 1).core_mut().model.output_hz();
    assert!((words - 25.0).abs() < 0.01, "the model turns at 25 Hz: {words}");
    // Jog: registers 10 and 11 touch: one 10 write.
    support::done("stop", on(&mut line, &*p, Operation::Stop));
    wait(&mut line, Duration::from_secs(60));
    let (r, sent) = run::<ModbusRtu>(&mut line, &*p, &Operation::Jog);
    support::done("jog", r);
    assert_eq!(sent.len(), 1, "{sent:02X?}");
    assert_eq!(&sent[0][..11], [3, 0x10, 0, 10, 0, 2, 4, 0, 1, 0, 1]);
    assert!(drive_mut(&mut line, 1).core_mut().model.is_jogging(), "the simulated drive jogs");
    // Reset: the same register twice, two writes in order (a pulse).
    support::done("stop", on(&mut line, &*p, Operation::Stop));
    drive_mut(&mut line, 1).core_mut().model.trip_now(Trip::External);
    let (r, sent) = run::<ModbusRtu>(&mut line, &*p, &Operation::Reset);
    support::done("reset", r);
    let heads: Vec<&[u8]> = sent.iter().map(|x| &x[..6]).collect();
    assert_eq!(heads, [&[3, 0x06, 0, 6, 0, 1][..], &[3, 0x06, 0, 6, 0, 0][..]]);
    assert_eq!(status_on(&mut line, &*p).fault, None);
}

#[test]
fn bad_writes_are_named_with_their_lines() {
    let bad = |from: &str, to: &str| {
        assert!(MULTI.contains(from), "{from}");
        match Template::from_toml_str("m.toml", &MULTI.replacen(from, to, 1)) {
            Ok(_) => panic!("{to:?} was taken"),
            Err(e) => e.errors,
        }
    };
    // A register beyond 16 bits in run's second write, line 14.
    let e = bad("{ register = 5, value = 1 }", "{ register = 70000, value = 1 }");
    assert_eq!(
        e,
        [(
            14,
            "command.run: write 2: register 70000 is not a Modbus register (0..65535, 0x0000..0xFFFF)".into()
        )]
    );
    // A value beyond 16 bits, line 15.
    let e = bad("{ register = 5, value = 0 }", "{ register = 5, value = 65536 }");
    assert_eq!(e, [(15, "command.stop: write 1: value 65536 does not fit a register (0..65535)".into())]);
    // An unknown key in a write: toml's own error, on its line.
    let e = bad("{ register = 4, value = 0 }", "{ register = 4, val = 0 }");
    assert_eq!(e[0].0, 16, "{e:?}");
    // A mix of forms.
    let e = bad("stop = [{ register = 5, value = 0 }]", "stop = 7");
    assert!(e.iter().any(|(l, m)| *l == 13 && m.contains("not a mix")), "{e:?}");
    // A command register where every command names its own.
    let e = bad("[command]\n", "[command]\nregister = 9\n");
    assert_eq!(e.len(), 1, "{e:?}");
    assert_eq!(e[0].0, 14);
    assert!(e[0].1.starts_with("command.register: every command here names its own registers"), "{e:?}");
    // Reverse without forward.
    let e = bad("forward = [{ register = 4, value = 0 }]\n", "");
    assert!(e.iter().any(|(l, m)| *l == 13 && m.contains("reverse and forward together")), "{e:?}");
    // The setpoint's writes may not write the setpoint itself, line 24.
    let e = bad("writes = [{ register = 3, value = 1 }]", "writes = [{ register = 2, value = 1 }]");
    assert_eq!(e, [(24, "setpoint.writes: write 1: register 2 is the setpoint's own".into())]);
    // A command writing the setpoint's register.
    let e = bad("stop = [{ register = 5, value = 0 }]", "stop = [{ register = 2, value = 0 }]");
    assert_eq!(
        e,
        [(
            13,
            "command.stop: write 1: register 2 is the setpoint's: give the setpoint under [setpoint]".into()
        )]
    );
    // A value or bit form without its command register.
    let text = GOOD.replacen("register = 200\n", "", 1);
    let e = Template::from_toml_str("t.toml", &text).unwrap_err().errors;
    assert!(e.iter().any(|(_, m)| m.starts_with("[command] needs register")), "{e:?}");
}

/// A drive whose direction is the setpoint's sign (an i16 REF, 20000 = 50 Hz, as the ABB Drives
/// profile's REF1), with a value-form control word.
const SIGNED: &str = r#"kind = "signed-test"
maker = "Test"
model = "S1"
source = "a public manual, table 8"
protocols = ["modbus-rtu"]
[serial]
baud = 9600
format = "8N2"
[status]
running = { register = 3, bit = 2 }
output_hz = { register = 4, type = "i16", scale = 0.1 }
[command]
register = 0
run = 0x7F
stop = 0x76
[setpoint]
register = 1
type = "i16"
full_scale = 20000
max_hz = 50.0
reverse = "negative"
"#;

#[test]
fn a_negative_setpoint_reverses_the_simulated_drive() {
    let family =
        template::register(Template::from_toml_str("signed.toml", SIGNED).unwrap_or_else(|e| panic!("{e}")))
            .unwrap();
    round_trip(family);
    let mut line = template_line(family, 3);
    let p =
        template::profile::TemplateProfile::new(family, drivebus_proto::protocol::WireProtocol::ModbusRtu, 3)
            .unwrap();
    // The status reads the setpoint, then the status word and output frequency (3..4).
    let spans: Vec<(u16, u16)> = p.reads().iter().map(|r| (r.start, r.quantity)).collect();
    assert_eq!(spans, [(1, 1), (3, 2)]);
    // A reverse with the setpoint at 0 has no sign to turn: refused, nothing written.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Reverse);
    assert!(matches!(&r, Err(DriveError::Unsupported(m)) if m.contains("setpoint is 0 Hz")), "{r:?}");
    assert_eq!(sent.len(), 1, "the setpoint read only: {sent:02X?}");
    // 25 Hz: the setpoint read (0, forward), then 10000 written.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::SetSpeed(25.0));
    support::done("speed", r);
    assert_eq!(&sent[0][..6], [3, 0x03, 0, 1, 0, 1]);
    assert_eq!(&sent[1][..6], [3, 0x06, 0, 1, 0x27, 0x10]);
    support::done("run", on(&mut line, &p, Operation::Run));
    wait(&mut line, Duration::from_secs(30));
    let s = status_on(&mut line, &p);
    assert_eq!((s.output_hz, s.direction.as_deref()), (Some(25.0), Some("forward")), "{s:?}");
    // Reverse: the setpoint read and written back negated (-10000 = 0xD8F0).
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Reverse);
    support::done("reverse", r);
    assert_eq!(&sent[1][..6], [3, 0x06, 0, 1, 0xD8, 0xF0], "{sent:02X?}");
    wait(&mut line, Duration::from_secs(60));
    let s = status_on(&mut line, &p);
    assert_eq!((s.output_hz, s.direction.as_deref()), (Some(25.0), Some("reverse")), "{s:?}");
    let m = drive_mut(&mut line, 1).core_mut().model.output_rotation();
    assert_eq!(m, drivebus_sim::model::Rotation::Reverse, "the simulated drive turns in reverse");
    // A new speed keeps the direction: 20 Hz in reverse is -8000 (0xE0C0).
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::SetSpeed(20.0));
    support::done("speed", r);
    assert_eq!(&sent[1][..6], [3, 0x06, 0, 1, 0xE0, 0xC0], "{sent:02X?}");
    // And Reverse turns it forward again (+8000).
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Reverse);
    support::done("reverse", r);
    assert_eq!(&sent[1][..6], [3, 0x06, 0, 1, 0x1F, 0x40], "{sent:02X?}");
    wait(&mut line, Duration::from_secs(60));
    let s = status_on(&mut line, &p);
    assert_eq!((s.output_hz, s.direction.as_deref()), (Some(20.0), Some("forward")), "{s:?}");
}

#[test]
fn a_negative_setpoint_needs_a_signed_type_and_no_reverse_command() {
    let bad = |from: &str, to: &str| {
        assert!(SIGNED.contains(from), "{from}");
        match Template::from_toml_str("s.toml", &SIGNED.replacen(from, to, 1)) {
            Ok(_) => panic!("{to:?} was taken"),
            Err(e) => e.errors,
        }
    };
    let e = bad("type = \"i16\"\nfull", "type = \"u16\"\nfull");
    assert_eq!(e.len(), 1, "{e:?}");
    assert_eq!(e[0].0, 21);
    assert!(e[0].1.starts_with("setpoint.reverse = \"negative\" needs a signed type"), "{e:?}");
    let e = bad("reverse = \"negative\"", "reverse = \"sign\"");
    assert_eq!(e[0].0, 21);
    assert!(e[0].1.contains("the one form is \"negative\""), "{e:?}");
    let e = bad("stop = 0x76\n", "stop = 0x76\nreverse = 0x77\n");
    assert!(e.iter().any(|(l, m)| *l == 12 && m.contains("leave reverse and forward out")), "{e:?}");
}

/// The first six bytes of each request (unit, function, register or start, value or quantity).
fn heads(sent: &[Vec<u8>]) -> Vec<Vec<u8>> {
    sent.iter().map(|x| x[..6].to_vec()).collect()
}

#[test]
fn the_v20_template_runs_by_two_registers_and_reverses_by_a_third() {
    let family: Family = "siemens-v20".parse().expect("shipped");
    let p =
        template::profile::TemplateProfile::new(family, drivebus_proto::protocol::WireProtocol::ModbusRtu, 1)
            .unwrap();
    // 40005 (the direction) alone, then 40024...40030 in one read.
    let spans: Vec<(u16, u16)> = p.reads().iter().map(|r| (r.start, r.quantity)).collect();
    assert_eq!(spans, [(4, 1), (23, 7)]);
    let mut line = template_line(family, 1);
    // A status refresh on the wire: 2 requests of 8 bytes; 7 + 19 bytes back.
    let mut replied = 0;
    let (r, sent) = run_counting::<ModbusRtu>(&mut line, &p, &Operation::Status, &mut replied);
    support::status_of("status", r);
    assert_eq!((sent.iter().map(Vec::len).sum::<usize>(), replied), (16, 26));
    // 25 Hz of P2000 = 50 Hz: 50.00 % = 5000 into 40003.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::SetSpeed(25.0));
    support::done("speed", r);
    assert_eq!(heads(&sent), [vec![1, 0x06, 0, 2, 0x13, 0x88]]);
    // Run: RUN ENABLE (40004), then CMD START (40006).
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Run);
    support::done("run", r);
    assert_eq!(heads(&sent), [vec![1, 0x06, 0, 3, 0, 1], vec![1, 0x06, 0, 5, 0, 1]]);
    wait(&mut line, Duration::from_secs(30));
    let s = status_on(&mut line, &p);
    assert!(s.running, "{s:?}");
    assert_eq!((s.output_hz, s.direction.as_deref()), (Some(25.0), Some("forward")), "{s:?}");
    let names: Vec<&str> = s.values.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(names, ["dc_bus_v", "energy_kwh", "motor_rpm", "power_kw", "torque_nm"]);
    assert!(s.values.iter().any(|v| v.name == "dc_bus_v" && v.value > 100.0), "{s:?}");
    // Reverse: 40005 read, then 1 written to it.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Reverse);
    support::done("reverse", r);
    assert_eq!(heads(&sent), [vec![1, 0x03, 0, 4, 0, 1], vec![1, 0x06, 0, 4, 0, 1]]);
    wait(&mut line, Duration::from_secs(60));
    let s = status_on(&mut line, &p);
    // FREQ OUTPUT reads -25.00 Hz on the wire; the view shows 25 Hz in reverse.
    assert_eq!((s.output_hz, s.direction.as_deref()), (Some(25.0), Some("reverse")), "{s:?}");
    // Stop: CMD START = 0 only.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Stop);
    support::done("stop", r);
    assert_eq!(heads(&sent), [vec![1, 0x06, 0, 5, 0, 0]]);
    wait(&mut line, Duration::from_secs(60));
    assert!(!status_on(&mut line, &p).running);
    // Reset: a pulse on FAULT ACK (40007).
    drive_mut(&mut line, 1).core_mut().model.trip_now(Trip::External);
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Reset);
    support::done("reset", r);
    assert_eq!(heads(&sent), [vec![1, 0x06, 0, 6, 0, 1], vec![1, 0x06, 0, 6, 0, 0]]);
    assert_eq!(drive_mut(&mut line, 1).core_mut().model.trip(), None, "the simulated drive was reset");
}

#[test]
fn the_fc51_template_commands_its_fc_profile_control_word() {
    let family: Family = "danfoss-fc51".parse().expect("shipped");
    let p =
        template::profile::TemplateProfile::new(family, drivebus_proto::protocol::WireProtocol::ModbusRtu, 1)
            .unwrap();
    // 16-13, 16-14, the control word read back and the status word: four reads (none touch).
    let spans: Vec<(u16, u16)> = p.reads().iter().map(|r| (r.start, r.quantity)).collect();
    assert_eq!(spans, [(16129, 1), (16139, 1), (49999, 1), (50199, 1)]);
    let mut line = template_line(family, 1);
    // A status refresh on the wire: 4 requests of 8 bytes; 4 replies of 7.
    let mut replied = 0;
    let (r, sent) = run_counting::<ModbusRtu>(&mut line, &p, &Operation::Status, &mut replied);
    support::status_of("status", r);
    assert_eq!((sent.iter().map(Vec::len).sum::<usize>(), replied), (32, 28));
    // 25 Hz of 50 Hz: 0x2000 into 50010 REF.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::SetSpeed(25.0));
    support::done("speed", r);
    assert_eq!(heads(&sent), [vec![1, 0x06, 0xC3, 0x59, 0x20, 0x00]]);
    // Run: 0x043C with bit 6 (start) set into 50000 CTW.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Run);
    support::done("run", r);
    assert_eq!(heads(&sent), [vec![1, 0x06, 0xC3, 0x4F, 0x04, 0x7C]]);
    wait(&mut line, Duration::from_secs(30));
    let s = status_on(&mut line, &p);
    assert!(s.running, "{s:?}");
    assert_eq!((s.output_hz, s.direction.as_deref()), (Some(25.0), Some("forward")), "{s:?}");
    // Reverse: bit 15 added to the word as last written.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Reverse);
    support::done("reverse", r);
    assert_eq!(heads(&sent).last().unwrap(), &[1, 0x06, 0xC3, 0x4F, 0x84, 0x7C]);
    wait(&mut line, Duration::from_secs(60));
    let s = status_on(&mut line, &p);
    assert_eq!(s.direction.as_deref(), Some("reverse"), "{s:?}");
    // Stop: bit 6 cleared, the rest kept.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Stop);
    support::done("stop", r);
    assert_eq!(heads(&sent), [vec![1, 0x06, 0xC3, 0x4F, 0x84, 0x3C]]);
}

/// The status refresh through `p`: its outcome, the requests and the replies, byte for byte.
fn status_bytes(
    line: &mut VirtualLine,
    p: &dyn Profile,
) -> (drivebus_drive::profile::DriveStatus, Vec<Vec<u8>>, Vec<Vec<u8>>) {
    let mut replies = Vec::new();
    let plan = p.plan(&Operation::Status).expect("a status plan");
    let (r, sent) = support::execute(plan, |x| {
        let reply = support::transact::<ModbusRtu>(line, x, GAP);
        replies.push(reply.clone().unwrap_or_default());
        reply
    });
    (support::status_of("status", r), sent, replies)
}

#[test]
fn the_optidrive_e3_template_reads_its_packed_status_word_and_commands_bit_0() {
    let family: Family = "invertek-optidrive-e3".parse().expect("shipped");
    let t = family.template().unwrap();
    assert_eq!((t.baud, t.serial_default(t.protocols[0]).1.to_string().as_str()), (115200, "8N1"));
    let p =
        template::profile::TemplateProfile::new(family, drivebus_proto::protocol::WireProtocol::ModbusRtu, 1)
            .unwrap();
    // Registers 6...8 (status word, output frequency, current) and 22...24 (speed reference,
    // DC bus, heatsink): two reads of three.
    let spans: Vec<(u16, u16)> = p.reads().iter().map(|r| (r.start, r.quantity)).collect();
    assert_eq!(spans, [(5, 3), (21, 3)]);
    let mut line = template_line(family, 1);
    // A status refresh on the wire: 2 requests of 8 bytes; 2 replies of 11.
    let (s, sent, replies) = status_bytes(&mut line, &p);
    assert!(!s.running, "{s:?}");
    assert_eq!(
        sent,
        [
            vec![0x01, 0x03, 0x00, 0x05, 0x00, 0x03, 0x15, 0xCA],
            vec![0x01, 0x03, 0x00, 0x15, 0x00, 0x03, 0x14, 0x0F]
        ]
    );
    assert_eq!(replies.iter().map(Vec::len).collect::<Vec<_>>(), [11, 11]);
    // 25 Hz: 250 (Hz x10) into register 2.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::SetSpeed(25.0));
    support::done("speed", r);
    assert_eq!(sent, [vec![0x01, 0x06, 0x00, 0x01, 0x00, 0xFA, 0x58, 0x49]]);
    // Run: bit 0 (run enable) of register 1.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Run);
    support::done("run", r);
    assert_eq!(sent, [vec![0x01, 0x06, 0x00, 0x00, 0x00, 0x01, 0x48, 0x0A]]);
    wait(&mut line, Duration::from_secs(30));
    let (s, _, replies) = status_bytes(&mut line, &p);
    assert!(s.running, "{s:?}");
    assert_eq!((s.output_hz, s.setpoint_hz, s.direction.as_deref()), (Some(25.0), Some(25.0), None), "{s:?}");
    // Register 6 running: status byte bit 0, no error code; register 7: 250.
    assert_eq!(replies[0][3..7], [0x00, 0x01, 0x00, 0xFA], "{replies:?}");
    let names: Vec<&str> = s.values.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(names, ["dc_bus_v", "heatsink_c"]);
    assert!(s.values.iter().any(|v| v.name == "dc_bus_v" && v.value > 100.0), "{s:?}");
    // Stop: bit 0 cleared.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Stop);
    support::done("stop", r);
    assert_eq!(sent, [vec![0x01, 0x06, 0x00, 0x00, 0x00, 0x00, 0x89, 0xCA]]);
    wait(&mut line, Duration::from_secs(60));
    assert!(!status_on(&mut line, &p).running);
    // An external trip: register 6 holds 11 in its high byte and the tripped bit (1) in its low.
    drive_mut(&mut line, 1).core_mut().model.trip_now(Trip::External);
    let (s, _, replies) = status_bytes(&mut line, &p);
    assert_eq!(replies[0][3..5], [0x0B, 0x02], "{replies:?}");
    let fault = s.fault.clone().expect("tripped");
    assert_eq!((fault.code, fault.text.as_str()), (11, "external trip"), "{s:?}");
    // Reset: bit 2 set, then cleared.
    let (r, sent) = run::<ModbusRtu>(&mut line, &p, &Operation::Reset);
    support::done("reset", r);
    assert_eq!(
        sent,
        [
            vec![0x01, 0x06, 0x00, 0x00, 0x00, 0x04, 0x88, 0x09],
            vec![0x01, 0x06, 0x00, 0x00, 0x00, 0x00, 0x89, 0xCA]
        ]
    );
    assert_eq!(drive_mut(&mut line, 1).core_mut().model.trip(), None, "the simulated drive was reset");
    // The error code stays in the high byte after the reset; the tripped bit is clear, so no
    // fault shows.
    let (s, _, replies) = status_bytes(&mut line, &p);
    assert_eq!(replies[0][3..5], [0x0B, 0x00], "{replies:?}");
    assert_eq!(s.fault, None, "{s:?}");
}

/// A drive whose register 5 packs the fault code in its low byte and the state in its high byte
/// (running bit 8, tripped bit 9), with a temperature in the high byte of register 7.
const PACKED: &str = r#"kind = "packed-test"
maker = "Test"
model = "Packed"
source = "written for this test"
protocols = ["modbus-rtu"]
[serial]
baud = 9600
format = "8N1"
[status]
running = { register = 5, bit = 8 }
tripped = { register = 5, bit = 9 }
fault = { register = 5, mask = 0x00FF }
output_hz = { register = 6, scale = 0.1 }
[values]
heatsink_c = { register = 7, mask = 0xFF00, unit = "C" }
[command]
register = 0
run = 1
stop = 0
reset = 4
[setpoint]
register = 1
scale = 0.1
max_hz = 50.0
[faults]
14 = "external fault"
200 = "over-current"
"#;

#[test]
fn a_mask_takes_a_field_of_a_register() {
    let t = Template::from_toml_str("p.toml", PACKED).unwrap_or_else(|e| panic!("{e}"));
    let fault = t.status.fault.as_ref().unwrap();
    assert_eq!(fault.mask, Some(0x00FF));
    assert_eq!(fault.value(&[0x020E]), 14.0, "the low byte of 0x020E");
    assert!(t.status.tripped.as_ref().unwrap().flag(&[0x020E]));
    assert!(!t.status.running.as_ref().unwrap().flag(&[0x020E]));
    let heat = &t.status.extra[0].value;
    assert_eq!(heat.value(&[0x2AFF]), 42.0, "the high byte of 0x2AFF, shifted down");
    assert_eq!(heat.encode(42.0), [0x2A00], "written into its field, the other bits 0");
    assert_eq!(heat.encode(300.0), [0xFF00], "held to the field's largest value");
}

#[test]
fn packed_fields_come_from_the_simulated_drive() {
    let family = template::register(Template::from_toml_str("p.toml", PACKED).unwrap()).unwrap();
    round_trip(family);
    let mut line = template_line(family, 3);
    let p = drivebus_drive::profile::for_drive(family, family.default_protocol(), 3).unwrap();
    let heat = drivebus_drive::profile::round_to(support::model(&mut line, 1).heatsink_c(), 0);
    let s = status_on(&mut line, &*p);
    let v = s.values.iter().find(|v| v.name == "heatsink_c").expect("heatsink_c");
    assert_eq!(v.value, heat, "the high byte of register 7: {s:?}");
    drive_mut(&mut line, 1).core_mut().model.trip_now(Trip::External);
    let s = status_on(&mut line, &*p);
    let fault = s.fault.clone().expect("tripped: the low byte's code");
    assert_eq!((fault.code, fault.text.as_str()), (14, "external fault"), "{s:?}");
    assert!(!s.running, "{s:?}");
}

#[test]
fn bad_masks_are_named_with_their_lines() {
    let bad = |from: &str, to: &str| {
        assert!(PACKED.contains(from), "{from}");
        Template::from_toml_str("p.toml", &PACKED.replacen(from, to, 1)).unwrap_err().errors
    };
    let on = |e: &[(usize, String)], line: usize, text: &str| {
        assert!(e.iter().any(|(l, m)| *l == line && m.contains(text)), "line {line}: {text}: {e:?}")
    };
    // A mask of zero, line 12.
    let e = bad("mask = 0x00FF", "mask = 0");
    on(&e, 12, "status.fault: mask 0x0 takes no bit");
    // Wider than the type, line 12.
    let e = bad("mask = 0x00FF", "mask = 0x1FF00");
    on(&e, 12, "status.fault: mask 0x1FF00 is wider than a U16 (0x1..0xFFFF)");
    // A 32-bit value takes a 32-bit mask.
    let wide = PACKED.replacen("mask = 0xFF00, unit", "type = \"u32\", mask = 0x1FF00, unit", 1);
    let t = Template::from_toml_str("p.toml", &wide).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(t.status.extra[0].value.value(&[0x0001, 0x8000]), 0x180 as f64, "bits 8..16 of 0x00018000");
    // Overlapping a flag's bit, line 12: bits 0..8 take running's bit 8.
    let e = bad("mask = 0x00FF", "mask = 0x01FF");
    on(&e, 12, "status.fault: mask 0x01FF overlaps status.running's (register 5)");
    // A flag's bit inside a field given before it, line 12 (the second of the two).
    let e = bad(
        "tripped = { register = 5, bit = 9 }\nfault = { register = 5, mask = 0x00FF }",
        "fault = { register = 5, mask = 0x00FF }\ntripped = { register = 5, bit = 3 }",
    );
    on(&e, 12, "status.tripped: bit 3 overlaps status.fault's (register 5)");
    // Both bit and mask, line 10.
    let e = bad("register = 5, bit = 8 }", "register = 5, bit = 8, mask = 0x0100 }");
    on(&e, 10, "status.running: give bit or mask, not both");
    // Gaps, line 12.
    let e = bad("mask = 0x00FF", "mask = 0x0F0F");
    on(&e, 12, "status.fault: mask 0x0F0F has gaps");
    // A signed type, line 12.
    let e = bad("mask = 0x00FF", "type = \"i16\", mask = 0x00FF");
    on(&e, 12, "a mask takes an unsigned field");
    // A fault code the field cannot hold, line 27.
    let e = bad("200 = \"over-current\"", "300 = \"over-current\"");
    on(&e, 27, "fault 300: status.fault's mask holds 0..255");
}
