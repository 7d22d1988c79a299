//! TOSHIBA Inverter Protocol, ASCII and binary mode: communication numbers. A read (`R`, `G`)
//! gives the number's data; a write the drive acknowledged (`W`, `P`) its new data; a block
//! read (`X`, binary mode) the data of the numbers f875–f879 select, once those selections have
//! been heard (read or written). Each reply's CMD case says whether the drive is tripped. A
//! read is answered by the reply the drive would send, in the request's own mode and form.

use drivebus_proto::toshiba::ascii::AsciiAddress;
use drivebus_proto::toshiba::binary::{BinaryAddress, BinaryReplyBody, BinaryRequestBody, BlockRequest};
use drivebus_proto::toshiba::{block_read_item, Cmd, CommNo, TipReply, TipRequest};
use drivebus_proto::Instant;

use super::items::{Fresh, Item, Items, Value};

/// f875, the first block read item selection; f876–f879 follow.
const F875: u16 = 0x0875;

/// FE70, the rated current that scales FE03 (read-only).
const FE70: u16 = 0xFE70;

/// A set-up value a profile reads once per drive to decode a status (FE70, f875–f879): served
/// whatever its age, until a write to it is heard.
fn setup(comm_no: CommNo) -> bool {
    comm_no.0 == FE70 || (F875..F875 + 5).contains(&comm_no.0)
}

/// The drive a request addresses by number (not a broadcast, not omitted).
fn drive(request: &TipRequest) -> Option<u8> {
    match request {
        TipRequest::Ascii(r) => match r.inv_no {
            AsciiAddress::Unit(n) => Some(n),
            _ => None,
        },
        TipRequest::Binary(r) => match r.inv_no {
            BinaryAddress::Unit(n) => Some(n),
            _ => None,
        },
    }
}

/// What a request does: a number read or written, or a block read of `n_r` groups.
enum Ask {
    Number { cmd: Cmd, comm_no: CommNo },
    Block(BlockRequest),
}

fn ask(request: &TipRequest) -> Option<Ask> {
    match request {
        TipRequest::Ascii(r) => Some(Ask::Number { cmd: r.cmd, comm_no: r.comm_no }),
        TipRequest::Binary(r) => match r.body {
            BinaryRequestBody::Block(b) => Some(Ask::Block(b)),
            body => Some(Ask::Number { cmd: body.cmd()?, comm_no: body.comm_no()? }),
        },
    }
}

/// The numbers a block read's groups carry, as the drive's f875–f879 were last heard; a group
/// whose selection is 0 (or unknown to the protocol) carries 0000 (`None` here).
fn block_items(latest: impl Fn(Item) -> Option<Value>, groups: u8) -> Option<Vec<Option<CommNo>>> {
    (0..u16::from(groups))
        .map(|i| match latest(Item::CommNo(F875 + i))? {
            Value::Word(selection) => Some(block_read_item(selection)),
            _ => None,
        })
        .collect()
}

/// Forgets the set-up value `request` writes (`W`, `P`), of its drive or, broadcast, of every
/// drive: until the drive's answer is heard, what it holds is not known.
pub(super) fn forget_written(request: &[u8], items: &mut Items) {
    let Ok(req) = TipRequest::parse(request) else { return };
    let Some(Ask::Number { cmd: Cmd::W | Cmd::P, comm_no }) = ask(&req) else { return };
    if setup(comm_no) {
        items.forget(drive(&req), Item::CommNo(comm_no.0));
    }
}

/// True when `request` reads (`R`, `G`) a set-up value not held.
pub(super) fn unheard_setup(request: &[u8], items: &Items) -> bool {
    let Ok(req) = TipRequest::parse(request) else { return false };
    let (Some(unit), Some(Ask::Number { cmd: Cmd::R | Cmd::G, comm_no })) = (drive(&req), ask(&req)) else {
        return false;
    };
    setup(comm_no) && items.latest(unit, Item::CommNo(comm_no.0)).is_none()
}

/// Learns from drive `request`'s `reply` heard at `now`; false when it tells nothing.
pub(super) fn learn(request: &[u8], reply: &[u8], now: Instant, items: &mut Items) -> bool {
    let (Ok(req), Ok(rep)) = (TipRequest::parse(request), TipReply::parse(reply)) else { return false };
    let Some(unit) = drive(&req) else { return false };
    if !matches!(
        (&req, &rep),
        (TipRequest::Ascii(_), TipReply::Ascii(_)) | (TipRequest::Binary(_), TipReply::Binary(_))
    ) {
        return false;
    }
    // Any reply says whether the drive is tripped now.
    items.put(unit, Item::Tripped, Value::Word(rep.tripped().into()), now);
    match ask(&req) {
        Some(Ask::Number { cmd, comm_no }) => {
            let echoed = match &rep {
                TipReply::Ascii(r) => r.comm_no() == Some(comm_no),
                TipReply::Binary(r) => matches!(
                    r.body,
                    BinaryReplyBody::Data { cmd: c, comm_no: n, .. }
                        if (c, n) == (cmd, comm_no)
                ),
            };
            match rep.data().filter(|_| echoed) {
                Some(data) => {
                    items.put(unit, Item::CommNo(comm_no.0), Value::Word(data), now);
                    true
                }
                None => false,
            }
        }
        Some(Ask::Block(b)) => {
            let TipReply::Binary(r) = &rep else { return false };
            let BinaryReplyBody::Block(y) = r.body else { return false };
            match block_items(|item| items.latest(unit, item), y.n_r) {
                Some(numbers) if y.n_r == b.reply_groups() => {
                    for (n, v) in numbers.iter().zip(y.rdata()) {
                        if let Some(n) = n {
                            items.put(unit, Item::CommNo(n.0), Value::Word(*v), now);
                        }
                    }
                    // The writes it carries go to numbers f870/f871 select: not learnt, so
                    // only a pure read counts as understood.
                    b.n_w == 0
                }
                _ => false,
            }
        }
        None => false,
    }
}

/// The reply to `request`, a read of a number (`R`, `G`) or a block read without writes (`X`),
/// made of what `fresh` holds.
pub(super) fn answer(request: &[u8], fresh: &Fresh<'_>) -> Option<Vec<u8>> {
    let req = TipRequest::parse(request).ok()?;
    let unit = drive(&req)?;
    let tripped = fresh.word(unit, Item::Tripped)? != 0;
    let reply = match (ask(&req)?, &req) {
        (Ask::Number { cmd: Cmd::R | Cmd::G, comm_no }, _) => {
            req.reply(unit, tripped, fresh.word_or_setup(unit, Item::CommNo(comm_no.0), setup(comm_no))?)?
        }
        (Ask::Block(b), TipRequest::Binary(r)) if b.n_w == 0 => {
            let numbers = block_items(|item| fresh.latest(unit, item), b.reply_groups())?;
            let rdata = numbers
                .into_iter()
                .map(|n| match n {
                    Some(n) => fresh.word(unit, Item::CommNo(n.0)),
                    None => Some(0),
                })
                .collect::<Option<Vec<u16>>>()?;
            TipReply::Binary(r.block_reply(unit, tripped, &rdata)?)
        }
        _ => return None,
    };
    let mut out = [0u8; 64];
    let n = reply.emit(&mut out).ok()?;
    Some(out[..n].to_vec())
}
