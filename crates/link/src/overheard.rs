//! What a gateway hears on its line that it did not send, without I/O: another master's
//! requests, each paired with the drive's reply that follows it, and garbled traffic. The bus
//! owner's listening side ([`crate::role`]) feeds on it: a standby learns values from the
//! replies, a master yields when it hears another master's request.
//!
//! A request is a whole frame of the bus's protocol as a drive receives it; what follows it
//! within the response timeout is read as its reply. A broadcast of a drive acting as bus
//! master (`drivebus_drive::interdrive`) is not a master's request.

use std::time::Duration;

use drivebus_proto::deframe::{Deframer, Event};
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::session::Protocol;
use drivebus_proto::Instant;

/// One thing heard.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Heard {
    /// Another master's request (its bytes).
    Request(Vec<u8>),
    /// A drive's reply to the request heard before it.
    Reply {
        /// The request.
        request: Vec<u8>,
        /// The reply.
        reply: Vec<u8>,
    },
    /// Bytes that make no whole frame with a good checksum.
    Garbled,
}

/// The listener of one bus.
pub(crate) struct Overheard<P: Protocol> {
    protocol: WireProtocol,
    requests: Deframer<P::RequestScanner>,
    replies: Deframer<P::ReplyScanner>,
    /// The request heard last and when, while its reply may still come.
    awaiting: Option<(Vec<u8>, Instant)>,
    timeout: Duration,
}

impl<P: Protocol> Overheard<P> {
    /// A listener for `proto` (spoken as `protocol`) that waits `timeout` for a reply.
    pub(crate) fn new(proto: &P, protocol: WireProtocol, timeout: Duration) -> Self {
        Overheard {
            protocol,
            requests: Deframer::new(proto.request_scanner()),
            replies: Deframer::new(proto.reply_scanner()),
            awaiting: None,
            timeout,
        }
    }

    /// Bytes heard at `now`.
    pub(crate) fn push(&mut self, now: Instant, bytes: &[u8], out: &mut Vec<Heard>) {
        if self.awaiting.as_ref().is_some_and(|(_, at)| now.saturating_since(*at) > self.timeout) {
            self.awaiting = None;
            self.replies.finish(&mut |_| {});
        }
        let protocol = self.protocol;
        match self.awaiting.take() {
            Some((request, at)) => {
                let mut reply = None;
                self.replies.push(bytes, &mut |e| {
                    if let Event::Frame { bytes, .. } = e {
                        reply.get_or_insert_with(|| bytes.to_vec());
                    }
                });
                match reply {
                    Some(reply) => {
                        self.replies.finish(&mut |_| {});
                        out.push(Heard::Reply { request, reply });
                    }
                    None => self.awaiting = Some((request, at)),
                }
            }
            None => {
                let mut heard = Vec::new();
                self.requests.push(bytes, &mut |e| match e {
                    Event::Frame { bytes, .. } => {
                        if drivebus_drive::interdrive::master_drive_broadcast(protocol, bytes).is_none() {
                            heard.push(Heard::Request(bytes.to_vec()));
                        }
                    }
                    Event::Rejected { .. } => heard.push(Heard::Garbled),
                });
                if let Some(Heard::Request(r)) = heard.iter().rev().find(|h| matches!(h, Heard::Request(_))) {
                    self.awaiting = Some((r.clone(), now));
                }
                out.extend(heard);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use drivebus_proto::checksum::crc16_modbus;
    use drivebus_proto::modbus::rtu::ModbusRtu;

    fn rtu(frame: &[u8]) -> Vec<u8> {
        let mut v = frame.to_vec();
        v.extend_from_slice(&crc16_modbus(frame).to_le_bytes());
        v
    }

    #[test]
    fn a_request_and_its_reply_are_paired_and_a_late_reply_is_not() {
        let mut o = Overheard::new(&ModbusRtu, WireProtocol::ModbusRtu, Duration::from_millis(100));
        let req = rtu(&[1, 3, 0x21, 0x02, 0, 1]);
        let rep = rtu(&[1, 3, 2, 0x0F, 0xA0]);
        let mut out = Vec::new();
        o.push(Instant::from_millis(0), &req, &mut out);
        o.push(Instant::from_millis(10), &rep, &mut out);
        assert_eq!(
            out,
            [Heard::Request(req.clone()), Heard::Reply { request: req.clone(), reply: rep.clone() }]
        );
        // The next request is a request again, not a reply.
        out.clear();
        o.push(Instant::from_millis(50), &req, &mut out);
        assert_eq!(out, [Heard::Request(req.clone())]);
        // A reply after the timeout pairs with nothing.
        out.clear();
        o.push(Instant::from_millis(300), &rep, &mut out);
        assert!(!out.iter().any(|h| matches!(h, Heard::Reply { .. })), "{out:?}");
    }

    #[test]
    fn noise_is_garbled_and_a_drives_broadcast_is_no_masters_request() {
        let mut o = Overheard::new(&ModbusRtu, WireProtocol::ModbusRtu, Duration::from_millis(100));
        let mut out = Vec::new();
        let mut bad = rtu(&[1, 3, 0x21, 0x02, 0, 1]);
        bad[7] ^= 0xFF;
        o.push(Instant::from_millis(0), &bad, &mut out);
        assert!(out.contains(&Heard::Garbled), "{out:?}");
        out.clear();
        // A generic drive acting as bus master broadcasts its frequency (06 to 2001H at address 0).
        o.push(Instant::from_millis(100), &[0x00, 0x06, 0x20, 0x01, 0x0F, 0xA0, 0xD7, 0x93], &mut out);
        assert!(out.is_empty(), "{out:?}");
    }
}
