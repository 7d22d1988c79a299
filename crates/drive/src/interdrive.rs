//! The frames a drive acting as bus master broadcasts every cycle (seed 004 9.2.2 (2): "变频器
//! 作为主机,使用广播地址发送命令到从机,从机不应答"; the Toshiba manual's inter-drive
//! communication, f806 = 3/4), recognised so that `decode`, `sniff` and the gateway can name
//! them. The simulator sends exactly these (`drivebus_sim::interdrive`).

use drivebus_proto::modbus::{Request, RequestPdu};
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::toshiba::binary::{BinaryAddress, BinaryRequest, BinaryRequestBody};

use crate::registers::generic::reg;

/// What a generic master drive's broadcast is.
pub const GENERIC_MASTER_BROADCAST: &str =
    "broadcast as a drive acting as bus master sends it every cycle (seed 004 9.2.2 (2)): every drive acts, none answers";
/// What a Toshiba master drive's broadcast block write is.
pub const TOSHIBA_MASTER_BROADCAST: &str =
    "inter-drive communication: a master drive's (f806 = 3/4) run command (WDATA1, to FA00) and frequency (WDATA2 in 0.01 % of its FH, to FA01) to every inverter";

/// The name of `frame`, a whole request of `protocol`, when it is a broadcast
/// a drive acting as bus master sends: a Modbus 06 to address 0 writing 2000H (command) or
/// 2001H (frequency), or a Toshiba binary block write (`X`, nW > 0) to every inverter (FF).
pub fn master_drive_broadcast(protocol: WireProtocol, frame: &[u8]) -> Option<&'static str> {
    let modbus = match protocol {
        WireProtocol::ModbusRtu => Request::parse_rtu(frame).ok(),
        WireProtocol::ModbusAscii => Request::parse_ascii(frame).ok(),
        WireProtocol::ToshibaBinary => {
            let r = BinaryRequest::parse(frame).ok()?;
            return match (r.inv_no, r.body) {
                (BinaryAddress::Broadcast, BinaryRequestBody::Block(b)) if b.n_w > 0 => {
                    Some(TOSHIBA_MASTER_BROADCAST)
                }
                _ => None,
            };
        }
        _ => None,
    }?;
    match modbus.pdu {
        RequestPdu::WriteSingleRegister { address, .. }
            if modbus.unit.0 == 0 && (address.0 == reg::COMMAND || address.0 == reg::FREQUENCY) =>
        {
            Some(GENERIC_MASTER_BROADCAST)
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_master_drives_broadcasts_are_named_and_nothing_else() {
        // 06 to 0: 2001H = 40.00 Hz, RTU and ASCII.
        let rtu = [0x00, 0x06, 0x20, 0x01, 0x0F, 0xA0];
        let crc = drivebus_proto::checksum::crc16_modbus(&rtu).to_le_bytes();
        let frame = [&rtu[..], &crc[..]].concat();
        assert_eq!(master_drive_broadcast(WireProtocol::ModbusRtu, &frame), Some(GENERIC_MASTER_BROADCAST));
        let lrc = drivebus_proto::checksum::lrc(&rtu);
        let ascii = format!(":00062001 0FA0{lrc:02X}\r\n").replace(' ', "");
        assert_eq!(
            master_drive_broadcast(WireProtocol::ModbusAscii, ascii.as_bytes()),
            Some(GENERIC_MASTER_BROADCAST)
        );
        // The same write to drive 1 is not a broadcast.
        let one = [0x01, 0x06, 0x20, 0x01, 0x0F, 0xA0];
        let crc = drivebus_proto::checksum::crc16_modbus(&one).to_le_bytes();
        assert_eq!(master_drive_broadcast(WireProtocol::ModbusRtu, &[&one[..], &crc[..]].concat()), None);
        // Toshiba: 2F FF 58 02 00 C400 2710 SUM.
        let mut x = vec![0x2F, 0xFF, 0x58, 0x02, 0x00, 0xC4, 0x00, 0x27, 0x10];
        x.push(x.iter().fold(0u8, |a, b| a.wrapping_add(*b)));
        assert_eq!(master_drive_broadcast(WireProtocol::ToshibaBinary, &x), Some(TOSHIBA_MASTER_BROADCAST));
        // A block read to one inverter is not.
        let mut y = vec![0x2F, 0x01, 0x58, 0x00, 0x05];
        y.push(y.iter().fold(0u8, |a, b| a.wrapping_add(*b)));
        assert_eq!(master_drive_broadcast(WireProtocol::ToshibaBinary, &y), None);
        assert_eq!(master_drive_broadcast(WireProtocol::B800, b"anything"), None);
    }
}
