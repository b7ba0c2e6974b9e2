//! [`RemoteOptions`]: timeouts, retries, concurrency, range merging and the disk cache of remote
//! reads, with their defaults and the environment variables that change them
//! (docs/RELIABILITY.md "Remote reads").

use backon::ExponentialBuilder;
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
    /// drawn uniformly between half of it and all of it (jitter). The default, 5 ms, makes a
    /// transient fault (a 503, a connection dropped mid-body) cost little; with the default 7
    /// retries the steps still add up to 635 ms (5 + 10 + ... + 320), about the 750 ms of the
    /// earlier 4 retries from 50 ms, so a server that is unavailable for a while is waited for as
    /// long as before.
    pub backoff: Duration,
    /// The longest backoff, and the most a `Retry-After` header is obeyed for.
    pub backoff_max: Duration,
    /// The most requests in flight at once to one endpoint (scheme, host and port; an S3
    /// bucket): a cap. Within it the source sizes each endpoint's requests in flight itself,
    /// from the measured latency and rate of reads ([`super::flight`]), from
    /// [`super::flight::FLOOR`] (or the cap, if lower) up.
    pub in_flight: usize,
    /// Largest merged request: adjacent ranges of one object waiting for the same endpoint are
    /// read by one request up to this many bytes.
    pub merge_bytes: u64,
    /// The directory of the local disk cache, if any.
    pub cache_dir: Option<PathBuf>,
    /// Bound on the disk cache's bytes (least recently used files go first).
    pub cache_bytes: u64,
    /// The most hedged reads, in percent of the requests sent ([`super::flight`]); 0 turns
    /// hedging off (a store billed per request, or a test counting the requests a server sees).
    pub hedge_percent: u32,
    /// A PEM file of certificate authorities trusted for `https://` and S3 endpoints besides
    /// the system's (a private CA, a test server's own).
    pub ca_file: Option<PathBuf>,
    /// Speak HTTP/2 with prior knowledge (h2c) to `http://` endpoints: only for servers that
    /// speak it (nginx's `listen ... http2;`), as a plain-HTTP server cannot offer it. `https://`
    /// endpoints use HTTP/2 whenever the server offers it (ALPN), without this.
    pub h2c: bool,
}

impl Default for RemoteOptions {
    fn default() -> Self {
        RemoteOptions {
            timeout: Duration::from_secs(10),
            connect_timeout: Duration::from_secs(2),
            retries: 7,
            backoff: Duration::from_millis(5),
            backoff_max: Duration::from_secs(2),
            in_flight: 256,
            merge_bytes: 4 << 20,
            cache_dir: None,
            cache_bytes: 1 << 30,
            hedge_percent: 5,
            ca_file: None,
            h2c: false,
        }
    }
}

/// The environment variables [`RemoteOptions::from_env`] reads, with what each sets.
pub const ENV_VARS: [(&str, &str); 12] = [
    ("CLIPMAP_REMOTE_TIMEOUT_MS", "whole-request timeout, milliseconds (default 10000)"),
    ("CLIPMAP_REMOTE_CONNECT_TIMEOUT_MS", "connect timeout, milliseconds (default 2000)"),
    ("CLIPMAP_REMOTE_RETRIES", "retries after the first attempt (default 7)"),
    ("CLIPMAP_REMOTE_BACKOFF_MS", "first backoff, milliseconds (default 5)"),
    ("CLIPMAP_REMOTE_BACKOFF_MAX_MS", "longest backoff and Retry-After obeyed, milliseconds (default 2000)"),
    ("CLIPMAP_REMOTE_IN_FLIGHT", "most requests in flight per endpoint; sized within it (default 256)"),
    ("CLIPMAP_REMOTE_MERGE_BYTES", "largest merged range request, bytes (default 4194304)"),
    ("CLIPMAP_REMOTE_CACHE_DIR", "directory of the local disk cache (default: no cache)"),
    ("CLIPMAP_REMOTE_CACHE_BYTES", "bound on the disk cache, bytes (default 1073741824)"),
    ("CLIPMAP_REMOTE_HEDGE_PERCENT", "most hedged reads, percent of the requests; 0 turns hedging off (default 5)"),
    (
        "CLIPMAP_REMOTE_CA_FILE",
        "PEM file of extra certificate authorities trusted for https:// and S3 (default: the system's only)",
    ),
    ("CLIPMAP_REMOTE_H2C", "1: HTTP/2 with prior knowledge to http:// endpoints (h2c); 0: HTTP/1.1 (default 0)"),
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
        if let Some(n) = num("CLIPMAP_REMOTE_HEDGE_PERCENT", 0, 50, "a percentage from 0 (no hedging) to 50")? {
            o.hedge_percent = n as u32;
        }
        if let Some(d) = get("CLIPMAP_REMOTE_CA_FILE").filter(|d| !d.is_empty()) {
            o.ca_file = Some(PathBuf::from(d));
        }
        if let Some(n) = num("CLIPMAP_REMOTE_H2C", 0, 1, "0 (HTTP/1.1) or 1 (HTTP/2 with prior knowledge)")? {
            o.h2c = n == 1;
        }
        Ok(o)
    }

    /// The retries' backoffs, as `backon` draws them: before retry n (1 for the first), a wait
    /// drawn uniformly between half of `min(backoff × 2^(n-1), backoff_max)` and all of it, and
    /// at most [`retries`](Self::retries) of them. (`backon`'s jitter adds up to one more delay to
    /// its delay, so its delays are the halves.)
    pub(crate) fn backoff_policy(&self) -> ExponentialBuilder {
        let first = self.backoff.min(self.backoff_max);
        ExponentialBuilder::new()
            .with_min_delay(first / 2)
            .with_max_delay(self.backoff_max / 2)
            .with_factor(2.0)
            .with_jitter()
            .with_max_times(self.retries as usize)
    }

    /// The wait before a retry whose backoff is `backoff`, when the server asked for
    /// `retry_after`: what it asked, up to [`backoff_max`](Self::backoff_max), and never less
    /// than the backoff.
    pub(crate) fn wait_for(&self, backoff: Duration, retry_after: Option<Duration>) -> Duration {
        retry_after.map_or(backoff, |r| r.min(self.backoff_max).max(backoff))
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
    fn the_ca_file_and_h2c_are_read_from_their_variables() {
        let d = RemoteOptions::default();
        assert_eq!((d.ca_file.as_deref(), d.h2c), (None, false), "off unless asked for");
        let o = RemoteOptions::from_vars(|k| match k {
            "CLIPMAP_REMOTE_CA_FILE" => Some("certs/ca.pem".into()),
            "CLIPMAP_REMOTE_H2C" => Some("1".into()),
            _ => None,
        })
        .unwrap();
        assert_eq!((o.ca_file.as_deref(), o.h2c), (Some(std::path::Path::new("certs/ca.pem")), true));
        let e = RemoteOptions::from_vars(|k| (k == "CLIPMAP_REMOTE_H2C").then(|| "yes".into())).unwrap_err();
        assert_eq!(e.var, "CLIPMAP_REMOTE_H2C");
        assert!(e.to_string().contains("found `yes`") && e.to_string().contains("prior knowledge"), "{e}");
        assert!(ENV_VARS.iter().any(|(v, _)| *v == "CLIPMAP_REMOTE_CA_FILE"));
        assert!(ENV_VARS.iter().any(|(v, _)| *v == "CLIPMAP_REMOTE_H2C"));
    }

    #[test]
    fn backoff_doubles_up_to_the_bound_and_jitter_keeps_at_least_half() {
        use backon::BackoffBuilder;
        let o = RemoteOptions {
            retries: 5,
            backoff: Duration::from_millis(100),
            backoff_max: Duration::from_millis(350),
            ..Default::default()
        };
        // The bound before retry n: 100, 200, then 400 capped at 350.
        let bounds = [100u64, 200, 350, 350, 350].map(Duration::from_millis);
        let slack = Duration::from_micros(10);
        let (mut lowest, mut highest) = ([f64::MAX; 5], [0f64; 5]);
        for seed in 0..200 {
            let waits: Vec<Duration> = o.backoff_policy().with_jitter_seed(seed).build().collect();
            assert_eq!(waits.len(), 5, "one wait per retry, no more");
            for (n, (w, b)) in waits.iter().zip(bounds).enumerate() {
                assert!(*w + slack >= b / 2 && *w <= b + slack, "retry {}: {w:?} outside [{:?}, {b:?}]", n + 1, b / 2);
                let f = w.as_secs_f64() / b.as_secs_f64();
                lowest[n] = lowest[n].min(f);
                highest[n] = highest[n].max(f);
            }
        }
        for n in 0..5 {
            assert!(
                lowest[n] < 0.6 && highest[n] > 0.9,
                "retry {}: jitter spread {}..{}",
                n + 1,
                lowest[n],
                highest[n]
            );
        }
        let none = RemoteOptions { retries: 0, ..o.clone() };
        assert_eq!(none.backoff_policy().build().count(), 0, "no retries, no waits");
        // A first backoff above the bound starts at the bound.
        let over = RemoteOptions { backoff: Duration::from_secs(9), ..o.clone() };
        assert!(over.backoff_policy().build().all(|w| w <= Duration::from_millis(350) + slack));
    }

    #[test]
    fn the_default_backoff_starts_at_5_ms_and_keeps_the_earlier_total_budget() {
        use backon::BackoffBuilder;
        let o = RemoteOptions::default();
        assert_eq!((o.backoff, o.retries), (Duration::from_millis(5), 7));
        // The bound before retry n: 5, 10, 20, ... 320 ms (each under the 2 s cap).
        let bounds: Vec<Duration> = (0..7).map(|n| Duration::from_millis(5 << n)).collect();
        let total: Duration = bounds.iter().sum();
        assert_eq!(total, Duration::from_millis(635), "about the 750 ms of 4 retries from 50 ms");
        let slack = Duration::from_micros(10);
        for seed in 0..100 {
            let waits: Vec<Duration> = o.backoff_policy().with_jitter_seed(seed).build().collect();
            assert_eq!(waits.len(), 7);
            for (n, (w, b)) in waits.iter().zip(&bounds).enumerate() {
                assert!(
                    *w + slack >= *b / 2 && *w <= *b + slack,
                    "retry {}: {w:?} outside [{:?}, {b:?}]",
                    n + 1,
                    *b / 2
                );
            }
            // The first fault costs at most 5 ms, not the 25 to 50 ms of before.
            assert!(waits[0] <= Duration::from_millis(5) + slack);
        }
        // The variable still sets it, and a value out of range is refused naming it.
        let o = RemoteOptions::from_vars(|k| (k == "CLIPMAP_REMOTE_BACKOFF_MS").then(|| "50".into())).unwrap();
        assert_eq!(o.backoff, Duration::from_millis(50));
        let e = RemoteOptions::from_vars(|k| (k == "CLIPMAP_REMOTE_BACKOFF_MS").then(|| "600001".into())).unwrap_err();
        assert_eq!(e.var, "CLIPMAP_REMOTE_BACKOFF_MS");
        assert!(e.to_string().contains("found `600001`") && e.to_string().contains("0 to 600000"), "{e}");
    }

    #[test]
    fn retry_after_is_obeyed_up_to_the_longest_backoff_and_never_shortens_one() {
        let o = RemoteOptions { backoff_max: Duration::from_millis(350), ..Default::default() };
        let ms = Duration::from_millis;
        assert_eq!(o.wait_for(ms(80), None), ms(80));
        assert_eq!(o.wait_for(ms(80), Some(ms(200))), ms(200));
        assert_eq!(o.wait_for(ms(80), Some(ms(60_000))), ms(350), "bounded by backoff_max");
        assert_eq!(o.wait_for(ms(80), Some(ms(1))), ms(80), "never shorter than the backoff");
    }
}
