//! Whatever a client sends, the Modbus TCP server answers every well-framed request with a
//! well-formed reply (data or exception) in order, closes connections whose framing is broken,
//! keeps serving everyone else, and never panics.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use drivebus_gateway::{Gateway, GatewayConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

static PANICS: AtomicUsize = AtomicUsize::new(0);

/// A small deterministic generator (xorshift), so a failure can be replayed.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

fn random_pdu(rng: &mut Rng) -> Vec<u8> {
    const FUNCTIONS: [u8; 11] = [0x01, 0x03, 0x04, 0x05, 0x06, 0x08, 0x0F, 0x10, 0x17, 0x2B, 0x90];
    let fc = if rng.below(8) == 0 { rng.below(256) as u8 } else { FUNCTIONS[rng.below(11) as usize] };
    let len = rng.below(40) as usize;
    let mut pdu = vec![fc];
    for _ in 0..len {
        // Small numbers often, so addresses and counts land near the map's edges.
        let b = if rng.below(2) == 0 { rng.below(4) as u8 } else { rng.below(256) as u8 };
        pdu.push(b);
    }
    pdu
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn random_requests_get_well_formed_answers_and_never_a_panic() {
    let previous = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        PANICS.fetch_add(1, Ordering::SeqCst);
        previous(info);
    }));
    let mut config = GatewayConfig::demo();
    config.store = None;
    // Writes are refused at once (no bus time), after the request has been parsed and checked.
    config.modbus.read_only = true;
    let gw: Arc<Gateway> = Gateway::start(config, None).unwrap();
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(drivebus_gateway::modbus_tcp::serve(gw.clone(), listener));

    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut s = TcpStream::connect(addr).await.unwrap();
    let mut answered = 0;
    for batch in 0..100u16 {
        // 20 pipelined requests per write, each to a unit 0..12 (10 exist).
        let mut out = Vec::new();
        let mut sent = Vec::new();
        for k in 0..20u16 {
            let tid = batch * 20 + k;
            let unit = rng.below(13) as u8;
            let pdu = random_pdu(&mut rng);
            out.extend_from_slice(&tid.to_be_bytes());
            out.extend_from_slice(&[0, 0]);
            out.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
            out.push(unit);
            out.extend_from_slice(&pdu);
            sent.push((tid, unit, pdu[0]));
        }
        s.write_all(&out).await.unwrap();
        for (tid, unit, fc) in sent {
            let mut h = [0u8; 7];
            tokio::time::timeout(Duration::from_secs(60), s.read_exact(&mut h))
                .await
                .expect("an answer in time")
                .unwrap_or_else(|e| {
                    panic!("request {tid} (unit {unit}, FC {fc:02X}): connection closed: {e}")
                });
            assert_eq!(u16::from_be_bytes([h[0], h[1]]), tid, "answers in order");
            assert_eq!(&h[2..4], &[0, 0]);
            assert_eq!(h[6], unit);
            let len = u16::from_be_bytes([h[4], h[5]]) as usize;
            assert!((3..=254).contains(&len), "length {len}");
            let mut pdu = vec![0u8; len - 1];
            s.read_exact(&mut pdu).await.unwrap();
            assert_eq!(pdu[0] & 0x7F, fc & 0x7F, "request {tid}: the answer's function");
            if pdu[0] & 0x80 != 0 {
                assert_eq!(pdu.len(), 2);
                assert!([1, 2, 3, 4, 0x0A, 0x0B].contains(&pdu[1]), "exception {:02X}", pdu[1]);
            } else if fc == 0x03 || fc == 0x04 {
                assert_eq!(pdu.len(), 2 + pdu[1] as usize, "byte count");
            }
            answered += 1;
        }
    }
    assert_eq!(answered, 2000);

    // Broken framing closes that connection only.
    for garbage in [&[0u8, 1, 0, 7, 0, 6, 1, 3][..], &[0, 1, 0, 0, 0, 0], &[0, 1, 0, 0, 1, 0, 1]] {
        let mut bad = TcpStream::connect(addr).await.unwrap();
        bad.write_all(garbage).await.unwrap();
        bad.write_all(&[0u8; 64]).await.unwrap();
        let mut buf = [0u8; 16];
        let n =
            tokio::time::timeout(Duration::from_secs(60), bad.read(&mut buf)).await.expect("closed in time");
        assert!(matches!(n, Ok(0) | Err(_)), "{garbage:02X?}: {n:?}");
    }
    let mut good = TcpStream::connect(addr).await.unwrap();
    good.write_all(&[0, 9, 0, 0, 0, 6, 1, 4, 0, 0, 0, 1]).await.unwrap();
    let mut h = [0u8; 11];
    good.read_exact(&mut h).await.unwrap();
    assert_eq!(&h[..2], &[0, 9]);
    assert_eq!(&h[7..9], &[4, 2]);
    assert_eq!(PANICS.load(Ordering::SeqCst), 0, "a task panicked");
}
