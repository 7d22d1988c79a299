//! Hex bytes from the command line: `01 03 FD00`, `0x01,0x03`, `7E:38:31`, in one argument or many.

use anyhow::{bail, Result};

/// Parses every argument as hex bytes and concatenates them.
///
/// Separators between bytes may be spaces, commas, colons, dashes or nothing; a `0x` prefix is
/// allowed per group. Each group must have an even number of digits.
pub fn parse_hex_args(args: &[String]) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    for (i, arg) in args.iter().enumerate() {
        for group in arg.split(|c: char| c.is_whitespace() || matches!(c, ',' | ':' | '-' | ';')) {
            if group.is_empty() {
                continue;
            }
            let digits = group.strip_prefix("0x").or_else(|| group.strip_prefix("0X")).unwrap_or(group);
            if let Some((pos, c)) = digits.char_indices().find(|(_, c)| !c.is_ascii_hexdigit()) {
                bail!(
                    "argument {} has {:?} at character {} of {:?}: give the bytes as hex, e.g. 7E 38 31 35 32 32 46 7F",
                    i + 1,
                    c,
                    pos + 1,
                    group
                );
            }
            if digits.len() % 2 != 0 {
                bail!(
                    "argument {} has an odd number of hex digits in {:?}: each byte is two digits (write 0A, not A)",
                    i + 1,
                    group
                );
            }
            for pair in digits.as_bytes().chunks(2) {
                let s = std::str::from_utf8(pair).expect("ascii hex digits");
                out.push(u8::from_str_radix(s, 16).expect("checked hex digits"));
            }
        }
    }
    if out.is_empty() {
        bail!("no bytes given: pass the bytes on the wire in hex, e.g. drivebus decode --protocol b800 7E 38 31 35 32 32 46 7F");
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(v: &[&str]) -> Vec<String> {
        v.iter().map(|x| x.to_string()).collect()
    }

    #[test]
    fn accepts_common_spellings() {
        assert_eq!(parse_hex_args(&s(&["01 03", "FD00"])).unwrap(), [1, 3, 0xFD, 0]);
        assert_eq!(parse_hex_args(&s(&["0x01,0x03"])).unwrap(), [1, 3]);
        assert_eq!(parse_hex_args(&s(&["7e:38"])).unwrap(), [0x7E, 0x38]);
    }

    #[test]
    fn rejects_bad_digits_with_a_reason() {
        let e = parse_hex_args(&s(&["01", "0G"])).unwrap_err().to_string();
        assert!(e.contains("argument 2") && e.contains("'G'"), "{e}");
        let e = parse_hex_args(&s(&["013"])).unwrap_err().to_string();
        assert!(e.contains("odd number"), "{e}");
        assert!(parse_hex_args(&s(&[" "])).is_err());
    }
}
