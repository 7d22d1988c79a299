//! What one drive's parameter values cost on the heap: a simulated plant holds one
//! [`ParamStore`] per drive, 10 000 of them in `bench/scale.sh`'s big plant (issue 25).
//!
//! The heap is counted by a global allocator of this test binary alone, which forwards to the
//! system's and adds up the bytes live.
#![allow(unsafe_code)] // GlobalAlloc is an unsafe trait; this one only forwards and counts.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicIsize, Ordering};

use drivebus_drive::{Catalog, Family, ParamStore};

struct Counting;

static LIVE: AtomicIsize = AtomicIsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LIVE.fetch_add(layout.size() as isize, Ordering::SeqCst);
        System.alloc(layout)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size() as isize, Ordering::SeqCst);
        System.dealloc(ptr, layout)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// A store holds its values and its EEPROM counts in two lists and nothing per parameter: one
/// list per parameter cost 24 bytes more a parameter (and an allocation each).
#[test]
fn a_store_holds_one_value_per_element_and_nothing_per_parameter() {
    for family in [Family::Generic, Family::Toshiba, Family::Danfoss, Family::B800] {
        let catalog = Catalog::load(family).unwrap();
        let before = LIVE.load(Ordering::SeqCst);
        let store = ParamStore::new(catalog.clone());
        let bytes = LIVE.load(Ordering::SeqCst) - before;
        let values = catalog.iter().map(|p| p.len()).sum::<usize>();
        assert_eq!(catalog.value_count(), values, "{family}");
        assert_eq!(bytes as usize, 8 * values + 8 * catalog.len(), "{family}: {bytes} bytes");
        drop(store);
    }
}
