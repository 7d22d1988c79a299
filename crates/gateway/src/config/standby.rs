//! `[standby]`: a second gateway on the same lines. `role = "active"` (the default) or
//! `"standby"`, `silence_ms` (default 500): how long a line must carry no master request before
//! a listening gateway takes it (docs/gateway.md, "A warm standby").

use std::time::Duration;

use drivebus_link::role::RoleConfig;

use super::ctx::Ctx;
use super::file::FileStandby;
use super::{BusConfig, ConfigError};

/// Refuses a silence shorter than a bus's shortest poll interval: between two rounds of polls
/// that line would fall silent for longer, and a standby would take it over from a master
/// that is alive. (Equal is fine: a round's own exchanges shorten the pause after it.)
pub(super) fn check_polls(
    cx: &Ctx,
    raw: &FileStandby,
    role: &RoleConfig,
    buses: &[BusConfig],
) -> Result<(), ConfigError> {
    for b in buses {
        if let Some(why) = super::no_standby(b) {
            let span = raw.role.as_ref().map_or(0..0, |s| s.span());
            return cx.err(span, "standby", why);
        }
        let Some(poll) = b.drives.iter().map(|d| d.poll).min() else { continue };
        if poll > role.silence {
            let span = raw.silence_ms.as_ref().map_or(0..0, |s| s.span());
            return cx.err(
                span,
                "standby.silence_ms",
                format!(
                    "{} ms is shorter than bus {}'s shortest poll_ms {}: the line falls silent between polls and a standby would take it over; make silence_ms at least that",
                    role.silence.as_millis(),
                    b.name,
                    poll.as_millis()
                ),
            );
        }
    }
    Ok(())
}

/// Checks `[standby]`: the role every bus of the gateway starts in.
pub(super) fn check(cx: &Ctx, raw: &FileStandby) -> Result<RoleConfig, ConfigError> {
    let standby = match &raw.role {
        None => false,
        Some(r) => match r.get_ref().as_str() {
            "active" => false,
            "standby" => true,
            other => {
                return cx.err(
                    r.span(),
                    "standby.role",
                    format!("{other:?} is not a role: use \"active\" or \"standby\""),
                )
            }
        },
    };
    let silence = cx.within(
        &raw.silence_ms,
        50..=60_000,
        "standby.silence_ms",
        " ms",
        RoleConfig::DEFAULT_SILENCE.as_millis() as u64,
    )?;
    Ok(RoleConfig { standby, silence: Duration::from_millis(silence) })
}
