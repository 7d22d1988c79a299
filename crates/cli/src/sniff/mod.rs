//! The passive sniffer's logic, without I/O (`drivebus sniff` is in `commands::sniff`):
//! [`analyze`] frames, pairs and counts what a listener hears, [`detect`] finds the baud rate and
//! format from traffic, [`capture`] writes and reads captures.

pub use drivebus_analyze as analyze;
pub mod capture;
pub mod detect;

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use drivebus_drive::profile::{for_drive, run_blocking, DriveError, Operation};
    use drivebus_proto::line::{CharFormat, Parity};
    use drivebus_proto::{Direction, Instant};
    use drivebus_sim::bus::VirtualLine;
    use drivebus_sim::config::{BusSpec, DriveSpec};

    use super::analyze::{Analyzer, Kind, Record, Settings, Side};
    use super::detect::{candidates_for, detect, find_setting, Burst, SettingPort};

    /// Line traffic of `exchanges` status reads of the drive `spec` on a simulated line, as a
    /// listener hears it: (when each burst's first character starts, its bytes). Also the line's
    /// baud and format.
    fn traffic(
        spec: &str,
        baud: Option<u32>,
        format: Option<CharFormat>,
        exchanges: usize,
    ) -> (u32, CharFormat, Vec<Burst>) {
        traffic_every(spec, baud, format, exchanges, Duration::from_millis(300))
    }

    /// [`traffic`] with a master that sends a request every `period`.
    fn traffic_every(
        spec: &str,
        baud: Option<u32>,
        format: Option<CharFormat>,
        exchanges: usize,
        period: Duration,
    ) -> (u32, CharFormat, Vec<Burst>) {
        let drive: DriveSpec = spec.parse().expect("drive spec");
        let bus = BusSpec::new(vec![drive], baud, format).expect("bus");
        let d = &bus.drives[0];
        let mut line = VirtualLine::new(bus.baud, bus.format, Instant::ZERO);
        line.add_device(drivebus_sim::family::build(d, Instant::ZERO).expect("drive"));
        line.attach_tap();
        let protocol = d.protocol.unwrap_or_else(|| d.wire_protocols()[0]);
        let profile = for_drive(d.family, protocol, d.address).expect("profile");
        let mut bursts = Vec::new();
        let mut t = Instant::from_millis(10);
        let mut tap = Vec::new();
        for _ in 0..exchanges {
            let mut plan = profile.plan(&Operation::Status).expect("plan");
            let status = run_blocking(&mut *plan, |ex| {
                line.run_until(t);
                line.master_write(t, &ex.request);
                let end = t + period;
                while let Some(at) = line.next_deadline().filter(|&at| at <= end) {
                    line.advance_to(at);
                    tap.clear();
                    line.tap_read(&mut tap);
                    if !tap.is_empty() {
                        let start = at - line.char_time() * tap.len() as u32;
                        bursts.push((Duration::from_nanos(start.as_nanos()), tap.clone()));
                    }
                }
                line.advance_to(end);
                let mut got = Vec::new();
                line.master_read(&mut got);
                t = end;
                Ok::<_, DriveError>(ex.expect_reply.then_some(got))
            });
            status.expect("a status");
        }
        (bus.baud, bus.format, bursts)
    }

    /// Every burst pushed as one read at the time its last character ends.
    fn listen(
        bursts: &[Burst],
        baud: u32,
        format: CharFormat,
        protocols: Vec<&'static str>,
    ) -> (Analyzer, Vec<Record>) {
        let mut a = Analyzer::new(Settings {
            protocols,
            baud,
            format,
            reply_timeout: Duration::from_millis(500),
            sides: vec![Side::Both],
        });
        let mut out = Vec::new();
        let mut end = Duration::ZERO;
        for (start, bytes) in bursts {
            end = *start + format.wire_time(baud, bytes.len());
            out.extend(a.tick(end));
            out.extend(a.push(0, end, bytes));
        }
        out.extend(a.finish(end + Duration::from_secs(1)));
        (a, out)
    }

    const SIX: [(&str, &str); 6] = [
        ("generic@1:modbus-rtu", "modbus-rtu"),
        ("generic@1:modbus-ascii", "modbus-ascii"),
        ("toshiba@3:toshiba-ascii", "toshiba-ascii"),
        ("toshiba@3:toshiba-binary", "toshiba-binary"),
        ("danfoss@4", "danfoss-fc"),
        ("b800@5", "b800"),
    ];

    #[test]
    fn each_protocol_is_found_and_every_request_paired_with_its_reply() {
        for (spec, protocol) in SIX {
            let (baud, format, bursts) = traffic(spec, None, None, 6);
            let (a, records) = listen(&bursts, baud, format, Vec::new());
            assert_eq!(a.protocols(), [protocol], "{spec}");
            let requests: Vec<&Record> = records
                .iter()
                .filter(|r| r.direction == Direction::Master && r.kind == Kind::Frame)
                .collect();
            let replies: Vec<&Record> = records.iter().filter(|r| r.direction == Direction::Drive).collect();
            assert!(requests.len() >= 6, "{spec}: {records:#?}");
            assert_eq!(requests.len(), replies.len(), "{spec}: {records:#?}");
            assert!(records.iter().all(|r| r.valid() && r.kind == Kind::Frame), "{spec}: {records:#?}");
            for r in &replies {
                let l = r.latency.unwrap_or_else(|| panic!("{spec}: a reply without latency: {r:?}"));
                // The drive answers 5 ms after the request, plus the reply's wire time.
                assert!(l >= Duration::from_millis(5) && l < Duration::from_millis(200), "{spec}: {l:?}");
            }
            let stats: Vec<_> = a.stats().values().collect();
            assert_eq!(stats.len(), 1, "{spec}: one address: {:?}", a.stats());
            assert_eq!(stats[0].requests, requests.len() as u64);
            assert_eq!(stats[0].replies, replies.len() as u64);
            assert_eq!((stats[0].timeouts, stats[0].errors), (0, 0));
            assert!(stats[0].latency_quantile(0.5) <= stats[0].latency_quantile(0.99));
            let load = a.bus_load();
            assert!(load > 0.0 && load < 1.0, "{spec}: {load}");
        }
    }

    #[test]
    fn a_request_without_reply_is_a_timeout_and_a_damaged_reply_an_error() {
        // A status read is two exchanges: four requests in all.
        let (baud, format, mut bursts) = traffic("generic@7:modbus-rtu", None, None, 2);
        // Remove the first reply, damage the second's CRC.
        assert_eq!(bursts.len(), 8, "{bursts:?}");
        bursts.remove(1);
        let n = bursts[2].1.len();
        bursts[2].1[n - 1] ^= 0xFF;
        let (a, records) = listen(&bursts, baud, format, vec!["modbus-rtu"]);
        let s = &a.stats()[&("modbus-rtu", 7)];
        assert_eq!((s.requests, s.replies, s.timeouts, s.errors), (4, 2, 1, 1), "{records:#?}");
        assert!(records.iter().any(|r| r.kind == Kind::NoReply && r.json()["error"] == "no reply"));
        let bad = records.iter().find(|r| !r.valid() && r.kind == Kind::Frame).expect("the damaged reply");
        assert_eq!(bad.direction, Direction::Drive);
        assert_eq!(bad.address(), Some(7));
        assert!(
            bad.json()["error"].as_str().is_some_and(|e| e.contains("CRC") || e.contains("checksum")),
            "{}",
            bad.json()
        );
    }

    fn rtu(body: &[u8]) -> Vec<u8> {
        let mut v = body.to_vec();
        v.extend_from_slice(&drivebus_proto::checksum::crc16_modbus(body).to_le_bytes());
        v
    }

    #[test]
    fn a_master_retrying_a_silent_drive_is_not_its_echo() {
        // 06 to drive 3 (no such drive) three times 112 ms apart, then 06 to drive 1 and its
        // echo 14 ms later.
        let to3 = rtu(&[3, 6, 0x20, 1, 0x0F, 0xA0]);
        let to1 = rtu(&[1, 6, 0x20, 1, 0x0F, 0xA0]);
        let ms = Duration::from_millis;
        let bursts: Vec<Burst> = vec![
            (ms(0), to3.clone()),
            (ms(112), to3.clone()),
            (ms(224), to3),
            (ms(340), to1.clone()),
            (ms(354), to1),
        ];
        let (a, records) = listen(&bursts, 9600, CharFormat::EVEN_8E1, vec!["modbus-rtu"]);
        let shape: Vec<(Direction, Option<u8>, bool)> =
            records.iter().map(|r| (r.direction, r.address(), r.kind == Kind::NoReply)).collect();
        use Direction::{Drive, Master};
        assert_eq!(
            shape,
            [
                (Master, Some(3), false),
                (Master, Some(3), true),
                (Master, Some(3), false),
                (Master, Some(3), true),
                (Master, Some(3), false),
                (Master, Some(3), true),
                (Master, Some(1), false),
                (Drive, Some(1), false),
            ],
            "{records:#?}"
        );
        let s3 = &a.stats()[&("modbus-rtu", 3)];
        assert_eq!((s3.requests, s3.replies, s3.timeouts), (3, 0, 3));
        let s1 = &a.stats()[&("modbus-rtu", 1)];
        assert_eq!((s1.requests, s1.replies, s1.timeouts), (1, 1, 0));
        assert!(records[7].latency.is_some_and(|l| l < ms(20)));
    }

    #[test]
    fn a_second_protocol_that_starts_later_is_found_and_its_first_frames_decoded() {
        // Modbus RTU first, then B800 on the same line (at the same baud and format).
        let (baud, format, mut bursts) =
            traffic("generic@1:modbus-rtu", Some(9600), Some(CharFormat::NONE_8N1), 3);
        let (_, _, b800) = traffic("b800@5", Some(9600), Some(CharFormat::NONE_8N1), 2);
        let shift = bursts.last().unwrap().0 + Duration::from_millis(100);
        bursts.extend(b800.iter().map(|(t, b)| (*t + shift, b.clone())));
        let (a, records) = listen(&bursts, baud, format, Vec::new());
        assert_eq!(a.protocols(), ["modbus-rtu", "b800"]);
        assert!(records.iter().all(|r| r.valid()), "no B800 byte is a Modbus error: {records:#?}");
        assert_eq!(a.garbled(), 0);
        let b: Vec<&Record> = records.iter().filter(|r| r.protocol == "b800").collect();
        assert_eq!(b.len(), b800.len(), "every B800 frame, the first ones too: {b:#?}");
        assert!(b.iter().filter(|r| r.direction == Direction::Drive).all(|r| r.latency.is_some()));
    }

    #[test]
    fn a_frame_split_across_late_reads_stays_whole_and_a_cut_one_ends_at_the_silence() {
        // At 115200 t3.5 is 1.75 ms; a reply read in two pieces 37 ms apart (a stalled reader)
        // is still one frame.
        let req = rtu(&[1, 3, 0x21, 0, 0, 2]);
        let reply = rtu(&[1, 3, 4, 0, 0, 0x0A, 0]);
        let ms = Duration::from_millis;
        let mut a = Analyzer::new(Settings {
            protocols: vec!["modbus-rtu"],
            baud: 115200,
            format: CharFormat::NONE_8N1,
            reply_timeout: ms(500),
            sides: vec![Side::Both],
        });
        let mut out = a.push(0, ms(10), &[&req[..], &reply[..2]].concat());
        out.extend(a.tick(ms(12)));
        out.extend(a.push(0, ms(47), &reply[2..]));
        assert_eq!(out.len(), 2, "{out:#?}");
        assert!(out.iter().all(|r| r.valid()));
        assert_eq!(out[1].latency, Some(ms(37)));
        // A reply cut short, then a silence and the next request: the cut one is invalid at
        // once, the request after it valid.
        let mut out = a.push(0, ms(100), &req);
        out.extend(a.push(0, ms(110), &reply[..5]));
        out.extend(a.push(0, ms(120), &req));
        out.extend(a.finish(ms(200)));
        let valid: Vec<bool> = out.iter().filter(|r| r.kind == Kind::Frame).map(|r| r.valid()).collect();
        assert_eq!(valid, [true, false, true], "{out:#?}");
    }

    #[test]
    fn json_has_the_fields_the_issue_names() {
        let (baud, format, bursts) = traffic("generic@2:modbus-rtu", None, None, 2);
        let (_, records) = listen(&bursts, baud, format, vec!["modbus-rtu"]);
        let req = records[0].json();
        for key in ["time", "protocol", "direction", "address", "valid", "function", "fields"] {
            assert!(req.get(key).is_some(), "{key} missing in {req}");
        }
        assert_eq!(req["direction"], "master");
        assert_eq!(req["address"], 2);
        assert_eq!(req["function"], 3);
        let reply = records[1].json();
        assert_eq!(reply["direction"], "drive");
        assert!(reply["latency_ms"].as_f64().is_some_and(|l| l > 5.0), "{reply}");
        assert!(reply.get("error").is_none());
    }

    #[test]
    fn four_wire_ports_give_the_direction() {
        let (baud, format, bursts) = traffic("b800@9", None, None, 2);
        let mut a = Analyzer::new(Settings {
            protocols: Vec::new(),
            baud,
            format,
            reply_timeout: Duration::from_millis(500),
            sides: vec![Side::Only(Direction::Master), Side::Only(Direction::Drive)],
        });
        let mut out = Vec::new();
        for (i, (start, bytes)) in bursts.iter().enumerate() {
            out.extend(a.push(i % 2, *start + format.wire_time(baud, bytes.len()), bytes));
        }
        out.extend(a.finish(Duration::from_secs(9)));
        let dirs: Vec<Direction> = out.iter().map(|r| r.direction).collect();
        assert_eq!(
            dirs,
            [Direction::Master, Direction::Drive, Direction::Master, Direction::Drive],
            "{out:#?}"
        );
        assert!(out[1].latency.is_some() && out[3].latency.is_some());
    }

    /// Baud, data bits and parity (a receiver cannot tell stop bits apart, see `detect`).
    fn key(baud: u32, f: CharFormat) -> (u32, u8, Parity) {
        (baud, f.data_bits, f.parity)
    }

    #[test]
    fn baud_format_and_protocol_are_found_from_recorded_traffic() {
        let odd8 = CharFormat { data_bits: 8, parity: Parity::Odd, stop_bits: 1 };
        let even7 = CharFormat { data_bits: 7, parity: Parity::Even, stop_bits: 1 };
        let cases: [(&str, &str, Option<u32>, Option<CharFormat>); 9] = [
            (SIX[0].0, SIX[0].1, None, None),
            (SIX[0].0, SIX[0].1, Some(38400), Some(odd8)),
            (SIX[1].0, SIX[1].1, None, None),
            (SIX[1].0, SIX[1].1, Some(19200), Some(even7)),
            (SIX[2].0, SIX[2].1, None, None),
            (SIX[3].0, SIX[3].1, Some(57600), None),
            (SIX[4].0, SIX[4].1, None, None),
            (SIX[5].0, SIX[5].1, None, None),
            (SIX[5].0, SIX[5].1, Some(115200), Some(CharFormat::EVEN_8E1)),
        ];
        for (spec, protocol, baud, format) in cases {
            let (baud, format, bursts) = traffic(spec, baud, format, 4);
            let ((b, f), score) =
                detect(&bursts, baud, format).unwrap_or_else(|| panic!("{spec}: nothing found"));
            assert_eq!(key(b, f), key(baud, format), "{spec} at {baud} {format}: found {b} {f}");
            assert_eq!(score.protocol, Some(protocol), "{spec} at {baud} {format}");
            assert!(score.frames >= 8, "{spec}: {score:?}");
        }
    }

    /// A serial port at some setting on a line carrying recorded `bursts`: what it reads is what
    /// a UART at its setting makes of each burst (see `detect::receive`), handed over when the
    /// burst's last character has arrived, on a simulated clock that a read with nothing to give
    /// advances by the port's read timeout, as the real port's 100 ms does.
    struct ReplayPort {
        bursts: Vec<Burst>,
        baud: u32,
        format: CharFormat,
        setting: (u32, CharFormat),
        set_at: Duration,
        now: Duration,
        next: usize,
        /// Every setting asked for, in order.
        sets: Vec<(u32, CharFormat)>,
    }

    impl ReplayPort {
        fn new(bursts: Vec<Burst>, baud: u32, format: CharFormat) -> ReplayPort {
            let setting = (9600, CharFormat::NONE_8N1);
            ReplayPort {
                bursts,
                baud,
                format,
                setting,
                set_at: Duration::ZERO,
                now: Duration::ZERO,
                next: 0,
                sets: Vec::new(),
            }
        }
    }

    impl SettingPort for ReplayPort {
        fn set(&mut self, baud: u32, format: CharFormat) -> std::io::Result<()> {
            self.setting = (baud, format);
            self.set_at = self.now;
            self.sets.push((baud, format));
            Ok(())
        }
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let until = self.now + Duration::from_millis(100);
            let Some((start, bytes)) = self.bursts.get(self.next) else {
                self.now = until;
                return Ok(0);
            };
            let end = *start + self.format.wire_time(self.baud, bytes.len());
            if end > until {
                self.now = until;
                return Ok(0);
            }
            self.next += 1;
            self.now = self.now.max(end);
            // A burst that began before the port was set is lost with the flush.
            if *start < self.set_at {
                return Ok(0);
            }
            let got = super::detect::receive(
                &[(*start, bytes.clone())],
                self.baud,
                self.format,
                self.setting.0,
                self.setting.1,
            );
            buf[..got.len()].copy_from_slice(&got);
            Ok(got.len())
        }
        fn now(&self) -> Duration {
            self.now
        }
    }

    #[test]
    fn a_slow_master_is_found_on_the_port_path_at_its_real_timing() {
        // A master reading a drive's status every 700 ms (each read two exchanges), at 38400 8O1:
        // the 22nd of 36 candidates. With 150 ms at each candidate the right one heard at most a
        // burst or two; the search listens until it has heard enough.
        let odd8 = CharFormat { data_bits: 8, parity: Parity::Odd, stop_bits: 1 };
        for (spec, protocol) in [SIX[0], SIX[4]] {
            let (baud, format, bursts) =
                traffic_every(spec, Some(38400), Some(odd8), 60, Duration::from_millis(700));
            let mut port = ReplayPort::new(bursts, baud, format);
            let found = find_setting(&mut port, candidates_for(None, None), || false).unwrap();
            let ((b, f), score) =
                found.unwrap_or_else(|| panic!("{spec}: nothing found; tried {:?}", port.sets));
            assert_eq!(key(b, f), key(38400, odd8), "{spec}: found {b} {f}");
            assert_eq!(score.protocol, Some(protocol), "{spec}");
            assert!(score.frames >= super::detect::ENOUGH_FRAMES, "{spec}: {score:?}");
            assert!(port.sets.len() <= 36, "{spec}: {}", port.sets.len());
            // It took as long as the traffic needed, not the worst case of every candidate.
            assert!(port.now < Duration::from_secs(60), "{spec}: {:?}", port.now);
        }
    }

    #[test]
    fn a_given_baud_or_format_narrows_the_search_to_it() {
        let even7 = CharFormat { data_bits: 7, parity: Parity::Even, stop_bits: 1 };
        let (baud, format, bursts) =
            traffic_every(SIX[1].0, Some(19200), Some(even7), 40, Duration::from_millis(250));
        // --baud 19200: only the formats at 19200 are tried.
        let mut port = ReplayPort::new(bursts.clone(), baud, format);
        let ((b, f), _) =
            find_setting(&mut port, candidates_for(Some(19200), None), || false).unwrap().unwrap();
        assert_eq!(key(b, f), key(19200, even7));
        assert!(port.sets.iter().all(|(b, _)| *b == 19200), "{:?}", port.sets);
        // --serial 7E1: only the baud rates, in that format.
        let mut port = ReplayPort::new(bursts, baud, format);
        let ((b, f), _) =
            find_setting(&mut port, candidates_for(None, Some(even7)), || false).unwrap().unwrap();
        assert_eq!(key(b, f), key(19200, even7));
        assert!(port.sets.iter().all(|(_, f)| *f == even7), "{:?}", port.sets);
        assert_eq!(candidates_for(Some(9600), Some(even7)), [(9600, even7)]);
        assert_eq!(candidates_for(None, None).len(), 36);
    }

    #[test]
    fn the_search_listens_by_what_it_hears_on_explicit_times() {
        use super::detect::{Search, Step, GIVE_UP, MAX_LISTEN, MIN_LISTEN};
        let ms = Duration::from_millis;
        let two = vec![(9600, CharFormat::EVEN_8E1), (19200, CharFormat::EVEN_8E1)];
        // Nothing heard: it waits at the first candidate, then gives up.
        let mut s = Search::new(two.clone(), ms(0));
        assert_eq!(s.poll(ms(4000)), Step::Listen(GIVE_UP));
        assert_eq!(s.poll(GIVE_UP), Step::Done(None));
        // Noise (no valid frame) once a second: until the pace is known a candidate gets the
        // longest budget, then three of the gaps heard.
        let mut s = Search::new(two.clone(), ms(0));
        s.push(ms(1000), &[0x55; 8]);
        assert_eq!(s.poll(ms(1000)), Step::Listen(ms(1000) + MAX_LISTEN));
        s.push(ms(2000), &[0x55; 8]);
        s.push(ms(3000), &[0x55; 8]);
        assert_eq!(s.poll(ms(3000)), Step::Listen(ms(1000) + MAX_LISTEN));
        assert_eq!(s.poll(ms(1000) + MAX_LISTEN), Step::Switch(19200, CharFormat::EVEN_8E1));
        // Once six bursts were heard the budget is three of the longest gap: traffic every
        // 400 ms gives a candidate 1.2 s.
        let mut s = Search::new(vec![(9600, CharFormat::EVEN_8E1)], ms(0));
        for i in 0..5 {
            s.push(ms(1000 + 400 * i), &[0x55; 8]);
        }
        assert_eq!(s.budget(), MAX_LISTEN);
        s.push(ms(3000), &[0x55; 8]);
        assert_eq!(s.budget(), ms(1200));
        assert_eq!(s.poll(ms(3000)), Step::Done(None), "six bursts and no valid frame: the last candidate");
        // Quick traffic (bursts 20 ms apart) after a fresh start: six bursts end a candidate as
        // soon as it has listened MIN_LISTEN.
        let mut s = Search::new(two, ms(0));
        for i in 0..6 {
            s.push(ms(10 + 20 * i), &[0x55; 4]);
        }
        assert!(matches!(s.poll(ms(150)), Step::Listen(_)));
        assert_eq!(s.poll(ms(10) + MIN_LISTEN), Step::Switch(19200, CharFormat::EVEN_8E1));
        // A valid frame four times over ends the search at once.
        let req = rtu(&[1, 3, 0x21, 0, 0, 2]);
        for i in 0..4 {
            s.push(ms(300 + 30 * i), &req);
        }
        match s.poll(ms(400)) {
            Step::Done(Some(((19200, f), score))) => {
                assert_eq!((f, score.protocol), (CharFormat::EVEN_8E1, Some("modbus-rtu")))
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn the_uart_model_garbles_a_wrong_setting() {
        let bursts: Vec<Burst> = vec![(Duration::ZERO, b"HELLO".to_vec())];
        let right = super::detect::receive(&bursts, 9600, CharFormat::EVEN_8E1, 9600, CharFormat::EVEN_8E1);
        assert_eq!(right, b"HELLO");
        let wrong_baud =
            super::detect::receive(&bursts, 9600, CharFormat::EVEN_8E1, 19200, CharFormat::EVEN_8E1);
        assert_ne!(wrong_baud, b"HELLO");
        // 'E', 'L', 'O' have an odd number of ones: even parity bit 1, so an 8N1 receiver sees a
        // good stop bit; 'H' = 0x48 has 2: parity 0, a framing error (00).
        let no_parity =
            super::detect::receive(&bursts, 9600, CharFormat::EVEN_8E1, 9600, CharFormat::NONE_8N1);
        assert_eq!(no_parity, [0, b'E', b'L', b'L', b'O']);
    }

    #[test]
    fn a_capture_reads_back_as_written() {
        use super::capture::{read, PcapWriter};
        let mut buf = Vec::new();
        let mut w = PcapWriter::new(&mut buf).unwrap();
        let t = Duration::from_micros(1_700_000_000_123_456);
        w.frame(t, "modbus-rtu", Direction::Master, &[1, 3, 0x21, 2, 0, 1, 0x2E, 0x36]).unwrap();
        w.frame(t + Duration::from_millis(7), "b800", Direction::Drive, &[0x7E, 1, 2, 3, 0x7F]).unwrap();
        drop(w);
        let p = read(&buf).unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!(
            (p[0].time, p[0].protocol, p[0].direction),
            (t, Some("modbus-rtu"), Some(Direction::Master))
        );
        assert_eq!(p[0].bytes, [1, 3, 0x21, 2, 0, 1, 0x2E, 0x36]);
        assert_eq!((p[1].protocol, p[1].direction), (Some("b800"), Some(Direction::Drive)));
        assert_eq!(p[1].time - p[0].time, Duration::from_millis(7));
        let hex = read(b"# a request\n01 03 21 02 00 01 2E 36\n\n7E 30 35 37 30 33 33 7F\n").unwrap();
        assert_eq!(hex.len(), 2);
        assert!(read(b"01 0Z\n").unwrap_err().to_string().contains("line 1"));
    }
}
