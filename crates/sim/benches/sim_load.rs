//! Load benchmark: 32 virtual lines of 32 drives each (8 lines per family) at 115200 baud,
//! each polled as fast as the line allows by an in-process master (a `MasterSession` reading
//! one status value per drive, round robin). The whole plant runs on simulated time; the
//! figures are CPU time per simulated second (the share of one core the simulator needs to keep
//! up in real time, masters included) and resident memory per drive.
//!
//! Run: `cargo bench -p drivebus-sim --bench sim_load` (or `bench/sim_load.sh`).
//! Options through the environment: `SIM_SECONDS` (default 20).
#![allow(missing_docs)]

use std::time::Duration;

use drivebus_drive::Family;
use drivebus_proto::checksum::{crc16_modbus, xor8};
use drivebus_proto::line::CharFormat;
use drivebus_proto::session::{MasterEvent, MasterSession, Protocol, Timing};
use drivebus_proto::{b800, fc, modbus, Instant};
use drivebus_sim::bus::VirtualLine;
use drivebus_sim::config::DriveSpec;

const LINES_PER_FAMILY: usize = 8;
const DRIVES: u8 = 32;
const BAUD: u32 = 115_200;

fn rtu(addr: u8, reg: u16) -> Vec<u8> {
    let mut v = vec![addr, 0x03, (reg >> 8) as u8, reg as u8, 0, 1];
    let crc = crc16_modbus(&v);
    v.extend_from_slice(&crc.to_le_bytes());
    v
}

fn fc_read_16_13(addr: u8) -> Vec<u8> {
    // Parameter block: AK 1 read, PNU 1613 (0x64D); control word 0 (bit 10 clear: ignored).
    let mut v = vec![0x02, 0x0E, 0x80 | addr, 0x16, 0x4D, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0];
    v.push(xor8(&v));
    v
}

fn b800_status(addr: u8) -> Vec<u8> {
    let digits = format!("{:02X}54", addr as u16 + 128);
    let cs = !digits.bytes().fold(0u8, |a, b| a.wrapping_add(b));
    let mut v = vec![0x7E];
    v.extend_from_slice(digits.as_bytes());
    v.extend_from_slice(format!("{cs:02X}").as_bytes());
    v.push(0x7F);
    v
}

/// One line with its master; returns (transactions, replies).
fn run_line<P: Protocol + Default>(
    family: Family,
    protocol: Option<&str>,
    format: CharFormat,
    requests: Vec<Vec<u8>>,
    seconds: u64,
    lines: &mut Vec<VirtualLine>,
) -> (u64, u64) {
    let mut line = VirtualLine::new(BAUD, format, Instant::ZERO);
    for a in 1..=DRIVES {
        let spec = DriveSpec {
            family,
            address: a,
            protocol: protocol.map(|p: &str| p.parse().expect("a protocol")),
            response: Duration::from_millis(2),
            load: 0.5,
            params: Vec::new(),
        };
        let mut d = drivebus_sim::family::build(&spec, Instant::ZERO).expect("drive");
        d.core_mut().response_delay = spec.response;
        line.add_device(d);
    }
    let (_, t35) = drivebus_proto::line::modbus_t15_t35(BAUD);
    let timing = Timing::new(BAUD, format, Duration::from_millis(50), t35);
    let proto = P::default();
    let mut master = MasterSession::new(proto, timing);
    let end = Instant::ZERO + Duration::from_secs(seconds);
    let mut now = Instant::ZERO;
    let mut next = 0usize;
    let (mut tx, mut ok) = (0u64, 0u64);
    let mut rx = Vec::new();
    while now < end {
        if master.is_idle() {
            let bytes = &requests[next % requests.len()];
            next += 1;
            let req = master.protocol().parse_request(bytes).expect("request parses");
            master.send(now, &req).expect("idle");
        }
        if let Some(bytes) = master.poll_transmit(now) {
            let bytes = bytes.to_vec();
            line.master_write(now, &bytes);
            tx += 1;
        }
        let t = [master.poll_timeout(), line.next_deadline()].into_iter().flatten().min().unwrap_or(end);
        now = t.max(now);
        line.advance_to(now);
        rx.clear();
        line.master_read(&mut rx);
        if !rx.is_empty() {
            master.handle_input(now, &rx);
        }
        master.handle_timeout(now);
        if let Some(MasterEvent::Reply(_)) = master.poll_event() {
            ok += 1;
        }
    }
    lines.push(line);
    (tx, ok)
}

fn cpu_time() -> Duration {
    let text = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = text.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let ticks: u64 = fields.get(11).and_then(|s| s.parse().ok()).unwrap_or(0)
        + fields.get(12).and_then(|s| s.parse().ok()).unwrap_or(0);
    Duration::from_millis(ticks * 10)
}

fn rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        .unwrap_or(0)
}

fn main() {
    let seconds: u64 = std::env::var("SIM_SECONDS").ok().and_then(|s| s.parse().ok()).unwrap_or(20);
    let rss0 = rss_kib();
    let cpu0 = cpu_time();
    let wall0 = std::time::Instant::now();
    let mut lines = Vec::new();
    let mut rows = Vec::new();
    for i in 0..LINES_PER_FAMILY * 4 {
        let fam = i % 4;
        let (tx, ok) = match fam {
            0 => run_line::<modbus::rtu::ModbusRtu>(
                Family::Generic,
                Some("modbus-rtu"),
                CharFormat::NONE_8N2,
                (1..=DRIVES).map(|a| rtu(a, 0x2103)).collect(),
                seconds,
                &mut lines,
            ),
            1 => run_line::<modbus::rtu::ModbusRtu>(
                Family::Toshiba,
                Some("modbus-rtu"),
                CharFormat::EVEN_8E1,
                (1..=DRIVES).map(|a| rtu(a, 0xFD00)).collect(),
                seconds,
                &mut lines,
            ),
            2 => run_line::<fc::Fc>(
                Family::Danfoss,
                None,
                CharFormat::EVEN_8E1,
                (1..=DRIVES).map(fc_read_16_13).collect(),
                seconds,
                &mut lines,
            ),
            _ => run_line::<b800::B800>(
                Family::B800,
                None,
                CharFormat::NONE_8N1,
                (1..=DRIVES).map(b800_status).collect(),
                seconds,
                &mut lines,
            ),
        };
        rows.push((fam, tx, ok));
    }
    let cpu = cpu_time() - cpu0;
    let wall = wall0.elapsed();
    let rss = rss_kib().saturating_sub(rss0);
    let drives = (LINES_PER_FAMILY * 4) as f64 * DRIVES as f64;
    let names = ["generic (modbus-rtu)", "toshiba (modbus-rtu)", "danfoss (fc)", "b800"];
    println!(
        "sim_load: {} lines x {DRIVES} drives at {BAUD} baud, {seconds} s simulated, full polling",
        LINES_PER_FAMILY * 4
    );
    for (fam, name) in names.iter().enumerate() {
        let (tx, ok): (u64, u64) =
            rows.iter().filter(|r| r.0 == fam).fold((0, 0), |a, r| (a.0 + r.1, a.1 + r.2));
        println!(
            "  {name:22} {:>8.0} transactions/s per line, {:.2} % answered",
            tx as f64 / seconds as f64 / LINES_PER_FAMILY as f64,
            100.0 * ok as f64 / tx.max(1) as f64
        );
    }
    let core_share = cpu.as_secs_f64() / seconds as f64;
    println!("  CPU: {:.2} s for {seconds} s simulated = {:.1} % of one core in real time ({:.1} us per drive per second)", cpu.as_secs_f64(), 100.0 * core_share, 1e6 * core_share / drives);
    println!("  wall: {:.2} s", wall.as_secs_f64());
    println!(
        "  memory: {:.1} MiB resident for {drives} drives and 32 lines ({:.1} KiB per drive)",
        rss as f64 / 1024.0,
        rss as f64 / drives
    );
    drop(lines);
}
