//! What a bus is, below the engine, the owner and the fair queues that all use it: its
//! configuration ([`BusConfig`], [`FairConfig`]), why a transaction failed ([`BusError`]), its
//! counts ([`BusStats`]), each drive's health ([`Health`]) and a job's [`Priority`].

use std::fmt;
use std::time::Duration;

use drivebus_proto::line::CharFormat;
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::Instant;

/// How a bus is run.
#[derive(Clone, Debug)]
pub struct BusConfig {
    /// The protocol on the bus.
    pub protocol: WireProtocol,
    /// Baud rate (for character times and gaps).
    pub baud: u32,
    /// Character format.
    pub format: CharFormat,
    /// Response timeout; `None`: the protocol's default.
    pub response_timeout: Option<Duration>,
    /// Retries after a timeout or a damaged reply.
    pub retries: u8,
    /// Discard the local echo that 2-wire adapters hear of their own transmission.
    pub echo: bool,
    /// Failed transactions in a row after which a drive is offline.
    pub offline_after: u32,
    /// Longest wait between probes of an offline drive.
    pub max_backoff: Duration,
    /// The silence kept before each request; `None`: the protocol's (Modbus RTU t3.5, FC 2
    /// characters, ...). `Some(ZERO)` for links with no line behind them (a pty to a
    /// simulator, a TCP server that frames by itself).
    pub gap: Option<Duration>,
    /// RS-485 direction control on a serial port (off by default: USB-RS485 adapters switch
    /// by themselves).
    pub rs485: crate::port::Rs485,
    /// Modbus RTU: discard a reply with a silence over t1.5 between two of its bytes, as the
    /// Modbus serial-line specification says. Off by default: USB adapters and device servers
    /// deliver bytes in bursts with gaps of their own (an FTDI chip's latency timer is 16 ms),
    /// and would lose good replies. For on-board UARTs where a frame's bytes come as sent.
    pub strict_t15: bool,
    /// The family of the drives on the bus, where its manual adds to the protocol's timing:
    /// a generic bus in Modbus RTU keeps at least 10 ms of silence before each request (seed
    /// 004), not only t3.5. `None`: the protocol's timing alone. `gap` overrides both.
    pub family: Option<drivebus_drive::Family>,
    /// How on-demand reads share the bus with polling.
    pub on_demand: FairConfig,
    /// With another gateway on the same line: listen first and master the bus only when the
    /// line falls silent (see `crate::role`). `None`: the only master, sending at once.
    pub role: Option<crate::role::RoleConfig>,
    /// Modbus TCP: the bus's Modbus RTU frames go in MBAP to a Modbus TCP server
    /// (`protocol = "modbus-tcp"`, [`crate::mbap`]); no silence is kept between requests and
    /// the response timeout is 1 s unless given.
    pub modbus_tcp: bool,
    /// Modbus TCP: the most requests in flight on the connection (`max_in_flight`, default 1).
    /// Above 1 the bus is run by the pipelined owner ([`crate::Bus::spawn_pipelined`]): answers
    /// matched by transaction id, one request per drive at a time.
    pub max_in_flight: usize,
}

/// The most requests a Modbus TCP bus may have in flight ([`BusConfig::max_in_flight`]: 1..16,
/// the gateway's `max_in_flight` and the commands' `--max-in-flight`).
pub const MAX_IN_FLIGHT: usize = 16;

/// Why requests in flight together are refused on any bus but a Modbus TCP one.
pub const IN_FLIGHT_NEEDS_MODBUS_TCP: &str = "only a modbus-tcp bus can have requests in flight together";

impl BusConfig {
    /// The protocol's name as users give it: `modbus-tcp` for Modbus over MBAP, else the wire
    /// protocol's.
    pub fn protocol_name(&self) -> &'static str {
        if self.modbus_tcp {
            crate::mbap::MODBUS_TCP
        } else {
            self.protocol.name()
        }
    }

    /// A configuration with the protocol's defaults: 2 retries, no echo, offline after 3
    /// failures, probes at most every 30 s.
    pub fn new(protocol: WireProtocol, baud: u32, format: CharFormat) -> Self {
        BusConfig {
            protocol,
            baud,
            format,
            response_timeout: None,
            retries: 2,
            echo: false,
            offline_after: 3,
            max_backoff: Duration::from_secs(30),
            gap: None,
            rs485: crate::port::Rs485::Off,
            strict_t15: false,
            family: None,
            on_demand: FairConfig::default(),
            role: None,
            modbus_tcp: false,
            max_in_flight: 1,
        }
    }
}

/// Why a transaction failed. The drive's own refusal is not here: it is a valid reply.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BusError {
    /// No (whole) reply within the response timeout, after every retry.
    Timeout {
        /// The link.
        link: String,
        /// The drive's address.
        address: u8,
        /// Attempts made.
        attempts: u8,
    },
    /// Replies came back damaged every time (bad checksum, cut short).
    Corrupt {
        /// The link.
        link: String,
        /// The last error.
        error: String,
    },
    /// The drive is offline and its next probe is not due yet.
    Offline {
        /// The drive's address.
        address: u8,
    },
    /// The link failed (port gone, connection refused).
    Link(String),
    /// The request itself is not a valid frame of the bus's protocol (a caller bug).
    BadRequest(String),
    /// The bus owner has stopped.
    Closed,
    /// Too many on-demand reads wait on the bus (or from this client); nothing was sent.
    Busy(String),
    /// The bus listens as a standby (another gateway masters the line): nothing was sent.
    Standby(String),
    /// The bus listens as a standby and has never heard the set-up value a poll reads (the
    /// master does not read it): answered at once, nothing was sent.
    Unheard(String),
}

impl fmt::Display for BusError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BusError::Timeout { link, address, attempts } => write!(
                f,
                "no answer from drive {address} on {link} after {attempts} attempt{}: check the address, baud rate, serial format and wiring",
                if *attempts == 1 { "" } else { "s" }
            ),
            BusError::Corrupt { link, error } => {
                write!(f, "damaged replies on {link} ({error}): check termination, grounding and the serial format")
            }
            BusError::Offline { address } => write!(f, "drive {address} is offline; it is probed again after its backoff"),
            BusError::Link(e) => f.write_str(e),
            BusError::BadRequest(e) => write!(f, "cannot send that request: {e}"),
            BusError::Closed => f.write_str("the bus has stopped"),
            BusError::Busy(e) => write!(f, "the bus is busy: {e}"),
            BusError::Standby(link) => write!(
                f,
                "{link} is listening as a standby: another gateway masters the line, send it there"
            ),
            BusError::Unheard(link) => write!(
                f,
                "{link} is listening as a standby and never heard this set-up value: the master \
                 does not read it (a drivebus master reads it every 30 s)"
            ),
        }
    }
}

impl std::error::Error for BusError {}

/// Whether a job may wait behind others.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Priority {
    /// A user's command: goes ahead of polling.
    Command,
    /// A request passed through from a Modbus bridge: after commands, ahead of polling.
    Bridge,
    /// A read a client asked for now (a parameter): shares the bus with polling, client by
    /// client (the `fair` module).
    OnDemand,
    /// Cyclic polling.
    Poll,
    /// A probe of an address that may hold no drive (a bus scan): sent only when nothing else
    /// waits, with one attempt, and the address's link health left alone (an empty address is
    /// not an offline drive).
    Scan,
}

/// Counts of one bus.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BusStats {
    /// Requests put on the line (retries included).
    pub transactions: u64,
    /// Matching replies.
    pub replies: u64,
    /// Requests that got no reply in time.
    pub timeouts: u64,
    /// Damaged replies (bad checksum, cut short, malformed).
    pub checksum_errors: u64,
    /// Retries.
    pub retries: u64,
    /// Broadcasts sent.
    pub broadcasts: u64,
    /// Broadcasts heard on the line that this master did not send: another talker commands
    /// every drive (a drive acting as bus master, seed 004 9.2.2 (2), Toshiba f806 = 3/4).
    pub foreign_broadcasts: u64,
    /// Session time of the last of them, seconds.
    pub last_foreign_broadcast_s: Option<f64>,
    /// Time the line carried our requests and the replies, seconds.
    pub wire_seconds: f64,
    /// Bytes of our requests and their replies on the line (what `wire_seconds` reckons).
    pub wire_bytes: u64,
    /// Session time since the bus started, seconds.
    pub elapsed_seconds: f64,
    /// Modbus TCP answers to no request in flight (a stray or repeated transaction id, or an
    /// answer that came after its request timed out), dropped.
    pub stray_replies: u64,
}

impl BusStats {
    /// Time on the wire divided by elapsed time, 0..=1. Wire time is reckoned at the baud rate,
    /// so a link that carries bytes faster than that (a pty, a simulator without pacing) could
    /// reckon more than the time that passed: the figure stops at 1.
    pub fn utilization(&self) -> f64 {
        if self.elapsed_seconds > 0.0 {
            (self.wire_seconds / self.elapsed_seconds).min(1.0)
        } else {
            0.0
        }
    }
}

/// One drive's link health.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Health {
    /// True until `offline_after` failures in a row.
    pub online: bool,
    /// Session time of the last good reply, seconds.
    pub last_seen_s: Option<f64>,
    /// Failed transactions in a row.
    pub failures_in_row: u32,
    /// Transactions attempted.
    pub transactions: u64,
    /// Transactions that failed.
    pub errors: u64,
    pub(crate) backoff: Duration,
    pub(crate) next_probe: Option<Instant>,
}

/// How on-demand reads share a bus with polling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FairConfig {
    /// The part of the bus time on-demand reads get while polls wait, 0..=1 (0: only when no
    /// poll waits; 1: always ahead of polls, as commands).
    pub share: f64,
    /// The most on-demand reads waiting on the bus, all clients together.
    pub queue: usize,
    /// The most on-demand reads one client may have waiting.
    pub per_client: usize,
}

impl Default for FairConfig {
    /// Half the bus time, 32 reads waiting, 8 of them per client.
    fn default() -> Self {
        FairConfig { share: 0.5, queue: 32, per_client: 8 }
    }
}
