//! [`RemoteOptions`]: timeouts, retries, concurrency, range merging and the disk cache of remote
//! reads, with their defaults and the environment variables that change them
//! (docs/RELIABILITY.md "Remote reads").

use std::path::PathBuf;
use std::time::Duration;

/// How remote tiles are read. [`RemoteOptions::default`] is what the tools use unless the
/// `CLIPMAP_REMOTE_*` environment variables ([`RemoteOptions::from_env`]) say otherwise.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RemoteOptions {
    /// Whole-request bound: connecting, sending and receiving the body.
    pub timeout: Duration,
    /// Bound on opening a connection.
    pub connect_timeout: Duration,
    /// Attempts after the first one for a failure worth retrying (5xx, 429, 408, a reset or
    /// timed-out connection, a truncated body).
    pub retries: u32,
    /// The first backoff; each retry doubles it, up to [`RemoteOptions::backoff_max`]; the wait is
    /// drawn uniformly between half of it and all of it (jitter).
    pub backoff: Duration,
    /// The longest backoff, and the most a `Retry-After` header is obeyed for.
    pub backoff_max: Duration,
    /// Requests in flight at once to one endpoint (scheme, host and port; an S3 bucket).
    pub in_flight: usize,
    /// Largest merged request: adjacent ranges of one object waiting for the same endpoint are
    /// read by one request up to this many bytes.
    pub merge_bytes: u64,
    /// The directory of the local disk cache, if any.
    pub cache_dir: Option<PathBuf>,
    /// Bound on the disk cache's bytes (least recently used files go first).
    pub cache_bytes: u64,
}

impl Default for RemoteOptions {
    fn default() -> Self {
        RemoteOptions {
            timeout: Duration::from_secs(10),
            connect_timeout: Duration::from_secs(2),
            retries: 4,
            backoff: Duration::from_millis(50),
            backoff_max: Duration::from_secs(2),
            in_flight: 16,
            merge_bytes: 4 << 20,
            cache_dir: None,
            cache_bytes: 1 << 30,
        }
    }
}

/// The environment variables [`RemoteOptions::from_env`] reads, with what each sets.
pub const ENV_VARS: [(&str, &str); 9] = [
    ("CLIPMAP_REMOTE_TIMEOUT_MS", "whole-request timeout, milliseconds (default 10000)"),
    ("CLIPMAP_REMOTE_CONNECT_TIMEOUT_MS", "connect timeout, milliseconds (default 2000)"),
    ("CLIPMAP_REMOTE_RETRIES", "retries after the first attempt (default 4)"),
    ("CLIPMAP_REMOTE_BACKOFF_MS", "first backoff, milliseconds (default 50)"),
    ("CLIPMAP_REMOTE_BACKOFF_MAX_MS", "longest backoff and Retry-After obeyed, milliseconds (default 2000)"),
    ("CLIPMAP_REMOTE_IN_FLIGHT", "requests in flight per endpoint (default 16)"),
    ("CLIPMAP_REMOTE_MERGE_BYTES", "largest merged range request, bytes (default 4194304)"),
    ("CLIPMAP_REMOTE_CACHE_DIR", "directory of the local disk cache (default: no cache)"),
    ("CLIPMAP_REMOTE_CACHE_BYTES", "bound on the disk cache, bytes (default 1073741824)"),
];

/// A `CLIPMAP_REMOTE_*` variable with a value that cannot be used.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("environment variable {var}: found `{found}`, expected {expected}; set it to such a value or unset it for the default")]
pub struct OptionsError {
    /// The variable.
    pub var: &'static str,
    /// Its value.
    pub found: String,
    /// What it may hold.
    pub expected: &'static str,
}

impl RemoteOptions {
    /// The defaults, changed by the `CLIPMAP_REMOTE_*` variables of the process environment.
    pub fn from_env() -> Result<Self, OptionsError> {
        Self::from_vars(|k| std::env::var(k).ok())
    }

    /// The defaults, changed by the variables `get` returns.
    pub(crate) fn from_vars(get: impl Fn(&str) -> Option<String>) -> Result<Self, OptionsError> {
        let mut o = RemoteOptions::default();
        let num =
            |var: &'static str, min: u64, max: u64, expected: &'static str| -> Result<Option<u64>, OptionsError> {
                let Some(v) = get(var) else { return Ok(None) };
                match v.trim().parse::<u64>() {
                    Ok(n) if (min..=max).contains(&n) => Ok(Some(n)),
                    _ => Err(OptionsError { var, found: v, expected }),
                }
            };
        let ms = Duration::from_millis;
        if let Some(n) = num("CLIPMAP_REMOTE_TIMEOUT_MS", 1, 3_600_000, "milliseconds from 1 to 3600000")? {
            o.timeout = ms(n);
        }
        if let Some(n) = num("CLIPMAP_REMOTE_CONNECT_TIMEOUT_MS", 1, 600_000, "milliseconds from 1 to 600000")? {
            o.connect_timeout = ms(n);
        }
        if let Some(n) = num("CLIPMAP_REMOTE_RETRIES", 0, 100, "a number of retries from 0 to 100")? {
            o.retries = n as u32;
        }
        if let Some(n) = num("CLIPMAP_REMOTE_BACKOFF_MS", 0, 600_000, "milliseconds from 0 to 600000")? {
            o.backoff = ms(n);
        }
        if let Some(n) = num("CLIPMAP_REMOTE_BACKOFF_MAX_MS", 0, 3_600_000, "milliseconds from 0 to 3600000")? {
            o.backoff_max = ms(n);
        }
        if let Some(n) = num("CLIPMAP_REMOTE_IN_FLIGHT", 1, 1024, "a number of requests from 1 to 1024")? {
            o.in_flight = n as usize;
        }
        if let Some(n) = num("CLIPMAP_REMOTE_MERGE_BYTES", 0, 1 << 30, "bytes from 0 (no merging) to 1073741824")? {
            o.merge_bytes = n;
        }
        if let Some(d) = get("CLIPMAP_REMOTE_CACHE_DIR").filter(|d| !d.is_empty()) {
            o.cache_dir = Some(PathBuf::from(d));
        }
        if let Some(n) = num("CLIPMAP_REMOTE_CACHE_BYTES", 1, u64::MAX, "a positive number of bytes")? {
            o.cache_bytes = n;
        }
        Ok(o)
    }

    /// The backoff before retry `attempt` (1 for the first retry), jittered by `unit` in [0, 1).
    pub(crate) fn backoff_for(&self, attempt: u32, unit: f64) -> Duration {
        let base = self.backoff.saturating_mul(1u32 << attempt.saturating_sub(1).min(20)).min(self.backoff_max);
        base.mul_f64(0.5 + 0.5 * unit.clamp(0.0, 1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variables_change_the_defaults_and_bad_values_name_the_variable() {
        let o = RemoteOptions::from_vars(|k| match k {
            "CLIPMAP_REMOTE_TIMEOUT_MS" => Some("250".into()),
            "CLIPMAP_REMOTE_IN_FLIGHT" => Some("3".into()),
            _ => None,
        })
        .unwrap();
        assert_eq!(o.timeout, Duration::from_millis(250));
        assert_eq!(o.in_flight, 3);
        assert_eq!(o.retries, RemoteOptions::default().retries);
        let e = RemoteOptions::from_vars(|k| (k == "CLIPMAP_REMOTE_IN_FLIGHT").then(|| "0".into())).unwrap_err();
        assert_eq!(e.var, "CLIPMAP_REMOTE_IN_FLIGHT");
        assert!(e.to_string().contains("found `0`") && e.to_string().contains("1 to 1024"), "{e}");
    }

    #[test]
    fn backoff_doubles_up_to_the_bound_and_jitter_keeps_at_least_half() {
        let o = RemoteOptions {
            backoff: Duration::from_millis(100),
            backoff_max: Duration::from_millis(350),
            ..Default::default()
        };
        assert_eq!(o.backoff_for(1, 0.999_999).as_millis(), 99);
        assert_eq!(o.backoff_for(2, 0.0), Duration::from_millis(100));
        assert_eq!(o.backoff_for(3, 0.0), Duration::from_millis(175), "400 is capped at 350, then halved");
        assert_eq!(o.backoff_for(30, 0.0), Duration::from_millis(175));
    }
}
