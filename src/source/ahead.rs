//! Request shaping for tiles read in byte ranges of one object (a remote COG): the tiles a read
//! queue is about to read are announced ([`ReadAhead::announce`]); a read of one of them fetches,
//! with the same ranged request, the announced tiles whose stored bytes lie next to its own
//! (separated by at most [`GAP_BYTES`], whose bytes are fetched and dropped), up to a byte cap.
//! The other tiles of that request then take their bytes from it rather than sending a request
//! each.
//!
//! The request's bytes are handed over as they arrive ([`Feed::push`]): a tile takes its own
//! bytes as soon as the last of them has arrived, while the rest of the request is still on its
//! way, so that the readers decode a row of tiles while the row streams in instead of waiting for
//! all of it. Each tile's bytes are gathered into a buffer of their own, the one copy of a byte on
//! its way from the answer to the decoder. The bytes between the announced tiles are dropped,
//! except those of a whole tile lying there that nobody announced yet: its bytes are kept as
//! well (bounded like the others by [`KEPT_BYTES`]), so that its read, when it comes, takes them
//! instead of fetching the same bytes again.
//!
//! Only announced tiles are read ahead: a tile the queue does not mean to read is never fetched,
//! beyond a gap of at most [`GAP_BYTES`] between two that it does. A tile withdrawn
//! ([`ReadAhead::withdraw`]: its read was dropped) leaves the request it was merged into while
//! that request is not sent yet; once it is, the tile's bytes come anyway and are kept for it,
//! so that a view coming back for it takes them rather than fetching them a second time; bytes
//! read for tiles nobody takes are dropped once the spans kept pass [`KEPT_BYTES`]. A request
//! is sent by the read of its first tile; a merged request whose tiles are all unwanted is
//! never sent, and a partly wanted one completes. It may run detached from that read
//! ([`Ticket::detach`]): the read then decodes its own tile as soon as that tile's bytes are
//! whole, and the next tiles of its run as they arrive, rather than after the whole request. A
//! request that fails part way leaves the tiles whose bytes had all arrived to be taken (they
//! are that object's bytes, whole) and the others to be read on their own.

pub use super::merge::Piece;
use super::merge::{run, Rule};
use std::collections::{HashMap, HashSet, VecDeque};
use std::hash::Hash;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};

/// The longest run of bytes no wanted tile holds that a merged request reads (and drops) to join
/// two tiles.
pub const GAP_BYTES: u64 = 16 << 10;

/// Most tiles remembered as announced (the oldest are forgotten first).
pub const MAX_ANNOUNCED: usize = 1 << 14;

/// Most bytes of merged requests kept for tiles that have not taken theirs yet; past it the
/// oldest requests' bytes are dropped (their tiles are then read on their own).
pub const KEPT_BYTES: u64 = 64 << 20;

/// Bytes shared between readers.
pub type Shared = Arc<Vec<u8>>;

/// One tile of a merged request and its bytes as they are gathered.
struct Gathered<K> {
    piece: Piece<K>,
    /// The bytes arrived so far (its buffer, made when the first arrives).
    buf: Vec<u8>,
    /// All its bytes, once they have arrived, until taken.
    whole: Option<Shared>,
}

/// What has arrived of a merged request.
struct Fill<K> {
    tiles: Vec<Gathered<K>>,
    /// Bytes of the request handed over so far, from its start.
    got: u64,
    /// The request is over (whole or failed): tiles not whole by now never will be.
    ended: bool,
    /// The request was sent: its bytes come whether or not its tiles are still wanted.
    sent: bool,
}

/// One merged request: its range, the tiles merged into it (those that still are to take their
/// bytes from it are the ones `State::by_tile` maps to it), and what has arrived.
struct Span<K> {
    start: u64,
    end: u64,
    waiting: HashSet<K>,
    fill: Mutex<Fill<K>>,
    /// Signalled when a tile's bytes are whole, and when the request ends.
    grew: Condvar,
}

impl<K> Span<K> {
    fn lock(&self) -> MutexGuard<'_, Fill<K>> {
        self.fill.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Hands over the request's next bytes.
    fn push(&self, bytes: &[u8]) {
        let mut f = self.lock();
        let from = self.start.saturating_add(f.got);
        let to = from.saturating_add(bytes.len() as u64);
        let mut whole = false;
        for g in &mut f.tiles {
            let (a, b) = (g.piece.start.max(from), g.piece.end().min(to));
            if a >= b || g.whole.is_some() {
                continue;
            }
            if g.buf.capacity() == 0 {
                g.buf.reserve_exact(g.piece.len as usize);
            }
            // Bytes arrive in order, so a tile's bytes are appended in order too.
            debug_assert_eq!(g.buf.len() as u64, a - g.piece.start);
            g.buf.extend_from_slice(&bytes[(a - from) as usize..(b - from) as usize]);
            if g.buf.len() as u64 == g.piece.len {
                g.whole = Some(Arc::new(std::mem::take(&mut g.buf)));
                whole = true;
            }
        }
        f.got += bytes.len() as u64;
        drop(f);
        if whole {
            self.grew.notify_all();
        }
    }

    /// Ends the request: tiles not whole by now are read on their own.
    fn end(&self) {
        let mut f = self.lock();
        if f.ended {
            return;
        }
        f.ended = true;
        for g in &mut f.tiles {
            g.buf = Vec::new();
        }
        drop(f);
        self.grew.notify_all();
    }
}

impl<K: Copy + Eq> Span<K> {
    /// `tile`'s bytes (its first byte, its bytes), waiting for them while the request runs;
    /// `None` when the request ended without them.
    fn take(&self, tile: K) -> (u64, Option<Shared>) {
        let mut f = self.lock();
        loop {
            let Some(g) = f.tiles.iter_mut().find(|g| g.piece.key == tile) else { return (0, None) };
            let start = g.piece.start;
            if let Some(b) = g.whole.take() {
                return (start, Some(b));
            }
            if f.ended {
                return (start, None);
            }
            f = self.grew.wait(f).unwrap_or_else(|e| e.into_inner());
        }
    }
}

struct State<K> {
    announced: HashSet<K>,
    order: VecDeque<K>,
    /// Spans, oldest first.
    spans: VecDeque<Arc<Span<K>>>,
    /// Tile to span.
    by_tile: HashMap<K, Arc<Span<K>>>,
}

/// The announced tiles and the merged requests of one object.
pub struct ReadAhead<K> {
    state: Mutex<State<K>>,
}

impl<K> Default for ReadAhead<K> {
    fn default() -> Self {
        ReadAhead {
            state: Mutex::new(State {
                announced: HashSet::new(),
                order: VecDeque::new(),
                spans: VecDeque::new(),
                by_tile: HashMap::new(),
            }),
        }
    }
}

/// What a read of a tile is to do.
pub enum Plan<K> {
    /// Read the tile on its own.
    Alone,
    /// Its bytes, taken from the request that read them: `bytes` from byte `start` (its own
    /// first byte; `None`: that request failed before they arrived, read it on its own).
    Take { start: u64, bytes: Option<Shared> },
    /// Send the request for `start..end`, which holds the tile and `merged` others: start it
    /// with the ticket's feed ([`Ticket::detach`]), which hands its bytes over as they arrive.
    Send { start: u64, end: u64, merged: Vec<K>, ticket: Ticket<K> },
}

/// A request sent by one read, to be started elsewhere with its feed ([`Ticket::detach`]).
/// Dropped instead (the read failed or panicked first), it ends the request, so that no tile
/// waits for it for ever.
pub struct Ticket<K> {
    span: Arc<Span<K>>,
    head: K,
    /// The request runs elsewhere: its feed ends it, not the ticket.
    detached: bool,
}

/// Hands a request's bytes over to the tiles merged into it, from any thread (the one the answer
/// arrives on). It ends the request when its last clone is dropped, whether or not
/// [`Feed::end`] was called.
pub struct Feed<K>(Arc<FeedOf<K>>);

struct FeedOf<K> {
    span: Arc<Span<K>>,
}

impl<K> Drop for FeedOf<K> {
    fn drop(&mut self) {
        self.span.end();
    }
}

impl<K> Clone for Feed<K> {
    fn clone(&self) -> Self {
        Feed(Arc::clone(&self.0))
    }
}

impl<K> Feed<K> {
    /// The request's next bytes, in order from its first.
    pub fn push(&self, bytes: &[u8]) {
        self.0.span.push(bytes);
    }

    /// Ends the request (all its bytes handed over, or as many as arrived before it failed):
    /// tiles whose bytes are not whole by now read on their own.
    pub fn end(&self) {
        self.0.span.end();
    }
}

impl<K: Copy + Eq> Ticket<K> {
    /// Hands the request to `send`, which starts it elsewhere with its feed (the request ends at
    /// [`Feed::end`], or when the feed's last clone is dropped), and waits only for the sending
    /// tile's own bytes while the rest stream in, so that the sending read decodes its tile,
    /// and then the next ones, as they arrive rather than once the whole request has. `None`:
    /// the request ended without them (read the tile on its own).
    pub fn detach(mut self, send: impl FnOnce(Feed<K>)) -> Option<(u64, Shared)> {
        self.detached = true;
        self.span.lock().sent = true;
        send(Feed(Arc::new(FeedOf { span: Arc::clone(&self.span) })));
        match self.span.take(self.head) {
            (start, Some(b)) => Some((start, b)),
            _ => None,
        }
    }
}

impl<K> Drop for Ticket<K> {
    fn drop(&mut self) {
        if !self.detached {
            self.span.end();
        }
    }
}

impl<K: Copy + Eq + Hash> ReadAhead<K> {
    fn lock(&self) -> MutexGuard<'_, State<K>> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// `tiles` are about to be read.
    pub fn announce(&self, tiles: impl IntoIterator<Item = K>) {
        let mut st = self.lock();
        for k in tiles {
            if st.announced.insert(k) {
                st.order.push_back(k);
            }
        }
        while st.order.len() > MAX_ANNOUNCED {
            if let Some(old) = st.order.pop_front() {
                st.announced.remove(&old);
            }
        }
    }

    /// `tile` will not be read after all: it is not read ahead, and a request it was merged into
    /// keeps no bytes for it, unless that request was sent already: its bytes then come anyway,
    /// and are kept for the tile (within [`KEPT_BYTES`]) in case it is wanted again, rather than
    /// fetched a second time.
    pub fn withdraw(&self, tile: K) {
        let mut st = self.lock();
        st.announced.remove(&tile);
        let Some(span) = st.by_tile.get(&tile).cloned() else { return };
        let mut f = span.lock();
        if f.sent {
            return;
        }
        st.by_tile.remove(&tile);
        Self::forget_taken(&mut st);
        drop(st);
        if let Some(g) = f.tiles.iter_mut().find(|g| g.piece.key == tile) {
            (g.buf, g.whole) = (Vec::new(), None);
            // Nothing more is gathered for it.
            g.piece.len = 0;
        }
    }

    /// Forgets the spans no tile waits for any more (their bytes go with the last reader).
    fn forget_taken(st: &mut State<K>) {
        let by_tile = &st.by_tile;
        st.spans.retain(|s| s.waiting.iter().any(|k| by_tile.get(k).is_some_and(|o| Arc::ptr_eq(o, s))));
    }

    /// What the read of `tile` is to do. `near` lists tiles whose bytes may lie next to its own
    /// (the caller's neighbourhood of it in the object's order); `place` gives a tile's stored
    /// bytes (`None`: not to be merged, as a sparse tile), asked outside the lock, for `tile`,
    /// for those of `near` that are announced and in no request yet, and for the tiles of `near`
    /// between them (in `near`'s order) that are not announced: those whose bytes lie wholly in
    /// the request's range (its gaps) keep their bytes too, so that a read of one later takes
    /// them rather than fetching them again.
    pub fn plan(&self, tile: K, near: &[K], place: impl Fn(&K) -> Option<Piece<K>>, cap: u64) -> Plan<K> {
        let keys: Vec<K> = {
            let mut st = self.lock();
            st.announced.remove(&tile);
            if let Some(span) = st.by_tile.remove(&tile) {
                Self::forget_taken(&mut st);
                drop(st);
                let (start, bytes) = span.take(tile);
                return Plan::Take { start, bytes };
            }
            near.iter()
                .filter(|k| **k != tile && st.announced.contains(k) && !st.by_tile.contains_key(k))
                .copied()
                .collect()
        };
        if keys.is_empty() {
            return Plan::Alone;
        }
        let Some(own) = place(&tile) else { return Plan::Alone };
        let mut pieces: Vec<Piece<K>> = keys.iter().filter_map(&place).collect();
        // The unannounced tiles of `near` between the first and the last tile the request may
        // hold: those in its gaps are gathered too.
        let at = |k: &K| near.iter().position(|n| n == k);
        let spots: Vec<usize> = pieces.iter().map(|p| p.key).chain([tile]).filter_map(|k| at(&k)).collect();
        let spare: Vec<Piece<K>> = match (spots.iter().min(), spots.iter().max()) {
            (Some(&lo), Some(&hi)) => {
                near[lo..=hi].iter().filter(|k| **k != tile && !keys.contains(k)).filter_map(&place).collect()
            }
            _ => Vec::new(),
        };
        let mut st = self.lock();
        // Claimed by another read meanwhile: not this request's.
        pieces.retain(|p| st.announced.contains(&p.key) && !st.by_tile.contains_key(&p.key));
        pieces.push(own);
        pieces.sort_by_key(|p| p.start);
        let Some(head) = pieces.iter().position(|p| p.key == tile) else { return Plan::Alone };
        let (lo, hi) = run(&pieces, head, Rule::within(GAP_BYTES, cap));
        if lo == hi {
            return Plan::Alone;
        }
        let mut run = pieces[lo..=hi].to_vec();
        let start = run.iter().map(|p| p.start).min().unwrap_or(0);
        let end = run.iter().map(Piece::end).max().unwrap_or(start);
        let merged: Vec<K> = run.iter().map(|p| p.key).filter(|k| *k != tile).collect();
        // Tiles in the gaps, in no request and not announced (an announced one is read on its
        // own as planned).
        let gaps: Vec<Piece<K>> = spare
            .into_iter()
            .filter(|p| p.start >= start && p.end() <= end && p.len > 0)
            .filter(|p| !st.by_tile.contains_key(&p.key) && !st.announced.contains(&p.key))
            .filter(|p| run.iter().all(|r| r.key != p.key))
            .collect();
        run.extend(gaps.iter().copied());
        let fill = Fill {
            tiles: run.iter().map(|p| Gathered { piece: *p, buf: Vec::new(), whole: None }).collect(),
            got: 0,
            ended: false,
            sent: false,
        };
        let span = Arc::new(Span {
            start,
            end,
            waiting: merged.iter().chain(gaps.iter().map(|p| &p.key)).copied().collect(),
            fill: Mutex::new(fill),
            grew: Condvar::new(),
        });
        for k in merged.iter().chain(gaps.iter().map(|p| &p.key)) {
            st.announced.remove(k);
            st.by_tile.insert(*k, Arc::clone(&span));
        }
        st.spans.push_back(Arc::clone(&span));
        Self::trim(&mut st);
        Plan::Send { start, end, merged, ticket: Ticket { span, head: tile, detached: false } }
    }

    /// Drops the oldest spans' claims while more than [`KEPT_BYTES`] are held.
    fn trim(st: &mut State<K>) {
        Self::forget_taken(st);
        let mut held: u64 = st.spans.iter().map(|s| s.end - s.start).sum();
        while held > KEPT_BYTES && st.spans.len() > 1 {
            let Some(old) = st.spans.pop_front() else { break };
            held -= old.end - old.start;
            for k in &old.waiting {
                if st.by_tile.get(k).is_some_and(|o| Arc::ptr_eq(o, &old)) {
                    st.by_tile.remove(k);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Whether `lo..=hi` of `pieces` may be one request: every gap within `gap`, the bytes within
    /// `cap` (or one piece alone), no piece reaching back before the run's first.
    fn valid(pieces: &[Piece<usize>], lo: usize, hi: usize, gap: u64, cap: u64) -> bool {
        if lo == hi {
            return true;
        }
        let run = &pieces[lo..=hi];
        let start = run[0].start;
        let mut end = run[0].end();
        for p in &run[1..] {
            if p.start < start || p.start.saturating_sub(end) > gap {
                return false;
            }
            end = end.max(p.end());
        }
        end - start <= cap
    }

    /// Pieces side by side with gaps (some none, some past the merge gap), sorted by start.
    fn pieces() -> impl Strategy<Value = Vec<Piece<usize>>> {
        prop::collection::vec((1u64..40_000, prop_oneof![Just(0u64), 0u64..20_000, 15_000u64..100_000]), 1..40)
            .prop_map(|v| {
                let mut at = 0;
                v.into_iter()
                    .enumerate()
                    .map(|(key, (len, gap))| {
                        at += gap;
                        let p = Piece { key, start: at, len };
                        at += len;
                        p
                    })
                    .collect()
            })
    }

    fn object(len: u64) -> Vec<u8> {
        (0..len).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect()
    }

    proptest! {
        /// Against a brute-force oracle of the policy: the run grows forward as far as any valid
        /// run from the head does, then backward as far as any valid run to that end does; its
        /// bytes stay within the cap, its gaps within the gap; and every piece's bytes cut out of
        /// the merged request are the bytes of its own range.
        #[test]
        fn coalescing_is_the_oracle_s_run_and_gives_each_piece_its_own_bytes(
            ps in pieces(), head_seed in any::<usize>(), cap in 0u64..400_000,
        ) {
            let head = head_seed % ps.len();
            let (lo, hi) = run(&ps, head, Rule::within(GAP_BYTES, cap));
            prop_assert!(lo <= head && head <= hi);
            prop_assert!(valid(&ps, lo, hi, GAP_BYTES, cap));
            let far = (head..ps.len()).filter(|&h| valid(&ps, head, h, GAP_BYTES, cap)).max().unwrap();
            // Valid runs are intervals: every h up to `far` is valid too, so the greedy reaches it.
            prop_assert_eq!(hi, far);
            let back = (0..=head).filter(|&l| valid(&ps, l, hi, GAP_BYTES, cap)).min().unwrap();
            prop_assert_eq!(lo, back);
            let (start, end) = (ps[lo].start, ps[lo..=hi].iter().map(|p| p.end()).max().unwrap());
            if lo < hi {
                prop_assert!(end - start <= cap, "{} bytes over the cap {}", end - start, cap);
            }
            for w in ps[lo..=hi].windows(2) {
                prop_assert!(w[1].start - w[0].end() <= GAP_BYTES);
            }
            let obj = object(end);
            let merged = &obj[start as usize..end as usize];
            for p in &ps[lo..=hi] {
                let from = (p.start - start) as usize;
                prop_assert_eq!(&merged[from..from + p.len as usize], &obj[p.start as usize..p.end() as usize]);
            }
        }

        /// Threads reading announced tiles in any order through [`ReadAhead`]: each gets exactly
        /// the bytes of its own range, no request is larger than the cap (but a lone tile), and
        /// there are never more requests than tiles.
        #[test]
        fn reads_through_read_ahead_get_their_own_bytes(
            ps in pieces(), order_seed in any::<u64>(), cap in 0u64..400_000, withdrawn in any::<u64>(),
        ) {
            let ahead = ReadAhead::<usize>::default();
            let end = ps.iter().map(|p| p.end()).max().unwrap();
            let obj = object(end);
            let keys: Vec<usize> = ps.iter().map(|p| p.key).collect();
            ahead.announce(keys.iter().copied());
            // Some tiles are withdrawn (their reads dropped) and never read.
            let gone: Vec<usize> = keys.iter().copied().filter(|k| withdrawn >> (k % 64) & 1 == 1 && k % 3 == 0).collect();
            for k in &gone {
                ahead.withdraw(*k);
            }
            let mut order: Vec<usize> = keys.iter().copied().filter(|k| !gone.contains(k)).collect();
            let mut x = order_seed | 1;
            for i in (1..order.len()).rev() {
                x ^= x << 13; x ^= x >> 7; x ^= x << 17;
                order.swap(i, (x % (i as u64 + 1)) as usize);
            }
            let requests = Mutex::new(Vec::<(u64, u64)>::new());
            let next = std::sync::atomic::AtomicUsize::new(0);
            let place = |k: &usize| Some(ps[*k]);
            let read = |k: usize| -> Vec<u8> {
                let fetch = |s: u64, e: u64| {
                    requests.lock().unwrap().push((s, e));
                    obj[s as usize..e as usize].to_vec()
                };
                let p = ps[k];
                match ahead.plan(k, &keys, place, cap) {
                    Plan::Alone => fetch(p.start, p.end()),
                    Plan::Take { start, bytes: Some(b) } => {
                        assert_eq!(start, p.start, "a tile's bytes start at its first byte");
                        b.to_vec()
                    }
                    Plan::Take { bytes: None, .. } => fetch(p.start, p.end()),
                    Plan::Send { start, end, ticket, .. } => {
                        let b = fetch(start, end);
                        let (own_start, own) = ticket
                            .detach(|feed| {
                                // Handed over in pieces of any size, as an answer arrives, on a
                                // thread of its own.
                                std::thread::spawn(move || {
                                    let mut at = 0;
                                    let mut x = k as u64 * 7 + 1;
                                    while at < b.len() {
                                        x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
                                        let n = ((x >> 33) as usize % 9000 + 1).min(b.len() - at);
                                        feed.push(&b[at..at + n]);
                                        at += n;
                                    }
                                });
                            })
                            .expect("the sender's own bytes");
                        assert_eq!(own_start, p.start);
                        own.to_vec()
                    }
                }
            };
            let got: Vec<(usize, Vec<u8>)> = std::thread::scope(|scope| {
                let threads: Vec<_> = (0..4)
                    .map(|_| {
                        scope.spawn(|| {
                            let mut mine = Vec::new();
                            loop {
                                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                                let Some(&k) = order.get(i) else { return mine };
                                mine.push((k, read(k)));
                            }
                        })
                    })
                    .collect();
                threads.into_iter().flat_map(|t| t.join().unwrap()).collect()
            });
            prop_assert_eq!(got.len(), order.len());
            for (k, bytes) in &got {
                let p = ps[*k];
                prop_assert_eq!(bytes.as_slice(), &obj[p.start as usize..p.end() as usize], "tile {}", k);
            }
            let requests = requests.into_inner().unwrap();
            prop_assert!(requests.len() <= order.len());
            for (s, e) in &requests {
                let lone = ps.iter().any(|p| p.start == *s && p.end() == *e);
                prop_assert!(lone || e - s <= cap, "request {}..{} over the cap {}", s, e, cap);
            }
        }
    }

    fn row(n: usize, len: u64, gap: u64) -> Vec<Piece<usize>> {
        (0..n).map(|key| Piece { key, start: key as u64 * (len + gap), len }).collect()
    }

    #[test]
    fn announced_neighbours_are_read_with_the_first_and_take_their_bytes_from_it() {
        let ps = row(10, 1000, 0);
        let ahead = ReadAhead::<usize>::default();
        ahead.announce(0..10);
        let place = |k: &usize| Some(ps[*k]);
        let all: Vec<usize> = (0..10).collect();
        let Plan::Send { start, end, merged, ticket } = ahead.plan(3, &all, place, 1 << 20) else { panic!() };
        assert_eq!((start, end, merged.len()), (0, 10_000, 9));
        let obj = object(10_000);
        let (own_start, own) = ticket.detach(|feed| feed.push(&obj)).unwrap();
        assert_eq!((own_start, own.as_slice()), (3000, &obj[3000..4000]));
        match ahead.plan(7, &all, place, 1 << 20) {
            Plan::Take { start: 7000, bytes: Some(b) } => assert_eq!(b.as_slice(), &obj[7000..8000]),
            _ => panic!("tile 7 takes its bytes from the request"),
        }
        // Taken once: a second read of the same tile is a read of its own.
        assert!(matches!(ahead.plan(7, &all, place, 1 << 20), Plan::Alone));
    }

    #[test]
    fn a_tile_takes_its_bytes_once_they_have_arrived_while_the_request_still_runs() {
        let ps = row(4, 1000, 0);
        let place = |k: &usize| Some(ps[*k]);
        let all: Vec<usize> = (0..4).collect();
        let ahead = ReadAhead::<usize>::default();
        ahead.announce(0..4);
        let Plan::Send { ticket, .. } = ahead.plan(0, &all, place, 1 << 20) else { panic!() };
        let obj = object(4000);
        // Tile 0's and 1's bytes and half of tile 2's have arrived; the request goes on. The
        // sending tile has its own bytes at once.
        let mut running = None;
        let (_, own) = ticket
            .detach(|feed| {
                feed.push(&obj[..1500]);
                feed.push(&obj[1500..2500]);
                running = Some(feed);
            })
            .unwrap();
        assert_eq!(own.as_slice(), &obj[..1000]);
        let feed = running.unwrap();
        std::thread::scope(|scope| {
            let taker = scope.spawn(|| match ahead.plan(1, &all, place, 1 << 20) {
                Plan::Take { start: 1000, bytes: Some(b) } => b.to_vec(),
                _ => panic!("tile 1 takes its bytes"),
            });
            assert_eq!(taker.join().unwrap(), &obj[1000..2000], "taken before the request ended");
            // Tile 2 waits for the rest of its bytes, which arrive after it asked.
            let waiter = scope.spawn(|| match ahead.plan(2, &all, place, 1 << 20) {
                Plan::Take { start: 2000, bytes: Some(b) } => b.to_vec(),
                _ => panic!("tile 2 takes its bytes"),
            });
            std::thread::sleep(std::time::Duration::from_millis(20));
            feed.push(&obj[2500..3200]);
            assert_eq!(waiter.join().unwrap(), &obj[2000..3000]);
        });
        // The request fails before tile 3's bytes are whole (its feed dropped): tile 3 reads on
        // its own.
        drop(feed);
        assert!(matches!(ahead.plan(3, &all, place, 1 << 20), Plan::Take { bytes: None, .. }));
    }

    #[test]
    fn unannounced_tiles_are_not_read_ahead_nor_gaps_past_the_bound() {
        let place_of = |ps: Vec<Piece<usize>>| move |k: &usize| Some(ps[*k]);
        let ahead = ReadAhead::<usize>::default();
        let all: Vec<usize> = (0..6).collect();
        // Nothing announced: each tile alone.
        assert!(matches!(ahead.plan(0, &all, place_of(row(6, 1000, 0)), 1 << 20), Plan::Alone));
        // Tiles 0, 1 and 4, 5 announced; 2 and 3 (2000 bytes, under the gap) not: one request
        // reads 0..=5, dropping the bytes of 2 and 3.
        ahead.announce([0, 1, 4, 5]);
        let mut ps = row(6, 1000, 0);
        ps.remove(3);
        ps.remove(2);
        let keyed: HashMap<usize, Piece<usize>> = ps.iter().map(|p| (p.key, *p)).collect();
        match ahead.plan(0, &all, |k: &usize| keyed.get(k).copied(), 1 << 20) {
            Plan::Send { start: 0, end: 6000, merged, .. } => assert_eq!(merged, vec![1, 4, 5]),
            _ => panic!("the gap of 2000 bytes is read"),
        }
        // A gap past the bound splits the run.
        let ahead = ReadAhead::<usize>::default();
        ahead.announce(0..2);
        let far = vec![Piece { key: 0, start: 0, len: 10 }, Piece { key: 1, start: 10 + GAP_BYTES + 1, len: 10 }];
        assert!(matches!(ahead.plan(0, &[0, 1], place_of(far), 1 << 20), Plan::Alone));
    }

    #[test]
    fn withdrawn_tiles_leave_their_request_and_a_dropped_ticket_fails_it() {
        let ps = row(4, 1000, 0);
        let place = |k: &usize| Some(ps[*k]);
        let all: Vec<usize> = (0..4).collect();
        let ahead = ReadAhead::<usize>::default();
        ahead.announce(0..4);
        ahead.withdraw(3);
        let Plan::Send { end, merged, ticket, .. } = ahead.plan(0, &all, place, 1 << 20) else { panic!() };
        assert_eq!((end, merged), (3000, vec![1, 2]), "a tile withdrawn before is not read");
        ahead.withdraw(2);
        // The read that sent the request fails without finishing: its tiles read on their own.
        drop(ticket);
        // (The ticket was never detached: the request was not sent, so tile 2 kept nothing.)
        assert!(matches!(ahead.plan(1, &all, place, 1 << 20), Plan::Take { bytes: None, .. }));
        assert!(matches!(ahead.plan(2, &all, place, 1 << 20), Plan::Alone), "withdrawn: nothing kept for it");
        assert!(ahead.lock().spans.is_empty() && ahead.lock().by_tile.is_empty());
    }

    #[test]
    fn a_tile_withdrawn_once_its_request_was_sent_takes_its_bytes_when_wanted_again() {
        let ps = row(4, 1000, 0);
        let place = |k: &usize| Some(ps[*k]);
        let all: Vec<usize> = (0..4).collect();
        let ahead = ReadAhead::<usize>::default();
        ahead.announce(0..4);
        let Plan::Send { ticket, .. } = ahead.plan(0, &all, place, 1 << 20) else { panic!() };
        let obj = object(4000);
        ticket.detach(|feed| feed.push(&obj)).unwrap();
        ahead.withdraw(2);
        ahead.announce([2]);
        match ahead.plan(2, &all, place, 1 << 20) {
            Plan::Take { start: 2000, bytes: Some(b) } => assert_eq!(b.as_slice(), &obj[2000..3000]),
            _ => panic!("tile 2 takes the bytes its sent request brought"),
        }
    }

    #[test]
    fn an_unannounced_tile_in_a_gap_keeps_its_bytes_for_its_read() {
        // Tiles 0, 1, 2 back to back; only 0 and 2 announced: 1 lies in the request's gap.
        let ps = row(3, 1000, 0);
        let place = |k: &usize| Some(ps[*k]);
        let all: Vec<usize> = (0..3).collect();
        let ahead = ReadAhead::<usize>::default();
        ahead.announce([0, 2]);
        let Plan::Send { start: 0, end: 3000, merged, ticket } = ahead.plan(0, &all, place, 1 << 20) else { panic!() };
        assert_eq!(merged, vec![2]);
        let obj = object(3000);
        ticket.detach(|feed| feed.push(&obj)).unwrap();
        match ahead.plan(1, &all, place, 1 << 20) {
            Plan::Take { start: 1000, bytes: Some(b) } => assert_eq!(b.as_slice(), &obj[1000..2000]),
            _ => panic!("tile 1 takes the bytes the request passed over"),
        }
    }

    #[test]
    fn the_cap_bounds_a_request_and_zero_reads_nothing_ahead() {
        let ps = row(10, 1000, 0);
        let place = |k: &usize| Some(ps[*k]);
        let all: Vec<usize> = (0..10).collect();
        let ahead = ReadAhead::<usize>::default();
        ahead.announce(0..10);
        let Plan::Send { start, end, .. } = ahead.plan(5, &all, place, 3500) else { panic!() };
        // Forward first: 5, 6, 7, then back to 5's left while it fits.
        assert_eq!((start, end), (5000, 8000));
        let ahead = ReadAhead::<usize>::default();
        ahead.announce(0..10);
        assert!(matches!(ahead.plan(5, &all, place, 0), Plan::Alone));
    }

    #[test]
    fn kept_bytes_are_bounded() {
        let len = KEPT_BYTES / 4;
        let ps = row(20, len, 0);
        let place = |k: &usize| Some(ps[*k]);
        let all: Vec<usize> = (0..20).collect();
        let ahead = ReadAhead::<usize>::default();
        ahead.announce(0..20);
        // Requests of two tiles each, none of whose second tile is read.
        for head in (0..20).step_by(2) {
            let Plan::Send { ticket, .. } = ahead.plan(head, &all, place, 2 * len) else { panic!() };
            assert!(ticket.detach(|_| {}).is_none(), "no byte arrived");
        }
        let st = ahead.lock();
        let held: u64 = st.spans.iter().map(|s| s.end - s.start).sum();
        assert!(held <= KEPT_BYTES, "{held} bytes held");
        assert!(st.by_tile.len() <= 2, "{} tiles still claim a request", st.by_tile.len());
    }
}
