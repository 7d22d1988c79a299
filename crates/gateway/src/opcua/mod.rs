//! The OPC UA front end (async-opcua): every drive and bus of the gateway as objects in the
//! namespace `urn:drivebus` ([`nodes`]), values from the cache with the time the drive answered
//! and a status that tells the truth ([`publish`]), writes and methods as gateway commands
//! ([`manager`]), the gateway's tokens as users ([`auth`]). docs/opcua.md describes it for
//! integrators.
//!
//! The drives and buses are not copied into the library's address space: [`space`] makes their
//! nodes when a request names them, from the cache. Subscriptions cost no bus traffic: the
//! publisher hands each poll's changed values to the monitored items that exist.

pub mod auth;
pub mod history;
pub mod manager;
pub mod nodes;
pub mod publish;
pub mod sessions;
pub mod space;
pub mod standard;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use opcua::crypto::SecurityPolicy;
use opcua::server::address_space::AddressSpace;
use opcua::server::diagnostics::{DiagnosticsNodeManagerBuilder, NamespaceMetadata};
use opcua::server::node_manager::memory::{CoreNodeManagerImpl, InMemoryNodeManagerBuilder};
use opcua::server::node_manager::ServerContext;
use opcua::server::{ServerBuilder, ServerEndpoint, ServerHandle, ServerUserToken};
use opcua::types::{BuildInfo, DataValue, DateTime, MessageSecurityMode, StatusCode, UAString, Variant};
use tokio::net::TcpListener;

use crate::config::OpcUaConfig;
use crate::core::{BusView, DriveView, Gateway};
use manager::DriveNodes;
use nodes::{Ids, BUS_VARIABLES, DRIVE_VARIABLES};

/// The placeholder user that lets endpoints offer user name logins (the users themselves are
/// the gateway's tokens, checked by [`auth::TokenAuth`]).
const TOKEN_USERS: &str = "tokens";

/// Where the server's certificate, key and trusted client certificates live: `[opcua] pki_dir`,
/// else `pki` beside the store when the store's path names a folder, else `pki` in the state
/// folder ([`crate::config::state_dir`]). Never the working directory unless the user named it.
pub fn pki_dir(config: &crate::GatewayConfig, cfg: &OpcUaConfig) -> Result<PathBuf, String> {
    pki_dir_in(config, cfg, crate::config::state_dir::state_dir)
}

/// [`pki_dir`] with the state folder from `state`.
pub fn pki_dir_in(
    config: &crate::GatewayConfig,
    cfg: &OpcUaConfig,
    state: impl FnOnce() -> Result<PathBuf, String>,
) -> Result<PathBuf, String> {
    if let Some(p) = &cfg.pki_dir {
        return Ok(p.clone());
    }
    match config.store.as_ref().and_then(|s| s.parent()) {
        Some(dir) if !dir.as_os_str().is_empty() => Ok(dir.join("pki")),
        _ => state()
            .map(|d| d.join("pki"))
            .map_err(|e| format!("OPC UA: no folder for the server's key ({e}): set [opcua] pki_dir")),
    }
}

/// Copies the client certificates of `[opcua] trusted_clients` into `pki/trusted`, where
/// the server looks for them. Returns how many.
pub fn trust_clients(pki: &std::path::Path, certs: &[PathBuf]) -> Result<usize, String> {
    let dir = pki.join("trusted");
    std::fs::create_dir_all(&dir).map_err(|e| format!("OPC UA: cannot make {}: {e}", dir.display()))?;
    for c in certs {
        let bytes = std::fs::read(c).map_err(|e| {
            format!(
                "OPC UA: cannot read the client certificate {} ([opcua] trusted_clients): {e}",
                c.display()
            )
        })?;
        // The server finds a trusted certificate by its own file name for it (subject and
        // thumbprint), so a DER file that does not parse is refused here, with its path.
        let cert = opcua::crypto::X509::from_der(&bytes).map_err(|e| {
            format!("OPC UA: {} is not a DER certificate ([opcua] trusted_clients): {e}", c.display())
        })?;
        let name = opcua::crypto::CertificateStore::cert_file_name(&cert);
        std::fs::write(dir.join(&name), bytes)
            .map_err(|e| format!("OPC UA: cannot write {}: {e}", dir.join(&name).display()))?;
    }
    Ok(certs.len())
}

/// The host clients should use, in the endpoint URLs the server advertises: `[opcua] host`,
/// else the listener's address, else, when it listens on every address (0.0.0.0, ::), the
/// machine's host name (`host_name`): never `opc.tcp://0.0.0.0:4840/`.
pub fn advertised_host(
    host: Option<&str>,
    listen: std::net::SocketAddr,
    host_name: impl FnOnce() -> Option<String>,
) -> Result<String, String> {
    if let Some(h) = host {
        return Ok(h.to_string());
    }
    match listen.ip() {
        ip if ip.is_unspecified() => host_name().filter(|h| !h.is_empty()).ok_or_else(|| {
            format!(
                "OPC UA: listening on {listen}, but this machine's host name is unknown: \
                 set [opcua] host to the name clients use"
            )
        }),
        std::net::IpAddr::V6(ip) => Ok(format!("[{ip}]")),
        ip => Ok(ip.to_string()),
    }
}

/// The machine's host name.
pub fn machine_host_name() -> Option<String> {
    nix::unistd::gethostname().ok().and_then(|h| h.into_string().ok())
}

/// The URL clients connect to: `opc.tcp://HOST:PORT` with the [`advertised_host`].
pub fn endpoint_url(cfg: &OpcUaConfig, listen: std::net::SocketAddr) -> Result<String, String> {
    Ok(format!(
        "opc.tcp://{}:{}",
        advertised_host(cfg.host.as_deref(), listen, machine_host_name)?,
        listen.port()
    ))
}

/// Builds the OPC UA server for `listener` (creating its certificate on first start; errors
/// here stop `serve` at start, with the reason) and returns what serves it until the process
/// ends, handing the cache's changes to subscriptions.
pub fn start(
    gw: Arc<Gateway>,
    cfg: &OpcUaConfig,
    listener: TcpListener,
) -> Result<impl std::future::Future<Output = Result<(), String>>, String> {
    let addr = listener.local_addr().map_err(|e| e.to_string())?;
    let pki = pki_dir(&gw.config(), cfg)?;
    trust_clients(&pki, &cfg.trusted_clients)?;
    let host = advertised_host(cfg.host.as_deref(), addr, machine_host_name)?;
    let (server, handle) = build(&gw, &host, addr.port(), &pki)?;
    let ns = handle
        .get_namespace_index(nodes::NAMESPACE)
        .ok_or_else(|| "OPC UA: the namespace urn:drivebus is missing".to_string())?;
    Ok(async move {
        let changes = gw.subscribe();
        let subs = handle.subscriptions().clone();
        crate::metrics::attached(&gw).serve_opcua(subs.clone());
        tokio::spawn(publish::publish(gw, Ids { ns }, subs, changes));
        server.run_with(listener).await.map_err(|e| format!("OPC UA server stopped: {e}"))
    })
}

/// The endpoints: None; Basic256Sha256 Sign and SignAndEncrypt. On each, passwords are
/// encrypted with [`auth::PASSWORD_POLICY`] (None included).
pub fn endpoints() -> Vec<(&'static str, ServerEndpoint)> {
    let users = [TOKEN_USERS.to_string(), auth::ANONYMOUS.to_string()];
    let b = SecurityPolicy::Basic256Sha256;
    let mut endpoints = vec![
        ("none", ServerEndpoint::new_none("/", &users)),
        ("basic256sha256_sign", ServerEndpoint::new("/", b, MessageSecurityMode::Sign, &users)),
        (
            "basic256sha256_sign_encrypt",
            ServerEndpoint::new("/", b, MessageSecurityMode::SignAndEncrypt, &users),
        ),
    ];
    for (_, e) in &mut endpoints {
        e.password_security_policy = Some(auth::PASSWORD_POLICY.to_string());
    }
    endpoints
}

/// The server and its handle: endpoints (None; Basic256Sha256 Sign and SignAndEncrypt), the
/// certificate in `pki` (made on first start), the tokens as users, the drive node manager.
fn build(
    gw: &Arc<Gateway>,
    host: &str,
    port: u16,
    pki: &std::path::Path,
) -> Result<(opcua::server::Server, ServerHandle), String> {
    let gw_nodes = gw.clone();
    // A login not yet seen by a request counts as long as the longest session timeout.
    let pending_for = Duration::from_millis(opcua::server::constants::MAX_SESSION_TIMEOUT);
    let sessions = Arc::new(sessions::Sessions::new(pending_for));
    let sessions_nodes = sessions.clone();
    let mut builder = ServerBuilder::new()
        // Namespace 0: the part of the core namespace clients use (standard.rs), not all of
        // it; then the library's diagnostics, then the drives.
        .without_node_managers()
        .with_node_manager(InMemoryNodeManagerBuilder::new(
            |context: ServerContext, space: &mut AddressSpace| {
                space.import_node_set(
                    &standard::StandardNodes::new(),
                    context.type_tree.write().namespaces_mut(),
                );
                CoreNodeManagerImpl::new(context.node_managers.clone(), context.status.clone())
            },
        ))
        .with_node_manager(DiagnosticsNodeManagerBuilder)
        .application_name("drivebus gateway")
        .application_uri(format!("urn:drivebus:gateway:{}", gw.config().name))
        .product_uri("urn:drivebus")
        .build_info(BuildInfo {
            product_uri: "urn:drivebus".into(),
            manufacturer_name: "drivebus".into(),
            product_name: "drivebus gateway".into(),
            software_version: env!("CARGO_PKG_VERSION").into(),
            build_number: "0".into(),
            build_date: DateTime::now(),
        })
        .host(host)
        .discovery_urls(vec![format!("opc.tcp://{host}:{port}/")])
        .port(port)
        .pki_dir(pki)
        .create_sample_keypair(true)
        .trust_client_certs(false)
        .add_user_token(TOKEN_USERS, ServerUserToken::user_pass(TOKEN_USERS, ""))
        .max_session_timeout_ms(opcua::server::constants::MAX_SESSION_TIMEOUT)
        .with_authenticator(Arc::new(auth::TokenAuth::new(gw.clone(), sessions)))
        .with_node_manager(move |context: ServerContext| {
            let index = context.type_tree.write().namespaces_mut().add_namespace(nodes::NAMESPACE);
            DriveNodes::new(
                gw_nodes,
                NamespaceMetadata {
                    namespace_uri: nodes::NAMESPACE.to_string(),
                    namespace_index: index,
                    ..Default::default()
                },
                sessions_nodes,
            )
        });
    for (id, e) in endpoints() {
        builder = builder.add_endpoint(id, e);
    }
    // A hall of 1000 drives has 10 000 cache variables; SCADA clients subscribe to them in one
    // subscription and in large calls.
    // How often subscriptions are looked at for notifications to send: the library's default
    // (100 ms) adds up to that much to every change's latency.
    builder = builder.subscription_poll_interval_ms(10);
    // async-opcua accepts on its own and tells no one the peer's address: no per-address
    // limit here ([limits] per_address covers the other listeners). A client must say HELLO
    // within the header timeout (whole seconds, at least 1).
    let header = gw.limits().config().header_timeout;
    builder = builder.hello_timeout(header.as_secs().max(1).try_into().unwrap_or(u32::MAX));
    let limits = builder.limits_mut();
    limits.subscriptions.max_monitored_items_per_sub = 100_000;
    limits.operational.max_monitored_items_per_call = 10_000;
    // Clients that want changes within tens of milliseconds may ask for short intervals (the
    // library's floor is 100 ms); values arrive at most once per poll anyway.
    limits.subscriptions.min_publishing_interval_ms = 20.0;
    limits.subscriptions.min_sampling_interval_ms = 20.0;
    builder = builder.default_endpoint("none");
    builder.build().map_err(|e| format!("OPC UA: cannot start the server: {e}"))
}

/// Unix milliseconds as an OPC UA DateTime (100 ns ticks since 1601).
pub fn datetime_ms(ms: i64) -> DateTime {
    DateTime::from(ms.saturating_mul(10_000).saturating_add(116_444_736_000_000_000))
}

/// The status of a drive's values: Good while fresh, Uncertain when older than three poll
/// intervals, Bad_NoCommunication while the drive or its bus is offline, Bad_WaitingForInitialData
/// before the first answer. Never a stale value marked Good.
pub fn quality(v: &DriveView, bus_online: bool) -> StatusCode {
    if v.online == Some(false) || !bus_online {
        StatusCode::BadNoCommunication
    } else if v.last_seen_ms.is_none() {
        StatusCode::BadWaitingForInitialData
    } else if v.age_ms.is_some_and(|a| a > 3 * v.poll_ms) {
        StatusCode::UncertainLastUsableValue
    } else {
        StatusCode::Good
    }
}

/// The variables of a drive that are the gateway's own knowledge, not the drive's values.
const GATEWAY_KNOWLEDGE: [&str; 4] = ["Online", "AgeMs", "ErrorRate", "Source"];

/// A drive's variables as data values, in [`DRIVE_VARIABLES`] order, from the view `v` taken at
/// `now` (docs/opcua.md, "Values, timestamps and status"). The drive's values carry as source
/// timestamp the time the drive last answered: the last poll that confirmed them, whether it
/// changed them or not (`now` before the first answer), so a client sees how fresh they are.
/// `Online`, `AgeMs`, `ErrorRate` and `Source` are the gateway's own knowledge, always Good,
/// their source timestamp `now`: `AgeMs` is its server timestamp minus the drive values' source
/// timestamp; `Source` says `standby` while the values are heard from another gateway's polls.
pub fn drive_values(v: &DriveView, bus_online: bool, now: DateTime) -> Vec<DataValue> {
    let q = quality(v, bus_online);
    let answered = v.last_seen_ms.map(datetime_ms).unwrap_or(now);
    let opt = |x: Option<f64>| x.map_or(Variant::Empty, Variant::Double);
    DRIVE_VARIABLES
        .iter()
        .map(|def| {
            let value = match def.name {
                "OutputFrequency" => opt(v.output_hz),
                "Setpoint" => opt(v.setpoint_hz),
                "Current" => opt(v.current_a),
                "Running" => v.running.map_or(Variant::Empty, Variant::Boolean),
                "Direction" => Variant::String(UAString::from(v.direction.clone().unwrap_or_default())),
                "FaultCode" => Variant::UInt32(v.fault.as_ref().map_or(0, |f| f.code)),
                "FaultText" => Variant::String(UAString::from(
                    v.fault.as_ref().map(|f| f.text.clone()).unwrap_or_default(),
                )),
                "Online" => Variant::Boolean(v.online == Some(true) && bus_online),
                "AgeMs" => v.age_ms.map_or(Variant::Empty, |a| Variant::Double(a as f64)),
                "Source" => Variant::String(UAString::from(v.source)),
                _ => Variant::Double(v.error_rate),
            };
            let own = GATEWAY_KNOWLEDGE.contains(&def.name);
            DataValue {
                value: Some(value),
                status: Some(if own { StatusCode::Good } else { q }),
                source_timestamp: Some(if own { now } else { answered }),
                server_timestamp: Some(now),
                ..Default::default()
            }
        })
        .collect()
}

/// A drive's named values (`Values/<name>`, a template's `[values]`) `names` as data values,
/// under the rules of the drive's values in [`drive_values`]: the status of [`quality`], the
/// source timestamp of the drive's last answer, empty before the first.
pub fn named_values<'a>(
    v: &DriveView,
    names: impl IntoIterator<Item = &'a str>,
    bus_online: bool,
    now: DateTime,
) -> Vec<DataValue> {
    let q = quality(v, bus_online);
    let answered = v.last_seen_ms.map(datetime_ms).unwrap_or(now);
    names
        .into_iter()
        .map(|name| DataValue {
            value: Some(v.values.get(name).map_or(Variant::Empty, |x| Variant::Double(x.value))),
            status: Some(q),
            source_timestamp: Some(answered),
            server_timestamp: Some(now),
            ..Default::default()
        })
        .collect()
}

/// Whether `bus` is online (a bus the gateway does not know counts as online).
pub fn bus_online(gw: &Gateway, bus: &str) -> bool {
    gw.buses().iter().find(|b| b.config.name == bus).map_or(true, |b| b.online())
}

/// A bus's variables as values, in [`BUS_VARIABLES`] order.
pub fn bus_values(b: &BusView) -> Vec<Variant> {
    BUS_VARIABLES
        .iter()
        .map(|def| match def.name {
            "Transactions" => Variant::UInt64(b.transactions),
            "Timeouts" => Variant::UInt64(b.timeouts),
            "ChecksumErrors" => Variant::UInt64(b.checksum_errors),
            "Retries" => Variant::UInt64(b.retries),
            "Utilization" => Variant::Double(b.utilization),
            "Role" => Variant::String(UAString::from(b.role)),
            _ => Variant::Boolean(b.online),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_key_is_beside_a_named_store_else_in_the_state_folder_never_in_the_working_directory() {
        let state = || Ok(PathBuf::from("/state/drivebus"));
        let mut config = crate::GatewayConfig::from_toml("t.toml", "[opcua]\n").unwrap();
        let o = config.opcua.clone().unwrap();
        config.store = Some(PathBuf::from("/var/lib/drivebus/drivebus.db"));
        assert_eq!(pki_dir_in(&config, &o, state).unwrap(), PathBuf::from("/var/lib/drivebus/pki"));
        // A store path with no folder is in the working directory: the key does not follow it.
        config.store = Some(PathBuf::from("drivebus-demo.db"));
        assert_eq!(pki_dir_in(&config, &o, state).unwrap(), PathBuf::from("/state/drivebus/pki"));
        config.store = None;
        assert_eq!(pki_dir_in(&config, &o, state).unwrap(), PathBuf::from("/state/drivebus/pki"));
        let err = pki_dir_in(&config, &o, || Err("no state folder".into())).unwrap_err();
        assert!(err.contains("[opcua] pki_dir"), "{err}");
        // Named by the user: as named.
        let named = OpcUaConfig { pki_dir: Some(PathBuf::from("keys")), ..o };
        assert_eq!(pki_dir_in(&config, &named, state).unwrap(), PathBuf::from("keys"));
    }
}

#[cfg(test)]
mod host_tests {
    use super::*;

    #[test]
    fn every_address_is_advertised_by_the_machines_name_never_as_0_0_0_0() {
        let name = || Some("gw-7".to_string());
        let any4 = "0.0.0.0:4840".parse().unwrap();
        let any6 = "[::]:4840".parse().unwrap();
        assert_eq!(advertised_host(None, any4, name).unwrap(), "gw-7");
        assert_eq!(advertised_host(None, any6, name).unwrap(), "gw-7");
        assert_eq!(
            advertised_host(Some("scada-gw.plant.local"), any4, name).unwrap(),
            "scada-gw.plant.local"
        );
        assert_eq!(advertised_host(None, "10.0.0.5:4840".parse().unwrap(), name).unwrap(), "10.0.0.5");
        assert_eq!(advertised_host(None, "[fd00::5]:4840".parse().unwrap(), name).unwrap(), "[fd00::5]");
        let err = advertised_host(None, any4, || None).unwrap_err();
        assert!(err.contains("[opcua] host"), "{err}");
    }
}
