//! The file schema: the sections as TOML reads them, each value with its place in the file
//! ([`Spanned`]) for the errors. Unknown keys are refused here; everything else is checked
//! by the section's check.

use serde::Deserialize;
use toml::Spanned;

/// The whole file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileConfig {
    pub(super) name: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) templates: Vec<Spanned<String>>,
    #[serde(default)]
    pub(super) http: FileHttp,
    #[serde(default)]
    pub(super) modbus: FileModbus,
    #[serde(default)]
    pub(super) store: FileStore,
    #[serde(default)]
    pub(super) token: Vec<FileToken>,
    #[serde(default)]
    pub(super) bus: Vec<FileBus>,
    #[serde(default)]
    pub(super) linkage: Vec<Spanned<FileLinkage>>,
    pub(super) mqtt: Option<FileMqtt>,
    #[serde(default)]
    pub(super) opcua: FileOpcUa,
    #[serde(default)]
    pub(super) bridge: Vec<FileBridge>,
    #[serde(default)]
    pub(super) modbus_rtu: Vec<FileModbusRtu>,
    pub(super) sparkplug: Option<FileSparkplug>,
    #[serde(default)]
    pub(super) limits: FileLimits,
    pub(super) standby: Option<FileStandby>,
}

/// `[standby]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileStandby {
    pub(super) role: Option<Spanned<String>>,
    pub(super) silence_ms: Option<Spanned<u64>>,
}

/// `[limits]` as written.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileLimits {
    pub(super) per_address: Option<Spanned<usize>>,
    pub(super) header_timeout_ms: Option<Spanned<u64>>,
    pub(super) idle_timeout_s: Option<u64>,
    pub(super) reserve_fds: Option<u64>,
}

/// `[opcua]` as written.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileOpcUa {
    pub(super) listen: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) disabled: bool,
    pub(super) anonymous_read: Option<bool>,
    pub(super) pki_dir: Option<String>,
    #[serde(default)]
    pub(super) trusted_clients: Vec<String>,
    #[serde(default)]
    pub(super) insecure_writes: bool,
    pub(super) max_sessions_per_user: Option<Spanned<usize>>,
    pub(super) host: Option<Spanned<String>>,
}

/// `[http]` as written.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileHttp {
    pub(super) listen: Option<Spanned<String>>,
    pub(super) anonymous_read: Option<bool>,
    pub(super) max_body: Option<Spanned<usize>>,
    #[serde(default)]
    pub(super) hosts: Vec<Spanned<String>>,
    pub(super) tls_cert: Option<Spanned<String>>,
    pub(super) tls_key: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) allow_plaintext: bool,
}

/// `[modbus]` as written.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileModbus {
    pub(super) listen: Option<Spanned<String>>,
    pub(super) allow: Option<Vec<Spanned<String>>>,
    #[serde(default)]
    pub(super) read_only: bool,
    pub(super) max_connections: Option<Spanned<usize>>,
}

/// `[store]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileStore {
    pub(super) path: Option<String>,
    #[serde(default)]
    pub(super) disabled: bool,
    #[serde(default = "default_retention_days")]
    pub(super) retention_days: u64,
    #[serde(default = "default_max_size_mb")]
    pub(super) max_size_mb: u64,
    #[serde(default = "default_min_free_mb")]
    pub(super) min_free_mb: u64,
}

impl Default for FileStore {
    fn default() -> Self {
        FileStore {
            path: None,
            disabled: false,
            retention_days: default_retention_days(),
            max_size_mb: default_max_size_mb(),
            min_free_mb: default_min_free_mb(),
        }
    }
}

/// The default `retention_days`.
fn default_retention_days() -> u64 {
    365
}

/// The default `min_free_mb`.
fn default_min_free_mb() -> u64 {
    super::STORE_MIN_FREE_MB
}

/// The default `max_size_mb`.
fn default_max_size_mb() -> u64 {
    1024
}

/// A `[[token]]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileToken {
    pub(super) name: Spanned<String>,
    pub(super) token: Spanned<String>,
    pub(super) role: Spanned<String>,
}

/// A `[[bus]]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileBus {
    pub(super) name: Spanned<String>,
    pub(super) port: Spanned<String>,
    pub(super) protocol: Option<Spanned<String>>,
    pub(super) baud: Option<Spanned<u32>>,
    pub(super) serial: Option<Spanned<String>>,
    pub(super) timeout_ms: Option<u64>,
    pub(super) retries: Option<u8>,
    #[serde(default)]
    pub(super) echo: bool,
    #[serde(default)]
    pub(super) strict_t15: bool,
    pub(super) rs485: Option<Spanned<String>>,
    pub(super) on_demand_share: Option<Spanned<f64>>,
    pub(super) on_demand_queue: Option<Spanned<usize>>,
    pub(super) on_demand_per_client: Option<Spanned<usize>>,
    pub(super) param_cache_ms: Option<u64>,
    pub(super) max_in_flight: Option<Spanned<i64>>,
    #[serde(default)]
    pub(super) drive: Vec<FileDrive>,
}

/// A `[[bus.drive]]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileDrive {
    pub(super) name: Spanned<String>,
    pub(super) family: Spanned<String>,
    pub(super) address: Spanned<u8>,
    pub(super) unit_id: Option<Spanned<u8>>,
    pub(super) poll_ms: Option<Spanned<u64>>,
    pub(super) priority: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) locked: bool,
    pub(super) load: Option<f64>,
}

/// A `[[linkage]]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileLinkage {
    pub(super) leader: Spanned<String>,
    pub(super) follower: Spanned<String>,
    pub(super) ratio: Option<f64>,
    pub(super) offset_hz: Option<f64>,
}

/// `[mqtt]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileMqtt {
    pub(super) url: Spanned<String>,
    pub(super) topic_prefix: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) discovery: bool,
    #[serde(default)]
    pub(super) allow_commands: Vec<Spanned<String>>,
    pub(super) client_id: Option<Spanned<String>>,
    pub(super) username: Option<Spanned<String>>,
    pub(super) password: Option<Spanned<String>>,
    pub(super) password_env: Option<Spanned<String>>,
    /// TLS (`mqtts://`): the CA file, the client's certificate and key; the plain-text opt-out.
    pub(super) ca_file: Option<Spanned<String>>,
    pub(super) client_cert: Option<Spanned<String>>,
    pub(super) client_key: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) allow_plaintext: bool,
}

/// `[sparkplug]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileSparkplug {
    pub(super) urls: Spanned<Vec<Spanned<String>>>,
    pub(super) group_id: Option<Spanned<String>>,
    pub(super) edge_node_id: Option<Spanned<String>>,
    pub(super) primary_host: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) commands: bool,
    pub(super) username: Option<Spanned<String>>,
    pub(super) password: Option<Spanned<String>>,
    pub(super) password_env: Option<Spanned<String>>,
    /// TLS (`mqtts://`): the CA file, the client's certificate and key; the plain-text opt-out.
    pub(super) ca_file: Option<Spanned<String>>,
    pub(super) client_cert: Option<Spanned<String>>,
    pub(super) client_key: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) allow_plaintext: bool,
    pub(super) store_forward_max: Option<Spanned<u64>>,
    pub(super) store_forward_max_age_s: Option<Spanned<u64>>,
    pub(super) store_forward_rate: Option<Spanned<u64>>,
}

/// A `[[bridge]]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileBridge {
    pub(super) bus: Spanned<String>,
    pub(super) listen: Spanned<String>,
    pub(super) framing: Option<Spanned<String>>,
    pub(super) functions: Option<Vec<Spanned<i64>>>,
}

/// A `[[modbus_rtu]]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileModbusRtu {
    pub(super) port: Spanned<String>,
    pub(super) baud: Option<Spanned<u32>>,
    pub(super) serial: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) write: bool,
}
