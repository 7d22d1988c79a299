//! The poll schedule around commands, on tokio's paused clock. A command's refresh (the drive's
//! status read after the command, ahead of polls) counts as the drive's poll: the next poll is an
//! interval after it. On a full line, 32 generic drives at 115200 baud polled every 500 ms (two
//! reads a status, each behind the manual's 10 ms of silence: about 0.95 s of line time a round,
//! so each drive is polled about once a second whatever `poll_ms` says), with speed commands
//! coming ten a second, the drives due are polled oldest values first, whether a poll or a
//! refresh read them last, and the bus's poll lag shows the line is full (and none on a line
//! that keeps its intervals).

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use drivebus_gateway::core::{Change, Command};
use drivebus_gateway::{Gateway, GatewayConfig};
use tokio::time::Instant;

/// One bus of `drives` generic drives at 115200 baud, each polled every `poll_ms`.
fn line(drives: u8, poll_ms: u64) -> GatewayConfig {
    let mut text = String::from(
        "[http]\nanonymous_read = true\n\
         [[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 115200\n",
    );
    for a in 1..=drives {
        text.push_str(&format!(
            "[[bus.drive]]\nname = \"vfd-{a}\"\nfamily = \"generic\"\naddress = {a}\npoll_ms = {poll_ms}\n"
        ));
    }
    GatewayConfig::from_toml("plant.toml", &text).unwrap()
}

/// Waits (up to `limit`) for the next status of drive `id` in the cache; when it came.
async fn next_status(
    changes: &mut tokio::sync::broadcast::Receiver<Change>,
    id: &str,
    limit: Duration,
) -> Instant {
    let wait = async {
        loop {
            match changes.recv().await {
                Ok(Change::Drive(v)) if v.id == id => return Instant::now(),
                Ok(_) => {}
                Err(e) => panic!("the changes were not followed: {e}"),
            }
        }
    };
    tokio::time::timeout(limit, wait).await.unwrap_or_else(|_| panic!("no status of {id} in {limit:?}"))
}

#[tokio::test(start_paused = true)]
async fn the_refresh_after_a_command_counts_as_the_drives_poll() {
    let poll = Duration::from_millis(1000);
    let gw = Gateway::start(line(1, 1000), None).unwrap();
    let mut changes = gw.subscribe();
    // A poll has just ended; the next is due a second after it began.
    next_status(&mut changes, "vfd-1", Duration::from_secs(10)).await;
    let polled = next_status(&mut changes, "vfd-1", Duration::from_secs(10)).await;
    tokio::time::sleep_until(polled + Duration::from_millis(600)).await;
    gw.command("vfd-1", Command::Speed(30.0), "test").await.unwrap();
    // The command's refresh has read the status (its change is the last one sent).
    let refreshed = Instant::now();
    let mut changes = gw.subscribe();
    let next = next_status(&mut changes, "vfd-1", Duration::from_secs(10)).await;
    assert!(
        next - refreshed >= poll - Duration::from_millis(5),
        "polled {:?} after the command's refresh (poll_ms {poll:?})",
        next - refreshed
    );
    // And then every second again, on time.
    let after = next_status(&mut changes, "vfd-1", Duration::from_secs(10)).await;
    assert!(after - next >= poll - Duration::from_millis(5), "{:?}", after - next);
    let lag = gw.buses()[0].poll_lag();
    assert!(lag < Duration::from_millis(5), "polls began {lag:?} late");
}

#[tokio::test(start_paused = true)]
async fn a_line_that_keeps_its_intervals_shows_no_poll_lag() {
    // 8 drives polled every second, all due at once from the start: the last of each round
    // begins some 0.2 s after it was due, every second, so its values wait no longer than the
    // interval.
    let gw = Gateway::start(line(8, 1000), None).unwrap();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let bus = gw.buses()[0].clone();
    let mut most = Duration::ZERO;
    for _ in 0..200 {
        tokio::time::sleep(Duration::from_millis(25)).await;
        most = most.max(bus.poll_lag());
    }
    assert!(most < Duration::from_millis(5), "a poll lag of {most:?} on a line that keeps its intervals");
    assert!(bus.stats().transactions > 8 * 2 * 7, "{:?}", bus.stats());
}

/// Over `run`, the longest any of `drives` went without a new status in the cache (a poll's or
/// a command's refresh), and how many statuses came.
async fn worst_gap(gw: &Arc<Gateway>, drives: u8, run: Duration) -> (Duration, usize) {
    let mut changes = gw.subscribe();
    let start = Instant::now();
    let end = start + run;
    let mut last: HashMap<String, Instant> = HashMap::new();
    let (mut worst, mut statuses) = (Duration::ZERO, 0);
    loop {
        match tokio::time::timeout_at(end, changes.recv()).await {
            Err(_) => break,
            Ok(Ok(Change::Drive(v))) => {
                let now = Instant::now();
                worst = worst.max(now - last.get(&v.id).copied().unwrap_or(start));
                last.insert(v.id, now);
                statuses += 1;
            }
            Ok(Err(e)) => panic!("the changes were not followed: {e}"),
            Ok(_) => {}
        }
    }
    assert_eq!(last.len(), usize::from(drives), "every drive was read");
    for t in last.values() {
        worst = worst.max(end - *t);
    }
    (worst, statuses)
}

#[tokio::test(start_paused = true)]
async fn on_a_full_line_the_oldest_values_are_read_first() {
    const DRIVES: u8 = 32;
    let gw = Gateway::start(line(DRIVES, 500), None).unwrap();
    tokio::time::sleep(Duration::from_secs(3)).await;
    // Ten speed commands a second, to drives picked at random (a fixed sequence).
    let stirrer = {
        let gw = gw.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(100));
            let mut x: u64 = 12345;
            for k in 0usize.. {
                tick.tick().await;
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let id = format!("vfd-{}", 1 + (x >> 33) as usize % usize::from(DRIVES));
                tokio::spawn(gw.command(&id, Command::Speed([20.0, 30.0, 40.0, 50.0][k % 4]), "test"));
            }
        })
    };
    tokio::time::sleep(Duration::from_secs(2)).await;
    let (worst, statuses) = worst_gap(&gw, DRIVES, Duration::from_secs(30)).await;
    stirrer.abort();
    eprintln!("worst {worst:?}, {statuses} statuses");
    // The line gives some 27 statuses a second besides the commands' writes, 10 of them the
    // commands' refreshes: a drive's values are 32 / 27 = 1.2 s old on average. Read in turn
    // whatever the refreshes read (as before), the drives waited for 32 polls and the commands
    // between them: 1.85 s at worst.
    assert!(statuses > 30 * 25, "{statuses} statuses in 30 s");
    assert!(worst < Duration::from_millis(1750), "a drive went {worst:?} without a new status");
    // The line is full, and the bus says so: polls begin far behind their schedule (while the
    // bytes on the wire take some 11 % of the time).
    let bus = &gw.buses()[0];
    let (lag, wire) = (bus.poll_lag(), bus.stats().utilization());
    assert!(lag > Duration::from_millis(300) && wire < 0.2, "polls {lag:?} late, the wire busy {wire}");
}
