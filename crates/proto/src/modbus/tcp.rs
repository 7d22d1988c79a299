//! Modbus TCP's MBAP header (Modbus Messaging on TCP/IP Implementation Guide V1.0b): the seven
//! bytes before the PDU, `transaction (2) protocol (2) length (2) unit (1)`, where `length`
//! counts the unit byte and the PDU.

use crate::checksum::crc16_modbus;
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

/// The Modbus TCP frame of a Modbus RTU frame (`unit PDU CRC`, its CRC already checked or
/// computed by whoever made it) numbered `transaction`, written into `out`; returns its length.
/// How a master that frames its requests as RTU (the drive profiles) speaks to a Modbus TCP
/// device: the unit is the RTU address, the CRC is dropped.
pub fn mbap_from_rtu(transaction: u16, rtu: &[u8], out: &mut [u8]) -> Result<usize, EmitError> {
    if rtu.len() < 4 || rtu.len() - 3 > MAX_PDU {
        return Err(EmitError::Invalid("a Modbus RTU frame has an address, 1..253 bytes of PDU and a CRC"));
    }
    let pdu = &rtu[1..rtu.len() - 2];
    crate::error::need(out, MBAP_LEN + pdu.len())?;
    Mbap::request(transaction, rtu[0], pdu.len()).emit(out)?;
    out[MBAP_LEN..MBAP_LEN + pdu.len()].copy_from_slice(pdu);
    Ok(MBAP_LEN + pdu.len())
}

/// The Modbus RTU frame (`unit PDU CRC`, the CRC computed) of a whole Modbus TCP frame, written
/// into `out`; returns its length. `frame` is one frame as [`Mbap::next_frame`] found it.
pub fn rtu_from_mbap(frame: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    let Some((header, len)) = Mbap::next_frame(frame)? else {
        return Err(FrameError::Truncated {
            what: "Modbus TCP frame",
            expected: MBAP_LEN.max(frame.len() + 1),
            got: frame.len(),
        });
    };
    let pdu = &frame[MBAP_LEN..len];
    let n = pdu.len() + 3;
    if out.len() < n {
        return Err(FrameError::TooLong { what: "Modbus RTU frame", max: out.len(), got: n });
    }
    out[0] = header.unit;
    out[1..n - 2].copy_from_slice(pdu);
    let crc = crc16_modbus(&out[..n - 2]);
    out[n - 2..n].copy_from_slice(&crc.to_le_bytes());
    Ok(n)
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
    }

    #[test]
    fn rtu_frames_cross_to_mbap_and_back() {
        // Read holding register 0x2100, one register, drive 1 (CRC 8E36 sent low byte first).
        let rtu = [0x01, 0x03, 0x21, 0x00, 0x00, 0x01, 0x8E, 0x36];
        let mut tcp = [0u8; MAX_ADU];
        let n = mbap_from_rtu(7, &rtu, &mut tcp).unwrap();
        assert_eq!(&tcp[..n], [0, 7, 0, 0, 0, 6, 1, 0x03, 0x21, 0x00, 0x00, 0x01]);
        let mut back = [0u8; 260];
        let m = rtu_from_mbap(&tcp[..n], &mut back).unwrap();
        assert_eq!(back[..m], rtu, "the CRC is computed again");
        assert!(mbap_from_rtu(1, &rtu[..3], &mut tcp).is_err(), "no PDU");
        assert!(mbap_from_rtu(1, &rtu, &mut tcp[..8]).is_err(), "no room");
        assert!(rtu_from_mbap(&tcp[..n - 1], &mut back).is_err(), "cut short");
        assert!(rtu_from_mbap(&tcp[..n], &mut back[..5]).is_err(), "no room");
        assert!(Mbap::parse(&[0, 1, 0, 0, 0, 1, 1]).is_err(), "a PDU has a function code");
        assert!(Mbap::parse(&[0, 1, 0, 0, 0, 255, 1]).is_err(), "254 bytes at most");
    }
}
