//! Trip forensics in the gateway: the detail of a `trip` event, with the drive's values just
//! before the trip (the cache's last status) and as the poll that saw the trip found them.

use drivebus_drive::profile::{DriveStatus, Fault};
use serde_json::{json, Value};

/// A status as the trip event keeps it.
fn values(s: &DriveStatus) -> Value {
    json!({
        "running": s.running,
        "direction": s.direction,
        "output_hz": s.output_hz,
        "setpoint_hz": s.setpoint_hz,
        "current_a": s.current_a,
    })
}

/// The detail of a `trip` event: `{"code", "text", "before": {"time_ms", "running",
/// "direction", "output_hz", "setpoint_hz", "current_a", "commanded_hz"} or null, "at_trip":
/// {...}}`. `before` is the last status the cache held (read at `before_ms`), null when the
/// drive was tripped at the first poll; `commanded_hz` is the last speed commanded through the
/// gateway; `at_trip` is the poll that saw the trip.
pub fn trip_detail(
    fault: &Fault,
    before: Option<&DriveStatus>,
    before_ms: Option<i64>,
    commanded_hz: Option<f64>,
    at_trip: &DriveStatus,
) -> Value {
    let before = before.map(|s| {
        let mut v = values(s);
        v["time_ms"] = json!(before_ms);
        v["commanded_hz"] = json!(commanded_hz);
        v
    });
    json!({ "code": fault.code, "text": fault.text, "before": before, "at_trip": values(at_trip) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_detail_keeps_the_values_before_and_at_the_trip() {
        let fault = Fault { code: 3, text: "OC3".into() };
        let before =
            DriveStatus { running: true, output_hz: Some(40.0), current_a: Some(7.5), ..Default::default() };
        let at = DriveStatus { fault: Some(fault.clone()), ..Default::default() };
        let d = trip_detail(&fault, Some(&before), Some(1000), Some(40.0), &at);
        assert_eq!(d["code"], 3);
        assert_eq!(d["before"]["output_hz"], 40.0);
        assert_eq!(d["before"]["current_a"], 7.5);
        assert_eq!(d["before"]["time_ms"], 1000);
        assert_eq!(d["at_trip"]["running"], false);
        assert!(trip_detail(&fault, None, None, None, &at)["before"].is_null());
    }
}
