//! The parameter channel: PKE = AK (bits 15–12) | PNU (bits 11–0), IND, PWE.
//!
//! seed 003 (`seeds/003_26a4c04ca1af5f26.txt`), 5.4.7: "Bits 12–15 transfer parameter commands
//! from master to slave and return processed slave responses to the master."

use core::fmt;
use core::str::FromStr;

/// A parameter number: `4-14` on the drive's display is PNU 414 on the wire (the number
/// written without the dash, as a decimal number). PKE holds it in bits 0–11, so 0–4095.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ParameterNumber(u16);

impl ParameterNumber {
    /// The largest PNU that fits in PKE bits 0–11.
    pub const MAX: u16 = 0x0FFF;

    /// The parameter with PNU `pnu`, if it fits in 12 bits.
    pub const fn new(pnu: u16) -> Option<ParameterNumber> {
        if pnu <= Self::MAX {
            Some(ParameterNumber(pnu))
        } else {
            None
        }
    }
    /// Parameter `group-number` (`4-14` is `from_parts(4, 14)`), if it is a valid number.
    pub const fn from_parts(group: u16, number: u16) -> Option<ParameterNumber> {
        if number > 99 || group > 40 {
            return None;
        }
        Self::new(group * 100 + number)
    }
    /// The PNU, as carried in PKE bits 0–11 (`4-14` gives 414).
    pub const fn pnu(self) -> u16 {
        self.0
    }
    /// The part before the dash (4 for `4-14`).
    pub const fn group(self) -> u16 {
        self.0 / 100
    }
    /// The part after the dash (14 for `4-14`).
    pub const fn number(self) -> u16 {
        self.0 % 100
    }
    /// Writes `g-nn` into `buf`; returns the bytes written (at most 5).
    pub fn write_ascii(self, buf: &mut [u8; 5]) -> usize {
        let g = self.group();
        let n = self.number();
        let mut i = 0;
        if g >= 10 {
            buf[i] = b'0' + (g / 10) as u8;
            i += 1;
        }
        buf[i] = b'0' + (g % 10) as u8;
        buf[i + 1] = b'-';
        buf[i + 2] = b'0' + (n / 10) as u8;
        buf[i + 3] = b'0' + (n % 10) as u8;
        i + 4
    }
}

impl fmt::Display for ParameterNumber {
    /// `4-14`, `0-01`, `16-14`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-{:02}", self.group(), self.number())
    }
}

/// Why a parameter number did not parse.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParameterNumberError {
    /// Not `g-nn` (two digits after the dash) nor a plain PNU.
    Syntax,
    /// The PNU does not fit in PKE bits 0–11.
    TooLarge,
}

impl fmt::Display for ParameterNumberError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ParameterNumberError::Syntax => f.write_str(
                "a parameter number is group-number with two digits after the dash (4-14) or a PNU (414)",
            ),
            ParameterNumberError::TooLarge => {
                f.write_str("parameter number too large: PNU is 0..4095 (up to 40-95)")
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for ParameterNumberError {}

impl FromStr for ParameterNumber {
    type Err = ParameterNumberError;
    /// `4-14` (exactly two digits after the dash) or a plain PNU such as `414` (older VLT
    /// parameter numbers such as `520` have no dash).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        let (group, number) = match s.split_once('-') {
            Some((g, n)) => {
                if n.len() != 2 {
                    return Err(ParameterNumberError::Syntax);
                }
                (digits(g)?, digits(n)?)
            }
            None => (0, digits(s)?),
        };
        let pnu = group
            .checked_mul(100)
            .and_then(|g| g.checked_add(number))
            .ok_or(ParameterNumberError::TooLarge)?;
        if pnu > u32::from(Self::MAX) {
            return Err(ParameterNumberError::TooLarge);
        }
        Ok(ParameterNumber(pnu as u16))
    }
}

/// A run of 1..=9 ASCII digits as a number.
fn digits(s: &str) -> Result<u32, ParameterNumberError> {
    if s.is_empty() || s.len() > 9 {
        return Err(if s.len() > 9 { ParameterNumberError::TooLarge } else { ParameterNumberError::Syntax });
    }
    let mut v = 0u32;
    for c in s.bytes() {
        if !c.is_ascii_digit() {
            return Err(ParameterNumberError::Syntax);
        }
        v = v * 10 + u32::from(c - b'0');
    }
    Ok(v)
}

/// AK from the master: seed 003 Table 5.5 "Parameter Commands", plus AK 4 from the FC 300
/// Design Guide (protocols.md 2.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ParameterCommand {
    /// 0: "No command." Nothing is read or written.
    NoCommand = 0x0,
    /// 1: "Read parameter value."
    ReadValue = 0x1,
    /// 2: "Write parameter value in RAM (word)."
    WriteRamWord = 0x2,
    /// 3: "Write parameter value in RAM (double word)."
    WriteRamDoubleWord = 0x3,
    /// 4: read parameter description element (IND = element number).
    ReadDescription = 0x4,
    /// D: "Write parameter value in RAM and EEPROM (double word)."
    WriteRamEepromDoubleWord = 0xD,
    /// E: "Write parameter value in RAM and EEPROM (word)."
    WriteRamEepromWord = 0xE,
    /// F: "Read text." (IND high byte 04 = read, 05 = write text.)
    ///
    /// seed 003 Table 5.5 names F "Read text." only, but its 5.4.6 says "The text block is
    /// used to read or write texts", and protocols.md 2.5 gives IND 05xx for writing: so
    /// drivebus calls it "read/write text".
    Text = 0xF,
}

impl ParameterCommand {
    /// The command for AK `ak` (0–15), if the master table has it.
    pub const fn from_ak(ak: u8) -> Option<ParameterCommand> {
        Some(match ak {
            0x0 => ParameterCommand::NoCommand,
            0x1 => ParameterCommand::ReadValue,
            0x2 => ParameterCommand::WriteRamWord,
            0x3 => ParameterCommand::WriteRamDoubleWord,
            0x4 => ParameterCommand::ReadDescription,
            0xD => ParameterCommand::WriteRamEepromDoubleWord,
            0xE => ParameterCommand::WriteRamEepromWord,
            0xF => ParameterCommand::Text,
            _ => return None,
        })
    }
    /// The AK code.
    pub const fn ak(self) -> u8 {
        self as u8
    }
    /// The manual's name.
    pub const fn name(self) -> &'static str {
        match self {
            // FC 300 DG errata (protocols.md 2.10): its "read 16-14" example carries AK 0.
            ParameterCommand::NoCommand => "no command: nothing is read or written",
            ParameterCommand::ReadValue => "read parameter value",
            ParameterCommand::WriteRamWord => "write parameter value in RAM (word)",
            ParameterCommand::WriteRamDoubleWord => "write parameter value in RAM (double word)",
            ParameterCommand::ReadDescription => "read parameter description element",
            ParameterCommand::WriteRamEepromDoubleWord => {
                "write parameter value in RAM and EEPROM (double word)"
            }
            ParameterCommand::WriteRamEepromWord => "write parameter value in RAM and EEPROM (word)",
            ParameterCommand::Text => "read/write text",
        }
    }
    /// True for the four write commands (their value is in PWE).
    pub const fn is_write(self) -> bool {
        matches!(
            self,
            ParameterCommand::WriteRamWord
                | ParameterCommand::WriteRamDoubleWord
                | ParameterCommand::WriteRamEepromDoubleWord
                | ParameterCommand::WriteRamEepromWord
        )
    }
}

/// AK from the drive: seed 003 Table 5.6 "Response", plus AK 3 from the FC 300 Design Guide.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ParameterResponse {
    /// 0: "No response."
    NoResponse = 0x0,
    /// 1: "Parameter value transferred (word)."
    ValueWord = 0x1,
    /// 2: "Parameter value transferred (double word)."
    ValueDoubleWord = 0x2,
    /// 3: description element transferred.
    Description = 0x3,
    /// 7: "Command cannot be performed." The fault code is in PWElow.
    CannotPerform = 0x7,
    /// F: "Text transferred."
    Text = 0xF,
}

impl ParameterResponse {
    /// The response for AK `ak` (0–15), if the drive table has it.
    pub const fn from_ak(ak: u8) -> Option<ParameterResponse> {
        Some(match ak {
            0x0 => ParameterResponse::NoResponse,
            0x1 => ParameterResponse::ValueWord,
            0x2 => ParameterResponse::ValueDoubleWord,
            0x3 => ParameterResponse::Description,
            0x7 => ParameterResponse::CannotPerform,
            0xF => ParameterResponse::Text,
            _ => return None,
        })
    }
    /// The AK code.
    pub const fn ak(self) -> u8 {
        self as u8
    }
    /// The manual's name.
    pub const fn name(self) -> &'static str {
        match self {
            ParameterResponse::NoResponse => "no response",
            ParameterResponse::ValueWord => "parameter value transferred (word)",
            ParameterResponse::ValueDoubleWord => "parameter value transferred (double word)",
            ParameterResponse::Description => "description element transferred",
            ParameterResponse::CannotPerform => "command cannot be performed",
            ParameterResponse::Text => "text transferred",
        }
    }
}

/// The fault code a drive sends in PWElow with AK 7 "command cannot be performed"
/// (protocols.md 2.4, the decimal table of the FC 280/FC 360/FC 100 guides).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FaultCode(pub u16);

impl FaultCode {
    crate::error::named_codes! {
        FaultCode;
        /// What the code means, if the table has it.
        ///
        /// The older FC 100 / FC 322 guides print the same codes in hex (0x11, 0x82, 0x83):
        /// they are 17, 130 and 131 here (protocols.md 2.4).
        fn meaning also { 6 | 7 => "not used" };
        /// 0: illegal parameter number.
        ILLEGAL_PARAMETER_NUMBER(0) => "illegal parameter number",
        /// 1: parameter cannot be changed.
        CANNOT_BE_CHANGED(1) => "parameter cannot be changed",
        /// 2: upper or lower limit exceeded.
        LIMIT_EXCEEDED(2) => "upper or lower limit exceeded",
        /// 3: subindex corrupted.
        SUBINDEX_CORRUPTED(3) => "subindex corrupted",
        /// 4: no array.
        NO_ARRAY(4) => "no array",
        /// 5: wrong data type.
        WRONG_DATA_TYPE(5) => "wrong data type",
        /// 9: description element not available.
        NO_DESCRIPTION_ELEMENT(9) => "description element not available",
        /// 11: no parameter write access.
        NO_WRITE_ACCESS(11) => "no parameter write access",
        /// 15: no text available.
        NO_TEXT(15) => "no text available",
        /// 17: not while running.
        NOT_WHILE_RUNNING(17) => "not while running",
        /// 18: other error.
        OTHER_ERROR(18) => "other error",
        /// 130: no bus access for this parameter.
        NO_BUS_ACCESS(130) => "no bus access for this parameter",
        /// 131: write to factory set-up not possible.
        FACTORY_SETUP(131) => "write to factory set-up not possible",
        /// 132: no LCP access.
        NO_LCP_ACCESS(132) => "no LCP access",
        /// 252: unknown viewer.
        UNKNOWN_VIEWER(252) => "unknown viewer",
        /// 253: request not supported.
        NOT_SUPPORTED(253) => "request not supported",
        /// 254: unknown attribute.
        UNKNOWN_ATTRIBUTE(254) => "unknown attribute",
        /// 255: no error.
        NO_ERROR(255) => "no error",
    }
}

impl fmt::Display for FaultCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)?;
        crate::error::write_meaning(f, self.meaning(), "not in the fault table")
    }
}

/// The name of description element `ind` (IND with AK 4 / AK 3), protocols.md 2.5.
pub const fn description_element(ind: u16) -> Option<&'static str> {
    Some(match ind {
        1 => "basic characteristics",
        2 => "number of elements",
        4 => "unit",
        6 => "name",
        7 => "lower limit",
        8 => "upper limit",
        20 => "default",
        21 => "additional characteristics",
        _ => return None,
    })
}

/// The name of data type `code` (low byte of the basic characteristics), protocols.md 2.5.
pub const fn data_type(code: u8) -> Option<&'static str> {
    Some(match code {
        3 => "Int16",
        4 => "Int32",
        5 => "Uint8",
        6 => "Uint16",
        7 => "Uint32",
        9 => "text string",
        10 => "byte string",
        13 => "time difference",
        33 => "reserved",
        35 => "bit sequence",
        _ => return None,
    })
}

/// IND high byte for a text read (AK F).
pub const IND_READ_TEXT: u8 = 0x04;
/// IND high byte for a text write (AK F).
pub const IND_WRITE_TEXT: u8 = 0x05;

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::string::ToString;

    #[test]
    fn parameter_numbers() {
        // protocols.md 2.4: 4-14 = 414 = 0x19E, 3-41 = 0x155, 16-14 = 0x64E, 15-30 = 0x5FA, 0-01 = 1.
        for (s, pnu) in [("4-14", 0x19E), ("3-41", 0x155), ("16-14", 0x64E), ("15-30", 0x5FA), ("0-01", 1)] {
            let p: ParameterNumber = s.parse().unwrap();
            assert_eq!(p.pnu(), pnu, "{s}");
            assert_eq!(p.to_string(), s);
            let mut b = [0; 5];
            let n = p.write_ascii(&mut b);
            assert_eq!(&b[..n], s.as_bytes());
        }
        assert_eq!("520".parse::<ParameterNumber>().unwrap().pnu(), 0x208);
        assert_eq!("40-95".parse::<ParameterNumber>().unwrap().pnu(), 4095);
        assert_eq!("40-96".parse::<ParameterNumber>(), Err(ParameterNumberError::TooLarge));
        assert_eq!("4096".parse::<ParameterNumber>(), Err(ParameterNumberError::TooLarge));
        assert_eq!("99999999999".parse::<ParameterNumber>(), Err(ParameterNumberError::TooLarge));
        for bad in ["4-1", "4-141", "-14", "4-", "a-14", "", "4_14", "4--14", "+414"] {
            assert_eq!(bad.parse::<ParameterNumber>(), Err(ParameterNumberError::Syntax), "{bad}");
        }
        assert_eq!(ParameterNumber::from_parts(4, 14), ParameterNumber::new(414));
        assert_eq!(ParameterNumber::from_parts(4, 100), None);
        assert_eq!(ParameterNumber::new(4096), None);
        assert_eq!(ParameterNumber::new(1).unwrap().to_string(), "0-01");
    }

    #[test]
    fn ak_tables() {
        for ak in 0..16u8 {
            if let Some(c) = ParameterCommand::from_ak(ak) {
                assert_eq!(c.ak(), ak);
            }
            if let Some(r) = ParameterResponse::from_ak(ak) {
                assert_eq!(r.ak(), ak);
            }
        }
        let masters: std::vec::Vec<u8> =
            (0..16).filter(|&a| ParameterCommand::from_ak(a).is_some()).collect();
        assert_eq!(masters, [0, 1, 2, 3, 4, 0xD, 0xE, 0xF]);
        let drives: std::vec::Vec<u8> =
            (0..16).filter(|&a| ParameterResponse::from_ak(a).is_some()).collect();
        assert_eq!(drives, [0, 1, 2, 3, 7, 0xF]);
    }

    #[test]
    fn fault_table() {
        for c in [0, 1, 2, 3, 4, 5, 9, 11, 15, 17, 18, 130, 131, 132, 252, 253, 254, 255] {
            assert!(FaultCode(c).meaning().is_some(), "{c}");
        }
        assert_eq!(FaultCode(0x11).to_string(), "17 (not while running)");
        assert_eq!(FaultCode(0x82).to_string(), "130 (no bus access for this parameter)");
        assert_eq!(FaultCode(100).to_string(), "100 (not in the fault table)");
    }
}
