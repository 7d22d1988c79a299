//! A drive tripping while the gateway polls it: the `trip` event in the store keeps the drive's
//! values just before the trip (from the cache) and at the poll that saw it.

mod support;

use std::time::Duration;

use drivebus_gateway::core::Command;
use drivebus_gateway::{Gateway, GatewayConfig};
use drivebus_store::{EventFilter, EventKind};
use support::fresh_store;

#[tokio::test(start_paused = true)]
async fn a_trip_is_stored_with_the_values_before_it() {
    let (path, store) = fresh_store("trip-forensics");
    let text = "[store]\ndisabled = true\n\
        [[bus]]\nname = \"line\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
        [[bus.drive]]\nname = \"fan\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 250\n";
    let gw = Gateway::start(GatewayConfig::from_toml("t.toml", text).unwrap(), Some(store)).unwrap();
    gw.command("fan", Command::Speed(30.0), "test").await.unwrap();
    gw.command("fan", Command::Run, "test").await.unwrap();
    // Paused time: the virtual clock advances as far as the polls need.
    for _ in 0..120 {
        tokio::time::sleep(Duration::from_millis(500)).await;
        let v = gw.drive_view(&gw.drive("fan").unwrap());
        if v.output_hz.is_some_and(|hz| (hz - 30.0).abs() < 0.01) {
            break;
        }
    }
    let v = gw.drive_view(&gw.drive("fan").unwrap());
    assert_eq!(v.output_hz, Some(30.0), "{v:?}");
    let bus = gw.buses().iter().find(|b| b.config.name == "line").unwrap().clone();
    {
        let mut line = bus.line.as_ref().unwrap().lock().unwrap();
        let port = (0..=line.devices()).find(|&p| line.drive(p).is_some()).expect("a drive on the line");
        let d = line.drive_mut(port).expect("the fan");
        d.core_mut().model.trip_now(drivebus_sim::model::Trip::OverCurrent);
    }
    let filter = EventFilter { drive: Some("fan".into()), kind: Some(EventKind::Trip), ..Default::default() };
    let mut trips = Vec::new();
    for _ in 0..120 {
        tokio::time::sleep(Duration::from_millis(500)).await;
        trips = gw.store().unwrap().events(&filter).unwrap();
        if !trips.is_empty() {
            break;
        }
    }
    assert_eq!(trips.len(), 1, "one trip event: {trips:?}");
    let d = &trips[0].detail;
    assert_eq!(d["code"], 1, "{d}");
    assert_eq!(d["text"], "over-current", "{d}");
    let before = &d["before"];
    assert_eq!(before["running"], true, "{d}");
    assert_eq!(before["output_hz"], 30.0, "{d}");
    assert_eq!(before["setpoint_hz"], 30.0, "{d}");
    assert_eq!(before["commanded_hz"], 30.0, "{d}");
    assert!(before["current_a"].as_f64().is_some_and(|a| a > 0.0), "{d}");
    let ms = before["time_ms"].as_i64().expect("when the values were read");
    assert!(ms <= trips[0].time_ms, "{d}");
    // The poll that saw the trip: the motor coasts, no longer driven.
    assert_eq!(d["at_trip"]["running"], false, "{d}");
    drop(gw);
    let _ = std::fs::remove_file(&path);
}
