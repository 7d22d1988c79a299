//! The running gateway: a bus owner and a poll scheduler per bus, a state cache where every
//! value carries its age, commands that go ahead of polling and are answered only when the drive
//! confirmed, linkage rules, events to the store and to live subscribers.
//!
//! Every front end (HTTP, Modbus TCP, MQTT, the dashboard) goes through [`Gateway`]: reads come
//! from the cache ([`Gateway::drive_view`], the Modbus TCP register map) and never touch a bus;
//! writes go through [`Gateway::command`], which checks the lock, sends the command through the
//! bus owner and writes the audit trail before it answers.
//!
//! How the parts fit: each file below imports only from those above it (this one only
//! declares and re-exports them); the files marked `impl` add methods to [`Gateway`].
//!
//! ```text
//!  command    Command, CommandError, ParamReading: what is asked, what happened
//!  cache      DriveEntry (DriveState; the drive's profile on its bus owner), BusEntry
//!  views      DriveView, BusView (built from the cache), Change for live subscribers
//!  scan       ScanReport, Found, Scans: a bus scan's progress and findings (crate::scan runs it)
//!  gateway    Gateway: Topology (what runs), counters, accessors, drive_view/bus_view
//!  linkage    impl: follow: a leader's new output ──► its followers' setpoints
//!  events     impl: update ◄── a poll's result: DriveState, trip/offline events, trend samples
//!                   record/announce: an event ──► store, log, live subscribers (Change)
//!  audit      impl: command records (pending, then the result), refused writes, failed logins
//!  lanes      impl: in_lane(): one lane per drive, work carried out in the order handed over
//!  execute    impl: command(): lane ──► lock ──► audit ──► drive ──► audit ──► refresh; read_param()
//!  scheduler  impl: per bus, poll each drive when due ──► update; refresh after a command
//!  workbench  impl: read_params(), backup(), restore() (rows through command()), trip_history()
//!  start      impl: config ──► buses (owner + drives) ──► Topology ──► Gateway; reload swaps it
//! ```
//!
//! The core knows no front end: each front end says a [`CommandError`] in its own words, and
//! keeps its own counts in the one value it attaches to the gateway ([`Gateway::attached`]):
//! `metrics::FrontEnds` lists them all, and the metrics read them.

mod audit;
mod cache;
mod command;
mod events;
mod execute;
mod gateway;
mod lanes;
mod linkage;
pub mod scan;
mod scheduler;
mod start;
mod views;
mod workbench;

pub use audit::MAX_LOGIN_FAILURES;
pub use cache::{BusEntry, DriveEntry, DriveState, ValueDef};
pub use command::{Command, CommandError, ParamReading, MAX_MESSAGE_CHARS, MAX_SPEED_HZ};
pub use gateway::{Counters, Gateway, Topology, ROLE_WATCH};
pub use lanes::MAX_LANE_QUEUE;
pub use start::Reload;
pub use views::{
    drive_master, log_line, BusView, Change, DriveView, FaultView, ValueView, DRIVE_MASTER_WINDOW_S,
};
pub use workbench::{ParamRow, RestoreOptions, RestoreRow, RowError};

pub use drivebus_store::time::now_ms as unix_ms;
