//! The unified drive API, sans-IO: one profile per family turns an operation (run, stop, set
//! speed, read status, read or write a parameter) into the requests its protocol needs, and the
//! replies into a result. The profile never touches a line: a bus owner (drivebus-link) sends
//! each request and hands back the reply, and tests do the same on a virtual line with
//! simulated time.
//!
//! ```text
//! let mut plan = profile.plan(&Operation::SetSpeed(40.0))?;   // checked against the limits
//! let mut reply = None;
//! loop {
//!     match plan.step(reply.as_deref())? {
//!         Step::Send(x) => reply = bus.transact(x)?,            // None when no reply is due
//!         Step::Done(outcome) => break outcome,
//!     }
//! }
//! ```
//!
//! That loop is [`run`] (for async callers) and [`run_blocking`]: give either the plan and a
//! closure that sends an exchange and returns its reply.

use std::fmt;

pub use drivebus_proto::protocol::WireProtocol;

use crate::{Family, ParamDef, Storage};

pub mod b800;
pub mod danfoss;
pub mod generic;
pub mod toshiba;
pub mod trips;

/// What to do to a drive.
#[derive(Clone, Debug, PartialEq)]
pub enum Operation {
    /// Read the drive's state.
    Status,
    /// Start (in the direction last commanded).
    Run,
    /// Ramp to a stop.
    Stop,
    /// Reverse the direction (a running drive ramps through zero).
    Reverse,
    /// Run at the jog speed.
    Jog,
    /// Reset a fault.
    Reset,
    /// Set the speed setpoint, Hz.
    SetSpeed(f64),
    /// Read a parameter by the manual's name (`P0.02`, `0010`, `4-14`, `F-12`).
    ReadParam(String),
    /// Write a parameter (raw integer as on the wire; see [`ParamDef::to_raw`]).
    WriteParam {
        /// The manual's name.
        name: String,
        /// The raw value.
        raw: i64,
        /// RAM (default) or EEPROM where the protocol lets the master choose.
        storage: Storage,
    },
}

/// A drive's state, as far as its protocol tells.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DriveStatus {
    /// The drive's number on the bus.
    pub address: u8,
    /// True while the output is on.
    pub running: bool,
    /// `"forward"` or `"reverse"`, where readable.
    pub direction: Option<String>,
    /// Output frequency, Hz.
    pub output_hz: Option<f64>,
    /// Setpoint, Hz, where readable.
    pub setpoint_hz: Option<f64>,
    /// Motor current, A, where readable.
    pub current_a: Option<f64>,
    /// The fault in force, if any.
    pub fault: Option<Fault>,
    /// Values beyond these, by name, where the drive kind gives them (a template's `[values]`:
    /// DC-bus voltage, power, temperature, ...); empty for the built-in families.
    pub values: Vec<NamedValue>,
}

/// A status value beyond the six every drive has: `dc_bus_v = 560 V`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct NamedValue {
    /// Its name (`dc_bus_v`).
    pub name: String,
    /// The value, in `unit`.
    pub value: f64,
    /// Its unit (`V`), or empty.
    pub unit: String,
}

/// `x` rounded to `places` decimals: a value at the resolution the drive reports it, without
/// the noise of scaling in binary floating point (14.25025 A from 0.01 % of 14.5 A is 14.25 A).
pub fn round_to(x: f64, places: i32) -> f64 {
    let f = 10f64.powi(places);
    (x * f).round() / f
}

/// A drive's fault: its code and the manual's text for it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Fault {
    /// The code as the drive reports it.
    pub code: u32,
    /// What it means.
    pub text: String,
}

/// The result of an operation.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    /// Done; nothing to report.
    Done,
    /// The drive's state.
    Status(DriveStatus),
    /// A parameter's raw value.
    Param(i64),
}

/// What a plan that sends requests of type `A` does next (the generic and Toshiba plans).
pub(crate) enum Next<A> {
    /// Send this request.
    Send(A),
    /// End with this outcome.
    Done(Outcome),
}

/// The step a plan takes after deciding `next`: the request `encode` frames (kept in `sent`
/// to read its reply), or the end. Once the plan has ended, done or failed, `finished` is set.
pub(crate) fn step_to<A: Copy>(
    next: Result<Next<A>, DriveError>,
    sent: &mut Option<A>,
    finished: &mut bool,
    encode: impl FnOnce(A) -> Result<Exchange, DriveError>,
) -> Result<Step, DriveError> {
    match next {
        Ok(Next::Send(ask)) => {
            let exchange = encode(ask)?;
            *sent = Some(ask);
            Ok(Step::Send(exchange))
        }
        Ok(Next::Done(outcome)) => {
            *finished = true;
            Ok(Step::Done(outcome))
        }
        Err(e) => {
            *finished = true;
            Err(e)
        }
    }
}

/// One request to put on the line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Exchange {
    /// The whole frame, checksum included.
    pub request: Vec<u8>,
    /// False for broadcasts: no reply comes, the bus waits the turnaround delay.
    pub expect_reply: bool,
}

/// What a plan wants next.
#[derive(Clone, Debug, PartialEq)]
pub enum Step {
    /// Send this and call [`Plan::step`] again with the reply (`None` if none was due).
    Send(Exchange),
    /// The operation is finished.
    Done(Outcome),
}

/// Which of the manual's lists a refusal's code belongs to: a front end passes a Modbus exception
/// through to Modbus clients and names the others.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CodeSpace {
    /// A Modbus exception code (01 illegal function, 02 illegal address, 03 illegal value, ...).
    ModbusException,
    /// A TOSHIBA Inverter Protocol error code (ASCII or binary mode).
    ToshibaError,
    /// A Danfoss FC fault code (the PWE of an AK = 7 reply).
    FcFault,
    /// A B800 error code (the `e` reply).
    B800Error,
    /// The drive's trip or alarm number (Toshiba FC90, Danfoss alarm log).
    Trip,
    /// A status word the refusal was read from (Danfoss FC profile).
    StatusWord,
}

impl CodeSpace {
    /// A short name for JSON and the audit trail.
    pub fn as_str(self) -> &'static str {
        match self {
            CodeSpace::ModbusException => "modbus_exception",
            CodeSpace::ToshibaError => "toshiba_error",
            CodeSpace::FcFault => "fc_fault",
            CodeSpace::B800Error => "b800_error",
            CodeSpace::Trip => "trip",
            CodeSpace::StatusWord => "status_word",
        }
    }
}

/// Why an operation failed, sorted by what the user can do about it.
#[derive(Clone, Debug, PartialEq)]
pub enum DriveError {
    /// The drive answered no: an exception or error code, with the manual's meaning.
    Refused {
        /// The code as the drive sent it.
        code: u32,
        /// Which of the manual's lists the code belongs to.
        space: CodeSpace,
        /// What it means, from the manual.
        meaning: String,
    },
    /// A value the drive cannot take (checked before anything is sent).
    OutOfRange(String),
    /// The operation or parameter does not exist for this family or protocol.
    Unsupported(String),
    /// The reply did not make sense (wrong shape, wrong register).
    Protocol(String),
}

impl fmt::Display for DriveError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DriveError::Refused { code, meaning, .. } => {
                write!(f, "the drive refused: code {code:#04X}, {meaning}")
            }
            DriveError::OutOfRange(s) | DriveError::Unsupported(s) | DriveError::Protocol(s) => {
                f.write_str(s)
            }
        }
    }
}

impl std::error::Error for DriveError {}

/// An operation in progress: a small state machine over request/reply exchanges.
pub trait Plan: Send {
    /// The next step, given the reply to the last [`Step::Send`] (`None` before the first
    /// exchange and after a broadcast).
    fn step(&mut self, reply: Option<&[u8]>) -> Result<Step, DriveError>;
}

/// Runs `plan` to its end: each exchange it asks for goes to `transact`, whose reply (`None`
/// when none was due) the plan gets back. The one loop that drives a plan: async callers await
/// it, the others use [`run_blocking`].
pub async fn run<E, F, Fut>(plan: &mut dyn Plan, mut transact: F) -> Result<Outcome, E>
where
    E: From<DriveError>,
    F: FnMut(Exchange) -> Fut,
    Fut: std::future::Future<Output = Result<Option<Vec<u8>>, E>>,
{
    let mut reply: Option<Vec<u8>> = None;
    loop {
        match plan.step(reply.as_deref())? {
            Step::Done(outcome) => return Ok(outcome),
            Step::Send(exchange) => reply = transact(exchange).await?,
        }
    }
}

/// [`run`] with a `transact` that returns its reply without waiting on a runtime (a blocking
/// bus, a virtual line stepped by hand).
pub fn run_blocking<E>(
    plan: &mut dyn Plan,
    mut transact: impl FnMut(Exchange) -> Result<Option<Vec<u8>>, E>,
) -> Result<Outcome, E>
where
    E: From<DriveError>,
{
    use std::future::Future;
    use std::task::{Context, Poll, Wake, Waker};
    /// Nothing waits, so nothing is woken.
    struct NoWake;
    impl Wake for NoWake {
        fn wake(self: std::sync::Arc<Self>) {}
    }
    let run = std::pin::pin!(run(plan, |x| std::future::ready(transact(x))));
    let waker = Waker::from(std::sync::Arc::new(NoWake));
    match run.poll(&mut Context::from_waker(&waker)) {
        Poll::Ready(result) => result,
        // Every future in it is ready at once: it never waits.
        Poll::Pending => Err(DriveError::Protocol("a blocking plan run had to wait".to_string()).into()),
    }
}

/// One drive family spoken in one protocol, for one drive address.
pub trait Profile: Send + Sync {
    /// The family.
    fn family(&self) -> Family;
    /// The protocol in use.
    fn protocol(&self) -> WireProtocol;
    /// The drive's number on the bus.
    fn address(&self) -> u8;
    /// The parameter named `name` in this family's catalog, with its unit and limits.
    fn param(&self, name: &str) -> Result<&ParamDef, DriveError>;
    /// Starts `op`, after checking its values (a speed against the drive's limits).
    fn plan(&self, op: &Operation) -> Result<Box<dyn Plan>, DriveError>;
    /// Makes the next status read again the drive's set-up values that the profile otherwise
    /// reads once and keeps to decode a status (Danfoss 3-00, 3-02, 3-03; Toshiba FE70, and
    /// f875–f879 in TIP binary mode): they may have been changed on the drive's panel, and a
    /// standby that started listening later learns them only from such a read. What is known
    /// is kept until the new values come. Profiles that keep no set-up value do nothing.
    fn refresh_setup(&self) {}
    /// A status that reads none of those set-up values, for a standby listening beside a master
    /// that never reads them: it decodes with what the profile knows of them, and a value that
    /// needs one it does not know comes out unknown (`None`), never guessed (Danfoss: output
    /// frequency, direction and setpoint; Toshiba: current). `None` for a profile that keeps no
    /// set-up value (its status is the same plan).
    fn plan_status_without_setup(&self) -> Option<Result<Box<dyn Plan>, DriveError>> {
        None
    }
}

/// The profile for drive `address` of `family` spoken in `protocol`.
pub fn for_drive(
    family: Family,
    protocol: WireProtocol,
    address: u8,
) -> Result<Box<dyn Profile>, DriveError> {
    family.check_protocol(protocol).map_err(DriveError::Unsupported)?;
    let wrong = || DriveError::Unsupported(format!("a {family} drive does not speak {protocol}"));
    Ok(match family {
        Family::Generic => {
            let p = generic::GenericProtocol::from_wire(protocol).ok_or_else(wrong)?;
            Box::new(generic::GenericProfile::new(address, p)?)
        }
        Family::Toshiba => Box::new(toshiba::ToshibaProfile::new(address, protocol)?),
        Family::Danfoss => Box::new(danfoss::DanfossProfile::new(address)?),
        Family::B800 => Box::new(b800::B800Profile::new(address)?),
        Family::Template(_) => {
            Box::new(crate::template::profile::TemplateProfile::new(family, protocol, address)?)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sends `n` exchanges, each carrying the length of the last reply, then is done.
    struct Counting {
        left: u8,
        replies: Vec<Option<Vec<u8>>>,
    }

    impl Plan for Counting {
        fn step(&mut self, reply: Option<&[u8]>) -> Result<Step, DriveError> {
            if self.left < 3 {
                self.replies.push(reply.map(<[u8]>::to_vec));
            }
            if self.left == 0 {
                return Ok(Step::Done(Outcome::Param(self.replies.len() as i64)));
            }
            self.left -= 1;
            Ok(Step::Send(Exchange { request: vec![self.left], expect_reply: self.left != 1 }))
        }
    }

    #[test]
    fn a_plan_runs_to_its_end_with_each_reply_handed_back() {
        let mut plan = Counting { left: 3, replies: Vec::new() };
        let mut sent = Vec::new();
        let outcome = run_blocking(&mut plan, |x| {
            sent.push(x.request[0]);
            Ok::<_, DriveError>(x.expect_reply.then(|| vec![x.request[0]; 2]))
        });
        assert_eq!(outcome, Ok(Outcome::Param(3)));
        assert_eq!(sent, [2, 1, 0]);
        assert_eq!(plan.replies, [Some(vec![2, 2]), None, Some(vec![0, 0])]);
        // The transaction's error ends the run with it.
        let mut plan = Counting { left: 3, replies: Vec::new() };
        let e = run_blocking(&mut plan, |_| Err(DriveError::Protocol("no answer".into())));
        assert_eq!(e, Err(DriveError::Protocol("no answer".into())));
    }
}
