//! Linkage: follower drives that track a leader's output frequency (`[[linkage]]` rules).

use std::sync::atomic::Ordering;
use std::sync::Arc;

use super::cache::DriveEntry;
use super::command::Command;
use super::gateway::Gateway;

/// No linkage write to the drive yet.
pub(super) const LINKAGE_NONE: u8 = 0;
/// The linkage's last write to the drive was confirmed.
const LINKAGE_HOLDS: u8 = 1;
/// The linkage's last write to the drive failed.
const LINKAGE_FAILS: u8 = 2;

impl Gateway {
    /// Applies the linkage rules whose leader is drive `i`, now at `hz`.
    pub(super) fn follow(self: &Arc<Self>, leader: &DriveEntry, hz: f64) {
        let topo = self.topology();
        for rule in &topo.config.linkage {
            if rule.leader != leader.config.name {
                continue;
            }
            let Some(&fi) = topo.index.get(&rule.follower) else { continue };
            let f = topo.drives[fi].clone();
            let target = ((hz * rule.ratio + rule.offset_hz).max(0.0) * 100.0).round() / 100.0;
            let current = f.with_state(|s| s.commanded_hz);
            if current.is_some_and(|c| (c - target).abs() < 0.005) || f.locked() {
                continue;
            }
            if f.linking.swap(true, Ordering::Relaxed) {
                continue;
            }
            let gw = self.clone();
            let actor = format!("linkage:{}", rule.leader);
            tokio::spawn(async move {
                // The audit trail has the linkage taking hold, failing and recovering; not each
                // setpoint it writes (one per leader poll).
                let result = f.command.set_speed(target).await;
                let now = if result.is_ok() { LINKAGE_HOLDS } else { LINKAGE_FAILS };
                let changed = f.linkage.swap(now, Ordering::Relaxed) != now;
                let audit = match &result {
                    Ok(()) => {
                        let mut s = f.state.write().unwrap_or_else(|p| p.into_inner());
                        s.commanded_hz = Some(target);
                        if s.last_error.as_deref().is_some_and(|e| e.starts_with("linkage:")) {
                            s.last_error = None;
                        }
                        changed.then(|| "ok".to_string())
                    }
                    Err(e) => {
                        f.state.write().unwrap_or_else(|p| p.into_inner()).last_error =
                            Some(format!("linkage: {e}"));
                        changed.then(|| format!("error: {e}"))
                    }
                };
                if let Some(result) = audit {
                    gw.audit(
                        Some(f.bus.clone()),
                        &f.config.name,
                        &actor,
                        &Command::Speed(target).action(),
                        result,
                    )
                    .await;
                }
                f.linking.store(false, Ordering::Relaxed);
            });
        }
    }
}
