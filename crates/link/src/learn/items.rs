//! What a listener has learnt, item by item: each drive's values by the protocol's own
//! addressing, each with the time it was heard.

use std::collections::HashMap;

use drivebus_proto::b800::SlaveReply;
use drivebus_proto::fc::{ParameterNumber, ParameterResponse};
use drivebus_proto::Instant;

/// At most this many items are remembered; more (a master reading everything once, a scan)
/// start the memory afresh.
const MAX_ITEMS: usize = 65536;

/// One thing a drive told, named as its protocol names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(crate) enum Item {
    /// Modbus: a register of the holding (03) or input (04) table.
    Register {
        /// 3 or 4.
        table: u8,
        /// The register.
        register: u16,
    },
    /// TIP: a communication number's value.
    CommNo(u16),
    /// TIP: whether the drive's last reply said it is tripped (lower-case CMD).
    Tripped,
    /// FC: a parameter's value, by PNU and IND.
    Parameter {
        /// PNU.
        pnu: ParameterNumber,
        /// IND.
        ind: u16,
    },
    /// FC: the status word and main actual value every reply carries.
    Process,
    /// B800: the reply to a read command, by the command's letter.
    Command(u8),
}

/// What an item was.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Value {
    /// A register, a communication number's data, a flag (0 or 1).
    Word(u16),
    /// An FC parameter value: AK 1 (word) or 2 (double word), and PWE.
    Parameter {
        /// How the drive said it.
        ak: ParameterResponse,
        /// PWE.
        pwe: u32,
    },
    /// FC PCD1 and PCD2 of a reply.
    Process {
        /// The status word.
        stw: u16,
        /// The main actual value, as on the wire.
        mav: u16,
    },
    /// A B800 reply.
    Reply(SlaveReply),
}

/// Every item heard, by drive.
#[derive(Default)]
pub(crate) struct Items {
    map: HashMap<(u8, Item), (Value, Instant)>,
}

impl Items {
    /// Drive `drive`'s `item` was `value` at `now`.
    pub(crate) fn put(&mut self, drive: u8, item: Item, value: Value, now: Instant) {
        if self.map.len() >= MAX_ITEMS && !self.map.contains_key(&(drive, item)) {
            self.map.clear();
        }
        self.map.insert((drive, item), (value, now));
    }

    /// Forgets `item` of `drive`, or of every drive with `None` (a write to it was heard: its
    /// value is no longer known).
    pub(crate) fn forget(&mut self, drive: Option<u8>, item: Item) {
        match drive {
            Some(d) => {
                self.map.remove(&(d, item));
            }
            None => self.map.retain(|(_, i), _| *i != item),
        }
    }

    /// The last value of `item` heard, however long ago.
    pub(crate) fn latest(&self, drive: u8, item: Item) -> Option<Value> {
        self.map.get(&(drive, item)).map(|(v, _)| *v)
    }

    /// The items heard at or after `since`.
    pub(crate) fn since(&self, since: Instant) -> Fresh<'_> {
        Fresh { items: self, since }
    }
}

/// The items heard at or after a time: what may answer a poll begun then.
pub(crate) struct Fresh<'a> {
    items: &'a Items,
    since: Instant,
}

impl Fresh<'_> {
    /// `item` of `drive`, if heard since.
    pub(crate) fn get(&self, drive: u8, item: Item) -> Option<Value> {
        let (v, at) = self.items.map.get(&(drive, item))?;
        (*at >= self.since).then_some(*v)
    }

    /// A word item of `drive`, if heard since.
    pub(crate) fn word(&self, drive: u8, item: Item) -> Option<u16> {
        match self.get(drive, item)? {
            Value::Word(w) => Some(w),
            _ => None,
        }
    }

    /// A word item of `drive`: if heard since, or however long ago when `setup` (a set-up
    /// value, kept until a write to it is heard).
    pub(crate) fn word_or_setup(&self, drive: u8, item: Item, setup: bool) -> Option<u16> {
        if setup {
            match self.latest(drive, item)? {
                Value::Word(w) => Some(w),
                _ => None,
            }
        } else {
            self.word(drive, item)
        }
    }

    /// The last value of `item` heard, however long ago (what a drive is set up to do, to
    /// read the fresh values by).
    pub(crate) fn latest(&self, drive: u8, item: Item) -> Option<Value> {
        self.items.latest(drive, item)
    }
}
