//! A drive as bus master: seed 004 9.2.2 (2), "变频器作为主机,使用广播地址发送命令到从机,从机
//! 不应答" (the drive as master sends commands to the slaves at the broadcast address; the
//! slaves do not answer), and the Toshiba manual's inter-drive communication (f806 = 3/4 master,
//! 0..2 slave, proportional control of speed by the slaves' f810..f814).
//!
//! [`BusMaster`] wraps a family drive: the drive still answers a master of its own as before,
//! and on its own clock broadcasts, every cycle, its run/stop and its frequency in its own
//! protocol:
//!
//! | family | frames every cycle |
//! |---|---|
//! | generic (RTU or ASCII) | 06 to address 0: 2001H = the setpoint (0.01 Hz), then, 10 ms of silence later, 2000H = 2 (forward run), 3 (reverse run) or 7 (decelerate to stop) |
//! | toshiba (TIP) | binary block write to every inverter `2F FF 58 02 00 FA00 FA01 SUM`: FA00 = C400 (command and frequency priority, run; bit 9 reverse) or C000 (stop), FA01 = the frequency in 0.01 % of the master's FH (f806 = 3: its frequency command; 4: its output frequency) |
//!
//! The followers need nothing else: generic drives obey broadcast writes (P0.01 = 2, P0.00 = 4,
//! the simulator's starting values), Toshiba drives obey broadcast block writes to the numbers
//! f870/f871 select (FA00, FA01 by default) and scale FA01 through f810..f814. The choices the
//! manuals leave open are in docs/simulator.md, "Decisions".

use std::collections::VecDeque;
use std::time::Duration;

use drivebus_drive::Family;
use drivebus_proto::modbus::{RegisterAddress, Request, RequestPdu, UnitId};
use drivebus_proto::toshiba::binary::{BinaryAddress, BinaryRequest, BlockRequest};
use drivebus_proto::Instant;

use crate::drive::{Device, DriveCore, DriveSnapshot, VirtualDrive};
use crate::model::{Rotation, RunState};

/// How often a master drive broadcasts unless the bus file says otherwise (`cycle_ms`).
pub const DEFAULT_CYCLE: Duration = Duration::from_millis(100);
/// The silence a generic master keeps between its two frames: seed 004's RTU frame
/// delimiter, "保持无输入信号大于等于 10ms" (also kept in ASCII mode).
pub const GENERIC_GAP: Duration = drivebus_drive::registers::generic::FRAME_SILENCE;

/// Toshiba f806, inter-drive communication.
const F806: u32 = 0x0806;
/// Toshiba FH, maximum frequency (0.01 Hz): 100 % of the inter-drive frequency.
const FH: u32 = 0x0011;

/// A virtual drive that is also the line's bus master (see the module docs).
pub struct BusMaster {
    drive: Box<dyn VirtualDrive>,
    cycle: Duration,
    char_time: Duration,
    /// When the next frame goes out.
    next: Instant,
    /// When the cycle in progress started.
    cycle_start: Instant,
    /// Frames of this cycle not yet sent.
    queue: VecDeque<Vec<u8>>,
}

impl BusMaster {
    /// Makes `drive` the bus master, broadcasting every `cycle` from `now` on a line whose
    /// characters take `char_time`. Errors name what the family cannot do.
    pub fn new(
        drive: Box<dyn VirtualDrive>,
        cycle: Duration,
        char_time: Duration,
        now: Instant,
    ) -> Result<Self, String> {
        match (drive.family(), drive.protocol().as_str()) {
            (Family::Generic, _) => {}
            (Family::Toshiba, p) if p != drivebus_proto::protocol::WireProtocol::ModbusRtu.name() => {}
            (Family::Toshiba, _) => {
                return Err("a Toshiba master drive broadcasts in the TOSHIBA protocol's binary mode: \
                            remove protocol = \"modbus-rtu\""
                    .into())
            }
            (family, _) => {
                return Err(format!(
                    "the {family} manual describes no drive acting as bus master: role = \"master\" \
                     is for generic and toshiba drives"
                ))
            }
        }
        if cycle.is_zero() {
            return Err("the master's cycle must be longer than 0 ms".into());
        }
        Ok(BusMaster { drive, cycle, char_time, next: now, cycle_start: now, queue: VecDeque::new() })
    }

    /// The broadcast cycle.
    pub fn cycle(&self) -> Duration {
        self.cycle
    }

    /// The frames the master sends this cycle, from its state now.
    pub fn frames(&self) -> Vec<Vec<u8>> {
        broadcast_frames(self.drive.as_ref())
    }

    /// The silence kept after a frame before the next of the same cycle.
    fn gap(&self) -> Duration {
        match self.drive.family() {
            Family::Generic => GENERIC_GAP,
            _ => self.char_time * 4,
        }
    }
}

/// The frames a master drive broadcasts now (see the module docs); none for a family without
/// a master role.
pub fn broadcast_frames(drive: &dyn VirtualDrive) -> Vec<Vec<u8>> {
    let core = drive.core();
    let m = &core.model;
    // Stopping (ramping down) is not running: the followers ramp down with the master.
    let running = m.state() == RunState::Running;
    let reverse = m.rotation() == Rotation::Reverse;
    match drive.family() {
        Family::Generic => {
            let centi = (m.setpoint_hz() * 100.0).round().clamp(0.0, f64::from(u16::MAX)) as u16;
            let command = match (running, reverse) {
                (false, _) => 7,
                (true, false) => 2,
                (true, true) => 3,
            };
            let ascii = drive.protocol() == "modbus-ascii";
            [(0x2001, centi), (0x2000, command)]
                .into_iter()
                .filter_map(|(register, value)| modbus_broadcast(register, value, ascii))
                .collect()
        }
        Family::Toshiba => {
            let hz = if core.params.get(F806) == Some(4) { m.output_hz() } else { m.setpoint_hz() };
            let fh = core.params.get(FH).unwrap_or(8000).max(1) as f64;
            let percent = (hz * 100.0 / fh * 10_000.0).round().clamp(0.0, f64::from(u16::MAX)) as u16;
            let mut command: u16 = if running { 0xC400 } else { 0xC000 };
            if running && reverse {
                command |= 0x0200;
            }
            let Ok(block) = BlockRequest::new(&[command, percent], 0) else { return Vec::new() };
            let mut out = [0u8; 16];
            match BinaryRequest::block(BinaryAddress::Broadcast, block).emit(&mut out) {
                Ok(n) => vec![out[..n].to_vec()],
                Err(_) => Vec::new(),
            }
        }
        _ => Vec::new(),
    }
}

/// `06` to the broadcast address 0, RTU or ASCII.
fn modbus_broadcast(register: u16, value: u16, ascii: bool) -> Option<Vec<u8>> {
    let request = Request {
        unit: UnitId(0),
        pdu: RequestPdu::WriteSingleRegister { address: RegisterAddress(register), value },
    };
    let mut out = [0u8; 32];
    let n = if ascii { request.emit_ascii(&mut out) } else { request.emit_rtu(&mut out) }.ok()?;
    Some(out[..n].to_vec())
}

impl Device for BusMaster {
    fn receive(&mut self, now: Instant, bytes: &[u8]) {
        self.drive.receive(now, bytes);
    }

    fn silence(&mut self, now: Instant) {
        self.drive.silence(now);
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>> {
        if let Some(reply) = self.drive.poll_transmit(now) {
            return Some(reply);
        }
        if now < self.next {
            return None;
        }
        if self.queue.is_empty() {
            self.cycle_start = now;
            self.queue = self.frames().into();
        }
        let frame = self.queue.pop_front()?;
        let sent = now + self.char_time * frame.len() as u32;
        self.next = if self.queue.is_empty() {
            (self.cycle_start + self.cycle).max(sent + self.gap())
        } else {
            sent + self.gap()
        };
        Some(frame)
    }

    fn poll_timeout(&self) -> Option<Instant> {
        Some(self.drive.poll_timeout().map_or(self.next, |t| t.min(self.next)))
    }

    fn advance_to(&mut self, now: Instant) {
        self.drive.advance_to(now);
    }

    crate::drive::device_is_a_drive!();
}

impl VirtualDrive for BusMaster {
    fn protocol(&self) -> String {
        self.drive.protocol()
    }

    fn core(&self) -> &DriveCore {
        self.drive.core()
    }

    fn core_mut(&mut self) -> &mut DriveCore {
        self.drive.core_mut()
    }

    fn control_source(&self) -> String {
        self.drive.control_source()
    }

    fn power_cycle(&mut self, now: Instant) {
        self.drive.power_cycle(now);
    }

    fn set_param(&mut self, name: &str, value: &str) -> Result<(), String> {
        self.drive.set_param(name, value)
    }

    fn press_run(&mut self, run: bool) -> Result<(), String> {
        self.drive.press_run(run)
    }

    fn set_keypad_hz(&mut self, hz: f64) -> Result<(), String> {
        self.drive.set_keypad_hz(hz)
    }

    fn snapshot(&self) -> DriveSnapshot {
        DriveSnapshot { role: Some("master".into()), ..self.drive.snapshot() }
    }
}
