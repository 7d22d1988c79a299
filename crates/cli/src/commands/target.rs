//! What every command shares: the options that say where the drive is and how to speak to
//! it ([`Target`]), and the failures with their exit statuses.

use anyhow::Result;

/// Where the drive is and how to speak to it, as given before or after the command (see
/// `crate::options`, which declares them for each command).
#[derive(Debug, Clone, Default)]
pub struct Target {
    /// Serial device (/dev/ttyUSB0, a pty) or tcp://HOST:PORT of a serial device server
    /// (`sniff` takes two: one per direction of a 4-wire line).
    pub port: Vec<String>,
    /// The drive family (generic, toshiba, danfoss, b800, auto for scan); for `simulate`, a
    /// drive on the virtual bus as KIND@ADDR[:PROTOCOL]; for `events` and `trend` a drive's name.
    pub drive: Vec<String>,
    /// The drive's address (`monitor` takes several: --address 1 --address 2).
    pub address: Vec<u8>,
    /// The protocol: for `decode` the wire format; for a drive, where its family speaks several.
    pub protocol: Option<String>,
    /// Baud rate (default: the family's; 0 for `auto`: the family's, or for `sniff` found from
    /// the traffic).
    pub baud: Option<u32>,
    /// Character format such as 8E1 (default or `auto`: the family's; for `sniff`, found from
    /// the traffic).
    pub serial: Option<String>,
    /// Response timeout in milliseconds (default: the protocol's).
    pub timeout: Option<u64>,
    /// Retries after a timeout or a damaged reply.
    pub retries: u8,
    /// Silence kept before each request, in milliseconds (default: the protocol's).
    pub gap: Option<f64>,
    /// RS-485 direction control on a serial port: off, auto, kernel, rts.
    pub rs485: String,
    /// Modbus RTU: discard a reply with a silence over t1.5 between two of its bytes.
    pub strict_t15: bool,
    /// Discard the local echo of our own requests.
    pub echo: bool,
    /// Modbus TCP: the most requests in flight on the connection (1..16; default 1).
    pub max_in_flight: Option<usize>,
    /// Output JSON.
    pub json: bool,
}

/// `--baud`: a number, or `auto` (kept as 0 and read back by [`Target::baud`] as none given).
/// A `--baud` value: a rate, or `auto` (0).
pub(crate) fn parse_baud(s: &str) -> Result<u32, String> {
    if s.eq_ignore_ascii_case("auto") {
        return Ok(0);
    }
    match s.parse::<u32>() {
        Ok(b) if b > 0 => Ok(b),
        _ => Err(format!("{s:?} is not a baud rate: give a number such as 9600, or auto")),
    }
}

impl Target {
    /// The one `--port` given, if any (only `sniff` takes two).
    pub fn one_port(&self) -> Result<Option<String>> {
        match self.port.as_slice() {
            [] => Ok(None),
            [one] => Ok(Some(one.clone())),
            _ => Err(fail(EXIT_USAGE, "give one --port: only sniff listens on two (one per direction)")),
        }
    }

    /// `--baud`, unless absent or `auto`.
    pub fn baud(&self) -> Option<u32> {
        self.baud.filter(|&b| b != 0)
    }

    /// `--serial`, unless absent or `auto`.
    pub fn serial(&self) -> Option<&String> {
        self.serial.as_ref().filter(|s| !s.eq_ignore_ascii_case("auto"))
    }
}

/// Exit status: the drive answered no.
pub const EXIT_REFUSED: u8 = 1;
/// Exit status: no answer, or the link failed.
pub const EXIT_LINK: u8 = 2;
/// Exit status: bad usage or a value out of range.
pub const EXIT_USAGE: u8 = 3;

/// A failure with its exit status.
#[derive(Debug)]
pub struct Failure {
    /// The exit status.
    pub code: u8,
    /// One line for stderr.
    pub message: String,
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Failure {}

pub(crate) fn fail(code: u8, message: impl Into<String>) -> anyhow::Error {
    anyhow::Error::new(Failure { code, message: message.into() })
}

/// A bad-usage failure (exit 3).
pub fn usage(message: impl Into<String>) -> anyhow::Error {
    fail(EXIT_USAGE, message)
}

/// A link failure (exit 2).
pub fn link_failure(message: impl Into<String>) -> anyhow::Error {
    fail(EXIT_LINK, message)
}
