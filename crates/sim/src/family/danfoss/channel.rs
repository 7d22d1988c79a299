//! The parameter channel of the FC telegram: PKE (AK and PNU), IND and PWE.
//!
//! seed 003 (`seeds/003_26a4c04ca1af5f26.txt`) 5.4.7: "Bits 12–15 transfer parameter commands
//! from master to slave and return processed slave responses to the master." Table 5.5 gives
//! the commands, Table 5.6 the responses; "If the command cannot be performed, the slave sends
//! this response 0111 Command cannot be performed and issues the following fault report"
//! (the fault codes of protocols.md 2.4, in PWElow).

use drivebus_drive::{ParamDef, Size, Storage, WriteError};
use drivebus_proto::fc::{FaultCode, ParameterCommand, ParameterNumber, ParameterResponse};

use super::State;

/// The most text characters a reply carries (the codec's text-block limit).
const MAX_TEXT: usize = 100;

/// What the drive answers in the parameter part of its reply.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) enum Answer {
    /// A process block: STW and MAV only.
    Process,
    /// A parameter block.
    Param {
        /// The response.
        ak: ParameterResponse,
        /// The PNU, echoed.
        pnu: ParameterNumber,
        /// IND, echoed.
        ind: u16,
        /// The value, description element or fault code.
        pwe: u32,
    },
    /// A text block.
    Text {
        /// AK F (text) or AK 3 (the name element).
        ak: ParameterResponse,
        /// The PNU, echoed.
        pnu: ParameterNumber,
        /// IND, echoed.
        ind: u16,
        /// The characters.
        text: Vec<u8>,
    },
}

impl Answer {
    /// AK 7 "command cannot be performed" with `code` in PWElow; PNU and IND echoed.
    pub(super) fn fault(pnu: ParameterNumber, ind: u16, code: FaultCode) -> Answer {
        Answer::Param { ak: ParameterResponse::CannotPerform, pnu, ind, pwe: u32::from(code.0) }
    }
}

/// The FC fault code for a refused write (protocols.md 2.4).
fn fault_of(error: &WriteError) -> FaultCode {
    match error {
        WriteError::UnknownParameter { .. } => FaultCode::ILLEGAL_PARAMETER_NUMBER,
        WriteError::ReadOnly { .. } => FaultCode::CANNOT_BE_CHANGED,
        WriteError::OutOfRange(_) => FaultCode::LIMIT_EXCEEDED,
        WriteError::NotWhileRunning { .. } => FaultCode::NOT_WHILE_RUNNING,
        WriteError::NoSuchElement { .. } => FaultCode::SUBINDEX_CORRUPTED,
    }
}

/// A raw value as PWE: a word in PWElow (two's complement, PWEhigh 0), a double word in all
/// 32 bits (two's complement).
fn to_pwe(raw: i64, size: Size) -> u32 {
    match size {
        Size::Word => u32::from(raw as u16),
        Size::Dword => raw as u32,
    }
}

/// PWE as a raw value of `def`: PWElow for a word, all of PWE for a double word; signed when
/// the parameter's range goes below 0 (Int16/Int32), else unsigned.
fn from_pwe(pwe: u32, def: &ParamDef) -> i64 {
    let signed = def.min < 0;
    match def.size {
        Size::Word if signed => i64::from(pwe as u16 as i16),
        Size::Word => i64::from(pwe as u16),
        Size::Dword if signed => i64::from(pwe as i32),
        Size::Dword => i64::from(pwe),
    }
}

/// The FC data type code (protocols.md 2.5): Int16 3, Int32 4, Uint8 5, Uint16 6, Uint32 7.
/// The catalog gives the width and the range; a word whose range fits a byte is a Uint8.
fn data_type(def: &ParamDef) -> u32 {
    match def.size {
        Size::Word if def.min < 0 => 3,
        Size::Word if def.max <= 255 => 5,
        Size::Word => 6,
        Size::Dword if def.min < 0 => 4,
        Size::Dword => 7,
    }
}

/// Description element 4: "The conversion index is in the high byte of PWElow and the unit
/// index is in the low byte of PWElow. Conversion index is signed 8 and unit index is
/// unsigned 8" (FC 300 Design Guide, conversion and unit of measurement).
fn unit_element(def: &ParamDef) -> u32 {
    let decimal = -i32::from(def.scale);
    let (unit_index, conversion) = match def.unit.as_str() {
        "s" => (4, decimal),
        "h" => (4, 74),
        // The catalog shows kW with 2 decimals for 10 W steps: W with conversion index 1.
        "kW" => (9, decimal + 3),
        "rpm" => (11, 67),
        "°C" => (17, 100),
        "V" => (21, decimal),
        "A" => (22, decimal),
        "%" => (24, decimal),
        "Hz" => (28, decimal),
        _ => (0, decimal),
    };
    u32::from(conversion as i8 as u8) << 8 | unit_index
}

/// A text as the drive sends it: ASCII, at most [`MAX_TEXT`] characters.
fn wire_text(text: &str) -> Vec<u8> {
    text.chars().take(MAX_TEXT).map(|c| if c.is_ascii() { c as u8 } else { b'?' }).collect()
}

impl State {
    /// A parameter block's command.
    pub(super) fn parameter(
        &mut self,
        ak: ParameterCommand,
        pnu: ParameterNumber,
        ind: u16,
        pwe: u32,
    ) -> Answer {
        match ak {
            // Table 5.5 "No command." / Table 5.6 "No response."
            ParameterCommand::NoCommand => {
                Answer::Param { ak: ParameterResponse::NoResponse, pnu, ind, pwe: 0 }
            }
            ParameterCommand::ReadValue => self.read(pnu, ind),
            ParameterCommand::WriteRamWord => self.write(pnu, ind, pwe, Size::Word, Storage::Ram),
            ParameterCommand::WriteRamDoubleWord => self.write(pnu, ind, pwe, Size::Dword, Storage::Ram),
            ParameterCommand::WriteRamEepromWord => self.write(pnu, ind, pwe, Size::Word, Storage::Eeprom),
            ParameterCommand::WriteRamEepromDoubleWord => {
                self.write(pnu, ind, pwe, Size::Dword, Storage::Eeprom)
            }
            ParameterCommand::ReadDescription => self.describe(pnu, ind),
            ParameterCommand::Text => self.text(pnu, ind),
        }
    }

    /// A text block from the master: AK F reads or writes a text; any other AK in a text block
    /// is "other error".
    pub(super) fn text_block(&mut self, ak: ParameterCommand, pnu: ParameterNumber, ind: u16) -> Answer {
        match ak {
            ParameterCommand::Text => self.text(pnu, ind),
            _ => Answer::fault(pnu, ind, FaultCode::OTHER_ERROR),
        }
    }

    /// The catalog entry of `pnu`, or fault 0, and the array index of IND's low byte
    /// (protocols.md 2.5: "Only the low byte is used as the array index"), or fault 4 / 3.
    fn element(&self, pnu: ParameterNumber, ind: u16) -> Result<(ParamDef, usize), FaultCode> {
        let def = self
            .core
            .params
            .catalog()
            .by_number(u32::from(pnu.pnu()))
            .ok_or(FaultCode::ILLEGAL_PARAMETER_NUMBER)?
            .clone();
        let index = usize::from(ind & 0xFF);
        if def.array.is_none() && index != 0 {
            return Err(FaultCode::NO_ARRAY);
        }
        if index >= def.len() {
            return Err(FaultCode::SUBINDEX_CORRUPTED);
        }
        Ok((def, index))
    }

    /// The value reply: AK 1 for a word parameter, AK 2 for a double word (project decision).
    fn value(def: &ParamDef, pnu: ParameterNumber, ind: u16, raw: i64) -> Answer {
        let ak = match def.size {
            Size::Word => ParameterResponse::ValueWord,
            Size::Dword => ParameterResponse::ValueDoubleWord,
        };
        Answer::Param { ak, pnu, ind, pwe: to_pwe(raw, def.size) }
    }

    /// AK 1 "Read parameter value."
    fn read(&mut self, pnu: ParameterNumber, ind: u16) -> Answer {
        let (def, index) = match self.element(pnu, ind) {
            Ok(found) => found,
            Err(code) => return Answer::fault(pnu, ind, code),
        };
        match self.core.params.get_element(def.name.as_str(), index) {
            Some(raw) => Self::value(&def, pnu, ind, raw),
            None => Answer::fault(pnu, ind, FaultCode::SUBINDEX_CORRUPTED),
        }
    }

    /// AK 2/3 "Write parameter value in RAM (word/double word)", AK E/D "... in RAM and
    /// EEPROM". The reply returns the value written, as AK 1 or AK 2.
    fn write(&mut self, pnu: ParameterNumber, ind: u16, pwe: u32, size: Size, storage: Storage) -> Answer {
        let (def, index) = match self.element(pnu, ind) {
            Ok(found) => found,
            Err(code) => return Answer::fault(pnu, ind, code),
        };
        if def.read_only {
            return Answer::fault(pnu, ind, FaultCode::CANNOT_BE_CHANGED);
        }
        // Decision: the AK's width must be the parameter's (Int16/Uint16/Uint8 with AK 2/E,
        // Int32/Uint32 with AK 3/D), else fault 5 "wrong data type".
        if def.size != size {
            return Answer::fault(pnu, ind, FaultCode::WRONG_DATA_TYPE);
        }
        let raw = from_pwe(pwe, &def);
        let running = self.core.model.is_running();
        // 8-31 Address: "1-126 with the FC protocol" (the catalog allows 247 for Modbus RTU).
        if def.name == "8-31" && !(1..=126).contains(&raw) {
            return Answer::fault(pnu, ind, FaultCode::LIMIT_EXCEEDED);
        }
        if let Err(e) = self.core.params.set_element(def.name.as_str(), index, raw, storage, running) {
            return Answer::fault(pnu, ind, fault_of(&e));
        }
        if def.name == "8-31" {
            self.core.address = raw as u8;
        }
        self.apply_settings();
        // 3-00/3-02/3-03, 4-10, 8-54 change what the last bus reference means; a drive that
        // never had a valid control word keeps the setpoint it has.
        if self.ctw.data_valid() {
            self.apply_reference();
        }
        Self::value(&def, pnu, ind, raw)
    }

    /// AK 4: read description element IND, answered with AK 3.
    fn describe(&mut self, pnu: ParameterNumber, ind: u16) -> Answer {
        let Some(def) = self.core.params.catalog().by_number(u32::from(pnu.pnu())).cloned() else {
            return Answer::fault(pnu, ind, FaultCode::ILLEGAL_PARAMETER_NUMBER);
        };
        let numeric = |pwe: u32| Answer::Param { ak: ParameterResponse::Description, pnu, ind, pwe };
        match ind {
            1 => {
                // FC 300 example: PWElow 0405 = "additional text available" + type 5 (Uint8).
                let text = if def.choices.is_empty() { 0 } else { 0x0400 };
                let read_only = if def.read_only { 0x0200 } else { 0 };
                let array = if def.array.is_some() { 0x4000 } else { 0 };
                numeric(array | text | read_only | data_type(&def))
            }
            2 => numeric(def.len() as u32),
            4 => numeric(unit_element(&def)),
            6 => Answer::Text { ak: ParameterResponse::Description, pnu, ind, text: wire_text(&def.title) },
            7 => numeric(to_pwe(def.min, def.size)),
            8 => numeric(to_pwe(def.max, def.size)),
            20 => numeric(to_pwe(def.default, def.size)),
            _ => Answer::fault(pnu, ind, FaultCode::NO_DESCRIPTION_ELEMENT),
        }
    }

    /// AK F: IND 04xx (or 0000) reads the parameter's name, IND 00nn the text of value nn - 1,
    /// IND 05xx writes a text (refused: no catalog parameter is a text string).
    fn text(&mut self, pnu: ParameterNumber, ind: u16) -> Answer {
        let Some(def) = self.core.params.catalog().by_number(u32::from(pnu.pnu())).cloned() else {
            return Answer::fault(pnu, ind, FaultCode::ILLEGAL_PARAMETER_NUMBER);
        };
        let text = match (ind >> 8, ind & 0xFF) {
            (0x04, _) | (0x00, 0) => wire_text(&def.title),
            (0x00, n) => match def.choice(i64::from(n) - 1) {
                Some(t) => wire_text(t),
                None => return Answer::fault(pnu, ind, FaultCode::NO_TEXT),
            },
            (0x05, _) => return Answer::fault(pnu, ind, FaultCode::WRONG_DATA_TYPE),
            _ => return Answer::fault(pnu, ind, FaultCode::NO_TEXT),
        };
        Answer::Text { ak: ParameterResponse::Text, pnu, ind, text }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use drivebus_drive::{Catalog, Family};

    fn def(name: &str) -> ParamDef {
        Catalog::load(Family::Danfoss).unwrap().get(name).unwrap().clone()
    }

    #[test]
    fn pwe_round_trips_signed_and_unsigned() {
        let preset = def("3-10");
        assert_eq!(to_pwe(-100, preset.size), 0x0000_FF9C);
        assert_eq!(from_pwe(0x0000_FF9C, &preset), -100);
        let min_ref = def("3-02");
        assert_eq!(to_pwe(-1000, min_ref.size), 0xFFFF_FC18);
        assert_eq!(from_pwe(0xFFFF_FC18, &min_ref), -1000);
        let high = def("4-14");
        assert_eq!(from_pwe(0xFFFF_03E8, &high), 1000, "a word write reads PWElow only");
        assert_eq!(from_pwe(0x0000_FFFF, &high), 65535);
    }

    #[test]
    fn description_codes() {
        assert_eq!(data_type(&def("0-01")), 5, "0-01 Language is a Uint8");
        assert_eq!(data_type(&def("4-14")), 6);
        assert_eq!(data_type(&def("3-10")), 3);
        assert_eq!(data_type(&def("3-41")), 7);
        assert_eq!(data_type(&def("3-02")), 4);
        // Conversion index -1 (0xFF) and unit index 28 (Hz).
        assert_eq!(unit_element(&def("4-14")), 0xFF1C);
        assert_eq!(unit_element(&def("16-14")), 0xFE16);
        assert_eq!(unit_element(&def("1-25")), 0x430B);
        assert_eq!(unit_element(&def("1-20")), 0x0109);
        assert_eq!(wire_text("Heatsink Temp."), b"Heatsink Temp.");
        assert_eq!(wire_text("25 °C"), b"25 ?C");
    }
}
