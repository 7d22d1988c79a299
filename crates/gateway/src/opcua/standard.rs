//! The standard nodes (namespace 0) the OPC UA server serves: the part of the OPC UA core
//! namespace a client of the gateway uses, not all of it.
//!
//! The library's core node manager copies the whole core namespace (about 5100 nodes: every
//! standard type with the instance declarations of each, PubSub and certificate management
//! objects, the deprecated type dictionaries) into its address space, about 11 MB of heap that
//! does not depend on the plant. [`StandardNodes`] hands it only:
//! - every type (data, object, variable and reference types), with the non-declaration
//!   properties of data types (`EnumStrings`, `EnumValues`, `OptionSetValues`) and each data
//!   type's `Default Binary` encoding;
//! - the instance declarations of the types the gateway's nodes and events are of (and their
//!   super types): [`DECLARED_TYPES`], so that `AnalogItemType`'s `EURange` and
//!   `EngineeringUnits` and the fields of `BaseEventType` (the event filters' select clauses)
//!   are known;
//! - everything organized under `Root`: the folders, the `Server` object (status, capabilities,
//!   namespaces, diagnostics, methods), except [`LEFT_OUT`] (PubSub and certificate management,
//!   which the gateway does not do, and the type dictionaries that `DataTypeDefinition`
//!   replaced);
//! - the modelling rules the kept nodes name.
//!
//! No kept node keeps a reference to a node left out, so a browse never meets a dangling
//! target. docs/opcua.md ("Namespace 0") says what a client finds.

use std::collections::{HashMap, HashSet};

use opcua::core_namespace::CoreNamespace;
use opcua::nodes::{ImportedItem, NodeSetImport, NodeSetNamespaceMapper};
use opcua::types::{
    Identifier, NamespaceMap, NodeClass, NodeId, ObjectId, ObjectTypeId, ReferenceTypeId, VariableTypeId,
};

/// The types whose instance declarations are served, with those of their super types: the types
/// of the gateway's own nodes (folders, objects, analog and plain variables, properties) and
/// of the events it raises.
pub const DECLARED_TYPES: [u32; 6] = [
    ObjectTypeId::BaseEventType as u32,
    ObjectTypeId::FolderType as u32,
    ObjectTypeId::BaseObjectType as u32,
    VariableTypeId::AnalogItemType as u32,
    VariableTypeId::BaseDataVariableType as u32,
    VariableTypeId::PropertyType as u32,
];

/// Subtrees under `Root` that are not served: PubSub (`Server/PublishSubscribe`), push
/// certificate management (`Server/ServerConfiguration`) and the type dictionaries of the
/// OPC Binary and XML Schema type systems (deprecated; clients read `DataTypeDefinition`).
pub const LEFT_OUT: [u32; 4] = [
    ObjectId::PublishSubscribe as u32,
    ObjectId::ServerConfiguration as u32,
    ObjectId::OPCBinarySchema_TypeSystem as u32,
    ObjectId::XmlSchema_TypeSystem as u32,
];

/// References that make a node part of another (the hierarchy a browse from `Root` follows).
const HIERARCHY: [u32; 5] = [
    ReferenceTypeId::Organizes as u32,
    ReferenceTypeId::HasComponent as u32,
    ReferenceTypeId::HasProperty as u32,
    ReferenceTypeId::HasOrderedComponent as u32,
    ReferenceTypeId::HasNotifier as u32,
];

/// The part of the core namespace the server serves (module doc): a [`NodeSetImport`] for the
/// core node manager, which makes the core namespace's nodes and keeps those chosen.
pub struct StandardNodes {
    keep: HashSet<u32>,
}

/// What the choice needs to know of a node of the core namespace.
struct Facts {
    class: NodeClass,
    default_binary: bool,
}

/// The numeric identifier of a namespace 0 node id (every core node has one).
fn numeric(id: &NodeId) -> Option<u32> {
    match (&id.namespace, &id.identifier) {
        (0, Identifier::Numeric(n)) => Some(*n),
        _ => None,
    }
}

fn is_type(class: NodeClass) -> bool {
    matches!(
        class,
        NodeClass::DataType | NodeClass::ObjectType | NodeClass::VariableType | NodeClass::ReferenceType
    )
}

impl StandardNodes {
    /// Chooses the nodes: makes every node of the core namespace once, notes its class and
    /// references, and drops it (the address space is filled by a second pass, [`Self::load`]).
    pub fn new() -> Self {
        let mut namespaces = NamespaceMap::new();
        let mut map = NodeSetNamespaceMapper::new(&mut namespaces);
        CoreNamespace.register_namespaces(&mut map);
        let mut facts: HashMap<u32, Facts> = HashMap::new();
        // Forward references (source, type, target), whichever side the node set put them on.
        let mut forward: HashMap<u32, Vec<(u32, u32)>> = HashMap::new();
        for item in CoreNamespace.load(&map) {
            let node = item.node.as_node();
            let Some(id) = numeric(node.node_id()) else { continue };
            let default_binary = node.browse_name().name.as_ref() == "Default Binary";
            facts.insert(id, Facts { class: node.node_class(), default_binary });
            for r in &item.references {
                let (Some(target), Some(kind)) = (numeric(&r.target_id), numeric(&r.type_id)) else {
                    continue;
                };
                let (from, to) = if r.is_forward { (id, target) } else { (target, id) };
                forward.entry(from).or_default().push((kind, to));
            }
        }
        let refs = |id: u32| forward.get(&id).into_iter().flatten().copied();
        let declaration =
            |id: u32| refs(id).any(|(kind, _)| kind == ReferenceTypeId::HasModellingRule as u32);
        let class = |id: u32| facts.get(&id).map(|f| f.class);

        // The declared types and their super types.
        let mut declared: HashSet<u32> = HashSet::new();
        let mut supertype: HashMap<u32, u32> = HashMap::new();
        for (&from, list) in &forward {
            for &(kind, to) in list {
                if kind == ReferenceTypeId::HasSubtype as u32 {
                    supertype.insert(to, from);
                }
            }
        }
        for t in DECLARED_TYPES {
            let mut t = Some(t);
            while let Some(x) = t.filter(|x| declared.insert(*x)) {
                t = supertype.get(&x).copied();
            }
        }

        let types: Vec<u32> = facts.iter().filter(|(_, f)| is_type(f.class)).map(|(id, _)| *id).collect();
        let mut keep: HashSet<u32> = types.iter().copied().collect();
        // Everything under Root and the parts of the types that are served, then the modelling
        // rules the kept nodes name (and their own parts).
        let mut todo: Vec<u32> = types.clone();
        todo.push(ObjectId::RootFolder as u32);
        keep.insert(ObjectId::RootFolder as u32);
        let left_out: HashSet<u32> = LEFT_OUT.into_iter().collect();
        let mut rules: Vec<u32> = Vec::new();
        while let Some(x) = todo.pop() {
            let x_is_type = class(x).is_some_and(is_type);
            for (kind, to) in refs(x) {
                if kind == ReferenceTypeId::HasModellingRule as u32 {
                    rules.push(to);
                }
                if kind == ReferenceTypeId::HasEncoding as u32 {
                    if facts.get(&to).is_some_and(|f| f.default_binary) && keep.insert(to) {
                        todo.push(to);
                    }
                    continue;
                }
                let part = HIERARCHY.contains(&kind);
                if !part || class(to).map_or(true, is_type) || left_out.contains(&to) || keep.contains(&to) {
                    continue;
                }
                if x_is_type && declaration(to) && !declared.contains(&x) {
                    continue;
                }
                keep.insert(to);
                todo.push(to);
            }
            if todo.is_empty() {
                for r in rules.drain(..) {
                    if class(r).is_some() && keep.insert(r) {
                        todo.push(r);
                    }
                }
            }
        }
        StandardNodes { keep }
    }

    /// Whether the node `id` of namespace 0 is served.
    pub fn serves(&self, id: u32) -> bool {
        self.keep.contains(&id)
    }

    /// How many nodes are served.
    pub fn len(&self) -> usize {
        self.keep.len()
    }

    /// Whether no node is served (never: `Root` always is).
    pub fn is_empty(&self) -> bool {
        self.keep.is_empty()
    }
}

impl Default for StandardNodes {
    fn default() -> Self {
        Self::new()
    }
}

impl NodeSetImport for StandardNodes {
    fn register_namespaces(&self, namespaces: &mut NodeSetNamespaceMapper) {
        CoreNamespace.register_namespaces(namespaces)
    }

    fn get_own_namespaces(&self) -> Vec<String> {
        CoreNamespace.get_own_namespaces()
    }

    fn load<'a>(
        &'a self,
        namespaces: &'a NodeSetNamespaceMapper,
    ) -> Box<dyn Iterator<Item = ImportedItem> + 'a> {
        Box::new(CoreNamespace.load(namespaces).filter_map(|mut item| {
            let id = numeric(item.node.as_node().node_id())?;
            if !self.keep.contains(&id) {
                return None;
            }
            item.references.retain(|r| numeric(&r.target_id).map_or(true, |t| self.keep.contains(&t)));
            Some(item)
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use opcua::types::DataTypeId;
    use opcua::types::{MethodId, VariableId};

    /// The data types the gateway's variables are of.
    const VALUE_TYPES: [u32; 6] = [
        DataTypeId::Boolean as u32,
        DataTypeId::Double as u32,
        DataTypeId::String as u32,
        DataTypeId::UInt32 as u32,
        DataTypeId::Range as u32,
        DataTypeId::EUInformation as u32,
    ];

    /// Every node of the whole core namespace, with its references.
    fn whole() -> HashMap<u32, ImportedItem> {
        let mut namespaces = NamespaceMap::new();
        let mut map = NodeSetNamespaceMapper::new(&mut namespaces);
        CoreNamespace.register_namespaces(&mut map);
        CoreNamespace.load(&map).map(|i| (numeric(i.node.as_node().node_id()).unwrap(), i)).collect()
    }

    #[test]
    fn what_clients_use_is_served_and_pubsub_certificates_and_dictionaries_are_not() {
        let s = StandardNodes::new();
        let served = [
            ObjectId::RootFolder as u32,
            ObjectId::ObjectsFolder as u32,
            ObjectId::TypesFolder as u32,
            ObjectId::ViewsFolder as u32,
            ObjectId::Server as u32,
            VariableId::Server_NamespaceArray as u32,
            VariableId::Server_ServerArray as u32,
            VariableId::Server_ServerStatus as u32,
            VariableId::Server_ServerStatus_State as u32,
            VariableId::Server_ServerStatus_BuildInfo_ProductUri as u32,
            VariableId::Server_ServerCapabilities_OperationLimits_MaxNodesPerRead as u32,
            VariableId::Server_ServerDiagnostics_ServerDiagnosticsSummary as u32,
            ObjectId::HistoryServerCapabilities_AggregateFunctions as u32,
            MethodId::Server_GetMonitoredItems as u32,
            VariableId::Server_GetMonitoredItems_InputArguments as u32,
            // The fields of the events the gateway raises (event filters' select clauses).
            VariableId::BaseEventType_EventId as u32,
            VariableId::BaseEventType_SourceNode as u32,
            VariableId::BaseEventType_Message as u32,
            VariableId::BaseEventType_Severity as u32,
            // The properties of the drives' analog variables.
            VariableId::BaseAnalogType_EURange as u32,
            VariableId::BaseAnalogType_EngineeringUnits as u32,
            ObjectId::ModellingRule_Mandatory as u32,
            ObjectTypeId::ServerType as u32,
            ObjectTypeId::AlarmConditionType as u32,
            VariableTypeId::AnalogItemType as u32,
            ReferenceTypeId::HasComponent as u32,
            VariableId::NodeClass_EnumValues as u32,
            ObjectId::EUInformation_Encoding_DefaultBinary as u32,
        ];
        for id in served.into_iter().chain(VALUE_TYPES) {
            assert!(s.serves(id), "i={id} is not served");
        }
        let left_out = [
            ObjectId::PublishSubscribe as u32,
            ObjectId::ServerConfiguration as u32,
            VariableId::OpcUa_BinarySchema as u32,
            VariableId::OpcUa_XmlSchema as u32,
            ObjectId::EUInformation_Encoding_DefaultXml as u32,
            // A declaration of a type the gateway has no instance of.
            VariableId::AlarmConditionType_ShelvingState_CurrentState as u32,
            VariableId::ServerType_ServerStatus as u32,
        ];
        for id in left_out {
            assert!(!s.serves(id), "i={id} is served");
        }
        let all = whole();
        assert!(s.len() * 3 < all.len(), "{} of {} core nodes served", s.len(), all.len());
    }

    #[test]
    fn a_served_node_refers_only_to_served_nodes() {
        let s = StandardNodes::new();
        let mut namespaces = NamespaceMap::new();
        let mut map = NodeSetNamespaceMapper::new(&mut namespaces);
        s.register_namespaces(&mut map);
        let mut n = 0;
        for item in s.load(&map) {
            n += 1;
            let id = numeric(item.node.as_node().node_id()).unwrap();
            for r in &item.references {
                let t = numeric(&r.target_id).unwrap();
                assert!(s.serves(t), "i={id} refers to i={t}, which is not served");
            }
        }
        assert_eq!(n, s.len());
    }
}
