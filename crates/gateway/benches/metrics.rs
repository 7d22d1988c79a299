#![allow(missing_docs)] // criterion_group! generates undocumented items
//! `GET /metrics` at plant scale: the exposition of 10 000 simulated drives on 320 virtual buses
//! (115200 baud, polled every second, as bench/scale.sh's big plant), rendered in process once
//! every drive has answered so every drive series is there. The gateway keeps polling while
//! the scrapes are timed, as it does in service.
//!
//! `metrics/render_10000_drives` is the whole exposition as `GET /metrics` serves it.
//! `metrics/floor_write_the_same_lines` is its floor, measured in the same run: as many lines
//! of the same length written with `write!` into a reused buffer, reading no drive. The last
//! line printed is both timed again, interleaved, and their ratio (render / floor), the figure
//! that means something on a loaded machine.
//!
//! Run: `cargo bench -p drivebus-gateway --bench metrics`.

use std::fmt::Write as _;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use drivebus_gateway::{Gateway, GatewayConfig};

const BUSES: usize = 320;
const DRIVES: usize = 10_000;

/// The big plant's configuration: `DRIVES` generic drives spread over `BUSES` virtual buses.
fn plant() -> GatewayConfig {
    let mut toml = String::from("name = \"scale\"\n[http]\nanonymous_read = true\n");
    let mut n = 0;
    for b in 0..BUSES {
        let per = DRIVES / BUSES + usize::from(b < DRIVES % BUSES);
        let _ = write!(
            toml,
            "[[bus]]\nname = \"line-{}\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 115200\n",
            b + 1
        );
        for a in 1..=per {
            n += 1;
            let _ = write!(
                toml,
                "[[bus.drive]]\nname = \"vfd-{n}\"\nfamily = \"generic\"\naddress = {a}\npoll_ms = 1000\n"
            );
        }
    }
    GatewayConfig::from_toml("(bench plant)", &toml).unwrap_or_else(|e| panic!("{e}"))
}

fn scrape(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build().unwrap();
    let gw: Arc<Gateway> = rt.block_on(async {
        let mut config = plant();
        config.store = None;
        let gw = Gateway::start(config, None).unwrap();
        let deadline = Instant::now() + Duration::from_secs(120);
        while gw.drives().iter().any(|d| gw.drive_view(d).online != Some(true)) {
            assert!(Instant::now() < deadline, "not every drive online after 120 s");
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        gw
    });
    assert_eq!(gw.drives().len(), DRIVES);
    let _guard = rt.enter();
    let mut group = c.benchmark_group("metrics");
    group.throughput(Throughput::Elements(DRIVES as u64));
    group.sample_size(30);
    group.bench_function("render_10000_drives", |b| {
        b.iter(|| black_box(drivebus_gateway::metrics::render(&gw).unwrap()))
    });
    // The floor: as many lines of the same length written with `write!` into a reused buffer,
    // without reading any drive. On a loaded machine both move together; their ratio is the
    // figure to compare between builds.
    let text = drivebus_gateway::metrics::render(&gw).unwrap();
    let (lines, bytes) = (text.lines().count(), text.len());
    let mut buf = String::with_capacity(bytes + 4096);
    group.bench_function("floor_write_the_same_lines", |b| {
        b.iter(|| {
            buf.clear();
            floor(&mut buf, lines, bytes);
            black_box(buf.len())
        })
    });
    group.finish();

    // Both again, interleaved, so the ratio is measured under the same load.
    let (mut render, mut written) = (Duration::ZERO, Duration::ZERO);
    for _ in 0..20 {
        let t = Instant::now();
        black_box(drivebus_gateway::metrics::render(&gw).unwrap());
        render += t.elapsed();
        let t = Instant::now();
        buf.clear();
        floor(&mut buf, lines, bytes);
        black_box(buf.len());
        written += t.elapsed();
    }
    println!(
        "metrics: render {:.1} ms, floor {:.1} ms ({lines} lines, {} KiB): render / floor = {:.2}",
        render.as_secs_f64() * 1000.0 / 20.0,
        written.as_secs_f64() * 1000.0 / 20.0,
        bytes / 1024,
        render.as_secs_f64() / written.as_secs_f64()
    );
}

/// `lines` lines making about `bytes` bytes, each a series with three labels and a number
/// written with `write!`, as the least a renderer of the same text could cost.
fn floor(out: &mut String, lines: usize, bytes: usize) {
    let pad = "x".repeat((bytes / lines.max(1)).saturating_sub(60));
    for i in 0..lines {
        let _ = writeln!(
            out,
            "drivebus_drive_output_hz{{bus=\"line-{}\",drive=\"vfd-{i}\",family=\"{pad}\"}} {}",
            i % 320,
            i as f64 * 0.5
        );
    }
}

criterion_group!(benches, scrape);
criterion_main!(benches);
