//! The whole reader, from text to model or to the one error line.

use std::collections::HashSet;
use std::net::IpAddr;
use std::time::Duration;

use drivebus_drive::Family;
use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;

use super::*;

#[test]
fn the_demo_parses_and_has_every_family() {
    let c = GatewayConfig::demo();
    let families: HashSet<Family> = c.drives().map(|(_, d)| d.family).collect();
    assert_eq!(families.len(), 4);
    assert!(c.buses.iter().all(|b| b.port == Port::Virtual));
    assert!(c.drives().count() >= 8);
}

fn err(text: &str) -> String {
    GatewayConfig::from_toml("plant.toml", text).unwrap_err().to_string()
}

/// Asserts that `text` is refused with an error that begins with `start`.
fn refused(text: &str, start: &str) {
    let e = err(text);
    assert!(e.starts_with(start), "{e}");
}

#[test]
fn store_retention_and_size_cap() {
    let c = GatewayConfig::from_toml("plant.toml", "").unwrap();
    assert_eq!(c.store_limits, drivebus_store::Limits::default());
    let c =
        GatewayConfig::from_toml("plant.toml", "[store]\nretention_days = 30\nmax_size_mb = 0\n").unwrap();
    assert_eq!(c.store_limits, drivebus_store::Limits::from_days_and_mb(30, 0));
    assert_eq!(c.store_limits.max_bytes, None);
    refused("[store]\nmax_size_mb = -1\n", "plant.toml:2: field `store.max_size_mb`");
}

#[test]
fn errors_name_the_file_line_and_field() {
    assert!(err("[[bus]]\nname = \"a\"\nport = \"virtual\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"siemens\"\naddress = 1\n").starts_with("plant.toml:6: field `bus.drive.family`: unknown drive family \"siemens\": expected generic, toshiba, danfoss, b800 or a template kind (generic-2000h, "));
    assert_eq!(err("[[bus]]\nname = \"a\"\nport = \"virtual\"\nbaud = 12\n[[bus.drive]]\nname = \"x\"\nfamily = \"b800\"\naddress = 1\n"), "plant.toml:4: field `bus.baud`: 12 is outside 300..1000000");
    refused("[http]\nlisten = \"localhost\"\n", "plant.toml:2: field `http.listen`");
    refused(
        "[[bus]]\nname = \"a\"\nport = \"virtual\"\nspeed = 3\n",
        "plant.toml:4: field `bus.speed`: unknown field `speed`",
    );
    refused("[[bus]]\nname = \"a\"\nport = \"virtual\"\nprotocol = \"b800\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"danfoss\"\naddress = 1\n", "plant.toml:4: field `bus.protocol`: drive \"x\": a danfoss drive does not speak");
    assert_eq!(
        err("[[token]]\nname = \"s\"\ntoken = \"short\"\nrole = \"write\"\n"),
        "plant.toml:3: field `token.token`: a token needs at least 16 characters"
    );
    assert_eq!(
        err("[[token]]\nname = \"ops\"\ntoken = \"aaaaaaaaaaaaaaaa\"\nrole = \"write\"\n\
             [[token]]\nname = \"ops\"\ntoken = \"bbbbbbbbbbbbbbbb\"\nrole = \"read\"\n"),
        "plant.toml:6: field `token.name`: \"ops\": two tokens have the same name; give each its own"
    );
    refused(
        "[opcua]\nhost = \"opc.tcp://gw:4840\"\n",
        "plant.toml:2: field `opcua.host`: \"opc.tcp://gw:4840\": give the host name",
    );
    refused(
        "[opcua]\nmax_sessions_per_user = 0\n",
        "plant.toml:2: field `opcua.max_sessions_per_user`: use 1 or more",
    );
    let o =
        GatewayConfig::from_toml("p.toml", "[opcua]\nhost = \"gw-1.plant.local\"\n").unwrap().opcua.unwrap();
    assert_eq!(
        (o.host.as_deref(), o.max_sessions_per_user, o.insecure_writes),
        (Some("gw-1.plant.local"), 10, false)
    );
    assert_eq!(
        err("[[linkage]]\nleader = \"a\"\nfollower = \"b\"\n"),
        "plant.toml:2: field `linkage.leader`: no drive is named \"a\""
    );
}

#[test]
fn mqtt_settings_are_checked() {
    let ok = GatewayConfig::from_toml(
        "p.toml",
        "[mqtt]\nurl = \"mqtt://10.0.0.9\"\nallow_commands = [\"line-1/*/stop\", \"*/*/*\"]\nallow_plaintext = true\n",
    )
    .unwrap();
    assert_eq!(ok.mqtt.unwrap().allow_commands.len(), 2);
    refused("[mqtt]\nurl = \"tcp://x:1883\"\n", "plant.toml:2: field `mqtt.url`: ");
    refused(
        "[mqtt]\nurl = \"mqtt://x:1883\"\nallow_commands = [\n  \"line-1/*\",\n]\n",
        "plant.toml:4: field `mqtt.allow_commands`: ",
    );
    let e = err("[mqtt]\nurl = \"mqtt://x:1883\"\nallow_commands = [\"a/b/start\"]\n");
    assert!(e.contains("start"), "{e}");
    refused(
        "[mqtt]\nurl = \"mqtt://x:1883\"\ntopic_prefix = \"plant/#\"\n",
        "plant.toml:3: field `mqtt.topic_prefix`: ",
    );
}

#[test]
fn values_of_the_wrong_type_name_their_field() {
    refused(
        "[[bus]]\nname = \"a\"\nport = \"virtual\"\nbaud = \"fast\"\n",
        "plant.toml:4: field `bus.baud`: invalid type",
    );
    refused("[[bus]]\nname = \"a\"\nport = \"virtual\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"b800\"\naddress = 300\n", "plant.toml:7: field `bus.drive.address`: ");
    assert_eq!(
        err("[http]\nmax_body = 0\n"),
        "plant.toml:2: field `http.max_body`: 0 is outside 256..16777216 bytes"
    );
    assert_eq!(
        err("[modbus]\nmax_connections = 0\n"),
        "plant.toml:2: field `modbus.max_connections`: use 1 or more"
    );
}

#[test]
fn fair_use_and_limits_are_checked_and_have_defaults() {
    let bus = "[[bus]]\nname = \"a\"\nport = \"virtual\"\n";
    let drive = "[[bus.drive]]\nname = \"x\"\nfamily = \"generic\"\naddress = 1\n";
    let field = |key: &str, value: &str| err(&format!("{bus}{key} = {value}\n{drive}"));
    assert_eq!(
        field("on_demand_share", "1.5"),
        "plant.toml:4: field `bus.on_demand_share`: 1.5 is not a share of the bus time: use 0.0..1.0 (0.5: half)"
    );
    for key in ["on_demand_queue", "on_demand_per_client"] {
        assert_eq!(field(key, "0"), format!("plant.toml:4: field `bus.{key}`: use 1 or more"));
    }
    assert_eq!(err("[limits]\nper_address = 0\n"), "plant.toml:2: field `limits.per_address`: use 1 or more");
    assert_eq!(
        err("[limits]\nheader_timeout_ms = 5\n"),
        "plant.toml:2: field `limits.header_timeout_ms`: 5 is outside 100..600000"
    );

    let c = GatewayConfig::from_toml("plant.toml", &format!("{bus}{drive}")).unwrap();
    assert_eq!(c.buses[0].on_demand, drivebus_link::FairConfig { share: 0.5, queue: 32, per_client: 8 });
    assert_eq!(c.buses[0].param_cache, Duration::from_millis(200));
    assert_eq!(c.limits, LimitsConfig::default());
    let c = GatewayConfig::from_toml(
        "plant.toml",
        &format!("[limits]\nper_address = 8\nidle_timeout_s = 0\n{bus}on_demand_share = 0.25\nparam_cache_ms = 0\n{drive}"),
    )
    .unwrap();
    assert_eq!((c.limits.per_address, c.limits.idle_timeout), (8, Duration::ZERO));
    assert_eq!((c.buses[0].on_demand.share, c.buses[0].param_cache), (0.25, Duration::ZERO));
}

#[test]
fn the_gateway_name_follows_the_name_rule() {
    assert_eq!(err("name = \"hall 3/west\"\n"), "plant.toml:1: field `name`: use letters, digits, - and _ only (it is the MQTT topic level and client id)");
    let ok = GatewayConfig::from_toml("p.toml", "name = \" hall-3_west \"\n").unwrap();
    assert_eq!(ok.name, "hall-3_west");
    assert_eq!(GatewayConfig::from_toml("p.toml", "").unwrap().name, "drivebus");
}

#[test]
fn a_polled_drive_never_has_the_broadcast_address() {
    let bus = |family: &str, protocol: &str, address: u8| {
        format!("[[bus]]\nname = \"a\"\nport = \"/dev/ttyUSB0\"\nprotocol = \"{protocol}\"\n[[bus.drive]]\nname = \"all\"\nfamily = \"{family}\"\naddress = {address}\n")
    };
    assert_eq!(err(&bus("generic", "modbus-rtu", 0)), "plant.toml:8: field `bus.drive.address`: drive \"all\": a generic drive on modbus-rtu has an address in 1..254, not 0 (0 is the broadcast address: every drive obeys it)");
    // The generic manual allows addresses up to FEH, beyond the Modbus specification's 247.
    assert!(GatewayConfig::from_toml("p.toml", &bus("generic", "modbus-rtu", 254)).is_ok());
    assert!(err(&bus("generic", "modbus-rtu", 255)).contains("1..254"));
    assert!(err(&bus("toshiba", "modbus-rtu", 248)).contains("1..247"));
    // Out of range for the protocol: the address's line and field, whatever the family.
    let e = err(&bus("danfoss", "danfoss-fc", 127));
    assert!(e.starts_with("plant.toml:8: field `bus.drive.address`: ") && e.contains("1..126"), "{e}");
    let e = err(&bus("b800", "b800", 64));
    assert!(e.starts_with("plant.toml:8: field `bus.drive.address`: ") && e.contains("1..63"), "{e}");
    assert!(err(&bus("b800", "b800", 0)).contains("1..63"));
    // A family that does not speak the protocol: the protocol's line.
    refused(&bus("b800", "modbus-rtu", 1), "plant.toml:4: field `bus.protocol`: ");
    assert!(
        GatewayConfig::from_toml("p.toml", &bus("toshiba", "toshiba-binary", 0)).is_ok(),
        "TIP drive 0 exists"
    );
    let e = err(&bus("toshiba", "toshiba-binary", 64));
    assert!(e.starts_with("plant.toml:8: field `bus.drive.address`: ") && e.contains("0..63"), "{e}");
}

#[test]
fn linkage_loops_and_second_rules_are_refused() {
    let drives = "[[bus]]\nname = \"a\"\nport = \"virtual\"\n[[bus.drive]]\nname = \"d1\"\nfamily = \"generic\"\naddress = 1\n[[bus.drive]]\nname = \"d2\"\nfamily = \"generic\"\naddress = 2\n[[bus.drive]]\nname = \"d3\"\nfamily = \"generic\"\naddress = 3\n";
    let rule = |l: &str, f: &str| format!("[[linkage]]\nleader = \"{l}\"\nfollower = \"{f}\"\n");
    let ok = format!("{drives}{}{}", rule("d1", "d2"), rule("d2", "d3"));
    assert_eq!(GatewayConfig::from_toml("p.toml", &ok).unwrap().linkage.len(), 2, "a chain is fine");
    let e = err(&format!("{drives}{}{}", rule("d1", "d2"), rule("d2", "d1")));
    assert!(e.contains("field `linkage.follower`") && e.contains("closes a loop"), "{e}");
    let e = err(&format!("{drives}{}{}{}", rule("d1", "d2"), rule("d2", "d3"), rule("d3", "d1")));
    assert!(e.contains("closes a loop"), "{e}");
    let e = err(&format!("{drives}{}{}", rule("d1", "d3"), rule("d2", "d3")));
    assert!(e.contains("already follows another drive"), "{e}");
}

#[test]
fn duplicate_names_addresses_and_units_are_refused() {
    let two = "[[bus]]\nname = \"a\"\nport = \"virtual\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"b800\"\naddress = 1\n[[bus.drive]]\nname = \"x\"\nfamily = \"b800\"\naddress = 2\n";
    assert!(err(two).contains("two drives are named \"x\""));
    let two = two.replace("address = 2", "address = 1").replacen("name = \"x\"", "name = \"y\"", 1);
    assert!(err(&two).contains("have address 1"));
}

#[test]
fn defaults_follow_the_family() {
    let c = GatewayConfig::from_toml(
        "p.toml",
        "[[bus]]\nname = \"a\"\nport = \"tcp://10.0.0.5:4001\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"toshiba\"\naddress = 1\n",
    )
    .unwrap();
    let b = &c.buses[0];
    assert_eq!(b.port, Port::Tcp("10.0.0.5:4001".into()));
    assert_eq!((b.baud, b.format, b.protocol), (19200, CharFormat::EVEN_8E1, WireProtocol::ToshibaBinary));
    assert_eq!(c.http.listen.to_string(), "127.0.0.1:8080");
    assert_eq!(c.modbus.listen.to_string(), "127.0.0.1:5020");
    assert_eq!(b.drives[0].unit_id, 1);
    let loopback: Vec<IpAddr> = vec!["127.0.0.1".parse().unwrap(), "::1".parse().unwrap()];
    assert_eq!(c.modbus.allow, loopback);
    assert_eq!(c.modbus.max_connections, 16_384);
}

#[test]
fn drives_past_the_247th_get_no_unit() {
    let mut text = String::new();
    for b in 0..9 {
        text += &format!("[[bus]]\nname = \"b{b}\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\n");
        for a in 1..=30 {
            text += &format!("[[bus.drive]]\nname = \"d{b}-{a}\"\nfamily = \"generic\"\naddress = {a}\n");
        }
    }
    let c = GatewayConfig::from_toml("p.toml", &text).unwrap();
    let units: Vec<u8> = c.drives().map(|(_, d)| d.unit_id).collect();
    assert_eq!(units[..247], (1..=247).collect::<Vec<u8>>()[..]);
    assert!(units[247..].iter().all(|&u| u == 0));
}

#[test]
fn modbus_allow_is_explicit_or_loopback() {
    let c = GatewayConfig::from_toml("p.toml", "[modbus]\nallow = []\nread_only = true\n").unwrap();
    assert!(c.modbus.allow.is_empty() && c.modbus.read_only);
    let c = GatewayConfig::from_toml("p.toml", "[modbus]\nallow = [\"10.0.0.7\"]\n").unwrap();
    assert_eq!(c.modbus.allow, vec!["10.0.0.7".parse::<IpAddr>().unwrap()]);
    assert_eq!(
        err("[modbus]\nallow = [\"plc\"]\n"),
        "plant.toml:2: field `modbus.allow`: \"plc\" is not an IP address"
    );
}

#[test]
fn sparkplug_settings_have_defaults_and_are_checked() {
    let c = GatewayConfig::from_toml(
        "p.toml",
        "name = \"hall-1\"\n[sparkplug]\nurls = [\"mqtt://a\", \"mqtt://b:1884\"]\n",
    )
    .unwrap();
    let sp = c.sparkplug.unwrap();
    assert_eq!(sp.urls, ["mqtt://a", "mqtt://b:1884"]);
    assert_eq!(sp.group_id, "drivebus");
    assert_eq!((sp.edge_node_id, sp.primary_host, sp.commands), (None, None, false));
    assert_eq!(
        (sp.store_forward_max, sp.store_forward_max_age_s),
        (SPARKPLUG_STORE_MAX, SPARKPLUG_STORE_MAX_AGE_S)
    );
    let full = "[sparkplug]\nurls = [\"mqtt://a\"]\ngroup_id = \"plant\"\nedge_node_id = \"hall-9\"\n\
                primary_host = \"scada\"\ncommands = true\nusername = \"u\"\npassword = \"p\"\nallow_plaintext = true\n\
                store_forward_max = 10\nstore_forward_max_age_s = 60\nstore_forward_rate = 500\n";
    let sp = GatewayConfig::from_toml("p.toml", full).unwrap().sparkplug.unwrap();
    assert_eq!(sp.edge_node_id.as_deref(), Some("hall-9"));
    assert_eq!(sp.primary_host.as_deref(), Some("scada"));
    assert_eq!(sp.credentials, Some(("u".into(), "p".into())));
    assert!(sp.commands);
    assert_eq!((sp.store_forward_max, sp.store_forward_max_age_s, sp.store_forward_rate), (10, 60, 500));
    refused("[sparkplug]\nurls = []\n", "plant.toml:2: field `sparkplug.urls`: give at least one broker");
    refused(
        "[sparkplug]\nurls = [\"mqtt://a\", \"tcp://b\"]\n",
        "plant.toml:2: field `sparkplug.urls`: \"tcp://b\"",
    );
    refused(
        "[sparkplug]\nurls = [\"mqtt://a\"]\ngroup_id = \"a/b\"\n",
        "plant.toml:3: field `sparkplug.group_id`: ",
    );
    refused(
        "[sparkplug]\nurls = [\"mqtt://a\"]\nprimary_host = \"#\"\n",
        "plant.toml:3: field `sparkplug.primary_host`: ",
    );
    refused(
        "[sparkplug]\nurls = [\"mqtt://a\"]\nstore_forward_max = 0\n",
        "plant.toml:3: field `sparkplug.store_forward_max`: give a number above 0",
    );
    refused(
        "[sparkplug]\nurls = [\"mqtt://a\"]\nusername = \"u\"\n",
        "plant.toml:3: field `sparkplug.username`: give a password",
    );
    let e = err("[sparkplug]\nurl = \"mqtt://a\"\n");
    assert!(e.contains("unknown field `url`"), "{e}");
}

#[test]
fn mqtt_credentials_come_whole_or_not_at_all() {
    let base = "[mqtt]\nurl = \"mqtt://127.0.0.1:1883\"\n";
    let c = GatewayConfig::from_toml("p.toml", &format!("{base}username = \"plant\"\npassword = \"pw\"\n"))
        .unwrap();
    assert_eq!(c.mqtt.unwrap().credentials, Some(("plant".into(), "pw".into())));
    assert_eq!(
        err(&format!("{base}username = \"plant\"\n")),
        "plant.toml:3: field `mqtt.username`: give a password (or password_env) with the user name"
    );
    assert_eq!(
        err(&format!("{base}username = \"plant\"\npassword_env = \"DRIVEBUS_TEST_NO_SUCH_VARIABLE\"\n")),
        "plant.toml:4: field `mqtt.password_env`: the environment variable \"DRIVEBUS_TEST_NO_SUCH_VARIABLE\" is not set"
    );
}

#[test]
fn damaged_files_are_errors_never_panics() {
    // Deterministic damage to the demo file: characters replaced, lines dropped or doubled.
    let mut x: u64 = 0x2545_F491_4F6C_DD1D;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let lines: Vec<&str> = DEMO.lines().collect();
    for _ in 0..2000 {
        let mut text = String::new();
        for l in &lines {
            match next() % 40 {
                0 => {}
                1 => {
                    text.push_str(l);
                    text.push('\n');
                    text.push_str(l);
                    text.push('\n');
                }
                2 => {
                    let mut b: Vec<char> = l.chars().collect();
                    if !b.is_empty() {
                        let i = (next() as usize) % b.len();
                        b[i] = {
                            const DAMAGE: &[u8] = b" =\"[]x0-9.,#\\\t";
                            DAMAGE[(next() as usize) % DAMAGE.len()]
                        } as char;
                    }
                    text.extend(b);
                    text.push('\n');
                }
                _ => {
                    text.push_str(l);
                    text.push('\n');
                }
            }
        }
        let r = std::panic::catch_unwind(|| GatewayConfig::from_toml("d.toml", &text));
        let r = r.unwrap_or_else(|_| panic!("from_toml panicked on:\n{text}"));
        if let Err(e) = r {
            let e = e.to_string();
            assert!(e.starts_with("d.toml"), "{e}");
            assert!(!e.contains('\n'), "one line: {e:?}");
        }
    }
}

#[test]
fn the_configuration_imports_no_front_end() {
    // Only its own files, std and the crates below the gateway: a rule a front end also applies
    // lives here, and the front end imports it.
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src/config");
    let needle = ["crate", "::"].concat();
    let mut files = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        for (i, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            assert!(!code.contains(&needle), "{}:{}: {line}", path.display(), i + 1);
        }
        files += 1;
    }
    assert!(files > 10, "{files} files in {}", dir.display());
}

#[path = "../../tests/tls_support/mod.rs"]
mod tls_support;

#[test]
fn broker_tls_keys_are_checked_with_their_files() {
    let pki = tls_support::TestPki::new("config", &["broker.plant"]);
    let p = tls_support::TestPki::toml;
    for section in ["[mqtt]\nurl", "[sparkplug]\nurls"] {
        let name = if section.starts_with("[mqtt]") { "mqtt" } else { "sparkplug" };
        let url = |u: &str| if name == "mqtt" { format!("\"{u}\"") } else { format!("[\"{u}\"]") };
        let tls = url("mqtts://broker.plant");
        let good = format!(
            "{section} = {tls}\nca_file = \"{}\"\nclient_cert = \"{}\"\nclient_key = \"{}\"\n",
            p(&pki.ca),
            p(&pki.client_cert),
            p(&pki.client_key)
        );
        let c = GatewayConfig::from_toml("plant.toml", &good).unwrap();
        let t = if name == "mqtt" { c.mqtt.unwrap().tls } else { c.sparkplug.unwrap().tls };
        assert_eq!(t.ca_file.as_deref(), Some(pki.ca.as_path()));
        assert_eq!(t.client_key.as_deref(), Some(pki.client_key.as_path()));

        let cases = [
            (
                format!("{section} = {tls}\nca_file = \"/nonexistent/ca.pem\"\n"),
                format!("plant.toml:3: field `{name}.ca_file`: ca_file /nonexistent/ca.pem: cannot read it"),
            ),
            (
                format!("{section} = {tls}\nca_file = \"{}\"\n", p(&pki.client_key)),
                format!("plant.toml:3: field `{name}.ca_file`: ca_file {}: no certificate in it", p(&pki.client_key)),
            ),
            (
                format!("{section} = {tls}\nclient_key = \"{}\"\n", p(&pki.client_key)),
                format!("plant.toml:3: field `{name}.client_key`: client_key needs client_cert"),
            ),
            (
                format!("{section} = {tls}\nclient_cert = \"{}\"\nclient_key = \"{}\"\n", p(&pki.client_cert), p(&pki.server_key)),
                format!("plant.toml:3: field `{name}.client_cert`: client_cert {} and client_key {}: the key is not the certificate's", p(&pki.client_cert), p(&pki.server_key)),
            ),
            (
                format!("{section} = {}\nca_file = \"{}\"\n", url("mqtt://broker.plant"), p(&pki.ca)),
                format!("plant.toml:3: field `{name}.ca_file`: is for TLS: use an mqtts:// broker URL"),
            ),
            (
                format!("{section} = {}\nusername = \"u\"\npassword = \"p\"\n", url("mqtt://10.0.0.9")),
                format!("plant.toml:2: field `{name}.{}`: the broker password would cross the network to 10.0.0.9 in clear: use mqtts://10.0.0.9, or set [{name}] allow_plaintext = true", if name == "mqtt" { "url" } else { "urls" }),
            ),
        ];
        for (text, want) in cases {
            let e = err(&text);
            assert!(e.starts_with(&want), "{e}\nwanted: {want}");
            assert!(!e.contains('\n'), "one line: {e}");
        }
        // The opt-out, and a broker on this machine.
        let plain = format!(
            "{section} = {}\nusername = \"u\"\npassword = \"p\"\nallow_plaintext = true\n",
            url("mqtt://10.0.0.9")
        );
        assert!(GatewayConfig::from_toml("plant.toml", &plain).is_ok());
        let local = format!("{section} = {}\nusername = \"u\"\npassword = \"p\"\n", url("mqtt://127.0.0.1"));
        assert!(GatewayConfig::from_toml("plant.toml", &local).is_ok());
    }
    let e = err("[mqtt]\nurl = \"mqtt://10.0.0.9\"\nallow_commands = [\"*/*/stop\"]\n");
    assert!(e.contains("motor commands would cross the network to 10.0.0.9 in clear"), "{e}");
    let e = err("[sparkplug]\nurls = [\"mqtt://a\"]\ncommands = true\n");
    assert!(e.contains("motor commands would cross the network to a in clear"), "{e}");
}

#[test]
fn https_keys_are_checked_with_their_files() {
    let pki = tls_support::TestPki::new("config-http", &["localhost"]);
    let p = tls_support::TestPki::toml;
    let good =
        format!("[http]\ntls_cert = \"{}\"\ntls_key = \"{}\"\n", p(&pki.server_cert), p(&pki.server_key));
    let c = GatewayConfig::from_toml("plant.toml", &good).unwrap();
    let tls = c.http.tls.unwrap();
    assert_eq!(
        (tls.cert.as_path(), tls.key.as_path()),
        (pki.server_cert.as_path(), pki.server_key.as_path())
    );
    for (text, want) in [
        (
            format!("[http]\ntls_cert = \"{}\"\ntls_key = \"{}\"\n", p(&pki.server_cert), p(&pki.client_key)),
            format!(
                "plant.toml:2: field `http.tls_cert`: tls_cert {} and tls_key {}: the key is not the certificate's",
                p(&pki.server_cert),
                p(&pki.client_key)
            ),
        ),
        (
            format!("[http]\ntls_cert = \"{}\"\ntls_key = \"/nonexistent/key.pem\"\n", p(&pki.server_cert)),
            "plant.toml:3: field `http.tls_key`: tls_key /nonexistent/key.pem: cannot read it".to_string(),
        ),
        (
            format!("[http]\ntls_cert = \"{}\"\ntls_key = \"{}\"\n", p(&pki.server_key), p(&pki.server_key)),
            format!("plant.toml:2: field `http.tls_cert`: tls_cert {}: no certificate in it", p(&pki.server_key)),
        ),
        (
            format!("[http]\ntls_cert = \"{}\"\n", p(&pki.server_cert)),
            "plant.toml:2: field `http.tls_cert`: give tls_key too".to_string(),
        ),
    ] {
        let e = err(&text);
        assert!(e.starts_with(&want), "{e}\nwanted: {want}");
        assert!(!e.contains('\n'), "one line: {e}");
    }
}

#[test]
fn write_tokens_over_plain_http_off_loopback_are_refused_unless_opted_out() {
    let write = "[[token]]\nname = \"scada\"\ntoken = \"0123456789abcdef-w\"\nrole = \"write\"\n";
    let read = "[[token]]\nname = \"view\"\ntoken = \"0123456789abcdef-r\"\nrole = \"read\"\n";
    let e = err(&format!("[http]\nlisten = \"0.0.0.0:8080\"\n{write}"));
    assert_eq!(
        e,
        "plant.toml:2: field `http.listen`: write tokens would cross the network in clear on \
         http://0.0.0.0:8080: give [http] tls_cert and tls_key (HTTPS), listen on 127.0.0.1, or set \
         [http] allow_plaintext = true to accept that"
    );
    for ok in [
        format!("[http]\nlisten = \"0.0.0.0:8080\"\nallow_plaintext = true\n{write}"),
        format!("[http]\nlisten = \"0.0.0.0:8080\"\n{read}"),
        format!("[http]\nlisten = \"127.0.0.1:8080\"\n{write}"),
        format!("[http]\nlisten = \"[::1]:8080\"\n{write}"),
        write.to_string(),
    ] {
        assert!(GatewayConfig::from_toml("plant.toml", &ok).is_ok(), "{ok}");
    }
}

#[test]
fn standby_sets_every_buses_role_and_bad_values_are_refused() {
    let bus = "[[bus]]\nname = \"l\"\nport = \"/dev/ttyUSB0\"\nprotocol = \"modbus-rtu\"\n";
    let c = GatewayConfig::from_toml("plant.toml", bus).unwrap();
    assert_eq!(c.buses[0].role, None, "without [standby]: the only master");
    let c = GatewayConfig::from_toml("plant.toml", &format!("[standby]\nrole = \"standby\"\n{bus}")).unwrap();
    let role = c.buses[0].role.expect("a role");
    assert!(role.standby);
    assert_eq!(role.silence, Duration::from_millis(500));
    let c = GatewayConfig::from_toml("plant.toml", &format!("[standby]\nsilence_ms = 800\n{bus}")).unwrap();
    assert_eq!(c.buses[0].role.map(|r| (r.standby, r.silence)), Some((false, Duration::from_millis(800))));
    let e = err(&format!("[standby]\nrole = \"backup\"\n{bus}"));
    assert!(e.contains("standby.role") && e.contains("\"active\" or \"standby\""), "{e}");
    let e = err(&format!("[standby]\nsilence_ms = 10\n{bus}"));
    assert!(e.contains("standby.silence_ms") && e.contains("50..60000"), "{e}");
    let e = err("[standby]\nrole = \"standby\"\nsilence = 3\n");
    assert!(e.contains("silence"), "{e}");
    // A line polled every second falls silent longer than 500 ms between polls.
    let slow =
        format!("{bus}[[bus.drive]]\nname = \"d\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 1000\n");
    let e = err(&format!("[standby]\nsilence_ms = 500\n{slow}"));
    assert!(e.contains("plant.toml:2") && e.contains("shortest poll_ms 1000"), "{e}");
    assert!(GatewayConfig::from_toml("plant.toml", &format!("[standby]\nsilence_ms = 1500\n{slow}")).is_ok());
    // A Modbus TCP bus has no line to listen to.
    let mbap = "[[bus]]\nname = \"m\"\nport = \"tcp://10.0.0.5:502\"\nprotocol = \"modbus-tcp\"\n";
    let e = err(&format!("[standby]\nrole = \"standby\"\n{mbap}"));
    assert!(e.contains("bus m speaks Modbus TCP"), "{e}");
}
