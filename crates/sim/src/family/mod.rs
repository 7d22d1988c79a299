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
