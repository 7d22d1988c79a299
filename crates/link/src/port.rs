//! Where a bus is ([`Port`]: a serial device with its baud rate, format and RS-485 direction
//! control, a serial device server over TCP, or a virtual line of simulated drives) and the one
//! opener of it, used by the async bus owner (`PortLink`), the blocking bus
//! (the `blocking` module) and the gateway. What to do when a port is lost (reopen it, and when)
//! is the engine's decision, not the port's.

use std::io;
use std::net::TcpStream;
use std::time::Duration;

use drivebus_proto::line::{CharFormat, Parity};

/// A serial device and the settings it is opened with.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SerialSettings {
    /// The device (`/dev/ttyUSB0`, a pty's path).
    pub path: String,
    /// Baud rate.
    pub baud: u32,
    /// Character format.
    pub format: CharFormat,
    /// RS-485 direction control.
    pub rs485: Rs485,
}

/// Where a bus is.
#[derive(Clone)]
pub enum Port {
    /// A serial device.
    Serial(SerialSettings),
    /// A serial device server (`host:port`), raw bytes over TCP.
    Tcp(String),
    /// A Modbus TCP server (`host:port`: a drive's Ethernet card, a Modbus TCP/RTU gateway):
    /// the bus's Modbus frames go in MBAP, the drive's address as the unit id
    /// ([`crate::mbap`]).
    ModbusTcp(String),
    /// A virtual line of simulated drives in this process.
    #[cfg(feature = "virtual")]
    Virtual(VirtualPort),
}

/// A virtual line and the name it goes by.
#[cfg(feature = "virtual")]
#[derive(Clone)]
pub struct VirtualPort {
    /// The line.
    pub line: std::sync::Arc<std::sync::Mutex<drivebus_sim::bus::VirtualLine>>,
    /// Its name in messages (`virtual:line-1`).
    pub name: String,
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

/// How long a TCP connection may take to open, per address the host name resolves to.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(3);

/// A port opened with its settings, before it is given to a driver (blocking or async).
pub(crate) enum Opened {
    /// A serial device.
    Serial(OpenedSerial),
    /// A connected, blocking TCP stream with Nagle's delay off.
    Tcp {
        /// Where it goes (`host:port`).
        addr: String,
        /// The connection.
        stream: TcpStream,
    },
    /// A virtual line.
    #[cfg(feature = "virtual")]
    Virtual(VirtualPort),
}

/// A serial device set up (raw mode, baud rate, format, exclusive access), blocking, with its
/// direction control chosen.
pub(crate) struct OpenedSerial {
    /// What it was opened with.
    pub(crate) settings: SerialSettings,
    /// The device.
    pub(crate) tty: serialport::TTYPort,
    /// The direction control in force.
    pub(crate) direction: Direction,
    /// The device has no modem lines (a pty): RTS toggles are skipped.
    pub(crate) no_rts: bool,
}

impl SerialSettings {
    /// Opens the device with these settings and chooses its direction control.
    pub(crate) fn open(&self) -> io::Result<OpenedSerial> {
        use std::os::fd::AsRawFd;
        // serialport sets the line up (raw mode, baud, format, exclusive access) and leaves the
        // descriptor blocking.
        let tty = serial_builder(&self.path, self.baud, self.format)
            .open_native()
            .map_err(|e| open_error(&self.path, e))?;
        let fd = tty.as_raw_fd();
        let (direction, no_rts) = choose_direction(&self.path, fd, self.rs485, || set_rts(fd, false))?;
        Ok(OpenedSerial { settings: self.clone(), tty, direction, no_rts })
    }
}

impl Port {
    /// The port a user spelled: `tcp://HOST:PORT` for a serial device server, anything else a
    /// serial device opened at `baud` with `format` and RS-485 mode `rs485`.
    pub fn parse(spelling: &str, baud: u32, format: CharFormat, rs485: Rs485) -> Port {
        match spelling.strip_prefix("tcp://") {
            Some(addr) => Port::Tcp(addr.to_string()),
            None => Port::Serial(SerialSettings { path: spelling.to_string(), baud, format, rs485 }),
        }
    }

    /// The Modbus TCP server a user spelled `tcp://HOST[:PORT]` (port 502 where none is
    /// given), or a sentence saying what to give.
    pub fn modbus_tcp(spelling: &str) -> Result<Port, String> {
        match spelling.strip_prefix("tcp://") {
            Some(addr) if !addr.is_empty() => Ok(Port::ModbusTcp(crate::mbap::with_default_port(addr))),
            _ => Err(format!(
                "{spelling:?} is not a Modbus TCP server: give tcp://HOST[:PORT] (port 502 by default)"
            )),
        }
    }

    /// Its name in messages (`/dev/ttyUSB0`, `tcp://10.0.0.5:4001`, `virtual:line-1`).
    pub fn name(&self) -> String {
        match self {
            Port::Serial(s) => s.path.clone(),
            Port::Tcp(addr) | Port::ModbusTcp(addr) => format!("tcp://{addr}"),
            #[cfg(feature = "virtual")]
            Port::Virtual(v) => v.name.clone(),
        }
    }

    /// Opens the port with its settings (the one place that does): a serial device with its
    /// direction control, a TCP connection (at most 3 s per address the host resolves to), a
    /// virtual line at once. Blocks while it connects.
    pub(crate) fn open(&self) -> io::Result<Opened> {
        match self {
            Port::Serial(s) => s.open().map(Opened::Serial),
            Port::Tcp(addr) | Port::ModbusTcp(addr) => {
                Ok(Opened::Tcp { addr: addr.clone(), stream: dial(addr)? })
            }
            #[cfg(feature = "virtual")]
            Port::Virtual(v) => Ok(Opened::Virtual(v.clone())),
        }
    }
}

/// Connects to `addr` (`host:port`), trying each address it resolves to.
pub(crate) fn dial(addr: &str) -> io::Result<TcpStream> {
    use std::net::ToSocketAddrs;
    let mut last = io::Error::new(io::ErrorKind::NotFound, format!("tcp://{addr}: no such host"));
    let addrs = addr
        .to_socket_addrs()
        .map_err(|e| io::Error::new(e.kind(), format!("cannot resolve tcp://{addr}: {e}")))?;
    for a in addrs {
        match TcpStream::connect_timeout(&a, CONNECT_TIMEOUT) {
            Ok(s) => {
                s.set_nodelay(true)?;
                return Ok(s);
            }
            Err(e) => last = io::Error::new(e.kind(), format!("cannot connect to tcp://{addr}: {e}")),
        }
    }
    Err(last)
}

/// Switches RTS on or off (`TIOCMBIS` / `TIOCMBIC`) on the serial device `fd`.
pub(crate) fn set_rts(fd: std::os::fd::RawFd, on: bool) -> io::Result<()> {
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
