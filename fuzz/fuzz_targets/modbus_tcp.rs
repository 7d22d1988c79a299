#![no_main]
//! Fuzzes the Modbus TCP request reading the gateway does: MBAP headers and request PDUs taken
//! off a client's stream one after the other (`drivebus_proto::modbus::tcp::Mbap`,
//! `RequestPdu`). Checks: nothing panics; a header that reads back names a frame within the
//! longest a PDU allows; a request that parses emits back to the bytes it was read from.

use drivebus_proto::modbus::tcp::{Mbap, MAX_ADU, MBAP_LEN};
use drivebus_proto::modbus::RequestPdu;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let mut pos = 0;
    while let Ok(Some(header)) = Mbap::parse(&data[pos..]) {
        let end = pos + header.frame_len();
        assert!(header.frame_len() <= MAX_ADU);
        let Some(pdu) = data.get(pos + MBAP_LEN..end) else { break };
        if let Ok(request) = RequestPdu::parse(pdu) {
            let mut out = [0u8; MAX_ADU];
            let n = request.emit(&mut out).expect("a request that parsed emits");
            assert_eq!(&out[..n], pdu, "a parsed request emits as it was read");
        }
        pos = end;
    }
});
