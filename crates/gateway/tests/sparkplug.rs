//! The Sparkplug edge node in process, on an embedded broker (rumqttd): a reload that adds and
//! removes drives brings their DBIRTH and DDEATH (a new bus, a rebirth), the store-and-forward
//! queue stays within its limit, dropping the oldest and counting them, and the primary host
//! going offline brings the NDEATH and a new session whose births wait for the host, then the
//! data kept meanwhile, historical and in order. The specification's assertions one by one are
//! in sparkplug_conformance.rs.
//! The interop with a Sparkplug host nobody here wrote is in crates/cli/tests/sparkplug.rs.

mod mqtt_support;
mod support;

use std::net::SocketAddr;

use drivebus_gateway::config::SparkplugConfig;
use drivebus_gateway::sparkplug::payload::{self, DataType, Payload};
use drivebus_gateway::{Command, Gateway, GatewayConfig};
use mqtt_support::{rumqttd, Msg, Subscriber, PATIENCE};

fn drive(name: &str, address: u8) -> String {
    format!("[[bus.drive]]\nname = \"{name}\"\nfamily = \"generic\"\naddress = {address}\npoll_ms = 100\n")
}

fn bus(name: &str, drives: &[(&str, u8)]) -> String {
    let mut s =
        format!("[[bus]]\nname = \"{name}\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n");
    for (d, a) in drives {
        s.push_str(&drive(d, *a));
    }
    s
}

fn config(name: &str, buses: &str) -> GatewayConfig {
    GatewayConfig::from_toml("plant.toml", &format!("name = \"{name}\"\n[store]\ndisabled = true\n{buses}"))
        .unwrap()
}

fn sparkplug(broker: SocketAddr) -> SparkplugConfig {
    SparkplugConfig::new(&format!("mqtt://{broker}"))
}

fn decoded(m: &Msg) -> Payload {
    payload::decode(&m.payload).unwrap()
}

/// `(kind, device)` of a Sparkplug topic of edge node `edge`.
fn kind<'a>(m: &'a Msg, edge: &str) -> Option<(&'a str, Option<&'a str>)> {
    let mut it = m.topic.split('/');
    let (_, _, kind, e) = (it.next()?, it.next()?, it.next()?, it.next()?);
    (e == edge).then_some((kind, it.next()))
}

/// Every seq from the last NBIRTH on follows the one before.
fn assert_seq_continues(log: &[Msg], edge: &str) {
    let from = log.iter().rposition(|m| kind(m, edge).is_some_and(|(k, _)| k == "NBIRTH")).unwrap();
    let seqs: Vec<u64> = log[from..]
        .iter()
        .filter(|m| kind(m, edge).is_some_and(|(k, _)| k != "NDEATH" && !k.ends_with("CMD")))
        .map(|m| decoded(m).seq.unwrap())
        .collect();
    assert_eq!(seqs[0], 0);
    assert!(seqs.windows(2).all(|w| w[1] == (w[0] + 1) % 256), "{seqs:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reload_brings_dbirth_for_added_drives_ddeath_for_removed_ones_and_a_rebirth_for_a_new_bus() {
    let broker = rumqttd().await;
    let sub = Subscriber::start(broker, "host", "spBv1.0/#").await;
    let gw = Gateway::start(config("hall-r", &bus("line-1", &[("d1", 1), ("d2", 2)])), None).unwrap();
    drivebus_gateway::sparkplug::spawn(gw.clone(), &sparkplug(broker)).unwrap();
    let born = |log: &[Msg], d: &str, from: usize| {
        log[from..].iter().any(|m| kind(m, "hall-r") == Some(("DBIRTH", Some(d))))
    };
    sub.wait("d1 and d2 born", |log| (born(log, "d1", 0) && born(log, "d2", 0)).then_some(())).await;

    let mark = sub.log.lock().unwrap().len();
    gw.reload(config("hall-r", &bus("line-1", &[("d1", 1), ("d3", 3)])), "test").await.unwrap();
    sub.wait("d2's DDEATH and d3's DBIRTH", |log| {
        let dead = log[mark..].iter().any(|m| kind(m, "hall-r") == Some(("DDEATH", Some("d2"))));
        (dead && born(log, "d3", mark)).then_some(())
    })
    .await;
    {
        let log = sub.log.lock().unwrap();
        assert!(
            !log[mark..].iter().any(|m| kind(m, "hall-r").is_some_and(|(k, _)| k == "NBIRTH")),
            "no rebirth for drives"
        );
        assert_seq_continues(&log, "hall-r");
    }

    let mark = sub.log.lock().unwrap().len();
    let two = format!("{}{}", bus("line-1", &[("d1", 1), ("d3", 3)]), bus("line-2", &[("d4", 1)]));
    gw.reload(config("hall-r", &two), "test").await.unwrap();
    sub.wait("a rebirth with the new bus", |log| {
        let nbirth = log[mark..].iter().find(|m| kind(m, "hall-r").is_some_and(|(k, _)| k == "NBIRTH"))?;
        let p = decoded(nbirth);
        let has_bus = p.metrics.iter().any(|m| m.name.as_deref() == Some("Buses/line-2/Online"));
        (has_bus && ["d1", "d3", "d4"].iter().all(|d| born(log, d, mark))).then_some(())
    })
    .await;
    assert_seq_continues(&sub.log.lock().unwrap(), "hall-r");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_store_and_forward_queue_keeps_the_newest_within_its_limit() {
    let broker = rumqttd().await;
    let dir = std::env::temp_dir().join(format!("drivebus-sparkplug-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let db = dir.join("limit.db");
    let _ = std::fs::remove_file(&db);
    let store = drivebus_store::Store::open(&db).unwrap();
    let gw = Gateway::start(config("hall-q", &bus("line-1", &[("d1", 1)])), Some(store.clone())).unwrap();
    let mut sp = sparkplug(broker);
    sp.primary_host = Some("scada".into());
    sp.store_forward_max = 5;
    drivebus_gateway::sparkplug::spawn(gw.clone(), &sp).unwrap();
    gw.command("d1", Command::Speed(50.0), "test").await.unwrap();
    gw.command("d1", Command::Run, "test").await.unwrap();
    let metrics = drivebus_gateway::sparkplug::metrics(&gw);
    let start = std::time::Instant::now();
    while metrics.stored() < 20 || metrics.queued() != 5 {
        assert!(start.elapsed() < PATIENCE, "stored {} queued {}", metrics.stored(), metrics.queued());
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    assert!(metrics.dropped() >= 15, "dropped {}", metrics.dropped());
    assert_eq!(store.spool_len("drivebus/hall-q").unwrap(), 5);
    // Nothing was published: the primary host never said online.
    let sub = Subscriber::start(broker, "scada", "spBv1.0/#").await;
    assert_eq!(metrics.messages("nbirth"), 0);
    let newest = store.spool_peek("drivebus/hall-q", 5).unwrap();
    sub.publish("spBv1.0/STATE/scada", r#"{"online": true, "timestamp": 1}"#, true).await;
    let kept = sub
        .wait("the kept data, historical", |log| {
            let hist: Vec<Payload> = log
                .iter()
                .filter(|m| kind(m, "hall-q") == Some(("DDATA", Some("d1"))))
                .map(decoded)
                .filter(|p| p.metrics.iter().all(|m| m.is_historical == Some(true)))
                .collect();
            (hist.len() >= newest.len()).then_some(hist)
        })
        .await;
    // In order, and none of those dropped before: nothing older than the oldest kept then.
    let times: Vec<i64> = kept.iter().map(|p| p.timestamp.unwrap() as i64).collect();
    assert!(times.windows(2).all(|w| w[0] <= w[1]), "{times:?}");
    assert!(times.iter().all(|t| *t >= newest[0].time_ms), "{times:?} {newest:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// 200 DCMDs (Run, Stop and a Setpoint in turn) published in one burst are carried out in the
/// order published: the audit trail lists them so, and the drive ends stopped at the last
/// setpoint. (Each DCMD used to start a task of its own, which could reach the drive in any order.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_dcmds_is_carried_out_in_the_order_published() {
    use prost::Message;

    let broker = rumqttd().await;
    let dir = std::env::temp_dir().join(format!("drivebus-sparkplug-order-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let db = dir.join("order.db");
    let _ = std::fs::remove_file(&db);
    let store = drivebus_store::Store::open(&db).unwrap();
    let gw = Gateway::start(config("hall-o", &bus("line-1", &[("d1", 1)])), Some(store.clone())).unwrap();
    let sub = Subscriber::start(broker, "host", "spBv1.0/#").await;
    let mut sp = sparkplug(broker);
    sp.commands = true;
    drivebus_gateway::sparkplug::spawn(gw.clone(), &sp).unwrap();
    sub.wait("d1 born", |log| {
        log.iter().any(|m| kind(m, "hall-o") == Some(("DBIRTH", Some("d1")))).then_some(())
    })
    .await;

    let metric = |name: &str, datatype: payload::DataType, value: payload::Value| payload::Metric {
        name: Some(name.to_string()),
        datatype: Some(datatype as u32),
        value: Some(value),
        ..Default::default()
    };
    let mut want = Vec::new();
    for i in 0..200u32 {
        let (m, action) = match i % 3 {
            0 => (
                metric("Command/Run", payload::DataType::Boolean, payload::Value::Boolean(true)),
                "run".into(),
            ),
            1 => (
                metric("Command/Stop", payload::DataType::Boolean, payload::Value::Boolean(true)),
                "stop".into(),
            ),
            _ => {
                let hz = f64::from(i) / 4.0;
                let m = metric("Setpoint", payload::DataType::Double, payload::Value::Double(hz));
                (m, Command::Speed(hz).action())
            }
        };
        want.push(action);
        let p = Payload { timestamp: Some(1), metrics: vec![m], seq: Some(0), ..Default::default() };
        sub.client
            .publish("spBv1.0/drivebus/DCMD/hall-o/d1", rumqttc::QoS::AtLeastOnce, false, p.encode_to_vec())
            .await
            .unwrap();
    }
    assert_eq!(want.last().map(String::as_str), Some("stop"));

    let filter = drivebus_store::EventFilter {
        drive: Some("d1".into()),
        kind: Some(drivebus_store::EventKind::Command),
        ..Default::default()
    };
    let start = std::time::Instant::now();
    let done = loop {
        let events = store.events(&filter).unwrap();
        let done: Vec<_> =
            events.iter().filter(|e| e.result.as_deref() != Some(drivebus_store::PENDING)).collect();
        if done.len() >= want.len() {
            break events;
        }
        assert!(start.elapsed() < PATIENCE * 2, "{} of {} carried out", done.len(), want.len());
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    };
    let audited: Vec<&str> = done.iter().map(|e| e.action.as_deref().unwrap()).collect();
    assert_eq!(audited, want);
    for e in &done {
        assert_eq!(e.actor.as_deref(), Some("sparkplug:drivebus/hall-o"), "{e:?}");
        assert_eq!(e.result.as_deref(), Some("ok"), "{e:?}");
    }
    // The drive ends stopped, at the last setpoint commanded.
    let d = gw.drive("d1").unwrap();
    let start = std::time::Instant::now();
    while gw.drive_view(&d).running != Some(false) {
        assert!(start.elapsed() < PATIENCE, "{:?}", gw.drive_view(&d));
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    assert_eq!(gw.drive_view(&d).setpoint_hz, Some(f64::from(197u32) / 4.0));
    let _ = std::fs::remove_dir_all(&dir);
}

fn bd_seq(p: &Payload) -> Option<u64> {
    p.metrics.iter().find(|m| m.name.as_deref() == Some("bdSeq")).and_then(|m| match m.value {
        Some(payload::Value::Long(b)) => Some(b),
        _ => None,
    })
}

/// `OutputFrequency` of d1 in a DDATA (by the alias of the last DBIRTH before it), and whether
/// the DDATA is historical.
fn output_hz(log: &[Msg], at: usize) -> Option<(f64, bool)> {
    if kind(&log[at], "hall-h") != Some(("DDATA", Some("d1"))) {
        return None;
    }
    let birth = log[..at].iter().rposition(|m| kind(m, "hall-h") == Some(("DBIRTH", Some("d1"))))?;
    let alias =
        decoded(&log[birth]).metrics.iter().find(|m| m.name.as_deref() == Some("OutputFrequency"))?.alias;
    decoded(&log[at]).metrics.iter().find(|m| m.alias == alias).and_then(|m| match m.value {
        Some(payload::Value::Double(hz)) => Some((hz, m.is_historical == Some(true))),
        _ => None,
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_primary_host_offline_brings_the_ndeath_a_new_session_and_the_kept_data_when_it_is_back() {
    let broker = rumqttd().await;
    let dir = std::env::temp_dir().join(format!("drivebus-sparkplug-host-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let db = dir.join("host.db");
    let _ = std::fs::remove_file(&db);
    let store = drivebus_store::Store::open(&db).unwrap();
    let gw = Gateway::start(config("hall-h", &bus("line-1", &[("d1", 1)])), Some(store)).unwrap();
    let host = Subscriber::start(broker, "scada", "spBv1.0/#").await;
    host.publish("spBv1.0/STATE/scada", r#"{"online": true, "timestamp": 1}"#, true).await;
    let mut sp = sparkplug(broker);
    sp.primary_host = Some("scada".into());
    drivebus_gateway::sparkplug::spawn(gw.clone(), &sp).unwrap();
    let first = host
        .wait("the births", |log| {
            let at = log.iter().position(|m| kind(m, "hall-h") == Some(("NBIRTH", None)))?;
            log[at..]
                .iter()
                .any(|m| kind(m, "hall-h") == Some(("DBIRTH", Some("d1"))))
                .then(|| decoded(&log[at]))
        })
        .await;
    let bd = bd_seq(&first).unwrap();

    // The host goes offline: the node's NDEATH, with the session's bdSeq.
    let mark = host.log.lock().unwrap().len();
    host.publish("spBv1.0/STATE/scada", r#"{"online": false, "timestamp": 2}"#, true).await;
    let death = host
        .wait("the NDEATH", |log| {
            log[mark..].iter().find(|m| kind(m, "hall-h") == Some(("NDEATH", None))).cloned()
        })
        .await;
    assert_eq!(bd_seq(&decoded(&death)), Some(bd));
    let metrics = drivebus_gateway::sparkplug::metrics(&gw);
    assert_eq!(metrics.messages("ndeath"), 1);

    // d1 ramps to 40 Hz while nobody listens: kept.
    gw.command("d1", Command::Speed(40.0), "test").await.unwrap();
    gw.command("d1", Command::Run, "test").await.unwrap();
    let d1 = gw.drive("d1").unwrap();
    let start = std::time::Instant::now();
    // And a new MQTT session, which waits for the host: nothing is published.
    while (gw.drive_view(&d1).output_hz.unwrap_or(0.0) - 40.0).abs() > 0.05
        || metrics.stored() < 3
        || metrics.connections() < 2
    {
        assert!(
            start.elapsed() < PATIENCE,
            "d1 at {:?} Hz, {} kept, {} sessions",
            gw.drive_view(&d1).output_hz,
            metrics.stored(),
            metrics.connections()
        );
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    let away = host.log.lock().unwrap().len();
    // A DDATA sent before the node read the offline STATE came while the host was online: look
    // from the NDEATH on.
    let died = mark
        + host.log.lock().unwrap()[mark..]
            .iter()
            .position(|m| kind(m, "hall-h") == Some(("NDEATH", None)))
            .unwrap();
    assert!(
        host.log.lock().unwrap()[died..away]
            .iter()
            .all(|m| kind(m, "hall-h").map_or(true, |(k, _)| k == "NDEATH" || k.ends_with("CMD"))),
        "published while the host was offline"
    );

    // Back: births with the next bdSeq, then the ramp, historical and in order, then live data.
    host.publish("spBv1.0/STATE/scada", r#"{"online": true, "timestamp": 3}"#, true).await;
    let back = host
        .wait("births with the next bdSeq", |log| {
            let at = away + log[away..].iter().position(|m| kind(m, "hall-h") == Some(("NBIRTH", None)))?;
            Some((at, bd_seq(&decoded(&log[at]))?))
        })
        .await;
    assert_eq!(back.1, (bd + 1) % 256);
    let back = back.0;
    host.wait("the kept ramp up to 40 Hz", |log| {
        (back..log.len())
            .any(|i| output_hz(log, i).is_some_and(|(hz, h)| h && (hz - 40.0).abs() < 0.05))
            .then_some(())
    })
    .await;
    gw.command("d1", Command::Speed(35.0), "test").await.unwrap();
    host.wait("live data after the kept", |log| {
        (back..log.len()).any(|i| output_hz(log, i).is_some_and(|(_, h)| !h)).then_some(())
    })
    .await;
    let log = host.log.lock().unwrap().clone();
    let ddata: Vec<usize> =
        (back..log.len()).filter(|i| kind(&log[*i], "hall-h") == Some(("DDATA", Some("d1")))).collect();
    let historical = |i: &usize| decoded(&log[*i]).metrics.iter().all(|m| m.is_historical == Some(true));
    let split = ddata.iter().position(|i| !historical(i)).unwrap();
    assert!(ddata[split..].iter().all(|i| !historical(i)), "historical data after live data");
    let times: Vec<u64> = ddata[..split].iter().map(|i| decoded(&log[*i]).timestamp.unwrap()).collect();
    assert!(times.windows(2).all(|w| w[0] <= w[1]), "kept data out of order: {times:?}");
    let ramp: Vec<f64> =
        ddata[..split].iter().filter_map(|i| output_hz(&log, *i)).map(|(hz, _)| hz).collect();
    assert!(ramp.len() >= 3 && ramp.windows(2).all(|w| w[0] <= w[1]), "the ramp, in order: {ramp:?}");
    assert_seq_continues(&log, "hall-h");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A drive of a shipped template kind (`generic-2000h`) is a Sparkplug device like any other:
/// its DBIRTH carries the status metrics and its parameters by the template's names, and a new
/// setpoint shows in its DDATA.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_templated_drive_is_born_with_its_status_and_parameters() {
    let broker = rumqttd().await;
    let sub = Subscriber::start(broker, "host", "spBv1.0/#").await;
    let text = "[[bus]]\nname = \"line-t\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
                [[bus.drive]]\nname = \"tpl\"\nfamily = \"generic-2000h\"\naddress = 1\npoll_ms = 100\n";
    let gw = Gateway::start(config("hall-t", text), None).unwrap();
    drivebus_gateway::sparkplug::spawn(gw.clone(), &sparkplug(broker)).unwrap();
    let birth = sub
        .wait("tpl's DBIRTH", |log| {
            log.iter().find(|m| kind(m, "hall-t") == Some(("DBIRTH", Some("tpl")))).map(decoded)
        })
        .await;
    let metric = |name: &str| birth.metrics.iter().find(|m| m.name.as_deref() == Some(name));
    for (name, _, _) in drivebus_gateway::sparkplug::node::STATUS_METRICS {
        assert!(metric(name).is_some(), "{name} in {:?}", birth.metrics);
    }
    // The template's parameters, by its names (P0.04: the maximum frequency, in Hz).
    let p004 = metric("Parameters/P0.04").expect("a parameter of the template");
    assert_eq!(p004.datatype, Some(DataType::Double as u32), "{p004:?}");
    // A new setpoint shows in a DDATA.
    gw.command("tpl", Command::Speed(12.5), "test").await.expect("speed");
    sub.wait("tpl's setpoint in a DDATA", |log| {
        log.iter()
            .filter(|m| kind(m, "hall-t") == Some(("DDATA", Some("tpl"))))
            .any(|m| {
                decoded(m)
                    .metrics
                    .iter()
                    .any(|x| matches!(x.value, Some(payload::Value::Double(hz)) if hz == 12.5))
            })
            .then_some(())
    })
    .await;
}

/// A template's `[values]` are metrics of its device: `Values/<name>`, Double, with the value's
/// unit (`engUnit`) and its reading in the DBIRTH, then in DDATA by alias as it changes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_templates_named_values_are_metrics_in_dbirth_and_ddata() {
    let broker = rumqttd().await;
    let sub = Subscriber::start(broker, "host", "spBv1.0/#").await;
    let text = "name = \"hall-v\"\ntemplates = [\"bits.toml\"]\n[store]\ndisabled = true\n\
                [[bus]]\nname = \"line-v\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\n\
                [[bus.drive]]\nname = \"fan\"\nfamily = \"gw-bits\"\naddress = 1\npoll_ms = 100\n";
    let (_, config) = support::with_bits_template("sparkplug-values", text);
    let gw = Gateway::start(config, None).unwrap();
    drivebus_gateway::sparkplug::spawn(gw.clone(), &sparkplug(broker)).unwrap();
    let birth = sub
        .wait("fan's DBIRTH", |log| {
            log.iter().find(|m| kind(m, "hall-v") == Some(("DBIRTH", Some("fan")))).map(decoded)
        })
        .await;
    let metric = |name: &str| birth.metrics.iter().find(|m| m.name.as_deref() == Some(name)).cloned();
    let unit = |m: &payload::Metric| {
        let p = m.properties.as_ref()?;
        let at = p.keys.iter().position(|k| k == "engUnit")?;
        match &p.values[at].value {
            Some(payload::PropertyValueKind::String(s)) => Some(s.clone()),
            _ => None,
        }
    };
    let dc = metric("Values/dc_bus_v").unwrap_or_else(|| panic!("Values/dc_bus_v in {:?}", birth.metrics));
    assert_eq!(dc.datatype, Some(DataType::Double as u32), "{dc:?}");
    assert_eq!(unit(&dc).as_deref(), Some("V"), "{dc:?}");
    // Its reading: in the DBIRTH when the drive had answered, else (born null) in a DDATA.
    let dc_alias = dc.alias.expect("an alias");
    let simulated = |m: &payload::Metric| matches!(m.value, Some(payload::Value::Double(v)) if (400.0..700.0).contains(&v));
    assert!(simulated(&dc) || dc.is_null == Some(true), "{dc:?}");
    sub.wait("the simulated DC bus", |log| {
        let data = log.iter().filter(|m| kind(m, "hall-v") == Some(("DDATA", Some("fan")))).map(decoded);
        (simulated(&dc)
            || data.into_iter().any(|p| p.metrics.iter().any(|x| x.alias == Some(dc_alias) && simulated(x))))
        .then_some(())
    })
    .await;
    let power = metric("Values/power_kw").expect("Values/power_kw");
    assert_eq!(unit(&power).as_deref(), Some("kW"), "{power:?}");
    let power_alias = power.alias.expect("an alias");
    // Every alias of the device is its own.
    let mut aliases: Vec<u64> = birth.metrics.iter().filter_map(|m| m.alias).collect();
    let count = aliases.len();
    aliases.sort_unstable();
    aliases.dedup();
    assert_eq!(aliases.len(), count, "{:?}", birth.metrics);

    // Running at 40 Hz the power moves: its DDATA by alias.
    gw.command("fan", Command::Speed(40.0), "test").await.expect("speed");
    gw.command("fan", Command::Run, "test").await.expect("run");
    sub.wait("the power in a DDATA", |log| {
        log.iter()
            .filter(|m| kind(m, "hall-v") == Some(("DDATA", Some("fan"))))
            .any(|m| {
                decoded(m).metrics.iter().any(|x| {
                    x.alias == Some(power_alias)
                        && matches!(x.value, Some(payload::Value::Double(v)) if v > 0.0)
                })
            })
            .then_some(())
    })
    .await;
}
