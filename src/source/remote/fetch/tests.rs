use super::*;
use std::sync::atomic::AtomicUsize;

/// A backend over one in-memory object per name, answering each get after `delay` and
/// failing the first `fail_first` attempts with 503.
struct Mem {
    objects: HashMap<String, Vec<u8>>,
    delay: Duration,
    fail_first: AtomicUsize,
    gets: Mutex<Vec<(u64, u64)>>,
    /// When each get was answered.
    at: Mutex<Vec<std::time::Instant>>,
    concurrent: AtomicUsize,
    peak: AtomicUsize,
    /// While true, every get waits (so that a test can line ranges up behind it).
    hold: Mutex<bool>,
    /// The `Retry-After` of each failure.
    retry_after: Mutex<Duration>,
    release: Condvar,
}

impl Backend for Mem {
    fn get(&self, loc: &Location, start: u64, len: u64) -> Result<Got, Failure> {
        let now = self.concurrent.fetch_add(1, Ordering::SeqCst) + 1;
        self.peak.fetch_max(now, Ordering::SeqCst);
        let mut held = self.hold.lock().unwrap();
        while *held {
            held = self.release.wait(held).unwrap();
        }
        drop(held);
        std::thread::sleep(self.delay);
        self.concurrent.fetch_sub(1, Ordering::SeqCst);
        self.gets.lock().unwrap().push((start, len));
        self.at.lock().unwrap().push(std::time::Instant::now());
        if self.fail_first.load(Ordering::SeqCst) > 0 {
            self.fail_first.fetch_sub(1, Ordering::SeqCst);
            return Err(Failure::Transient {
                why: "503".into(),
                retry_after: Some(*self.retry_after.lock().unwrap()),
                timed_out: false,
            });
        }
        let o = self.objects.get(&loc.target).ok_or(Failure::NotFound)?;
        let s = (start as usize).min(o.len());
        let e = ((start + len) as usize).min(o.len());
        // In pieces of 100 bytes, as a body arrives in chunks.
        let parts = o[s..e].chunks(100).map(Bytes::copy_from_slice).collect();
        Ok(Got { bytes: Segments(parts), object_len: Some(o.len() as u64), validator: None })
    }
    fn head(&self, loc: &Location) -> Result<u64, Failure> {
        self.objects.get(&loc.target).map(|o| o.len() as u64).ok_or(Failure::NotFound)
    }
    fn put(&self, _: &Location, _: Bytes) -> Result<(), Failure> {
        Err(Failure::Fatal("read-only".into()))
    }
    fn get_object(&self, loc: &Location, _: &ObjectRequest) -> Result<Object, Failure> {
        let got = self.get(loc, 0, 1 << 20)?;
        Ok(Object { bytes: got.bytes.to_bytes(), content_type: None })
    }
}

fn fetcher(mem: Arc<Mem>, opts: RemoteOptions) -> Fetcher {
    Fetcher::new(opts, mem.clone(), mem)
}

fn mem(delay_ms: u64, fail_first: usize) -> Arc<Mem> {
    let object: Vec<u8> = (0..4096u32).map(|i| (i * 7 % 251) as u8).collect();
    Arc::new(Mem {
        objects: [("http://h:1/o".to_string(), object)].into_iter().collect(),
        delay: Duration::from_millis(delay_ms),
        fail_first: AtomicUsize::new(fail_first),
        gets: Mutex::new(Vec::new()),
        at: Mutex::new(Vec::new()),
        concurrent: AtomicUsize::new(0),
        peak: AtomicUsize::new(0),
        hold: Mutex::new(false),
        release: Condvar::new(),
        retry_after: Mutex::new(Duration::from_millis(1)),
    })
}

fn expected(start: u64, len: u64) -> Vec<u8> {
    (start as u32..(start + len) as u32).map(|i| (i * 7 % 251) as u8).collect()
}

/// A backend whose streamed answers are cut half way through their body for the first
/// `cuts` attempts, and whose object's version is `v2` from attempt `new_version_at` on.
struct Cutting {
    object: Vec<u8>,
    cuts: AtomicUsize,
    new_version_at: usize,
    attempts: Mutex<Vec<(u64, u64)>>,
}

impl Backend for Cutting {
    fn get(&self, _: &Location, _: u64, _: u64) -> Result<Got, Failure> {
        Err(Failure::Fatal("streamed only".into()))
    }
    fn get_streamed(&self, _: &Location, start: u64, len: u64, sink: &Arc<dyn Sink>) -> Result<(), Failure> {
        let n = {
            let mut a = self.attempts.lock().unwrap();
            a.push((start, len));
            a.len()
        };
        let version = if n >= self.new_version_at { "ETag \"v2\"" } else { "ETag \"v1\"" };
        sink.head(Some(self.object.len() as u64), Some(version)).map_err(Failure::Fatal)?;
        let body = &self.object[start as usize..((start + len) as usize).min(self.object.len())];
        let cut = self.cuts.load(Ordering::SeqCst) > 0;
        let upto = if cut { body.len() / 2 } else { body.len() };
        for piece in body[..upto].chunks(300) {
            sink.bytes(Bytes::copy_from_slice(piece));
        }
        if cut {
            self.cuts.fetch_sub(1, Ordering::SeqCst);
            return Err(Failure::transient(format!("the body was cut after {upto} bytes")));
        }
        Ok(())
    }
    fn head(&self, _: &Location) -> Result<u64, Failure> {
        Ok(self.object.len() as u64)
    }
    fn put(&self, _: &Location, _: Bytes) -> Result<(), Failure> {
        Err(Failure::Fatal("read-only".into()))
    }
}

/// Keeps what it is handed; refuses any version but `v1`.
#[derive(Default)]
struct Kept(Mutex<Vec<u8>>);

impl Sink for Kept {
    fn head(&self, _: Option<u64>, validator: Option<&str>) -> Result<(), String> {
        match validator {
            Some("ETag \"v1\"") => Ok(()),
            v => Err(format!("another version: {v:?}")),
        }
    }
    fn bytes(&self, bytes: Bytes) {
        self.0.lock().unwrap().extend_from_slice(&bytes);
    }
}

/// A [`Cutting`] backend, a fetcher over it (1 ms backoffs) and the object's location.
fn cutting(cuts: usize, new_version_at: usize) -> (Arc<Cutting>, Fetcher, Location) {
    let backend = Arc::new(Cutting {
        object: (0..4096u32).map(|i| (i * 7 % 251) as u8).collect(),
        cuts: AtomicUsize::new(cuts),
        new_version_at,
        attempts: Mutex::new(Vec::new()),
    });
    let opts = RemoteOptions { backoff: Duration::from_millis(1), ..Default::default() };
    let f = Fetcher::new(opts, backend.clone(), backend.clone());
    (backend, f, Location::parse("http://h:1/o").unwrap())
}

#[test]
fn a_streamed_range_cut_short_resumes_where_it_was_cut_and_hands_each_byte_over_once() {
    let (backend, f, loc) = cutting(2, usize::MAX);
    let kept = Arc::new(Kept::default());
    f.stream(&loc, 50, 4000, kept.clone()).unwrap();
    assert_eq!(*kept.0.lock().unwrap(), expected(50, 4000), "every byte once, in order");
    // Each retry asks only for what had not arrived.
    assert_eq!(*backend.attempts.lock().unwrap(), vec![(50, 4000), (2050, 2000), (3050, 1000)]);
    let c = &f.counters;
    assert_eq!((c.requests.load(Ordering::SeqCst), c.retries.load(Ordering::SeqCst)), (3, 2));
    assert_eq!(c.bytes.load(Ordering::SeqCst), 4000);
}

#[test]
fn a_streamed_range_whose_object_changed_on_a_retry_stops_with_the_bytes_of_the_first_version() {
    let (backend, f, loc) = cutting(1, 2);
    let kept = Arc::new(Kept::default());
    let e = f.stream(&loc, 0, 4000, kept.clone()).unwrap_err();
    assert!(e.to_string().contains("another version"), "{e}");
    // The refusal is not retried; the bytes of version 1 that arrived stay, none of version 2.
    assert_eq!(backend.attempts.lock().unwrap().len(), 2);
    assert_eq!(*kept.0.lock().unwrap(), expected(0, 2000));
    // Past the object's end: short, after the bytes that exist.
    let (_, f, _) = cutting(0, usize::MAX);
    let kept = Arc::new(Kept::default());
    let e = f.stream(&loc, 4000, 200, kept.clone()).unwrap_err();
    assert!(matches!(e, ReadError::Short { got: 96, expected: 200, .. }), "{e:?}");
    assert_eq!(*kept.0.lock().unwrap(), expected(4000, 96));
}

#[test]
fn ranges_waiting_together_are_merged_and_each_gets_its_own_bytes() {
    let m = mem(0, 0);
    *m.hold.lock().unwrap() = true;
    let f = Arc::new(fetcher(m.clone(), RemoteOptions { in_flight: 1, ..Default::default() }));
    let loc = Location::parse("http://h:1/o").unwrap();
    let spawn = |start: u64| {
        let (f, loc) = (f.clone(), loc.clone());
        std::thread::spawn(move || (start, f.read(&loc, start, 256).unwrap()))
    };
    // One read holds the only slot while eight adjacent ranges queue behind it.
    let mut threads = vec![spawn(3000)];
    while m.concurrent.load(Ordering::SeqCst) == 0 {
        std::thread::yield_now();
    }
    threads.extend((0..8u64).map(|i| spawn(i * 256)));
    let ep = f.endpoint(&loc.endpoint);
    while ep.state.lock().unwrap().waiting.len() < 8 {
        std::thread::yield_now();
    }
    *m.hold.lock().unwrap() = false;
    m.release.notify_all();
    for t in threads {
        let (start, got) = t.join().unwrap();
        assert_eq!(got.to_bytes().as_ref(), expected(start, 256).as_slice(), "range at {start}");
    }
    let gets = m.gets.lock().unwrap().clone();
    assert_eq!(gets, vec![(3000, 256), (0, 2048)], "the eight adjacent waiting ranges share one request");
    assert_eq!(f.merged.get(), 8);
    assert_eq!(m.peak.load(Ordering::SeqCst), 1, "one request in flight at most");
}

#[test]
fn the_bound_on_requests_in_flight_holds_per_endpoint() {
    let m = mem(20, 0);
    let f = Arc::new(fetcher(m.clone(), RemoteOptions { in_flight: 3, merge_bytes: 0, ..Default::default() }));
    let loc = Location::parse("http://h:1/o").unwrap();
    let threads: Vec<_> = (0..12u64)
        .map(|i| {
            let (f, loc) = (f.clone(), loc.clone());
            std::thread::spawn(move || f.read(&loc, i * 300, 100).unwrap())
        })
        .collect();
    for t in threads {
        t.join().unwrap();
    }
    assert!(m.peak.load(Ordering::SeqCst) <= 3, "peak {}", m.peak.load(Ordering::SeqCst));
    assert_eq!(m.gets.lock().unwrap().len(), 12, "ranges that are not adjacent are not merged");
}

#[test]
fn transient_failures_are_retried_and_not_found_is_not() {
    let m = mem(0, 2);
    let f = fetcher(m.clone(), RemoteOptions { backoff: Duration::from_millis(1), ..Default::default() });
    let loc = Location::parse("http://h:1/o").unwrap();
    assert_eq!(f.read(&loc, 10, 20).unwrap().to_bytes().as_ref(), expected(10, 20).as_slice());
    assert_eq!(f.counters.retries.load(Ordering::Relaxed), 2);
    let missing = Location::parse("http://h:1/nothing").unwrap();
    assert!(matches!(f.read(&missing, 0, 1), Err(ReadError::NotFound { .. })));
    assert_eq!(f.counters.retries.load(Ordering::Relaxed), 2, "a 404 is final");
    let m = mem(0, 100);
    let f = fetcher(m.clone(), RemoteOptions { retries: 3, backoff: Duration::from_millis(1), ..Default::default() });
    match f.read(&loc, 0, 1) {
        Err(ReadError::Failed { attempts, .. }) => assert_eq!(attempts, 4),
        other => panic!("{other:?}"),
    }
}

#[test]
fn retry_after_is_waited_for_up_to_the_longest_backoff() {
    let loc = Location::parse("http://h:1/o").unwrap();
    let quick = RemoteOptions { backoff: Duration::from_millis(1), ..Default::default() };
    // Asked to wait 300 ms: the retry comes no sooner.
    let m = mem(0, 1);
    *m.retry_after.lock().unwrap() = Duration::from_millis(300);
    let f = fetcher(m.clone(), RemoteOptions { backoff_max: Duration::from_secs(5), ..quick.clone() });
    let t = std::time::Instant::now();
    assert_eq!(f.read(&loc, 0, 10).unwrap().len(), 10);
    assert!(t.elapsed() >= Duration::from_millis(300), "{:?}", t.elapsed());
    assert_eq!(f.counters.retries.load(Ordering::Relaxed), 1);
    // Asked to wait a minute: obeyed only up to the longest backoff.
    let m = mem(0, 1);
    *m.retry_after.lock().unwrap() = Duration::from_secs(60);
    let f = fetcher(m.clone(), RemoteOptions { backoff_max: Duration::from_millis(20), ..quick });
    let t = std::time::Instant::now();
    assert_eq!(f.read(&loc, 0, 10).unwrap().len(), 10);
    assert!(t.elapsed() >= Duration::from_millis(20) && t.elapsed() < Duration::from_secs(30), "{:?}", t.elapsed());
    assert_eq!(m.gets.lock().unwrap().len(), 2);
}

#[test]
fn a_retry_after_holds_back_every_request_to_the_endpoint() {
    let loc = Location::parse("http://h:1/o").unwrap();
    let m = mem(0, 1);
    *m.retry_after.lock().unwrap() = Duration::from_millis(300);
    let opts = RemoteOptions {
        backoff: Duration::from_millis(1),
        backoff_max: Duration::from_secs(5),
        merge_bytes: 0,
        ..Default::default()
    };
    let f = Arc::new(fetcher(m.clone(), opts));
    let first = {
        let (f, loc) = (f.clone(), loc.clone());
        std::thread::spawn(move || f.read(&loc, 0, 10).map(|s| s.len()))
    };
    // Once the first read was told to wait, another read of the endpoint waits too.
    while f.counters.retries.load(Ordering::SeqCst) == 0 {
        std::thread::yield_now();
    }
    assert_eq!(f.read(&loc, 1000, 10).unwrap().len(), 10);
    assert_eq!(first.join().unwrap().unwrap(), 10);
    let (gets, at) = (m.gets.lock().unwrap().clone(), m.at.lock().unwrap().clone());
    assert_eq!(gets.len(), 3, "{gets:?}");
    let other = gets.iter().position(|g| g.0 == 1000).unwrap();
    assert!(at[other].duration_since(at[0]) >= Duration::from_millis(300), "{:?}", at[other].duration_since(at[0]));
}

#[test]
fn whole_objects_wait_for_retry_after_and_not_found_is_not_retried() {
    let loc = Location::parse("http://h:1/o").unwrap();
    let m = mem(0, 1);
    *m.retry_after.lock().unwrap() = Duration::from_millis(300);
    let opts =
        RemoteOptions { backoff: Duration::from_millis(1), backoff_max: Duration::from_secs(5), ..Default::default() };
    let f = fetcher(m.clone(), opts);
    let t = std::time::Instant::now();
    assert_eq!(f.object(&loc, &ObjectRequest::default()).unwrap().bytes.len(), 4096);
    assert!(t.elapsed() >= Duration::from_millis(300), "{:?}", t.elapsed());
    assert_eq!(f.counters.retries.load(Ordering::Relaxed), 1);
    let gone = Location::parse("http://h:1/gone").unwrap();
    assert!(matches!(f.object(&gone, &ObjectRequest::default()), Err(ReadError::NotFound { .. })));
    assert_eq!(f.counters.retries.load(Ordering::Relaxed), 1);
}

#[test]
fn segments_slice_across_pieces_without_losing_a_byte() {
    let s = Segments((0..5u8).map(|i| Bytes::from(vec![i; 3])).collect());
    assert_eq!(s.len(), 15);
    let mid = s.slice(2, 11);
    assert_eq!(mid.to_bytes().as_ref(), &[0, 1, 1, 1, 2, 2, 2, 3, 3]);
    let mut out = [9u8; 9];
    mid.copy_to(&mut out);
    assert_eq!(out, [0, 1, 1, 1, 2, 2, 2, 3, 3]);
    assert!(s.slice(15, 15).is_empty());
}

#[test]
fn hedges_stay_within_five_percent_of_the_requests_sent() {
    let h = Hedges::default();
    assert!(!h.take(), "no request sent, no hedge");
    h.sent.store(99, Ordering::Relaxed);
    // 99 requests: one hedge makes 5 of 100 requests... up to the share, then none.
    let taken = (0..10).filter(|_| h.take()).count();
    assert_eq!((taken, h.hedged()), (5, 5));
    assert!(h.hedged() as f64 <= flight::HEDGE_SHARE * h.sent.load(Ordering::Relaxed) as f64);
    // Twenty more requests: one more hedge.
    h.sent.fetch_add(20, Ordering::Relaxed);
    assert_eq!((0..10).filter(|_| h.take()).count(), 1);
}

#[test]
fn has_room_says_what_take_would_do_and_takes_nothing() {
    let h = Hedges::default();
    assert!(!h.has_room(), "no request sent, no room");
    h.sent.store(39, Ordering::Relaxed);
    // 39 requests: two hedges fit in 5 % of 41 requests, a third does not (3 > 0.05 x 42).
    for n in 0..2 {
        assert!(h.has_room(), "hedge {n}");
        assert!(h.has_room(), "asking again takes nothing");
        assert_eq!(h.hedged(), n);
        assert!(h.take());
    }
    assert!(!h.has_room());
    assert!(!h.take(), "no room, no hedge");
    assert_eq!(h.hedged(), 2);
    // The predicate agrees with take across many counts.
    for sent in 0..200 {
        let h = Hedges::default();
        h.sent.store(sent, Ordering::Relaxed);
        let room = h.has_room();
        assert_eq!(room, h.take(), "{sent} requests sent");
    }
    let none = Hedges::within(0.0);
    none.sent.store(1_000_000, Ordering::Relaxed);
    assert!(!none.has_room(), "hedging off");
    assert!(!none.on() && Hedges::default().on(), "only a share above 0 times reads for a hedge");
}

#[test]
fn a_hedge_share_of_zero_percent_hedges_nothing() {
    let opts = RemoteOptions::from_vars(|k| (k == "CLIPMAP_REMOTE_HEDGE_PERCENT").then(|| "0".into())).unwrap();
    assert_eq!(opts.hedge_percent, 0);
    let h = Hedges::within(f64::from(opts.hedge_percent) / 100.0);
    h.sent.store(1_000_000, Ordering::Relaxed);
    assert!(!h.take(), "hedging off");
    let e = RemoteOptions::from_vars(|k| (k == "CLIPMAP_REMOTE_HEDGE_PERCENT").then(|| "51".into())).unwrap_err();
    assert_eq!(e.var, "CLIPMAP_REMOTE_HEDGE_PERCENT");
}

#[test]
fn a_range_past_the_end_of_the_object_is_short() {
    let f = fetcher(mem(0, 0), RemoteOptions::default());
    let loc = Location::parse("http://h:1/o").unwrap();
    match f.read(&loc, 4000, 256) {
        Err(ReadError::Short { got, expected, .. }) => assert_eq!((got, expected), (96, 256)),
        other => panic!("{other:?}"),
    }
}
