//! Byte links: a real serial port, a TCP connection to a serial device server, and the
//! simulator's virtual line in the same process.
//!
//! Every link tells time the same way: session time ([`Instant`]) is tokio time since the link
//! was made, so under `tokio::time::pause()` a whole bus runs on a virtual clock.

use std::future::Future;
use std::io;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_proto::line::{CharFormat, Parity};
use drivebus_proto::Instant;
use drivebus_sim::bus::VirtualLine;
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

/// A serial port (USB-RS485 adapter, on-board UART).
pub struct SerialLink {
    path: String,
    baud: u32,
    format: CharFormat,
    port: tokio_serial::SerialStream,
    clock: Clock,
}

fn open_serial(path: &str, baud: u32, format: CharFormat) -> io::Result<tokio_serial::SerialStream> {
    use tokio_serial::{DataBits, FlowControl, SerialPortBuilderExt, StopBits};
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
        .open_native_async()
        .map_err(|e| io::Error::new(io::ErrorKind::NotFound, format!("cannot open serial port {path}: {e}")))
}

impl SerialLink {
    /// Opens `path` at `baud` with `format` (e.g. 9600 8E1).
    pub fn open(path: &str, baud: u32, format: CharFormat) -> io::Result<Self> {
        Ok(SerialLink {
            path: path.to_string(),
            baud,
            format,
            port: open_serial(path, baud, format)?,
            clock: Clock::new(),
        })
    }
}

impl Link for SerialLink {
    fn name(&self) -> String {
        self.path.clone()
    }
    fn clock(&self) -> Clock {
        self.clock
    }
    async fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.port.write_all(bytes).await?;
        self.port.flush().await
    }
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self.port.read(buf).await? {
            0 => Err(io::Error::new(io::ErrorKind::UnexpectedEof, format!("{} closed", self.path))),
            n => Ok(n),
        }
    }
    async fn reopen(&mut self) -> io::Result<()> {
        self.port = open_serial(&self.path, self.baud, self.format)?;
        Ok(())
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

/// The simulator's virtual line in the same process: paced at its baud rate on tokio time.
pub struct SimLink {
    line: Arc<Mutex<VirtualLine>>,
    clock: Clock,
    name: String,
}

impl SimLink {
    /// A link to `line` (whose simulated time starts with this link).
    pub fn new(line: Arc<Mutex<VirtualLine>>, name: &str) -> Self {
        SimLink { line, clock: Clock::new(), name: name.to_string() }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, VirtualLine> {
        self.line.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl Link for SimLink {
    fn name(&self) -> String {
        self.name.clone()
    }
    fn clock(&self) -> Clock {
        self.clock
    }
    async fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        let now = self.now();
        self.lock().master_write(now, bytes);
        Ok(())
    }
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let mut got = Vec::new();
        loop {
            let now = self.now();
            let next = {
                let mut line = self.lock();
                line.advance_to(now);
                line.master_read(&mut got);
                line.next_deadline()
            };
            if !got.is_empty() {
                let n = got.len().min(buf.len());
                buf[..n].copy_from_slice(&got[..n]);
                if n < got.len() {
                    // Keep order: put the rest back by writing nothing and returning what fits;
                    // buffers here are always large enough (a frame's worth at most).
                    return Err(io::Error::other("read buffer smaller than a burst"));
                }
                return Ok(n);
            }
            match next {
                Some(t) if t > now => tokio::time::sleep_until(self.clock.tokio(t)).await,
                Some(_) => tokio::task::yield_now().await,
                // Nothing on the line: wait a while (a write from us is the only way out, and
                // the caller cancels this read to write).
                None => tokio::time::sleep(Duration::from_millis(50)).await,
            }
        }
    }
    async fn reopen(&mut self) -> io::Result<()> {
        Ok(())
    }
}
