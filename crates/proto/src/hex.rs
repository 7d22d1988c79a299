//! Hex-ASCII digits, as the ASCII protocols (Modbus ASCII, Toshiba ASCII, B800) carry bytes.

/// Upper-case hex digits, the form every drivebus transmitter uses.
const DIGITS: &[u8; 16] = b"0123456789ABCDEF";

/// The value of one hex digit, upper or lower case; `None` for any other byte.
#[inline]
pub const fn digit_value(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'A'..=b'F' => Some(c - b'A' + 10),
        b'a'..=b'f' => Some(c - b'a' + 10),
        _ => None,
    }
}

/// True for `0-9 A-F a-f`.
#[inline]
pub const fn is_hex_digit(c: u8) -> bool {
    digit_value(c).is_some()
}

/// The upper-case hex digit for the low nibble of `n`.
#[inline]
pub const fn nibble_digit(n: u8) -> u8 {
    DIGITS[(n & 0x0F) as usize]
}

/// The two upper-case hex digits of `b`, high nibble first.
#[inline]
pub const fn byte_digits(b: u8) -> [u8; 2] {
    [nibble_digit(b >> 4), nibble_digit(b)]
}

/// Decodes two hex digits (high nibble first) into a byte.
#[inline]
pub const fn decode_pair(hi: u8, lo: u8) -> Option<u8> {
    match (digit_value(hi), digit_value(lo)) {
        (Some(h), Some(l)) => Some(h << 4 | l),
        _ => None,
    }
}

/// Decodes `2 * out.len()` hex digits from `digits` into `out`.
///
/// Returns the offset in `digits` of the first non-hex byte on failure.
pub fn decode_into(digits: &[u8], out: &mut [u8]) -> Result<(), usize> {
    debug_assert!(digits.len() >= out.len() * 2);
    for (i, o) in out.iter_mut().enumerate() {
        let hi = digits[2 * i];
        let lo = digits[2 * i + 1];
        *o = match decode_pair(hi, lo) {
            Some(b) => b,
            None => return Err(if is_hex_digit(hi) { 2 * i + 1 } else { 2 * i }),
        };
    }
    Ok(())
}

/// Decodes a run of 1..=8 hex digits as a number.
pub fn decode_number(digits: &[u8]) -> Option<u32> {
    if digits.is_empty() || digits.len() > 8 {
        return None;
    }
    let mut v = 0u32;
    for &c in digits {
        v = v << 4 | digit_value(c)? as u32;
    }
    Some(v)
}

/// Writes `bytes` as upper-case hex digits into `out`, which must hold `2 * bytes.len()`.
pub fn encode_into(bytes: &[u8], out: &mut [u8]) {
    for (i, &b) in bytes.iter().enumerate() {
        let [h, l] = byte_digits(b);
        out[2 * i] = h;
        out[2 * i + 1] = l;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_every_byte() {
        for b in 0..=255u8 {
            let [h, l] = byte_digits(b);
            assert_eq!(decode_pair(h, l), Some(b));
            assert_eq!(decode_pair(h.to_ascii_lowercase(), l.to_ascii_lowercase()), Some(b));
        }
    }

    #[test]
    fn rejects_non_hex() {
        assert_eq!(digit_value(b'G'), None);
        assert_eq!(digit_value(b':'), None);
        let mut out = [0u8; 2];
        assert_eq!(decode_into(b"0G12", &mut out), Err(1));
        assert_eq!(decode_into(b"01x2", &mut out), Err(2));
        assert_eq!(decode_number(b"0960"), Some(0x0960));
        assert_eq!(decode_number(b""), None);
    }
}
