//! The patches of a growing texture, indexed by bounding box in an R*-tree (`rstar`): which
//! patches a tile needs, and which tiles a patch touches.

use super::{Grid, Patch, WorldBox};
use rstar::primitives::{GeomWithData, Rectangle};
use rstar::{RTree, AABB};
use std::sync::Arc;

type Entry = GeomWithData<Rectangle<[f64; 2]>, usize>;

/// Every patch accepted so far, and an R*-tree of their boxes.
#[derive(Default)]
pub struct PatchIndex {
    patches: Vec<Arc<Patch>>,
    tree: RTree<Entry>,
    /// Union of the boxes.
    extent: Option<WorldBox>,
}

impl PatchIndex {
    /// An empty index.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a patch (checked by [`Patch::new`]).
    pub fn insert(&mut self, patch: Patch) -> Arc<Patch> {
        let b = patch.bbox;
        let patch = Arc::new(patch);
        self.tree.insert(GeomWithData::new(Rectangle::from_corners(b.min, b.max), self.patches.len()));
        self.patches.push(Arc::clone(&patch));
        self.extent = Some(match self.extent {
            None => b,
            Some(e) => WorldBox {
                min: [e.min[0].min(b.min[0]), e.min[1].min(b.min[1])],
                max: [e.max[0].max(b.max[0]), e.max[1].max(b.max[1])],
            },
        });
        patch
    }

    /// Number of patches.
    pub fn len(&self) -> usize {
        self.patches.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.patches.is_empty()
    }

    /// Every patch, in the order they came.
    pub fn patches(&self) -> &[Arc<Patch>] {
        &self.patches
    }

    /// The union of every patch's box (`None` while empty).
    pub fn extent(&self) -> Option<WorldBox> {
        self.extent
    }

    /// The patches whose boxes meet `b` (touching counts), in the order they came.
    pub(crate) fn meeting(&self, b: &WorldBox) -> Vec<&Arc<Patch>> {
        let env = AABB::from_corners(b.min, b.max);
        let mut found: Vec<usize> = self.tree.locate_in_envelope_intersecting(&env).map(|e| e.data).collect();
        found.sort_unstable();
        found.into_iter().map(|i| &self.patches[i]).collect()
    }

    /// The patches tile (s, t) of level `k` needs: those whose boxes meet the tile's.
    pub(crate) fn for_tile(&self, grid: &Grid, k: u32, s: i64, t: i64) -> Vec<&Arc<Patch>> {
        self.meeting(&grid.tile_box(k, s, t))
    }

    /// The level-`k` tiles `patch` may change, `[s0, s1) x [t0, t1)`, one texel wider on each
    /// side than the texels whose centres it covers (so that rounding at the box's edges never
    /// leaves out a tile); `None` when it covers no texel centre.
    pub(crate) fn tiles_of(grid: &Grid, patch: &Patch, k: u32) -> Option<[i64; 4]> {
        let [i0, j0, i1, j1] = grid.texels_in(&patch.bbox);
        if i0 >= i1 || j0 >= j1 {
            return None;
        }
        grid.tiles_over([i0 - 1, j0 - 1, i1 + 1, j1 + 1], k)
    }

    /// The number of levels the texture needs now: level 0, and coarser ones until the level-0
    /// tiles under the extent fit in at most 2 x 2 tiles of the top level. (At most 2, not 1: a
    /// grid anchored at the origin splits an extent that crosses it at every level. The count
    /// only grows as the extent does.) 0 while empty.
    pub fn levels(&self, grid: &Grid) -> u32 {
        let Some(e) = self.extent else { return 0 };
        let Some(t0) = grid.tiles_over(grid.texels_in(&e), 0) else { return 1 };
        let mut k = 0;
        loop {
            let span = 1i64 << k;
            let w = (t0[2] - 1).div_euclid(span) - t0[0].div_euclid(span) + 1;
            let h = (t0[3] - 1).div_euclid(span) - t0[1].div_euclid(span) + 1;
            if (w <= 2 && h <= 2) || k >= 40 {
                return k + 1;
            }
            k += 1;
        }
    }
}
