#![allow(missing_docs)] // criterion_group! generates undocumented items
//! `GET /metrics` at plant scale: the exposition of 10 000 simulated drives on 320 virtual buses
//! (115200 baud, polled every second, as bench/scale.sh's big plant), rendered in process once
//! every drive has answered so every drive series is there. The gateway keeps polling while
//! the scrapes are timed, as it does in service.
//!
//! `metrics/render_10000_drives` is the whole exposition as `GET /metrics` serves it.
//! `metrics/drive_series_written_by_hand_10000_drives` is the alternative its design was
//! measured against: the nine drive families (nine tenths of the text) written straight into a
//! reused buffer with `itoa`/`dtoa`, as prometheus-client formats numbers, without the library's
//! encoder.
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
    let mut buf = String::new();
    group.bench_function("drive_series_written_by_hand_10000_drives", |b| {
        b.iter(|| {
            buf.clear();
            drive_series_by_hand(&gw, &mut buf);
            black_box(buf.len())
        })
    });
    group.finish();
}

/// The drive families of the exposition written by hand: one pass per family over a snapshot
/// of the drives, as the collector does, numbers formatted with itoa and dtoa.
fn drive_series_by_hand(gw: &Gateway, out: &mut String) {
    struct Row<'a> {
        bus: &'a str,
        drive: &'a str,
        family: &'a str,
        values: [Option<f64>; 6],
        counts: [u64; 2],
        fault: Option<u32>,
    }
    let drives = gw.drives();
    let rows: Vec<Row> = drives
        .iter()
        .map(|d| {
            d.with_state(|s| {
                let st = s.status.as_ref();
                Row {
                    bus: &d.bus,
                    drive: &d.config.name,
                    family: d.config.family.as_str(),
                    values: [
                        st.and_then(|x| x.output_hz),
                        s.setpoint_hz(),
                        st.and_then(|x| x.current_a),
                        st.map(|x| f64::from(u8::from(x.running))),
                        s.online.map(|o| f64::from(u8::from(o))),
                        s.updated.map(|t| t.elapsed().as_secs_f64()),
                    ],
                    counts: [s.polls, s.poll_errors],
                    fault: (s.online.is_some() || st.is_some())
                        .then(|| st.and_then(|x| x.fault.as_ref()).map_or(0, |f| f.code)),
                }
            })
        })
        .collect();
    let gauges = ["output_hz", "setpoint_hz", "current_a", "running", "online", "data_age_seconds"];
    for (i, name) in gauges.iter().enumerate() {
        let _ = write!(out, "# HELP drivebus_drive_{name} help.\n# TYPE drivebus_drive_{name} gauge\n");
        for r in rows.iter() {
            let Some(v) = r.values[i] else { continue };
            let _ = write!(
                out,
                "drivebus_drive_{name}{{bus=\"{}\",drive=\"{}\",family=\"{}\"}} ",
                r.bus, r.drive, r.family
            );
            out.push_str(dtoa::Buffer::new().format(v));
            out.push('\n');
        }
    }
    let _ = write!(out, "# HELP drivebus_drive_fault_code help.\n# TYPE drivebus_drive_fault_code gauge\n");
    for r in rows.iter() {
        let Some(code) = r.fault else { continue };
        let _ = write!(
            out,
            "drivebus_drive_fault_code{{bus=\"{}\",drive=\"{}\",family=\"{}\"}} ",
            r.bus, r.drive, r.family
        );
        out.push_str(itoa::Buffer::new().format(code));
        out.push('\n');
    }
    for (i, name) in ["polls", "poll_errors"].iter().enumerate() {
        let _ = write!(out, "# HELP drivebus_drive_{name} help.\n# TYPE drivebus_drive_{name} counter\n");
        for r in rows.iter() {
            let _ = write!(
                out,
                "drivebus_drive_{name}_total{{bus=\"{}\",drive=\"{}\",family=\"{}\"}} ",
                r.bus, r.drive, r.family
            );
            out.push_str(itoa::Buffer::new().format(r.counts[i]));
            out.push('\n');
        }
    }
}

criterion_group!(benches, scrape);
criterion_main!(benches);
