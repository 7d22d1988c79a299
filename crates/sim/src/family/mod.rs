//! One virtual drive per family, each behaving as its manual says.
//!
//! | module | family | protocols | manual |
//! |---|---|---|---|
//! | [`generic`] | generic Chinese VFD | Modbus RTU or ASCII (2000H/2100H map) | `seeds/004_e8ea1998fe1a671e.txt` |
//! | [`toshiba`] | Toshiba VF-AS1 | TIP ASCII + binary, or Modbus-RTU (f829) | `seeds/002_43d8a4399c8be05f.txt` |
//! | [`danfoss`] | Danfoss FC | FC protocol | `seeds/003_26a4c04ca1af5f26.txt` |
//! | [`b800`] | B800 | B800 hex-ASCII | `seeds/000_04b515f0e0c1734e.txt` |
//! | [`template`] | a template kind | Modbus RTU or ASCII, the template's map | the template's source |

pub mod b800;
pub mod danfoss;
pub mod generic;
pub mod template;
pub mod toshiba;

use drivebus_drive::Family;
use drivebus_proto::Instant;

use crate::drive::VirtualDrive;
use crate::spec::{ConfigError, DriveSpec};

/// Builds the virtual drive `spec` describes, at simulated time `now`.
pub fn build(spec: &DriveSpec, now: Instant) -> Result<Box<dyn VirtualDrive>, ConfigError> {
    let err = |e: String| ConfigError(format!("{}@{}: {e}", spec.family, spec.address));
    Ok(match spec.family {
        Family::B800 => Box::new(b800::B800Drive::new(spec.address, now).map_err(err)?),
        Family::Generic => {
            let wire = spec.protocol.unwrap_or(Family::Generic.default_protocol());
            let protocol =
                generic::GenericProtocol::from_wire(wire).ok_or_else(|| err(format!("speaks no {wire}")))?;
            Box::new(generic::GenericDrive::new(spec.address, protocol, now).map_err(err)?)
        }
        Family::Toshiba => {
            let protocol =
                spec.protocol.and_then(toshiba::ToshibaProtocol::of).unwrap_or(toshiba::ToshibaProtocol::Tip);
            Box::new(toshiba::ToshibaDrive::new(spec.address, protocol, now).map_err(err)?)
        }
        Family::Danfoss => Box::new(danfoss::DanfossDrive::new(spec.address, now).map_err(err)?),
        Family::Template(_) => {
            let wire = spec.protocol.unwrap_or(spec.family.default_protocol());
            Box::new(template::TemplateDrive::new(spec.family, spec.address, wire, now).map_err(err)?)
        }
    })
}
