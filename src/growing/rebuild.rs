//! Rebuilding the tiles of a growing texture: level 0 from the patches, coarser levels from their
//! four children, in increasing level order, a bounded number per step.

use super::index::PatchIndex;
use super::{Grid, Patch};
use rayon::prelude::*;
use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;

/// A tile's key: level, S, T.
pub(crate) type TileKey = (u32, i64, i64);

/// A rebuilt tile: its texels, and which of them have data (`false`: no patch covers the texel,
/// or nothing below it has data; its bytes are zero).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Tile {
    /// `tile * tile * bytes_per_texel` bytes, row-major.
    pub texels: Vec<u8>,
    /// One flag per texel: whether it has data.
    pub has_data: Flags,
    /// How many flags are set (counted once, when the tile is built).
    filled: usize,
}

/// One bit a texel, row-major, in 64-bit words (bit i of word i / 64 for texel i).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Flags {
    words: Vec<u64>,
    len: usize,
}

impl Flags {
    /// `len` flags, all clear.
    pub fn new(len: usize) -> Flags {
        Flags { words: vec![0; len.div_ceil(64)], len }
    }

    /// Flags from bytes of 8 flags each (bit i % 8 of byte i / 8), as tile files store them.
    pub(crate) fn from_bytes(bytes: &[u8], len: usize) -> Flags {
        let mut f = Flags::new(len);
        for (w, chunk) in f.words.iter_mut().zip(bytes.chunks(8)) {
            let mut b = [0u8; 8];
            b[..chunk.len()].copy_from_slice(chunk);
            *w = u64::from_le_bytes(b);
        }
        if !len.is_multiple_of(64) {
            if let Some(last) = f.words.last_mut() {
                *last &= (1u64 << (len % 64)) - 1;
            }
        }
        f
    }

    /// The flags as bytes of 8 (see `Flags::from_bytes`), `len.div_ceil(8)` of them.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out: Vec<u8> = self.words.iter().flat_map(|w| w.to_le_bytes()).collect();
        out.truncate(self.len.div_ceil(8));
        out
    }

    /// Number of flags.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Flag `i`.
    pub fn get(&self, i: usize) -> bool {
        self.words[i / 64] >> (i % 64) & 1 == 1
    }

    /// Sets flag `i`.
    pub fn set(&mut self, i: usize) {
        self.words[i / 64] |= 1 << (i % 64);
    }

    /// Sets flags `a..b`, a word at a time.
    pub(crate) fn set_run(&mut self, a: usize, b: usize) {
        let mut i = a;
        while i < b {
            let (w, bit) = (i / 64, i % 64);
            let take = (64 - bit).min(b - i);
            let mask = if take == 64 { u64::MAX } else { ((1u64 << take) - 1) << bit };
            self.words[w] |= mask;
            i += take;
        }
    }

    /// Number of flags set.
    pub fn count(&self) -> usize {
        self.words.iter().map(|w| w.count_ones() as usize).sum()
    }
}

impl Tile {
    fn empty(grid: &Grid) -> Tile {
        let n = (grid.tile * grid.tile) as usize;
        Tile { texels: vec![0; n * grid.bytes_per_texel], has_data: Flags::new(n), filled: 0 }
    }

    /// The tile from its texels and flags.
    pub fn new(texels: Vec<u8>, has_data: Flags) -> Tile {
        Tile { texels, has_data, filled: 0 }.counted()
    }

    /// Whether texel `i` (row-major) has data.
    pub fn has(&self, i: usize) -> bool {
        self.has_data.get(i)
    }

    /// Counts the flags.
    fn counted(mut self) -> Tile {
        self.filled = self.has_data.count();
        self
    }

    /// Whether any texel has data.
    pub(crate) fn any_data(&self) -> bool {
        self.filled > 0
    }

    /// Whether every texel has data.
    pub fn full(&self) -> bool {
        self.filled == self.has_data.len()
    }
}

/// Level-0 tile (s, t) from the patches of `index` that meet it: each texel from the winning
/// patch ([`Patch::beats`]) among those whose box holds the texel's centre, sampled there.
///
/// Painted rather than searched: the candidates are laid down worst first, each over the texels
/// whose centres its box holds (a rectangle, found per axis from the same centre arithmetic as
/// [`Grid::texel_centre`] and [`WorldBox::contains`]), with its pixel column per texel column
/// worked out once; the winner is laid down last. The result is the same texel for texel.
pub(crate) fn level0_tile(grid: &Grid, index: &PatchIndex, s: i64, t: i64) -> Tile {
    let mut out = Tile::empty(grid);
    let mut candidates: Vec<(usize, &Arc<Patch>)> = index.for_tile(grid, 0, s, t).into_iter().enumerate().collect();
    if candidates.is_empty() {
        return out;
    }
    // Worst first; among equals (same rating, time and id) the earliest last, as a search keeping
    // the first of equals would pick it.
    candidates.sort_by(|(ia, a), (ib, b)| {
        a.rating.total_cmp(&b.rating).then(a.time.cmp(&b.time)).then(a.id.cmp(&b.id)).then(ib.cmp(ia))
    });
    let (n, bpt) = (grid.tile as usize, grid.bytes_per_texel);
    let base = [s * n as i64, t * n as i64];
    let mut cols: Vec<usize> = Vec::with_capacity(n);
    for (_, c) in candidates {
        let (Some([x0, x1]), Some([y0, y1])) = (span(grid, c, 0, base[0], n), span(grid, c, 1, base[1], n)) else {
            continue;
        };
        let w = c.width as usize;
        cols.clear();
        cols.extend((x0..x1).map(|x| pixel(c, 0, grid.texel_centre(base[0] + x as i64, 0)[0]) * bpt));
        // A patch at the grid's resolution (and aligned to it) maps a run of texels to a run of
        // pixels: its rows are copied whole.
        let run = cols.windows(2).all(|p| p[1] == p[0] + bpt);
        for y in y0..y1 {
            let v = pixel(c, 1, grid.texel_centre(0, base[1] + y as i64)[1]);
            let src = &c.texels[v * w * bpt..(v + 1) * w * bpt];
            let row = &mut out.texels[(y * n + x0) * bpt..(y * n + x1) * bpt];
            if run {
                row.copy_from_slice(&src[cols[0]..cols[0] + row.len()]);
                out.has_data.set_run(y * n + x0, y * n + x1);
                continue;
            }
            match bpt {
                1 => gather::<1>(row, src, &cols),
                2 => gather::<2>(row, src, &cols),
                3 => gather::<3>(row, src, &cols),
                4 => gather::<4>(row, src, &cols),
                6 => gather::<6>(row, src, &cols),
                8 => gather::<8>(row, src, &cols),
                _ => {
                    for (dst, &u) in row.chunks_exact_mut(bpt).zip(&cols) {
                        dst.copy_from_slice(&src[u..u + bpt]);
                    }
                }
            }
            out.has_data.set_run(y * n + x0, y * n + x1);
        }
    }
    out.counted()
}

/// Texels of `B` bytes from `src` at byte offsets `cols` into `row`, in order (a copy of a known
/// size per texel, not a call).
fn gather<const B: usize>(row: &mut [u8], src: &[u8], cols: &[usize]) {
    for (dst, &u) in row.chunks_exact_mut(B).zip(cols) {
        let texel: [u8; B] = src[u..u + B].try_into().expect("B bytes");
        dst.copy_from_slice(&texel);
    }
}

/// The texels `[a, b)` of a tile (its first level-0 texel along `axis` is `base`, `n` texels a
/// side) whose centres lie in the patch's box along that axis; `None` when none do. Starts from
/// the closed form and corrects it by the centre test itself, so it agrees with
/// [`WorldBox::contains`] at every edge, whatever the rounding.
fn span(grid: &Grid, p: &Patch, axis: usize, base: i64, n: usize) -> Option<[usize; 2]> {
    let centre = |i: i64| if axis == 0 { grid.texel_centre(i, 0)[0] } else { grid.texel_centre(0, i)[1] };
    // The first texel whose centre is at or past `v`: the centres grow with the index, so the
    // texels inside [min, max) are those from threshold(min) up to threshold(max).
    let threshold = |v: f64| {
        let mut i = ((v - grid.origin[axis]) * grid.texels_per_unit - 0.5).ceil() as i64;
        while centre(i - 1) >= v {
            i -= 1;
        }
        while centre(i) < v {
            i += 1;
        }
        i
    };
    let end = base + n as i64;
    let a = threshold(p.bbox.min[axis]).clamp(base, end);
    let b = threshold(p.bbox.max[axis]).clamp(base, end);
    (a < b).then(|| [(a - base) as usize, (b - base) as usize])
}

/// The patch's pixel (column for axis 0, row for axis 1) at world coordinate `c` inside its box:
/// as [`Patch::sample`] picks it.
fn pixel(p: &Patch, axis: usize, c: f64) -> usize {
    let size = if axis == 0 { p.width } else { p.height } as i64;
    let (min, max) = (p.bbox.min[axis], p.bbox.max[axis]);
    // Columns count from the box's left edge, rows from its top (the largest y), as in image files.
    let from_edge = if axis == 0 { c - min } else { max - c };
    ((from_edge / (max - min) * size as f64) as i64).clamp(0, size - 1) as usize
}

/// Level-0 tile (s, t) with the patches' edges feathered over `feather` level-0 texels (the
/// optional blend; `feather` > 0): at each texel, the patches whose boxes hold its centre, best
/// first ([`Patch::beats`]), are laid one over the next with an opacity `a = min(1, d / feather)`,
/// `d` the distance in level-0 texels from the texel's centre to the patch's nearest box edge
/// (the last one opaque): `v = a1 v1 + (1 - a1) (a2 v2 + (1 - a2) (... v_n))`, per component in
/// f64, rounded half up. Deep inside the best patch (`d >= feather`) this is the best patch's
/// texel, as without the blend; towards its edge it fades into what lies beneath it, so patch
/// edges leave no seam. Searched per texel rather than painted: the blend is the slower path.
pub(crate) fn level0_tile_feathered(grid: &Grid, index: &PatchIndex, s: i64, t: i64, feather: f64) -> Tile {
    let mut out = Tile::empty(grid);
    let mut cands: Vec<&Arc<Patch>> = index.for_tile(grid, 0, s, t);
    if cands.is_empty() {
        return out;
    }
    cands.sort_by(|a, b| b.rating.total_cmp(&a.rating).then(b.time.cmp(&a.time)).then(b.id.cmp(&a.id)));
    let (n, bpt, cb) = (grid.tile as usize, grid.bytes_per_texel, grid.component_bytes);
    let comps = bpt / cb;
    let max = if cb == 1 { 255.0 } else { 65535.0 };
    let mut over: Vec<(&Arc<Patch>, f64)> = Vec::with_capacity(cands.len());
    let mut acc = vec![0f64; comps];
    for y in 0..n {
        for x in 0..n {
            let c = grid.texel_centre(s * n as i64 + x as i64, t * n as i64 + y as i64);
            over.clear();
            for p in &cands {
                if p.bbox.contains(c) {
                    let b = &p.bbox;
                    let d = (c[0] - b.min[0]).min(b.max[0] - c[0]).min(c[1] - b.min[1]).min(b.max[1] - c[1]);
                    let a = (d * grid.texels_per_unit / feather).min(1.0);
                    over.push((p, a));
                    if a >= 1.0 {
                        break;
                    }
                }
            }
            let Some(last) = over.len().checked_sub(1) else { continue };
            acc.iter_mut().for_each(|v| *v = 0.0);
            let mut rest = 1.0;
            for (i, (p, a)) in over.iter().enumerate() {
                let a = if i == last { 1.0 } else { *a };
                let v = p.sample(c, bpt);
                for (ci, sum) in acc.iter_mut().enumerate() {
                    let at = ci * cb;
                    let value = if cb == 1 { v[at] as f64 } else { u16::from_le_bytes([v[at], v[at + 1]]) as f64 };
                    *sum += rest * a * value;
                }
                rest *= 1.0 - a;
            }
            let o = (y * n + x) * bpt;
            for (ci, sum) in acc.iter().enumerate() {
                let v = (sum + 0.5).floor().clamp(0.0, max);
                if cb == 1 {
                    out.texels[o + ci] = v as u8;
                } else {
                    out.texels[o + 2 * ci..o + 2 * ci + 2].copy_from_slice(&(v as u16).to_le_bytes());
                }
            }
            out.has_data.set(y * n + x);
        }
    }
    out.counted()
}

/// Tile (s, t) of level k > 0 from its four children of level k-1 (`children[dy][dx]` is child
/// (2s + dx, 2t + dy); `None` for a child with no data at all): each texel the rounded average,
/// per component, of the children's texels under it that have data.
pub(crate) fn parent_tile(grid: &Grid, children: [[Option<&Tile>; 2]; 2]) -> Tile {
    let mut out = Tile::empty(grid);
    let (n, h) = (grid.tile as usize, grid.tile as usize / 2);
    let (bpt, cb) = (grid.bytes_per_texel, grid.component_bytes);
    let comps = bpt / cb;
    // Tiles of one texel: the parent's only texel lies over the four children's only texels.
    if n == 1 {
        let under: Vec<(&Tile, usize)> = children.iter().flatten().flatten().map(|c| (*c, 0)).collect();
        average(&under, &mut out, 0, comps, cb);
        return out.counted();
    }
    let mut under: Vec<(&Tile, usize)> = Vec::with_capacity(4);
    for (cy, row) in children.iter().enumerate() {
        for (cx, child) in row.iter().enumerate() {
            let Some(child) = child else { continue };
            if cb == 1 && child.full() {
                // The common case, a child with data everywhere: whole rows of 8-bit texels.
                let rows = QuadrantRows { n, h, cx, cy };
                match bpt {
                    1 => rows.average8::<1>(child, &mut out),
                    2 => rows.average8::<2>(child, &mut out),
                    3 => rows.average8::<3>(child, &mut out),
                    4 => rows.average8::<4>(child, &mut out),
                    b => rows.average8_any(b, child, &mut out),
                }
                continue;
            }
            for y in 0..h {
                let o_row = (cy * h + y) * n + cx * h;
                let i_row = 2 * y * n;
                for x in 0..h {
                    let (i, o) = (i_row + 2 * x, o_row + x);
                    let quad = [i, i + 1, i + n, i + n + 1];
                    let d = |q: usize| child.has(q);
                    if cb == 1 && d(quad[0]) && d(quad[1]) && d(quad[2]) && d(quad[3]) {
                        // The common case: four 8-bit texels with data, averaged in place.
                        let t = &child.texels;
                        let dst = &mut out.texels[o * bpt..(o + 1) * bpt];
                        for (c, v) in dst.iter_mut().enumerate() {
                            let sum = t[quad[0] * bpt + c] as u32
                                + t[quad[1] * bpt + c] as u32
                                + t[quad[2] * bpt + c] as u32
                                + t[quad[3] * bpt + c] as u32;
                            *v = ((sum + 2) / 4) as u8;
                        }
                        out.has_data.set(o);
                        continue;
                    }
                    under.clear();
                    under.extend(quad.iter().filter(|&&q| d(q)).map(|&q| (*child, q)));
                    average(&under, &mut out, o, comps, cb);
                }
            }
        }
    }
    out.counted()
}

/// The quadrant of a parent tile (`n` texels a side, `h` = n / 2) that child (`cx`, `cy`) covers.
struct QuadrantRows {
    n: usize,
    h: usize,
    cx: usize,
    cy: usize,
}

impl QuadrantRows {
    /// The quadrant from a child whose texels all have data, 8-bit components, `B` bytes a
    /// texel: each texel the rounded average of the 2 x 2 below it.
    fn average8<const B: usize>(&self, child: &Tile, out: &mut Tile) {
        let (n, h) = (self.n, self.h);
        // Each pair of rows summed down first (a loop the compiler vectorises), then pairs of
        // neighbouring texels across.
        let mut down = vec![0u16; n * B];
        for y in 0..h {
            let r0 = &child.texels[2 * y * n * B..(2 * y + 1) * n * B];
            let r1 = &child.texels[(2 * y + 1) * n * B..(2 * y + 2) * n * B];
            for ((d, &a), &b) in down.iter_mut().zip(r0).zip(r1) {
                *d = a as u16 + b as u16;
            }
            let o = ((self.cy * h + y) * n + self.cx * h) * B;
            let dst = &mut out.texels[o..o + h * B];
            for (d, pair) in dst.chunks_exact_mut(B).zip(down.chunks_exact(2 * B)) {
                for c in 0..B {
                    d[c] = ((pair[c] + pair[B + c] + 2) / 4) as u8;
                }
            }
            out.has_data.set_run(o / B, o / B + h);
        }
    }

    /// [`Self::average8`] for any number of bytes a texel.
    fn average8_any(&self, bpt: usize, child: &Tile, out: &mut Tile) {
        let (n, h) = (self.n, self.h);
        for y in 0..h {
            for x in 0..h {
                let i = 2 * y * n + 2 * x;
                let o = (self.cy * h + y) * n + self.cx * h + x;
                for c in 0..bpt {
                    let t = |q: usize| child.texels[q * bpt + c] as u16;
                    out.texels[o * bpt + c] = ((t(i) + t(i + 1) + t(i + n) + t(i + n + 1) + 2) / 4) as u8;
                }
                out.has_data.set(o);
            }
        }
    }
}

/// Texel `o` of `out` as the rounded average, per component, of the texels `under` (tile and
/// texel index; all with data); left without data when `under` is empty.
fn average(under: &[(&Tile, usize)], out: &mut Tile, o: usize, comps: usize, cb: usize) {
    if under.is_empty() {
        return;
    }
    let (bpt, count) = (comps * cb, under.len() as u64);
    for c in 0..comps {
        let sum: u64 = under
            .iter()
            .map(|&(t, i)| {
                let at = i * bpt + c * cb;
                if cb == 1 {
                    t.texels[at] as u64
                } else {
                    u16::from_le_bytes([t.texels[at], t.texels[at + 1]]) as u64
                }
            })
            .sum();
        let avg = (sum + count / 2) / count;
        let at = o * bpt + c * cb;
        if cb == 1 {
            out.texels[at] = avg as u8;
        } else {
            out.texels[at..at + 2].copy_from_slice(&(avg as u16).to_le_bytes());
        }
    }
    out.has_data.set(o);
}

/// The tiles of a growing texture and those waiting to be rebuilt.
pub struct Rebuilder {
    grid: Grid,
    tiles: HashMap<TileKey, Arc<Tile>>,
    /// Waiting, in rebuild order: by level, then T, then S.
    dirty: BTreeSet<(u32, i64, i64)>,
    /// Tiles whose content changed (or that were dropped) since [`Rebuilder::take_changed`].
    changed: BTreeSet<TileKey>,
    /// Levels the texture has.
    levels: u32,
    /// Level-0 texels over which patch edges are feathered (0: the best patch wins outright).
    feather: f64,
}

impl Rebuilder {
    /// Nothing built yet.
    pub fn new(grid: Grid) -> Self {
        Rebuilder::restore(grid, HashMap::new(), 0)
    }

    /// Tiles built earlier (read back from a store) and the levels the texture had then.
    pub(crate) fn restore(grid: Grid, tiles: HashMap<TileKey, Arc<Tile>>, levels: u32) -> Self {
        Rebuilder { grid, tiles, dirty: BTreeSet::new(), changed: BTreeSet::new(), levels, feather: 0.0 }
    }

    /// Feathers patch edges over `texels` level-0 texels from now on ([`level0_tile_feathered`];
    /// 0: off). Tiles built before keep what they hold until rebuilt.
    pub(crate) fn set_feather(&mut self, texels: f64) {
        self.feather = if texels.is_finite() && texels > 0.0 { texels } else { 0.0 };
    }

    /// The feather width in level-0 texels (0: off).
    pub fn feather(&self) -> f64 {
        self.feather
    }

    /// Marks every tile of every level that `patch` may change, whatever is built now: what a
    /// restart does for the patches whose rebuild it cannot know finished (a tile rebuilt before
    /// a crash would otherwise look unchanged, and its parent would never learn of the patch).
    pub(crate) fn mark_footprint(&mut self, index: &PatchIndex, patch: &Patch) {
        self.patch_added(index, patch);
        for k in 1..self.levels {
            if let Some([s0, t0, s1, t1]) = PatchIndex::tiles_of(&self.grid, patch, k) {
                for t in t0..t1 {
                    for s in s0..s1 {
                        self.dirty.insert((k, t, s));
                    }
                }
            }
        }
    }

    /// Marks tile (s, t) of level k to be rebuilt (a damaged file, say).
    pub(crate) fn mark_tile(&mut self, k: u32, s: i64, t: i64) {
        self.dirty.insert((k, t, s));
    }

    /// The tiles whose content changed or that were dropped since the last call, in key order
    /// (what a store must write or delete).
    pub(crate) fn take_changed(&mut self) -> Vec<TileKey> {
        std::mem::take(&mut self.changed).into_iter().collect()
    }

    /// Puts back tiles [`Rebuilder::take_changed`] handed out that could not be saved.
    pub(crate) fn unsaved(&mut self, keys: impl IntoIterator<Item = TileKey>) {
        self.changed.extend(keys);
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Marks what a newly indexed `patch` changes: its level-0 tiles (each rebuilt tile then marks
    /// its parent, so the change climbs to the top). When the patch made the texture grow new
    /// coarser levels, every tile of the old top level marks its new parent too, so that the new
    /// top is built from everything below it.
    pub fn patch_added(&mut self, index: &PatchIndex, patch: &Patch) {
        let levels = index.levels(&self.grid).max(1);
        if levels > self.levels {
            let old_top = self.levels.checked_sub(1);
            let tops: Vec<TileKey> = self.tiles.keys().filter(|k| Some(k.0) == old_top).copied().collect();
            self.levels = levels;
            for (k, s, t) in tops {
                self.mark_parent(k, s, t);
            }
        }
        if let Some([s0, t0, s1, t1]) = PatchIndex::tiles_of(&self.grid, patch, 0) {
            for t in t0..t1 {
                for s in s0..s1 {
                    self.dirty.insert((0, t, s));
                }
            }
        }
    }

    fn mark_parent(&mut self, k: u32, s: i64, t: i64) {
        if k + 1 < self.levels {
            self.dirty.insert((k + 1, t.div_euclid(2), s.div_euclid(2)));
        }
    }

    /// Number of tiles waiting.
    pub fn pending(&self) -> usize {
        self.dirty.len()
    }

    /// Levels the texture has now.
    pub fn levels(&self) -> u32 {
        self.levels
    }

    /// Rebuilds at most `max` waiting tiles, lowest level first (a parent after its children);
    /// returns the tiles rebuilt, in order. A tile with no data is dropped rather than kept.
    /// The waiting tiles of one level are built side by side (rayon): none reads another.
    pub fn step(&mut self, index: &PatchIndex, max: usize) -> Vec<TileKey> {
        let mut done = Vec::new();
        while done.len() < max {
            let Some(&(k, _, _)) = self.dirty.first() else { break };
            let mut batch = Vec::new();
            while batch.len() < max - done.len() {
                match self.dirty.first() {
                    Some(&(level, t, s)) if level == k => {
                        self.dirty.pop_first();
                        batch.push((k, s, t));
                    }
                    _ => break,
                }
            }
            let built: Vec<Tile> = batch.par_iter().map(|&(k, s, t)| self.build(index, k, s, t)).collect();
            for ((k, s, t), tile) in batch.into_iter().zip(built) {
                let changed = match (tile.any_data(), self.tiles.get(&(k, s, t))) {
                    (true, Some(old)) => **old != tile,
                    (true, None) => true,
                    (false, old) => old.is_some(),
                };
                if tile.any_data() {
                    self.tiles.insert((k, s, t), Arc::new(tile));
                } else {
                    self.tiles.remove(&(k, s, t));
                }
                if changed {
                    self.changed.insert((k, s, t));
                    self.mark_parent(k, s, t);
                }
                done.push((k, s, t));
            }
        }
        done
    }

    /// Tile (s, t) of level k from what is built below it (level 0: from the patches).
    fn build(&self, index: &PatchIndex, k: u32, s: i64, t: i64) -> Tile {
        if k == 0 {
            if self.feather > 0.0 {
                return level0_tile_feathered(&self.grid, index, s, t, self.feather);
            }
            return level0_tile(&self.grid, index, s, t);
        }
        let child = |dx: i64, dy: i64| self.tiles.get(&(k - 1, 2 * s + dx, 2 * t + dy)).map(|t| &**t);
        parent_tile(&self.grid, [[child(0, 0), child(1, 0)], [child(0, 1), child(1, 1)]])
    }

    /// Tile (s, t) of level k as built (`None`: no data there, or not built yet).
    pub fn tile(&self, k: u32, s: i64, t: i64) -> Option<&Arc<Tile>> {
        self.tiles.get(&(k, s, t))
    }

    /// Number of tiles built (with data).
    pub fn len(&self) -> usize {
        self.tiles.len()
    }

    /// Whether no tile is built.
    pub fn is_empty(&self) -> bool {
        self.tiles.is_empty()
    }

    /// Every built tile's key.
    pub fn keys(&self) -> impl Iterator<Item = &TileKey> {
        self.tiles.keys()
    }
}
