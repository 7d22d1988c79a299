//! Inputs the fuzz targets found, kept as tests named after what they showed.

use drivebus_proto::toshiba::binary::BinaryCodec;
use drivebus_proto::{Codec, Deframer, Direction, Event, Scan, Scanner};

/// fuzz/toshiba_binary crash-59c67dd7: from a drive, `2F 52 52 FF D2` (an R request shape,
/// 5 bytes, good SUM) is delivered once the following bytes prove that the 7-byte R reply
/// reading is wrong; alone, the scanner waits for the 7 bytes a drive's R reply has, so that a
/// real reply whose first 5 bytes happen to sum right is never cut short.
#[test]
fn toshiba_binary_request_shape_from_a_drive_needs_lookahead() {
    let stream =
        [0x2F, 0x52, 0xA0, 0x2F, 0x52, 0xFF, 0x2F, 0x52, 0x52, 0xFF, 0xD2, 0xFF, 0x2F, 0x52, 0x52, 0xFF];
    let mut frames = Vec::new();
    let mut d = Deframer::new(BinaryCodec::scanner(Some(Direction::Drive)));
    d.push(&stream, &mut |e| {
        if let Event::Frame { bytes, position } = e {
            frames.push((position, bytes.to_vec()))
        }
    });
    assert_eq!(frames, [(6, vec![0x2F, 0x52, 0x52, 0xFF, 0xD2])]);
    let alone = BinaryCodec::scanner(Some(Direction::Drive)).scan(&[0x2F, 0x52, 0x52, 0xFF, 0xD2], 0);
    assert_eq!(alone, Scan::Incomplete { checked: 0 });
    // A 7-byte reply whose first 5 bytes also sum right is taken whole.
    let reply = [0x2F, 0x52, 0x52, 0xFF, 0xD2, 0x00, 0xA4];
    assert_eq!(drivebus_proto::checksum::sum8(&reply[..6]), 0xA4);
    assert_eq!(BinaryCodec::scanner(Some(Direction::Drive)).scan(&reply, 0), Scan::Frame { len: 7 });
}
