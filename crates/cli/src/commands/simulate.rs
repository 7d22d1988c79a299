//! `drivebus simulate`: virtual drives on a virtual RS-485 line, behind a pty or a TCP port.

use drivebus_gateway::text::count;
use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use drivebus_proto::line::CharFormat;
use drivebus_sim::config::{BusSpec, DriveSpec};
use drivebus_sim::runtime::{Endpoint, Simulator};

/// Arguments of `drivebus simulate`, with `crate::options`' `--drive KIND@ADDR[:PROTOCOL]` (one per
/// drive: generic@1:modbus-rtu, toshiba@2, danfoss@3, b800@5), `--baud` and `--serial`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// A TOML file describing the whole bus (see docs/simulator.md); --drive adds to it.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Create a pseudo-terminal and a symlink at PATH to it: open PATH as a serial port. Give
    /// it more than once (and with --tcp, --modbus-tcp) for several masters on one line: each
    /// hears the drives and the other masters, and two talking at once garble each other.
    #[arg(long, value_name = "PATH")]
    pub pty: Vec<PathBuf>,
    /// Serve raw bytes on HOST:PORT, as a serial device server does (more than once: several
    /// masters, as with --pty).
    #[arg(long, value_name = "HOST:PORT")]
    pub tcp: Vec<SocketAddr>,
    /// Serve Modbus TCP (MBAP) on HOST:PORT, as a drive with an Ethernet card or a Modbus
    /// TCP/RTU gateway does: the unit id is the drive's address, and each drive speaks Modbus
    /// RTU on the virtual line behind it (more than once: several masters, as with --pty).
    #[arg(long, value_name = "HOST:PORT")]
    pub modbus_tcp: Vec<SocketAddr>,
    /// Create a second pseudo-terminal (symlink at PATH) that carries a copy of every byte on
    /// the virtual line, both directions, paced as on the line: open it with `drivebus sniff`.
    #[arg(long, value_name = "PATH")]
    pub tap: Option<PathBuf>,
    /// Serve the HTTP/JSON control interface (faults, load, trips, state) on HOST:PORT.
    #[arg(long, value_name = "HOST:PORT")]
    pub control: Option<SocketAddr>,
    /// Bytes take no wire time (for benchmarks of clients over a pty or TCP); the default
    /// paces every byte at --baud.
    #[arg(long)]
    pub no_pacing: bool,
    /// Every drive's response time in microseconds (default: 5 ms, or the bus file's).
    #[arg(long, value_name = "US")]
    pub response_us: Option<u64>,
    /// Print each frame decoded, one line each.
    #[arg(short, long)]
    pub verbose: bool,
}

/// Builds the bus the arguments describe.
pub fn bus_spec(args: &SimulateArgs, target: &crate::commands::target::Target) -> Result<BusSpec> {
    let format = match target.serial() {
        Some(s) => Some(s.parse::<CharFormat>().map_err(|e| anyhow::anyhow!("--serial {s:?}: {e}"))?),
        None => None,
    };
    let mut extra = Vec::new();
    for d in &target.drive {
        extra.push(d.parse::<DriveSpec>()?);
    }
    let bus = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read the bus file {}", path.display()))?;
            let mut bus = BusSpec::from_toml(&path.display().to_string(), &text)?;
            bus.drives.extend(extra);
            if let Some(b) = target.baud() {
                bus.baud = b;
            }
            if let Some(f) = format {
                bus.format = f;
            }
            bus.check()?;
            bus
        }
        None => BusSpec::new(extra, target.baud(), format)?,
    };
    let mut bus = bus;
    if args.no_pacing {
        bus.pacing = false;
    }
    if let Some(us) = args.response_us {
        if us > 10_000_000 {
            bail!("--response-us {us} is over 10 s (10000000)");
        }
        for d in &mut bus.drives {
            d.response = std::time::Duration::from_micros(us);
        }
    }
    bus.check()?;
    bus.drives.iter().try_for_each(|d| d.check())?;
    Ok(bus)
}

/// Behind a Modbus TCP endpoint every drive speaks Modbus RTU: those that were given no
/// protocol are set to it, and a drive that cannot speak it is refused.
fn speak_modbus_rtu(bus: &mut BusSpec) -> Result<()> {
    use drivebus_proto::protocol::WireProtocol;
    for d in &mut bus.drives {
        match d.protocol {
            Some(WireProtocol::ModbusRtu) => {}
            None if d.family.protocols().contains(&WireProtocol::ModbusRtu) => {
                d.protocol = Some(WireProtocol::ModbusRtu)
            }
            Some(p) => bail!(
                "--modbus-tcp serves Modbus drives: {}@{} is set to speak {p} (drop :{p} or use --tcp)",
                d.family,
                d.address
            ),
            None => bail!(
                "--modbus-tcp serves Modbus drives: a {} drive does not speak Modbus (use --tcp or --pty)",
                d.family
            ),
        }
    }
    Ok(())
}

/// Runs `drivebus simulate` until interrupted.
pub fn run(args: &SimulateArgs, target: &crate::commands::target::Target) -> Result<u8> {
    let endpoints: Vec<Endpoint> = args
        .pty
        .iter()
        .map(|p| Endpoint::Pty(p.clone()))
        .chain(args.tcp.iter().map(|a| Endpoint::Tcp(*a)))
        .chain(args.modbus_tcp.iter().map(|a| Endpoint::ModbusTcp(*a)))
        .collect();
    if endpoints.is_empty() {
        bail!(
            "say where the master connects: --pty PATH, --tcp HOST:PORT or --modbus-tcp HOST:PORT (one per master)"
        );
    }
    for (i, p) in args.pty.iter().enumerate() {
        if args.pty[..i].contains(p) || args.tap.as_ref() == Some(p) {
            bail!("{} is given twice: each --pty and the --tap needs its own path", p.display());
        }
    }
    let tcp: Vec<&SocketAddr> = args.tcp.iter().chain(&args.modbus_tcp).collect();
    for (i, a) in tcp.iter().enumerate() {
        if a.port() != 0 && tcp[..i].contains(a) {
            bail!("{a} is given twice: each master needs its own port");
        }
    }
    let mut bus = bus_spec(args, target)?;
    if !args.modbus_tcp.is_empty() {
        speak_modbus_rtu(&mut bus)?;
    }
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    rt.block_on(async move {
        let sim = Simulator::new(&bus)?;
        println!(
            "drivebus simulate: {} at {} baud {}{}: {}",
            count(bus.drives.len(), "drive", "drives"),
            bus.baud,
            bus.format,
            if bus.pacing { "" } else { " (no pacing)" },
            bus.drives
                .iter()
                .map(|d| format!(
                    "{}@{}{}",
                    d.family,
                    d.address,
                    d.protocol.map(|p| format!(":{p}")).unwrap_or_default()
                ))
                .collect::<Vec<_>>()
                .join(" ")
        );
        if let Some(addr) = args.control {
            let s = sim.clone();
            let listener = tokio::net::TcpListener::bind(addr)
                .await
                .with_context(|| format!("cannot listen for the control interface on {addr}"))?;
            println!("control http://{}/drives", listener.local_addr()?);
            tokio::spawn(async move { axum_serve(listener, s).await });
        }
        if let Some(path) = &args.tap {
            let (at, feed) =
                sim.clone().serve_tap(path).with_context(|| format!("tap {}", path.display()))?;
            println!("{at}");
            let shown = path.display().to_string();
            tokio::spawn(async move {
                if let Err(e) = feed.await {
                    eprintln!("drivebus: tap {shown} stopped: {e}");
                }
            });
        }
        let verbose = args.verbose;
        // Listened for before the ready lines are printed: a signal right after them is not lost.
        let mut stop = StopSignals::new()?;
        let several = endpoints.len() > 1;
        let mut masters = tokio::task::JoinSet::new();
        let mut made: Vec<PathBuf> = Vec::new();
        // Every master is on the line before any is served: each knows there are several.
        let ids: Vec<usize> = (0..endpoints.len())
            .map(|i| if i == 0 { drivebus_sim::bus::MASTER } else { sim.add_master() })
            .collect();
        for (endpoint, &master) in endpoints.iter().zip(&ids) {
            // Each port is open (and its ready line printed) before the next is made: the
            // masters' numbers follow the order of the ready lines.
            let (ready_tx, ready_rx) = tokio::sync::oneshot::channel();
            let what = match endpoint {
                Endpoint::Pty(p) => format!("pty {}", p.display()),
                Endpoint::Tcp(a) => format!("tcp {a}"),
                Endpoint::ModbusTcp(a) => format!("modbus-tcp {a}"),
            };
            let serve = sim.clone().serve_master(master, endpoint.clone(), verbose, move |at| {
                let who = if several { format!(" (master {master})") } else { String::new() };
                println!("listening on {at}{who}");
                let _ = ready_tx.send(());
            });
            masters.spawn(async move { serve.await.with_context(|| what) });
            // A port that fails to open ends its task at once: its error is reported below.
            if ready_rx.await.is_ok() {
                if let Endpoint::Pty(p) = endpoint {
                    made.push(p.clone());
                }
            }
        }
        let ended = tokio::select! {
            Some(r) = masters.join_next() => r.context("a master's port task failed").and_then(|r| r),
            _ = stop.wait() => Ok(()),
        };
        // Only the links this simulator made: a path refused (someone else's file) is kept.
        for p in &made {
            let _ = std::fs::remove_file(p);
        }
        ended?;
        if let Some(p) = &args.tap {
            let _ = std::fs::remove_file(p);
        }
        Ok::<_, anyhow::Error>(())
    })?;
    Ok(0)
}

/// SIGINT (Ctrl-C) and SIGTERM (`kill`, a service manager stopping it), listened for from
/// creation on: either ends the simulator the same way, its pty link removed.
struct StopSignals {
    #[cfg(unix)]
    int: tokio::signal::unix::Signal,
    #[cfg(unix)]
    term: tokio::signal::unix::Signal,
}

impl StopSignals {
    fn new() -> Result<StopSignals> {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{signal, SignalKind};
            Ok(StopSignals { int: signal(SignalKind::interrupt())?, term: signal(SignalKind::terminate())? })
        }
        #[cfg(not(unix))]
        Ok(StopSignals {})
    }

    /// Resolves at the first of the two signals.
    async fn wait(&mut self) {
        #[cfg(unix)]
        tokio::select! {
            _ = self.int.recv() => {}
            _ = self.term.recv() => {}
        }
        #[cfg(not(unix))]
        let _ = tokio::signal::ctrl_c().await;
    }
}

async fn axum_serve(listener: tokio::net::TcpListener, sim: std::sync::Arc<Simulator>) {
    if let Err(e) = drivebus_sim::runtime::serve_router(listener, sim).await {
        eprintln!("drivebus: control interface stopped: {e}");
    }
}
