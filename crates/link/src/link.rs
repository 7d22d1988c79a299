//! Byte links: a real serial port, a TCP connection to a serial device server, and the
//! simulator's virtual line in the same process.
//!
//! Every link tells time the same way: session time ([`Instant`]) is tokio time since the link
//! was made, so under `tokio::time::pause()` a whole bus runs on a virtual clock.

use std::future::Future;
use std::io;
use std::time::Duration;

use drivebus_proto::line::{CharFormat, Parity};
use drivebus_proto::Instant;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

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

/// How the RS-485 transceiver's driver is switched on for sending.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Rs485 {
    /// Nothing to do: the adapter switches by itself (most USB-RS485 adapters), or the line
    /// is RS-232, a pty or a TCP server.
    #[default]
    Off,
    /// The kernel's RS-485 mode where the driver has it, else RTS toggled around each write.
    Auto,
    /// The kernel's RS-485 mode (Linux `TIOCSRS485`: RTS on while sending); an error where
    /// the driver lacks it.
    Kernel,
    /// RTS on, write, wait until the last bit has left (`tcdrain`), RTS off.
    Rts,
}

impl std::str::FromStr for Rs485 {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(Rs485::Off),
            "auto" => Ok(Rs485::Auto),
            "kernel" => Ok(Rs485::Kernel),
            "rts" => Ok(Rs485::Rts),
            other => Err(format!("unknown RS-485 mode {other:?}: use off, auto, kernel or rts")),
        }
    }
}

/// What direction control a serial link ended up with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// None (the adapter does it, or it was not asked for).
    None,
    /// The kernel switches the driver.
    Kernel,
    /// drivebus toggles RTS around each write.
    Rts,
}

/// A serial port (USB-RS485 adapter, on-board UART).
pub struct SerialLink {
    path: String,
    baud: u32,
    format: CharFormat,
    /// `None` after a reopen that failed: the old descriptor is closed before the device is
    /// opened again, since a port open for exclusive use cannot be opened a second time.
    port: Option<tokio_serial::SerialStream>,
    clock: Clock,
    rs485: Rs485,
    direction: Direction,
    /// The port has no modem lines (a pty): RTS toggles are skipped.
    no_rts: bool,
}

/// Turns on the kernel's RS-485 mode (RTS on while sending, off after) on `fd`.
#[cfg(target_os = "linux")]
fn kernel_rs485(fd: std::os::fd::RawFd) -> io::Result<()> {
    /// `struct serial_rs485` of `<linux/serial.h>`.
    #[repr(C)]
    struct SerialRs485 {
        flags: u32,
        delay_rts_before_send: u32,
        delay_rts_after_send: u32,
        padding: [u32; 5],
    }
    const SER_RS485_ENABLED: u32 = 1 << 0;
    const SER_RS485_RTS_ON_SEND: u32 = 1 << 1;
    let conf = SerialRs485 {
        flags: SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND,
        delay_rts_before_send: 0,
        delay_rts_after_send: 0,
        padding: [0; 5],
    };
    // SAFETY: `fd` is an open descriptor owned by the caller's port for the whole call, and
    // TIOCSRS485 reads exactly one `struct serial_rs485`, which `conf` is (repr(C), same
    // fields and size: 32 bytes), alive until the call returns.
    #[allow(unsafe_code)]
    let r = unsafe { libc::ioctl(fd, libc::TIOCSRS485 as _, &conf as *const SerialRs485) };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn kernel_rs485(_fd: i32) -> io::Result<()> {
    Err(io::Error::new(io::ErrorKind::Unsupported, "the kernel's RS-485 mode is Linux only"))
}

/// True for errors that mean "this device has no such control" (a pty, a driver without
/// RS-485 support), as opposed to a failing port.
fn unsupported(e: &io::Error) -> bool {
    let code = matches!(e.raw_os_error(), Some(c) if c == libc::ENOTTY || c == libc::EINVAL || c == libc::EOPNOTSUPP);
    // serialport's errors carry the errno's text only (nix's wording for ENOTTY and EINVAL).
    let text = e.to_string();
    code || e.kind() == io::ErrorKind::Unsupported
        || ["Not a typewriter", "Inappropriate ioctl", "Invalid argument", "not supported"]
            .iter()
            .any(|t| text.contains(t))
}

/// The serialport builder for `path` at `baud` with `format`, no flow control.
pub(crate) fn serial_builder(path: &str, baud: u32, format: CharFormat) -> tokio_serial::SerialPortBuilder {
    use tokio_serial::{DataBits, FlowControl, StopBits};
    let data_bits = if format.data_bits == 7 { DataBits::Seven } else { DataBits::Eight };
    let parity = match format.parity {
        Parity::None => tokio_serial::Parity::None,
        Parity::Even => tokio_serial::Parity::Even,
        Parity::Odd => tokio_serial::Parity::Odd,
    };
    let stop_bits = if format.stop_bits == 2 { StopBits::Two } else { StopBits::One };
    tokio_serial::new(path, baud)
        .data_bits(data_bits)
        .parity(parity)
        .stop_bits(stop_bits)
        .flow_control(FlowControl::None)
}

/// The error of a serial port that would not open.
pub(crate) fn open_error(path: &str, e: tokio_serial::Error) -> io::Error {
    // ErrorKind::ResourceBusy is newer than the crate's minimum Rust: EBUSY is told by its text.
    let busy = e.description.contains("lock on serial port") || e.description.contains("busy");
    if busy {
        // Another program holds the port (the exclusive lock, or TIOCEXCL's EBUSY).
        return io::Error::other(format!(
            "cannot open serial port {path}: another program has it open (close it; fuser -v {path} shows which)"
        ));
    }
    let kind = match e.kind {
        tokio_serial::ErrorKind::Io(kind) => kind,
        _ => io::ErrorKind::NotFound,
    };
    io::Error::new(kind, format!("cannot open serial port {path}: {e}"))
}

fn open_serial(path: &str, baud: u32, format: CharFormat) -> io::Result<tokio_serial::SerialStream> {
    use tokio_serial::SerialPortBuilderExt;
    serial_builder(path, baud, format).open_native_async().map_err(|e| open_error(path, e))
}

/// Chooses the direction control `rs485` asks for on the port `fd` (named `path`): the
/// kernel's RS-485 mode where asked for and present, else RTS toggling, with RTS switched off
/// for receiving by `rts_off`. Returns the direction and whether the port has no modem lines
/// (a pty: its RTS toggles are then skipped).
pub(crate) fn choose_direction(
    path: &str,
    fd: std::os::fd::RawFd,
    rs485: Rs485,
    rts_off: impl FnOnce() -> io::Result<()>,
) -> io::Result<(Direction, bool)> {
    let kernel = match rs485 {
        Rs485::Off => return Ok((Direction::None, false)),
        Rs485::Kernel | Rs485::Auto => kernel_rs485(fd),
        Rs485::Rts => Err(io::Error::new(io::ErrorKind::Unsupported, "RTS asked for")),
    };
    match (kernel, rs485) {
        (Ok(()), _) => Ok((Direction::Kernel, false)),
        (Err(e), Rs485::Kernel) => Err(io::Error::new(
            e.kind(),
            format!("{path}: the driver has no kernel RS-485 mode ({e}): use --rs485 rts or auto"),
        )),
        // Receive: RTS off. A port without modem lines (a pty) has nothing to switch.
        (Err(_), _) => match rts_off() {
            Ok(()) => Ok((Direction::Rts, false)),
            Err(e) if unsupported(&e) => Ok((Direction::Rts, true)),
            Err(e) => Err(io::Error::new(e.kind(), format!("{path}: cannot switch RTS: {e}"))),
        },
    }
}

impl SerialLink {
    /// Opens `path` at `baud` with `format` (e.g. 9600 8E1), with no direction control.
    pub fn open(path: &str, baud: u32, format: CharFormat) -> io::Result<Self> {
        Self::open_rs485(path, baud, format, Rs485::Off)
    }

    /// Opens `path` with RS-485 direction control `rs485`.
    pub fn open_rs485(path: &str, baud: u32, format: CharFormat, rs485: Rs485) -> io::Result<Self> {
        let mut link = SerialLink {
            path: path.to_string(),
            baud,
            format,
            port: Some(open_serial(path, baud, format)?),
            clock: Clock::new(),
            rs485,
            direction: Direction::None,
            no_rts: false,
        };
        link.setup_direction()?;
        Ok(link)
    }

    /// The direction control in force.
    pub fn direction(&self) -> Direction {
        self.direction
    }

    fn setup_direction(&mut self) -> io::Result<()> {
        use std::os::fd::AsRawFd;
        use tokio_serial::SerialPort;
        let Some(port) = self.port.as_mut() else { return Err(not_open(&self.path)) };
        let fd = port.as_raw_fd();
        let (direction, no_rts) = choose_direction(&self.path, fd, self.rs485, || {
            port.write_request_to_send(false).map_err(io::Error::from)
        })?;
        self.direction = direction;
        self.no_rts = no_rts;
        Ok(())
    }

    fn set_rts(&mut self, on: bool) -> io::Result<()> {
        use tokio_serial::SerialPort;
        if self.no_rts {
            return Ok(());
        }
        let Some(port) = self.port.as_mut() else { return Err(not_open(&self.path)) };
        port.write_request_to_send(on).map_err(|e| {
            let e = io::Error::from(e);
            io::Error::new(e.kind(), format!("{}: cannot switch RTS: {e}", self.path))
        })
    }
}

impl SerialLink {
    fn port(&mut self) -> io::Result<&mut tokio_serial::SerialStream> {
        match &mut self.port {
            Some(p) => Ok(p),
            None => Err(not_open(&self.path)),
        }
    }
}

/// The error for a port whose reopening failed.
fn not_open(path: &str) -> io::Error {
    io::Error::new(io::ErrorKind::NotConnected, format!("{path} is not open (reopening it failed)"))
}

impl Link for SerialLink {
    fn name(&self) -> String {
        self.path.clone()
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
            0 => Err(io::Error::new(io::ErrorKind::UnexpectedEof, format!("{} closed", self.path))),
            n => Ok(n),
        }
    }
    async fn reopen(&mut self) -> io::Result<()> {
        // Close first: opened for exclusive use, the device refuses a second open.
        self.port = None;
        self.port = Some(open_serial(&self.path, self.baud, self.format)?);
        self.no_rts = false;
        self.setup_direction()
    }
}

/// Raw bytes over TCP to a serial device server ("RTU over TCP").
pub struct TcpLink {
    addr: String,
    stream: Option<tokio::net::TcpStream>,
    clock: Clock,
}

impl TcpLink {
    /// Connects to `addr` (`host:port`).
    pub async fn connect(addr: &str) -> io::Result<Self> {
        let stream = Self::dial(addr).await?;
        Ok(TcpLink { addr: addr.to_string(), stream: Some(stream), clock: Clock::new() })
    }

    async fn dial(addr: &str) -> io::Result<tokio::net::TcpStream> {
        let s = tokio::time::timeout(Duration::from_secs(3), tokio::net::TcpStream::connect(addr))
            .await
            .map_err(|_| {
                io::Error::new(io::ErrorKind::TimedOut, format!("no answer from tcp://{addr} within 3 s"))
            })?
            .map_err(|e| io::Error::new(e.kind(), format!("cannot connect to tcp://{addr}: {e}")))?;
        s.set_nodelay(true)?;
        Ok(s)
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
        self.stream = Some(Self::dial(&self.addr).await?);
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
