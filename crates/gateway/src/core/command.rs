//! What a front end asks of a drive ([`Command`]) and the core's typed outcome when it was not
//! done ([`CommandError`]); each front end says the outcome in its own words. Carried out by
//! [`Gateway::command`](super::Gateway::command) (execute.rs).

use drivebus_drive::profile::{CodeSpace, DriveError};
use drivebus_link::drive::Error as LinkError;
use drivebus_link::owner::BusError;
use serde::Serialize;

/// Most characters of a message (an error, an audit result) that may quote a user's value.
pub const MAX_MESSAGE_CHARS: usize = 512;

/// The largest speed, Hz, a command may ask for; beyond it the command is refused before any
/// drive's profile sees it (no drive runs at 100 kHz; `1e308` is not worth 309 digits).
pub const MAX_SPEED_HZ: f64 = 100_000.0;

/// A command to a drive.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// Start.
    Run,
    /// Ramp to a stop.
    Stop,
    /// Reverse the direction.
    Reverse,
    /// Run at the jog speed.
    Jog,
    /// Reset a fault.
    Reset,
    /// Set the speed setpoint, Hz.
    Speed(f64),
    /// Write a parameter by the manual's name, value in its unit.
    SetParam {
        /// The manual's name (`P0.02`, `0010`, `4-14`, `F-12`).
        name: String,
        /// The value in its unit (`"50"`, `"50 Hz"`, a choice's number).
        value: String,
        /// Write to EEPROM where the protocol lets the master choose (RAM otherwise).
        eeprom: bool,
    },
    /// Write a parameter's raw value (as the drive holds it; a register client's write).
    SetParamRaw {
        /// The manual's name.
        name: String,
        /// The raw value.
        raw: i64,
        /// The value in its unit, for the audit trail.
        shown: String,
        /// Write to EEPROM where the protocol lets the master choose (RAM otherwise).
        eeprom: bool,
    },
}

impl Command {
    /// The command as written in the audit trail (`run`, `speed 40 Hz`, `param 4-14 = 50`).
    pub fn action(&self) -> String {
        match self {
            Command::Run => "run".into(),
            Command::Stop => "stop".into(),
            Command::Reverse => "reverse".into(),
            Command::Jog => "jog".into(),
            Command::Reset => "reset".into(),
            Command::Speed(hz) => format!("speed {} Hz", crate::text::number(*hz)),
            Command::SetParam { name, value: shown, eeprom }
            | Command::SetParamRaw { name, shown, eeprom, .. } => {
                let (name, shown) = (crate::text::shown(name), crate::text::shown(shown));
                format!("param {name} = {shown}{}", if *eeprom { " (eeprom)" } else { "" })
            }
        }
    }

    /// Parses a command name as used in URLs and topics (`run`, `stop`, `reverse`, `jog`, `reset`).
    pub fn from_name(name: &str) -> Option<Command> {
        Some(match name {
            "run" => Command::Run,
            "stop" => Command::Stop,
            "reverse" => Command::Reverse,
            "jog" => Command::Jog,
            "reset" => Command::Reset,
            _ => return None,
        })
    }
}

/// What happened to a command or parameter read that was not done: the core's typed outcome.
/// Each front end says it in its own words (HTTP status in `http::error`, Modbus exception in
/// `modbus_tcp`, OPC UA status in `opcua::manager`, the MQTT result's `kind`).
#[derive(Debug)]
pub enum CommandError {
    /// No drive has that id.
    UnknownDrive(String),
    /// No bus has that name.
    UnknownBus(String),
    /// The drive is locked against writes.
    Locked(String),
    /// The request was not valid (bad value, unknown parameter) and nothing was sent.
    Invalid(String),
    /// The drive answered no.
    Refused {
        /// The drive's code.
        code: u32,
        /// Which of the manual's lists the code belongs to.
        space: CodeSpace,
        /// The manual's meaning.
        meaning: String,
    },
    /// The operation does not exist for this drive.
    Unsupported(String),
    /// The drive did not answer, or its replies were damaged, or it is offline.
    NoAnswer(String),
    /// The bus's port is gone.
    LinkDown(String),
    /// The reply made no sense.
    Protocol(String),
    /// Too many parameter reads wait on the drive's bus (or from this client); nothing was
    /// sent: try again shortly.
    Busy(String),
    /// The command's audit record could not be committed (the store failed: disk full, read
    /// only): the command was not sent.
    NotRecorded(String),
    /// The drive's bus listens as a standby (another gateway masters the line): nothing was
    /// sent.
    Standby(String),
}

impl std::fmt::Display for CommandError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CommandError::UnknownDrive(id) => {
                // A name is short; a client that sends a page of text gets its start back.
                let (shown, more) = crate::text::cut(id, 64);
                write!(f, "no drive {shown:?}{more}")
            }
            CommandError::UnknownBus(name) => {
                let (shown, more) = crate::text::cut(name, 64);
                write!(f, "no bus {shown:?}{more}")
            }
            CommandError::Locked(id) => {
                write!(f, "drive {id:?} is locked against writes: unlock it in the configuration")
            }
            CommandError::Invalid(s) | CommandError::Unsupported(s) | CommandError::Protocol(s) => {
                f.write_str(s)
            }
            CommandError::Refused { code, meaning, .. } => {
                write!(f, "the drive refused: code {code:#04X}, {meaning}")
            }
            CommandError::NoAnswer(s)
            | CommandError::LinkDown(s)
            | CommandError::Busy(s)
            | CommandError::Standby(s) => f.write_str(s),
            CommandError::NotRecorded(e) => write!(
                f,
                "the command was not sent: its audit record cannot be stored ({e}); free the store's disk or fix its permissions"
            ),
        }
    }
}

impl std::error::Error for CommandError {}

impl CommandError {
    /// A short kind for JSON errors and the audit trail.
    pub fn kind(&self) -> &'static str {
        match self {
            CommandError::UnknownDrive(_) => "unknown_drive",
            CommandError::UnknownBus(_) => "unknown_bus",
            CommandError::Locked(_) => "locked",
            CommandError::Invalid(_) => "invalid",
            CommandError::Refused { .. } => "refused",
            CommandError::Unsupported(_) => "unsupported",
            CommandError::NoAnswer(_) => "no_answer",
            CommandError::LinkDown(_) => "link_down",
            CommandError::Protocol(_) => "protocol",
            CommandError::Busy(_) => "busy",
            CommandError::NotRecorded(_) => "not_recorded",
            CommandError::Standby(_) => "standby",
        }
    }
}

impl From<LinkError> for CommandError {
    fn from(e: LinkError) -> Self {
        match e {
            LinkError::Drive(DriveError::Refused { code, space, meaning }) => {
                CommandError::Refused { code, space, meaning }
            }
            LinkError::Drive(DriveError::OutOfRange(s)) => CommandError::Invalid(s),
            LinkError::Drive(DriveError::Unsupported(s)) => CommandError::Unsupported(s),
            LinkError::Drive(DriveError::Protocol(s)) => CommandError::Protocol(s),
            LinkError::Bus(BusError::Link(s)) => CommandError::LinkDown(s),
            LinkError::Bus(BusError::Closed) => CommandError::LinkDown("the bus has stopped".into()),
            LinkError::Bus(e @ BusError::Busy(_)) => CommandError::Busy(e.to_string()),
            LinkError::Bus(e @ BusError::Standby(_)) => CommandError::Standby(e.to_string()),
            LinkError::Bus(e) => CommandError::NoAnswer(e.to_string()),
        }
    }
}

/// A parameter's value as read from a drive.
#[derive(Clone, Debug, Serialize)]
pub struct ParamReading {
    /// The manual's name.
    pub name: String,
    /// The manual's title.
    pub title: String,
    /// Raw value on the wire.
    pub raw: i64,
    /// The value in its unit.
    pub value: f64,
    /// The unit.
    pub unit: String,
    /// The value as the keypad would show it (`50.00 Hz`, a choice's text).
    pub text: String,
}
