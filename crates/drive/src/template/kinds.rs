//! The drive kinds templates add: a process-wide list, each kind a [`Family::Template`] whose
//! name, catalog and map live here for the rest of the process (a kind is never taken back: a
//! configuration reload may add kinds, and a drive made with one keeps it).
//!
//! The templates shipped in `templates/` at the repository root are compiled in and known to
//! every command without `--template` ([`shipped`]).

use std::sync::{Arc, OnceLock, RwLock};

use drivebus_proto::protocol::WireProtocol;

use super::Template;
use crate::{Catalog, Family};

/// A template kind's number in the process's list.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct KindId(pub(crate) u16);

/// A registered kind: its template and what the family methods hand out.
#[derive(Debug)]
pub(crate) struct Kind {
    pub(crate) template: Template,
    pub(crate) name: &'static str,
    pub(crate) model: &'static str,
    pub(crate) source: &'static str,
    pub(crate) protocols: &'static [WireProtocol],
    pub(crate) catalog: Arc<Catalog>,
    /// What `drivebus trips` says the history comes from.
    pub(crate) history_source: &'static str,
}

fn list() -> &'static RwLock<Vec<&'static Kind>> {
    static KINDS: OnceLock<RwLock<Vec<&'static Kind>>> = OnceLock::new();
    KINDS.get_or_init(|| RwLock::new(Vec::new()))
}

/// The templates shipped with drivebus (`templates/` at the repository root): file name and text.
pub const SHIPPED: &[(&str, &str)] = &[
    ("templates/generic-2000h.toml", include_str!("../../../../templates/generic-2000h.toml")),
    ("templates/abb-acs550.toml", include_str!("../../../../templates/abb-acs550.toml")),
    ("templates/siemens-v20.toml", include_str!("../../../../templates/siemens-v20.toml")),
    ("templates/danfoss-fc51.toml", include_str!("../../../../templates/danfoss-fc51.toml")),
    (
        "templates/invertek-optidrive-e3.toml",
        include_str!("../../../../templates/invertek-optidrive-e3.toml"),
    ),
];

/// The shipped templates, registered on first use; an error names a shipped file that does not
/// check (the crate's tests check every one, so it means a broken build).
pub fn shipped() -> Result<Vec<Family>, String> {
    static SHIPPED_KINDS: OnceLock<Result<Vec<Family>, String>> = OnceLock::new();
    SHIPPED_KINDS
        .get_or_init(|| {
            SHIPPED
                .iter()
                .map(|(file, text)| {
                    let t = Template::from_toml_str(file, text).map_err(|e| e.to_string())?;
                    register_one(t)
                })
                .collect()
        })
        .clone()
}

/// Makes `template` a drive kind; its [`Family`]. The same template registered again (a file
/// given twice, a configuration reloaded) is the same kind; another template with a kind's name
/// is refused.
pub fn register(template: Template) -> Result<Family, String> {
    shipped()?;
    register_one(template)
}

fn register_one(template: Template) -> Result<Family, String> {
    let mut kinds = list().write().unwrap_or_else(|p| p.into_inner());
    if let Some(i) = kinds.iter().position(|k| k.name == template.kind) {
        let same = kinds[i].template == Template { file: kinds[i].template.file.clone(), ..template.clone() };
        return if same {
            Ok(Family::Template(KindId(i as u16)))
        } else {
            Err(format!(
                "{}: kind {:?} is already given by {}: give each template its own kind",
                template.file, template.kind, kinds[i].template.file
            ))
        };
    }
    let id = u16::try_from(kinds.len()).map_err(|_| "too many template kinds".to_string())?;
    let family = Family::Template(KindId(id));
    let catalog = Catalog::from_params(family, &template.file, &template.source, template.params.clone())
        .map_err(|e| e.to_string())?;
    let kind: &'static Kind = Box::leak(Box::new(Kind {
        name: Box::leak(template.kind.clone().into_boxed_str()),
        model: Box::leak(format!("{} {}", template.maker, template.model).into_boxed_str()),
        source: Box::leak(template.source.clone().into_boxed_str()),
        protocols: Box::leak(template.protocols.clone().into_boxed_slice()),
        catalog: Arc::new(catalog),
        history_source: Box::leak(
            if template.fault_history.is_empty() {
                "the fault in force only: the template gives no fault_history".to_string()
            } else {
                format!(
                    "the template's status.fault (fault in force) and fault_history {} (newest first)",
                    template.fault_history.join(", ")
                )
            }
            .into_boxed_str(),
        ),
        template,
    }));
    kinds.push(kind);
    Ok(family)
}

/// The kind numbered `id`.
pub(crate) fn kind(id: KindId) -> &'static Kind {
    let kinds = list().read().unwrap_or_else(|p| p.into_inner());
    // A KindId is only ever made by `register`, for an entry that stays.
    kinds[usize::from(id.0)]
}

/// What the trip history of kind `id` comes from (`drivebus trips`).
pub(crate) fn history_source(id: KindId) -> &'static str {
    kind(id).history_source
}

/// The kind named `name` (any letter case), the shipped templates included.
pub(crate) fn by_name(name: &str) -> Option<Family> {
    let _ = shipped();
    let kinds = list().read().unwrap_or_else(|p| p.into_inner());
    kinds.iter().position(|k| k.name.eq_ignore_ascii_case(name)).map(|i| Family::Template(KindId(i as u16)))
}

/// Every kind templates have added so far, the shipped ones included.
pub fn registered() -> Vec<Family> {
    let _ = shipped();
    let kinds = list().read().unwrap_or_else(|p| p.into_inner());
    (0..kinds.len()).map(|i| Family::Template(KindId(i as u16))).collect()
}

impl Family {
    /// The template of a template kind (`None` for a built-in family).
    pub fn template(self) -> Option<&'static Template> {
        match self {
            Family::Template(id) => Some(&kind(id).template),
            _ => None,
        }
    }
}
