//! `[limits]`: connection limits and timeouts of every listener (limits.rs applies them).

use std::time::Duration;

use super::ctx::Ctx;
use super::file::FileLimits;
use super::{ConfigError, LimitsConfig, HEADER_TIMEOUT_MS};

/// Checks `[limits]`.
pub(super) fn check(cx: &Ctx, raw: &FileLimits) -> Result<LimitsConfig, ConfigError> {
    let mut limits = LimitsConfig::default();
    limits.per_address = cx.at_least_one(&raw.per_address, "limits.per_address", limits.per_address)?;
    let header_ms =
        cx.within(&raw.header_timeout_ms, 100..=600_000, "limits.header_timeout_ms", "", HEADER_TIMEOUT_MS)?;
    limits.header_timeout = Duration::from_millis(header_ms);
    if let Some(t) = raw.idle_timeout_s {
        limits.idle_timeout = Duration::from_secs(t);
    }
    if let Some(r) = raw.reserve_fds {
        limits.reserve_fds = r;
    }
    Ok(limits)
}
