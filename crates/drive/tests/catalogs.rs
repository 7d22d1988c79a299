//! The embedded catalogs: they load, hold what the issue and the project decisions name, and
//! look up and convert values as documented.

use std::collections::HashSet;
use std::sync::Arc;

use drivebus_drive::{Catalog, Family, ParamDef, Size, Storage, ValueError};

fn catalog(family: Family) -> Arc<Catalog> {
    match Catalog::load(family) {
        Ok(c) => c,
        Err(e) => panic!("{e}"),
    }
}

fn param(family: Family, name: &str) -> ParamDef {
    match catalog(family).get(name) {
        Some(p) => p.clone(),
        None => panic!("{family} catalog has no {name}"),
    }
}

#[test]
fn every_catalog_loads_with_at_least_30_parameters() {
    for family in Family::ALL {
        let c = catalog(family);
        assert_eq!(c.family(), family);
        assert_eq!(c.file(), format!("catalogs/{family}.toml"));
        assert_eq!(c.source(), family.manual());
        assert!(c.len() >= 30, "{family} has only {} parameters", c.len());
        // Loading again gives the same shared catalog.
        assert!(Arc::ptr_eq(&c, &catalog(family)));
    }
}

/// Every parameter the issue names, with its wire number.
const NAMED: &[(Family, &str, u32)] = &[
    (Family::Generic, "P0.02", 0x0002),
    (Family::Generic, "P3.09", 0x0309),
    (Family::Generic, "P3.10", 0x0310),
    (Family::Generic, "P3.11", 0x0311),
    (Family::Generic, "P3.12", 0x0312),
    (Family::Toshiba, "0010", 0x0010),
    (Family::Toshiba, "0012", 0x0012),
    (Family::Toshiba, "f803", 0x0803),
    (Family::Toshiba, "f804", 0x0804),
    (Family::Toshiba, "f829", 0x0829),
    (Family::Danfoss, "0-01", 1),
    (Family::Danfoss, "3-02", 302),
    (Family::Danfoss, "3-03", 303),
    (Family::Danfoss, "3-19", 319),
    (Family::Danfoss, "3-41", 341),
    (Family::Danfoss, "3-42", 342),
    (Family::Danfoss, "4-12", 412),
    (Family::Danfoss, "4-14", 414),
    (Family::Danfoss, "8-30", 830),
    (Family::Danfoss, "8-31", 831),
    (Family::Danfoss, "8-32", 832),
    (Family::Danfoss, "8-33", 833),
    (Family::Danfoss, "8-34", 834),
    (Family::Danfoss, "8-35", 835),
    (Family::Danfoss, "8-36", 836),
    (Family::Danfoss, "15-30", 1530),
    (Family::Danfoss, "16-13", 1613),
    (Family::Danfoss, "16-14", 1614),
    (Family::B800, "F-10", 10),
    (Family::B800, "F-12", 12),
];

#[test]
fn every_parameter_the_issue_names_is_present_with_its_wire_number() {
    for &(family, name, number) in NAMED {
        let p = param(family, name);
        assert_eq!(p.name, name, "{family} {name}");
        assert_eq!(p.number, number, "{family} {name}");
        assert_eq!(catalog(family).by_number(number).map(|p| p.name.as_str()), Some(name));
    }
}

#[test]
fn the_issue_named_parameters_have_the_documented_units_and_shapes() {
    let fc = |n| param(Family::Danfoss, n);
    assert_eq!((fc("3-41").unit.as_str(), fc("3-41").scale, fc("3-41").size), ("s", 2, Size::Dword));
    assert_eq!((fc("4-12").unit.as_str(), fc("4-12").scale), ("Hz", 1));
    assert_eq!((fc("4-14").unit.as_str(), fc("4-14").scale), ("Hz", 1));
    assert_eq!((fc("16-14").unit.as_str(), fc("16-14").scale, fc("16-14").read_only), ("A", 2, true));
    assert!(fc("16-13").read_only);
    let alarm_log = fc("15-30");
    assert!(alarm_log.read_only);
    assert_eq!(alarm_log.array, Some(10));
    assert_eq!(alarm_log.len(), 10);

    let tosh = |n| param(Family::Toshiba, n);
    assert_eq!((tosh("0010").unit.as_str(), tosh("0010").scale), ("s", 1));
    assert_eq!((tosh("0012").unit.as_str(), tosh("0012").scale), ("Hz", 2));
    assert!(!tosh("0011").while_running, "maximum frequency cannot change while running");
    assert_eq!(tosh("f829").format(0), "Toshiba");
    assert_eq!(tosh("f829").format(1), "Modbus-RTU");

    let generic = |n| param(Family::Generic, n);
    assert_eq!(generic("P0.01").format(2), "communication");
    assert_eq!((generic("P0.02").unit.as_str(), generic("P0.02").scale), ("Hz", 2));

    let b800 = |n| param(Family::B800, n);
    assert_eq!(b800("F-10").format(0), "off");
    assert_eq!(b800("F-10").format(1), "on");
    assert_eq!(b800("F-12").format(0), "terminals");
    assert_eq!(b800("F-12").format(1), "keypad");
    assert_eq!(b800("F-12").format(2), "host run/stop");
}

#[test]
fn defaults_follow_the_project_decisions() {
    let default = |family, name: &str| {
        let p = param(family, name);
        p.format(p.default)
    };
    // Toshiba: 19200 bps 8E1, Toshiba protocol; block write FA00, FA01; block read FD01 FD00 FE03 FC90 FE05.
    assert_eq!(default(Family::Toshiba, "f800"), "19200 bps");
    assert_eq!(default(Family::Toshiba, "f801"), "even parity");
    assert_eq!(default(Family::Toshiba, "f829"), "Toshiba");
    assert!(default(Family::Toshiba, "f870").ends_with("(FA00)"));
    assert!(default(Family::Toshiba, "f871").ends_with("(FA01)"));
    for (name, item) in
        [("f875", "FD01"), ("f876", "FD00"), ("f877", "FE03"), ("f878", "FC90"), ("f879", "FE05")]
    {
        assert!(default(Family::Toshiba, name).ends_with(&format!("({item})")), "{name}");
    }
    // Danfoss: 9600 bps, even parity, FC protocol.
    assert_eq!(default(Family::Danfoss, "8-30"), "FC");
    assert_eq!(default(Family::Danfoss, "8-32"), "9600 baud");
    assert_eq!(default(Family::Danfoss, "8-33"), "even parity, 1 stop bit");
    // Generic: 9600 bps, ASCII 7N2.
    assert_eq!(default(Family::Generic, "P3.09"), "9600 bps");
    assert_eq!(default(Family::Generic, "P3.10"), "ASCII 1-7-2, no parity");
    // B800: keypad mode, rpm available, keypad step 0.5 Hz.
    assert_eq!(default(Family::B800, "F-12"), "keypad");
    assert_eq!(default(Family::B800, "F-10"), "on");
    assert_eq!(default(Family::B800, "F-19"), "0.5 Hz");
}

#[test]
fn defaults_and_choices_lie_within_range_and_size() {
    for family in Family::ALL {
        for p in catalog(family).iter() {
            assert!(p.min <= p.default && p.default <= p.max, "{family} {}", p.name);
            assert!(p.check(p.default).is_ok(), "{family} {}", p.name);
            let (lowest, highest) = p.size.raw_limits();
            assert!(lowest <= p.min && p.max <= highest, "{family} {} does not fit a {:?}", p.name, p.size);
            for c in &p.choices {
                assert!(p.contains(c.value), "{family} {} choice {}", p.name, c.value);
            }
            assert!(p.choices.windows(2).all(|w| w[0].value < w[1].value), "{family} {}", p.name);
            assert!(!p.is_empty());
            if p.read_only {
                assert!(p.while_running, "{family} {}: while_running means nothing when read-only", p.name);
            }
        }
    }
}

#[test]
fn names_aliases_and_numbers_are_unique_per_family() {
    for family in Family::ALL {
        let c = catalog(family);
        let mut names = HashSet::new();
        let mut numbers = HashSet::new();
        for p in c.iter() {
            assert!(names.insert(p.name.to_lowercase()), "{family}: name {} twice", p.name);
            if let Some(alias) = &p.alias {
                assert!(names.insert(alias.to_lowercase()), "{family}: alias {alias} twice");
            }
            assert!(numbers.insert(p.number), "{family}: number {} twice", p.number);
        }
    }
}

#[test]
fn every_name_spells_its_own_wire_number() {
    for family in Family::ALL {
        for p in catalog(family).iter() {
            assert_eq!(family.parse_number(&p.name), Some(p.number), "{family} {}", p.name);
        }
    }
}

#[test]
fn lookups_accept_the_alternative_spellings() {
    let cases: &[(Family, &[&str], &str)] = &[
        (Family::Toshiba, &["f803", "F803", "0803", "0x0803", " f803 "], "f803"),
        (Family::Toshiba, &["0010", "dEC", "DEC", "dec"], "0010"),
        (Family::Toshiba, &["0011", "FH", "fh"], "0011"),
        (Family::Toshiba, &["FA01", "fa01"], "FA01"),
        (Family::Generic, &["P0.02", "p0.02", "0x0002"], "P0.02"),
        (Family::Generic, &["P3.10", "p3.10", "0310H"], "P3.10"),
        (Family::Generic, &["2103H", "2103h", "0x2103"], "2103H"),
        (Family::Danfoss, &["4-14", "04-14", "414", "0x19E"], "4-14"),
        (Family::Danfoss, &["0-01", "00-01", "1"], "0-01"),
        (Family::Danfoss, &["16-14", "1614"], "16-14"),
        (Family::B800, &["F-12", "f-12", "F12", "12"], "F-12"),
    ];
    for &(family, spellings, name) in cases {
        let c = catalog(family);
        for spelling in spellings {
            assert_eq!(c.get(spelling).map(|p| p.name.as_str()), Some(name), "{family} {spelling:?}");
            assert_eq!(c.lookup(*spelling).map(|p| p.name.as_str()), Some(name), "{family} {spelling:?}");
        }
    }
    assert_eq!(catalog(Family::Toshiba).lookup(0x0803u32).map(|p| p.name.as_str()), Some("f803"));
    for (family, missing) in [
        (Family::Toshiba, "f999"),
        (Family::Toshiba, "803"),
        (Family::Generic, "P9.99"),
        (Family::Generic, "0002"),
        (Family::Danfoss, "99-99"),
        (Family::B800, "F-99"),
        (Family::B800, ""),
    ] {
        assert!(catalog(family).get(missing).is_none(), "{family} {missing:?}");
    }
}

#[test]
fn iteration_follows_catalog_order() {
    let firsts: Vec<_> = Family::ALL
        .iter()
        .map(|&f| catalog(f).iter().next().map(|p| p.name.clone()).unwrap_or_default())
        .collect();
    assert_eq!(firsts, ["P0.00", "0000", "0-01", "F-01"]);
    let b800: Vec<_> = catalog(Family::B800).iter().map(|p| p.number).collect();
    assert!(b800.windows(2).all(|w| w[0] < w[1]), "B800 is listed F-01, F-02, ...");
    let fc = catalog(Family::Danfoss);
    let via_into_iter: Vec<_> = fc.as_ref().into_iter().map(|p| p.number).collect();
    let via_params: Vec<_> = fc.params().iter().map(|p| p.number).collect();
    assert_eq!(via_into_iter, via_params);
}

#[test]
fn range_errors_read_as_one_line() {
    let high = param(Family::Danfoss, "4-14");
    assert_eq!(
        high.to_raw(600.0).map_err(|e| e.to_string()),
        Err("4-14 is 0.0..500.0 Hz, 600 is out of range".into())
    );
    assert_eq!(
        high.check(6000).map_err(|e| e.to_string()),
        Err("4-14 is 0.0..500.0 Hz, 600.0 is out of range".into())
    );
    let e = high.to_raw(-0.1).err();
    assert_eq!(e.as_ref().map(|e| (e.min, e.max)), Some((0, 5000)));

    let keypad = param(Family::Generic, "P0.02");
    assert_eq!(
        keypad.to_raw(400.01).map_err(|e| e.to_string()),
        Err("P0.02 is 0.00..400.00 Hz, 400.01 is out of range".into())
    );
    let timeout = param(Family::Toshiba, "f803");
    assert_eq!(
        timeout.to_raw(101.0).map_err(|e| e.to_string()),
        Err("f803 is 0..100 s, 101 is out of range".into())
    );
    let baud = param(Family::Danfoss, "8-32");
    assert_eq!(baud.check(9).map_err(|e| e.to_string()), Err("8-32 is 0..7, 9 is out of range".into()));
    assert_eq!(
        keypad.to_raw(f64::NAN).map_err(|e| e.to_string()),
        Err("P0.02 is 0.00..400.00 Hz, NaN is out of range".into())
    );
    assert!(keypad.to_raw(f64::INFINITY).is_err());
    assert!(keypad.to_raw(1e300).is_err());
}

#[test]
fn values_convert_between_units_and_raw() {
    let keypad = param(Family::Generic, "P0.02");
    assert_eq!(keypad.to_raw(50.0), Ok(5000));
    assert_eq!(keypad.to_raw(0.285), Ok(29), "rounded as written in decimal");
    assert_eq!(keypad.to_raw(12.344), Ok(1234));
    assert_eq!(keypad.from_raw(5000), 50.0);
    assert_eq!(keypad.format(5000), "50.00 Hz");
    assert_eq!(keypad.format(5), "0.05 Hz");

    let decel = param(Family::Toshiba, "0010");
    assert_eq!(decel.to_raw(10.0), Ok(100), "manual E6581315: W 0010 0064 is 10.0 s");
    assert_eq!(decel.format(100), "10.0 s");

    let min_ref = param(Family::Danfoss, "3-02");
    assert_eq!(min_ref.to_raw(-12.5), Ok(-12500));
    assert_eq!(min_ref.format(-12500), "-12.500 Hz");
    assert_eq!(param(Family::Danfoss, "16-14").format(524), "5.24 A", "protocols.md 2.5: 524 is 5.24 A");
    assert_eq!(param(Family::Danfoss, "1-25").format(1420), "1420 rpm");

    let timeout = param(Family::Toshiba, "f803");
    assert_eq!(timeout.format(0), "off");
    assert_eq!(timeout.format(10), "10 s");
    assert_eq!(param(Family::Danfoss, "15-30").format(7), "7");
}

#[test]
fn typed_values_parse_as_numbers_units_or_choices() {
    let baud = param(Family::Danfoss, "8-32");
    assert_eq!(baud.parse_value("9600 baud"), Ok(2));
    assert_eq!(baud.parse_value("9600 BAUD"), Ok(2));
    assert_eq!(baud.parse_value("2"), Ok(2));
    assert_eq!(
        baud.parse_value("fast").map_err(|e| e.to_string()),
        Err("8-32 takes a number or one of 2400 baud, 4800 baud, 9600 baud, 19200 baud, 38400 baud, \
             57600 baud, 76800 baud, 115200 baud, not \"fast\""
            .into())
    );
    let keypad = param(Family::Generic, "P0.02");
    assert_eq!(keypad.parse_value("50"), Ok(5000));
    assert_eq!(keypad.parse_value("50.00 Hz"), Ok(5000));
    assert_eq!(keypad.parse_value(" 12.5hz "), Ok(1250));
    assert_eq!(
        keypad.parse_value("500 Hz").map_err(|e| e.to_string()),
        Err("P0.02 is 0.00..400.00 Hz, 500 is out of range".into())
    );
    assert!(matches!(keypad.parse_value("50 rpm"), Err(ValueError::NotAValue { .. })));
    assert_eq!(
        keypad.parse_value("fifty").map_err(|e| e.to_string()),
        Err("P0.02 takes a number, not \"fifty\"".into())
    );
    assert_eq!(param(Family::Toshiba, "f803").parse_value("off"), Ok(0));
}

#[test]
fn storage_says_which_writes_can_reach_the_eeprom() {
    let tosh = catalog(Family::Toshiba);
    for p in tosh.iter().filter(|p| p.name.starts_with("FA")) {
        assert_eq!(p.storage, Storage::Ram, "{} is RAM only (protocols.md 1.9)", p.name);
    }
    assert_eq!(param(Family::Toshiba, "0010").storage, Storage::Eeprom);
    assert_eq!(param(Family::Generic, "2001H").storage, Storage::Ram);
    assert_eq!(param(Family::Danfoss, "3-41").storage, Storage::Eeprom);
}

#[test]
fn embedded_text_is_the_catalog_file() {
    for family in Family::ALL {
        let text = Catalog::embedded_toml(family);
        assert!(text.contains(&format!("family = \"{family}\"")));
        let reparsed = Catalog::from_toml_str("again.toml", text).map(|c| c.len());
        assert_eq!(reparsed, Ok(catalog(family).len()));
    }
}
