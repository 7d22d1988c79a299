//! Trip forensics: each family's trip history, as far as its protocol gives it.
//!
//! The history is read with the operations every profile has: a [`Operation::Status`] (the trip
//! in force) and a [`Operation::ReadParam`] of each name [`history_reads`] lists; then
//! [`history_of`] puts the values together, newest trip first.
//!
//! | family | the trip in force | the history |
//! |---|---|---|
//! | generic | 2100H (status) | P4.00 last fault (with P4.02 output frequency and P4.03 current at it), P4.01 previous fault |
//! | toshiba | FC90 (status) | FE10–FE13 past trips 1–4 (FE10 the newest, with FE00 output frequency at the trip) |
//! | danfoss | 15-30[0] (status) | 15-30 Alarm Log, elements 0–9 (0 the newest) |
//! | b800 | `t` status, high byte | none: F-13 keeps the last four trips, but the protocol has no parameter access |
//! | a template | `status.fault` (with `tripped`, only while it is set) | the `fault_history` parameters, newest first |
//!
//! A drive that logs the trip in force shows it as the newest entry of its history too.
//!
//! [`Operation::Status`]: super::Operation::Status
//! [`Operation::ReadParam`]: super::Operation::ReadParam

use super::{danfoss, generic, toshiba, DriveStatus, Fault};
use crate::{Catalog, Family};

/// The history as JSON, as `drivebus trips --json` prints it and the gateway's
/// `GET /api/drives/{id}/trips` answers it: `{"address", "family", "current": {"code", "text"} |
/// null, "history": [{"index", "code", "text", "output_hz", "current_a"}], "source"}`.
pub fn history_json(address: u8, family: Family, h: &TripHistory) -> serde_json::Value {
    serde_json::json!({
        "address": address,
        "family": family.to_string(),
        "current": h.current.as_ref().map(|f| serde_json::json!({"code": f.code, "text": f.text})),
        "history": h.entries.iter().map(|e| serde_json::json!({
            "index": e.index,
            "code": e.code,
            "text": e.text,
            "output_hz": e.output_hz,
            "current_a": e.current_a,
        })).collect::<Vec<_>>(),
        "source": h.source,
    })
}

/// One trip of the history.
#[derive(Clone, Debug, PartialEq)]
pub struct TripEntry {
    /// 1 for the newest trip, 2 for the one before, ...
    pub index: usize,
    /// The code as the drive logs it.
    pub code: u32,
    /// What it means, from the manual (or drivebus' numbering where the manual has none).
    pub text: String,
    /// Output frequency at the trip, Hz, where the drive logs it.
    pub output_hz: Option<f64>,
    /// Motor current at the trip, A, where the drive logs it.
    pub current_a: Option<f64>,
}

/// A drive's trip history.
#[derive(Clone, Debug, PartialEq)]
pub struct TripHistory {
    /// The trip in force, if any.
    pub current: Option<Fault>,
    /// The logged trips, newest first; empty where the protocol gives no log.
    pub entries: Vec<TripEntry>,
    /// Where the values come from, in the manual's numbers.
    pub source: &'static str,
}

/// What the protocol of `family` gives of the trip history, in the manual's numbers.
pub fn source(family: Family) -> &'static str {
    match family {
        Family::Generic => "2100H (fault in force), P4.00/P4.01 (last and previous fault), P4.02/P4.03 (frequency and current at the last fault)",
        Family::Toshiba => "FC90 (trip in force), FE10-FE13 (past trips 1-4), FE00 (output frequency at the last trip)",
        Family::Danfoss => "15-30 Alarm Log (10 entries, newest first)",
        Family::B800 => {
            "the t status (trip in force) only: the protocol has no parameter access, F-13 (last four trips) is on the keypad"
        }
        Family::Template(id) => crate::template::kinds::history_source(id),
    }
}

/// The parameters to read (by the manual's name, in this order) for the history of a drive of
/// `family`; [`history_of`] takes their raw values in the same order.
pub fn history_reads(family: Family) -> Vec<String> {
    match family {
        Family::Generic => ["P4.00", "P4.01", "P4.02", "P4.03"].map(String::from).to_vec(),
        Family::Toshiba => ["FE10", "FE11", "FE12", "FE13", "FE00"].map(String::from).to_vec(),
        Family::Danfoss => (0..10).map(|i| format!("15-30[{i}]")).collect(),
        Family::B800 => Vec::new(),
        Family::Template(_) => family.template().map_or_else(Vec::new, |t| t.fault_history.clone()),
    }
}

/// The history of a drive of `family` from its status and the raw values of
/// [`history_reads`] (in that order; missing values count as 0, "no trip").
pub fn history_of(family: Family, status: &DriveStatus, raws: &[i64]) -> TripHistory {
    let raw = |i: usize| raws.get(i).copied().unwrap_or(0);
    if let Some(t) = family.template() {
        // A template's `fault_history`: codes only, newest first, the template's texts.
        let entries = (0..t.fault_history.len())
            .map(raw)
            .filter(|&code| code != 0)
            .enumerate()
            .map(|(i, code)| {
                let code = u32::try_from(code).unwrap_or(0);
                TripEntry { index: i + 1, code, text: t.fault_text(code), output_hz: None, current_a: None }
            })
            .collect();
        return TripHistory { current: status.fault.clone(), entries, source: source(family) };
    }
    // The value in units of catalog parameter `name`, as the catalog scales it.
    let scaled = |name: &str, raw: i64| {
        Catalog::load(family)
            .ok()
            .and_then(|c| c.get(name).map(|d| d.from_raw(raw)))
            .map(|v| super::round_to(v, 2))
    };
    let entry = |index: usize, code: i64, text: String| TripEntry {
        index,
        code: u32::try_from(code).unwrap_or(0),
        text,
        output_hz: None,
        current_a: None,
    };
    // Per family: how many trip codes lead the reads (newest first), their text, and where
    // the newest trip's output frequency and current are (catalog name, place in the reads).
    type At = Option<(&'static str, usize)>;
    let (codes, text, hz, amps): (usize, fn(i64) -> String, At, At) = match family {
        Family::Generic => {
            (2, |code| generic::fault_text(code as u16), Some(("P4.02", 2)), Some(("P4.03", 3)))
        }
        Family::Toshiba => (4, |code| toshiba::trip_text(code as u16), Some(("FE00", 4)), None),
        Family::Danfoss => (
            10,
            |code| {
                danfoss::alarm_text(code as u32)
                    .map_or_else(|| format!("alarm {code} (not in drivebus' alarm list)"), str::to_string)
            },
            None,
            None,
        ),
        Family::B800 | Family::Template(_) => (0, |code| code.to_string(), None, None),
    };
    let at_trip = |at: At| at.and_then(|(name, i)| scaled(name, raw(i)));
    let mut entries = Vec::new();
    for k in (0..codes).filter(|&k| raw(k) != 0) {
        let code = raw(k);
        let mut e = entry(k + 1, code, text(code));
        if k == 0 {
            e.output_hz = at_trip(hz);
            e.current_a = at_trip(amps);
        }
        entries.push(e);
    }
    // Entries are numbered by their place in the drive's log; gaps (a cleared slot) close up.
    for (i, e) in entries.iter_mut().enumerate() {
        e.index = i + 1;
    }
    TripHistory { current: status.fault.clone(), entries, source: source(family) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_family_reads_what_it_names() {
        for family in Family::ALL {
            let catalog = Catalog::load(family).expect("catalog");
            for name in history_reads(family) {
                let base = name.split('[').next().unwrap_or(&name);
                assert!(catalog.get(base).is_some(), "{family}: {name} is not in the catalog");
            }
        }
    }

    #[test]
    fn toshiba_history_newest_first_with_the_frequency_at_the_trip() {
        let status =
            DriveStatus { fault: Some(Fault { code: 3, text: toshiba::trip_text(3) }), ..Default::default() };
        let h = history_of(Family::Toshiba, &status, &[0x03, 0x10, 0, 0, 4000]);
        assert_eq!(h.entries.len(), 2);
        assert_eq!((h.entries[0].index, h.entries[0].code), (1, 3));
        assert_eq!(h.entries[0].output_hz, Some(40.0));
        assert!(h.entries[1].text.starts_with("OH"), "{:?}", h.entries[1]);
        assert_eq!(h.entries[1].output_hz, None);
        assert_eq!(h.current.map(|f| f.code), Some(3));
    }

    #[test]
    fn generic_history_scales_the_last_fault() {
        let h = history_of(Family::Generic, &DriveStatus::default(), &[1, 2, 4000, 123]);
        assert_eq!(h.entries.len(), 2);
        assert_eq!(h.entries[0].output_hz, Some(40.0));
        assert_eq!(h.entries[0].current_a, Some(12.3));
        assert_eq!(h.entries[1].text, "over-voltage");
        assert!(h.current.is_none());
    }
}
