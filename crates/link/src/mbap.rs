//! Modbus TCP as a framing of a TCP port: the engine and the drive profiles speak Modbus RTU
//! frames (`address PDU CRC`), and [`MbapFraming`] carries each one as an MBAP frame (unit id =
//! the address, the CRC dropped, a transaction id of its own) and turns the answers back into
//! RTU frames with their CRC computed. An answer whose transaction id is not the request's (a
//! late answer to an earlier attempt) is dropped, so it is never taken for the current one.
//! One request is in flight at a time (`max_in_flight` 1); with more, the pipelined bus owner
//! ([`crate::pipelined`]) carries MBAP itself and matches answers by [`MbapTransactions`].
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

/// The transactions of one connection in flight: the ids it gives, the answers it matches to
/// them by transaction id and unit (in any order), and what came in that is not a whole frame
/// yet. An answer to no transaction in flight (a stray id, a second answer to one already
/// answered, one given up on) is counted and dropped. The one place that matches MBAP answers:
/// [`MbapFraming`] (one request at a time) and the pipelined bus owner
/// ([`crate::pipelined`], `max_in_flight` > 1) both use it.
#[derive(Debug, Default)]
pub struct MbapTransactions {
    /// The next request's transaction id.
    next: u16,
    /// The transaction id and unit of each request in flight.
    outstanding: Vec<(u16, u8)>,
    /// Bytes read that are not a whole MBAP frame yet.
    pending: Vec<u8>,
    /// Answers dropped because no request in flight had their transaction id and unit.
    stray: u64,
}

impl MbapTransactions {
    /// No transaction in flight.
    pub fn new() -> Self {
        MbapTransactions::default()
    }

    /// Forgets every transaction in flight and what came in part (the connection was opened
    /// again); the ids go on from where they were.
    pub fn reset(&mut self) {
        self.outstanding.clear();
        self.pending.clear();
    }

    /// Answers dropped so far: to no transaction in flight, or from another unit.
    pub fn stray(&self) -> u64 {
        self.stray
    }

    /// How many transactions are in flight.
    pub fn in_flight(&self) -> usize {
        self.outstanding.len()
    }

    /// The MBAP frame that carries the RTU frame `rtu`, with the next transaction id, now in
    /// flight; that id. A broadcast (unit 0) expects no answer and is not kept in flight.
    pub fn send(&mut self, rtu: &[u8]) -> io::Result<(u16, Vec<u8>)> {
        let transaction = self.next;
        let mut out = vec![0u8; MAX_ADU];
        let n = mbap_from_rtu(transaction, rtu, &mut out)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, format!("not a Modbus request: {e}")))?;
        self.next = self.next.wrapping_add(1);
        out.truncate(n);
        // An id still in flight after 65536 more requests was given up on long ago.
        self.forget(transaction);
        if rtu[0] != 0 {
            self.outstanding.push((transaction, rtu[0]));
        }
        Ok((transaction, out))
    }

    /// Gives up on `transaction` (its time is out): an answer that comes later is stray.
    pub fn forget(&mut self, transaction: u16) {
        self.outstanding.retain(|&(t, _)| t != transaction);
    }

    /// Takes `bytes` read from the connection: each whole frame that answers a transaction in
    /// flight is handed to `answer` (its id and the answer as an RTU frame, CRC computed) and
    /// that transaction is over; others are counted as stray and dropped. A damaged header is
    /// an error: nothing after it can be trusted to be framed right, and the connection must
    /// be opened again.
    pub fn incoming(&mut self, bytes: &[u8], mut answer: impl FnMut(u16, &[u8])) -> io::Result<()> {
        self.pending.extend_from_slice(bytes);
        let mut pos = 0;
        let result = loop {
            match Mbap::next_frame(&self.pending[pos..]) {
                Ok(Some((header, len))) => {
                    let frame = &self.pending[pos..pos + len];
                    let key = (header.transaction, header.unit);
                    match self.outstanding.iter().position(|&o| o == key) {
                        Some(i) => {
                            self.outstanding.remove(i);
                            let mut rtu = [0u8; MAX_ADU];
                            if let Ok(n) = rtu_from_mbap(frame, &mut rtu) {
                                answer(header.transaction, &rtu[..n]);
                            }
                        }
                        None => self.stray += 1,
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
}

/// The MBAP framing of one connection with one request in flight (`max_in_flight` 1), for a
/// link whose reads and writes carry RTU frames: the transaction it expects, and the answers
/// not handed on yet.
#[derive(Debug, Default)]
pub struct MbapFraming {
    transactions: MbapTransactions,
    /// RTU frames made from answers, not handed on yet.
    ready: Vec<u8>,
}

impl MbapFraming {
    /// A framing for a fresh connection.
    pub fn new() -> Self {
        MbapFraming::default()
    }

    /// Forgets what is in flight (the connection was opened again).
    pub fn reset(&mut self) {
        self.transactions.reset();
        self.ready.clear();
    }

    /// Answers dropped so far because they answered another transaction.
    pub fn stale(&self) -> u64 {
        self.transactions.stray()
    }

    /// The MBAP frame that carries the RTU frame `rtu`, with the next transaction id.
    pub fn outgoing(&mut self, rtu: &[u8]) -> io::Result<Vec<u8>> {
        // The request before it (a retry's first attempt) is given up on.
        self.transactions.outstanding.clear();
        let (_, out) = self.transactions.send(rtu)?;
        // Whatever was left of an earlier answer belongs to an earlier transaction.
        self.ready.clear();
        Ok(out)
    }

    /// Takes `bytes` read from the connection: every whole frame that answers the request in
    /// flight becomes an RTU frame to hand on ([`MbapFraming::take`]); others are dropped. A
    /// damaged header is an error: nothing after it can be trusted to be framed right, and the
    /// connection must be opened again.
    pub fn incoming(&mut self, bytes: &[u8]) -> io::Result<()> {
        let ready = &mut self.ready;
        self.transactions.incoming(bytes, |_, rtu| ready.extend_from_slice(rtu))
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

    /// The read of [`READ`] to `unit`, as an RTU frame.
    fn read_of(unit: u8) -> Vec<u8> {
        let mut r = READ.to_vec();
        r[0] = unit;
        let crc = drivebus_proto::checksum::crc16_modbus(&r[..6]).to_le_bytes();
        r[6..].copy_from_slice(&crc);
        r
    }

    #[test]
    fn answers_in_any_order_are_matched_by_transaction_and_unit() {
        let mut t = MbapTransactions::new();
        let ids: Vec<u16> = (1..=4).map(|u| t.send(&read_of(u)).unwrap().0).collect();
        assert_eq!(ids, [0, 1, 2, 3]);
        assert_eq!(t.in_flight(), 4);
        // Answers in reverse order, the last two in one read, one cut in two.
        let answer = |id: u16, unit: u8| vec![0, id as u8, 0, 0, 0, 5, unit, 3, 2, 0, unit];
        let mut got = Vec::new();
        let mut bytes = answer(3, 4);
        bytes.extend(answer(2, 3));
        t.incoming(&bytes, |id, rtu| got.push((id, rtu.to_vec()))).unwrap();
        let cut = answer(1, 2);
        t.incoming(&cut[..5], |id, rtu| got.push((id, rtu.to_vec()))).unwrap();
        t.incoming(&cut[5..], |id, rtu| got.push((id, rtu.to_vec()))).unwrap();
        let order: Vec<u16> = got.iter().map(|(id, _)| *id).collect();
        assert_eq!(order, [3, 2, 1]);
        for (id, rtu) in &got {
            let unit = *id as u8 + 1;
            let crc = drivebus_proto::checksum::crc16_modbus(&[unit, 3, 2, 0, unit]).to_le_bytes();
            assert_eq!(rtu[..], [unit, 3, 2, 0, unit, crc[0], crc[1]], "transaction {id}");
        }
        // A second answer to 3, an unknown id, id 0 from the wrong unit: stray, dropped.
        got.clear();
        t.incoming(&answer(3, 4), |id, rtu| got.push((id, rtu.to_vec()))).unwrap();
        t.incoming(&answer(77, 1), |id, rtu| got.push((id, rtu.to_vec()))).unwrap();
        t.incoming(&answer(0, 9), |id, rtu| got.push((id, rtu.to_vec()))).unwrap();
        assert!(got.is_empty());
        assert_eq!(t.stray(), 3);
        // Given up on (timed out): its late answer is stray too.
        t.forget(0);
        t.incoming(&answer(0, 1), |id, rtu| got.push((id, rtu.to_vec()))).unwrap();
        assert!(got.is_empty());
        assert_eq!((t.stray(), t.in_flight()), (4, 0));
        // A broadcast is not kept in flight.
        t.send(&read_of(0)).unwrap();
        assert_eq!(t.in_flight(), 0);
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
