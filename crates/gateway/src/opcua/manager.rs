//! The node manager of `urn:drivebus`: reads of cache variables come from the cache
//! ([`super::space`]), reads of parameters go to the drive, writes and method
//! calls become gateway commands, answered when the drive confirmed, with a status code that
//! says why not.

use std::collections::VecDeque;
use std::sync::Arc;

use async_trait::async_trait;
use opcua::server::address_space::{read_node_value, DefaultTypeTree, EventNotifier};
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::{
    AddReferenceResult, BrowseNode, BrowsePathItem, ExternalReference, ExternalReferenceRequest, HistoryNode,
    MethodCall, MonitoredItemRef, NodeManager, ReadNode, RequestContext, ServerContext, WriteNode,
};
use opcua::server::CreateMonitoredItem;
use opcua::types::{
    AttributeId, BrowseDirection, DataValue, DateTime, DiagnosticInfo, MessageSecurityMode, NodeId,
    ReadRawModifiedDetails, ReferenceDescription, StatusCode, TimestampsToReturn, UAString, Variant,
};

use super::nodes::{Ids, Target};
use super::sessions::{Seen, Sessions};
use super::space::Space;
use crate::config::Role;
use crate::core::{Command, CommandError, Gateway};

/// The node manager of `urn:drivebus`: the types and folders kept, every drive and bus made
/// on demand from the gateway ([`super::space`]).
pub struct DriveNodes {
    gw: Arc<Gateway>,
    ids: Ids,
    namespace: NamespaceMetadata,
    /// The sessions of each user (`[opcua] max_sessions_per_user`).
    sessions: Arc<Sessions>,
    space: Space,
}

/// The references of a browse left for BrowseNext.
struct Rest(VecDeque<ReferenceDescription>);

impl DriveNodes {
    /// A node manager for `gw` in `namespace` (its index already assigned), counting the
    /// sessions of each user in `sessions`.
    pub fn new(gw: Arc<Gateway>, namespace: NamespaceMetadata, sessions: Arc<Sessions>) -> Self {
        let ids = Ids { ns: namespace.namespace_index };
        DriveNodes { space: Space::new(gw.clone(), ids), gw, ids, namespace, sessions }
    }

    /// Whether the request's session is within its user's `[opcua] max_sessions_per_user`; a
    /// session beyond is refused, and audited (aggregated).
    async fn within_cap(&self, context: &RequestContext) -> bool {
        let session = &context.session;
        let weak = Arc::downgrade(session);
        let seen = Seen {
            id: Arc::as_ptr(session) as usize,
            open: Box::new(move || weak.upgrade().is_some_and(|s| s.read().is_activated())),
        };
        let user = super::auth::user_name(context.user_token());
        let max = super::auth::max_sessions_per_user(&self.gw);
        if self.sessions.seen(user, seen, max, std::time::Instant::now()) {
            return true;
        }
        let why =
            format!("too_many_sessions: user {user} holds {max} sessions ([opcua] max_sessions_per_user)");
        self.gw.audit_login_refusal(&actor(context), &why).await;
        false
    }
}

/// A command's failure in OPC UA's words (docs/opcua.md, "Status codes").
pub fn status_of(e: &CommandError) -> StatusCode {
    match e {
        CommandError::UnknownDrive(_) | CommandError::UnknownBus(_) => StatusCode::BadNodeIdUnknown,
        CommandError::Locked(_) => StatusCode::BadNotWritable,
        CommandError::Invalid(_) => StatusCode::BadOutOfRange,
        CommandError::Refused { .. } => StatusCode::BadInvalidState,
        CommandError::Unsupported(_) => StatusCode::BadNotSupported,
        CommandError::NoAnswer(_) => StatusCode::BadTimeout,
        CommandError::LinkDown(_) => StatusCode::BadNoCommunication,
        CommandError::Protocol(_) => StatusCode::BadCommunicationError,
        CommandError::Busy(_) => StatusCode::BadTooManyOperations,
        CommandError::NotRecorded(_) => StatusCode::BadResourceUnavailable,
        CommandError::Standby(_) => StatusCode::BadInvalidState,
    }
}

fn diagnostics(why: &str) -> DiagnosticInfo {
    DiagnosticInfo { additional_info: Some(UAString::from(why)), ..Default::default() }
}

/// Whose parameter reads wait in one queue on a bus (docs/gateway.md, "Fair use of a bus"):
/// the session and its authenticated user, never anything the client chose (its application
/// URI, its session name); [`super::sessions`] caps the sessions of a user.
pub fn reader(user: &opcua::server::authenticator::UserToken, session_id: u32) -> String {
    format!("opcua:{}@session-{session_id}", super::auth::user_name(user))
}

/// The audit trail's actor of a request: `opcua:<user>@<client>`, where the client is the
/// application URI the client gave for its session (async-opcua does not hand node managers the
/// peer's address).
fn actor(context: &RequestContext) -> String {
    let session = context.session().read();
    let app = session.application_description().application_uri.as_ref().to_string();
    let client = if app.is_empty() { format!("session-{}", context.session_id()) } else { app };
    format!("opcua:{}@{client}", super::auth::user_name(context.user_token()))
}

/// `Ok` when the session's user may write; the status code and a sentence otherwise.
fn may_write(gw: &Gateway, context: &RequestContext) -> Result<(), (StatusCode, String)> {
    match super::auth::role(&gw.config().tokens, context.user_token()) {
        Some(Role::Write) => Ok(()),
        Some(Role::Read) => Err((StatusCode::BadUserAccessDenied, "this user's token has role read".into())),
        None => Err((
            StatusCode::BadUserAccessDenied,
            "log in with a write token to write or call methods".into(),
        )),
    }
}

/// `Ok` when a session on a channel of `mode` may write and call methods: Sign or
/// SignAndEncrypt, or any with `[opcua] insecure_writes`. On `None` anyone on the path could
/// change the command in flight: `Bad_SecurityModeInsufficient`.
pub fn channel_secure_enough(
    mode: MessageSecurityMode,
    insecure_writes: bool,
) -> Result<(), (StatusCode, String)> {
    match mode {
        MessageSecurityMode::Sign | MessageSecurityMode::SignAndEncrypt => Ok(()),
        _ if insecure_writes => Ok(()),
        _ => Err((
            StatusCode::BadSecurityModeInsufficient,
            "insecure: writes and method calls need a Sign or SignAndEncrypt session \
             (Basic256Sha256), or [opcua] insecure_writes = true"
                .into(),
        )),
    }
}

/// A Double from a written or passed value; `BadTypeMismatch` for any other type.
fn double(v: Option<&Variant>) -> Result<f64, StatusCode> {
    match v {
        Some(Variant::Double(x)) => Ok(*x),
        Some(Variant::Float(x)) => Ok(f64::from(*x)),
        _ => Err(StatusCode::BadTypeMismatch),
    }
}

impl DriveNodes {
    async fn read_parameter(&self, drive: &str, name: &str, client: &str) -> DataValue {
        match self.gw.read_param(drive, name, client).await {
            Ok(r) => {
                let now = DateTime::now();
                DataValue {
                    value: Some(Variant::Double(r.value)),
                    status: Some(StatusCode::Good),
                    source_timestamp: Some(now),
                    server_timestamp: Some(now),
                    ..Default::default()
                }
            }
            Err(e) => DataValue {
                status: Some(status_of(&e)),
                server_timestamp: Some(DateTime::now()),
                ..Default::default()
            },
        }
    }

    /// Whether the session may write to or call on `drive` (`action` says what, for the audit
    /// trail), asked before the value or the arguments are looked at: a refusal is audited
    /// (aggregated) whatever the value was.
    async fn authorize(
        &self,
        context: &RequestContext,
        drive: &str,
        action: &str,
    ) -> Result<(), (StatusCode, String)> {
        let refused = may_write(&self.gw, context).map_err(|(code, why)| (code, format!("forbidden: {why}")));
        let insecure_writes = self.gw.config().opcua.as_ref().is_some_and(|o| o.insecure_writes);
        let mode = context.session().read().message_security_mode();
        let refused = refused.and_then(|()| channel_secure_enough(mode, insecure_writes));
        if let Err((code, why)) = refused {
            self.gw.audit_refusal(drive, &actor(context), action, &why).await;
            return Err((code, why));
        }
        Ok(())
    }

    /// Runs `command` for the session (authorized); the status code says how it ended.
    async fn run(
        &self,
        context: &RequestContext,
        drive: &str,
        command: Command,
    ) -> Result<(), (StatusCode, String)> {
        self.gw.command(drive, command, &actor(context)).await.map_err(|e| (status_of(&e), e.to_string()))
    }
}

#[async_trait]
impl NodeManager for DriveNodes {
    fn owns_node(&self, id: &NodeId) -> bool {
        id.namespace == self.ids.ns
    }

    fn name(&self) -> &str {
        "drivebus"
    }

    fn namespaces_for_user(&self, _context: &RequestContext) -> Vec<NamespaceMetadata> {
        vec![self.namespace.clone()]
    }

    async fn init(&self, type_tree: &mut DefaultTypeTree, _context: ServerContext) {
        self.space.kept().load_into_type_tree(type_tree);
    }

    async fn resolve_external_references(
        &self,
        context: &RequestContext,
        items: &mut [&mut ExternalReferenceRequest],
    ) {
        let type_tree = context.type_tree.read();
        let mut view = self.space.view();
        for item in items.iter_mut() {
            if let Some(meta) = view.metadata(item.node_id(), item.result_mask(), &*type_tree) {
                item.set(meta);
            }
        }
    }

    async fn browse(
        &self,
        context: &RequestContext,
        nodes_to_browse: &mut [BrowseNode],
    ) -> Result<(), StatusCode> {
        let type_tree = context.type_tree.read();
        let mut view = self.space.view();
        for node in nodes_to_browse.iter_mut() {
            if node.node_id().is_null() {
                continue;
            }
            if let Some(mut rest) = node.take_continuation_point::<Rest>() {
                node.set_status(StatusCode::Good);
                while node.remaining() > 0 {
                    let Some(r) = rest.0.pop_front() else { break };
                    node.add_unchecked(r);
                }
                if !rest.0.is_empty() {
                    node.set_next_continuation_point(rest);
                }
                continue;
            }
            let id = node.node_id().clone();
            if self.owns_node(&id) {
                if !view.exists(&id) {
                    continue;
                }
                node.set_status(StatusCode::Good);
            }
            let filter = if node.reference_type_id().is_null() {
                None
            } else {
                Some((node.reference_type_id().clone(), node.include_subtypes()))
            };
            let refs = view.references(&id, filter, &*type_tree, node.browse_direction(), None);
            let mut rest = VecDeque::new();
            for (ty, forward, target) in refs {
                let Some(meta) = view.metadata(&target, node.result_mask(), &*type_tree) else {
                    if !self.owns_node(&target) {
                        let direction = if forward {
                            opcua::server::address_space::ReferenceDirection::Forward
                        } else {
                            opcua::server::address_space::ReferenceDirection::Inverse
                        };
                        node.push_external_reference(ExternalReference::new(target.into(), ty, direction));
                    }
                    continue;
                };
                if let AddReferenceResult::Full(r) = node.add(&*type_tree, meta.into_ref_desc(forward, ty)) {
                    rest.push_back(r);
                }
            }
            if !rest.is_empty() {
                node.set_next_continuation_point(Box::new(Rest(rest)));
            }
        }
        Ok(())
    }

    async fn translate_browse_paths_to_node_ids(
        &self,
        context: &RequestContext,
        nodes: &mut [&mut BrowsePathItem],
    ) -> Result<(), StatusCode> {
        let type_tree = context.type_tree.read();
        let mut view = self.space.view();
        let name_mask = opcua::types::BrowseDescriptionResultMask::RESULT_MASK_BROWSE_NAME;
        for item in nodes.iter_mut() {
            if let Some(name) = item.unmatched_browse_name() {
                let matched = view
                    .metadata(item.node_id(), name_mask, &*type_tree)
                    .is_some_and(|m| name.is_null() || m.browse_name == *name);
                if !matched {
                    continue;
                }
                item.set_browse_name_matched(context.current_node_manager_index);
            }
            let mut matching = vec![item.node_id().clone()];
            let mut found = Vec::new();
            for (depth, element) in item.path().iter().enumerate() {
                let mut next = Vec::new();
                for id in &matching {
                    let filter = (!element.reference_type_id.is_null())
                        .then(|| (element.reference_type_id.clone(), element.include_subtypes));
                    let direction =
                        if element.is_inverse { BrowseDirection::Inverse } else { BrowseDirection::Forward };
                    for (_, _, target) in
                        view.references(id, filter, &*type_tree, direction, Some(&element.target_name))
                    {
                        if next.contains(&target) {
                            continue;
                        }
                        match view.metadata(&target, name_mask, &*type_tree) {
                            Some(m)
                                if element.target_name.is_null() || m.browse_name == element.target_name =>
                            {
                                found.push((target.clone(), depth + 1, None));
                                next.push(target);
                            }
                            Some(_) => {}
                            None if !self.owns_node(&target) => {
                                found.push((target, depth + 1, Some(element.target_name.clone())));
                            }
                            None => {}
                        }
                    }
                }
                matching = next;
            }
            for (id, depth, unmatched) in found {
                item.add_element(id, depth, unmatched);
            }
        }
        Ok(())
    }

    async fn read(
        &self,
        context: &RequestContext,
        max_age: f64,
        timestamps_to_return: TimestampsToReturn,
        nodes_to_read: &mut [&mut ReadNode],
    ) -> Result<(), StatusCode> {
        if !self.within_cap(context).await {
            nodes_to_read.iter_mut().for_each(|n| n.set_error(StatusCode::BadTooManySessions));
            return Ok(());
        }
        let client = reader(context.user_token(), context.session_id());
        let mut view = self.space.view();
        for n in nodes_to_read.iter_mut() {
            let value =
                self.read_one(&mut view, context, n.node(), max_age, timestamps_to_return, &client).await;
            n.set_result(value);
        }
        Ok(())
    }

    async fn history_read_raw_modified(
        &self,
        context: &RequestContext,
        details: &ReadRawModifiedDetails,
        nodes: &mut [&mut HistoryNode],
        timestamps_to_return: TimestampsToReturn,
    ) -> Result<(), StatusCode> {
        if !self.within_cap(context).await {
            nodes.iter_mut().for_each(|n| n.set_status(StatusCode::BadTooManySessions));
            return Ok(());
        }
        super::history::read_raw(&self.gw, &self.ids, &self.space, details, nodes, timestamps_to_return)
            .await;
        Ok(())
    }

    async fn create_monitored_items(
        &self,
        context: &RequestContext,
        items: &mut [&mut CreateMonitoredItem],
    ) -> Result<(), StatusCode> {
        if !self.within_cap(context).await {
            items.iter_mut().for_each(|i| i.set_status(StatusCode::BadTooManySessions));
            return Ok(());
        }
        let client = reader(context.user_token(), context.session_id());
        let mut view = self.space.view();
        for item in items.iter_mut() {
            let what = item.item_to_monitor().clone();
            let read = {
                let Some(space) = view.space_of(&what.node_id) else {
                    item.set_status(StatusCode::BadNodeIdUnknown);
                    continue;
                };
                match space.validate_node_read(context, &what) {
                    Err(e) => Err(e),
                    Ok(n) => Ok(read_node_value(n, context, &what, 0.0, item.timestamps_to_return())),
                }
            };
            let read = match read {
                Err(e) => {
                    item.set_status(e);
                    continue;
                }
                Ok(r) => r,
            };
            // An event item only ever receives events: no initial value.
            if what.attribute_id == AttributeId::EventNotifier {
                let subscribable = matches!(&read.value, Some(Variant::Byte(b))
                    if EventNotifier::from_bits_truncate(*b).contains(EventNotifier::SUBSCRIBE_TO_EVENTS));
                item.set_status(if subscribable {
                    StatusCode::Good
                } else {
                    StatusCode::BadAttributeIdInvalid
                });
                continue;
            }
            let read = match (&what.attribute_id, self.ids.target(&what.node_id)) {
                (AttributeId::Value, Target::Parameter { drive, name }) => {
                    self.read_parameter(&drive, &name, &client).await
                }
                _ => read,
            };
            if read.status() != StatusCode::BadAttributeIdInvalid {
                item.set_initial_value(read);
            }
            item.set_status(StatusCode::Good);
        }
        Ok(())
    }

    async fn delete_monitored_items(&self, _context: &RequestContext, _items: &[&MonitoredItemRef]) {
        // Nothing to stop: values are handed to the subscriptions as the polls bring them.
    }

    async fn write(
        &self,
        context: &RequestContext,
        nodes_to_write: &mut [&mut WriteNode],
    ) -> Result<(), StatusCode> {
        if !self.within_cap(context).await {
            nodes_to_write.iter_mut().for_each(|w| w.set_status(StatusCode::BadTooManySessions));
            return Ok(());
        }
        for w in nodes_to_write.iter_mut() {
            let value = w.value();
            if value.attribute_id != AttributeId::Value {
                w.set_status(StatusCode::BadNotWritable);
                continue;
            }
            if !self.space.view().exists(&value.node_id) {
                w.set_status(StatusCode::BadNodeIdUnknown);
                continue;
            }
            // What the node takes (a speed, a writable parameter), before its value is looked at.
            let (drive, param) = match self.ids.target(&value.node_id) {
                Target::DriveVariable { drive, variable } if variable == "Setpoint" => (drive, None),
                Target::Parameter { drive, name } => {
                    let read_only =
                        self.gw.drive(&drive).ok().and_then(|d| d.param(&name).ok().map(|p| p.read_only));
                    if read_only != Some(false) {
                        w.set_status(StatusCode::BadNotWritable);
                        continue;
                    }
                    (drive, Some(name))
                }
                _ => {
                    w.set_status(StatusCode::BadNotWritable);
                    continue;
                }
            };
            let x = double(value.value.value.as_ref());
            let command = |x: f64| match &param {
                None => Command::Speed(x),
                Some(name) => Command::SetParam { name: name.clone(), value: format!("{x}"), eeprom: false },
            };
            let action = match (&x, &param) {
                (Ok(x), _) => command(*x).action(),
                (Err(_), None) => "speed (not a Double)".to_string(),
                (Err(_), Some(name)) => format!("param {} (not a Double)", crate::text::shown(name)),
            };
            let done = match self.authorize(context, &drive, &action).await {
                Err(e) => Err(e),
                Ok(()) => match x {
                    Err(code) => Err((code, "write a Double (or a Float)".to_string())),
                    Ok(x) => self.run(context, &drive, command(x)).await,
                },
            };
            match done {
                Ok(()) => w.set_status(StatusCode::Good),
                Err((code, why)) => {
                    w.set_diagnostic_info(diagnostics(&why));
                    w.set_status(code);
                }
            }
        }
        Ok(())
    }

    async fn call(
        &self,
        context: &RequestContext,
        methods_to_call: &mut [&mut MethodCall],
    ) -> Result<(), StatusCode> {
        if !self.within_cap(context).await {
            methods_to_call.iter_mut().for_each(|m| m.set_status(StatusCode::BadTooManySessions));
            return Ok(());
        }
        for m in methods_to_call.iter_mut() {
            let Target::Method { drive, method } = self.ids.target(m.method_id()) else {
                m.set_status(StatusCode::BadMethodInvalid);
                continue;
            };
            if self.ids.drive(&drive) != *m.object_id() {
                m.set_status(StatusCode::BadMethodInvalid);
                continue;
            }
            if self.gw.drive(&drive).is_err() {
                m.set_status(StatusCode::BadNodeIdUnknown);
                continue;
            }
            // Only SetSpeed takes an argument (its InputArguments say so).
            if method != "SetSpeed" && !m.arguments().is_empty() {
                m.set_status(StatusCode::BadTooManyArguments);
                continue;
            }
            // Authorized before the arguments are looked at.
            let action = match method.as_str() {
                "SetSpeed" => match m.arguments() {
                    [hz] => double(Some(hz))
                        .map_or("speed (not a Double)".into(), |hz| Command::Speed(hz).action()),
                    _ => "speed".into(),
                },
                other => other.to_ascii_lowercase(),
            };
            if let Err((code, why)) = self.authorize(context, &drive, &action).await {
                m.set_diagnostic_info(diagnostics(&why));
                m.set_status(code);
                continue;
            }
            let command = match method.as_str() {
                "Run" => Ok(Command::Run),
                "Stop" => Ok(Command::Stop),
                "Reverse" => Ok(Command::Reverse),
                "Reset" => Ok(Command::Reset),
                "SetSpeed" => match m.arguments() {
                    [hz] => match double(Some(hz)) {
                        Ok(hz) => Ok(Command::Speed(hz)),
                        Err(code) => {
                            m.set_argument_error(vec![code]);
                            continue;
                        }
                    },
                    [] => Err(StatusCode::BadArgumentsMissing),
                    _ => Err(StatusCode::BadTooManyArguments),
                },
                _ => Err(StatusCode::BadMethodInvalid),
            };
            match command {
                Err(code) => m.set_status(code),
                Ok(command) => match self.run(context, &drive, command).await {
                    Ok(()) => {
                        m.set_outputs(Vec::new());
                        m.set_status(StatusCode::Good);
                    }
                    Err((code, why)) => {
                        m.set_diagnostic_info(diagnostics(&why));
                        m.set_status(code);
                    }
                },
            }
        }
        Ok(())
    }
}

impl DriveNodes {
    /// One attribute of one node: a parameter's value from the drive (never a stale value; the
    /// reads of a session's client wait in one queue on the bus), anything else from the nodes
    /// made from the cache.
    async fn read_one(
        &self,
        view: &mut super::space::View<'_>,
        context: &RequestContext,
        node: &opcua::server::node_manager::ParsedReadValueId,
        max_age: f64,
        timestamps: TimestampsToReturn,
        client: &str,
    ) -> DataValue {
        let checked = view.read(context, node, max_age, timestamps);
        match (&node.attribute_id, self.ids.target(&node.node_id)) {
            (AttributeId::Value, Target::Parameter { drive, name }) if !checked.status().is_bad() => {
                self.read_parameter(&drive, &name, client).await
            }
            _ => checked,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use opcua::server::authenticator::UserToken;

    #[test]
    fn reads_queue_by_session_and_authenticated_user() {
        let token = crate::config::Token {
            name: "ops".into(),
            secret: "0123456789abcdef".into(),
            role: crate::config::Role::Read,
        };
        let user = super::super::auth::user_token(&token);
        assert_eq!(reader(&user, 7), "opcua:ops@session-7");
        assert_eq!(reader(&UserToken(super::super::auth::ANONYMOUS.into()), 8), "opcua:anonymous@session-8");
    }

    #[test]
    fn writes_need_a_signed_channel_unless_insecure_writes() {
        assert!(channel_secure_enough(MessageSecurityMode::Sign, false).is_ok());
        assert!(channel_secure_enough(MessageSecurityMode::SignAndEncrypt, false).is_ok());
        let (code, why) = channel_secure_enough(MessageSecurityMode::None, false).unwrap_err();
        assert_eq!(code, StatusCode::BadSecurityModeInsufficient);
        assert!(why.starts_with("insecure: ") && why.contains("insecure_writes"), "{why}");
        assert!(channel_secure_enough(MessageSecurityMode::None, true).is_ok());
    }
}
