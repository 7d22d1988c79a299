//! The parameter values of one drive, with the checks a drive makes on a write.

use std::fmt;
use std::sync::Arc;

use crate::catalog::{Catalog, CatalogError, ParamKey};
use crate::family::Family;
use crate::param::{ParamDef, RangeError, Storage};

/// The parameter values of one drive: what a simulated drive holds, or what a backup holds.
///
/// Starts from the catalog's defaults. [`set`](ParamStore::set) checks a write the way a drive
/// does (read-only, not while running, range) and counts writes that reach the EEPROM, per
/// parameter, so a test can see a master wearing out a drive's EEPROM with cyclic writes.
#[derive(Debug, Clone)]
pub struct ParamStore {
    catalog: Arc<Catalog>,
    /// Every parameter's values in catalog order, one per array element, in one list (a list
    /// per parameter cost a simulated drive about 2 KB more); the catalog says where each
    /// parameter's are ([`Catalog::value_range`]).
    values: Vec<i64>,
    eeprom_writes: Vec<u64>,
}

impl ParamStore {
    /// A store holding every parameter's default.
    pub fn new(catalog: Arc<Catalog>) -> Self {
        let mut values = Vec::with_capacity(catalog.value_count());
        for p in catalog.iter() {
            values.extend(std::iter::repeat(p.default).take(p.len()));
        }
        let eeprom_writes = vec![0; catalog.len()];
        ParamStore { catalog, values, eeprom_writes }
    }

    /// A store with the defaults of a family's embedded catalog.
    pub fn for_family(family: Family) -> Result<Self, CatalogError> {
        Ok(ParamStore::new(Catalog::load(family)?))
    }

    /// The catalog the store follows.
    pub fn catalog(&self) -> &Arc<Catalog> {
        &self.catalog
    }

    /// The value of a parameter (its first element, for an array); `None` for an unknown key.
    pub fn get<'k>(&self, key: impl Into<ParamKey<'k>>) -> Option<i64> {
        self.get_element(key, 0)
    }

    /// One element of an array parameter; `None` for an unknown key or an index past the end.
    pub fn get_element<'k>(&self, key: impl Into<ParamKey<'k>>, index: usize) -> Option<i64> {
        self.values(key)?.get(index).copied()
    }

    /// All elements of a parameter (one for a plain parameter).
    pub fn values<'k>(&self, key: impl Into<ParamKey<'k>>) -> Option<&[i64]> {
        let i = self.catalog.index_of(key.into())?;
        Some(&self.values[self.catalog.value_range(i)])
    }

    /// Writes a parameter as a master would (element 0 of an array).
    ///
    /// `storage` is where the write is asked to go; a write to a RAM-only parameter never
    /// reaches the EEPROM. `running` is whether the motor runs now.
    pub fn set<'k>(
        &mut self,
        key: impl Into<ParamKey<'k>>,
        raw: i64,
        storage: Storage,
        running: bool,
    ) -> Result<(), WriteError> {
        self.set_element(key, 0, raw, storage, running)
    }

    /// Writes one element of a parameter, checking as a drive does, in this order: the parameter
    /// exists, the element exists, it is writable, it may change while running, the value is in range.
    pub fn set_element<'k>(
        &mut self,
        key: impl Into<ParamKey<'k>>,
        index: usize,
        raw: i64,
        storage: Storage,
        running: bool,
    ) -> Result<(), WriteError> {
        let i = self.position(key.into(), index)?;
        let def = &self.catalog.params()[i];
        if def.read_only {
            return Err(WriteError::ReadOnly { name: def.name.clone() });
        }
        if running && !def.while_running {
            return Err(WriteError::NotWhileRunning { name: def.name.clone() });
        }
        def.check(raw).map_err(WriteError::OutOfRange)?;
        self.values[self.catalog.value_range(i).start + index] = raw;
        if storage == Storage::Eeprom && def.storage == Storage::Eeprom {
            self.eeprom_writes[i] += 1;
        }
        Ok(())
    }

    /// Sets a value as the drive itself does (a monitor it measures, its trip log): no read-only,
    /// running or range check, and never an EEPROM write.
    pub fn force<'k>(
        &mut self,
        key: impl Into<ParamKey<'k>>,
        index: usize,
        raw: i64,
    ) -> Result<(), WriteError> {
        let i = self.position(key.into(), index)?;
        self.values[self.catalog.value_range(i).start + index] = raw;
        Ok(())
    }

    /// How many writes of a parameter reached the EEPROM; `None` for an unknown key.
    pub fn eeprom_writes<'k>(&self, key: impl Into<ParamKey<'k>>) -> Option<u64> {
        let i = self.catalog.index_of(key.into())?;
        Some(self.eeprom_writes[i])
    }

    /// How many writes reached the EEPROM, over all parameters.
    pub fn total_eeprom_writes(&self) -> u64 {
        self.eeprom_writes.iter().sum()
    }

    /// Puts every parameter back to its default (a factory reset); the EEPROM counters stay.
    pub fn reset_to_defaults(&mut self) {
        for (i, def) in self.catalog.iter().enumerate() {
            self.values[self.catalog.value_range(i)].fill(def.default);
        }
    }

    /// The parameters with their values, in catalog order.
    pub fn iter(&self) -> impl Iterator<Item = (&ParamDef, &[i64])> + '_ {
        self.catalog.iter().enumerate().map(|(i, def)| (def, &self.values[self.catalog.value_range(i)]))
    }

    fn position(&self, key: ParamKey<'_>, index: usize) -> Result<usize, WriteError> {
        let i = self.catalog.index_of(key).ok_or_else(|| WriteError::UnknownParameter {
            family: self.catalog.family(),
            key: key.to_string(),
        })?;
        let len = self.catalog.value_range(i).len();
        if index >= len {
            let name = self.catalog.params()[i].name.clone();
            return Err(WriteError::NoSuchElement { name, index, len });
        }
        Ok(i)
    }
}

/// Why a drive refuses a parameter write.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WriteError {
    /// The catalog has no such parameter (Toshiba error 0002, Modbus exception 02, FC error 0).
    UnknownParameter {
        /// The family whose catalog was searched.
        family: Family,
        /// The name or number as given.
        key: String,
    },
    /// The parameter cannot be written (FC error 1).
    ReadOnly {
        /// The parameter's name.
        name: String,
    },
    /// The value is outside the parameter's range (Toshiba 0001, Modbus exception 03, FC error 2).
    OutOfRange(RangeError),
    /// The parameter cannot change while the motor runs (Toshiba 0000, FC error 17).
    NotWhileRunning {
        /// The parameter's name.
        name: String,
    },
    /// The array index is past the end (FC error 3, subindex corrupted).
    NoSuchElement {
        /// The parameter's name.
        name: String,
        /// The index asked for.
        index: usize,
        /// The number of elements.
        len: usize,
    },
}

impl fmt::Display for WriteError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WriteError::UnknownParameter { family, key } => {
                write!(f, "the {family} catalog has no parameter {key}")
            }
            WriteError::ReadOnly { name } => write!(f, "{name} is read-only"),
            WriteError::OutOfRange(e) => e.fmt(f),
            WriteError::NotWhileRunning { name } => {
                write!(f, "{name} cannot be changed while the motor runs")
            }
            WriteError::NoSuchElement { name, index, len } => {
                write!(f, "{name} has {len} element(s), there is no index {index}")
            }
        }
    }
}

impl std::error::Error for WriteError {}

impl From<RangeError> for WriteError {
    fn from(e: RangeError) -> Self {
        WriteError::OutOfRange(e)
    }
}
