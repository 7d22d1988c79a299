//! The checksums of the six wire formats, each checked against the manuals' examples.
//!
//! | protocol | function |
//! |---|---|
//! | Modbus RTU | [`crc16_modbus`] (sent low byte first) |
//! | Modbus ASCII | [`lrc`] over the binary bytes |
//! | Toshiba TIP ASCII and binary | [`sum8`] |
//! | Danfoss FC | [`xor8`] |
//! | B800 | [`not_sum8`] over the ASCII characters |

/// CRC-16/MODBUS: reflected polynomial 0xA001, initial value 0xFFFF, no final XOR.
///
/// The value is returned as a number; on the wire it goes low byte first
/// (`crc.to_le_bytes()`). Table driven: one lookup per byte.
#[inline]
pub fn crc16_modbus(bytes: &[u8]) -> u16 {
    crc16_modbus_update(0xFFFF, bytes)
}

/// Continues a CRC-16/MODBUS computation from `crc` over more `bytes`.
#[inline]
pub fn crc16_modbus_update(mut crc: u16, bytes: &[u8]) -> u16 {
    for &b in bytes {
        crc = (crc >> 8) ^ CRC16_TABLE[((crc ^ b as u16) & 0xFF) as usize];
    }
    crc
}

const CRC16_TABLE: [u16; 256] = {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = i as u16;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xA001 } else { crc >> 1 };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
};

/// The inverse of the high bytes of [`CRC16_TABLE`]: the high byte of `T[i]` is different for
/// every `i`, so one step of the CRC can be undone.
const CRC16_INV_HIGH: [u8; 256] = {
    let mut inv = [0u8; 256];
    let mut i = 0;
    while i < 256 {
        inv[(CRC16_TABLE[i] >> 8) as usize] = i as u8;
        i += 1;
    }
    inv
};

/// Runs CRC-16/MODBUS backwards: the register before `bytes` that ends as `crc` after them
/// (`crc16_modbus_update(crc16_modbus_rewind(crc, b), b) == crc`).
pub fn crc16_modbus_rewind(mut crc: u16, bytes: &[u8]) -> u16 {
    for &b in bytes.iter().rev() {
        // Forward: crc' = (crc >> 8) ^ T[(crc ^ b) & 0xFF]; the high byte of crc' is T's.
        let idx = CRC16_INV_HIGH[(crc >> 8) as usize];
        let high = (crc ^ CRC16_TABLE[idx as usize]) & 0xFF;
        crc = high << 8 | (idx ^ b) as u16;
    }
    crc
}

/// The byte `x` whose CRC-16/MODBUS register, after `x` alone from 0xFFFF, is `crc`; `None`
/// when no single byte gets there.
pub fn crc16_modbus_one_byte(crc: u16) -> Option<u8> {
    // After one byte x from 0xFFFF the register is 0x00FF ^ T[x ^ 0xFF].
    let t = crc ^ 0x00FF;
    let idx = CRC16_INV_HIGH[(t >> 8) as usize];
    (CRC16_TABLE[idx as usize] == t).then_some(idx ^ 0xFF)
}

/// Modbus ASCII LRC: the two's complement of the 8-bit sum of the binary bytes.
#[inline]
pub fn lrc(bytes: &[u8]) -> u8 {
    sum8(bytes).wrapping_neg()
}

/// The 8-bit sum of `bytes` (Toshiba Inverter Protocol, ASCII and binary).
#[inline]
pub fn sum8(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |acc, &b| acc.wrapping_add(b))
}

/// The bitwise NOT of the 8-bit sum of `bytes` (B800, over the ASCII characters).
///
/// seed 000: "the logical NOT of the byte result of the byte addition of all transmitted
/// ASCII bytes excluding the START and STOP flags and the checksum itself".
#[inline]
pub fn not_sum8(bytes: &[u8]) -> u8 {
    !sum8(bytes)
}

/// XOR of all bytes, starting from 0 (Danfoss FC BCC).
///
/// seed 003: "Before the first byte in the telegram is received, the calculated checksum is 0."
#[inline]
pub fn xor8(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |acc, &b| acc ^ b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc16_runs_backwards_and_finds_the_one_byte() {
        let frame = [0x01, 0x06, 0x00, 0x02, 0x13, 0x88];
        let state = crc16_modbus(&frame[..1]);
        assert_eq!(crc16_modbus_rewind(crc16_modbus(&frame), &frame[1..]), state);
        assert_eq!(crc16_modbus_update(crc16_modbus_rewind(0x1234, &frame), &frame), 0x1234);
        for x in 0..=255u8 {
            assert_eq!(crc16_modbus_one_byte(crc16_modbus(&[x])), Some(x));
        }
        // 256 registers are reachable in one byte; most are not.
        assert_eq!((0..=u16::MAX).filter(|&c| crc16_modbus_one_byte(c).is_some()).count(), 256);
    }

    #[test]
    fn crc16_check_value() {
        // CRC-16/MODBUS catalogue check value.
        assert_eq!(crc16_modbus(b"123456789"), 0x4B37);
    }

    #[test]
    fn crc16_modbus_spec_example() {
        // 11 03 00 6B 00 03 -> 76 87 on the wire (low byte first).
        assert_eq!(crc16_modbus(&[0x11, 0x03, 0x00, 0x6B, 0x00, 0x03]).to_le_bytes(), [0x76, 0x87]);
    }

    #[test]
    fn crc16_seed_002_examples() {
        // seed 002: 01 03 FD 00 00 01 B5 A6 / 01 03 02 17 70 B6 50 / 01 83 03 01 31
        assert_eq!(crc16_modbus(&[0x01, 0x03, 0xFD, 0x00, 0x00, 0x01]).to_le_bytes(), [0xB5, 0xA6]);
        assert_eq!(crc16_modbus(&[0x01, 0x03, 0x02, 0x17, 0x70]).to_le_bytes(), [0xB6, 0x50]);
        assert_eq!(crc16_modbus(&[0x01, 0x03, 0xFD, 0x00, 0x00, 0x02]).to_le_bytes(), [0xF5, 0xA7]);
        assert_eq!(crc16_modbus(&[0x01, 0x83, 0x03]).to_le_bytes(), [0x01, 0x31]);
    }

    #[test]
    fn crc16_seed_004_examples() {
        // seed 004: the RTU read's E8 4B is the CRC of the first four bytes only.
        assert_eq!(crc16_modbus(&[0x01, 0x03, 0x21, 0x04]).to_le_bytes(), [0xE8, 0x4B]);
        assert_eq!(crc16_modbus(&[0x01, 0x03, 0x21, 0x04, 0x00, 0x01]).to_le_bytes(), [0xCF, 0xF7]);
        assert_eq!(crc16_modbus(&[0x01, 0x06, 0x00, 0x02, 0x13, 0x88]).to_le_bytes(), [0x25, 0x5C]);
        assert_eq!(crc16_modbus(&[0x01, 0x08, 0x01, 0x02, 0x03, 0x04]).to_le_bytes(), [0x41, 0x04]);
    }

    #[test]
    fn crc16_update_is_incremental() {
        let all = crc16_modbus(b"123456789");
        let split = crc16_modbus_update(crc16_modbus(b"1234"), b"56789");
        assert_eq!(all, split);
    }

    #[test]
    fn lrc_examples() {
        // :010604051234AA  :010321020002D7  :010304010001F6  :0106000213885C  :010801020304ED
        assert_eq!(lrc(&[0x01, 0x06, 0x04, 0x05, 0x12, 0x34]), 0xAA);
        assert_eq!(lrc(&[0x01, 0x03, 0x21, 0x02, 0x00, 0x02]), 0xD7);
        assert_eq!(lrc(&[0x01, 0x03, 0x04, 0x01, 0x00, 0x01]), 0xF6);
        assert_eq!(lrc(&[0x01, 0x06, 0x00, 0x02, 0x13, 0x88]), 0x5C);
        assert_eq!(lrc(&[0x01, 0x08, 0x01, 0x02, 0x03, 0x04]), 0xED);
    }

    #[test]
    fn b800_examples() {
        // seed 000: "81" "R" -> 2F ; "85" "P" "0960" -> 5E ; "G" "R" -> 2D ; "01" "r" -> 35
        assert_eq!(not_sum8(b"8152"), 0x2F);
        assert_eq!(not_sum8(b"85500960"), 0x5E);
        assert_eq!(not_sum8(b"4752"), 0x2D);
        assert_eq!(not_sum8(b"4753"), 0x2C);
        assert_eq!(not_sum8(b"0172"), 0x35);
        assert_eq!(not_sum8(b"0570"), 0x33);
    }

    #[test]
    fn toshiba_and_fc_examples() {
        assert_eq!(sum8(&[0x2F, 0x52, 0x00, 0x00]), 0x81);
        assert_eq!(sum8(&[0x2F, 0x57, 0x00, 0x10, 0x00, 0x64]), 0xFA);
        assert_eq!(sum8(b"(R0000&"), 0x60);
        assert_eq!(xor8(&[0x02, 0x06, 0x04, 0x04, 0x7C, 0x20, 0x00]), 0x58);
        assert_eq!(xor8(&[0x02, 0x06, 0x04, 0x06, 0x07, 0x00, 0x00]), 0x01);
    }
}
