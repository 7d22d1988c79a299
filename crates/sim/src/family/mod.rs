//! One virtual drive per family, each behaving as its manual says.
//!
//! | module | family | protocols | manual |
//! |---|---|---|---|
//! | [`generic`] | generic Chinese VFD | Modbus RTU or ASCII (2000H/2100H map) | `seeds/004_e8ea1998fe1a671e.txt` |
//! | [`toshiba`] | Toshiba VF-AS1 | TIP ASCII + binary, or Modbus-RTU (f829) | `seeds/002_43d8a4399c8be05f.txt` |
//! | [`danfoss`] | Danfoss FC | FC protocol | `seeds/003_26a4c04ca1af5f26.txt` |
//! | [`b800`] | B800 | B800 hex-ASCII | `seeds/000_04b515f0e0c1734e.txt` |

pub mod b800;
pub mod danfoss;
pub mod generic;
pub mod toshiba;

use drivebus_drive::Family;
use drivebus_proto::Instant;

use crate::config::{ConfigError, DriveSpec};
use crate::drive::VirtualDrive;

/// Builds the virtual drive `spec` describes, at simulated time `now`.
pub fn build(spec: &DriveSpec, now: Instant) -> Result<Box<dyn VirtualDrive>, ConfigError> {
    let err = |e: String| ConfigError(format!("{}@{}: {e}", spec.family, spec.address));
    Ok(match spec.family {
        Family::B800 => Box::new(b800::B800Drive::new(spec.address, now).map_err(err)?),
        Family::Generic => {
            let protocol = match spec.protocol.as_deref() {
                Some("modbus-rtu") => generic::GenericProtocol::Rtu,
                _ => generic::GenericProtocol::Ascii,
            };
            Box::new(generic::GenericDrive::new(spec.address, protocol, now).map_err(err)?)
        }
        Family::Toshiba => {
            let protocol = match spec.protocol.as_deref() {
                Some("modbus-rtu") => toshiba::ToshibaProtocol::ModbusRtu,
                _ => toshiba::ToshibaProtocol::Tip,
            };
            Box::new(toshiba::ToshibaDrive::new(spec.address, protocol, now).map_err(err)?)
        }
        Family::Danfoss => Box::new(danfoss::DanfossDrive::new(spec.address, now).map_err(err)?),
    })
}

/// The codec names a master may use to talk to the drive `spec` describes.
pub fn wire_protocols(spec: &DriveSpec) -> &'static [&'static str] {
    match (spec.family, spec.protocol.as_deref()) {
        (Family::Generic, Some("modbus-rtu")) => &["modbus-rtu"],
        (Family::Generic, _) => &["modbus-ascii"],
        (Family::Toshiba, Some("modbus-rtu")) => &["modbus-rtu"],
        (Family::Toshiba, _) => &["toshiba-ascii", "toshiba-binary"],
        (Family::Danfoss, _) => &["danfoss-fc"],
        (Family::B800, _) => &["b800"],
    }
}
