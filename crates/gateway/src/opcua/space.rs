//! The address space of `urn:drivebus`, made on demand from the gateway's state: what exists
//! once (the types, the `Drives` and `Buses` folders) is kept; a drive's or bus's nodes are made
//! when a request names them, with their values from the cache, and dropped when it is answered.
//! A drive's parameter nodes are made only for a request about its `Parameters` folder or a
//! parameter. 1000 drives cost the gateway's cache and nothing more here.

use std::collections::VecDeque;

use opcua::server::address_space::{AddressSpace, NodeType, ReferenceDirection, TypeTree};
use opcua::server::node_manager::{NodeMetadata, RequestContext};
use opcua::types::{
    BrowseDescriptionResultMask, BrowseDirection, DataValue, DateTime, ExpandedNodeId, Identifier,
    LocalizedText, NodeClass, NodeId, ReferenceTypeId,
};

use super::nodes::{self, Ids, BUS_VARIABLES, DRIVE_VARIABLES};
use crate::core::Gateway;

/// Where a node of the namespace lives.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum Home {
    /// Among what exists once (types, folders), or a node of another namespace.
    Kept,
    /// Made for the drive named; with its parameters when `parameters`.
    Drive {
        /// The drive's id.
        name: String,
        /// Whether the request is about its parameters.
        parameters: bool,
    },
    /// Made for the bus named.
    Bus(String),
    /// Names a drive or bus the gateway does not have.
    Missing,
}

/// One reference of a node: its type, whether forward, its target.
pub type Ref = (NodeId, bool, NodeId);

/// The namespace's nodes: the part that exists once, and the gateway to make the rest from.
pub struct Space {
    gw: std::sync::Arc<Gateway>,
    ids: Ids,
    kept: AddressSpace,
}

impl Space {
    /// The space of `gw` in the namespace `ids`, its types and folders made.
    pub fn new(gw: std::sync::Arc<Gateway>, ids: Ids) -> Space {
        let mut kept = AddressSpace::new();
        kept.add_namespace(nodes::NAMESPACE, ids.ns);
        nodes::build_types(&mut kept, &ids);
        Space { gw, ids, kept }
    }

    /// What exists once (for the type tree).
    pub fn kept(&self) -> &AddressSpace {
        &self.kept
    }

    /// The namespace's ids.
    pub fn ids(&self) -> &Ids {
        &self.ids
    }

    /// Where `id` lives.
    pub fn home(&self, id: &NodeId) -> Home {
        if id.namespace != self.ids.ns {
            return Home::Kept;
        }
        let Identifier::String(s) = &id.identifier else { return Home::Kept };
        let s = s.as_ref();
        if let Some(rest) = s.strip_prefix("Drives/") {
            let (name, tail) = rest.split_once('/').unwrap_or((rest, ""));
            if self.gw.drive(name).is_err() {
                return Home::Missing;
            }
            let parameters = tail == "Parameters" || tail.starts_with("Parameters/");
            return Home::Drive { name: name.to_string(), parameters };
        }
        if let Some(rest) = s.strip_prefix("Buses/") {
            let name = rest.split_once('/').map_or(rest, |(n, _)| n);
            if !self.gw.buses().iter().any(|b| b.config.name == name) {
                return Home::Missing;
            }
            return Home::Bus(name.to_string());
        }
        Home::Kept
    }

    /// Makes the nodes of `home` with their current values.
    fn make(&self, home: &Home) -> Option<AddressSpace> {
        let mut space = AddressSpace::new();
        space.add_namespace(nodes::NAMESPACE, self.ids.ns);
        let now = DateTime::now();
        match home {
            Home::Drive { name, parameters } => {
                let d = self.gw.drive(name).ok()?;
                nodes::add_drive(&mut space, &self.ids, &d, *parameters, self.gw.store().is_some());
                let v = self.gw.drive_view(&d);
                let values = super::drive_values(&v, super::bus_online(&self.gw, &v.bus), now);
                let named = d.named_values();
                let named_values = super::named_values(
                    &v,
                    named.iter().map(|x| x.name.as_str()),
                    super::bus_online(&self.gw, &v.bus),
                    now,
                );
                let ids = DRIVE_VARIABLES
                    .iter()
                    .map(|def| self.ids.drive_member(name, def.name))
                    .chain(named.iter().map(|x| self.ids.value(name, &x.name)));
                for (id, dv) in ids.zip(values.into_iter().chain(named_values)) {
                    if let Some(NodeType::Variable(var)) = space.find_mut(&id) {
                        var.set_data_value(dv);
                    }
                }
            }
            Home::Bus(name) => {
                let b = self.gw.buses().iter().find(|b| &b.config.name == name)?.clone();
                nodes::add_bus(&mut space, &self.ids, &b);
                let values = super::bus_values(&self.gw.bus_view(&b));
                for (def, value) in BUS_VARIABLES.iter().zip(values) {
                    if let Some(NodeType::Variable(var)) =
                        space.find_mut(&self.ids.bus_member(name, def.name))
                    {
                        var.set_data_value(DataValue::new_at(value, now));
                    }
                }
            }
            Home::Kept | Home::Missing => return None,
        }
        Some(space)
    }

    /// A request's view: the nodes it names, made as it names them.
    pub fn view(&self) -> View<'_> {
        View { space: self, made: VecDeque::new() }
    }
}

/// How many drives' or buses' nodes a request keeps made at once: requests name their nodes
/// drive by drive, and a request about 1000 drives must not hold 1000 drives' nodes.
const KEPT_MADE: usize = 4;

/// The nodes one request needs, made as it names them; the last few kept ([`KEPT_MADE`]).
pub struct View<'a> {
    space: &'a Space,
    made: VecDeque<(Home, Option<AddressSpace>)>,
}

impl View<'_> {
    /// The address space holding `id` (or, for a node of another namespace, what exists once),
    /// `None` when `id` names a drive or bus the gateway does not have.
    pub fn space_of(&mut self, id: &NodeId) -> Option<&AddressSpace> {
        match self.space.home(id) {
            Home::Kept => Some(&self.space.kept),
            Home::Missing => None,
            home => {
                let at = match self.made.iter().position(|(h, _)| *h == home) {
                    Some(at) => at,
                    None => {
                        if self.made.len() == KEPT_MADE {
                            self.made.pop_back();
                        }
                        let made = self.space.make(&home);
                        self.made.push_front((home, made));
                        0
                    }
                };
                self.made[at].1.as_ref()
            }
        }
    }

    /// The node `id`, if it exists in the namespace.
    pub fn node(&mut self, id: &NodeId) -> Option<&NodeType> {
        self.space_of(id)?.find(id)
    }

    /// Whether `id` is a node of the namespace that exists.
    pub fn exists(&mut self, id: &NodeId) -> bool {
        id.namespace == self.space.ids.ns && self.node(id).is_some()
    }

    /// The references of `id` this namespace knows (also for nodes of other namespaces, such
    /// as the Objects folder that organizes `Drives`), of type `filter` (with its subtypes when
    /// asked), in `direction`. With `named`, the folders' drives and buses are only those of
    /// that browse name (a browse path through a folder of 10 000 drives looks at one).
    pub fn references(
        &mut self,
        id: &NodeId,
        filter: Option<(NodeId, bool)>,
        type_tree: &dyn TypeTree,
        direction: BrowseDirection,
        named: Option<&opcua::types::QualifiedName>,
    ) -> Vec<Ref> {
        let ids = self.space.ids;
        let mut out: Vec<Ref> = match self.space_of(id) {
            None => return Vec::new(),
            Some(space) => space
                .find_references(id, filter.clone(), type_tree, direction)
                .map(|r| {
                    (
                        r.reference_type.clone(),
                        matches!(r.direction, ReferenceDirection::Forward),
                        r.target_node.clone(),
                    )
                })
                .collect(),
        };
        // The folders organize every drive and bus, which are made on demand.
        let forward = matches!(direction, BrowseDirection::Forward | BrowseDirection::Both);
        let organizes = match &filter {
            None => true,
            Some((ty, subtypes)) => {
                let o: NodeId = ReferenceTypeId::Organizes.into();
                *ty == o || (*subtypes && type_tree.is_subtype_of(&o, ty))
            }
        };
        if forward && organizes {
            let gw = &self.space.gw;
            let organized = |target: NodeId| (ReferenceTypeId::Organizes.into(), true, target);
            if let Some(name) = named.filter(|n| !n.is_null()) {
                let name_of = name.name.as_ref();
                let ours = name.namespace_index == ids.ns;
                if *id == ids.drives() && ours && gw.drive(name_of).is_ok() {
                    out.push(organized(ids.drive(name_of)));
                } else if *id == ids.buses() && ours && gw.buses().iter().any(|b| b.config.name == name_of) {
                    out.push(organized(ids.bus(name_of)));
                }
            } else if *id == ids.drives() {
                out.extend(
                    gw.drives()
                        .iter()
                        .map(|d| (ReferenceTypeId::Organizes.into(), true, ids.drive(&d.config.name))),
                );
            } else if *id == ids.buses() {
                out.extend(
                    gw.buses()
                        .iter()
                        .map(|b| (ReferenceTypeId::Organizes.into(), true, ids.bus(&b.config.name))),
                );
            }
        }
        out
    }

    /// What a reference to `id` shows (browse name, display name, class, type definition), if
    /// `id` is a node of the namespace that exists.
    pub fn metadata(
        &mut self,
        id: &NodeId,
        mask: BrowseDescriptionResultMask,
        type_tree: &dyn TypeTree,
    ) -> Option<NodeMetadata> {
        if id.namespace != self.space.ids.ns {
            return None;
        }
        let ids = self.space.ids;
        // A drive or bus in a folder's listing: no need to make its nodes.
        if let Some(target) = self.object(id) {
            let (name, ty) = target;
            return Some(NodeMetadata {
                node_id: ExpandedNodeId::new(id.clone()),
                type_definition: ExpandedNodeId::new(ty),
                browse_name: ids.name(&name),
                display_name: LocalizedText::from(name.as_str()),
                node_class: NodeClass::Object,
            });
        }
        let space = self.space_of(id)?;
        let node = space.find(id)?.as_node();
        let type_definition = if mask.contains(BrowseDescriptionResultMask::RESULT_MASK_TYPE_DEFINITION)
            && matches!(node.node_class(), NodeClass::Object | NodeClass::Variable)
        {
            space
                .find_references(
                    id,
                    Some((ReferenceTypeId::HasTypeDefinition, false)),
                    type_tree,
                    BrowseDirection::Forward,
                )
                .next()
                .map_or_else(ExpandedNodeId::null, |r| ExpandedNodeId::new(r.target_node.clone()))
        } else {
            ExpandedNodeId::null()
        };
        Some(NodeMetadata {
            node_id: ExpandedNodeId::new(id.clone()),
            type_definition,
            browse_name: node.browse_name().clone(),
            display_name: node.display_name().clone(),
            node_class: node.node_class(),
        })
    }

    /// The name and type of the drive or bus object `id` names, if it names one that exists.
    fn object(&self, id: &NodeId) -> Option<(String, NodeId)> {
        let Identifier::String(s) = &id.identifier else { return None };
        let s = s.as_ref();
        let ids = self.space.ids;
        if let Some(name) = s.strip_prefix("Drives/").filter(|n| !n.contains('/')) {
            return self.space.gw.drive(name).ok().map(|_| (name.to_string(), ids.drive_type()));
        }
        if let Some(name) = s.strip_prefix("Buses/").filter(|n| !n.contains('/')) {
            return self
                .space
                .gw
                .buses()
                .iter()
                .any(|b| b.config.name == name)
                .then(|| (name.to_string(), ids.bus_type()));
        }
        None
    }

    /// Reads an attribute of `id` as the library does for nodes it keeps.
    pub fn read(
        &mut self,
        context: &RequestContext,
        node: &opcua::server::node_manager::ParsedReadValueId,
        max_age: f64,
        timestamps: opcua::types::TimestampsToReturn,
    ) -> DataValue {
        match self.space_of(&node.node_id) {
            Some(space) => space.read(context, node, max_age, timestamps),
            None => {
                DataValue { status: Some(opcua::types::StatusCode::BadNodeIdUnknown), ..Default::default() }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use opcua::server::address_space::DefaultTypeTree;

    fn demo() -> crate::GatewayConfig {
        let mut cfg = crate::GatewayConfig::demo();
        cfg.store = None;
        cfg
    }

    fn listed(view: &mut View<'_>, folder: &NodeId) -> Vec<NodeId> {
        let tree = DefaultTypeTree::new();
        let organizes = Some((ReferenceTypeId::Organizes.into(), false));
        view.references(folder, organizes, &tree, BrowseDirection::Forward, None)
            .into_iter()
            .map(|(_, _, t)| t)
            .collect()
    }

    #[tokio::test]
    async fn drives_are_made_when_named_and_their_parameters_only_when_asked_for() {
        let gw = Gateway::start(demo(), None).unwrap();
        let space = Space::new(gw.clone(), Ids { ns: 2 });
        let ids = *space.ids();
        // What is kept: the types and the folders, no drive.
        assert!(space.kept().find(&ids.drive_type()).is_some());
        assert!(space.kept().find(&ids.drives()).is_some());
        assert!(space.kept().find(&ids.drive("pump-1")).is_none());
        assert!(space.kept().find(&ids.drive_member("pump-1", "OutputFrequency")).is_none());

        // A drive variable's request makes the drive, not its parameters.
        let d = gw.drive("ahu-1").unwrap();
        let param = d.catalog().iter().next().unwrap().name.clone();
        let plain = space.make(&space.home(&ids.drive_member("ahu-1", "Setpoint"))).unwrap();
        assert!(plain.find(&ids.drive_member("ahu-1", "Setpoint")).is_some());
        assert!(plain.find(&ids.drive_member("ahu-1", "Parameters")).is_some());
        assert!(plain.find(&ids.parameter("ahu-1", &param)).is_none());
        let with = space.make(&space.home(&ids.drive_member("ahu-1", "Parameters"))).unwrap();
        assert!(with.find(&ids.parameter("ahu-1", &param)).is_some());

        let mut view = space.view();
        assert!(view.exists(&ids.parameter("ahu-1", &param)));
        assert!(!view.exists(&ids.parameter("ahu-1", "no-such-parameter")));
        assert!(!view.exists(&ids.drive("no-such-drive")));
        assert!(view.exists(&ids.bus_member("line-toshiba", "Transactions")));
        let drives = listed(&mut view, &ids.drives());
        assert_eq!(drives.len(), gw.drives().len());
        assert!(drives.contains(&ids.drive("pump-1")));
        // A browse path through the folder looks at the drive it names only.
        let tree = DefaultTypeTree::new();
        let named = |view: &mut View<'_>, name: &str| {
            let name = opcua::types::QualifiedName::new(ids.ns, name);
            let organizes = Some((ReferenceTypeId::Organizes.into(), false));
            view.references(&ids.drives(), organizes, &tree, BrowseDirection::Forward, Some(&name))
        };
        assert_eq!(
            named(&mut view, "pump-1").into_iter().map(|(_, _, t)| t).collect::<Vec<_>>(),
            [ids.drive("pump-1")]
        );
        assert!(named(&mut view, "no-such-drive").is_empty());
        // A drive in the folder's listing shows its name and type without being made.
        let meta = view.metadata(&ids.drive("pump-1"), BrowseDescriptionResultMask::all(), &tree).unwrap();
        assert_eq!(meta.browse_name, ids.name("pump-1"));
        assert_eq!(meta.type_definition, ExpandedNodeId::new(ids.drive_type()));
    }

    #[tokio::test]
    async fn a_reload_adds_and_removes_drives_at_once() {
        let gw = Gateway::start(demo(), None).unwrap();
        let space = Space::new(gw.clone(), Ids { ns: 2 });
        let ids = *space.ids();
        assert!(space.view().exists(&ids.drive("pump-1")));
        let mut next = demo();
        for bus in &mut next.buses {
            bus.drives.retain(|d| d.name != "pump-1");
        }
        let mut added = next.buses[0].drives[0].clone();
        added.name = "pump-9".into();
        added.address = 99;
        next.buses[0].drives.push(added);
        gw.reload(next, "test").await.unwrap();
        let mut view = space.view();
        assert!(!view.exists(&ids.drive("pump-1")));
        assert!(!view.exists(&ids.drive_member("pump-1", "OutputFrequency")));
        assert!(view.exists(&ids.drive_member("pump-9", "OutputFrequency")));
        let drives = listed(&mut view, &ids.drives());
        assert!(
            drives.contains(&ids.drive("pump-9")) && !drives.contains(&ids.drive("pump-1")),
            "{drives:?}"
        );
    }
}
