//! ASCII-mode frames described field by field for tools.

use crate::describe::{CodeStyle, Command, Describe, Direction, Field, Target};
use crate::hex;

use super::{AsciiAddress, AsciiFrame, AsciiReply, AsciiReplyBody, MAX_FRAME, SUM_MARK};
use crate::toshiba::{describe_value, tripped_field, ERROR_LETTER};

fn inv_field(inv_no: AsciiAddress, out: &mut dyn FnMut(Field<'_>)) {
    match inv_no {
        AsciiAddress::Omitted => {}
        AsciiAddress::Unit(n) => out(Field::dec("INV-NO", n as i64)),
        AsciiAddress::Wildcard { .. } => {
            if let Ok(Some(chars)) = inv_no.chars() {
                out(Field::text("INV-NO", &chars)
                    .with_meaning("wildcard: the smallest matching number answers"));
            }
        }
    }
}

fn sum_field(frame: &AsciiFrame, out: &mut dyn FnMut(Field<'_>)) {
    let mut buf = [0u8; MAX_FRAME];
    if let Ok(n) = frame.emit(&mut buf) {
        if n >= 6 && buf[n - 5] == SUM_MARK {
            if let Some(s) = hex::decode_pair(buf[n - 4], buf[n - 3]) {
                out(Field::hex("SUM", s as u32, 2));
            }
        }
    }
}

impl Describe for AsciiFrame {
    fn direction(&self) -> Direction {
        match self {
            AsciiFrame::Request(_) => Direction::Master,
            AsciiFrame::Reply(_) => Direction::Drive,
        }
    }

    fn target(&self) -> Target {
        match self {
            AsciiFrame::Request(r) => r.inv_no.target(),
            AsciiFrame::Reply(r) => r.inv_no.map_or(Target::Implicit, Target::Unit),
        }
    }

    fn command(&self) -> Command {
        match self {
            AsciiFrame::Request(r) => {
                Command { code: r.cmd.letter(), style: CodeStyle::Letter, name: r.cmd.name() }
            }
            AsciiFrame::Reply(r) => reply_command(r.tripped, &r.body),
        }
    }

    fn is_refusal(&self) -> bool {
        matches!(self, AsciiFrame::Reply(AsciiReply { body: AsciiReplyBody::Error(_), .. }))
    }

    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        match self {
            AsciiFrame::Request(r) => {
                inv_field(r.inv_no, out);
                out(r.comm_no.field());
                if let Some(d) = r.data {
                    describe_value(r.comm_no.format(), "data", d.value, d.digits, out);
                }
            }
            AsciiFrame::Reply(r) => {
                if let Some(n) = r.inv_no {
                    out(Field::dec("INV-NO", n as i64));
                }
                out(tripped_field(r.tripped));
                match r.body {
                    AsciiReplyBody::Data { comm_no, data, .. } => {
                        out(comm_no.field());
                        describe_value(comm_no.format(), "data", data, 4, out);
                    }
                    AsciiReplyBody::Error(code) => out(code.field()),
                }
            }
        }
        sum_field(self, out);
    }
}

fn reply_command(tripped: bool, body: &AsciiReplyBody) -> Command {
    let case = if tripped { 0x20 } else { 0 };
    match body {
        AsciiReplyBody::Data { cmd, .. } => {
            Command { code: cmd.letter() | case, style: CodeStyle::Letter, name: cmd.name() }
        }
        AsciiReplyBody::Error(_) => {
            Command { code: ERROR_LETTER | case, style: CodeStyle::Letter, name: "error reply" }
        }
    }
}
