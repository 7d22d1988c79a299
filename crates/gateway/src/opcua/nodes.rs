//! The address space in the namespace `urn:drivebus`: string node ids built from names, so they
//! stay the same across restarts (`ns=<urn:drivebus>;s=Drives/pump-1/OutputFrequency`).
//!
//! ```text
//! Objects
//! ├─ Drives                       folder
//! │  └─ <drive id>                DriveType; events: trips, resets, online/offline
//! │     ├─ OutputFrequency ...    variables from the cache (see DRIVE_VARIABLES)
//! │     ├─ Run Stop Reverse Reset SetSpeed(hz)   methods
//! │     ├─ Parameters/<name>      every catalog parameter, read from the drive when read
//! │     └─ Values/<name>          a templated drive's named values ([values]), from the cache
//! └─ Buses                        folder
//!    └─ <bus name>                BusType; events: bus offline/online
//!       └─ Transactions ...       the bus owner's statistics (see BUS_VARIABLES)
//! ```

use opcua::server::address_space::{
    AccessLevel, AddressSpace, EventNotifier, MethodBuilder, ObjectBuilder, ObjectTypeBuilder,
    VariableBuilder,
};
use opcua::types::{
    DataTypeId, EUInformation, LocalizedText, NodeId, ObjectId, ObjectTypeId, QualifiedName, Range,
    ReferenceTypeId, UAString, VariableTypeId, Variant,
};

use crate::core::{BusEntry, DriveEntry};

/// The namespace of every node of the gateway.
pub const NAMESPACE: &str = "urn:drivebus";

/// An engineering unit of UNECE Recommendation 20, as OPC UA's EUInformation names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unit {
    /// The common code (`HTZ`).
    pub code: &'static str,
    /// The symbol shown (`Hz`).
    pub symbol: &'static str,
    /// The unit's name.
    pub name: &'static str,
}

/// Hertz.
pub const HERTZ: Unit = Unit { code: "HTZ", symbol: "Hz", name: "hertz" };
/// Ampere.
pub const AMPERE: Unit = Unit { code: "AMP", symbol: "A", name: "ampere" };
/// Millisecond.
pub const MILLISECOND: Unit = Unit { code: "C26", symbol: "ms", name: "millisecond" };

/// The units a template's value or a catalog parameter may give, by their symbols (UNECE
/// Recommendation 20 common codes).
const UNITS: [Unit; 14] = [
    HERTZ,
    AMPERE,
    MILLISECOND,
    Unit { code: "VLT", symbol: "V", name: "volt" },
    Unit { code: "WTT", symbol: "W", name: "watt" },
    Unit { code: "KWT", symbol: "kW", name: "kilowatt" },
    Unit { code: "KWH", symbol: "kWh", name: "kilowatt hour" },
    Unit { code: "CEL", symbol: "°C", name: "degree Celsius" },
    Unit { code: "SEC", symbol: "s", name: "second" },
    Unit { code: "MIN", symbol: "min", name: "minute" },
    Unit { code: "HUR", symbol: "h", name: "hour" },
    Unit { code: "RPM", symbol: "rpm", name: "revolutions per minute" },
    Unit { code: "P1", symbol: "%", name: "percent" },
    Unit { code: "BAR", symbol: "bar", name: "bar [unit of pressure]" },
];

impl Unit {
    /// The unit as OPC UA's EUInformation: UnitId is the common code's three characters, one
    /// byte each (OPC UA Part 8, 5.6.3).
    pub fn eu_information(&self) -> EUInformation {
        let id = self.code.bytes().fold(0i32, |acc, b| (acc << 8) | i32::from(b));
        EUInformation {
            namespace_uri: UAString::from("http://www.opcfoundation.org/UA/units/un/cefact"),
            unit_id: id,
            display_name: LocalizedText::new("", self.symbol),
            description: LocalizedText::new("", self.name),
        }
    }

    /// The unit of a catalog parameter's or a template value's unit text (`Hz`, `A`, `ms`,
    /// `V`, `kW`, `°C`, ...), if it is one the gateway knows.
    pub fn from_symbol(symbol: &str) -> Option<Unit> {
        UNITS.into_iter().find(|u| u.symbol == symbol)
    }
}

/// A unit text as EUInformation: the unit's common code where the gateway knows the symbol,
/// else UnitId -1 ("no code", OPC UA Part 8, 5.6.3) with the text as its display name.
pub fn eu_information_of(symbol: &str) -> EUInformation {
    match Unit::from_symbol(symbol) {
        Some(u) => u.eu_information(),
        None => EUInformation {
            namespace_uri: UAString::from("http://www.opcfoundation.org/UA/units/un/cefact"),
            unit_id: -1,
            display_name: LocalizedText::new("", symbol),
            description: LocalizedText::new("", symbol),
        },
    }
}

/// One variable of a drive or bus object.
#[derive(Clone, Copy, Debug)]
pub struct VariableDef {
    /// Its browse name.
    pub name: &'static str,
    /// Its data type.
    pub data_type: DataTypeId,
    /// Its unit, if it has one.
    pub unit: Option<Unit>,
    /// Its range (EURange), where known.
    pub range: Option<(f64, f64)>,
    /// Whether a client may write it (with a write token).
    pub writable: bool,
    /// Whether the store keeps it as a trend: then it is `Historizing` and answers HistoryRead.
    pub trend: bool,
}

const fn var(name: &'static str, data_type: DataTypeId, unit: Option<Unit>) -> VariableDef {
    VariableDef { name, data_type, unit, range: None, writable: false, trend: false }
}

/// The variables of a drive, from the cache.
pub const DRIVE_VARIABLES: &[VariableDef] = &[
    VariableDef { trend: true, ..var("OutputFrequency", DataTypeId::Double, Some(HERTZ)) },
    VariableDef { writable: true, trend: true, ..var("Setpoint", DataTypeId::Double, Some(HERTZ)) },
    VariableDef { trend: true, ..var("Current", DataTypeId::Double, Some(AMPERE)) },
    var("Running", DataTypeId::Boolean, None),
    var("Direction", DataTypeId::String, None),
    var("FaultCode", DataTypeId::UInt32, None),
    var("FaultText", DataTypeId::String, None),
    var("Online", DataTypeId::Boolean, None),
    var("AgeMs", DataTypeId::Double, Some(MILLISECOND)),
    VariableDef { range: Some((0.0, 1.0)), ..var("ErrorRate", DataTypeId::Double, None) },
    // `master` (polled by this gateway) or `standby` (heard from another gateway's polls).
    var("Source", DataTypeId::String, None),
];

/// The variables of a bus, from the bus owner's statistics.
pub const BUS_VARIABLES: &[VariableDef] = &[
    var("Transactions", DataTypeId::UInt64, None),
    var("Timeouts", DataTypeId::UInt64, None),
    var("ChecksumErrors", DataTypeId::UInt64, None),
    var("Retries", DataTypeId::UInt64, None),
    VariableDef { range: Some((0.0, 1.0)), ..var("Utilization", DataTypeId::Double, None) },
    var("Online", DataTypeId::Boolean, None),
    // `master` or `standby` (`[standby]`).
    var("Role", DataTypeId::String, None),
];

/// The methods of a drive; `SetSpeed` takes one Double argument, `hz`.
pub const DRIVE_METHODS: &[&str] = &["Run", "Stop", "Reverse", "Reset", "SetSpeed"];

/// Node ids of the gateway's namespace (index `ns` on this server).
#[derive(Clone, Copy, Debug)]
pub struct Ids {
    /// The namespace index of `urn:drivebus`.
    pub ns: u16,
}

impl Ids {
    fn id(&self, path: impl Into<String>) -> NodeId {
        NodeId::new(self.ns, path.into())
    }
    /// `Drives`.
    pub fn drives(&self) -> NodeId {
        self.id("Drives")
    }
    /// `Buses`.
    pub fn buses(&self) -> NodeId {
        self.id("Buses")
    }
    /// `DriveType`.
    pub fn drive_type(&self) -> NodeId {
        self.id("DriveType")
    }
    /// `BusType`.
    pub fn bus_type(&self) -> NodeId {
        self.id("BusType")
    }
    /// `Drives/<drive>`.
    pub fn drive(&self, drive: &str) -> NodeId {
        self.id(format!("Drives/{drive}"))
    }
    /// `Drives/<drive>/<member>` (a variable or a method).
    pub fn drive_member(&self, drive: &str, member: &str) -> NodeId {
        self.id(format!("Drives/{drive}/{member}"))
    }
    /// `Drives/<drive>/Parameters/<name>`.
    pub fn parameter(&self, drive: &str, name: &str) -> NodeId {
        self.id(format!("Drives/{drive}/Parameters/{name}"))
    }
    /// `Drives/<drive>/Values/<name>`: a named value of a templated drive.
    pub fn value(&self, drive: &str, name: &str) -> NodeId {
        self.id(format!("Drives/{drive}/Values/{name}"))
    }
    /// `Buses/<bus>`.
    pub fn bus(&self, bus: &str) -> NodeId {
        self.id(format!("Buses/{bus}"))
    }
    /// `Buses/<bus>/<member>`.
    pub fn bus_member(&self, bus: &str, member: &str) -> NodeId {
        self.id(format!("Buses/{bus}/{member}"))
    }
}

/// What a node of the namespace is, from its id.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Target {
    /// A drive's cache variable (`Drives/<drive>/<variable>`).
    DriveVariable {
        /// The drive's id.
        drive: String,
        /// The variable's name.
        variable: String,
    },
    /// A drive's method (`Drives/<drive>/<method>`).
    Method {
        /// The drive's id.
        drive: String,
        /// The method's name.
        method: String,
    },
    /// A catalog parameter (`Drives/<drive>/Parameters/<name>`).
    Parameter {
        /// The drive's id.
        drive: String,
        /// The manual's name.
        name: String,
    },
    /// Anything else of the namespace.
    Other,
}

impl Ids {
    /// What `id` names, if it is of this namespace.
    pub fn target(&self, id: &NodeId) -> Target {
        if id.namespace != self.ns {
            return Target::Other;
        }
        let opcua::types::Identifier::String(s) = &id.identifier else { return Target::Other };
        let s = s.as_ref();
        let Some(rest) = s.strip_prefix("Drives/") else { return Target::Other };
        let mut parts = rest.splitn(3, '/');
        let (Some(drive), Some(member)) = (parts.next(), parts.next()) else { return Target::Other };
        let drive = drive.to_string();
        match (member, parts.next()) {
            ("Parameters", Some(name)) => Target::Parameter { drive, name: name.to_string() },
            (m, None) if DRIVE_METHODS.contains(&m) => Target::Method { drive, method: m.to_string() },
            (v, None) if DRIVE_VARIABLES.iter().any(|d| d.name == v) => {
                Target::DriveVariable { drive, variable: v.to_string() }
            }
            _ => Target::Other,
        }
    }
}

impl Ids {
    /// A browse name in the gateway's namespace.
    pub fn name(&self, name: &str) -> QualifiedName {
        QualifiedName::new(self.ns, name)
    }
}

/// Adds the `EngineeringUnits` property of `id`.
fn add_unit(space: &mut AddressSpace, ids: &Ids, id: &NodeId, unit: EUInformation) {
    let eu = ids.id(format!("{}/EngineeringUnits", id_path(id)));
    VariableBuilder::new(&eu, QualifiedName::new(0, "EngineeringUnits"), "EngineeringUnits")
        .data_type(DataTypeId::EUInformation)
        .value(unit)
        .has_type_definition(VariableTypeId::PropertyType)
        .property_of(id.clone())
        .insert(space);
}

/// Adds a variable and its properties; `history` when the store keeps it as a trend
/// (`Historizing`, AccessLevel HistoryRead).
fn add_variable(
    space: &mut AddressSpace,
    ids: &Ids,
    id: &NodeId,
    parent: &NodeId,
    def: &VariableDef,
    history: bool,
) {
    let mut b = VariableBuilder::new(id, ids.name(def.name), def.name)
        .data_type(def.data_type)
        .value(Variant::Empty)
        .has_type_definition(if def.unit.is_some() || def.range.is_some() {
            VariableTypeId::AnalogItemType
        } else {
            VariableTypeId::BaseDataVariableType
        })
        .component_of(parent.clone());
    let mut access = AccessLevel::CURRENT_READ;
    if def.writable {
        access |= AccessLevel::CURRENT_WRITE;
    }
    if history && def.trend {
        access |= AccessLevel::HISTORY_READ;
        b = b.historizing(true);
    }
    b = b.access_level(access).user_access_level(access);
    b.insert(space);
    if let Some(unit) = def.unit {
        add_unit(space, ids, id, unit.eu_information());
    }
    if let Some((low, high)) = def.range {
        let r = ids.id(format!("{}/EURange", id_path(id)));
        VariableBuilder::new(&r, QualifiedName::new(0, "EURange"), "EURange")
            .data_type(DataTypeId::Range)
            .value(Range { low, high })
            .has_type_definition(VariableTypeId::PropertyType)
            .property_of(id.clone())
            .insert(space);
    }
}

fn id_path(id: &NodeId) -> String {
    match &id.identifier {
        opcua::types::Identifier::String(s) => s.as_ref().to_string(),
        other => other.to_string(),
    }
}

/// Builds what exists once: the types (`DriveType`, `BusType` and their members) and the
/// `Drives` and `Buses` folders. Drives and buses are made on demand ([`add_drive`], [`add_bus`]).
pub fn build_types(space: &mut AddressSpace, ids: &Ids) {
    ObjectTypeBuilder::new(&ids.drive_type(), ids.name("DriveType"), "DriveType")
        .subtype_of(ObjectTypeId::BaseObjectType)
        .generates_event(ObjectTypeId::BaseEventType)
        .description("A variable-frequency drive on an RS-485 bus, as the gateway sees it")
        .insert(space);
    ObjectTypeBuilder::new(&ids.bus_type(), ids.name("BusType"), "BusType")
        .subtype_of(ObjectTypeId::BaseObjectType)
        .generates_event(ObjectTypeId::BaseEventType)
        .description("An RS-485 bus and its statistics")
        .insert(space);
    // The types' members, so a client browsing DriveType sees what every drive has.
    let members =
        [("DriveType", ids.drive_type(), DRIVE_VARIABLES), ("BusType", ids.bus_type(), BUS_VARIABLES)];
    for (ty, ty_id, vars) in members {
        for def in vars {
            let id = ids.id(format!("{ty}/{}", def.name));
            add_variable(space, ids, &id, &ty_id, def, false);
            space.insert_reference(
                &id,
                &NodeId::from(ObjectId::ModellingRule_Mandatory),
                ReferenceTypeId::HasModellingRule,
            );
        }
    }
    for (folder, name) in [(ids.drives(), "Drives"), (ids.buses(), "Buses")] {
        ObjectBuilder::new(&folder, ids.name(name), name)
            .is_folder()
            .organized_by(ObjectId::ObjectsFolder)
            .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
            .insert(space);
    }
}

/// Adds the object `obj` named `name`, of the type and in the folder `(type, folder)`, whose
/// events clients may subscribe to.
fn add_object(
    space: &mut AddressSpace,
    ids: &Ids,
    obj: &NodeId,
    name: &str,
    (type_definition, folder): (NodeId, NodeId),
    description: String,
) {
    ObjectBuilder::new(obj, ids.name(name), name)
        .has_type_definition(type_definition)
        .organized_by(folder)
        .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
        .description(description)
        .insert(space);
}

/// Adds one drive: its object, variables and methods, and with `parameters` its `Parameters`
/// folder's contents (the folder itself is always there). `history`: the store keeps the drive's
/// trends ([`VariableDef::trend`]).
pub fn add_drive(space: &mut AddressSpace, ids: &Ids, d: &DriveEntry, parameters: bool, history: bool) {
    let name = d.config.name.as_str();
    let obj = ids.drive(name);
    let description = format!("{} drive at address {} on bus {}", d.config.family, d.config.address, d.bus);
    add_object(space, ids, &obj, name, (ids.drive_type(), ids.drives()), description);
    for def in DRIVE_VARIABLES {
        add_variable(space, ids, &ids.drive_member(name, def.name), &obj, def, history);
    }
    for m in DRIVE_METHODS {
        let id = ids.drive_member(name, m);
        let mut b = MethodBuilder::new(&id, ids.name(m), *m)
            .component_of(obj.clone())
            .executable(true)
            .user_executable(true);
        if *m == "SetSpeed" {
            let args = ids.drive_member(name, "SetSpeed/InputArguments");
            b = b.input_args(space, &args, &[("hz", DataTypeId::Double).into()]);
        }
        b.insert(space);
    }
    let params = ids.drive_member(name, "Parameters");
    ObjectBuilder::new(&params, ids.name("Parameters"), "Parameters")
        .is_folder()
        .component_of(obj.clone())
        .insert(space);
    add_values(space, ids, d, &obj);
    if !parameters {
        return;
    }
    for p in d.catalog().iter() {
        let id = ids.parameter(name, &p.name);
        let mut b = VariableBuilder::new(&id, ids.name(&p.name), p.name.as_str())
            .data_type(DataTypeId::Double)
            .value(Variant::Empty)
            .description(p.title.as_str())
            .has_type_definition(VariableTypeId::BaseDataVariableType)
            .component_of(params.clone());
        if !p.read_only {
            b = b.writable();
        }
        b.insert(space);
        if let Some(unit) = Unit::from_symbol(&p.unit) {
            add_unit(space, ids, &id, unit.eu_information());
        }
    }
}

/// Adds a drive's `Values` folder and a variable per named value (a template's `[values]`):
/// Double, read-only, an AnalogItemType with its EngineeringUnits where it has a unit. A drive
/// without named values has no folder.
fn add_values(space: &mut AddressSpace, ids: &Ids, d: &DriveEntry, obj: &NodeId) {
    let named = d.named_values();
    if named.is_empty() {
        return;
    }
    let drive = d.config.name.as_str();
    let folder = ids.drive_member(drive, "Values");
    ObjectBuilder::new(&folder, ids.name("Values"), "Values")
        .is_folder()
        .description("The drive's values beyond the standard ones, as its template names them")
        .component_of(obj.clone())
        .insert(space);
    for x in &named {
        let id = ids.value(drive, &x.name);
        let access = AccessLevel::CURRENT_READ;
        VariableBuilder::new(&id, ids.name(&x.name), x.name.as_str())
            .data_type(DataTypeId::Double)
            .value(Variant::Empty)
            .has_type_definition(if x.unit.is_empty() {
                VariableTypeId::BaseDataVariableType
            } else {
                VariableTypeId::AnalogItemType
            })
            .access_level(access)
            .user_access_level(access)
            .component_of(folder.clone())
            .insert(space);
        if !x.unit.is_empty() {
            add_unit(space, ids, &id, eu_information_of(&x.unit));
        }
    }
}

/// Adds one bus: its object and variables.
pub fn add_bus(space: &mut AddressSpace, ids: &Ids, b: &BusEntry) {
    let name = b.config.name.as_str();
    let obj = ids.bus(name);
    let c = &b.config;
    let description = format!("{} on {} at {} {}", c.protocol_name(), c.port, c.baud, c.format);
    add_object(space, ids, &obj, name, (ids.bus_type(), ids.buses()), description);
    for def in BUS_VARIABLES {
        add_variable(space, ids, &ids.bus_member(name, def.name), &obj, def, false);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_ids_are_the_common_codes_bytes() {
        // OPC UA Part 8: "HTZ" -> 0x48545A.
        assert_eq!(HERTZ.eu_information().unit_id, 0x48_54_5A);
        assert_eq!(AMPERE.eu_information().unit_id, 0x41_4D_50);
        // A template value's unit: its code where known, else no code (-1) and the text shown.
        assert_eq!(eu_information_of("V").unit_id, 0x56_4C_54);
        assert_eq!(eu_information_of("%").unit_id, 0x50_31);
        let odd = eu_information_of("m3/h");
        assert_eq!((odd.unit_id, odd.display_name.text.as_ref()), (-1, "m3/h"));
    }

    #[test]
    fn node_ids_name_what_they_are() {
        let ids = Ids { ns: 2 };
        assert_eq!(
            ids.target(&ids.drive_member("pump-1", "Setpoint")),
            Target::DriveVariable { drive: "pump-1".into(), variable: "Setpoint".into() }
        );
        assert_eq!(
            ids.target(&ids.drive_member("pump-1", "SetSpeed")),
            Target::Method { drive: "pump-1".into(), method: "SetSpeed".into() }
        );
        assert_eq!(
            ids.target(&ids.parameter("ahu-1", "4-14")),
            Target::Parameter { drive: "ahu-1".into(), name: "4-14".into() }
        );
        assert_eq!(ids.target(&ids.drive("pump-1")), Target::Other);
        assert_eq!(ids.target(&NodeId::new(3, "Drives/pump-1/Setpoint")), Target::Other);
        assert_eq!(ids.target(&ids.drive_member("pump-1", "Nope")), Target::Other);
    }
}
