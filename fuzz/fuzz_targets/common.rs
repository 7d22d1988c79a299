//! The harness every deframer target shares.
//!
//! The first input byte picks a direction and a chunk size; the rest is the byte stream. The
//! stream is fed in chunks, with a silence signal after some chunks; every frame is parsed and
//! described. Checks: nothing panics; every byte is either in a good frame or counted as
//! dropped; every good frame re-scans, alone (followed by silence where the protocol delimits
//! frames by silence), as a good frame of the same length.

use drivebus_proto::deframe::Scanner;
use drivebus_proto::describe::Describe;
use drivebus_proto::{Codec, Deframer, Direction, Event, Scan};

pub fn run<C: Codec>(data: &[u8]) {
    let Some((&ctl, stream)) = data.split_first() else { return };
    let from = match ctl & 3 {
        0 => None,
        1 => Some(Direction::Master),
        _ => Some(Direction::Drive),
    };
    let chunk = 1 + (ctl >> 2) as usize;
    let silence_every = (ctl >> 5) as usize; // 0: never
    let mut deframer = Deframer::new(C::scanner(from));
    let mut frame_bytes = 0u64;
    let mut check = |e: Event<'_>| {
        if let Event::Frame { bytes, .. } = e {
            frame_bytes += bytes.len() as u64;
            // Alone, the frame scans as itself, or (Modbus RTU) silence after it makes it one,
            // or the scanner waits for more: a lookahead protocol (TIP binary from a drive takes
            // a 5-byte request shape only once 7 bytes prove the 7-byte reply reading wrong).
            // It must never reject or skip a frame it delivered.
            let scanner = C::scanner(from);
            let alone = scanner.scan(bytes, 0);
            let whole = |s: Scan| matches!(s, Scan::Frame { len } if len == bytes.len());
            assert!(
                whole(alone) || whole(scanner.silence(bytes)) || matches!(alone, Scan::Incomplete { .. }),
                "a delivered frame does not scan alone as the same frame: {alone:?}"
            );
            if let Ok(frame) = C::parse(bytes, from) {
                let _ = (frame.direction(), frame.target(), frame.command(), frame.is_refusal());
                let mut n = 0usize;
                frame.fields(&mut |f| {
                    n += f.name.len();
                });
                core::hint::black_box(n);
            }
        }
    };
    for (i, piece) in stream.chunks(chunk).enumerate() {
        deframer.push(piece, &mut check);
        if silence_every != 0 && i % silence_every == 0 {
            deframer.silence(&mut check);
        }
        assert!(deframer.buffered() <= core::mem::size_of::<<C::Scanner as Scanner>::Buffer>());
    }
    deframer.finish(&mut check);
    let stats = deframer.stats();
    assert_eq!(deframer.buffered(), 0);
    assert_eq!(
        frame_bytes + stats.dropped_bytes,
        stream.len() as u64,
        "bytes in frames plus bytes dropped must be every byte fed"
    );
}
