//! One lane per drive: what front ends ask of a drive is carried out in the order they handed
//! it over, one at a time. The order is fixed when the work is handed over
//! ([`Gateway::in_lane`] queues it before it returns, without awaiting), so the tasks a front end
//! spawns afterwards, and the order the runtime polls them in, cannot reorder it. One task per
//! busy lane drains it, and ends when the lane is empty.

use std::collections::{HashMap, VecDeque};
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};

use tokio::sync::oneshot;

use super::command::CommandError;
use super::gateway::Gateway;

/// How much work may wait in one drive's lane; beyond it a hand-over is refused with
/// [`CommandError::Busy`] (nothing is sent).
pub const MAX_LANE_QUEUE: usize = 1024;

type Job = Pin<Box<dyn Future<Output = ()> + Send>>;

#[derive(Default)]
struct Queue {
    jobs: VecDeque<Job>,
    draining: bool,
}

/// Every lane with work in it, by key (a drive's id).
#[derive(Default)]
pub(super) struct Lanes {
    queues: Arc<Mutex<HashMap<String, Queue>>>,
}

impl Lanes {
    /// Queues `job` at the end of lane `key`, and starts the lane's task if it has none.
    fn hand_over(&self, key: &str, job: Job) -> Result<(), CommandError> {
        let mut queues = self.queues.lock().unwrap_or_else(|p| p.into_inner());
        let q = queues.entry(key.to_string()).or_default();
        if q.jobs.len() >= MAX_LANE_QUEUE {
            return Err(CommandError::Busy(format!(
                "{MAX_LANE_QUEUE} commands already wait for drive {key:?}: try again when they are done"
            )));
        }
        q.jobs.push_back(job);
        if !q.draining {
            q.draining = true;
            tokio::spawn(drain(self.queues.clone(), key.to_string()));
        }
        Ok(())
    }
}

/// Carries out lane `key`'s work in order until it is empty.
async fn drain(queues: Arc<Mutex<HashMap<String, Queue>>>, key: String) {
    loop {
        let job = {
            let mut queues = queues.lock().unwrap_or_else(|p| p.into_inner());
            let Some(q) = queues.get_mut(&key) else { return };
            match q.jobs.pop_front() {
                Some(job) => job,
                None => {
                    queues.remove(&key);
                    return;
                }
            }
        };
        // A task of its own, so that a job that panics ends only itself, not the lane.
        let _ = tokio::spawn(job).await;
    }
}

impl Gateway {
    /// Hands `job` to lane `key` (a drive's id; for a unit the gateway has no drive for, any
    /// name that stands for it alone) and returns its result when it has run: after everything
    /// handed to that lane before, and before everything handed over after. The order is fixed
    /// when this returns (it does not wait), so a front end calls it in the order the requests
    /// came, and may then await the result anywhere. The job runs even if the result is no longer
    /// awaited. [`CommandError::Busy`] when [`MAX_LANE_QUEUE`] jobs already wait in the lane.
    pub fn in_lane<T: Send + 'static>(
        &self,
        key: &str,
        job: impl Future<Output = T> + Send + 'static,
    ) -> impl Future<Output = Result<T, CommandError>> + Send + 'static {
        let (tx, rx) = oneshot::channel();
        let handed = self.lanes.hand_over(
            key,
            Box::pin(async move {
                let _ = tx.send(job.await);
            }),
        );
        async move {
            handed?;
            rx.await.map_err(|_| {
                CommandError::NoAnswer(
                    "the command ended without a result (the gateway stopped, or failed on it: see its log)"
                        .into(),
                )
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::core::{Change, Command};

    fn gateway() -> Arc<Gateway> {
        let mut cfg = crate::GatewayConfig::demo();
        cfg.store = None;
        Gateway::start(cfg, None).unwrap()
    }

    /// Jobs of one lane run one at a time in the order handed over, though the first takes the
    /// longest and their results are awaited in the reverse order; another lane does not wait.
    #[tokio::test(start_paused = true)]
    async fn a_lane_runs_its_jobs_one_at_a_time_in_the_order_handed_over() {
        let gw = gateway();
        let log = Arc::new(Mutex::new(Vec::new()));
        let job = |name: &'static str, ms: u64| {
            let log = log.clone();
            async move {
                log.lock().unwrap().push(format!("{name} start"));
                tokio::time::sleep(Duration::from_millis(ms)).await;
                log.lock().unwrap().push(format!("{name} end"));
                name
            }
        };
        let handed =
            [gw.in_lane("d", job("a", 30)), gw.in_lane("d", job("b", 20)), gw.in_lane("d", job("c", 10))];
        let other = gw.in_lane("e", job("x", 1));
        let mut tasks = Vec::new();
        for h in handed.into_iter().rev() {
            tasks.push(tokio::spawn(h));
            tokio::task::yield_now().await;
        }
        assert_eq!(other.await.unwrap(), "x");
        let results: Vec<&str> = futures_results(tasks).await;
        assert_eq!(results, ["c", "b", "a"]);
        let log = log.lock().unwrap().clone();
        let d: Vec<&str> = log.iter().map(String::as_str).filter(|l| !l.starts_with('x')).collect();
        assert_eq!(d, ["a start", "a end", "b start", "b end", "c start", "c end"]);
        // The other lane's job did not wait for this one's.
        let x = log.iter().position(|l| l == "x end").unwrap();
        assert!(x < log.iter().position(|l| l == "a end").unwrap(), "{log:?}");
    }

    async fn futures_results<T>(tasks: Vec<tokio::task::JoinHandle<Result<T, CommandError>>>) -> Vec<T> {
        let mut out = Vec::new();
        for t in tasks {
            out.push(t.await.unwrap().unwrap());
        }
        out
    }

    /// Commands to a drive are carried out (and audited) in the order `Gateway::command` was
    /// called, though each is awaited in a task of its own started in the reverse order: the
    /// drive ends in the state of the last one.
    #[tokio::test(start_paused = true)]
    async fn commands_are_carried_out_in_the_order_of_the_calls_whatever_the_tasks_order() {
        let gw = gateway();
        let id = gw.drives()[0].config.name.clone();
        let mut changes = gw.subscribe();
        let sent = [Command::Speed(20.0), Command::Run, Command::Speed(35.0), Command::Stop];
        let handed: Vec<_> = sent.iter().map(|c| gw.command(&id, c.clone(), "test")).collect();
        let mut tasks = Vec::new();
        for h in handed.into_iter().rev() {
            tasks.push(tokio::spawn(h));
            tokio::task::yield_now().await;
        }
        futures_results(tasks).await;
        let mut audited = Vec::new();
        while audited.len() < sent.len() {
            if let Change::Event(e) = changes.recv().await.unwrap() {
                if e.kind == drivebus_store::EventKind::Command && e.drive.as_deref() == Some(id.as_str()) {
                    assert_eq!(e.result.as_deref(), Some("ok"), "{e:?}");
                    audited.push(e.action.unwrap());
                }
            }
        }
        let want: Vec<String> = sent.iter().map(Command::action).collect();
        assert_eq!(audited, want);
        // Stopped (once it ramped down), and it stays so.
        let stopped = async {
            loop {
                if let Ok(Change::Drive(v)) = changes.recv().await {
                    if v.id == id && v.running == Some(false) {
                        return;
                    }
                }
            }
        };
        tokio::time::timeout(Duration::from_secs(120), stopped).await.expect("the drive stops");
        tokio::time::sleep(Duration::from_secs(5)).await;
        let v = gw.drive_view(&gw.drive(&id).unwrap());
        assert_eq!(v.running, Some(false), "{v:?}");
        assert_eq!(gw.drives()[0].with_state(|s| s.commanded_hz), Some(35.0));
    }

    /// A lane holds at most MAX_LANE_QUEUE jobs: one more is refused at once, nothing run.
    #[tokio::test(start_paused = true)]
    async fn a_full_lane_refuses_more_as_busy() {
        let gw = gateway();
        let ran = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let handed: Vec<_> = (0..MAX_LANE_QUEUE)
            .map(|_| {
                let ran = ran.clone();
                gw.in_lane("d", async move {
                    ran.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                })
            })
            .collect();
        let refused = gw.in_lane("d", async { unreachable!("a job refused runs") });
        assert!(matches!(refused.await, Err(CommandError::Busy(_))));
        for h in handed {
            h.await.unwrap();
        }
        assert_eq!(ran.load(std::sync::atomic::Ordering::Relaxed), MAX_LANE_QUEUE);
    }
}
