//! `drivebus panel`: the drive's panel over the line. Shows what its display shows and presses
//! its keys (`--key run`, `--key up`, ...); on a Toshiba drive `--show TEXT` puts four
//! characters on its LEDs (LED setting by communication, FA10 = 1 with FA11/FA12) and
//! `--release` gives the LEDs back to the drive's monitor. See docs/commissioning.md, "The panel".

use anyhow::Result;
use clap::Args;
use drivebus_drive::{panel, Family, Storage};
use drivebus_link::drive::Drive;
use serde_json::json;

use crate::commands::drive::{classify, connect, runtime, status_json};
use crate::commands::target::{fail, Target, EXIT_USAGE};

/// `panel` options.
#[derive(Args, Debug)]
pub struct PanelArgs {
    /// Press a key: run, stop, up, down, reset, reverse, jog; repeat it for several, pressed in
    /// the order given.
    #[arg(long = "key", value_name = "KEY")]
    keys: Vec<String>,
    /// Frequency step of one press of up or down, Hz (default: the display's last digit, 0.1 Hz
    /// Toshiba, 0.01 Hz others).
    #[arg(long, value_name = "HZ")]
    step: Option<f64>,
    /// Toshiba: show TEXT (up to 4 characters) on the drive's panel LEDs (FA10 = 1, FA11, FA12).
    #[arg(long, value_name = "TEXT", conflicts_with = "release")]
    show: Option<String>,
    /// Toshiba: give the panel LEDs back to the drive's own monitor (FA10 = 0).
    #[arg(long)]
    release: bool,
}

/// `panel`.
pub fn run(args: &PanelArgs, t: &Target) -> Result<u8> {
    for key in &args.keys {
        if !panel::KEYS.contains(&key.as_str()) {
            return Err(fail(EXIT_USAGE, format!("unknown key {key:?}: use {}", panel::KEYS.join(", "))));
        }
    }
    if let Some(step) = args.step {
        if !(step > 0.0 && step <= 100.0) {
            return Err(fail(EXIT_USAGE, format!("--step {step} is outside 0..100 Hz")));
        }
    }
    let led = match &args.show {
        Some(text) => Some(panel::led_words(text).map_err(|e| fail(EXIT_USAGE, format!("--show: {e}")))?),
        None => None,
    };
    runtime()?.block_on(async {
        let (drive, label) = connect(t).await?;
        let family = drive.profile().family();
        if (led.is_some() || args.release) && family != Family::Toshiba {
            return Err(fail(
                EXIT_USAGE,
                format!(
                    "--show and --release set the Toshiba panel's LEDs by communication (FA10); a {family} \
                     drive's display is not written over the line"
                ),
            ));
        }
        let step = args.step.unwrap_or_else(|| panel::step_hz(family));
        // The setpoint the presses of up and down move, read once: a drive may report the
        // new one only once it runs (Toshiba FE02 follows FA01 with FA00 bit 14).
        let mut setpoint = None;
        for key in &args.keys {
            press(&drive, key, step, &mut setpoint)
                .await
                .map_err(|e| classify(e, &format!("{label}: key {key}")))?;
        }
        if let Some((fa11, fa12)) = led {
            for (name, value) in [("FA11", fa11), ("FA12", fa12), ("FA10", 1)] {
                drive
                    .write_param(name, &value.to_string(), Storage::Ram)
                    .await
                    .map_err(|e| classify(e, &label))?;
            }
        }
        if args.release {
            drive.write_param("FA10", "0", Storage::Ram).await.map_err(|e| classify(e, &label))?;
        }
        let status = drive.status().await.map_err(|e| classify(e, &label))?;
        let from_led = family == Family::Toshiba
            && drive.read_param("FA10").await.map_err(|e| classify(e, &label))?.0 == 1;
        let display = if from_led {
            let fa11 = drive.read_param("FA11").await.map_err(|e| classify(e, &label))?.0;
            let fa12 = drive.read_param("FA12").await.map_err(|e| classify(e, &label))?.0;
            panel::led_text(fa11 as u16, fa12 as u16)
        } else {
            panel::display(family, &status)
        };
        if t.json {
            let mut v = json!({"display": display, "led_by_communication": from_led, "keys": args.keys});
            if let (Some(o), serde_json::Value::Object(s)) = (v.as_object_mut(), status_json(&status)) {
                o.extend(s);
            }
            println!("{v}");
        } else {
            let width = display.chars().count().max(5);
            println!("{label}");
            println!("  ┌{}┐", "─".repeat(width + 2));
            println!("  │ {display:>width$} │  {}", state_text(&status, from_led));
            println!("  └{}┘", "─".repeat(width + 2));
            if !args.keys.is_empty() {
                println!("  pressed    {}", args.keys.join(", "));
            }
        }
        Ok(0)
    })
}

/// One key press, through the drive's commands; `setpoint` is the one up and down move.
async fn press(
    drive: &Drive,
    key: &str,
    step: f64,
    setpoint: &mut Option<f64>,
) -> Result<(), drivebus_link::drive::Error> {
    match key {
        "run" => drive.run().await,
        "stop" => drive.stop().await,
        "reset" => drive.reset().await,
        "reverse" => drive.reverse().await,
        "jog" => drive.jog().await,
        _ => {
            let set = match *setpoint {
                Some(hz) => hz,
                None => drive.status().await?.setpoint_hz.unwrap_or(0.0),
            };
            let hz = drivebus_drive::profile::round_to(
                if key == "up" { set + step } else { (set - step).max(0.0) },
                2,
            );
            drive.set_speed(hz).await?;
            *setpoint = Some(hz);
            Ok(())
        }
    }
}

/// The line beside the display: the state, and whose text it shows.
fn state_text(s: &drivebus_drive::profile::DriveStatus, from_led: bool) -> String {
    let state = match (&s.fault, s.running) {
        (Some(f), _) => format!("tripped ({})", f.text),
        (None, true) => format!("running {}", s.direction.as_deref().unwrap_or("")).trim_end().to_string(),
        (None, false) => "stopped".to_string(),
    };
    if from_led {
        format!("{state}; the LEDs show the LED data (FA10 = 1)")
    } else {
        state
    }
}
