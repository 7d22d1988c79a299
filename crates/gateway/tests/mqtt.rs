//! MQTT against an in-process broker (rumqttd) on a free port: retained statuses, commands by
//! topic (allowed, refused), the last will, a broker restart, Home Assistant discovery, and
//! two gateways side by side on one broker. Real sockets and the real clock: the waits are
//! generous and nothing asserts speed.

mod mqtt_support;
mod support;

use std::collections::HashSet;

use mqtt_support::*;
use serde_json::Value;

fn running_at(v: &Value, hz: f64) -> bool {
    v["running"] == true
        && v["setpoint_hz"].as_f64() == Some(hz)
        && v["output_hz"].as_f64().is_some_and(|x| x > 1.0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn statuses_are_retained_and_commands_move_a_drive() {
    let (broker, broker5) = rumqttd_both().await;
    let p = "drivebus/hall-a";
    let watcher = Subscriber::start(broker, "watcher", &format!("{p}/#")).await;
    // A retained command would run again at each reconnection of the gateway: refused.
    watcher.publish(&format!("{p}/line-toshiba/pump-1/set/run"), "1", true).await;
    watcher.wait("the broker to hold the retained command", |log| (!log.is_empty()).then_some(())).await;
    let gw = demo_gateway(
        "hall-a",
        broker5,
        &["line-toshiba/pump-1/*", "*/*/stop", "line-toshiba/pump-3/run"],
        false,
    );
    let r = watcher.wait_json(&format!("{p}/line-toshiba/pump-1/result"), |r| r["command"] == "run").await;
    assert_eq!(r["error"]["kind"], "retained", "{r}");
    // Clearing it (an empty retained message) is no command either: the next result is the
    // answer to the next command.
    watcher.publish(&format!("{p}/line-toshiba/pump-1/set/run"), "", true).await;

    // A subscriber that comes later gets every drive's status, retained.
    watcher.wait_json(&format!("{p}/line-toshiba/pump-2/status"), |v| v["online"] == true).await;
    let late = Subscriber::start(broker, "late", &format!("{p}/#")).await;
    wait_all_statuses(&late, p).await;
    let availability = late
        .wait(&format!("{p}/status"), |log| log.iter().find(|m| m.topic == format!("{p}/status")).cloned())
        .await;
    assert_eq!((availability.text.as_str(), availability.retain), ("online", true));
    let pump = late.latest()[&format!("{p}/line-toshiba/pump-1/status")].clone();
    let v: Value = serde_json::from_str(&pump.text).unwrap();
    assert_eq!(
        (v["family"].as_str(), v["unit_id"].as_u64(), v["running"].as_bool()),
        (Some("toshiba"), Some(4), Some(false))
    );

    // Speed as {"hz": ..} and run: results say ok, the drive runs, its status says so.
    watcher.publish(&format!("{p}/line-toshiba/pump-1/set/speed"), r#"{"hz": 35}"#, false).await;
    let r = watcher.wait_json(&format!("{p}/line-toshiba/pump-1/result"), |r| r["command"] != "run").await;
    assert_eq!((&r["command"], &r["ok"]), (&Value::from("speed"), &Value::from(true)), "{r}");
    assert_eq!(r["error"], Value::Null);
    watcher.publish(&format!("{p}/line-toshiba/pump-1/set/run"), "1", false).await;
    watcher
        .wait_json(&format!("{p}/line-toshiba/pump-1/result"), |r| r["command"] == "run" && r["ok"] == true)
        .await;
    watcher.wait_json(&format!("{p}/line-toshiba/pump-1/status"), |v| running_at(v, 35.0)).await;
    // The command is in the audit trail with the MQTT actor, and on the events topic.
    let e = watcher
        .wait_json(&format!("{p}/line-toshiba/pump-1/events"), |e| {
            e["kind"] == "command" && e["action"] == "run"
        })
        .await;
    assert_eq!(e["actor"], "mqtt:drivebus-hall-a");
    assert_eq!(e["result"], "ok");

    // A plain number works too, and stop is allowed everywhere.
    watcher.publish(&format!("{p}/line-toshiba/pump-1/set/speed"), "20", false).await;
    watcher
        .wait_json(&format!("{p}/line-toshiba/pump-1/status"), |v| v["setpoint_hz"].as_f64() == Some(20.0))
        .await;
    watcher.publish(&format!("{p}/line-toshiba/pump-1/set/stop"), "PRESS", false).await;
    watcher.wait_json(&format!("{p}/line-toshiba/pump-1/status"), |v| v["running"] == false).await;

    // Refusals: each gets a result with the reason, and nothing reaches a drive.
    let ok_before = gw.counters.commands_ok.load(std::sync::atomic::Ordering::Relaxed);
    let cases = [
        ("line-generic/fan-1/set/run", "1", "forbidden"), // not in allow_commands
        ("line-toshiba/pump-1/set/speed", "fast", "invalid"), // not a number
        ("line-toshiba/pump-1/set/explode", "1", "invalid"), // no such command
        ("line-generic/pump-1/set/stop", "1", "unknown_drive"), // wrong bus
        ("line-generic/nobody/set/stop", "1", "unknown_drive"), // no such drive
        ("line-toshiba/pump-3/set/run", "1", "locked"),   // allowed, but the drive is locked
    ];
    for (topic, payload, kind) in cases {
        let full = format!("{p}/{topic}");
        let result = format!("{}/result", full.rsplit_once("/set/").unwrap().0);
        let command = topic.rsplit('/').next().unwrap();
        watcher.publish(&full, payload, false).await;
        let r = watcher.wait_json(&result, |r| r["command"] == command && r["error"]["kind"] == kind).await;
        assert_eq!(r["ok"], false, "{topic}: {r}");
        assert!(!r["error"]["message"].as_str().unwrap().is_empty(), "{r}");
    }
    assert_eq!(gw.counters.commands_ok.load(std::sync::atomic::Ordering::Relaxed), ok_before);
    let fan = gw.drive_view(&gw.drive("fan-1").unwrap());
    assert_eq!(fan.running, Some(false));
    let pump = gw.drive_view(&gw.drive("pump-1").unwrap());
    assert_eq!(pump.running, Some(false), "a refused command moved pump-1");
    assert!(drivebus_gateway::metrics::front_ends(&gw).mqtt_publishes("status") >= 10);
    assert!(drivebus_gateway::metrics::front_ends(&gw).mqtt_publishes("result") >= 10);

    // Statuses are not published faster than once a second per drive (changes of running
    // state aside): conveyor-1 is polled every 250 ms.
    let topic = format!("{p}/line-generic/conveyor-1/status");
    let before = watcher.log.lock().unwrap().iter().filter(|m| m.topic == topic).count();
    tokio::time::sleep(std::time::Duration::from_secs(3)).await;
    let after = watcher.log.lock().unwrap().iter().filter(|m| m.topic == topic).count();
    assert!(after - before <= 4, "{} statuses of conveyor-1 in 3 s", after - before);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_broker_gets_the_state_again_and_the_will_says_offline() {
    let (first, first5) = rumqttd_both().await;
    let relay = Relay::start(first5).await;
    let _gw = demo_gateway("hall-r", relay.addr, &[], false);
    let p = "drivebus/hall-r";
    let on_first = Subscriber::start(first, "on-first", &format!("{p}/#")).await;
    on_first
        .wait(&format!("{p}/status online"), |log| {
            log.iter().any(|m| m.topic == format!("{p}/status") && m.text == "online").then_some(())
        })
        .await;
    wait_all_statuses(&Subscriber::start(first, "late-first", &format!("{p}/#")).await, p).await;

    // "Restart": every connection drops and the gateway finds an empty broker.
    let (second, second5) = rumqttd_both().await;
    let on_second = Subscriber::start(second, "on-second", &format!("{p}/#")).await;
    relay.switch(second5);

    // The first broker saw the gateway go away: its last will.
    on_first
        .wait(&format!("{p}/status offline"), |log| {
            log.iter().any(|m| m.topic == format!("{p}/status") && m.text == "offline").then_some(())
        })
        .await;
    // The gateway reconnected to the second and published its state there.
    on_second
        .wait(&format!("{p}/status online on the new broker"), |log| {
            log.iter().any(|m| m.topic == format!("{p}/status") && m.text == "online").then_some(())
        })
        .await;
    wait_every_status(&on_second, p, "every drive's status on the new broker").await;
    // ...retained, for whoever comes later.
    let later = Subscriber::start(second, "later", &format!("{p}/#")).await;
    wait_all_statuses(&later, p).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_gateways_side_by_side_on_one_broker() {
    let (broker, broker5) = rumqttd_both().await;
    let _a = demo_gateway("hall-a", broker5, &["*/*/*"], false);
    let _b = demo_gateway("hall-b", broker5, &[], false);
    let plant = Subscriber::start(broker, "plant", "drivebus/#").await;
    plant
        .wait("both gateways online", |log| {
            let online: HashSet<&str> = log
                .iter()
                .filter(|m| m.topic.ends_with("/status") && m.text == "online")
                .map(|m| m.topic.as_str())
                .collect();
            (online.contains("drivebus/hall-a/status") && online.contains("drivebus/hall-b/status"))
                .then_some(())
        })
        .await;
    let late = Subscriber::start(broker, "plant-late", "drivebus/#").await;
    wait_all_statuses(&late, "drivebus/hall-a").await;
    wait_all_statuses(&late, "drivebus/hall-b").await;
    // The same drive name in two halls: two topics, two drives.
    let latest = late.latest();
    assert!(latest.contains_key("drivebus/hall-a/line-toshiba/pump-1/status"));
    assert!(latest.contains_key("drivebus/hall-b/line-toshiba/pump-1/status"));

    // A command to hall-a's pump-1 moves that one only; hall-b allows no commands at all.
    plant.publish("drivebus/hall-a/line-toshiba/pump-1/set/run", "1", false).await;
    plant.publish("drivebus/hall-b/line-toshiba/pump-1/set/run", "1", false).await;
    plant.wait_json("drivebus/hall-a/line-toshiba/pump-1/status", |v| v["running"] == true).await;
    let r = plant.wait_json("drivebus/hall-b/line-toshiba/pump-1/result", |r| r["command"] == "run").await;
    assert_eq!(r["error"]["kind"], "forbidden", "{r}");
    assert_eq!(_b.drive_view(&_b.drive("pump-1").unwrap()).running, Some(false));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn home_assistant_discovery() {
    let (broker, broker5) = rumqttd_both().await;
    let _gw = demo_gateway("hall-d", broker5, &[], true);
    let first = Subscriber::start(broker, "ha-first", "homeassistant/#").await;
    first.wait_json("homeassistant/sensor/hall-d_mixer-2_fault/config", |_| true).await;
    // Home Assistant subscribing later (or restarting) finds them retained.
    let ha = Subscriber::start(broker, "ha", "homeassistant/#").await;
    let config = ha
        .wait_json("homeassistant/sensor/hall-d_pump-1_output_hz/config", |c| {
            c["unit_of_measurement"] == "Hz"
        })
        .await;
    assert_eq!(config["state_topic"], "drivebus/hall-d/line-toshiba/pump-1/status");
    assert_eq!(config["availability_topic"], "drivebus/hall-d/status");
    assert_eq!(config["unique_id"], "hall-d_pump-1_output_hz");
    let drives = demo_drives();
    ha.wait("a state sensor per drive", |log| {
        drives
            .iter()
            .all(|(_, d)| {
                log.iter()
                    .any(|m| m.topic == format!("homeassistant/sensor/hall-d_{d}_state/config") && m.retain)
            })
            .then_some(())
    })
    .await;
}

/// 30 commands to one drive published in one burst (run, stop and a speed in turn) are carried
/// out in the order published: the audit trail lists them so, and the drive ends as the last
/// ones left it, stopped at the last speed. (Each message used to start a task of its own that then took its turn.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_commands_is_carried_out_in_the_order_published() {
    let (broker, broker5) = rumqttd_both().await;
    let p = "drivebus/hall-o";
    let watcher = Subscriber::start(broker, "watcher", &format!("{p}/#")).await;
    let gw = demo_gateway("hall-o", broker5, &["line-toshiba/pump-1/*"], false);
    let events = collect_events(&gw);
    watcher.wait_json(&format!("{p}/line-toshiba/pump-1/status"), |v| v["online"] == true).await;
    let mut want = Vec::new();
    for i in 0..30u32 {
        let (cmd, payload, action) = match i % 3 {
            0 => ("run", "1".to_string(), "run".to_string()),
            1 => ("stop", "1".to_string(), "stop".to_string()),
            _ => {
                let hz = f64::from(i) / 2.0;
                ("speed", format!("{hz}"), drivebus_gateway::Command::Speed(hz).action())
            }
        };
        want.push(action);
        watcher.publish(&format!("{p}/line-toshiba/pump-1/set/{cmd}"), &payload, false).await;
    }
    let done = |events: &[drivebus_store::Event]| -> Vec<String> {
        events
            .iter()
            .filter(|e| e.kind == drivebus_store::EventKind::Command && e.drive.as_deref() == Some("pump-1"))
            .map(|e| e.action.clone().unwrap_or_default())
            .collect()
    };
    support_wait(|| done(&events.lock().unwrap()).len() >= want.len(), || done(&events.lock().unwrap()))
        .await;
    assert_eq!(done(&events.lock().unwrap()), want);
    // The last two: a stop, then a speed of 14.5 Hz.
    let d = gw.drive("pump-1").unwrap();
    support_wait(|| gw.drive_view(&d).running == Some(false), || gw.drive_view(&d)).await;
    assert_eq!(gw.drive_view(&d).setpoint_hz, Some(14.5), "{:?}", gw.drive_view(&d));
}

/// Waits (at most [`PATIENCE`]) for `ready`, showing `what` if it never is.
async fn support_wait<T: std::fmt::Debug>(ready: impl Fn() -> bool, what: impl Fn() -> T) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while !ready() {
        assert!(tokio::time::Instant::now() < deadline, "waited {PATIENCE:?}: {:?}", what());
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
}

/// A drive of a shipped template kind (`generic-2000h`): its retained status says its kind and
/// its values, Home Assistant discovers its sensors, and a command by topic moves it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_templated_drive_has_its_state_topics_discovery_and_commands() {
    let (broker, broker5) = rumqttd_both().await;
    let text = "name = \"hall-t\"\n[store]\ndisabled = true\n\
                [[bus]]\nname = \"line-t\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\n\
                [[bus.drive]]\nname = \"tpl\"\nfamily = \"generic-2000h\"\naddress = 1\npoll_ms = 100\n";
    let config = drivebus_gateway::GatewayConfig::from_toml("plant.toml", text).unwrap();
    let gw = drivebus_gateway::Gateway::start(config, None).unwrap();
    let mqtt = drivebus_gateway::config::MqttConfig {
        url: format!("mqtt://{broker5}"),
        topic_prefix: None,
        discovery: true,
        allow_commands: vec!["line-t/tpl/*".to_string()],
        client_id: None,
        credentials: None,
        tls: Default::default(),
    };
    drivebus_gateway::mqtt::spawn(gw.clone(), &mqtt).unwrap();
    let p = "drivebus/hall-t/line-t/tpl";
    let sub = Subscriber::start(broker, "watcher", "#").await;
    let status = sub.wait_json(&format!("{p}/status"), |v| v["online"] == true).await;
    assert_eq!(status["family"], "generic-2000h", "{status}");
    let config = sub
        .wait_json("homeassistant/sensor/hall-t_tpl_output_hz/config", |c| c["unit_of_measurement"] == "Hz")
        .await;
    assert_eq!(config["state_topic"], format!("{p}/status"));
    sub.wait_json("homeassistant/sensor/hall-t_tpl_state/config", |_| true).await;
    sub.publish(&format!("{p}/set/speed"), r#"{"hz": 15}"#, false).await;
    let r = sub.wait_json(&format!("{p}/result"), |r| r["command"] == "speed").await;
    assert_eq!(r["ok"], true, "{r}");
    sub.publish(&format!("{p}/set/run"), "1", false).await;
    sub.wait_json(&format!("{p}/status"), |v| running_at(v, 15.0)).await;
}

/// A template's `[values]` in Home Assistant: a sensor per value, with its unit, device class
/// and the drive's status topic, whose `values.<name>.value` the template reads, announced
/// with the standard sensors.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_templated_drives_named_values_are_discovered_as_sensors() {
    let (broker, broker5) = rumqttd_both().await;
    let text = "name = \"hall-v\"\ntemplates = [\"bits.toml\"]\n[store]\ndisabled = true\n\
                [[bus]]\nname = \"line-v\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\n\
                [[bus.drive]]\nname = \"fan\"\nfamily = \"gw-bits\"\naddress = 1\npoll_ms = 100\n";
    let (_, config) = support::with_bits_template("mqtt-values", text);
    let gw = drivebus_gateway::Gateway::start(config, None).unwrap();
    let mqtt = drivebus_gateway::config::MqttConfig {
        url: format!("mqtt://{broker5}"),
        topic_prefix: None,
        discovery: true,
        allow_commands: vec![],
        client_id: None,
        credentials: None,
        tls: Default::default(),
    };
    drivebus_gateway::mqtt::spawn(gw.clone(), &mqtt).unwrap();
    let sub = Subscriber::start(broker, "ha", "#").await;
    let status_topic = "drivebus/hall-v/line-v/fan/status";
    for (name, unit, class) in [("dc_bus_v", "V", "voltage"), ("power_kw", "kW", "power")] {
        let c =
            sub.wait_json(&format!("homeassistant/sensor/hall-v_fan_values_{name}/config"), |_| true).await;
        assert_eq!(c["unique_id"], format!("hall-v_fan_values_{name}"), "{c}");
        assert_eq!(c["name"], name, "{c}");
        assert_eq!(c["state_topic"], status_topic, "{c}");
        assert_eq!(c["unit_of_measurement"], unit, "{c}");
        assert_eq!(c["device_class"], class, "{c}");
        assert_eq!(c["state_class"], "measurement", "{c}");
        assert_eq!(c["availability_topic"], "drivebus/hall-v/status", "{c}");
        assert_eq!(c["device"]["identifiers"][0], "drivebus_hall-v_fan", "{c}");
        // The template reads the value the status topic carries.
        let template = c["value_template"].as_str().unwrap();
        assert!(template.contains(&format!("value_json['values']['{name}']['value']")), "{template}");
    }
    let status = sub.wait_json(status_topic, |v| v["values"]["dc_bus_v"]["value"].is_number()).await;
    assert_eq!(status["values"]["dc_bus_v"]["unit"], "V", "{status}");
    // The standard sensors are still there.
    sub.wait_json("homeassistant/sensor/hall-v_fan_output_hz/config", |c| c["unit_of_measurement"] == "Hz")
        .await;
}

/// `[standby]`: a gateway that masters no bus says `offline` and publishes no drive status, no
/// discovery and no event; once it takes a line it says `online` and publishes them all.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_standby_publishes_no_state_until_it_masters_a_bus() {
    let (broker, broker5) = rumqttd_both().await;
    let watcher = Subscriber::start(broker, "watcher", "#").await;
    // Nobody else masters the demo's lines: the standby takes them after twice 3 s.
    let role = drivebus_link::role::RoleConfig { standby: true, silence: std::time::Duration::from_secs(3) };
    let gw = demo_gateway_as("standby-a", broker5, &[], true, None, Some(role));
    let p = "drivebus/standby-a";
    let availability = format!("{p}/status");
    let online = watcher
        .wait("the gateway online", |log| {
            log.iter().position(|m| m.topic == availability && m.text == "online")
        })
        .await;
    assert!(*gw.mastering().borrow(), "online only once it masters a bus");
    let log = watcher.log.lock().unwrap().clone();
    let before: Vec<_> = log[..online].iter().map(|m| (m.topic.as_str(), m.text.as_str())).collect();
    assert!(!before.is_empty(), "a standby says offline while it listens");
    assert!(
        before.iter().all(|&(t, text)| t == availability && text == "offline"),
        "a standby publishes nothing but its availability: {before:#?}"
    );
    // As master: discovery and every drive's status, each saying its values are its own.
    wait_every_status(&watcher, p, "every drive's status from the new master").await;
    watcher
        .wait("discovery", |log| {
            log[online..].iter().find(|m| m.topic.starts_with("homeassistant/")).cloned()
        })
        .await;
    // The lines are taken one by one: a drive's status says `standby` until its own is.
    let drives = demo_drives();
    watcher
        .wait("every drive's status saying master", |log| {
            drives
                .iter()
                .all(|(b, d)| {
                    let topic = format!("{p}/{b}/{d}/status");
                    log.iter()
                        .rev()
                        .find(|m| m.topic == topic)
                        .is_some_and(|m| m.text.contains(r#""source":"master""#))
                })
                .then_some(())
        })
        .await;
}
