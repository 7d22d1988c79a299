//! The edge node without I/O: topics, aliases, `seq`, births, deaths and data messages made
//! from the gateway's views, and commands read from DCMD/NCMD payloads. The runtime
//! ([`super::run`]) decides what is published and what waits in the store.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use drivebus_drive::ParamDef;

use super::payload::{DataType, Metric, Payload, Value};
use crate::core::{BusView, Command, DriveView, ValueDef};

/// The Sparkplug B topic namespace.
pub const NAMESPACE: &str = "spBv1.0";

/// Highest `Setpoint` a DCMD may ask for, Hz (the drive's own limits are checked after).
pub const MAX_SETPOINT_HZ: f64 = 600.0;

/// Bus statistics are published (NDATA) at most this often unless a bus's link changed, ms.
pub const NODE_DATA_INTERVAL_MS: i64 = 10_000;

/// A device's status metrics, in alias order: (name, type, unit). `Source` says whose poll
/// the values come from: `master` (this gateway's own) or `standby` (heard on a line another
/// gateway masters, `[standby]`), as MQTT's `"source"` does.
pub const STATUS_METRICS: [(&str, DataType, &str); 9] = [
    ("OutputFrequency", DataType::Double, "Hz"),
    ("Setpoint", DataType::Double, "Hz"),
    ("Current", DataType::Double, "A"),
    ("Running", DataType::Boolean, ""),
    ("Direction", DataType::String, ""),
    ("FaultCode", DataType::UInt32, ""),
    ("FaultText", DataType::String, ""),
    ("Online", DataType::Boolean, ""),
    ("Source", DataType::String, ""),
];

/// A device's command metrics (Boolean, written `true`), after the status metrics.
pub const COMMAND_METRICS: [&str; 4] = ["Command/Run", "Command/Stop", "Command/Reverse", "Command/Reset"];

/// The prefix of a device's parameter metrics (`Parameters/<name>`, Double, in the unit).
pub const PARAMETER_PREFIX: &str = "Parameters/";

/// The prefix of a device's named values (a template's `[values]`: `Values/dc_bus_v`, Double, in
/// the value's unit), read-only, after the parameters.
pub const VALUE_PREFIX: &str = "Values/";

/// The node's rebirth request metric. It has no alias (operational-behavior-data-commands-
/// rebirth-name-aliases): a host asks for a rebirth by name, knowing nothing of this node.
pub const REBIRTH: &str = "Node Control/Rebirth";

/// The birth/death sequence metric, of type Int64 as the specification says
/// (message-flow-edge-node-birth-publish-nbirth-payload-bdSeq).
pub const BD_SEQ: &str = "bdSeq";

const SETPOINT: usize = 1;
const FIXED: usize = STATUS_METRICS.len() + COMMAND_METRICS.len();

/// Why a command was refused: a short kind (metrics label) and the sentence logged.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refusal {
    /// `not_sparkplug`, `unknown_device`, `unknown_metric`, `wrong_type`, `out_of_range`,
    /// `disabled`.
    pub kind: &'static str,
    /// What was wrong and what to do.
    pub message: String,
}

fn refuse(kind: &'static str, message: impl Into<String>) -> Refusal {
    Refusal { kind, message: message.into() }
}

/// What an NCMD asks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NodeCommand {
    /// Send NBIRTH and every DBIRTH again.
    Rebirth,
}

/// A device message to publish (or, for data, to keep while nobody listens).
#[derive(Clone, Debug, PartialEq)]
pub enum DeviceMessage {
    /// DBIRTH.
    Birth(Payload),
    /// DDATA: the metrics that changed, with names and aliases (see [`Node::live`]).
    Data(Payload),
    /// DDEATH.
    Death(Payload),
}

/// What a device has beyond the fixed metrics: its writable parameters and its named values,
/// each list shared with every device of the same kind.
#[derive(Clone, Debug)]
pub struct DeviceDef {
    /// The writable parameters (`Parameters/<name>`).
    pub params: Arc<[ParamDef]>,
    /// The named values (`Values/<name>`).
    pub values: Arc<[ValueDef]>,
}

impl Default for DeviceDef {
    /// No parameters, no named values.
    fn default() -> Self {
        DeviceDef { params: Arc::from([]), values: Arc::from([]) }
    }
}

impl PartialEq for DeviceDef {
    fn eq(&self, other: &Self) -> bool {
        (Arc::ptr_eq(&self.params, &other.params) || self.params == other.params)
            && (Arc::ptr_eq(&self.values, &other.values) || self.values == other.values)
    }
}

struct Device {
    base_alias: u64,
    def: DeviceDef,
    born: bool,
    /// The status metrics' values, then the named values'.
    last: Option<Vec<Option<Value>>>,
}

impl Device {
    /// The first index of the named values.
    fn values_at(&self) -> usize {
        FIXED + self.def.params.len()
    }

    fn metric_name(&self, i: usize) -> String {
        match i {
            _ if i < STATUS_METRICS.len() => STATUS_METRICS[i].0.to_string(),
            _ if i < FIXED => COMMAND_METRICS[i - STATUS_METRICS.len()].to_string(),
            _ if i < self.values_at() => format!("{PARAMETER_PREFIX}{}", self.def.params[i - FIXED].name),
            _ => format!("{VALUE_PREFIX}{}", self.def.values[i - self.values_at()].name),
        }
    }

    fn index_of(&self, m: &Metric) -> Option<usize> {
        let count = self.values_at() + self.def.values.len();
        if let Some(a) = m.alias {
            let i = a.checked_sub(self.base_alias)? as usize;
            return (i < count).then_some(i);
        }
        let name = m.name.as_deref()?;
        if let Some(i) = STATUS_METRICS.iter().position(|(n, _, _)| *n == name) {
            return Some(i);
        }
        if let Some(i) = COMMAND_METRICS.iter().position(|n| *n == name) {
            return Some(STATUS_METRICS.len() + i);
        }
        if let Some(v) = name.strip_prefix(VALUE_PREFIX) {
            return self.def.values.iter().position(|d| d.name == v).map(|i| self.values_at() + i);
        }
        let p = name.strip_prefix(PARAMETER_PREFIX)?;
        self.def.params.iter().position(|d| d.name == p).map(|i| FIXED + i)
    }

    /// The metric index of the `k`-th value of [`Device::last`] (a status metric or a named
    /// value).
    fn index_of_last(&self, k: usize) -> usize {
        if k < STATUS_METRICS.len() {
            k
        } else {
            self.values_at() + k - STATUS_METRICS.len()
        }
    }
}

/// The values of a drive's status metrics, in [`STATUS_METRICS`] order.
pub fn status_values(v: &DriveView) -> [Option<Value>; 9] {
    let known = v.running.is_some();
    [
        v.output_hz.map(Value::Double),
        v.setpoint_hz.map(Value::Double),
        v.current_a.map(Value::Double),
        v.running.map(Value::Boolean),
        v.direction.clone().map(Value::String),
        known.then(|| Value::Int(v.fault.as_ref().map_or(0, |f| f.code))),
        known.then(|| Value::String(v.fault.as_ref().map_or(String::new(), |f| f.text.clone()))),
        v.online.map(Value::Boolean),
        Some(Value::String(v.source.to_string())),
    ]
}

/// The values of a drive's named values `defs` (`Values/<name>`), in their order: `None` where
/// the view has none (before the first answer).
pub fn named_values(v: &DriveView, defs: &[ValueDef]) -> Vec<Option<Value>> {
    defs.iter().map(|d| v.values.get(&d.name).map(|x| Value::Double(x.value))).collect()
}

/// The edge node's session state.
pub struct Node {
    group: String,
    edge: String,
    seq: u8,
    next_alias: u64,
    devices: BTreeMap<String, Device>,
    buses: HashMap<String, BusState>,
}

/// A bus's first alias, and when its statistics were last sent with its link state then.
struct BusState {
    base_alias: u64,
    last: Option<(i64, bool)>,
}

const BUS_METRICS: [(&str, DataType); 5] = [
    ("Online", DataType::Boolean),
    ("Transactions", DataType::UInt64),
    ("Timeouts", DataType::UInt64),
    ("ChecksumErrors", DataType::UInt64),
    ("Utilization", DataType::Double),
];

fn bus_values(b: &BusView) -> [Value; 5] {
    [
        Value::Boolean(b.online),
        Value::Long(b.transactions),
        Value::Long(b.timeouts),
        Value::Long(b.checksum_errors),
        Value::Double(b.utilization),
    ]
}

fn datatype_of(v: &Value) -> Option<DataType> {
    match v {
        Value::Int(_) => Some(DataType::UInt32),
        Value::Long(_) => Some(DataType::UInt64),
        Value::Boolean(_) => Some(DataType::Boolean),
        Value::String(_) => Some(DataType::String),
        Value::Double(_) => Some(DataType::Double),
        Value::Float(_) | Value::Bytes(_) => None,
    }
}

impl Node {
    /// A node `edge` of group `group`, with no device yet.
    pub fn new(group: &str, edge: &str) -> Node {
        Node {
            group: group.to_string(),
            edge: edge.to_string(),
            seq: 0,
            // The buses and devices take their aliases as they come; bdSeq and the rebirth
            // metric have none.
            next_alias: 1,
            devices: BTreeMap::new(),
            buses: HashMap::new(),
        }
    }

    /// `spBv1.0/<group>/<kind>/<edge node>`.
    pub fn node_topic(&self, kind: &str) -> String {
        format!("{NAMESPACE}/{}/{kind}/{}", self.group, self.edge)
    }

    /// `spBv1.0/<group>/<kind>/<edge node>/<device>`.
    pub fn device_topic(&self, kind: &str, device: &str) -> String {
        format!("{NAMESPACE}/{}/{kind}/{}/{device}", self.group, self.edge)
    }

    /// `group/edge node`, the node's key in the store and its audit actor's name.
    pub fn key(&self) -> String {
        format!("{}/{}", self.group, self.edge)
    }

    /// The devices known, in id order.
    pub fn device_ids(&self) -> Vec<String> {
        self.devices.keys().cloned().collect()
    }

    /// Puts the devices in line with the gateway's drives: `(id, parameters and values)`. New
    /// ones get aliases never used before in this process; returns the ids that are gone and
    /// were born (they need a DDEATH).
    pub fn sync_devices(&mut self, drives: Vec<(String, DeviceDef)>) -> Vec<String> {
        let keep: std::collections::HashSet<&String> = drives.iter().map(|(id, _)| id).collect();
        let gone: Vec<String> = self.devices.keys().filter(|id| !keep.contains(id)).cloned().collect();
        let mut dead = Vec::new();
        for id in gone {
            if self.devices.remove(&id).is_some_and(|d| d.born) {
                dead.push(id);
            }
        }
        for (id, def) in drives {
            if self.devices.get(&id).is_some_and(|d| d.def == def) {
                continue;
            }
            let base_alias = self.next_alias;
            self.next_alias += (FIXED + def.params.len() + def.values.len()) as u64;
            // A device whose metrics changed is born again with its new aliases.
            self.devices.insert(id, Device { base_alias, def, born: false, last: None });
        }
        dead
    }

    /// Sets `p`'s sequence number and moves it on (0..=255, wrapping).
    pub fn stamp(&mut self, p: &mut Payload) {
        p.seq = Some(u64::from(self.seq));
        self.seq = self.seq.wrapping_add(1);
    }

    /// The NBIRTH of a new session or a rebirth: `bdSeq`, the rebirth control and each bus's
    /// statistics; `seq` 0. Every device must be born again after it.
    pub fn nbirth(&mut self, bd_seq: u64, buses: &[BusView], now_ms: i64) -> Payload {
        let t = now_ms as u64;
        let mut metrics = vec![
            Metric::birth_by_name(BD_SEQ, DataType::Int64, Some(Value::Long(bd_seq)), t),
            Metric::birth_by_name(REBIRTH, DataType::Boolean, Some(Value::Boolean(false)), t),
        ];
        self.buses.retain(|name, _| buses.iter().any(|b| &b.name == name));
        for b in buses {
            let next = &mut self.next_alias;
            let bus = self.buses.entry(b.name.clone()).or_insert_with(|| {
                let base_alias = *next;
                *next += BUS_METRICS.len() as u64;
                BusState { base_alias, last: None }
            });
            bus.last = Some((now_ms, b.online));
            for (i, ((name, ty), v)) in BUS_METRICS.iter().zip(bus_values(b)).enumerate() {
                let alias = bus.base_alias + i as u64;
                let m = Metric::birth(&format!("Buses/{}/{name}", b.name), alias, *ty, Some(v), t);
                metrics.push(if *name == "Utilization" { m.with_unit("ratio") } else { m });
            }
        }
        for d in self.devices.values_mut() {
            d.born = false;
            d.last = None;
        }
        self.seq = 0;
        let mut p = Payload { timestamp: Some(t), metrics, ..Payload::default() };
        self.stamp(&mut p);
        p
    }

    /// The NDEATH (also the MQTT will) of session `bd_seq`.
    pub fn ndeath(bd_seq: u64, now_ms: i64) -> Payload {
        Payload {
            timestamp: Some(now_ms as u64),
            metrics: vec![Metric::birth_by_name(
                BD_SEQ,
                DataType::Int64,
                Some(Value::Long(bd_seq)),
                now_ms as u64,
            )],
            ..Payload::default()
        }
    }

    /// NDATA with a bus's statistics when its link changed or [`NODE_DATA_INTERVAL_MS`] passed
    /// since the last; `None` otherwise, and for a bus not in the NBIRTH.
    pub fn on_bus(&mut self, b: &BusView, now_ms: i64) -> Option<Payload> {
        let bus = self.buses.get_mut(&b.name)?;
        let (at, online) = bus.last?;
        if online == b.online && now_ms - at < NODE_DATA_INTERVAL_MS {
            return None;
        }
        bus.last = Some((now_ms, b.online));
        let base = bus.base_alias;
        let metrics = bus_values(b)
            .into_iter()
            .enumerate()
            .map(|(i, v)| Metric {
                alias: Some(base + i as u64),
                timestamp: Some(now_ms as u64),
                value: Some(v),
                ..Metric::default()
            })
            .collect();
        Some(Payload { timestamp: Some(now_ms as u64), metrics, ..Payload::default() })
    }

    /// What drive `v`'s new view calls for. While `publishing`: a DBIRTH for a device not born
    /// (unless it is offline), a DDEATH when a born device went offline, DDATA with the
    /// metrics that changed. While not: DDATA with what changed (to keep), whatever the link.
    pub fn on_drive(&mut self, v: &DriveView, publishing: bool, now_ms: i64) -> Option<DeviceMessage> {
        let d = self.devices.get_mut(&v.id)?;
        let mut values = status_values(v).to_vec();
        values.extend(named_values(v, &d.def.values));
        let t = v.last_seen_ms.unwrap_or(now_ms) as u64;
        if publishing && v.online == Some(false) {
            d.last = Some(values);
            if !d.born {
                return None;
            }
            d.born = false;
            return Some(DeviceMessage::Death(Payload {
                timestamp: Some(now_ms as u64),
                ..Payload::default()
            }));
        }
        if publishing && !d.born {
            d.born = true;
            let mut metrics: Vec<Metric> = STATUS_METRICS
                .iter()
                .zip(values.iter())
                .enumerate()
                .map(|(i, ((name, ty, unit), val))| {
                    Metric::birth(name, d.base_alias + i as u64, *ty, val.clone(), t).with_unit(unit)
                })
                .collect();
            for (i, name) in COMMAND_METRICS.iter().enumerate() {
                let alias = d.base_alias + (STATUS_METRICS.len() + i) as u64;
                metrics.push(Metric::birth(name, alias, DataType::Boolean, Some(Value::Boolean(false)), t));
            }
            for (i, p) in d.def.params.iter().enumerate() {
                let alias = d.base_alias + (FIXED + i) as u64;
                let name = format!("{PARAMETER_PREFIX}{}", p.name);
                metrics.push(Metric::birth(&name, alias, DataType::Double, None, t).with_unit(&p.unit));
            }
            for (i, (x, val)) in d.def.values.iter().zip(&values[STATUS_METRICS.len()..]).enumerate() {
                let alias = d.base_alias + (d.values_at() + i) as u64;
                let name = format!("{VALUE_PREFIX}{}", x.name);
                metrics
                    .push(Metric::birth(&name, alias, DataType::Double, val.clone(), t).with_unit(&x.unit));
            }
            d.last = Some(values);
            return Some(DeviceMessage::Birth(Payload {
                timestamp: Some(now_ms as u64),
                metrics,
                ..Payload::default()
            }));
        }
        let changed: Vec<Metric> = values
            .iter()
            .enumerate()
            .filter(|(k, val)| d.last.as_ref().map_or(true, |l| l.get(*k) != Some(*val)))
            .map(|(k, val)| {
                let i = d.index_of_last(k);
                let datatype = STATUS_METRICS.get(k).map_or(DataType::Double, |m| m.1);
                Metric {
                    name: Some(d.metric_name(i)),
                    alias: Some(d.base_alias + i as u64),
                    timestamp: Some(t),
                    is_null: val.is_none().then_some(true),
                    // A value that became unknown keeps its type so the host can read the null.
                    datatype: val.is_none().then_some(datatype as u32),
                    value: val.clone(),
                    ..Metric::default()
                }
            })
            .collect();
        d.last = Some(values);
        (!changed.is_empty()).then(|| {
            DeviceMessage::Data(Payload { timestamp: Some(t), metrics: changed, ..Payload::default() })
        })
    }

    /// DDATA with a parameter's value just written (the write's result).
    pub fn param_written(&self, device: &str, name: &str, value: f64, now_ms: i64) -> Option<Payload> {
        let d = self.devices.get(device).filter(|d| d.born)?;
        let i = d.def.params.iter().position(|p| p.name == name)?;
        Some(Payload {
            timestamp: Some(now_ms as u64),
            metrics: vec![Metric {
                alias: Some(d.base_alias + (FIXED + i) as u64),
                timestamp: Some(now_ms as u64),
                value: Some(Value::Double(value)),
                ..Metric::default()
            }],
            ..Payload::default()
        })
    }

    /// A live DDATA: aliases only (the births gave the names).
    pub fn live(mut p: Payload) -> Payload {
        for m in &mut p.metrics {
            m.name = None;
        }
        p
    }

    /// A DDATA to keep in the store: names only, since aliases may differ after a restart.
    pub fn to_keep(mut p: Payload) -> Payload {
        for m in &mut p.metrics {
            m.alias = None;
        }
        p
    }

    /// A kept DDATA of `device` made ready to send late: names turned into this session's
    /// aliases, every metric flagged `is_historical`. `None` when the device is not born now
    /// (removed, or offline) or none of its metrics is known.
    pub fn historical(&self, device: &str, mut p: Payload) -> Option<Payload> {
        let d = self.devices.get(device).filter(|d| d.born)?;
        p.metrics.retain_mut(|m| match d.index_of(m) {
            Some(i) => {
                m.alias = Some(d.base_alias + i as u64);
                m.name = None;
                m.is_historical = Some(true);
                true
            }
            None => false,
        });
        (!p.metrics.is_empty()).then_some(p)
    }

    /// Whether `device` is born in this session.
    pub fn is_born(&self, device: &str) -> bool {
        self.devices.get(device).is_some_and(|d| d.born)
    }

    /// Reads an NCMD.
    pub fn node_command(&self, p: &Payload) -> Result<Vec<NodeCommand>, Refusal> {
        if p.metrics.is_empty() {
            return Err(refuse("unknown_metric", "an NCMD without metrics"));
        }
        p.metrics
            .iter()
            .map(|m| {
                if m.alias.is_some() && m.name.as_deref() != Some(REBIRTH) {
                    return Err(refuse(
                        "unknown_metric",
                        format!(
                            "NCMD metric {}: the node's metrics take no commands by alias: name {REBIRTH:?}",
                            describe(m)
                        ),
                    ));
                }
                if m.name.as_deref() != Some(REBIRTH) {
                    return Err(refuse(
                        "unknown_metric",
                        format!("NCMD metric {}: the node takes {REBIRTH:?} only", describe(m)),
                    ));
                }
                check_type(m, DataType::Boolean)?;
                match m.value {
                    Some(Value::Boolean(true)) => Ok(NodeCommand::Rebirth),
                    _ => Err(refuse("out_of_range", format!("{REBIRTH:?} wants true"))),
                }
            })
            .collect()
    }

    /// Reads a DCMD for `device` into gateway commands, all checked before any is sent: one
    /// bad metric refuses the whole message.
    pub fn device_command(&self, device: &str, p: &Payload) -> Result<Vec<Command>, Refusal> {
        let d = self.devices.get(device).ok_or_else(|| {
            refuse("unknown_device", format!("DCMD for {device:?}: no such device on this edge node"))
        })?;
        if p.metrics.is_empty() {
            return Err(refuse("unknown_metric", format!("DCMD for {device:?} without metrics")));
        }
        p.metrics
            .iter()
            .map(|m| {
                let i = d.index_of(m).ok_or_else(|| {
                    refuse("unknown_metric", format!("DCMD for {device:?}: no metric {}", describe(m)))
                })?;
                let name = d.metric_name(i);
                match i {
                    SETPOINT => {
                        check_type(m, DataType::Double).map_err(|r| with_name(r, &name))?;
                        let Some(Value::Double(hz)) = m.value else {
                            return Err(refuse("wrong_type", format!("{name}: give a Double value in Hz")));
                        };
                        if !hz.is_finite() || !(0.0..=MAX_SETPOINT_HZ).contains(&hz) {
                            return Err(refuse(
                                "out_of_range",
                                format!("{name}: {hz} Hz is outside 0..{MAX_SETPOINT_HZ} Hz"),
                            ));
                        }
                        Ok(Command::Speed(hz))
                    }
                    _ if i < STATUS_METRICS.len() => {
                        Err(refuse("unknown_metric", format!("{name} is read-only: it cannot be written")))
                    }
                    _ if i < FIXED => {
                        check_type(m, DataType::Boolean).map_err(|r| with_name(r, &name))?;
                        if m.value != Some(Value::Boolean(true)) {
                            return Err(refuse("out_of_range", format!("{name}: write true to command it")));
                        }
                        let cmd = ["run", "stop", "reverse", "reset"][i - STATUS_METRICS.len()];
                        Ok(Command::from_name(cmd).expect("the four command metrics are commands"))
                    }
                    _ if i >= d.values_at() => {
                        Err(refuse("unknown_metric", format!("{name} is read-only: it cannot be written")))
                    }
                    _ => {
                        let def = &d.def.params[i - FIXED];
                        check_type(m, DataType::Double).map_err(|r| with_name(r, &name))?;
                        let Some(Value::Double(v)) = m.value else {
                            return Err(refuse("wrong_type", format!("{name}: give a Double value")));
                        };
                        def.to_raw(v).map_err(|e| refuse("out_of_range", format!("{name}: {e}")))?;
                        Ok(Command::SetParam { name: def.name.clone(), value: format!("{v}"), eeprom: false })
                    }
                }
            })
            .collect()
    }
}

fn with_name(mut r: Refusal, name: &str) -> Refusal {
    r.message = format!("{name}: {}", r.message);
    r
}

fn describe(m: &Metric) -> String {
    match (&m.name, m.alias) {
        (Some(n), _) => format!("{n:?}"),
        (None, Some(a)) => format!("with alias {a}"),
        (None, None) => "without a name or an alias".into(),
    }
}

/// A command metric must carry the expected type (when it says one) and a value of it.
fn check_type(m: &Metric, want: DataType) -> Result<(), Refusal> {
    if let Some(t) = m.datatype {
        if t != want as u32 {
            return Err(refuse(
                "wrong_type",
                format!("datatype {} where {} is expected", DataType::name(t), want.as_str()),
            ));
        }
    }
    match &m.value {
        Some(v) if datatype_of(v) == Some(want) => Ok(()),
        Some(_) => Err(refuse("wrong_type", format!("the value is not a {}", want.as_str()))),
        None => Err(refuse("wrong_type", format!("no value: give a {}", want.as_str()))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::FaultView;
    use drivebus_drive::{Catalog, Family};

    fn view(id: &str, online: Option<bool>, hz: f64) -> DriveView {
        DriveView {
            id: id.into(),
            bus: "line-1".into(),
            family: "generic".into(),
            protocol: "modbus-rtu".into(),
            address: 1,
            unit_id: 1,
            locked: false,
            online,
            running: Some(hz > 0.0),
            direction: Some("forward".into()),
            output_hz: Some(hz),
            setpoint_hz: Some(40.0),
            current_a: Some(1.5),
            fault: None,
            values: Default::default(),
            age_ms: Some(0),
            last_seen_ms: Some(1_000),
            error_rate: 0.0,
            polls: 1,
            last_error: None,
            poll_ms: 250,
            source: "master",
        }
    }

    fn params() -> Arc<[ParamDef]> {
        Catalog::load(Family::Generic).unwrap().iter().filter(|p| !p.read_only).cloned().collect()
    }

    /// A generic drive's metrics: its writable parameters, no named values.
    fn plain() -> DeviceDef {
        DeviceDef { params: params(), values: Arc::from([]) }
    }

    fn node() -> Node {
        let mut n = Node::new("plant", "hall-1");
        n.sync_devices(vec![("pump-1".into(), plain()), ("pump-2".into(), plain())]);
        n
    }

    /// A templated drive's metrics: no parameters, two named values.
    fn with_values() -> DeviceDef {
        let def = |name: &str, unit: &str| ValueDef { name: name.into(), unit: unit.into() };
        DeviceDef { params: Arc::from([]), values: Arc::from([def("dc_bus_v", "V"), def("power_kw", "kW")]) }
    }

    #[test]
    fn named_values_are_read_only_metrics_born_with_their_unit_and_sent_when_they_change() {
        let mut n = Node::new("plant", "hall-1");
        n.sync_devices(vec![("fan".into(), with_values())]);
        let mut v = view("fan", Some(true), 0.0);
        v.values.insert("dc_bus_v".into(), crate::core::ValueView { value: 540.0, unit: "V".into() });
        let Some(DeviceMessage::Birth(b)) = n.on_drive(&v, true, 5) else { panic!("no DBIRTH") };
        let dc = b.metrics.iter().find(|m| m.name.as_deref() == Some("Values/dc_bus_v")).unwrap();
        assert_eq!(
            (dc.value.clone(), dc.datatype),
            (Some(Value::Double(540.0)), Some(DataType::Double as u32))
        );
        let unit = dc.properties.as_ref().unwrap();
        assert_eq!(unit.keys, ["engUnit"]);
        // Not read yet: born null, with its type.
        let kw = b.metrics.iter().find(|m| m.name.as_deref() == Some("Values/power_kw")).unwrap();
        assert_eq!((kw.value.clone(), kw.is_null), (None, Some(true)), "{kw:?}");
        let aliases: std::collections::HashSet<_> = b.metrics.iter().filter_map(|m| m.alias).collect();
        assert_eq!(aliases.len(), STATUS_METRICS.len() + COMMAND_METRICS.len() + 2);

        // A change of one value: DDATA with that metric only, by its alias and name.
        v.values.insert("power_kw".into(), crate::core::ValueView { value: 1.5, unit: "kW".into() });
        let Some(DeviceMessage::Data(d)) = n.on_drive(&v, true, 6) else { panic!("no DDATA") };
        assert_eq!(d.metrics.len(), 1, "{:?}", d.metrics);
        assert_eq!(d.metrics[0].name.as_deref(), Some("Values/power_kw"));
        assert_eq!((d.metrics[0].alias, d.metrics[0].value.clone()), (kw.alias, Some(Value::Double(1.5))));
        assert_eq!(n.on_drive(&v, true, 7), None, "nothing changed");
        // Kept DDATA by name finds the alias again.
        let kept = Node::to_keep(d.clone());
        assert_eq!(n.historical("fan", kept).unwrap().metrics[0].alias, kw.alias);

        // Written by name or alias: refused, read-only.
        let by_alias = Payload {
            metrics: vec![Metric {
                alias: dc.alias,
                datatype: Some(DataType::Double as u32),
                value: Some(Value::Double(1.0)),
                ..Metric::default()
            }],
            ..Payload::default()
        };
        for p in [cmd("Values/dc_bus_v", Value::Double(1.0), DataType::Double), by_alias] {
            let e = n.device_command("fan", &p).unwrap_err();
            assert_eq!(e.kind, "unknown_metric", "{e:?}");
            assert!(e.message.contains("Values/dc_bus_v is read-only"), "{e:?}");
        }
    }

    fn birth(n: &mut Node, id: &str) -> Payload {
        match n.on_drive(&view(id, Some(true), 0.0), true, 5) {
            Some(DeviceMessage::Birth(p)) => p,
            other => panic!("no DBIRTH: {other:?}"),
        }
    }

    #[test]
    fn aliases_are_unique_across_the_node_and_kept_by_a_rebirth() {
        let mut n = node();
        let nb = n.nbirth(7, &[], 1);
        let a = birth(&mut n, "pump-1");
        let b = birth(&mut n, "pump-2");
        let mut aliases: Vec<u64> =
            nb.metrics.iter().chain(&a.metrics).chain(&b.metrics).filter_map(|m| m.alias).collect();
        let count = aliases.len();
        aliases.sort_unstable();
        aliases.dedup();
        assert_eq!(aliases.len(), count, "aliases repeat");
        assert!(a.metrics.iter().all(|m| m.alias.is_some() && m.name.is_some() && m.datatype.is_some()));
        let hz = a.metrics.iter().find(|m| m.name.as_deref() == Some("OutputFrequency")).unwrap();
        assert_eq!(hz.properties.as_ref().unwrap().keys, ["engUnit"]);
        n.nbirth(7, &[], 2);
        assert_eq!(
            birth(&mut n, "pump-1").metrics,
            a.metrics.iter().map(|m| Metric { timestamp: Some(1_000), ..m.clone() }).collect::<Vec<_>>()
        );
    }

    #[test]
    fn the_rebirth_metric_has_no_alias_and_bd_seq_is_an_int64() {
        let mut n = node();
        let nb = n.nbirth(3, &[], 1);
        let rebirth = nb.metrics.iter().find(|m| m.name.as_deref() == Some(REBIRTH)).unwrap();
        assert_eq!(rebirth.alias, None, "operational-behavior-data-commands-rebirth-name-aliases");
        assert_eq!(rebirth.datatype, Some(DataType::Boolean as u32));
        assert_eq!(rebirth.value, Some(Value::Boolean(false)));
        for p in [&nb, &Node::ndeath(3, 1)] {
            let bd = p.metrics.iter().find(|m| m.name.as_deref() == Some(BD_SEQ)).unwrap();
            assert_eq!((bd.datatype, &bd.value), (Some(DataType::Int64 as u32), &Some(Value::Long(3))));
        }
        // A rebirth is asked by name; no alias stands for it (alias 1 is a device's or a bus's).
        let mut by_alias = cmd("x", Value::Boolean(true), DataType::Boolean);
        by_alias.metrics[0].name = None;
        by_alias.metrics[0].alias = Some(1);
        let r = n.node_command(&by_alias).unwrap_err();
        assert_eq!(r.kind, "unknown_metric");
        assert!(r.message.contains("by alias"), "{}", r.message);
        assert_eq!(
            n.node_command(&cmd(REBIRTH, Value::Boolean(true), DataType::Boolean)),
            Ok(vec![NodeCommand::Rebirth])
        );
    }

    #[test]
    fn seq_starts_at_zero_with_nbirth_and_wraps_after_255() {
        let mut n = node();
        assert_eq!(n.nbirth(0, &[], 1).seq, Some(0));
        let mut p = Payload::default();
        for expected in (1..=255).chain(0..=1) {
            n.stamp(&mut p);
            assert_eq!(p.seq, Some(expected));
        }
        assert_eq!(n.nbirth(0, &[], 1).seq, Some(0));
    }

    #[test]
    fn data_on_change_only_death_when_offline_birth_when_back() {
        let mut n = node();
        n.nbirth(0, &[], 1);
        birth(&mut n, "pump-1");
        assert_eq!(n.on_drive(&view("pump-1", Some(true), 0.0), true, 6), None);
        let Some(DeviceMessage::Data(p)) = n.on_drive(&view("pump-1", Some(true), 12.5), true, 7) else {
            panic!()
        };
        let names: Vec<_> = p.metrics.iter().map(|m| m.name.clone().unwrap()).collect();
        assert_eq!(names, ["OutputFrequency", "Running"]);
        assert_eq!(p.metrics[0].timestamp, Some(1_000), "the time the drive answered");
        assert!(Node::live(p).metrics.iter().all(|m| m.name.is_none() && m.alias.is_some()));
        assert!(matches!(
            n.on_drive(&view("pump-1", Some(false), 12.5), true, 8),
            Some(DeviceMessage::Death(_))
        ));
        assert_eq!(n.on_drive(&view("pump-1", Some(false), 12.5), true, 9), None);
        assert!(matches!(
            n.on_drive(&view("pump-1", Some(true), 12.5), true, 10),
            Some(DeviceMessage::Birth(_))
        ));
        // A fault shows in FaultCode and FaultText.
        let mut v = view("pump-1", Some(true), 12.5);
        v.fault = Some(FaultView { code: 0x21, text: "overcurrent".into() });
        let Some(DeviceMessage::Data(p)) = n.on_drive(&v, true, 11) else { panic!() };
        assert_eq!(p.metrics[0].value, Some(Value::Int(0x21)));
        assert_eq!(p.metrics[1].value, Some(Value::String("overcurrent".into())));
    }

    #[test]
    fn values_heard_on_a_line_another_gateway_masters_are_marked_standby_until_polled_here() {
        let mut n = node();
        n.nbirth(0, &[], 1);
        // Born while its bus listens: the values are the other master's, heard.
        let mut v = view("pump-1", Some(true), 10.0);
        v.source = "standby";
        let Some(DeviceMessage::Birth(p)) = n.on_drive(&v, true, 5) else { panic!("no DBIRTH") };
        let source = p.metrics.iter().find(|m| m.name.as_deref() == Some("Source")).expect("Source");
        assert_eq!(source.value, Some(Value::String("standby".into())), "{source:?}");
        assert_eq!(source.datatype, Some(DataType::String as u32));
        // Its bus taken: the mark changes, in a DDATA of that metric alone.
        v.source = "master";
        let Some(DeviceMessage::Data(p)) = n.on_drive(&v, true, 6) else { panic!("no DDATA") };
        let names: Vec<_> = p.metrics.iter().map(|m| m.name.clone().unwrap()).collect();
        assert_eq!(names, ["Source"]);
        assert_eq!(p.metrics[0].value, Some(Value::String("master".into())));
        // A drive of a bus it masters says so from its birth.
        let p = birth(&mut n, "pump-2");
        let source = p.metrics.iter().find(|m| m.name.as_deref() == Some("Source")).expect("Source");
        assert_eq!(source.value, Some(Value::String("master".into())));
    }

    #[test]
    fn kept_data_goes_back_out_with_this_session_s_aliases_flagged_historical() {
        let mut n = node();
        // Nobody listens: data is made with names for the store.
        let Some(DeviceMessage::Data(p)) = n.on_drive(&view("pump-1", Some(true), 3.0), false, 1) else {
            panic!()
        };
        let kept = Node::to_keep(p);
        assert!(kept.metrics.iter().all(|m| m.alias.is_none() && m.name.is_some()));
        assert_eq!(n.historical("pump-1", kept.clone()), None, "not born yet");
        n.nbirth(0, &[], 2);
        let b = birth(&mut n, "pump-1");
        let h = n.historical("pump-1", kept).unwrap();
        let hz_alias = b.metrics.iter().find(|m| m.name.as_deref() == Some("OutputFrequency")).unwrap().alias;
        assert_eq!(h.metrics[0].alias, hz_alias);
        assert!(h.metrics.iter().all(|m| m.is_historical == Some(true) && m.name.is_none()));
    }

    fn cmd(name: &str, value: Value, datatype: DataType) -> Payload {
        Payload {
            metrics: vec![Metric {
                name: Some(name.into()),
                datatype: Some(datatype as u32),
                value: Some(value),
                ..Metric::default()
            }],
            ..Payload::default()
        }
    }

    #[test]
    fn commands_are_read_by_name_or_alias_and_checked_before_any_is_sent() {
        let mut n = node();
        n.nbirth(0, &[], 1);
        let b = birth(&mut n, "pump-1");
        let alias = |name: &str| b.metrics.iter().find(|m| m.name.as_deref() == Some(name)).unwrap().alias;
        assert_eq!(
            n.device_command("pump-1", &cmd("Setpoint", Value::Double(30.0), DataType::Double)),
            Ok(vec![Command::Speed(30.0)])
        );
        let mut by_alias = cmd("x", Value::Boolean(true), DataType::Boolean);
        by_alias.metrics[0].name = None;
        by_alias.metrics[0].alias = alias("Command/Run");
        assert_eq!(n.device_command("pump-1", &by_alias), Ok(vec![Command::Run]));
        let p = params().iter().find(|p| p.max > p.min).unwrap().clone();
        let ok = p.from_raw(p.min);
        assert_eq!(
            n.device_command(
                "pump-1",
                &cmd(&format!("Parameters/{}", p.name), Value::Double(ok), DataType::Double)
            ),
            Ok(vec![Command::SetParam { name: p.name.clone(), value: format!("{ok}"), eeprom: false }])
        );
        let kind = |r: Result<Vec<Command>, Refusal>| r.unwrap_err().kind;
        assert_eq!(
            kind(n.device_command("pump-9", &cmd("Setpoint", Value::Double(1.0), DataType::Double))),
            "unknown_device"
        );
        assert_eq!(
            kind(n.device_command("pump-1", &cmd("Speed", Value::Double(1.0), DataType::Double))),
            "unknown_metric"
        );
        assert_eq!(
            kind(n.device_command("pump-1", &cmd("OutputFrequency", Value::Double(1.0), DataType::Double))),
            "unknown_metric"
        );
        assert_eq!(
            kind(n.device_command("pump-1", &cmd("Setpoint", Value::String("x".into()), DataType::String))),
            "wrong_type"
        );
        assert_eq!(
            kind(n.device_command("pump-1", &cmd("Setpoint", Value::Float(3.0), DataType::Double))),
            "wrong_type"
        );
        assert_eq!(
            kind(n.device_command("pump-1", &cmd("Setpoint", Value::Double(-1.0), DataType::Double))),
            "out_of_range"
        );
        assert_eq!(
            kind(n.device_command("pump-1", &cmd("Setpoint", Value::Double(f64::NAN), DataType::Double))),
            "out_of_range"
        );
        assert_eq!(
            kind(n.device_command("pump-1", &cmd("Command/Stop", Value::Boolean(false), DataType::Boolean))),
            "out_of_range"
        );
        let too_big = p.from_raw(p.max) + 1000.0;
        assert_eq!(
            kind(n.device_command(
                "pump-1",
                &cmd(&format!("Parameters/{}", p.name), Value::Double(too_big), DataType::Double)
            )),
            "out_of_range"
        );
        // One bad metric refuses the whole message.
        let mut both = cmd("Command/Run", Value::Boolean(true), DataType::Boolean);
        both.metrics.extend(cmd("Nonsense", Value::Boolean(true), DataType::Boolean).metrics);
        assert_eq!(kind(n.device_command("pump-1", &both)), "unknown_metric");
        assert_eq!(
            n.node_command(&cmd(REBIRTH, Value::Boolean(true), DataType::Boolean)),
            Ok(vec![NodeCommand::Rebirth])
        );
        assert_eq!(
            n.node_command(&cmd(REBIRTH, Value::Boolean(false), DataType::Boolean)).unwrap_err().kind,
            "out_of_range"
        );
        assert_eq!(
            n.node_command(&cmd("Reboot", Value::Boolean(true), DataType::Boolean)).unwrap_err().kind,
            "unknown_metric"
        );
    }

    #[test]
    fn a_removed_drive_needs_a_death_and_a_new_one_new_aliases() {
        let mut n = node();
        let nb = n.nbirth(0, &[], 1);
        let a = birth(&mut n, "pump-1");
        birth(&mut n, "pump-2");
        let dead = n.sync_devices(vec![("pump-1".into(), plain()), ("fan-1".into(), plain())]);
        assert_eq!(dead, ["pump-2"]);
        assert!(n.is_born("pump-1") && !n.is_born("fan-1"));
        let f = birth(&mut n, "fan-1");
        let used: Vec<u64> = nb.metrics.iter().chain(&a.metrics).filter_map(|m| m.alias).collect();
        assert!(f.metrics.iter().all(|m| !used.contains(&m.alias.unwrap())));
    }
}
