//! The values B800 frames carry: addresses, speeds, currents, status and error codes.
//!
//! Every value with a unit is a newtype, so a speed in 60 x Hz cannot be passed where a
//! current in 0.1 A is expected.

use core::fmt;

use crate::error::EmitError;

/// A drive's number, 1–63 (seed 000: "valid addresses { 1 63 }").
///
/// The number a user sets on the drive; the master's DA byte is this + 128
/// ([`Address::master_da`]), a drive's reply carries it unchanged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Address(u8);

impl Address {
    /// The lowest drive number.
    pub const MIN: u8 = 1;
    /// The highest drive number (seed 000: "Up to 63 drive addresses are permitted").
    pub const MAX: u8 = 63;

    /// Drive `n`, or `None` outside 1–63.
    pub const fn new(n: u8) -> Option<Address> {
        if n >= Self::MIN && n <= Self::MAX {
            Some(Address(n))
        } else {
            None
        }
    }

    /// Drive `n`, or an [`EmitError`] outside 1–63.
    pub const fn try_new(n: u8) -> Result<Address, EmitError> {
        match Self::new(n) {
            Some(a) => Ok(a),
            None => Err(EmitError::OutOfRange {
                field: "drive address",
                value: n as u32,
                min: Self::MIN as u32,
                max: Self::MAX as u32,
            }),
        }
    }

    /// The drive number, 1–63.
    pub const fn get(self) -> u8 {
        self.0
    }

    /// The DA byte a master sends to this drive: the number + 128 (0x81–0xBF).
    ///
    /// seed 000: "For communication with the B800 from a Host controller, add the value 128
    /// to the drive address."
    pub const fn master_da(self) -> u8 {
        self.0 + super::MASTER_OFFSET
    }
}

impl fmt::Display for Address {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// Whom a master's frame addresses: one drive, or every drive with the global address `G`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Destination {
    /// One drive (DA = number + 128).
    Drive(Address),
    /// Every drive (DA = 'G', 0x47); none replies.
    Global,
}

impl Destination {
    /// The DA byte on the wire (before hex encoding).
    pub const fn da(self) -> u8 {
        match self {
            Destination::Drive(a) => a.master_da(),
            Destination::Global => super::GLOBAL,
        }
    }

    /// The DA byte's meaning in a master frame: drive + 128, `G`, or `None` for any other byte.
    pub const fn from_da(da: u8) -> Option<Destination> {
        if da == super::GLOBAL {
            return Some(Destination::Global);
        }
        if da & 0x80 == 0 {
            return None;
        }
        match Address::new(da - super::MASTER_OFFSET) {
            Some(a) => Some(Destination::Drive(a)),
            None => None,
        }
    }
}

/// A speed as the B800 carries it: a 16-bit word of 60 x Hz (used by `P` and, by project
/// decision, the `z` reply).
///
/// seed 000: "Note that the transmitted speed in Hertz is always 60x the speed required.
/// Therefore 40Hz is transmitted as 40.0 x 60 = 2400."
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Speed(u16);

impl Speed {
    /// The highest speed a 16-bit word of 60 x Hz can carry: 65535 / 60 Hz.
    pub const MAX_HZ: f64 = 65535.0 / 60.0;

    /// A speed from its wire value (60 x Hz).
    pub const fn from_raw(raw: u16) -> Speed {
        Speed(raw)
    }

    /// The wire value (60 x Hz).
    pub const fn raw(self) -> u16 {
        self.0
    }

    /// The speed nearest `hz` (resolution 1/60 Hz); an error for a negative, non-finite or
    /// too high speed (above 1092.25 Hz the word overflows). `from_hz(40.0)` is 0x0960.
    pub fn from_hz(hz: f64) -> Result<Speed, EmitError> {
        word_of(hz, 60.0, "target speed must be 0 to 1092.25 Hz: the wire carries 60 x Hz in a 16-bit word")
            .map(Speed)
    }

    /// The speed in Hz.
    pub fn hz(self) -> f64 {
        self.0 as f64 / 60.0
    }
}

/// The 16-bit word nearest `value * steps` (`steps` wire units per unit); `error` for a
/// negative, non-finite or too high value.
fn word_of(value: f64, steps: f64, error: &'static str) -> Result<u16, EmitError> {
    let x = value * steps + 0.5;
    // A range test, so that NaN fails it too.
    if !(0.5..65536.0).contains(&x) {
        return Err(EmitError::Invalid(error));
    }
    // `as` truncates toward zero; with the 0.5 added above that rounds to nearest.
    Ok(x as u16)
}

/// Motor current in 0.1 A, the `a` reply's word (project decision: "`a` motor current in 0.1 A").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Current(u16);

impl Current {
    /// A current from its wire value (0.1 A).
    pub const fn from_raw(raw: u16) -> Current {
        Current(raw)
    }

    /// The wire value (0.1 A).
    pub const fn raw(self) -> u16 {
        self.0
    }

    /// The current nearest `amps` (resolution 0.1 A); an error below 0 or above 6553.5 A.
    pub fn from_amps(amps: f64) -> Result<Current, EmitError> {
        word_of(amps, 10.0, "motor current must be 0 to 6553.5 A: the wire carries 0.1 A in a 16-bit word")
            .map(Current)
    }

    /// The current in A.
    pub fn amps(self) -> f64 {
        self.0 as f64 / 10.0
    }
}

/// Motor speed in rpm, the `m` reply's word (project decision: "`m` motor speed in rpm").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Rpm(u16);

impl Rpm {
    /// A speed from its wire value (rpm).
    pub const fn from_raw(raw: u16) -> Rpm {
        Rpm(raw)
    }

    /// The wire value.
    pub const fn raw(self) -> u16 {
        self.0
    }

    /// The speed in rpm.
    pub const fn rpm(self) -> u16 {
        self.0
    }
}

/// The drive's software version as BCD, the `v` reply's word (project decision:
/// "`v` software version as BCD (0x0100 = 1.00)").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Version(u16);

impl Version {
    /// A version from its wire value.
    pub const fn from_raw(raw: u16) -> Version {
        Version(raw)
    }

    /// `major.minor`, each 0–99, as BCD; `None` above 99.
    pub const fn new(major: u8, minor: u8) -> Option<Version> {
        if major > 99 || minor > 99 {
            return None;
        }
        let hi = ((major / 10) << 4) | (major % 10);
        let lo = ((minor / 10) << 4) | (minor % 10);
        Some(Version((hi as u16) << 8 | lo as u16))
    }

    /// The wire value.
    pub const fn raw(self) -> u16 {
        self.0
    }

    /// True when all four digits are 0–9.
    pub const fn is_bcd(self) -> bool {
        let v = self.0;
        (v & 0xF) < 10 && (v >> 4 & 0xF) < 10 && (v >> 8 & 0xF) < 10 && (v >> 12 & 0xF) < 10
    }

    /// The number before the point (the high byte read as BCD).
    pub const fn major(self) -> u8 {
        let hi = (self.0 >> 8) as u8;
        (hi >> 4) * 10 + (hi & 0xF)
    }

    /// The number after the point (the low byte read as BCD).
    pub const fn minor(self) -> u8 {
        let lo = self.0 as u8;
        (lo >> 4) * 10 + (lo & 0xF)
    }
}

impl fmt::Display for Version {
    /// `1.00`; a word that is not BCD shows as `0x01AB`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.is_bcd() {
            write!(f, "{}.{:02}", self.major(), self.minor())
        } else {
            write!(f, "0x{:04X}", self.0)
        }
    }
}

/// The state code in the low byte of the `t` reply's status word (project decision: the
/// seed's code list, 0x02 standby, 0x93 running, 0x99 hardware enable missing, 0x9A tripped).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DriveState {
    /// 0x02: stopped, ready.
    Standby,
    /// 0x93: running.
    Running,
    /// 0x99: the hardware enable input is off.
    HardwareEnableMissing,
    /// 0x9A: tripped; the high byte carries the trip code.
    Tripped,
    /// Any other code.
    Other(u8),
}

impl DriveState {
    /// The code on the wire.
    pub const fn code(self) -> u8 {
        match self {
            DriveState::Standby => 0x02,
            DriveState::Running => 0x93,
            DriveState::HardwareEnableMissing => 0x99,
            DriveState::Tripped => 0x9A,
            DriveState::Other(c) => c,
        }
    }

    /// The state for a code.
    pub const fn from_code(code: u8) -> DriveState {
        match code {
            0x02 => DriveState::Standby,
            0x93 => DriveState::Running,
            0x99 => DriveState::HardwareEnableMissing,
            0x9A => DriveState::Tripped,
            c => DriveState::Other(c),
        }
    }

    /// What the state means, for the known codes.
    pub const fn meaning(self) -> Option<&'static str> {
        match self {
            DriveState::Standby => Some("standby"),
            DriveState::Running => Some("running"),
            DriveState::HardwareEnableMissing => Some("hardware enable missing"),
            DriveState::Tripped => Some("tripped"),
            DriveState::Other(_) => None,
        }
    }
}

/// The `t` reply's status word: low byte a [`DriveState`] code, high byte the trip code while
/// tripped, else 0x00 (project decision).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DriveStatus(u16);

impl DriveStatus {
    /// A status from its wire value.
    pub const fn from_raw(raw: u16) -> DriveStatus {
        DriveStatus(raw)
    }

    /// A status word for a state that is not tripped (high byte 0x00).
    pub const fn new(state: DriveState) -> DriveStatus {
        DriveStatus(state.code() as u16)
    }

    /// The status word of a drive tripped with `trip_code`.
    pub const fn tripped(trip_code: u8) -> DriveStatus {
        DriveStatus((trip_code as u16) << 8 | 0x9A)
    }

    /// The wire value.
    pub const fn raw(self) -> u16 {
        self.0
    }

    /// The state (low byte).
    pub const fn state(self) -> DriveState {
        DriveState::from_code(self.0 as u8)
    }

    /// The trip code (high byte) while tripped; `None` in any other state.
    pub const fn trip_code(self) -> Option<u8> {
        match self.state() {
            DriveState::Tripped => Some((self.0 >> 8) as u8),
            _ => None,
        }
    }
}

/// The code an `e` reply carries: why the drive did not carry out a command.
///
/// seed 000: "The error code will have one of the following values: 0x02 ... 0x9A".
/// Codes outside the seed's list are kept as they are (a drive may know more).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ErrorCode(pub u8);

impl ErrorCode {
    crate::error::named_codes! {
        ErrorCode;
        /// The seed's text for the code, `None` for a code not in its list.
        fn meaning;
        /// 0x02: "Drive in Standby (status information)".
        STANDBY(0x02) => "drive in standby (status information)",
        /// 0x91: "B800 not in keypad mode".
        NOT_KEYPAD_MODE(0x91) => "not in keypad mode",
        /// 0x92: "B800 speed in RPM not available (F-10 = 0)".
        RPM_NOT_AVAILABLE(0x92) => "speed in RPM not available (F-10 = 0)",
        /// 0x93: "B800 running – command cannot be carried out".
        RUNNING(0x93) => "drive running: command cannot be carried out",
        /// 0x94: "B800 stopped – command cannot be carried out".
        STOPPED(0x94) => "drive stopped: command cannot be carried out",
        /// 0x95: "Invalid data – incorrect checksum".
        BAD_CHECKSUM(0x95) => "invalid data: incorrect checksum",
        /// 0x97: "Invalid command – command not recognized".
        UNKNOWN_COMMAND(0x97) => "invalid command: command not recognized",
        /// 0x98: "B800 parameters locked – command cannot be carried out".
        PARAMETERS_LOCKED(0x98) => "parameters locked: command cannot be carried out",
        /// 0x99: "B800 hardware enable not present".
        NO_HARDWARE_ENABLE(0x99) => "hardware enable not present",
        /// 0x9A: "B800 tripped".
        TRIPPED(0x9A) => "tripped",
    }
}

impl fmt::Display for ErrorCode {
    /// `95 (invalid data: incorrect checksum)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:02X}", self.0)?;
        crate::error::write_meaning(f, self.meaning(), "not in the seed's list")
    }
}
