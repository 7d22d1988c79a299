//! ParamStore: one drive's values, refused writes and EEPROM write counting.

use drivebus_drive::{Family, ParamStore, Storage, WriteError};

fn store(family: Family) -> ParamStore {
    match ParamStore::for_family(family) {
        Ok(s) => s,
        Err(e) => panic!("{e}"),
    }
}

#[test]
fn a_new_store_holds_the_defaults() {
    for family in Family::ALL {
        let s = store(family);
        let mut count = 0;
        for (def, values) in s.iter() {
            assert_eq!(values.len(), def.len(), "{family} {}", def.name);
            assert!(values.iter().all(|&v| v == def.default), "{family} {}", def.name);
            count += 1;
        }
        assert_eq!(count, s.catalog().len());
        assert_eq!(s.total_eeprom_writes(), 0);
    }
    let b800 = store(Family::B800);
    assert_eq!(b800.get("F-12"), Some(1));
    assert_eq!(b800.get(12), Some(1));
}

#[test]
fn writes_are_read_back_by_any_spelling() -> Result<(), WriteError> {
    let mut s = store(Family::Toshiba);
    s.set("f803", 5, Storage::Eeprom, false)?;
    assert_eq!(s.get("f803"), Some(5));
    assert_eq!(s.get("F803"), Some(5));
    assert_eq!(s.get("0803"), Some(5));
    assert_eq!(s.get(0x0803), Some(5));
    s.set(0x0010, 64, Storage::Ram, true)?;
    assert_eq!(s.get("dEC"), Some(64));
    assert_eq!(s.get("nonsense"), None);
    Ok(())
}

#[test]
fn eeprom_writes_are_counted_per_parameter() -> Result<(), WriteError> {
    let mut s = store(Family::Toshiba);
    // W (RAM and EEPROM) to a setting counts; P (RAM only) does not.
    s.set("0010", 100, Storage::Eeprom, false)?;
    s.set("0010", 101, Storage::Eeprom, false)?;
    s.set("0010", 102, Storage::Ram, false)?;
    assert_eq!(s.eeprom_writes("0010"), Some(2));
    assert_eq!(s.eeprom_writes("dEC"), Some(2));
    assert_eq!(s.eeprom_writes("0009"), Some(0));
    // FAxx are RAM only: W does not reach the EEPROM (protocols.md, Toshiba decisions).
    for _ in 0..10 {
        s.set("FA01", 6000, Storage::Eeprom, true)?;
    }
    assert_eq!(s.eeprom_writes("FA01"), Some(0));
    assert_eq!(s.get("FA01"), Some(6000));
    assert_eq!(s.total_eeprom_writes(), 2);
    assert_eq!(s.eeprom_writes("f999"), None);

    // A refused write is not counted.
    assert!(s.set("0010", 70000, Storage::Eeprom, false).is_err());
    assert_eq!(s.eeprom_writes("0010"), Some(2));
    Ok(())
}

#[test]
fn read_only_parameters_refuse_writes() {
    for (family, name) in [
        (Family::Danfoss, "16-14"),
        (Family::Danfoss, "16-13"),
        (Family::Danfoss, "15-30"),
        (Family::Toshiba, "FD00"),
        (Family::Generic, "2103H"),
        (Family::B800, "F-13"),
    ] {
        let mut s = store(family);
        let before = s.get(name);
        let e = s.set(name, 0, Storage::Eeprom, false);
        assert_eq!(e, Err(WriteError::ReadOnly { name: name.to_string() }), "{family} {name}");
        assert_eq!(e.map_err(|e| e.to_string()), Err(format!("{name} is read-only")));
        assert_eq!(s.get(name), before);
        assert_eq!(s.eeprom_writes(name), Some(0));
    }
}

#[test]
fn out_of_range_writes_carry_the_range() {
    let mut s = store(Family::Danfoss);
    match s.set("4-14", 6000, Storage::Eeprom, false) {
        Err(WriteError::OutOfRange(e)) => {
            assert_eq!((e.min, e.max), (0, 5000));
            assert_eq!(e.to_string(), "4-14 is 0.0..500.0 Hz, 600.0 is out of range");
        }
        other => panic!("expected OutOfRange, got {other:?}"),
    }
    assert_eq!(s.get("4-14"), Some(650));
}

#[test]
fn some_parameters_cannot_change_while_running() -> Result<(), WriteError> {
    let mut s = store(Family::Toshiba);
    let e = s.set("FH", 6000, Storage::Eeprom, true);
    assert_eq!(e, Err(WriteError::NotWhileRunning { name: "0011".into() }));
    assert_eq!(e.map_err(|e| e.to_string()), Err("0011 cannot be changed while the motor runs".into()));
    s.set("FH", 6000, Storage::Eeprom, false)?;
    assert_eq!(s.get("0011"), Some(6000));
    // The upper limit may change while running.
    s.set("0012", 5000, Storage::Eeprom, true)?;

    let mut fc = store(Family::Danfoss);
    assert!(matches!(fc.set("1-24", 900, Storage::Eeprom, true), Err(WriteError::NotWhileRunning { .. })));
    Ok(())
}

#[test]
fn unknown_parameters_are_refused() {
    let mut s = store(Family::Generic);
    let e = s.set("P9.99", 1, Storage::Eeprom, false);
    assert_eq!(e, Err(WriteError::UnknownParameter { family: Family::Generic, key: "P9.99".into() }));
    assert_eq!(e.map_err(|e| e.to_string()), Err("the generic catalog has no parameter P9.99".into()));
    let e = s.set(0x7777, 1, Storage::Eeprom, false).map_err(|e| e.to_string());
    assert_eq!(e, Err("the generic catalog has no parameter number 30583 (0x7777)".into()));
}

#[test]
fn array_elements_are_addressed_by_index() -> Result<(), WriteError> {
    let mut fc = store(Family::Danfoss);
    assert_eq!(fc.values("15-30").map(<[i64]>::len), Some(10));
    // The drive logs alarms itself; a master cannot write the log.
    fc.force("15-30", 0, 14)?;
    fc.force("15-30", 9, 7)?;
    assert_eq!(fc.get("15-30"), Some(14));
    assert_eq!(fc.get_element("15-30", 9), Some(7));
    assert_eq!(fc.get_element("15-30", 10), None);
    let e = fc.force("15-30", 10, 1);
    assert_eq!(e, Err(WriteError::NoSuchElement { name: "15-30".into(), index: 10, len: 10 }));
    assert_eq!(e.map_err(|e| e.to_string()), Err("15-30 has 10 element(s), there is no index 10".into()));
    assert!(matches!(fc.set_element("15-30", 1, 0, Storage::Ram, false), Err(WriteError::ReadOnly { .. })));

    fc.set_element("3-10", 7, -2500, Storage::Eeprom, false)?;
    assert_eq!(fc.get_element("3-10", 7), Some(-2500));
    assert_eq!(fc.eeprom_writes("3-10"), Some(1));
    Ok(())
}

#[test]
fn force_sets_monitors_without_counting() -> Result<(), WriteError> {
    let mut s = store(Family::Toshiba);
    s.force("FD00", 0, 6000)?;
    assert_eq!(s.get("fd00"), Some(6000));
    assert_eq!(s.total_eeprom_writes(), 0);
    Ok(())
}

#[test]
fn reset_to_defaults_restores_values_and_keeps_counters() -> Result<(), WriteError> {
    let mut s = store(Family::B800);
    s.set("F-12", 2, Storage::Eeprom, false)?;
    s.set("F-19", 10, Storage::Eeprom, false)?;
    s.reset_to_defaults();
    assert_eq!(s.get("F-12"), Some(1));
    assert_eq!(s.get("F-19"), Some(5));
    assert_eq!(s.eeprom_writes("F-12"), Some(1));
    Ok(())
}
