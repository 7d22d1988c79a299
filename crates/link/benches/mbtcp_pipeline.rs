//! Polls per second on a Modbus TCP bus whose answers take 5 ms (a Modbus TCP/RTU gateway, a
//! drive's Ethernet card across a plant network), with one request in flight (`max_in_flight`
//! 1, the half-duplex bus owner over `MbapFraming`) and with 4 (the pipelined owner). Four drives
//! (unit ids 1..4), each polled in a loop of its own (one 03 read), for 10 s of simulated time on
//! tokio's paused clock over an in-memory connection whose server answers every request 5 ms
//! after it came, each on its own (as a gateway to several serial lines).
//!
//! Run: `cargo bench -p drivebus-link --bench mbtcp_pipeline`.
#![allow(missing_docs)]

use std::io;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use drivebus_drive::profile::Exchange;
use drivebus_link::mbap::MbapFraming;
use drivebus_link::{Bus, BusConfig, Clock, Link, Priority};
use drivebus_proto::protocol::WireProtocol;
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

const LATENCY: Duration = Duration::from_millis(5);
const DRIVES: u8 = 4;
const SECONDS: u64 = 10;

/// An in-memory connection; with `framing`, its reads and writes carry RTU frames (what the
/// half-duplex owner speaks), without it MBAP bytes (the pipelined owner's).
struct MemLink {
    stream: DuplexStream,
    framing: Option<MbapFraming>,
    clock: Clock,
}

impl Link for MemLink {
    fn name(&self) -> String {
        "mem".into()
    }
    fn clock(&self) -> Clock {
        self.clock
    }
    async fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        match self.framing.as_mut() {
            Some(f) => {
                let frame = f.outgoing(bytes)?;
                self.stream.write_all(&frame).await
            }
            None => self.stream.write_all(bytes).await,
        }
    }
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            if let Some(f) = self.framing.as_mut() {
                let n = f.take(buf);
                if n > 0 {
                    return Ok(n);
                }
            }
            let mut chunk = [0u8; 512];
            let n = self.stream.read(&mut chunk).await?;
            if n == 0 {
                return Err(io::ErrorKind::UnexpectedEof.into());
            }
            match self.framing.as_mut() {
                Some(f) => f.incoming(&chunk[..n])?,
                None => {
                    buf[..n].copy_from_slice(&chunk[..n]);
                    return Ok(n);
                }
            }
        }
    }
    async fn reopen(&mut self) -> io::Result<()> {
        Err(io::Error::other("the bench's connection is not opened again"))
    }
}

/// Answers every MBAP read on `stream` LATENCY after it came, each on its own.
async fn server(stream: DuplexStream) {
    let (mut r, w) = tokio::io::split(stream);
    let w = Arc::new(tokio::sync::Mutex::new(w));
    let mut pending = Vec::new();
    let mut buf = [0u8; 1024];
    loop {
        let Ok(n) = r.read(&mut buf).await else { return };
        if n == 0 {
            return;
        }
        pending.extend_from_slice(&buf[..n]);
        while pending.len() >= 12 {
            let f: Vec<u8> = pending.drain(..12).collect();
            let w = w.clone();
            tokio::spawn(async move {
                tokio::time::sleep(LATENCY).await;
                let answer = [f[0], f[1], 0, 0, 0, 5, f[6], 0x03, 0x02, 0x01, 0xF4];
                let _ = w.lock().await.write_all(&answer).await;
            });
        }
    }
}

fn read(unit: u8) -> Exchange {
    let mut v = vec![unit, 0x03, 0x21, 0x03, 0, 1];
    let crc = drivebus_proto::checksum::crc16_modbus(&v);
    v.extend_from_slice(&crc.to_le_bytes());
    Exchange { request: v, expect_reply: true }
}

/// Polls per second with `max_in_flight` requests in flight.
async fn polls_per_second(max_in_flight: usize) -> f64 {
    let (client, far) = tokio::io::duplex(1 << 16);
    tokio::spawn(server(far));
    let mut config = BusConfig::new(WireProtocol::ModbusRtu, 9600, "8N1".parse().unwrap());
    config.modbus_tcp = true;
    config.max_in_flight = max_in_flight;
    let clock = Clock::new();
    let bus = if max_in_flight > 1 {
        Bus::spawn_pipelined(MemLink { stream: client, framing: None, clock }, config)
    } else {
        Bus::spawn(MemLink { stream: client, framing: Some(MbapFraming::new()), clock }, config)
    }
    .expect("bus");
    let polls = Arc::new(AtomicU64::new(0));
    let end = tokio::time::Instant::now() + Duration::from_secs(SECONDS);
    let mut loops = Vec::new();
    for unit in 1..=DRIVES {
        let (bus, polls) = (bus.clone(), polls.clone());
        loops.push(tokio::spawn(async move {
            while tokio::time::Instant::now() < end {
                bus.transact(unit, read(unit), Priority::Poll, None).await.expect("answered");
                polls.fetch_add(1, Ordering::Relaxed);
            }
        }));
    }
    for l in loops {
        l.await.unwrap();
    }
    polls.load(Ordering::Relaxed) as f64 / SECONDS as f64
}

fn main() {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().start_paused(true).build().unwrap();
    println!("Modbus TCP, {DRIVES} drives, answers after {} ms, {SECONDS} s simulated:", LATENCY.as_millis());
    for n in [1, 4] {
        let rate = rt.block_on(polls_per_second(n));
        println!("  max_in_flight {n}: {rate:.0} polls/s");
    }
}
