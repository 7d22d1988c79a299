//! HTTPS with `[http] tls_cert` and `tls_key` (a certificate made at test time): the dashboard,
//! the API, the metrics and the health answers over TLS to a client that checks the
//! certificate; a plain HTTP request to it gets no answer; a client that opens a connection and
//! never starts the handshake is closed by the header timeout, as over plain HTTP.

mod tls_support;

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use drivebus_gateway::{Gateway, GatewayConfig};
use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, ServerName};
use tls_support::TestPki;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio_rustls::rustls::{ClientConfig, RootCertStore};

const PATIENCE: Duration = Duration::from_secs(60);

async fn start(pki: &TestPki) -> (Arc<Gateway>, SocketAddr) {
    let text = format!(
        "[http]\nanonymous_read = true\ntls_cert = \"{}\"\ntls_key = \"{}\"\n\
         [limits]\nheader_timeout_ms = 300\n\
         [[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
         [[bus.drive]]\nname = \"d1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 100\n",
        TestPki::toml(&pki.server_cert),
        TestPki::toml(&pki.server_key)
    );
    let cfg = GatewayConfig::from_toml("plant.toml", &text).unwrap();
    let tls = cfg.http.tls.clone().expect("HTTPS configured");
    let server = drivebus_gateway::config::tls::server_config(&tls.cert, &tls.key).unwrap();
    let gw = Gateway::start(cfg, None).unwrap();
    let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(drivebus_gateway::http::serve(gw.clone(), l, Some(server)));
    (gw, addr)
}

fn client(ca: &std::path::Path) -> tokio_rustls::TlsConnector {
    let mut roots = RootCertStore::empty();
    for c in CertificateDer::pem_file_iter(ca).unwrap() {
        roots.add(c.unwrap()).unwrap();
    }
    let provider = Arc::new(tokio_rustls::rustls::crypto::ring::default_provider());
    let config = ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth();
    tokio_rustls::TlsConnector::from(Arc::new(config))
}

/// `GET path` over TLS: the status line and the body.
async fn get(connector: &tokio_rustls::TlsConnector, at: SocketAddr, path: &str) -> (String, String) {
    let tcp = TcpStream::connect(at).await.unwrap();
    let mut tls = connector.connect(ServerName::try_from("localhost").unwrap(), tcp).await.unwrap();
    let req = format!("GET {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n");
    tls.write_all(req.as_bytes()).await.unwrap();
    let mut out = Vec::new();
    tokio::time::timeout(PATIENCE, tls.read_to_end(&mut out)).await.unwrap().unwrap_or(0);
    let text = String::from_utf8_lossy(&out).into_owned();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    (head.lines().next().unwrap_or("").to_string(), body.to_string())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn https_serves_the_dashboard_api_metrics_and_health() {
    let pki = TestPki::new("https", &["localhost"]);
    let (_gw, at) = start(&pki).await;
    let connector = client(&pki.ca);
    for (path, says) in [
        ("/healthz", "\"status\":\"ok\""),
        ("/api/drives", "\"id\":\"d1\""),
        ("/metrics", "drivebus_"),
        ("/", "<html"),
    ] {
        let (status, body) = get(&connector, at, path).await;
        assert!(status.starts_with("HTTP/1.1 200"), "{path}: {status}");
        assert!(body.contains(says), "{path}: {body:.300}");
    }

    // A client that trusts another CA refuses the certificate.
    let other = client(&pki.other_ca);
    let tcp = TcpStream::connect(at).await.unwrap();
    let e = other.connect(ServerName::try_from("localhost").unwrap(), tcp).await.unwrap_err();
    assert!(e.to_string().contains("UnknownIssuer"), "{e}");

    // Plain HTTP to the HTTPS listener: no HTTP answer, the connection is closed.
    let mut plain = TcpStream::connect(at).await.unwrap();
    plain.write_all(b"GET /healthz HTTP/1.1\r\nHost: localhost\r\n\r\n").await.unwrap();
    let mut out = Vec::new();
    let _ = tokio::time::timeout(PATIENCE, plain.read_to_end(&mut out)).await.expect("closed");
    assert!(!String::from_utf8_lossy(&out).contains("200 OK"), "{out:?}");

    // A connection that never starts its handshake is closed by the header timeout.
    let mut silent = TcpStream::connect(at).await.unwrap();
    let mut buf = [0u8; 16];
    let n =
        tokio::time::timeout(PATIENCE, silent.read(&mut buf)).await.expect("closed by the header timeout");
    assert!(matches!(n, Ok(0) | Err(_)), "{n:?}");
}

/// A reload keeps the listener as it runs: a write token added while it serves plain HTTP on
/// every address (e.g. `--http 0.0.0.0:8080` on the command line) is refused, the running
/// configuration kept.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reload_may_not_add_a_write_token_to_a_plain_listener_off_loopback() {
    let bus = "[[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
               [[bus.drive]]\nname = \"d1\"\nfamily = \"generic\"\naddress = 1\n";
    let mut running = GatewayConfig::from_toml("plant.toml", bus).unwrap();
    running.http.listen = "0.0.0.0:8080".parse().unwrap();
    let gw = Gateway::start(running, None).unwrap();
    let token = "[[token]]\nname = \"scada\"\ntoken = \"0123456789abcdef-w\"\nrole = \"write\"\n";
    let next = GatewayConfig::from_toml("plant.toml", &format!("{token}{bus}")).unwrap();
    let e = gw.reload(next, "test").await.unwrap_err();
    assert!(e.starts_with("write tokens would cross the network in clear on http://0.0.0.0:8080"), "{e}");
    assert!(gw.config().tokens.is_empty());
    // With the opt-out it is taken.
    let next =
        GatewayConfig::from_toml("plant.toml", &format!("[http]\nallow_plaintext = true\n{token}{bus}"))
            .unwrap();
    gw.reload(next, "test").await.unwrap();
    assert_eq!(gw.config().tokens.len(), 1);
}
