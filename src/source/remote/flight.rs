//! How many requests an endpoint has in flight: sized by the source itself from what it
//! measures (docs/COG.md, "Requests in flight").
//!
//! By Little's law the requests in flight a stream of reads needs are its rate times its
//! latency. An endpoint's [`Sizing`] keeps both, smoothed: the latency of its successful
//! requests, and the rate at which reads arrive for it (reads waiting for a slot included, so
//! that a saturated endpoint measures more than it serves). Its limit is their product with
//! [`HEADROOM`], within bounds: never below [`FLOOR`] (the earlier fixed number; or the cap, if
//! lower) and never above the cap (`CLIPMAP_REMOTE_IN_FLIGHT`). A read queue that runs as many
//! reads as its endpoints allow (`TileSource::read_slots`) then sees the limit grow while it is
//! the bottleneck: each window at most doubles it, like a slow start.
//!
//! A store that says it is overloaded (`429`, `503`, S3's `SlowDown`) halves a ceiling on the
//! limit, other failures worth retrying take a quarter off it, at most once a latency (the
//! answers of one burst count once); each success gives it back a little (one request a
//! ceiling's worth of successes: additive increase, multiplicative decrease).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// The limit's lowest value (unless the cap is lower): the fixed number of requests in flight of
/// earlier versions, so that a light load is read exactly as before.
pub const FLOOR: usize = 16;

/// Factor over rate x latency: room for the rate's bursts and the latency's spread.
pub const HEADROOM: f64 = 2.0;

/// The window over which the arrival rate is measured.
pub(crate) const WINDOW: Duration = Duration::from_millis(100);

/// Weight of a new latency sample in the smoothed latency.
const LATENCY_WEIGHT: f64 = 0.1;

/// The latencies kept for the hedging quantile (the most recent).
const KEPT_LATENCIES: usize = 200;

/// Answers measured before a read is hedged at all.
pub const HEDGE_SAMPLES: usize = 20;

/// The quantile of an endpoint's recent latencies past which a read still unanswered is sent
/// once more (a hedge): about one read in twenty at most, fewer with the share's bound.
pub const HEDGE_QUANTILE: f64 = 0.95;

/// The most hedges, as a share of the requests sent, by default (`CLIPMAP_REMOTE_HEDGE_PERCENT`
/// changes it; 0 turns hedging off).
pub const HEDGE_SHARE: f64 = 0.05;

/// A read is hedged no sooner than this many times the median latency...
pub(crate) const HEDGE_OVER_MEDIAN: u32 = 3;

/// ...and no sooner than this: a hedge is for a request held far longer than its peers, not for
/// the jitter of a busy machine.
pub(crate) const HEDGE_MIN: Duration = Duration::from_millis(50);

/// An endpoint whose [`HEDGE_QUANTILE`] is within this factor of its median is stable: its
/// answers come at one pace, and a read still unanswered well past it is held, not jittered...
pub(crate) const HEDGE_STABLE_SPREAD: f64 = 1.5;

/// ...so a read of a stable endpoint is hedged sooner: past this many times the median (and the
/// quantile)...
pub(crate) const HEDGE_OVER_MEDIAN_STABLE: f64 = 1.5;

/// ...and no sooner than this. At 20 ms a request, a read held far longer is hedged after about
/// 33 ms instead of 66, and its tile comes about two ticks (60 a second) sooner.
pub(crate) const HEDGE_MIN_STABLE: Duration = Duration::from_millis(25);

/// A read sent before its endpoint had measured [`HEDGE_SAMPLES`] answers asks this often
/// whether it may be hedged now: a cold start's first requests, sent before any answer, are
/// hedged once the answers to the others say when.
pub const HEDGE_RECHECK: Duration = Duration::from_millis(10);

/// Why an endpoint's limit is what it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reason {
    /// Nothing measured yet: the floor.
    Start,
    /// Rate x latency x headroom is below the floor.
    Floor,
    /// Rate x latency x headroom.
    Demand,
    /// Rate x latency x headroom is above the cap (`CLIPMAP_REMOTE_IN_FLIGHT`).
    Cap,
    /// Held down after the store answered 429, 503 or SlowDown.
    Throttled,
    /// Held down after failures worth retrying (timeouts, resets).
    Failures,
}

impl Reason {
    /// The reason as `STATS` and the logs name it.
    pub fn as_str(self) -> &'static str {
        match self {
            Reason::Start => "start",
            Reason::Floor => "floor",
            Reason::Demand => "rate x latency",
            Reason::Cap => "cap (CLIPMAP_REMOTE_IN_FLIGHT)",
            Reason::Throttled => "throttled (429/503/SlowDown)",
            Reason::Failures => "failures",
        }
    }
}

/// What one attempt's outcome tells the sizing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Answered, after this long.
    Answered(Duration),
    /// The store said it is overloaded.
    Throttled,
    /// Another failure worth retrying.
    Failed,
}

/// One endpoint's measured latency and rate, and the limit they give.
#[derive(Clone, Debug)]
pub struct Sizing {
    cap: usize,
    floor: usize,
    latency: Option<f64>,
    rate: Option<f64>,
    window_start: Option<Instant>,
    arrivals: u64,
    /// The AIMD ceiling: `cap` unless the store pushed back.
    ceiling: usize,
    /// Successes since the ceiling last grew.
    successes: usize,
    ceiling_reason: Reason,
    last_cut: Option<Instant>,
    limit: usize,
    reason: Reason,
    /// The latest answered latencies, oldest first.
    recent: VecDeque<Duration>,
}

impl Sizing {
    /// A sizing capped at `cap` (at least 1).
    pub fn new(cap: usize) -> Sizing {
        let cap = cap.max(1);
        let floor = FLOOR.min(cap);
        Sizing {
            cap,
            floor,
            latency: None,
            rate: None,
            window_start: None,
            arrivals: 0,
            ceiling: cap,
            successes: 0,
            ceiling_reason: Reason::Throttled,
            last_cut: None,
            limit: floor,
            reason: Reason::Start,
            recent: VecDeque::new(),
        }
    }

    /// Requests allowed in flight now.
    pub fn limit(&self) -> usize {
        self.limit
    }

    /// Why.
    pub fn reason(&self) -> Reason {
        self.reason
    }

    /// The smoothed latency of a successful request, once one was measured.
    pub fn latency(&self) -> Option<Duration> {
        self.latency.map(Duration::from_secs_f64)
    }

    /// The [`HEDGE_QUANTILE`] of the recent latencies, once [`HEDGE_SAMPLES`] were measured,
    /// and their median.
    pub fn quantiles(&self) -> Option<(Duration, Duration)> {
        if self.recent.len() < HEDGE_SAMPLES {
            return None;
        }
        let mut v: Vec<Duration> = self.recent.iter().copied().collect();
        v.sort_unstable();
        let at = ((v.len() as f64 * HEDGE_QUANTILE).ceil() as usize).clamp(1, v.len()) - 1;
        Some((v[at], v[v.len() / 2]))
    }

    /// How long a read waits unanswered before it is sent once more: the [`HEDGE_QUANTILE`]
    /// of the recent latencies, at least [`HEDGE_OVER_MEDIAN`] times their median and
    /// [`HEDGE_MIN`]; where the quantile is within [`HEDGE_STABLE_SPREAD`] of the median (a
    /// stable endpoint), at least [`HEDGE_OVER_MEDIAN_STABLE`] times the median and
    /// [`HEDGE_MIN_STABLE`]. None before [`HEDGE_SAMPLES`] were measured.
    pub(crate) fn hedge_after(&self) -> Option<Duration> {
        let (q, median) = self.quantiles()?;
        if q.as_secs_f64() <= median.as_secs_f64() * HEDGE_STABLE_SPREAD {
            return Some(q.max(median.mul_f64(HEDGE_OVER_MEDIAN_STABLE)).max(HEDGE_MIN_STABLE));
        }
        Some(q.max(median * HEDGE_OVER_MEDIAN).max(HEDGE_MIN))
    }

    /// The smoothed rate of reads arriving, per second, once a window was measured.
    pub fn rate(&self) -> Option<f64> {
        self.rate
    }

    /// A read arrived at `now`. True when the limit changed.
    pub fn arrive(&mut self, now: Instant) -> bool {
        self.arrivals += 1;
        let start = *self.window_start.get_or_insert(now);
        let dt = now.saturating_duration_since(start);
        if dt < WINDOW {
            return false;
        }
        // The arrival that closes a window opens the next one: it is counted in both, and the
        // rate is the arrivals after a window's first one over its span.
        let inst = (self.arrivals - 1) as f64 / dt.as_secs_f64();
        // A window that ends after a pause measures the pause too: the rate falls.
        self.rate = Some(match self.rate {
            None => inst,
            Some(r) => 0.5 * r + 0.5 * inst,
        });
        self.arrivals = 1;
        self.window_start = Some(now);
        self.resize()
    }

    /// An attempt ended at `now` with `outcome`. True when the limit changed.
    pub fn attempt(&mut self, now: Instant, outcome: Outcome) -> bool {
        match outcome {
            Outcome::Answered(d) => {
                if self.recent.len() == KEPT_LATENCIES {
                    self.recent.pop_front();
                }
                self.recent.push_back(d);
                let s = d.as_secs_f64();
                self.latency = Some(match self.latency {
                    None => s,
                    Some(l) => l + LATENCY_WEIGHT * (s - l),
                });
                if self.ceiling < self.cap {
                    self.successes += 1;
                    if self.successes >= self.ceiling {
                        self.ceiling += 1;
                        self.successes = 0;
                    }
                }
            }
            Outcome::Throttled | Outcome::Failed => {
                // One cut per latency: the failures of one burst of requests count once.
                let quiet = self.latency.map_or(Duration::from_millis(50), Duration::from_secs_f64);
                if self.last_cut.is_some_and(|t| now.saturating_duration_since(t) < quiet) {
                    return false;
                }
                self.last_cut = Some(now);
                let (factor, reason) = match outcome {
                    Outcome::Throttled => (0.5, Reason::Throttled),
                    _ => (0.75, Reason::Failures),
                };
                self.ceiling = ((self.ceiling.min(self.limit) as f64 * factor) as usize).max(1);
                self.successes = 0;
                self.ceiling_reason = reason;
            }
        }
        self.resize()
    }

    /// Sets the limit from what was measured; true when it changed.
    fn resize(&mut self) -> bool {
        let (want, reason) = match (self.rate, self.latency) {
            (Some(r), Some(l)) => {
                // (Less a hair, so that a product of exactly n is n, not n + 1.)
                let want = (r * l * HEADROOM - 1e-6).ceil();
                if want > self.cap as f64 {
                    (self.cap, Reason::Cap)
                } else if want < self.floor as f64 {
                    (self.floor, Reason::Floor)
                } else {
                    (want as usize, Reason::Demand)
                }
            }
            _ => (self.floor, Reason::Start),
        };
        let ceiling = self.ceiling.max(1);
        let (limit, reason) = if ceiling < want { (ceiling, self.ceiling_reason) } else { (want, reason) };
        let changed = limit != self.limit;
        self.limit = limit;
        self.reason = reason;
        changed
    }
}

/// True for a failure by which a store says it is overloaded: `429`, `503`, S3's `SlowDown`.
pub(crate) fn is_throttle(why: &str) -> bool {
    ["429", "503", "SlowDown", "Slow Down", "TooManyRequests", "Too Many Requests"].iter().any(|w| why.contains(w))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    /// Feeds `rate` arrivals a second for `secs` seconds, each answered after `latency`.
    fn drive(s: &mut Sizing, t0: Instant, rate: u64, latency: Duration, secs: u64) -> Instant {
        let step = Duration::from_secs(1) / rate as u32;
        let mut now = t0;
        for _ in 0..rate * secs {
            now += step;
            s.arrive(now);
            s.attempt(now, Outcome::Answered(latency));
        }
        now
    }

    #[test]
    fn the_limit_is_rate_times_latency_with_headroom_within_floor_and_cap() {
        let t0 = Instant::now();
        let mut s = Sizing::new(256);
        assert_eq!((s.limit(), s.reason()), (16, Reason::Start));
        // 1000 reads a second at 40 ms: 40 in flight, 80 with headroom.
        drive(&mut s, t0, 1000, 40 * MS, 2);
        assert_eq!((s.limit(), s.reason()), (80, Reason::Demand));
        // At 5 ms: 10 with headroom, below the floor.
        let mut s = Sizing::new(256);
        drive(&mut s, t0, 1000, 5 * MS, 2);
        assert_eq!((s.limit(), s.reason()), (16, Reason::Floor));
        // At 400 ms: 800, capped.
        let mut s = Sizing::new(256);
        drive(&mut s, t0, 1000, 400 * MS, 2);
        assert_eq!((s.limit(), s.reason()), (256, Reason::Cap));
        // A cap under the floor is the limit from the start.
        let s = Sizing::new(3);
        assert_eq!(s.limit(), 3);
    }

    #[test]
    fn a_throttled_store_halves_the_limit_once_a_burst_and_successes_give_it_back_slowly() {
        let t0 = Instant::now();
        let mut s = Sizing::new(256);
        let mut now = drive(&mut s, t0, 1000, 40 * MS, 2);
        assert_eq!(s.limit(), 80);
        // A burst of 503s within one latency: one cut.
        for _ in 0..20 {
            now += MS;
            s.attempt(now, Outcome::Throttled);
        }
        assert_eq!((s.limit(), s.reason()), (40, Reason::Throttled));
        // A latency later, another cut.
        now += 50 * MS;
        s.attempt(now, Outcome::Throttled);
        assert_eq!(s.limit(), 20);
        // A timeout takes a quarter off.
        now += 50 * MS;
        s.attempt(now, Outcome::Failed);
        assert_eq!((s.limit(), s.reason()), (15, Reason::Failures));
        // Additive increase: 15 successes give back one request, and 15 more none yet.
        for _ in 0..15 {
            now += MS;
            s.attempt(now, Outcome::Answered(40 * MS));
        }
        assert_eq!(s.limit(), 16);
        for _ in 0..15 {
            now += MS;
            s.attempt(now, Outcome::Answered(40 * MS));
        }
        assert_eq!(s.limit(), 16);
        // Long enough and the demand's figure is back.
        drive(&mut s, now, 1000, 40 * MS, 10);
        assert_eq!((s.limit(), s.reason()), (80, Reason::Demand));
    }

    #[test]
    fn the_rate_falls_after_a_pause_and_the_limit_with_it() {
        let t0 = Instant::now();
        let mut s = Sizing::new(256);
        let now = drive(&mut s, t0, 1000, 40 * MS, 2);
        assert_eq!(s.limit(), 80);
        // Ten reads a second for a few seconds: below the floor.
        drive(&mut s, now, 10, 40 * MS, 5);
        assert_eq!((s.limit(), s.reason()), (16, Reason::Floor));
    }

    #[test]
    fn a_read_is_hedged_past_the_95th_percentile_of_the_recent_latencies_once_twenty_were_measured() {
        let t0 = Instant::now();
        let mut s = Sizing::new(256);
        for i in 1..20u32 {
            s.attempt(t0, Outcome::Answered(MS * 10 * i));
            assert_eq!(s.hedge_after(), None, "{i} answers");
        }
        s.attempt(t0, Outcome::Answered(200 * MS));
        // 10..=200 ms: the 19th of 20 (the median, 110 ms, times 3 is more).
        assert_eq!(s.quantiles(), Some((190 * MS, 110 * MS)));
        assert_eq!(s.hedge_after(), Some(330 * MS));
        // Only the latest 200 count: 300 answers of 20 ms, then 100 ms ones.
        for _ in 0..300 {
            s.attempt(t0, Outcome::Answered(20 * MS));
        }
        assert_eq!(s.hedge_after(), Some(30 * MS), "stable: one and a half times the median");
        for _ in 0..10 {
            s.attempt(t0, Outcome::Answered(100 * MS));
        }
        assert_eq!(s.quantiles(), Some((20 * MS, 20 * MS)), "10 of 200 are the top 5 %, past the quantile");
        s.attempt(t0, Outcome::Answered(100 * MS));
        assert_eq!(s.hedge_after(), Some(100 * MS), "11 of 200 reach it");
        // Fast answers: never sooner than 25 ms when stable...
        for _ in 0..200 {
            s.attempt(t0, Outcome::Answered(MS));
        }
        assert_eq!(s.hedge_after(), Some(HEDGE_MIN_STABLE));
        // ...and 50 ms when they spread: 180 of 1 ms, 20 of 3 ms.
        for _ in 0..20 {
            s.attempt(t0, Outcome::Answered(3 * MS));
        }
        assert_eq!(s.quantiles(), Some((3 * MS, MS)));
        assert_eq!(s.hedge_after(), Some(HEDGE_MIN));
    }

    #[test]
    fn throttling_is_told_from_the_failure_text() {
        assert!(is_throttle("HTTP 503 Service Unavailable"));
        assert!(is_throttle("HTTP 429 Too Many Requests"));
        assert!(is_throttle("Generic S3 error: SlowDown: Please reduce your request rate"));
        assert!(!is_throttle("HTTP 500 Internal Server Error"));
        assert!(!is_throttle("connection reset"));
    }
}
