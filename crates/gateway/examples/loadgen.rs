//! Load generator for bench/gateway_load.sh: closed-loop Modbus TCP and HTTP clients on one
//! thread, requests/s and latency percentiles; and a many-connections test.
//!
//! ```text
//! loadgen load  --modbus HOST:PORT [--clients 128] [--units 1-10] [--rate R] [--http HOST:PORT
//!               --http-clients 64 --path /api/drives] [--secs 10]
//! loadgen conns --modbus HOST:PORT --n 10000 [--units 1-10]
//! ```
//!
//! Each Modbus client reads the ten input registers (FC 04, address 0, count 10) of a unit in a
//! loop, one request outstanding; each HTTP client sends keep-alive `GET <path>` in a loop.
//! With `--rate R` the Modbus clients together send R requests/s on a schedule (each client
//! every `clients / R` seconds, staggered) instead of back to back: the latency of a server
//! that is not saturated. tokio's timer ends waits on whole milliseconds, so requests leave in
//! bursts of about R / 1000 at each tick: a harder load than the same rate spread evenly.
//! Latency is measured from the write of a request to the end of its answer.

use std::cell::RefCell;
use std::net::SocketAddr;
use std::rc::Rc;
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Latencies in microseconds, one bucket per microsecond up to 100 ms.
struct Histogram {
    buckets: Vec<u64>,
    count: u64,
    errors: u64,
}

impl Histogram {
    fn new() -> Self {
        Histogram { buckets: vec![0; 100_001], count: 0, errors: 0 }
    }
    fn record(&mut self, d: Duration) {
        let us = (d.as_micros() as usize).min(100_000);
        self.buckets[us] += 1;
        self.count += 1;
    }
    fn percentile(&self, p: f64) -> f64 {
        let target = ((self.count as f64) * p).ceil() as u64;
        let mut seen = 0;
        for (us, n) in self.buckets.iter().enumerate() {
            seen += n;
            if seen >= target.max(1) {
                return us as f64 / 1000.0;
            }
        }
        100.0
    }
}

fn arg(args: &[String], name: &str) -> Option<String> {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1).cloned())
}

fn units(spec: &str) -> Vec<u8> {
    match spec.split_once('-') {
        Some((a, b)) => (a.parse().expect("--units A-B")..=b.parse().expect("--units A-B")).collect(),
        None => vec![spec.parse().expect("--units N")],
    }
}

fn modbus_request(tid: u16, unit: u8) -> [u8; 12] {
    let t = tid.to_be_bytes();
    [t[0], t[1], 0, 0, 0, 6, unit, 4, 0, 0, 0, 10]
}

/// One Modbus read of ten input registers; Ok when the answer is a 29-byte FC 04 reply.
///
/// The reply is read with as few `read` calls as the kernel allows (one, when it arrived whole):
/// a read shorter than the buffer tells tokio the socket is drained, so the next request waits
/// on epoll instead of trying a read that fails with EAGAIN. Two `read_exact` calls (header,
/// then body) made three reads per request, and the generator, not the server, was the limit.
async fn modbus_read(s: &mut TcpStream, tid: u16, unit: u8, buf: &mut [u8; 64]) -> std::io::Result<bool> {
    s.write_all(&modbus_request(tid, unit)).await?;
    let mut got = 0;
    let mut want = 9;
    while got < want {
        let n = s.read(&mut buf[got..]).await?;
        if n == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        got += n;
        if want == 9 && got >= 6 {
            let len = u16::from_be_bytes([buf[4], buf[5]]) as usize;
            if !(2..=58).contains(&len) {
                return Ok(false);
            }
            want = 6 + len;
        }
    }
    Ok(got == want && buf[7] == 4 && buf[8] == 20 && u16::from_be_bytes([buf[0], buf[1]]) == tid)
}

/// Every `period` from `first` on, or back to back without one.
struct Schedule {
    next: Instant,
    period: Duration,
}

async fn modbus_client(
    addr: SocketAddr,
    unit: u8,
    stop: Instant,
    mut schedule: Option<Schedule>,
    h: Rc<RefCell<Histogram>>,
) {
    let Ok(mut s) = TcpStream::connect(addr).await else {
        h.borrow_mut().errors += 1;
        return;
    };
    let _ = s.set_nodelay(true);
    let mut buf = [0u8; 64];
    let mut tid = 0u16;
    while Instant::now() < stop {
        if let Some(sch) = schedule.as_mut() {
            tokio::time::sleep_until(sch.next.into()).await;
            sch.next += sch.period;
            // Behind (a slow answer): start again from now rather than catch up in a burst.
            let now = Instant::now();
            if sch.next < now {
                sch.next = now;
            }
        }
        tid = tid.wrapping_add(1);
        let t = Instant::now();
        match modbus_read(&mut s, tid, unit, &mut buf).await {
            Ok(true) => h.borrow_mut().record(t.elapsed()),
            Ok(false) => h.borrow_mut().errors += 1,
            Err(_) => {
                h.borrow_mut().errors += 1;
                return;
            }
        }
    }
}

/// One keep-alive GET; Ok(true) on a 200 with its whole body read.
async fn http_get(s: &mut TcpStream, req: &[u8], buf: &mut Vec<u8>) -> std::io::Result<bool> {
    s.write_all(req).await?;
    buf.clear();
    let mut chunk = [0u8; 16384];
    loop {
        let n = s.read(&mut chunk).await?;
        if n == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        buf.extend_from_slice(&chunk[..n]);
        let Some(end) = buf.windows(4).position(|w| w == b"\r\n\r\n") else { continue };
        let head = std::str::from_utf8(&buf[..end]).unwrap_or("");
        let ok = head.starts_with("HTTP/1.1 200");
        let len = head
            .lines()
            .find_map(|l| {
                let (k, v) = l.split_once(':')?;
                k.eq_ignore_ascii_case("content-length").then(|| v.trim().parse::<usize>().ok())?
            })
            .unwrap_or(0);
        while buf.len() < end + 4 + len {
            let n = s.read(&mut chunk).await?;
            if n == 0 {
                return Err(std::io::ErrorKind::UnexpectedEof.into());
            }
            buf.extend_from_slice(&chunk[..n]);
        }
        return Ok(ok);
    }
}

async fn http_client(addr: SocketAddr, path: String, stop: Instant, h: Rc<RefCell<Histogram>>) {
    let Ok(mut s) = TcpStream::connect(addr).await else {
        h.borrow_mut().errors += 1;
        return;
    };
    let _ = s.set_nodelay(true);
    let req = format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: keep-alive\r\n\r\n").into_bytes();
    let mut buf = Vec::with_capacity(16384);
    while Instant::now() < stop {
        let t = Instant::now();
        match http_get(&mut s, &req, &mut buf).await {
            Ok(true) => h.borrow_mut().record(t.elapsed()),
            Ok(false) => h.borrow_mut().errors += 1,
            Err(_) => {
                h.borrow_mut().errors += 1;
                return;
            }
        }
    }
}

fn report(what: &str, clients: usize, secs: f64, h: &Histogram) {
    println!(
        "{what}: {clients} clients, {} requests in {secs:.1} s = {:.0} req/s; latency p50 {:.3} ms, p99 {:.3} ms, max<= {:.3} ms; errors {}",
        h.count,
        h.count as f64 / secs,
        h.percentile(0.50),
        h.percentile(0.99),
        h.percentile(1.0),
        h.errors
    );
}

async fn load(args: &[String]) {
    let secs: f64 = arg(args, "--secs").map_or(10.0, |s| s.parse().expect("--secs"));
    let units = units(&arg(args, "--units").unwrap_or_else(|| "1-10".into()));
    let modbus: Option<SocketAddr> = arg(args, "--modbus").map(|a| a.parse().expect("--modbus HOST:PORT"));
    let http: Option<SocketAddr> = arg(args, "--http").map(|a| a.parse().expect("--http HOST:PORT"));
    let clients: usize = arg(args, "--clients").map_or(128, |s| s.parse().expect("--clients"));
    let http_clients: usize = arg(args, "--http-clients").map_or(64, |s| s.parse().expect("--http-clients"));
    let path = arg(args, "--path").unwrap_or_else(|| "/api/drives".into());
    let rate: Option<f64> = arg(args, "--rate").map(|s| match s.parse::<f64>() {
        Ok(r) if r.is_finite() && r > 0.0 => r,
        _ => {
            eprintln!("loadgen: --rate {s:?}: give the requests per second, a number above 0");
            std::process::exit(3)
        }
    });
    let mh = Rc::new(RefCell::new(Histogram::new()));
    let hh = Rc::new(RefCell::new(Histogram::new()));
    let start = Instant::now();
    let stop = start + Duration::from_secs_f64(secs);
    let mut tasks = Vec::new();
    if let Some(addr) = modbus {
        for i in 0..clients {
            let schedule = rate.map(|r| {
                let period = Duration::from_secs_f64(clients as f64 / r);
                Schedule { next: start + period.mul_f64(i as f64 / clients as f64), period }
            });
            tasks.push(tokio::task::spawn_local(modbus_client(
                addr,
                units[i % units.len()],
                stop,
                schedule,
                mh.clone(),
            )));
        }
    }
    if let Some(addr) = http {
        for _ in 0..http_clients {
            tasks.push(tokio::task::spawn_local(http_client(addr, path.clone(), stop, hh.clone())));
        }
    }
    for t in tasks {
        let _ = t.await;
    }
    let took = start.elapsed().as_secs_f64();
    if modbus.is_some() {
        report("modbus", clients, took, &mh.borrow());
    }
    if http.is_some() {
        report(&format!("http GET {path}"), http_clients, took, &hh.borrow());
    }
}

async fn conns(args: &[String]) {
    let addr: SocketAddr = arg(args, "--modbus").expect("--modbus HOST:PORT").parse().expect("--modbus");
    let n: usize = arg(args, "--n").map_or(10_000, |s| s.parse().expect("--n"));
    let units = units(&arg(args, "--units").unwrap_or_else(|| "1-10".into()));
    let start = Instant::now();
    let mut socks = Vec::with_capacity(n);
    let mut connect_errors = 0;
    for _ in 0..n {
        match TcpStream::connect(addr).await {
            Ok(s) => socks.push(s),
            Err(_) => connect_errors += 1,
        }
    }
    let connected = start.elapsed();
    let ok = Rc::new(RefCell::new(0usize));
    let mut tasks = Vec::new();
    for (i, mut s) in socks.into_iter().enumerate() {
        let ok = ok.clone();
        let unit = units[i % units.len()];
        tasks.push(tokio::task::spawn_local(async move {
            let mut buf = [0u8; 64];
            let r =
                tokio::time::timeout(Duration::from_secs(30), modbus_read(&mut s, 1, unit, &mut buf)).await;
            if matches!(r, Ok(Ok(true))) {
                *ok.borrow_mut() += 1;
            }
            s
        }));
    }
    let mut held = Vec::new();
    for t in tasks {
        if let Ok(s) = t.await {
            held.push(s);
        }
    }
    println!(
        "connections: {n} opened ({connect_errors} refused) in {:.2} s; {} of {n} answered one read each, all in {:.2} s",
        connected.as_secs_f64(),
        ok.borrow(),
        start.elapsed().as_secs_f64()
    );
    drop(held);
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let Err(e) = drivebus_gateway::limits::raise_nofile_limit() {
        eprintln!("loadgen: cannot raise the open files limit: {e}");
    }
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
    let local = tokio::task::LocalSet::new();
    match args.get(1).map(String::as_str) {
        Some("load") => local.block_on(&rt, load(&args)),
        Some("conns") => local.block_on(&rt, conns(&args)),
        _ => {
            eprintln!(
                "usage: loadgen load --modbus HOST:PORT [--clients 128] [--http HOST:PORT] [--secs 10]"
            );
            eprintln!("       loadgen conns --modbus HOST:PORT --n 10000");
            std::process::exit(2);
        }
    }
}
