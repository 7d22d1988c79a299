//! Typed B800 frames: the master's packet (`Request`) and the drive's reply packet (`Reply`),
//! with `parse` and `emit`.
//!
//! seed 000: "FG1 [DA] [CMD] ([DATA]) [CS] FG2" from the master and
//! "FG1 [DA] [REPLY] ([DATA]) [CS] FG2" from a drive, every field between the flags sent as
//! ASCII hex: "a RUN command ('R' = 0x52 (hex)) is sent as two consecutive ASCII codes ie
//! 0x35, 0x32".

use crate::checksum::not_sum8;
use crate::error::{need, ChecksumKind, EmitError, FrameError, MismatchHint};
use crate::hex::byte_digits;

use super::values::{Address, Current, Destination, DriveStatus, ErrorCode, Rpm, Speed, Version};
use super::{ERROR_LETTER, FG1, FG2, MASTER_OFFSET};

/// Hex digit values by byte, 0xFF for a byte that is not `0-9 A-F a-f`.
pub(crate) const HEX: [u8; 256] = {
    let mut t = [0xFFu8; 256];
    let mut i = 0;
    while i < 256 {
        if let Some(v) = crate::hex::digit_value(i as u8) {
            t[i] = v;
        }
        i += 1;
    }
    t
};

/// The byte two hex digits (already checked) stand for.
#[inline]
pub(crate) fn pair(hi: u8, lo: u8) -> u8 {
    (HEX[hi as usize] << 4) | (HEX[lo as usize] & 0x0F)
}

/// The name [`FrameError::Unknown`] gives a master's command byte.
pub const CMD_FIELD: &str = "CMD";
/// The name [`FrameError::Unknown`] gives a drive's reply byte.
pub const REPLY_FIELD: &str = "REPLY";

/// A master's command (seed 000: "CMD = Master Command").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MasterCommand {
    /// `R` (0x52) "Run command"; with F-12 = 2, R to a running drive reverses it.
    Run,
    /// `S` (0x53) "Stop command".
    Stop,
    /// `A` (0x41) "Motor current request".
    MotorCurrent,
    /// `Z` (0x5A) "Speed request in Hz".
    SpeedHz,
    /// `M` (0x4D) "Speed request in RPM".
    SpeedRpm,
    /// `T` (0x54) "Drive Status request".
    Status,
    /// `V` (0x56) "Software version request".
    Version,
    /// `P` (0x50) "Set new speed in Hz" (keypad mode only, F-12 = 1), DATA one word of 60 x Hz.
    SetSpeed(Speed),
    /// `I` (0x49) "Increase speed on ramp" (keypad mode only).
    Increase,
    /// `L` (0x4C) "Reduce speed on ramp" (keypad mode only).
    Reduce,
}

impl MasterCommand {
    /// The command letter (the CMD byte).
    pub const fn letter(self) -> u8 {
        match self {
            MasterCommand::Run => b'R',
            MasterCommand::Stop => b'S',
            MasterCommand::MotorCurrent => b'A',
            MasterCommand::SpeedHz => b'Z',
            MasterCommand::SpeedRpm => b'M',
            MasterCommand::Status => b'T',
            MasterCommand::Version => b'V',
            MasterCommand::SetSpeed(_) => b'P',
            MasterCommand::Increase => b'I',
            MasterCommand::Reduce => b'L',
        }
    }

    /// The manual's name for the command.
    pub const fn name(self) -> &'static str {
        match self {
            MasterCommand::Run => "run command",
            MasterCommand::Stop => "stop command",
            MasterCommand::MotorCurrent => "motor current request",
            MasterCommand::SpeedHz => "speed request in Hz",
            MasterCommand::SpeedRpm => "speed request in RPM",
            MasterCommand::Status => "drive status request",
            MasterCommand::Version => "software version request",
            MasterCommand::SetSpeed(_) => "set new speed in Hz",
            MasterCommand::Increase => "increase speed on ramp",
            MasterCommand::Reduce => "reduce speed on ramp",
        }
    }

    /// The letter of the reply that carries it out: the lower case of the command.
    ///
    /// seed 000: "All responses to valid commands will be the lower case equivalent to the
    /// command received."
    pub const fn reply_letter(self) -> u8 {
        self.letter() | 0x20
    }

    /// The DATA word, for `P`.
    const fn data(self) -> Data {
        match self {
            MasterCommand::SetSpeed(s) => Data::Word(s.raw()),
            _ => Data::None,
        }
    }

    /// Reads the command `cmd` and its DATA digits (hex already checked).
    fn read(cmd: u8, data: &[u8]) -> Result<MasterCommand, FrameError> {
        let (command, what) = match cmd {
            b'R' => (MasterCommand::Run, "the DATA of R (run command)"),
            b'S' => (MasterCommand::Stop, "the DATA of S (stop command)"),
            b'A' => (MasterCommand::MotorCurrent, "the DATA of A (motor current request)"),
            b'Z' => (MasterCommand::SpeedHz, "the DATA of Z (speed request in Hz)"),
            b'M' => (MasterCommand::SpeedRpm, "the DATA of M (speed request in RPM)"),
            b'T' => (MasterCommand::Status, "the DATA of T (drive status request)"),
            b'V' => (MasterCommand::Version, "the DATA of V (software version request)"),
            b'I' => (MasterCommand::Increase, "the DATA of I (increase speed on ramp)"),
            b'L' => (MasterCommand::Reduce, "the DATA of L (reduce speed on ramp)"),
            b'P' => {
                // seed 000: "A word (16-bit) value is always transmitted."
                let w = word(data, "the DATA of P (set new speed in Hz)")?;
                return Ok(MasterCommand::SetSpeed(Speed::from_raw(w)));
            }
            _ => return Err(FrameError::Unknown { field: CMD_FIELD, value: cmd as u32 }),
        };
        data_bytes(data, 0, 0, what)?;
        Ok(command)
    }
}

/// A drive's reply (seed 000: "REPLY = Slave reply"), with its DATA.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SlaveReply {
    /// `r` (0x72) "Run command executed".
    Run,
    /// `s` (0x73) "Stop command executed".
    Stop,
    /// `a` (0x61) "Motor current", one word in 0.1 A.
    MotorCurrent(Current),
    /// `z` (0x7A) "Speed request in Hz", one word of 60 x Hz.
    SpeedHz(Speed),
    /// `m` (0x6D) "Speed request in RPM", one word in rpm.
    SpeedRpm(Rpm),
    /// `t` (0x74) "Drive Status returned", the status word.
    Status(DriveStatus),
    /// `v` (0x76) "Software version returned", one word as BCD.
    Version(Version),
    /// `p` (0x70) "New speed in Hz loaded".
    SetSpeed,
    /// `i` (0x69) "Increase speed actioned".
    Increase,
    /// `l` (0x6C) "Reduce speed actioned" (the seed's OCR prints it as 'I').
    Reduce,
    /// `e` (0x65) "Error – command not executed (error code gives reason why)".
    Error {
        /// Why.
        code: ErrorCode,
        /// True when the code came (or goes) as a 4-digit word `00xx` instead of 2 digits.
        word: bool,
    },
}

impl SlaveReply {
    /// An `e` reply with a one-byte code, as drivebus sends it.
    pub const fn error(code: ErrorCode) -> SlaveReply {
        SlaveReply::Error { code, word: false }
    }

    /// The reply letter (the REPLY byte).
    pub const fn letter(self) -> u8 {
        match self {
            SlaveReply::Run => b'r',
            SlaveReply::Stop => b's',
            SlaveReply::MotorCurrent(_) => b'a',
            SlaveReply::SpeedHz(_) => b'z',
            SlaveReply::SpeedRpm(_) => b'm',
            SlaveReply::Status(_) => b't',
            SlaveReply::Version(_) => b'v',
            SlaveReply::SetSpeed => b'p',
            SlaveReply::Increase => b'i',
            SlaveReply::Reduce => b'l',
            SlaveReply::Error { .. } => ERROR_LETTER,
        }
    }

    /// The manual's name for the reply.
    pub const fn name(self) -> &'static str {
        match self {
            SlaveReply::Run => "run command executed",
            SlaveReply::Stop => "stop command executed",
            SlaveReply::MotorCurrent(_) => "motor current",
            SlaveReply::SpeedHz(_) => "speed in Hz",
            SlaveReply::SpeedRpm(_) => "speed in RPM",
            SlaveReply::Status(_) => "drive status returned",
            SlaveReply::Version(_) => "software version returned",
            SlaveReply::SetSpeed => "new speed in Hz loaded",
            SlaveReply::Increase => "increase speed actioned",
            SlaveReply::Reduce => "reduce speed actioned",
            SlaveReply::Error { .. } => "error: command not executed",
        }
    }

    /// True for the `e` reply.
    pub const fn is_error(self) -> bool {
        matches!(self, SlaveReply::Error { .. })
    }

    const fn data(self) -> Data {
        match self {
            SlaveReply::MotorCurrent(v) => Data::Word(v.raw()),
            SlaveReply::SpeedHz(v) => Data::Word(v.raw()),
            SlaveReply::SpeedRpm(v) => Data::Word(v.raw()),
            SlaveReply::Status(v) => Data::Word(v.raw()),
            SlaveReply::Version(v) => Data::Word(v.raw()),
            SlaveReply::Error { code, word: false } => Data::Byte(code.0),
            SlaveReply::Error { code, word: true } => Data::Word(code.0 as u16),
            _ => Data::None,
        }
    }

    /// Reads the reply `letter` and its DATA digits (hex already checked).
    fn read(letter: u8, data: &[u8]) -> Result<SlaveReply, FrameError> {
        let (reply, what) = match letter {
            b'r' => (SlaveReply::Run, "the DATA of r (run command executed)"),
            b's' => (SlaveReply::Stop, "the DATA of s (stop command executed)"),
            b'p' => (SlaveReply::SetSpeed, "the DATA of p (new speed in Hz loaded)"),
            b'i' => (SlaveReply::Increase, "the DATA of i (increase speed actioned)"),
            b'l' => (SlaveReply::Reduce, "the DATA of l (reduce speed actioned)"),
            b'a' => {
                let w = word(data, "the DATA of a (motor current)")?;
                return Ok(SlaveReply::MotorCurrent(Current::from_raw(w)));
            }
            b'z' => {
                let w = word(data, "the DATA of z (speed in Hz)")?;
                return Ok(SlaveReply::SpeedHz(Speed::from_raw(w)));
            }
            b'm' => {
                let w = word(data, "the DATA of m (speed in RPM)")?;
                return Ok(SlaveReply::SpeedRpm(Rpm::from_raw(w)));
            }
            b't' => {
                let w = word(data, "the DATA of t (drive status returned)")?;
                return Ok(SlaveReply::Status(DriveStatus::from_raw(w)));
            }
            b'v' => {
                let w = word(data, "the DATA of v (software version returned)")?;
                return Ok(SlaveReply::Version(Version::from_raw(w)));
            }
            ERROR_LETTER => {
                // seed 000: "[Start Flag], [Drive Addr], ['e'], [error code], [checksum],
                // [stop flag]": a byte code (0x02..0x9A); a 4-digit word is accepted too.
                let n = data_bytes(data, 1, 2, "the DATA of e (error code)")?;
                let v = number(data);
                if v > 0xFF {
                    return Err(FrameError::OutOfRange { field: "error code", value: v, min: 0, max: 0xFF });
                }
                return Ok(SlaveReply::Error { code: ErrorCode(v as u8), word: n == 2 });
            }
            _ => return Err(FrameError::Unknown { field: REPLY_FIELD, value: letter as u32 }),
        };
        data_bytes(data, 0, 0, what)?;
        Ok(reply)
    }
}

/// A master's packet: DA (one drive + 128, or `G`), CMD and its DATA.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Request {
    /// Whom it addresses.
    pub da: Destination,
    /// What it asks.
    pub cmd: MasterCommand,
}

impl Request {
    /// A request for `cmd` to `da`.
    pub const fn new(da: Destination, cmd: MasterCommand) -> Request {
        Request { da, cmd }
    }

    /// A request for `cmd` to drive `address`.
    pub const fn to_drive(address: Address, cmd: MasterCommand) -> Request {
        Request { da: Destination::Drive(address), cmd }
    }

    /// A global request (DA `G`): every drive acts, none replies.
    pub const fn global(cmd: MasterCommand) -> Request {
        Request { da: Destination::Global, cmd }
    }

    /// Bytes on the wire, flags included.
    pub const fn wire_len(&self) -> usize {
        self.cmd.data().wire_len()
    }

    /// Reads a whole master frame, flags included: framing, hex digits, CS, DA, CMD, DATA.
    pub fn parse(bytes: &[u8]) -> Result<Request, FrameError> {
        let w = split(bytes)?;
        match classify(w.da)? {
            Sender::Master(da) => Ok(Request { da, cmd: MasterCommand::read(w.cmd, w.data)? }),
            Sender::Drive(_) => Err(FrameError::Malformed(
                "a DA of 01-3F is a drive's reply: a master sends the drive number + 128 (81-BF) or G",
            )),
        }
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        emit_frame(self.da.da(), self.cmd.letter(), self.cmd.data(), out)
    }
}

/// A drive's reply packet: DA (its plain number), REPLY and its DATA.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Reply {
    /// The drive that answers (seed 000: "returns its own Drive address").
    pub da: Address,
    /// What it answers.
    pub reply: SlaveReply,
}

impl Reply {
    /// A reply from drive `da`.
    pub const fn new(da: Address, reply: SlaveReply) -> Reply {
        Reply { da, reply }
    }

    /// Bytes on the wire, flags included.
    pub const fn wire_len(&self) -> usize {
        self.reply.data().wire_len()
    }

    /// Reads a whole drive frame, flags included: framing, hex digits, CS, DA, REPLY, DATA.
    pub fn parse(bytes: &[u8]) -> Result<Reply, FrameError> {
        let w = split(bytes)?;
        match classify(w.da)? {
            Sender::Drive(da) => Ok(Reply { da, reply: SlaveReply::read(w.cmd, w.data)? }),
            Sender::Master(_) => Err(FrameError::Malformed(
                "a DA of 81-BF or G is a master's frame: a drive replies with its plain number 01-3F",
            )),
        }
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        emit_frame(self.da.get(), self.reply.letter(), self.reply.data(), out)
    }
}

/// A frame from either side.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Packet {
    /// From the master.
    Request(Request),
    /// From a drive.
    Reply(Reply),
}

impl Packet {
    /// Reads a whole frame; the DA byte tells who sent it (bit 7 set or `G`: the master;
    /// 01–3F: a drive).
    pub fn parse(bytes: &[u8]) -> Result<Packet, FrameError> {
        let w = split(bytes)?;
        Ok(match classify(w.da)? {
            Sender::Master(da) => Packet::Request(Request { da, cmd: MasterCommand::read(w.cmd, w.data)? }),
            Sender::Drive(da) => Packet::Reply(Reply { da, reply: SlaveReply::read(w.cmd, w.data)? }),
        })
    }

    /// Writes the frame into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        match self {
            Packet::Request(r) => r.emit(out),
            Packet::Reply(r) => r.emit(out),
        }
    }
}

/// Who sent a frame, by its DA byte.
pub(crate) enum Sender {
    Master(Destination),
    Drive(Address),
}

/// Reads the DA byte: 81–BF or `G` from the master, 01–3F from a drive.
pub(crate) fn classify(da: u8) -> Result<Sender, FrameError> {
    if let Some(a) = Address::new(da) {
        return Ok(Sender::Drive(a));
    }
    if let Some(d) = Destination::from_da(da) {
        return Ok(Sender::Master(d));
    }
    Err(if da & 0x80 != 0 {
        FrameError::OutOfRange {
            field: "drive address (DA - 128)",
            value: (da - MASTER_OFFSET) as u32,
            min: Address::MIN as u32,
            max: Address::MAX as u32,
        }
    } else if da == 0 {
        FrameError::OutOfRange {
            field: "drive address",
            value: 0,
            min: Address::MIN as u32,
            max: Address::MAX as u32,
        }
    } else {
        FrameError::Unknown { field: "DA", value: da as u32 }
    })
}

/// The fields of a frame whose framing, digits and CS are good.
pub(crate) struct Wire<'a> {
    pub da: u8,
    pub cmd: u8,
    /// The DATA digits (an even number, all hex).
    pub data: &'a [u8],
}

/// Checks the framing of `bytes` (flags, hex digits, digit count, CS) and splits the fields.
pub(crate) fn split(bytes: &[u8]) -> Result<Wire<'_>, FrameError> {
    let (first, digits, last) = match bytes {
        [first, digits @ .., last] => (*first, digits, *last),
        _ => return Err(short(bytes.len())),
    };
    if first != FG1 {
        return Err(FrameError::Malformed("a B800 frame starts with the start flag FG1 7E"));
    }
    if last != FG2 {
        return Err(FrameError::Malformed("a B800 frame ends with the stop flag FG2 7F"));
    }
    // seed 000: "Any non-ASCII byte received other than the START / STOP flags will terminate
    // the data reception" (project decision: any byte that is not a hex digit).
    // One pass for both: any digit's table entry above 0x0F marks a non-hex byte.
    let (mut marks, mut sum) = (0u8, 0u8);
    for &c in digits {
        marks |= HEX[c as usize];
        sum = sum.wrapping_add(c);
    }
    if marks > 0x0F {
        if let Some(i) = digits.iter().position(|&c| HEX[c as usize] > 0x0F) {
            let byte = digits.get(i).copied().unwrap_or(0);
            return Err(FrameError::NonHex { byte, offset: i + 1 });
        }
    }
    verify_summed(digits, sum)?;
    match digits {
        [a0, a1, c0, c1, data @ .., _, _] => Ok(Wire { da: pair(*a0, *a1), cmd: pair(*c0, *c1), data }),
        _ => Err(short(bytes.len())),
    }
}

/// The DA and CMD/REPLY bytes of a frame, from its header only: the flags in place, an even
/// count of at least 6 digits between them, the DA and CMD digits hex. Neither the DATA nor the
/// CS is looked at (the scanner has checked the CS); `None` when the header does not read.
#[inline]
pub(crate) fn header(bytes: &[u8]) -> Option<(u8, u8)> {
    match bytes {
        [FG1, a0, a1, c0, c1, rest @ .., FG2] if rest.len() >= 2 && rest.len() % 2 == 0 => {
            let hex = [a0, a1, c0, c1].iter().all(|&&c| HEX[c as usize] <= 0x0F);
            hex.then(|| (pair(*a0, *a1), pair(*c0, *c1)))
        }
        _ => None,
    }
}

fn short(got: usize) -> FrameError {
    FrameError::Truncated { what: "a B800 frame (FG1 DA CMD CS FG2)", expected: super::MIN_FRAME, got }
}

/// Checks the hex digits between the flags (all already known to be hex): an even count of
/// at least 6 and the CS.
#[inline]
pub(crate) fn verify(digits: &[u8]) -> Result<(), FrameError> {
    verify_summed(digits, crate::checksum::sum8(digits))
}

/// [`verify`] with the 8-bit sum of all of `digits` (CS digits included) already known.
#[inline]
fn verify_summed(digits: &[u8], sum: u8) -> Result<(), FrameError> {
    let n = digits.len();
    if n % 2 != 0 {
        return Err(FrameError::OddDigits { count: n });
    }
    let [body @ .., s0, s1] = digits else {
        return Err(short(n + 2));
    };
    if n < 6 {
        return Err(short(n + 2));
    }
    // seed 000: "the logical NOT of the byte result of the byte addition of all transmitted
    // ASCII bytes excluding the START and STOP flags and the checksum itself", over the
    // characters as received (a lower-case digit counts as its lower-case code).
    let computed = !sum.wrapping_sub(*s0).wrapping_sub(*s1);
    let carried = pair(*s0, *s1);
    if carried != computed {
        return Err(FrameError::ChecksumMismatch {
            kind: ChecksumKind::Cs,
            carried: carried as u16,
            computed: computed as u16,
            hint: hint(body, carried),
        });
    }
    Ok(())
}

/// A master that computed CS over the plain drive number and then sent DA = number + 128.
fn hint(body: &[u8], carried: u8) -> Option<MismatchHint> {
    let [a0, a1, ..] = body else { return None };
    let da = pair(*a0, *a1);
    if da & 0x80 == 0 {
        return None;
    }
    let plain = da - MASTER_OFFSET;
    let [p0, p1] = byte_digits(plain);
    let sum =
        crate::checksum::sum8(body).wrapping_sub(*a0).wrapping_sub(*a1).wrapping_add(p0).wrapping_add(p1);
    (!sum == carried).then_some(MismatchHint::OtherAddress { address: plain })
}

/// Checks that DATA holds `min..=max` bytes; returns how many it holds.
fn data_bytes(data: &[u8], min: usize, max: usize, what: &'static str) -> Result<usize, FrameError> {
    let got = data.len() / 2;
    if got < min {
        return Err(FrameError::Truncated { what, expected: min, got });
    }
    if got > max {
        return Err(FrameError::TooLong { what, max, got });
    }
    Ok(got)
}

/// DATA as exactly one 16-bit word, high byte first.
fn word(data: &[u8], what: &'static str) -> Result<u16, FrameError> {
    data_bytes(data, 2, 2, what)?;
    Ok(number(data) as u16)
}

/// The value of up to 8 hex digits (already checked).
fn number(digits: &[u8]) -> u32 {
    digits.iter().fold(0u32, |acc, &c| acc << 4 | (HEX[c as usize] & 0x0F) as u32)
}

/// The DATA of a frame.
#[derive(Clone, Copy)]
enum Data {
    None,
    Byte(u8),
    Word(u16),
}

impl Data {
    const fn digits(self) -> usize {
        match self {
            Data::None => 0,
            Data::Byte(_) => 2,
            Data::Word(_) => 4,
        }
    }

    /// FG1 + DA + CMD + DATA + CS + FG2.
    const fn wire_len(self) -> usize {
        1 + 2 + 2 + self.digits() + 2 + 1
    }
}

/// Writes `FG1 DA CMD DATA CS FG2`, every field between the flags as upper-case hex digits.
fn emit_frame(da: u8, cmd: u8, data: Data, out: &mut [u8]) -> Result<usize, EmitError> {
    let len = data.wire_len();
    need(out, len)?;
    let out = &mut out[..len];
    out[0] = FG1;
    out[1..3].copy_from_slice(&byte_digits(da));
    out[3..5].copy_from_slice(&byte_digits(cmd));
    match data {
        Data::None => {}
        Data::Byte(b) => out[5..7].copy_from_slice(&byte_digits(b)),
        Data::Word(w) => {
            // seed 000: "The high byte is transmitted first."
            let [hi, lo] = w.to_be_bytes();
            out[5..7].copy_from_slice(&byte_digits(hi));
            out[7..9].copy_from_slice(&byte_digits(lo));
        }
    }
    let body_end = len - 3;
    let cs = not_sum8(&out[1..body_end]);
    out[body_end..len - 1].copy_from_slice(&byte_digits(cs));
    out[len - 1] = FG2;
    Ok(len)
}
