//! Modbus RTU and ASCII: registers by table and number. A read (03, 04) and the read part of a
//! read/write (17) give the values read; a write the drive acknowledged (06, 10, the write part
//! of 17) gives the holding registers' new values. A read is answered by the reply the drive
//! would send, made of its registers.

use drivebus_proto::modbus::pdu::RegisterAddress;
use drivebus_proto::modbus::{Registers, Reply, ReplyPdu, Request, RequestPdu, UnitId};
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::Instant;

use super::items::{Fresh, Item, Items, Value};

const HOLDING: u8 = 3;
const INPUT: u8 = 4;

/// Learns from drive `request`'s `reply` heard at `now`; false when it tells nothing.
pub(super) fn learn(
    protocol: WireProtocol,
    request: &[u8],
    reply: &[u8],
    now: Instant,
    items: &mut Items,
) -> bool {
    let (Some(req), Some(rep)) = (parse_request(protocol, request), parse_reply(protocol, reply)) else {
        return false;
    };
    let unit = req.unit.0;
    if unit == 0 || rep.unit.0 != unit {
        return false;
    }
    let mut put = |table: u8, start: u16, values: &mut dyn Iterator<Item = u16>| {
        for (i, v) in values.enumerate() {
            let register = start.wrapping_add(i as u16);
            items.put(unit, Item::Register { table, register }, Value::Word(v), now);
        }
    };
    match (req.pdu, rep.pdu) {
        (
            RequestPdu::ReadHoldingRegisters { start: RegisterAddress(s), quantity },
            ReplyPdu::ReadHoldingRegisters { values },
        ) if values.len() == quantity as usize => put(HOLDING, s, &mut values.iter()),
        (
            RequestPdu::ReadInputRegisters { start: RegisterAddress(s), quantity },
            ReplyPdu::ReadInputRegisters { values },
        ) if values.len() == quantity as usize => put(INPUT, s, &mut values.iter()),
        (
            RequestPdu::WriteSingleRegister { address: RegisterAddress(a), value },
            ReplyPdu::WriteSingleRegister { address: RegisterAddress(echo), value: echoed },
        ) if (a, value) == (echo, echoed) => put(HOLDING, a, &mut std::iter::once(value)),
        (
            RequestPdu::WriteMultipleRegisters { start: RegisterAddress(s), values },
            ReplyPdu::WriteMultipleRegisters { start: RegisterAddress(echo), quantity },
        ) if (s, values.len()) == (echo, quantity as usize) => put(HOLDING, s, &mut values.iter()),
        (
            RequestPdu::ReadWriteMultipleRegisters {
                read_start: RegisterAddress(r),
                read_quantity,
                write_start: RegisterAddress(w),
                values: written,
            },
            ReplyPdu::ReadWriteMultipleRegisters { values },
        ) if values.len() == read_quantity as usize => {
            // The drive writes before it reads: what it read is newer where the two overlap.
            put(HOLDING, w, &mut written.iter());
            put(HOLDING, r, &mut values.iter());
        }
        _ => return false,
    }
    true
}

/// The reply to `request`, a register read (03, 04), made of what `fresh` holds.
pub(super) fn answer(protocol: WireProtocol, request: &[u8], fresh: &Fresh<'_>) -> Option<Vec<u8>> {
    let req = parse_request(protocol, request)?;
    let (table, start, quantity) = match req.pdu {
        RequestPdu::ReadHoldingRegisters { start: RegisterAddress(s), quantity } => (HOLDING, s, quantity),
        RequestPdu::ReadInputRegisters { start: RegisterAddress(s), quantity } => (INPUT, s, quantity),
        _ => return None,
    };
    let unit = req.unit.0;
    if unit == 0 {
        return None;
    }
    let values = (0..quantity)
        .map(|i| fresh.word(unit, Item::Register { table, register: start.wrapping_add(i) }))
        .collect::<Option<Vec<u16>>>()?;
    let values = Registers::from_values(&values);
    let pdu = match table {
        HOLDING => ReplyPdu::ReadHoldingRegisters { values },
        _ => ReplyPdu::ReadInputRegisters { values },
    };
    let reply = Reply { unit: UnitId(unit), pdu };
    let mut out = [0u8; 520];
    let n = match protocol {
        WireProtocol::ModbusAscii => reply.emit_ascii(&mut out).ok()?,
        _ => reply.emit_rtu(&mut out).ok()?,
    };
    Some(out[..n].to_vec())
}

fn parse_request(protocol: WireProtocol, bytes: &[u8]) -> Option<Request<'_>> {
    match protocol {
        WireProtocol::ModbusAscii => Request::parse_ascii(bytes).ok(),
        _ => Request::parse_rtu(bytes).ok(),
    }
}

fn parse_reply(protocol: WireProtocol, bytes: &[u8]) -> Option<Reply<'_>> {
    match protocol {
        WireProtocol::ModbusAscii => Reply::parse_ascii(bytes).ok(),
        _ => Reply::parse_rtu(bytes).ok(),
    }
}
