//! Modbus TCP's MBAP header (Modbus Messaging on TCP/IP Implementation Guide V1.0b): the seven
//! bytes before the PDU, `transaction (2) protocol (2) length (2) unit (1)`, where `length`
//! counts the unit byte and the PDU.

use crate::error::{EmitError, FrameError};
use crate::modbus::pdu::MAX_PDU;

/// Bytes of the MBAP header.
pub const MBAP_LEN: usize = 7;
/// The longest Modbus TCP frame: the header and a 253-byte PDU.
pub const MAX_ADU: usize = MBAP_LEN + MAX_PDU;

/// An MBAP header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mbap {
    /// The transaction identifier the client chose; the answer repeats it.
    pub transaction: u16,
    /// The protocol identifier: 0 for Modbus.
    pub protocol: u16,
    /// Bytes that follow the length field: the unit byte and the PDU (2..=254).
    pub length: u16,
    /// The unit identifier (the drive behind a gateway).
    pub unit: u8,
}

impl Mbap {
    /// Reads the header at the start of `bytes`: `Ok(None)` until seven bytes are there; an
    /// error for a protocol other than Modbus or a length a PDU cannot have (after which
    /// nothing on the stream can be trusted to be framed right).
    pub fn parse(bytes: &[u8]) -> Result<Option<Mbap>, FrameError> {
        let &[t0, t1, p0, p1, l0, l1, unit, ..] = bytes else { return Ok(None) };
        let header = Mbap {
            transaction: u16::from_be_bytes([t0, t1]),
            protocol: u16::from_be_bytes([p0, p1]),
            length: u16::from_be_bytes([l0, l1]),
            unit,
        };
        if header.protocol != 0 {
            return Err(FrameError::Unknown {
                field: "MBAP protocol identifier",
                value: header.protocol as u32,
            });
        }
        crate::error::in_range("MBAP length", header.length as u32, 2, 1 + MAX_PDU as u32)?;
        Ok(Some(header))
    }

    /// The header of a request of `pdu_len` bytes to `unit`, numbered `transaction`.
    pub fn request(transaction: u16, unit: u8, pdu_len: usize) -> Mbap {
        Mbap { transaction, protocol: 0, length: 1 + pdu_len.min(MAX_PDU) as u16, unit }
    }

    /// The first whole frame of a stream: its header and length once all of it is in `bytes`
    /// (`Ok(None)` until then), an error where the header is damaged (see [`Mbap::parse`]).
    /// The one MBAP stream splitter: the gateway's server and bridge and the drive client read
    /// their streams with it.
    pub fn next_frame(bytes: &[u8]) -> Result<Option<(Mbap, usize)>, FrameError> {
        Ok(Mbap::parse(bytes)?.map(|h| (h, h.frame_len())).filter(|&(_, len)| bytes.len() >= len))
    }

    /// Bytes of the whole frame: header and PDU.
    pub fn frame_len(&self) -> usize {
        6 + self.length as usize
    }

    /// The header of the answer to this request, whose PDU takes `pdu_len` bytes.
    pub fn answer(&self, pdu_len: usize) -> Mbap {
        Mbap { length: 1 + pdu_len.min(MAX_PDU) as u16, ..*self }
    }

    /// Writes the header into `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, EmitError> {
        crate::error::need(out, MBAP_LEN)?;
        out[0..2].copy_from_slice(&self.transaction.to_be_bytes());
        out[2..4].copy_from_slice(&self.protocol.to_be_bytes());
        out[4..6].copy_from_slice(&self.length.to_be_bytes());
        out[6] = self.unit;
        Ok(MBAP_LEN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headers_read_back_and_bad_ones_are_named() {
        let h = Mbap { transaction: 0x1234, protocol: 0, length: 6, unit: 3 };
        let mut b = [0u8; MBAP_LEN];
        assert_eq!(h.emit(&mut b), Ok(MBAP_LEN));
        assert_eq!(b, [0x12, 0x34, 0, 0, 0, 6, 3]);
        assert_eq!(Mbap::parse(&b), Ok(Some(h)));
        assert_eq!(h.frame_len(), 12);
        assert_eq!(h.answer(5).length, 6);
        assert_eq!(Mbap::parse(&b[..6]), Ok(None));
        assert!(Mbap::parse(&[0, 1, 0, 1, 0, 6, 1]).is_err(), "protocol 1 is not Modbus");
        assert_eq!(Mbap::request(0x1234, 3, 5), h);
        let frame = [0x12, 0x34, 0, 0, 0, 6, 3, 3, 0, 0, 0, 1, 9];
        assert_eq!(Mbap::next_frame(&frame[..11]), Ok(None), "the PDU is not all there");
        assert_eq!(Mbap::next_frame(&frame), Ok(Some((h, 12))), "one frame and a byte of the next");
        assert!(Mbap::next_frame(&[0, 1, 0, 1, 0, 6, 1, 3]).is_err());
        assert!(Mbap::parse(&[0, 1, 0, 0, 0, 1, 1]).is_err(), "a PDU has a function code");
        assert!(Mbap::parse(&[0, 1, 0, 0, 0, 255, 1]).is_err(), "254 bytes at most");
    }
}
