//! `[standby]`: a second gateway on the same lines. `role = "active"` (the default) or
//! `"standby"`, `silence_ms` (default 500): how long a line must carry no master request before
//! a listening gateway takes it (docs/gateway.md, "A warm standby").

use std::time::Duration;

use drivebus_link::role::RoleConfig;

use super::ctx::Ctx;
use super::file::FileStandby;
use super::ConfigError;

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
