//! One line per frame for `drivebus simulate -v`: what the master sent and what the drives
//! answered, decoded with the bus's protocols.

use drivebus_proto::describe::CodeStyle;
use drivebus_proto::protocol::{CodecJob, WireProtocol};
use drivebus_proto::{Codec, Deframer, Describe, Direction, Event, Target};

/// A streaming decoder for one protocol and one direction that prints a line per frame.
pub struct Monitor {
    inner: Box<dyn MonitorImpl + Send>,
}

trait MonitorImpl {
    fn push(&mut self, bytes: &[u8], out: &mut Vec<String>);
}

struct Typed<C: Codec> {
    deframer: Deframer<C::Scanner>,
    from: Direction,
    report_rejects: bool,
}

impl<C: Codec> MonitorImpl for Typed<C>
where
    C::Scanner: Send,
{
    fn push(&mut self, bytes: &[u8], out: &mut Vec<String>) {
        let from = self.from;
        let report = self.report_rejects;
        self.deframer.push(bytes, &mut |e| match e {
            Event::Frame { bytes, .. } => match C::parse(bytes, Some(from)) {
                Ok(f) => out.push(format!("{} {}", C::NAME, line_of(&f))),
                Err(err) if report => out.push(format!("{} {}: invalid: {err}", C::NAME, hex(bytes))),
                Err(_) => {}
            },
            Event::Rejected { bytes, error, .. } if report => {
                out.push(format!("{} {}: invalid: {error}", C::NAME, hex(bytes)))
            }
            Event::Rejected { .. } => {}
        });
    }
}

impl Monitor {
    /// A monitor for `protocol` and frames from `from`. `report_rejects`: print damaged
    /// frames too (only useful when one protocol is on the line).
    pub fn new(protocol: WireProtocol, from: Direction, report_rejects: bool) -> Monitor {
        struct Make(Direction, bool);
        impl CodecJob for Make {
            type Output = Box<dyn MonitorImpl + Send>;
            fn run<C: Codec + 'static>(self) -> Self::Output
            where
                C::Scanner: Send + 'static,
            {
                let Make(from, report_rejects) = self;
                Box::new(Typed::<C> { deframer: Deframer::new(C::scanner(Some(from))), from, report_rejects })
            }
        }
        Monitor { inner: protocol.with_codec(Make(from, report_rejects)) }
    }

    /// Feeds bytes; returns a line per frame completed.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<String> {
        let mut out = Vec::new();
        self.inner.push(bytes, &mut out);
        out
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(" ")
}

/// `master to drive 1: 03 read holding registers; starting address 2103, quantity 1`.
pub fn line_of<F: Describe>(f: &F) -> String {
    let who = match (f.direction(), f.target()) {
        (Direction::Master, Target::Unit(n)) => format!("master to drive {n}"),
        (Direction::Master, Target::Broadcast) => "master to all drives".into(),
        (Direction::Master, Target::Wildcard { .. }) => "master to drives by wildcard".into(),
        (Direction::Master, Target::Implicit) => "master to the drive".into(),
        (Direction::Drive, Target::Unit(n)) => format!("drive {n} to master"),
        (Direction::Drive, _) => "drive to master".into(),
    };
    let c = f.command();
    let code = match c.style {
        CodeStyle::Letter => format!("'{}'", c.code as char),
        CodeStyle::Hex => format!("{:02X}", c.code),
    };
    let mut fields = Vec::new();
    f.fields(&mut |field| fields.push(field.to_string()));
    let refusal = if f.is_refusal() { " (refused)" } else { "" };
    format!("{who}: {code} {}{refusal}; {}", c.name, fields.join(", "))
}
