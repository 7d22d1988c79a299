//! The drive's panel over the line: what its display shows and what its keys do, the same for
//! the simulator (which shows it) and `drivebus panel` (which reads it over the line).
//!
//! - The Toshiba manual's "utilizing panel LEDs and keys by communication": with FA10 = 1 the
//!   panel's LEDs show the LED data a master wrote to FA11 and FA12 (four ASCII characters, the
//!   first of each pair in the high byte; codes 00H–1FH are blank), with FA10 = 0 the drive's
//!   own monitor.
//! - The generic manual's remote keypad on the communication port ("通过该通讯口也可以接远控
//!   键盘"): a master that shows what the keypad shows and presses its keys through the
//!   registers (2000H commands, 2001H frequency).
//!
//! The display, where the drive computes it: the trip in force (Toshiba: its panel name such
//! as `OC3`; generic `E-01` with the 2100H code; others `E` and the code), else the output
//! frequency while the motor turns and the setpoint while it stands, to the display's
//! resolution (Toshiba 0.1 Hz, others 0.01 Hz). Decisions: docs/commissioning.md, "The panel".

use crate::profile::DriveStatus;
use crate::Family;

/// The keys `drivebus panel --key` presses, as the panel names them.
pub const KEYS: &[&str] = &["run", "stop", "up", "down", "reset", "reverse", "jog"];

/// Characters the Toshiba panel shows (FA11, FA12: two each).
pub const LED_CHARS: usize = 4;

/// What the panel of a `family` drive in state `status` shows (see the module docs).
pub fn display(family: Family, status: &DriveStatus) -> String {
    if let Some(f) = &status.fault {
        return match family {
            // The profile's text is "NAME: meaning".
            Family::Toshiba => f.text.split(':').next().unwrap_or("").trim().to_string(),
            Family::Generic => format!("E-{:02}", f.code),
            _ => format!("E{:02}", f.code),
        };
    }
    let hz = if status.running { status.output_hz } else { status.setpoint_hz.or(status.output_hz) };
    let hz = hz.unwrap_or(0.0);
    match family {
        Family::Toshiba => format!("{hz:.1}"),
        _ => format!("{hz:.2}"),
    }
}

/// The frequency step of one press of ▲ or ▼: the display's last digit.
pub fn step_hz(family: Family) -> f64 {
    match family {
        Family::Toshiba => 0.1,
        _ => 0.01,
    }
}

/// The four characters FA11 and FA12 hold, as the LEDs show them (00H–1FH blank).
pub fn led_text(fa11: u16, fa12: u16) -> String {
    [fa11 >> 8, fa11 & 0xFF, fa12 >> 8, fa12 & 0xFF]
        .into_iter()
        .map(|c| if (0x20..=0x7E).contains(&c) { char::from(c as u8) } else { ' ' })
        .collect()
}

/// FA11 and FA12 for `text`: up to four printable ASCII characters, blank-padded.
pub fn led_words(text: &str) -> Result<(u16, u16), String> {
    if text.chars().count() > LED_CHARS || !text.chars().all(|c| c.is_ascii_graphic() || c == ' ') {
        return Err(format!("the panel shows up to {LED_CHARS} printable ASCII characters, not {text:?}"));
    }
    let mut b = [0x20u16; LED_CHARS];
    for (slot, c) in b.iter_mut().zip(text.bytes()) {
        *slot = u16::from(c);
    }
    Ok((b[0] << 8 | b[1], b[2] << 8 | b[3]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::Fault;

    fn status(running: bool, out: f64, set: f64) -> DriveStatus {
        DriveStatus {
            address: 1,
            running,
            direction: None,
            output_hz: Some(out),
            setpoint_hz: Some(set),
            current_a: None,
            fault: None,
            values: Vec::new(),
        }
    }

    #[test]
    fn what_the_display_shows() {
        assert_eq!(display(Family::Generic, &status(true, 39.5, 40.0)), "39.50");
        assert_eq!(display(Family::Generic, &status(false, 0.0, 40.0)), "40.00");
        assert_eq!(display(Family::Toshiba, &status(true, 60.0, 60.0)), "60.0");
        let mut tripped = status(false, 0.0, 60.0);
        tripped.fault =
            Some(Fault { code: 3, text: "OC3: over-current during constant speed operation".into() });
        assert_eq!(display(Family::Toshiba, &tripped), "OC3");
        assert_eq!(display(Family::Generic, &tripped), "E-03");
    }

    #[test]
    fn led_data_both_ways() {
        let (a, b) = led_words("HELO").unwrap();
        assert_eq!((a, b), (0x4845, 0x4C4F));
        assert_eq!(led_text(a, b), "HELO");
        assert_eq!(led_words("AB").map(|(a, b)| led_text(a, b)).unwrap(), "AB  ");
        assert_eq!(led_text(0x0041, 0x1F42), " A B", "00H-1FH are blank");
        assert!(led_words("TOO LONG").unwrap_err().contains("up to 4"));
        assert!(led_words("é").is_err());
    }
}
