//! `drivebus serve`: the gateway and its listeners in one process, until Ctrl-C or SIGTERM.

use std::net::SocketAddr;
use std::sync::Arc;

use tokio::net::TcpListener;

use crate::gateway::Gateway;

/// Where the service listens, once bound.
#[derive(Clone, Debug)]
pub struct Bound {
    /// The HTTP listener.
    pub http: SocketAddr,
    /// The Modbus TCP listener.
    pub modbus: SocketAddr,
    /// The Modbus bridges' listeners, with their buses.
    pub bridges: Vec<(String, SocketAddr)>,
}

async fn bind(addr: SocketAddr, what: &str, option: &str) -> Result<TcpListener, String> {
    TcpListener::bind(addr).await.map_err(|e| {
        format!("cannot listen for {what} on {addr}: {e}: give another address with {option} HOST:PORT")
    })
}

/// Binds the listeners of `gw`'s configuration, calls `ready` with them, and serves until the
/// process is asked to stop; then flushes the store.
pub async fn run(gw: Arc<Gateway>, ready: impl FnOnce(&Bound)) -> Result<(), String> {
    let cfg = gw.config().clone();
    let http = bind(cfg.http.listen, "HTTP", "--http").await?;
    let modbus = bind(cfg.modbus.listen, "Modbus TCP", "--modbus").await?;
    let mut bound = Bound {
        http: http.local_addr().map_err(|e| e.to_string())?,
        modbus: modbus.local_addr().map_err(|e| e.to_string())?,
        bridges: Vec::new(),
    };
    let router = crate::http::router(gw.clone());
    let http_task = tokio::spawn(async move {
        axum::serve(http, router.into_make_service_with_connect_info::<SocketAddr>()).await
    });
    let modbus_task = tokio::spawn(crate::modbus_tcp::serve(gw.clone(), modbus));
    if let Some(m) = &cfg.mqtt {
        crate::mqtt::spawn(gw.clone(), m)?;
    }
    for b in &cfg.bridges {
        let l = bind(b.listen, &format!("the Modbus bridge to bus {}", b.bus), "--bridge BUS=").await?;
        bound.bridges.push((b.bus.clone(), l.local_addr().map_err(|e| e.to_string())?));
        tokio::spawn(crate::bridge::serve(gw.clone(), b.clone(), l));
    }
    for m in &cfg.modbus_rtu {
        tokio::spawn(crate::modbus_rtu::Slave::open(gw.clone(), m)?.run());
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
        r = http_task => Err(format!("the HTTP server stopped: {r:?}")),
        r = modbus_task => Err(format!("the Modbus TCP server stopped: {r:?}")),
    };
    if let Some(store) = gw.store() {
        store.flush().map_err(|e| e.to_string())?;
    }
    result
}
