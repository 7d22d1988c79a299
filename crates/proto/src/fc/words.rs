//! The process data words of the FC profile: control word (CTW), status word (STW) and the
//! reference / main actual value (MRV, MAV).
//!
//! Bit layouts: protocols.md 2.6 (control word, "8-10 = FC profile") and 2.7 (status word);
//! scaling: protocols.md 2.8 and the project decision "0x4000 = 100 % of the range set by
//! 3-02/3-03 (signed, two's complement)".

use core::fmt;

/// Control word, FC profile (PCD1 from the master).
///
/// Each bit has a meaning for 0 and for 1 (protocols.md 2.6); the accessors are named after
/// the value 1. Bit 10 = 0 makes the drive ignore the whole word ("data invalid").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ControlWord(pub u16);

/// The common control words from one list: a constant each, [`ControlWord::name`], and the
/// command name of a process block that carries the word.
macro_rules! common_words {
    ($($(#[$doc:meta])* $constant:ident = $word:literal => $name:literal,)*) => {
        $($(#[$doc])* pub const $constant: ControlWord = ControlWord($word);)*

        /// The name of a common word (`047C` "start", ...), if this is one.
        pub const fn name(self) -> Option<&'static str> {
            Some(match self.0 {
                $($word => $name,)*
                0x0000 => "data invalid: the control word is ignored",
                _ => return None,
            })
        }

        /// The command name of a process block carrying this word: `process block: start`.
        pub(crate) const fn process_block_name(self) -> &'static str {
            match self.0 {
                $($word => concat!("process block: ", $name),)*
                _ => "process block: control word and reference",
            }
        }
    };
}

impl ControlWord {
    common_words! {
        /// `047C`: start (bits 2, 3, 4, 5, 6, 10; the manual's example).
        START = 0x047C => "start",
        /// `043C`: ramp stop (bit 6 = 0).
        RAMP_STOP = 0x043C => "ramp stop",
        /// `0474`: coast (bit 3 = 0).
        COAST = 0x0474 => "coast",
        /// `046C`: quick stop (bit 4 = 0).
        QUICK_STOP = 0x046C => "quick stop",
        /// `04FC`: reset; the drive resets on the 0->1 edge of bit 7, so send it after `047C`/`043C`.
        RESET = 0x04FC => "reset",
        /// `847C`: start reverse (bit 15; only if 8-54 allows the bus to reverse).
        START_REVERSE = 0x847C => "start reverse",
        /// `057C`: jog (bit 8; speed 3-19 Jog Speed).
        JOG = 0x057C => "jog",
    }

    /// Bit 02: 1 = ramp, 0 = DC brake (+stop).
    pub const BIT_RAMP: u16 = 1 << 2;
    /// Bit 03: 1 = no coasting, 0 = coasting.
    pub const BIT_NO_COASTING: u16 = 1 << 3;
    /// Bit 04: 1 = ramp, 0 = quick stop.
    pub const BIT_NO_QUICK_STOP: u16 = 1 << 4;
    /// Bit 05: 1 = use ramp, 0 = hold (freeze) output frequency.
    pub const BIT_NO_HOLD: u16 = 1 << 5;
    /// Bit 06: 1 = start, 0 = ramp stop.
    pub const BIT_START: u16 = 1 << 6;
    /// Bit 07: 1 = reset (on the 0->1 edge).
    pub const BIT_RESET: u16 = 1 << 7;
    /// Bit 08: 1 = jog.
    pub const BIT_JOG: u16 = 1 << 8;
    /// Bit 09: 1 = ramp 2, 0 = ramp 1.
    pub const BIT_RAMP_2: u16 = 1 << 9;
    /// Bit 10: 1 = data valid, 0 = data invalid (the control word is ignored).
    pub const BIT_DATA_VALID: u16 = 1 << 10;
    /// Bit 11: 1 = relay 01 active.
    pub const BIT_RELAY_1: u16 = 1 << 11;
    /// Bit 12: 1 = relay 02 (or 04) active.
    pub const BIT_RELAY_2: u16 = 1 << 12;
    /// Bit 15: 1 = reverse.
    pub const BIT_REVERSE: u16 = 1 << 15;

    /// The word with `mask` set or cleared.
    pub const fn with(self, mask: u16, on: bool) -> ControlWord {
        ControlWord(if on { self.0 | mask } else { self.0 & !mask })
    }
    /// True when every bit of `mask` is set.
    pub const fn has(self, mask: u16) -> bool {
        self.0 & mask == mask
    }
    /// Bits 00–01: preset reference select (3-10[0..3]).
    pub const fn preset_reference(self) -> u8 {
        (self.0 & 0b11) as u8
    }
    /// Bit 02 = 1: ramp (not DC brake).
    pub const fn ramp(self) -> bool {
        self.has(Self::BIT_RAMP)
    }
    /// Bit 02 = 0: DC brake (+stop).
    pub const fn dc_brake(self) -> bool {
        !self.ramp()
    }
    /// Bit 03 = 1: no coasting.
    pub const fn no_coasting(self) -> bool {
        self.has(Self::BIT_NO_COASTING)
    }
    /// Bit 03 = 0: coasting.
    pub const fn coasting(self) -> bool {
        !self.no_coasting()
    }
    /// Bit 04 = 0: quick stop.
    pub const fn quick_stop(self) -> bool {
        !self.has(Self::BIT_NO_QUICK_STOP)
    }
    /// Bit 05 = 0: hold (freeze) output frequency.
    pub const fn hold(self) -> bool {
        !self.has(Self::BIT_NO_HOLD)
    }
    /// Bit 06 = 1: start (0: ramp stop).
    pub const fn start(self) -> bool {
        self.has(Self::BIT_START)
    }
    /// Bit 07 = 1: reset (acts on the 0->1 edge).
    pub const fn reset(self) -> bool {
        self.has(Self::BIT_RESET)
    }
    /// Bit 08 = 1: jog.
    pub const fn jog(self) -> bool {
        self.has(Self::BIT_JOG)
    }
    /// Bit 09 = 1: ramp 2 (0: ramp 1).
    pub const fn ramp_2(self) -> bool {
        self.has(Self::BIT_RAMP_2)
    }
    /// Bit 10 = 1: data valid; with 0 the drive ignores the control word.
    pub const fn data_valid(self) -> bool {
        self.has(Self::BIT_DATA_VALID)
    }
    /// Bit 11 = 1: relay 01 active.
    pub const fn relay_1(self) -> bool {
        self.has(Self::BIT_RELAY_1)
    }
    /// Bit 12 = 1: relay 02 (or 04) active.
    pub const fn relay_2(self) -> bool {
        self.has(Self::BIT_RELAY_2)
    }
    /// Bits 13–14: set-up select.
    pub const fn setup(self) -> u8 {
        ((self.0 >> 13) & 0b11) as u8
    }
    /// Bit 15 = 1: reverse.
    pub const fn reverse(self) -> bool {
        self.has(Self::BIT_REVERSE)
    }

    /// The meaning of bit `bit` (0–15) when it is set.
    pub const fn bit_name(bit: u8) -> &'static str {
        match bit {
            0 => "preset reference select lsb",
            1 => "preset reference select msb",
            2 => "ramp (no DC brake)",
            3 => "no coasting",
            4 => "ramp (no quick stop)",
            5 => "use ramp (no hold)",
            6 => "start",
            7 => "reset",
            8 => "jog",
            9 => "ramp 2",
            10 => "data valid",
            11 => "relay 01 active",
            12 => "relay 02 active",
            13 => "set-up select lsb",
            14 => "set-up select msb",
            15 => "reverse",
            _ => "no such bit",
        }
    }
}

impl fmt::Display for ControlWord {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04X}", self.0)?;
        if let Some(n) = self.name() {
            write!(f, " ({n})")?;
        }
        Ok(())
    }
}

/// Status word, FC profile (PCD1 from the drive). Accessors are named after the value 1
/// (protocols.md 2.7).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct StatusWord(pub u16);

impl StatusWord {
    /// True when every bit of `mask` is set.
    pub const fn has(self, mask: u16) -> bool {
        self.0 & mask == mask
    }
    const fn bit(self, n: u8) -> bool {
        self.0 >> n & 1 == 1
    }
    /// The word with bit `n` (0–15) set or cleared.
    pub const fn with_bit(self, n: u8, on: bool) -> StatusWord {
        let mask = 1u16 << (n & 15);
        StatusWord(if on { self.0 | mask } else { self.0 & !mask })
    }
    /// Bit 00: control ready.
    pub const fn control_ready(self) -> bool {
        self.bit(0)
    }
    /// Bit 01: drive ready.
    pub const fn drive_ready(self) -> bool {
        self.bit(1)
    }
    /// Bit 02: enable (0: coasting).
    pub const fn enable(self) -> bool {
        self.bit(2)
    }
    /// Bit 03: trip.
    pub const fn trip(self) -> bool {
        self.bit(3)
    }
    /// Bit 04: error (no trip).
    pub const fn error(self) -> bool {
        self.bit(4)
    }
    /// Bit 06: triplock.
    pub const fn triplock(self) -> bool {
        self.bit(6)
    }
    /// Bit 07: warning.
    pub const fn warning(self) -> bool {
        self.bit(7)
    }
    /// Bit 08: speed = reference.
    pub const fn at_reference(self) -> bool {
        self.bit(8)
    }
    /// Bit 09: bus control (0: local operation).
    pub const fn bus_control(self) -> bool {
        self.bit(9)
    }
    /// Bit 10: frequency limit OK (0: out of frequency limit).
    pub const fn frequency_limit_ok(self) -> bool {
        self.bit(10)
    }
    /// Bit 11: in operation.
    pub const fn in_operation(self) -> bool {
        self.bit(11)
    }
    /// Bit 12: stopped, auto start (overtemperature).
    pub const fn stopped_auto_start(self) -> bool {
        self.bit(12)
    }
    /// Bit 13: voltage exceeded.
    pub const fn voltage_exceeded(self) -> bool {
        self.bit(13)
    }
    /// Bit 14: torque (current limit) exceeded.
    pub const fn torque_exceeded(self) -> bool {
        self.bit(14)
    }
    /// Bit 15: timer (thermal) exceeded.
    pub const fn timer_exceeded(self) -> bool {
        self.bit(15)
    }

    /// The meaning of bit `bit` (0–15) when it is set.
    pub const fn bit_name(bit: u8) -> &'static str {
        match bit {
            0 => "control ready",
            1 => "drive ready",
            2 => "enable",
            3 => "trip",
            4 => "error (no trip)",
            5 => "reserved",
            6 => "triplock",
            7 => "warning",
            8 => "speed = reference",
            9 => "bus control",
            10 => "frequency limit OK",
            11 => "in operation",
            12 => "stopped, auto start (overtemperature)",
            13 => "voltage exceeded",
            14 => "torque (current limit) exceeded",
            15 => "timer (thermal) exceeded",
            _ => "no such bit",
        }
    }
}

impl fmt::Display for StatusWord {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04X}", self.0)
    }
}

/// The bus reference (MRV, PCD2 from the master) or the main actual value (MAV, PCD2 from
/// the drive): signed, two's complement, `0x4000` = 100 % of the reference range
/// (`0xC000` = -100 %, the full range is about ±200 %).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Reference(pub i16);

impl Reference {
    /// 100 % on the wire.
    pub const FULL: i16 = 0x4000;

    /// The reference from its word on the wire.
    pub const fn from_word(word: u16) -> Reference {
        Reference(word as i16)
    }
    /// The word on the wire.
    pub const fn word(self) -> u16 {
        self.0 as u16
    }
    /// The value in percent of the reference range (`0x2000` = 50 %).
    pub fn percent(self) -> f64 {
        f64::from(self.0) * 100.0 / f64::from(Self::FULL)
    }
    /// The nearest reference to `percent`, saturated at the ends of the 16-bit range
    /// (about -200 % and +200 %).
    pub fn from_percent(percent: f64) -> Reference {
        Reference(round_sat(percent * f64::from(Self::FULL) / 100.0))
    }
    /// The value in Hz for the reference range `min_hz`..`max_hz` (3-02 Minimum Reference,
    /// 3-03 Maximum Reference): `0` is `min_hz`, `0x4000` is `max_hz`, linear beyond.
    /// With 3-00 = -max..+max pass `min_hz = 0`: the scale is then symmetric.
    pub fn hz(self, min_hz: f64, max_hz: f64) -> f64 {
        min_hz + (max_hz - min_hz) * f64::from(self.0) / f64::from(Self::FULL)
    }
    /// The nearest reference to `hz` in the range `min_hz`..`max_hz` (see [`hz`](Self::hz)),
    /// saturated; an empty range (`min_hz == max_hz`) gives 0.
    pub fn from_hz(hz: f64, min_hz: f64, max_hz: f64) -> Reference {
        let span = max_hz - min_hz;
        if span == 0.0 || span.is_nan() {
            return Reference(0);
        }
        Reference(round_sat((hz - min_hz) / span * f64::from(Self::FULL)))
    }
}

/// Rounds half away from zero and saturates to `i16` (no `f64::round` in `core`).
fn round_sat(x: f64) -> i16 {
    // `as` saturates and maps NaN to 0.
    let r = if x >= 0.0 { x + 0.5 } else { x - 0.5 };
    (r as i64).clamp(i16::MIN as i64, i16::MAX as i64) as i16
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn common_control_words_are_named() {
        use ControlWord as W;
        let words = [W::START, W::RAMP_STOP, W::COAST, W::QUICK_STOP, W::RESET, W::START_REVERSE, W::JOG];
        let names = ["start", "ramp stop", "coast", "quick stop", "reset", "start reverse", "jog"];
        for (word, name) in words.into_iter().zip(names) {
            assert_eq!(word.name(), Some(name));
            assert_eq!(word.process_block_name().strip_prefix("process block: "), Some(name));
        }
        assert_eq!(ControlWord(0x047C), ControlWord::START);
        assert_eq!(ControlWord(0).name(), Some("data invalid: the control word is ignored"));
        assert_eq!(ControlWord(0).process_block_name(), "process block: control word and reference");
        assert_eq!(ControlWord(0x047D).name(), None);
    }

    #[test]
    fn common_control_words_have_the_table_bits() {
        let s = ControlWord::START;
        assert!(s.ramp() && s.no_coasting() && !s.quick_stop() && !s.hold() && s.start() && s.data_valid());
        assert!(!s.reset() && !s.jog() && !s.reverse() && s.preset_reference() == 0 && s.setup() == 0);
        assert!(!ControlWord::RAMP_STOP.start() && ControlWord::RAMP_STOP.data_valid());
        assert!(ControlWord::COAST.coasting() && ControlWord::COAST.start());
        assert!(ControlWord::QUICK_STOP.quick_stop());
        assert!(ControlWord::RESET.reset());
        assert!(ControlWord::START_REVERSE.reverse() && ControlWord::START_REVERSE.start());
        assert!(ControlWord::JOG.jog());
        assert_eq!(ControlWord::START.with(ControlWord::BIT_START, false), ControlWord::RAMP_STOP);
        assert_eq!(ControlWord::START.with(ControlWord::BIT_REVERSE, true), ControlWord::START_REVERSE);
        assert_eq!(ControlWord(0x6003).setup(), 3);
        assert_eq!(ControlWord(0x6003).preset_reference(), 3);
    }

    #[test]
    fn status_word_examples() {
        // protocols.md 2.7: STW 0607 = bits 0, 1, 2, 9, 10.
        let s = StatusWord(0x0607);
        assert!(
            s.control_ready() && s.drive_ready() && s.enable() && s.bus_control() && s.frequency_limit_ok()
        );
        assert!(!s.trip() && !s.in_operation() && !s.warning());
        // "running at 50 %": 0F03 = bits 0, 1, 8, 9, 10, 11.
        let r = StatusWord(0x0F03);
        assert!(r.in_operation() && r.at_reference() && !r.enable());
        assert_eq!(StatusWord(0).with_bit(3, true), StatusWord(0x0008));
    }

    #[test]
    fn reference_scaling() {
        assert_eq!(Reference(0x2000).percent(), 50.0);
        assert_eq!(Reference::from_word(0xC000).percent(), -100.0);
        assert_eq!(Reference::from_percent(100.0), Reference(0x4000));
        assert_eq!(Reference::from_percent(-100.0).word(), 0xC000);
        assert_eq!(Reference::from_percent(500.0), Reference(i16::MAX));
        assert_eq!(Reference::from_percent(-500.0), Reference(i16::MIN));
        assert_eq!(Reference::from_percent(f64::NAN), Reference(0));
        // protocols.md 2.8: low limit 0 Hz, high limit 50 Hz, MAV 0x2000 = 25 Hz.
        assert_eq!(Reference(0x2000).hz(0.0, 50.0), 25.0);
        assert_eq!(Reference::from_hz(25.0, 0.0, 50.0), Reference(0x2000));
        assert_eq!(Reference::from_hz(10.0, 10.0, 50.0), Reference(0));
        assert_eq!(Reference(0x4000).hz(10.0, 50.0), 50.0);
        assert_eq!(Reference::from_hz(1.0, 5.0, 5.0), Reference(0));
        assert_eq!(Reference::from_percent(0.00305), Reference(0));
        assert_eq!(Reference::from_percent(0.00306), Reference(1));
    }
}
