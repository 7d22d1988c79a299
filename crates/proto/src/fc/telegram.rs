//! The FC telegram: `STX LGE ADR <data> BCC`, its three block types, the address byte,
//! and the scanner that finds telegrams in a byte stream.
//!
//! ```text
//! process block    02 06 ADR PCD1 PCD2 BCC                          LGE 6, 8 bytes
//! parameter block  02 0E ADR PKE IND PWEhigh PWElow PCD1 PCD2 BCC   LGE 14, 16 bytes
//! text block       02 LGE ADR PKE IND Ch1..Chn PCD1 PCD2 BCC        LGE 10 + n
//! ```
//!
//! Words are big-endian. LGE counts the bytes after it (data + ADR + BCC), so a telegram is
//! LGE + 2 bytes long. The text block follows seed 003 (`seeds/003_26a4c04ca1af5f26.txt`)
//! Illustration 5.7 "Text Block": PKE IND Ch1 Ch2 .. Chn PCD1 PCD2; the FC 300 / VLT 5000
//! text example (`02 11 01 F0 01 00 01 45 4E 47 4C 49 53 48 ..`, LGE 0x11 = 10 + 7) puts the
//! characters right after IND, and its LGE leaves room for exactly PCD1 and PCD2 after them.
//! A text of exactly 4 characters has LGE 14 and is a parameter block on the wire (the
//! characters sit in PWE); it parses back as [`Block::Parameter`].

use crate::checksum::xor8;
use crate::deframe::{Scan, Scanner};
use crate::describe::Target;
use crate::error::{need, ChecksumKind, EmitError, FrameError};

use super::parameter::{ParameterCommand, ParameterNumber, ParameterResponse, IND_WRITE_TEXT};
use super::words::{ControlWord, Reference, StatusWord};
use super::FaultCode;

/// STX, the first byte of every telegram.
pub const STX: u8 = 0x02;
/// LGE of a process block.
pub const LGE_PROCESS: u8 = 6;
/// LGE of a parameter block.
pub const LGE_PARAMETER: u8 = 14;
/// The most text characters drivebus accepts in a text block (the manuals give no limit;
/// parameter names and texts are far shorter).
pub const MAX_TEXT: usize = 100;
/// The largest LGE accepted: a text block with [`MAX_TEXT`] characters.
pub const MAX_LGE: u8 = 10 + MAX_TEXT as u8;
/// The longest telegram, in bytes.
pub const MAX_TELEGRAM: usize = MAX_LGE as usize + 2;

/// The exact message for each impossible LGE below 10.
const SHORT_LGE: [&str; 10] = [
    "LGE 0x00 is not a telegram length (6 process, 14 parameter, 10+n text)",
    "LGE 0x01 is not a telegram length (6 process, 14 parameter, 10+n text)",
    "LGE 0x02 is not a telegram length (6 process, 14 parameter, 10+n text)",
    "LGE 0x03 is not a telegram length (6 process, 14 parameter, 10+n text)",
    "LGE 0x04 is not a telegram length (6 process, 14 parameter, 10+n text)",
    "LGE 0x05 is not a telegram length (6 process, 14 parameter, 10+n text)",
    "LGE 0x06 is a telegram length",
    "LGE 0x07 is not a telegram length (6 process, 14 parameter, 10+n text)",
    "LGE 0x08 is not a telegram length (6 process, 14 parameter, 10+n text)",
    "LGE 0x09 is not a telegram length (6 process, 14 parameter, 10+n text)",
];

/// Checks LGE: 6 (process), 14 (parameter) or 10 + n (text, n up to [`MAX_TEXT`]).
#[inline]
pub fn check_lge(lge: u8) -> Result<(), FrameError> {
    match lge {
        LGE_PROCESS | 10..=MAX_LGE => Ok(()),
        0..=9 => Err(FrameError::Malformed(SHORT_LGE[lge as usize])),
        _ => Err(FrameError::OutOfRange {
            field: "text telegram LGE (10 + at most 100 characters)",
            value: lge as u32,
            min: 10,
            max: MAX_LGE as u32,
        }),
    }
}

/// How ADR is coded (seed 003 5.4.4 and protocols.md 2.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum AddressFormat {
    /// Bit 7 = 1, bits 0–6 = address 1–126, 0 = broadcast (ADR `80`). Example: address 1 is `81`.
    #[default]
    OneTo126,
    /// Bit 7 = 0, bit 5 = 1 = broadcast, bits 0–4 = address 1–31 (bit 6 unused).
    /// Example: address 22 is `16`.
    OneTo31,
}

impl AddressFormat {
    /// "address format 1–126" or "address format 1–31".
    pub const fn name(self) -> &'static str {
        match self {
            AddressFormat::OneTo126 => "address format 1–126",
            AddressFormat::OneTo31 => "address format 1–31",
        }
    }
    /// The highest address of the format.
    pub const fn max_address(self) -> u8 {
        match self {
            AddressFormat::OneTo126 => 126,
            AddressFormat::OneTo31 => 31,
        }
    }
}

/// The address byte ADR, as on the wire; always a valid address or broadcast.
///
/// seed 003: "The slave returns the address byte unchanged to the master in the response
/// telegram." So a reply carries the request's ADR byte, format and unused bits included.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Adr(u8);

impl Adr {
    /// Broadcast in address format 1–126: "Bit 0–6 = 0 broadcast."
    pub const BROADCAST: Adr = Adr(0x80);
    /// Broadcast in address format 1–31 (bit 5 = 1).
    pub const BROADCAST_31: Adr = Adr(0x20);

    /// The ADR of drive `address` in `format` (1–126 or 1–31).
    pub fn new(address: u8, format: AddressFormat) -> Result<Adr, EmitError> {
        let max = format.max_address();
        if address == 0 || address > max {
            return Err(EmitError::OutOfRange {
                field: "FC address",
                value: address as u32,
                min: 1,
                max: max as u32,
            });
        }
        Ok(Adr(match format {
            AddressFormat::OneTo126 => 0x80 | address,
            AddressFormat::OneTo31 => address,
        }))
    }

    /// The broadcast ADR of `format`.
    pub const fn broadcast(format: AddressFormat) -> Adr {
        match format {
            AddressFormat::OneTo126 => Adr::BROADCAST,
            AddressFormat::OneTo31 => Adr::BROADCAST_31,
        }
    }

    /// Reads an ADR byte from the wire. Address 0 (format 1–31, bit 5 = 0) and 127
    /// (format 1–126) are neither a drive nor broadcast, and are refused.
    ///
    /// seed 003 5.4.4: "Bit 7 = 1 (address format 1–126 active). Bit 0–6 = frequency
    /// converter address 1–126. Bit 0–6 = 0 broadcast."
    pub const fn from_byte(byte: u8) -> Result<Adr, FrameError> {
        let adr = Adr(byte);
        if !adr.is_broadcast() {
            let a = match adr.format() {
                AddressFormat::OneTo126 => byte & 0x7F,
                AddressFormat::OneTo31 => byte & 0x1F,
            };
            if a == 0 || a == 127 {
                return Err(FrameError::OutOfRange {
                    field: match adr.format() {
                        AddressFormat::OneTo126 => "ADR address (format 1–126)",
                        AddressFormat::OneTo31 => "ADR address (format 1–31)",
                    },
                    value: a as u32,
                    min: 1,
                    max: adr.format().max_address() as u32,
                });
            }
        }
        Ok(adr)
    }

    /// The byte on the wire.
    pub const fn byte(self) -> u8 {
        self.0
    }

    /// The address format (bit 7).
    pub const fn format(self) -> AddressFormat {
        if self.0 & 0x80 != 0 {
            AddressFormat::OneTo126
        } else {
            AddressFormat::OneTo31
        }
    }

    /// True for a broadcast: ADR `80`, or bit 5 in format 1–31 ("bits 0–4 are then ignored").
    pub const fn is_broadcast(self) -> bool {
        match self.format() {
            AddressFormat::OneTo126 => self.0 & 0x7F == 0,
            AddressFormat::OneTo31 => self.0 & 0x20 != 0,
        }
    }

    /// The drive's address (1–126 or 1–31), `None` for a broadcast.
    pub const fn address(self) -> Option<u8> {
        if self.is_broadcast() {
            return None;
        }
        Some(match self.format() {
            AddressFormat::OneTo126 => self.0 & 0x7F,
            AddressFormat::OneTo31 => self.0 & 0x1F,
        })
    }

    /// The user-facing target: the address number, or broadcast.
    pub const fn target(self) -> Target {
        match self.address() {
            Some(a) => Target::Unit(a),
            None => Target::Broadcast,
        }
    }

    /// What the byte says, for a decoder.
    pub const fn meaning(self) -> &'static str {
        match (self.format(), self.is_broadcast()) {
            (AddressFormat::OneTo126, false) => "address format 1–126",
            (AddressFormat::OneTo31, false) => "address format 1–31",
            (AddressFormat::OneTo126, true) => "broadcast, address format 1–126",
            (AddressFormat::OneTo31, true) => "broadcast, address format 1–31",
        }
    }
}

/// A parameter block's parameter channel: PKE (AK and PNU), IND and PWE.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ParameterBlock<A> {
    /// AK, PKE bits 15–12: the command (master) or response (drive).
    pub ak: A,
    /// PNU, PKE bits 11–0.
    pub pnu: ParameterNumber,
    /// IND: the array index in the low byte, the description element number (AK 4/3),
    /// or 04xx read / 05xx write text (AK F).
    pub ind: u16,
    /// PWE, 32 bits: PWEhigh then PWElow. A word parameter uses PWElow.
    pub pwe: u32,
}

impl<A> ParameterBlock<A> {
    /// PWEhigh.
    pub const fn pwe_high(&self) -> u16 {
        (self.pwe >> 16) as u16
    }
    /// PWElow.
    pub const fn pwe_low(&self) -> u16 {
        self.pwe as u16
    }
    /// The four PWE bytes as on the wire (a 4-character text).
    pub const fn pwe_bytes(&self) -> [u8; 4] {
        self.pwe.to_be_bytes()
    }
}

/// A text block's parameter channel: PKE, IND and the characters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TextBlock<'a, A> {
    /// AK, PKE bits 15–12.
    pub ak: A,
    /// PNU, PKE bits 11–0.
    pub pnu: ParameterNumber,
    /// IND (04xx read text, 05xx write text, or a description element number).
    pub ind: u16,
    /// Ch1..Chn.
    pub text: &'a [u8],
}

/// The three telegram types of seed 003 5.4.6; each also carries PCD1 and PCD2.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Block<'a, A> {
    /// "Process block (PCD)": PCD1 and PCD2 only (LGE 6).
    Process,
    /// "Parameter block": PKE IND PWEhigh PWElow, then PCD1 PCD2 (LGE 14).
    Parameter(ParameterBlock<A>),
    /// "Text block": PKE IND Ch1..Chn, then PCD1 PCD2 (LGE 10 + n).
    Text(TextBlock<'a, A>),
}

impl<A: Copy> Block<'_, A> {
    /// AK, PNU and IND, unless this is a process block.
    pub fn header(&self) -> Option<(A, ParameterNumber, u16)> {
        match *self {
            Block::Process => None,
            Block::Parameter(p) => Some((p.ak, p.pnu, p.ind)),
            Block::Text(t) => Some((t.ak, t.pnu, t.ind)),
        }
    }
    /// LGE for this block (6, 14 or 10 + n).
    pub fn lge(&self) -> usize {
        match self {
            Block::Process => LGE_PROCESS as usize,
            Block::Parameter(_) => LGE_PARAMETER as usize,
            Block::Text(t) => 10 + t.text.len(),
        }
    }
}

/// A telegram read without deciding who sent it: AK still a number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawTelegram<'a> {
    /// ADR.
    pub adr: Adr,
    /// The block with AK as a number 0–15.
    pub block: Block<'a, u8>,
    /// PCD1 (CTW from the master, STW from the drive).
    pub pcd1: u16,
    /// PCD2 (reference from the master, MAV from the drive).
    pub pcd2: u16,
    /// BCC as carried (checked).
    pub bcc: u8,
}

#[inline]
fn be16(b: [u8; 2]) -> u16 {
    u16::from_be_bytes(b)
}

#[inline]
fn split_pke(pke: u16) -> (u8, ParameterNumber) {
    let pnu = ParameterNumber::new(pke & ParameterNumber::MAX).unwrap_or_default();
    ((pke >> 12) as u8, pnu)
}

impl<'a> RawTelegram<'a> {
    /// Reads one whole telegram: STX, LGE, length, BCC, ADR and the block.
    pub fn parse(bytes: &'a [u8]) -> Result<RawTelegram<'a>, FrameError> {
        let (stx, lge) = match bytes {
            [stx, lge, ..] => (*stx, *lge),
            _ => return Err(FrameError::Truncated { what: "an FC telegram", expected: 8, got: bytes.len() }),
        };
        if stx != STX {
            return Err(FrameError::Unknown { field: "start byte (STX is 02)", value: stx as u32 });
        }
        check_lge(lge)?;
        let total = lge as usize + 2;
        if bytes.len() < total {
            return Err(FrameError::Truncated {
                what: "the telegram its LGE announces",
                expected: total,
                got: bytes.len(),
            });
        }
        if bytes.len() > total {
            return Err(FrameError::Inconsistent {
                field: "LGE",
                value: lge as u32,
                expected: bytes.len() as u32 - 2,
            });
        }
        let Some((&bcc, covered)) = bytes.split_last() else {
            return Err(FrameError::Malformed("empty telegram"));
        };
        // seed 003 5.4.5: "The checksum is calculated as an XOR-function. Before the first
        // byte in the telegram is received, the calculated checksum is 0."
        let computed = xor8(covered);
        if computed != bcc {
            return Err(bcc_mismatch(bcc, computed));
        }
        let [_, _, adr, data @ ..] = covered else {
            return Err(FrameError::Malformed("telegram without ADR"));
        };
        let adr = Adr::from_byte(*adr)?;
        let Some((head, &[c0, c1, r0, r1])) = data.split_last_chunk::<4>() else {
            return Err(FrameError::Malformed("telegram without PCD1 and PCD2"));
        };
        let block = match (lge, head) {
            (LGE_PROCESS, []) => Block::Process,
            (LGE_PARAMETER, &[k0, k1, i0, i1, w0, w1, w2, w3]) => {
                let (ak, pnu) = split_pke(be16([k0, k1]));
                Block::Parameter(ParameterBlock {
                    ak,
                    pnu,
                    ind: be16([i0, i1]),
                    pwe: u32::from_be_bytes([w0, w1, w2, w3]),
                })
            }
            (_, &[k0, k1, i0, i1, ref text @ ..]) => {
                let (ak, pnu) = split_pke(be16([k0, k1]));
                Block::Text(TextBlock { ak, pnu, ind: be16([i0, i1]), text })
            }
            _ => return Err(FrameError::Malformed("telegram data does not fit its LGE")),
        };
        Ok(RawTelegram { adr, block, pcd1: be16([c0, c1]), pcd2: be16([r0, r1]), bcc })
    }

    /// AK, unless this is a process block.
    pub fn ak(&self) -> Option<u8> {
        self.block.header().map(|(ak, _, _)| ak)
    }
}

/// ADR and, unless this is a process block, AK and PNU of a reply telegram, from its header
/// only: STX, LGE (against the telegram's length), ADR and PKE. IND, PWE, the text, PCD1 and
/// PCD2 are not read and BCC is not checked (the scanner has); `None` when the header does not
/// read (or its AK is not in the drive's table).
#[inline]
pub fn reply_header(bytes: &[u8]) -> Option<(Adr, Option<(ParameterResponse, ParameterNumber)>)> {
    let (&[stx, lge, adr], rest) = bytes.split_first_chunk::<3>()?;
    if stx != STX || check_lge(lge).is_err() || bytes.len() != lge as usize + 2 {
        return None;
    }
    let adr = Adr::from_byte(adr).ok()?;
    if lge == LGE_PROCESS {
        return Some((adr, None));
    }
    let &[k0, k1, ..] = rest else { return None };
    let (ak, pnu) = split_pke(be16([k0, k1]));
    Some((adr, Some((ParameterResponse::from_ak(ak)?, pnu))))
}

/// The BCC mismatch error.
pub(crate) const fn bcc_mismatch(carried: u8, computed: u8) -> FrameError {
    FrameError::ChecksumMismatch {
        kind: ChecksumKind::Bcc,
        carried: carried as u16,
        computed: computed as u16,
        hint: None,
    }
}

/// Writes a telegram; returns its length.
fn emit_telegram<A: Copy>(
    adr: Adr,
    block: &Block<'_, A>,
    ak: impl Fn(A) -> u8,
    pcd1: u16,
    pcd2: u16,
    out: &mut [u8],
) -> Result<usize, EmitError> {
    if let Block::Text(t) = block {
        if t.text.len() > MAX_TEXT {
            return Err(EmitError::OutOfRange {
                field: "text length",
                value: t.text.len().min(u32::MAX as usize) as u32,
                min: 0,
                max: MAX_TEXT as u32,
            });
        }
    }
    let lge = block.lge();
    let total = lge + 2;
    need(out, total)?;
    let out = &mut out[..total];
    out[0] = STX;
    out[1] = lge as u8;
    out[2] = adr.byte();
    let mut at = 3;
    let mut put = |bytes: &[u8]| {
        out[at..at + bytes.len()].copy_from_slice(bytes);
        at += bytes.len();
    };
    match *block {
        Block::Process => {}
        Block::Parameter(p) => {
            put(&(u16::from(ak(p.ak) & 0xF) << 12 | p.pnu.pnu()).to_be_bytes());
            put(&p.ind.to_be_bytes());
            put(&p.pwe.to_be_bytes());
        }
        Block::Text(t) => {
            put(&(u16::from(ak(t.ak) & 0xF) << 12 | t.pnu.pnu()).to_be_bytes());
            put(&t.ind.to_be_bytes());
            put(t.text);
        }
    }
    put(&pcd1.to_be_bytes());
    put(&pcd2.to_be_bytes());
    out[total - 1] = xor8(&out[..total - 1]);
    Ok(total)
}

/// A telegram from the master: ADR, the block with a [`ParameterCommand`], CTW and reference.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Request<'a> {
    /// ADR: the drive addressed, or broadcast.
    pub adr: Adr,
    /// Process, parameter or text block.
    pub block: Block<'a, ParameterCommand>,
    /// PCD1: the control word (CTW).
    pub ctw: ControlWord,
    /// PCD2: the bus reference (MRV).
    pub reference: Reference,
}

impl<'a> Request<'a> {
    /// A process block: control word and reference.
    pub const fn process(adr: Adr, ctw: ControlWord, reference: Reference) -> Self {
        Request { adr, block: Block::Process, ctw, reference }
    }

    /// A parameter block with PCD1 = 0000 (bit 10 = 0: the drive ignores the control word)
    /// and PCD2 = 0; set them with [`with_process`](Self::with_process).
    pub const fn parameter(adr: Adr, ak: ParameterCommand, pnu: ParameterNumber, ind: u16, pwe: u32) -> Self {
        Request {
            adr,
            block: Block::Parameter(ParameterBlock { ak, pnu, ind, pwe }),
            ctw: ControlWord(0),
            reference: Reference(0),
        }
    }

    /// AK 1: read parameter `pnu`, array index `index`.
    pub const fn read(adr: Adr, pnu: ParameterNumber, index: u8) -> Self {
        Self::parameter(adr, ParameterCommand::ReadValue, pnu, index as u16, 0)
    }

    /// AK 2 (RAM) or E (RAM and EEPROM): write a word parameter (value in PWElow).
    pub const fn write_word(adr: Adr, pnu: ParameterNumber, index: u8, value: u16, eeprom: bool) -> Self {
        let ak = if eeprom { ParameterCommand::WriteRamEepromWord } else { ParameterCommand::WriteRamWord };
        Self::parameter(adr, ak, pnu, index as u16, value as u32)
    }

    /// AK 3 (RAM) or D (RAM and EEPROM): write a double-word parameter.
    pub const fn write_double_word(
        adr: Adr,
        pnu: ParameterNumber,
        index: u8,
        value: u32,
        eeprom: bool,
    ) -> Self {
        let ak = if eeprom {
            ParameterCommand::WriteRamEepromDoubleWord
        } else {
            ParameterCommand::WriteRamDoubleWord
        };
        Self::parameter(adr, ak, pnu, index as u16, value)
    }

    /// AK 4: read description element `element` (IND; see `description_element`).
    pub const fn read_description(adr: Adr, pnu: ParameterNumber, element: u16) -> Self {
        Self::parameter(adr, ParameterCommand::ReadDescription, pnu, element, 0)
    }

    /// AK F in a parameter block with PWE 0: read a text. `ind` as the drive expects it
    /// (04xx in the newer guides; the FC 300 / VLT 5000 example reads text `value + 1` with IND 0001).
    pub const fn read_text(adr: Adr, pnu: ParameterNumber, ind: u16) -> Self {
        Self::parameter(adr, ParameterCommand::Text, pnu, ind, 0)
    }

    /// AK F in a text block: write `text` at array index `index` (IND 05xx).
    pub const fn write_text(adr: Adr, pnu: ParameterNumber, index: u8, text: &'a [u8]) -> Self {
        Request {
            adr,
            block: Block::Text(TextBlock {
                ak: ParameterCommand::Text,
                pnu,
                ind: (IND_WRITE_TEXT as u16) << 8 | index as u16,
                text,
            }),
            ctw: ControlWord(0),
            reference: Reference(0),
        }
    }

    /// The same request with PCD1 = `ctw` and PCD2 = `reference`.
    pub const fn with_process(mut self, ctw: ControlWord, reference: Reference) -> Self {
        self.ctw = ctw;
        self.reference = reference;
        self
    }

    /// Reads a telegram as sent by the master (AK from the master table).
    pub fn parse(bytes: &'a [u8]) -> Result<Self, FrameError> {
        Self::from_raw(RawTelegram::parse(bytes)?)
    }

    /// Types a raw telegram as a request.
    pub fn from_raw(raw: RawTelegram<'a>) -> Result<Self, FrameError> {
        Ok(Request {
            adr: raw.adr,
            block: type_block(raw.block, ParameterCommand::from_ak, "AK (parameter command)")?,
            ctw: ControlWord(raw.pcd1),
            reference: Reference::from_word(raw.pcd2),
        })
    }

    /// Writes the telegram into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        emit_telegram(self.adr, &self.block, ParameterCommand::ak, self.ctw.0, self.reference.word(), out)
    }

    /// The parameter command, unless this is a process block.
    pub fn command(&self) -> Option<ParameterCommand> {
        self.block.header().map(|(ak, _, _)| ak)
    }
}

/// A telegram from a drive: ADR (echoed), the block with a [`ParameterResponse`], STW and MAV.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reply<'a> {
    /// ADR, the request's byte returned unchanged.
    pub adr: Adr,
    /// Process, parameter or text block.
    pub block: Block<'a, ParameterResponse>,
    /// PCD1: the status word (STW).
    pub stw: StatusWord,
    /// PCD2: the main actual value (MAV), the output frequency scaled like the reference.
    pub mav: Reference,
}

impl<'a> Reply<'a> {
    /// A process block: status word and MAV.
    pub const fn process(adr: Adr, stw: StatusWord, mav: Reference) -> Self {
        Reply { adr, block: Block::Process, stw, mav }
    }

    /// A parameter block with STW and MAV 0; set them with [`with_process`](Self::with_process).
    pub const fn parameter(
        adr: Adr,
        ak: ParameterResponse,
        pnu: ParameterNumber,
        ind: u16,
        pwe: u32,
    ) -> Self {
        Reply {
            adr,
            block: Block::Parameter(ParameterBlock { ak, pnu, ind, pwe }),
            stw: StatusWord(0),
            mav: Reference(0),
        }
    }

    /// AK 1: a word value (in PWElow).
    pub const fn value_word(adr: Adr, pnu: ParameterNumber, ind: u16, value: u16) -> Self {
        Self::parameter(adr, ParameterResponse::ValueWord, pnu, ind, value as u32)
    }

    /// AK 2: a double-word value.
    pub const fn value_double_word(adr: Adr, pnu: ParameterNumber, ind: u16, value: u32) -> Self {
        Self::parameter(adr, ParameterResponse::ValueDoubleWord, pnu, ind, value)
    }

    /// AK 7 "command cannot be performed" with `fault` in PWElow.
    pub const fn fault(adr: Adr, pnu: ParameterNumber, ind: u16, fault: FaultCode) -> Self {
        Self::parameter(adr, ParameterResponse::CannotPerform, pnu, ind, fault.0 as u32)
    }

    /// AK 3: description element `element` with a numeric value.
    pub const fn description(adr: Adr, pnu: ParameterNumber, element: u16, value: u32) -> Self {
        Self::parameter(adr, ParameterResponse::Description, pnu, element, value)
    }

    /// A text block (AK F "text transferred", or AK 3 for the name element).
    pub const fn text(
        adr: Adr,
        ak: ParameterResponse,
        pnu: ParameterNumber,
        ind: u16,
        text: &'a [u8],
    ) -> Self {
        Reply {
            adr,
            block: Block::Text(TextBlock { ak, pnu, ind, text }),
            stw: StatusWord(0),
            mav: Reference(0),
        }
    }

    /// The same reply with PCD1 = `stw` and PCD2 = `mav`.
    pub const fn with_process(mut self, stw: StatusWord, mav: Reference) -> Self {
        self.stw = stw;
        self.mav = mav;
        self
    }

    /// Reads a telegram as sent by a drive (AK from the response table).
    pub fn parse(bytes: &'a [u8]) -> Result<Self, FrameError> {
        Self::from_raw(RawTelegram::parse(bytes)?)
    }

    /// Types a raw telegram as a reply.
    pub fn from_raw(raw: RawTelegram<'a>) -> Result<Self, FrameError> {
        Ok(Reply {
            adr: raw.adr,
            block: type_block(raw.block, ParameterResponse::from_ak, "AK (response)")?,
            stw: StatusWord(raw.pcd1),
            mav: Reference::from_word(raw.pcd2),
        })
    }

    /// Writes the telegram into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        emit_telegram(self.adr, &self.block, ParameterResponse::ak, self.stw.0, self.mav.word(), out)
    }

    /// The response, unless this is a process block.
    pub fn response(&self) -> Option<ParameterResponse> {
        self.block.header().map(|(ak, _, _)| ak)
    }

    /// The value of an AK 1 or AK 2 reply (a master accepts either for any parameter).
    pub fn value(&self) -> Option<u32> {
        match self.block {
            Block::Parameter(p)
                if matches!(p.ak, ParameterResponse::ValueWord | ParameterResponse::ValueDoubleWord) =>
            {
                Some(p.pwe)
            }
            _ => None,
        }
    }

    /// The fault code of an AK 7 reply.
    pub fn fault_code(&self) -> Option<FaultCode> {
        match self.block {
            Block::Parameter(p) if p.ak == ParameterResponse::CannotPerform => Some(FaultCode(p.pwe_low())),
            _ => None,
        }
    }

    /// The characters of a text block.
    pub fn text_chars(&self) -> Option<&'a [u8]> {
        match self.block {
            Block::Text(t) => Some(t.text),
            _ => None,
        }
    }
}

fn type_block<'a, A>(
    block: Block<'a, u8>,
    table: fn(u8) -> Option<A>,
    field: &'static str,
) -> Result<Block<'a, A>, FrameError> {
    let ak = |ak: u8| table(ak).ok_or(FrameError::Unknown { field, value: ak as u32 });
    Ok(match block {
        Block::Process => Block::Process,
        Block::Parameter(p) => {
            Block::Parameter(ParameterBlock { ak: ak(p.ak)?, pnu: p.pnu, ind: p.ind, pwe: p.pwe })
        }
        Block::Text(t) => Block::Text(TextBlock { ak: ak(t.ak)?, pnu: t.pnu, ind: t.ind, text: t.text }),
    })
}

/// Finds FC telegrams in a byte stream (either direction: the framing is the same).
///
/// STX 02 starts a candidate; LGE must be 6, 14 or 10 + n (n up to [`MAX_TEXT`]); the BCC is
/// checked. A failed candidate is skipped one byte at a time, so a telegram that starts
/// inside it is still found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FcScanner;

impl Scanner for FcScanner {
    type Buffer = [u8; MAX_TELEGRAM];

    #[inline]
    fn scan(&self, buf: &[u8], _checked: usize) -> Scan {
        match buf {
            [] => Scan::Incomplete { checked: 0 },
            [STX] => Scan::Incomplete { checked: 0 },
            [STX, lge, ..] => {
                let lge = *lge;
                if let Err(error) = check_lge(lge) {
                    return Scan::Invalid { len: 2, skip: 1, error };
                }
                let total = lge as usize + 2;
                let Some((&bcc, covered)) = buf.get(..total).and_then(|f| f.split_last()) else {
                    return Scan::Incomplete { checked: 0 };
                };
                let computed = xor8(covered);
                if computed != bcc {
                    return Scan::Invalid { len: total, skip: 1, error: bcc_mismatch(bcc, computed) };
                }
                Scan::Frame { len: total }
            }
            _ => Scan::Noise { len: buf.iter().position(|&b| b == STX).unwrap_or(buf.len()).max(1) },
        }
    }

    /// protocols.md 2.9: "The gap between characters inside a telegram must not exceed
    /// 2 characters", so silence ends a telegram in progress: it was cut short. Skip 1, so
    /// a telegram that starts inside it (behind a corrupted LGE) is still found.
    fn silence(&self, buf: &[u8]) -> Scan {
        Scan::Invalid { len: buf.len(), skip: 1, error: self.truncated(buf) }
    }

    fn truncated(&self, buf: &[u8]) -> FrameError {
        match buf {
            [STX, lge, ..] if check_lge(*lge).is_ok() => FrameError::Truncated {
                what: "the telegram its LGE announces",
                expected: *lge as usize + 2,
                got: buf.len(),
            },
            _ => FrameError::Truncated { what: "an FC telegram", expected: 8, got: buf.len() },
        }
    }
}
