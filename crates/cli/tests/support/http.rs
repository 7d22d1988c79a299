//! A small HTTP/1.1 client for the tests (the simulator's control interface, the gateway,
//! chromedriver): JSON in and out ([`http_json`]), or a token and text ([`request`]); and a
//! free loopback port for a server the test starts ([`free_port`]).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::time::Duration;

use serde_json::Value;

/// A free loopback port (bound, read, released).
#[allow(dead_code)]
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).expect("a free loopback port").port()
}

/// How long an answer may take.
const PATIENCE: Duration = Duration::from_secs(90);

/// One HTTP/1.1 request: the status and the body (chunked bodies joined). Reads by the head's
/// length, since chromedriver keeps the connection open whatever the request says.
fn exchange(
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &str,
    body: &str,
) -> Result<(u16, Vec<u8>), String> {
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(5)).map_err(|e| e.to_string())?;
    s.set_read_timeout(Some(PATIENCE)).map_err(|e| e.to_string())?;
    let req = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\n{headers}Content-Type: application/json; charset=utf-8\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    s.write_all(req.as_bytes()).map_err(|e| e.to_string())?;
    let mut raw = Vec::new();
    let mut buf = [0u8; 16384];
    let (head, body_start) = loop {
        if let Some(i) = raw.windows(4).position(|w| w == b"\r\n\r\n") {
            break (String::from_utf8_lossy(&raw[..i]).to_string(), i + 4);
        }
        let n = s.read(&mut buf).map_err(|e| format!("{method} {path}: {e}"))?;
        if n == 0 {
            return Err(format!("{method} {path}: the connection closed before the answer"));
        }
        raw.extend_from_slice(&buf[..n]);
    };
    let status: u16 = head
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| format!("bad status line: {head}"))?;
    let header = |name: &str| {
        head.lines().skip(1).find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.trim().eq_ignore_ascii_case(name).then(|| v.trim().to_ascii_lowercase())
        })
    };
    let mut content = raw.split_off(body_start);
    if header("transfer-encoding").is_some_and(|v| v.contains("chunked")) {
        while !content.windows(5).any(|w| w == b"0\r\n\r\n") {
            let n = s.read(&mut buf).map_err(|e| format!("{method} {path}: {e}"))?;
            if n == 0 {
                break;
            }
            content.extend_from_slice(&buf[..n]);
        }
        content = dechunk(&content)?;
    } else if let Some(len) = header("content-length").and_then(|v| v.parse::<usize>().ok()) {
        while content.len() < len {
            let n = s.read(&mut buf).map_err(|e| format!("{method} {path}: {e}"))?;
            if n == 0 {
                return Err(format!("{method} {path}: short body"));
            }
            content.extend_from_slice(&buf[..n]);
        }
        content.truncate(len);
    } else {
        s.read_to_end(&mut content).map_err(|e| format!("{method} {path}: {e}"))?;
    }
    Ok((status, content))
}

/// One HTTP/1.1 request with a JSON body; the status and the JSON answer.
#[allow(dead_code)]
pub fn http_json(
    addr: SocketAddr,
    method: &str,
    path: &str,
    body: Option<&Value>,
) -> Result<(u16, Value), String> {
    let body = body.map(|b| b.to_string()).unwrap_or_default();
    let (status, content) = exchange(addr, method, path, "", &body)?;
    let value = if content.is_empty() {
        Value::Null
    } else {
        serde_json::from_slice(&content).map_err(|e| format!("{method} {path}: not JSON ({e})"))?
    };
    Ok((status, value))
}

/// `method path` with an optional bearer token and body: the status and the body as text.
/// Panics (the test fails) when the gateway cannot be reached.
#[allow(dead_code)]
pub fn request(
    addr: SocketAddr,
    method: &str,
    path: &str,
    token: Option<&str>,
    body: Option<&str>,
) -> (u16, String) {
    let auth = token.map(|t| format!("Authorization: Bearer {t}\r\n")).unwrap_or_default();
    let (status, content) =
        exchange(addr, method, path, &auth, body.unwrap_or("")).unwrap_or_else(|e| panic!("{e}"));
    (status, String::from_utf8_lossy(&content).to_string())
}

fn dechunk(mut b: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    loop {
        let eol = b.windows(2).position(|w| w == b"\r\n").ok_or("bad chunk")?;
        let size_text = String::from_utf8_lossy(&b[..eol]).to_string();
        let size = usize::from_str_radix(size_text.split(';').next().unwrap_or("").trim(), 16)
            .map_err(|_| format!("bad chunk size {size_text:?}"))?;
        b = &b[eol + 2..];
        if size == 0 {
            return Ok(out);
        }
        out.extend_from_slice(b.get(..size).ok_or("short chunk")?);
        b = b.get(size + 2..).ok_or("short chunk")?;
    }
}
