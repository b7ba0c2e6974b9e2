//! A renderer's requests through the request mapping: taken by the writer, dead or stalled
//! renderers holding its lock, a truncated mapping, torn copies.

use super::*;

#[test]
fn a_renderer_request_reaches_the_writer_and_a_dead_renderer_does_not_silence_the_others() {
    use std::os::unix::fs::FileExt;
    let dir = tempfile::tempdir().unwrap();
    let (_map, w) = hash_service(dir.path(), "req", 1024, 64, 32);
    assert_eq!(w.request(), None);
    let c = Client::attach(dir.path(), "req").unwrap();
    assert!(c.request_centre([123, -45], [1.5, 0.0]));
    assert!(c.request_centre([124, -46], [1.5, 0.0]));
    let r = w.request().unwrap();
    assert_eq!((r.centre, r.velocity, r.count), ([124, -46], [1.5, 0.0], 2));
    // A renderer killed between taking the lock (odd, with its pid) and releasing it.
    let f = std::fs::OpenOptions::new().write(true).open(w.request_path()).unwrap();
    let held = layout::request_lock::locked(3 << 32, dead_pid());
    f.write_all_at(&held.to_le_bytes(), layout::request::SEQ as u64).unwrap();
    assert_eq!(w.request(), None, "a half-written request is never taken");
    assert!(c.request_centre([7, 8], [0.0, 0.0]));
    let r = w.request().unwrap();
    assert_eq!(r.centre, [7, 8]);
    let seq = c.raw_request().unwrap().load(layout::request::SEQ, Ordering::Acquire);
    assert_eq!(seq, 5 << 32, "taken over from epoch 3 to 4, then the request: epoch 5; never backwards");
    w.close();
    assert!(c.closed());
}

#[test]
fn a_dead_renderers_lock_was_taken_over_through_an_even_word_exposing_its_partial_fields() {
    use layout::request_lock::locked;
    use std::os::unix::fs::FileExt;
    let dir = tempfile::tempdir().unwrap();
    let (_map, w) = hash_service(dir.path(), "dead", 1024, 64, 32);
    let c = Client::attach(dir.path(), "dead").unwrap();
    assert!(c.request_centre([1, 2], [0.0, 0.0]));
    // A renderer killed half way through its stores: the word odd at epoch 7 with its pid, the
    // centre's s stored, its t and the count not.
    let f = std::fs::OpenOptions::new().write(true).open(w.request_path()).unwrap();
    f.write_all_at(&locked(7 << 32, dead_pid()).to_le_bytes(), layout::request::SEQ as u64).unwrap();
    f.write_all_at(&999u64.to_le_bytes(), layout::request::CENTRE_S as u64).unwrap();
    super::client::LOCK_WORDS.with(|w| w.borrow_mut().clear());
    assert!(c.request_centre([5, 6], [0.0, 0.0]));
    let stored = super::client::LOCK_WORDS.with(|w| w.borrow().clone());
    assert_eq!(
        stored,
        [locked(8 << 32, std::process::id()), 9 << 32],
        "from the dead renderer's odd word straight to our own at the next epoch, then released: never an even word over its partial fields"
    );
    let r = w.request().unwrap();
    assert_eq!((r.centre, r.count), ([5, 6], 2));
}

/// The pid of a process that has exited (and been reaped): no live process has it for a while.
fn dead_pid() -> u32 {
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

#[test]
fn a_stalled_renderer_holding_the_request_lock_is_never_overruled_so_no_request_is_a_mix() {
    let dir = tempfile::tempdir().unwrap();
    let (_map, w) = hash_service(dir.path(), "stall", 1024, 64, 32);
    let c = Client::attach(dir.path(), "stall").unwrap();
    assert!(c.request_centre([1, 2], [0.0, 0.0]));
    let r = c.raw_request().unwrap();
    let q = layout::request::SEQ;
    // A renderer (alive: this process) takes the lock word and stalls half way through its
    // stores, far longer than the 100 ms after which a dead renderer's lock is taken over.
    let free = r.load(q, Ordering::Acquire);
    let mine = layout::request_lock::locked(free, std::process::id());
    assert_eq!(r.compare_exchange(q, free, mine), Ok(free));
    r.store(layout::request::CENTRE_S, 1000, Ordering::Relaxed);
    // Another renderer meanwhile: it waits for the live owner (bounded) and gives up, leaving the
    // word and the fields alone.
    let other = Client::attach(dir.path(), "stall").unwrap();
    let t = std::time::Instant::now();
    let taken = std::thread::scope(|s| s.spawn(|| other.request_centre([-5, -6], [0.0, 0.0])).join().unwrap());
    assert!(!taken, "a live renderer's lock was taken over after {:?}", t.elapsed());
    assert!(t.elapsed() >= std::time::Duration::from_millis(layout::request_lock::WAIT_MS));
    assert_eq!(r.load(q, Ordering::Acquire), mine, "the stalled renderer still holds the word");
    assert_eq!(w.request(), None, "nothing is taken while the word is held (the service keeps its centre)");
    // The stalled renderer wakes up, finishes its stores and releases the word: the service
    // reads exactly its request, and the word moved forward only.
    r.store(layout::request::CENTRE_T, 2000, Ordering::Relaxed);
    let count = r.load(layout::request::COUNT, Ordering::Relaxed);
    r.store(layout::request::COUNT, count + 1, Ordering::Relaxed);
    let next = layout::request_lock::released(mine);
    assert_eq!(r.compare_exchange(q, mine, next), Ok(mine), "nobody stored over its word");
    assert!(next > free);
    let got = w.request().unwrap();
    assert_eq!((got.centre, got.count), ([1000, 2000], 2));
    // And the other renderer's next request goes through.
    assert!(other.request_centre([-5, -6], [0.0, 0.0]));
    assert_eq!(w.request().unwrap().centre, [-5, -6]);
}

#[test]
fn a_request_mapping_truncated_by_a_renderer_never_faults_the_writer_and_is_reported_once() {
    let dir = tempfile::tempdir().unwrap();
    let (_map, w) = hash_service(dir.path(), "trunc", 1024, 64, 32);
    let c = Client::attach(dir.path(), "trunc").unwrap();
    assert!(c.request_centre([10, 20], [0.0, 0.0]));
    assert_eq!(w.request().unwrap().centre, [10, 20]);
    let f = std::fs::OpenOptions::new().write(true).open(w.request_path()).unwrap();
    f.set_len(100).unwrap();
    // A mapped request file would raise SIGBUS here (the page past the end is gone).
    for _ in 0..5 {
        assert_eq!(w.request(), None);
        assert_eq!(w.request_count(), 0);
    }
    let (n, first) = w.request_faults();
    assert_eq!(n, 1, "reported once, not on every read");
    let first = first.unwrap();
    assert!(first.contains("clipmap-trunc.req") && first.contains("100 bytes, expected 4096"), "{first}");
    // Whole again (a renderer re-creates its contents): read again, still one report.
    f.set_len(layout::REQUEST_BYTES).unwrap();
    use std::os::unix::fs::FileExt;
    f.write_all_at(&9u64.to_le_bytes(), layout::request::COUNT as u64).unwrap();
    assert_eq!(w.request().map(|r| r.count), Some(9));
    assert_eq!(w.request_faults().0, 1);
}

#[test]
fn a_request_is_taken_only_when_two_copies_agree() {
    use std::os::unix::fs::FileExt;
    let dir = tempfile::tempdir().unwrap();
    let (_map, w) = hash_service(dir.path(), "copies", 1024, 64, 32);
    let f = std::fs::OpenOptions::new().read(true).write(true).open(w.request_path()).unwrap();
    // A renderer that writes requests as fast as it can while the service reads: every request
    // read is one whole request (centre t = -centre s, count = centre s), never a mix.
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        s.spawn(|| {
            let c = Client::attach(dir.path(), "copies").unwrap();
            let mut i = 1i64;
            while !stop.load(Ordering::Relaxed) {
                assert!(c.request_centre([i, -i], [i as f64, 0.0]));
                i += 1;
            }
        });
        let mut seen = 0;
        let t = std::time::Instant::now();
        while seen < 2000 && t.elapsed() < std::time::Duration::from_secs(20) {
            if let Some(r) = w.request() {
                assert_eq!(r.centre[1], -r.centre[0], "{r:?}");
                assert_eq!(r.velocity[0], r.centre[0] as f64, "{r:?}");
                assert_eq!(r.count as i64, r.centre[0], "{r:?}");
                seen += 1;
            }
        }
        stop.store(true, Ordering::Relaxed);
        assert!(seen > 0);
    });
    let mut b = [0u8; 8];
    f.read_exact_at(&mut b, layout::request::SEQ as u64).unwrap();
    assert_eq!(u64::from_le_bytes(b) & 1, 0);
}
