//! Byte links: a real serial port, a TCP connection to a serial device server, and the
//! simulator's virtual line in the same process.
//!
//! Every link tells time the same way: session time ([`Instant`]) is tokio time since the link
//! was made, so under `tokio::time::pause()` a whole bus runs on a virtual clock.

use std::future::Future;
use std::io;
use std::time::Duration;

use drivebus_proto::line::CharFormat;
use drivebus_proto::Instant;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::port::{dial, open_error, set_rts, Opened, OpenedSerial, Port, SerialSettings};
pub use crate::port::{Direction, Rs485};

/// A half-duplex byte link to a bus.
pub trait Link: Send + 'static {
    /// Where it goes, for messages (`/dev/ttyUSB0`, `tcp://10.0.0.5:4001`).
    fn name(&self) -> String;
    /// The link's clock (session time).
    fn clock(&self) -> Clock;
    /// Session time now.
    fn now(&self) -> Instant {
        self.clock().now()
    }
    /// Writes all of `bytes`.
    fn write(&mut self, bytes: &[u8]) -> impl Future<Output = io::Result<()>> + Send;
    /// Reads what has arrived (at least one byte); cancel-safe.
    fn read(&mut self, buf: &mut [u8]) -> impl Future<Output = io::Result<usize>> + Send;
    /// Closes and opens the link again (after a device server rebooted, a USB adapter
    /// came back).
    fn reopen(&mut self) -> impl Future<Output = io::Result<()>> + Send;
    /// Whether it is open; a link made closed (`PortLink::new`) is opened
    /// by the bus owner before its first transaction.
    fn is_open(&self) -> bool {
        true
    }
}

/// Session time from a tokio base instant.
#[derive(Clone, Copy, Debug)]
pub struct Clock {
    base: tokio::time::Instant,
}

impl Clock {
    /// A clock whose epoch is now.
    pub fn new() -> Self {
        Clock { base: tokio::time::Instant::now() }
    }
    /// Session time now.
    pub fn now(&self) -> Instant {
        Instant::from_nanos(self.base.elapsed().as_nanos().min(u64::MAX as u128) as u64)
    }
    /// The tokio instant of session time `t`.
    pub fn tokio(&self, t: Instant) -> tokio::time::Instant {
        self.base + Duration::from_nanos(t.as_nanos())
    }
}

impl Default for Clock {
    fn default() -> Self {
        Clock::new()
    }
}

/// A serial port (USB-RS485 adapter, on-board UART).
pub struct SerialLink {
    settings: SerialSettings,
    /// `None` after a reopen that failed: the old descriptor is closed before the device is
    /// opened again, since a port open for exclusive use cannot be opened a second time.
    port: Option<tokio_serial::SerialStream>,
    clock: Clock,
    direction: Direction,
    /// The port has no modem lines (a pty): RTS toggles are skipped.
    no_rts: bool,
}

impl SerialLink {
    /// Opens `path` at `baud` with `format` (e.g. 9600 8E1), with no direction control.
    pub fn open(path: &str, baud: u32, format: CharFormat) -> io::Result<Self> {
        Self::open_rs485(path, baud, format, Rs485::Off)
    }

    /// Opens `path` with RS-485 direction control `rs485`.
    pub fn open_rs485(path: &str, baud: u32, format: CharFormat, rs485: Rs485) -> io::Result<Self> {
        let settings = SerialSettings { path: path.to_string(), baud, format, rs485 };
        Self::from_opened(settings.open()?, Clock::new())
    }

    /// The async link of a serial device the opener has set up, telling time by `clock`.
    pub(crate) fn from_opened(opened: OpenedSerial, clock: Clock) -> io::Result<Self> {
        let OpenedSerial { settings, tty, direction, no_rts } = opened;
        let port = tokio_serial::SerialStream::try_from(tty).map_err(|e| open_error(&settings.path, e))?;
        Ok(SerialLink { settings, port: Some(port), clock, direction, no_rts })
    }

    /// The direction control in force.
    pub fn direction(&self) -> Direction {
        self.direction
    }

    fn set_rts(&mut self, on: bool) -> io::Result<()> {
        use std::os::fd::AsRawFd;
        if self.no_rts {
            return Ok(());
        }
        let fd = self.port()?.as_raw_fd();
        set_rts(fd, on)
            .map_err(|e| io::Error::new(e.kind(), format!("{}: cannot switch RTS: {e}", self.settings.path)))
    }

    fn port(&mut self) -> io::Result<&mut tokio_serial::SerialStream> {
        match &mut self.port {
            Some(p) => Ok(p),
            None => Err(not_open(&self.settings.path)),
        }
    }
}

/// The error for a port whose reopening failed.
fn not_open(path: &str) -> io::Error {
    io::Error::new(io::ErrorKind::NotConnected, format!("{path} is not open (reopening it failed)"))
}

impl Link for SerialLink {
    fn name(&self) -> String {
        self.settings.path.clone()
    }
    fn clock(&self) -> Clock {
        self.clock
    }
    async fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        if self.direction != Direction::Rts {
            // No drain: the session knows the request's wire time, and waiting for the UART
            // here would block the thread for it.
            return self.port()?.write_all(bytes).await;
        }
        self.set_rts(true)?;
        let r = async {
            let port = self.port()?;
            port.write_all(bytes).await?;
            // Until the last bit has left the UART (tcdrain), then back to receive.
            port.flush().await
        }
        .await;
        let off = self.set_rts(false);
        r.and(off)
    }
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self.port()?.read(buf).await? {
            0 => Err(io::Error::new(io::ErrorKind::UnexpectedEof, format!("{} closed", self.settings.path))),
            n => Ok(n),
        }
    }
    async fn reopen(&mut self) -> io::Result<()> {
        // Close first: opened for exclusive use, the device refuses a second open.
        self.port = None;
        let opened = self.settings.open()?;
        *self = Self::from_opened(opened, self.clock)?;
        Ok(())
    }
}

/// Connects to `addr` (`host:port`) on a blocking thread: a connection may take seconds, which
/// the runtime's own threads must not wait.
pub(crate) async fn dial_async(addr: &str) -> io::Result<std::net::TcpStream> {
    let to = addr.to_string();
    tokio::task::spawn_blocking(move || dial(&to))
        .await
        .map_err(|e| io::Error::other(format!("cannot connect to tcp://{addr}: {e}")))?
}

/// Opens `port` (see [`Port::open`]) without blocking the runtime.
pub(crate) async fn open_async(port: &Port) -> io::Result<Opened> {
    match port {
        Port::Tcp(addr) | Port::ModbusTcp(addr) => {
            Ok(Opened::Tcp { addr: addr.clone(), stream: dial_async(addr).await? })
        }
        port => port.open(),
    }
}

/// Raw bytes over TCP to a serial device server ("RTU over TCP").
pub struct TcpLink {
    addr: String,
    stream: Option<tokio::net::TcpStream>,
    clock: Clock,
}

impl TcpLink {
    /// Connects to `addr` (`host:port`), trying each address it resolves to for 3 s.
    pub async fn connect(addr: &str) -> io::Result<Self> {
        Self::from_std(addr, dial_async(addr).await?, Clock::new())
    }

    /// The async link of a connection to `addr` the opener made, telling time by `clock`.
    pub(crate) fn from_std(addr: &str, stream: std::net::TcpStream, clock: Clock) -> io::Result<Self> {
        Ok(TcpLink { addr: addr.to_string(), stream: Some(Self::to_tokio(stream)?), clock })
    }

    fn to_tokio(stream: std::net::TcpStream) -> io::Result<tokio::net::TcpStream> {
        stream.set_nonblocking(true)?;
        tokio::net::TcpStream::from_std(stream)
    }

    fn stream(&mut self) -> io::Result<&mut tokio::net::TcpStream> {
        let addr = &self.addr;
        self.stream.as_mut().ok_or_else(|| {
            io::Error::new(io::ErrorKind::NotConnected, format!("tcp://{addr} is not connected"))
        })
    }
}

impl Link for TcpLink {
    fn name(&self) -> String {
        format!("tcp://{}", self.addr)
    }
    fn clock(&self) -> Clock {
        self.clock
    }
    async fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        let r = self.stream()?.write_all(bytes).await;
        if r.is_err() {
            self.stream = None;
        }
        r
    }
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.stream()?.read(buf).await?;
        if n == 0 {
            self.stream = None;
            return Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                format!("tcp://{} closed the connection", self.addr),
            ));
        }
        Ok(n)
    }
    async fn reopen(&mut self) -> io::Result<()> {
        self.stream = None;
        self.stream = Some(Self::to_tokio(dial_async(&self.addr).await?)?);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::fd::AsFd;

    #[tokio::test]
    async fn a_serial_link_reopens_on_the_same_device() {
        let pair = nix::pty::openpty(None, None).expect("a pty");
        let device = nix::unistd::ttyname(pair.slave.as_fd()).expect("its name");
        let path = device.to_str().unwrap();
        let mut link = SerialLink::open(path, 9600, "8N1".parse().unwrap()).expect("open");
        // Opened for exclusive use: without closing first, the second open of the device fails.
        link.reopen().await.expect("reopen the same device");
        link.write(&[1, 2, 3]).await.expect("a write to the reopened port");
        drop(pair.master);
    }
}
