//! Live reload on a virtual clock: only what changed restarts; unchanged buses keep polling
//! without a gap and keep their statistics; a configuration that does not check changes nothing.

use std::sync::Arc;
use std::time::Duration;

use drivebus_gateway::core::Change;
use drivebus_gateway::{Gateway, GatewayConfig};

const TOKEN_A: &str = "[[token]]\nname = \"ops-a\"\ntoken = \"aaaaaaaaaaaaaaaaaaaa\"\nrole = \"write\"\n";
const TOKEN_B: &str = "[[token]]\nname = \"ops-b\"\ntoken = \"bbbbbbbbbbbbbbbbbbbb\"\nrole = \"write\"\n";

fn bus(name: &str, drive: &str, poll_ms: u64) -> String {
    format!(
        "[[bus]]\nname = \"{name}\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 38400\n\
         [[bus.drive]]\nname = \"{drive}\"\nfamily = \"generic\"\naddress = 1\npoll_ms = {poll_ms}\n"
    )
}

fn config(text: &str) -> GatewayConfig {
    GatewayConfig::from_toml("plant.toml", text).unwrap()
}

#[tokio::test(start_paused = true)]
async fn a_reload_adds_and_removes_buses_and_tokens_while_the_unchanged_bus_polls_on() {
    let before = format!("{TOKEN_A}{TOKEN_B}{}{}", bus("line-1", "d1", 100), bus("line-2", "d2", 100));
    let gw = Gateway::start(config(&before), None).unwrap();
    let mut changes = gw.subscribe();
    // Every refresh of d1, on the virtual clock.
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    tokio::spawn(async move {
        while let Ok(c) = changes.recv().await {
            if let Change::Drive(v) = &c {
                if v.id == "d1" {
                    let _ = tx.send((tokio::time::Instant::now(), v.polls));
                }
            }
            if let Change::Event(e) = &c {
                if e.kind.as_str() == "reload" {
                    let _ = tx.send((tokio::time::Instant::now(), u64::MAX));
                }
            }
        }
    });
    tokio::time::sleep(Duration::from_secs(5)).await;
    let line1 = gw.buses().iter().find(|b| b.config.name == "line-1").unwrap().clone();
    let old_d2 = gw.drive("d2").unwrap();
    let tx_before = line1.stats().transactions;

    let after = format!("{TOKEN_A}{}{}", bus("line-1", "d1", 100), bus("line-3", "d3", 100));
    let r = gw.reload(config(&after), "signal").await.unwrap();
    assert!(r.summary.contains("bus added line-3"), "{}", r.summary);
    assert!(r.summary.contains("bus removed line-2"), "{}", r.summary);
    assert!(r.summary.contains("tokens changed"), "{}", r.summary);
    tokio::time::sleep(Duration::from_secs(5)).await;

    // The unchanged bus is the same bus: same owner, statistics carried on.
    let line1_now = gw.buses().iter().find(|b| b.config.name == "line-1").unwrap().clone();
    assert!(Arc::ptr_eq(&line1, &line1_now), "line-1 was rebuilt");
    assert!(line1_now.stats().transactions > tx_before);
    // d1 never missed a poll interval: no gap between refreshes over 2 intervals, and its count
    // kept rising through the reload (no reset).
    let mut seen = Vec::new();
    while let Ok(x) = rx.try_recv() {
        seen.push(x);
    }
    let reload_at = seen.iter().position(|(_, p)| *p == u64::MAX).expect("the reload event");
    let refreshes: Vec<_> = seen.iter().filter(|(_, p)| *p != u64::MAX).collect();
    assert!(refreshes.len() >= 95, "{} refreshes in 10 s at 100 ms", refreshes.len());
    for w in refreshes.windows(2) {
        assert!(
            w[1].0 - w[0].0 <= Duration::from_millis(200),
            "a gap of {:?} in d1's polls",
            w[1].0 - w[0].0
        );
        assert!(w[1].1 > w[0].1, "d1's poll count went from {} to {}", w[0].1, w[1].1);
    }
    assert!(reload_at > 10 && reload_at + 10 < seen.len(), "the reload was in the middle of the run");

    // The new drive is polled; the removed one is gone and no longer polled.
    let d3 = gw.drive_view(&gw.drive("d3").unwrap());
    assert_eq!(d3.online, Some(true), "{d3:?}");
    assert!(d3.polls > 10, "{d3:?}");
    assert!(gw.drive("d2").is_err());
    let polls = old_d2.state().polls;
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(old_d2.state().polls, polls, "the removed bus is still polled");
    // The removed token is refused from now on.
    let tokens: Vec<String> = gw.config().tokens.iter().map(|t| t.name.clone()).collect();
    assert_eq!(tokens, vec!["ops-a"]);
}

#[tokio::test(start_paused = true)]
async fn a_configuration_that_does_not_check_keeps_the_running_one() {
    let text = format!("{TOKEN_A}{}", bus("line-1", "d1", 100));
    let gw = Gateway::start(config(&text), None).unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let broken = GatewayConfig::from_toml("plant.toml", "[[bus]]\nname = 3\n").map_err(|e| e.to_string());
    let why = broken.clone().unwrap_err();
    drivebus_gateway::server::reload_with(&gw, broken, "signal").await;
    assert_eq!(gw.health().reloads(), (0, 1));
    assert_eq!(gw.health().last_reload_error(), Some(why));
    let polls = gw.drive("d1").unwrap().state().polls;
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert!(gw.drive("d1").unwrap().state().polls > polls, "the running configuration stopped");
    // A good one afterwards clears the failure.
    drivebus_gateway::server::reload_with(&gw, Ok(config(&text)), "signal").await;
    assert_eq!(gw.health().reloads(), (1, 1));
    assert_eq!(gw.health().last_reload_error(), None);
}

#[tokio::test(start_paused = true)]
async fn a_lock_set_in_the_file_applies_at_once_and_the_drive_keeps_its_cache() {
    let text = format!("{TOKEN_A}{}", bus("line-1", "d1", 100));
    let gw = Gateway::start(config(&text), None).unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let d1 = gw.drive("d1").unwrap();
    assert!(!d1.locked());
    let locked = text.replace("poll_ms = 100", "poll_ms = 100\nlocked = true");
    gw.reload(config(&locked), "signal").await.unwrap();
    let again = gw.drive("d1").unwrap();
    assert!(Arc::ptr_eq(&d1, &again), "a lock change rebuilt the drive");
    assert!(again.locked());
    let e = gw.command("d1", drivebus_gateway::Command::Run, "test").await.unwrap_err();
    assert_eq!(e.kind(), "locked");
}

/// A `[[bridge]]` or `[[modbus_rtu]]` added (or changed) by a reload is named as needing a
/// restart, in the result, the log line's summary and the audit event, like the other
/// restart-only settings; the rest of the file applies.
#[tokio::test(start_paused = true)]
async fn bridge_and_rtu_slave_changes_are_named_as_needing_a_restart() {
    let before = format!("{TOKEN_A}{}", bus("line-1", "d1", 100));
    let gw = Gateway::start(config(&before), None).unwrap();
    let after = format!(
        "{TOKEN_A}{TOKEN_B}{}[[bridge]]\nbus = \"line-1\"\nlisten = \"127.0.0.1:5021\"\n\
         [[modbus_rtu]]\nport = \"/dev/ttyS1\"\n",
        bus("line-1", "d1", 100)
    );
    let r = gw.reload(config(&after), "signal").await.unwrap();
    assert_eq!(r.needs_restart, ["bridge", "modbus_rtu"]);
    assert!(r.summary.contains("tokens changed"), "{}", r.summary);
    assert!(r.summary.contains("needs a restart to apply: bridge, modbus_rtu"), "{}", r.summary);
}
