//! Toshiba VF-AS1 (manual E6581315, `seeds/002_43d8a4399c8be05f.txt`; protocols.md section 1):
//! one profile for the three ways the drive talks, Modbus-RTU, the TOSHIBA Inverter Protocol
//! (TIP) in ASCII mode and TIP in binary mode, one [`WireProtocol`] per profile ([`ToshibaProtocol`]
//! is the drive's own setting, f829, that picks TIP or Modbus-RTU).
//!
//! | operation | exchanges |
//! |---|---|
//! | Status | read FD01 (status 1), FD00 (output frequency), FE02 (frequency command), FE03 (current, 0.01 % of FE70), FE70 (rated current, 0.1 A: read once per profile, and again after [`Profile::refresh_setup`]), FC90 (trip code, only when FD01 says tripped). Binary mode (block status, on by default, [`ToshibaProfile::with_block_status`]): one `X` block read of the items f875–f879 select (read once per profile and after a refresh; FD01, FD00, FE03 needed), asking for the read groups up to the last of those three (3 with the default selection; FC90 is used where it lies within them, else read when FD01 says tripped), and FE02: 31 bytes on the wire instead of 56 |
//! | Run / Jog | read FD01 (trip, direction), write FA00 = C400H / C500H with bit 9 = the direction FD01 shows |
//! | Reverse | read FD01, write FA00 with bit 9 turned over (a running drive ramps through zero) |
//! | Stop | write FA00 = C000H (command and frequency priority kept, run off), bit 9 as last known |
//! | Reset | read FD01; when tripped: write FA00 with bit 13 (fault reset), write it again without, read FC90 |
//! | SetSpeed | write FA01, 0.01 Hz (used while FA00 bit 14 is set, which Run, Jog, Reverse and Stop set) |
//! | ReadParam / WriteParam | `R` / `W` (RAM and EEPROM) / `P` (RAM) in TIP; 03 / 06 in Modbus-RTU |
//!
//! Every FA00 command carries bit 15 (command priority) and bit 14 (frequency priority): the
//! drive acts on FA00 only with bit 15, and uses FA01 only with bit 14 (protocols.md 1.9).
//! TIP requests always carry the inverter number, and ASCII requests `&` + SUM (optional in the
//! manual), so that the drive checks them and its reply can be matched.
//!
//! Decisions (where the manuals are silent; they match the simulated VF-AS1 of `drivebus-sim`):
//!
//! - **Storage.** TIP lets the master choose: [`Storage::Ram`] is `P`, [`Storage::Eeprom`] is
//!   `W`. Modbus-RTU cannot: 06 writes RAM and EEPROM for every number but the FAxx commands,
//!   so a [`Storage::Ram`] write of an EEPROM setting over Modbus is [`DriveError::Unsupported`]
//!   with a sentence that names the way out (TIP's `P`, f829 = 0), never a silent EEPROM
//!   write. A RAM-only number (FAxx, f400) cannot be written with [`Storage::Eeprom`].
//! - **Refusals.** TIP error replies (0000–0004) and Modbus exceptions (01–04) are
//!   [`DriveError::Refused`] with the manual's meaning. The VF-AS1 takes a run command while
//!   tripped without an error and ignores it, so Run, Jog and Reverse read FD01 first: a
//!   tripped drive gets no command, and the plan ends with `Refused { code: <FC90 trip code> }`.
//!   So does a Reset after which the trip persists. A TIP reply in lower case (tripped) to a
//!   run command is refused the same way.
//! - **Reverse** acts on a running drive; a stopped drive gets no command
//!   ([`DriveError::Unsupported`]): FA00 bit 9 without bit 10 starts nothing, and FD01 shows
//!   the drive's own direction, which Run follows. A Reset of a drive that is not tripped sends
//!   nothing after the status read, so a running drive is not disturbed.
//! - **Speed limits.** SetSpeed is checked before anything is sent against the lower of FH
//!   (0011, maximum frequency) and UL (0012, upper limit), starting at the catalog defaults
//!   and learnt from every ReadParam/WriteParam of 0011/0012 through the profile, or set with
//!   [`ToshibaProfile::set_speed_limits`].
//! - **Broadcast.** Modbus address 0, TIP `**` (ASCII) or FF (binary), asked for with address
//!   [`TIP_BROADCAST`] = 255. Run (forward), Stop, SetSpeed and WriteParam go out with
//!   `expect_reply: false`; Status, ReadParam, Jog, Reverse and Reset read the drive first and
//!   are [`DriveError::Unsupported`]. TIP lets inverter 00 answer a broadcast; the profile does
//!   not wait for it.
//! - **Trip codes.** [`trip_text`] knows the VF-AS1 codes drivebus is sure of; the simulated
//!   drive reports 03 (OC3), 0C (OP3), 10 (OH), 11 (E), 18 (Err5) and 1E (UP1).

use std::fmt;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};

use drivebus_proto::modbus::ExceptionCode;
use drivebus_proto::toshiba::ascii::{AsciiAddress, AsciiReply, AsciiReplyBody, AsciiRequest};
use drivebus_proto::toshiba::binary::{
    BinaryAddress, BinaryReply, BinaryReplyBody, BinaryRequest, BlockRequest,
};
use drivebus_proto::toshiba::{block_read_item, Cmd, CommNo, Command1, ErrorCode, Status1};

use super::generic::{
    raw_of, ModbusAnswer, ModbusAsk, ModbusFraming, RegisterJob, RegisterRules, SpeedLimits,
};
use super::{
    CodeSpace, DriveError, DriveStatus, Exchange, Fault, Operation, Outcome, Plan, Profile, Step,
    WireProtocol,
};
use crate::{Catalog, Family, ParamDef, Storage};

/// The address that makes a TIP profile a broadcast (`**` in ASCII mode, FF in binary mode).
/// A Modbus-RTU profile broadcasts with address 0.
pub const TIP_BROADCAST: u8 = 0xFF;

/// FA00 communication command 1.
const FA00: u16 = 0xFA00;
/// FA01 frequency command, 0.01 Hz.
const FA01: u16 = 0xFA01;
/// FD00 output frequency, 0.01 Hz.
const FD00: u16 = 0xFD00;
/// FD01 operating status 1.
const FD01: u16 = 0xFD01;
/// FE02 frequency command value, 0.01 Hz.
const FE02: u16 = 0xFE02;
/// FE03 output current, 0.01 % of FE70.
const FE03: u16 = 0xFE03;
/// FE70 rated current, 0.1 A.
const FE70: u16 = 0xFE70;
/// FC90 trip code.
const FC90: u16 = 0xFC90;

/// Command and frequency priority: every FA00 word the profile writes has them.
const PRIORITY: u16 = Command1::COMMAND_PRIORITY | Command1::FREQUENCY_PRIORITY;

/// Which protocol a VF-AS1 is set to speak (parameter f829): the TOSHIBA Inverter Protocol,
/// whose ASCII and binary modes it tells apart per frame, or Modbus-RTU. The profile speaks one
/// [`WireProtocol`] of it; the simulated VF-AS1 of `drivebus-sim` answers all of it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ToshibaProtocol {
    /// f829 = 0: TOSHIBA Inverter Protocol, ASCII and binary mode on one line.
    Tip,
    /// f829 = 1: Modbus-RTU.
    ModbusRtu,
}

impl ToshibaProtocol {
    /// The setting that speaks `protocol`, if the VF-AS1 speaks it.
    pub fn of(protocol: WireProtocol) -> Option<Self> {
        match protocol {
            WireProtocol::ModbusRtu => Some(ToshibaProtocol::ModbusRtu),
            WireProtocol::ToshibaAscii | WireProtocol::ToshibaBinary => Some(ToshibaProtocol::Tip),
            _ => None,
        }
    }

    /// The wire protocols a master may use with a drive so set.
    pub fn wire_protocols(self) -> &'static [WireProtocol] {
        match self {
            ToshibaProtocol::Tip => &[WireProtocol::ToshibaAscii, WireProtocol::ToshibaBinary],
            ToshibaProtocol::ModbusRtu => &[WireProtocol::ModbusRtu],
        }
    }

    /// Its name: the protocols' names joined by `+` (`toshiba-ascii+toshiba-binary`).
    pub fn name(self) -> String {
        self.wire_protocols().iter().map(|p| p.name()).collect::<Vec<_>>().join("+")
    }

    /// The value of f829 that selects it.
    pub fn f829(self) -> i64 {
        match self {
            ToshibaProtocol::Tip => 0,
            ToshibaProtocol::ModbusRtu => 1,
        }
    }

    /// The protocol f829 = `value` selects (anything but 1 is TOSHIBA, the shipment setting).
    pub fn from_f829(value: i64) -> Self {
        if value == 1 {
            ToshibaProtocol::ModbusRtu
        } else {
            ToshibaProtocol::Tip
        }
    }

    /// The address that broadcasts: 0 in Modbus-RTU, [`TIP_BROADCAST`] in TIP.
    pub fn broadcast_address(self) -> u8 {
        match self {
            ToshibaProtocol::ModbusRtu => 0,
            ToshibaProtocol::Tip => TIP_BROADCAST,
        }
    }
}

/// The panel name and meaning of a VF-AS1 trip code (FC90, FE10–FE13), for the codes drivebus
/// knows; others are named by number.
pub fn trip_text(code: u16) -> String {
    let (name, text) = match code {
        0x00 => ("nErr", "no trip"),
        0x01 => ("OC1", "over-current during acceleration"),
        0x02 => ("OC2", "over-current during deceleration"),
        0x03 => ("OC3", "over-current during constant speed operation"),
        0x04 => ("OCL", "over-current in the load at start-up"),
        0x08 => ("EPHI", "input phase failure"),
        0x09 => ("EPHO", "output phase failure"),
        0x0A => ("OP1", "over-voltage during acceleration"),
        0x0B => ("OP2", "over-voltage during deceleration"),
        0x0C => ("OP3", "over-voltage during constant speed operation"),
        0x0D => ("OL1", "inverter overload"),
        0x0E => ("OL2", "motor overload"),
        0x0F => ("OLr", "dynamic braking resistor overload"),
        0x10 => ("OH", "overheat"),
        0x11 => ("E", "emergency stop"),
        0x12 => ("EEP1", "EEPROM fault"),
        0x15 => ("Err2", "main unit RAM fault"),
        0x16 => ("Err3", "main unit ROM fault"),
        0x17 => ("Err4", "CPU fault"),
        0x18 => ("Err5", "communication time-out (interruption of operation)"),
        0x1A => ("Err7", "current detector fault"),
        0x1B => ("Err8", "optional unit fault"),
        0x1D => ("UC", "low current operation"),
        0x1E => ("UP1", "main circuit under-voltage"),
        0x20 => ("Ot", "over-torque"),
        0x22 => ("EF2", "ground fault"),
        0x25 => ("OCr", "dynamic braking resistor over-current"),
        0x26 => ("OH2", "external thermal trip"),
        _ => {
            return format!(
                "trip code {code:02X}H (not in drivebus' table: see the VF-AS1 manual's trip list)"
            )
        }
    };
    format!("{name}: {text}")
}

/// What a TIP error code means (protocols.md 1.6, VF-AS1 manual 4.3 "Transmission errors").
pub fn tip_error_meaning(code: u16) -> String {
    let text = match code {
        0 => {
            "impossible to execute: the command cannot be carried out now (a parameter that cannot \
              change while running, a write during setup or initialisation, an EEPROM fault, or a \
              monitor written)"
        }
        1 => "data error: invalid data (out of range, too many digits)",
        2 => "communication number error: there is no such communication number",
        3 => "command error: there is no such command",
        4 => "checksum error: the checksum of the request did not match (damaged on the line)",
        _ => return format!("{} ({code:04X}H)", ErrorCode(code).name()),
    };
    text.to_string()
}

/// What a Modbus exception means on the VF-AS1 (protocols.md 1.8).
pub fn modbus_exception_meaning(code: u8) -> String {
    let text = match code {
        1 => "illegal function (the VF-AS1 knows 03, 06 and 2B/0E; TIP's command error)",
        2 => "illegal data address: there is no such communication number",
        3 => "illegal data value: data error (out of range), or a read of more than one word",
        4 => {
            "slave device failure: impossible to execute (a parameter that cannot change while \
              running, a write during setup, an EEPROM fault, or a monitor written)"
        }
        other => {
            return match ExceptionCode(other).meaning() {
                Some(m) => format!("{m} (an exception the VF-AS1 manual does not list)"),
                None => "an exception code Modbus does not define".to_string(),
            }
        }
    };
    text.to_string()
}

/// What a profile has learnt about its drive and shares with its plans.
#[derive(Debug, Default)]
struct Memory {
    /// FE70, 0.1 A; 0 until read.
    rated_current: AtomicU32,
    /// The direction last read from FD01 or commanded.
    reverse: AtomicBool,
    /// What the drive's block read items (f875–f879) carry, once read.
    block: Mutex<BlockMap>,
    /// The next status reads FE70 (and f875–f879 in block status) again
    /// ([`Profile::refresh_setup`]).
    refresh: AtomicBool,
}

impl Memory {
    fn block(&self) -> BlockMap {
        *self.block.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn set_block(&self, map: BlockMap) {
        *self.block.lock().unwrap_or_else(|p| p.into_inner()) = map;
    }
}

/// The first of the block read item selections f875–f879.
const F875: u16 = 0x0875;
/// The last of them.
const F879: u16 = 0x0879;

/// What a block read (`X`) carries, as f875–f879 select it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum BlockMap {
    /// Not read yet.
    #[default]
    Unknown,
    /// The communication number of each read item (0: no selection); it carries FD01, FD00
    /// and FE03, so a status needs only the block and FE02.
    Items([u16; 5]),
    /// The selection lacks FD01, FD00 or FE03 (or the drive would not tell): status reads
    /// one number per request.
    Unusable,
}

impl BlockMap {
    /// The map of the selections f875–f879 hold.
    fn of(selections: [u16; 5]) -> BlockMap {
        let items = selections.map(|s| block_read_item(s).map_or(0, |c| c.0));
        if [FD01, FD00, FE03].iter().all(|n| items.contains(n)) {
            BlockMap::Items(items)
        } else {
            BlockMap::Unusable
        }
    }

    /// The read groups to ask for: up to the last of FD01, FD00 and FE03 (fewer groups, a
    /// shorter reply; FC90 comes along where it lies within them).
    fn groups(self) -> u8 {
        match self {
            BlockMap::Items(items) => {
                let last = items.iter().rposition(|n| [FD01, FD00, FE03].contains(n)).unwrap_or(4);
                u8::try_from(last + 1).unwrap_or(5)
            }
            _ => 5,
        }
    }
}

/// A Toshiba VF-AS1 at one inverter number (or a broadcast), in one of its protocols.
#[derive(Debug)]
pub struct ToshibaProfile {
    address: u8,
    protocol: WireProtocol,
    /// The broadcast address of `protocol`.
    broadcast: u8,
    catalog: Arc<Catalog>,
    limits: Arc<SpeedLimits>,
    memory: Arc<Memory>,
    block_status: bool,
}

impl ToshibaProfile {
    /// A profile for inverter `address` speaking `protocol`: Modbus-RTU 1..=247 (0 =
    /// broadcast), TIP ASCII 0..=99, TIP binary 0..=63 ([`TIP_BROADCAST`] = broadcast); the
    /// ranges are the family's capability table ([`Family::address_range`]).
    pub fn new(address: u8, protocol: WireProtocol) -> Result<Self, DriveError> {
        let Some(setting) = ToshibaProtocol::of(protocol) else {
            return Err(DriveError::Unsupported(format!(
                "the VF-AS1 speaks {} or {}, not {protocol}",
                ToshibaProtocol::Tip.name().replace('+', ", "),
                ToshibaProtocol::ModbusRtu.name()
            )));
        };
        let broadcast = setting.broadcast_address();
        let (lo, hi) = Family::Toshiba.address_range(protocol);
        if !(lo..=hi).contains(&address) && address != broadcast {
            return Err(DriveError::OutOfRange(format!(
                "a VF-AS1 speaking {protocol} has inverter number {lo}..{hi}, or {broadcast} for a broadcast; not {address}"
            )));
        }
        let catalog = Catalog::load(Family::Toshiba)
            .map_err(|e| DriveError::Unsupported(format!("the Toshiba catalog does not load: {e}")))?;
        let limits = SpeedLimits::from_catalog(&catalog, "0011", "maximum frequency", "0012", "upper limit")?;
        Ok(ToshibaProfile {
            address,
            protocol,
            broadcast,
            catalog,
            limits: Arc::new(limits),
            memory: Arc::new(Memory::default()),
            block_status: true,
        })
    }

    /// Block status (on by default): in TIP binary mode, Status reads FD01, FD00, FE03 (and
    /// FC90 where selected) in one `X` block exchange and FE02 in one `R`. The block reply does
    /// not say which items it carries, so the first status reads f875–f879 once (and again after
    /// a write of one of them through the profile); a selection without FD01, FD00 and FE03
    /// falls back to one read per number. With `off`, Status always reads one number per
    /// request. Other protocols ignore it.
    pub fn with_block_status(mut self, on: bool) -> Self {
        self.block_status = on;
        self
    }

    /// The protocol in use.
    pub fn wire(&self) -> WireProtocol {
        self.protocol
    }

    /// True for the broadcast address of the protocol.
    pub fn is_broadcast(&self) -> bool {
        self.address == self.broadcast
    }

    /// The limits SetSpeed is checked against, raw 0.01 Hz: (0011 FH maximum frequency, 0012
    /// UL upper limit). They start at the catalog defaults.
    pub fn speed_limits(&self) -> (i64, i64) {
        self.limits.get()
    }

    /// Sets the limits SetSpeed is checked against, raw 0.01 Hz, as read from the drive. A
    /// ReadParam or WriteParam of 0011 or 0012 through this profile sets them as well.
    pub fn set_speed_limits(&self, max_frequency: i64, upper_limit: i64) {
        self.limits.set(max_frequency, upper_limit);
    }

    fn def(&self, name: &str) -> Result<&ParamDef, DriveError> {
        self.catalog.get(name).ok_or_else(|| {
            DriveError::Unsupported(format!(
                "{:?} is not a parameter of the VF-AS1 (catalogs/toshiba.toml): name it by its \
                 communication number or title, 0010, dEC, f803 or FD00",
                name.trim()
            ))
        })
    }

    fn needs_reply(&self, what: &str) -> Result<(), DriveError> {
        if self.is_broadcast() {
            return Err(DriveError::Unsupported(format!(
                "{what} reads the drive first, and a broadcast gets no answer: use a drive's own number"
            )));
        }
        Ok(())
    }

    /// The storage rules of the protocol in use.
    fn storage_check(&self) -> impl Fn(&ParamDef, Storage) -> Result<(), String> {
        let protocol = self.protocol;
        move |def: &ParamDef, asked: Storage| match (def.storage, asked, protocol) {
            (Storage::Ram, Storage::Eeprom, _) => Err(format!(
                "{} lives in RAM only ({}): it cannot be stored in EEPROM; ask for Storage::Ram",
                def.name, def.title
            )),
            (Storage::Eeprom, Storage::Ram, WireProtocol::ModbusRtu) => Err(format!(
                "Modbus-RTU has no RAM-only write on the VF-AS1: 06 stores {} in RAM and EEPROM (every \
                 number but FAxx); ask for Storage::Eeprom, or use the TOSHIBA protocol's P command \
                 (f829 = 0) to change RAM only",
                def.name
            )),
            _ => Ok(()),
        }
    }

    fn plan_for(&self, job: Job) -> Box<dyn Plan> {
        Box::new(ToshibaPlan {
            link: Link { protocol: self.protocol, address: self.address, broadcast: self.is_broadcast() },
            limits: Arc::clone(&self.limits),
            memory: Arc::clone(&self.memory),
            job,
            sent: None,
            finished: false,
        })
    }

    fn direction_bit(&self) -> u16 {
        if self.memory.reverse.load(Ordering::Relaxed) {
            Command1::REVERSE
        } else {
            0
        }
    }
}

impl Profile for ToshibaProfile {
    fn family(&self) -> Family {
        Family::Toshiba
    }

    fn protocol(&self) -> WireProtocol {
        self.protocol
    }

    fn address(&self) -> u8 {
        self.address
    }

    fn param(&self, name: &str) -> Result<&ParamDef, DriveError> {
        self.def(name)
    }

    /// A status without FE70 and f875–f879: the block read where its items are known, else
    /// one number per request; the current only where FE70 is known.
    fn plan_status_without_setup(&self) -> Option<Result<Box<dyn Plan>, DriveError>> {
        if let Err(e) = self.needs_reply("Status") {
            return Some(Err(e));
        }
        let block = self.block_status && self.protocol == WireProtocol::ToshibaBinary;
        let mut todo = match (block, self.memory.block()) {
            (true, map @ BlockMap::Items(_)) => vec![Ask::Block(map.groups()), Ask::Read(FE02)],
            _ => single_status_reads(),
        };
        todo.reverse();
        Some(Ok(self.plan_for(Job::Status(StatusJob { todo, got: Monitors::default() }))))
    }

    /// The next status reads FE70 again, and in TIP binary mode with block status f875–f879.
    /// A broadcast profile reads nothing.
    fn refresh_setup(&self) {
        if !self.is_broadcast() {
            self.memory.refresh.store(true, Ordering::Relaxed);
        }
    }

    fn plan(&self, op: &Operation) -> Result<Box<dyn Plan>, DriveError> {
        let command = |kind: CommandKind| -> Result<Job, DriveError> {
            if self.is_broadcast() && kind == CommandKind::Run {
                // No drive can be read: run forward.
                return Ok(write_fa00(PRIORITY | Command1::RUN, "run forward"));
            }
            self.needs_reply(kind.name())?;
            Ok(Job::Command(CommandJob { kind, stage: CommandStage::Start, base: 0, was_tripped: false }))
        };
        let job = match op {
            Operation::Status => {
                self.needs_reply("Status")?;
                let block = self.block_status && self.protocol == WireProtocol::ToshibaBinary;
                // Set-up values read again on the slow schedule: the drive's panel may have
                // changed them, and a standby listening learns them from these reads.
                let refresh = self.memory.refresh.swap(false, Ordering::Relaxed);
                let mut todo = match (block, self.memory.block()) {
                    (true, _) if refresh => (F875..=F879).map(Ask::Read).collect(),
                    (true, BlockMap::Unknown) => (F875..=F879).map(Ask::Read).collect(),
                    (true, map @ BlockMap::Items(_)) => vec![Ask::Block(map.groups()), Ask::Read(FE02)],
                    _ => single_status_reads(),
                };
                if refresh || self.memory.rated_current.load(Ordering::Relaxed) == 0 {
                    todo.push(Ask::Read(FE70));
                }
                todo.reverse();
                Job::Status(StatusJob { todo, got: Monitors::default() })
            }
            Operation::Run => command(CommandKind::Run)?,
            Operation::Jog => command(CommandKind::Jog)?,
            Operation::Reverse => command(CommandKind::Reverse)?,
            Operation::Reset => command(CommandKind::Reset)?,
            Operation::Stop => write_fa00(PRIORITY | self.direction_bit(), "stop"),
            Operation::SetSpeed(_) | Operation::ReadParam(_) | Operation::WriteParam { .. } => {
                let rules = RegisterRules {
                    setpoint: ("FA01", FA01),
                    def: &|name| self.def(name),
                    needs_reply: &|what| self.needs_reply(what),
                    limits: &self.limits,
                    storage_check: &self.storage_check(),
                };
                match rules.job(op)? {
                    RegisterJob::Write { register, value, ram, what, learn } => {
                        Job::Write { comm: register, value, ram, what, learn }
                    }
                    RegisterJob::Read { register, signed, name } => {
                        Job::Read { comm: register, signed, name }
                    }
                }
            }
        };
        Ok(self.plan_for(job))
    }
}

/// Queues (in `todo`, sent last first) what a status reads once the block read items are
/// known: the block and FE02, or one number per request.
fn next_status_reads(todo: &mut Vec<Ask>, map: BlockMap) {
    let next = match map {
        BlockMap::Items(_) => vec![Ask::Block(map.groups()), Ask::Read(FE02)],
        _ => single_status_reads(),
    };
    todo.extend(next.into_iter().rev());
}

/// Status one number per request: FD01, FD00, FE02, FE03 (in sending order).
fn single_status_reads() -> Vec<Ask> {
    vec![Ask::Read(FD01), Ask::Read(FD00), Ask::Read(FE02), Ask::Read(FE03)]
}

fn write_fa00(word: u16, what: &str) -> Job {
    Job::Write {
        comm: FA00,
        value: word,
        ram: true,
        what: format!("FA00 = {word:04X}H ({what})"),
        learn: None,
    }
}

// ---------------------------------------------------------------------------------------------
// The wire: one request and its reply in the protocol in use
// ---------------------------------------------------------------------------------------------

/// One request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ask {
    /// Read one communication number.
    Read(u16),
    /// Write one: `ram` picks TIP's `P` over `W` (Modbus has 06 only).
    Write { comm: u16, value: u16, ram: bool },
    /// TIP binary `X`: no write groups, this many read groups.
    Block(u8),
}

impl fmt::Display for Ask {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Ask::Read(c) => write!(f, "read of {c:04X}"),
            Ask::Write { comm, value, ram: true } => write!(f, "write (RAM) of {value:04X}H to {comm:04X}"),
            Ask::Write { comm, value, ram: false } => write!(f, "write of {value:04X}H to {comm:04X}"),
            Ask::Block(n) => write!(f, "block read (X) of {n} groups"),
        }
    }
}

/// What a reply said (refusals are errors).
#[derive(Clone, Debug, PartialEq, Eq)]
enum Answer {
    /// The word read or written; `tripped` when a TIP reply came in lower case.
    Data { value: u16, tripped: bool },
    /// The read groups of a block reply.
    Block { items: Vec<u16> },
    /// Nothing is due after a broadcast.
    Broadcast,
}

#[derive(Clone, Copy, Debug)]
struct Link {
    protocol: WireProtocol,
    address: u8,
    broadcast: bool,
}

impl Link {
    fn modbus_ask(ask: Ask) -> Option<ModbusAsk> {
        match ask {
            Ask::Read(c) => Some(ModbusAsk::Read { start: c, quantity: 1 }),
            Ask::Write { comm, value, .. } => Some(ModbusAsk::Write { register: comm, value }),
            Ask::Block(_) => None,
        }
    }

    fn encode(&self, ask: Ask) -> Result<Vec<u8>, DriveError> {
        let cannot = |e: &dyn fmt::Display| DriveError::Protocol(format!("the {ask} cannot be framed: {e}"));
        match self.protocol {
            WireProtocol::ModbusRtu => {
                let m = Link::modbus_ask(ask)
                    .ok_or_else(|| cannot(&"block communication is TIP binary mode only"))?;
                ModbusFraming::Rtu.encode(if self.broadcast { 0 } else { self.address }, m)
            }
            WireProtocol::ToshibaAscii => {
                let inv = if self.broadcast { AsciiAddress::ALL } else { AsciiAddress::Unit(self.address) };
                let request = match ask {
                    Ask::Read(c) => AsciiRequest::read(inv, CommNo(c)),
                    Ask::Write { comm, value, ram: true } => {
                        AsciiRequest::write_ram(inv, CommNo(comm), value)
                    }
                    Ask::Write { comm, value, ram: false } => AsciiRequest::write(inv, CommNo(comm), value),
                    Ask::Block(_) => return Err(cannot(&"block communication is TIP binary mode only")),
                };
                let mut out = [0u8; 32];
                let n = request.with_sum().emit(&mut out).map_err(|e| cannot(&e))?;
                Ok(out[..n].to_vec())
            }
            WireProtocol::ToshibaBinary => {
                let inv =
                    if self.broadcast { BinaryAddress::Broadcast } else { BinaryAddress::Unit(self.address) };
                let request = match ask {
                    Ask::Read(c) => BinaryRequest::read(inv, CommNo(c)),
                    Ask::Write { comm, value, ram: true } => {
                        BinaryRequest::write_ram(inv, CommNo(comm), value)
                    }
                    Ask::Write { comm, value, ram: false } => BinaryRequest::write(inv, CommNo(comm), value),
                    Ask::Block(n) => {
                        BinaryRequest::block(inv, BlockRequest::new(&[], n).map_err(|e| cannot(&e))?)
                    }
                };
                let mut out = [0u8; 32];
                let n = request.emit(&mut out).map_err(|e| cannot(&e))?;
                Ok(out[..n].to_vec())
            }
            other => Err(cannot(&format_args!("the VF-AS1 does not speak {other}"))),
        }
    }

    /// Reads the reply to `ask`: data, or the drive's refusal, or a protocol error.
    fn decode(&self, ask: Ask, reply: Option<&[u8]>, what: &str) -> Result<Answer, DriveError> {
        if self.broadcast {
            return Ok(Answer::Broadcast);
        }
        let bytes = reply.ok_or_else(|| DriveError::Protocol(format!("no reply came to the {ask}")))?;
        let bad = |why: String| DriveError::Protocol(format!("the reply to the {ask} {why}"));
        let (cmd, comm, written) = match ask {
            Ask::Read(c) => (Cmd::R, c, None),
            Ask::Write { comm, value, ram } => (if ram { Cmd::P } else { Cmd::W }, comm, Some(value)),
            Ask::Block(_) => (Cmd::R, 0, None),
        };
        let tip_refusal = |code: ErrorCode| DriveError::Refused {
            code: u32::from(code.0),
            space: CodeSpace::ToshibaError,
            meaning: format!("{} (in reply to the {ask}: {what})", tip_error_meaning(code.0)),
        };
        // A TIP reply must come from the inverter asked (`number` as the mode writes it).
        let from_inverter = |inv_no: Option<u8>, number: String| {
            if inv_no == Some(self.address) {
                return Ok(());
            }
            Err(bad(format!("carries inverter number {inv_no:?}, not {number}")))
        };
        // A TIP data reply: the echo of the request, with the data and the trip flag.
        let echoed = |got_cmd: Cmd, got_comm: u16, value: u16, tripped: bool| {
            check_echo(cmd, comm, written, got_cmd, got_comm, value).map_err(bad)?;
            Ok(Answer::Data { value, tripped })
        };
        match self.protocol {
            WireProtocol::ModbusRtu => {
                let m = Link::modbus_ask(ask).ok_or_else(|| bad("was not expected".to_string()))?;
                match ModbusFraming::Rtu.decode(self.address, m, bytes)? {
                    ModbusAnswer::Registers(r) => {
                        let value =
                            r.first().copied().ok_or_else(|| bad("carries no register".to_string()))?;
                        Ok(Answer::Data { value, tripped: false })
                    }
                    ModbusAnswer::Written => Ok(Answer::Data { value: written.unwrap_or(0), tripped: false }),
                    ModbusAnswer::Exception(code) => Err(DriveError::Refused {
                        code: u32::from(code),
                        space: CodeSpace::ModbusException,
                        meaning: format!("{} (in reply to the {m}: {what})", modbus_exception_meaning(code)),
                    }),
                }
            }
            WireProtocol::ToshibaAscii => {
                let reply = AsciiReply::parse(bytes)
                    .map_err(|e| bad(format!("is not a valid TOSHIBA ASCII frame: {e}")))?;
                from_inverter(reply.inv_no, format!("{:02}", self.address))?;
                match reply.body {
                    AsciiReplyBody::Error(code) => Err(tip_refusal(code)),
                    AsciiReplyBody::Data { cmd: c, comm_no, data } => {
                        echoed(c, comm_no.0, data, reply.tripped)
                    }
                }
            }
            WireProtocol::ToshibaBinary => {
                let reply = BinaryReply::parse(bytes)
                    .map_err(|e| bad(format!("is not a valid TOSHIBA binary frame: {e}")))?;
                from_inverter(reply.inv_no, self.address.to_string())?;
                match (reply.body, ask) {
                    (BinaryReplyBody::Error(code), _) => Err(tip_refusal(code)),
                    (BinaryReplyBody::Block(b), Ask::Block(n)) => {
                        if b.rdata().len() != usize::from(n) {
                            return Err(bad(format!("carries {} read groups, not {n}", b.rdata().len())));
                        }
                        Ok(Answer::Block { items: b.rdata().to_vec() })
                    }
                    (BinaryReplyBody::Data { cmd: c, comm_no, data }, Ask::Read(_) | Ask::Write { .. }) => {
                        echoed(c, comm_no.0, data, reply.tripped)
                    }
                    _ => Err(bad("is not the kind of reply the request asks for".to_string())),
                }
            }
            other => Err(bad(format!("cannot be read: the VF-AS1 does not speak {other}"))),
        }
    }
}

/// A TIP reply must echo the command and number, and a write's value.
fn check_echo(
    cmd: Cmd,
    comm: u16,
    written: Option<u16>,
    got_cmd: Cmd,
    got_comm: u16,
    data: u16,
) -> Result<(), String> {
    if got_cmd != cmd || got_comm != comm {
        return Err(format!("answers {} {got_comm:04X}", char::from(got_cmd.letter())));
    }
    match written {
        Some(value) if value != data => Err(format!("echoes {data:04X}H instead of {value:04X}H")),
        _ => Ok(()),
    }
}

// ---------------------------------------------------------------------------------------------
// Plans
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum CommandKind {
    Run,
    Jog,
    Reverse,
    Reset,
}

impl CommandKind {
    fn name(self) -> &'static str {
        match self {
            CommandKind::Run => "Run",
            CommandKind::Jog => "Jog",
            CommandKind::Reverse => "Reverse",
            CommandKind::Reset => "Reset",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum CommandStage {
    /// Nothing sent yet: read FD01.
    Start,
    /// FD01 asked.
    Status,
    /// The command word written.
    Written,
    /// Reset: the word with bit 13 written; now write it without.
    ResetWritten,
    /// Reset: bit 13 cleared again.
    ResetCleared,
    /// FC90 asked, to say why the command cannot act (`after_reset`: the trip persists).
    TripCode { after_reset: bool },
}

#[derive(Debug)]
struct CommandJob {
    kind: CommandKind,
    stage: CommandStage,
    /// The FA00 word without the fault reset bit.
    base: u16,
    was_tripped: bool,
}

/// The monitors a Status has read.
#[derive(Debug, Default)]
struct Monitors {
    /// f875–f879 as read (block read item selections).
    selections: [u16; 5],
    fd01: u16,
    fd00: u16,
    fe02: u16,
    fe03: u16,
    fc90: Option<u16>,
}

#[derive(Debug)]
struct StatusJob {
    /// Requests still to send, last first.
    todo: Vec<Ask>,
    got: Monitors,
}

#[derive(Debug)]
enum Job {
    Status(StatusJob),
    Command(CommandJob),
    Write { comm: u16, value: u16, ram: bool, what: String, learn: Option<(u32, i64)> },
    Read { comm: u16, signed: bool, name: String },
}

impl Job {
    /// The operation in words, for refusals.
    fn what(&self) -> String {
        match self {
            Job::Status(_) => "Status".to_string(),
            Job::Command(c) => c.kind.name().to_string(),
            Job::Write { what, .. } => what.clone(),
            Job::Read { name, .. } => format!("ReadParam {name}"),
        }
    }
}

/// An operation in progress on a VF-AS1.
struct ToshibaPlan {
    link: Link,
    limits: Arc<SpeedLimits>,
    memory: Arc<Memory>,
    job: Job,
    sent: Option<Ask>,
    finished: bool,
}

type Next = super::Next<Ask>;

fn data(answer: &Option<Answer>) -> (u16, bool) {
    match answer {
        Some(Answer::Data { value, tripped }) => (*value, *tripped),
        _ => (0, false),
    }
}

fn tripped_refusal(code: u16, after_reset: bool) -> DriveError {
    let meaning = if after_reset {
        format!("the trip {} persists after the fault reset: its cause is still there", trip_text(code))
    } else {
        format!(
            "the inverter is tripped ({}; FD01 bit 1) and ignores run commands until the fault is reset",
            trip_text(code)
        )
    };
    DriveError::Refused { code: u32::from(code), space: CodeSpace::Trip, meaning }
}

impl ToshibaPlan {
    fn advance(&mut self, answer: Option<Answer>) -> Result<Next, DriveError> {
        match &mut self.job {
            Job::Write { comm, value, ram, learn, .. } => match answer {
                None => Ok(Next::Send(Ask::Write { comm: *comm, value: *value, ram: *ram })),
                Some(_) => {
                    if let Some((number, raw)) = learn {
                        self.limits.learn(*number, *raw);
                    }
                    if *comm == FA00 {
                        self.memory.reverse.store(*value & Command1::REVERSE != 0, Ordering::Relaxed);
                    }
                    if (F875..=F879).contains(comm) {
                        self.memory.set_block(BlockMap::Unknown);
                    }
                    Ok(Next::Done(Outcome::Done))
                }
            },
            Job::Read { comm, signed, .. } => match answer {
                None => Ok(Next::Send(Ask::Read(*comm))),
                Some(_) => {
                    let raw = raw_of(data(&answer).0, *signed);
                    self.limits.learn(u32::from(*comm), raw);
                    Ok(Next::Done(Outcome::Param(raw)))
                }
            },
            Job::Status(s) => {
                match (self.sent, &answer) {
                    (Some(Ask::Block(_)), Some(Answer::Block { items })) => {
                        let BlockMap::Items(numbers) = self.memory.block() else {
                            return Err(DriveError::Protocol(
                                "a block reply came before the block's read items were known".to_string(),
                            ));
                        };
                        for (&number, &value) in numbers.iter().zip(items) {
                            match number {
                                FD01 => s.got.fd01 = value,
                                FD00 => s.got.fd00 = value,
                                FE03 => s.got.fe03 = value,
                                FC90 => s.got.fc90 = Some(value),
                                _ => {}
                            }
                        }
                        self.memory.reverse.store(s.got.fd01 & Status1::REVERSE != 0, Ordering::Relaxed);
                        if s.got.fd01 & Status1::TRIPPED != 0 && s.got.fc90.is_none() {
                            s.todo.insert(0, Ask::Read(FC90));
                        }
                    }
                    (Some(Ask::Read(c @ F875..=F879)), Some(Answer::Data { value, .. })) => {
                        s.got.selections[usize::from(c - F875)] = *value;
                        if c == F879 {
                            let map = BlockMap::of(s.got.selections);
                            self.memory.set_block(map);
                            next_status_reads(&mut s.todo, map);
                        }
                    }
                    (Some(Ask::Read(c)), Some(Answer::Data { value, .. })) => match c {
                        FD01 => {
                            s.got.fd01 = *value;
                            self.memory.reverse.store(value & Status1::REVERSE != 0, Ordering::Relaxed);
                            if value & Status1::TRIPPED != 0 {
                                s.todo.insert(0, Ask::Read(FC90));
                            }
                        }
                        FD00 => s.got.fd00 = *value,
                        FE02 => s.got.fe02 = *value,
                        FE03 => s.got.fe03 = *value,
                        FE70 => self.memory.rated_current.store(u32::from(*value), Ordering::Relaxed),
                        FC90 => s.got.fc90 = Some(*value),
                        _ => {}
                    },
                    _ => {}
                }
                match s.todo.pop() {
                    Some(ask) => Ok(Next::Send(ask)),
                    None => {
                        let rated = self.memory.rated_current.load(Ordering::Relaxed);
                        Ok(Next::Done(Outcome::Status(status_of(self.link.address, &s.got, rated))))
                    }
                }
            }
            Job::Command(c) => {
                let (value, tripped_reply) = data(&answer);
                match c.stage {
                    CommandStage::Start => {
                        c.stage = CommandStage::Status;
                        Ok(Next::Send(Ask::Read(FD01)))
                    }
                    CommandStage::Status => {
                        let fd01 = value;
                        self.memory.reverse.store(fd01 & Status1::REVERSE != 0, Ordering::Relaxed);
                        let tripped = fd01 & Status1::TRIPPED != 0;
                        let running = fd01 & Status1::RUNNING != 0;
                        let direction = if fd01 & Status1::REVERSE != 0 { Command1::REVERSE } else { 0 };
                        if c.kind == CommandKind::Reset {
                            if !tripped {
                                // Nothing to reset; a running drive is left alone.
                                return Ok(Next::Done(Outcome::Done));
                            }
                            c.was_tripped = true;
                            c.base = PRIORITY | direction;
                            c.stage = CommandStage::ResetWritten;
                            let word = c.base | Command1::FAULT_RESET;
                            return Ok(Next::Send(Ask::Write { comm: FA00, value: word, ram: true }));
                        }
                        if tripped {
                            c.stage = CommandStage::TripCode { after_reset: false };
                            return Ok(Next::Send(Ask::Read(FC90)));
                        }
                        let word = match c.kind {
                            CommandKind::Run => PRIORITY | Command1::RUN | direction,
                            CommandKind::Jog => PRIORITY | Command1::RUN | Command1::JOG | direction,
                            _ => {
                                if !running {
                                    return Err(DriveError::Unsupported(
                                        "the drive is stopped: FA00 bit 9 without bit 10 starts nothing, so \
                                         Reverse acts on a running drive (Run follows the direction FD01 \
                                         shows)"
                                            .to_string(),
                                    ));
                                }
                                let jog = if fd01 & Status1::JOG != 0 { Command1::JOG } else { 0 };
                                PRIORITY | Command1::RUN | jog | (direction ^ Command1::REVERSE)
                            }
                        };
                        c.base = word;
                        c.stage = CommandStage::Written;
                        Ok(Next::Send(Ask::Write { comm: FA00, value: word, ram: true }))
                    }
                    CommandStage::Written => {
                        if tripped_reply {
                            c.stage = CommandStage::TripCode { after_reset: false };
                            return Ok(Next::Send(Ask::Read(FC90)));
                        }
                        self.memory.reverse.store(c.base & Command1::REVERSE != 0, Ordering::Relaxed);
                        Ok(Next::Done(Outcome::Done))
                    }
                    CommandStage::ResetWritten => {
                        c.stage = CommandStage::ResetCleared;
                        Ok(Next::Send(Ask::Write { comm: FA00, value: c.base, ram: true }))
                    }
                    CommandStage::ResetCleared => {
                        c.stage = CommandStage::TripCode { after_reset: true };
                        Ok(Next::Send(Ask::Read(FC90)))
                    }
                    CommandStage::TripCode { after_reset } => {
                        if after_reset && value == 0 {
                            return Ok(Next::Done(Outcome::Done));
                        }
                        Err(tripped_refusal(value, after_reset))
                    }
                }
            }
        }
    }
}

fn status_of(address: u8, m: &Monitors, rated_current: u32) -> DriveStatus {
    let tripped = m.fd01 & Status1::TRIPPED != 0;
    let code = m.fc90.unwrap_or(0);
    let reverse = m.fd01 & Status1::REVERSE != 0;
    DriveStatus {
        address,
        running: m.fd01 & Status1::RUNNING != 0,
        direction: Some(if reverse { "reverse" } else { "forward" }.to_string()),
        output_hz: Some(f64::from(m.fd00) / 100.0),
        setpoint_hz: Some(f64::from(m.fe02) / 100.0),
        // FE03 is 0.01 % of FE70 (0.1 A): 0.01 A is as fine as the product means anything.
        current_a: (rated_current > 0)
            .then(|| super::round_to(f64::from(m.fe03) * f64::from(rated_current) / 100_000.0, 2)),
        fault: (tripped || code != 0).then(|| Fault { code: u32::from(code), text: trip_text(code) }),
        values: Vec::new(),
    }
}

impl Plan for ToshibaPlan {
    fn step(&mut self, reply: Option<&[u8]>) -> Result<Step, DriveError> {
        if self.finished {
            return Err(DriveError::Protocol("this plan has finished; plan the operation again".to_string()));
        }
        let answer = match self.sent {
            Some(ask) => match self.link.decode(ask, reply, &self.job.what()) {
                Ok(a) => Some(a),
                // A drive that will not tell its block read items is read one number per
                // request.
                Err(DriveError::Refused { .. })
                    if matches!((ask, &self.job), (Ask::Read(F875..=F879), Job::Status(_))) =>
                {
                    self.memory.set_block(BlockMap::Unusable);
                    if let Job::Status(s) = &mut self.job {
                        s.todo.retain(|a| !matches!(a, Ask::Read(F875..=F879)));
                        next_status_reads(&mut s.todo, BlockMap::Unusable);
                    }
                    None
                }
                Err(e) => {
                    self.finished = true;
                    return Err(e);
                }
            },
            None => None,
        };
        let next = self.advance(answer);
        let link = self.link;
        super::step_to(next, &mut self.sent, &mut self.finished, |ask| {
            Ok(Exchange { request: link.encode(ask)?, expect_reply: !link.broadcast })
        })
    }
}

impl fmt::Debug for ToshibaPlan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ToshibaPlan")
            .field("link", &self.link)
            .field("job", &self.job)
            .finish_non_exhaustive()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_current_is_given_at_the_drives_resolution() {
        // 98.28 % of 14.5 A is 14.2506 A in binary floating point's approximation.
        let m = Monitors { fd01: 0, fd00: 0, fe02: 0, fe03: 9828, fc90: None, ..Default::default() };
        assert_eq!(status_of(1, &m, 145).current_a, Some(14.25));
        let m = Monitors { fe03: 1915, ..m };
        assert_eq!(status_of(1, &m, 100).current_a, Some(1.92));
    }

    /// A drive that refuses to tell its block read items (error 0002 to f875) is read one
    /// number per request, and the profile does not ask again.
    #[test]
    fn a_refused_block_selection_falls_back_to_single_reads() {
        let p = ToshibaProfile::new(1, WireProtocol::ToshibaBinary).unwrap_or_else(|e| panic!("{e}"));
        let request = |step: Result<Step, DriveError>| match step {
            Ok(Step::Send(x)) => BinaryRequest::parse(&x.request).unwrap_or_else(|e| panic!("{e}")),
            other => panic!("expected a request, got {other:?}"),
        };
        let mut plan = p.plan(&Operation::Status).unwrap_or_else(|e| panic!("{e}"));
        let first = request(plan.step(None));
        assert_eq!(first.body.comm_no(), Some(CommNo(F875)));
        let refusal = first.error_reply(1, false, ErrorCode::COMM_NO_ERROR);
        let mut out = [0u8; 32];
        let n = refusal.emit(&mut out).unwrap_or_else(|e| panic!("{e}"));
        let next = request(plan.step(Some(&out[..n])));
        assert_eq!(next.body.comm_no(), Some(CommNo(FD01)), "single reads: {next:?}");
        assert_eq!(p.memory.block(), BlockMap::Unusable);
        let mut again = p.plan(&Operation::Status).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(request(again.step(None)).body.comm_no(), Some(CommNo(FD01)));
    }
}
