//! Toshiba Inverter Protocol (TIP) of the VF-AS1, ASCII mode and binary mode
//! (`seeds/002_43d8a4399c8be05f.txt` and the public manuals in protocols.md section 1).
//! Modbus-RTU on the same drive lives in [`crate::modbus`].
//!
//! The drive tells the two modes apart by the start code (protocols.md 1.3):
//!
//! | mode | start code | frame |
//! |---|---|---|
//! | [`ascii`] | `(` (28H) | `( [INV-NO:2] CMD COMNO:4 [DATA:0..4] [& SUM:2] ) CR` |
//! | [`binary`] | `/` (2FH) | `2F [INV-NO] CMD COMNO:2 [DATA:2] SUM`, block `X`/`Y` |
//!
//! This module holds what both modes share: the communication numbers ([`CommNo`], with a
//! table of the known ones, their names, units and scales), the commands ([`Cmd`]), the error
//! codes 0000–0004 ([`ErrorCode`]), the bit layouts of FA00, FD01 and FC91 ([`Command1`],
//! [`Status1`], [`Alarm`]), the 0.01 Hz value ([`Frequency`]), the serial defaults and
//! [`timing`]; and the pieces for a drive that hears both modes on one line: [`TipScanner`]
//! (start code `(` or 2F picks the mode), [`TipRequest`] / [`TipReply`] and the [`Tip`]
//! protocol. Masters that speak one mode use [`ascii::TipAscii`] or [`binary::TipBinary`].
//!
//! Replies while the inverter is tripped carry the command in lower case (CMD + 20H): `r`,
//! `w`, `p`, `g`, `n` (protocols.md 1.4/1.5); every typed reply has a `tripped` flag for it.

use core::time::Duration;

use crate::describe::Field;
use crate::line::CharFormat;
use crate::session::Timing;

pub mod ascii;
pub mod binary;
mod tip;

#[cfg(test)]
mod session_tests;

pub use tip::{Tip, TipPending, TipReply, TipRequest, TipScanner};

/// ASCII mode's start code `(` (28H): a frame that starts with it is an ASCII-mode frame.
pub const ASCII_START: u8 = b'(';
/// Binary mode's start code 2FH (`/`): a frame that starts with it is a binary-mode frame.
pub const BINARY_START: u8 = 0x2F;

/// The serial speed a VF-AS1 ships with (project decision; 9600, 19200 and 38400 allowed).
pub const DEFAULT_BAUD: u32 = 19200;
/// 8 data bits, even parity, 1 stop bit: the drive's default (it sends with 2 stop bits).
pub const DEFAULT_FORMAT: CharFormat = CharFormat::EVEN_8E1;
/// The master's default response timeout.
pub const RESPONSE_TIMEOUT: Duration = Duration::from_millis(100);
/// Characters of silence the master leaves after the last byte before its next request.
///
/// The manual asks for no silence (the drive ignores everything before a start code); this
/// gap only gives the drive time to turn its transmitter off.
pub const MIN_GAP_CHARS: u32 = 4;

/// Master timing for TIP at `baud` and `format`: 100 ms response timeout, a gap of
/// [`MIN_GAP_CHARS`] characters between exchanges.
pub fn timing(baud: u32, format: CharFormat) -> Timing {
    let gap = format.char_time(baud) * MIN_GAP_CHARS;
    Timing::new(baud, format, RESPONSE_TIMEOUT, gap)
}

/// [`timing`] at the drive's defaults, 19200 bps 8E1.
pub fn default_timing() -> Timing {
    timing(DEFAULT_BAUD, DEFAULT_FORMAT)
}

/// The number block communication reads for read-item selection `selection` (f875–f879;
/// protocols.md 1.7): 1 FD01, 2 FD00, 3 FE03, 4 FE05, 5 FC91, 6 FD22, 7 FD06, 8 FD07, 9 FE35,
/// 10 FE36, 11 FE37, 12 FE04, 13 FC90 (13 a project addition); `None` for 0 (no selection) and
/// anything else.
pub const fn block_read_item(selection: u16) -> Option<CommNo> {
    Some(CommNo(match selection {
        1 => 0xFD01,
        2 => 0xFD00,
        3 => 0xFE03,
        4 => 0xFE05,
        5 => 0xFC91,
        6 => 0xFD22,
        7 => 0xFD06,
        8 => 0xFD07,
        9 => 0xFE35,
        10 => 0xFE36,
        11 => 0xFE37,
        12 => 0xFE04,
        13 => 0xFC90,
        _ => return None,
    }))
}

/// The number block communication writes for write-item selection `selection` (f870/f871):
/// 1 FA00, 2 FA20, 3 FA01, 4 FA50, 5 FA51; `None` for 0 (no selection) and anything else.
pub const fn block_write_item(selection: u16) -> Option<CommNo> {
    Some(CommNo(match selection {
        1 => 0xFA00,
        2 => 0xFA20,
        3 => 0xFA01,
        4 => 0xFA50,
        5 => 0xFA51,
        _ => return None,
    }))
}

/// A communication number (COMNO): the 16-bit number of a parameter or monitor, e.g. FD00.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct CommNo(pub u16);

impl CommNo {
    /// FA00 communication command 1 (RAM only), bits in [`Command1`].
    pub const COMMAND_1: CommNo = CommNo(0xFA00);
    /// FA01 frequency command from communication (RAM only), 0.01 Hz.
    pub const FREQUENCY_COMMAND: CommNo = CommNo(0xFA01);
    /// FD00 output frequency (current value), 0.01 Hz.
    pub const OUTPUT_FREQUENCY: CommNo = CommNo(0xFD00);
    /// FD01 inverter operating status 1 (current), bits in [`Status1`].
    pub const STATUS_1: CommNo = CommNo(0xFD01);
    /// FE01 inverter operating status 1 held at the last trip, bits in [`Status1`].
    pub const STATUS_1_AT_TRIP: CommNo = CommNo(0xFE01);
    /// FE02 frequency command value, 0.01 Hz.
    pub const FREQUENCY_COMMAND_VALUE: CommNo = CommNo(0xFE02);
    /// FE03 output current, 0.01 % of the rated value.
    pub const OUTPUT_CURRENT: CommNo = CommNo(0xFE03);
    /// FE05 output voltage, 0.01 % of the rated value.
    pub const OUTPUT_VOLTAGE: CommNo = CommNo(0xFE05);
    /// FC90 current trip code.
    pub const TRIP_CODE: CommNo = CommNo(0xFC90);
    /// FC91 alarm information monitor, bits in [`Alarm`].
    pub const ALARM: CommNo = CommNo(0xFC91);
    /// FE70 rated current, 0.1 A.
    pub const RATED_CURRENT: CommNo = CommNo(0xFE70);
    /// 0010 deceleration time, 0.1 s.
    pub const DECELERATION_TIME: CommNo = CommNo(0x0010);
    /// 0012 upper-limit (maximum output) frequency, 0.01 Hz.
    pub const UPPER_LIMIT_FREQUENCY: CommNo = CommNo(0x0012);

    /// What the table knows about this number.
    pub fn info(self) -> Option<&'static CommInfo> {
        COMM_NOS.binary_search_by_key(&self.0, |i| i.comm_no.0).ok().and_then(|i| COMM_NOS.get(i))
    }

    /// The manual's name for this number, where the table knows it.
    pub fn name(self) -> Option<&'static str> {
        self.info().map(|i| i.name)
    }

    /// How the data of this number reads ([`Format::Raw`] for numbers the table does not know).
    pub fn format(self) -> Format {
        self.info().map_or(Format::Raw, |i| i.format)
    }

    /// `data` in this number's unit (`FE03` 077B -> 19.15 %), where it has one.
    pub fn value(self, data: u16) -> Option<f64> {
        match self.format() {
            Format::Scaled { decimals, .. } => Some(scale(data, decimals)),
            _ => None,
        }
    }

    /// `data` in Hz when this number is a 0.01 Hz value (FA01, FD00, FE02, ...).
    pub fn hz(self, data: u16) -> Option<f64> {
        match self.format() {
            Format::Scaled { unit: "Hz", decimals: 2 } => Some(Frequency(data).hz()),
            _ => None,
        }
    }

    /// True for the FAxx command numbers, which live in RAM only (W writes no EEPROM there).
    pub const fn is_ram_only(self) -> bool {
        self.0 & 0xFF00 == 0xFA00
    }

    /// The "communication number" field of a frame, with the number's name.
    pub fn field(self) -> Field<'static> {
        let f = Field::hex("communication number", self.0 as u32, 4);
        match self.name() {
            Some(name) => f.with_meaning(name),
            None => f,
        }
    }

    /// Hands `out` the data field `name` of this number: its quantity where it has a unit,
    /// then one flag per set bit where it is bit coded.
    pub fn describe_data(self, name: &'static str, data: u16, out: &mut dyn FnMut(Field<'_>)) {
        describe_value(self.format(), name, data, 4, out);
    }
}

/// Hands `out` a 16-bit data field read with `format`, shown with `digits` hex digits.
pub(crate) fn describe_value(
    format: Format,
    name: &'static str,
    data: u16,
    digits: u8,
    out: &mut dyn FnMut(Field<'_>),
) {
    let field = Field::hex(name, data as u32, digits);
    match format {
        Format::Scaled { unit, decimals } => out(field.with_quantity(scale(data, decimals), unit, decimals)),
        Format::Bits(bits) => {
            out(field);
            for bit in bits.iter().filter(|b| data & b.mask != 0) {
                out(Field::flag(bit.name, true));
            }
        }
        Format::Code | Format::Raw => out(field),
    }
}

fn scale(data: u16, decimals: u8) -> f64 {
    let div = match decimals {
        0 => 1.0,
        1 => 10.0,
        2 => 100.0,
        _ => 1000.0,
    };
    data as f64 / div
}

/// How the 16-bit data of a communication number reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// A number in `unit` with `decimals` decimal places: raw × 10^-decimals.
    Scaled {
        /// The unit symbol (`"Hz"`, `"%"`, `"A"`, `"V"`, `"s"`).
        unit: &'static str,
        /// Decimal places of the wire resolution (2 for 0.01 Hz).
        decimals: u8,
    },
    /// Bit coded; the named bits.
    Bits(&'static [Bit]),
    /// A code number (a trip code, a model code, a version).
    Code,
    /// Not known: shown as hex.
    Raw,
}

/// One named bit of a bit-coded value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bit {
    /// The bit's mask (`1 << n`).
    pub mask: u16,
    /// What a 1 in it means.
    pub name: &'static str,
}

/// What the table knows about one communication number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CommInfo {
    /// The number.
    pub comm_no: CommNo,
    /// Its name (from the manual's section titles, or from the VF-S11 driver in LinuxCNC).
    pub name: &'static str,
    /// How its data reads.
    pub format: Format,
}

const HZ: Format = Format::Scaled { unit: "Hz", decimals: 2 };
const PERCENT_001: Format = Format::Scaled { unit: "%", decimals: 2 };

const fn info(n: u16, name: &'static str, format: Format) -> CommInfo {
    CommInfo { comm_no: CommNo(n), name, format }
}

/// The communication numbers drivebus knows, sorted by number (protocols.md 1.9).
///
/// Names come from the VF-AS1 manual's section titles where the seed's table of contents shows
/// them (FA50–FA52, FD06/FD07, FE02, FB05, ...), else from the VF-S11 driver in LinuxCNC.
pub static COMM_NOS: &[CommInfo] = &[
    // manual VF-AS1 p.17: "2F 57 00 10 00 64 FA" writes 10.0 s (100 = 64H) to 0010.
    info(0x0010, "deceleration time", Format::Scaled { unit: "s", decimals: 1 }),
    // LinuxCNC vfs11_vfd.c: REG_UPPERLIMIT 0x0012 "limit on output frequency in VFD".
    info(0x0012, "upper-limit frequency", HZ),
    info(0xFA00, "communication command 1", Format::Bits(Command1::BITS)),
    info(0xFA01, "frequency command (communication)", HZ),
    info(0xFA20, "communication command 2", Format::Raw),
    info(0xFA26, "communication command 3", Format::Raw),
    info(0xFA50, "terminal board output data", Format::Raw),
    info(0xFA51, "FM analog output data", Format::Raw),
    info(0xFA52, "AM analog output data", Format::Raw),
    info(0xFB05, "inverter model (capacity) code", Format::Code),
    info(0xFC90, "trip code", Format::Code),
    info(0xFC91, "alarm information", Format::Bits(Alarm::BITS)),
    info(0xFD00, "output frequency", HZ),
    info(0xFD01, "inverter operating status 1", Format::Bits(Status1::BITS)),
    info(0xFD06, "input terminal board status", Format::Raw),
    info(0xFD07, "output terminal board status", Format::Raw),
    info(0xFD42, "inverter operating status 2", Format::Raw),
    info(0xFD45, "inverter operating command mode status", Format::Raw),
    info(0xFD46, "inverter operating frequency mode status", Format::Raw),
    info(0xFD49, "inverter operating status 3", Format::Raw),
    info(0xFE00, "output frequency at trip", HZ),
    info(0xFE01, "inverter operating status 1 at trip", Format::Bits(Status1::BITS)),
    info(0xFE02, "frequency command value", HZ),
    info(0xFE03, "output current", PERCENT_001),
    info(0xFE05, "output voltage", PERCENT_001),
    info(0xFE06, "input terminal board status at trip", Format::Raw),
    info(0xFE07, "output terminal board status at trip", Format::Raw),
    info(0xFE08, "CPU1 version", Format::Code),
    info(0xFE09, "EEPROM version", Format::Code),
    info(0xFE10, "past trip 1", Format::Code),
    info(0xFE11, "past trip 2", Format::Code),
    info(0xFE12, "past trip 3", Format::Code),
    info(0xFE13, "past trip 4", Format::Code),
    info(0xFE16, "estimated operating frequency", HZ),
    info(0xFE27, "inverter load factor", Format::Raw),
    info(0xFE42, "inverter operating status 2 at trip", Format::Raw),
    info(0xFE45, "inverter operating command mode status at trip", Format::Raw),
    info(0xFE46, "inverter operating frequency mode status at trip", Format::Raw),
    info(0xFE49, "inverter operating status 3 at trip", Format::Raw),
    info(0xFE70, "rated current", Format::Scaled { unit: "A", decimals: 1 }),
    info(0xFE71, "rated voltage", Format::Scaled { unit: "V", decimals: 1 }),
    info(0xFE73, "CPU2 version", Format::Code),
    info(0xFE79, "cumulative operation time alarm", Format::Raw),
];

/// A frequency in 0.01 Hz, as FA01, FD00, FE02 and 0012 carry it (1770H = 60.00 Hz).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Frequency(pub u16);

impl Frequency {
    /// The value in Hz.
    pub fn hz(self) -> f64 {
        self.0 as f64 / 100.0
    }

    /// The nearest 0.01 Hz step to `hz`; `None` outside 0.00..=655.35 Hz.
    pub fn from_hz(hz: f64) -> Option<Frequency> {
        // Round half up without `f64::round` (not in core).
        let centi = hz * 100.0 + 0.5;
        if (0.0..65536.0).contains(&centi) {
            Some(Frequency(centi as u16))
        } else {
            None
        }
    }
}

/// A TIP command (CMD), as both modes spell it: one ASCII letter, 52H `R` and so on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Cmd {
    /// `R` (52H): reads the data with the specified communication number.
    R,
    /// `W` (57H): writes the data to RAM and EEPROM (FAxx: RAM only).
    W,
    /// `P` (50H): writes the data to RAM only.
    P,
    /// `G` (47H, binary mode only): reads, like `R`, with dummy data in the request.
    G,
}

impl Cmd {
    /// The letter on the wire (upper case: the form of requests and of untripped replies).
    pub const fn letter(self) -> u8 {
        match self {
            Cmd::R => b'R',
            Cmd::W => b'W',
            Cmd::P => b'P',
            Cmd::G => b'G',
        }
    }

    /// The command for `letter` and whether it was lower case (a tripped inverter's reply).
    pub const fn from_letter(letter: u8) -> Option<(Cmd, bool)> {
        Some(match letter {
            b'R' => (Cmd::R, false),
            b'W' => (Cmd::W, false),
            b'P' => (Cmd::P, false),
            b'G' => (Cmd::G, false),
            b'r' => (Cmd::R, true),
            b'w' => (Cmd::W, true),
            b'p' => (Cmd::P, true),
            b'g' => (Cmd::G, true),
            _ => return None,
        })
    }

    /// The manual's description.
    pub const fn name(self) -> &'static str {
        match self {
            Cmd::R => "read",
            Cmd::W => "write (RAM and EEPROM)",
            Cmd::P => "write (RAM)",
            Cmd::G => "read (dummy data)",
        }
    }

    /// True for the commands that write (`W`, `P`).
    pub const fn is_write(self) -> bool {
        matches!(self, Cmd::W | Cmd::P)
    }
}

/// The letter of an error reply: `N` (4EH), `n` (6EH) while the inverter is tripped.
pub const ERROR_LETTER: u8 = b'N';

/// The error code of an error reply (protocols.md 1.6: VF-AS1 manual 4.3 "Transmission errors").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ErrorCode(pub u16);

impl ErrorCode {
    /// 0000 impossible to execute: a parameter not changeable while running, a write during
    /// setup or initialisation, an EEPROM fault.
    pub const IMPOSSIBLE_TO_EXECUTE: ErrorCode = ErrorCode(0x0000);
    /// 0001 data error: invalid data (out of range, too many digits).
    pub const DATA_ERROR: ErrorCode = ErrorCode(0x0001);
    /// 0002 communication number error: no such communication number.
    pub const COMM_NO_ERROR: ErrorCode = ErrorCode(0x0002);
    /// 0003 command error: no such command (ASCII mode answers it, binary mode does not).
    pub const COMMAND_ERROR: ErrorCode = ErrorCode(0x0003);
    /// 0004 checksum error: the checksum does not match.
    pub const CHECKSUM_ERROR: ErrorCode = ErrorCode(0x0004);

    /// The manual's name, or "unknown error code".
    pub const fn name(self) -> &'static str {
        match self.0 {
            0 => "impossible to execute",
            1 => "data error",
            2 => "communication number error",
            3 => "command error",
            4 => "checksum error",
            _ => "unknown error code",
        }
    }

    /// The "error code" field of an error reply.
    pub fn field(self) -> Field<'static> {
        Field::hex("error code", self.0 as u32, 4).with_meaning(self.name())
    }
}

macro_rules! bits {
    ($(#[$m:meta])* $ty:ident { $($(#[$cm:meta])* $c:ident = $bit:literal, $text:literal;)* }) => {
        $(#[$m])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
        pub struct $ty(pub u16);

        impl $ty {
            $($(#[$cm])* pub const $c: u16 = 1 << $bit;)*
            /// Every named bit, from bit 15 down.
            pub const BITS: &'static [Bit] = &[$(Bit { mask: 1 << $bit, name: $text }),*];

            /// True when every bit of `mask` is set.
            pub const fn contains(self, mask: u16) -> bool {
                self.0 & mask == mask
            }

            /// The names of the bits that are set, from bit 15 down.
            pub fn set_bits(self) -> impl Iterator<Item = &'static str> {
                Self::BITS.iter().filter(move |b| self.0 & b.mask != 0).map(|b| b.name)
            }
        }
    };
}

bits! {
    /// FA00 communication command 1 (VF-S11 layout from the LinuxCNC driver; protocols.md 1.9
    /// asks to verify it against the VF-AS1 tables, which were not found).
    Command1 {
        /// Bit 15: command priority (communication has command authority).
        COMMAND_PRIORITY = 15, "command priority";
        /// Bit 14: frequency priority (FA01 is used).
        FREQUENCY_PRIORITY = 14, "frequency priority";
        /// Bit 13: fault reset.
        FAULT_RESET = 13, "fault reset";
        /// Bit 12: emergency stop (E trip).
        EMERGENCY_STOP = 12, "emergency stop";
        /// Bit 11: coast stop.
        COAST_STOP = 11, "coast stop";
        /// Bit 10: run (1) / stop (0).
        RUN = 10, "run";
        /// Bit 9: reverse (1) / forward (0).
        REVERSE = 9, "reverse";
        /// Bit 8: jog run.
        JOG = 8, "jog run";
        /// Bit 7: DC braking.
        DC_BRAKING = 7, "DC braking";
        /// Bit 6: acceleration/deceleration pattern 2.
        ACC_DEC_PATTERN_2 = 6, "acc/dec pattern 2";
        /// Bit 5: PI control off.
        PI_OFF = 5, "PI control off";
        /// Bit 4: motor 2 selected.
        MOTOR_2 = 4, "motor 2";
        /// Bit 3: preset-speed selection bit 3.
        PRESET_SPEED_3 = 3, "preset speed bit 3";
        /// Bit 2: preset-speed selection bit 2.
        PRESET_SPEED_2 = 2, "preset speed bit 2";
        /// Bit 1: preset-speed selection bit 1.
        PRESET_SPEED_1 = 1, "preset speed bit 1";
        /// Bit 0: preset-speed selection bit 0.
        PRESET_SPEED_0 = 0, "preset speed bit 0";
    }
}

impl Command1 {
    /// C400: command and frequency priority, run forward.
    pub const RUN_FORWARD: Command1 = Command1(0xC400);
    /// C600: command and frequency priority, run reverse.
    pub const RUN_REVERSE: Command1 = Command1(0xC600);
    /// C000: command and frequency priority, stopped.
    pub const STOP: Command1 = Command1(0xC000);
    /// 0000: communication gives up command and frequency authority.
    pub const RELEASE: Command1 = Command1(0x0000);
}

bits! {
    /// FD01 / FE01 inverter operating status 1 (VF-S11 layout from the LinuxCNC driver).
    Status1 {
        /// Bit 14: standby.
        STANDBY = 14, "standby";
        /// Bit 13: standby with ST on.
        STANDBY_ST_ON = 13, "standby (ST on)";
        /// Bit 12: emergency-stopped.
        EMERGENCY_STOPPED = 12, "emergency-stopped";
        /// Bit 11: coast-stopped.
        COAST_STOPPED = 11, "coast-stopped";
        /// Bit 10: running.
        RUNNING = 10, "running";
        /// Bit 9: reverse.
        REVERSE = 9, "reverse";
        /// Bit 8: jog.
        JOG = 8, "jog";
        /// Bit 7: DC braking.
        DC_BRAKING = 7, "DC braking";
        /// Bit 6: acceleration pattern 2.
        ACC_PATTERN_2 = 6, "acc pattern 2";
        /// Bit 5: PI control off.
        PI_OFF = 5, "PI control off";
        /// Bit 4: motor 2.
        MOTOR_2 = 4, "motor 2";
        /// Bit 2: alarm.
        ALARM = 2, "alarm";
        /// Bit 1: tripped.
        TRIPPED = 1, "tripped";
        /// Bit 0: failure FL.
        FAILURE_FL = 0, "failure FL";
    }
}

bits! {
    /// FC91 alarm information (VF-S11 layout from the LinuxCNC driver).
    Alarm {
        /// Bit 15: auto-stop.
        AUTO_STOP = 15, "auto-stop";
        /// Bit 14: stop after power loss.
        POWER_LOSS_STOP = 14, "stop after power loss";
        /// Bit 13: main voltage.
        MAIN_VOLTAGE = 13, "main voltage";
        /// Bit 10: cumulative operating hours.
        CUMULATIVE_HOURS = 10, "cumulative operating hours";
        /// Bit 9: braking-resistor overload.
        BRAKING_RESISTOR_OVERLOAD = 9, "braking-resistor overload";
        /// Bit 8: over-torque.
        OVER_TORQUE = 8, "over-torque";
        /// Bit 7: low current.
        LOW_CURRENT = 7, "low current";
        /// Bit 5: main under-voltage.
        MAIN_UNDER_VOLTAGE = 5, "main under-voltage";
        /// Bit 4: over-voltage.
        OVER_VOLTAGE = 4, "over-voltage";
        /// Bit 3: overheat.
        OVERHEAT = 3, "overheat";
        /// Bit 2: motor overload.
        MOTOR_OVERLOAD = 2, "motor overload";
        /// Bit 1: inverter overload.
        INVERTER_OVERLOAD = 1, "inverter overload";
        /// Bit 0: over-current.
        OVER_CURRENT = 0, "over-current";
    }
}

/// The read items of a block-communication reply by default (f875–f879, project decision).
pub const BLOCK_READ_DEFAULTS: [CommNo; 5] = [
    CommNo::STATUS_1,
    CommNo::OUTPUT_FREQUENCY,
    CommNo::OUTPUT_CURRENT,
    CommNo::TRIP_CODE,
    CommNo::OUTPUT_VOLTAGE,
];
/// The write targets of a block-communication request by default (f870/f871, project decision).
pub const BLOCK_WRITE_DEFAULTS: [CommNo; 2] = [CommNo::COMMAND_1, CommNo::FREQUENCY_COMMAND];

/// The "tripped" field of a reply.
pub(crate) fn tripped_field(tripped: bool) -> Field<'static> {
    let f = Field::flag("tripped", tripped);
    if tripped {
        f.with_meaning("lower-case CMD: the inverter is tripped")
    } else {
        f
    }
}

/// The checksum hint for a SUM that is the sum of a prefix of the covered bytes only.
pub(crate) fn prefix_hint(covered: &[u8], carried: u8) -> Option<crate::error::MismatchHint> {
    let mut sum = 0u8;
    let mut hint = None;
    for (i, &b) in covered.iter().enumerate().take(covered.len().saturating_sub(1)) {
        sum = sum.wrapping_add(b);
        if sum == carried {
            hint = Some(crate::error::MismatchHint::PrefixOnly { len: (i + 1) as u8 });
        }
    }
    hint
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_is_sorted_and_unique() {
        for w in COMM_NOS.windows(2) {
            assert!(w[0].comm_no < w[1].comm_no, "{:04X} before {:04X}", w[0].comm_no.0, w[1].comm_no.0);
        }
    }

    #[test]
    fn known_numbers() {
        assert_eq!(CommNo(0xFE03).name(), Some("output current"));
        // seeds/002_43d8a4399c8be05f.txt, table of contents: "RFE03077BCR" -> 077B = 1915 = 19.15 %.
        assert_eq!(CommNo(0xFE03).value(0x077B), Some(19.15));
        assert_eq!(CommNo::OUTPUT_FREQUENCY.hz(0x1770), Some(60.0));
        assert_eq!(CommNo::OUTPUT_CURRENT.hz(0x1770), None);
        assert_eq!(CommNo::RATED_CURRENT.value(123), Some(12.3));
        assert_eq!(CommNo::DECELERATION_TIME.value(0x64), Some(10.0));
        assert_eq!(CommNo(0x1234).format(), Format::Raw);
        assert!(CommNo::COMMAND_1.is_ram_only());
        assert!(!CommNo::DECELERATION_TIME.is_ram_only());
    }

    #[test]
    fn frequency_scale() {
        assert_eq!(Frequency(0x1770).hz(), 60.0);
        assert_eq!(Frequency::from_hz(60.0), Some(Frequency(0x1770)));
        assert_eq!(Frequency::from_hz(655.35), Some(Frequency(0xFFFF)));
        assert_eq!(Frequency::from_hz(655.36), None);
        assert_eq!(Frequency::from_hz(-1.0), None);
    }

    #[test]
    fn bits() {
        let c = Command1::RUN_FORWARD;
        assert!(c.contains(Command1::RUN | Command1::COMMAND_PRIORITY | Command1::FREQUENCY_PRIORITY));
        assert!(!c.contains(Command1::REVERSE));
        let names: std::vec::Vec<_> = c.set_bits().collect();
        assert_eq!(names, ["command priority", "frequency priority", "run"]);
        assert!(Status1(0x0002).contains(Status1::TRIPPED));
        assert_eq!(Alarm(0x8001).set_bits().count(), 2);
    }

    #[test]
    fn error_names() {
        assert_eq!(ErrorCode(4).name(), "checksum error");
        assert_eq!(ErrorCode::COMM_NO_ERROR.name(), "communication number error");
        assert_eq!(ErrorCode(9).name(), "unknown error code");
    }

    #[test]
    fn cmd_letters() {
        assert_eq!(Cmd::from_letter(b'r'), Some((Cmd::R, true)));
        assert_eq!(Cmd::from_letter(b'X'), None);
        assert_eq!(Cmd::P.letter(), 0x50);
    }

    #[test]
    fn default_timing_is_19200_8e1() {
        let t = default_timing();
        assert_eq!(t.response_timeout, Duration::from_millis(100));
        // 11 bits at 19200 = 573 µs; 4 characters = 2.29 ms.
        assert_eq!(t.char_time.as_micros(), 572);
        assert_eq!(t.min_gap, t.char_time * 4);
    }
}
