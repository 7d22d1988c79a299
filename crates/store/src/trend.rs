//! Trends: each drive's output frequency, current and setpoint over time, at 1 s and 1 min
//! resolution.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// One reading of a drive, given to [`Store::sample`](crate::Store::sample). Values the poll did
/// not get are `None`; non-finite values are dropped as if `None`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// When it was read: unix time in milliseconds.
    pub time_ms: i64,
    /// The drive's id (name) in the gateway.
    pub drive: String,
    /// Output frequency, Hz.
    pub output_hz: Option<f64>,
    /// Output current, A.
    pub current_a: Option<f64>,
    /// Frequency setpoint, Hz.
    pub setpoint_hz: Option<f64>,
}

/// The resolution of a trend: one point per second (kept a day) or per minute (kept a year).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Resolution {
    /// 1 s buckets, `"1s"`.
    #[serde(rename = "1s")]
    Second,
    /// 1 min buckets, `"1m"`.
    #[serde(rename = "1m")]
    Minute,
}

impl Resolution {
    /// The bucket width in milliseconds.
    pub fn millis(self) -> i64 {
        match self {
            Resolution::Second => 1_000,
            Resolution::Minute => 60_000,
        }
    }

    /// How long buckets of this resolution are kept, in milliseconds: a day for 1 s, 365 days for
    /// 1 min.
    pub fn retention_ms(self) -> i64 {
        match self {
            Resolution::Second => 86_400_000,
            Resolution::Minute => 365 * 86_400_000,
        }
    }

    /// The resolution a query of `span_ms` gets when it names none: 1 s up to an hour, 1 min
    /// beyond (the HTTP trend and OPC UA HistoryRead alike).
    pub fn for_span(span_ms: i64) -> Resolution {
        if span_ms <= 3_600_000 {
            Resolution::Second
        } else {
            Resolution::Minute
        }
    }

    /// `"1s"` or `"1m"`.
    pub fn as_str(self) -> &'static str {
        match self {
            Resolution::Second => "1s",
            Resolution::Minute => "1m",
        }
    }
}

impl fmt::Display for Resolution {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Resolution {
    type Err = String;

    fn from_str(s: &str) -> Result<Resolution, String> {
        match s {
            "1s" => Ok(Resolution::Second),
            "1m" => Ok(Resolution::Minute),
            _ => Err(format!("unknown resolution {s:?}: give 1s or 1m")),
        }
    }
}

/// Which trend [`Store::trend`](crate::Store::trend) returns: one drive, buckets starting in
/// `since_ms..until_ms`, at one resolution.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TrendQuery {
    /// The drive's id.
    pub drive: String,
    /// Buckets starting at or after this time (unix ms).
    pub since_ms: i64,
    /// Buckets starting before this time (unix ms).
    pub until_ms: i64,
    /// Which table: 1 s or 1 min buckets.
    pub resolution: Resolution,
}

/// One bucket of a trend. Values are averages over the samples that fell in the bucket; a value
/// no sample in the bucket had is `None`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrendPoint {
    /// The bucket's start: unix ms, a multiple of the resolution.
    pub time_ms: i64,
    /// Average output frequency, Hz.
    pub output_hz: Option<f64>,
    /// Average output current, A.
    pub current_a: Option<f64>,
    /// Lowest output frequency in the bucket, Hz.
    pub output_hz_min: Option<f64>,
    /// Highest output frequency in the bucket, Hz.
    pub output_hz_max: Option<f64>,
    /// Average setpoint, Hz.
    pub setpoint_hz: Option<f64>,
    /// How many samples fell in the bucket.
    pub samples: u32,
}
