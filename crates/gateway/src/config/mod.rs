//! The gateway's configuration: one TOML file naming the buses, the drives on them, the
//! listeners, the tokens, the linkage rules and the store. Every error names the file, the
//! line and the field, and nothing starts until the whole file is right.
//!
//! [`GatewayConfig::from_toml`] reads in three steps, a file each:
//! - the file schema (`file.rs`): TOML reads the text into the `File*` sections, each value with
//!   its place; a value of the wrong type or an unknown key stops here;
//! - one check per section, in the section's file (`http.rs`, `modbus.rs`, `token.rs`,
//!   `name.rs`, `bus.rs` with `drive.rs`, `linkage.rs`, `mqtt.rs`, `sparkplug.rs`, `store.rs`,
//!   `opcua.rs`, `limits.rs`, `bridge.rs`, `modbus_rtu.rs`), in that order: each turns its
//!   section into its part of the model or returns the first error, through `ctx.rs` (the line
//!   and field of a value, the checks several sections share);
//! - the checked model (`model.rs`): [`GatewayConfig`] and its parts, what the rest of the
//!   gateway uses.
//!
//! The rules a front end also applies at run time (an MQTT URL, topic prefix and command
//! pattern, a Sparkplug id) live in their section's file here, and the front end imports them:
//! the configuration depends on no front end.
//!
//! ```toml
//! name = "hall-1"                       # the gateway's name (MQTT topic tree, dashboards)
//! templates = ["vfd-a.toml"]            # drive templates whose kinds `family` may name (docs/templates.md)
//!
//! [http]
//! listen = "127.0.0.1:8080"
//! anonymous_read = false                # reads without a token
//! hosts = ["scada.plant.local"]         # names in Host besides addresses and localhost
//!
//! [modbus]
//! listen = "127.0.0.1:5020"
//! allow = ["127.0.0.1"]                 # client addresses that may write (default: loopback)
//! read_only = false                     # refuse every write
//! max_connections = 16384               # beyond it, new connections are closed
//!
//! [store]
//! path = "/var/lib/drivebus/drivebus.db" # default: drivebus.db in the state folder
//! retention_days = 365                  # events older are deleted (0: kept for ever)
//! max_size_mb = 1024                    # beyond it the oldest events and trends go (0: no cap)
//! min_free_mb = 64                      # /readyz: the free space its filesystem needs (0: any)
//!
//! [mqtt]                                # optional (docs/mqtt.md)
//! url = "mqtt://127.0.0.1:1883"
//! allow_commands = ["line-1/*/stop"]    # command topics accepted: <bus>/<drive>/<command>, * = any
//!
//! [sparkplug]                           # optional: a Sparkplug B edge node (docs/sparkplug.md)
//! urls = ["mqtt://10.0.0.9:1883"]       # tried in turn
//! primary_host = "scada"                # publish only while this host's STATE is online
//!
//! [[token]]
//! name = "scada"
//! token = "change-me-0123456789"
//! role = "write"                        # read | write
//!
//! [[bus]]
//! name = "line-1"
//! port = "/dev/ttyUSB0"                 # a device, tcp://HOST:PORT, or "virtual" (simulated)
//! protocol = "modbus-rtu"               # or modbus-tcp, with port = "tcp://HOST[:502]"
//! baud = 19200
//! serial = "8E1"
//! timeout_ms = 200
//! retries = 2
//! on_demand_share = 0.5                 # bus time for parameter reads while polls wait
//! on_demand_queue = 32                  # parameter reads waiting; beyond: busy
//! on_demand_per_client = 8              # of them, from one client address
//! param_cache_ms = 200                  # a read this soon after the last is that value
//!
//! [[bus.drive]]
//! name = "pump-1"
//! family = "generic"
//! address = 1
//! poll_ms = 500
//! priority = "high"                     # high | normal | low
//!
//! [[linkage]]
//! leader = "pump-1"
//! follower = "pump-2"
//! ratio = 0.5
//! offset_hz = 2.0
//!
//! [limits]                              # every listener (limits.rs)
//! per_address = 64                      # connections from one address on each listener
//! header_timeout_ms = 5000              # a request header (a frame's rest) within this
//! idle_timeout_s = 300                  # a connection silent this long is closed (0: never)
//! reserve_fds = 256                     # descriptors kept for the other listeners and buses
//!
//! [[bridge]]                            # Modbus TCP straight through to a bus (bridge.rs)
//! bus = "line-1"
//! listen = "127.0.0.1:5021"
//! framing = "mbap"                      # mbap | rtu (RTU over TCP)
//! functions = [1, 2, 3, 4, 5, 6, 15, 16, 23, 43]  # passed to the bus (the default)
//!
//! [[modbus_rtu]]                        # the unified map as a Modbus RTU slave (modbus_rtu.rs)
//! port = "/dev/ttyS1"
//! baud = 19200
//! serial = "8E1"
//! write = false                         # accept writes (read-only unless true)
//! ```

mod broker;
mod bus;
mod ctx;
mod drive;
mod file;
mod http;
mod limits;
mod linkage;
mod modbus;
mod model;
mod name;
mod opcua;
mod standby;
mod store;
pub use store::DEFAULT_FILE as DEFAULT_STORE_FILE;
mod templates;
mod token;

pub mod bridge;
pub mod modbus_rtu;
pub mod mqtt;
pub mod sparkplug;
pub mod state_dir;
pub mod tls;

pub use drivebus_drive::ConfigError;
pub use model::*;
pub use name::valid_name;

use ctx::Ctx;
use file::FileConfig;

/// The embedded demo: a virtual bus per family with simulated drives on each.
pub const DEMO: &str = include_str!("../demo.toml");

/// The file name of the demo's store, in the state folder.
pub const DEMO_STORE: &str = "drivebus-demo.db";

/// Why bus `b` cannot share its line with a standby, if it cannot: a Modbus TCP bus has no
/// line to listen to.
pub fn no_standby(b: &BusConfig) -> Option<String> {
    matches!(b.port, Port::ModbusTcp(_)).then(|| {
        format!(
            "bus {} speaks Modbus TCP: there is no shared line to listen to; a standby needs serial or tcp:// (raw) buses",
            b.name
        )
    })
}

impl GatewayConfig {
    /// The embedded demo configuration.
    /// Its store is `drivebus-demo.db` in the state folder ([`state_dir`]), never in the
    /// working directory; without a state folder it keeps none.
    pub fn demo() -> Self {
        // The embedded file is checked by a test; a failure here is a build defect.
        let mut config =
            GatewayConfig::from_toml("(embedded demo)", DEMO).unwrap_or_else(|e| panic!("demo config: {e}"));
        config.store = state_dir::state_dir().ok().map(|d| d.join(DEMO_STORE));
        config
    }

    /// Reads a configuration; errors name `file`, the line and the field.
    pub fn from_toml(file: &str, text: &str) -> Result<Self, ConfigError> {
        let cx = Ctx { file, text };
        let raw: FileConfig = toml::from_str(text).map_err(|e| cx.toml_error(&e))?;
        // First: the drives' families may be the templates' kinds.
        let templates = templates::check(&cx, &raw.templates)?;
        let http = http::check(&cx, &raw.http)?;
        let modbus = modbus::check(&cx, &raw.modbus)?;
        let tokens = token::check(&cx, &raw.token)?;
        http::check_plaintext(&cx, &raw.http, &http, &tokens)?;
        let name = name::check(&cx, &raw.name)?;
        let mut buses = bus::check(&cx, &raw.bus)?;
        let role = raw.standby.as_ref().map(|s| standby::check(&cx, s)).transpose()?;
        if let (Some(s), Some(r)) = (&raw.standby, &role) {
            standby::check_polls(&cx, s, r, &buses)?;
        }
        for b in &mut buses {
            b.role = role;
        }
        let linkage = linkage::check(&cx, &raw.linkage, &buses)?;
        let mqtt = raw.mqtt.map(|m| mqtt::check(&cx, m)).transpose()?;
        let sparkplug = raw.sparkplug.map(|sp| sparkplug::check(&cx, sp)).transpose()?;
        let store_min_free_mb = raw.store.min_free_mb;
        let (store, store_limits) = store::check(&cx, raw.store, state_dir::state_dir())?;
        let opcua = opcua::check(&cx, &raw.opcua, &http)?;
        let limits = limits::check(&cx, &raw.limits)?;
        let bridges = bridge::check(&cx, &raw.bridge, &buses)?;
        let modbus_rtu = modbus_rtu::check(&cx, &raw.modbus_rtu)?;
        Ok(GatewayConfig {
            name,
            templates,
            http,
            modbus,
            store,
            store_limits,
            store_min_free_mb,
            tokens,
            buses,
            linkage,
            mqtt,
            opcua,
            bridges,
            modbus_rtu,
            sparkplug,
            limits,
        })
    }
}

#[cfg(test)]
mod tests;
