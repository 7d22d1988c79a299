//! Binary-mode frames described field by field for tools.

use crate::describe::{CodeStyle, Command, Describe, Direction, Field, Target};

use super::{BinaryAddress, BinaryFrame, BinaryReply, BinaryReplyBody, BinaryRequestBody, Cmd};
use super::{BLOCK, BLOCK_REPLY, BROADCAST, MAX_FRAME, MAX_READ_GROUPS};
use crate::toshiba::{
    describe_value, tripped_field, BLOCK_READ_DEFAULTS, BLOCK_WRITE_DEFAULTS, ERROR_LETTER,
};

const RDATA_NAMES: [&str; 5] = ["RDATA1", "RDATA2", "RDATA3", "RDATA4", "RDATA5"];
const WDATA_NAMES: [&str; 2] = ["WDATA1", "WDATA2"];

fn command_of(code: u8) -> Command {
    let name = match code & !0x20 {
        b'R' => Cmd::R.name(),
        b'W' => Cmd::W.name(),
        b'P' => Cmd::P.name(),
        b'G' => Cmd::G.name(),
        BLOCK => "block communication",
        BLOCK_REPLY => "block communication reply",
        _ => "error reply",
    };
    Command { code, style: CodeStyle::Letter, name }
}

impl Describe for BinaryFrame {
    fn direction(&self) -> Direction {
        match self {
            BinaryFrame::Request(_) => Direction::Master,
            BinaryFrame::Reply(_) => Direction::Drive,
        }
    }

    fn target(&self) -> Target {
        match self {
            BinaryFrame::Request(r) => r.inv_no.target(),
            BinaryFrame::Reply(r) => r.inv_no.map_or(Target::Implicit, Target::Unit),
        }
    }

    fn command(&self) -> Command {
        match self {
            BinaryFrame::Request(r) => command_of(r.body.code()),
            BinaryFrame::Reply(r) => {
                let case = if r.tripped { 0x20 } else { 0 };
                let code = match r.body {
                    BinaryReplyBody::Data { cmd, .. } => cmd.letter(),
                    BinaryReplyBody::Block(_) => BLOCK_REPLY,
                    BinaryReplyBody::Error(_) => ERROR_LETTER,
                };
                command_of(code | case)
            }
        }
    }

    fn is_refusal(&self) -> bool {
        matches!(self, BinaryFrame::Reply(BinaryReply { body: BinaryReplyBody::Error(_), .. }))
    }

    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        match self {
            BinaryFrame::Request(r) => {
                match r.inv_no {
                    BinaryAddress::Omitted => {}
                    BinaryAddress::Unit(n) => out(Field::hex("INV-NO", n as u32, 2)),
                    BinaryAddress::Broadcast => out(Field::hex("INV-NO", BROADCAST as u32, 2)
                        .with_meaning("broadcast: inverter 00 answers")),
                }
                match r.body {
                    BinaryRequestBody::Read { comm_no } => out(comm_no.field()),
                    BinaryRequestBody::Write { comm_no, data }
                    | BinaryRequestBody::WriteRam { comm_no, data } => {
                        out(comm_no.field());
                        comm_no.describe_data("data", data, out);
                    }
                    BinaryRequestBody::ReadDummy { comm_no, dummy } => {
                        out(comm_no.field());
                        out(Field::hex("dummy data", dummy as u32, 4));
                    }
                    BinaryRequestBody::Block(b) => {
                        out(Field::dec("nW", b.n_w as i64));
                        let n_r = Field::dec("nR", b.n_r as i64);
                        out(if b.n_r > MAX_READ_GROUPS {
                            n_r.with_meaning("more than 5: the reply carries no read data")
                        } else {
                            n_r
                        });
                        for ((&d, name), comm_no) in
                            b.wdata().iter().zip(WDATA_NAMES).zip(BLOCK_WRITE_DEFAULTS)
                        {
                            comm_no.describe_data(name, d, out);
                        }
                    }
                }
            }
            BinaryFrame::Reply(r) => {
                if let Some(n) = r.inv_no {
                    out(Field::hex("INV-NO", n as u32, 2));
                }
                out(tripped_field(r.tripped));
                match r.body {
                    BinaryReplyBody::Data { comm_no, data, .. } => {
                        out(comm_no.field());
                        describe_value(comm_no.format(), "data", data, 4, out);
                    }
                    BinaryReplyBody::Block(b) => {
                        out(Field::dec("nR", b.n_r as i64));
                        for ((&d, name), comm_no) in
                            b.rdata().iter().zip(RDATA_NAMES).zip(BLOCK_READ_DEFAULTS)
                        {
                            comm_no.describe_data(name, d, out);
                        }
                    }
                    BinaryReplyBody::Error(code) => out(code.field()),
                }
            }
        }
        let mut buf = [0u8; MAX_FRAME];
        if let Ok(n) = self.emit(&mut buf) {
            out(Field::hex("SUM", buf[n - 1] as u32, 2));
        }
    }
}
