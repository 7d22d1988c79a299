//! The async link of a [`Port`] for the bus owner: one link over whatever the port is (a
//! serial device with its RS-485 settings, a device server, a virtual line), opened by the one
//! opener ([`Port`]'s), reopened when the engine says so.

use std::io;

use crate::link::{open_async, Clock, Direction, Link, SerialLink, TcpLink};
use crate::mbap::MbapFraming;
use crate::port::{Opened, Port};

/// The async link of a [`Port`], for the bus owner ([`crate::Bus::spawn`]). It is opened at
/// once ([`PortLink::open`]) or not ([`PortLink::new`]: the bus owner opens it before the first
/// transaction, as after a loss), and it keeps one clock for its whole life, so session time
/// never goes back on a reopen.
pub struct PortLink {
    port: Port,
    inner: Option<Inner>,
    clock: Clock,
}

/// An open port's async link.
enum Inner {
    Serial(SerialLink),
    Tcp(TcpLink),
    /// A Modbus TCP server: the RTU frames of the engine in MBAP.
    Mbap(TcpLink, MbapFraming),
    #[cfg(feature = "virtual")]
    Virtual(crate::sim_link::SimLink),
}

impl PortLink {
    /// A link to `port`, not open yet: the bus owner opens it before the first transaction.
    pub fn new(port: Port) -> Self {
        PortLink { port, inner: None, clock: Clock::new() }
    }

    /// A link to `port`, opened now (an error says why it would not open).
    pub async fn open(port: Port) -> io::Result<Self> {
        let mut link = PortLink::new(port);
        link.reopen().await?;
        Ok(link)
    }

    /// Where it goes.
    pub fn port(&self) -> &Port {
        &self.port
    }

    /// The direction control in force on a serial device (`None` otherwise, or while closed).
    pub fn direction(&self) -> Direction {
        match &self.inner {
            Some(Inner::Serial(s)) => s.direction(),
            _ => Direction::None,
        }
    }

    fn inner(&mut self) -> io::Result<&mut Inner> {
        let name = &self.port;
        self.inner.as_mut().ok_or_else(|| {
            io::Error::new(io::ErrorKind::NotConnected, format!("{} is not open", name.name()))
        })
    }
}

impl Link for PortLink {
    fn name(&self) -> String {
        self.port.name()
    }
    fn clock(&self) -> Clock {
        self.clock
    }
    fn is_open(&self) -> bool {
        self.inner.is_some()
    }
    async fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        match self.inner()? {
            Inner::Serial(l) => l.write(bytes).await,
            Inner::Tcp(l) => l.write(bytes).await,
            Inner::Mbap(l, framing) => {
                let frame = framing.outgoing(bytes)?;
                l.write(&frame).await
            }
            #[cfg(feature = "virtual")]
            Inner::Virtual(l) => l.write(bytes).await,
        }
    }
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self.inner()? {
            Inner::Serial(l) => l.read(buf).await,
            Inner::Tcp(l) => l.read(buf).await,
            Inner::Mbap(l, framing) => loop {
                let n = framing.take(buf);
                if n > 0 {
                    return Ok(n);
                }
                let mut frame = [0u8; 512];
                // Cancel-safe: what a read brought is in the framing before the next await.
                let got = l.read(&mut frame).await?;
                framing.incoming(&frame[..got])?;
            },
            #[cfg(feature = "virtual")]
            Inner::Virtual(l) => l.read(buf).await,
        }
    }
    async fn reopen(&mut self) -> io::Result<()> {
        // Close first: opened for exclusive use, a serial device refuses a second open.
        self.inner = None;
        let clock = self.clock;
        self.inner = Some(match open_async(&self.port).await? {
            Opened::Serial(o) => Inner::Serial(SerialLink::from_opened(o, clock)?),
            Opened::Tcp { addr, stream } => match self.port {
                Port::ModbusTcp(_) => {
                    Inner::Mbap(TcpLink::from_std(&addr, stream, clock)?, MbapFraming::new())
                }
                _ => Inner::Tcp(TcpLink::from_std(&addr, stream, clock)?),
            },
            #[cfg(feature = "virtual")]
            Opened::Virtual(v) => {
                Inner::Virtual(crate::sim_link::SimLink::with_clock(v.line, &v.name, clock))
            }
        });
        Ok(())
    }
}
