//! A bus on a Modbus TCP server (`protocol = "modbus-tcp"`): the engine's RTU frames go in MBAP,
//! an answer to another transaction is dropped, and a connection the server closed is opened
//! again and the request sent once more. The server is a script in this file, one thread, so
//! what it receives and sends is exactly what the test says.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::Duration;

use drivebus_drive::profile::Exchange;
use drivebus_link::blocking::BlockingBus;
use drivebus_link::{Bus, BusConfig, Port, PortLink, Priority};
use drivebus_proto::protocol::WireProtocol;

/// Read one holding register at 2100H of drive 1, as the profiles frame it (RTU).
fn read_request() -> Exchange {
    Exchange { request: vec![0x01, 0x03, 0x21, 0x00, 0x00, 0x01, 0x8E, 0x36], expect_reply: true }
}

/// The RTU reply the bus hands back for the value `v`.
fn rtu_reply(v: u16) -> Vec<u8> {
    let mut r = vec![0x01, 0x03, 0x02, (v >> 8) as u8, v as u8];
    r.extend_from_slice(&drivebus_proto::checksum::crc16_modbus(&r).to_le_bytes());
    r
}

/// Reads one MBAP request (12 bytes: a read of holding registers) and checks its PDU and unit.
fn request_on(s: &mut TcpStream) -> [u8; 2] {
    let mut req = [0u8; 12];
    s.read_exact(&mut req).expect("a request");
    assert_eq!(&req[2..], [0, 0, 0, 6, 1, 0x03, 0x21, 0x00, 0x00, 0x01], "MBAP, unit 1, the PDU as sent");
    [req[0], req[1]]
}

/// The MBAP answer to transaction `t` with the value `v`.
fn answer(t: [u8; 2], v: u16) -> Vec<u8> {
    vec![t[0], t[1], 0, 0, 0, 5, 1, 0x03, 0x02, (v >> 8) as u8, v as u8]
}

/// The server's script: on the first connection, the first request is answered by a stray
/// answer to another transaction and then by its own (value 111); the second request is
/// met by closing the connection. On the second connection, the request is answered (222).
/// Returns the address and the thread, which ends with the transaction ids it saw.
fn scripted_server() -> (String, std::thread::JoinHandle<Vec<u16>>) {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().unwrap().to_string();
    let server = std::thread::spawn(move || {
        let mut seen = Vec::new();
        let (mut first, _) = listener.accept().expect("the first connection");
        let t = request_on(&mut first);
        seen.push(u16::from_be_bytes(t));
        let stray = [t[0] ^ 0x80, t[1]];
        first.write_all(&answer(stray, 999)).unwrap();
        first.write_all(&answer(t, 111)).unwrap();
        let t = request_on(&mut first);
        seen.push(u16::from_be_bytes(t));
        drop(first);
        let (mut second, _) = listener.accept().expect("the connection opened again");
        let t = request_on(&mut second);
        seen.push(u16::from_be_bytes(t));
        second.write_all(&answer(t, 222)).unwrap();
        // Until the client goes.
        let _ = second.read(&mut [0u8; 16]);
        seen
    });
    (addr, server)
}

fn config() -> BusConfig {
    let mut c = BusConfig::new(WireProtocol::ModbusRtu, 9600, "8N1".parse().unwrap());
    c.modbus_tcp = true;
    c.response_timeout = Some(Duration::from_secs(10));
    c
}

#[tokio::test]
async fn the_bus_owner_drops_stray_answers_and_reopens_a_closed_connection() {
    let (addr, server) = scripted_server();
    let bus = Bus::spawn(PortLink::new(Port::ModbusTcp(addr)), config()).expect("spawn");
    let r = bus.transact(1, read_request(), Priority::Command, None).await.expect("answered");
    assert_eq!(r, Some(rtu_reply(111)), "the stray answer (999) is not taken for it");
    let r = bus.transact(1, read_request(), Priority::Command, None).await.expect("answered after a reopen");
    assert_eq!(r, Some(rtu_reply(222)));
    let stats = bus.stats();
    assert_eq!(stats.timeouts, 0, "{stats:?}");
    bus.close().await;
    let seen = server.join().expect("the script ran to its end");
    assert_eq!(seen.len(), 3);
    assert!(seen[0] != seen[1] && seen[1] != seen[2], "a transaction id per request: {seen:?}");
}

#[test]
fn the_blocking_bus_does_the_same() {
    let (addr, server) = scripted_server();
    let mut bus = BlockingBus::open(&format!("tcp://{addr}"), config()).expect("connect");
    let r = bus.transact(1, &read_request(), Priority::Command, None).expect("answered");
    assert_eq!(r, Some(rtu_reply(111)));
    let r = bus.transact(1, &read_request(), Priority::Command, None).expect("answered after a reopen");
    assert_eq!(r, Some(rtu_reply(222)));
    drop(bus);
    assert_eq!(server.join().expect("the script ran to its end").len(), 3);
}

#[test]
fn a_modbus_tcp_bus_needs_a_tcp_port() {
    match BlockingBus::open("/dev/ttyS9", config()) {
        Err(e) => assert!(e.to_string().contains("give tcp://HOST[:PORT]"), "{e}"),
        Ok(_) => panic!("a serial device is not a Modbus TCP server"),
    }
}
