//! B800 series on its hex-ASCII protocol (`b800`): [`B800Profile`].
//!
//! Manual: `seeds/000_04b515f0e0c1734e.txt`, with protocols.md section 4 and its "B800"
//! project decisions. The protocol has ten commands and nothing else: `R` run, `S` stop,
//! `A` current, `Z` speed in Hz, `M` speed in rpm, `T` status, `V` version, `P` set speed,
//! `I` / `L` speed up / down. A drive answers with the lower-case letter, or `e` and an error
//! code from the seed's list, which the profile returns as `Refused` with the seed's meaning.
//!
//! | operation | telegrams | notes |
//! |---|---|---|
//! | Status | `T`, then `Z` and `A` while running | stopped, tripped or without hardware enable the output is off: 0 Hz, 0 A |
//! | Run | `T`, then `R` unless already running | with F-12 = 2, `R` to a running drive reverses it: the profile never sends it to one |
//! | Stop | `S` | `e 02` "drive in standby" is success |
//! | Reverse | `T`, then `R` to a running drive | reverses only with F-12 = 2; keypad mode (`e 93`) is `Refused`, a stopped drive `Unsupported` |
//! | Jog | none | `Unsupported`: the protocol has no jog |
//! | Reset | `T`, then `S` if tripped | see below |
//! | SetSpeed | `P`, 60 x Hz | keypad mode only: `e 91` otherwise |
//! | ReadParam, WriteParam | none | `Unsupported`: the protocol has no parameter access |
//!
//! **Reset.** The seed has no reset command. The project's simulator clears a trip on `S`
//! (a decision of the simulated drive, documented there: "a tripped drive must be recoverable
//! from the host"), so Reset reads the status and sends `S` to a tripped drive only; `e 9A`
//! means the trip's cause persists. A real B800 may need its keypad or terminals to reset.
//!
//! **Limits.** The protocol cannot read F-01 Maximum frequency or F-02 Minimum frequency, so
//! SetSpeed is checked against the catalog defaults (0.0..50.0 Hz) unless the profile is told
//! the drive's settings with [`B800Profile::with_frequency_limits`]. The drive itself holds a
//! `P` outside its limits at the nearer one.
//!
//! **Status.** `T` gives the state and, while tripped, the trip code in its high byte (the
//! codes are project decisions, [`trip_text`]); the setpoint is the one this profile set last
//! (the protocol cannot read it back), the direction is not readable.
//!
//! **Global.** Address 0 is the global address `G`: every drive acts, none answers. Run (`G R`),
//! Stop (`G S`), SetSpeed (`G P`) and Reverse (`G R`: the seed's "reverse direction of all
//! drives (F-12 = 2)", the same frame as "start all drives") are sent without a status read;
//! the rest is `Unsupported`.

use std::sync::{Arc, Mutex};

use drivebus_proto::b800::{
    Address, Destination, DriveState, ErrorCode, MasterCommand, Reply, Request, SlaveReply, Speed, MAX_FRAME,
};

use super::{
    CodeSpace, DriveError, DriveStatus, Exchange, Fault, Operation, Outcome, Plan, Profile, Step,
    WireProtocol,
};
use crate::{Catalog, Family, ParamDef};

/// The protocol the B800 speaks.
pub const PROTOCOL: WireProtocol = WireProtocol::B800;

/// The text of a B800 trip code, as the `t` reply's high byte carries it. The seed lists no
/// trip codes: these are the project's simulator's (01 over-current .. 06 external).
pub fn trip_text(code: u8) -> Option<&'static str> {
    Some(match code {
        0x01 => "over-current",
        0x02 => "over-voltage",
        0x03 => "under-voltage",
        0x04 => "over-temperature",
        0x05 => "communication loss",
        0x06 => "external trip",
        _ => return None,
    })
}

/// The refusal for an `e` reply.
fn refused(code: ErrorCode) -> DriveError {
    DriveError::Refused {
        code: u32::from(code.0),
        space: CodeSpace::B800Error,
        meaning: code.meaning().unwrap_or("not in the seed's error list").to_string(),
    }
}

/// A B800 series drive on its hex-ASCII protocol, for one address (or `G`, every drive).
///
/// ```
/// use drivebus_drive::profile::b800::B800Profile;
/// use drivebus_drive::profile::{Operation, Profile, Step};
///
/// let b800 = B800Profile::new(5)?;
/// let mut plan = b800.plan(&Operation::SetSpeed(40.0))?;
/// let Step::Send(x) = plan.step(None)? else { panic!("a set speed sends P") };
/// // seed 000: drive 5 (DA 85), P (50), 40.0 Hz x 60 = 0960, CS 5E, all as hex ASCII.
/// assert_eq!(x.request, b"\x7E855009605E\x7F");
/// # Ok::<(), drivebus_drive::profile::DriveError>(())
/// ```
#[derive(Debug)]
pub struct B800Profile {
    address: u8,
    destination: Destination,
    catalog: Arc<Catalog>,
    /// F-02 and F-01 as the profile assumes them, Hz.
    min_hz: f64,
    max_hz: f64,
    /// The setpoint this profile set last, Hz.
    setpoint: Arc<Mutex<Option<f64>>>,
}

impl B800Profile {
    /// Drive `address` (1–63; the master sends it + 128), or 0 for the global address `G`.
    pub fn new(address: u8) -> Result<Self, DriveError> {
        let destination = if address == 0 {
            Destination::Global
        } else {
            Destination::Drive(Address::new(address).ok_or_else(|| {
                DriveError::OutOfRange(format!(
                    "a B800 drive address is 1 to 63 (0 for the global address G), not {address}"
                ))
            })?)
        };
        let catalog = Catalog::load(Family::B800)
            .map_err(|e| DriveError::Unsupported(format!("the B800 catalog does not load: {e}")))?;
        let default_hz = |name: &str| catalog.get(name).map(|d| d.from_raw(d.default));
        let max_hz = default_hz("F-01").unwrap_or(50.0);
        let min_hz = default_hz("F-02").unwrap_or(0.0);
        Ok(B800Profile {
            address,
            destination,
            catalog,
            min_hz,
            max_hz,
            setpoint: Arc::new(Mutex::new(None)),
        })
    }

    /// The same profile checking SetSpeed against the drive's F-02 Minimum frequency and F-01
    /// Maximum frequency (Hz), which the protocol cannot read; each must lie in its catalog
    /// range, and `min_hz` not above `max_hz`.
    pub fn with_frequency_limits(mut self, min_hz: f64, max_hz: f64) -> Result<Self, DriveError> {
        for (name, hz) in [("F-02", min_hz), ("F-01", max_hz)] {
            let def = self.param(name)?;
            def.to_raw(hz).map_err(|e| DriveError::OutOfRange(e.to_string()))?;
        }
        if min_hz > max_hz {
            return Err(DriveError::OutOfRange(format!(
                "F-02 Minimum frequency {min_hz} Hz is above F-01 Maximum frequency {max_hz} Hz"
            )));
        }
        self.min_hz = min_hz;
        self.max_hz = max_hz;
        Ok(self)
    }

    /// The SetSpeed limits the profile checks, Hz: (F-02, F-01).
    pub fn frequency_limits(&self) -> (f64, f64) {
        (self.min_hz, self.max_hz)
    }

    fn global(&self) -> bool {
        self.destination == Destination::Global
    }

    fn check_speed(&self, hz: f64) -> Result<Speed, DriveError> {
        if !hz.is_finite() {
            return Err(DriveError::OutOfRange(format!("{hz} is not a speed")));
        }
        if hz < 0.0 {
            return Err(DriveError::OutOfRange(format!(
                "{hz} Hz is below 0 Hz: the B800 protocol has no signed speed"
            )));
        }
        if hz + 1e-9 < self.min_hz {
            return Err(DriveError::OutOfRange(format!(
                "{hz} Hz is below the minimum frequency F-02 = {:.1} Hz",
                self.min_hz
            )));
        }
        if hz > self.max_hz + 1e-9 {
            return Err(DriveError::OutOfRange(format!(
                "{hz} Hz is above the maximum frequency F-01 = {:.1} Hz",
                self.max_hz
            )));
        }
        Speed::from_hz(hz).map_err(|e| DriveError::OutOfRange(e.to_string()))
    }

    fn plan_for(&self, op: &Operation) -> Result<B800Plan, DriveError> {
        let mut plan = B800Plan {
            destination: self.destination,
            address: self.address,
            setpoint: Arc::clone(&self.setpoint),
            goal: Goal::Done,
            queue: Vec::new(),
            sent: None,
            status: None,
            output_hz: None,
            current_a: None,
        };
        let global = self.global();
        let needs_reply = |what: &str| {
            DriveError::Unsupported(format!(
                "{what} needs the drive's reply, and no drive answers the global address G"
            ))
        };
        match op {
            Operation::Status => {
                if global {
                    return Err(needs_reply("a status"));
                }
                plan.goal = Goal::Status;
                plan.push(MasterCommand::Status, Purpose::Status);
            }
            Operation::Run => {
                if global {
                    plan.push(MasterCommand::Run, Purpose::Command);
                } else {
                    plan.push(MasterCommand::Status, Purpose::BeforeRun);
                }
            }
            Operation::Stop => plan.push(MasterCommand::Stop, Purpose::Stop),
            Operation::Reverse => {
                if global {
                    plan.push(MasterCommand::Run, Purpose::Command);
                } else {
                    plan.push(MasterCommand::Status, Purpose::BeforeReverse);
                }
            }
            Operation::Jog => {
                return Err(DriveError::Unsupported(
                    "the B800 protocol has no jog command (its commands are R S A Z M T V P I L)".to_string(),
                ))
            }
            Operation::Reset => {
                if global {
                    return Err(needs_reply(
                        "a reset sends S to tripped drives only, which needs each drive's status, and so",
                    ));
                }
                plan.push(MasterCommand::Status, Purpose::BeforeReset);
            }
            Operation::SetSpeed(hz) => {
                let speed = self.check_speed(*hz)?;
                plan.push(MasterCommand::SetSpeed(speed), Purpose::SetSpeed(*hz));
            }
            Operation::ReadParam(name) | Operation::WriteParam { name, .. } => {
                let def = self.param(name)?;
                return Err(DriveError::Unsupported(format!(
                    "the B800 protocol has no parameter access (its commands are R S A Z M T V P I L): \
                     set {} {} on the drive's keypad",
                    def.name, def.title
                )));
            }
        }
        Ok(plan)
    }
}

impl Profile for B800Profile {
    fn family(&self) -> Family {
        Family::B800
    }

    fn protocol(&self) -> WireProtocol {
        PROTOCOL
    }

    /// The drive's number, 0 for the global address `G`.
    fn address(&self) -> u8 {
        self.address
    }

    fn param(&self, name: &str) -> Result<&ParamDef, DriveError> {
        self.catalog.get(name).ok_or_else(|| {
            DriveError::Unsupported(format!("the B800 catalog has no parameter {:?}", name.trim()))
        })
    }

    fn plan(&self, op: &Operation) -> Result<Box<dyn Plan>, DriveError> {
        Ok(Box::new(self.plan_for(op)?))
    }
}

/// What the plan ends with.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Goal {
    Done,
    Status,
}

/// Why a command is sent, which says what its reply means.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Purpose {
    /// `T` for a status.
    Status,
    /// `Z` / `A` for a status.
    Measure,
    /// `T` before `R`: a running drive gets no `R`.
    BeforeRun,
    /// `T` before `R`: only a running drive is reversed.
    BeforeReverse,
    /// `T` before `S`: only a tripped drive is reset.
    BeforeReset,
    /// `R` for a run (or a global command): the letter is enough.
    Command,
    /// `R` to a running drive, to reverse it.
    Reverse,
    /// `S` for a stop: `e 02` (standby) is success.
    Stop,
    /// `S` to a tripped drive, to reset it.
    Reset,
    /// `P` with this speed in Hz.
    SetSpeed(f64),
}

/// True in the states whose output is off: standby, tripped, hardware enable missing.
fn output_off(state: DriveState) -> bool {
    matches!(state, DriveState::Standby | DriveState::Tripped | DriveState::HardwareEnableMissing)
}

/// A B800 plan: the commands to send, in order, and what their replies taught.
struct B800Plan {
    destination: Destination,
    address: u8,
    setpoint: Arc<Mutex<Option<f64>>>,
    goal: Goal,
    /// The commands still to send, in order.
    queue: Vec<(MasterCommand, Purpose)>,
    sent: Option<(MasterCommand, Purpose)>,
    status: Option<drivebus_proto::b800::DriveStatus>,
    output_hz: Option<f64>,
    current_a: Option<f64>,
}

impl B800Plan {
    fn push(&mut self, cmd: MasterCommand, purpose: Purpose) {
        self.queue.push((cmd, purpose));
    }

    fn setpoint(&self) -> std::sync::MutexGuard<'_, Option<f64>> {
        self.setpoint.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Takes in the reply to `cmd`.
    fn take_reply(&mut self, cmd: MasterCommand, purpose: Purpose, bytes: &[u8]) -> Result<(), DriveError> {
        let reply = Reply::parse(bytes)
            .map_err(|e| DriveError::Protocol(format!("the reply is not a B800 frame: {e}")))?;
        if reply.da.get() != self.address {
            return Err(DriveError::Protocol(format!(
                "the reply comes from drive {}, the request went to drive {}",
                reply.da, self.address
            )));
        }
        let letter = reply.reply.letter();
        if let SlaveReply::Error { code, .. } = reply.reply {
            return self.error(purpose, code);
        }
        if letter != cmd.reply_letter() {
            return Err(DriveError::Protocol(format!(
                "{} ({}) was answered with '{}' ({})",
                cmd.letter() as char,
                cmd.name(),
                letter as char,
                reply.reply.name()
            )));
        }
        match (purpose, reply.reply) {
            (
                Purpose::Status | Purpose::BeforeRun | Purpose::BeforeReverse | Purpose::BeforeReset,
                SlaveReply::Status(s),
            ) => {
                self.status = Some(s);
                self.after_status(purpose, s.state())?;
            }
            (Purpose::Measure, SlaveReply::SpeedHz(speed)) => self.output_hz = Some(speed.hz()),
            (Purpose::Measure, SlaveReply::MotorCurrent(current)) => self.current_a = Some(current.amps()),
            (Purpose::SetSpeed(hz), _) => *self.setpoint() = Some(hz),
            _ => {}
        }
        Ok(())
    }

    /// What a `t` reply decides.
    fn after_status(&mut self, purpose: Purpose, state: DriveState) -> Result<(), DriveError> {
        let running = state == DriveState::Running;
        match purpose {
            // Standby, tripped or without hardware enable the output is off: T is enough.
            Purpose::Status if !output_off(state) => {
                self.push(MasterCommand::SpeedHz, Purpose::Measure);
                self.push(MasterCommand::MotorCurrent, Purpose::Measure);
            }
            // Already running: nothing to do (an R would reverse it with F-12 = 2).
            Purpose::BeforeRun if running => {}
            Purpose::BeforeRun => self.push(MasterCommand::Run, Purpose::Command),
            Purpose::BeforeReverse if running => self.push(MasterCommand::Run, Purpose::Reverse),
            Purpose::BeforeReverse => {
                return Err(DriveError::Unsupported(format!(
                    "the B800 protocol reverses only a running drive (R to a running drive with F-12 = 2), \
                     and this one is not running ({}): it has no direction command",
                    state.meaning().unwrap_or("unknown state")
                )))
            }
            Purpose::BeforeReset if state == DriveState::Tripped => {
                self.push(MasterCommand::Stop, Purpose::Reset)
            }
            _ => {}
        }
        Ok(())
    }

    /// An `e` reply to a command sent for `purpose`.
    fn error(&mut self, purpose: Purpose, code: ErrorCode) -> Result<(), DriveError> {
        match (purpose, code) {
            // seed 000: 02 "Drive in Standby (status information)": nothing to stop.
            (Purpose::Stop, ErrorCode::STANDBY) => Ok(()),
            // The drive said no: a refusal (exit 1 on the command line), with what to change.
            (Purpose::Reverse, ErrorCode::RUNNING) => Err(DriveError::Refused {
                code: u32::from(code.0),
                space: CodeSpace::B800Error,
                meaning:
                    "running: command cannot be carried out; the drive is in keypad mode (F-12 = 1), and \
                          the B800 protocol reverses a running drive only with F-12 = 2"
                        .to_string(),
            }),
            (Purpose::Reset, ErrorCode::TRIPPED) => Err(DriveError::Refused {
                code: u32::from(code.0),
                space: CodeSpace::B800Error,
                meaning: "tripped: the trip is still in force after S, its cause persists".to_string(),
            }),
            _ => Err(refused(code)),
        }
    }

    /// The outcome once the queue is empty.
    fn finish(&mut self) -> Result<Outcome, DriveError> {
        if self.goal == Goal::Done {
            return Ok(Outcome::Done);
        }
        let status = self.status.ok_or_else(|| DriveError::Protocol("no status was read".to_string()))?;
        let state = status.state();
        let fault = match (status.trip_code(), state) {
            (Some(code), _) => Some(Fault {
                code: u32::from(code),
                text: trip_text(code).map_or_else(|| format!("trip code {code:02X}"), str::to_string),
            }),
            (None, DriveState::HardwareEnableMissing) => {
                Some(Fault { code: 0x99, text: "hardware enable missing".to_string() })
            }
            _ => None,
        };
        let off = output_off(state);
        Ok(Outcome::Status(DriveStatus {
            address: self.address,
            running: state == DriveState::Running,
            direction: None,
            output_hz: if off { Some(0.0) } else { self.output_hz.map(|hz| super::round_to(hz, 3)) },
            setpoint_hz: *self.setpoint(),
            current_a: if off { Some(0.0) } else { self.current_a },
            fault,
            values: Vec::new(),
        }))
    }
}

impl Plan for B800Plan {
    fn step(&mut self, reply: Option<&[u8]>) -> Result<Step, DriveError> {
        if let Some((cmd, purpose)) = self.sent.take() {
            match self.destination {
                // No drive answers G: the drives took it.
                Destination::Global => {
                    if let Purpose::SetSpeed(hz) = purpose {
                        *self.setpoint() = Some(hz);
                    }
                }
                Destination::Drive(_) => {
                    let bytes = reply.ok_or_else(|| {
                        DriveError::Protocol(format!("drive {} did not answer", self.address))
                    })?;
                    self.take_reply(cmd, purpose, bytes)?;
                }
            }
        }
        if self.queue.is_empty() {
            return self.finish().map(Step::Done);
        }
        let (cmd, purpose) = self.queue.remove(0);
        let mut buf = [0u8; MAX_FRAME];
        let n = Request::new(self.destination, cmd)
            .emit(&mut buf)
            .map_err(|e| DriveError::Protocol(format!("the B800 frame cannot be built: {e}")))?;
        self.sent = Some((cmd, purpose));
        Ok(Step::Send(Exchange {
            request: buf[..n].to_vec(),
            expect_reply: self.destination != Destination::Global,
        }))
    }
}
