//! Reading byte ranges of remote objects: one `Endpoint` per scheme-host-port (or S3 bucket),
//! each with a bound on its requests in flight; adjacent ranges of one object that wait for the
//! same endpoint are read by one merged request; every request is retried with backoff and
//! jitter when its failure is worth retrying.
//!
//! The calling threads are the engine's blocking read threads: a read waits (bounded by the
//! timeouts and retries of the requests ahead of it) for a request slot of its endpoint, then
//! reads its own range together with the waiting ranges adjacent to it. A slow endpoint holds
//! only its own slots, so reads of other endpoints go on.

use super::flight::{self, Sizing};
use super::location::Location;
use super::options::RemoteOptions;
use crate::source::merge::{self, Merged, Piece, Rule};
use bytes::Bytes;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, OnceLock};
use std::time::{Duration, Instant};

/// One attempt's failure, as a backend classifies it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Failure {
    /// The object does not exist (404, 410, S3 NoSuchKey): not retried.
    NotFound,
    /// Access refused (401, 403): not retried.
    Denied(String),
    /// Worth retrying (5xx, 408, 429, a reset or timed-out connection, a truncated or
    /// mis-sized body), after `retry_after` when the server said so.
    Transient {
        /// What happened.
        why: String,
        /// The server's `Retry-After`, if any.
        retry_after: Option<Duration>,
        /// The attempt ran out of time.
        timed_out: bool,
    },
    /// Not worth retrying (another 4xx, a location that cannot be read).
    Fatal(String),
}

impl Failure {
    /// A transient failure without `Retry-After`.
    pub(crate) fn transient(why: impl Into<String>) -> Failure {
        Failure::Transient { why: why.into(), retry_after: None, timed_out: false }
    }
}

/// What one ranged read returned: bytes from the range's start, in the pieces they arrived in
/// (never copied into one buffer on the way). Fewer bytes than asked only when the object ends
/// there (`object_len` then says where); a body cut short is a [`Failure`].
#[derive(Clone, Debug)]
pub struct Got {
    /// The bytes.
    pub bytes: Segments,
    /// The object's length, when known.
    pub object_len: Option<u64>,
    /// The version of the object the bytes are of, when the store says: its `ETag`, else its
    /// `Last-Modified` (as `ETag "..."` or `Last-Modified ...`). Two answers with different
    /// validators are of two versions of the object and are never mixed.
    pub validator: Option<String>,
}

/// Bytes of one range and what the answer said of the object they are of.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Versioned {
    /// The bytes.
    pub bytes: Segments,
    /// The object's length, when the answer said.
    pub object_len: Option<u64>,
    /// The object's version ([`Got::validator`]), when the answer said.
    pub validator: Option<String>,
}

/// Bytes in pieces, in order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Segments(pub Vec<Bytes>);

impl From<Bytes> for Segments {
    fn from(b: Bytes) -> Self {
        Segments(vec![b])
    }
}

impl Segments {
    /// Bytes in all.
    pub fn len(&self) -> usize {
        self.0.iter().map(Bytes::len).sum()
    }

    /// True when there are no bytes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes `from..to` (within [`Segments::len`]), without copying.
    pub fn slice(&self, from: usize, to: usize) -> Segments {
        let mut out = Vec::new();
        let mut at = 0usize;
        for p in &self.0 {
            let (a, b) = (at, at + p.len());
            at = b;
            if b <= from || a >= to {
                continue;
            }
            out.push(p.slice(from.max(a) - a..to.min(b) - a));
        }
        Segments(out)
    }

    /// Copies every byte into `out`, which is [`Segments::len`] long.
    pub(crate) fn copy_to(&self, out: &mut [u8]) {
        let mut at = 0;
        for p in &self.0 {
            out[at..at + p.len()].copy_from_slice(p);
            at += p.len();
        }
    }

    /// The bytes in one piece (copied only when there are several).
    pub fn to_bytes(&self) -> Bytes {
        match self.0.as_slice() {
            [] => Bytes::new(),
            [one] => one.clone(),
            _ => {
                let mut v = Vec::with_capacity(self.len());
                for p in &self.0 {
                    v.extend_from_slice(p);
                }
                Bytes::from(v)
            }
        }
    }
}

/// Where the bytes of a streamed range go as they arrive ([`Fetcher::stream`]).
pub trait Sink: Send + Sync {
    /// What an answer says of the object (its length and version), before any of its bytes:
    /// `Err` refuses the answer, and the read fails with it (not retried).
    fn head(&self, object_len: Option<u64>, validator: Option<&str>) -> Result<(), String>;
    /// The range's next bytes, in order.
    fn bytes(&self, bytes: Bytes);
}

/// A protocol that reads remote objects: one attempt per call, blocking, bounded by the
/// options' timeouts.
pub trait Backend: Send + Sync {
    /// Bytes `[start, start + len)` of `loc`.
    fn get(&self, loc: &Location, start: u64, len: u64) -> Result<Got, Failure>;
    /// Bytes `[start, start + len)` of `loc`, handed to `sink` as they arrive: the answer's head
    /// first ([`Sink::head`]), then its bytes, checked as [`Backend::get`] checks them (a body
    /// cut short fails, after the bytes that did arrive). Fewer bytes than asked only where the
    /// object ends. This default reads the range whole, then hands it over.
    fn get_streamed(&self, loc: &Location, start: u64, len: u64, sink: &Arc<dyn Sink>) -> Result<(), Failure> {
        let got = self.get(loc, start, len)?;
        sink.head(got.object_len, got.validator.as_deref()).map_err(Failure::Fatal)?;
        for b in got.bytes.0 {
            sink.bytes(b);
        }
        Ok(())
    }
    /// Like [`Backend::get`], but when no answer came within `hedge.after` and the budget
    /// allows one more ([`Hedges::take`]), the same request is sent once more (a hedge) and the
    /// first successful answer is used, whole (never bytes of two answers, which may be of two
    /// versions of the object); the other request is cancelled. Returns the answer and whether
    /// a hedge was sent. This default never hedges.
    fn get_hedged(&self, loc: &Location, start: u64, len: u64, hedge: Hedge) -> Result<(Got, bool), Failure> {
        let _ = hedge;
        self.get(loc, start, len).map(|g| (g, false))
    }
    /// Answers so far that ignored a range (a whole object sent for a ranged GET, used after
    /// its checks): a server that makes every read fetch the whole object.
    fn ranges_ignored(&self) -> u64 {
        0
    }
    /// Answers so far by the HTTP version they came in (this default counts none: a backend
    /// whose client does not tell, such as S3's, which speaks HTTP/1.1).
    fn versions(&self) -> super::protocol::AnswerVersions {
        super::protocol::AnswerVersions::default()
    }
    /// The object's length (a HEAD request).
    fn head(&self, loc: &Location) -> Result<u64, Failure>;
    /// Stores `bytes` as the object `loc`.
    fn put(&self, loc: &Location, bytes: Bytes) -> Result<(), Failure>;
    /// The whole object `loc` with a plain GET (a tile of a tile service): `404`/`410` are
    /// [`Failure::NotFound`], a `204` an empty [`Object`], a body over `req.max_bytes` a fatal
    /// failure. This default refuses (a backend without whole-object reads).
    fn get_object(&self, loc: &Location, req: &ObjectRequest) -> Result<Object, Failure> {
        let _ = (loc, req);
        Err(Failure::Fatal("this store cannot read whole objects with a plain GET".into()))
    }
}

/// How to ask for a whole object ([`Backend::get_object`]).
#[derive(Clone, Debug, Default)]
pub struct ObjectRequest {
    /// Headers sent with the request (a User-Agent, an API key): never written to logs or errors.
    pub headers: Vec<(String, String)>,
    /// The most bytes the body may hold.
    pub max_bytes: u64,
}

/// A whole object and what its answer said of it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Object {
    /// The body (empty for a `204`).
    pub bytes: Bytes,
    /// The answer's `Content-Type`, if any.
    pub content_type: Option<String>,
}

/// Why a range could not be read, after retries.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ReadError {
    /// The object does not exist.
    #[error("{location}: not found")]
    NotFound {
        /// The object.
        location: String,
    },
    /// Access refused.
    #[error("{location}: access refused: {why}")]
    Denied {
        /// The object.
        location: String,
        /// The server's answer.
        why: String,
    },
    /// The object ends before the range does.
    #[error("{location}: the object ends {got} bytes into the range of {expected}")]
    Short {
        /// The object.
        location: String,
        /// Bytes of the range that exist.
        got: u64,
        /// Bytes asked for.
        expected: u64,
    },
    /// Every attempt failed (or the failure was not worth retrying).
    #[error("{location}: {why} (after {attempts} attempt{s})", s = if *attempts == 1 { "" } else { "s" })]
    Failed {
        /// The object.
        location: String,
        /// The last failure.
        why: String,
        /// Attempts made.
        attempts: u32,
        /// The last attempt ran out of time.
        timed_out: bool,
    },
}

/// Counters of remote reads since the source was opened.
#[derive(Debug, Default)]
pub struct Counters {
    /// Requests sent (retries included).
    pub requests: AtomicU64,
    /// Retries.
    pub retries: AtomicU64,
    /// Bytes received.
    pub bytes: AtomicU64,
    /// Ranges that failed after retries.
    pub failures: AtomicU64,
    /// Ranges served from the disk cache.
    pub cache_hits: AtomicU64,
    /// Most requests in flight at once to one endpoint.
    pub peak_in_flight: AtomicU64,
    /// Microseconds reads waited for a request slot of their endpoint, all reads together.
    pub slot_wait_us: AtomicU64,
    /// Microseconds of the attempts that were answered (sent to answered, body included).
    pub request_us: AtomicU64,
    /// Attempts answered (the count `request_us` is the sum over).
    pub answered: AtomicU64,
    /// Attempts the store answered with 429, 503 or SlowDown.
    pub throttled: AtomicU64,
}

/// The hedges of a fetcher and the requests they are a share of.
#[derive(Debug)]
pub struct Hedges {
    /// Requests sent (as [`Counters::requests`]).
    sent: AtomicU64,
    /// Hedges sent (each also counted in `sent` and in [`Counters::requests`]).
    hedged: AtomicU64,
    /// The most hedges, as a share of the requests sent; 0: none.
    share: f64,
}

impl Default for Hedges {
    /// Within [`flight::HEDGE_SHARE`] of the requests.
    fn default() -> Self {
        Hedges::within(flight::HEDGE_SHARE)
    }
}

impl Hedges {
    /// Hedges within `share` of the requests sent (0: none).
    pub fn within(share: f64) -> Hedges {
        Hedges { sent: AtomicU64::new(0), hedged: AtomicU64::new(0), share }
    }

    /// Whether one more hedge, with `hedged` sent so far and `sent` requests, keeps the hedges
    /// within their share of the requests (the hedge counted as a request too).
    fn allows(&self, hedged: u64, sent: u64) -> bool {
        (hedged + 1) as f64 <= self.share * (sent + 1) as f64
    }

    /// Whether hedging is on (a share above 0): only then is a read timed for a hedge. A read
    /// sent while the budget has no room waits for room as it waits for its time.
    pub fn on(&self) -> bool {
        self.share > 0.0
    }

    /// Whether a hedge could be taken now ([`Hedges::take`] without taking it).
    pub fn has_room(&self) -> bool {
        self.allows(self.hedged(), self.sent.load(Ordering::Relaxed))
    }

    /// Takes one hedge if it keeps the hedges within their share of the requests.
    pub fn take(&self) -> bool {
        let sent = self.sent.load(Ordering::Relaxed);
        let within = |h: u64| self.allows(h, sent).then_some(h + 1);
        let taken = self.hedged.fetch_update(Ordering::Relaxed, Ordering::Relaxed, within).is_ok();
        if taken {
            // A hedge is a request too.
            self.sent.fetch_add(1, Ordering::Relaxed);
        }
        taken
    }

    /// Hedges sent so far.
    pub fn hedged(&self) -> u64 {
        self.hedged.load(Ordering::Relaxed)
    }
}

/// When a read may be hedged ([`Backend::get_hedged`]).
#[derive(Clone)]
pub struct Hedge {
    /// How long its first request may go unanswered, as its endpoint's answers measure it when
    /// asked: `None` while too few were measured, and then asked again after
    /// [`flight::HEDGE_RECHECK`]. Asked while the request waits, not once when it is sent, so
    /// that a request sent before the first answers (a cold start's) is hedged too; and once it
    /// is time, the hedge waits for room in the budget the same way.
    pub after: Arc<dyn Fn() -> Option<Duration> + Send + Sync>,
    /// The budget a hedge is taken from.
    pub budget: Arc<Hedges>,
}

impl std::fmt::Debug for Hedge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Not the time itself: asking takes the endpoint's lock, which whoever prints may hold.
        f.debug_struct("Hedge").field("after", &"asked while the request waits").field("budget", &self.budget).finish()
    }
}

impl Hedge {
    /// How long to wait, `elapsed` after the request was sent, before asking again whether to
    /// hedge it: zero when it is time to hedge.
    pub fn wait(&self, elapsed: Duration) -> Duration {
        match (self.after)() {
            Some(after) => after.saturating_sub(elapsed),
            None => flight::HEDGE_RECHECK,
        }
    }
}

impl Counters {
    fn waited(&self, since: Instant) {
        self.slot_wait_us.fetch_add(since.elapsed().as_micros() as u64, Ordering::Relaxed);
    }
}

/// A range a reading thread waits for.
struct Req {
    object: String,
    loc: Location,
    start: u64,
    len: u64,
    result: OnceLock<Result<Versioned, ReadError>>,
}

struct EpState {
    in_flight: usize,
    waiting: Vec<Arc<Req>>,
    /// How many requests may be in flight ([`flight`]).
    sizing: Sizing,
}

impl EpState {
    /// A read arrived: counted in the rate; true when the limit grew.
    fn arrive(&mut self, key: &str) -> bool {
        let before = (self.sizing.limit(), self.sizing.reason());
        self.sizing.arrive(Instant::now()) && self.resized(key, before)
    }

    /// Logs a change of the limit's reason (one line a change, at info; a change of size alone
    /// at debug). True when the limit grew.
    fn resized(&self, key: &str, (was, was_reason): (usize, flight::Reason)) -> bool {
        let (limit, reason) = (self.sizing.limit(), self.sizing.reason());
        let latency_ms = self.sizing.latency().map_or(0.0, |l| l.as_secs_f64() * 1e3);
        let reads_per_s = self.sizing.rate().unwrap_or(0.0).round();
        if reason != was_reason {
            tracing::info!(
                endpoint = %key, limit, was, reason = reason.as_str(), was_reason = was_reason.as_str(),
                latency_ms, reads_per_s, "remote requests in flight: {limit} ({})", reason.as_str()
            );
        } else {
            tracing::debug!(endpoint = %key, limit, was, reason = reason.as_str(), latency_ms, reads_per_s, "remote requests in flight resized");
        }
        limit > was
    }

    fn has_slot(&self) -> bool {
        self.in_flight < self.sizing.limit()
    }
}

/// An endpoint's requests in flight and what sized them, as `STATS` reports them.
#[derive(Clone, Debug, PartialEq)]
pub struct EndpointFlight {
    /// The endpoint (`scheme://host:port`, `s3://bucket`).
    pub endpoint: String,
    /// Requests allowed in flight now.
    pub limit: usize,
    /// Why ([`flight::Reason::as_str`]).
    pub reason: &'static str,
    /// The smoothed latency of an answered request.
    pub latency: Option<Duration>,
    /// The smoothed rate of reads arriving, per second.
    pub rate: Option<f64>,
}

/// One endpoint: its slots and the ranges waiting for them.
struct Endpoint {
    /// Its key ([`Location::endpoint`]), for the log.
    key: String,
    state: Mutex<EpState>,
    wake: Condvar,
    /// No request is sent to the endpoint before this instant: its server answered `429` or
    /// `503` with a `Retry-After` (the rate limit is the host's, not one request's).
    paused_until: Mutex<Option<std::time::Instant>>,
}

impl Endpoint {
    fn new(key: &str, cap: usize) -> Endpoint {
        Endpoint {
            key: key.to_string(),
            state: Mutex::new(EpState { in_flight: 0, waiting: Vec::new(), sizing: Sizing::new(cap) }),
            wake: Condvar::new(),
            paused_until: Mutex::new(None),
        }
    }

    /// Tells the sizing how an attempt ended; wakes the waiting reads when the limit grew.
    fn attempted(&self, outcome: flight::Outcome) {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let before = (st.sizing.limit(), st.sizing.reason());
        if st.sizing.attempt(Instant::now(), outcome) && st.resized(&self.key, before) {
            drop(st);
            self.wake.notify_all();
        }
    }

    /// Sends nothing for `wait` from now (or longer, if already paused longer).
    fn pause(&self, wait: Duration) {
        let until = std::time::Instant::now() + wait;
        let mut p = self.paused_until.lock().unwrap_or_else(|e| e.into_inner());
        if p.is_none_or(|t| t < until) {
            *p = Some(until);
        }
    }

    /// Waits out a pause of the endpoint, if one is on.
    fn wait_pause(&self) {
        let until = *self.paused_until.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(wait) = until.and_then(|t| t.checked_duration_since(std::time::Instant::now())) {
            std::thread::sleep(wait);
        }
    }
}

/// Reads ranges through a backend per scheme, one `Endpoint` per endpoint.
pub struct Fetcher {
    opts: RemoteOptions,
    endpoints: Mutex<HashMap<String, Arc<Endpoint>>>,
    http: Arc<dyn Backend>,
    s3: Arc<dyn Backend>,
    /// The counters.
    pub counters: Counters,
    /// Ranges read by a request merged with another range: the waiting ranges this fetcher merges
    /// ([`merge::run`]) and the read-ahead requests it is told of (`RangeReader::stream`).
    pub merged: Merged,
    /// The ranges fetched so far, and those fetched twice.
    pub seen: super::seen::Seen,
    /// The hedges sent, within their share of the requests.
    pub hedges: Arc<Hedges>,
}

impl Fetcher {
    /// A fetcher over the two backends.
    pub fn new(opts: RemoteOptions, http: Arc<dyn Backend>, s3: Arc<dyn Backend>) -> Fetcher {
        let hedges = Arc::new(Hedges::within(f64::from(opts.hedge_percent) / 100.0));
        Fetcher {
            opts,
            endpoints: Mutex::new(HashMap::new()),
            http,
            s3,
            counters: Counters::default(),
            merged: Merged::default(),
            seen: super::seen::Seen::default(),
            hedges,
        }
    }

    /// Answers so far, of every backend, that ignored a range ([`Backend::ranges_ignored`]).
    pub fn ranges_ignored(&self) -> u64 {
        self.http.ranges_ignored() + self.s3.ranges_ignored()
    }

    /// Answers so far, of every backend, by HTTP version ([`Backend::versions`]).
    pub fn versions(&self) -> super::protocol::AnswerVersions {
        self.http.versions().plus(self.s3.versions())
    }

    /// The options.
    pub fn options(&self) -> &RemoteOptions {
        &self.opts
    }

    fn backend(&self, loc: &Location) -> &dyn Backend {
        match loc.scheme {
            super::location::Scheme::Http => self.http.as_ref(),
            super::location::Scheme::S3 => self.s3.as_ref(),
        }
    }

    fn endpoint(&self, key: &str) -> Arc<Endpoint> {
        let mut m = self.endpoints.lock().unwrap_or_else(|e| e.into_inner());
        Arc::clone(m.entry(key.to_string()).or_insert_with(|| Arc::new(Endpoint::new(key, self.opts.in_flight))))
    }

    /// Requests the endpoint `key` ([`Location::endpoint`]) may have in flight now: what its
    /// sizing says, or where a new one starts.
    pub fn in_flight_limit(&self, key: &str) -> usize {
        let m = self.endpoints.lock().unwrap_or_else(|e| e.into_inner());
        match m.get(key) {
            Some(ep) => ep.state.lock().unwrap_or_else(|e| e.into_inner()).sizing.limit(),
            None => Sizing::new(self.opts.in_flight).limit(),
        }
    }

    /// Each endpoint's requests in flight and what sized them, by endpoint.
    pub fn flight(&self) -> Vec<EndpointFlight> {
        let m = self.endpoints.lock().unwrap_or_else(|e| e.into_inner());
        let mut v: Vec<EndpointFlight> = m
            .iter()
            .map(|(k, ep)| {
                let st = ep.state.lock().unwrap_or_else(|e| e.into_inner());
                EndpointFlight {
                    endpoint: k.clone(),
                    limit: st.sizing.limit(),
                    reason: st.sizing.reason().as_str(),
                    latency: st.sizing.latency(),
                    rate: st.sizing.rate(),
                }
            })
            .collect();
        v.sort_by(|a, b| a.endpoint.cmp(&b.endpoint));
        v
    }

    /// Bytes `[start, start + len)` of `loc`: waits for a slot of its endpoint, merges with the
    /// adjacent waiting ranges of the same object, retries.
    pub fn read(&self, loc: &Location, start: u64, len: u64) -> Result<Segments, ReadError> {
        self.read_versioned(loc, start, len).map(|v| v.bytes)
    }

    /// Like [`Fetcher::read`], with the object's length and version as the answer gave them
    /// (the same for every range a merged request read).
    pub fn read_versioned(&self, loc: &Location, start: u64, len: u64) -> Result<Versioned, ReadError> {
        let ep = self.endpoint(&loc.endpoint);
        let me = Arc::new(Req { object: loc.to_string(), loc: loc.clone(), start, len, result: OnceLock::new() });
        let queued = Instant::now();
        let mut st = ep.state.lock().unwrap_or_else(|e| e.into_inner());
        if st.arrive(&ep.key) {
            ep.wake.notify_all();
        }
        st.waiting.push(Arc::clone(&me));
        loop {
            if me.result.get().is_some() {
                break;
            }
            if st.has_slot() {
                self.counters.waited(queued);
                let batch = take_batch(&mut st.waiting, &me, self.opts.merge_bytes);
                st.in_flight += 1;
                self.counters.peak_in_flight.fetch_max(st.in_flight as u64, Ordering::Relaxed);
                drop(st);
                self.run_batch(&batch);
                st = ep.state.lock().unwrap_or_else(|e| e.into_inner());
                st.in_flight -= 1;
                ep.wake.notify_all();
                break;
            }
            st = ep.wake.wait(st).unwrap_or_else(|e| e.into_inner());
        }
        drop(st);
        me.result.get().cloned().unwrap_or_else(|| {
            Err(ReadError::Failed {
                location: me.object.clone(),
                why: "no result".into(),
                attempts: 0,
                timed_out: false,
            })
        })
    }

    /// Bytes `[start, start + len)` of `loc`, handed to `sink` as they arrive, in order: waits
    /// for a slot of its endpoint (the range is never merged with others: the caller merged
    /// it), and retries, each retry asking only for the bytes that have not arrived yet, so that
    /// no byte reaches the sink twice. The bytes that arrived before a failure stay handed over.
    pub fn stream(&self, loc: &Location, start: u64, len: u64, sink: Arc<dyn Sink>) -> Result<(), ReadError> {
        let ep = self.endpoint(&loc.endpoint);
        {
            let queued = Instant::now();
            let mut st = ep.state.lock().unwrap_or_else(|e| e.into_inner());
            if st.arrive(&ep.key) {
                ep.wake.notify_all();
            }
            while !st.has_slot() {
                st = ep.wake.wait(st).unwrap_or_else(|e| e.into_inner());
            }
            self.counters.waited(queued);
            st.in_flight += 1;
            self.counters.peak_in_flight.fetch_max(st.in_flight as u64, Ordering::Relaxed);
        }
        let _slot = Slot(ep);
        let counted = Arc::new(Counted { inner: sink, got: AtomicU64::new(0) });
        let as_sink: Arc<dyn Sink> = counted.clone();
        let object = loc.to_string();
        let result = self.with_retries(loc, &object, |b| {
            let got = counted.got.load(Ordering::Relaxed);
            if got >= len {
                return Ok(());
            }
            b.get_streamed(loc, start + got, len - got, &as_sink)
        });
        let got = counted.got.load(Ordering::Relaxed);
        self.counters.bytes.fetch_add(got, Ordering::Relaxed);
        self.seen.fetched(&object, start, got);
        let result = match result {
            Ok(()) if got < len => Err(ReadError::Short { location: object, got, expected: len }),
            r => r,
        };
        if result.is_err() {
            self.counters.failures.fetch_add(1, Ordering::Relaxed);
        }
        result
    }

    /// The whole object `loc` ([`Backend::get_object`]): waits for a slot of its endpoint (the
    /// same bound on requests in flight as ranged reads), and retries transient failures,
    /// obeying `Retry-After`.
    pub fn object(&self, loc: &Location, req: &ObjectRequest) -> Result<Object, ReadError> {
        let ep = self.endpoint(&loc.endpoint);
        {
            let queued = Instant::now();
            let mut st = ep.state.lock().unwrap_or_else(|e| e.into_inner());
            if st.arrive(&ep.key) {
                ep.wake.notify_all();
            }
            while !st.has_slot() {
                st = ep.wake.wait(st).unwrap_or_else(|e| e.into_inner());
            }
            self.counters.waited(queued);
            st.in_flight += 1;
            self.counters.peak_in_flight.fetch_max(st.in_flight as u64, Ordering::Relaxed);
        }
        let _slot = Slot(ep);
        let result = self.with_retries(loc, &loc.to_string(), |b| b.get_object(loc, req));
        if matches!(result, Err(ReadError::Denied { .. } | ReadError::Failed { .. } | ReadError::Short { .. })) {
            self.counters.failures.fetch_add(1, Ordering::Relaxed);
        }
        result
    }

    /// Reads the merged range of `batch` (sorted, adjacent) and hands each range its bytes.
    fn run_batch(&self, batch: &[Arc<Req>]) {
        let first = &batch[0];
        let start = first.start;
        let end = batch.iter().map(|r| r.start + r.len).max().unwrap_or(start);
        self.merged.count(batch.len() as u64);
        let ep = self.endpoint(&first.loc.endpoint);
        let got = self.with_retries(&first.loc, &first.object, |b| {
            if !self.hedges.on() {
                return b.get(&first.loc, start, end - start);
            }
            let ep = Arc::clone(&ep);
            let after = move || ep.state.lock().unwrap_or_else(|e| e.into_inner()).sizing.hedge_after();
            let hedge = Hedge { after: Arc::new(after), budget: Arc::clone(&self.hedges) };
            b.get_hedged(&first.loc, start, end - start, hedge).map(|(got, hedged)| {
                if hedged {
                    self.counters.requests.fetch_add(1, Ordering::Relaxed);
                }
                got
            })
        });
        if let Ok(g) = &got {
            self.seen.fetched(&first.object, start, g.bytes.len() as u64);
        }
        for r in batch {
            let result = match &got {
                Ok(g) => {
                    let from = (r.start - start) as usize;
                    let to = from + r.len as usize;
                    if g.bytes.len() >= to {
                        Ok(Versioned {
                            bytes: g.bytes.slice(from, to),
                            object_len: g.object_len,
                            validator: g.validator.clone(),
                        })
                    } else {
                        Err(ReadError::Short {
                            location: r.object.clone(),
                            got: (g.bytes.len().saturating_sub(from)) as u64,
                            expected: r.len,
                        })
                    }
                }
                Err(e) => Err(e.clone()),
            };
            if result.is_err() {
                self.counters.failures.fetch_add(1, Ordering::Relaxed);
            }
            let _ = r.result.set(result);
        }
    }

    /// Runs `attempt` until it succeeds, fails for good or runs out of retries.
    ///
    /// The retries are `backon`'s blocking retry: it is maintained, small (one dependency,
    /// `fastrand`, for the jitter), runs on the calling thread without a runtime, and takes the
    /// three things this needs as plain closures: which failures to retry (`when`: only
    /// [`Failure::Transient`]), the backoff (an exponential one with jitter,
    /// [`RemoteOptions::backoff_policy`]), and a hook before each wait (`notify`), where the retry
    /// is counted and the server's `Retry-After` is obeyed. object_store's own retry
    /// configuration would serve the S3 backend only, and only for requests it sends itself.
    pub(crate) fn with_retries<T>(
        &self,
        loc: &Location,
        object: &str,
        attempt: impl Fn(&dyn Backend) -> Result<T, Failure>,
    ) -> Result<T, ReadError>
    where
        T: GotBytes,
    {
        use backon::BlockingRetryable;
        // The name as errors and logs show it (a URL's password and signatures replaced).
        let object = &*crate::place::redacted(object);
        let backend = self.backend(loc);
        let ep = self.endpoint(&loc.endpoint);
        let attempts = std::cell::Cell::new(0u32);
        let result = (|| {
            // A `Retry-After` another request of this endpoint was told is waited out first.
            ep.wait_pause();
            attempts.set(attempts.get() + 1);
            self.counters.requests.fetch_add(1, Ordering::Relaxed);
            self.hedges.sent.fetch_add(1, Ordering::Relaxed);
            let sent = Instant::now();
            let r = attempt(backend);
            match &r {
                Ok(_) => {
                    let took = sent.elapsed();
                    self.counters.request_us.fetch_add(took.as_micros() as u64, Ordering::Relaxed);
                    self.counters.answered.fetch_add(1, Ordering::Relaxed);
                    ep.attempted(flight::Outcome::Answered(took));
                }
                Err(Failure::Transient { why, .. }) if flight::is_throttle(why) => {
                    self.counters.throttled.fetch_add(1, Ordering::Relaxed);
                    ep.attempted(flight::Outcome::Throttled);
                }
                Err(Failure::Transient { .. }) => ep.attempted(flight::Outcome::Failed),
                Err(_) => {}
            }
            r
        })
        .retry(self.opts.backoff_policy())
        .when(|f| matches!(f, Failure::Transient { .. }))
        .notify(|f, backoff| {
            let Failure::Transient { why, retry_after, .. } = f else { return };
            // `backon` sleeps the backoff next; a longer `Retry-After` (bounded) is slept here.
            let wait = self.opts.wait_for(backoff, *retry_after);
            if retry_after.is_some() {
                // The server's rate limit holds for every request to it, not only this one.
                ep.pause(wait);
            }
            self.counters.retries.fetch_add(1, Ordering::Relaxed);
            tracing::debug!(location = %object, attempt = attempts.get(), ?wait, "remote read failed ({why}); retrying");
            if wait > backoff {
                std::thread::sleep(wait - backoff);
            }
        })
        .call();
        let n = attempts.get();
        match result {
            Ok(v) => {
                self.counters.bytes.fetch_add(v.byte_count(), Ordering::Relaxed);
                Ok(v)
            }
            Err(Failure::NotFound) => Err(ReadError::NotFound { location: object.to_string() }),
            Err(Failure::Denied(why)) => Err(ReadError::Denied { location: object.to_string(), why }),
            Err(Failure::Fatal(why)) => {
                Err(ReadError::Failed { location: object.to_string(), why, attempts: n, timed_out: false })
            }
            Err(Failure::Transient { why, timed_out, .. }) => {
                Err(ReadError::Failed { location: object.to_string(), why, attempts: n, timed_out })
            }
        }
    }
}

/// A sink that counts the bytes handed to it (where a retry resumes).
struct Counted {
    inner: Arc<dyn Sink>,
    got: AtomicU64,
}

impl Sink for Counted {
    fn head(&self, object_len: Option<u64>, validator: Option<&str>) -> Result<(), String> {
        self.inner.head(object_len, validator)
    }

    fn bytes(&self, bytes: Bytes) {
        self.got.fetch_add(bytes.len() as u64, Ordering::Relaxed);
        self.inner.bytes(bytes);
    }
}

/// A request slot of an endpoint, given back when dropped.
struct Slot(Arc<Endpoint>);

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.state.lock().unwrap_or_else(|e| e.into_inner()).in_flight -= 1;
        self.0.wake.notify_all();
    }
}

/// Results whose bytes are counted.
pub(crate) trait GotBytes {
    /// Bytes received.
    fn byte_count(&self) -> u64;
}

impl GotBytes for Got {
    fn byte_count(&self) -> u64 {
        self.bytes.len() as u64
    }
}

impl GotBytes for Object {
    fn byte_count(&self) -> u64 {
        self.bytes.len() as u64
    }
}

impl GotBytes for u64 {
    fn byte_count(&self) -> u64 {
        0
    }
}

impl GotBytes for () {
    fn byte_count(&self) -> u64 {
        0
    }
}

/// Takes `me` and the waiting ranges of the same object adjacent to it (a contiguous run, at
/// most `merge_bytes` in all unless `me` alone is larger) out of `waiting`, sorted by start.
fn take_batch(waiting: &mut Vec<Arc<Req>>, me: &Arc<Req>, merge_bytes: u64) -> Vec<Arc<Req>> {
    let mut same: Vec<Arc<Req>> = waiting.iter().filter(|r| r.object == me.object).cloned().collect();
    same.sort_by_key(|r| r.start);
    let at = same.iter().position(|r| Arc::ptr_eq(r, me)).unwrap_or(0);
    let ranges: Vec<Piece<usize>> =
        same.iter().enumerate().map(|(key, r)| Piece { key, start: r.start, len: r.len }).collect();
    let (lo, hi) = merge::run(&ranges, at, Rule::touching(merge_bytes));
    let batch: Vec<Arc<Req>> = same[lo..=hi].to_vec();
    waiting.retain(|r| !batch.iter().any(|b| Arc::ptr_eq(b, r)));
    batch
}

#[cfg(test)]
mod tests;
