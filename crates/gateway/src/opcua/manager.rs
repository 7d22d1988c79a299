//! The node manager of `urn:drivebus`: reads of a drive's variables come from the cache (values
//! and status as [`super::publish`] puts them in the address space, the source timestamp of the
//! poll that last confirmed them), reads of parameters go to the drive, writes and method
//! calls become gateway commands, answered when the drive confirmed, with a status code that
//! says why not.

use std::sync::Arc;

use async_trait::async_trait;
use opcua::server::address_space::AddressSpace;
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::memory::InMemoryNodeManagerImpl;
use opcua::server::node_manager::{MethodCall, ParsedReadValueId, RequestContext, ServerContext, WriteNode};
use opcua::sync::RwLock;
use opcua::types::{
    AttributeId, DataValue, DateTime, DiagnosticInfo, MessageSecurityMode, StatusCode, TimestampsToReturn,
    UAString, Variant,
};

use super::nodes::{Ids, Target};
use super::sessions::{Seen, Sessions};
use crate::config::Role;
use crate::gateway::{Command, CommandError, Gateway};

/// The node manager's own part: the gateway and the namespace's index.
pub struct DriveNodes {
    gw: Arc<Gateway>,
    ids: Ids,
    namespace: NamespaceMetadata,
    /// Told once the address space is built, so the publisher starts filling it.
    built: Arc<tokio::sync::Notify>,
    /// The nodes made for each drive and bus, kept for a reload that removes them.
    made: std::sync::Mutex<(super::nodes::Made, super::nodes::Made)>,
    /// The sessions of each user (`[opcua] max_sessions_per_user`).
    sessions: Arc<Sessions>,
}

impl DriveNodes {
    /// A node manager for `gw` in `namespace` (its index already assigned), counting the
    /// sessions of each user in `sessions`.
    pub fn new(gw: Arc<Gateway>, namespace: NamespaceMetadata, sessions: Arc<Sessions>) -> Self {
        DriveNodes {
            gw,
            ids: Ids { ns: namespace.namespace_index },
            namespace,
            built: Arc::new(tokio::sync::Notify::new()),
            made: Default::default(),
            sessions,
        }
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

    /// Wakes (once) when the address space is built.
    pub fn built(&self) -> Arc<tokio::sync::Notify> {
        self.built.clone()
    }
}

/// A command's failure in OPC UA's words (docs/opcua.md, "Status codes").
pub fn status_of(e: &CommandError) -> StatusCode {
    match e {
        CommandError::UnknownDrive(_) => StatusCode::BadNodeIdUnknown,
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

/// `dv` with the timestamps a read asked for.
fn only(mut dv: DataValue, timestamps: TimestampsToReturn) -> DataValue {
    if matches!(timestamps, TimestampsToReturn::Server | TimestampsToReturn::Neither) {
        (dv.source_timestamp, dv.source_picoseconds) = (None, None);
    }
    if matches!(timestamps, TimestampsToReturn::Source | TimestampsToReturn::Neither) {
        (dv.server_timestamp, dv.server_picoseconds) = (None, None);
    }
    dv
}

impl DriveNodes {
    /// Brings the address space in line with the gateway's drives and buses after a reload:
    /// adds those it lacks, removes those that are gone. Returns whether anything changed.
    pub fn sync(&self, space: &RwLock<AddressSpace>) -> bool {
        let mut made = self.made.lock().unwrap_or_else(|p| p.into_inner());
        let (drives, buses) = (self.gw.drives(), self.gw.buses());
        let same = drives.len() == made.0.len()
            && buses.len() == made.1.len()
            && drives.iter().all(|d| made.0.contains_key(&d.config.name))
            && buses.iter().all(|b| made.1.contains_key(&b.config.name));
        if same {
            return false;
        }
        let mut space = space.write();
        let (made_drives, made_buses) = &mut *made;
        made_drives.retain(|name, nodes| {
            let keep = drives.iter().any(|d| &d.config.name == name);
            if !keep {
                super::nodes::remove(&mut space, nodes);
            }
            keep
        });
        made_buses.retain(|name, nodes| {
            let keep = buses.iter().any(|b| &b.config.name == name);
            if !keep {
                super::nodes::remove(&mut space, nodes);
            }
            keep
        });
        for b in buses.iter() {
            if !made_buses.contains_key(&b.config.name) {
                made_buses.insert(b.config.name.clone(), super::nodes::add_bus(&mut space, &self.ids, b));
            }
        }
        for d in drives.iter() {
            if !made_drives.contains_key(&d.config.name) {
                made_drives.insert(d.config.name.clone(), super::nodes::add_drive(&mut space, &self.ids, d));
            }
        }
        true
    }

    /// Drive `drive`'s variables from the cache, now, in [`super::nodes::DRIVE_VARIABLES`] order.
    fn cached(&self, drive: &str) -> Option<Vec<DataValue>> {
        let d = self.gw.drive(drive).ok()?;
        let v = self.gw.drive_view(&d);
        let bus_online = super::bus_online(&self.gw, &v.bus);
        Some(super::drive_values(&v, bus_online, DateTime::now()))
    }

    /// Replaces the values read from the address space of the drives' variables in `nodes` with
    /// the cache's, now: the same value and status, with the source timestamp of the poll that
    /// last confirmed them (the address space keeps the one that last changed them). The
    /// variables of one drive in one Read come from one look at the cache, so they agree
    /// (`AgeMs` with the others' source timestamp).
    fn fill_from_cache(
        &self,
        address_space: &RwLock<AddressSpace>,
        nodes: &[&ParsedReadValueId],
        out: &mut [DataValue],
        timestamps: TimestampsToReturn,
    ) {
        let mut drives: std::collections::HashMap<String, Option<Vec<DataValue>>> = Default::default();
        for (n, dv) in nodes.iter().zip(out.iter_mut()) {
            let Target::DriveVariable { drive, variable } = self.ids.target(&n.node_id) else {
                continue;
            };
            let whole_value = n.attribute_id == AttributeId::Value
                && matches!(n.index_range, opcua::types::NumericRange::None);
            if !whole_value || address_space.read().find(&n.node_id).is_none() {
                continue;
            }
            let Some(i) = super::nodes::DRIVE_VARIABLES.iter().position(|def| def.name == variable) else {
                continue;
            };
            let values = drives.entry(drive).or_insert_with_key(|drive| self.cached(drive));
            if let Some(cached) = values.as_ref().and_then(|values| values.get(i)) {
                *dv = only(cached.clone(), timestamps);
            }
        }
    }

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
impl InMemoryNodeManagerImpl for DriveNodes {
    async fn init(&self, space: &mut AddressSpace, _context: ServerContext) {
        let made = super::nodes::build(space, &self.ids, &self.gw.drives(), &self.gw.buses());
        *self.made.lock().unwrap_or_else(|p| p.into_inner()) = made;
        self.built.notify_one();
    }

    fn name(&self) -> &str {
        "drivebus"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        vec![self.namespace.clone()]
    }

    async fn read_values(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        nodes: &[&ParsedReadValueId],
        max_age: f64,
        timestamps_to_return: TimestampsToReturn,
    ) -> Vec<DataValue> {
        if !self.within_cap(context).await {
            return nodes.iter().map(|_| DataValue::from(StatusCode::BadTooManySessions)).collect();
        }
        let mut out = Vec::with_capacity(nodes.len());
        for n in nodes {
            let param = match (&n.attribute_id, self.ids.target(&n.node_id)) {
                (AttributeId::Value, Target::Parameter { drive, name }) => Some((drive, name)),
                _ => None,
            };
            match param {
                // A parameter is read from the drive when it is read: never a stale value.
                // The reads of a session's client wait in one queue on the bus.
                Some((drive, name)) => out.push(
                    self.read_parameter(&drive, &name, &reader(context.user_token(), context.session_id()))
                        .await,
                ),
                None => out.push(address_space.read().read(context, n, max_age, timestamps_to_return)),
            }
        }
        self.fill_from_cache(address_space, nodes, &mut out, timestamps_to_return);
        out
    }

    async fn write(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
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
            if address_space.read().find(&value.node_id).is_none() {
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
        _address_space: &RwLock<AddressSpace>,
        methods_to_call: &mut [&mut &mut MethodCall],
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
            if !["Run", "Stop", "Reverse", "Reset", "SetSpeed"].contains(&method.as_str()) {
                m.set_status(StatusCode::BadMethodInvalid);
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
