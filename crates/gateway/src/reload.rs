//! What a configuration reload changes: the running configuration compared with the new one,
//! section by section, before anything is touched. [`Gateway::reload`](crate::core::Gateway::reload)
//! carries the plan out; the plan is also what the log and the audit trail say.

use serde_json::{json, Value};

use crate::config::{BusConfig, DriveConfig, GatewayConfig, OpcUaConfig};

/// The difference between two configurations, as the gateway applies it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plan {
    /// Buses in the new configuration only.
    pub buses_added: Vec<String>,
    /// Buses in the old configuration only.
    pub buses_removed: Vec<String>,
    /// Buses in both whose port, protocol, baud, format, timing or `max_in_flight` changed
    /// (or, on a virtual bus, any of its drives): closed and opened again.
    pub buses_changed: Vec<String>,
    /// Drives added to buses that are kept.
    pub drives_added: Vec<String>,
    /// Drives removed from buses that are kept.
    pub drives_removed: Vec<String>,
    /// Drives of kept buses whose settings (other than the lock) changed: rebuilt, polled anew.
    pub drives_changed: Vec<String>,
    /// Drives whose `locked` changed.
    pub locks_changed: Vec<String>,
    /// The tokens changed.
    pub tokens_changed: bool,
    /// `[modbus] allow` or `read_only` changed.
    pub modbus_rules_changed: bool,
    /// `[http] anonymous_read` changed.
    pub http_rules_changed: bool,
    /// `[opcua] anonymous_read`, `insecure_writes` or `max_sessions_per_user` changed: read at
    /// each login and request, so they apply at once.
    pub opcua_rules_changed: bool,
    /// The linkage rules changed.
    pub linkage_changed: bool,
    /// Settings that changed and need a restart (listeners, store, MQTT, Sparkplug, the
    /// bridges, the Modbus RTU slaves, the gateway's name).
    pub needs_restart: Vec<String>,
}

/// `[opcua]`'s rules (read at each login and request: they apply at once) and the rest (the
/// server is built with it: a restart).
fn opcua_parts(o: &Option<OpcUaConfig>) -> (Option<(bool, bool, usize)>, Option<OpcUaConfig>) {
    let rules = o.as_ref().map(|o| (o.anonymous_read, o.insecure_writes, o.max_sessions_per_user));
    let rest = o.clone().map(|o| OpcUaConfig {
        anonymous_read: false,
        insecure_writes: false,
        max_sessions_per_user: 0,
        ..o
    });
    (rules, rest)
}

/// Whether a bus can keep running as it is (its drives aside, unless it is virtual: a virtual
/// bus's simulated drives are built from its drive list).
fn same_bus(a: &BusConfig, b: &BusConfig) -> bool {
    fn line(
        x: &BusConfig,
    ) -> (
        &crate::config::Port,
        drivebus_proto::protocol::WireProtocol,
        u32,
        drivebus_proto::line::CharFormat,
        Option<std::time::Duration>,
        u8,
        bool,
        bool,
        drivebus_link::Rs485,
    ) {
        (&x.port, x.protocol, x.baud, x.format, x.timeout, x.retries, x.echo, x.strict_t15, x.rs485)
    }
    // The owner's queue and the parameter cache are built with the bus, and so is the owner
    // itself: one request in flight or the pipelined one (`max_in_flight` on modbus-tcp).
    let fair = |x: &BusConfig| (x.on_demand, x.param_cache, x.role, x.max_in_flight);
    let same_drives =
        || a.drives.len() == b.drives.len() && a.drives.iter().zip(&b.drives).all(|(x, y)| same_drive(x, y));
    line(a) == line(b) && fair(a) == fair(b) && (a.port != crate::config::Port::Virtual || same_drives())
}

/// Whether a drive entry can be kept as it is: everything but the lock (applied in place) is
/// the same.
pub fn same_drive(a: &DriveConfig, b: &DriveConfig) -> bool {
    DriveConfig { locked: b.locked, ..a.clone() } == *b
}

/// Compares the running configuration `old` with `new`.
pub fn plan(old: &GatewayConfig, new: &GatewayConfig) -> Plan {
    let mut p = Plan::default();
    for b in &new.buses {
        match old.buses.iter().find(|o| o.name == b.name) {
            None => p.buses_added.push(b.name.clone()),
            Some(o) if !same_bus(o, b) => p.buses_changed.push(b.name.clone()),
            Some(o) => {
                for d in &b.drives {
                    match o.drives.iter().find(|x| x.name == d.name) {
                        None => p.drives_added.push(d.name.clone()),
                        Some(x) if !same_drive(x, d) => p.drives_changed.push(d.name.clone()),
                        Some(_) => {}
                    }
                }
                for x in &o.drives {
                    if !b.drives.iter().any(|d| d.name == x.name) {
                        p.drives_removed.push(x.name.clone());
                    }
                }
            }
        }
    }
    for o in &old.buses {
        if !new.buses.iter().any(|b| b.name == o.name) {
            p.buses_removed.push(o.name.clone());
        }
    }
    for (_, d) in new.drives() {
        if old.drives().any(|(_, o)| o.name == d.name && o.locked != d.locked) {
            p.locks_changed.push(d.name.clone());
        }
    }
    p.tokens_changed = old.tokens != new.tokens;
    p.modbus_rules_changed =
        (&old.modbus.allow, old.modbus.read_only) != (&new.modbus.allow, new.modbus.read_only);
    p.http_rules_changed = old.http.anonymous_read != new.http.anonymous_read;
    p.linkage_changed = old.linkage != new.linkage;
    let (old_opcua, new_opcua) = (opcua_parts(&old.opcua), opcua_parts(&new.opcua));
    // Switched on or off: a restart, not a rule change.
    p.opcua_rules_changed = old_opcua.1 == new_opcua.1 && old_opcua.0 != new_opcua.0;
    let restart = [
        ("http.listen", old.http.listen != new.http.listen),
        ("http.max_body", old.http.max_body != new.http.max_body),
        ("http.tls", old.http.tls != new.http.tls),
        ("modbus.listen", old.modbus.listen != new.modbus.listen),
        ("modbus.max_connections", old.modbus.max_connections != new.modbus.max_connections),
        ("store", old.store != new.store),
        ("store limits", old.store_limits != new.store_limits),
        ("mqtt", old.mqtt != new.mqtt),
        ("opcua", old_opcua.1 != new_opcua.1),
        ("sparkplug", old.sparkplug != new.sparkplug),
        ("name", old.name != new.name),
        ("limits", old.limits != new.limits),
        ("bridge", old.bridges != new.bridges),
        ("modbus_rtu", old.modbus_rtu != new.modbus_rtu),
    ];
    p.needs_restart = restart.iter().filter(|(_, c)| *c).map(|(n, _)| n.to_string()).collect();
    p
}

impl Plan {
    /// Whether nothing changed.
    pub fn is_empty(&self) -> bool {
        *self == Plan::default()
    }

    /// One line for the log: `bus line-2 added; drive fan-3 added; tokens changed`.
    pub fn summary(&self) -> String {
        let mut parts = Vec::new();
        let lists = [
            ("bus", "added", &self.buses_added),
            ("bus", "removed", &self.buses_removed),
            ("bus", "reopened", &self.buses_changed),
            ("drive", "added", &self.drives_added),
            ("drive", "removed", &self.drives_removed),
            ("drive", "rebuilt", &self.drives_changed),
            ("lock", "changed on", &self.locks_changed),
        ];
        for (what, verb, names) in lists {
            if !names.is_empty() {
                parts.push(format!("{what} {verb} {}", names.join(", ")));
            }
        }
        for (changed, what) in [
            (self.tokens_changed, "tokens changed"),
            (self.modbus_rules_changed, "Modbus TCP write rules changed"),
            (self.http_rules_changed, "HTTP rules changed"),
            (self.opcua_rules_changed, "OPC UA rules changed"),
            (self.linkage_changed, "linkage rules changed"),
        ] {
            if changed {
                parts.push(what.to_string());
            }
        }
        if !self.needs_restart.is_empty() {
            parts.push(format!("needs a restart to apply: {}", self.needs_restart.join(", ")));
        }
        if parts.is_empty() {
            "no change".to_string()
        } else {
            parts.join("; ")
        }
    }

    /// The plan as the audit event's detail.
    pub fn to_json(&self) -> Value {
        json!({
            "buses_added": self.buses_added,
            "buses_removed": self.buses_removed,
            "buses_reopened": self.buses_changed,
            "drives_added": self.drives_added,
            "drives_removed": self.drives_removed,
            "drives_rebuilt": self.drives_changed,
            "locks_changed": self.locks_changed,
            "tokens_changed": self.tokens_changed,
            "modbus_rules_changed": self.modbus_rules_changed,
            "http_rules_changed": self.http_rules_changed,
            "opcua_rules_changed": self.opcua_rules_changed,
            "linkage_changed": self.linkage_changed,
            "needs_restart": self.needs_restart,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BASE: &str = r#"
[[token]]
name = "ops"
token = "0123456789abcdef0123"
role = "write"

[[bus]]
name = "line-1"
port = "virtual"
protocol = "modbus-rtu"
[[bus.drive]]
name = "pump-1"
family = "generic"
address = 1

[[bus]]
name = "line-2"
port = "/dev/ttyUSB7"
protocol = "modbus-rtu"
[[bus.drive]]
name = "fan-1"
family = "generic"
address = 1
"#;

    fn cfg(text: &str) -> GatewayConfig {
        GatewayConfig::from_toml("t.toml", text).unwrap()
    }

    #[test]
    fn the_same_file_changes_nothing() {
        let p = plan(&cfg(BASE), &cfg(BASE));
        assert!(p.is_empty());
        assert_eq!(p.summary(), "no change");
    }

    #[test]
    fn a_drive_added_to_a_serial_bus_keeps_the_bus() {
        let more = format!("{BASE}[[bus.drive]]\nname = \"fan-2\"\nfamily = \"generic\"\naddress = 2\n");
        let p = plan(&cfg(BASE), &cfg(&more));
        assert_eq!(p.drives_added, vec!["fan-2"]);
        assert!(p.buses_changed.is_empty(), "{p:?}");
    }

    #[test]
    fn a_max_in_flight_change_reopens_the_modbus_tcp_bus() {
        let tcp = |n: u8| {
            format!(
                "[[bus]]\nname = \"eth\"\nport = \"tcp://10.0.0.5:502\"\nprotocol = \"modbus-tcp\"\n\
                 max_in_flight = {n}\n[[bus.drive]]\nname = \"fan\"\nfamily = \"generic\"\naddress = 1\n"
            )
        };
        let p = plan(&cfg(&tcp(1)), &cfg(&tcp(4)));
        assert_eq!(p.buses_changed, vec!["eth"], "{p:?}");
        assert!(p.drives_changed.is_empty() && p.needs_restart.is_empty(), "{p:?}");
        assert!(plan(&cfg(&tcp(4)), &cfg(&tcp(4))).is_empty());
    }

    #[test]
    fn a_drive_added_to_a_virtual_bus_reopens_it() {
        let more = BASE.replace(
            "[[bus]]\nname = \"line-2\"",
            "[[bus.drive]]\nname = \"pump-2\"\nfamily = \"generic\"\naddress = 2\n\n[[bus]]\nname = \"line-2\"",
        );
        let p = plan(&cfg(BASE), &cfg(&more));
        assert_eq!(p.buses_changed, vec!["line-1"]);
        assert!(p.drives_added.is_empty());
    }

    #[test]
    fn baud_lock_token_and_listener_changes_are_each_named() {
        let changed = BASE
            .replace("port = \"/dev/ttyUSB7\"", "port = \"/dev/ttyUSB7\"\nbaud = 19200")
            .replace("role = \"write\"", "role = \"read\"")
            .replace("address = 1\n\n[[bus]]", "address = 1\nlocked = true\n\n[[bus]]")
            + "[http]\nlisten = \"127.0.0.1:9999\"\n";
        let p = plan(&cfg(BASE), &cfg(&changed));
        assert_eq!(p.buses_changed, vec!["line-2"]);
        assert_eq!(p.locks_changed, vec!["pump-1"]);
        assert!(p.tokens_changed);
        assert_eq!(p.needs_restart, vec!["http.listen"]);
        assert!(p.summary().contains("needs a restart to apply: http.listen"), "{}", p.summary());
    }

    #[test]
    fn opcua_rules_apply_at_once_and_its_listener_needs_a_restart() {
        let open = format!("{BASE}[opcua]\nanonymous_read = true\n");
        let rules = format!(
            "{BASE}[opcua]\nanonymous_read = false\ninsecure_writes = true\nmax_sessions_per_user = 3\n"
        );
        let p = plan(&cfg(&open), &cfg(&rules));
        assert!(p.opcua_rules_changed);
        assert!(p.needs_restart.is_empty(), "{:?}", p.needs_restart);
        assert!(p.summary().contains("OPC UA rules changed"), "{}", p.summary());
        let moved = format!("{BASE}[opcua]\nanonymous_read = true\nlisten = \"127.0.0.1:4841\"\n");
        let p = plan(&cfg(&open), &cfg(&moved));
        assert!(!p.opcua_rules_changed);
        assert_eq!(p.needs_restart, vec!["opcua"]);
        let host = format!("{BASE}[opcua]\nanonymous_read = true\nhost = \"gw-1.plant.local\"\n");
        assert_eq!(plan(&cfg(&open), &cfg(&host)).needs_restart, vec!["opcua"]);
    }

    #[test]
    fn a_sparkplug_change_needs_a_restart() {
        let with = format!("{BASE}[sparkplug]\nurls = [\"mqtt://127.0.0.1:1883\"]\n");
        let p = plan(&cfg(BASE), &cfg(&with));
        assert_eq!(p.needs_restart, vec!["sparkplug"]);
    }

    #[test]
    fn bridge_and_rtu_slave_changes_are_named_as_needing_a_restart() {
        let with = |functions: &str, baud: u32| {
            format!(
                "{BASE}[[bridge]]\nbus = \"line-2\"\nlisten = \"127.0.0.1:5021\"\n{functions}\n\
                 [[modbus_rtu]]\nport = \"/dev/ttyS1\"\nbaud = {baud}\n"
            )
        };
        assert!(plan(&cfg(&with("", 19200)), &cfg(&with("", 19200))).is_empty());
        let p = plan(&cfg(&with("", 19200)), &cfg(&with("functions = [3]", 9600)));
        assert_eq!(p.needs_restart, vec!["bridge", "modbus_rtu"]);
        assert!(p.summary().contains("needs a restart to apply: bridge, modbus_rtu"), "{}", p.summary());
        let p = plan(&cfg(BASE), &cfg(&with("", 19200)));
        assert_eq!(p.needs_restart, vec!["bridge", "modbus_rtu"]);
    }

    #[test]
    fn a_bus_removed_and_one_added() {
        let other = BASE.replace("name = \"line-2\"", "name = \"line-3\"");
        let p = plan(&cfg(BASE), &cfg(&other));
        assert_eq!(p.buses_added, vec!["line-3"]);
        assert_eq!(p.buses_removed, vec!["line-2"]);
    }
}
