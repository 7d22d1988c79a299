//! What a listening gateway learns from another master's traffic, without I/O: the values its
//! drives answered and when, and which drives the master polls how often.
//!
//! Values: each answered request is read by its meaning, in the protocol's own addressing, and
//! what it says is kept by drive and item with the time it was heard ([`items`]): Modbus
//! registers by table ([`modbus`]: reads 03, 04 and 17, and acknowledged writes 06, 10, 17),
//! TIP communication numbers ([`toshiba`]: `R`, `G`, acknowledged `W` and `P`, block reads),
//! FC parameters by PNU and IND with every reply's status word and MAV ([`fc`]), B800 replies
//! by read command ([`b800`]). A standby's own poll is answered from whatever the master's
//! requests covered, whatever their form, span, order or interval: the reply is rebuilt as the
//! drive would send it to the standby's request, and the profile decodes it as its own (one
//! decoding for both). A reply no meaning is read from (an error reply, a text block) is kept
//! by its request's bytes, and answers the same bytes. What answers a poll was heard since it
//! began, or at most the master's own poll interval of that drive before (the bus owner
//! chooses, [`Learnt::interval`]): the standby's value is never older than the master's view
//! of it. Set-up values a profile reads once to decode a status (FC 3-00, 3-02, 3-03, 4-14,
//! 16-02; TIP FE70, f875–f879) answer whatever their age, until a write to them is heard
//! ([`Learnt::request`]).
//!
//! Schedule: the interval between two requests with the same bytes to one drive, the median of
//! the latest [`GAPS`] (an outlier, such as the burst after a master's start-up listening or a
//! retry, is left out); a drive's interval is its most frequent request's.

mod b800;
mod fc;
mod items;
mod modbus;
mod toshiba;

use std::collections::HashMap;
use std::time::Duration;

use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::Instant;

use items::Items;

/// At most this many distinct requests (or replies by request) are remembered; more (a master
/// reading everything once, a scan) start the memory afresh.
const MAX_REQUESTS: usize = 4096;

/// How many of a request's latest intervals its learnt interval is the median of: an outlier
/// (the burst after a master's start-up listening, a retry not told from a poll, a gap while
/// the master was busy) changes nothing while fewer than half of them are outliers, and a new
/// interval of the master's is learnt after three sendings.
const GAPS: usize = 5;

/// A request heard repeatedly: when last, and the latest intervals between its sendings.
#[derive(Clone, Copy, Debug)]
struct Repeat {
    address: u8,
    last: Instant,
    /// The latest intervals, `heard` of them (at most [`GAPS`]), the newest at `heard % GAPS`
    /// once full.
    gaps: [Duration; GAPS],
    heard: usize,
}

impl Repeat {
    /// Adds an interval heard, in place of the oldest once [`GAPS`] are kept.
    fn push(&mut self, gap: Duration) {
        self.gaps[self.heard % GAPS] = gap;
        self.heard += 1;
        if self.heard == 2 * GAPS {
            self.heard = GAPS;
        }
    }

    /// The median of the intervals kept (of two or four, the longer middle one: a standby that
    /// takes over never polls faster than the master did on the strength of a lone short gap);
    /// `None` before the request was heard twice.
    fn interval(&self) -> Option<Duration> {
        let mut kept = self.gaps;
        let kept = &mut kept[..self.heard.min(GAPS)];
        kept.sort_unstable();
        kept.get(kept.len() / 2).copied()
    }
}

/// What one bus's listener has learnt.
pub(crate) struct Learnt {
    protocol: WireProtocol,
    /// What the drives said, by the protocol's addressing.
    items: Items,
    /// Replies no meaning was read from: request bytes -> (reply bytes, when heard).
    replies: HashMap<Vec<u8>, (Vec<u8>, Instant)>,
    /// Each distinct request heard, for the schedule.
    requests: HashMap<Vec<u8>, Repeat>,
    /// The last request heard, and whether its reply was.
    last: Option<(Vec<u8>, bool)>,
}

impl Learnt {
    /// Nothing learnt yet on a bus speaking `protocol`.
    pub(crate) fn new(protocol: WireProtocol) -> Self {
        Learnt {
            protocol,
            items: Items::default(),
            replies: HashMap::new(),
            requests: HashMap::new(),
            last: None,
        }
    }

    /// Another master's request heard at `now`, to drive `address` (`None`: a broadcast, which
    /// is no drive's poll).
    pub(crate) fn request(&mut self, now: Instant, address: Option<u8>, request: &[u8]) {
        // The same request again after no reply is the master's retry, not its next poll.
        let retry = self.last.as_ref().is_some_and(|(r, answered)| r == request && !answered);
        self.last = Some((request.to_vec(), false));
        match self.protocol {
            WireProtocol::ToshibaAscii | WireProtocol::ToshibaBinary => {
                toshiba::forget_written(request, &mut self.items)
            }
            WireProtocol::DanfossFc => fc::forget_written(request, &mut self.items),
            _ => {}
        }
        let Some(address) = address.filter(|_| !retry) else { return };
        if self.requests.len() >= MAX_REQUESTS && !self.requests.contains_key(request) {
            self.requests.clear();
        }
        let r = self.requests.entry(request.to_vec()).or_insert(Repeat {
            address,
            last: now,
            gaps: [Duration::ZERO; GAPS],
            heard: 0,
        });
        let gap = now.saturating_since(r.last);
        if !gap.is_zero() {
            r.push(gap);
        }
        r.last = now;
    }

    /// The drive's `reply` to `request` heard at `now`.
    pub(crate) fn reply(&mut self, now: Instant, request: &[u8], reply: &[u8]) {
        if let Some((r, answered)) = &mut self.last {
            *answered |= r == request;
        }
        let items = &mut self.items;
        let understood = match self.protocol {
            WireProtocol::ModbusRtu | WireProtocol::ModbusAscii => {
                modbus::learn(self.protocol, request, reply, now, items)
            }
            WireProtocol::ToshibaAscii | WireProtocol::ToshibaBinary => {
                toshiba::learn(request, reply, now, items)
            }
            WireProtocol::DanfossFc => fc::learn(request, reply, now, items),
            WireProtocol::B800 => b800::learn(request, reply, now, items),
        };
        if understood {
            self.replies.remove(request);
            return;
        }
        if self.replies.len() >= MAX_REQUESTS && !self.replies.contains_key(request) {
            self.replies.clear();
        }
        self.replies.insert(request.to_vec(), (reply.to_vec(), now));
    }

    /// The reply to `request` made of what was heard at or after `since`, when all of it was.
    pub(crate) fn answer(&self, request: &[u8], since: Instant) -> Option<Vec<u8>> {
        let fresh = self.items.since(since);
        let rebuilt = match self.protocol {
            WireProtocol::ModbusRtu | WireProtocol::ModbusAscii => {
                modbus::answer(self.protocol, request, &fresh)
            }
            WireProtocol::ToshibaAscii | WireProtocol::ToshibaBinary => toshiba::answer(request, &fresh),
            WireProtocol::DanfossFc => fc::answer(request, &fresh),
            WireProtocol::B800 => b800::answer(request, &fresh),
        };
        rebuilt.or_else(|| {
            let (reply, at) = self.replies.get(request)?;
            (*at >= since).then(|| reply.clone())
        })
    }

    /// True when `request` reads a set-up value of drive `address` that the master does not
    /// read: its polls of the drive were heard (twice, so its interval is known), the value
    /// never was (or a write to it was heard since). Before the master's polls are heard
    /// nothing can be told: the standby waits.
    pub(crate) fn master_skips_setup(&self, address: u8, request: &[u8]) -> bool {
        self.interval(address).is_some() && self.unheard_setup(request)
    }

    /// True when `request` reads a set-up value of which nothing was ever heard (or a write
    /// to it was heard since).
    pub(crate) fn unheard_setup(&self, request: &[u8]) -> bool {
        match self.protocol {
            WireProtocol::ToshibaAscii | WireProtocol::ToshibaBinary => {
                toshiba::unheard_setup(request, &self.items)
            }
            WireProtocol::DanfossFc => fc::unheard_setup(request, &self.items),
            _ => false,
        }
    }

    /// The interval at which the master polled each drive it polled (a drive's most frequent
    /// request's).
    pub(crate) fn schedule(&self) -> HashMap<u8, Duration> {
        let addresses: std::collections::HashSet<u8> = self.requests.values().map(|r| r.address).collect();
        addresses.into_iter().filter_map(|a| Some((a, self.interval(a)?))).collect()
    }

    /// The interval at which the master polled drive `address`, once heard twice.
    pub(crate) fn interval(&self, address: u8) -> Option<Duration> {
        self.requests.values().filter(|r| r.address == address).filter_map(Repeat::interval).min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use drivebus_proto::checksum::crc16_modbus;

    /// The bytes of a Toshiba request.
    fn emit(r: &drivebus_proto::toshiba::TipRequest) -> Vec<u8> {
        let mut out = [0u8; 32];
        let n = r.emit(&mut out).unwrap();
        out[..n].to_vec()
    }

    fn rtu(frame: &[u8]) -> Vec<u8> {
        let mut v = frame.to_vec();
        v.extend_from_slice(&crc16_modbus(frame).to_le_bytes());
        v
    }

    #[test]
    fn a_read_is_answered_from_other_spans_heard_since_it_began() {
        let mut l = Learnt::new(WireProtocol::ModbusRtu);
        let t = Instant::from_millis;
        // The master reads 2100H..2101H, then 2102H alone.
        l.reply(t(10), &rtu(&[1, 3, 0x21, 0x00, 0, 2]), &rtu(&[1, 3, 4, 0, 7, 0x0F, 0xA0]));
        l.reply(t(20), &rtu(&[1, 3, 0x21, 0x02, 0, 1]), &rtu(&[1, 3, 2, 0x01, 0x02]));
        // The standby's own read of 2101H..2102H, begun at 5 ms: rebuilt from both.
        let mine = rtu(&[1, 3, 0x21, 0x01, 0, 2]);
        assert_eq!(l.answer(&mine, t(5)), Some(rtu(&[1, 3, 4, 0x0F, 0xA0, 0x01, 0x02])));
        // Begun after the first read was heard: not all of it is fresh.
        assert_eq!(l.answer(&mine, t(15)), None);
        // Another drive, or another table: nothing heard.
        assert_eq!(l.answer(&rtu(&[2, 3, 0x21, 0x01, 0, 2]), t(0)), None);
        assert_eq!(l.answer(&rtu(&[1, 4, 0x21, 0x01, 0, 2]), t(0)), None);
    }

    #[test]
    fn a_read_write_and_the_writes_a_drive_acknowledged_tell_the_registers_new_values() {
        let mut l = Learnt::new(WireProtocol::ModbusRtu);
        let t = Instant::from_millis;
        // 17: write 2001H = 0FA0H, then read 2100H..2101H.
        l.reply(
            t(10),
            &rtu(&[1, 0x17, 0x21, 0x00, 0, 2, 0x20, 0x01, 0, 1, 2, 0x0F, 0xA0]),
            &rtu(&[1, 0x17, 4, 0, 7, 0x0F, 0xA0]),
        );
        assert_eq!(l.answer(&rtu(&[1, 3, 0x21, 0x00, 0, 2]), t(0)), Some(rtu(&[1, 3, 4, 0, 7, 0x0F, 0xA0])));
        assert_eq!(l.answer(&rtu(&[1, 3, 0x20, 0x01, 0, 1]), t(0)), Some(rtu(&[1, 3, 2, 0x0F, 0xA0])));
        // 06 acknowledged (the request echoed): P0.02 = 1388H.
        let write = rtu(&[1, 6, 0, 2, 0x13, 0x88]);
        l.reply(t(20), &write, &write);
        // 10 acknowledged: P0.07..P0.08 = 0064H, 00C8H.
        l.reply(t(30), &rtu(&[1, 0x10, 0, 7, 0, 2, 4, 0, 0x64, 0, 0xC8]), &rtu(&[1, 0x10, 0, 7, 0, 2]));
        let mine = rtu(&[1, 3, 0, 7, 0, 2]);
        assert_eq!(l.answer(&mine, t(25)), Some(rtu(&[1, 3, 4, 0, 0x64, 0, 0xC8])));
        assert_eq!(l.answer(&rtu(&[1, 3, 0, 2, 0, 1]), t(15)), Some(rtu(&[1, 3, 2, 0x13, 0x88])));
        // Writes go to holding registers, not input registers.
        assert_eq!(l.answer(&rtu(&[1, 4, 0, 2, 0, 1]), t(0)), None);
        // A write refused (exception 03) tells nothing: the old value stays.
        l.reply(t(40), &rtu(&[1, 6, 0, 2, 0xFF, 0xFF]), &rtu(&[1, 0x86, 3]));
        assert_eq!(l.answer(&rtu(&[1, 3, 0, 2, 0, 1]), t(15)), Some(rtu(&[1, 3, 2, 0x13, 0x88])));
        // Nor does a reply that is not the request's echo.
        l.reply(t(50), &rtu(&[1, 6, 0, 2, 0x00, 0x01]), &rtu(&[1, 6, 0, 2, 0x00, 0x02]));
        assert_eq!(l.answer(&rtu(&[1, 3, 0, 2, 0, 1]), t(15)), Some(rtu(&[1, 3, 2, 0x13, 0x88])));
        // A broadcast write (unit 0) is not a drive's value.
        let broadcast = rtu(&[0, 6, 0, 3, 0, 1]);
        l.reply(t(60), &broadcast, &broadcast);
        assert_eq!(l.answer(&rtu(&[1, 3, 0, 3, 0, 1]), t(0)), None);
    }

    #[test]
    fn an_error_reply_answers_only_the_same_request_and_a_value_replaces_it() {
        use drivebus_proto::toshiba::ascii::{AsciiAddress, AsciiRequest};
        use drivebus_proto::toshiba::{CommNo, ErrorCode, TipRequest};
        let mut l = Learnt::new(WireProtocol::ToshibaAscii);
        let t = Instant::from_millis;
        let plain = TipRequest::Ascii(AsciiRequest::read(AsciiAddress::Unit(3), CommNo(0xFE03)));
        let summed = TipRequest::Ascii(AsciiRequest::read(AsciiAddress::Unit(3), CommNo(0xFE03)).with_sum());
        let reply = |r: &TipRequest, tripped, data| {
            let mut out = [0u8; 32];
            let n = r.reply(3, tripped, data).unwrap().emit(&mut out).unwrap();
            out[..n].to_vec()
        };
        // FE03 refused (data error): only the same request gets the same error back.
        let mut out = [0u8; 32];
        let n = plain.error_reply(3, false, ErrorCode(1)).emit(&mut out).unwrap();
        l.reply(t(10), &emit(&plain), &out[..n]);
        assert_eq!(l.answer(&emit(&plain), t(0)), Some(out[..n].to_vec()));
        assert_eq!(l.answer(&emit(&summed), t(0)), None);
        // Read by the master without SUM, while tripped: the standby's request with SUM gets
        // the reply the drive would give it, SUM and lower case included.
        l.reply(t(20), &emit(&plain), &reply(&plain, true, 0x1234));
        assert_eq!(l.answer(&emit(&summed), t(15)), Some(reply(&summed, true, 0x1234)));
        assert_eq!(l.answer(&emit(&plain), t(15)), Some(reply(&plain, true, 0x1234)));
        // Heard before the poll began (and no longer the master's interval): nothing.
        assert_eq!(l.answer(&emit(&summed), t(25)), None);
    }

    #[test]
    fn an_fc_write_the_drive_acknowledged_answers_a_read_with_the_latest_status_word() {
        use drivebus_proto::fc::{
            AddressFormat, Adr, ControlWord, FaultCode, ParameterNumber, Reference, Reply, Request,
            StatusWord, MAX_TELEGRAM,
        };
        let mut l = Learnt::new(WireProtocol::DanfossFc);
        let t = Instant::from_millis;
        let bytes = |emit: &dyn Fn(&mut [u8]) -> usize| {
            let mut out = [0u8; MAX_TELEGRAM];
            let n = emit(&mut out);
            out[..n].to_vec()
        };
        let adr = Adr::new(5, AddressFormat::OneTo126).unwrap();
        let (p414, p412) = (ParameterNumber::new(414).unwrap(), ParameterNumber::new(412).unwrap());
        // The master writes 4-14 = 65.0 Hz (AK 2), acknowledged with AK 1.
        let write = bytes(&|o| Request::write_word(adr, p414, 0, 650, false).emit(o).unwrap());
        let ack = Reply::value_word(adr, p414, 0, 650)
            .with_process(StatusWord(0x0F07), Reference::from_word(0x2000));
        l.reply(t(10), &write, &bytes(&|o| ack.emit(o).unwrap()));
        // Then a process block: a newer status word and MAV.
        let process =
            bytes(&|o| Request::process(adr, ControlWord(0x047C), Reference(0x2000)).emit(o).unwrap());
        let now = Reply::process(adr, StatusWord(0x0B07), Reference::from_word(0x1000));
        l.reply(t(20), &process, &bytes(&|o| now.emit(o).unwrap()));
        // The standby reads 4-14 with its own control word, in address format 1-31: the drive's
        // reply to that telegram, with the latest status word and MAV.
        let adr31 = Adr::new(5, AddressFormat::OneTo31).unwrap();
        let read = bytes(&|o| {
            Request::read(adr31, p414, 0)
                .with_process(ControlWord(0x003C), Reference(0x1234))
                .emit(o)
                .unwrap()
        });
        let expected = Reply::value_word(adr31, p414, 0, 650)
            .with_process(StatusWord(0x0B07), Reference::from_word(0x1000));
        assert_eq!(l.answer(&read, t(5)), Some(bytes(&|o| expected.emit(o).unwrap())));
        // Begun after the write was heard: 4-14 is a set-up value, answered whatever its age,
        // but with a status word and MAV heard since the poll began.
        assert_eq!(l.answer(&read, t(15)), Some(bytes(&|o| expected.emit(o).unwrap())));
        assert_eq!(l.answer(&read, t(25)), None);
        // A process block of the standby: the status word and MAV alone.
        let mine = bytes(&|o| Request::process(adr31, ControlWord(0), Reference(0)).emit(o).unwrap());
        let expected = Reply::process(adr31, StatusWord(0x0B07), Reference::from_word(0x1000));
        assert_eq!(l.answer(&mine, t(15)), Some(bytes(&|o| expected.emit(o).unwrap())));
        // AK 7 "cannot be performed" to a read of 4-12 is no value of 4-12.
        let refused = bytes(&|o| Request::read(adr, p412, 0).emit(o).unwrap());
        let fault = bytes(&|o| Reply::fault(adr, p412, 0, FaultCode(0)).emit(o).unwrap());
        l.reply(t(30), &refused, &fault);
        let other = bytes(&|o| Request::read(adr31, p412, 0).emit(o).unwrap());
        assert_eq!(l.answer(&other, t(0)), None);
        assert_eq!(l.answer(&refused, t(0)), Some(fault));
    }

    #[test]
    fn an_fc_set_up_value_answers_whatever_its_age_until_a_write_to_it_is_heard() {
        use drivebus_proto::fc::{
            AddressFormat, Adr, ControlWord, ParameterNumber, Reference, Reply, Request, StatusWord,
            MAX_TELEGRAM,
        };
        let mut l = Learnt::new(WireProtocol::DanfossFc);
        let t = Instant::from_millis;
        let bytes = |emit: &dyn Fn(&mut [u8]) -> usize| {
            let mut out = [0u8; MAX_TELEGRAM];
            let n = emit(&mut out);
            out[..n].to_vec()
        };
        let adr = Adr::new(4, AddressFormat::OneTo126).unwrap();
        let pnu = |n| ParameterNumber::new(n).unwrap();
        let (stw, mav) = (StatusWord(0x0F07), Reference::from_word(0x3000));
        let read = |n| bytes(&|o| Request::read(adr, pnu(n), 0).emit(o).unwrap());
        let value =
            |n, v| bytes(&|o| Reply::value_word(adr, pnu(n), 0, v).with_process(stw, mav).emit(o).unwrap());
        // The master reads 3-03 (50.000 Hz), 16-02 (80.0 %) and 16-14 once, at 10 ms; a process
        // block at 100 ms keeps the status word fresh.
        for (n, v) in [(303, 50000), (1602, 800), (1614, 1234)] {
            l.request(t(10), Some(4), &read(n));
            l.reply(t(10), &read(n), &value(n, v));
        }
        let process = bytes(&|o| Request::process(adr, ControlWord(0x003C), Reference(0)).emit(o).unwrap());
        let now = bytes(&|o| Reply::process(adr, stw, mav).emit(o).unwrap());
        l.request(t(100), Some(4), &process);
        l.reply(t(100), &process, &now);
        // A poll begun at 50 ms: 3-03 and 16-02 are answered, 16-14 (a process value) is not.
        assert_eq!(l.answer(&read(303), t(50)), Some(value(303, 50000)));
        assert_eq!(l.answer(&read(1602), t(50)), Some(value(1602, 800)));
        assert_eq!(l.answer(&read(1614), t(50)), None);
        // A write of 3-03 heard, its answer not: 3-03 is no longer known.
        let write = bytes(&|o| Request::write_word(adr, pnu(303), 0, 60000, false).emit(o).unwrap());
        l.request(t(110), Some(4), &write);
        assert_eq!(l.answer(&read(303), t(50)), None);
        // Said at once to a standby's poll (a status is read without it); 16-14 is waited for.
        assert!(l.unheard_setup(&read(303)) && !l.unheard_setup(&read(1614)));
        assert_eq!(l.answer(&read(1602), t(50)), Some(value(1602, 800)));
        // A telegram with a valid control word (bit 10) sets the reference: 16-02 is forgotten.
        let run = bytes(&|o| Request::process(adr, ControlWord(0x047C), Reference(0x2000)).emit(o).unwrap());
        l.request(t(120), Some(4), &run);
        assert_eq!(l.answer(&read(1602), t(50)), None);
        // Read again: known again.
        l.request(t(130), Some(4), &read(303));
        l.reply(t(130), &read(303), &value(303, 60000));
        assert_eq!(l.answer(&read(303), t(50)), Some(value(303, 60000)));
    }

    #[test]
    fn a_tip_set_up_value_answers_whatever_its_age_until_a_write_to_it_is_heard() {
        use drivebus_proto::toshiba::ascii::{AsciiAddress, AsciiRequest};
        use drivebus_proto::toshiba::{CommNo, TipRequest};
        let mut l = Learnt::new(WireProtocol::ToshibaAscii);
        let t = Instant::from_millis;
        let read = |n| TipRequest::Ascii(AsciiRequest::read(AsciiAddress::Unit(0), CommNo(n)).with_sum());
        let reply = |r: &TipRequest, data| {
            let mut out = [0u8; 32];
            let n = r.reply(0, false, data).unwrap().emit(&mut out).unwrap();
            out[..n].to_vec()
        };
        // Inverter 0: FE70 (rated current), f875 and FD00 read at 10 ms; FD00 again at 100 ms.
        for (n, v) in [(0xFE70, 145), (0x0875, 2), (0xFD00, 4000)] {
            l.reply(t(10), &emit(&read(n)), &reply(&read(n), v));
        }
        l.reply(t(100), &emit(&read(0xFD00)), &reply(&read(0xFD00), 4001));
        // A poll begun at 50 ms: FE70 and f875 whatever their age, FD00 only as heard since.
        assert_eq!(l.answer(&emit(&read(0xFE70)), t(50)), Some(reply(&read(0xFE70), 145)));
        assert_eq!(l.answer(&emit(&read(0x0875)), t(50)), Some(reply(&read(0x0875), 2)));
        assert_eq!(l.answer(&emit(&read(0xFD00)), t(50)), Some(reply(&read(0xFD00), 4001)));
        assert_eq!(l.answer(&emit(&read(0xFD00)), t(150)), None);
        // A `P` write of f875 heard (to inverter 0), its answer not: f875 is no longer known.
        let write = TipRequest::Ascii(AsciiRequest::write_ram(AsciiAddress::Unit(0), CommNo(0x0875), 3));
        l.request(t(110), Some(0), &emit(&write));
        assert_eq!(l.answer(&emit(&read(0x0875)), t(50)), None);
        assert_eq!(l.answer(&emit(&read(0xFE70)), t(50)), Some(reply(&read(0xFE70), 145)));
        assert!(l.unheard_setup(&emit(&read(0x0875))));
        assert!(!l.unheard_setup(&emit(&read(0xFE70))) && !l.unheard_setup(&emit(&read(0xFD00))));
    }

    #[test]
    fn a_tip_block_read_is_read_by_the_selections_a_write_set() {
        use drivebus_proto::toshiba::binary::{BinaryAddress, BinaryRequest, BlockRequest};
        use drivebus_proto::toshiba::CommNo;
        let mut l = Learnt::new(WireProtocol::ToshibaBinary);
        let t = Instant::from_millis;
        let emit = |r: BinaryRequest| {
            let mut out = [0u8; 16];
            let n = r.emit(&mut out).unwrap();
            out[..n].to_vec()
        };
        let reply = |r: BinaryRequest, data: u16| {
            let mut out = [0u8; 16];
            let n = r.reply(2, false, data).unwrap().emit(&mut out).unwrap();
            out[..n].to_vec()
        };
        let unit = BinaryAddress::Unit(2);
        let block = BinaryRequest::block(unit, BlockRequest::new(&[], 2).unwrap());
        let block_reply = |rdata: &[u16]| {
            let mut out = [0u8; 16];
            let n = block.block_reply(2, false, rdata).unwrap().emit(&mut out).unwrap();
            out[..n].to_vec()
        };
        // Before the selections are known, a block read answers only itself.
        l.reply(t(10), &emit(block), &block_reply(&[0x0003, 0x0FA0]));
        assert_eq!(l.answer(&emit(block), t(0)), Some(block_reply(&[0x0003, 0x0FA0])));
        assert_eq!(l.answer(&emit(BinaryRequest::read(unit, CommNo(0xFD00))), t(0)), None);
        // The master sets f875 = 12 (FE04) and f876 = 2 (FD00) with `P`, acknowledged.
        for (n, selection) in [(0x0875, 12), (0x0876, 2)] {
            let w = BinaryRequest::write_ram(unit, CommNo(n), selection);
            l.reply(t(20), &emit(w), &reply(w, selection));
        }
        l.reply(t(30), &emit(block), &block_reply(&[0x0123, 0x0FA0]));
        // A read of FD00 and FE04 is answered from the block, in the standby's form (`R`, `G`).
        let fd00 = BinaryRequest::read(unit, CommNo(0xFD00));
        assert_eq!(l.answer(&emit(fd00), t(25)), Some(reply(fd00, 0x0FA0)));
        let fe04 = BinaryRequest::read_dummy(unit, CommNo(0xFE04));
        assert_eq!(l.answer(&emit(fe04), t(25)), Some(reply(fe04, 0x0123)));
        // The block read itself is rebuilt from the items.
        assert_eq!(l.answer(&emit(block), t(25)), Some(block_reply(&[0x0123, 0x0FA0])));
        // The values must be fresh (the selections, the drive's set-up, need not).
        assert_eq!(l.answer(&emit(block), t(35)), None);
    }

    #[test]
    fn the_interval_is_not_skewed_by_a_start_up_burst_a_retry_or_a_busy_master() {
        let mut l = Learnt::new(WireProtocol::ModbusRtu);
        let a = rtu(&[1, 3, 0x21, 0x00, 0, 2]);
        let a_reply = rtu(&[1, 3, 4, 0, 0, 0, 0]);
        let b = rtu(&[2, 3, 0x21, 0x00, 0, 2]);
        let b_reply = rtu(&[2, 3, 4, 0, 0, 0, 0]);
        let t = Instant::from_millis;
        let poll = |l: &mut Learnt, at: u64| {
            l.request(t(at), Some(1), &a);
            l.reply(t(at + 10), &a, &a_reply);
        };
        let ms = Duration::from_millis;
        // Drive 1 polled every 500 ms; its first poll waited out the master's start-up
        // listening, so the second came 30 ms after it.
        poll(&mut l, 0);
        poll(&mut l, 30);
        poll(&mut l, 530);
        assert_eq!(l.interval(1), Some(ms(500)), "of 30 and 500 ms, the longer");
        poll(&mut l, 1030);
        assert_eq!(l.interval(1), Some(ms(500)), "the burst is an outlier");
        // At 1530 drive 1 does not answer; drive 2 is polled, then drive 1 again (the retry,
        // which is no poll, though another request came between).
        l.request(t(1530), Some(1), &a);
        l.request(t(1550), Some(2), &b);
        l.reply(t(1560), &b, &b_reply);
        poll(&mut l, 1580);
        assert_eq!(l.interval(1), Some(ms(500)), "the retry is an outlier");
        poll(&mut l, 2030);
        poll(&mut l, 2530);
        // The master was busy for a second: its next poll of drive 1 came 1500 ms later.
        poll(&mut l, 4030);
        assert_eq!(l.interval(1), Some(ms(500)), "the busy gap is an outlier");
        poll(&mut l, 4530);
        assert_eq!(l.interval(1), Some(ms(500)));
        // The master's interval changes to 200 ms: learnt after three sendings.
        for at in [4730, 4930] {
            poll(&mut l, at);
            assert_eq!(l.interval(1), Some(ms(500)));
        }
        poll(&mut l, 5130);
        assert_eq!(l.interval(1), Some(ms(200)));
    }

    #[test]
    fn the_schedule_is_each_drives_most_frequent_request() {
        let mut l = Learnt::new(WireProtocol::ModbusRtu);
        let a = rtu(&[1, 3, 0x21, 0x00, 0, 2]);
        let b = rtu(&[1, 3, 0x30, 0x00, 0, 1]);
        for k in 0..10u64 {
            l.request(Instant::from_millis(k * 200), Some(1), &a);
            l.request(Instant::from_millis(k * 1000 + 5), Some(1), &b);
        }
        let s = l.schedule();
        assert_eq!(s.get(&1), Some(&Duration::from_millis(200)));
        assert_eq!(s.get(&2), None);
        // Drive 2 polled every second, each poll retried once 50 ms later and answered: every
        // second.
        let c = rtu(&[2, 3, 0x21, 0x00, 0, 2]);
        let answer = rtu(&[2, 3, 4, 0, 0, 0, 0]);
        for k in 0..10u64 {
            l.request(Instant::from_millis(k * 1000), Some(2), &c);
            l.request(Instant::from_millis(k * 1000 + 50), Some(2), &c);
            l.reply(Instant::from_millis(k * 1000 + 60), &c, &answer);
        }
        assert_eq!(l.schedule().get(&2), Some(&Duration::from_secs(1)));
    }
}
