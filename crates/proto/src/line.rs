//! The character format of a serial line and the times it implies: how long a character
//! takes on the wire, Modbus t1.5 and t3.5, and the protocols' gaps.

use core::fmt;
use core::str::FromStr;
use core::time::Duration;

/// Parity bit setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Parity {
    /// No parity bit.
    None,
    /// Even parity.
    Even,
    /// Odd parity.
    Odd,
}

/// Data bits, parity and stop bits, written as `8E1`, `7N2`, `8N1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CharFormat {
    /// Data bits, 7 or 8.
    pub data_bits: u8,
    /// Parity.
    pub parity: Parity,
    /// Stop bits, 1 or 2.
    pub stop_bits: u8,
}

impl CharFormat {
    /// 8 data bits, even parity, 1 stop bit: Modbus RTU's default, Toshiba's and FC's.
    pub const EVEN_8E1: CharFormat = CharFormat { data_bits: 8, parity: Parity::Even, stop_bits: 1 };
    /// 8 data bits, no parity, 1 stop bit: B800.
    pub const NONE_8N1: CharFormat = CharFormat { data_bits: 8, parity: Parity::None, stop_bits: 1 };
    /// 8 data bits, no parity, 2 stop bits: the generic drive's RTU default.
    pub const NONE_8N2: CharFormat = CharFormat { data_bits: 8, parity: Parity::None, stop_bits: 2 };
    /// 7 data bits, no parity, 2 stop bits: the generic drive's ASCII default (seed 004).
    pub const NONE_7N2: CharFormat = CharFormat { data_bits: 7, parity: Parity::None, stop_bits: 2 };

    /// Bits on the wire per character: start + data + parity + stop.
    pub const fn bits_per_char(self) -> u32 {
        1 + self.data_bits as u32
            + if matches!(self.parity, Parity::None) { 0 } else { 1 }
            + self.stop_bits as u32
    }

    /// The time one character takes at `baud` (1.146 ms for 11 bits at 9600).
    pub fn char_time(self, baud: u32) -> Duration {
        bits_time(self.bits_per_char(), baud)
    }

    /// The time `bytes` characters take back to back at `baud`.
    pub fn wire_time(self, baud: u32, bytes: usize) -> Duration {
        bits_time(self.bits_per_char() * bytes as u32, baud)
    }
}

/// The time `bits` bits take at `baud`, rounded up to the nanosecond.
pub fn bits_time(bits: u32, baud: u32) -> Duration {
    let baud = baud.max(1) as u64;
    Duration::from_nanos((bits as u64 * 1_000_000_000).div_ceil(baud))
}

/// Modbus t1.5 and t3.5 for `baud`: computed from the 11-bit character at 19200 baud and
/// below, fixed at 750 µs and 1.750 ms above (Modbus over Serial Line V1.02).
pub fn modbus_t15_t35(baud: u32) -> (Duration, Duration) {
    if baud > 19200 {
        (Duration::from_micros(750), Duration::from_micros(1750))
    } else {
        (bits_time(33, baud) / 2, bits_time(77, baud) / 2)
    }
}

impl fmt::Display for CharFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let p = match self.parity {
            Parity::None => 'N',
            Parity::Even => 'E',
            Parity::Odd => 'O',
        };
        write!(f, "{}{}{}", self.data_bits, p, self.stop_bits)
    }
}

/// Why a character format string did not parse.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BadCharFormat;

impl fmt::Display for BadCharFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(
            "a serial format is data bits (7 or 8), parity (N, E or O) and stop bits (1 or 2), e.g. 8E1",
        )
    }
}

impl FromStr for CharFormat {
    type Err = BadCharFormat;
    fn from_str(s: &str) -> Result<Self, BadCharFormat> {
        let b = s.as_bytes();
        if b.len() != 3 {
            return Err(BadCharFormat);
        }
        let data_bits = match b[0] {
            b'7' => 7,
            b'8' => 8,
            _ => return Err(BadCharFormat),
        };
        let parity = match b[1].to_ascii_uppercase() {
            b'N' => Parity::None,
            b'E' => Parity::Even,
            b'O' => Parity::Odd,
            _ => return Err(BadCharFormat),
        };
        let stop_bits = match b[2] {
            b'1' => 1,
            b'2' => 2,
            _ => return Err(BadCharFormat),
        };
        Ok(CharFormat { data_bits, parity, stop_bits })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn char_time_at_9600() {
        // 11 bits at 9600 baud = 1.1458 ms.
        let t = CharFormat::EVEN_8E1.char_time(9600);
        assert_eq!(t.as_micros(), 1145);
        assert_eq!(CharFormat::NONE_8N1.bits_per_char(), 10);
        assert_eq!(CharFormat::NONE_7N2.bits_per_char(), 10);
    }

    #[test]
    fn modbus_gaps() {
        let (t15, t35) = modbus_t15_t35(9600);
        assert_eq!(t15.as_micros(), 1718);
        assert_eq!(t35.as_micros(), 4010);
        let (t15, t35) = modbus_t15_t35(115200);
        assert_eq!((t15.as_micros(), t35.as_micros()), (750, 1750));
    }

    #[test]
    fn parse_formats() {
        assert_eq!("8E1".parse(), Ok(CharFormat::EVEN_8E1));
        assert_eq!("7n2".parse(), Ok(CharFormat::NONE_7N2));
        assert_eq!("9N1".parse::<CharFormat>(), Err(BadCharFormat));
        assert_eq!(CharFormat::NONE_8N2.to_string_buf(), *b"8N2");
    }

    impl CharFormat {
        fn to_string_buf(self) -> [u8; 3] {
            let p = match self.parity {
                Parity::None => b'N',
                Parity::Even => b'E',
                Parity::Odd => b'O',
            };
            [b'0' + self.data_bits, p, b'0' + self.stop_bits]
        }
    }
}
