//! The timestamps of a drive's OPC UA values (docs/opcua.md, "Values, timestamps and status"):
//! the drive's values carry the time it last answered, the gateway's own variables the time they
//! were computed, and `AgeMs` is the gap between the two.

use drivebus_gateway::core::DriveView;
use drivebus_gateway::opcua::nodes::DRIVE_VARIABLES;
use drivebus_gateway::opcua::{datetime_ms, drive_values};
use opcua::types::{DataValue, StatusCode, Variant};

fn view(last_seen_ms: Option<i64>, age_ms: Option<u64>, online: Option<bool>) -> DriveView {
    DriveView {
        id: "pump-1".into(),
        bus: "line-1".into(),
        family: "toshiba".into(),
        protocol: "toshiba-binary".into(),
        address: 1,
        unit_id: 1,
        locked: false,
        online,
        running: Some(false),
        direction: Some("forward".into()),
        output_hz: Some(0.0),
        setpoint_hz: Some(0.0),
        current_a: Some(0.0),
        fault: None,
        values: Default::default(),
        age_ms,
        last_seen_ms,
        error_rate: 0.0,
        polls: 3,
        last_error: None,
        poll_ms: 500,
        source: "master",
    }
}

fn by_name(values: &[DataValue], name: &str) -> DataValue {
    let i = DRIVE_VARIABLES.iter().position(|d| d.name == name).unwrap();
    values[i].clone()
}

#[test]
fn the_drives_values_carry_the_time_it_last_answered_and_age_ms_is_the_gap_to_now() {
    let answered = 1_800_000_000_000;
    let now = datetime_ms(answered + 120);
    let values = drive_values(&view(Some(answered), Some(120), Some(true)), true, now);
    for name in ["OutputFrequency", "Setpoint", "Current", "Running", "Direction", "FaultCode", "FaultText"] {
        let v = by_name(&values, name);
        assert_eq!(v.status(), StatusCode::Good, "{name}");
        assert_eq!(v.source_timestamp, Some(datetime_ms(answered)), "{name}: the poll that confirmed it");
        assert_eq!(v.server_timestamp, Some(now), "{name}");
    }
    let age = by_name(&values, "AgeMs");
    assert_eq!(age.value, Some(Variant::Double(120.0)));
    assert_eq!(age.source_timestamp, Some(now), "the gateway's own knowledge, computed now");
    let gap = age.server_timestamp.unwrap().ticks()
        - by_name(&values, "FaultCode").source_timestamp.unwrap().ticks();
    assert_eq!(gap / 10_000, 120, "AgeMs = its server timestamp - the values' source timestamp");
}

#[test]
fn an_offline_drive_keeps_the_time_of_its_last_answer_and_a_new_one_has_none_yet() {
    let answered = 1_800_000_000_000;
    let now = datetime_ms(answered + 60_000);
    let values = drive_values(&view(Some(answered), Some(60_000), Some(false)), true, now);
    let hz = by_name(&values, "OutputFrequency");
    assert_eq!(hz.status(), StatusCode::BadNoCommunication);
    assert_eq!(hz.source_timestamp, Some(datetime_ms(answered)));
    assert_eq!(by_name(&values, "Online").status(), StatusCode::Good);

    let values = drive_values(&view(None, None, None), true, now);
    let hz = by_name(&values, "OutputFrequency");
    assert_eq!(hz.status(), StatusCode::BadWaitingForInitialData);
    assert_eq!(hz.source_timestamp, Some(now));
}

#[test]
fn a_standby_says_so_in_source_and_its_fresh_values_stay_good() {
    let answered = 1_800_000_000_000;
    let now = datetime_ms(answered + 120);
    let mut v = view(Some(answered), Some(120), Some(true));
    assert_eq!(by_name(&drive_values(&v, true, now), "Source").value, Some(Variant::from("master")));
    v.source = "standby";
    let values = drive_values(&v, true, now);
    let source = by_name(&values, "Source");
    assert_eq!(source.value, Some(Variant::from("standby")));
    assert_eq!((source.status(), source.source_timestamp), (StatusCode::Good, Some(now)));
    let hz = by_name(&values, "OutputFrequency");
    assert_eq!(hz.status(), StatusCode::Good, "heard values are the drive's answers, fresh");
    assert_eq!(hz.source_timestamp, Some(datetime_ms(answered)));
}
