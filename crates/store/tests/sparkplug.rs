//! The Sparkplug edge node's bdSeq and store-and-forward queue survive reopening the file.

use drivebus_store::{SpoolDropped, Store};

#[test]
fn bd_seq_counts_up_across_reopening_and_wraps_after_255() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("drivebus.db");
    {
        let s = Store::open(&path).unwrap();
        assert_eq!(s.next_bd_seq("drivebus/hall-1").unwrap(), 0);
        assert_eq!(s.next_bd_seq("drivebus/hall-1").unwrap(), 1);
        // Another edge node has its own count.
        assert_eq!(s.next_bd_seq("drivebus/hall-2").unwrap(), 0);
    }
    let s = Store::open(&path).unwrap();
    assert_eq!(s.next_bd_seq("drivebus/hall-1").unwrap(), 2);
    for expected in 3..=255 {
        assert_eq!(s.next_bd_seq("drivebus/hall-1").unwrap(), expected);
    }
    assert_eq!(s.next_bd_seq("drivebus/hall-1").unwrap(), 0);
}

fn item(device: &str, time_ms: i64, byte: u8) -> (String, i64, Vec<u8>) {
    (device.to_string(), time_ms, vec![byte; 3])
}

#[test]
fn the_queue_keeps_order_and_drops_the_oldest_beyond_its_limits() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("drivebus.db");
    let node = "drivebus/hall-1";
    {
        let s = Store::open(&path).unwrap();
        let items: Vec<_> = (0..5).map(|i| item("pump-1", 1000 + i, i as u8)).collect();
        assert_eq!(
            s.spool_push(node, &items, 4, 0).unwrap(),
            SpoolDropped { over_count: 1, too_old: 0, queued: 4 }
        );
        assert_eq!(
            s.spool_push("other/node", &[item("x", 1, 9)], 4, 0).unwrap(),
            SpoolDropped { queued: 1, ..SpoolDropped::default() }
        );
        assert_eq!(s.spool_len(node).unwrap(), 4);
    }
    let s = Store::open(&path).unwrap();
    let q = s.spool_peek(node, 10).unwrap();
    assert_eq!(q.iter().map(|m| m.payload[0]).collect::<Vec<_>>(), [1, 2, 3, 4]);
    assert!(q.iter().all(|m| m.device == "pump-1"));
    assert!(q.windows(2).all(|w| w[0].id < w[1].id));
    assert_eq!(s.spool_remove(node, q[1].id).unwrap(), 2);
    assert_eq!(s.spool_len(node).unwrap(), 2);
    assert_eq!(s.spool_peek(node, 10).unwrap().iter().map(|m| m.payload[0]).collect::<Vec<_>>(), [3, 4]);
    // Too old: read before 1004 ms.
    let pushed = s.spool_push(node, &[item("pump-2", 2000, 7)], 100, 1004).unwrap();
    assert_eq!((pushed.too_old, pushed.queued), (1, 2));
    let q = s.spool_peek(node, 10).unwrap();
    assert_eq!(
        q.iter().map(|m| (m.device.as_str(), m.time_ms)).collect::<Vec<_>>(),
        [("pump-1", 1004), ("pump-2", 2000)]
    );
    // The other node's queue is untouched.
    assert_eq!(s.spool_len("other/node").unwrap(), 1);
}

#[test]
fn a_store_made_before_the_sparkplug_tables_gets_them_when_opened() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("drivebus.db");
    Store::open(&path).unwrap();
    {
        let c = rusqlite::Connection::open(&path).unwrap();
        c.execute_batch("DROP TABLE sparkplug_spool; DROP TABLE sparkplug_node;").unwrap();
    }
    let s = Store::open(&path).unwrap();
    assert_eq!(s.next_bd_seq("g/n").unwrap(), 0);
    assert_eq!(s.spool_len("g/n").unwrap(), 0);
}
