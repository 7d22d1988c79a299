//! Carrying out what a front end asks of a drive: [`Gateway::command`] (the lock, the audit
//! record around the command, the drive's state read after it) and [`Gateway::read_param`].

use std::future::Future;
use std::sync::atomic::Ordering;
use std::sync::Arc;

use drivebus_drive::Storage;

use super::cache::DriveEntry;
use super::command::{Command, CommandError, ParamReading, MAX_MESSAGE_CHARS, MAX_SPEED_HZ};
use super::gateway::Gateway;

impl Gateway {
    /// Sends `command` to drive `id` on behalf of `actor` (for the audit trail); the future
    /// returned ends with the drive's confirmation. The command takes its place in the drive's
    /// lane ([`Gateway::in_lane`]) when this is called, not when the future is first awaited:
    /// commands for one drive are carried out one at a time, in the order of the calls. The
    /// command is in the store (result `pending`) before it is sent, and its result before the
    /// future ends. A command whose audit record cannot be committed is not sent:
    /// [`CommandError::NotRecorded`].
    pub fn command(
        self: &Arc<Self>,
        id: &str,
        command: Command,
        actor: &str,
    ) -> impl Future<Output = Result<(), CommandError>> + Send + 'static {
        let handed = self.drive(id).map(|_| {
            let (gw, key, actor) = (self.clone(), id.to_string(), actor.to_string());
            self.in_lane(id, async move { gw.carry_out(&key, command, &actor).await })
        });
        async move { handed?.await? }
    }

    /// [`Gateway::command`], its turn come.
    /// (The drive is looked up again: a reload may have replaced it while the command waited.)
    async fn carry_out(
        self: &Arc<Self>,
        id: &str,
        command: Command,
        actor: &str,
    ) -> Result<(), CommandError> {
        let d = self.drive(id)?;
        if d.locked() {
            let e = CommandError::Locked(id.to_string());
            self.counters.commands_failed.fetch_add(1, Ordering::Relaxed);
            let outcome = format!("{}: {e}", e.kind());
            self.audit(Some(d.bus.clone()), id, actor, &command.action(), outcome).await;
            return Err(e);
        }
        if let Some(e) = d.standby_refusal() {
            // Refused before a record is made: a client that keeps writing to a standby is
            // counted per window (crate::refusals) rather than filling the trail.
            self.audit_refusal(id, actor, &command.action(), &format!("{}: {e}", e.kind())).await;
            return Err(e);
        }
        let pending = self.audit_pending(&d, actor, &command).await?;
        let mut result = self.execute(&d, &command).await;
        if let Err(CommandError::Refused { meaning, .. }) = &mut result {
            // Say why from what the drive reports now.
            self.refresh(&d).await;
            if let Some(f) = d.with_state(|s| s.status.as_ref().and_then(|x| x.fault.clone())) {
                *meaning =
                    format!("{meaning}; the drive is tripped (fault {}: {}): reset it first", f.code, f.text);
            }
        }
        match &result {
            Ok(()) => self.counters.commands_ok.fetch_add(1, Ordering::Relaxed),
            Err(_) => self.counters.commands_failed.fetch_add(1, Ordering::Relaxed),
        };
        let outcome = match &result {
            Ok(()) => "ok".to_string(),
            Err(e) => crate::text::shown_max(&format!("{}: {e}", e.kind()), MAX_MESSAGE_CHARS),
        };
        self.audit_done(pending, outcome).await;
        if result.is_ok() {
            // Read the drive's state now, so the answer (and every front end's cache) shows
            // what the command did.
            self.refresh(&d).await;
        }
        result
    }

    async fn execute(&self, d: &DriveEntry, command: &Command) -> Result<(), CommandError> {
        let map = CommandError::from;
        let storage = |eeprom: bool| if eeprom { Storage::Eeprom } else { Storage::Ram };
        // After a parameter write, a value read a moment ago is not the drive's any more.
        let forget = |name: &str| {
            if let Ok(def) = d.param(name) {
                d.params.forget(&def.name);
            }
        };
        match command {
            Command::Run => d.command.run().await.map_err(map)?,
            Command::Stop => d.command.stop().await.map_err(map)?,
            Command::Reverse => d.command.reverse().await.map_err(map)?,
            Command::Jog => d.command.jog().await.map_err(map)?,
            Command::Reset => d.command.reset().await.map_err(map)?,
            Command::Speed(hz) => {
                if !hz.is_finite() || hz.abs() > MAX_SPEED_HZ {
                    return Err(CommandError::Invalid(format!(
                        "speed {} Hz is not a speed: give a number of Hz within ±{MAX_SPEED_HZ}",
                        crate::text::number(*hz)
                    )));
                }
                d.command.set_speed(*hz).await.map_err(map)?;
                d.state.write().unwrap_or_else(|p| p.into_inner()).commanded_hz = Some(*hz);
            }
            Command::SetParam { name, value, eeprom } => {
                let written = d.command.write_param(name, value, storage(*eeprom)).await.map(|_| ());
                forget(name);
                written.map_err(map)?;
            }
            Command::SetParamRaw { name, raw, eeprom, .. } => {
                let written = d.command.write_param_raw(name, *raw, storage(*eeprom)).await;
                forget(name);
                written.map_err(map)?;
            }
        }
        Ok(())
    }

    /// Reads parameter `name` of drive `id` on behalf of `client` (its address, or a session
    /// where the address is not known): from the drive, in turn with other clients' reads and
    /// sharing the bus with polls ([`drivebus_link::fair`]), or the value read less than
    /// `param_cache_ms` ago. [`CommandError::Busy`] when too many reads wait on the bus.
    pub async fn read_param(&self, id: &str, name: &str, client: &str) -> Result<ParamReading, CommandError> {
        let d = self.drive(id)?;
        let def = d.param(name)?.clone();
        let reader = d.command.on_demand_for(client);
        let raw = d
            .params
            .read(&def.name, || async { reader.read_param(&def.name).await.map(|(raw, _)| raw) })
            .await?;
        Ok(ParamReading {
            name: def.name.clone(),
            title: def.title.clone(),
            raw,
            value: def.from_raw(raw),
            unit: def.unit.clone(),
            text: def.format(raw),
        })
    }
}
