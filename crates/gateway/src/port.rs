//! The link behind a configured bus: a serial device or a device server that may be missing at
//! start and may vanish and come back (the bus is then reported offline and reopened by the bus
//! owner). A virtual line of simulated drives in this process is [`crate::virtual_bus`].

use std::io;

use drivebus_link::drive::AnyLink;
use drivebus_link::link::{Clock, Link, SerialLink, TcpLink};
use drivebus_proto::Instant;

use crate::config::{BusConfig, Port};

/// A serial port or device server that opens lazily and reopens after it failed.
pub struct PortLink {
    port: Port,
    baud: u32,
    format: drivebus_proto::line::CharFormat,
    inner: Option<AnyLink>,
    clock: Clock,
}

impl PortLink {
    /// A link to `bus`'s port, not yet opened.
    pub fn new(bus: &BusConfig) -> Self {
        PortLink {
            port: bus.port.clone(),
            baud: bus.baud,
            format: bus.format,
            inner: None,
            clock: Clock::new(),
        }
    }

    async fn open(&mut self) -> io::Result<&mut AnyLink> {
        if self.inner.is_none() {
            let link = match &self.port {
                Port::Serial(path) => AnyLink::Serial(SerialLink::open(path, self.baud, self.format)?),
                Port::Tcp(addr) => AnyLink::Tcp(TcpLink::connect(addr).await?),
                Port::Virtual => {
                    return Err(io::Error::other("a virtual bus has no port"));
                }
            };
            self.inner = Some(link);
        }
        Ok(self.inner.as_mut().expect("opened above"))
    }
}

impl Link for PortLink {
    fn name(&self) -> String {
        self.port.to_string()
    }
    fn clock(&self) -> Clock {
        // One clock for the link's whole life: the session's time never goes back on a reopen.
        self.clock
    }
    fn now(&self) -> Instant {
        self.clock.now()
    }
    async fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        let r = self.open().await?.write(bytes).await;
        if r.is_err() {
            self.inner = None;
        }
        r
    }
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let r = self.open().await?.read(buf).await;
        if r.is_err() {
            self.inner = None;
        }
        r
    }
    async fn reopen(&mut self) -> io::Result<()> {
        self.inner = None;
        self.open().await.map(|_| ())
    }
}
