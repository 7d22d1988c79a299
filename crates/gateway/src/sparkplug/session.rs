//! The edge node's session states without I/O: connected or not, waiting for the primary host,
//! publishing, sending kept data, leaving because the primary host went offline. The runtime
//! ([`super::run`]) feeds it what happens and does the [`Step`] it returns.
//!
//! ```text
//! Disconnected         --connected-->       Connected (Birth at once without a primary host)
//! Connected            --STATE online-->    Birth, then born(kept data?): Publishing or Draining
//! Draining             --queue empty-->     Publishing
//! Publishing, Draining --rebirth-->         Birth
//! Publishing, Draining --STATE offline-->   Leaving (Leave: NDEATH, DISCONNECT)
//! Publishing, Draining --not master-->      Leaving (Leave: NDEATH, DISCONNECT)
//! Connected            --master-->          Birth (with the host online, if there is one)
//! any                  --lost-->            Disconnected (the next session: the next bdSeq)
//! ```
//!
//! With `[standby]` the node births only while the gateway masters at least one bus
//! ([`Session::master`]): a standby keeps its MQTT session (its will the NDEATH of its bdSeq)
//! without births and keeps no data (the master publishes it). Losing the last bus ends the
//! Sparkplug session as a primary host going offline does: the explicit NDEATH carries the
//! bdSeq of the session it ends, and the next session (the next bdSeq) births when the gateway
//! masters a bus again.
//!
//! With a primary host, the node births only after a STATE of that host saying online in this
//! MQTT session (message-flow-edge-node-birth-publish-phid-wait); a STATE older than the newest
//! seen is ignored (message-flow-edge-node-birth-publish-phid-wait-timestamp). When the host goes
//! offline while the node is in a Sparkplug session, the node publishes its NDEATH and disconnects
//! (message-flow-edge-node-birth-publish-phid-offline, operational-behavior-edge-node-termination-
//! host-offline); the next session takes the next bdSeq.

/// Where the edge node stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// No MQTT session: data is kept.
    Disconnected,
    /// An MQTT session without births yet: waiting for the primary host to be online (or the
    /// births are about to go out). Data is kept.
    Connected,
    /// Births sent: data goes out live.
    Publishing,
    /// Births sent and kept data waiting: it goes out first, and new data joins the queue.
    Draining,
    /// The primary host went offline: the NDEATH is sent and the session closing. Data is kept.
    Leaving,
}

/// What the runtime does after an event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// Nothing.
    Stay,
    /// Publish NBIRTH and every DBIRTH, then call [`Session::born`].
    Birth,
    /// Publish the NDEATH of the session's bdSeq, then disconnect from the broker; the next
    /// session takes the next bdSeq.
    Leave,
}

/// The edge node's state and the primary host's newest STATE timestamp.
#[derive(Clone, Debug)]
pub struct Session {
    phase: Phase,
    primary: bool,
    host_timestamp: Option<u64>,
    /// The primary host said online in this MQTT session (always true without one).
    host_online: bool,
    /// The gateway masters at least one bus.
    master: bool,
}

impl Session {
    /// A node not connected yet; `primary`: it waits for a primary host; `master`: the
    /// gateway masters a bus now ([`Session::master`]).
    pub fn new(primary: bool, master: bool) -> Session {
        Session { phase: Phase::Disconnected, primary, host_timestamp: None, host_online: !primary, master }
    }

    /// Births may go out in a connected session: the primary host (if any) said online in it,
    /// and the gateway masters a bus.
    fn ready(&self) -> bool {
        self.host_online && self.master
    }

    /// Where the node stands.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Births sent in this session: data, NDATA and commands' results may go out.
    pub fn publishing(&self) -> bool {
        matches!(self.phase, Phase::Publishing | Phase::Draining)
    }

    /// New data goes to the store-and-forward queue rather than out live.
    /// A standby keeps nothing: the master publishes the data.
    pub fn keeps_data(&self) -> bool {
        self.master && self.phase != Phase::Publishing
    }

    /// An MQTT session opened: births at once without a primary host; with one, only once its
    /// STATE in this session says online.
    pub fn connected(&mut self) -> Step {
        self.phase = Phase::Connected;
        self.host_online = !self.primary;
        if self.ready() {
            Step::Birth
        } else {
            Step::Stay
        }
    }

    /// The gateway took its first bus (`true`) or lost its last one (`false`): a connected
    /// node births (once the primary host is online), a node with births leaves.
    pub fn master(&mut self, master: bool) -> Step {
        if master == self.master {
            return Step::Stay;
        }
        self.master = master;
        match (master, self.phase) {
            (true, Phase::Connected) if self.ready() => Step::Birth,
            (false, Phase::Publishing | Phase::Draining) => {
                self.phase = Phase::Leaving;
                Step::Leave
            }
            _ => Step::Stay,
        }
    }

    /// The births went out; `kept`: data waits in the queue.
    pub fn born(&mut self, kept: bool) {
        if matches!(self.phase, Phase::Connected | Phase::Publishing | Phase::Draining) {
            self.phase = if kept { Phase::Draining } else { Phase::Publishing };
        }
    }

    /// The queue is empty: data goes out live.
    pub fn drained(&mut self) {
        if self.phase == Phase::Draining {
            self.phase = Phase::Publishing;
        }
    }

    /// The MQTT session ended (or a publish found it gone).
    pub fn lost(&mut self) {
        self.phase = Phase::Disconnected;
    }

    /// A rebirth asked (NCMD, or a reload that changed the node's metrics): only in a session
    /// with births.
    pub fn rebirth(&mut self) -> Step {
        if self.publishing() {
            Step::Birth
        } else {
            Step::Stay
        }
    }

    /// The primary host's STATE: `online` at `timestamp`. One older than the newest seen is
    /// ignored; online births a connected node; offline makes a node with births leave.
    pub fn host_state(&mut self, online: bool, timestamp: u64) -> Step {
        if !self.primary || self.host_timestamp.is_some_and(|t| timestamp < t) {
            return Step::Stay;
        }
        self.host_timestamp = Some(timestamp);
        if matches!(self.phase, Phase::Connected | Phase::Publishing | Phase::Draining) {
            self.host_online = online;
        }
        match (online, self.phase) {
            (true, Phase::Connected) if self.ready() => Step::Birth,
            (false, Phase::Publishing | Phase::Draining) => {
                self.phase = Phase::Leaving;
                Step::Leave
            }
            _ => Step::Stay,
        }
    }
}

/// Reads a host's STATE payload, JSON `{"online": true|false, "timestamp": <ms>}`:
/// `(online, timestamp)` (a missing timestamp counts as 0), or what is wrong with it.
pub fn parse_state(payload: &[u8]) -> Result<(bool, u64), String> {
    let v = serde_json::from_slice::<serde_json::Value>(payload).map_err(|_| {
        "the primary host's STATE is not JSON {\"online\": ..., \"timestamp\": ...}".to_string()
    })?;
    let online = v
        .get("online")
        .and_then(serde_json::Value::as_bool)
        .ok_or_else(|| "the primary host's STATE has no \"online\": true|false".to_string())?;
    Ok((online, v.get("timestamp").and_then(serde_json::Value::as_u64).unwrap_or(0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn publishing(primary: bool) -> Session {
        let mut s = Session::new(primary, true);
        let step = s.connected();
        if primary {
            assert_eq!(step, Step::Stay);
            assert_eq!(s.host_state(true, 10), Step::Birth);
        } else {
            assert_eq!(step, Step::Birth);
        }
        s.born(false);
        assert_eq!(s.phase(), Phase::Publishing);
        s
    }

    #[test]
    fn without_a_primary_host_a_session_births_at_once_and_states_are_ignored() {
        let mut s = Session::new(false, true);
        assert_eq!(s.phase(), Phase::Disconnected);
        assert!(s.keeps_data() && !s.publishing());
        assert_eq!(s.connected(), Step::Birth);
        s.born(true);
        assert_eq!(s.phase(), Phase::Draining);
        assert!(s.publishing() && s.keeps_data());
        s.drained();
        assert_eq!(s.phase(), Phase::Publishing);
        assert!(!s.keeps_data());
        assert_eq!(s.host_state(false, 1), Step::Stay);
        assert_eq!(s.phase(), Phase::Publishing);
    }

    #[test]
    fn with_a_primary_host_births_wait_for_its_online_state_in_the_session() {
        let mut s = Session::new(true, true);
        // A STATE before any session: remembered, nothing to do.
        assert_eq!(s.host_state(true, 5), Step::Stay);
        assert_eq!(s.connected(), Step::Stay, "waits for a STATE in this session");
        assert_eq!(s.phase(), Phase::Connected);
        assert_eq!(s.rebirth(), Step::Stay, "no rebirth before the births");
        assert_eq!(s.host_state(false, 6), Step::Stay, "offline: keep waiting, connected");
        assert_eq!(s.phase(), Phase::Connected);
        assert_eq!(s.host_state(true, 4), Step::Stay, "older than the newest STATE");
        assert_eq!(s.host_state(true, 6), Step::Birth, "as new as the newest counts");
        s.born(false);
        assert_eq!(s.host_state(true, 7), Step::Stay, "online again: already born");
        assert_eq!(s.phase(), Phase::Publishing);
    }

    #[test]
    fn the_primary_host_offline_makes_a_node_with_births_leave_and_birth_in_its_next_session() {
        for draining in [false, true] {
            let mut s = publishing(true);
            if draining {
                assert_eq!(s.rebirth(), Step::Birth);
                s.born(true);
                assert_eq!(s.phase(), Phase::Draining);
            }
            assert_eq!(s.host_state(false, 9), Step::Stay, "older than the online STATE: stays");
            assert_eq!(s.host_state(false, 10), Step::Leave, "as new as the online STATE");
            assert_eq!(s.phase(), Phase::Leaving);
            assert!(s.keeps_data() && !s.publishing());
            assert_eq!(s.rebirth(), Step::Stay);
            assert_eq!(s.host_state(true, 11), Step::Stay, "back already: births in the next session");
            s.born(false);
            assert_eq!(s.phase(), Phase::Leaving, "no births while leaving");
            s.lost();
            assert_eq!(s.phase(), Phase::Disconnected);
            assert_eq!(s.connected(), Step::Stay);
            assert_eq!(s.host_state(true, 11), Step::Birth, "the retained online STATE again");
            s.born(true);
            assert_eq!(s.phase(), Phase::Draining, "what was kept meanwhile goes out first");
        }
    }

    #[test]
    fn a_lost_session_keeps_data_and_the_next_one_births_again() {
        let mut s = publishing(false);
        assert_eq!(s.rebirth(), Step::Birth);
        s.lost();
        assert_eq!(s.phase(), Phase::Disconnected);
        assert!(s.keeps_data());
        assert_eq!(s.rebirth(), Step::Stay);
        s.born(false);
        assert_eq!(s.phase(), Phase::Disconnected, "births need a session");
        assert_eq!(s.connected(), Step::Birth);
    }

    #[test]
    fn a_standby_births_only_once_it_masters_a_bus_and_keeps_no_data_before() {
        for primary in [false, true] {
            let mut s = Session::new(primary, false);
            assert!(!s.keeps_data(), "a standby keeps nothing, even disconnected");
            assert_eq!(s.connected(), Step::Stay, "connected, no births while standby");
            if primary {
                assert_eq!(s.host_state(true, 3), Step::Stay, "the host online: still standby");
            }
            assert_eq!(s.phase(), Phase::Connected);
            assert!(!s.keeps_data() && !s.publishing());
            assert_eq!(s.rebirth(), Step::Stay, "no rebirth without births");
            assert_eq!(s.master(false), Step::Stay);
            assert_eq!(s.master(true), Step::Birth, "its first bus: NBIRTH and DBIRTHs");
            assert!(s.keeps_data(), "a master keeps data until the births are out");
            s.born(false);
            assert_eq!(s.phase(), Phase::Publishing);
            assert_eq!(s.master(true), Step::Stay, "another bus taken: nothing new");
        }
        // With a primary host not online yet, a takeover waits for the host as births do.
        let mut s = Session::new(true, false);
        s.connected();
        assert_eq!(s.master(true), Step::Stay, "no host online in this session");
        assert_eq!(s.host_state(true, 1), Step::Birth);
    }

    #[test]
    fn losing_the_last_bus_ends_the_session_with_its_ndeath_and_the_next_one_waits() {
        for draining in [false, true] {
            let mut s = publishing(false);
            if draining {
                assert_eq!(s.rebirth(), Step::Birth);
                s.born(true);
            }
            assert_eq!(s.master(false), Step::Leave, "the NDEATH of this session's bdSeq");
            assert_eq!(s.phase(), Phase::Leaving);
            assert!(!s.publishing() && !s.keeps_data());
            assert_eq!(s.master(false), Step::Stay);
            s.lost();
            assert_eq!(s.connected(), Step::Stay, "the next session: no births while standby");
            assert_eq!(s.master(true), Step::Birth, "taken back: births with the new bdSeq");
        }
        // A node that lost its bus while disconnected has nothing to end; it births on its
        // next takeover only.
        let mut s = publishing(false);
        s.lost();
        assert_eq!(s.master(false), Step::Stay);
        assert_eq!(s.connected(), Step::Stay);
        assert_eq!(s.master(true), Step::Birth);
    }

    #[test]
    fn a_state_payload_is_read_or_said_wrong() {
        assert_eq!(parse_state(br#"{"online": true, "timestamp": 12}"#), Ok((true, 12)));
        assert_eq!(parse_state(br#"{"online": false}"#), Ok((false, 0)));
        assert!(parse_state(b"ONLINE").unwrap_err().contains("not JSON"));
        assert!(parse_state(br#"{"timestamp": 1}"#).unwrap_err().contains("no \"online\""));
    }
}
