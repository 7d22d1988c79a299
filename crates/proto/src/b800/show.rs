//! The protocol-neutral view of a B800 frame ([`Describe`]).

use crate::describe::{CodeStyle, Command, Describe, Direction, Field, Target};
use crate::error::FrameError;

use super::frame::{pair, Packet};
use super::values::{Destination, ErrorCode};
use super::{MasterCommand, SlaveReply};

/// A parsed B800 frame from either side, with the bytes it was read from (for its CS).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame<'a> {
    bytes: &'a [u8],
    packet: Packet,
}

impl<'a> Frame<'a> {
    /// Reads a whole frame (see [`Packet::parse`]).
    pub fn parse(bytes: &'a [u8]) -> Result<Frame<'a>, FrameError> {
        Ok(Frame { bytes, packet: Packet::parse(bytes)? })
    }

    /// The typed frame.
    pub fn packet(&self) -> Packet {
        self.packet
    }

    /// The bytes it was read from.
    pub fn bytes(&self) -> &'a [u8] {
        self.bytes
    }

    /// The CS byte as carried.
    pub fn cs(&self) -> u8 {
        match self.bytes {
            [.., s0, s1, _] => pair(*s0, *s1),
            _ => 0,
        }
    }
}

impl Describe for Frame<'_> {
    fn direction(&self) -> Direction {
        match self.packet {
            Packet::Request(_) => Direction::Master,
            Packet::Reply(_) => Direction::Drive,
        }
    }

    fn target(&self) -> Target {
        match self.packet {
            Packet::Request(r) => match r.da {
                Destination::Drive(a) => Target::Unit(a.get()),
                Destination::Global => Target::Broadcast,
            },
            Packet::Reply(r) => Target::Unit(r.da.get()),
        }
    }

    fn command(&self) -> Command {
        let (code, name) = match self.packet {
            Packet::Request(r) => (r.cmd.letter(), r.cmd.name()),
            Packet::Reply(r) => (r.reply.letter(), r.reply.name()),
        };
        Command { code, style: CodeStyle::Letter, name }
    }

    fn is_refusal(&self) -> bool {
        matches!(self.packet, Packet::Reply(r) if r.reply.is_error())
    }

    fn fields(&self, out: &mut dyn FnMut(Field<'_>)) {
        match self.packet {
            Packet::Request(r) => {
                out(match r.da {
                    Destination::Drive(a) => {
                        Field::hex("DA", a.master_da() as u32, 2).with_meaning("drive address + 128")
                    }
                    Destination::Global => Field::hex("DA", r.da.da() as u32, 2).with_meaning("global 'G'"),
                });
                command_fields(r.cmd, out);
            }
            Packet::Reply(r) => {
                out(Field::hex("DA", r.da.get() as u32, 2).with_meaning("drive address"));
                reply_fields(r.reply, out);
            }
        }
        out(Field::hex("CS", self.cs() as u32, 2));
    }
}

fn command_fields(cmd: MasterCommand, out: &mut dyn FnMut(Field<'_>)) {
    if let MasterCommand::SetSpeed(s) = cmd {
        out(Field::hex("target speed", s.raw() as u32, 4).with_quantity(s.hz(), "Hz", 2));
    }
}

fn reply_fields(reply: SlaveReply, out: &mut dyn FnMut(Field<'_>)) {
    match reply {
        SlaveReply::MotorCurrent(c) => {
            out(Field::hex("motor current", c.raw() as u32, 4).with_quantity(c.amps(), "A", 1))
        }
        SlaveReply::SpeedHz(s) => {
            out(Field::hex("speed in Hz", s.raw() as u32, 4).with_quantity(s.hz(), "Hz", 2))
        }
        SlaveReply::SpeedRpm(r) => {
            out(Field::hex("speed in RPM", r.raw() as u32, 4).with_quantity(r.rpm() as f64, "rpm", 0))
        }
        SlaveReply::Status(st) => {
            out(Field::hex("drive status", st.raw() as u32, 4));
            // The word's high byte goes first on the wire: the trip code, then the state.
            if let Some(trip) = st.trip_code() {
                out(Field::hex("trip code", trip as u32, 2));
            }
            let state = st.state();
            let f = Field::hex("state", state.code() as u32, 2);
            out(f.with_meaning(state.meaning().unwrap_or("not a known state code")));
        }
        SlaveReply::Version(v) => {
            let f = Field::hex("software version", v.raw() as u32, 4);
            // BCD: the four hex digits read as the version, 0100 = 1.00.
            out(f.with_meaning(if v.is_bcd() { "BCD" } else { "not BCD" }));
        }
        SlaveReply::Error { code, word } => {
            let f = Field::hex("error code", code.0 as u32, if word { 4 } else { 2 });
            out(f.with_meaning(error_meaning(code)));
        }
        SlaveReply::Run
        | SlaveReply::Stop
        | SlaveReply::SetSpeed
        | SlaveReply::Increase
        | SlaveReply::Reduce => {}
    }
}

fn error_meaning(code: ErrorCode) -> &'static str {
    code.meaning().unwrap_or("not in the seed's list of error codes")
}
