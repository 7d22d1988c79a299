//! `drivebus sniff`: listen to a line someone else drives, never transmit; every frame decoded,
//! requests paired with replies, per-address statistics, a pcapng capture (see docs/sniff.md).
//! The analysis is in `crate::sniff`; this is the I/O around it.

use drivebus_gateway::text::count;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result};
use clap::Args;
use drivebus_link::listen::Listener;
use drivebus_proto::line::CharFormat;
use drivebus_proto::Direction;

use crate::commands::target::{fail, Target, EXIT_LINK, EXIT_REFUSED, EXIT_USAGE};
use crate::sniff::analyze::{Analyzer, Kind, Record, Settings, Side, PROTOCOLS};
use crate::sniff::capture::{self, PcapWriter};
use crate::sniff::detect;

/// Arguments of `drivebus sniff` (with the global `--port` (twice for a 4-wire line: the
/// master's pair first), `--baud`, `--serial`, `--protocol`, `--timeout` and `--json`).
#[derive(Args, Debug)]
pub struct SniffArgs {
    /// Stop after this many seconds.
    #[arg(long, value_name = "SECS")]
    pub duration: Option<f64>,
    /// Stop after this many frames.
    #[arg(long, value_name = "N")]
    pub count: Option<u64>,
    /// Write every frame to FILE (pcapng; Wireshark and tshark open it, see docs/sniff.md).
    #[arg(long, value_name = "FILE.pcap")]
    pub write: Option<PathBuf>,
    /// Replay a capture (pcap, pcapng, or a hex dump with one burst per line) instead of
    /// listening to a port.
    #[arg(long, value_name = "FILE")]
    pub read: Option<PathBuf>,
}

/// The protocols `--protocol` names (empty: auto).
fn protocols(t: &Target) -> Result<Vec<&'static str>> {
    match t.protocol.as_deref() {
        None | Some("auto") => Ok(Vec::new()),
        Some(p) => match PROTOCOLS.iter().find(|x| **x == p) {
            Some(x) => Ok(vec![*x]),
            None => {
                Err(fail(EXIT_USAGE, format!("unknown protocol {p:?}: use auto, {}", PROTOCOLS.join(", "))))
            }
        },
    }
}

fn format_of(t: &Target) -> Result<Option<CharFormat>> {
    t.serial()
        .map(|s| s.parse::<CharFormat>().map_err(|e| fail(EXIT_USAGE, format!("--serial {s:?}: {e}"))))
        .transpose()
}

fn now() -> Duration {
    SystemTime::now().duration_since(UNIX_EPOCH).unwrap_or_default()
}

/// The longest wait for a read before the analysis is told the time.
const TICK: Duration = Duration::from_millis(100);

/// How often the per-address statistics are shown while listening.
const STATS_EVERY: Duration = Duration::from_secs(10);

/// Prints records and the capture, and counts toward `--count`.
struct Output {
    json: bool,
    pcap: Option<PcapWriter<BufWriter<std::fs::File>>>,
    since: Option<Duration>,
    frames: u64,
    stdout: BufWriter<std::io::Stdout>,
    /// Flush every batch (a terminal), or at most every [`FLUSH_EVERY`] (a file or a pipe).
    live: bool,
    flushed: std::time::Instant,
}

/// How long rows may wait in the output buffer when stdout is not a terminal.
const FLUSH_EVERY: Duration = Duration::from_millis(100);

impl Output {
    fn new(json: bool, write: Option<&PathBuf>) -> Result<Self> {
        let pcap = match write {
            Some(path) => {
                let f = std::fs::File::create(path)
                    .with_context(|| format!("cannot create the capture {}", path.display()))?;
                Some(PcapWriter::new(BufWriter::new(f))?)
            }
            None => None,
        };
        if !json {
            println!("{:>10}  {:<14} {:<6}  {:>3}  meaning", "time s", "protocol", "from", "addr");
        }
        use std::io::IsTerminal;
        let live = std::io::stdout().is_terminal();
        let stdout = BufWriter::with_capacity(64 * 1024, std::io::stdout());
        Ok(Output { json, pcap, since: None, frames: 0, stdout, live, flushed: std::time::Instant::now() })
    }

    fn emit(&mut self, records: Vec<Record>) -> Result<()> {
        let out = &mut self.stdout;
        for r in records {
            let since = *self.since.get_or_insert(r.time);
            if r.kind == Kind::Frame {
                self.frames += 1;
                if let Some(w) = &mut self.pcap {
                    w.frame(r.time, r.protocol, r.direction, &r.frame.bytes)?;
                }
            }
            if self.json {
                writeln!(out, "{}", r.json())?;
            } else {
                writeln!(out, "{}", r.row(since))?;
            }
        }
        if self.live || self.flushed.elapsed() >= FLUSH_EVERY {
            self.stdout.flush()?;
            self.flushed = std::time::Instant::now();
        }
        Ok(())
    }

    fn close(&mut self) -> Result<()> {
        self.stdout.flush()?;
        if let Some(w) = &mut self.pcap {
            w.flush()?;
        }
        Ok(())
    }
}

/// The per-address statistics and the bus load, as a table.
fn summary(a: &Analyzer, baud: u32, format: CharFormat, heard: bool) -> String {
    let mut s = String::new();
    let ms = |d: Option<Duration>| d.map_or("-".to_string(), |d| format!("{:.1}", d.as_secs_f64() * 1e3));
    s.push_str(&format!(
        "{:<14} {:>4} {:>8} {:>8} {:>8} {:>6} {:>8} {:>8}\n",
        "protocol", "addr", "requests", "replies", "timeouts", "errors", "p50 ms", "p99 ms"
    ));
    for ((p, addr), st) in a.stats() {
        s.push_str(&format!(
            "{:<14} {:>4} {:>8} {:>8} {:>8} {:>6} {:>8} {:>8}\n",
            p,
            addr,
            st.requests,
            st.replies,
            st.timeouts,
            st.errors,
            ms(st.latency_quantile(0.5)),
            ms(st.latency_quantile(0.99))
        ));
    }
    s.push_str(&format!(
        "{}, {} garbled, bus load {:.1} % at {baud} {format}{}\n",
        count(a.frames() as usize, "frame", "frames"),
        a.garbled(),
        a.bus_load() * 100.0,
        if heard && a.protocols().is_empty() { " (no protocol found)" } else { "" }
    ));
    s
}

/// Runs `drivebus sniff`: exit 0 when a valid frame was heard, 1 when bytes came but no valid
/// frame, 2 when nothing came or the port failed.
pub fn run(args: &SniffArgs, t: &Target) -> Result<u8> {
    let protocols = protocols(t)?;
    let format = format_of(t)?;
    if args.duration.is_some_and(|d| !(d > 0.0 && d.is_finite())) {
        return Err(fail(EXIT_USAGE, "--duration must be a number of seconds above 0"));
    }
    if args.count == Some(0) {
        return Err(fail(EXIT_USAGE, "--count must be at least 1"));
    }
    let reply_timeout = Duration::from_millis(t.timeout.unwrap_or(1000));
    match &args.read {
        Some(_) if !t.port.is_empty() => {
            Err(fail(EXIT_USAGE, "--read replays a capture: give it or --port, not both"))
        }
        Some(path) => replay(args, t, path, protocols, format, reply_timeout),
        None => listen(args, t, protocols, format, reply_timeout),
    }
}

fn replay(
    args: &SniffArgs,
    t: &Target,
    path: &PathBuf,
    mut protocols: Vec<&'static str>,
    format: Option<CharFormat>,
    reply_timeout: Duration,
) -> Result<u8> {
    let data = std::fs::read(path).with_context(|| format!("cannot read the capture {}", path.display()))?;
    let packets = capture::read(&data).map_err(|e| fail(EXIT_USAGE, format!("{}: {e}", path.display())))?;
    if protocols.is_empty() {
        for p in packets.iter().filter_map(|p| p.protocol) {
            if !protocols.contains(&p) {
                protocols.push(p);
            }
        }
    }
    let directed = packets.iter().all(|p| p.direction.is_some());
    let sides = if directed {
        vec![Side::Only(Direction::Master), Side::Only(Direction::Drive)]
    } else {
        vec![Side::Both]
    };
    let (baud, format) = (t.baud().unwrap_or(9600), format.unwrap_or(CharFormat::NONE_8N1));
    let mut a = Analyzer::new(Settings { protocols, baud, format, reply_timeout, sides });
    let mut out = Output::new(t.json, args.write.as_ref())?;
    let mut last = Duration::ZERO;
    for p in &packets {
        let port = match p.direction {
            Some(Direction::Drive) if directed => 1,
            _ => 0,
        };
        let mut r = a.tick(p.time);
        r.extend(a.push(port, p.time, &p.bytes));
        out.emit(r)?;
        last = p.time;
        if args.count.is_some_and(|c| out.frames >= c) {
            break;
        }
    }
    out.emit(a.finish(last + reply_timeout))?;
    out.close()?;
    eprint!("{}", summary(&a, baud, format, !packets.is_empty()));
    Ok(exit_code(&a, !packets.is_empty()))
}

fn exit_code(a: &Analyzer, heard: bool) -> u8 {
    if a.stats().values().any(|s| s.requests + s.replies > 0) || (a.frames() > a.garbled()) {
        0
    } else if heard {
        EXIT_REFUSED
    } else {
        EXIT_LINK
    }
}

/// A serial port as the setting search sees it, on the wall clock since `start`.
struct LivePort<'a> {
    port: &'a mut Listener,
    start: std::time::Instant,
}

impl detect::SettingPort for LivePort<'_> {
    fn set(&mut self, baud: u32, format: CharFormat) -> std::io::Result<()> {
        self.port.set(baud, format)
    }
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.port.read(buf)
    }
    fn now(&self) -> Duration {
        self.start.elapsed()
    }
}

fn listen(
    args: &SniffArgs,
    t: &Target,
    protocols: Vec<&'static str>,
    format: Option<CharFormat>,
    reply_timeout: Duration,
) -> Result<u8> {
    let paths = match t.port.as_slice() {
        [] => {
            return Err(fail(
                EXIT_USAGE,
                "say where to listen: --port /dev/ttyUSB0 (twice for a 4-wire line), or --read FILE",
            ))
        }
        [_] | [_, _] => t.port.clone(),
        _ => {
            return Err(fail(
                EXIT_USAGE,
                "give one --port, or two for a 4-wire line (the master's pair first)",
            ))
        }
    };
    if paths.iter().any(|p| p.starts_with("tcp://")) {
        return Err(fail(
            EXIT_USAGE,
            "sniff listens on a serial port, not tcp://: clamp an RS-485 adapter on the line",
        ));
    }
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        std::thread::spawn(move || {
            if let Ok(rt) = tokio::runtime::Builder::new_current_thread().enable_all().build() {
                rt.block_on(async {
                    let _ = tokio::signal::ctrl_c().await;
                });
                stop.store(true, Ordering::Relaxed);
            }
        });
    }
    let start = std::time::Instant::now();
    let deadline = args.duration.map(|d| start + Duration::from_secs_f64(d));
    let baud0 = t.baud().unwrap_or(9600);
    let format0 = format.unwrap_or(CharFormat::NONE_8N1);
    let mut ports = Vec::new();
    for p in &paths {
        let l = Listener::open(p, baud0, format0, Duration::from_millis(100))
            .map_err(|e| fail(EXIT_LINK, e.to_string()))?;
        ports.push(l);
    }
    let given = format;
    let (mut baud, mut format) = (baud0, format0);
    let auto_setting = t.baud().is_none() || given.is_none();
    if auto_setting {
        if ports[0].is_pty() {
            eprintln!(
                "drivebus: {} is a pseudo-terminal: its baud rate and format are not real, so they are not detected (taken as {baud} {format}; say --baud and --serial for the load and t3.5)",
                ports[0].path()
            );
        } else {
            let candidates = detect::candidates_for(t.baud(), given);
            eprintln!(
                "drivebus: finding the {} from the traffic on {} ({})",
                match (t.baud(), given) {
                    (Some(_), _) => "format",
                    (_, Some(_)) => "baud rate",
                    _ => "baud rate and format",
                },
                ports[0].path(),
                count(candidates.len(), "setting", "settings"),
            );
            let mut live = LivePort { port: &mut ports[0], start: std::time::Instant::now() };
            match detect::find_setting(&mut live, candidates, || stop.load(Ordering::Relaxed))? {
                Some(((b, f), _)) => {
                    (baud, format) = (t.baud().unwrap_or(b), given.unwrap_or(f));
                    eprintln!("drivebus: the line runs at {baud} {format}");
                    for p in &mut ports {
                        p.set(baud, format).map_err(|e| fail(EXIT_LINK, e.to_string()))?;
                    }
                }
                None => eprintln!(
                    "drivebus: no setting gave a valid frame: listening at {baud} {format} (is the line busy? are A and B swapped?)"
                ),
            }
        }
    }
    for p in &ports {
        if !p.is_pty() && !p.low_latency() {
            eprintln!("drivebus: {}: the driver has no low-latency mode: reads may come late by its timer (FTDI: 16 ms)", p.path());
        }
    }
    eprintln!(
        "drivebus: listening on {} at {baud} {format}, {}",
        paths.join(" (master) and ") + if paths.len() == 2 { " (drives)" } else { "" },
        if protocols.is_empty() { "protocol auto".to_string() } else { protocols.join(", ") }
    );
    let sides = if ports.len() == 2 {
        vec![Side::Only(Direction::Master), Side::Only(Direction::Drive)]
    } else {
        vec![Side::Both]
    };
    let mut a = Analyzer::new(Settings { protocols, baud, format, reply_timeout, sides });
    let (tx, rx) = mpsc::channel::<(usize, Duration, Vec<u8>)>();
    let (etx, erx) = mpsc::channel::<String>();
    for (i, mut port) in ports.into_iter().enumerate() {
        let (tx, etx, stop) = (tx.clone(), etx.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while !stop.load(Ordering::Relaxed) {
                match port.read(&mut buf) {
                    Ok(0) => {}
                    Ok(n) => {
                        if tx.send((i, now(), buf[..n].to_vec())).is_err() {
                            return;
                        }
                    }
                    Err(e) => {
                        let _ = etx.send(e.to_string());
                        return;
                    }
                }
            }
        });
    }
    drop(tx);
    let mut out = Output::new(t.json, args.write.as_ref())?;
    let mut heard = false;
    let mut announced = 0;
    let mut shown = std::time::Instant::now();
    let mut failure = None;
    loop {
        if stop.load(Ordering::Relaxed) || deadline.is_some_and(|d| std::time::Instant::now() >= d) {
            break;
        }
        if let Ok(e) = erx.try_recv() {
            failure = Some(e);
            break;
        }
        // Ticks end a frame after a long quiet, time out requests and settle the detection:
        // none of that needs finer than TICK.
        let wait =
            deadline.map_or(TICK, |d| TICK.min(d.saturating_duration_since(std::time::Instant::now())));
        let records = match rx.recv_timeout(wait) {
            Ok((port, time, bytes)) => {
                heard = true;
                a.push(port, time, &bytes)
            }
            Err(mpsc::RecvTimeoutError::Timeout) => a.tick(now()),
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        };
        if a.protocols().len() > announced {
            announced = a.protocols().len();
            eprintln!("drivebus: heard {}", a.protocols().join(", "));
        }
        out.emit(records)?;
        if args.count.is_some_and(|c| out.frames >= c) {
            break;
        }
        // The live statistics, every 10 s (stderr: stdout stays one row or object per frame).
        if shown.elapsed() >= STATS_EVERY && heard {
            shown = std::time::Instant::now();
            eprint!("{}", summary(&a, baud, format, heard));
        }
    }
    stop.store(true, Ordering::Relaxed);
    out.emit(a.finish(now()))?;
    out.close()?;
    eprint!("{}", summary(&a, baud, format, heard));
    if let Some(e) = failure {
        return Err(fail(EXIT_LINK, e));
    }
    if !heard {
        eprintln!(
            "drivebus: heard nothing on {} in {:.1} s: check the wiring (A/B) and that the line is busy",
            paths.join(" and "),
            start.elapsed().as_secs_f64()
        );
    }
    Ok(exit_code(&a, heard))
}
