//! What a simulated drive's panel shows for a trip: each family's own code.

use drivebus_proto::Instant;
use drivebus_sim::drive::VirtualDrive;
use drivebus_sim::family::b800::B800Drive;
use drivebus_sim::family::generic::{GenericDrive, GenericProtocol};
use drivebus_sim::family::toshiba::{ToshibaDrive, ToshibaProtocol};
use drivebus_sim::model::Trip;

fn tripped(mut drive: Box<dyn VirtualDrive>) -> String {
    drive.core_mut().model.trip_now(Trip::OverCurrent);
    drive.snapshot().display
}

#[test]
fn the_panel_shows_a_trip_in_the_family_s_own_code() {
    let toshiba = ToshibaDrive::new(1, ToshibaProtocol::Tip, Instant::ZERO).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(tripped(Box::new(toshiba)), "OC3");
    let generic = GenericDrive::new(1, GenericProtocol::Rtu, Instant::ZERO).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(tripped(Box::new(generic)), "E-01");
    let b800 = B800Drive::new(1, Instant::ZERO).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(tripped(Box::new(b800)), "E01");
}
