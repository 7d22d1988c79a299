//! The register map every drive shows to Modbus TCP clients, whatever its family
//! (docs/register-map.md): ten input registers from the cache, the command word and the
//! setpoint as holding registers, and a window of 32-bit holding registers over the drive's
//! parameter catalog.

use drivebus_drive::Family;

use crate::core::{DriveEntry, DriveState};

/// Input registers (FC 04): how many there are.
pub const INPUT_COUNT: u16 = 10;
/// Input register 0: the status word.
pub const IN_STATUS: u16 = 0;
/// Input register 1: output frequency, 0.01 Hz.
pub const IN_OUTPUT_HZ: u16 = 1;
/// Input register 2: setpoint, 0.01 Hz.
pub const IN_SETPOINT_HZ: u16 = 2;
/// Input register 3: motor current, 0.01 A.
pub const IN_CURRENT_A: u16 = 3;
/// Input register 4: fault code (0 = none).
pub const IN_FAULT: u16 = 4;
/// Input register 5: link status (0 never polled, 1 online, 2 offline).
pub const IN_LINK: u16 = 5;
/// Input register 6: data age, 0.1 s (65535 = never read or saturated).
pub const IN_AGE: u16 = 6;
/// Input register 7: poll error rate, per mille.
pub const IN_ERROR_RATE: u16 = 7;
/// Input register 8: family (1 generic, 2 toshiba, 3 danfoss, 4 b800, 5 a template kind).
pub const IN_FAMILY: u16 = 8;
/// Input register 9: the drive's address on its bus.
pub const IN_ADDRESS: u16 = 9;

/// Status word bit 0: the output is on.
pub const ST_RUNNING: u16 = 1 << 0;
/// Status word bit 1: turning in reverse.
pub const ST_REVERSE: u16 = 1 << 1;
/// Status word bit 2: a fault is in force.
pub const ST_FAULT: u16 = 1 << 2;
/// Status word bit 3: the last poll was answered.
pub const ST_ONLINE: u16 = 1 << 3;
/// Status word bit 4: the values are older than three poll intervals, or were never read.
pub const ST_STALE: u16 = 1 << 4;
/// Status word bit 5: the drive is locked against writes.
pub const ST_LOCKED: u16 = 1 << 5;
/// Status word bit 6: the values were heard, not polled: the gateway is a standby on the
/// drive's bus (another gateway masters the line, `[standby]`) and refuses writes to it.
pub const ST_STANDBY: u16 = 1 << 6;

/// Holding register 0: the command word.
pub const HR_COMMAND: u16 = 0;
/// Holding register 1: the setpoint, 0.01 Hz.
pub const HR_SETPOINT: u16 = 1;
/// The first holding register of the parameter window: parameter `i` of the catalog is at
/// `PARAM_BASE + 2 * i` (high word) and `PARAM_BASE + 2 * i + 1` (low word).
pub const PARAM_BASE: u16 = 1000;

/// Command word bit 0: run (1) or stop (0).
pub const CMD_RUN: u16 = 1 << 0;
/// Command word bit 1: reverse direction.
pub const CMD_REVERSE: u16 = 1 << 1;
/// Command word bit 2: fault reset, on a 0 -> 1 write.
pub const CMD_RESET: u16 = 1 << 2;
/// Command word bit 3: jog, on a 0 -> 1 write; the drive keeps running while it is 1.
pub const CMD_JOG: u16 = 1 << 3;
/// The bits of the command word that mean something.
pub const CMD_MASK: u16 = CMD_RUN | CMD_REVERSE | CMD_RESET | CMD_JOG;

/// The family's number in input register 8.
pub fn family_code(f: Family) -> u16 {
    match f {
        Family::Generic => 1,
        Family::Toshiba => 2,
        Family::Danfoss => 3,
        Family::B800 => 4,
        Family::Template(_) => 5,
    }
}

/// A value in hundredths (0.01 Hz, 0.01 A), as an unsigned register: the magnitude, saturated.
pub fn hundredths(v: Option<f64>) -> u16 {
    match v {
        Some(v) if v.is_finite() => (v.abs() * 100.0).round().min(65535.0) as u16,
        _ => 0,
    }
}

/// Whether the cached status says the drive turns in reverse.
pub fn is_reverse(s: &DriveState) -> bool {
    s.status.as_ref().and_then(|x| x.direction.as_deref()) == Some("reverse")
}

/// The ten input registers of drive `d` from its cached state (one read lock, no allocation).
pub fn input_registers(d: &DriveEntry, out: &mut [u16; INPUT_COUNT as usize]) {
    let poll_ms = d.config.poll.as_millis().min(u128::from(u64::MAX)) as u64;
    let locked = d.locked();
    let standby = d.role() == drivebus_link::role::Role::Standby;
    d.with_state(|s| {
        let st = s.status.as_ref();
        let age_ms = s.updated.map(|t| t.elapsed().as_millis().min(u128::from(u64::MAX)) as u64);
        let mut word = 0;
        if st.is_some_and(|x| x.running) {
            word |= ST_RUNNING;
        }
        if is_reverse(s) {
            word |= ST_REVERSE;
        }
        if st.is_some_and(|x| x.fault.is_some()) {
            word |= ST_FAULT;
        }
        if s.online == Some(true) {
            word |= ST_ONLINE;
        }
        if age_ms.map_or(true, |a| a > poll_ms.saturating_mul(3)) {
            word |= ST_STALE;
        }
        if locked {
            word |= ST_LOCKED;
        }
        if standby {
            word |= ST_STANDBY;
        }
        out[IN_STATUS as usize] = word;
        out[IN_OUTPUT_HZ as usize] = hundredths(st.and_then(|x| x.output_hz));
        out[IN_SETPOINT_HZ as usize] = hundredths(st.and_then(|x| x.setpoint_hz).or(s.commanded_hz));
        out[IN_CURRENT_A as usize] = hundredths(st.and_then(|x| x.current_a));
        out[IN_FAULT as usize] = st.and_then(|x| x.fault.as_ref()).map_or(0, |f| f.code.min(65535) as u16);
        out[IN_LINK as usize] = match s.online {
            None => 0,
            Some(true) => 1,
            Some(false) => 2,
        };
        out[IN_AGE as usize] = age_ms.map_or(65535, |a| (a / 100).min(65535) as u16);
        out[IN_ERROR_RATE as usize] =
            s.poll_errors.saturating_mul(1000).checked_div(s.polls).map_or(0, |r| r.min(1000) as u16);
    });
    out[IN_FAMILY as usize] = family_code(d.config.family);
    out[IN_ADDRESS as usize] = u16::from(d.config.address);
}

/// What a command-word write sends, in order, given what the drive does now.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CommandPlan {
    /// Fault reset (bit 2 went 0 -> 1).
    pub reset: bool,
    /// Stop (run and jog are 0 and the drive runs).
    pub stop: bool,
    /// Reverse (bit 1 differs from the drive's direction).
    pub reverse: bool,
    /// Run (bit 0 is 1 and the drive does not run).
    pub run: bool,
    /// Jog (bit 3 went 0 -> 1).
    pub jog: bool,
}

/// Compares the written word `new` with the drive's state (`running`, `reverse`) and the word
/// written before (`old`, for the edge-triggered bits) and says what to send.
pub fn plan_command(new: u16, old: u16, running: bool, reverse: bool) -> CommandPlan {
    let edge = |bit: u16| new & bit != 0 && old & bit == 0;
    let jog = edge(CMD_JOG);
    let keep_running = new & (CMD_RUN | CMD_JOG) != 0;
    CommandPlan {
        reset: edge(CMD_RESET),
        stop: !keep_running && running,
        reverse: (new & CMD_REVERSE != 0) != reverse,
        run: new & CMD_RUN != 0 && !running && !jog,
        jog,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_command_word_sends_only_what_changes() {
        let none = CommandPlan::default();
        assert_eq!(plan_command(CMD_RUN, 0, false, false), CommandPlan { run: true, ..none });
        assert_eq!(plan_command(CMD_RUN, CMD_RUN, true, false), none);
        assert_eq!(plan_command(0, CMD_RUN, true, false), CommandPlan { stop: true, ..none });
        assert_eq!(
            plan_command(CMD_RUN | CMD_REVERSE, CMD_RUN, true, false),
            CommandPlan { reverse: true, ..none }
        );
        assert_eq!(plan_command(0, 0, false, true), CommandPlan { reverse: true, ..none });
        assert_eq!(plan_command(CMD_RESET, 0, false, false), CommandPlan { reset: true, ..none });
        assert_eq!(plan_command(CMD_RESET, CMD_RESET, false, false), none);
        assert_eq!(plan_command(CMD_JOG, 0, false, false), CommandPlan { jog: true, ..none });
        // Jogging keeps the drive running; dropping jog stops it.
        assert_eq!(plan_command(CMD_JOG, CMD_JOG, true, false), none);
        assert_eq!(plan_command(0, CMD_JOG, true, false), CommandPlan { stop: true, ..none });
    }

    #[test]
    fn hundredths_saturate_and_ignore_nonsense() {
        assert_eq!(hundredths(Some(40.0)), 4000);
        assert_eq!(hundredths(Some(-12.5)), 1250);
        assert_eq!(hundredths(Some(1e9)), 65535);
        assert_eq!(hundredths(Some(f64::NAN)), 0);
        assert_eq!(hundredths(None), 0);
    }
}
