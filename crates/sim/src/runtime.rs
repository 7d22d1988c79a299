//! The simulator in real time: a virtual bus behind a pseudo-terminal or a TCP port, so any
//! serial program (pymodbus, mbpoll, a PLC runtime, `drivebus` itself) can talk to it, and a
//! small HTTP/JSON control interface to disturb it.
//!
//! Simulated time is the wall time since the simulator started; the line's pacing then holds
//! in real time: a byte written by the master reaches the drives one character time later.
//!
//! Several masters can share the line, each on its own pty or TCP port
//! ([`Simulator::add_master`], [`Simulator::serve_master`]): every byte one sends reaches the
//! drives and the other masters, and two sending at once garble each other.

use std::io;
use std::net::SocketAddr;
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{ready, Context, Poll};
use std::time::Duration;

use axum::extract::{Path as UrlPath, State};
use axum::http::StatusCode;
use axum::routing::get;
use axum::{Json, Router};
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::{Direction, Instant};
use serde::Deserialize;
use serde_json::{json, Value};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::sync::{watch, Notify};

use crate::bus::{Faults, VirtualLine};
use crate::config::{BusSpec, ConfigError};
use crate::model::Trip;
use crate::monitor::Monitor;

/// A running virtual bus.
pub struct Simulator {
    line: Mutex<VirtualLine>,
    start: std::time::Instant,
    /// Bumped whenever something outside the line's own timeline changed it (a master wrote,
    /// the control interface changed a drive): every pump then looks again.
    changed: watch::Sender<u64>,
    /// Rung when the tap has bytes to pass on.
    tap_wake: Notify,
    protocols: Vec<WireProtocol>,
}

/// Where the master reaches the bus.
#[derive(Clone, Debug)]
pub enum Endpoint {
    /// A pseudo-terminal, with a symlink at this path to its device.
    Pty(PathBuf),
    /// Raw bytes over TCP, as a serial device server gives them.
    Tcp(SocketAddr),
    /// Modbus TCP (MBAP), as a drive with an Ethernet card or a Modbus TCP/RTU gateway: each
    /// request goes on the line as Modbus RTU to the drive its unit id names.
    ModbusTcp(SocketAddr),
}

/// How long the Modbus TCP endpoint waits for a drive's answer before it answers exception 0B
/// (gateway target device failed to respond).
const MODBUS_TCP_WAIT: Duration = Duration::from_secs(1);

impl Simulator {
    /// Builds every drive of `bus` on a fresh line.
    pub fn new(bus: &BusSpec) -> Result<Arc<Self>, ConfigError> {
        let line = bus.build_line()?;
        let mut protocols: Vec<WireProtocol> = Vec::new();
        for spec in &bus.drives {
            for &p in spec.wire_protocols() {
                if !protocols.contains(&p) {
                    protocols.push(p);
                }
            }
        }
        Ok(Arc::new(Simulator {
            line: Mutex::new(line),
            start: std::time::Instant::now(),
            changed: watch::channel(0).0,
            tap_wake: Notify::new(),
            protocols,
        }))
    }

    /// Simulated time now.
    pub fn now(&self) -> Instant {
        Instant::from_nanos(self.start.elapsed().as_nanos().min(u64::MAX as u128) as u64)
    }

    fn wall(&self, t: Instant) -> tokio::time::Instant {
        tokio::time::Instant::from_std(self.start + Duration::from_nanos(t.as_nanos()))
    }

    /// The line, brought up to now.
    pub fn line(&self) -> MutexGuard<'_, VirtualLine> {
        let mut l = self.line.lock().unwrap_or_else(|p| p.into_inner());
        l.advance_to(self.now());
        l.advance_devices();
        l
    }

    /// The wire protocols spoken on the line.
    pub fn protocols(&self) -> &[WireProtocol] {
        &self.protocols
    }

    /// Adds another master's port to the line; returns its number for
    /// [`Simulator::serve_master`] (the first master, served by [`Simulator::serve`], is 0).
    pub fn add_master(&self) -> usize {
        self.line.lock().unwrap_or_else(|p| p.into_inner()).add_master()
    }

    /// Serves the bus at `endpoint` until the process ends; calls `ready` with where it
    /// listens. With `verbose`, prints a line per frame decoded.
    pub async fn serve(
        self: Arc<Self>,
        endpoint: Endpoint,
        verbose: bool,
        ready: impl FnOnce(String),
    ) -> io::Result<()> {
        self.serve_master(crate::bus::MASTER, endpoint, verbose, ready).await
    }

    /// Serves master `master` (from [`Simulator::add_master`]) at `endpoint` until the process
    /// ends, as [`Simulator::serve`] does the first. With `verbose` and several masters (add
    /// them all before serving), the first prints every frame on the line, each request marked
    /// with the master that sent it.
    pub async fn serve_master(
        self: Arc<Self>,
        master: usize,
        endpoint: Endpoint,
        verbose: bool,
        ready: impl FnOnce(String),
    ) -> io::Result<()> {
        match endpoint {
            Endpoint::Pty(path) => {
                let pty = Pty::open(&path)?;
                ready(format!("pty {} -> {}", path.display(), pty.device.display()));
                let (r, w) = tokio::io::split(pty.master);
                // The slave stays open here so the master never sees EIO between clients.
                let _slave = pty.slave;
                self.pump(master, r, w, verbose).await
            }
            Endpoint::ModbusTcp(addr) => {
                let listener = tokio::net::TcpListener::bind(addr).await?;
                ready(format!("modbus-tcp {}", listener.local_addr()?));
                let turn = Arc::new(tokio::sync::Mutex::new(()));
                // The connections end with the endpoint (dropping the set aborts them).
                let mut connections = tokio::task::JoinSet::new();
                loop {
                    let (stream, peer) = listener.accept().await?;
                    while connections.try_join_next().is_some() {}
                    if verbose {
                        println!("Modbus TCP client {peer} connected");
                    }
                    let _ = stream.set_nodelay(true);
                    let (sim, turn) = (self.clone(), turn.clone());
                    connections.spawn(async move {
                        let result = sim.serve_mbap(master, stream, turn).await;
                        if verbose {
                            println!(
                                "Modbus TCP client {peer} left ({})",
                                result.err().map_or("closed".into(), |e| e.to_string())
                            );
                        }
                    });
                }
            }
            Endpoint::Tcp(addr) => {
                let listener = tokio::net::TcpListener::bind(addr).await?;
                ready(format!("tcp {}", listener.local_addr()?));
                loop {
                    let (stream, peer) = listener.accept().await?;
                    if verbose {
                        println!("client {peer} connected");
                    }
                    let _ = stream.set_nodelay(true);
                    let (r, w) = stream.into_split();
                    let result = self.clone().pump(master, r, w, verbose).await;
                    if verbose {
                        println!(
                            "client {peer} left ({})",
                            result.err().map_or("closed".into(), |e| e.to_string())
                        );
                    }
                }
            }
        }
    }

    /// Serves one Modbus TCP client on `stream` as master `master`; `turn` keeps one exchange on
    /// the line at a time across clients.
    async fn serve_mbap(
        self: Arc<Self>,
        master: usize,
        mut stream: tokio::net::TcpStream,
        turn: Arc<tokio::sync::Mutex<()>>,
    ) -> io::Result<()> {
        use drivebus_proto::modbus::tcp::{mbap_from_rtu, rtu_from_mbap, Mbap, MAX_ADU};
        let mut buf = vec![0u8; 2048];
        let mut len = 0;
        loop {
            let n = stream.read(&mut buf[len..]).await?;
            if n == 0 {
                return Ok(());
            }
            len += n;
            let mut pos = 0;
            loop {
                let (header, total) = match Mbap::next_frame(&buf[pos..len]) {
                    Ok(Some(frame)) => frame,
                    Ok(None) => break,
                    // Nothing after a damaged header can be trusted to be framed right.
                    Err(_) => return Ok(()),
                };
                let mut rtu = [0u8; MAX_ADU];
                let Ok(rn) = rtu_from_mbap(&buf[pos..pos + total], &mut rtu) else { return Ok(()) };
                pos += total;
                let answer = {
                    let _turn = turn.lock().await;
                    self.exchange_rtu(master, &rtu[..rn], header.unit != 0).await
                };
                let mut out = [0u8; MAX_ADU];
                let sent = match answer {
                    Some(reply) => mbap_from_rtu(header.transaction, &reply, &mut out),
                    None if header.unit == 0 => continue,
                    // No drive answered: what a Modbus TCP/RTU gateway says (exception 0B).
                    None => {
                        let fc = rtu[1] & 0x7F;
                        let mut ex = [header.unit, fc | 0x80, 0x0B, 0, 0];
                        let crc = drivebus_proto::checksum::crc16_modbus(&ex[..3]).to_le_bytes();
                        ex[3..].copy_from_slice(&crc);
                        mbap_from_rtu(header.transaction, &ex, &mut out)
                    }
                };
                if let Ok(m) = sent {
                    stream.write_all(&out[..m]).await?;
                }
            }
            buf.copy_within(pos..len, 0);
            len -= pos;
        }
    }

    /// Puts the Modbus RTU request `rtu` on the line and waits for the drive's reply frame
    /// (`None`: none came within [`MODBUS_TCP_WAIT`], or none is due).
    async fn exchange_rtu(&self, master: usize, rtu: &[u8], reply_due: bool) -> Option<Vec<u8>> {
        use drivebus_proto::deframe::{Deframer, Event};
        use drivebus_proto::modbus::rtu::RtuScanner;
        self.line.lock().unwrap_or_else(|p| p.into_inner()).master_write_from(master, self.now(), rtu);
        self.changed.send_modify(|g| *g = g.wrapping_add(1));
        let mut changed = self.changed.subscribe();
        if !reply_due {
            return None;
        }
        let give_up = tokio::time::Instant::now() + MODBUS_TCP_WAIT;
        let mut replies = Deframer::new(RtuScanner::replies());
        let mut out = Vec::new();
        loop {
            let deadline = self.line.lock().unwrap_or_else(|p| p.into_inner()).next_deadline();
            let until = deadline.map_or(give_up, |d| self.wall(d).min(give_up));
            tokio::select! {
                _ = tokio::time::sleep_until(until) => {}
                _ = changed.changed() => {}
            }
            {
                let mut line = self.line.lock().unwrap_or_else(|p| p.into_inner());
                line.advance_to(self.now());
                line.master_read_to(master, &mut out);
                if line.tap_pending() {
                    self.tap_wake.notify_one();
                }
            }
            let mut reply = None;
            replies.push(&out, &mut |e| {
                if let Event::Frame { bytes, .. } = e {
                    if bytes.first() == rtu.first() && reply.is_none() {
                        reply = Some(bytes.to_vec());
                    }
                }
            });
            out.clear();
            if reply.is_some() {
                return reply;
            }
            if tokio::time::Instant::now() >= give_up {
                return None;
            }
        }
    }

    async fn pump<R, W>(self: Arc<Self>, master: usize, mut r: R, mut w: W, verbose: bool) -> io::Result<()>
    where
        R: AsyncRead + Unpin,
        W: AsyncWrite + Unpin,
    {
        let single = self.protocols.len() == 1;
        let several = self.line.lock().unwrap_or_else(|p| p.into_inner()).masters() > 1;
        // With several masters, what one receives mixes the others' requests with the drives'
        // answers: the first prints every frame from the line's log, which says who sent each.
        let from_log = several && verbose;
        if from_log && master == crate::bus::MASTER {
            self.line.lock().unwrap_or_else(|p| p.into_inner()).attach_log();
        }
        let mut logged = Vec::new();
        let mut changed = self.changed.subscribe();
        // With the log, only the first master prints.
        let mut monitors: Vec<(Monitor, Monitor)> = if verbose && !(from_log && master != crate::bus::MASTER)
        {
            self.protocols
                .iter()
                .map(|&p| {
                    (Monitor::new(p, Direction::Master, single), Monitor::new(p, Direction::Drive, single))
                })
                .collect()
        } else {
            Vec::new()
        };
        let mut buf = vec![0u8; 4096];
        let mut out = Vec::new();
        loop {
            let deadline = self.line.lock().unwrap_or_else(|p| p.into_inner()).next_deadline();
            let sleep = match deadline {
                Some(d) => tokio::time::sleep_until(self.wall(d)),
                None => tokio::time::sleep(Duration::from_secs(3600)),
            };
            tokio::select! {
                n = r.read(&mut buf) => {
                    let n = n?;
                    if n == 0 {
                        return Ok(());
                    }
                    let now = self.now();
                    self.line.lock().unwrap_or_else(|p| p.into_inner()).master_write_from(master, now, &buf[..n]);
                    self.changed.send_modify(|g| *g = g.wrapping_add(1));
                    for (m, _) in monitors.iter_mut().filter(|_| !from_log) {
                        for l in m.push(&buf[..n]) {
                            println!("{:>10.3} {l}", now.as_nanos() as f64 / 1e9);
                        }
                    }
                }
                _ = sleep => {}
                _ = changed.changed() => {}
            }
            let now = self.now();
            {
                let mut line = self.line.lock().unwrap_or_else(|p| p.into_inner());
                line.advance_to(now);
                line.master_read_to(master, &mut out);
                if from_log && master == crate::bus::MASTER {
                    line.log_read(&mut logged);
                }
                if line.tap_pending() {
                    self.tap_wake.notify_one();
                }
            }
            for (talker, bytes) in logged.drain(..) {
                let t = now.as_nanos() as f64 / 1e9;
                for (to_drives, from_drives) in &mut monitors {
                    let lines = match talker {
                        crate::bus::Talker::Master(m) => {
                            to_drives.push(&bytes).into_iter().map(|l| format!("[master {m}] {l}")).collect()
                        }
                        crate::bus::Talker::Device(_) => from_drives.push(&bytes),
                    };
                    for l in lines {
                        println!("{t:>10.3} {l}");
                    }
                }
            }
            if !out.is_empty() {
                for (_, m) in monitors.iter_mut().filter(|_| !from_log) {
                    for l in m.push(&out) {
                        println!("{:>10.3} {l}", now.as_nanos() as f64 / 1e9);
                    }
                }
                w.write_all(&out).await?;
                w.flush().await?;
                out.clear();
            }
        }
    }

    /// Serves a tap at `path`: a second pseudo-terminal that carries a copy of every byte on
    /// the virtual line, from the master and from the drives, each burst when its last
    /// character has arrived (as a passive listener on the pair of wires hears it). Listen-only:
    /// what is written to the tap is discarded. Bytes nobody reads are discarded when the pty's
    /// buffer fills, so a sniffer that opens the tap late starts with current traffic.
    ///
    /// Opens the tap now (an error says why it could not be made) and returns where it is
    /// (`tap PATH -> /dev/pts/N`) and the task that feeds it, to spawn.
    pub fn serve_tap(
        self: Arc<Self>,
        path: &Path,
    ) -> io::Result<(String, impl std::future::Future<Output = io::Result<()>> + Send + 'static)> {
        let pty = Pty::open(path)?;
        self.line.lock().unwrap_or_else(|p| p.into_inner()).attach_tap();
        let at = format!("tap {} -> {}", path.display(), pty.device.display());
        let feed = async move {
            let mut bytes = Vec::new();
            let mut sink = [0u8; 256];
            loop {
                self.tap_wake.notified().await;
                self.line.lock().unwrap_or_else(|p| p.into_inner()).tap_read(&mut bytes);
                // Whatever a program wrote to the tap: a listener's line has no talker.
                while matches!(nix::unistd::read(pty.master.fd.get_ref().as_raw_fd(), &mut sink), Ok(n) if n > 0)
                {
                }
                pty.write_or_discard(&bytes)?;
                bytes.clear();
            }
        };
        Ok((at, feed))
    }

    /// The HTTP/JSON control interface (see `docs/simulator.md`).
    pub fn control_router(self: Arc<Self>) -> Router {
        Router::new()
            .route("/", get(index))
            .route("/drives", get(list_drives))
            .route("/drives/:n", get(get_drive).post(patch_drive))
            .route("/faults", get(get_faults).put(put_faults))
            .route("/stats", get(get_stats))
            .with_state(self)
    }

    /// Serves the control interface on `addr`; calls `ready` with the bound address.
    pub async fn serve_control(
        self: Arc<Self>,
        addr: SocketAddr,
        ready: impl FnOnce(SocketAddr),
    ) -> io::Result<()> {
        let listener = tokio::net::TcpListener::bind(addr).await?;
        ready(listener.local_addr()?);
        axum::serve(listener, self.control_router()).await
    }
}

/// Serves the control interface on an already bound listener.
pub async fn serve_router(listener: tokio::net::TcpListener, sim: Arc<Simulator>) -> io::Result<()> {
    axum::serve(listener, sim.control_router()).await
}

type ApiResult = Result<Json<Value>, (StatusCode, Json<Value>)>;

fn api_error(status: StatusCode, msg: impl Into<String>) -> (StatusCode, Json<Value>) {
    (status, Json(json!({ "error": msg.into() })))
}

async fn index() -> Json<Value> {
    Json(json!({
        "endpoints": {
            "GET /drives": "every drive's state",
            "GET /drives/{n}": "drive n (1 = first --drive)",
            "POST /drives/{n}": "change drive n: {\"load\": 0.8, \"trip\": \"over-current\", \"reset\": true, \"silent\": true, \"hardware_enable\": false, \"supply\": 1.0, \"params\": {\"F-12\": 2}, \"power_cycle\": true, \"run\": true, \"keypad_hz\": 40}",
            "GET /faults, PUT /faults": "{\"corrupt_rate\": 0.01, \"drop_rate\": 0.0, \"extra_latency_ms\": 0}",
            "GET /stats": "what the line has carried (garbled_frames: frames two talkers garbled at once; garbled_frames_by_master: each master's share)"
        }
    }))
}

fn snapshot(line: &mut VirtualLine, n: usize) -> Option<Value> {
    let d = line.drive(n)?;
    let mut s = serde_json::to_value(d.snapshot()).ok()?;
    s["silent"] = json!(line.is_silent(n));
    s["n"] = json!(n);
    Some(s)
}

async fn list_drives(State(sim): State<Arc<Simulator>>) -> Json<Value> {
    let mut line = sim.line();
    Json(Value::Array((1..=line.devices()).filter_map(|n| snapshot(&mut line, n)).collect()))
}

async fn get_drive(State(sim): State<Arc<Simulator>>, UrlPath(n): UrlPath<usize>) -> ApiResult {
    let mut line = sim.line();
    let count = line.devices();
    snapshot(&mut line, n).map(Json).ok_or_else(|| no_drive(n, count))
}

fn no_drive(n: usize, count: usize) -> (StatusCode, Json<Value>) {
    api_error(
        StatusCode::NOT_FOUND,
        format!("no drive {n}: drives are numbered 1..{count} in the order given"),
    )
}

/// Changes to one drive.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DrivePatch {
    params: Option<std::collections::BTreeMap<String, Value>>,
    power_cycle: Option<bool>,
    load: Option<f64>,
    trip: Option<String>,
    reset: Option<bool>,
    silent: Option<bool>,
    hardware_enable: Option<bool>,
    supply: Option<f64>,
    /// The keypad's RUN (true) or STOP (false) key.
    run: Option<bool>,
    /// The keypad frequency setting, Hz.
    keypad_hz: Option<f64>,
}

fn parse_trip(s: &str) -> Option<Trip> {
    Some(match s.to_ascii_lowercase().replace(['_', ' '], "-").as_str() {
        "over-current" | "overcurrent" | "oc" => Trip::OverCurrent,
        "over-voltage" | "overvoltage" | "ov" => Trip::OverVoltage,
        "under-voltage" | "undervoltage" | "uv" => Trip::UnderVoltage,
        "over-temperature" | "overtemperature" | "oh" => Trip::OverTemperature,
        "communication-timeout" | "comm-timeout" => Trip::CommunicationTimeout,
        "external" => Trip::External,
        _ => return None,
    })
}

/// `value` of the field `name` when it lies in 0..=`max`; else a 422 that says so, with what the
/// field means.
fn within(name: &str, value: f64, max: f64, meaning: &str) -> Result<f64, (StatusCode, Json<Value>)> {
    if (0.0..=max).contains(&value) {
        return Ok(value);
    }
    Err(api_error(
        StatusCode::UNPROCESSABLE_ENTITY,
        format!("{name} {value} is outside 0..{max} ({meaning})"),
    ))
}

async fn patch_drive(
    State(sim): State<Arc<Simulator>>,
    UrlPath(n): UrlPath<usize>,
    body: Result<Json<DrivePatch>, axum::extract::rejection::JsonRejection>,
) -> ApiResult {
    let Json(p) = body.map_err(|e| api_error(StatusCode::BAD_REQUEST, e.body_text()))?;
    let mut line = sim.line();
    let count = line.devices();
    if let Some(s) = p.silent {
        if n == 0 || n > count {
            return Err(no_drive(n, count));
        }
        line.set_silent(n, s);
    }
    let d = line.drive_mut(n).ok_or_else(|| no_drive(n, count))?;
    if let Some(params) = &p.params {
        for (name, v) in params {
            let text = match v {
                Value::String(s) => s.clone(),
                other => other.to_string(),
            };
            d.set_param(name, &text)
                .map_err(|e| api_error(StatusCode::UNPROCESSABLE_ENTITY, format!("{name}: {e}")))?;
        }
    }
    if p.power_cycle == Some(true) {
        let now = sim.now();
        d.power_cycle(now);
    }
    if let Some(load) = p.load {
        let load = within("load", load, 5.0, "fraction of rated torque")?;
        d.core_mut().model.set_load(load);
    }
    if let Some(supply) = p.supply {
        let supply = within("supply", supply, 2.0, "fraction of nominal")?;
        d.core_mut().model.set_supply(supply);
    }
    if let Some(on) = p.hardware_enable {
        d.core_mut().model.set_hardware_enable(on);
    }
    if let Some(t) = &p.trip {
        let trip = parse_trip(t).ok_or_else(|| {
            api_error(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!("unknown trip {t:?}: use over-current, over-voltage, under-voltage, over-temperature, communication-timeout or external"),
            )
        })?;
        d.core_mut().model.trip_now(trip);
    }
    if let Some(hz) = p.keypad_hz {
        d.set_keypad_hz(hz)
            .map_err(|e| api_error(StatusCode::UNPROCESSABLE_ENTITY, format!("keypad_hz: {e}")))?;
    }
    if p.reset == Some(true) {
        if let Err(t) = d.core_mut().model.reset() {
            return Err(api_error(
                StatusCode::CONFLICT,
                format!("the {} persists: the drive stays tripped", t.name()),
            ));
        }
    }
    if let Some(run) = p.run {
        d.press_run(run).map_err(|e| api_error(StatusCode::CONFLICT, e))?;
    }
    drop(line);
    sim.changed.send_modify(|g| *g = g.wrapping_add(1));
    let mut line = sim.line();
    snapshot(&mut line, n).map(Json).ok_or_else(|| no_drive(n, count))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FaultsBody {
    corrupt_rate: Option<f64>,
    drop_rate: Option<f64>,
    extra_latency_ms: Option<u64>,
}

fn faults_json(f: Faults) -> Value {
    json!({ "corrupt_rate": f.corrupt_rate, "drop_rate": f.drop_rate, "extra_latency_ms": f.extra_latency.as_millis() as u64 })
}

async fn get_faults(State(sim): State<Arc<Simulator>>) -> Json<Value> {
    Json(faults_json(sim.line().faults()))
}

async fn put_faults(
    State(sim): State<Arc<Simulator>>,
    body: Result<Json<FaultsBody>, axum::extract::rejection::JsonRejection>,
) -> ApiResult {
    let Json(b) = body.map_err(|e| api_error(StatusCode::BAD_REQUEST, e.body_text()))?;
    let mut line = sim.line();
    let mut f = line.faults();
    for (name, v, slot) in
        [("corrupt_rate", b.corrupt_rate, &mut f.corrupt_rate), ("drop_rate", b.drop_rate, &mut f.drop_rate)]
    {
        if let Some(v) = v {
            if !(0.0..=1.0).contains(&v) {
                return Err(api_error(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    format!("{name} {v} is not a probability 0..1"),
                ));
            }
            *slot = v;
        }
    }
    if let Some(ms) = b.extra_latency_ms {
        if ms > 60_000 {
            return Err(api_error(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!("extra_latency_ms {ms} is over 60000"),
            ));
        }
        f.extra_latency = Duration::from_millis(ms);
    }
    line.set_faults(f);
    Ok(Json(faults_json(f)))
}

async fn get_stats(State(sim): State<Arc<Simulator>>) -> Json<Value> {
    let line = sim.line();
    let s = line.stats();
    let elapsed = sim.now().as_nanos() as f64 / 1e9;
    Json(json!({
        "baud": line.baud(),
        "serial": line.format().to_string(),
        "master_bytes": s.master_bytes,
        "device_bytes": s.device_bytes,
        "masters": line.masters(),
        "collisions": s.collisions,
        "garbled_frames": s.garbled_frames,
        "garbled_frames_by_master": (0..line.masters()).map(|m| line.master_garbled_frames(m)).collect::<Vec<_>>(),
        "corrupted": s.corrupted,
        "dropped": s.dropped,
        "utilization": if elapsed > 0.0 { s.busy.as_secs_f64() / elapsed } else { 0.0 },
    }))
}

/// Makes room for the pty's link at `link`: nothing there, or a stale link of a simulator (to a
/// pseudo-terminal that is gone), which is removed. Anything else is refused, never deleted: a
/// regular file, a folder, a link to something else, or to a pseudo-terminal still open.
fn replace_stale_link(link: &Path) -> io::Result<()> {
    let Ok(meta) = link.symlink_metadata() else { return Ok(()) };
    let refuse = |what: String| {
        Err(io::Error::new(
            io::ErrorKind::AlreadyExists,
            format!(
                "{} exists ({what}): give another path, or remove it if it is not needed",
                link.display()
            ),
        ))
    };
    if !meta.file_type().is_symlink() {
        return refuse(if meta.is_dir() { "a folder".into() } else { "a file, not a link".into() });
    }
    let target = std::fs::read_link(link)?;
    if !target.starts_with("/dev/pts") {
        return refuse(format!("a link to {}", target.display()));
    }
    if target.exists() {
        return refuse(format!(
            "a link to {}, a pseudo-terminal still open: another simulator?",
            target.display()
        ));
    }
    std::fs::remove_file(link)
        .map_err(|e| io::Error::new(e.kind(), format!("cannot replace {}: {e}", link.display())))
}

/// A pseudo-terminal whose slave side a serial program opens.
struct Pty {
    master: PtyMaster,
    slave: OwnedFd,
    device: PathBuf,
}

impl Pty {
    fn open(link: &Path) -> io::Result<Pty> {
        use nix::sys::termios;
        // Before opening ours: a pty number freed by a simulator that was killed is reused by the
        // next one opened, which would make its stale link look alive.
        replace_stale_link(link)?;
        let pair = nix::pty::openpty(None, None).map_err(io::Error::from)?;
        // Raw mode: no echo, no CR/LF translation, bytes as they come.
        let mut t = termios::tcgetattr(pair.slave.as_fd()).map_err(io::Error::from)?;
        termios::cfmakeraw(&mut t);
        termios::tcsetattr(pair.slave.as_fd(), termios::SetArg::TCSANOW, &t).map_err(io::Error::from)?;
        let device = nix::unistd::ttyname(pair.slave.as_fd()).map_err(io::Error::from)?;
        std::os::unix::fs::symlink(&device, link).map_err(|e| {
            io::Error::new(e.kind(), format!("cannot create the link {}: {e}", link.display()))
        })?;
        let flags = nix::fcntl::fcntl(pair.master.as_raw_fd(), nix::fcntl::FcntlArg::F_GETFL)
            .map_err(io::Error::from)?;
        let flags = nix::fcntl::OFlag::from_bits_truncate(flags) | nix::fcntl::OFlag::O_NONBLOCK;
        nix::fcntl::fcntl(pair.master.as_raw_fd(), nix::fcntl::FcntlArg::F_SETFL(flags))
            .map_err(io::Error::from)?;
        // SAFETY: an `OwnedFd` is an open descriptor that stays open, and always returns the
        // same raw fd, for as long as the `AsyncFd` owns it: exactly `register`'s contract.
        #[allow(unsafe_code)]
        let fd = unsafe { AsyncFd::register(pair.master) }.map_err(io::Error::from)?;
        Ok(Pty { master: PtyMaster { fd }, slave: pair.slave, device })
    }
}

impl Pty {
    /// Writes `bytes` without waiting: when the buffer is full (nobody reads the slave side),
    /// what is queued there is discarded first, and what still does not fit is dropped.
    fn write_or_discard(&self, mut bytes: &[u8]) -> io::Result<()> {
        let fd = self.master.fd.get_ref();
        let mut flushed = false;
        while !bytes.is_empty() {
            match nix::unistd::write(fd, bytes) {
                Ok(n) => bytes = &bytes[n..],
                Err(nix::errno::Errno::EAGAIN) if !flushed => {
                    nix::sys::termios::tcflush(self.slave.as_fd(), nix::sys::termios::FlushArg::TCIFLUSH)
                        .map_err(io::Error::from)?;
                    flushed = true;
                }
                Err(nix::errno::Errno::EAGAIN) => return Ok(()),
                Err(nix::errno::Errno::EINTR) => {}
                Err(e) => return Err(io::Error::from(e)),
            }
        }
        Ok(())
    }
}

/// The master side of a pty as a tokio stream.
struct PtyMaster {
    fd: AsyncFd<OwnedFd>,
}

impl AsyncRead for PtyMaster {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.fd.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            match guard
                .try_io(|fd| nix::unistd::read(fd.get_ref().as_raw_fd(), unfilled).map_err(io::Error::from))
            {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for PtyMaster {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.fd.poll_write_ready(cx))?;
            match guard.try_io(|fd| nix::unistd::write(fd.get_ref(), data).map_err(io::Error::from)) {
                Ok(r) => return Poll::Ready(r),
                Err(_would_block) => continue,
            }
        }
    }
    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

#[cfg(test)]
mod link_tests {
    use super::replace_stale_link;

    #[test]
    fn only_a_stale_pty_link_is_replaced() {
        let dir = std::env::temp_dir().join(format!("drivebus-link-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // A regular file is kept and refused.
        let file = dir.join("notes.txt");
        std::fs::write(&file, "keep me").unwrap();
        let e = replace_stale_link(&file).unwrap_err().to_string();
        assert!(e.contains("a file, not a link"), "{e}");
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep me");
        // A link to something else is refused and kept.
        let other = dir.join("other");
        std::os::unix::fs::symlink(&file, &other).unwrap();
        assert!(replace_stale_link(&other).unwrap_err().to_string().contains("a link to"));
        assert!(other.symlink_metadata().is_ok());
        // A link to a pseudo-terminal that is gone is a simulator's leftover: replaced.
        let stale = dir.join("stale");
        std::os::unix::fs::symlink("/dev/pts/999999", &stale).unwrap();
        replace_stale_link(&stale).unwrap();
        assert!(stale.symlink_metadata().is_err());
        // Nothing there: nothing to do.
        replace_stale_link(&dir.join("nothing")).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }
}
