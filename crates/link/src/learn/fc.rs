//! Danfoss FC: parameters by PNU and IND, and the status word and main actual value (PCD1,
//! PCD2) every reply carries. A read (AK 1) gives the parameter's value; a write the drive
//! acknowledged (AK 2, 3, D, E answered with AK 1 or 2) its new value. A parameter read, or a
//! process block, is answered by the telegram the drive would send: the value heard, with the
//! drive's latest status word and MAV.

use drivebus_proto::fc::{
    Block, ParameterBlock, ParameterCommand, ParameterNumber, ParameterResponse, Reference, Reply, Request,
    StatusWord, MAX_TELEGRAM,
};
use drivebus_proto::Instant;

use super::items::{Fresh, Item, Items, Value};

/// 16-02 Reference [%]: the reference the drive holds, which a telegram with a valid control
/// word (bit 10) sets.
const REFERENCE_PCT: u16 = 1602;

/// A value a profile reads once per drive to decode a status (3-00, 3-02, 3-03, 4-14 set-up
/// values, 16-02 the reference the drive holds): served whatever its age, until a write to it
/// is heard.
fn setup(pnu: ParameterNumber, ind: u16) -> bool {
    ind == 0 && matches!(pnu.pnu(), 300 | 302 | 303 | 414 | REFERENCE_PCT)
}

/// Forgets what `request` may change of the values [`setup`] keeps, of its drive or, broadcast,
/// of every drive: the parameter it writes, and 16-02 when its control word is valid (bit 10:
/// the drive takes its reference).
pub(super) fn forget_written(request: &[u8], items: &mut Items) {
    let Ok(req) = Request::parse(request) else { return };
    let drive = req.adr.address();
    if let Block::Parameter(q) = req.block {
        if q.ak.is_write() && setup(q.pnu, q.ind) {
            items.forget(drive, Item::Parameter { pnu: q.pnu, ind: q.ind });
        }
    }
    if req.ctw.data_valid() {
        if let Some(pnu) = ParameterNumber::new(REFERENCE_PCT) {
            items.forget(drive, Item::Parameter { pnu, ind: 0 });
        }
    }
}

/// True when `request` is a parameter read (AK 1) of a set-up value not held.
pub(super) fn unheard_setup(request: &[u8], items: &Items) -> bool {
    let Ok(req) = Request::parse(request) else { return false };
    let (Some(unit), Block::Parameter(q)) = (req.adr.address(), req.block) else { return false };
    q.ak == ParameterCommand::ReadValue
        && setup(q.pnu, q.ind)
        && items.latest(unit, Item::Parameter { pnu: q.pnu, ind: q.ind }).is_none()
}

/// Learns from drive `request`'s `reply` heard at `now`; false when it tells nothing.
pub(super) fn learn(request: &[u8], reply: &[u8], now: Instant, items: &mut Items) -> bool {
    let (Ok(req), Ok(rep)) = (Request::parse(request), Reply::parse(reply)) else { return false };
    let Some(unit) = req.adr.address() else { return false };
    if rep.adr != req.adr {
        return false;
    }
    items.put(unit, Item::Process, Value::Process { stw: rep.stw.0, mav: rep.mav.word() }, now);
    match (req.block, rep.block) {
        (Block::Process, Block::Process) => true,
        (Block::Parameter(q), Block::Parameter(a)) => {
            let asked = q.ak == ParameterCommand::ReadValue || q.ak.is_write();
            let value = matches!(a.ak, ParameterResponse::ValueWord | ParameterResponse::ValueDoubleWord);
            if !(asked && value && a.pnu == q.pnu && a.ind == q.ind) {
                return false;
            }
            items.put(
                unit,
                Item::Parameter { pnu: q.pnu, ind: q.ind },
                Value::Parameter { ak: a.ak, pwe: a.pwe },
                now,
            );
            true
        }
        _ => false,
    }
}

/// The reply to `request`, a parameter read (AK 1) or a process block, made of what `fresh`
/// holds.
pub(super) fn answer(request: &[u8], fresh: &Fresh<'_>) -> Option<Vec<u8>> {
    let req = Request::parse(request).ok()?;
    let unit = req.adr.address()?;
    let Value::Process { stw, mav } = fresh.get(unit, Item::Process)? else { return None };
    let block = match req.block {
        Block::Process => Block::Process,
        Block::Parameter(q) if q.ak == ParameterCommand::ReadValue => {
            let item = Item::Parameter { pnu: q.pnu, ind: q.ind };
            let value = if setup(q.pnu, q.ind) { fresh.latest(unit, item) } else { fresh.get(unit, item) };
            let Value::Parameter { ak, pwe } = value? else {
                return None;
            };
            Block::Parameter(ParameterBlock { ak, pnu: q.pnu, ind: q.ind, pwe })
        }
        _ => return None,
    };
    let reply = Reply { adr: req.adr, block, stw: StatusWord(stw), mav: Reference::from_word(mav) };
    let mut out = [0u8; MAX_TELEGRAM];
    let n = reply.emit(&mut out).ok()?;
    Some(out[..n].to_vec())
}
