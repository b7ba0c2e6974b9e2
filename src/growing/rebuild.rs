//! Rebuilding the tiles of a growing texture: level 0 from the patches, coarser levels from their
//! four children, in increasing level order, a bounded number per step.

use super::index::PatchIndex;
use super::{Grid, Patch};
use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;

/// A tile's key: level, S, T.
pub type TileKey = (u32, i64, i64);

/// A rebuilt tile: its texels, and which of them have data (`false`: no patch covers the texel,
/// or nothing below it has data; its bytes are zero).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Tile {
    /// `tile * tile * bytes_per_texel` bytes, row-major.
    pub texels: Vec<u8>,
    /// One flag per texel.
    pub has_data: Vec<bool>,
}

impl Tile {
    fn empty(grid: &Grid) -> Tile {
        let n = (grid.tile * grid.tile) as usize;
        Tile { texels: vec![0; n * grid.bytes_per_texel], has_data: vec![false; n] }
    }

    /// Whether any texel has data.
    pub fn any_data(&self) -> bool {
        self.has_data.iter().any(|&d| d)
    }
}

/// Level-0 tile (s, t) from the patches of `index` that meet it: each texel from the winning
/// patch ([`Patch::beats`]) among those whose box holds the texel's centre, sampled there.
pub fn level0_tile(grid: &Grid, index: &PatchIndex, s: i64, t: i64) -> Tile {
    let mut out = Tile::empty(grid);
    let candidates = index.for_tile(grid, 0, s, t);
    if candidates.is_empty() {
        return out;
    }
    let (n, bpt) = (grid.tile as i64, grid.bytes_per_texel);
    for y in 0..n {
        for x in 0..n {
            let p = grid.texel_centre(s * n + x, t * n + y);
            let mut best: Option<&Arc<Patch>> = None;
            for c in &candidates {
                if c.bbox.contains(p) && best.is_none_or(|b| c.beats(b)) {
                    best = Some(c);
                }
            }
            if let Some(b) = best {
                let i = (y * n + x) as usize;
                out.texels[i * bpt..(i + 1) * bpt].copy_from_slice(b.sample(p, bpt));
                out.has_data[i] = true;
            }
        }
    }
    out
}

/// Tile (s, t) of level k > 0 from its four children of level k-1 (`children[dy][dx]` is child
/// (2s + dx, 2t + dy); `None` for a child with no data at all): each texel the rounded average,
/// per component, of the children's texels under it that have data.
pub fn parent_tile(grid: &Grid, children: [[Option<&Tile>; 2]; 2]) -> Tile {
    let mut out = Tile::empty(grid);
    let n = grid.tile as usize;
    let (bpt, cb) = (grid.bytes_per_texel, grid.component_bytes);
    let comps = bpt / cb;
    let mut sum = vec![0u64; comps];
    for y in 0..n {
        for x in 0..n {
            // The 2x2 texels of level k-1 under (x, y), all in one child.
            let (cx, cy) = ((2 * x) / n, (2 * y) / n);
            let Some(child) = children[cy][cx] else { continue };
            let (bx, by) = ((2 * x) % n, (2 * y) % n);
            sum.iter_mut().for_each(|v| *v = 0);
            let mut count = 0u64;
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let i = (by + dy) * n + bx + dx;
                if !child.has_data[i] {
                    continue;
                }
                count += 1;
                for (c, v) in sum.iter_mut().enumerate() {
                    let at = i * bpt + c * cb;
                    *v += if cb == 1 {
                        child.texels[at] as u64
                    } else {
                        u16::from_le_bytes([child.texels[at], child.texels[at + 1]]) as u64
                    };
                }
            }
            if count == 0 {
                continue;
            }
            let o = y * n + x;
            out.has_data[o] = true;
            for (c, v) in sum.iter().enumerate() {
                let avg = (v + count / 2) / count;
                let at = o * bpt + c * cb;
                if cb == 1 {
                    out.texels[at] = avg as u8;
                } else {
                    out.texels[at..at + 2].copy_from_slice(&(avg as u16).to_le_bytes());
                }
            }
        }
    }
    out
}

/// The tiles of a growing texture and those waiting to be rebuilt.
pub struct Rebuilder {
    grid: Grid,
    tiles: HashMap<TileKey, Tile>,
    /// Waiting, in rebuild order: by level, then T, then S.
    dirty: BTreeSet<(u32, i64, i64)>,
    /// Levels the texture has.
    levels: u32,
}

impl Rebuilder {
    /// Nothing built yet.
    pub fn new(grid: Grid) -> Self {
        Rebuilder { grid, tiles: HashMap::new(), dirty: BTreeSet::new(), levels: 0 }
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
    pub fn step(&mut self, index: &PatchIndex, max: usize) -> Vec<TileKey> {
        let mut done = Vec::new();
        while done.len() < max {
            let Some((k, t, s)) = self.dirty.pop_first() else { break };
            let tile = if k == 0 {
                level0_tile(&self.grid, index, s, t)
            } else {
                let child = |dx: i64, dy: i64| self.tiles.get(&(k - 1, 2 * s + dx, 2 * t + dy));
                parent_tile(&self.grid, [[child(0, 0), child(1, 0)], [child(0, 1), child(1, 1)]])
            };
            let changed = match (tile.any_data(), self.tiles.get(&(k, s, t))) {
                (true, Some(old)) => *old != tile,
                (true, None) => true,
                (false, old) => old.is_some(),
            };
            if tile.any_data() {
                self.tiles.insert((k, s, t), tile);
            } else {
                self.tiles.remove(&(k, s, t));
            }
            if changed {
                self.mark_parent(k, s, t);
            }
            done.push((k, s, t));
        }
        done
    }

    /// Tile (s, t) of level k as built (`None`: no data there, or not built yet).
    pub fn tile(&self, k: u32, s: i64, t: i64) -> Option<&Tile> {
        self.tiles.get(&(k, s, t))
    }

    /// Every built tile's key.
    pub fn keys(&self) -> impl Iterator<Item = &TileKey> {
        self.tiles.keys()
    }
}
