//! The gateway over virtual buses on a virtual clock: polling fills the cache, commands go
//! through and are audited, linkage follows, locks refuse.

mod support;

use drivebus_gateway::core::{Change, Command, CommandError};
use drivebus_gateway::{Gateway, GatewayConfig};
use support::{fresh_store, settle};

#[tokio::test(start_paused = true)]
async fn the_demo_polls_every_drive_and_runs_one() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    settle(3).await;
    for d in gw.drives().iter() {
        let v = gw.drive_view(d);
        assert_eq!(v.online, Some(true), "{} not online: {:?}", v.id, v.last_error);
        assert_eq!(v.running, Some(false), "{}", v.id);
        assert!(v.age_ms.is_some());
    }
    gw.command("pump-1", Command::Speed(40.0), "test").await.unwrap();
    gw.command("pump-1", Command::Run, "test").await.unwrap();
    settle(20).await;
    let v = gw.drive_view(&gw.drive("pump-1").unwrap());
    assert_eq!(v.running, Some(true));
    let hz = v.output_hz.unwrap();
    assert!((hz - 40.0).abs() < 0.05, "pump-1 at {hz} Hz");
    for b in gw.buses().iter() {
        let s = gw.bus_view(b);
        assert!(s.transactions > 0 && s.online, "{s:?}");
    }
}

#[tokio::test(start_paused = true)]
async fn every_family_runs_to_its_setpoint() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    for id in ["conveyor-1", "pump-2", "ahu-1", "mixer-1"] {
        gw.command(id, Command::Speed(30.0), "test").await.unwrap_or_else(|e| panic!("{id}: {e}"));
        gw.command(id, Command::Run, "test").await.unwrap_or_else(|e| panic!("{id}: {e}"));
    }
    settle(30).await;
    for id in ["conveyor-1", "pump-2", "ahu-1", "mixer-1"] {
        let v = gw.drive_view(&gw.drive(id).unwrap());
        assert_eq!(v.running, Some(true), "{id}");
        let hz = v.output_hz.unwrap();
        assert!((hz - 30.0).abs() < 0.1, "{id} at {hz} Hz");
    }
    // conveyor-2 follows conveyor-1: 30 * 0.5 + 5 = 20 Hz setpoint.
    let v = gw.drive_view(&gw.drive("conveyor-2").unwrap());
    assert_eq!(v.setpoint_hz, Some(20.0), "{v:?}");
}

#[tokio::test(start_paused = true)]
async fn refusals_say_why() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    settle(2).await;
    let e = gw.command("pump-3", Command::Run, "test").await.unwrap_err();
    assert!(matches!(e, CommandError::Locked(_)), "{e}");
    assert_eq!(drivebus_gateway::modbus_tcp::exception_of(&e).0, 0x01);
    let e = gw.command("nobody", Command::Run, "test").await.unwrap_err();
    assert_eq!(drivebus_gateway::http::error::status_of(&e).as_u16(), 404);
    let e = gw.command("fan-1", Command::Speed(500.0), "test").await.unwrap_err();
    assert!(matches!(e, CommandError::Invalid(_)), "{e}");
    assert_eq!(drivebus_gateway::modbus_tcp::exception_of(&e).0, 0x03);
    let e = gw.command("fan-1", Command::Speed(f64::NAN), "test").await.unwrap_err();
    assert_eq!(drivebus_gateway::http::error::status_of(&e).as_u16(), 422);
}

#[tokio::test(start_paused = true)]
async fn changes_are_streamed() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    let mut rx = gw.subscribe();
    gw.command("mixer-2", Command::Run, "test").await.unwrap();
    let mut saw_command = false;
    let mut saw_drive = false;
    while !(saw_command && saw_drive) {
        match rx.recv().await.unwrap() {
            Change::Event(e) if e.action.as_deref() == Some("run") => saw_command = true,
            Change::Drive(v) if v.id == "mixer-2" => saw_drive = true,
            _ => {}
        }
    }
}

#[tokio::test(start_paused = true)]
async fn parameters_read_from_the_drive() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    let p = gw.read_param("ahu-1", "4-14", "test").await.unwrap();
    assert_eq!(p.unit, "Hz");
    gw.command("ahu-1", Command::SetParam { name: "4-14".into(), value: "55".into(), eeprom: false }, "t")
        .await
        .unwrap();
    assert_eq!(gw.read_param("ahu-1", "4-14", "test").await.unwrap().value, 55.0);
    let e = gw.read_param("ahu-1", "99-99", "test").await.unwrap_err();
    assert_eq!(drivebus_gateway::http::error::status_of(&e).as_u16(), 422, "{e}");
}

#[test]
fn events_log_as_one_line() {
    use drivebus_gateway::core::log_line;
    use drivebus_store::{Event, EventKind};
    let mut e = Event::new(1_795_301_254_481, EventKind::Command);
    e.bus = Some("line-1".into());
    e.drive = Some("pump-1".into());
    e.actor = Some("http:scada@10.0.0.9".into());
    e.action = Some("speed 40 Hz".into());
    e.result = Some("ok".into());
    assert_eq!(
        log_line(&e),
        "2026-11-21T22:47:34.481Z command line-1/pump-1 speed 40 Hz by http:scada@10.0.0.9: ok"
    );
    let mut t = Event::new(1_795_301_254_481, EventKind::Trip);
    t.bus = Some("line-1".into());
    t.drive = Some("pump-1".into());
    t.actor = Some("gateway".into());
    t.detail = serde_json::json!({ "code": 3 });
    assert_eq!(log_line(&t), "2026-11-21T22:47:34.481Z trip line-1/pump-1 {\"code\":3}");
}

/// A follower that answers its polls but cannot take the linkage's setpoint once the leader is
/// past 16.7 Hz (three times that is above its 50 Hz limit): the audit trail has the linkage
/// taking hold (at 0 Hz) and failing, not one record per leader poll; polls and an operator's
/// command in between do not make the failure look new.
#[tokio::test(start_paused = true)]
async fn a_failing_linkage_is_audited_once_while_the_follower_polls_fine() {
    let (path, store) = fresh_store("linkage-fail");
    let text = "[store]\ndisabled = true\n\
        [[bus]]\nname = \"line\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
        [[bus.drive]]\nname = \"lead\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 250\n\
        [[bus.drive]]\nname = \"follow\"\nfamily = \"generic\"\naddress = 2\npoll_ms = 250\n\
        [[linkage]]\nleader = \"lead\"\nfollower = \"follow\"\nratio = 3.0\n";
    let gw = Gateway::start(GatewayConfig::from_toml("t.toml", text).unwrap(), Some(store)).unwrap();
    gw.command("lead", Command::Speed(30.0), "test").await.unwrap();
    gw.command("lead", Command::Run, "test").await.unwrap();
    settle(30).await;
    let view = gw.drive_view(&gw.drive("follow").unwrap());
    assert_eq!(view.online, Some(true), "the follower answers its polls");
    let filter =
        drivebus_store::EventFilter { drive: Some("follow".into()), limit: 1000, ..Default::default() };
    let linkage = || {
        let events = gw.store().unwrap().events(&filter).unwrap();
        events.into_iter().filter(|e| e.actor.as_deref() == Some("linkage:lead")).collect::<Vec<_>>()
    };
    let results = || -> Vec<String> { linkage().iter().filter_map(|e| e.result.clone()).collect() };
    let seen = results();
    assert_eq!(seen.len(), 2, "{seen:?}");
    assert_eq!(seen[0], "ok", "taking hold at 0 Hz: {seen:?}");
    assert!(seen[1].starts_with("error: ") && seen[1].contains("upper limit"), "{seen:?}");
    // An operator's command to the follower is not the linkage recovering.
    gw.command("follow", Command::Speed(10.0), "test").await.unwrap();
    settle(10).await;
    assert_eq!(results().len(), 2, "{:?}", results());
    drop(gw);
    let _ = std::fs::remove_file(&path);
}

#[tokio::test(start_paused = true)]
async fn linkage_taking_hold_is_audited_once_not_per_poll() {
    let (path, store) = fresh_store("linkage-audit");
    let gw = Gateway::start(GatewayConfig::demo(), Some(store)).unwrap();
    gw.command("conveyor-1", Command::Speed(30.0), "test").await.unwrap();
    gw.command("conveyor-1", Command::Run, "test").await.unwrap();
    settle(30).await;
    // conveyor-2 follows conveyor-1 through many polls while it ramps: one audit record.
    let filter =
        drivebus_store::EventFilter { drive: Some("conveyor-2".into()), limit: 1000, ..Default::default() };
    let events = gw.store().unwrap().events(&filter).unwrap();
    let linkage: Vec<_> =
        events.iter().filter(|e| e.actor.as_deref() == Some("linkage:conveyor-1")).collect();
    assert_eq!(linkage.len(), 1, "{events:?}");
    assert_eq!(linkage[0].result.as_deref(), Some("ok"));
    assert!(linkage[0].action.as_deref().is_some_and(|a| a.starts_with("speed ")), "{:?}", linkage[0]);
    drop(gw);
    let _ = std::fs::remove_file(&path);
}

/// One profile per drive: what a command teaches the profile shows in the next poll. The
/// Danfoss profile keeps the reference it sends in every telegram; a second profile for polls
/// reported 0 Hz after `speed 33` and `run` (the drive ran at 33 Hz).
#[tokio::test(start_paused = true)]
async fn a_speed_set_shows_as_the_setpoint_in_the_next_poll_for_every_family() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    settle(2).await;
    for id in ["conveyor-1", "pump-1", "ahu-1", "mixer-1"] {
        let mut changes = gw.subscribe();
        gw.command(id, Command::Speed(33.0), "test").await.unwrap_or_else(|e| panic!("{id}: {e}"));
        gw.command(id, Command::Run, "test").await.unwrap_or_else(|e| panic!("{id}: {e}"));
        // A poll already on the wire when the command was confirmed may answer first: the poll
        // after it is the first that started after the command.
        let p0 = gw.drive(id).unwrap().state().polls;
        let polled = loop {
            match changes.recv().await {
                Ok(Change::Drive(v)) if v.id == id && v.polls >= p0 + 2 => break v,
                Ok(_) => {}
                Err(e) => panic!("{id}: {e}"),
            }
        };
        assert_eq!(polled.setpoint_hz, Some(33.0), "{id}: {polled:?}");
    }
}

/// Refused writes do not flood the audit trail (issue 13, defect 5): 5 000 refusals from one
/// address over many connections are the first one at once and one event with the count when
/// the minute is over; another client's first refusal is audited at once as well.
#[tokio::test(start_paused = true)]
async fn repeated_refusals_are_one_audit_event_per_client_reason_and_minute() {
    let (path, store) = fresh_store("refusal-flood");
    let gw = Gateway::start(GatewayConfig::demo(), Some(store)).unwrap();
    let why = "forbidden: client 127.0.0.2 may not write ([modbus] allow)";
    for k in 0..5000u32 {
        let actor = format!("modbus:127.0.0.2:{}", 40000 + k % 64);
        gw.audit_refusal("pump-1", &actor, "modbus write of 1 register(s) at 0", why).await;
    }
    gw.audit_refusal("pump-1", "modbus:127.0.0.3:5000", "modbus write of 1 register(s) at 0", why).await;
    let refused = || {
        let filter = drivebus_store::EventFilter { limit: 10_000, ..Default::default() };
        let events = gw.store().unwrap().events(&filter).unwrap();
        events
            .into_iter()
            .filter(|e| e.actor.as_deref().is_some_and(|a| a.starts_with("modbus:127.0.0.")))
            .collect::<Vec<_>>()
    };
    assert_eq!(refused().len(), 2, "{:?}", refused());
    settle(61).await;
    let events = refused();
    assert_eq!(events.len(), 3, "{events:?}");
    let summary = events.iter().find(|e| e.actor.as_deref() == Some("modbus:127.0.0.2")).expect("a summary");
    assert_eq!(
        summary.result.as_deref(),
        Some(format!("4999 refused from modbus:127.0.0.2 in the last 60 s: {why}").as_str())
    );
    assert_eq!(summary.detail["repeated"], 4999);
    assert_eq!(summary.drive.as_deref(), Some("pump-1"));
    assert_eq!(gw.counters.commands_failed.load(std::sync::atomic::Ordering::Relaxed), 5001);
    // Quiet for a minute: nothing more; the next refusal is audited at once again.
    settle(120).await;
    assert_eq!(refused().len(), 3);
    gw.audit_refusal("pump-1", "modbus:127.0.0.2:1", "modbus write of 1 register(s) at 0", why).await;
    assert_eq!(refused().len(), 4);
    drop(gw);
    let _ = std::fs::remove_file(&path);
}

/// An offline drive is still polled, and its `polls` counter keeps rising with its failed polls
/// (issue 13, defect 10).
#[tokio::test(start_paused = true)]
async fn an_offline_drives_polls_keep_counting() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    settle(5).await;
    let bus = gw.buses().iter().find(|b| b.config.name == "line-generic").unwrap().clone();
    bus.line.as_ref().unwrap().lock().unwrap().set_silent(1, true);
    let d = gw.drive("conveyor-1").unwrap();
    settle(30).await;
    let offline = gw.drive_view(&d);
    assert_eq!(offline.online, Some(false), "{offline:?}");
    settle(60).await;
    let later = gw.drive_view(&d);
    assert!(later.polls > offline.polls, "polls stopped at {} while offline", later.polls);
    assert!(later.error_rate > offline.error_rate, "{offline:?} {later:?}");
}

/// A Danfoss drive's reference and MAV are 0x4000 = 100 % of 3-03: after a 3-03 write through
/// the gateway its polls scale MAV with the new 3-03 (one profile per drive learns it), so the
/// reported frequency is the one the drive runs at.
#[tokio::test(start_paused = true)]
async fn a_danfoss_3_03_write_changes_the_reported_scale() {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    settle(2).await;
    let bus = gw.buses().iter().find(|b| b.config.drives.iter().any(|d| d.name == "ahu-1")).unwrap().clone();
    let actual = || {
        let mut line = bus.line.as_ref().expect("a virtual bus").lock().unwrap();
        let port = (0..line.devices())
            .find(|&p| line.drive(p).is_some_and(|d| d.core().address == 1))
            .expect("ahu-1 on its line");
        line.drive(port).unwrap().core().model.output_hz()
    };
    let reported = |gw: &Gateway| gw.drive_view(&gw.drive("ahu-1").unwrap()).output_hz.unwrap_or(-1.0);
    // Steady: the drive at its speed, a poll after it got there.
    async fn steady(actual: &dyn Fn() -> f64, hz: f64) {
        let mut waited = 0;
        while (actual() - hz).abs() > 0.01 {
            assert!(waited < 120, "ahu-1 runs at {} Hz, not {hz} Hz", actual());
            settle(1).await;
            waited += 1;
        }
        settle(2).await;
    }
    gw.command("ahu-1", Command::Speed(20.0), "test").await.unwrap();
    gw.command("ahu-1", Command::Run, "test").await.unwrap();
    steady(&actual, 20.0).await;
    assert!(
        (reported(&gw) - actual()).abs() < 0.05,
        "reported {} Hz, runs at {} Hz",
        reported(&gw),
        actual()
    );
    let set = Command::SetParam { name: "3-03".into(), value: "100".into(), eeprom: false };
    gw.command("ahu-1", set, "test").await.unwrap();
    gw.command("ahu-1", Command::Speed(60.0), "test").await.unwrap();
    // 60 Hz is above the old 3-03 (50 Hz): the profile took the new scale for the reference
    // it sends and for the MAV it reads.
    steady(&actual, 60.0).await;
    assert!((reported(&gw) - 60.0).abs() < 0.05, "reported {} Hz, runs at {} Hz", reported(&gw), actual());
}

#[tokio::test(start_paused = true)]
async fn the_first_poll_after_the_start_up_listening_is_not_followed_by_another_at_once() {
    // An active gateway listens 500 ms before it sends; its drive is polled every 500 ms.
    let cfg = GatewayConfig::from_toml(
        "skew.toml",
        r#"
name = "skew"
[store]
disabled = true
[standby]
role = "active"
silence_ms = 500
[[bus]]
name = "line-1"
port = "virtual"
protocol = "modbus-rtu"
baud = 38400
serial = "8N2"
[[bus.drive]]
name = "pump-1"
family = "generic"
address = 1
poll_ms = 500
"#,
    )
    .unwrap();
    let gw = Gateway::start(cfg, None).unwrap();
    let bus = gw.buses()[0].clone();
    let sent = || gw.bus_view(&bus).transactions;
    support::wait_for("the first poll", std::time::Duration::from_secs(10), || sent() > 0).await;
    let started = tokio::time::Instant::now();
    assert!(gw.bus_view(&bus).role == "master");
    // Halfway to the second poll: the first poll's transactions alone. Then two polls a second.
    tokio::time::sleep_until(started + std::time::Duration::from_millis(250)).await;
    let first = sent();
    tokio::time::sleep_until(started + std::time::Duration::from_millis(1250)).await;
    let two = sent() - first;
    assert_eq!(
        first * 2,
        two,
        "the first poll ({first} transactions) was followed by another at once: the schedule \
         did not restart from the end of the listening ({two} transactions in the next second)"
    );
}
