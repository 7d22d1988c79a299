//! A Modbus TCP bus with `max_in_flight` above 1 (`Bus::spawn_pipelined`), on tokio's paused
//! clock over an in-memory connection, the server a script in each test: requests to several
//! drives in flight together, answers matched by transaction id in any order, one drive's jobs
//! kept in order, a silent drive timing out alone, stray and repeated answers counted and
//! dropped, and a lost connection failing every request in flight and opened again. And
//! `open_with` (the commands' opener, `--max-in-flight`) starting this owner on a real TCP
//! connection.

use std::io;
use std::time::Duration;

use drivebus_drive::profile::Exchange;
use drivebus_link::{Bus, BusConfig, BusError, Clock, Link, Priority};
use drivebus_proto::protocol::WireProtocol;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, DuplexStream};
use tokio::sync::mpsc;

/// A link over in-memory connections: each (re)open takes the next one the test offers, and
/// fails when none is offered.
struct MemLink {
    stream: Option<DuplexStream>,
    offered: mpsc::UnboundedReceiver<DuplexStream>,
    clock: Clock,
}

impl Link for MemLink {
    fn name(&self) -> String {
        "mem".to_string()
    }
    fn clock(&self) -> Clock {
        self.clock
    }
    fn is_open(&self) -> bool {
        self.stream.is_some()
    }
    async fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        match self.stream.as_mut() {
            Some(s) => s.write_all(bytes).await,
            None => Err(io::Error::new(io::ErrorKind::NotConnected, "not open")),
        }
    }
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let Some(s) = self.stream.as_mut() else { return std::future::pending().await };
        match s.read(buf).await? {
            0 => Err(io::Error::new(io::ErrorKind::UnexpectedEof, "closed by the server")),
            n => Ok(n),
        }
    }
    async fn reopen(&mut self) -> io::Result<()> {
        self.stream = None;
        match self.offered.try_recv() {
            Ok(s) => {
                self.stream = Some(s);
                Ok(())
            }
            Err(_) => Err(io::Error::new(io::ErrorKind::ConnectionRefused, "connection refused")),
        }
    }
}

/// The server's end of a connection: whole MBAP requests in, answers out.
struct Server<S = DuplexStream> {
    stream: S,
    pending: Vec<u8>,
}

/// One request as the server sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Request {
    transaction: u16,
    unit: u8,
    register: u16,
}

impl<S: AsyncRead + AsyncWrite + Unpin> Server<S> {
    /// The next request; `None` when the client closed the connection.
    async fn request(&mut self) -> Option<Request> {
        loop {
            if self.pending.len() >= 6 {
                let total = 6 + usize::from(u16::from_be_bytes([self.pending[4], self.pending[5]]));
                if self.pending.len() >= total {
                    let f: Vec<u8> = self.pending.drain(..total).collect();
                    return Some(Request {
                        transaction: u16::from_be_bytes([f[0], f[1]]),
                        unit: f[6],
                        register: u16::from_be_bytes([f[8], f[9]]),
                    });
                }
            }
            let mut buf = [0u8; 256];
            match self.stream.read(&mut buf).await {
                Ok(0) | Err(_) => return None,
                Ok(n) => self.pending.extend_from_slice(&buf[..n]),
            }
        }
    }

    /// Answers `r` with one register holding `value`.
    async fn answer(&mut self, r: Request, value: u16) {
        let [t0, t1] = r.transaction.to_be_bytes();
        let [v0, v1] = value.to_be_bytes();
        let _ = self.stream.write_all(&[t0, t1, 0, 0, 0, 5, r.unit, 0x03, 0x02, v0, v1]).await;
    }
}

/// A bus with `max_in_flight` requests in flight, its first connection open, and where further
/// connections are offered.
fn bus(max_in_flight: usize) -> (Bus, Server, mpsc::UnboundedSender<DuplexStream>) {
    let (client, server) = tokio::io::duplex(4096);
    let (offer, offered) = mpsc::unbounded_channel();
    let link = MemLink { stream: Some(client), offered, clock: Clock::new() };
    let mut c = BusConfig::new(WireProtocol::ModbusRtu, 9600, "8N1".parse().unwrap());
    c.modbus_tcp = true;
    c.max_in_flight = max_in_flight;
    c.response_timeout = Some(Duration::from_millis(500));
    let bus = Bus::spawn_pipelined(link, c).expect("spawn");
    (bus, Server { stream: server, pending: Vec::new() }, offer)
}

/// A read of one holding register of drive `unit`, as the profiles frame it (RTU).
fn read(unit: u8, register: u16) -> Exchange {
    let [r0, r1] = register.to_be_bytes();
    let mut v = vec![unit, 0x03, r0, r1, 0, 1];
    let crc = drivebus_proto::checksum::crc16_modbus(&v);
    v.extend_from_slice(&crc.to_le_bytes());
    Exchange { request: v, expect_reply: true }
}

/// The value a read answered with.
fn value(reply: &[u8]) -> u16 {
    u16::from_be_bytes([reply[3], reply[4]])
}

/// Reads register `register` of drive `unit` on `bus` in a task of its own.
fn spawn_read(bus: &Bus, unit: u8, register: u16) -> tokio::task::JoinHandle<Result<u16, BusError>> {
    let bus = bus.clone();
    tokio::spawn(async move {
        bus.transact(unit, read(unit, register), Priority::Poll, None)
            .await
            .map(|r| value(&r.expect("a reply")))
    })
}

#[tokio::test(start_paused = true)]
async fn requests_to_four_drives_are_in_flight_together_and_answers_matched_in_any_order() {
    let (bus, mut server, _offer) = bus(4);
    let reads: Vec<_> = (1..=4).map(|u| spawn_read(&bus, u, 0x2103)).collect();
    // All four arrive before any is answered: four requests outstanding on one connection.
    let mut got = Vec::new();
    for _ in 0..4 {
        got.push(server.request().await.expect("a request"));
    }
    let mut units: Vec<u8> = got.iter().map(|r| r.unit).collect();
    units.sort_unstable();
    assert_eq!(units, [1, 2, 3, 4]);
    let mut ids: Vec<u16> = got.iter().map(|r| r.transaction).collect();
    ids.dedup();
    assert_eq!(ids.len(), 4, "a transaction id each: {got:?}");
    // Answered last first: each read gets its own drive's value.
    for r in got.iter().rev() {
        server.answer(*r, 100 + u16::from(r.unit)).await;
    }
    for (unit, read) in (1..=4u8).zip(reads) {
        assert_eq!(read.await.unwrap(), Ok(100 + u16::from(unit)), "drive {unit}");
    }
    let s = bus.stats();
    assert_eq!((s.transactions, s.replies, s.timeouts, s.stray_replies), (4, 4, 0, 0), "{s:?}");
}

#[tokio::test(start_paused = true)]
async fn one_drives_jobs_go_one_at_a_time_in_their_order() {
    let (bus, mut server, _offer) = bus(4);
    let first = spawn_read(&bus, 1, 0x0001);
    tokio::task::yield_now().await;
    let second = spawn_read(&bus, 1, 0x0002);
    tokio::task::yield_now().await;
    let other = spawn_read(&bus, 2, 0x0003);
    // Drive 1's first read and drive 2's go together; drive 1's second waits for its first.
    let a = server.request().await.unwrap();
    let b = server.request().await.unwrap();
    assert_eq!((a.unit, a.register, b.unit, b.register), (1, 1, 2, 3), "{a:?} {b:?}");
    let early = tokio::time::timeout(Duration::from_millis(100), server.request()).await;
    assert!(early.is_err(), "drive 1's second read went before its first was answered: {early:?}");
    server.answer(b, 3).await;
    server.answer(a, 1).await;
    let c = server.request().await.unwrap();
    assert_eq!((c.unit, c.register), (1, 2));
    server.answer(c, 2).await;
    assert_eq!(first.await.unwrap(), Ok(1));
    assert_eq!(second.await.unwrap(), Ok(2));
    assert_eq!(other.await.unwrap(), Ok(3));
}

#[tokio::test(start_paused = true)]
async fn a_silent_drive_times_out_alone_and_stray_or_repeated_answers_are_dropped() {
    let (bus, mut server, _offer) = bus(4);
    let silent = spawn_read(&bus, 2, 0x2103);
    let talks = spawn_read(&bus, 1, 0x2103);
    let mut silent_ids = Vec::new();
    let mut answered = None;
    // Drive 2 never answers in time: three attempts (two retries), each a new transaction id.
    while silent_ids.len() < 3 || answered.is_none() {
        let r = server.request().await.expect("a request");
        if r.unit == 2 {
            silent_ids.push(r.transaction);
        } else {
            // An answer to an id never sent, then the answer, then the same answer again.
            server.answer(Request { transaction: 0x7777, ..r }, 9).await;
            server.answer(r, 11).await;
            server.answer(r, 12).await;
            answered = Some(r);
        }
    }
    assert_eq!(talks.await.unwrap(), Ok(11));
    match silent.await.unwrap() {
        Err(BusError::Timeout { address: 2, attempts: 3, .. }) => {}
        other => panic!("{other:?}"),
    }
    silent_ids.dedup();
    assert_eq!(silent_ids.len(), 3, "{silent_ids:?}");
    // The first attempt's answer, after it timed out: stray too, not taken for the next read.
    let late = Request { transaction: silent_ids[0], unit: 2, register: 0x2103 };
    server.answer(late, 13).await;
    let again = spawn_read(&bus, 2, 0x2103);
    let r = server.request().await.unwrap();
    server.answer(r, 14).await;
    assert_eq!(again.await.unwrap(), Ok(14));
    let s = bus.stats();
    assert_eq!((s.stray_replies, s.timeouts, s.retries), (3, 3, 2), "{s:?}");
}

#[tokio::test(start_paused = true)]
async fn a_lost_connection_fails_every_request_in_flight_and_is_opened_again() {
    let (bus, mut server, offer) = bus(4);
    let reads: Vec<_> = (1..=3).map(|u| spawn_read(&bus, u, 0x2103)).collect();
    for _ in 0..3 {
        server.request().await.expect("a request");
    }
    // The server goes with three requests outstanding; the connection is offered again.
    drop(server);
    let (client, server) = tokio::io::duplex(4096);
    offer.send(client).unwrap();
    let mut server = Server { stream: server, pending: Vec::new() };
    // Each is sent again on the new connection (once: the first open went through).
    let mut again = Vec::new();
    for _ in 0..3 {
        again.push(server.request().await.expect("sent again"));
    }
    for r in &again {
        server.answer(*r, 200 + u16::from(r.unit)).await;
    }
    for (unit, read) in (1..=3u8).zip(reads) {
        assert_eq!(read.await.unwrap(), Ok(200 + u16::from(unit)), "drive {unit}");
    }
    // Lost again, and nothing offered: every request in flight fails with the link's error,
    // and until the backoff (250 ms) has passed a job fails at once, nothing opened.
    let reads: Vec<_> = (1..=2).map(|u| spawn_read(&bus, u, 0x2103)).collect();
    for _ in 0..2 {
        server.request().await.expect("a request");
    }
    drop(server);
    for read in reads {
        match read.await.unwrap() {
            Err(BusError::Link(m)) => assert!(m.contains("mem"), "{m}"),
            other => panic!("{other:?}"),
        }
    }
    let (client, server) = tokio::io::duplex(4096);
    offer.send(client).unwrap();
    let mut server = Server { stream: server, pending: Vec::new() };
    match spawn_read(&bus, 1, 0x2103).await.unwrap() {
        Err(BusError::Link(m)) => assert!(m.contains("connection refused"), "{m}"),
        other => panic!("within the backoff: {other:?}"),
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let read = spawn_read(&bus, 1, 0x2103);
    let r = server.request().await.expect("opened again after the backoff");
    server.answer(r, 7).await;
    assert_eq!(read.await.unwrap(), Ok(7));
}

/// `open_with` on a Modbus TCP port with `max_in_flight` 2 starts the pipelined owner: a server
/// on a real loopback connection receives both drives' requests before it answers either (the
/// one-at-a-time owner would send the second only after the first's answer). Real sockets and
/// the real clock: the waits are generous deadlines, nothing asserts speed.
#[tokio::test]
async fn open_with_starts_the_pipelined_owner_on_a_modbus_tcp_port_with_max_in_flight() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = format!("tcp://{}", listener.local_addr().unwrap());
    let server = tokio::spawn(async move {
        let (stream, _) = listener.accept().await.unwrap();
        let mut server = Server { stream, pending: Vec::new() };
        let a = server.request().await.expect("a request");
        let b = server.request().await.expect("a second request before any answer");
        for r in [b, a] {
            server.answer(r, 200 + u16::from(r.unit)).await;
        }
        // Keep the connection until the client is done.
        server.request().await
    });
    let mut c = BusConfig::new(WireProtocol::ModbusRtu, 9600, "8N1".parse().unwrap());
    c.modbus_tcp = true;
    c.max_in_flight = 2;
    c.retries = 0;
    c.response_timeout = Some(Duration::from_secs(30));
    let bus = drivebus_link::drive::open_with(&port, c).await.expect("open");
    let reads = [spawn_read(&bus, 1, 0x2103), spawn_read(&bus, 2, 0x2103)];
    for (unit, read) in (1..=2u8).zip(reads) {
        let got = tokio::time::timeout(Duration::from_secs(60), read).await.expect("an answer in time");
        assert_eq!(got.unwrap(), Ok(200 + u16::from(unit)), "drive {unit}");
    }
    bus.close().await;
    assert_eq!(server.await.unwrap(), None, "the client closed the connection");
}
