//! B800: the replies to the read commands (`T` status, `Z` speed in Hz, `M` in rpm, `A`
//! current, `V` version) by command, error replies included. A read is answered by the
//! drive's reply to that command as heard, addressed as the drive would send it.

use drivebus_proto::b800::{Address, Destination, MasterCommand, Reply, Request, MAX_FRAME};
use drivebus_proto::Instant;

use super::items::{Fresh, Item, Items, Value};

/// The drive a read command addresses, and the command's letter.
fn read(request: &[u8]) -> Option<(Address, u8)> {
    let req = Request::parse(request).ok()?;
    let Destination::Drive(address) = req.da else { return None };
    match req.cmd {
        MasterCommand::Status
        | MasterCommand::SpeedHz
        | MasterCommand::SpeedRpm
        | MasterCommand::MotorCurrent
        | MasterCommand::Version => Some((address, req.cmd.letter())),
        _ => None,
    }
}

/// Learns from drive `request`'s `reply` heard at `now`; false when it tells nothing.
pub(super) fn learn(request: &[u8], reply: &[u8], now: Instant, items: &mut Items) -> bool {
    let (Some((address, letter)), Ok(rep)) = (read(request), Reply::parse(reply)) else { return false };
    let answers = rep.reply.letter() == letter.to_ascii_lowercase() || rep.reply.letter() == b'e';
    if rep.da != address || !answers {
        return false;
    }
    items.put(address.get(), Item::Command(letter), Value::Reply(rep.reply), now);
    true
}

/// The reply to `request`, a read command, as `fresh` holds it.
pub(super) fn answer(request: &[u8], fresh: &Fresh<'_>) -> Option<Vec<u8>> {
    let (address, letter) = read(request)?;
    let Value::Reply(reply) = fresh.get(address.get(), Item::Command(letter))? else { return None };
    let mut out = [0u8; MAX_FRAME];
    let n = Reply::new(address, reply).emit(&mut out).ok()?;
    Some(out[..n].to_vec())
}
