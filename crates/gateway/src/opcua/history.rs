//! Historical access: the drive variables the store keeps as trends (OutputFrequency, Setpoint,
//! Current; [`super::nodes::VariableDef::trend`]) answer HistoryRead (raw) from the store's
//! buckets, the same points `GET /api/drives/<id>/trend` gives for the same span: start
//! included, end excluded, 1 s buckets for spans up to an hour, 1 min beyond.

use std::sync::Arc;

use drivebus_store::{Resolution, TrendPoint, TrendQuery};
use opcua::server::node_manager::HistoryNode;
use opcua::server::ContinuationPoint;
use opcua::types::{
    DataValue, DateTime, HistoryData, ReadRawModifiedDetails, StatusCode, TimestampsToReturn, Variant,
};

use super::nodes::{Ids, Target, DRIVE_VARIABLES};
use super::space::Space;
use crate::core::Gateway;

/// The most values one answer carries when the client asks for all (0): the rest follows
/// with a continuation point.
pub const MAX_VALUES: usize = 10_000;

/// Where a read left off: the span and resolution it started with, and the time of the last
/// point given.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Position {
    /// Start of the span (included), unix ms.
    pub since_ms: i64,
    /// End of the span (excluded), unix ms.
    pub until_ms: i64,
    /// The buckets read.
    pub resolution: Resolution,
    /// Oldest first (start before end) or newest first.
    pub forward: bool,
}

/// The span a ReadRawModified details names, at `now_ms`: `None` when it names neither a start
/// nor an end (`Bad_HistoryOperationInvalid`). Only a start: from it to now; only an end: back
/// from it over the store's retention.
pub fn span(start: Option<i64>, end: Option<i64>, now_ms: i64) -> Option<Position> {
    let (since_ms, until_ms, forward) = match (start, end) {
        (None, None) => return None,
        (Some(s), None) => (s, now_ms.max(s), true),
        (None, Some(e)) => (e.saturating_sub(Resolution::Minute.retention_ms()), e, false),
        (Some(s), Some(e)) if s <= e => (s, e, true),
        (Some(s), Some(e)) => (e, s, false),
    };
    let resolution = Resolution::for_span(until_ms.saturating_sub(since_ms));
    Some(Position { since_ms, until_ms, resolution, forward })
}

/// The points of `points` (in time order) to give after `position`'s last point: at most
/// `max`, in the read's direction; and the position to go on from when more are left.
pub fn page(
    mut points: Vec<TrendPoint>,
    position: Position,
    max: usize,
) -> (Vec<TrendPoint>, Option<Position>) {
    if !position.forward {
        points.reverse();
    }
    if points.len() <= max {
        return (points, None);
    }
    points.truncate(max);
    let last = points[max - 1].time_ms;
    let next = if position.forward {
        Position { since_ms: last + 1, ..position }
    } else {
        Position { until_ms: last, ..position }
    };
    (points, Some(next))
}

/// Unix ms of an OPC UA DateTime, `None` for the null (min) time.
fn unix_ms(t: &DateTime) -> Option<i64> {
    if t.is_null() {
        return None;
    }
    Some(t.checked_ticks().saturating_sub(116_444_736_000_000_000) / 10_000)
}

/// A trend point's value of `variable`.
fn value_of(p: &TrendPoint, variable: &str) -> Option<f64> {
    match variable {
        "OutputFrequency" => p.output_hz,
        "Current" => p.current_a,
        "Setpoint" => p.setpoint_hz,
        _ => None,
    }
}

/// Answers a HistoryRead (raw) for `nodes`.
pub async fn read_raw(
    gw: &Arc<Gateway>,
    ids: &Ids,
    space: &Space,
    details: &ReadRawModifiedDetails,
    nodes: &mut [&mut HistoryNode],
    timestamps: TimestampsToReturn,
) {
    for node in nodes.iter_mut() {
        let id = node.node_id().clone();
        if id.namespace != ids.ns {
            continue;
        }
        if !space.view().exists(&id) {
            node.set_status(StatusCode::BadNodeIdUnknown);
            continue;
        }
        let (drive, variable) = match ids.target(&id) {
            Target::DriveVariable { drive, variable }
                if DRIVE_VARIABLES.iter().any(|d| d.name == variable && d.trend) && gw.store().is_some() =>
            {
                (drive, variable)
            }
            _ => {
                node.set_status(StatusCode::BadHistoryOperationUnsupported);
                continue;
            }
        };
        if details.is_read_modified {
            node.set_status(StatusCode::BadHistoryOperationUnsupported);
            continue;
        }
        if timestamps == TimestampsToReturn::Neither {
            node.set_status(StatusCode::BadTimestampsToReturnInvalid);
            continue;
        }
        let position = match node.continuation_point() {
            Some(cp) => match cp.get::<Position>() {
                Some(p) => *p,
                None => {
                    node.set_status(StatusCode::BadContinuationPointInvalid);
                    continue;
                }
            },
            None => {
                let (start, end) = (unix_ms(&details.start_time), unix_ms(&details.end_time));
                match span(start, end, drivebus_store::time::now_ms()) {
                    Some(p) => p,
                    None => {
                        node.set_status(StatusCode::BadHistoryOperationInvalid);
                        continue;
                    }
                }
            }
        };
        let max = match details.num_values_per_node {
            0 => MAX_VALUES,
            n => (n as usize).min(MAX_VALUES),
        };
        let query = TrendQuery {
            drive,
            since_ms: position.since_ms,
            until_ms: position.until_ms,
            resolution: position.resolution,
        };
        let gw2 = gw.clone();
        let points = tokio::task::spawn_blocking(move || gw2.store().map(|s| s.trend(&query))).await;
        let points = match points {
            Ok(Some(Ok(points))) => points,
            _ => {
                node.set_status(StatusCode::BadResourceUnavailable);
                continue;
            }
        };
        let (points, next) = page(points, position, max);
        let data_values = points
            .iter()
            .filter_map(|p| {
                let v = value_of(p, &variable)?;
                let t = super::datetime_ms(p.time_ms);
                let (source, server) = match timestamps {
                    TimestampsToReturn::Source => (Some(t), None),
                    TimestampsToReturn::Server => (None, Some(t)),
                    _ => (Some(t), Some(t)),
                };
                Some(DataValue {
                    value: Some(Variant::Double(v)),
                    status: Some(StatusCode::Good),
                    source_timestamp: source,
                    server_timestamp: server,
                    ..Default::default()
                })
            })
            .collect();
        node.set_result(HistoryData { data_values: Some(data_values) });
        node.set_next_continuation_point(next.map(|p| ContinuationPoint::new(Box::new(p))));
        node.set_status(StatusCode::Good);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(time_ms: i64) -> TrendPoint {
        TrendPoint {
            time_ms,
            output_hz: Some(time_ms as f64),
            current_a: None,
            output_hz_min: None,
            output_hz_max: None,
            setpoint_hz: None,
            samples: 1,
        }
    }

    #[test]
    fn a_span_follows_the_http_trends_rules() {
        let p = span(Some(1_000), Some(61_000), 0).unwrap();
        assert_eq!(
            (p.since_ms, p.until_ms, p.forward, p.resolution),
            (1_000, 61_000, true, Resolution::Second)
        );
        // End before start: newest first.
        let p = span(Some(61_000), Some(1_000), 0).unwrap();
        assert_eq!((p.since_ms, p.until_ms, p.forward), (1_000, 61_000, false));
        // Over an hour: minutes.
        assert_eq!(span(Some(0), Some(3_600_001), 0).unwrap().resolution, Resolution::Minute);
        // Only a start: up to now.
        assert_eq!(span(Some(5), None, 100).unwrap().until_ms, 100);
        assert!(span(None, None, 100).is_none());
    }

    #[test]
    fn pages_go_on_where_the_last_stopped_in_either_direction() {
        let all: Vec<_> = (0..5).map(|i| point(i * 1000)).collect();
        let start = span(Some(0), Some(5000), 0).unwrap();
        let (first, next) = page(all.clone(), start, 2);
        assert_eq!(first.iter().map(|p| p.time_ms).collect::<Vec<_>>(), [0, 1000]);
        let next = next.unwrap();
        assert_eq!(next.since_ms, 1001);
        let rest: Vec<_> = all.iter().filter(|p| p.time_ms >= next.since_ms).cloned().collect();
        let (second, next) = page(rest, next, 10);
        assert_eq!(second.iter().map(|p| p.time_ms).collect::<Vec<_>>(), [2000, 3000, 4000]);
        assert!(next.is_none());
        let back = span(Some(5000), Some(0), 0).unwrap();
        let (first, next) = page(all, back, 2);
        assert_eq!(first.iter().map(|p| p.time_ms).collect::<Vec<_>>(), [4000, 3000]);
        assert_eq!(next.unwrap().until_ms, 3000);
    }
}
