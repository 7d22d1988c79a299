//! The checked model: what the rest of the gateway reads of its configuration. Every value
//! here has passed its section's check ([`super`]), defaults filled in.

use std::fmt;
use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::time::Duration;

use drivebus_drive::Family;
use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;

/// A whole gateway.
#[derive(Clone, Debug, PartialEq)]
pub struct GatewayConfig {
    /// The gateway's name.
    pub name: String,
    /// The drive templates read (`templates = [...]`), whose kinds the drives may name.
    pub templates: Vec<PathBuf>,
    /// The HTTP listener.
    pub http: HttpConfig,
    /// The Modbus TCP listener.
    pub modbus: ModbusConfig,
    /// Where events and trends are kept (`None`: not kept).
    pub store: Option<PathBuf>,
    /// The store's retention and size cap (`[store] retention_days`, `max_size_mb`).
    pub store_limits: drivebus_store::Limits,
    /// The free space, MiB, the store's filesystem needs for the gateway to be ready (`[store]
    /// min_free_mb`, default [`STORE_MIN_FREE_MB`]; 0: not checked).
    pub store_min_free_mb: u64,
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
    pub bridges: Vec<BridgeConfig>,
    /// Modbus RTU slaves serving the unified map (`[[modbus_rtu]]`).
    pub modbus_rtu: Vec<ModbusRtuConfig>,
    /// The Sparkplug B edge node, if configured.
    pub sparkplug: Option<SparkplugConfig>,
    /// Connection limits and timeouts of every listener (`[limits]`).
    pub limits: LimitsConfig,
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
    /// Whether writes and method calls are taken over the unsigned `None` endpoint (default:
    /// refused with `Bad_SecurityModeInsufficient`; `--demo` on loopback sets it).
    pub insecure_writes: bool,
    /// Most sessions open at once per user (a token's name, or anonymous).
    pub max_sessions_per_user: usize,
    /// The host name clients should use, in the endpoint URLs the server advertises (default:
    /// the listener's address, or the machine's host name when it listens on every address).
    pub host: Option<String>,
}

impl OpcUaConfig {
    /// `[opcua]` with every default, listening on `listen`.
    pub fn new(listen: SocketAddr, anonymous_read: bool) -> Self {
        OpcUaConfig {
            listen,
            anonymous_read,
            pki_dir: None,
            trusted_clients: Vec::new(),
            insecure_writes: false,
            max_sessions_per_user: DEFAULT_MAX_SESSIONS_PER_USER,
            host: None,
        }
    }
}

/// The default of `[opcua] max_sessions_per_user`.
pub const DEFAULT_MAX_SESSIONS_PER_USER: usize = 10;

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
    /// checked when `anonymous_read` is on (http/host.rs).
    pub hosts: Vec<String>,
    /// HTTPS: the listener's certificate (chain) and private key, PEM (`tls_cert`, `tls_key`).
    pub tls: Option<HttpTls>,
    /// Serve write tokens over plain HTTP on an address other than loopback.
    pub allow_plaintext: bool,
}

/// The certificate and key that make the HTTP listener HTTPS.
#[derive(Clone, Debug, PartialEq)]
pub struct HttpTls {
    /// PEM file of the certificate, or its chain (the server's first).
    pub cert: PathBuf,
    /// PEM file of its private key.
    pub key: PathBuf,
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
    /// A Modbus TCP server (`protocol = "modbus-tcp"`): the drives' Modbus frames in MBAP,
    /// each drive's address its unit id (`host:port`, port 502 unless given).
    ModbusTcp(String),
    /// Simulated drives in this process, one per configured drive.
    Virtual,
}

impl fmt::Display for Port {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Port::Serial(p) => f.write_str(p),
            Port::Tcp(a) | Port::ModbusTcp(a) => write!(f, "tcp://{a}"),
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
    /// With another gateway on the same line (`[standby]`, `--standby`): listen first, master
    /// the bus only when the line falls silent. `None`: the only master.
    pub role: Option<drivebus_link::role::RoleConfig>,
    /// A modbus-tcp bus: the most requests in flight on its connection (`max_in_flight`, 1..16,
    /// default 1); above 1 they are pipelined, one per drive at a time.
    pub max_in_flight: usize,
    /// The drives.
    pub drives: Vec<DriveConfig>,
}

impl BusConfig {
    /// The bus's protocol as users name it: `modbus-tcp` on a Modbus TCP server, else the wire
    /// protocol's name.
    pub fn protocol_name(&self) -> &'static str {
        match self.port {
            Port::ModbusTcp(_) => drivebus_link::mbap::MODBUS_TCP,
            _ => self.protocol.name(),
        }
    }
}

/// Which drive is polled first when several are due and their values are as old (at start).
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
    /// `mqtt://HOST[:PORT]` (port 1883 when not given) or `mqtts://HOST[:PORT]` (TLS, 8883).
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
    /// TLS to the broker (`mqtts://`) and the plain-text opt-out.
    pub tls: BrokerTls,
}

/// How the gateway talks to an MQTT broker beside its URL, the same keys in `[mqtt]` and
/// `[sparkplug]` (docs/mqtt.md): whom to trust for an `mqtts://` broker, the certificate the
/// gateway shows, and the opt-out of the rule that credentials and commands do not cross a
/// network in clear.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BrokerTls {
    /// PEM file of the CA certificates the broker's certificate must chain to (default: the
    /// system's trusted roots).
    pub ca_file: Option<PathBuf>,
    /// PEM file of the gateway's client certificate (chain), for brokers that ask for one.
    pub client_cert: Option<PathBuf>,
    /// PEM file of its private key.
    pub client_key: Option<PathBuf>,
    /// Allow a plain `mqtt://` broker off this machine though a password or commands would
    /// cross the network in clear.
    pub allow_plaintext: bool,
}

/// The Sparkplug B edge node (docs/sparkplug.md).
#[derive(Clone, Debug, PartialEq)]
pub struct SparkplugConfig {
    /// Brokers, `mqtt://HOST[:PORT]` or `mqtts://HOST[:PORT]`, tried in turn when one cannot be
    /// reached.
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
    /// TLS to the brokers (`mqtts://`) and the plain-text opt-out.
    pub tls: BrokerTls,
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
            tls: BrokerTls::default(),
            store_forward_max: SPARKPLUG_STORE_MAX,
            store_forward_max_age_s: SPARKPLUG_STORE_MAX_AGE_S,
            store_forward_rate: SPARKPLUG_STORE_RATE,
        }
    }
}

// ---- the file as written -------------------------------------------------------------------

impl GatewayConfig {
    /// Every drive, in configuration order, with its bus.
    pub fn drives(&self) -> impl Iterator<Item = (&BusConfig, &DriveConfig)> {
        self.buses.iter().flat_map(|b| b.drives.iter().map(move |d| (b, d)))
    }
}

/// The default `[store] min_free_mb`.
pub const STORE_MIN_FREE_MB: u64 = 64;

/// How a bridge's requests come over TCP.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Framing {
    /// Modbus TCP: MBAP header and PDU.
    Mbap,
    /// RTU frames (address, PDU, CRC) over TCP.
    Rtu,
}

/// One `[[bridge]]`: Modbus TCP straight through to a bus (bridge.rs).
#[derive(Clone, Debug, PartialEq)]
pub struct BridgeConfig {
    /// The bus's name.
    pub bus: String,
    /// Where to listen.
    pub listen: SocketAddr,
    /// How requests are framed.
    pub framing: Framing,
    /// The function codes passed to the bus (`functions = [...]`, by default
    /// [`BRIDGE_FUNCTIONS`]); any other is answered with exception 01 and audited as refused.
    pub functions: Vec<u8>,
}

/// The functions a bridge passes unless its `functions` says otherwise: the reads (01-04), the
/// writes (05, 06, 0F, 10, 17; under the `[modbus]` write rules) and 2B (read device
/// identification, MEI type 0E only).
pub const BRIDGE_FUNCTIONS: [u8; 10] = [0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F, 0x10, 0x17, 0x2B];

/// Function 2B, the encapsulated interface: a bridge passes its MEI type 0E (read device
/// identification) only.
pub const FC_ENCAPSULATED: u8 = 0x2B;

/// The MEI type of read device identification (function 2B).
pub const MEI_DEVICE_ID: u8 = 0x0E;

impl BridgeConfig {
    /// A bridge of `bus` on `listen` with MBAP framing and the default functions.
    pub fn new(bus: &str, listen: SocketAddr) -> Self {
        BridgeConfig {
            bus: bus.to_string(),
            listen,
            framing: Framing::Mbap,
            functions: BRIDGE_FUNCTIONS.to_vec(),
        }
    }

    /// Whether the request `pdu` (function code first) is one of the functions this bridge
    /// passes; of function 2B, MEI type 0E (device identification) only.
    pub fn passes(&self, pdu: &[u8]) -> bool {
        match pdu {
            [FC_ENCAPSULATED, mei, ..] => *mei == MEI_DEVICE_ID && self.functions.contains(&FC_ENCAPSULATED),
            [fc, ..] => self.functions.contains(fc),
            [] => false,
        }
    }
}

/// One `[[modbus_rtu]]` slave: the unified map on a serial port (modbus_rtu.rs).
#[derive(Clone, Debug, PartialEq)]
pub struct ModbusRtuConfig {
    /// The serial device.
    pub port: String,
    /// Baud rate (default 19200).
    pub baud: u32,
    /// Character format (default 8E1).
    pub format: CharFormat,
    /// Accept writes (with `[modbus] read_only` off).
    pub write: bool,
}

impl ModbusRtuConfig {
    /// A slave on `port` at the Modbus serial-line defaults (19200 8E1), read-only.
    pub fn new(port: &str) -> Self {
        ModbusRtuConfig { port: port.to_string(), baud: 19200, format: CharFormat::EVEN_8E1, write: false }
    }
}

/// The `[limits]` section: connection limits and timeouts of every listener (limits.rs).
#[derive(Clone, Debug, PartialEq)]
pub struct LimitsConfig {
    /// Most connections from one address on each listener.
    pub per_address: usize,
    /// Time a client has to send a whole request header (HTTP), the rest of a frame it began
    /// (Modbus TCP, the bridge), its HELLO (OPC UA, whole seconds).
    pub header_timeout: Duration,
    /// A connection with nothing sent either way for this long is closed (zero: never).
    pub idle_timeout: Duration,
    /// Descriptors kept free: new connections are refused while fewer are left.
    pub reserve_fds: u64,
}

/// The default `per_address`.
pub const PER_ADDRESS: usize = 64;
/// The default `header_timeout_ms`.
pub const HEADER_TIMEOUT_MS: u64 = 5_000;
/// The default `idle_timeout_s`.
pub const IDLE_TIMEOUT_S: u64 = 300;
/// The default `reserve_fds`.
pub const RESERVE_FDS: u64 = 256;

impl Default for LimitsConfig {
    fn default() -> Self {
        LimitsConfig {
            per_address: PER_ADDRESS,
            header_timeout: Duration::from_millis(HEADER_TIMEOUT_MS),
            idle_timeout: Duration::from_secs(IDLE_TIMEOUT_S),
            reserve_fds: RESERVE_FDS,
        }
    }
}
