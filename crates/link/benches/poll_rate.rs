//! Poll rate and bus utilization of the bus owner: 8 generic drives (Modbus RTU) on the paced
//! virtual line, polled round robin (one 03 read of 2103H each) for 60 s of simulated time on
//! tokio's paused clock, at 9600 and 115200 baud, against the wire-time limit:
//!
//!   limit = 1 / (request wire time + drive response time + reply wire time + t3.5 gap)
//!
//! Run: `cargo bench -p drivebus-link --bench poll_rate` (or `bench/poll_rate.sh`).
//!
//! Then the same in real time (10 s per baud rate), where the bus owner and `SimLink` wait with
//! `drivebus_link::timer` (deadlines to the microsecond) rather than tokio's millisecond timer.
//! On the paused clock there is no wall time and tokio's timer is used: each wait there ends on
//! the next whole simulated millisecond, which is what the first figures show.
#![allow(missing_docs)]

use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_drive::profile::Exchange;
use drivebus_drive::Family;
use drivebus_link::{Bus, BusConfig, Priority, SimLink};
use drivebus_proto::checksum::crc16_modbus;
use drivebus_proto::line::{modbus_t15_t35, CharFormat};
use drivebus_proto::Instant;
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::config::DriveSpec;

const DRIVES: u8 = 8;
const RESPONSE: Duration = Duration::from_millis(2);
const SECONDS: u64 = 60;
const REAL_SECONDS: u64 = 10;

fn read(addr: u8) -> Exchange {
    let mut v = vec![addr, 0x03, 0x21, 0x03, 0, 1];
    let crc = crc16_modbus(&v);
    v.extend_from_slice(&crc.to_le_bytes());
    Exchange { request: v, expect_reply: true }
}

async fn run(baud: u32, seconds: u64) -> (f64, f64, f64) {
    let format = CharFormat::NONE_8N2;
    let mut line = VirtualLine::new(baud, format, Instant::ZERO);
    for a in 1..=DRIVES {
        let spec = DriveSpec {
            family: Family::Generic,
            address: a,
            protocol: Some(drivebus_proto::protocol::WireProtocol::ModbusRtu),
            response: RESPONSE,
            load: 0.5,
            params: Vec::new(),
        };
        let mut d = drivebus_sim::family::build(&spec, Instant::ZERO).expect("drive");
        d.core_mut().response_delay = RESPONSE;
        line.add_device(d);
    }
    let line = Arc::new(Mutex::new(line));
    let bus = Bus::spawn(
        SimLink::new(line, "virtual"),
        BusConfig::new(drivebus_proto::protocol::WireProtocol::ModbusRtu, baud, format),
    )
    .expect("bus");
    let start = tokio::time::Instant::now();
    let mut n = 0u64;
    while start.elapsed() < Duration::from_secs(seconds) {
        for a in 1..=DRIVES {
            bus.transact(a, read(a), Priority::Poll, None).await.expect("reply");
            n += 1;
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    let tps = n as f64 / elapsed;
    let char_s = format.char_time(baud).as_secs_f64();
    let (_, t35) = modbus_t15_t35(baud);
    // 8-byte request, 7-byte reply.
    let per = 8.0 * char_s + RESPONSE.as_secs_f64() + 7.0 * char_s + t35.as_secs_f64();
    let limit = 1.0 / per;
    (tps, limit, bus.stats().utilization())
}

fn main() {
    let paused = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .expect("runtime");
    let real = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
    println!(
        "poll_rate: {DRIVES} generic drives, Modbus RTU 8N2, 03 read of one register, drive response {} ms",
        RESPONSE.as_millis()
    );
    for (clock, rt, seconds) in [("simulated", &paused, SECONDS), ("real-time", &real, REAL_SECONDS)] {
        println!("  {clock} clock, {seconds} s per baud rate:");
        for baud in [9600, 115_200] {
            let wall = std::time::Instant::now();
            let (tps, limit, util) = rt.block_on(run(baud, seconds));
            println!(
                "  {baud:>6} baud: {tps:7.1} transactions/s, limit {limit:7.1}/s = {:.1} % of the limit; line utilization {:.1} % (wall {:.2} s)",
                100.0 * tps / limit,
                100.0 * util,
                wall.elapsed().as_secs_f64()
            );
        }
    }
}
