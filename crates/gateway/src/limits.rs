//! Connection limits, so that no client can exhaust the gateway (docs/gateway.md, "Connection
//! limits"): at most `per_address` connections from one address on each listener; new
//! connections refused while the process's open descriptors are within `reserve_fds` of its
//! limit (so the other listeners, the buses' ports and the store never starve); refusals
//! logged at a bounded rate. The header and idle timeouts are applied by each front end
//! ([`ReadDeadlines`], [`Activity`]).

use std::collections::HashMap;
use std::net::IpAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::time::Instant;

// The settings and their defaults are the configuration's (config/model.rs).
pub use crate::config::{LimitsConfig, HEADER_TIMEOUT_MS, IDLE_TIMEOUT_S, PER_ADDRESS, RESERVE_FDS};

/// How often refusals are logged at most (the first at once, then a count per interval).
const LOG_EVERY: Duration = Duration::from_secs(10);
/// How often the open descriptors are counted at most.
const COUNT_EVERY: Duration = Duration::from_secs(1);

/// Raises the soft limit of open files to the hard limit (each client is a descriptor).
/// Returns the soft limit in force.
pub fn raise_nofile_limit() -> std::io::Result<u64> {
    use nix::sys::resource::{getrlimit, setrlimit, Resource};
    let (soft, hard) = getrlimit(Resource::RLIMIT_NOFILE).map_err(std::io::Error::from)?;
    if soft < hard {
        setrlimit(Resource::RLIMIT_NOFILE, hard, hard).map_err(std::io::Error::from)?;
    }
    Ok(hard.max(soft))
}

/// The descriptors this process has open (`/proc/self/fd`); `None` where that cannot be read.
fn open_fds() -> Option<u64> {
    Some(std::fs::read_dir("/proc/self/fd").ok()?.count() as u64)
}

/// The process's descriptor budget, shared by every listener.
struct Descriptors {
    /// The soft limit.
    limit: u64,
    /// Open at the last count, and when that was.
    counted: Mutex<(u64, Option<Instant>)>,
    /// Connections admitted since the last count.
    since: AtomicU64,
}

impl Descriptors {
    /// How many are open now, at most: the last count (taken again when a second old) and the
    /// connections admitted since.
    fn open(&self) -> u64 {
        let mut c = self.counted.lock().unwrap_or_else(|p| p.into_inner());
        if c.1.map_or(true, |at| at.elapsed() >= COUNT_EVERY) {
            if let Some(n) = open_fds() {
                *c = (n, Some(Instant::now()));
                self.since.store(0, Ordering::Relaxed);
            }
        }
        c.0 + self.since.load(Ordering::Relaxed)
    }
}

/// The limits of the whole gateway; [`Limits::listener`] gives each listener its own count.
pub struct Limits {
    config: LimitsConfig,
    fds: Arc<Descriptors>,
}

impl Limits {
    /// Limits of `config`. Raises the soft descriptor limit to the hard limit first (a warning
    /// when it cannot).
    pub fn new(config: LimitsConfig) -> Limits {
        let limit = match raise_nofile_limit() {
            Ok(n) => n,
            Err(e) => {
                crate::log::warn(&format!("cannot raise the open files limit: {e}"));
                u64::MAX
            }
        };
        let fds = Descriptors { limit, counted: Mutex::new((0, None)), since: AtomicU64::new(0) };
        Limits { config, fds: Arc::new(fds) }
    }

    /// The settings.
    pub fn config(&self) -> &LimitsConfig {
        &self.config
    }

    /// The accounting of listener `name` (`HTTP`, `Modbus TCP`, `the bridge to line-1`).
    pub fn listener(&self, name: &str) -> Arc<Listener> {
        Arc::new(Listener {
            name: name.to_string(),
            config: self.config.clone(),
            fds: self.fds.clone(),
            by_address: Mutex::new(HashMap::new()),
            refused: Mutex::new(Refusals::default()),
        })
    }
}

/// Refusals since the last log line.
#[derive(Default)]
struct Refusals {
    logged: Option<Instant>,
    count: u64,
    last: String,
}

/// One listener's connections by address.
pub struct Listener {
    name: String,
    config: LimitsConfig,
    fds: Arc<Descriptors>,
    by_address: Mutex<HashMap<IpAddr, usize>>,
    refused: Mutex<Refusals>,
}

impl Listener {
    /// The next connection `listener` accepts that these limits admit, with its place. A failed
    /// accept (out of descriptors, a connection reset before it) is logged once and retried
    /// after a short pause: the listener keeps serving the others.
    pub async fn accept(
        self: &Arc<Self>,
        listener: &tokio::net::TcpListener,
    ) -> (tokio::net::TcpStream, std::net::SocketAddr, Permit) {
        let mut warned = false;
        loop {
            match listener.accept().await {
                Ok((sock, peer)) => {
                    if let Some(permit) = self.admit(peer.ip()) {
                        return (sock, peer, permit);
                    }
                }
                Err(e) => {
                    if !std::mem::replace(&mut warned, true) {
                        crate::log::warn(&format!("{}: accept failed: {e} (retrying)", self.name));
                    }
                    tokio::time::sleep(std::time::Duration::from_millis(20)).await;
                }
            }
        }
    }

    /// Admits a connection from `ip`, or refuses it (logged at a bounded rate): the returned
    /// [`Permit`] holds its place until dropped.
    pub fn admit(self: &Arc<Self>, ip: IpAddr) -> Option<Permit> {
        let ip = canonical(ip);
        let why = {
            let mut m = self.by_address.lock().unwrap_or_else(|p| p.into_inner());
            let n = m.entry(ip).or_insert(0);
            if *n >= self.config.per_address {
                Some(format!(
                    "{ip} has {n} connections open ([limits] per_address = {})",
                    self.config.per_address
                ))
            } else {
                *n += 1;
                None
            }
        };
        let why = why.or_else(|| {
            let open = self.fds.open();
            let room = self.fds.limit.saturating_sub(self.config.reserve_fds);
            (open >= room).then(|| {
                self.release(ip);
                format!(
                    "{open} descriptors open of {} ([limits] reserve_fds = {} kept for the other listeners and the buses)",
                    self.fds.limit, self.config.reserve_fds
                )
            })
        });
        match why {
            Some(why) => {
                self.refused(why);
                None
            }
            None => {
                self.fds.since.fetch_add(1, Ordering::Relaxed);
                Some(Permit { listener: self.clone(), ip })
            }
        }
    }

    /// Connections open from `ip` now.
    pub fn open_from(&self, ip: IpAddr) -> usize {
        self.by_address.lock().unwrap_or_else(|p| p.into_inner()).get(&canonical(ip)).copied().unwrap_or(0)
    }

    fn release(&self, ip: IpAddr) {
        let mut m = self.by_address.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(n) = m.get_mut(&ip) {
            *n -= 1;
            if *n == 0 {
                m.remove(&ip);
            }
        }
    }

    /// Logs a refusal: the first at once, then at most one line per [`LOG_EVERY`] with the count.
    fn refused(&self, why: String) {
        let mut r = self.refused.lock().unwrap_or_else(|p| p.into_inner());
        r.count += 1;
        r.last = why;
        if r.logged.map_or(true, |at| at.elapsed() >= LOG_EVERY) {
            let n = r.count;
            crate::log::warn(&format!(
                "{}: refused {n} connection{} in the last {} s; the last: {}",
                self.name,
                if n == 1 { "" } else { "s" },
                LOG_EVERY.as_secs(),
                r.last
            ));
            r.count = 0;
            r.logged = Some(Instant::now());
        }
    }
}

/// A connection's place on its listener; given back when dropped.
pub struct Permit {
    listener: Arc<Listener>,
    ip: IpAddr,
}

impl Drop for Permit {
    fn drop(&mut self) {
        self.listener.release(self.ip);
    }
}

/// An IPv4-mapped IPv6 address as IPv4 (one client, one count).
pub fn canonical(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(IpAddr::V6(v6), IpAddr::V4),
        v4 => v4,
    }
}

/// `at` plus `wait`; a wait too long to add (a timeout of billions of seconds in the
/// configuration) is thirty years.
fn later(at: Instant, wait: Duration) -> Instant {
    at.checked_add(wait).unwrap_or_else(|| at + Duration::from_secs(30 * 365 * 86_400))
}

/// The read deadlines of a framed connection (Modbus TCP, a bridge): the rest of a frame begun
/// within `header_timeout`, the next frame within `idle_timeout`. The idle deadline is one timer,
/// armed when the connection opens and moved on only when it fires (to the last read plus the
/// timeout), not on every request: at a hundred thousand requests a second, a timer set and
/// cleared around each read cost a few per cent of the server's time.
pub struct ReadDeadlines {
    header: Duration,
    idle: Duration,
    /// When the last bytes came.
    last: Instant,
    /// Fires at the idle deadline, or earlier (then it is moved on).
    idle_timer: Pin<Box<tokio::time::Sleep>>,
}

impl ReadDeadlines {
    /// The deadlines of `limits`, counted from now.
    pub fn new(limits: &LimitsConfig) -> Self {
        let last = Instant::now();
        // Zero: no idle timeout (the timer is never polled).
        let idle_timer = Box::pin(tokio::time::sleep_until(later(last, limits.idle_timeout)));
        ReadDeadlines { header: limits.header_timeout, idle: limits.idle_timeout, last, idle_timer }
    }

    /// Reads from `stream` into `buf` (`partial`: a frame is begun, so the header timeout
    /// applies): `None` when nothing came in time.
    pub async fn read<S: AsyncRead + Unpin>(
        &mut self,
        stream: &mut S,
        buf: &mut [u8],
        partial: bool,
    ) -> std::io::Result<Option<usize>> {
        use tokio::io::AsyncReadExt;
        let n = if partial && !self.header.is_zero() {
            match tokio::time::timeout(self.header, stream.read(buf)).await {
                Ok(r) => r?,
                Err(_) => return Ok(None),
            }
        } else if self.idle.is_zero() {
            stream.read(buf).await?
        } else {
            loop {
                tokio::select! {
                    biased;
                    r = stream.read(&mut *buf) => break r?,
                    () = &mut self.idle_timer => {
                        let at = later(self.last, self.idle);
                        if Instant::now() >= at {
                            return Ok(None);
                        }
                        self.idle_timer.as_mut().reset(at);
                    }
                }
            }
        };
        self.last = Instant::now();
        Ok(Some(n))
    }
}

/// A byte stream that notes when anything went through it either way, for idle timeouts.
pub struct Activity<S> {
    inner: S,
    last: Arc<AtomicU64>,
    start: Instant,
}

impl<S> Activity<S> {
    /// Wraps `inner`; [`Activity::idle`] watches it.
    pub fn new(inner: S) -> Self {
        Activity { inner, last: Arc::new(AtomicU64::new(0)), start: Instant::now() }
    }

    fn touch(&self) {
        self.last.store(self.start.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    /// A future that ends once nothing went through the stream for `timeout` (never when zero).
    pub fn idle(&self, timeout: Duration) -> impl std::future::Future<Output = ()> + Send + 'static {
        let (last, start) = (self.last.clone(), self.start);
        async move {
            if timeout.is_zero() {
                return std::future::pending().await;
            }
            loop {
                let at = later(start + Duration::from_millis(last.load(Ordering::Relaxed)), timeout);
                if Instant::now() >= at {
                    return;
                }
                tokio::time::sleep_until(at).await;
            }
        }
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Activity<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let r = Pin::new(&mut self.inner).poll_read(cx, buf);
        if matches!(r, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            self.touch();
        }
        r
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Activity<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let r = Pin::new(&mut self.inner).poll_write(cx, data);
        if matches!(r, Poll::Ready(Ok(n)) if n > 0) {
            self.touch();
        }
        r
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_address_gets_its_share_and_gives_it_back() {
        let limits = Limits::new(LimitsConfig { per_address: 2, ..LimitsConfig::default() });
        let l = limits.listener("test");
        let a: IpAddr = "127.0.0.2".parse().unwrap();
        let b: IpAddr = "::ffff:127.0.0.3".parse().unwrap();
        let p1 = l.admit(a).unwrap();
        let _p2 = l.admit(a).unwrap();
        assert!(l.admit(a).is_none(), "a third connection from one address");
        assert!(l.admit(b).is_some(), "another address is served");
        drop(p1);
        assert_eq!(l.open_from(a), 1);
        assert!(l.admit(a).is_some());
    }

    #[test]
    fn no_connection_within_the_reserve() {
        let limits = Limits::new(LimitsConfig { reserve_fds: u64::MAX, ..LimitsConfig::default() });
        let l = limits.listener("test");
        assert!(l.admit("127.0.0.2".parse().unwrap()).is_none());
        assert_eq!(l.open_from("127.0.0.2".parse().unwrap()), 0, "a refusal holds no place");
    }

    fn deadlines(header_s: u64, idle_s: u64) -> ReadDeadlines {
        ReadDeadlines::new(&LimitsConfig {
            header_timeout: Duration::from_secs(header_s),
            idle_timeout: Duration::from_secs(idle_s),
            ..LimitsConfig::default()
        })
    }

    /// The idle deadline counts from the last bytes, not from the connection's start: a request
    /// at 200 s keeps a 300 s connection until 500 s; then it is over.
    #[tokio::test(start_paused = true)]
    async fn the_idle_deadline_moves_with_each_request() {
        use tokio::io::AsyncWriteExt;
        let (mut client, mut server) = tokio::io::duplex(64);
        let mut d = deadlines(5, 300);
        let start = Instant::now();
        let mut buf = [0u8; 16];
        let writer = tokio::spawn(async move {
            tokio::time::sleep(Duration::from_secs(200)).await;
            client.write_all(b"x").await.unwrap();
            client
        });
        assert_eq!(d.read(&mut server, &mut buf, false).await.unwrap(), Some(1));
        assert_eq!(start.elapsed(), Duration::from_secs(200));
        let _client = writer.await.unwrap();
        assert_eq!(d.read(&mut server, &mut buf, false).await.unwrap(), None, "idle for 300 s");
        assert_eq!(start.elapsed(), Duration::from_secs(500));
    }

    /// The rest of a frame must come within the header timeout, however long the idle one.
    #[tokio::test(start_paused = true)]
    async fn a_begun_frame_has_the_header_timeout() {
        let (_client, mut server) = tokio::io::duplex(64);
        let mut d = deadlines(5, 300);
        let start = Instant::now();
        assert_eq!(d.read(&mut server, &mut [0u8; 16], true).await.unwrap(), None);
        assert_eq!(start.elapsed(), Duration::from_secs(5));
    }

    /// A timeout too long to add to a time (billions of years) is a wait, not a panic.
    #[tokio::test(start_paused = true)]
    async fn a_huge_timeout_is_a_long_wait() {
        use tokio::io::AsyncWriteExt;
        let (mut client, mut server) = tokio::io::duplex(64);
        let mut d = deadlines(5, u64::MAX);
        let activity = Activity::new(&mut server);
        let idle = activity.idle(Duration::from_secs(u64::MAX));
        client.write_all(b"x").await.unwrap();
        assert_eq!(d.read(&mut server, &mut [0u8; 16], false).await.unwrap(), Some(1));
        assert!(tokio::time::timeout(Duration::from_secs(86_400), idle).await.is_err());
    }
}
