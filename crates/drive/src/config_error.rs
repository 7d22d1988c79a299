//! The error of every configuration reader: the gateway's file, the simulator's bus
//! descriptions and their command-line flags.

use std::fmt;

/// Why a configuration is not usable: one line naming the place (file, line and field, or the
/// flag) and what was wrong.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigError(pub String);

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ConfigError {}
