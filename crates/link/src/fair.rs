//! Fair sharing of a bus between polling and on-demand reads (a client reading a parameter,
//! a Modbus TCP client reading the parameter window, an OPC UA read).
//!
//! On-demand reads wait in one queue per client, served round-robin, so a client that sends
//! many reads waits behind its own and not in front of the others. The queue is bounded (in
//! all and per client): a read beyond it is refused at once with [`BusError::Busy`] instead
//! of waiting for ever. When polls and on-demand reads both wait, the bus time goes to
//! on-demand reads for at most [`FairConfig::share`] of it, so polls keep their interval
//! whatever the clients do. Commands are not here: they go ahead of both.

use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::Duration;

use tokio::sync::Notify;

use crate::bus::BusError;
pub use crate::bus::FairConfig;

/// The on-demand reads waiting, one queue per client, served round-robin.
pub(crate) struct Queues<J> {
    config: FairConfig,
    /// Clients with reads waiting, the next to be served first.
    clients: VecDeque<(String, VecDeque<J>)>,
    waiting: usize,
}

impl<J> Queues<J> {
    /// Empty queues bounded by `config`.
    pub(crate) fn new(config: FairConfig) -> Self {
        Queues { config, clients: VecDeque::new(), waiting: 0 }
    }

    /// Queues `job` of `client`, or gives it back with [`BusError::Busy`] when the bus's
    /// queue or the client's own is full.
    pub(crate) fn push(&mut self, client: &str, job: J) -> Result<(), (J, BusError)> {
        if self.waiting >= self.config.queue {
            let e = BusError::Busy(format!(
                "{} on-demand reads are waiting on this bus (at most {}); try again shortly",
                self.waiting, self.config.queue
            ));
            return Err((job, e));
        }
        let at = self.clients.iter().position(|(c, _)| c == client);
        let mine = at.map_or(0, |k| self.clients[k].1.len());
        if mine >= self.config.per_client {
            let e = BusError::Busy(format!(
                "{mine} of this client's reads are waiting on this bus (at most {}); wait for their answers",
                self.config.per_client
            ));
            return Err((job, e));
        }
        match at {
            Some(k) => self.clients[k].1.push_back(job),
            None => self.clients.push_back((client.to_string(), VecDeque::from([job]))),
        }
        self.waiting += 1;
        Ok(())
    }

    /// The next read: the first of the client whose turn it is; that client goes to the back.
    pub(crate) fn pop(&mut self) -> Option<J> {
        let (client, mut jobs) = self.clients.pop_front()?;
        let job = jobs.pop_front();
        if !jobs.is_empty() {
            self.clients.push_back((client, jobs));
        }
        self.waiting -= usize::from(job.is_some());
        job
    }

    /// Whether no read waits.
    pub(crate) fn is_empty(&self) -> bool {
        self.waiting == 0
    }
}

/// The on-demand reads waiting on a bus (its fair [`Queues`], shared by the handles that queue
/// and the owner that serves them), and the owner's wake-up when one comes.
pub(crate) struct OnDemand<J> {
    queues: Mutex<Queues<J>>,
    ready: Notify,
}

impl<J> OnDemand<J> {
    /// Empty queues bounded by `config`.
    pub(crate) fn new(config: FairConfig) -> Self {
        OnDemand { queues: Mutex::new(Queues::new(config)), ready: Notify::new() }
    }

    fn queues(&self) -> std::sync::MutexGuard<'_, Queues<J>> {
        self.queues.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Queues `job` of `client` and wakes the owner (see [`Queues::push`]).
    pub(crate) fn push(&self, client: &str, job: J) -> Result<(), (J, BusError)> {
        self.queues().push(client, job)?;
        self.ready.notify_one();
        Ok(())
    }

    /// The next read, client by client.
    pub(crate) fn pop(&self) -> Option<J> {
        self.queues().pop()
    }

    /// Whether no read waits.
    pub(crate) fn is_empty(&self) -> bool {
        self.queues().is_empty()
    }

    /// Until a read has been queued (at once if one was queued since the last wake-up).
    pub(crate) async fn ready(&self) {
        self.ready.notified().await
    }
}

/// What runs next when a poll and an on-demand read both wait.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Turn {
    /// The poll.
    Poll,
    /// The on-demand read.
    OnDemand,
}

/// Keeps the on-demand reads' part of the contended bus time at the configured share.
///
/// `balance` is the bus time on-demand reads had beyond their share (negative: owed to them),
/// counted only while both kinds wait: an idle bus does not bank time for either.
#[derive(Clone, Debug)]
pub(crate) struct Share {
    share: f64,
    balance: f64,
}

impl Share {
    /// On-demand reads get `share` (clamped to 0..=1) of the contended bus time.
    pub(crate) fn new(share: f64) -> Self {
        let share = if share.is_finite() { share.clamp(0.0, 1.0) } else { 0.5 };
        Share { share, balance: 0.0 }
    }

    /// Who goes next when both wait.
    pub(crate) fn turn(&self) -> Turn {
        if self.share >= 1.0 || (self.share > 0.0 && self.balance < 0.0) {
            Turn::OnDemand
        } else {
            Turn::Poll
        }
    }

    /// Counts `took` of contended bus time given to `turn`.
    pub(crate) fn spent(&mut self, turn: Turn, took: Duration) {
        let t = took.as_secs_f64();
        match turn {
            Turn::OnDemand => self.balance += t * (1.0 - self.share),
            Turn::Poll => self.balance -= t * self.share,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clients_are_served_in_turn_whatever_each_sent() {
        let mut q = Queues::new(FairConfig { share: 0.5, queue: 100, per_client: 100 });
        for i in 0..5 {
            q.push("a", ("a", i)).unwrap();
        }
        q.push("b", ("b", 0)).unwrap();
        q.push("c", ("c", 0)).unwrap();
        let order: Vec<_> = std::iter::from_fn(|| q.pop()).collect();
        assert_eq!(order, [("a", 0), ("b", 0), ("c", 0), ("a", 1), ("a", 2), ("a", 3), ("a", 4)]);
        assert!(q.is_empty());
    }

    #[test]
    fn a_full_queue_refuses_with_busy() {
        let mut q = Queues::new(FairConfig { share: 0.5, queue: 3, per_client: 2 });
        q.push("a", 1).unwrap();
        q.push("a", 2).unwrap();
        let (job, e) = q.push("a", 3).unwrap_err();
        assert_eq!(job, 3);
        assert!(matches!(e, BusError::Busy(ref m) if m.contains("at most 2")), "{e}");
        q.push("b", 4).unwrap();
        let (_, e) = q.push("c", 5).unwrap_err();
        assert!(matches!(e, BusError::Busy(ref m) if m.contains("at most 3")), "{e}");
        assert_eq!(q.pop(), Some(1));
        q.push("c", 5).unwrap();
    }

    #[test]
    fn the_share_holds_over_contended_time() {
        for share in [0.25, 0.5, 0.75] {
            let mut s = Share::new(share);
            let (mut on_demand, mut polls) = (0.0, 0.0);
            for _ in 0..1000 {
                let turn = s.turn();
                // On-demand reads take 3 times as long as a poll.
                let took = if turn == Turn::OnDemand { 0.03 } else { 0.01 };
                s.spent(turn, Duration::from_secs_f64(took));
                *if turn == Turn::OnDemand { &mut on_demand } else { &mut polls } += took;
            }
            let got = on_demand / (on_demand + polls);
            assert!((got - share).abs() < 0.02, "share {share}: on-demand reads had {got:.3}");
        }
        assert_eq!(Share::new(0.0).turn(), Turn::Poll);
        assert_eq!(Share::new(1.0).turn(), Turn::OnDemand);
        // The first contended turn is the poll's.
        assert_eq!(Share::new(0.9).turn(), Turn::Poll);
    }
}
