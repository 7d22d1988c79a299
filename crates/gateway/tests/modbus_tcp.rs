//! The Modbus TCP server over the demo's virtual buses (real time, real sockets on 127.0.0.1):
//! the register map of every unit, writes that reach the drive and show in the cache, every
//! exception, pipelining, the parameter window, security and the connection limit.
//!
//! Waits poll with generous timeouts; nothing here depends on how fast the machine is.

mod support;

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use drivebus_drive::{Catalog, Family};
use drivebus_gateway::core::Change;
use drivebus_gateway::{Gateway, GatewayConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

const PATIENCE: Duration = Duration::from_secs(60);

async fn start(config: GatewayConfig) -> (Arc<Gateway>, SocketAddr) {
    let gw = Gateway::start(config, None).unwrap();
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(drivebus_gateway::modbus_tcp::serve(gw.clone(), listener));
    (gw, addr)
}

async fn demo() -> (Arc<Gateway>, SocketAddr) {
    start(GatewayConfig::demo()).await
}

/// A minimal Modbus TCP client.
struct Client {
    s: TcpStream,
    tid: u16,
}

/// A reply: the PDU, or an exception code.
type Reply = Result<Vec<u8>, u8>;

impl Client {
    async fn connect(addr: SocketAddr) -> Client {
        Client { s: TcpStream::connect(addr).await.unwrap(), tid: 0 }
    }

    fn frame(tid: u16, unit: u8, pdu: &[u8]) -> Vec<u8> {
        let mut f = tid.to_be_bytes().to_vec();
        f.extend_from_slice(&[0, 0]);
        f.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
        f.push(unit);
        f.extend_from_slice(pdu);
        f
    }

    async fn read_reply(&mut self) -> (u16, u8, Reply) {
        let mut h = [0u8; 7];
        tokio::time::timeout(PATIENCE, self.s.read_exact(&mut h)).await.expect("a reply in time").unwrap();
        assert_eq!(&h[2..4], &[0, 0], "protocol id");
        let len = u16::from_be_bytes([h[4], h[5]]) as usize;
        let mut pdu = vec![0u8; len - 1];
        self.s.read_exact(&mut pdu).await.unwrap();
        let tid = u16::from_be_bytes([h[0], h[1]]);
        if pdu[0] & 0x80 != 0 {
            assert_eq!(pdu.len(), 2, "exception reply {pdu:02X?}");
            return (tid, h[6], Err(pdu[1]));
        }
        (tid, h[6], Ok(pdu))
    }

    /// One request and its reply. Exception 0B (the drive did not answer in time: a loaded test
    /// machine can starve the virtual line) is retried a few times, as a SCADA master would.
    async fn call(&mut self, unit: u8, pdu: &[u8]) -> Reply {
        let mut reply = self.call_once(unit, pdu).await;
        for _ in 0..3 {
            if reply != Err(0x0B) {
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
            reply = self.call_once(unit, pdu).await;
        }
        reply
    }

    async fn call_once(&mut self, unit: u8, pdu: &[u8]) -> Reply {
        self.tid = self.tid.wrapping_add(1);
        self.s.write_all(&Self::frame(self.tid, unit, pdu)).await.unwrap();
        let (tid, u, reply) = self.read_reply().await;
        assert_eq!((tid, u), (self.tid, unit), "the reply answers the request");
        if let Ok(p) = &reply {
            assert_eq!(p[0], pdu[0], "function code");
        }
        reply
    }

    async fn read(&mut self, unit: u8, fc: u8, addr: u16, count: u16) -> Result<Vec<u16>, u8> {
        let mut pdu = vec![fc];
        pdu.extend_from_slice(&addr.to_be_bytes());
        pdu.extend_from_slice(&count.to_be_bytes());
        let p = self.call(unit, &pdu).await?;
        assert_eq!(p[1] as usize, 2 * count as usize, "byte count");
        Ok(p[2..].chunks(2).map(|c| u16::from_be_bytes([c[0], c[1]])).collect())
    }

    async fn input(&mut self, unit: u8, addr: u16, count: u16) -> Result<Vec<u16>, u8> {
        self.read(unit, 4, addr, count).await
    }

    async fn holding(&mut self, unit: u8, addr: u16, count: u16) -> Result<Vec<u16>, u8> {
        self.read(unit, 3, addr, count).await
    }

    async fn write1(&mut self, unit: u8, addr: u16, value: u16) -> Result<(), u8> {
        let mut pdu = vec![6];
        pdu.extend_from_slice(&addr.to_be_bytes());
        pdu.extend_from_slice(&value.to_be_bytes());
        let p = self.call(unit, &pdu).await?;
        assert_eq!(p, pdu, "FC06 echoes the request");
        Ok(())
    }

    async fn write(&mut self, unit: u8, addr: u16, values: &[u16]) -> Result<(), u8> {
        let mut pdu = vec![0x10];
        pdu.extend_from_slice(&addr.to_be_bytes());
        pdu.extend_from_slice(&(values.len() as u16).to_be_bytes());
        pdu.push((2 * values.len()) as u8);
        for v in values {
            pdu.extend_from_slice(&v.to_be_bytes());
        }
        let p = self.call(unit, &pdu).await?;
        assert_eq!(p, pdu[..5], "FC16 answers address and count");
        Ok(())
    }

    /// True when the server closed the connection (EOF or reset) within the patience.
    async fn closed(&mut self) -> bool {
        let mut b = [0u8; 16];
        matches!(tokio::time::timeout(PATIENCE, self.s.read(&mut b)).await, Ok(Ok(0)) | Ok(Err(_)))
    }
}

/// A wait that gives up (panics) after the patience.
struct Deadline(tokio::time::Instant);

impl Deadline {
    fn new() -> Deadline {
        Deadline(tokio::time::Instant::now() + PATIENCE)
    }

    async fn tick(&self, what: &str) {
        assert!(tokio::time::Instant::now() < self.0, "gave up waiting: {what}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

async fn all_online(addr: SocketAddr, units: u8) {
    let mut c = Client::connect(addr).await;
    let dl = Deadline::new();
    for unit in 1..=units {
        while c.input(unit, 0, 1).await.unwrap()[0] & 0x08 == 0 {
            dl.tick(&format!("unit {unit} online")).await;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_unit_shows_its_drive_from_the_cache() {
    let (gw, addr) = demo().await;
    all_online(addr, 10).await;
    let mut c = Client::connect(addr).await;
    for d in gw.drives().iter() {
        let unit = d.config.unit_id;
        let r = c.input(unit, 0, 10).await.unwrap();
        let status = r[0];
        assert_eq!(status & 0x01, 0, "{} runs", d.config.name);
        assert_ne!(status & 0x08, 0, "{} online", d.config.name);
        assert_eq!(status & 0x20 != 0, d.locked(), "{} lock bit", d.config.name);
        let family = match d.config.family {
            Family::Generic => 1,
            Family::Toshiba => 2,
            Family::Danfoss => 3,
            Family::B800 => 4,
            Family::Template(_) => 5,
        };
        assert_eq!(r[8], family, "{} family", d.config.name);
        assert_eq!(r[9], u16::from(d.config.address), "{} address", d.config.name);
        assert_eq!(r[5], 1, "{} link status", d.config.name);
        assert!(r[6] < 65535, "{} age", d.config.name);
        assert!(r[7] <= 1000, "{} error rate", d.config.name);
        // A sub-range is the same registers.
        let part = c.input(unit, 8, 2).await.unwrap();
        assert_eq!(part, r[8..10]);
    }
    assert_eq!(gw.drive("pump-3").unwrap().config.unit_id, 6);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn setpoint_and_run_reach_the_drive_and_the_cache_follows() {
    let (gw, addr) = demo().await;
    let mut changes = gw.subscribe();
    all_online(addr, 10).await;
    let mut c = Client::connect(addr).await;
    let unit = gw.drive("fan-1").unwrap().config.unit_id;
    c.write1(unit, 1, 3000).await.unwrap();
    c.write1(unit, 0, 0x0001).await.unwrap();
    // The writes were confirmed by the drive before they were answered; the cache follows.
    let dl = Deadline::new();
    loop {
        let r = c.input(unit, 0, 3).await.unwrap();
        if r[0] & 0x01 != 0 && r[2] == 3000 && r[1] > 0 {
            break;
        }
        dl.tick("fan-1 runs toward 30 Hz").await;
    }
    assert_eq!(c.holding(unit, 0, 2).await.unwrap(), vec![0x0001, 3000]);
    let v = gw.drive_view(&gw.drive("fan-1").unwrap());
    assert_eq!((v.running, v.setpoint_hz), (Some(true), Some(30.0)));
    // The audit trail names the client.
    let mut actors = Vec::new();
    while let Ok(ch) = changes.try_recv() {
        if let Change::Event(e) = ch {
            if e.drive.as_deref() == Some("fan-1") {
                actors.push((e.action.unwrap_or_default(), e.actor.unwrap_or_default()));
            }
        }
    }
    let local = c.s.local_addr().unwrap();
    let me = format!("modbus:{local}");
    assert!(actors.contains(&("speed 30 Hz".to_string(), me.clone())), "{actors:?}");
    assert!(actors.contains(&("run".to_string(), me.clone())), "{actors:?}");
    // Writing the same word again sends nothing; clearing run stops it.
    c.write(unit, 0, &[0x0001, 3000]).await.unwrap();
    c.write1(unit, 0, 0).await.unwrap();
    let dl = Deadline::new();
    while c.input(unit, 0, 1).await.unwrap()[0] & 0x01 != 0 {
        dl.tick("fan-1 stops").await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_exception_says_what_was_wrong() {
    let (gw, addr) = demo().await;
    let mut changes = gw.subscribe();
    let mut c = Client::connect(addr).await;
    // No drive with unit id 42 (nor 0).
    assert_eq!(c.input(42, 0, 1).await, Err(0x0B));
    assert_eq!(c.input(0, 0, 1).await, Err(0x0B));
    // Functions not served: read coils, write single coil, diagnostics.
    for fc in [0x01u8, 0x05, 0x08, 0x2B] {
        assert_eq!(c.call(1, &[fc, 0, 0, 0, 1]).await, Err(0x01), "FC {fc:02X}");
    }
    // Counts.
    assert_eq!(c.input(1, 0, 0).await, Err(0x03));
    assert_eq!(c.input(1, 0, 126).await, Err(0x03));
    assert_eq!(c.call(1, &[0x04, 0, 0, 0]).await, Err(0x03), "short PDU");
    assert_eq!(c.call(1, &[0x10, 0, 0, 0, 2, 3, 0, 0, 0]).await, Err(0x03), "byte count");
    // Addresses.
    assert_eq!(c.input(1, 5, 6).await, Err(0x02));
    assert_eq!(c.input(1, 10, 1).await, Err(0x02));
    assert_eq!(c.input(1, 0xFFFF, 2).await, Err(0x02));
    assert_eq!(c.holding(1, 1, 2).await, Err(0x02));
    assert_eq!(c.holding(1, 500, 1).await, Err(0x02));
    let n = Catalog::load(Family::Generic).unwrap().len() as u16;
    assert_eq!(c.holding(1, 1000 + 2 * n, 2).await, Err(0x02), "past the catalog");
    assert_eq!(c.holding(1, 1000 + 2 * n - 2, 4).await, Err(0x02), "runs past the catalog");
    assert_eq!(c.write1(1, 2, 1).await, Err(0x02));
    assert_eq!(c.write1(1, 1000, 1).await, Err(0x02), "FC06 to a high word");
    assert_eq!(c.write(1, 1001, &[0, 1]).await, Err(0x02), "a pair not aligned");
    // Values: bits the command word does not have; a speed the drive cannot do.
    assert_eq!(c.write1(1, 0, 0x0100).await, Err(0x03));
    assert_eq!(c.write1(3, 1, 50000).await, Err(0x03));
    // pump-3 is locked; the refusal is in the audit trail with the client.
    assert_eq!(c.write1(6, 0, 1).await, Err(0x01));
    assert_eq!(c.write1(6, 1, 1000).await, Err(0x01));
    let mut refused = 0;
    while let Ok(change) = changes.try_recv() {
        if let drivebus_gateway::core::Change::Event(e) = change {
            if e.drive.as_deref() == Some("pump-3") {
                assert!(e.result.as_deref().unwrap_or("").starts_with("locked: "), "{e:?}");
                assert!(e.actor.as_deref().unwrap_or("").starts_with("modbus:127.0.0.1:"), "{e:?}");
                refused += 1;
            }
        }
    }
    // The first refusal at once; the second, of the same client and reason, is counted and
    // written with the count when the minute is over (docs/gateway.md).
    assert_eq!(refused, 1, "the first refused write is audited at once");
    // The connection is still good after all of that.
    assert_eq!(c.input(1, 8, 1).await, Ok(vec![1]));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_malformed_header_closes_the_connection() {
    let (_gw, addr) = demo().await;
    for (what, header) in [
        ("protocol id 1", [0u8, 1, 0, 1, 0, 6, 1]),
        ("length 1", [0, 1, 0, 0, 0, 1, 1]),
        ("length 255", [0, 1, 0, 0, 0, 255, 1]),
    ] {
        let mut c = Client::connect(addr).await;
        c.s.write_all(&header).await.unwrap();
        c.s.write_all(&[4, 0, 0, 0, 1]).await.unwrap();
        assert!(c.closed().await, "{what}: still open");
    }
    // A good request before a bad one is answered, then the connection closes.
    let mut c = Client::connect(addr).await;
    let mut bytes = Client::frame(7, 1, &[4, 0, 8, 0, 1]);
    bytes.extend_from_slice(&[0, 8, 0, 9, 0, 6, 1, 4, 0, 0, 0, 1]);
    c.s.write_all(&bytes).await.unwrap();
    let (tid, _, reply) = c.read_reply().await;
    assert_eq!((tid, reply), (7, Ok(vec![4, 2, 0, 1])));
    assert!(c.closed().await);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pipelined_requests_are_answered_in_order() {
    let (gw, addr) = demo().await;
    all_online(addr, 10).await;
    let ahu = gw.drive("ahu-1").unwrap().config.unit_id;
    let mut c = Client::connect(addr).await;
    // Cached reads around a parameter read (which waits for the drive) and an exception.
    let mut bytes = Vec::new();
    bytes.extend(Client::frame(1, 1, &[4, 0, 8, 0, 2]));
    bytes.extend(Client::frame(2, ahu, &[3, 0x03, 0xE8, 0, 2]));
    bytes.extend(Client::frame(3, 99, &[4, 0, 0, 0, 1]));
    for tid in 4..40u16 {
        bytes.extend(Client::frame(tid, (tid % 10 + 1) as u8, &[4, 0, 9, 0, 1]));
    }
    c.s.write_all(&bytes).await.unwrap();
    let (tid, unit, r) = c.read_reply().await;
    assert_eq!((tid, unit, r), (1, 1, Ok(vec![4, 4, 0, 1, 0, 1])));
    let (tid, unit, r) = c.read_reply().await;
    assert_eq!((tid, unit), (2, ahu));
    assert_eq!(r.unwrap()[..2], [3, 4]);
    assert_eq!(c.read_reply().await, (3, 99, Err(0x0B)));
    for tid in 4..40u16 {
        let unit = (tid % 10 + 1) as u8;
        let address = gw.drive_by_unit(unit).unwrap().config.address;
        assert_eq!(c.read_reply().await, (tid, unit, Ok(vec![4, 2, 0, address])));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_parameter_window_reads_and_writes_the_drive() {
    let (gw, addr) = demo().await;
    all_online(addr, 10).await;
    let ahu = gw.drive("ahu-1").unwrap().config.unit_id;
    let catalog = Catalog::load(Family::Danfoss).unwrap();
    let i = catalog.params().iter().position(|p| p.name == "4-14").unwrap() as u16;
    let def = &catalog.params()[i as usize];
    let reg = 1000 + 2 * i;
    let mut c = Client::connect(addr).await;
    let before = gw.read_param("ahu-1", "4-14", "test").await.unwrap();
    let r = c.holding(ahu, reg, 2).await.unwrap();
    assert_eq!((i64::from(r[0]) << 16) | i64::from(r[1]), before.raw);
    // FC16, both registers: 55 Hz.
    let raw = def.to_raw(55.0).unwrap() as i32 as u32;
    c.write(ahu, reg, &[(raw >> 16) as u16, raw as u16]).await.unwrap();
    assert_eq!(gw.read_param("ahu-1", "4-14", "test").await.unwrap().value, 55.0);
    // FC06 to the low register: 52 Hz.
    let raw = def.to_raw(52.0).unwrap();
    c.write1(ahu, reg + 1, raw as u16).await.unwrap();
    assert_eq!(gw.read_param("ahu-1", "4-14", "test").await.unwrap().value, 52.0);
    // Reading the low half only, and two parameters at once.
    assert_eq!(c.holding(ahu, reg + 1, 1).await.unwrap(), vec![raw as u16]);
    let two = c.holding(ahu, reg, 4).await.unwrap();
    assert_eq!(two[..2], [0, raw as u16]);
    // Out of range for the parameter: nothing written.
    let too_much = (def.max + 1) as i32 as u32;
    assert_eq!(c.write(ahu, reg, &[(too_much >> 16) as u16, too_much as u16]).await, Err(0x03));
    assert_eq!(gw.read_param("ahu-1", "4-14", "test").await.unwrap().value, 52.0);
    // A signed 32-bit parameter (3-02, minimum reference, -4999.000..4999.000) keeps its sign.
    let k = catalog.params().iter().position(|p| p.name == "3-02").unwrap();
    let reg = 1000 + 2 * k as u16;
    let v = catalog.params()[k].to_raw(-12.5).unwrap() as i32 as u32;
    c.write(ahu, reg, &[(v >> 16) as u16, v as u16]).await.unwrap();
    assert_eq!(gw.read_param("ahu-1", "3-02", "test").await.unwrap().value, -12.5);
    let r = c.holding(ahu, reg, 2).await.unwrap();
    assert_eq!(((u32::from(r[0]) << 16) | u32::from(r[1])) as i32, -12500);
    // FC06: 16 bits, signed.
    c.write1(ahu, reg + 1, (-300i16) as u16).await.unwrap();
    assert_eq!(gw.read_param("ahu-1", "3-02", "test").await.unwrap().value, -0.3);
    // A read-only parameter (16-02) is not written.
    let k = catalog.params().iter().position(|p| p.name == "16-02").unwrap();
    assert_eq!(c.write(ahu, 1000 + 2 * k as u16, &[0, 1]).await, Err(0x02));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn writes_are_refused_by_configuration() {
    // read_only: everything but reads is refused.
    let mut config = GatewayConfig::demo();
    config.modbus.read_only = true;
    let (gw, addr) = start(config).await;
    let mut c = Client::connect(addr).await;
    assert_eq!(c.write1(3, 1, 1000).await, Err(0x01));
    assert_eq!(c.write(3, 0, &[1, 1000]).await, Err(0x01));
    assert!(c.input(3, 0, 10).await.is_ok());
    assert_eq!(gw.counters.commands_ok.load(std::sync::atomic::Ordering::Relaxed), 0);

    // allow without this client's address: reads only.
    let mut config = GatewayConfig::demo();
    config.modbus.allow = vec!["10.9.8.7".parse().unwrap()];
    let (_gw, addr) = start(config).await;
    let mut c = Client::connect(addr).await;
    assert_eq!(c.write1(3, 1, 1000).await, Err(0x01));
    assert!(c.holding(3, 0, 2).await.is_ok());

    // The default (loopback) lets this test write.
    let (_gw, addr) = demo().await;
    let mut c = Client::connect(addr).await;
    assert_eq!(c.write1(3, 1, 1000).await, Ok(()));
}

/// A flood of refused writes from one address over several connections (issue 13, defect 5):
/// every one is refused with exception 01, and the audit trail gets the first one only (the
/// count follows when the minute is over: tests/gateway.rs).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_of_refused_writes_adds_one_audit_event() {
    let mut config = GatewayConfig::demo();
    config.modbus.allow = vec!["10.9.8.7".parse().unwrap()];
    let (path, store) = support::fresh_store("modbus-flood");
    let gw = Gateway::start(config, Some(store)).unwrap();
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(drivebus_gateway::modbus_tcp::serve(gw.clone(), listener));
    let mut tasks = Vec::new();
    for _ in 0..8 {
        tasks.push(tokio::spawn(async move {
            let mut c = Client::connect(addr).await;
            for k in 0..250u16 {
                assert_eq!(c.write1(3, 1, 1000 + k).await, Err(0x01));
            }
        }));
    }
    for t in tasks {
        t.await.unwrap();
    }
    let filter = drivebus_store::EventFilter { limit: 10_000, ..Default::default() };
    let audited: Vec<_> = gw
        .store()
        .unwrap()
        .events(&filter)
        .unwrap()
        .into_iter()
        .filter(|e| e.actor.as_deref().is_some_and(|a| a.starts_with("modbus:127.0.0.1")))
        .collect();
    assert_eq!(audited.len(), 1, "{audited:?}");
    assert!(audited[0].result.as_deref().unwrap_or("").starts_with("forbidden: "), "{audited:?}");
    assert_eq!(gw.counters.commands_failed.load(std::sync::atomic::Ordering::Relaxed), 2000);
    drop(gw);
    let _ = std::fs::remove_file(&path);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_beyond_the_limit_are_closed() {
    let mut config = GatewayConfig::demo();
    config.modbus.max_connections = 2;
    let (_gw, addr) = start(config).await;
    let mut a = Client::connect(addr).await;
    let mut b = Client::connect(addr).await;
    assert!(a.input(1, 9, 1).await.is_ok());
    assert!(b.input(1, 9, 1).await.is_ok());
    let mut third = Client::connect(addr).await;
    assert!(third.closed().await, "a third connection was kept");
    drop(a);
    // Once one leaves, a new client is served again.
    let dl = Deadline::new();
    loop {
        let mut d = Client::connect(addr).await;
        d.s.write_all(&Client::frame(1, 1, &[4, 0, 9, 0, 1])).await.unwrap();
        let mut buf = [0u8; 11];
        if matches!(tokio::time::timeout(Duration::from_secs(5), d.s.read_exact(&mut buf)).await, Ok(Ok(_))) {
            break;
        }
        dl.tick("a slot frees").await;
    }
    assert!(b.input(1, 9, 1).await.is_ok());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_write_multiple_writes_then_reads() {
    let (gw, addr) = demo().await;
    all_online(addr, 10).await;
    let mut c = Client::connect(addr).await;
    // FC 23 on fan-1: write the setpoint (register 1) = 25.00 Hz, read registers 0..2.
    let p = c.call(3, &[0x17, 0, 0, 0, 2, 0, 1, 0, 1, 2, 0x09, 0xC4]).await.unwrap();
    assert_eq!(p[..2], [0x17, 4]);
    assert_eq!(u16::from_be_bytes([p[4], p[5]]), 2500);
    let dl = Deadline::new();
    while gw.drive_view(&gw.drive("fan-1").unwrap()).setpoint_hz != Some(25.0) {
        dl.tick("the cache shows fan-1's new setpoint").await;
    }
    assert_eq!(c.input(3, 2, 1).await, Ok(vec![2500]));
    // The B800 protocol has no parameter access; its jog does not exist.
    let mixer = gw.drive("mixer-1").unwrap().config.unit_id;
    assert_eq!(c.holding(mixer, 1000, 2).await, Err(0x01));
    assert_eq!(c.write1(mixer, 0, 0x0008).await, Err(0x01));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_drive_is_0b_and_a_drives_refusal_is_04() {
    let (gw, addr) = demo().await;
    all_online(addr, 10).await;
    let mut c = Client::connect(addr).await;
    let unit = |name: &str| gw.drive(name).unwrap().config.unit_id;

    // mixer-2 (B800, keypad mode F-12 = 1) told to run in reverse: it runs (run goes first on a
    // B800), then refuses the reverse with its error 93: exception 04, the drive still runs.
    let mixer = unit("mixer-2");
    assert_eq!(c.write1(mixer, 0, 3).await, Err(0x04));
    let dl = Deadline::new();
    while c.input(mixer, 0, 1).await.unwrap()[0] & 0x01 == 0 {
        dl.tick("mixer-2 running").await;
    }

    // conveyor-1 stops answering: a write that needs the drive is 0B (no answer), and the
    // setpoint is not shown as written.
    let conveyor = unit("conveyor-1");
    let bus = gw.buses().iter().find(|b| b.config.name == "line-generic").unwrap().clone();
    bus.line.as_ref().unwrap().lock().unwrap().set_silent(1, true);
    assert_eq!(c.write1(conveyor, 1, 2500).await, Err(0x0B));
    assert_ne!(c.holding(conveyor, 1, 1).await, Ok(vec![2500]), "a write nobody confirmed");
    bus.line.as_ref().unwrap().lock().unwrap().set_silent(1, false);
    assert_eq!(c.write1(conveyor, 1, 2500).await, Ok(()));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_request_does_nothing_of_what_it_asks() {
    let (gw, addr) = demo().await;
    all_online(addr, 10).await;
    let mut c = Client::connect(addr).await;
    let commands = |gw: &Gateway| gw.counters.commands_ok.load(std::sync::atomic::Ordering::Relaxed);
    let before = commands(&gw);
    let n = Catalog::load(Family::Generic).unwrap().len() as u16;
    let past = (1000 + 2 * n).to_be_bytes();
    // FC 23 writing fan-1's setpoint (25.00 Hz) with its read part past the parameter window:
    // exception 02 and no write (the whole request is checked first).
    let pdu = [0x17, past[0], past[1], 0, 2, 0, 1, 0, 1, 2, 0x09, 0xC4];
    assert_eq!(c.call(3, &pdu).await, Err(0x02));
    // The same with the read part beyond the command/setpoint pair.
    assert_eq!(c.call(3, &[0x17, 0, 1, 0, 2, 0, 1, 0, 1, 2, 0x09, 0xC4]).await, Err(0x02));
    // FC 16 of a command word with undefined bits and a setpoint: 03, the setpoint not written.
    assert_eq!(c.write(3, 0, &[0x0100, 2500]).await, Err(0x03));
    // FC 16 of two parameters whose second is out of its limits: 03, the first not written.
    assert_eq!(c.write(3, 1000, &[0, 1, 0x7FFF, 0xFFFF]).await, Err(0x03));
    assert_eq!(commands(&gw), before, "no command reached a drive");
    assert_ne!(gw.drive_view(&gw.drive("fan-1").unwrap()).setpoint_hz, Some(25.0));
}

/// A standby (`[standby]`, another gateway masters the line): every unit's status word says so
/// (bit 6), and a write is refused with exception 06 (server device busy), audited.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_standby_says_so_in_the_status_word_and_refuses_writes_with_exception_06() {
    use drivebus_gateway::modbus_tcp::map::{IN_STATUS, ST_STANDBY};
    let mut config = GatewayConfig::demo();
    // A line nobody else masters: the standby listens for twice 60 s before it takes it.
    let silence = Duration::from_secs(60);
    for b in &mut config.buses {
        b.role = Some(drivebus_link::role::RoleConfig { standby: true, silence });
    }
    let (gw, addr) = start(config).await;
    let mut events = gw.subscribe();
    let mut c = Client::connect(addr).await;
    for unit in 1..=10 {
        let word = c.input(unit, IN_STATUS, 1).await.unwrap()[0];
        assert_ne!(word & ST_STANDBY, 0, "unit {unit}: status word {word:#06X}");
    }
    assert_eq!(c.write1(3, 1, 1000).await, Err(0x06));
    assert_eq!(c.write(3, 0, &[1, 1000]).await, Err(0x06));
    let refused = tokio::time::timeout(PATIENCE, async {
        loop {
            if let Ok(Change::Event(e)) = events.recv().await {
                if e.actor.as_deref().is_some_and(|a| a.starts_with("modbus:")) {
                    return e;
                }
            }
        }
    })
    .await
    .expect("the refusal audited");
    assert!(refused.result.as_deref().unwrap().starts_with("standby: "), "{refused:?}");
    assert_eq!(gw.counters.commands_ok.load(std::sync::atomic::Ordering::Relaxed), 0);
}
