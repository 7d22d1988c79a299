//! What the front ends show: a drive's and a bus's view built from the cache, the changes live
//! subscribers receive ([`Change`]), and an event as one log line ([`log_line`], from
//! [`crate::log`]).

use std::collections::BTreeMap;
use std::sync::Arc;

use drivebus_link::owner::BusStats;
use drivebus_store::Event;
use serde::Serialize;

use super::cache::{BusEntry, DriveEntry};
pub use crate::log::log_line;

/// A drive as the API shows it: configuration, cached values and their age, link health.
#[derive(Clone, Debug, Serialize)]
pub struct DriveView {
    /// The drive's id.
    pub id: String,
    /// The bus's name.
    pub bus: String,
    /// The family.
    pub family: String,
    /// The wire protocol.
    pub protocol: String,
    /// Its number on the bus.
    pub address: u8,
    /// Its Modbus TCP unit id.
    pub unit_id: u8,
    /// Whether writes are refused.
    pub locked: bool,
    /// `true`/`false` after the first poll; `null` before.
    pub online: Option<bool>,
    /// Whether the output is on.
    pub running: Option<bool>,
    /// `forward`/`reverse`.
    pub direction: Option<String>,
    /// Output frequency, Hz.
    pub output_hz: Option<f64>,
    /// Setpoint, Hz (the drive's, or the last commanded where the drive does not tell).
    pub setpoint_hz: Option<f64>,
    /// Motor current, A.
    pub current_a: Option<f64>,
    /// The fault in force.
    pub fault: Option<FaultView>,
    /// Values beyond these, by name, where the drive gives them (a template's `[values]`:
    /// `{"dc_bus_v": {"value": 560.0, "unit": "V"}}`); left out when there are none.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub values: BTreeMap<String, ValueView>,
    /// Age of the values, ms (`null` before the first answer).
    pub age_ms: Option<u64>,
    /// When the drive last answered, unix ms.
    pub last_seen_ms: Option<i64>,
    /// Failed polls / polls.
    pub error_rate: f64,
    /// Polls made.
    pub polls: u64,
    /// The last error.
    pub last_error: Option<String>,
    /// The poll interval, ms.
    pub poll_ms: u64,
    /// Where the values come from: `master` (this gateway polls the drive) or `standby` (it
    /// heard another gateway's polls of the drive; `[standby]`, writes refused).
    pub source: &'static str,
}

/// A named value as the API shows it.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ValueView {
    /// The value, in `unit`.
    pub value: f64,
    /// Its unit (`V`), or empty.
    pub unit: String,
}

/// A fault as the API shows it.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct FaultView {
    /// The drive's code.
    pub code: u32,
    /// The manual's text.
    pub text: String,
}

/// A bus as the API shows it.
#[derive(Clone, Debug, Serialize)]
pub struct BusView {
    /// Its name.
    pub name: String,
    /// Its port.
    pub port: String,
    /// Its protocol.
    pub protocol: String,
    /// Baud rate.
    pub baud: u32,
    /// Character format.
    pub serial: String,
    /// False after the port failed.
    pub online: bool,
    /// Requests sent (retries included).
    pub transactions: u64,
    /// Replies received.
    pub replies: u64,
    /// Requests not answered in time.
    pub timeouts: u64,
    /// Damaged replies.
    pub checksum_errors: u64,
    /// Retries.
    pub retries: u64,
    /// Time on the wire / elapsed.
    pub utilization: f64,
    /// Broadcasts heard that the gateway did not send.
    pub foreign_broadcasts: u64,
    /// True while a drive acts as bus master on this line: a broadcast the gateway did not
    /// send was heard within the last [`DRIVE_MASTER_WINDOW_S`] seconds.
    pub drive_master: bool,
    /// `master` while the gateway polls the bus, `standby` while it only listens (another
    /// gateway masters the line, `[standby]`).
    pub role: &'static str,
    /// The drives' ids.
    pub drives: Vec<String>,
}

/// How long after the last broadcast it did not send the gateway still shows a bus as a
/// drive-master line, seconds.
pub const DRIVE_MASTER_WINDOW_S: f64 = 10.0;

/// True while a drive acts as bus master on the line of `stats` (see [`BusView::drive_master`]).
pub fn drive_master(stats: &BusStats) -> bool {
    stats.last_foreign_broadcast_s.is_some_and(|t| stats.elapsed_seconds - t <= DRIVE_MASTER_WINDOW_S)
}

/// A change for live subscribers (the HTTP stream, MQTT, the dashboard).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Change {
    /// A drive's values were refreshed.
    Drive(DriveView),
    /// Something happened (also in the store).
    Event(Event),
    /// A bus's statistics.
    Bus(BusView),
}

impl DriveView {
    /// The view of drive `d` from its cached state.
    pub fn of(d: &DriveEntry) -> DriveView {
        d.with_state(|s| {
            let st = s.status.as_ref();
            DriveView {
                id: d.config.name.clone(),
                bus: d.bus.clone(),
                family: d.config.family.as_str().to_string(),
                protocol: d.protocol_name.to_string(),
                address: d.config.address,
                unit_id: d.config.unit_id,
                locked: d.locked(),
                online: s.online,
                running: st.map(|x| x.running),
                direction: st.and_then(|x| x.direction.clone()),
                output_hz: st.and_then(|x| x.output_hz),
                setpoint_hz: s.setpoint_hz(),
                current_a: st.and_then(|x| x.current_a),
                fault: st
                    .and_then(|x| x.fault.as_ref())
                    .map(|f| FaultView { code: f.code, text: f.text.clone() }),
                values: st
                    .map(|x| {
                        x.values
                            .iter()
                            .map(|v| (v.name.clone(), ValueView { value: v.value, unit: v.unit.clone() }))
                            .collect()
                    })
                    .unwrap_or_default(),
                age_ms: s.updated.map(|t| t.elapsed().as_millis() as u64),
                last_seen_ms: s.updated_ms,
                error_rate: if s.polls == 0 { 0.0 } else { s.poll_errors as f64 / s.polls as f64 },
                polls: s.polls,
                last_error: s.last_error.clone(),
                poll_ms: d.config.poll.as_millis() as u64,
                source: d.role().as_str(),
            }
        })
    }
}

impl BusView {
    /// The view of bus `b` from its owner's counts; `drives` are the gateway's drives (those of
    /// `b` are listed).
    pub fn of(b: &BusEntry, drives: &[Arc<DriveEntry>]) -> BusView {
        let s = b.stats();
        BusView {
            name: b.config.name.clone(),
            port: b.config.port.to_string(),
            protocol: b.config.protocol_name().to_string(),
            baud: b.config.baud,
            serial: b.config.format.to_string(),
            online: b.online(),
            transactions: s.transactions,
            replies: s.replies,
            timeouts: s.timeouts,
            checksum_errors: s.checksum_errors,
            retries: s.retries,
            utilization: s.utilization(),
            foreign_broadcasts: s.foreign_broadcasts,
            drive_master: drive_master(&s),
            role: b.role().as_str(),
            drives: drives.iter().filter(|d| d.bus == b.config.name).map(|d| d.config.name.clone()).collect(),
        }
    }
}
