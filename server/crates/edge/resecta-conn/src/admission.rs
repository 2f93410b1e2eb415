//! The registry of open connections: admission against the caps (evicting the oldest
//! unauthenticated connection to make room), the per-connection handle the access checks mark,
//! and the sweep that closes connections whose handshake or idle timeout has passed.

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, Weak};
use std::time::Duration;

use futures_util::task::AtomicWaker;
use tokio::time::Instant;

use crate::limits::ConnLimits;

/// Which requests admit a connection (end its handshake period and take it off the
/// unauthenticated count).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdmitOn {
    /// Only requests the access policy authenticated ([`Conn::mark_authenticated`]): the server
    /// has a token.
    Authenticated,
    /// Any complete request head: the server has no token, so every request is as good as
    /// authenticated.
    AnyRequest,
}

/// Why the server closed a connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum CloseReason {
    /// No admitted request within the handshake timeout.
    HandshakeTimeout = 1,
    /// No request in flight and no byte either way within the idle timeout.
    IdleTimeout = 2,
    /// The oldest unauthenticated connection, closed to make room for a new one.
    Evicted = 3,
}

impl CloseReason {
    /// The `reason` label of `resecta_connections_closed_total`.
    pub fn label(self) -> &'static str {
        match self {
            Self::HandshakeTimeout => "handshake_timeout",
            Self::IdleTimeout => "idle_timeout",
            Self::Evicted => "evicted",
        }
    }

    fn from_u8(v: u8) -> Option<Self> {
        match v {
            1 => Some(Self::HandshakeTimeout),
            2 => Some(Self::IdleTimeout),
            3 => Some(Self::Evicted),
            _ => None,
        }
    }

    /// The error a closed connection's reads and writes return.
    pub(crate) fn io_error(self) -> std::io::Error {
        let kind = match self {
            Self::HandshakeTimeout | Self::IdleTimeout => std::io::ErrorKind::TimedOut,
            Self::Evicted => std::io::ErrorKind::ConnectionAborted,
        };
        std::io::Error::new(
            kind,
            format!("connection closed by the server: {}", self.label()),
        )
    }
}

/// Why a new connection was refused: every connection that counts against the cap is admitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Refused {
    #[error("connection refused: {0} connections open (max_connections), all authenticated")]
    MaxConnections(usize),
    #[error(
        "connection refused: {0} connections from this address (max_per_ip), all authenticated"
    )]
    MaxPerIp(usize),
}

impl Refused {
    /// The `reason` label of `resecta_connections_closed_total`.
    pub fn label(self) -> &'static str {
        match self {
            Self::MaxConnections(_) => "refused_max_connections",
            Self::MaxPerIp(_) => "refused_max_per_ip",
        }
    }
}

/// The address a per-IP cap counts: an IPv4 address, or an IPv6 /64 (one subscriber's prefix;
/// IPv4-mapped IPv6 addresses count as their IPv4 address).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum IpKey {
    V4([u8; 4]),
    V6Prefix([u8; 8]),
}

impl From<IpAddr> for IpKey {
    fn from(ip: IpAddr) -> Self {
        match ip.to_canonical() {
            IpAddr::V4(v4) => Self::V4(v4.octets()),
            IpAddr::V6(v6) => {
                let o = v6.octets();
                Self::V6Prefix(std::array::from_fn(|k| o[k]))
            }
        }
    }
}

/// The state of one connection, shared by its stream wrapper, its requests and the registry.
struct Shared {
    id: u64,
    face: &'static str,
    peer: SocketAddr,
    ip: IpKey,
    accepted: Instant,
    /// Milliseconds from `accepted` to the last byte moved either way (or the end of the last
    /// request).
    last_active_ms: AtomicU64,
    admitted: AtomicBool,
    admit_on: AdmitOn,
    in_flight: AtomicUsize,
    /// 0 while open, else a [`CloseReason`].
    closed: AtomicU8,
    read_waker: AtomicWaker,
    write_waker: AtomicWaker,
    admission: Weak<Admission>,
}

impl Shared {
    fn closed(&self) -> Option<CloseReason> {
        CloseReason::from_u8(self.closed.load(Ordering::Acquire))
    }

    /// Which timeout, if any, has passed at `now`.
    fn expired(&self, now: Instant, limits: &ConnLimits) -> Option<CloseReason> {
        if !self.admitted.load(Ordering::Acquire)
            && now.duration_since(self.accepted) >= limits.handshake_timeout
        {
            return Some(CloseReason::HandshakeTimeout);
        }
        let last =
            self.accepted + Duration::from_millis(self.last_active_ms.load(Ordering::Acquire));
        if self.in_flight.load(Ordering::Acquire) == 0
            && now.duration_since(last) >= limits.idle_timeout
        {
            return Some(CloseReason::IdleTimeout);
        }
        None
    }

    fn touch(&self) {
        let ms = Instant::now().duration_since(self.accepted).as_millis();
        self.last_active_ms
            .fetch_max(u64::try_from(ms).unwrap_or(u64::MAX), Ordering::AcqRel);
    }

    /// Marks the connection closed (the first reason wins) and wakes its reader and writer,
    /// which then fail with [`CloseReason::io_error`] and let the stream drop.
    fn close(&self, reason: CloseReason) -> bool {
        let first = self
            .closed
            .compare_exchange(0, reason as u8, Ordering::AcqRel, Ordering::Acquire)
            .is_ok();
        if first {
            self.read_waker.wake();
            self.write_waker.wake();
            tracing::debug!(conn = self.id, face = self.face, peer = %self.peer,
                reason = reason.label(), "connection closed");
            metrics::counter!("resecta_connections_closed_total",
                "face" => self.face, "reason" => reason.label())
            .increment(1);
        }
        first
    }
}

/// A handle on one accepted connection: it travels in each request's extensions, so that the
/// access checks can [`mark it authenticated`](Conn::mark_authenticated).
#[derive(Clone)]
pub struct Conn(Arc<Shared>);

impl fmt::Debug for Conn {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Conn")
            .field("id", &self.0.id)
            .field("face", &self.0.face)
            .field("peer", &self.0.peer)
            .field("admitted", &self.is_admitted())
            .field("closed", &self.0.closed())
            .finish()
    }
}

impl Conn {
    /// The client's address.
    pub fn peer(&self) -> SocketAddr {
        self.0.peer
    }

    /// Whether a request has admitted the connection.
    pub fn is_admitted(&self) -> bool {
        self.0.admitted.load(Ordering::Acquire)
    }

    /// Why the server closed the connection, if it did.
    pub fn close_reason(&self) -> Option<CloseReason> {
        self.0.closed()
    }

    /// The access policy accepted a request on this connection: it is no longer subject to the
    /// handshake timeout nor counted (or evicted) as unauthenticated. Idempotent and cheap
    /// after the first call; a connection already closed stays closed.
    pub fn mark_authenticated(&self) {
        if self.is_admitted() {
            return;
        }
        match self.0.admission.upgrade() {
            Some(admission) => admission.lock().admit(&self.0),
            None => self.0.admitted.store(true, Ordering::Release),
        }
    }

    /// A request head arrived: admits the connection when any request does ([`AdmitOn`]).
    pub(crate) fn note_request(&self) {
        if self.0.admit_on == AdmitOn::AnyRequest {
            self.mark_authenticated();
        }
    }

    /// Counts a request in flight until the guard drops: a connection with a request in flight
    /// is not idle, however long the request takes without moving bytes.
    pub(crate) fn start_request(&self) -> InFlight {
        self.0.in_flight.fetch_add(1, Ordering::AcqRel);
        InFlight(Arc::clone(&self.0))
    }

    pub(crate) fn touch(&self) {
        self.0.touch();
    }

    pub(crate) fn register_read(&self, waker: &std::task::Waker) {
        self.0.read_waker.register(waker);
    }

    pub(crate) fn register_write(&self, waker: &std::task::Waker) {
        self.0.write_waker.register(waker);
    }

    /// Takes the connection out of the registry (its stream is gone).
    pub(crate) fn release(&self) {
        if let Some(admission) = self.0.admission.upgrade() {
            admission.lock().remove(self.0.id);
        }
    }
}

/// A request in flight on a connection ([`Conn::start_request`]).
pub(crate) struct InFlight(Arc<Shared>);

impl Drop for InFlight {
    fn drop(&mut self) {
        // Idle time counts from the end of the last request.
        self.0.touch();
        self.0.in_flight.fetch_sub(1, Ordering::AcqRel);
    }
}

#[derive(Default)]
struct Registry {
    open: HashMap<u64, Arc<Shared>>,
    /// Not yet admitted, oldest first (ids grow with time).
    pending: BTreeMap<u64, Arc<Shared>>,
    per_ip: HashMap<IpKey, usize>,
}

impl Registry {
    fn remove(&mut self, id: u64) -> Option<Arc<Shared>> {
        let shared = self.open.remove(&id)?;
        self.pending.remove(&id);
        if let Some(n) = self.per_ip.get_mut(&shared.ip) {
            *n -= 1;
            if *n == 0 {
                self.per_ip.remove(&shared.ip);
            }
        }
        metrics::gauge!("resecta_connections_open", "face" => shared.face).decrement(1.0);
        Some(shared)
    }

    fn close(&mut self, id: u64, reason: CloseReason) {
        if let Some(shared) = self.remove(id) {
            shared.close(reason);
        }
    }

    fn admit(&mut self, shared: &Shared) {
        if shared.closed().is_none() {
            shared.admitted.store(true, Ordering::Release);
            self.pending.remove(&shared.id);
        }
    }

    /// The oldest unauthenticated connection (from `ip` when given).
    fn oldest_pending(&self, ip: Option<IpKey>) -> Option<u64> {
        self.pending
            .values()
            .find(|s| ip.is_none_or(|ip| s.ip == ip))
            .map(|s| s.id)
    }
}

/// The connections of a server's faces against one set of [`ConnLimits`].
pub struct Admission {
    limits: ConnLimits,
    admit_on: AdmitOn,
    registry: Mutex<Registry>,
    next_id: AtomicU64,
}

impl fmt::Debug for Admission {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Admission")
            .field("limits", &self.limits)
            .field("admit_on", &self.admit_on)
            .field("open", &self.open())
            .field("unauthenticated", &self.unauthenticated())
            .finish()
    }
}

impl Admission {
    /// A registry without its sweeper (tests sweep by hand); servers use [`Admission::start`].
    pub fn new(limits: ConnLimits, admit_on: AdmitOn) -> Arc<Self> {
        Arc::new(Self {
            limits,
            admit_on,
            registry: Mutex::new(Registry::default()),
            next_id: AtomicU64::new(1),
        })
    }

    /// A registry whose timeouts are enforced by a task that sweeps every
    /// [`ConnLimits::sweep_interval`] and ends when the registry is dropped. Call it within the
    /// tokio runtime that serves the faces.
    pub fn start(limits: ConnLimits, admit_on: AdmitOn) -> Arc<Self> {
        let admission = Self::new(limits, admit_on);
        let weak = Arc::downgrade(&admission);
        let period = admission.limits.sweep_interval();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                tick.tick().await;
                match weak.upgrade() {
                    Some(admission) => {
                        admission.sweep();
                    }
                    None => return,
                }
            }
        });
        admission
    }

    pub fn limits(&self) -> &ConnLimits {
        &self.limits
    }

    fn lock(&self) -> MutexGuard<'_, Registry> {
        self.registry.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Open connections (both faces).
    pub fn open(&self) -> usize {
        self.lock().open.len()
    }

    /// Open connections not yet admitted.
    pub fn unauthenticated(&self) -> usize {
        self.lock().pending.len()
    }

    /// Admits a new connection from `peer` on `face` (a metrics label), closing the oldest
    /// unauthenticated connection (of that address, for the per-IP cap) where a cap is reached;
    /// refused only when every connection counted against the cap is admitted.
    pub fn admit(self: &Arc<Self>, face: &'static str, peer: SocketAddr) -> Result<Conn, Refused> {
        let ip = IpKey::from(peer.ip());
        let mut reg = self.lock();
        let refuse = |r: Refused| {
            tracing::debug!(face, peer = %peer, reason = r.label(), "connection refused");
            metrics::counter!("resecta_connections_closed_total",
                "face" => face, "reason" => r.label())
            .increment(1);
            Err(r)
        };
        while reg.per_ip.get(&ip).copied().unwrap_or(0) >= self.limits.max_per_ip {
            match reg.oldest_pending(Some(ip)) {
                Some(id) => reg.close(id, CloseReason::Evicted),
                None => return refuse(Refused::MaxPerIp(self.limits.max_per_ip)),
            }
        }
        while reg.open.len() >= self.limits.max_connections {
            match reg.oldest_pending(None) {
                Some(id) => reg.close(id, CloseReason::Evicted),
                None => return refuse(Refused::MaxConnections(self.limits.max_connections)),
            }
        }
        while reg.pending.len() >= self.limits.max_unauthenticated {
            match reg.oldest_pending(None) {
                Some(id) => reg.close(id, CloseReason::Evicted),
                None => break,
            }
        }
        let accepted = Instant::now();
        let shared = Arc::new(Shared {
            id: self.next_id.fetch_add(1, Ordering::Relaxed),
            face,
            peer,
            ip,
            accepted,
            last_active_ms: AtomicU64::new(0),
            admitted: AtomicBool::new(false),
            admit_on: self.admit_on,
            in_flight: AtomicUsize::new(0),
            closed: AtomicU8::new(0),
            read_waker: AtomicWaker::new(),
            write_waker: AtomicWaker::new(),
            admission: Arc::downgrade(self),
        });
        reg.open.insert(shared.id, Arc::clone(&shared));
        reg.pending.insert(shared.id, Arc::clone(&shared));
        *reg.per_ip.entry(ip).or_insert(0) += 1;
        metrics::gauge!("resecta_connections_open", "face" => face).increment(1.0);
        Ok(Conn(shared))
    }

    /// Closes every connection whose handshake or idle timeout has passed; returns how many.
    pub fn sweep(&self) -> usize {
        let now = Instant::now();
        let mut reg = self.lock();
        let expired: Vec<(u64, CloseReason)> = reg
            .open
            .values()
            .filter_map(|s| s.expired(now, &self.limits).map(|r| (s.id, r)))
            .collect();
        for &(id, reason) in &expired {
            reg.close(id, reason);
        }
        expired.len()
    }
}
