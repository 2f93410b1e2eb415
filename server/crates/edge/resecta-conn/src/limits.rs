//! The limits on accepted connections and their validation.

use std::time::Duration;

/// Longest timeout accepted: a day (deadlines are instants; larger values only hide mistakes).
pub const MAX_TIMEOUT: Duration = Duration::from_secs(24 * 60 * 60);

/// Limits on the connections of the server's faces. The caps count both faces together (one
/// process, one file-descriptor table). [`Default`] is the safe default every deployment gets.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConnLimits {
    /// A connection must carry an admitted request (an authenticated one when the server has a
    /// token, any complete request head otherwise) within this time of being accepted, else it
    /// is closed. Covers the TLS handshake and a request head that never ends.
    pub handshake_timeout: Duration,
    /// A connection with no request in flight over which no byte has moved either way for this
    /// long is closed. HTTP/2 pings and server-sent-event keep-alives are bytes, so live
    /// streams never look idle; for HTTP/1 it also bounds the wait for the next request head.
    pub idle_timeout: Duration,
    /// Open connections, both faces together. At the cap the oldest unauthenticated
    /// connection is closed to make room; when every connection is authenticated the new one
    /// is refused.
    pub max_connections: usize,
    /// Open connections from one client address (IPv6: one /64), with the same eviction as
    /// `max_connections` among that address' connections.
    pub max_per_ip: usize,
    /// Connections not yet admitted. At the cap the oldest of them is closed to admit the new
    /// one, so a flood of idle connections cannot lock real clients out.
    pub max_unauthenticated: usize,
    /// Concurrent HTTP/2 streams (calls) per connection.
    pub http2_max_concurrent_streams: u32,
    /// Largest HTTP/2 header list (bytes, uncompressed) a client may send.
    pub http2_max_header_list_bytes: u32,
    /// HTTP/2 streams a client may open and reset before the server has accepted them (the
    /// rapid-reset attack); over it the connection is closed.
    pub http2_max_pending_accept_reset_streams: usize,
}

impl Default for ConnLimits {
    fn default() -> Self {
        Self {
            handshake_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(60),
            max_connections: 1024,
            max_per_ip: 128,
            max_unauthenticated: 256,
            http2_max_concurrent_streams: 100,
            http2_max_header_list_bytes: 16 << 10,
            http2_max_pending_accept_reset_streams: 20,
        }
    }
}

/// A limit out of range; names the setting as the configuration file spells it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LimitsError {
    #[error("{name} must be more than 0 s and at most {max_s} s (got {got:?})", max_s = MAX_TIMEOUT.as_secs())]
    Timeout { name: &'static str, got: Duration },
    #[error("{name} must be at least {min} (got {got})")]
    TooSmall {
        name: &'static str,
        min: u64,
        got: u64,
    },
    #[error("max_per_ip ({per_ip}) cannot exceed max_connections ({total})")]
    PerIpOverTotal { per_ip: usize, total: usize },
}

impl ConnLimits {
    /// Checks every limit; the first one out of range is the error.
    pub fn validate(&self) -> Result<(), LimitsError> {
        for (name, got) in [
            ("handshake_timeout_s", self.handshake_timeout),
            ("idle_timeout_s", self.idle_timeout),
        ] {
            if got.is_zero() || got > MAX_TIMEOUT {
                return Err(LimitsError::Timeout { name, got });
            }
        }
        let at_least = |name: &'static str, got: u64, min: u64| {
            if got < min {
                Err(LimitsError::TooSmall { name, min, got })
            } else {
                Ok(())
            }
        };
        at_least("max_connections", self.max_connections as u64, 1)?;
        at_least("max_per_ip", self.max_per_ip as u64, 1)?;
        at_least("max_unauthenticated", self.max_unauthenticated as u64, 1)?;
        at_least(
            "http2_max_concurrent_streams",
            u64::from(self.http2_max_concurrent_streams),
            1,
        )?;
        // Room for the pseudo-headers and the authorization and version headers of a call.
        at_least(
            "http2_max_header_list_bytes",
            u64::from(self.http2_max_header_list_bytes),
            1024,
        )?;
        at_least(
            "http2_max_pending_accept_reset_streams",
            self.http2_max_pending_accept_reset_streams as u64,
            1,
        )?;
        if self.max_per_ip > self.max_connections {
            return Err(LimitsError::PerIpOverTotal {
                per_ip: self.max_per_ip,
                total: self.max_connections,
            });
        }
        Ok(())
    }

    /// Interval of the HTTP/2 keep-alive pings that keep a live connection from looking idle:
    /// 30 s, or half the idle timeout when that is shorter.
    pub fn http2_keepalive_interval(&self) -> Duration {
        (self.idle_timeout / 2).min(Duration::from_secs(30))
    }

    /// Interval of server-sent-event keep-alive comments: 15 s, or a third of the idle timeout
    /// when that is shorter.
    pub fn sse_keepalive_interval(&self) -> Duration {
        (self.idle_timeout / 3).min(Duration::from_secs(15))
    }

    /// How often expired connections are looked for: a tenth of the shorter timeout, between
    /// 10 ms and 1 s. A timeout closes its connection at most this much late.
    pub fn sweep_interval(&self) -> Duration {
        (self.handshake_timeout.min(self.idle_timeout) / 10)
            .clamp(Duration::from_millis(10), Duration::from_secs(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_keepalives_stay_below_idle() {
        let l = ConnLimits::default();
        assert_eq!(l.validate(), Ok(()));
        assert_eq!(l.http2_keepalive_interval(), Duration::from_secs(30));
        assert_eq!(l.sse_keepalive_interval(), Duration::from_secs(15));
        assert_eq!(l.sweep_interval(), Duration::from_secs(1));
        let short = ConnLimits {
            idle_timeout: Duration::from_secs(3),
            ..ConnLimits::default()
        };
        assert_eq!(
            short.http2_keepalive_interval(),
            Duration::from_millis(1500)
        );
        assert_eq!(short.sse_keepalive_interval(), Duration::from_secs(1));
        assert_eq!(short.sweep_interval(), Duration::from_millis(300));
    }

    #[test]
    fn out_of_range_limits_are_named() {
        let bad = |f: fn(&mut ConnLimits)| {
            let mut l = ConnLimits::default();
            f(&mut l);
            l.validate().unwrap_err().to_string()
        };
        assert!(bad(|l| l.handshake_timeout = Duration::ZERO).contains("handshake_timeout_s"));
        assert!(bad(|l| l.idle_timeout = MAX_TIMEOUT * 2).contains("idle_timeout_s"));
        assert!(bad(|l| l.max_connections = 0).contains("max_connections"));
        assert!(bad(|l| l.max_unauthenticated = 0).contains("max_unauthenticated"));
        assert!(bad(|l| l.http2_max_concurrent_streams = 0).contains("concurrent_streams"));
        assert!(bad(|l| l.http2_max_header_list_bytes = 10).contains("header_list_bytes"));
        assert!(bad(|l| l.max_per_ip = 5000).contains("cannot exceed max_connections"));
    }
}
