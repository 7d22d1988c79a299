//! One module per subcommand.

pub mod config;
pub mod decode;
pub mod drive;
pub mod history;
pub mod monitor;
pub mod panel;
pub mod scan;
pub mod serve;
pub mod simulate;
pub mod sniff;
pub mod target;
pub mod template;
pub mod trips;
