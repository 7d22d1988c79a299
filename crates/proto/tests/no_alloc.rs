//! Deframing, parsing and describing a frame allocate nothing: a counting allocator watches
//! this thread while every codec decodes a stream of the manuals' frames.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

use drivebus_proto::{b800, fc, modbus, toshiba};
use drivebus_proto::{Codec, Deframer, Describe, Direction, Event};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if ARMED.with(|a| a.get()) {
            ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if ARMED.with(|a| a.get()) {
            ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Decodes `stream` in chunks of 3 bytes (so frames straddle pushes) and describes every
/// frame; returns (frames, allocations).
fn decode<C: Codec>(stream: &[u8], from: Direction) -> (usize, usize) {
    let mut deframer = Deframer::new(C::scanner(Some(from)));
    let mut frames = 0usize;
    let mut field_chars = 0usize;
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    ARMED.with(|a| a.set(true));
    for chunk in stream.chunks(3) {
        deframer.push(chunk, &mut |e| {
            if let Event::Frame { bytes, .. } = e {
                if let Ok(f) = C::parse(bytes, Some(from)) {
                    frames += 1;
                    let _ = (f.direction(), f.target(), f.command());
                    f.fields(&mut |field| field_chars += field.name.len());
                }
            }
        });
    }
    deframer.finish(&mut |_| {});
    ARMED.with(|a| a.set(false));
    assert!(field_chars > 0);
    (frames, ALLOCATIONS.load(Ordering::SeqCst) - before)
}

fn repeated(frame: &[u8], garbage: &[u8]) -> Vec<u8> {
    let mut v = Vec::new();
    for _ in 0..100 {
        v.extend_from_slice(frame);
        v.extend_from_slice(garbage);
    }
    v
}

/// A codec's decoding loop, returning (frames, allocations).
type Decoder = fn(&[u8], Direction) -> (usize, usize);

#[test]
fn no_codec_allocates_per_frame() {
    let cases: Vec<(&str, Decoder, Vec<u8>, Direction)> = vec![
        (
            "modbus-rtu",
            decode::<modbus::rtu::ModbusRtu>,
            repeated(&[0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50], &[]),
            Direction::Drive,
        ),
        (
            "modbus-ascii",
            decode::<modbus::ascii::ModbusAscii>,
            repeated(b":010321020002D7\r\n", b"zz"),
            Direction::Master,
        ),
        (
            "toshiba-ascii",
            decode::<toshiba::ascii::AsciiCodec>,
            repeated(b"(RFE03077B)\r", b"\x00"),
            Direction::Drive,
        ),
        (
            "toshiba-binary",
            decode::<toshiba::binary::BinaryCodec>,
            repeated(&[0x2F, 0x57, 0x00, 0x10, 0x00, 0x64, 0xFA], &[]),
            Direction::Master,
        ),
        (
            "danfoss-fc",
            decode::<fc::DanfossFc>,
            repeated(&[0x02, 0x0E, 0x01, 0x22, 0x08, 0, 0, 0, 0, 0x02, 0x0C, 0x06, 0x07, 0, 0, 0x28], &[]),
            Direction::Drive,
        ),
        ("b800", decode::<b800::B800>, repeated(b"\x7E85500960\x35\x45\x7F", b"\x00"), Direction::Master),
    ];
    for (name, f, stream, from) in cases {
        let (frames, allocations) = f(&stream, from);
        assert_eq!(frames, 100, "{name}: every frame decodes");
        assert_eq!(allocations, 0, "{name}: decoding allocated {allocations} times");
    }
}
