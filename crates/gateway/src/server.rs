//! `drivebus serve`: the gateway and its listeners in one process, until Ctrl-C or SIGTERM;
//! SIGHUP reloads the configuration ([`Gateway::reload`]).

use std::net::SocketAddr;
use std::sync::Arc;

use tokio::net::{TcpListener, TcpSocket};

use crate::config::GatewayConfig;
use crate::core::Gateway;
use crate::log;

/// Where the service listens, once bound.
#[derive(Clone, Debug)]
pub struct Bound {
    /// The HTTP listener.
    pub http: SocketAddr,
    /// The Modbus TCP listener.
    pub modbus: SocketAddr,
    /// The OPC UA listener, when configured.
    pub opcua: Option<SocketAddr>,
    /// The Modbus bridges' listeners, with their buses.
    pub bridges: Vec<(String, SocketAddr)>,
}

/// Reads the configuration again for a reload (the file, with the command line's overrides);
/// `Err` is the one-line reason it cannot be used.
pub type Loader = Box<dyn Fn() -> Result<GatewayConfig, String> + Send + Sync>;

/// Connections the kernel may hold completed for a listener before it accepts them (capped by
/// `net.core.somaxconn`). A plant's SCADA that restarts opens its connections all at once; with
/// the 128 of `TcpListener::bind` the excess handshakes were dropped and each of those clients
/// waited a second or more for its retry.
const BACKLOG: u32 = 4096;

fn bind(addr: SocketAddr, what: &str, option: &str) -> Result<TcpListener, String> {
    let listen = || -> std::io::Result<TcpListener> {
        let socket = if addr.is_ipv4() { TcpSocket::new_v4()? } else { TcpSocket::new_v6()? };
        socket.set_reuseaddr(true)?;
        socket.bind(addr)?;
        socket.listen(BACKLOG)
    };
    listen().map_err(|e| {
        format!("cannot listen for {what} on {addr}: {e}: give another address with {option} HOST:PORT")
    })
}

/// Binds the listeners of `gw`'s configuration, calls `ready` with them, and serves until the
/// process is asked to stop; then flushes the store. With a `loader`, SIGHUP reloads the
/// configuration through it.
pub async fn run(gw: Arc<Gateway>, loader: Option<Loader>, ready: impl FnOnce(&Bound)) -> Result<(), String> {
    let cfg = gw.config();
    gw.health().listener("http", cfg.http.listen, false);
    gw.health().listener("modbus", cfg.modbus.listen, false);
    if let Some(o) = &cfg.opcua {
        gw.health().listener("opcua", o.listen, false);
    }
    // HTTPS with [http] tls_cert and tls_key; write tokens in clear off this machine refused.
    if let Some(why) = cfg.http.plaintext_refusal(&cfg.tokens) {
        return Err(why);
    }
    let https = match &cfg.http.tls {
        Some(t) => Some(crate::config::tls::server_config(&t.cert, &t.key)?),
        None => None,
    };
    let http = bind(cfg.http.listen, if https.is_some() { "HTTPS" } else { "HTTP" }, "--http")?;
    let modbus = bind(cfg.modbus.listen, "Modbus TCP", "--modbus")?;
    // OPC UA is on by default: a box where 4840 is taken (another OPC UA server) still gets its
    // gateway, with the listener reported down (log, /readyz, metrics) instead of no gateway.
    let opcua = match &cfg.opcua {
        Some(o) => match bind(o.listen, "OPC UA", "--opcua") {
            Ok(l) => Some(l),
            Err(e) => {
                log::warn(&format!("{e}, or --no-opcua; serving without OPC UA"));
                None
            }
        },
        None => None,
    };
    let mut bound = Bound {
        http: http.local_addr().map_err(|e| e.to_string())?,
        modbus: modbus.local_addr().map_err(|e| e.to_string())?,
        opcua: opcua.as_ref().map(|l| l.local_addr()).transpose().map_err(|e| e.to_string())?,
        bridges: Vec::new(),
    };
    gw.health().listener("http", bound.http, true);
    gw.health().listener("modbus", bound.modbus, true);
    let http_task = tokio::spawn(crate::http::serve(gw.clone(), http, https));
    let modbus_task = tokio::spawn(crate::modbus_tcp::serve(gw.clone(), modbus));
    if let Some(m) = &cfg.mqtt {
        crate::mqtt::spawn(gw.clone(), m)?;
    }
    if let (Some(o), Some(listener), Some(addr)) = (&cfg.opcua, opcua, bound.opcua) {
        let serve = crate::opcua::start(gw.clone(), o, listener)?;
        gw.health().listener("opcua", addr, true);
        let gw2 = gw.clone();
        tokio::spawn(async move {
            if let Err(e) = serve.await {
                gw2.health().listener("opcua", addr, false);
                log::warn(&e);
            }
        });
    }
    if let Some(sp) = &cfg.sparkplug {
        crate::sparkplug::spawn(gw.clone(), sp)?;
    }
    if let Some(loader) = loader {
        tokio::spawn(reload_on_hangup(gw.clone(), loader));
    }
    for b in &cfg.bridges {
        let l = bind(b.listen, &format!("the Modbus bridge to bus {}", b.bus), "--bridge BUS=")?;
        let addr = l.local_addr().map_err(|e| e.to_string())?;
        gw.health().listener(&format!("bridge-{}", b.bus), addr, true);
        bound.bridges.push((b.bus.clone(), addr));
        tokio::spawn(crate::bridge::serve(gw.clone(), b.clone(), l));
    }
    for m in &cfg.modbus_rtu {
        tokio::spawn(crate::modbus_rtu::run(gw.clone(), m.clone()));
    }
    ready(&bound);
    let stop = async {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending().await } } => {}
        }
    };
    let result = tokio::select! {
        _ = stop => Ok(()),
        r = http_task => {
            gw.health().listener("http", bound.http, false);
            Err(format!("the HTTP server stopped: {r:?}"))
        }
        r = modbus_task => {
            gw.health().listener("modbus", bound.modbus, false);
            Err(format!("the Modbus TCP server stopped: {r:?}"))
        }
    };
    if let Some(store) = gw.store() {
        store.flush().map_err(|e| e.to_string())?;
    }
    result
}

/// Reloads the configuration on each SIGHUP (`systemctl reload drivebus`).
async fn reload_on_hangup(gw: Arc<Gateway>, loader: Loader) {
    let Ok(mut hup) = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::hangup()) else {
        log::warn("cannot catch SIGHUP: the configuration cannot be reloaded without a restart");
        return;
    };
    let loader = Arc::new(loader);
    while hup.recv().await.is_some() {
        let load = loader.clone();
        let next = tokio::task::spawn_blocking(move || load()).await.unwrap_or_else(|e| Err(e.to_string()));
        reload_with(&gw, next, "signal").await;
    }
}

/// Applies a configuration read for a reload, or keeps the running one when it did not check:
/// logs the outcome, counts it for the metrics and puts it in the audit trail.
pub async fn reload_with(gw: &Arc<Gateway>, next: Result<GatewayConfig, String>, actor: &str) {
    let result = match next {
        Ok(config) => gw.reload(config, actor).await,
        Err(e) => Err(e),
    };
    match result {
        Ok(r) => {
            gw.health().reloaded(Ok(()));
            log::info(&format!("configuration reloaded: {}", r.summary));
        }
        Err(e) => {
            gw.health().reloaded(Err(&e));
            log::warn(&format!("configuration not reloaded, the running one stays: {e}"));
            gw.reload_refused(actor, &e).await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A burst of clients that connect while the listener is busy elsewhere is held by the
    /// kernel, not dropped: 600 handshakes complete with nothing accepted yet (with a backlog
    /// of 128 the 130th would wait for ever here).
    #[tokio::test]
    async fn a_burst_of_connections_waits_in_the_backlog() {
        let listener = bind("127.0.0.1:0".parse().unwrap(), "a test", "--test").expect("listen");
        let addr = listener.local_addr().unwrap();
        let somaxconn: usize = std::fs::read_to_string("/proc/sys/net/core/somaxconn")
            .ok()
            .and_then(|s| s.trim().parse().ok())
            .unwrap_or(4096);
        let n = somaxconn.min(600);
        let held = tokio::task::spawn_blocking(move || {
            (0..n)
                .map(|i| {
                    std::net::TcpStream::connect_timeout(&addr, std::time::Duration::from_secs(20))
                        .unwrap_or_else(|e| {
                            panic!("connection {i} of {n} not taken while none was accepted: {e}")
                        })
                })
                .collect::<Vec<_>>()
        })
        .await
        .unwrap();
        assert_eq!(held.len(), n);
        drop(listener);
    }
}
