//! The codec's frame: a request or a reply, with the [`Describe`] view for tools.

use crate::codec::Codec;
use crate::describe::{CodeStyle, Command, Describe, Direction, Field, Target};
use crate::error::FrameError;

use super::parameter::{
    data_type, description_element, ParameterCommand, ParameterResponse, IND_READ_TEXT, IND_WRITE_TEXT,
};
use super::telegram::{Adr, Block, FcScanner, RawTelegram, Reply, Request};
use super::words::{ControlWord, Reference, StatusWord};
use super::FaultCode;

/// A decoded FC telegram from either side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Message<'a> {
    /// From the master.
    Request(Request<'a>),
    /// From a drive.
    Reply(Reply<'a>),
}

/// One telegram as `drivebus decode` shows it: the typed message and its BCC.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame<'a> {
    /// The request or reply.
    pub message: Message<'a>,
    /// BCC as carried (checked).
    pub bcc: u8,
}

/// Who sent `raw`: AK 7 only comes from a drive, AK 4, D and E only from the master; ADR is
/// echoed, so it tells nothing. Otherwise `from`; without it, what the block carries: AK 1
/// with a value in PWE is a drive's "value transferred" (a read request carries none), AK F
/// with text after IND 04xx is a drive's "text transferred" (a read-text request carries
/// none). Else the master.
pub fn infer_direction(raw: &RawTelegram<'_>, from: Option<Direction>) -> Direction {
    match (raw.ak(), from, &raw.block) {
        (Some(0x7), _, _) => Direction::Drive,
        (Some(0x4 | 0xD | 0xE), _, _) => Direction::Master,
        (_, Some(from), _) => from,
        (Some(0x1), None, Block::Parameter(p)) if p.pwe != 0 => Direction::Drive,
        (Some(0xF), None, Block::Text(t)) if t.ind >> 8 == 0x04 && !t.text.is_empty() => Direction::Drive,
        _ => Direction::Master,
    }
}

impl<'a> Frame<'a> {
    /// Reads a telegram; the direction is inferred from AK where it can be
    /// ([`infer_direction`]), else taken from `from`.
    pub fn parse(bytes: &'a [u8], from: Option<Direction>) -> Result<Frame<'a>, FrameError> {
        let raw = RawTelegram::parse(bytes)?;
        let bcc = raw.bcc;
        let message = match infer_direction(&raw, from) {
            Direction::Master => Message::Request(Request::from_raw(raw)?),
            Direction::Drive => Message::Reply(Reply::from_raw(raw)?),
        };
        Ok(Frame { message, bcc })
    }

    /// ADR.
    pub fn adr(&self) -> Adr {
        match self.message {
            Message::Request(r) => r.adr,
            Message::Reply(r) => r.adr,
        }
    }
}

/// The Danfoss FC protocol as a [`Codec`]: `danfoss-fc`.
#[derive(Clone, Copy, Debug, Default)]
pub struct DanfossFc;

impl Codec for DanfossFc {
    const NAME: &'static str = "danfoss-fc";
    type Scanner = FcScanner;
    type Frame<'a> = Frame<'a>;

    fn scanner(_from: Option<Direction>) -> FcScanner {
        FcScanner
    }

    fn parse(bytes: &[u8], from: Option<Direction>) -> Result<Frame<'_>, FrameError> {
        Frame::parse(bytes, from)
    }
}

const CTW_BITS: [&str; 16] = [
    "CTW bit 00",
    "CTW bit 01",
    "CTW bit 02",
    "CTW bit 03",
    "CTW bit 04",
    "CTW bit 05",
    "CTW bit 06",
    "CTW bit 07",
    "CTW bit 08",
    "CTW bit 09",
    "CTW bit 10",
    "CTW bit 11",
    "CTW bit 12",
    "CTW bit 13",
    "CTW bit 14",
    "CTW bit 15",
];

const STW_BITS: [&str; 16] = [
    "STW bit 00",
    "STW bit 01",
    "STW bit 02",
    "STW bit 03",
    "STW bit 04",
    "STW bit 05",
    "STW bit 06",
    "STW bit 07",
    "STW bit 08",
    "STW bit 09",
    "STW bit 10",
    "STW bit 11",
    "STW bit 12",
    "STW bit 13",
    "STW bit 14",
    "STW bit 15",
];

fn block_meaning<A>(block: &Block<'_, A>) -> &'static str {
    match block {
        Block::Process => "process block",
        Block::Parameter(_) => "parameter block",
        Block::Text(_) => "text block (10 + n characters)",
    }
}

/// PKE, AK, PNU (with the `g-nn` form) and IND.
fn header_fields(
    pke_ak: u8,
    ak_name: &'static str,
    pnu: super::ParameterNumber,
    ind: u16,
    ind_meaning: Option<&'static str>,
    out: &mut dyn FnMut(Field<'_>),
) {
    out(Field::hex("PKE", u32::from(pke_ak) << 12 | u32::from(pnu.pnu()), 4));
    out(Field::hex("AK", u32::from(pke_ak), 1).with_meaning(ak_name));
    out(Field::dec("PNU", i64::from(pnu.pnu())));
    let mut buf = [0u8; 5];
    let n = pnu.write_ascii(&mut buf);
    out(Field::text("parameter", &buf[..n]));
    let ind_field = Field::hex("IND", u32::from(ind), 4);
    out(match ind_meaning {
        Some(m) => ind_field.with_meaning(m),
        None => ind_field,
    });
}

/// The LGE and ADR fields of a telegram with `block`.
/// The code and name of an AK, and what IND means with it.
type AkHeader<A> = fn(A, u16) -> (u8, &'static str, Option<&'static str>);

/// LGE, ADR, and the PKE and IND (and the text) of a parameter or text block, the same in a
/// request and a reply but for what `header` says of their AK.
fn block_fields<A: Copy>(
    block: &Block<'_, A>,
    adr: Adr,
    header: AkHeader<A>,
    out: &mut dyn FnMut(Field<'_>),
) {
    out(Field::hex("LGE", block.lge() as u32, 2).with_meaning(block_meaning(block)));
    out(Field::hex("ADR", u32::from(adr.byte()), 2).with_meaning(adr.meaning()));
    let (ak, pnu, ind) = match block {
        Block::Process => return,
        Block::Parameter(p) => (p.ak, p.pnu, p.ind),
        Block::Text(t) => (t.ak, t.pnu, t.ind),
    };
    let (code, name, ind_meaning) = header(ak, ind);
    header_fields(code, name, pnu, ind, ind_meaning, out);
    if let Block::Text(t) = block {
        out(Field::text("text", t.text));
    }
}

/// What IND means in a request with `ak`: a description element, a text index or an array index.
fn command_ind(ak: ParameterCommand, ind: u16) -> Option<&'static str> {
    match ak {
        ParameterCommand::ReadDescription => description_element(ind),
        ParameterCommand::Text => Some(text_ind_meaning(ind)),
        _ => value_ind_meaning(ind),
    }
}

/// What IND means in a reply with `ak`, as [`command_ind`] for a request.
fn response_ind(ak: ParameterResponse, ind: u16) -> Option<&'static str> {
    match ak {
        ParameterResponse::Description => description_element(ind),
        ParameterResponse::Text => Some(text_ind_meaning(ind)),
        _ => value_ind_meaning(ind),
    }
}

fn text_ind_meaning(ind: u16) -> &'static str {
    match (ind >> 8) as u8 {
        IND_READ_TEXT => "read text (high byte 04)",
        IND_WRITE_TEXT => "write text (high byte 05)",
        _ => "text element: parameter value + 1",
    }
}

fn value_ind_meaning(ind: u16) -> Option<&'static str> {
    match ind {
        0 => None,
        0x0001..=0x00FF => Some("array index"),
        _ => Some("array index in the low byte (the high byte is not used)"),
    }
}

fn ctw_fields(ctw: ControlWord, out: &mut dyn FnMut(Field<'_>)) {
    let f = Field::hex("CTW", u32::from(ctw.0), 4);
    out(match ctw.name() {
        Some(n) => f.with_meaning(n),
        None if !ctw.data_valid() => f.with_meaning("data invalid: the control word is ignored"),
        None => f,
    });
    for bit in 0..16u8 {
        if ctw.0 >> bit & 1 == 1 {
            out(Field::flag(CTW_BITS[bit as usize], true).with_meaning(ControlWord::bit_name(bit)));
        }
    }
}

fn stw_fields(stw: StatusWord, out: &mut dyn FnMut(Field<'_>)) {
    out(Field::hex("STW", u32::from(stw.0), 4));
    for bit in 0..16u8 {
        if stw.0 >> bit & 1 == 1 {
            out(Field::flag(STW_BITS[bit as usize], true).with_meaning(StatusWord::bit_name(bit)));
        }
    }
}

fn reference_field(name: &'static str, r: Reference) -> Field<'static> {
    Field::hex(name, u32::from(r.word()), 4).with_quantity(r.percent(), "%", 2)
}

impl Describe for Frame<'_> {
    fn direction(&self) -> Direction {
        match self.message {
            Message::Request(_) => Direction::Master,
            Message::Reply(_) => Direction::Drive,
        }
    }

    fn target(&self) -> Target {
        self.adr().target()
    }

    fn command(&self) -> Command {
        let (code, name) = match self.message {
            Message::Request(r) => match r.command() {
                Some(c) => (c.ak(), c.name()),
                None => (0, r.ctw.process_block_name()),
            },
            Message::Reply(r) => match r.response() {
                Some(a) => (a.ak(), a.name()),
                None => (0, "process block: status word and MAV"),
            },
        };
        Command { code, style: CodeStyle::Hex, name }
    }

    fn is_refusal(&self) -> bool {
        matches!(self.message, Message::Reply(r) if r.response() == Some(ParameterResponse::CannotPerform))
    }

    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        let adr = self.adr();
        match self.message {
            Message::Request(r) => {
                block_fields(&r.block, adr, |ak, ind| (ak.ak(), ak.name(), command_ind(ak, ind)), out);
                if let Block::Parameter(p) = r.block {
                    let pwe = Field::hex("PWE", p.pwe, 8);
                    out(if p.ak.is_write() { pwe.with_meaning("value to write") } else { pwe });
                }
                ctw_fields(r.ctw, out);
                out(reference_field("MRV", r.reference));
            }
            Message::Reply(r) => {
                block_fields(&r.block, adr, |ak, ind| (ak.ak(), ak.name(), response_ind(ak, ind)), out);
                if let Block::Parameter(p) = r.block {
                    out(Field::hex("PWE", p.pwe, 8));
                    match p.ak {
                        ParameterResponse::CannotPerform => {
                            let code = FaultCode(p.pwe_low());
                            out(Field::dec("fault code", i64::from(code.0))
                                .with_meaning(code.meaning().unwrap_or("not in the fault table")));
                        }
                        ParameterResponse::Description if p.ind == 1 => {
                            let t = p.pwe as u8;
                            let f = Field::dec("data type", i64::from(t));
                            out(match data_type(t) {
                                Some(m) => f.with_meaning(m),
                                None => f,
                            });
                            out(Field::flag("additional text available", p.pwe & 0x0400 != 0));
                        }
                        ParameterResponse::Text => {
                            let chars = p.pwe_bytes();
                            out(Field::text("text", &chars));
                        }
                        _ => {}
                    }
                }
                stw_fields(r.stw, out);
                out(reference_field("MAV", r.mav));
            }
        }
        out(Field::hex("BCC", u32::from(self.bcc), 2));
    }
}
