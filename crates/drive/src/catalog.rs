//! Parameter catalogs: the TOML files under `catalogs/`, their loader, and lookups.

use std::collections::HashMap;
use std::fmt;
use std::sync::{Arc, OnceLock};

use toml::{Table, Value};

use crate::family::Family;
use crate::param::{Choice, ParamDef, Size, Storage};

/// The catalog files compiled into the crate, by family ("" for a template kind, whose
/// parameters its template file gives).
fn embedded_text(family: Family) -> &'static str {
    match family {
        Family::Template(_) => "",
        Family::Generic => include_str!("../catalogs/generic.toml"),
        Family::Toshiba => include_str!("../catalogs/toshiba.toml"),
        Family::Danfoss => include_str!("../catalogs/danfoss.toml"),
        Family::B800 => include_str!("../catalogs/b800.toml"),
    }
}

/// One family's parameters, in catalog order, with lookup by name and by wire number.
#[derive(Debug, Clone)]
pub struct Catalog {
    family: Family,
    file: String,
    source: String,
    params: Vec<ParamDef>,
    /// Lower-case names and aliases to indices into `params`.
    by_name: HashMap<String, usize>,
    by_number: HashMap<u32, usize>,
    /// Where each parameter's values start in a flat list of every parameter's values in
    /// catalog order, and (last) the list's length: a [`ParamStore`](crate::store::ParamStore)
    /// holds one such list.
    starts: Vec<usize>,
}

/// A parameter named as a person or a frame names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamKey<'a> {
    /// A name in any spelling [`Catalog::get`] accepts ("4-14", "f803", "P0.02", "dEC").
    Name(&'a str),
    /// A wire number (register, communication number, PNU, index).
    Number(u32),
}

impl<'a> From<&'a str> for ParamKey<'a> {
    fn from(name: &'a str) -> Self {
        ParamKey::Name(name)
    }
}

impl<'a> From<&'a String> for ParamKey<'a> {
    fn from(name: &'a String) -> Self {
        ParamKey::Name(name)
    }
}

impl From<u32> for ParamKey<'_> {
    fn from(number: u32) -> Self {
        ParamKey::Number(number)
    }
}

impl fmt::Display for ParamKey<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ParamKey::Name(name) => f.write_str(name),
            ParamKey::Number(number) => write!(f, "number {number} (0x{number:04X})"),
        }
    }
}

impl Catalog {
    /// The catalog compiled into the crate for `family`, parsed on first use and shared after.
    ///
    /// The embedded files are checked by this crate's tests, so an error here means the crate
    /// was built from a broken catalog file; it is returned rather than panicking.
    pub fn load(family: Family) -> Result<Arc<Catalog>, CatalogError> {
        static CATALOGS: [OnceLock<Result<Arc<Catalog>, CatalogError>>; 4] =
            [OnceLock::new(), OnceLock::new(), OnceLock::new(), OnceLock::new()];
        let slot = match family {
            Family::Template(id) => return Ok(crate::template::kinds::kind(id).catalog.clone()),
            Family::Generic => &CATALOGS[0],
            Family::Toshiba => &CATALOGS[1],
            Family::Danfoss => &CATALOGS[2],
            Family::B800 => &CATALOGS[3],
        };
        slot.get_or_init(|| {
            let file = format!("catalogs/{}.toml", family.as_str());
            let catalog = Catalog::from_toml_str(&file, embedded_text(family))?;
            if catalog.family != family {
                return Err(CatalogError::new(&file, None, Some("family"), "names another family"));
            }
            Ok(Arc::new(catalog))
        })
        .clone()
    }

    /// The text of the catalog file compiled in for `family` (for docs and tools).
    pub fn embedded_toml(family: Family) -> &'static str {
        embedded_text(family)
    }

    /// Parses and checks a catalog file; `file` names it in errors.
    ///
    /// Every problem is reported with the file, the parameter and the field: a missing or unknown
    /// field, a wrong type, a number that does not match the name, min above max, a default or
    /// choice outside the range, a value too wide for the size, a duplicate name or number.
    pub fn from_toml_str(file: &str, text: &str) -> Result<Catalog, CatalogError> {
        let table: Table = text
            .parse()
            .map_err(|e: toml::de::Error| CatalogError::new(file, None, None, e.to_string().trim_end()))?;
        let top = Fields { file, param: None, table: &table };
        top.reject_unknown(&["family", "source", "param"])?;
        let family_text = top.string("family")?;
        let family: Family = family_text.parse().map_err(|e: crate::family::UnknownFamily| {
            CatalogError::new(file, None, Some("family"), &e.to_string())
        })?;
        let source = top.optional_string("source")?.unwrap_or_default();
        let entries = match table.get("param") {
            Some(Value::Array(entries)) => entries,
            Some(_) => {
                return Err(CatalogError::new(file, None, Some("param"), "must be an array of tables"))
            }
            None => return Err(CatalogError::new(file, None, Some("param"), "missing: no parameters")),
        };

        let mut catalog = Catalog {
            family,
            file: file.to_string(),
            source,
            params: Vec::with_capacity(entries.len()),
            by_name: HashMap::new(),
            by_number: HashMap::new(),
            starts: vec![0],
        };
        for (index, entry) in entries.iter().enumerate() {
            let position = format!("#{}", index + 1);
            let Value::Table(entry) = entry else {
                return Err(CatalogError::new(file, Some(&position), None, "must be a table"));
            };
            let def = parse_param(file, family, &position, entry)?;
            catalog.insert(def)?;
        }
        Ok(catalog)
    }

    /// The catalog of `params` (a template's), checked for names and numbers used twice.
    pub fn from_params(
        family: Family,
        file: &str,
        source: &str,
        params: Vec<ParamDef>,
    ) -> Result<Catalog, CatalogError> {
        let mut catalog = Catalog {
            family,
            file: file.to_string(),
            source: source.to_string(),
            params: Vec::with_capacity(params.len()),
            by_name: HashMap::new(),
            by_number: HashMap::new(),
            starts: vec![0],
        };
        for def in params {
            catalog.insert(def)?;
        }
        Ok(catalog)
    }

    fn insert(&mut self, def: ParamDef) -> Result<(), CatalogError> {
        let index = self.params.len();
        let names = std::iter::once(("name", &def.name)).chain(def.alias.iter().map(|a| ("alias", a)));
        for (field, name) in names {
            if let Some(&other) = self.by_name.get(&name.to_lowercase()) {
                let message = format!("{name:?} is already used by {}", self.params[other].name);
                return Err(CatalogError::new(&self.file, Some(&def.name), Some(field), &message));
            }
            self.by_name.insert(name.to_lowercase(), index);
        }
        if let Some(&other) = self.by_number.get(&def.number) {
            let message = format!(
                "{} is already used by {}",
                self.family.format_number(def.number),
                self.params[other].name
            );
            return Err(CatalogError::new(&self.file, Some(&def.name), Some("number"), &message));
        }
        self.by_number.insert(def.number, index);
        self.starts.push(self.value_count() + def.len());
        self.params.push(def);
        Ok(())
    }

    /// Where the values of the parameter at index `i` are in a flat list of every parameter's
    /// values in catalog order (one per array element).
    pub fn value_range(&self, i: usize) -> std::ops::Range<usize> {
        self.starts[i]..self.starts[i + 1]
    }

    /// The length of the flat list of every parameter's values ([`value_range`](Self::value_range)).
    pub fn value_count(&self) -> usize {
        self.starts.last().copied().unwrap_or(0)
    }

    /// The family this catalog describes.
    pub fn family(&self) -> Family {
        self.family
    }

    /// The file name the catalog was loaded from ("catalogs/danfoss.toml").
    pub fn file(&self) -> &str {
        &self.file
    }

    /// The manual the catalog cites (`seeds/<file>`), or "" if the file names none.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// The number of parameters.
    pub fn len(&self) -> usize {
        self.params.len()
    }

    /// `true` if the catalog has no parameters (a loaded file always has some).
    pub fn is_empty(&self) -> bool {
        self.params.is_empty()
    }

    /// The parameters in catalog order.
    pub fn params(&self) -> &[ParamDef] {
        &self.params
    }

    /// Iterates over the parameters in catalog order.
    pub fn iter(&self) -> std::slice::Iter<'_, ParamDef> {
        self.params.iter()
    }

    /// Finds a parameter by name, alias or any spelling of its number, ignoring letter case:
    /// "f803", "F803" and "0803" for Toshiba, "P0.02" and "p0.02" for generic, "4-14" and "414"
    /// for FC, "F-12" and "12" for B800 (see [`Family::parse_number`]).
    pub fn get(&self, name: &str) -> Option<&ParamDef> {
        self.index_of(ParamKey::Name(name)).map(|i| &self.params[i])
    }

    /// Finds a parameter by its wire number.
    pub fn by_number(&self, number: u32) -> Option<&ParamDef> {
        self.by_number.get(&number).map(|&i| &self.params[i])
    }

    /// Finds a parameter by name or number.
    pub fn lookup<'k>(&self, key: impl Into<ParamKey<'k>>) -> Option<&ParamDef> {
        self.index_of(key.into()).map(|i| &self.params[i])
    }

    /// The position in catalog order of the parameter a key names.
    pub fn index_of(&self, key: ParamKey<'_>) -> Option<usize> {
        match key {
            ParamKey::Number(number) => self.by_number.get(&number).copied(),
            ParamKey::Name(name) => {
                let trimmed = name.trim();
                if let Some(&i) = self.by_name.get(&trimmed.to_lowercase()) {
                    return Some(i);
                }
                let number = self.family.parse_number(trimmed)?;
                self.by_number.get(&number).copied()
            }
        }
    }
}

impl<'a> IntoIterator for &'a Catalog {
    type Item = &'a ParamDef;
    type IntoIter = std::slice::Iter<'a, ParamDef>;

    fn into_iter(self) -> Self::IntoIter {
        self.params.iter()
    }
}

/// A catalog file that cannot be used, with where the problem is.
///
/// Displays as one line, for example
/// "catalogs/danfoss.toml: parameter 4-14: field `default`: 7000 is outside min..max (0..5000)".
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CatalogError {
    /// The file, as given to [`Catalog::from_toml_str`].
    pub file: String,
    /// The parameter's name, or `#n` (1-based position) if it has no usable name; `None` for the file itself.
    pub param: Option<String>,
    /// The field, if the problem is in one.
    pub field: Option<String>,
    /// What is wrong.
    pub message: String,
}

impl CatalogError {
    fn new(file: &str, param: Option<&str>, field: Option<&str>, message: &str) -> Self {
        CatalogError {
            file: file.to_string(),
            param: param.map(str::to_string),
            field: field.map(str::to_string),
            message: message.to_string(),
        }
    }
}

impl fmt::Display for CatalogError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: ", self.file)?;
        if let Some(param) = &self.param {
            write!(f, "parameter {param}: ")?;
        }
        if let Some(field) = &self.field {
            write!(f, "field `{field}`: ")?;
        }
        f.write_str(&self.message)
    }
}

impl std::error::Error for CatalogError {}

const PARAM_FIELDS: &[&str] = &[
    "name",
    "alias",
    "title",
    "number",
    "unit",
    "scale",
    "min",
    "max",
    "default",
    "read_only",
    "storage",
    "size",
    "choices",
    "array",
    "while_running",
    "comm",
    "note",
    "group",
];

/// Typed access to one TOML table's fields, with errors that say where.
struct Fields<'a> {
    file: &'a str,
    param: Option<&'a str>,
    table: &'a Table,
}

impl Fields<'_> {
    fn error(&self, field: &str, message: &str) -> CatalogError {
        CatalogError::new(self.file, self.param, Some(field), message)
    }

    fn reject_unknown(&self, known: &[&str]) -> Result<(), CatalogError> {
        match self.table.keys().find(|k| !known.contains(&k.as_str())) {
            Some(key) => Err(self.error(key, "unknown field")),
            None => Ok(()),
        }
    }

    fn required<'v>(&'v self, field: &str) -> Result<&'v Value, CatalogError> {
        self.table.get(field).ok_or_else(|| self.error(field, "missing"))
    }

    fn string(&self, field: &str) -> Result<String, CatalogError> {
        match self.required(field)? {
            Value::String(s) => Ok(s.clone()),
            other => Err(self.error(field, &format!("must be a string, not {}", other.type_str()))),
        }
    }

    fn optional_string(&self, field: &str) -> Result<Option<String>, CatalogError> {
        if self.table.contains_key(field) {
            self.string(field).map(Some)
        } else {
            Ok(None)
        }
    }

    fn int(&self, field: &str) -> Result<i64, CatalogError> {
        match self.required(field)? {
            Value::Integer(i) => Ok(*i),
            other => Err(self.error(field, &format!("must be an integer, not {}", other.type_str()))),
        }
    }

    fn int_in(&self, field: &str, min: i64, max: i64) -> Result<i64, CatalogError> {
        let i = self.int(field)?;
        if (min..=max).contains(&i) {
            Ok(i)
        } else {
            Err(self.error(field, &format!("{i} is not in {min}..{max}")))
        }
    }

    fn bool(&self, field: &str) -> Result<bool, CatalogError> {
        match self.required(field)? {
            Value::Boolean(b) => Ok(*b),
            other => Err(self.error(field, &format!("must be true or false, not {}", other.type_str()))),
        }
    }
}

fn parse_param(file: &str, family: Family, position: &str, table: &Table) -> Result<ParamDef, CatalogError> {
    // Name the parameter in errors as soon as it has a usable name.
    let unnamed = Fields { file, param: Some(position), table };
    let name = unnamed.string("name")?;
    if name.is_empty() || name.chars().any(char::is_whitespace) {
        return Err(unnamed.error("name", &format!("{name:?} is empty or has blanks")));
    }
    let f = Fields { file, param: Some(&name), table };
    f.reject_unknown(PARAM_FIELDS)?;

    let alias = f.optional_string("alias")?;
    if let Some(alias) = &alias {
        if alias.is_empty() || alias.chars().any(char::is_whitespace) {
            return Err(f.error("alias", &format!("{alias:?} is empty or has blanks")));
        }
    }
    let title = f.string("title")?;
    if title.trim().is_empty() {
        return Err(f.error("title", "is empty"));
    }
    let number = f.int_in("number", 0, i64::from(u32::MAX))?;
    let number = u32::try_from(number).map_err(|_| f.error("number", "does not fit 32 bits"))?;
    match family.parse_number(&name) {
        Some(expected) if expected == number => {}
        Some(expected) => {
            return Err(f.error(
                "number",
                &format!(
                    "{} does not match the name, which means {}",
                    family.format_number(number),
                    family.format_number(expected)
                ),
            ))
        }
        None => {
            return Err(f.error("name", &format!("{name:?} is not a {family} parameter name")));
        }
    }
    let unit = f.string("unit")?;
    let scale = f.int_in("scale", -9, 9)?;
    let scale = i8::try_from(scale).map_err(|_| f.error("scale", "does not fit"))?;
    let size = match f.string("size")?.as_str() {
        "word" => Size::Word,
        "dword" => Size::Dword,
        other => return Err(f.error("size", &format!("{other:?} is neither \"word\" nor \"dword\""))),
    };
    let storage = match f.string("storage")?.as_str() {
        "ram" => Storage::Ram,
        "eeprom" => Storage::Eeprom,
        other => return Err(f.error("storage", &format!("{other:?} is neither \"ram\" nor \"eeprom\""))),
    };
    let (lowest, highest) = size.raw_limits();
    let min = f.int_in("min", lowest, highest)?;
    let max = f.int_in("max", lowest, highest)?;
    if min > max {
        return Err(f.error("max", &format!("{max} is below min {min}")));
    }
    let default = f.int("default")?;
    if !(min..=max).contains(&default) {
        return Err(f.error("default", &format!("{default} is outside min..max ({min}..{max})")));
    }
    let read_only = f.bool("read_only")?;
    let while_running = if table.contains_key("while_running") { f.bool("while_running")? } else { true };
    let comm = if table.contains_key("comm") { f.bool("comm")? } else { false };
    let array = if table.contains_key("array") {
        let n = f.int_in("array", 1, 255)?;
        Some(u16::try_from(n).map_err(|_| f.error("array", "does not fit"))?)
    } else {
        None
    };
    let choices = parse_choices(&f, min, max)?;
    let note = f.optional_string("note")?;
    let group = f.optional_string("group")?.unwrap_or_default();

    Ok(ParamDef {
        group,
        name,
        alias,
        title,
        number,
        unit,
        scale,
        min,
        max,
        default,
        read_only,
        storage,
        size,
        choices,
        array,
        while_running,
        comm,
        note,
    })
}

fn parse_choices(f: &Fields<'_>, min: i64, max: i64) -> Result<Vec<Choice>, CatalogError> {
    let Some(value) = f.table.get("choices") else {
        return Ok(Vec::new());
    };
    let Value::Table(table) = value else {
        return Err(f.error("choices", "must be a table of value = \"text\""));
    };
    let mut choices = Vec::with_capacity(table.len());
    for (key, text) in table {
        let value: i64 = key
            .parse()
            .map_err(|_| f.error("choices", &format!("key {key:?} is not an integer raw value")))?;
        if !(min..=max).contains(&value) {
            return Err(f.error("choices", &format!("{value} is outside min..max ({min}..{max})")));
        }
        let Value::String(text) = text else {
            return Err(f.error("choices", &format!("the text of {value} must be a string")));
        };
        if text.trim().is_empty() {
            return Err(f.error("choices", &format!("the text of {value} is empty")));
        }
        if choices.iter().any(|c: &Choice| c.value == value) {
            return Err(f.error("choices", &format!("{value} is listed twice")));
        }
        choices.push(Choice { value, text: text.clone() });
    }
    choices.sort_by_key(|c| c.value);
    Ok(choices)
}

#[cfg(test)]
mod tests {
    use super::*;

    const ONE: &str = r#"
family = "danfoss"
source = "seeds/003_26a4c04ca1af5f26.txt"

[[param]]
name = "4-14"
title = "Motor Speed High Limit [Hz]"
number = 414
unit = "Hz"
scale = 1
min = 0
max = 5000
default = 650
read_only = false
storage = "eeprom"
size = "word"
"#;

    fn error_for(edit: impl Fn(&str) -> String) -> CatalogError {
        match Catalog::from_toml_str("test.toml", &edit(ONE)) {
            Ok(_) => panic!("the edited catalog loaded"),
            Err(e) => e,
        }
    }

    #[test]
    fn minimal_catalog_loads() -> Result<(), CatalogError> {
        let c = Catalog::from_toml_str("test.toml", ONE)?;
        assert_eq!(c.family(), Family::Danfoss);
        assert_eq!(c.len(), 1);
        assert_eq!(c.get("414").map(|p| p.number), Some(414));
        Ok(())
    }

    #[test]
    fn errors_name_file_parameter_and_field() {
        let e = error_for(|s| s.replace("default = 650", "default = 7000"));
        assert_eq!(
            e.to_string(),
            "test.toml: parameter 4-14: field `default`: 7000 is outside min..max (0..5000)"
        );
        let e = error_for(|s| s.replace("unit = \"Hz\"\n", ""));
        assert_eq!(e.to_string(), "test.toml: parameter 4-14: field `unit`: missing");
        let e = error_for(|s| s.replace("scale = 1", "scale = \"1\""));
        assert_eq!(e.to_string(), "test.toml: parameter 4-14: field `scale`: must be an integer, not string");
        let e = error_for(|s| s.replace("number = 414", "number = 415"));
        assert_eq!(
            e.to_string(),
            "test.toml: parameter 4-14: field `number`: 415 does not match the name, which means 414"
        );
        let e = error_for(|s| s.replace("size = \"word\"", "size = \"word\"\nwhile_runing = false"));
        assert_eq!(e.to_string(), "test.toml: parameter 4-14: field `while_runing`: unknown field");
        let e = error_for(|s| s.replace("max = 5000", "max = 70000"));
        assert_eq!(e.to_string(), "test.toml: parameter 4-14: field `max`: 70000 is not in -32768..65535");
        let e = error_for(|s| s.replace("name = \"4-14\"", "name = 414"));
        assert_eq!(e.to_string(), "test.toml: parameter #1: field `name`: must be a string, not integer");
        let e = error_for(|s| s.replace("size = \"word\"", "size = \"word\"\nchoices = { 9000 = \"fast\" }"));
        assert_eq!(
            e.to_string(),
            "test.toml: parameter 4-14: field `choices`: 9000 is outside min..max (0..5000)"
        );
        let e = error_for(|s| s.replace("family = \"danfoss\"", "family = \"abb\""));
        assert!(e.to_string().starts_with("test.toml: field `family`: unknown drive family"), "{e}");
    }

    #[test]
    fn duplicates_are_refused() {
        let block = ONE.find("[[param]]").map_or("", |at| &ONE[at..]);
        let same_name = format!("{ONE}\n{block}");
        let e = Catalog::from_toml_str("dup.toml", &same_name).err();
        assert_eq!(
            e.map(|e| e.to_string()).as_deref(),
            Some("dup.toml: parameter 4-14: field `name`: \"4-14\" is already used by 4-14")
        );
        let alias_clash =
            format!("{ONE}\n{}", block.replace("name = \"4-14\"", "name = \"4-12\"\nalias = \"4-14\""));
        let e = Catalog::from_toml_str("dup.toml", &alias_clash).err();
        assert_eq!(
            e.map(|e| e.to_string()).as_deref(),
            Some("dup.toml: parameter 4-12: field `number`: 414 does not match the name, which means 412")
        );
        let alias_clash = alias_clash.replacen("number = 414", "number = 412", 2).replacen(
            "number = 412",
            "number = 414",
            1,
        );
        let e = Catalog::from_toml_str("dup.toml", &alias_clash).err();
        assert_eq!(
            e.map(|e| e.to_string()).as_deref(),
            Some("dup.toml: parameter 4-12: field `alias`: \"4-14\" is already used by 4-14")
        );
    }

    #[test]
    fn syntax_errors_name_the_file() {
        let e = match Catalog::from_toml_str("bad.toml", "family = \n") {
            Ok(_) => panic!("loaded"),
            Err(e) => e,
        };
        assert!(e.to_string().starts_with("bad.toml: TOML parse error at line 1"), "{e}");
        assert_eq!(e.param, None);
    }
}
