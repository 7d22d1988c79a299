//! A serial port opened to listen only (`drivebus sniff`): blocking reads with a timeout, the
//! settings changed while it is open (to find a line's baud rate and format), and the adapter's
//! low-latency mode where it has one, so each read is timestamped close to the bytes' arrival.

use std::io::{self, Read};
use std::time::Duration;

use drivebus_proto::line::{CharFormat, Parity};
use tokio_serial::SerialPort;

use crate::port::{open_error, serial_builder};

/// A serial port that is only read from: nothing is ever written to it.
pub struct Listener {
    path: String,
    port: Box<dyn SerialPort>,
    pty: bool,
    low_latency: bool,
}

impl Listener {
    /// Opens `path` at `baud` and `format`, with reads that wait at most `timeout`, and asks the
    /// driver for its low-latency mode (an FTDI adapter then hands bytes over after 1 ms instead
    /// of 16 ms).
    pub fn open(path: &str, baud: u32, format: CharFormat, timeout: Duration) -> io::Result<Self> {
        let native = serial_builder(path, baud, format)
            .timeout(timeout)
            .open_native()
            .map_err(|e| open_error(path, e))?;
        let low_latency = set_low_latency(&native).is_ok();
        let pty = std::fs::canonicalize(path).is_ok_and(|p| p.starts_with("/dev/pts"));
        let l = Listener { path: path.to_string(), port: Box::new(native), pty, low_latency };
        // Whatever the port held from before is not the line now.
        let _ = l.port.clear(tokio_serial::ClearBuffer::Input);
        Ok(l)
    }

    /// The device's path.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// True for a pseudo-terminal (the simulator's tap): its baud rate and format are not real.
    pub fn is_pty(&self) -> bool {
        self.pty
    }

    /// True when the driver's low-latency mode is on.
    pub fn low_latency(&self) -> bool {
        self.low_latency
    }

    /// Changes the baud rate and format and drops what was received before.
    pub fn set(&mut self, baud: u32, format: CharFormat) -> io::Result<()> {
        use tokio_serial::{DataBits, StopBits};
        let e = |e: tokio_serial::Error| {
            io::Error::other(format!("{}: cannot set {baud} {format}: {e}", self.path))
        };
        self.port.set_baud_rate(baud).map_err(e)?;
        self.port
            .set_data_bits(if format.data_bits == 7 { DataBits::Seven } else { DataBits::Eight })
            .map_err(e)?;
        self.port
            .set_parity(match format.parity {
                Parity::None => tokio_serial::Parity::None,
                Parity::Even => tokio_serial::Parity::Even,
                Parity::Odd => tokio_serial::Parity::Odd,
            })
            .map_err(e)?;
        self.port
            .set_stop_bits(if format.stop_bits == 2 { StopBits::Two } else { StopBits::One })
            .map_err(e)?;
        self.port.clear(tokio_serial::ClearBuffer::Input).map_err(e)
    }

    /// Reads what has arrived, waiting up to the timeout; `Ok(0)` when nothing came.
    pub fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self.port.read(buf) {
            Ok(n) => Ok(n),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
                ) =>
            {
                Ok(0)
            }
            Err(e) => Err(io::Error::new(e.kind(), format!("{}: {e}", self.path))),
        }
    }
}

#[cfg(target_os = "linux")]
fn set_low_latency(port: &impl std::os::fd::AsRawFd) -> io::Result<()> {
    /// The head of the kernel's `struct serial_struct` (linux/serial.h), with room for the
    /// rest: only `flags` is read and written back.
    #[repr(C)]
    struct SerialStruct {
        head: [libc::c_int; 4],
        flags: libc::c_int,
        rest: [u64; 32],
    }
    const ASYNC_LOW_LATENCY: libc::c_int = 1 << 13;
    let fd = port.as_raw_fd();
    let mut s = SerialStruct { head: [0; 4], flags: 0, rest: [0; 32] };
    // SAFETY: TIOCGSERIAL writes one `struct serial_struct` (72 bytes on 64-bit Linux) to the
    // pointer; `SerialStruct` is larger and laid out the same for the fields it names, and
    // lives for the call. TIOCSSERIAL reads the same struct back.
    #[allow(unsafe_code)]
    let r = unsafe { libc::ioctl(fd, libc::TIOCGSERIAL as _, &mut s as *mut SerialStruct) };
    if r != 0 {
        return Err(io::Error::last_os_error());
    }
    s.flags |= ASYNC_LOW_LATENCY;
    // SAFETY: as above; the struct is the one the kernel just filled.
    #[allow(unsafe_code)]
    let r = unsafe { libc::ioctl(fd, libc::TIOCSSERIAL as _, &s as *const SerialStruct) };
    if r != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

#[cfg(not(target_os = "linux"))]
fn set_low_latency<T>(_port: &T) -> io::Result<()> {
    Err(io::Error::new(io::ErrorKind::Unsupported, "low-latency mode is Linux only"))
}
