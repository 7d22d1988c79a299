//! A bus master without a runtime: the calling thread writes the request and blocks in the
//! kernel until the reply's bytes arrive or the session's deadline passes.
//!
//! The same [`Engine`](crate::engine) as the async bus owner keeps the protocol's timing,
//! retries, echo stripping, statistics and drive health; only the waiting differs. For a
//! program that talks to one bus from one thread (a commissioning script, a test rig, a
//! product's service loop) it is the shortest path from request to reply: one `write` and, on
//! a serial port, one `read` per reply burst: no reactor, no wake-up of another thread.
//!
//! ```no_run
//! use drivebus_drive::profile::Exchange;
//! use drivebus_link::blocking::BlockingBus;
//! use drivebus_link::{BusConfig, Priority};
//! use drivebus_proto::protocol::WireProtocol;
//! let mut bus = BlockingBus::open("/dev/ttyUSB0", BusConfig::new(WireProtocol::ModbusRtu, 9600, "8E1".parse().unwrap()))?;
//! // Read 2 registers at 2100H from drive 1.
//! let request = vec![0x01, 0x03, 0x21, 0x00, 0x00, 0x02, 0xCE, 0x37];
//! let reply = bus.transact(1, &Exchange { request, expect_reply: true }, Priority::Command, None)?;
//! # Ok::<(), drivebus_link::BusError>(())
//! ```
//!
//! Waiting: with a deadline 100 ms away or more, a serial port is read with the termios
//! `VMIN = 0, VTIME = n` rule (the read returns at the first bytes, or after n tenths of a
//! second with none), so a reply costs one `read`; closer deadlines (the silence before a
//! request, the last stretch of a response timeout) are kept to the microsecond with `ppoll`.

use std::collections::HashMap;
use std::fs::File;
use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::os::fd::{AsFd, AsRawFd, FromRawFd, IntoRawFd, OwnedFd};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_drive::profile::Exchange;
use drivebus_proto::session::Protocol;
use drivebus_proto::Instant;

use crate::bus::{BusConfig, BusError, BusStats, Health, Priority};
use crate::engine::{with_engine, Action, Attempt, Engine, Next};
use crate::mbap::MbapFraming;
use crate::port::{set_rts, Direction, Opened, OpenedSerial, Port};

/// A bus run from the calling thread: one transaction per call, no runtime.
pub struct BlockingBus {
    io: Io,
    master: Box<dyn Master>,
    stats: Arc<Mutex<BusStats>>,
    health: Arc<Mutex<HashMap<u8, Health>>>,
}

/// What an engine waits with: the port, the clock and the read buffer.
struct Io {
    port: Port,
    /// `None` while closed (a reopen that failed).
    open: Option<Blocking>,
    clock: SyncClock,
    buf: Vec<u8>,
}

impl BlockingBus {
    /// Opens `port` (a serial device, or `tcp://HOST:PORT` for a serial device server) and
    /// runs `config`'s protocol on it.
    pub fn open(port: &str, config: BusConfig) -> Result<Self, BusError> {
        let port = if config.modbus_tcp {
            Port::modbus_tcp(port).map_err(BusError::Link)?
        } else {
            Port::parse(port, config.baud, config.format, config.rs485)
        };
        Self::open_port(port, config)
    }

    /// Opens `port` (a serial device, a serial device server or a virtual line) and runs
    /// `config`'s protocol on it.
    pub fn open_port(port: Port, config: BusConfig) -> Result<Self, BusError> {
        let mut io = Io { port, open: None, clock: SyncClock::new(), buf: vec![0; 1024] };
        io.reopen().map_err(|e| BusError::Link(e.to_string()))?;
        let stats = Arc::new(Mutex::new(BusStats::default()));
        let health = Arc::new(Mutex::new(HashMap::new()));
        let master: Box<dyn Master> =
            with_engine!(config, stats.clone(), health.clone(), |engine| Box::new(engine) as Box<dyn Master>);
        Ok(BlockingBus { io, master, stats, health })
    }

    /// Where the bus goes (`/dev/ttyUSB0`, `tcp://10.0.0.5:4001`).
    pub fn name(&self) -> String {
        self.io.port.name()
    }

    /// The RS-485 direction control in force (serial ports; `None` over TCP).
    pub fn direction(&self) -> Direction {
        match &self.io.open {
            Some(Blocking::Serial(s)) => s.direction,
            _ => Direction::None,
        }
    }

    /// Sends `exchange` to drive `address` and waits for the reply frame (`None` when no reply
    /// is due), with the bus's retries. `timeout` overrides the response timeout; a `Poll`
    /// to an offline drive is refused at once until its next probe is due.
    pub fn transact(
        &mut self,
        address: u8,
        exchange: &Exchange,
        priority: Priority,
        timeout: Option<Duration>,
    ) -> Result<Option<Vec<u8>>, BusError> {
        self.master.job(&mut self.io, Job { address, exchange, priority, timeout })
    }

    /// The bus's counts so far.
    pub fn stats(&self) -> BusStats {
        self.stats.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Each drive's link health.
    pub fn health(&self) -> HashMap<u8, Health> {
        self.health.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

/// Session time from a std instant.
struct SyncClock {
    epoch: std::time::Instant,
}

impl SyncClock {
    fn new() -> Self {
        SyncClock { epoch: std::time::Instant::now() }
    }
    fn now(&self) -> Instant {
        Instant::from_nanos(self.epoch.elapsed().as_nanos().min(u64::MAX as u128) as u64)
    }
    fn at(&self, t: Instant) -> std::time::Instant {
        self.epoch + Duration::from_nanos(t.as_nanos())
    }
}

/// One job for the bus: the arguments of [`BlockingBus::transact`].
struct Job<'a> {
    address: u8,
    exchange: &'a Exchange,
    priority: Priority,
    timeout: Option<Duration>,
}

/// An engine of some protocol, run with blocking I/O.
trait Master: Send {
    fn job(&mut self, io: &mut Io, job: Job<'_>) -> Result<Option<Vec<u8>>, BusError>;
}

impl<P: Protocol> Master for Engine<P>
where
    Engine<P>: Send,
{
    /// Carries out what the engine decides for the job.
    fn job(&mut self, io: &mut Io, job: Job<'_>) -> Result<Option<Vec<u8>>, BusError> {
        // One reading of the clock per step that can take time (the start, each wait), shared
        // by the engine calls between them.
        let mut now = io.clock.now();
        let Job { address, exchange: ex, priority, timeout } = job;
        let mut next =
            self.begin(now, io.port.name(), address, &ex.request, ex.expect_reply, priority, timeout);
        loop {
            next = match next {
                Next::Attempt => {
                    let attempt = run_attempt(self, io, &mut now);
                    self.attempted(now, attempt)
                }
                Next::Reopen => {
                    let reopened = io.reopen();
                    now = io.clock.now();
                    self.reopened(now, reopened)
                }
                Next::Done(result) => return result,
            }
        }
    }
}

/// Runs one attempt from session time `now`, which it keeps up to date across its waits.
fn run_attempt<P: Protocol>(engine: &mut Engine<P>, io: &mut Io, now: &mut Instant) -> Attempt {
    loop {
        match engine.poll(*now) {
            Action::Transmit => {
                if let Err(e) = io.write(engine.outgoing()) {
                    return Attempt::Link(format!("{}: {e}", io.port.name()));
                }
                engine.sent(*now);
            }
            Action::Done(attempt) => return attempt,
            Action::Wait(deadline) => {
                let read = io.read(deadline);
                *now = io.clock.now();
                match read {
                    Ok(0) => engine.timeout(*now),
                    Ok(n) => engine.input(*now, &io.buf[..n]),
                    Err(e) => return Attempt::Link(format!("{}: {e}", io.port.name())),
                }
            }
        }
    }
}

/// An open port, read and written with blocking system calls.
enum Blocking {
    Serial(SerialPort),
    Tcp(TcpPort),
    /// A Modbus TCP server: the engine's RTU frames in MBAP.
    Mbap(TcpPort, MbapFraming),
    #[cfg(feature = "virtual")]
    Virtual(VirtualIo),
}

impl Io {
    /// Closes the port and opens it again with its settings.
    fn reopen(&mut self) -> io::Result<()> {
        // Close first: opened for exclusive use, a serial device refuses a second open.
        self.open = None;
        self.open = Some(match self.port.open()? {
            Opened::Serial(o) => Blocking::Serial(SerialPort::new(o)),
            Opened::Tcp { addr, stream } => match self.port {
                Port::ModbusTcp(_) => Blocking::Mbap(TcpPort { addr, stream }, MbapFraming::new()),
                _ => Blocking::Tcp(TcpPort { addr, stream }),
            },
            #[cfg(feature = "virtual")]
            Opened::Virtual(v) => Blocking::Virtual(VirtualIo { line: v.line, held: Vec::new() }),
        });
        Ok(())
    }

    fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        match &mut self.open {
            Some(Blocking::Serial(s)) => s.write(bytes),
            Some(Blocking::Tcp(t)) => t.write(bytes),
            Some(Blocking::Mbap(t, framing)) => {
                let frame = framing.outgoing(bytes)?;
                t.write(&frame)
            }
            #[cfg(feature = "virtual")]
            Some(Blocking::Virtual(v)) => {
                v.write(self.clock.now(), bytes);
                Ok(())
            }
            None => Err(not_open(&self.port.name())),
        }
    }

    /// Reads what arrives before session time `deadline` into the buffer: `Ok(0)` when the
    /// deadline passed with nothing.
    fn read(&mut self, deadline: Instant) -> io::Result<usize> {
        match &mut self.open {
            Some(Blocking::Serial(s)) => s.read(&mut self.buf, self.clock.at(deadline)),
            Some(Blocking::Tcp(t)) => t.read(&mut self.buf, self.clock.at(deadline)),
            Some(Blocking::Mbap(t, framing)) => loop {
                let n = framing.take(&mut self.buf);
                if n > 0 {
                    return Ok(n);
                }
                let got = t.read(&mut self.buf, self.clock.at(deadline))?;
                if got == 0 {
                    return Ok(0);
                }
                framing.incoming(&self.buf[..got])?;
            },
            #[cfg(feature = "virtual")]
            Some(Blocking::Virtual(v)) => Ok(v.read(&mut self.buf, &self.clock, deadline)),
            None => Err(not_open(&self.port.name())),
        }
    }
}

/// A virtual line of simulated drives in this process, on the bus's session time: the line
/// is moved on to the clock's now before each look, and the thread sleeps until its next
/// event or the deadline.
#[cfg(feature = "virtual")]
struct VirtualIo {
    line: Arc<Mutex<drivebus_sim::bus::VirtualLine>>,
    /// What the line gave that did not fit the read buffer.
    held: Vec<u8>,
}

#[cfg(feature = "virtual")]
impl VirtualIo {
    fn write(&mut self, now: Instant, bytes: &[u8]) {
        self.line.lock().unwrap_or_else(|p| p.into_inner()).master_write(now, bytes);
    }

    /// Reads what the line brings before `deadline` (session time); 0 when nothing came.
    fn read(&mut self, buf: &mut [u8], clock: &SyncClock, deadline: Instant) -> usize {
        loop {
            let now = clock.now();
            let next = {
                let mut line = self.line.lock().unwrap_or_else(|p| p.into_inner());
                line.advance_to(now);
                line.master_read(&mut self.held);
                line.next_deadline()
            };
            if !self.held.is_empty() {
                let n = self.held.len().min(buf.len());
                buf[..n].copy_from_slice(&self.held[..n]);
                self.held.drain(..n);
                return n;
            }
            if now >= deadline {
                return 0;
            }
            let until = next.filter(|&t| t < deadline).unwrap_or(deadline);
            std::thread::sleep(clock.at(until).saturating_duration_since(std::time::Instant::now()));
        }
    }
}

/// The error for a port whose reopening failed.
fn not_open(name: &str) -> io::Error {
    io::Error::new(io::ErrorKind::NotConnected, format!("{name} is not open (reopening it failed)"))
}

/// Waits until `fd` is readable or `deadline` passes; true when readable (or hung up: the
/// read that follows tells).
fn wait_readable(fd: impl AsFd, deadline: std::time::Instant) -> io::Result<bool> {
    use nix::poll::{ppoll, PollFd, PollFlags};
    loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            return Ok(false);
        }
        let mut fds = [PollFd::new(fd.as_fd(), PollFlags::POLLIN)];
        match ppoll(&mut fds, Some(left.into()), None) {
            Ok(0) => continue,
            Ok(_) => return Ok(true),
            Err(nix::errno::Errno::EINTR) => continue,
            Err(e) => return Err(e.into()),
        }
    }
}

/// A serial port read and written with plain blocking system calls.
struct SerialPort {
    path: String,
    file: File,
    direction: Direction,
    /// The port has no modem lines (a pty): RTS toggles are skipped.
    no_rts: bool,
    /// The `VTIME` (tenths of a second) in force for reads.
    vtime: Option<u8>,
}

impl SerialPort {
    fn new(opened: OpenedSerial) -> Self {
        let OpenedSerial { settings, tty, direction, no_rts } = opened;
        // SAFETY: `into_raw_fd` hands over an open descriptor that nothing else owns or closes
        // (the port forgets it), so the `OwnedFd` is its only owner.
        #[allow(unsafe_code)]
        let fd = unsafe { OwnedFd::from_raw_fd(tty.into_raw_fd()) };
        SerialPort { path: settings.path, file: File::from(fd), direction, no_rts, vtime: None }
    }

    fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        if self.direction != Direction::Rts || self.no_rts {
            return self.file.write_all(bytes);
        }
        let fd = self.file.as_raw_fd();
        set_rts(fd, true)?;
        let r = self.file.write_all(bytes).and_then(|()| {
            // Until the last bit has left the UART, then back to receive.
            nix::sys::termios::tcdrain(&self.file).map_err(io::Error::from)
        });
        let off = set_rts(fd, false);
        r.and(off)
    }

    fn set_vtime(&mut self, tenths: u8) -> io::Result<()> {
        use nix::sys::termios::{tcgetattr, tcsetattr, SetArg, SpecialCharacterIndices};
        if self.vtime == Some(tenths) {
            return Ok(());
        }
        let mut t = tcgetattr(&self.file)?;
        t.control_chars[SpecialCharacterIndices::VMIN as usize] = 0;
        t.control_chars[SpecialCharacterIndices::VTIME as usize] = tenths;
        tcsetattr(&self.file, SetArg::TCSANOW, &t)?;
        self.vtime = Some(tenths);
        Ok(())
    }

    fn read(&mut self, buf: &mut [u8], deadline: std::time::Instant) -> io::Result<usize> {
        loop {
            let started = std::time::Instant::now();
            let left = deadline.saturating_duration_since(started);
            if left.is_zero() {
                return Ok(0);
            }
            // With VTIME: the shortest time an empty read can take unless the line hung up.
            let mut vtime_floor = None;
            if left >= Duration::from_millis(100) {
                // One read that returns at the first bytes, or empty after `tenths`.
                let tenths = (left.as_millis() / 100).min(255) as u8;
                self.set_vtime(tenths)?;
                vtime_floor = Some(Duration::from_millis(50 * u64::from(tenths)));
            } else if !wait_readable(&self.file, deadline)? {
                return Ok(0);
            }
            match self.file.read(buf) {
                // VTIME passed with nothing: look at the deadline again.
                Ok(0) if vtime_floor.is_some_and(|f| started.elapsed() >= f) => continue,
                // Readable (or VTIME cut short), yet nothing to read: the line hung up (a pty's
                // other side closed).
                Ok(0) => {
                    return Err(io::Error::new(
                        io::ErrorKind::UnexpectedEof,
                        format!("{} hung up", self.path),
                    ))
                }
                Ok(n) => return Ok(n),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
        }
    }
}

/// Raw bytes over TCP to a serial device server.
struct TcpPort {
    addr: String,
    stream: TcpStream,
}

impl TcpPort {
    fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.stream.write_all(bytes)
    }

    fn read(&mut self, buf: &mut [u8], deadline: std::time::Instant) -> io::Result<usize> {
        loop {
            if !wait_readable(&self.stream, deadline)? {
                return Ok(0);
            }
            return match self.stream.read(buf) {
                Ok(0) => Err(io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    format!("tcp://{} closed the connection", self.addr),
                )),
                Ok(n) => Ok(n),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => Err(e),
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pty whose slave is reached through a symlink in a temp dir; the master stays open.
    fn pty(tag: &str) -> (OwnedFd, std::path::PathBuf, std::path::PathBuf) {
        let pair = nix::pty::openpty(None, None).expect("a pty");
        let device = nix::unistd::ttyname(pair.slave.as_fd()).expect("its name");
        let link = std::env::temp_dir().join(format!("drivebus-reopen-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_file(&link);
        std::os::unix::fs::symlink(&device, &link).expect("a symlink");
        (pair.master, device, link)
    }

    #[test]
    fn a_serial_port_reopens_on_the_same_device_and_stays_closed_while_it_cannot() {
        let (_master, device, link) = pty("blocking");
        let path = link.to_str().unwrap().to_string();
        let settings = crate::port::SerialSettings {
            path: path.clone(),
            baud: 9600,
            format: "8N1".parse().unwrap(),
            rs485: crate::port::Rs485::Off,
        };
        let port = Port::Serial(settings.clone());
        let mut io = Io { port, open: None, clock: SyncClock::new(), buf: vec![0; 64] };
        io.reopen().expect("open");
        // Opened for exclusive use: without closing first, the second open of the device fails.
        io.reopen().expect("reopen the same device");
        assert!(matches!(io.open, Some(Blocking::Serial(_))));
        // Another program holding the port is named as such.
        let e = settings.open().err().expect("in use");
        assert!(e.to_string().contains("another program has it open"), "{e}");

        std::fs::remove_file(&link).unwrap();
        assert!(io.reopen().is_err(), "the device is gone");
        assert!(io.open.is_none());
        let e = io.write(&[1, 2, 3]).unwrap_err();
        assert_eq!(e.to_string(), format!("{path} is not open (reopening it failed)"));
        assert_eq!(io.port.name(), path);

        std::os::unix::fs::symlink(&device, &link).unwrap();
        io.reopen().expect("the device is back");
        assert!(matches!(io.open, Some(Blocking::Serial(_))));
        io.write(&[1, 2, 3]).expect("a write to the reopened port");
        let _ = std::fs::remove_file(&link);
    }
}
