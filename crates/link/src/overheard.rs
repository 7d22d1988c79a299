//! What a gateway hears on its line that it did not send, without I/O: another master's
//! requests, each paired with the drive's reply that follows it, requests left without a reply,
//! and garbled traffic. The bus owner's listening side ([`crate::role`]) feeds on it: a standby
//! learns values from the replies, a master yields when it hears another master's request.
//!
//! The line is read by the sniffer's analyser ([`drivebus_analyze::Analyzer`]) in the bus's
//! protocol: its framing (with the line's silences), its pairing of a reply with its request
//! within the response timeout. A broadcast of a drive acting as bus master
//! (`drivebus_drive::interdrive`) is not a master's request.

use std::time::Duration;

use drivebus_analyze::{Analyzer, Kind, Settings, Side};
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::Direction;
use drivebus_proto::Instant;

use crate::bus::BusConfig;

/// One thing heard.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Heard {
    /// Another master's request.
    Request {
        /// The drive it addresses, where it names one (`None` for a broadcast).
        address: Option<u8>,
        /// Its bytes.
        bytes: Vec<u8>,
    },
    /// A drive's reply to the request heard before it.
    Reply {
        /// The drive that answers, where known.
        address: Option<u8>,
        /// The request.
        request: Vec<u8>,
        /// The reply.
        reply: Vec<u8>,
    },
    /// A request that got no reply within the response timeout (or before the next request).
    NoReply {
        /// The drive it addressed, where it names one.
        address: Option<u8>,
    },
    /// Bytes that make no whole frame with a good checksum.
    Garbled,
}

/// The listener of one bus.
pub(crate) struct Overheard {
    protocol: WireProtocol,
    analyzer: Analyzer,
}

impl Overheard {
    /// A listener for the bus of `config` that waits `timeout` for a reply.
    pub(crate) fn new(config: &BusConfig, timeout: Duration) -> Self {
        let settings = Settings {
            protocols: vec![config.protocol.name()],
            baud: config.baud,
            format: config.format,
            reply_timeout: timeout,
            sides: vec![Side::Both],
        };
        Overheard { protocol: config.protocol, analyzer: Analyzer::new(settings).endless() }
    }

    /// Bytes heard at `now`.
    pub(crate) fn push(&mut self, now: Instant, bytes: &[u8], out: &mut Vec<Heard>) {
        let records = self.analyzer.push(0, Duration::from_nanos(now.as_nanos()), bytes);
        self.sort(records, out);
    }

    /// Nothing heard until `now`: a request whose reply is overdue is reported, a frame in
    /// progress after a long quiet ends.
    pub(crate) fn tick(&mut self, now: Instant, out: &mut Vec<Heard>) {
        let records = self.analyzer.tick(Duration::from_nanos(now.as_nanos()));
        self.sort(records, out);
    }

    fn sort(&self, records: Vec<drivebus_analyze::Record>, out: &mut Vec<Heard>) {
        for r in records {
            let address = r.address();
            let bytes = r.frame.bytes;
            out.push(match (r.kind, r.frame.error.is_none(), r.direction) {
                (Kind::NoReply, _, _) => Heard::NoReply { address },
                (Kind::Frame, false, _) => Heard::Garbled,
                (Kind::Frame, true, Direction::Master) => {
                    if drivebus_drive::interdrive::master_drive_broadcast(self.protocol, &bytes).is_some() {
                        continue;
                    }
                    // One drive by its number (TIP inverter 0 included); a broadcast none.
                    let address = match r.frame.target {
                        Some(drivebus_proto::describe::Target::Unit(n)) => Some(n),
                        _ => None,
                    };
                    Heard::Request { address, bytes }
                }
                (Kind::Frame, true, Direction::Drive) => match r.request {
                    Some(request) => Heard::Reply { address, request, reply: bytes },
                    // A reply to no request heard (its request went by before we listened).
                    None => continue,
                },
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use drivebus_proto::checksum::crc16_modbus;
    use drivebus_proto::line::CharFormat;

    fn listener() -> Overheard {
        let config = BusConfig::new(WireProtocol::ModbusRtu, 19200, CharFormat::EVEN_8E1);
        Overheard::new(&config, Duration::from_millis(100))
    }

    fn rtu(frame: &[u8]) -> Vec<u8> {
        let mut v = frame.to_vec();
        v.extend_from_slice(&crc16_modbus(frame).to_le_bytes());
        v
    }

    #[test]
    fn a_request_and_its_reply_are_paired_and_a_late_reply_is_not() {
        let mut o = listener();
        let req = rtu(&[1, 3, 0x21, 0x02, 0, 1]);
        let rep = rtu(&[1, 3, 2, 0x0F, 0xA0]);
        let mut out = Vec::new();
        o.push(Instant::from_millis(0), &req, &mut out);
        o.push(Instant::from_millis(10), &rep, &mut out);
        assert_eq!(
            out,
            [
                Heard::Request { address: Some(1), bytes: req.clone() },
                Heard::Reply { address: Some(1), request: req.clone(), reply: rep.clone() }
            ]
        );
        // The next request is a request again, not a reply.
        out.clear();
        o.push(Instant::from_millis(50), &req, &mut out);
        assert_eq!(out, [Heard::Request { address: Some(1), bytes: req.clone() }]);
        // A reply after the timeout pairs with nothing.
        out.clear();
        o.push(Instant::from_millis(300), &rep, &mut out);
        assert!(!out.iter().any(|h| matches!(h, Heard::Reply { .. })), "{out:?}");
        assert!(out.contains(&Heard::NoReply { address: Some(1) }), "{out:?}");
    }

    #[test]
    fn noise_is_garbled_and_a_drives_broadcast_is_no_masters_request() {
        let mut o = listener();
        let mut out = Vec::new();
        let mut bad = rtu(&[1, 3, 0x21, 0x02, 0, 1]);
        bad[7] ^= 0xFF;
        o.push(Instant::from_millis(0), &bad, &mut out);
        // The damaged frame ends with the line's silence.
        o.tick(Instant::from_millis(1000), &mut out);
        assert!(out.contains(&Heard::Garbled), "{out:?}");
        out.clear();
        // A generic drive acting as bus master broadcasts its frequency (06 to 2001H at address 0).
        o.push(Instant::from_millis(1100), &[0x00, 0x06, 0x20, 0x01, 0x0F, 0xA0, 0xD7, 0x93], &mut out);
        o.tick(Instant::from_millis(2000), &mut out);
        assert!(out.is_empty(), "{out:?}");
    }

    #[test]
    fn a_tip_binary_reply_that_begins_as_a_whole_request_is_the_reply() {
        use drivebus_proto::toshiba::binary::{BinaryAddress, BinaryRequest};
        use drivebus_proto::toshiba::CommNo;
        let config = BusConfig::new(WireProtocol::ToshibaBinary, 19200, CharFormat::EVEN_8E1);
        // R of 0876H to inverter 1: 2F 01 52 08 76, SUM 00. Its reply with data 0002H begins
        // with the same five bytes and 00: a whole request with a good SUM.
        let r = BinaryRequest::read(BinaryAddress::Unit(1), CommNo(0x0876));
        let (mut req, mut rep) = ([0u8; 16], [0u8; 16]);
        let (n, m) = (r.emit(&mut req).unwrap(), r.reply(1, false, 2).unwrap().emit(&mut rep).unwrap());
        let (req, rep) = (&req[..n], &rep[..m]);
        assert_eq!(rep[..req.len()], *req);
        let expected = [
            Heard::Request { address: Some(1), bytes: req.to_vec() },
            Heard::Reply { address: Some(1), request: req.to_vec(), reply: rep.to_vec() },
        ];
        // Heard as it came, and in one read (a listener that read late).
        let mut o = Overheard::new(&config, Duration::from_millis(100));
        let mut out = Vec::new();
        o.push(Instant::from_millis(0), req, &mut out);
        o.push(Instant::from_millis(10), rep, &mut out);
        o.tick(Instant::from_millis(500), &mut out);
        assert_eq!(out, expected);
        let mut o = Overheard::new(&config, Duration::from_millis(100));
        let mut out = Vec::new();
        o.push(Instant::from_millis(10), &[req, rep].concat(), &mut out);
        o.tick(Instant::from_millis(500), &mut out);
        assert_eq!(out, expected);
    }
}
