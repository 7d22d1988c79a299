//! The gateway's configuration: one TOML file naming the buses, the drives on them, the
//! listeners, the tokens, the linkage rules and the store. Every error names the file, the
//! line and the field, and nothing starts until the whole file is right.
//!
//! ```toml
//! name = "hall-1"                       # the gateway's name (MQTT topic tree, dashboards)
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
//! path = "drivebus.db"
//! retention_days = 365                  # events older are deleted (0: kept for ever)
//! max_size_mb = 1024                    # beyond it the oldest events and trends go (0: no cap)
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
//! protocol = "modbus-rtu"
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
//!
//! [[modbus_rtu]]                        # the unified map as a Modbus RTU slave (modbus_rtu.rs)
//! port = "/dev/ttyS1"
//! baud = 19200
//! serial = "8E1"
//! write = false                         # accept writes (read-only unless true)
//! ```

use std::collections::HashSet;
use std::fmt;
use std::net::{IpAddr, SocketAddr};
use std::ops::Range;
use std::path::PathBuf;
use std::time::Duration;

use drivebus_drive::Family;
use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;
use serde::Deserialize;
use toml::Spanned;

/// The embedded demo: a virtual bus per family with simulated drives on each.
pub const DEMO: &str = include_str!("demo.toml");

/// Why a configuration is not usable: one line naming the file, the line and the field.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigError(pub String);

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ConfigError {}

/// A whole gateway.
#[derive(Clone, Debug, PartialEq)]
pub struct GatewayConfig {
    /// The gateway's name.
    pub name: String,
    /// The HTTP listener.
    pub http: HttpConfig,
    /// The Modbus TCP listener.
    pub modbus: ModbusConfig,
    /// Where events and trends are kept (`None`: not kept).
    pub store: Option<PathBuf>,
    /// The store's retention and size cap (`[store] retention_days`, `max_size_mb`).
    pub store_limits: drivebus_store::Limits,
    /// Bearer tokens.
    pub tokens: Vec<Token>,
    /// The buses.
    pub buses: Vec<BusConfig>,
    /// Leader/follower rules.
    pub linkage: Vec<Linkage>,
    /// MQTT publishing, if configured.
    pub mqtt: Option<MqttConfig>,
    /// The OPC UA server (`None`: off).
    pub opcua: Option<OpcUaConfig>,
    /// Transparent Modbus bridges to buses (`[[bridge]]`).
    pub bridges: Vec<crate::bridge::BridgeConfig>,
    /// Modbus RTU slaves serving the unified map (`[[modbus_rtu]]`).
    pub modbus_rtu: Vec<crate::modbus_rtu::ModbusRtuConfig>,
    /// The Sparkplug B edge node, if configured.
    pub sparkplug: Option<SparkplugConfig>,
    /// Connection limits and timeouts of every listener (`[limits]`).
    pub limits: crate::limits::LimitsConfig,
}

/// The OPC UA server (docs/opcua.md).
#[derive(Clone, Debug, PartialEq)]
pub struct OpcUaConfig {
    /// Where to listen (`opc.tcp://` there).
    pub listen: SocketAddr,
    /// Whether anonymous sessions may read (default: `[http] anonymous_read`).
    pub anonymous_read: bool,
    /// The server's certificate, key and trusted client certificates (default: `pki` beside the
    /// store).
    pub pki_dir: Option<PathBuf>,
    /// Client certificates (DER files) trusted for signed and encrypted sessions.
    pub trusted_clients: Vec<PathBuf>,
}

/// The HTTP listener.
#[derive(Clone, Debug, PartialEq)]
pub struct HttpConfig {
    /// Where to listen.
    pub listen: SocketAddr,
    /// Whether reads need no token.
    pub anonymous_read: bool,
    /// Largest request body, bytes.
    pub max_body: usize,
    /// Names the gateway is reached by (`Host` header) besides its addresses and `localhost`;
    /// checked when `anonymous_read` is on (`crate::http::host`).
    pub hosts: Vec<String>,
}

/// The Modbus TCP listener.
#[derive(Clone, Debug, PartialEq)]
pub struct ModbusConfig {
    /// Where to listen.
    pub listen: SocketAddr,
    /// Client addresses allowed to write (reads are open to whoever reaches the listener).
    /// Without `allow` in the file: loopback only (127.0.0.1, ::1); `allow = []`: nobody.
    pub allow: Vec<IpAddr>,
    /// Refuse every write.
    pub read_only: bool,
    /// Most connections served at once.
    pub max_connections: usize,
}

/// What a token may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Role {
    /// Read values, events and trends.
    Read,
    /// Also command drives and write parameters.
    Write,
}

/// A bearer token.
#[derive(Clone, Debug, PartialEq)]
pub struct Token {
    /// Who holds it (shown in the audit trail).
    pub name: String,
    /// The secret.
    pub secret: String,
    /// What it may do.
    pub role: Role,
}

/// How a bus is reached.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Port {
    /// A serial device path.
    Serial(String),
    /// A serial device server, raw bytes over TCP.
    Tcp(String),
    /// Simulated drives in this process, one per configured drive.
    Virtual,
}

impl fmt::Display for Port {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Port::Serial(p) => f.write_str(p),
            Port::Tcp(a) => write!(f, "tcp://{a}"),
            Port::Virtual => f.write_str("virtual"),
        }
    }
}

/// One bus.
#[derive(Clone, Debug, PartialEq)]
pub struct BusConfig {
    /// Its name (unique).
    pub name: String,
    /// How it is reached.
    pub port: Port,
    /// The wire protocol.
    pub protocol: WireProtocol,
    /// Baud rate.
    pub baud: u32,
    /// Character format.
    pub format: CharFormat,
    /// Response timeout (`None`: the protocol's default).
    pub timeout: Option<Duration>,
    /// Retries after a timeout or damaged reply.
    pub retries: u8,
    /// Remove the local echo of 2-wire adapters.
    pub echo: bool,
    /// Modbus RTU: discard replies with a silence over t1.5 inside (on-board UARTs only).
    pub strict_t15: bool,
    /// RS-485 direction control on a serial port (`rs485`: off, auto, kernel or rts).
    pub rs485: drivebus_link::Rs485,
    /// How on-demand reads (parameters) share the bus with polling: `on_demand_share`,
    /// `on_demand_queue`, `on_demand_per_client` (docs/gateway.md, "Fair use of a bus").
    pub on_demand: drivebus_link::FairConfig,
    /// A parameter read within this time of the last read of the same parameter is answered
    /// with that value (`param_cache_ms`; zero: always from the drive).
    pub param_cache: Duration,
    /// The drives.
    pub drives: Vec<DriveConfig>,
}

/// Which drive is polled first when several are due.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum PollPriority {
    /// Polled first.
    High,
    /// The default.
    Normal,
    /// Polled last.
    Low,
}

/// One drive.
#[derive(Clone, Debug, PartialEq)]
pub struct DriveConfig {
    /// Its id in the gateway (unique across buses).
    pub name: String,
    /// The family.
    pub family: Family,
    /// Its number on the bus.
    pub address: u8,
    /// Its Modbus TCP unit id (unique; 1..247; 0 = none, for drives past the 247th that were
    /// given no `unit_id`).
    pub unit_id: u8,
    /// How often it is polled.
    pub poll: Duration,
    /// Poll order when several are due.
    pub priority: PollPriority,
    /// Refuse writes from everyone.
    pub locked: bool,
    /// Load on a simulated drive (fraction of rated torque).
    pub load: f64,
}

/// A follower's setpoint is the leader's output frequency times `ratio` plus `offset_hz`.
#[derive(Clone, Debug, PartialEq)]
pub struct Linkage {
    /// The leader's id.
    pub leader: String,
    /// The follower's id.
    pub follower: String,
    /// Multiplier.
    pub ratio: f64,
    /// Added, Hz.
    pub offset_hz: f64,
}

/// MQTT publishing (docs/mqtt.md).
#[derive(Clone, Debug, PartialEq)]
pub struct MqttConfig {
    /// `mqtt://HOST[:PORT]` (port 1883 when not given).
    pub url: String,
    /// Topic root (default `drivebus/<gateway>`).
    pub topic_prefix: Option<String>,
    /// Publish Home Assistant discovery messages.
    pub discovery: bool,
    /// Command topics accepted, as `<bus>/<drive>/<command>` patterns where `*` matches one level
    /// (empty: none).
    pub allow_commands: Vec<String>,
    /// The MQTT client id (default `drivebus-<gateway>`); commands are audited as
    /// `mqtt:<client id>`.
    pub client_id: Option<String>,
    /// User name and password for brokers that ask for them.
    pub credentials: Option<(String, String)>,
}

/// The Sparkplug B edge node (docs/sparkplug.md).
#[derive(Clone, Debug, PartialEq)]
pub struct SparkplugConfig {
    /// Brokers, `mqtt://HOST[:PORT]`, tried in turn when one cannot be reached.
    pub urls: Vec<String>,
    /// The Sparkplug group id.
    pub group_id: String,
    /// The edge node id (default: the gateway's name).
    pub edge_node_id: Option<String>,
    /// The primary host id: publish only while its STATE says online.
    pub primary_host: Option<String>,
    /// Whether DCMD commands reach the drives.
    pub commands: bool,
    /// User name and password for brokers that ask for them.
    pub credentials: Option<(String, String)>,
    /// Most data messages kept while nobody can receive them (oldest dropped first).
    pub store_forward_max: u64,
    /// Data messages older than this are dropped from the queue, seconds.
    pub store_forward_max_age_s: u64,
    /// Kept data messages sent per second at most when the queue drains (a host that comes
    /// back is not flooded, and a broker does not drop what a slow host cannot take).
    pub store_forward_rate: u64,
}

/// The default `param_cache_ms`: a parameter read this soon after the last read of the same
/// parameter is answered with that value.
pub const PARAM_CACHE_MS: u64 = 200;

/// The default Sparkplug group id.
pub const SPARKPLUG_GROUP: &str = "drivebus";
/// The default number of data messages kept for store-and-forward.
pub const SPARKPLUG_STORE_MAX: u64 = 1_000_000;
/// The default age limit of kept data messages, seconds (a day).
pub const SPARKPLUG_STORE_MAX_AGE_S: u64 = 86_400;
/// The default pace of a draining queue, messages per second.
pub const SPARKPLUG_STORE_RATE: u64 = 10_000;

impl SparkplugConfig {
    /// A configuration for broker `url` with every default (what `--sparkplug` makes).
    pub fn new(url: &str) -> SparkplugConfig {
        SparkplugConfig {
            urls: vec![url.to_string()],
            group_id: SPARKPLUG_GROUP.into(),
            edge_node_id: None,
            primary_host: None,
            commands: false,
            credentials: None,
            store_forward_max: SPARKPLUG_STORE_MAX,
            store_forward_max_age_s: SPARKPLUG_STORE_MAX_AGE_S,
            store_forward_rate: SPARKPLUG_STORE_RATE,
        }
    }
}

// ---- the file as written -------------------------------------------------------------------

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileConfig {
    name: Option<Spanned<String>>,
    #[serde(default)]
    http: FileHttp,
    #[serde(default)]
    modbus: FileModbus,
    #[serde(default)]
    store: FileStore,
    #[serde(default)]
    token: Vec<FileToken>,
    #[serde(default)]
    bus: Vec<FileBus>,
    #[serde(default)]
    linkage: Vec<Spanned<FileLinkage>>,
    mqtt: Option<FileMqtt>,
    #[serde(default)]
    opcua: FileOpcUa,
    #[serde(default)]
    bridge: Vec<crate::bridge::FileBridge>,
    #[serde(default)]
    modbus_rtu: Vec<crate::modbus_rtu::FileModbusRtu>,
    sparkplug: Option<FileSparkplug>,
    #[serde(default)]
    limits: FileLimits,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileLimits {
    per_address: Option<Spanned<usize>>,
    header_timeout_ms: Option<Spanned<u64>>,
    idle_timeout_s: Option<u64>,
    reserve_fds: Option<u64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileOpcUa {
    listen: Option<Spanned<String>>,
    #[serde(default)]
    disabled: bool,
    anonymous_read: Option<bool>,
    pki_dir: Option<String>,
    #[serde(default)]
    trusted_clients: Vec<String>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileHttp {
    listen: Option<Spanned<String>>,
    anonymous_read: Option<bool>,
    max_body: Option<Spanned<usize>>,
    #[serde(default)]
    hosts: Vec<Spanned<String>>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileModbus {
    listen: Option<Spanned<String>>,
    allow: Option<Vec<Spanned<String>>>,
    #[serde(default)]
    read_only: bool,
    max_connections: Option<Spanned<usize>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileStore {
    path: Option<String>,
    #[serde(default)]
    disabled: bool,
    #[serde(default = "default_retention_days")]
    retention_days: u64,
    #[serde(default = "default_max_size_mb")]
    max_size_mb: u64,
}

impl Default for FileStore {
    fn default() -> Self {
        FileStore {
            path: None,
            disabled: false,
            retention_days: default_retention_days(),
            max_size_mb: default_max_size_mb(),
        }
    }
}

fn default_retention_days() -> u64 {
    365
}

fn default_max_size_mb() -> u64 {
    1024
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileToken {
    name: Spanned<String>,
    token: Spanned<String>,
    role: Spanned<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileBus {
    name: Spanned<String>,
    port: Spanned<String>,
    protocol: Option<Spanned<String>>,
    baud: Option<Spanned<u32>>,
    serial: Option<Spanned<String>>,
    timeout_ms: Option<u64>,
    retries: Option<u8>,
    #[serde(default)]
    echo: bool,
    #[serde(default)]
    strict_t15: bool,
    rs485: Option<Spanned<String>>,
    on_demand_share: Option<Spanned<f64>>,
    on_demand_queue: Option<Spanned<usize>>,
    on_demand_per_client: Option<Spanned<usize>>,
    param_cache_ms: Option<u64>,
    #[serde(default)]
    drive: Vec<FileDrive>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileDrive {
    name: Spanned<String>,
    family: Spanned<String>,
    address: Spanned<u8>,
    unit_id: Option<Spanned<u8>>,
    poll_ms: Option<Spanned<u64>>,
    priority: Option<Spanned<String>>,
    #[serde(default)]
    locked: bool,
    load: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileLinkage {
    leader: Spanned<String>,
    follower: Spanned<String>,
    ratio: Option<f64>,
    offset_hz: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileMqtt {
    url: Spanned<String>,
    topic_prefix: Option<Spanned<String>>,
    #[serde(default)]
    discovery: bool,
    #[serde(default)]
    allow_commands: Vec<Spanned<String>>,
    client_id: Option<Spanned<String>>,
    username: Option<Spanned<String>>,
    password: Option<Spanned<String>>,
    password_env: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileSparkplug {
    urls: Spanned<Vec<Spanned<String>>>,
    group_id: Option<Spanned<String>>,
    edge_node_id: Option<Spanned<String>>,
    primary_host: Option<Spanned<String>>,
    #[serde(default)]
    commands: bool,
    username: Option<Spanned<String>>,
    password: Option<Spanned<String>>,
    password_env: Option<Spanned<String>>,
    store_forward_max: Option<Spanned<u64>>,
    store_forward_max_age_s: Option<Spanned<u64>>,
    store_forward_rate: Option<Spanned<u64>>,
}

/// The file being read, for errors that name its line and field.
pub(crate) struct Ctx<'a> {
    file: &'a str,
    text: &'a str,
}

impl Ctx<'_> {
    fn line(&self, span: Range<usize>) -> usize {
        self.text[..span.start.min(self.text.len())].lines().count().max(1)
            + usize::from(self.text[..span.start.min(self.text.len())].ends_with('\n'))
    }
    /// `file:line: field `field`: msg`.
    pub(crate) fn err<T>(
        &self,
        span: Range<usize>,
        field: &str,
        msg: impl fmt::Display,
    ) -> Result<T, ConfigError> {
        Err(ConfigError(format!("{}:{}: field `{field}`: {msg}", self.file, self.line(span))))
    }

    /// User name and password of section `section` (`mqtt`, `sparkplug`): both or neither; the
    /// password as written or from the environment variable `password_env`.
    fn credentials(
        &self,
        section: &str,
        at: Range<usize>,
        username: &Option<Spanned<String>>,
        password: &Option<Spanned<String>>,
        password_env: &Option<Spanned<String>>,
    ) -> Result<Option<(String, String)>, ConfigError> {
        let password = match (password, password_env) {
            (Some(p), None) => Some(p.get_ref().clone()),
            (None, Some(var)) => Some(std::env::var(var.get_ref()).or_else(|_| {
                self.err(
                    var.span(),
                    &format!("{section}.password_env"),
                    format!("the environment variable {:?} is not set", var.get_ref()),
                )
            })?),
            (Some(p), Some(_)) => {
                return self.err(
                    p.span(),
                    &format!("{section}.password"),
                    "give password or password_env, not both",
                )
            }
            (None, None) => None,
        };
        match (username, password) {
            (Some(u), Some(p)) => Ok(Some((u.get_ref().clone(), p))),
            (None, None) => Ok(None),
            (Some(u), None) => self.err(
                u.span(),
                &format!("{section}.username"),
                "give a password (or password_env) with the user name",
            ),
            (None, Some(_)) => self.err(at, &format!("{section}.username"), "a password needs a user name"),
        }
    }

    /// The field a value at `span` belongs to (`bus.drive.address`): the key before `=` on its
    /// line, under the last table header above it. `None` when the span is not at a `key =
    /// value` line (a header, a syntax error).
    fn field_at(&self, span: Range<usize>) -> Option<String> {
        let start = span.start.min(self.text.len());
        let line_start = self.text[..start].rfind('\n').map_or(0, |i| i + 1);
        let line_end = self.text[start..].find('\n').map_or(self.text.len(), |i| start + i);
        let (key, _) = self.text[line_start..line_end].split_once('=')?;
        let key = key.trim().trim_matches('"');
        if key.is_empty() || key.starts_with('[') || key.starts_with('#') {
            return None;
        }
        let table = self.text[..line_start]
            .lines()
            .rev()
            .map(str::trim)
            .find(|l| l.starts_with('['))
            .map(|h| h.trim_matches(|c| c == '[' || c == ']').trim().to_string());
        Some(match table {
            Some(t) if !t.is_empty() => format!("{t}.{key}"),
            _ => key.to_string(),
        })
    }
}

/// Reads a listener's `HOST:PORT` field (value, field name, default) with its file position.
type ListenerField<'a> = dyn Fn(&Option<Spanned<String>>, &str, &str) -> Result<SocketAddr, ConfigError> + 'a;

/// `[opcua]`: on unless `disabled = true`; anonymous reads as `[http]` unless said.
fn opcua_section(
    raw: &FileOpcUa,
    http: &HttpConfig,
    addr: &ListenerField<'_>,
) -> Result<Option<OpcUaConfig>, ConfigError> {
    if raw.disabled {
        return Ok(None);
    }
    Ok(Some(OpcUaConfig {
        listen: addr(&raw.listen, "opcua.listen", "127.0.0.1:4840")?,
        anonymous_read: raw.anonymous_read.unwrap_or(http.anonymous_read),
        pki_dir: raw.pki_dir.as_ref().map(PathBuf::from),
        trusted_clients: raw.trusted_clients.iter().map(PathBuf::from).collect(),
    }))
}

/// True for a name of a gateway, bus or drive: letters, digits, `-` and `_`, so it can be an MQTT
/// topic level, a URL path segment and a Prometheus label as it is.
pub fn valid_name(name: &str) -> bool {
    !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// Checks the `[sparkplug]` section.
fn sparkplug_section(cx: &Ctx, sp: FileSparkplug) -> Result<SparkplugConfig, ConfigError> {
    if sp.urls.get_ref().is_empty() {
        return cx.err(sp.urls.span(), "sparkplug.urls", "give at least one broker: [\"mqtt://HOST:PORT\"]");
    }
    for u in sp.urls.get_ref() {
        if let Err(e) = crate::mqtt::parse_url(u.get_ref()) {
            return cx.err(u.span(), "sparkplug.urls", e);
        }
    }
    for (field, id) in
        [("group_id", &sp.group_id), ("edge_node_id", &sp.edge_node_id), ("primary_host", &sp.primary_host)]
    {
        if let Some(id) = id {
            if let Err(e) = crate::sparkplug::check_id(id.get_ref()) {
                return cx.err(id.span(), &format!("sparkplug.{field}"), e);
            }
        }
    }
    let credentials =
        cx.credentials("sparkplug", sp.urls.span(), &sp.username, &sp.password, &sp.password_env)?;
    let positive = |v: &Option<Spanned<u64>>, field: &str, default: u64| match v {
        Some(n) if *n.get_ref() == 0 => cx.err(n.span(), field, "give a number above 0"),
        Some(n) => Ok(*n.get_ref()),
        None => Ok(default),
    };
    Ok(SparkplugConfig {
        urls: sp.urls.into_inner().into_iter().map(Spanned::into_inner).collect(),
        group_id: sp.group_id.map_or_else(|| SPARKPLUG_GROUP.to_string(), Spanned::into_inner),
        edge_node_id: sp.edge_node_id.map(Spanned::into_inner),
        primary_host: sp.primary_host.map(Spanned::into_inner),
        commands: sp.commands,
        credentials,
        store_forward_max: positive(
            &sp.store_forward_max,
            "sparkplug.store_forward_max",
            SPARKPLUG_STORE_MAX,
        )?,
        store_forward_max_age_s: positive(
            &sp.store_forward_max_age_s,
            "sparkplug.store_forward_max_age_s",
            SPARKPLUG_STORE_MAX_AGE_S,
        )?,
        store_forward_rate: positive(
            &sp.store_forward_rate,
            "sparkplug.store_forward_rate",
            SPARKPLUG_STORE_RATE,
        )?,
    })
}

impl GatewayConfig {
    /// The embedded demo configuration.
    pub fn demo() -> Self {
        // The embedded file is checked by a test; a failure here is a build defect.
        GatewayConfig::from_toml("(embedded demo)", DEMO).unwrap_or_else(|e| panic!("demo config: {e}"))
    }

    /// Reads a configuration; errors name `file`, the line and the field.
    pub fn from_toml(file: &str, text: &str) -> Result<Self, ConfigError> {
        let cx = Ctx { file, text };
        let raw: FileConfig = toml::from_str(text).map_err(|e| {
            // toml's messages may take several lines: one line here ("invalid table header:
            // duplicate key `modbus` in document root").
            let msg = e.message().trim().lines().map(str::trim).collect::<Vec<_>>().join(": ");
            match e.span() {
                // A value of the wrong type or range: name its field as the other checks do.
                Some(s) => match cx.field_at(s.clone()) {
                    Some(field) => ConfigError(format!("{file}:{}: field `{field}`: {msg}", cx.line(s))),
                    None => ConfigError(format!("{file}:{}: {msg}", cx.line(s))),
                },
                None => ConfigError(format!("{file}: {msg}")),
            }
        })?;

        let addr =
            |s: &Option<Spanned<String>>, field: &str, default: &str| -> Result<SocketAddr, ConfigError> {
                match s {
                    None => Ok(default.parse().expect("default listener")),
                    Some(s) => s.get_ref().parse().or_else(|_| {
                        cx.err(
                            s.span(),
                            field,
                            format!("{:?} is not HOST:PORT (e.g. 127.0.0.1:8080)", s.get_ref()),
                        )
                    }),
                }
            };
        let http = HttpConfig {
            listen: addr(&raw.http.listen, "http.listen", "127.0.0.1:8080")?,
            anonymous_read: raw.http.anonymous_read.unwrap_or(false),
            max_body: match &raw.http.max_body {
                Some(m) if !(256..=16 << 20).contains(m.get_ref()) => {
                    return cx.err(
                        m.span(),
                        "http.max_body",
                        format!("{} is outside 256..16777216 bytes", m.get_ref()),
                    )
                }
                Some(m) => *m.get_ref(),
                None => 64 * 1024,
            },
            hosts: {
                let mut hosts = Vec::new();
                for h in &raw.http.hosts {
                    let name = h.get_ref().trim();
                    if name.is_empty() || name.contains([':', '/', ' ', '[', ']', '@']) {
                        return cx.err(
                            h.span(),
                            "http.hosts",
                            format!(
                                "{:?}: give a host name alone (scada.plant.local), without scheme or port",
                                h.get_ref()
                            ),
                        );
                    }
                    hosts.push(name.to_ascii_lowercase());
                }
                hosts
            },
        };
        let allow = match &raw.modbus.allow {
            None => vec![IpAddr::from([127, 0, 0, 1]), IpAddr::from(std::net::Ipv6Addr::LOCALHOST)],
            Some(list) => {
                let mut allow = Vec::new();
                for a in list {
                    allow.push(a.get_ref().parse::<IpAddr>().or_else(|_| {
                        cx.err(a.span(), "modbus.allow", format!("{:?} is not an IP address", a.get_ref()))
                    })?);
                }
                allow
            }
        };
        let modbus = ModbusConfig {
            listen: addr(&raw.modbus.listen, "modbus.listen", "127.0.0.1:5020")?,
            allow,
            read_only: raw.modbus.read_only,
            max_connections: match &raw.modbus.max_connections {
                None => 16_384,
                Some(m) if *m.get_ref() == 0 => {
                    return cx.err(m.span(), "modbus.max_connections", "use 1 or more")
                }
                Some(m) => *m.get_ref(),
            },
        };

        let mut tokens = Vec::new();
        for t in &raw.token {
            let role = match t.role.get_ref().as_str() {
                "read" => Role::Read,
                "write" => Role::Write,
                other => return cx.err(t.role.span(), "token.role", format!("{other:?}: use read or write")),
            };
            if t.token.get_ref().len() < 16 {
                return cx.err(t.token.span(), "token.token", "a token needs at least 16 characters");
            }
            if tokens.iter().any(|x: &Token| x.secret == *t.token.get_ref()) {
                return cx.err(t.token.span(), "token.token", "two tokens have the same secret");
            }
            tokens.push(Token { name: t.name.get_ref().clone(), secret: t.token.get_ref().clone(), role });
        }

        let gateway_name = match &raw.name {
            None => "drivebus".to_string(),
            Some(n) => {
                let name = n.get_ref().trim().to_string();
                if !valid_name(&name) {
                    return cx.err(
                        n.span(),
                        "name",
                        "use letters, digits, - and _ only (it is the MQTT topic level and client id)",
                    );
                }
                name
            }
        };
        let mut buses = Vec::new();
        let mut names = HashSet::new();
        let mut units = HashSet::new();
        let mut next_unit = 1u8;
        for b in &raw.bus {
            let name = b.name.get_ref().trim().to_string();
            if !valid_name(&name) {
                return cx.err(b.name.span(), "bus.name", "use letters, digits, - and _ only");
            }
            if buses.iter().any(|x: &BusConfig| x.name == name) {
                return cx.err(b.name.span(), "bus.name", format!("two buses are named {name:?}"));
            }
            let port = match b.port.get_ref().as_str() {
                "virtual" if cfg!(not(feature = "virtual")) => {
                    return cx.err(
                        b.port.span(),
                        "bus.port",
                        "this build has no virtual buses (built without the `virtual` feature): give a serial device or tcp://HOST:PORT",
                    )
                }
                "virtual" => Port::Virtual,
                p if p.starts_with("tcp://") => Port::Tcp(p["tcp://".len()..].to_string()),
                "" => {
                    return cx.err(
                        b.port.span(),
                        "bus.port",
                        "give a device path, tcp://HOST:PORT or virtual",
                    )
                }
                p => Port::Serial(p.to_string()),
            };
            let rs485 = match &b.rs485 {
                Some(m) => m.get_ref().parse().or_else(|e: String| cx.err(m.span(), "bus.rs485", e))?,
                None => drivebus_link::Rs485::Off,
            };
            let mut drives = Vec::new();
            for d in &b.drive {
                let family: Family = d.family.get_ref().parse().or_else(|_| {
                    cx.err(d.family.span(), "bus.drive.family", "use generic, toshiba, danfoss or b800")
                })?;
                let dname = d.name.get_ref().trim().to_string();
                if !valid_name(&dname) {
                    return cx.err(d.name.span(), "bus.drive.name", "use letters, digits, - and _ only");
                }
                if !names.insert(dname.clone()) {
                    return cx.err(
                        d.name.span(),
                        "bus.drive.name",
                        format!("two drives are named {dname:?}"),
                    );
                }
                let unit_id = match &d.unit_id {
                    Some(u) if *u.get_ref() == 0 || *u.get_ref() > 247 => {
                        return cx.err(u.span(), "bus.drive.unit_id", "use 1..247");
                    }
                    Some(u) => *u.get_ref(),
                    None => {
                        while next_unit <= 247 && units.contains(&next_unit) {
                            next_unit += 1;
                        }
                        // Past 247 drives the rest have no Modbus TCP unit (0): HTTP/MQTT only.
                        if next_unit <= 247 {
                            next_unit
                        } else {
                            0
                        }
                    }
                };
                if unit_id != 0 && !units.insert(unit_id) {
                    let span = d.unit_id.as_ref().map_or(d.name.span(), |u| u.span());
                    return cx.err(span, "bus.drive.unit_id", format!("unit id {unit_id} is used twice"));
                }
                let poll_ms = d.poll_ms.as_ref().map_or(500, |p| *p.get_ref());
                if !(10..=3_600_000).contains(&poll_ms) {
                    let span = d.poll_ms.as_ref().map(|p| p.span()).unwrap_or(d.name.span());
                    return cx.err(span, "bus.drive.poll_ms", format!("{poll_ms} is outside 10..3600000"));
                }
                let priority = match d.priority.as_ref().map(|p| (p.get_ref().as_str(), p.span())) {
                    None | Some(("normal", _)) => PollPriority::Normal,
                    Some(("high", _)) => PollPriority::High,
                    Some(("low", _)) => PollPriority::Low,
                    Some((other, span)) => {
                        return cx.err(
                            span,
                            "bus.drive.priority",
                            format!("{other:?}: use high, normal or low"),
                        )
                    }
                };
                if drives.iter().any(|x: &DriveConfig| x.address == *d.address.get_ref()) {
                    return cx.err(
                        d.address.span(),
                        "bus.drive.address",
                        format!("two drives on bus {name:?} have address {}", d.address.get_ref()),
                    );
                }
                drives.push(DriveConfig {
                    name: dname,
                    family,
                    address: *d.address.get_ref(),
                    unit_id,
                    poll: Duration::from_millis(poll_ms),
                    priority,
                    locked: d.locked,
                    load: d.load.unwrap_or(0.4),
                });
            }
            let first = drives.first().map(|d| d.family);
            let protocol = match (&b.protocol, first) {
                (Some(p), _) => {
                    p.get_ref().parse::<WireProtocol>().or_else(|e| cx.err(p.span(), "bus.protocol", e))?
                }
                (None, Some(f)) => f.default_protocol(),
                (None, None) => {
                    return cx.err(b.name.span(), "bus.protocol", "give the bus's protocol or a drive")
                }
            };
            let protocol_span = b.protocol.as_ref().map_or(b.name.span(), |p| p.span());
            for (d, raw_drive) in drives.iter().zip(&b.drive) {
                if let Err(e) = d.family.check_protocol(protocol) {
                    return cx.err(protocol_span, "bus.protocol", format!("drive {:?}: {e}", d.name));
                }
                // A polled drive has an address of its own: never the broadcast address, which
                // every drive obeys and none answers (a lock on one drive would not hold).
                if let Err(e) = d.family.check_address(protocol, d.address) {
                    let broadcast = if d.address == 0 {
                        " (0 is the broadcast address: every drive obeys it)"
                    } else {
                        ""
                    };
                    return cx.err(
                        raw_drive.address.span(),
                        "bus.drive.address",
                        format!("drive {:?}: {e}{broadcast}", d.name),
                    );
                }
                if let Err(e) = drivebus_drive::profile::for_drive(d.family, protocol, d.address) {
                    return cx.err(protocol_span, "bus.protocol", format!("drive {:?}: {e}", d.name));
                }
            }
            let (db, df) = first.map_or((9600, CharFormat::NONE_8N1), |f| f.serial_default(protocol));
            let baud = match &b.baud {
                Some(v) if !(300..=1_000_000).contains(v.get_ref()) => {
                    return cx.err(v.span(), "bus.baud", format!("{} is outside 300..1000000", v.get_ref()))
                }
                Some(v) => *v.get_ref(),
                None => db,
            };
            let format = match &b.serial {
                Some(s) => {
                    s.get_ref().parse::<CharFormat>().or_else(|e| cx.err(s.span(), "bus.serial", e))?
                }
                None => df,
            };
            let mut on_demand = drivebus_link::FairConfig::default();
            if let Some(v) = &b.on_demand_share {
                let share = *v.get_ref();
                if !(0.0..=1.0).contains(&share) {
                    return cx.err(
                        v.span(),
                        "bus.on_demand_share",
                        format!("{share} is not a share of the bus time: use 0.0..1.0 (0.5: half)"),
                    );
                }
                on_demand.share = share;
            }
            for (v, field, to) in [
                (&b.on_demand_queue, "bus.on_demand_queue", &mut on_demand.queue),
                (&b.on_demand_per_client, "bus.on_demand_per_client", &mut on_demand.per_client),
            ] {
                if let Some(v) = v {
                    if *v.get_ref() == 0 {
                        return cx.err(v.span(), field, "use 1 or more");
                    }
                    *to = *v.get_ref();
                }
            }
            buses.push(BusConfig {
                on_demand,
                param_cache: Duration::from_millis(b.param_cache_ms.unwrap_or(PARAM_CACHE_MS)),
                name,
                port,
                protocol,
                baud,
                format,
                timeout: b.timeout_ms.map(Duration::from_millis),
                retries: b.retries.unwrap_or(2),
                echo: b.echo,
                strict_t15: b.strict_t15,
                rs485,
                drives,
            });
        }

        let mut linkage = Vec::new();
        for l in &raw.linkage {
            let span = l.span();
            let l = l.get_ref();
            for (who, field) in [(&l.leader, "linkage.leader"), (&l.follower, "linkage.follower")] {
                if !names.contains(who.get_ref()) {
                    return cx.err(who.span(), field, format!("no drive is named {:?}", who.get_ref()));
                }
            }
            if l.leader.get_ref() == l.follower.get_ref() {
                return cx.err(span, "linkage.follower", "a drive cannot follow itself");
            }
            if linkage.iter().any(|x: &Linkage| &x.follower == l.follower.get_ref()) {
                return cx.err(
                    l.follower.span(),
                    "linkage.follower",
                    format!(
                        "{:?} already follows another drive: one rule per follower",
                        l.follower.get_ref()
                    ),
                );
            }
            // A chain that comes back to its start would feed each setpoint from itself.
            let mut leader = l.leader.get_ref().as_str();
            while let Some(up) = linkage.iter().find(|x: &&Linkage| x.follower == leader) {
                if &up.leader == l.follower.get_ref() {
                    return cx.err(
                        l.follower.span(),
                        "linkage.follower",
                        format!(
                            "{:?} following {:?} closes a loop of linkage rules: each setpoint would feed itself",
                            l.follower.get_ref(),
                            l.leader.get_ref()
                        ),
                    );
                }
                leader = up.leader.as_str();
            }
            let ratio = l.ratio.unwrap_or(1.0);
            let offset_hz = l.offset_hz.unwrap_or(0.0);
            if !ratio.is_finite() || !offset_hz.is_finite() {
                return cx.err(span, "linkage.ratio", "ratio and offset_hz must be finite numbers");
            }
            linkage.push(Linkage {
                leader: l.leader.get_ref().clone(),
                follower: l.follower.get_ref().clone(),
                ratio,
                offset_hz,
            });
        }

        let mqtt = match raw.mqtt {
            None => None,
            Some(m) => {
                if let Err(e) = crate::mqtt::parse_url(m.url.get_ref()) {
                    return cx.err(m.url.span(), "mqtt.url", e);
                }
                if let Some(p) = &m.topic_prefix {
                    if let Err(e) = crate::mqtt::check_prefix(p.get_ref()) {
                        return cx.err(p.span(), "mqtt.topic_prefix", e);
                    }
                }
                for a in &m.allow_commands {
                    if let Err(e) = crate::mqtt::Pattern::parse(a.get_ref()) {
                        return cx.err(a.span(), "mqtt.allow_commands", e);
                    }
                }
                if let Some(c) = &m.client_id {
                    let c = c.get_ref();
                    if c.is_empty() || c.len() > 64 || c.contains(['+', '#', '/']) {
                        return cx.err(
                            m.client_id.as_ref().map_or(m.url.span(), |c| c.span()),
                            "mqtt.client_id",
                            "use 1 to 64 characters without +, # or /",
                        );
                    }
                }
                let credentials =
                    cx.credentials("mqtt", m.url.span(), &m.username, &m.password, &m.password_env)?;
                Some(MqttConfig {
                    url: m.url.get_ref().clone(),
                    topic_prefix: m.topic_prefix.map(|p| p.into_inner()),
                    discovery: m.discovery,
                    allow_commands: m.allow_commands.into_iter().map(|a| a.into_inner()).collect(),
                    client_id: m.client_id.map(|c| c.into_inner()),
                    credentials,
                })
            }
        };

        let sparkplug = match raw.sparkplug {
            None => None,
            Some(sp) => Some(sparkplug_section(&cx, sp)?),
        };

        let store_limits =
            drivebus_store::Limits::from_days_and_mb(raw.store.retention_days, raw.store.max_size_mb);
        let store = if raw.store.disabled {
            None
        } else {
            Some(PathBuf::from(raw.store.path.unwrap_or_else(|| "drivebus.db".to_string())))
        };
        let opcua = opcua_section(&raw.opcua, &http, &addr)?;
        let mut limits = crate::limits::LimitsConfig::default();
        if let Some(n) = &raw.limits.per_address {
            if *n.get_ref() == 0 {
                return cx.err(n.span(), "limits.per_address", "use 1 or more");
            }
            limits.per_address = *n.get_ref();
        }
        if let Some(t) = &raw.limits.header_timeout_ms {
            if !(100..=600_000).contains(t.get_ref()) {
                return cx.err(
                    t.span(),
                    "limits.header_timeout_ms",
                    format!("{} is outside 100..600000", t.get_ref()),
                );
            }
            limits.header_timeout = Duration::from_millis(*t.get_ref());
        }
        if let Some(t) = raw.limits.idle_timeout_s {
            limits.idle_timeout = Duration::from_secs(t);
        }
        if let Some(r) = raw.limits.reserve_fds {
            limits.reserve_fds = r;
        }
        let bridges = crate::bridge::configs(&cx, &raw.bridge, &buses)?;
        let modbus_rtu = crate::modbus_rtu::configs(&cx, &raw.modbus_rtu)?;
        Ok(GatewayConfig {
            name: gateway_name,
            http,
            modbus,
            store,
            store_limits,
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

    /// Every drive, in configuration order, with its bus.
    pub fn drives(&self) -> impl Iterator<Item = (&BusConfig, &DriveConfig)> {
        self.buses.iter().flat_map(|b| b.drives.iter().map(move |d| (b, d)))
    }
}

#[cfg(test)]
mod tests {
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

    #[test]
    fn store_retention_and_size_cap() {
        let c = GatewayConfig::from_toml("plant.toml", "").unwrap();
        assert_eq!(c.store_limits, drivebus_store::Limits::default());
        let c = GatewayConfig::from_toml("plant.toml", "[store]\nretention_days = 30\nmax_size_mb = 0\n")
            .unwrap();
        assert_eq!(c.store_limits, drivebus_store::Limits::from_days_and_mb(30, 0));
        assert_eq!(c.store_limits.max_bytes, None);
        let e = err("[store]\nmax_size_mb = -1\n");
        assert!(e.starts_with("plant.toml:2: field `store.max_size_mb`"), "{e}");
    }

    #[test]
    fn errors_name_the_file_line_and_field() {
        let e = err("[[bus]]\nname = \"a\"\nport = \"virtual\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"siemens\"\naddress = 1\n");
        assert_eq!(e, "plant.toml:6: field `bus.drive.family`: use generic, toshiba, danfoss or b800");
        let e = err("[[bus]]\nname = \"a\"\nport = \"virtual\"\nbaud = 12\n[[bus.drive]]\nname = \"x\"\nfamily = \"b800\"\naddress = 1\n");
        assert_eq!(e, "plant.toml:4: field `bus.baud`: 12 is outside 300..1000000");
        let e = err("[http]\nlisten = \"localhost\"\n");
        assert!(e.starts_with("plant.toml:2: field `http.listen`"), "{e}");
        let e = err("[[bus]]\nname = \"a\"\nport = \"virtual\"\nspeed = 3\n");
        assert!(e.starts_with("plant.toml:4: field `bus.speed`: unknown field `speed`"), "{e}");
        let e = err("[[bus]]\nname = \"a\"\nport = \"virtual\"\nprotocol = \"b800\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"danfoss\"\naddress = 1\n");
        assert!(
            e.starts_with("plant.toml:4: field `bus.protocol`: drive \"x\": a danfoss drive does not speak"),
            "{e}"
        );
        let e = err("[[token]]\nname = \"s\"\ntoken = \"short\"\nrole = \"write\"\n");
        assert_eq!(e, "plant.toml:3: field `token.token`: a token needs at least 16 characters");
        let e = err("[[linkage]]\nleader = \"a\"\nfollower = \"b\"\n");
        assert_eq!(e, "plant.toml:2: field `linkage.leader`: no drive is named \"a\"");
    }

    #[test]
    fn mqtt_settings_are_checked() {
        let ok = GatewayConfig::from_toml(
            "p.toml",
            "[mqtt]\nurl = \"mqtt://10.0.0.9\"\nallow_commands = [\"line-1/*/stop\", \"*/*/*\"]\n",
        )
        .unwrap();
        assert_eq!(ok.mqtt.unwrap().allow_commands.len(), 2);
        let e = err("[mqtt]\nurl = \"tcp://x:1883\"\n");
        assert!(e.starts_with("plant.toml:2: field `mqtt.url`: "), "{e}");
        let e = err("[mqtt]\nurl = \"mqtt://x:1883\"\nallow_commands = [\n  \"line-1/*\",\n]\n");
        assert!(e.starts_with("plant.toml:4: field `mqtt.allow_commands`: "), "{e}");
        let e = err("[mqtt]\nurl = \"mqtt://x:1883\"\nallow_commands = [\"a/b/start\"]\n");
        assert!(e.contains("start"), "{e}");
        let e = err("[mqtt]\nurl = \"mqtt://x:1883\"\ntopic_prefix = \"plant/#\"\n");
        assert!(e.starts_with("plant.toml:3: field `mqtt.topic_prefix`: "), "{e}");
    }

    #[test]
    fn values_of_the_wrong_type_name_their_field() {
        let e = err("[[bus]]\nname = \"a\"\nport = \"virtual\"\nbaud = \"fast\"\n");
        assert!(e.starts_with("plant.toml:4: field `bus.baud`: invalid type"), "{e}");
        let e = err("[[bus]]\nname = \"a\"\nport = \"virtual\"\n[[bus.drive]]\nname = \"x\"\nfamily = \"b800\"\naddress = 300\n");
        assert!(e.starts_with("plant.toml:7: field `bus.drive.address`: "), "{e}");
        let e = err("[http]\nmax_body = 0\n");
        assert_eq!(e, "plant.toml:2: field `http.max_body`: 0 is outside 256..16777216 bytes");
        let e = err("[modbus]\nmax_connections = 0\n");
        assert_eq!(e, "plant.toml:2: field `modbus.max_connections`: use 1 or more");
    }

    #[test]
    fn fair_use_and_limits_are_checked_and_have_defaults() {
        let bus = "[[bus]]\nname = \"a\"\nport = \"virtual\"\n";
        let drive = "[[bus.drive]]\nname = \"x\"\nfamily = \"generic\"\naddress = 1\n";
        let e = err(&format!("{bus}on_demand_share = 1.5\n{drive}"));
        assert_eq!(
            e,
            "plant.toml:4: field `bus.on_demand_share`: 1.5 is not a share of the bus time: use 0.0..1.0 (0.5: half)"
        );
        let e = err(&format!("{bus}on_demand_queue = 0\n{drive}"));
        assert_eq!(e, "plant.toml:4: field `bus.on_demand_queue`: use 1 or more");
        let e = err(&format!("{bus}on_demand_per_client = 0\n{drive}"));
        assert_eq!(e, "plant.toml:4: field `bus.on_demand_per_client`: use 1 or more");
        let e = err("[limits]\nper_address = 0\n");
        assert_eq!(e, "plant.toml:2: field `limits.per_address`: use 1 or more");
        let e = err("[limits]\nheader_timeout_ms = 5\n");
        assert_eq!(e, "plant.toml:2: field `limits.header_timeout_ms`: 5 is outside 100..600000");

        let c = GatewayConfig::from_toml("plant.toml", &format!("{bus}{drive}")).unwrap();
        assert_eq!(c.buses[0].on_demand, drivebus_link::FairConfig { share: 0.5, queue: 32, per_client: 8 });
        assert_eq!(c.buses[0].param_cache, Duration::from_millis(200));
        assert_eq!(c.limits, crate::limits::LimitsConfig::default());
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
        let e = err("name = \"hall 3/west\"\n");
        assert_eq!(
            e,
            "plant.toml:1: field `name`: use letters, digits, - and _ only (it is the MQTT topic level and client id)"
        );
        let ok = GatewayConfig::from_toml("p.toml", "name = \" hall-3_west \"\n").unwrap();
        assert_eq!(ok.name, "hall-3_west");
        assert_eq!(GatewayConfig::from_toml("p.toml", "").unwrap().name, "drivebus");
    }

    #[test]
    fn a_polled_drive_never_has_the_broadcast_address() {
        let bus = |family: &str, protocol: &str, address: u8| {
            format!("[[bus]]\nname = \"a\"\nport = \"/dev/ttyUSB0\"\nprotocol = \"{protocol}\"\n[[bus.drive]]\nname = \"all\"\nfamily = \"{family}\"\naddress = {address}\n")
        };
        let e = err(&bus("generic", "modbus-rtu", 0));
        assert_eq!(
            e,
            "plant.toml:8: field `bus.drive.address`: drive \"all\": a generic drive on modbus-rtu has an address in 1..254, not 0 (0 is the broadcast address: every drive obeys it)"
        );
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
        let e = err(&bus("b800", "modbus-rtu", 1));
        assert!(e.starts_with("plant.toml:4: field `bus.protocol`: "), "{e}");
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
        assert_eq!(
            (b.baud, b.format, b.protocol),
            (19200, CharFormat::EVEN_8E1, WireProtocol::ToshibaBinary)
        );
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
        let e = err("[modbus]\nallow = [\"plc\"]\n");
        assert_eq!(e, "plant.toml:2: field `modbus.allow`: \"plc\" is not an IP address");
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
                    primary_host = \"scada\"\ncommands = true\nusername = \"u\"\npassword = \"p\"\n\
                    store_forward_max = 10\nstore_forward_max_age_s = 60\nstore_forward_rate = 500\n";
        let sp = GatewayConfig::from_toml("p.toml", full).unwrap().sparkplug.unwrap();
        assert_eq!(sp.edge_node_id.as_deref(), Some("hall-9"));
        assert_eq!(sp.primary_host.as_deref(), Some("scada"));
        assert_eq!(sp.credentials, Some(("u".into(), "p".into())));
        assert!(sp.commands);
        assert_eq!((sp.store_forward_max, sp.store_forward_max_age_s, sp.store_forward_rate), (10, 60, 500));
        let e = err("[sparkplug]\nurls = []\n");
        assert!(e.starts_with("plant.toml:2: field `sparkplug.urls`: give at least one broker"), "{e}");
        let e = err("[sparkplug]\nurls = [\"mqtt://a\", \"tcp://b\"]\n");
        assert!(e.starts_with("plant.toml:2: field `sparkplug.urls`: \"tcp://b\""), "{e}");
        let e = err("[sparkplug]\nurls = [\"mqtt://a\"]\ngroup_id = \"a/b\"\n");
        assert!(e.starts_with("plant.toml:3: field `sparkplug.group_id`: "), "{e}");
        let e = err("[sparkplug]\nurls = [\"mqtt://a\"]\nprimary_host = \"#\"\n");
        assert!(e.starts_with("plant.toml:3: field `sparkplug.primary_host`: "), "{e}");
        let e = err("[sparkplug]\nurls = [\"mqtt://a\"]\nstore_forward_max = 0\n");
        assert!(
            e.starts_with("plant.toml:3: field `sparkplug.store_forward_max`: give a number above 0"),
            "{e}"
        );
        let e = err("[sparkplug]\nurls = [\"mqtt://a\"]\nusername = \"u\"\n");
        assert!(e.starts_with("plant.toml:3: field `sparkplug.username`: give a password"), "{e}");
        let e = err("[sparkplug]\nurl = \"mqtt://a\"\n");
        assert!(e.contains("unknown field `url`"), "{e}");
    }

    #[test]
    fn mqtt_credentials_come_whole_or_not_at_all() {
        let base = "[mqtt]\nurl = \"mqtt://127.0.0.1:1883\"\n";
        let c =
            GatewayConfig::from_toml("p.toml", &format!("{base}username = \"plant\"\npassword = \"pw\"\n"))
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
}
