//! Modbus TCP as a framing of a TCP port: the engine and the drive profiles speak Modbus RTU
//! frames (`address PDU CRC`), and [`MbapFraming`] carries each one as an MBAP frame (unit id =
//! the address, the CRC dropped, a transaction id of its own) and turns the answers back into
//! RTU frames with their CRC computed. An answer whose transaction id is not the request's (a
//! late answer to an earlier attempt) is dropped, so it is never taken for the current one.
//! One request is in flight at a time (`max_in_flight` 1).
//!
//! The conversions are proto's ([`drivebus_proto::modbus::tcp`]), shared with the gateway's
//! Modbus TCP server and bridge and the simulator's Modbus TCP endpoint.

use std::io;

use drivebus_proto::modbus::tcp::{mbap_from_rtu, rtu_from_mbap, Mbap, MAX_ADU};

/// The default TCP port of Modbus TCP.
pub const MODBUS_TCP_PORT: u16 = 502;

/// The protocol name users give a bus whose Modbus frames go in MBAP over TCP.
pub const MODBUS_TCP: &str = "modbus-tcp";

/// `HOST[:PORT]` with Modbus TCP's port 502 where none is given (IPv6 in brackets:
/// `[::1]:502`).
pub fn with_default_port(addr: &str) -> String {
    let has_port = match addr.rsplit_once(':') {
        Some((host, port)) => {
            !port.is_empty()
                && port.bytes().all(|b| b.is_ascii_digit())
                && (!host.contains(':') || host.ends_with(']'))
        }
        None => false,
    };
    if has_port {
        addr.to_string()
    } else {
        format!("{addr}:{MODBUS_TCP_PORT}")
    }
}

/// The MBAP framing of one connection: the transaction ids it gives and expects, and what came
/// in that is not a whole frame yet.
#[derive(Debug, Default)]
pub struct MbapFraming {
    /// The next request's transaction id.
    next: u16,
    /// The transaction id and unit of the request in flight.
    expect: Option<(u16, u8)>,
    /// Bytes read that are not a whole MBAP frame yet.
    pending: Vec<u8>,
    /// RTU frames made from answers, not handed on yet.
    ready: Vec<u8>,
    /// Answers dropped because their transaction id or unit was not the request's.
    stale: u64,
}

impl MbapFraming {
    /// A framing for a fresh connection.
    pub fn new() -> Self {
        MbapFraming::default()
    }

    /// Forgets what is in flight (the connection was opened again).
    pub fn reset(&mut self) {
        self.expect = None;
        self.pending.clear();
        self.ready.clear();
    }

    /// Answers dropped so far because they answered another transaction.
    pub fn stale(&self) -> u64 {
        self.stale
    }

    /// The MBAP frame that carries the RTU frame `rtu`, with the next transaction id.
    pub fn outgoing(&mut self, rtu: &[u8]) -> io::Result<Vec<u8>> {
        let transaction = self.next;
        self.next = self.next.wrapping_add(1);
        let mut out = vec![0u8; MAX_ADU];
        let n = mbap_from_rtu(transaction, rtu, &mut out)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, format!("not a Modbus request: {e}")))?;
        out.truncate(n);
        self.expect = Some((transaction, rtu[0]));
        // Whatever was left of an earlier answer belongs to an earlier transaction.
        self.ready.clear();
        Ok(out)
    }

    /// Takes `bytes` read from the connection: every whole frame that answers the request in
    /// flight becomes an RTU frame to hand on ([`MbapFraming::take`]); others are dropped. A
    /// damaged header is an error: nothing after it can be trusted to be framed right, and the
    /// connection must be opened again.
    pub fn incoming(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.pending.extend_from_slice(bytes);
        let mut pos = 0;
        let result = loop {
            match Mbap::next_frame(&self.pending[pos..]) {
                Ok(Some((header, len))) => {
                    let frame = &self.pending[pos..pos + len];
                    if self.expect == Some((header.transaction, header.unit)) {
                        let mut rtu = [0u8; MAX_ADU];
                        if let Ok(n) = rtu_from_mbap(frame, &mut rtu) {
                            self.ready.extend_from_slice(&rtu[..n]);
                        }
                        self.expect = None;
                    } else {
                        self.stale += 1;
                    }
                    pos += len;
                }
                Ok(None) => break Ok(()),
                Err(e) => {
                    break Err(io::Error::new(
                        io::ErrorKind::InvalidData,
                        format!("a damaged Modbus TCP header: {e}"),
                    ))
                }
            }
        };
        self.pending.drain(..pos);
        if result.is_err() {
            self.pending.clear();
        }
        result
    }

    /// Moves what is ready (RTU frames) into `buf`; returns how many bytes.
    pub fn take(&mut self, buf: &mut [u8]) -> usize {
        let n = self.ready.len().min(buf.len());
        buf[..n].copy_from_slice(&self.ready[..n]);
        self.ready.drain(..n);
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const READ: [u8; 8] = [0x01, 0x03, 0x21, 0x00, 0x00, 0x01, 0x8E, 0x36];

    #[test]
    fn answers_to_other_transactions_are_dropped() {
        let mut f = MbapFraming::new();
        let first = f.outgoing(&READ).unwrap();
        assert_eq!(&first[..2], [0, 0]);
        let second = f.outgoing(&READ).unwrap();
        assert_eq!(&second[..7], [0, 1, 0, 0, 0, 6, 1], "a new transaction id, unit 1");
        // A late answer to the first request, then the answer to the second split in two.
        let late = [0, 0, 0, 0, 0, 5, 1, 3, 2, 0, 7];
        let good = [0, 1, 0, 0, 0, 5, 1, 3, 2, 0, 9];
        f.incoming(&late).unwrap();
        f.incoming(&good[..4]).unwrap();
        let mut buf = [0u8; 64];
        assert_eq!(f.take(&mut buf), 0, "nothing answers transaction 1 yet");
        f.incoming(&good[4..]).unwrap();
        let n = f.take(&mut buf);
        let crc = drivebus_proto::checksum::crc16_modbus(&[1, 3, 2, 0, 9]).to_le_bytes();
        assert_eq!(buf[..n], [1, 3, 2, 0, 9, crc[0], crc[1]]);
        assert_eq!(f.stale(), 1);
        // Another unit's answer with the right transaction id is not the answer either.
        let _ = f.outgoing(&READ).unwrap();
        f.incoming(&[0, 2, 0, 0, 0, 5, 9, 3, 2, 0, 9]).unwrap();
        assert_eq!(f.take(&mut buf), 0);
        assert!(f.incoming(&[0, 2, 0, 7, 0, 5, 1]).is_err(), "protocol 7 is not Modbus");
    }

    #[test]
    fn the_default_port_is_502() {
        assert_eq!(with_default_port("10.0.0.5"), "10.0.0.5:502");
        assert_eq!(with_default_port("10.0.0.5:1502"), "10.0.0.5:1502");
        assert_eq!(with_default_port("plc.local"), "plc.local:502");
        assert_eq!(with_default_port("[::1]:5020"), "[::1]:5020");
        assert_eq!(with_default_port("[::1]"), "[::1]:502");
    }
}
