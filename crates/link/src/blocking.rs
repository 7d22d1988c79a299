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
use drivebus_proto::line::CharFormat;
use drivebus_proto::session::Protocol;
use drivebus_proto::Instant;

use crate::engine::{with_engine, Action, Attempt, Engine};
use crate::link::{choose_direction, open_error, serial_builder, Direction, Rs485};
use crate::owner::{BusConfig, BusError, BusStats, Health, Priority};

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
    clock: SyncClock,
    buf: Vec<u8>,
}

impl BlockingBus {
    /// Opens `port` (a serial device, or `tcp://HOST:PORT` for a serial device server) and
    /// runs `config`'s protocol on it.
    pub fn open(port: &str, config: BusConfig) -> Result<Self, BusError> {
        let port = match port.strip_prefix("tcp://") {
            Some(addr) => Port::Tcp(TcpPort::connect(addr).map_err(|e| BusError::Link(e.to_string()))?),
            None => Port::Serial(
                SerialPort::open(port, config.baud, config.format, config.rs485)
                    .map_err(|e| BusError::Link(e.to_string()))?,
            ),
        };
        let stats = Arc::new(Mutex::new(BusStats::default()));
        let health = Arc::new(Mutex::new(HashMap::new()));
        let master: Box<dyn Master> =
            with_engine!(config, stats.clone(), health.clone(), |engine| Box::new(engine) as Box<dyn Master>);
        Ok(BlockingBus {
            io: Io { port, clock: SyncClock::new(), buf: vec![0; 1024] },
            master,
            stats,
            health,
        })
    }

    /// Where the bus goes (`/dev/ttyUSB0`, `tcp://10.0.0.5:4001`).
    pub fn name(&self) -> String {
        self.io.port.name()
    }

    /// The RS-485 direction control in force (serial ports; `None` over TCP).
    pub fn direction(&self) -> Direction {
        match &self.io.port {
            Port::Serial(s) => s.direction,
            Port::Closed { .. } | Port::Tcp(_) => Direction::None,
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
        self.master.job(&mut self.io, address, exchange, priority, timeout)
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

/// An engine of some protocol, run with blocking I/O.
trait Master: Send {
    fn job(
        &mut self,
        io: &mut Io,
        address: u8,
        exchange: &Exchange,
        priority: Priority,
        timeout: Option<Duration>,
    ) -> Result<Option<Vec<u8>>, BusError>;
}

impl<P: Protocol> Master for Engine<P>
where
    Engine<P>: Send,
{
    fn job(
        &mut self,
        io: &mut Io,
        address: u8,
        exchange: &Exchange,
        priority: Priority,
        timeout: Option<Duration>,
    ) -> Result<Option<Vec<u8>>, BusError> {
        let clock = &io.clock;
        let broadcast = !exchange.expect_reply;
        // One reading of the clock per step that can take time (the start, each wait), shared
        // by the engine calls between them.
        let mut now = clock.now();
        let attempts = self.admit(now, address, broadcast, priority, timeout)?;
        let mut last = Attempt::Timeout;
        for i in 0..attempts {
            self.start(now, &exchange.request, i)?;
            last = run_attempt(self, &mut io.port, clock, &mut io.buf, &mut now);
            match last {
                Attempt::Reply(_) | Attempt::NoneDue => break,
                Attempt::Link(_) => {
                    // The port may have gone and come back: reopen once, then give up.
                    let reopened = io.port.reopen(self.config());
                    now = clock.now();
                    if reopened.is_err() {
                        break;
                    }
                }
                Attempt::Timeout | Attempt::Damaged(_) => now = clock.now(),
            }
        }
        self.finish(now, io.port.name(), address, broadcast, attempts, last)
    }
}

/// Runs one attempt from session time `now`, which it keeps up to date across its waits.
fn run_attempt<P: Protocol>(
    engine: &mut Engine<P>,
    port: &mut Port,
    clock: &SyncClock,
    buf: &mut [u8],
    now: &mut Instant,
) -> Attempt {
    loop {
        match engine.poll(*now) {
            Action::Transmit => {
                if let Err(e) = port.write(engine.outgoing()) {
                    return Attempt::Link(format!("{}: {e}", port.name()));
                }
                engine.sent(*now);
            }
            Action::Done(attempt) => return attempt,
            Action::Wait(deadline) => {
                let read = port.read(buf, clock.at(deadline));
                *now = clock.now();
                match read {
                    Ok(0) => engine.timeout(*now),
                    Ok(n) => engine.input(*now, &buf[..n]),
                    Err(e) => return Attempt::Link(format!("{}: {e}", port.name())),
                }
            }
        }
    }
}

enum Port {
    Serial(SerialPort),
    /// A serial port whose reopening failed: closed, to be opened again on the next attempt.
    Closed {
        path: String,
        rs485: Rs485,
    },
    Tcp(TcpPort),
}

impl Port {
    fn name(&self) -> String {
        match self {
            Port::Serial(SerialPort { path, .. }) | Port::Closed { path, .. } => path.clone(),
            Port::Tcp(t) => format!("tcp://{}", t.addr),
        }
    }

    fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        match self {
            Port::Serial(s) => s.write(bytes),
            Port::Closed { path, .. } => Err(not_open(path)),
            Port::Tcp(t) => t.write(bytes),
        }
    }

    /// Reads what arrives before `deadline`: `Ok(0)` when the deadline passed with nothing.
    fn read(&mut self, buf: &mut [u8], deadline: std::time::Instant) -> io::Result<usize> {
        match self {
            Port::Serial(s) => s.read(buf, deadline),
            Port::Closed { path, .. } => Err(not_open(path)),
            Port::Tcp(t) => t.read(buf, deadline),
        }
    }

    fn reopen(&mut self, config: &BusConfig) -> io::Result<()> {
        match self {
            Port::Serial(SerialPort { path, rs485, .. }) | Port::Closed { path, rs485 } => {
                let (path, rs485) = (std::mem::take(path), *rs485);
                // Close first: opened for exclusive use, the device refuses a second open.
                *self = Port::Closed { path: path.clone(), rs485 };
                *self = Port::Serial(SerialPort::open(&path, config.baud, config.format, rs485)?);
                Ok(())
            }
            Port::Tcp(t) => {
                t.stream = None;
                t.stream = Some(TcpPort::dial(&t.addr)?);
                Ok(())
            }
        }
    }
}

/// The error for a serial port whose reopening failed.
fn not_open(path: &str) -> io::Error {
    io::Error::new(io::ErrorKind::NotConnected, format!("{path} is not open (reopening it failed)"))
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
    rs485: Rs485,
    direction: Direction,
    /// The port has no modem lines (a pty): RTS toggles are skipped.
    no_rts: bool,
    /// The `VTIME` (tenths of a second) in force for reads.
    vtime: Option<u8>,
}

impl SerialPort {
    fn open(path: &str, baud: u32, format: CharFormat, rs485: Rs485) -> io::Result<Self> {
        // serialport sets the line up (raw mode, baud, format, exclusive access) and leaves the
        // descriptor blocking.
        let tty = serial_builder(path, baud, format).open_native().map_err(|e| open_error(path, e))?;
        // SAFETY: `into_raw_fd` hands over an open descriptor that nothing else owns or closes
        // (the port forgets it), so the `OwnedFd` is its only owner.
        #[allow(unsafe_code)]
        let fd = unsafe { OwnedFd::from_raw_fd(tty.into_raw_fd()) };
        let file = File::from(fd);
        let raw = file.as_raw_fd();
        let (direction, no_rts) = choose_direction(path, raw, rs485, || set_rts(raw, false))?;
        Ok(SerialPort { path: path.to_string(), file, rs485, direction, no_rts, vtime: None })
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

/// Switches RTS on or off (`TIOCMBIS` / `TIOCMBIC`).
fn set_rts(fd: std::os::fd::RawFd, on: bool) -> io::Result<()> {
    let bits: libc::c_int = libc::TIOCM_RTS;
    let request = if on { libc::TIOCMBIS } else { libc::TIOCMBIC };
    // SAFETY: `fd` is an open descriptor owned by the caller for the whole call; TIOCMBIS and
    // TIOCMBIC read one `int` through the pointer, which points at `bits`, alive until return.
    #[allow(unsafe_code)]
    let r = unsafe { libc::ioctl(fd, request as _, &bits as *const libc::c_int) };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Raw bytes over TCP to a serial device server.
struct TcpPort {
    addr: String,
    stream: Option<TcpStream>,
}

impl TcpPort {
    fn connect(addr: &str) -> io::Result<Self> {
        Ok(TcpPort { addr: addr.to_string(), stream: Some(Self::dial(addr)?) })
    }

    fn dial(addr: &str) -> io::Result<TcpStream> {
        use std::net::ToSocketAddrs;
        let mut last = io::Error::new(io::ErrorKind::NotFound, format!("tcp://{addr}: no such host"));
        for a in addr
            .to_socket_addrs()
            .map_err(|e| io::Error::new(e.kind(), format!("cannot resolve tcp://{addr}: {e}")))?
        {
            match TcpStream::connect_timeout(&a, Duration::from_secs(3)) {
                Ok(s) => {
                    s.set_nodelay(true)?;
                    return Ok(s);
                }
                Err(e) => last = io::Error::new(e.kind(), format!("cannot connect to tcp://{addr}: {e}")),
            }
        }
        Err(last)
    }

    fn stream(&mut self) -> io::Result<&mut TcpStream> {
        let addr = &self.addr;
        self.stream.as_mut().ok_or_else(|| {
            io::Error::new(io::ErrorKind::NotConnected, format!("tcp://{addr} is not connected"))
        })
    }

    fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        let r = self.stream()?.write_all(bytes);
        if r.is_err() {
            self.stream = None;
        }
        r
    }

    fn read(&mut self, buf: &mut [u8], deadline: std::time::Instant) -> io::Result<usize> {
        let TcpPort { addr, stream: slot } = self;
        let Some(stream) = slot.as_mut() else {
            return Err(io::Error::new(
                io::ErrorKind::NotConnected,
                format!("tcp://{addr} is not connected"),
            ));
        };
        loop {
            if !wait_readable(&*stream, deadline)? {
                return Ok(0);
            }
            let r = match stream.read(buf) {
                Ok(0) => Err(io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    format!("tcp://{addr} closed the connection"),
                )),
                Ok(n) => Ok(n),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => Err(e),
            };
            if r.is_err() {
                *slot = None;
            }
            return r;
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
        let config =
            BusConfig::new(drivebus_proto::protocol::WireProtocol::ModbusRtu, 9600, "8N1".parse().unwrap());
        let mut port =
            Port::Serial(SerialPort::open(&path, config.baud, config.format, Rs485::Off).expect("open"));
        // Opened for exclusive use: without closing first, the second open of the device fails.
        port.reopen(&config).expect("reopen the same device");
        assert!(matches!(port, Port::Serial(_)));
        // Another program holding the port is named as such.
        let e = SerialPort::open(&path, config.baud, config.format, Rs485::Off).err().expect("in use");
        assert!(e.to_string().contains("another program has it open"), "{e}");

        std::fs::remove_file(&link).unwrap();
        assert!(port.reopen(&config).is_err(), "the device is gone");
        assert!(matches!(port, Port::Closed { .. }));
        let e = port.write(&[1, 2, 3]).unwrap_err();
        assert_eq!(e.to_string(), format!("{path} is not open (reopening it failed)"));
        assert_eq!(port.name(), path);

        std::os::unix::fs::symlink(&device, &link).unwrap();
        port.reopen(&config).expect("the device is back");
        assert!(matches!(port, Port::Serial(_)));
        port.write(&[1, 2, 3]).expect("a write to the reopened port");
        let _ = std::fs::remove_file(&link);
    }
}
