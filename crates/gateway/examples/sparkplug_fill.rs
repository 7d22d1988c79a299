//! Fills a store's Sparkplug queue with what an edge node keeps while nobody listens, for the
//! drain benchmark (bench/sparkplug.sh): `COUNT` data messages spread over the last hour, round
//! robin over drives `vfd-1` .. `vfd-DRIVES`, each one changed output frequency and current,
//! made by the edge node's own code ([`Node::on_drive`], [`Node::to_keep`]).
//!
//! sparkplug_fill DB NODE COUNT DRIVES      e.g. sparkplug_fill plant.db drivebus/load 3600000 1000

use drivebus_gateway::core::DriveView;
use drivebus_gateway::sparkplug::node::{DeviceMessage, Node};
use prost::Message;

fn view(id: &str, hz: f64, time_ms: i64) -> DriveView {
    DriveView {
        id: id.into(),
        bus: "line-1".into(),
        family: "generic".into(),
        protocol: "modbus-rtu".into(),
        address: 1,
        unit_id: 0,
        locked: false,
        online: Some(true),
        running: Some(true),
        direction: Some("forward".into()),
        output_hz: Some(hz),
        setpoint_hz: Some(50.0),
        current_a: Some(hz / 5.0),
        fault: None,
        values: Default::default(),
        age_ms: Some(0),
        last_seen_ms: Some(time_ms),
        error_rate: 0.0,
        polls: 1,
        last_error: None,
        poll_ms: 500,
        source: "master",
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [db, node_key, count, drives] = args.as_slice() else {
        eprintln!("usage: sparkplug_fill DB GROUP/EDGE COUNT DRIVES");
        std::process::exit(2);
    };
    let (count, drives): (u64, u64) = match (count.parse(), drives.parse()) {
        (Ok(c), Ok(d)) if d > 0 => (c, d),
        _ => {
            eprintln!("sparkplug_fill: COUNT and DRIVES are numbers, DRIVES above 0");
            std::process::exit(2);
        }
    };
    let (group, edge) = node_key.split_once('/').unwrap_or(("drivebus", node_key));
    let store = drivebus_store::Store::open(std::path::Path::new(db)).unwrap_or_else(|e| {
        eprintln!("sparkplug_fill: {e}");
        std::process::exit(1);
    });
    let mut node = Node::new(group, edge);
    node.sync_devices((1..=drives).map(|i| (format!("vfd-{i}"), Default::default())).collect());
    let now = drivebus_gateway::core::unix_ms();
    let start = now - 3_600_000;
    let mut batch = Vec::with_capacity(10_000);
    for n in 0..count {
        let id = format!("vfd-{}", n % drives + 1);
        let t = start + (n as i64 * 3_600_000) / count.max(1) as i64;
        let hz = 20.0 + ((n / drives) % 300) as f64 / 10.0;
        if let Some(DeviceMessage::Data(p)) = node.on_drive(&view(&id, hz, t), false, t) {
            batch.push((id, t, Node::to_keep(p).encode_to_vec()));
        }
        if batch.len() == 10_000 || n + 1 == count {
            store.spool_push(node_key, &batch, u64::MAX, 0).unwrap_or_else(|e| {
                eprintln!("sparkplug_fill: {e}");
                std::process::exit(1);
            });
            batch.clear();
        }
    }
    println!("{} data messages queued for {node_key}", store.spool_len(node_key).unwrap_or(0));
}
