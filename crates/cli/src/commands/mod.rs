//! One module per subcommand.

pub mod decode;
pub mod drive;
pub mod monitor;
pub mod scan;
pub mod simulate;
