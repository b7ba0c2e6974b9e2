//! One level's toroidal window: its texel buffer and which of its texels are correct.
//!
//! Owns the buffer (`min(clip, level size)` texels per axis, texel (s, t) at (s mod clip,
//! t mod clip)), the `content` rectangle (level texels whose values in the buffer are correct;
//! always a rectangle no wider than the clip size), the `published` rectangle (what readers may
//! read; always inside `content`), and copying bands of texels from resident tiles. Deciding what
//! to copy and when is [`super`]'s business.
//!
//! Bands grow `content` one side at a time so that it stays a rectangle: columns to its left or
//! right across its rows, then rows below or above across its (by then full) columns; an empty
//! `content` is seeded with rows at the bottom of the goal.

use crate::cache::TileCache;
use crate::geom::{tiles_covering, wrap, Rect};
use crate::source::TileId;

/// A strip of lines adjacent to `content`, growing it along `axis` (0: s, 1: t) in direction
/// `dir` (-1 or +1) from line `start` for at most `depth` lines, spanning `across` on the other
/// axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Band {
    pub axis: usize,
    pub dir: i64,
    pub start: i64,
    pub depth: u64,
    pub across: (i64, i64),
}

impl Band {
    /// The texels of the first `depth` lines.
    pub fn rect(&self, depth: u64) -> Rect {
        let d = depth as i64;
        let (lo, hi) = if self.dir > 0 { (self.start, self.start + d) } else { (self.start - d + 1, self.start + 1) };
        if self.axis == 0 {
            Rect::new(lo, self.across.0, hi, self.across.1)
        } else {
            Rect::new(self.across.0, lo, self.across.1, hi)
        }
    }

    /// Texels in one line.
    pub fn line_texels(&self) -> u64 {
        (self.across.1 - self.across.0).max(0) as u64
    }
}

/// Memory outside this process's private heap that holds one level's window (the shared
/// mapping of [`crate::shm`], so that the engine writes texels where renderers read them, with no
/// second copy). Offsets are bytes within the window, row-major toroidal as in [`Window`].
pub trait WindowStore: Send + std::fmt::Debug {
    /// The window's length in bytes.
    fn len(&self) -> usize;
    /// True for a zero-length window.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Copies `src` into the window at byte `at` (`at + src.len() <= len()`).
    fn write(&mut self, at: usize, src: &[u8]);
    /// Copies the window's bytes at `at` into `out`.
    fn read(&self, at: usize, out: &mut [u8]);
}

/// Where a window's texels live.
#[derive(Debug)]
pub enum Store {
    /// Private memory of this process (the default).
    Private(Vec<u8>),
    /// Memory supplied by the caller, such as a shared mapping.
    External(Box<dyn WindowStore>),
}

impl Store {
    /// Length in bytes.
    pub fn len(&self) -> usize {
        match self {
            Store::Private(v) => v.len(),
            Store::External(e) => e.len(),
        }
    }

    /// True for a zero-length window.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    #[inline]
    fn write(&mut self, at: usize, src: &[u8]) {
        match self {
            Store::Private(v) => v[at..at + src.len()].copy_from_slice(src),
            Store::External(e) => e.write(at, src),
        }
    }

    /// Copies the bytes at `at` into `out`.
    pub fn read(&self, at: usize, out: &mut [u8]) {
        match self {
            Store::Private(v) => out.copy_from_slice(&v[at..at + out.len()]),
            Store::External(e) => e.read(at, out),
        }
    }

    /// The bytes themselves, when they are private to this process.
    pub fn as_slice(&self) -> Option<&[u8]> {
        match self {
            Store::Private(v) => Some(v),
            Store::External(_) => None,
        }
    }
}

/// One level's window.
#[derive(Debug)]
pub struct Window {
    pub level: u32,
    pub clip: u64,
    pub dims: [u64; 2],
    pub bpt: usize,
    pub tile: [u64; 2],
    pub buf: Store,
    pub content: Rect,
    pub published: Rect,
}

impl Window {
    /// The buffer size in texels per axis of a level of `size` texels.
    pub fn dims(size: [u64; 2], clip: u64) -> [u64; 2] {
        [clip.min(size[0]), clip.min(size[1])]
    }

    /// An empty window for a level of `size` texels read in `tile`-sized tiles, in private
    /// memory, or in `store` (which must be exactly the window's length).
    pub fn new(
        level: u32,
        size: [u64; 2],
        clip: u64,
        tile: [u64; 2],
        bpt: usize,
        store: Option<Box<dyn WindowStore>>,
    ) -> Self {
        let dims = Self::dims(size, clip);
        let len = (dims[0] * dims[1]) as usize * bpt;
        let buf = match store {
            Some(e) => {
                assert_eq!(e.len(), len, "level {level}: the window store's length differs from the window's");
                Store::External(e)
            }
            None => Store::Private(vec![0u8; len]),
        };
        Window { level, clip, dims, bpt, tile, buf, content: Rect::EMPTY, published: Rect::EMPTY }
    }

    /// Bytes of the buffer.
    pub fn bytes(&self) -> usize {
        self.buf.len()
    }

    /// The next band that grows `content` towards `goal` (which must lie in the tex region that
    /// `content` was last cut to), or `None` when `content` already covers it.
    pub fn next_band(&self, goal: &Rect) -> Option<Band> {
        let c = self.content;
        if goal.is_empty() || c.contains_rect(goal) {
            return None;
        }
        if c.is_empty() {
            return Some(Band { axis: 1, dir: 1, start: goal.t0, depth: goal.height(), across: (goal.s0, goal.s1) });
        }
        let band = if c.s0 > goal.s0 {
            Band { axis: 0, dir: -1, start: c.s0 - 1, depth: (c.s0 - goal.s0) as u64, across: (c.t0, c.t1) }
        } else if c.s1 < goal.s1 {
            Band { axis: 0, dir: 1, start: c.s1, depth: (goal.s1 - c.s1) as u64, across: (c.t0, c.t1) }
        } else if c.t0 > goal.t0 {
            Band { axis: 1, dir: -1, start: c.t0 - 1, depth: (c.t0 - goal.t0) as u64, across: (c.s0, c.s1) }
        } else {
            Band { axis: 1, dir: 1, start: c.t1, depth: (goal.t1 - c.t1) as u64, across: (c.s0, c.s1) }
        };
        Some(band)
    }

    /// How many of the band's first `max_depth` lines have all their tiles resident.
    pub fn resident_depth(&self, band: &Band, max_depth: u64, cache: &TileCache) -> u64 {
        let tile_len = self.tile[band.axis] as i64;
        let across_len = self.tile[1 - band.axis] as i64;
        let (a0, a1) = (band.across.0.div_euclid(across_len), (band.across.1 - 1).div_euclid(across_len) + 1);
        let mut d = 0u64;
        while d < max_depth {
            let line = band.start + band.dir * d as i64;
            let tile_line = line.div_euclid(tile_len);
            let run = if band.dir > 0 { (tile_line + 1) * tile_len - line } else { line - tile_line * tile_len + 1 };
            let all = (a0..a1).all(|a| {
                let (s, t) = if band.axis == 0 { (tile_line, a) } else { (a, tile_line) };
                s >= 0 && t >= 0 && cache.texels(TileId::new(self.level, s as u64, t as u64)).is_some()
            });
            if !all {
                break;
            }
            d += run as u64;
        }
        d.min(max_depth)
    }

    /// Copies the texels of `rect` from resident tiles into the buffer and returns the bytes
    /// copied. Every tile `rect` touches must be resident (checked by
    /// [`resident_depth`](Self::resident_depth)); returns `None`, copying nothing, if one is not.
    pub fn copy_rect(&mut self, rect: Rect, cache: &TileCache) -> Option<u64> {
        let tiles = tiles_covering(rect, self.tile);
        let mut sources = Vec::with_capacity(tiles.area() as usize);
        for tt in tiles.t0..tiles.t1 {
            for ts in tiles.s0..tiles.s1 {
                sources.push(cache.texels(TileId::new(self.level, ts as u64, tt as u64))?);
            }
        }
        let [tw, th] = [self.tile[0] as i64, self.tile[1] as i64];
        let bpt = self.bpt;
        let clip = self.clip as i64;
        // The runs of a row (split at tile edges and at the window's wrap) are the same for every
        // row: (tile column in `sources`, byte offset in a tile row, byte offset in a window row,
        // bytes). Computing them once keeps divisions out of the per-row loop.
        let mut runs = Vec::new();
        let mut s = rect.s0;
        while s < rect.s1 {
            let ts = s.div_euclid(tw);
            let ws = s.rem_euclid(clip);
            let end = ((ts + 1) * tw).min(rect.s1).min(s + (clip - ws));
            runs.push((
                (ts - tiles.s0) as usize,
                (s - ts * tw) as usize * bpt,
                ws as usize * bpt,
                (end - s) as usize * bpt,
            ));
            s = end;
        }
        let window_row = self.dims[0] as usize * bpt;
        let tile_row = tw as usize * bpt;
        let tiles_w = tiles.width() as usize;
        for t in rect.t0..rect.t1 {
            let tt = t.div_euclid(th);
            let src_row = (t - tt * th) as usize * tile_row;
            let dst_row = wrap(t, self.clip) as usize * window_row;
            let row_sources = &sources[(tt - tiles.t0) as usize * tiles_w..];
            for &(col, src_at, dst_at, n) in &runs {
                let (src, dst) = (src_row + src_at, dst_row + dst_at);
                self.buf.write(dst, &row_sources[col][src..src + n]);
            }
        }
        Some(rect.area() * bpt as u64)
    }

    /// Grows `content` by the first `depth` lines of `band` (which must have been copied).
    pub fn grow(&mut self, band: &Band, depth: u64) {
        let r = band.rect(depth);
        if self.content.is_empty() {
            self.content = r;
            return;
        }
        let c = &mut self.content;
        c.s0 = c.s0.min(r.s0);
        c.t0 = c.t0.min(r.t0);
        c.s1 = c.s1.max(r.s1);
        c.t1 = c.t1.max(r.t1);
    }
}
