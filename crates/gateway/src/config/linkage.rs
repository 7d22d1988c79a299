//! `[[linkage]]`: leader/follower rules between drives of any bus.

use toml::Spanned;

use super::ctx::Ctx;
use super::file::FileLinkage;
use super::{BusConfig, ConfigError, Linkage};

/// Checks the `[[linkage]]` sections against the drives of `buses`: one rule per follower, and
/// no loop (each setpoint would feed itself).
pub(super) fn check(
    cx: &Ctx,
    raw: &[Spanned<FileLinkage>],
    buses: &[BusConfig],
) -> Result<Vec<Linkage>, ConfigError> {
    let mut linkage: Vec<Linkage> = Vec::new();
    for l in raw {
        let span = l.span();
        let l = l.get_ref();
        for (who, field) in [(&l.leader, "linkage.leader"), (&l.follower, "linkage.follower")] {
            if !buses.iter().flat_map(|b| &b.drives).any(|d| d.name == *who.get_ref()) {
                return cx.err(who.span(), field, format!("no drive is named {:?}", who.get_ref()));
            }
        }
        if l.leader.get_ref() == l.follower.get_ref() {
            return cx.err(span, "linkage.follower", "a drive cannot follow itself");
        }
        if linkage.iter().any(|x| &x.follower == l.follower.get_ref()) {
            return cx.err(
                l.follower.span(),
                "linkage.follower",
                format!("{:?} already follows another drive: one rule per follower", l.follower.get_ref()),
            );
        }
        // A chain that comes back to its start would feed each setpoint from itself.
        let mut leader = l.leader.get_ref().as_str();
        while let Some(up) = linkage.iter().find(|x| x.follower == leader) {
            if &up.leader == l.follower.get_ref() {
                return cx.err(
                    l.follower.span(),
                    "linkage.follower",
                    format!(
                        "{:?} following {:?} closes a loop of linkage rules: each setpoint would feed itself",
                        l.follower.get_ref(),
                        l.leader.get_ref()
                    ),
                );
            }
            leader = up.leader.as_str();
        }
        let ratio = l.ratio.unwrap_or(1.0);
        let offset_hz = l.offset_hz.unwrap_or(0.0);
        if !ratio.is_finite() || !offset_hz.is_finite() {
            return cx.err(span, "linkage.ratio", "ratio and offset_hz must be finite numbers");
        }
        linkage.push(Linkage {
            leader: l.leader.get_ref().clone(),
            follower: l.follower.get_ref().clone(),
            ratio,
            offset_hz,
        });
    }
    Ok(linkage)
}
