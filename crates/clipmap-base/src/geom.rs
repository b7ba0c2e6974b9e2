//! Level geometry: where each level's window, valid region and tile grid lie for a given centre.
//!
//! Owns the pure arithmetic of clipmaps, in 64-bit integers: per-level centres, the tex region
//! (the clip-size window centred on the level centre, translated to stay inside the level,
//! docs/PERFORMER-REFERENCE.md §2.2), the valid region (tex region less the invalid border), toroidal addressing,
//! and the mem region (the tile grid covering the tex region plus `lookahead` tiles, docs/ARCHITECTURE.md §3).
//! Everything here is a synchronous function of its arguments; holding tiles and texels is left
//! to `clipmap::cache` and `clipmap::clip`.
//!
//! Bounds: level sizes are at most 2^30 and clip sizes at most 2^30, so every coordinate a
//! window can take fits in an `i64` with room to spare; arbitrary (even extreme) centres are
//! handled with saturating arithmetic before clamping.

use serde::Serialize;

/// A half-open rectangle `[s0, s1) x [t0, t1)`, in level texels or in tiles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize)]
pub struct Rect {
    /// First column.
    pub s0: i64,
    /// First row.
    pub t0: i64,
    /// One past the last column.
    pub s1: i64,
    /// One past the last row.
    pub t1: i64,
}

impl Rect {
    /// The empty rectangle.
    pub const EMPTY: Rect = Rect { s0: 0, t0: 0, s1: 0, t1: 0 };

    /// `[s0, s1) x [t0, t1)`.
    #[inline]
    pub const fn new(s0: i64, t0: i64, s1: i64, t1: i64) -> Self {
        Rect { s0, t0, s1, t1 }
    }

    /// Whether it holds no texel.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.s1 <= self.s0 || self.t1 <= self.t0
    }

    /// Columns (0 when empty).
    #[inline]
    pub fn width(&self) -> u64 {
        if self.is_empty() {
            0
        } else {
            (self.s1 - self.s0) as u64
        }
    }

    /// Rows (0 when empty).
    #[inline]
    pub fn height(&self) -> u64 {
        if self.is_empty() {
            0
        } else {
            (self.t1 - self.t0) as u64
        }
    }

    /// Number of texels (or tiles).
    #[inline]
    pub fn area(&self) -> u64 {
        self.width() * self.height()
    }

    /// Whether (s, t) lies inside.
    #[inline]
    pub fn contains(&self, s: i64, t: i64) -> bool {
        s >= self.s0 && s < self.s1 && t >= self.t0 && t < self.t1
    }

    /// Whether `other` lies entirely inside (an empty `other` always does).
    #[inline]
    pub fn contains_rect(&self, other: &Rect) -> bool {
        other.is_empty() || (other.s0 >= self.s0 && other.s1 <= self.s1 && other.t0 >= self.t0 && other.t1 <= self.t1)
    }

    /// The common part ([`Rect::EMPTY`] if none).
    #[inline]
    pub fn intersect(&self, other: &Rect) -> Rect {
        let r = Rect::new(self.s0.max(other.s0), self.t0.max(other.t0), self.s1.min(other.s1), self.t1.min(other.t1));
        if r.is_empty() {
            Rect::EMPTY
        } else {
            r
        }
    }
}

/// Level `k`'s default centre: level 0's centre shifted right by `k` (floor, also for negative
/// centres), so the windows of all levels are concentric.
#[inline]
pub fn default_centre(centre0: [i64; 2], k: u32) -> [i64; 2] {
    let k = k.min(63);
    [centre0[0] >> k, centre0[1] >> k]
}

/// Level `k`'s centre when level centres are aligned down to multiples of `alignment` level
/// texels (Performer's "shift and mask"; floor also for negative centres). `alignment` 0 or 1
/// gives [`default_centre`].
#[inline]
pub fn aligned_centre(centre0: [i64; 2], k: u32, alignment: u64) -> [i64; 2] {
    let c = default_centre(centre0, k);
    let a = alignment.clamp(1, 1 << 62) as i64;
    // Saturating: near i64::MIN the multiple below may not exist.
    c.map(|x| x.saturating_sub(x.rem_euclid(a)))
}

/// Euclidean `x mod m` (in `0..m` also for negative `x`). `m` must be in 1..=2^62.
#[inline]
pub fn wrap(x: i64, m: u64) -> u64 {
    x.rem_euclid(m as i64) as u64
}

/// Offset of level texel (s, t) in a toroidal window of `clip` texels a side whose buffer is
/// `dims` texels (dims are `min(clip, level size)` per axis). Texels are `(s mod clip, t mod clip)`
/// of the window, rows of `dims[0]` texels.
#[inline]
pub fn window_index(s: i64, t: i64, clip: u64, dims: [u64; 2]) -> usize {
    (wrap(t, clip) * dims[0] + wrap(s, clip)) as usize
}

/// Whether a level of a texture that spans 360 degrees of longitude (`global`) wraps along s:
/// it is wider than the clip size (a narrower one is resident whole along s) and its width is a
/// whole number of tiles (so its tile grid repeats modulo the width: tile `n` is tile 0 again).
/// Such a level's window is never translated to stay inside it along s: it crosses the
/// antimeridian, and texel s of it is texel `s mod width`.
#[inline]
pub fn level_wraps(global: bool, size: [u64; 2], tile: [u64; 2], clip: u64) -> bool {
    global && size[0] > clip && tile[0] > 0 && size[0].is_multiple_of(tile[0])
}

/// The grid width a wrapping level uses: the least divisor of `tiles` (the level's tiles
/// across) that is at least `grid`. Slots are tile S mod grid width; a wrapping window holds
/// tiles `n - 1` and `0` side by side, and only a grid width that divides `n` gives every run of
/// `grid` consecutive tiles, taken modulo `n`, distinct slots.
pub fn wrap_grid(tiles: u64, grid: u64) -> u64 {
    let grid = grid.clamp(1, tiles.max(1));
    (grid..=tiles).find(|d| tiles.is_multiple_of(*d)).unwrap_or(tiles.max(1))
}

/// Whether (s, t) lies in `r`, s taken modulo `period` when one is given (a wrapping level's
/// region, whose s-range may run past the level's width: `[s0, s1)` with `s1 - s0 <= period`).
#[inline]
pub fn contains_wrapped(r: &Rect, s: i64, t: i64, period: Option<u64>) -> bool {
    match period {
        None => r.contains(s, t),
        Some(p) => {
            let d = (s as i128 - r.s0 as i128).rem_euclid(p.max(1) as i128);
            !r.is_empty() && t >= r.t0 && t < r.t1 && (r.s0 as i128 + d) < r.s1 as i128
        }
    }
}

/// `r` moved along s by the multiple of `period` that puts its first column nearest `near`
/// (ties: the lower); `r` itself when empty.
#[inline]
pub fn shift_near(r: Rect, period: u64, near: i64) -> Rect {
    if r.is_empty() || period == 0 {
        return r;
    }
    let p = period as i64;
    let to = near - p / 2;
    let s0 = to + wrap(r.s0 - to, period) as i64;
    let d = s0 - r.s0;
    Rect::new(r.s0 + d, r.t0, r.s1 + d, r.t1)
}

/// One axis of the tex region: `[lo, lo + min(clip, size))` with `lo` as close to
/// `centre - clip/2` as the level allows.
fn window_axis(size: u64, clip: u64, centre: i64) -> (i64, i64) {
    if size <= clip {
        return (0, size as i64);
    }
    let lo = centre.saturating_sub((clip / 2) as i64).clamp(0, (size - clip) as i64);
    (lo, lo + clip as i64)
}

/// [`tex_region`] of a level that wraps along s ([`level_wraps`]): along s the window is centred
/// on the centre taken modulo the width and never translated, its first column in
/// `[0, width)` and its last possibly past the width (read modulo the width).
#[inline]
pub fn wrapping_tex_region(size: [u64; 2], clip: u64, centre: [i64; 2]) -> Rect {
    let lo = wrap(centre[0].saturating_sub((clip / 2) as i64), size[0]) as i64;
    let (t0, t1) = window_axis(size[1], clip, centre[1]);
    Rect::new(lo, t0, lo + clip.min(size[0]) as i64, t1)
}

/// The tex region of a level of `size` texels: the clip-size window centred on `centre`,
/// translated (never shrunk) to stay inside the level; the whole level on axes no larger than the
/// clip size.
#[inline]
pub fn tex_region(size: [u64; 2], clip: u64, centre: [i64; 2]) -> Rect {
    let (s0, s1) = window_axis(size[0], clip, centre[0]);
    let (t0, t1) = window_axis(size[1], clip, centre[1]);
    Rect::new(s0, t0, s1, t1)
}

/// The part of `tex` renderers may read: `border` texels less on each side along every axis on
/// which the level is larger than the clip size (the whole level is resident on the others),
/// except on a side where the window touches the level's edge.
#[inline]
pub fn valid_region(size: [u64; 2], clip: u64, border: u64, tex: Rect) -> Rect {
    // No border against the level's edge: the window cannot roam past it, so those texels are
    // never updated in place, and renderers keep the finest level up to the texture's edge.
    let lo = |axis: usize, at: i64| if size[axis] > clip && at > 0 { border as i64 } else { 0 };
    let hi = |axis: usize, at: i64| if size[axis] > clip && at < size[axis] as i64 { border as i64 } else { 0 };
    let r = Rect::new(tex.s0 + lo(0, tex.s0), tex.t0 + lo(1, tex.t0), tex.s1 - hi(0, tex.s1), tex.t1 - hi(1, tex.t1));
    if r.is_empty() {
        Rect::EMPTY
    } else {
        r
    }
}

/// [`valid_region`] of a level that wraps along s: along s the border is taken on both sides
/// (the window has no edge there).
#[inline]
pub fn wrapping_valid_region(size: [u64; 2], clip: u64, border: u64, tex: Rect) -> Rect {
    let r = valid_region(size, clip, border, tex);
    if r.is_empty() {
        return Rect::EMPTY;
    }
    // Its first column inside the level: a window starting within `border` of the seam has its
    // valid region start past it, the same columns a width to the west.
    let s0 = tex.s0 + border as i64;
    let west = if s0 >= size[0] as i64 { size[0] as i64 } else { 0 };
    let r = Rect::new(s0 - west, r.t0, tex.s1 - border as i64 - west, r.t1);
    if r.is_empty() {
        Rect::EMPTY
    } else {
        r
    }
}

/// [`mem_region`] of a level that wraps along s: along s the region is placed around the
/// window without staying inside the level, in tile indices that may run past the level's
/// tiles (tile U is tile `U mod n`).
#[inline]
pub fn wrapping_mem_region(size: [u64; 2], tile: [u64; 2], grid: [u64; 2], tex: Rect, velocity: [i64; 2]) -> Rect {
    let n = tiles_in_level(size, tile);
    // The level seen as three copies side by side, the window in the middle one: no edge is
    // near it, so the placement along s is the unclamped one.
    let wide = [size[0] * 3, size[1]];
    let mid = Rect::new(tex.s0 + size[0] as i64, tex.t0, tex.s1 + size[0] as i64, tex.t1);
    let r = mem_region(wide, tile, grid, mid, velocity);
    Rect::new(r.s0 - n[0] as i64, r.t0, r.s1 - n[0] as i64, r.t1)
}

/// The readable edge of a stack window: clip size less twice the border.
#[inline]
pub fn effective_size(clip: u64, border: u64) -> u64 {
    clip.saturating_sub(2 * border)
}

/// Tiles along each axis of a level.
#[inline]
pub fn tiles_in_level(size: [u64; 2], tile: [u64; 2]) -> [u64; 2] {
    [size[0].div_ceil(tile[0]), size[1].div_ceil(tile[1])]
}

/// The tiles (as a rectangle of tile indices) holding every texel of `rect`.
#[inline]
pub fn tiles_covering(rect: Rect, tile: [u64; 2]) -> Rect {
    if rect.is_empty() {
        return Rect::EMPTY;
    }
    let (w, h) = (tile[0] as i64, tile[1] as i64);
    Rect::new(
        rect.s0.div_euclid(w),
        rect.t0.div_euclid(h),
        (rect.s1 - 1).div_euclid(w) + 1,
        (rect.t1 - 1).div_euclid(h) + 1,
    )
}

/// The texels of tile (S, T), clipped to the level.
#[inline]
pub fn tile_texels(size: [u64; 2], tile: [u64; 2], st: [u64; 2]) -> Rect {
    let s0 = (st[0] * tile[0]) as i64;
    let t0 = (st[1] * tile[1]) as i64;
    Rect::new(s0, t0, (s0 + tile[0] as i64).min(size[0] as i64), (t0 + tile[1] as i64).min(size[1] as i64))
}

/// Edge of the mem region in tiles per axis: enough tiles to cover the tex region at any
/// alignment plus `lookahead`, never more than the level has (docs/ARCHITECTURE.md §3: clip 1024, 256-texel
/// tiles, lookahead 1 → 6 x 6).
#[inline]
pub fn mem_grid(size: [u64; 2], tile: [u64; 2], clip: u64, lookahead: u64) -> [u64; 2] {
    let n = tiles_in_level(size, tile);
    let axis = |a: usize| (clip.min(size[a]).div_ceil(tile[a]) + 1 + lookahead).min(n[a]);
    [axis(0), axis(1)]
}

/// The mem region (a rectangle of tile indices, `grid` tiles a side) around `tex`: it holds every
/// tile the tex region touches; the spare tiles go ahead of the motion along each axis where
/// `velocity` is non-zero and are split evenly otherwise; it stays inside the level.
#[inline]
pub fn mem_region(size: [u64; 2], tile: [u64; 2], grid: [u64; 2], tex: Rect, velocity: [i64; 2]) -> Rect {
    let n = tiles_in_level(size, tile);
    let need = tiles_covering(tex, tile);
    let axis = |lo: i64, hi: i64, a: usize| {
        let g = grid[a] as i64;
        let extra = (g - (hi - lo)).max(0);
        let before = match velocity[a].signum() {
            1 => 0,
            -1 => extra,
            _ => extra / 2,
        };
        let o = (lo - before).clamp(0, n[a] as i64 - g);
        (o, o + g)
    };
    let (s0, s1) = axis(need.s0, need.s1, 0);
    let (t0, t1) = axis(need.t0, need.t1, 1);
    Rect::new(s0, t0, s1, t1)
}

/// The mem grid a level uses: `configured` (a configuration's mem region) raised, per axis, to
/// the minimum that covers the tex region at any alignment (`mem_grid` with lookahead 0) and
/// never more than the level has; without one, [`mem_grid`] with `lookahead`.
#[inline]
pub fn level_grid(size: [u64; 2], tile: [u64; 2], clip: u64, lookahead: u64, configured: Option<[u64; 2]>) -> [u64; 2] {
    match configured {
        None => mem_grid(size, tile, clip, lookahead),
        Some(g) => {
            let n = tiles_in_level(size, tile);
            let least = mem_grid(size, tile, clip, 0);
            [g[0].max(least[0]).min(n[0]), g[1].max(least[1]).min(n[1])]
        }
    }
}

/// Everything a level's geometry needs from the engine's settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelShape {
    /// Level size in texels.
    pub size: [u64; 2],
    /// Tile size in texels.
    pub tile: [u64; 2],
    /// Clip size.
    pub clip: u64,
    /// The mem region's edge in tiles per axis (see [`level_grid`]; a divisor of the level's
    /// tiles across when `wrap`, [`wrap_grid`]).
    pub grid: [u64; 2],
    /// Whether the level wraps along s ([`level_wraps`]): its windows cross the antimeridian.
    pub wrap: bool,
}

/// Where a level's regions lie for one centre.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct LevelFrame {
    /// The level centre used.
    pub centre: [i64; 2],
    /// The window the level should hold.
    pub tex: Rect,
    /// The part of it renderers may read once it is up to date.
    pub valid: Rect,
    /// The tiles that should be in main memory.
    pub mem: Rect,
}

impl LevelShape {
    /// A shape whose mem grid is [`mem_grid`] with `lookahead` extra tiles per axis.
    #[inline]
    pub fn new(size: [u64; 2], tile: [u64; 2], clip: u64, lookahead: u64) -> Self {
        LevelShape { size, tile, clip, grid: mem_grid(size, tile, clip, lookahead), wrap: false }
    }

    /// The same shape wrapping along s ([`level_wraps`] decides whether it may): its grid width
    /// raised to a divisor of the level's tiles across ([`wrap_grid`]).
    #[inline]
    pub fn wrapping(self) -> Self {
        let n = tiles_in_level(self.size, self.tile);
        LevelShape { grid: [wrap_grid(n[0], self.grid[0]), self.grid[1]], wrap: true, ..self }
    }

    /// The period of s in tiles (`Some(tiles across)` when the level wraps).
    #[inline]
    pub fn tile_period(&self) -> Option<u64> {
        self.wrap.then(|| tiles_in_level(self.size, self.tile)[0])
    }

    /// The period of s in texels (`Some(width)` when the level wraps).
    #[inline]
    pub fn texel_period(&self) -> Option<u64> {
        self.wrap.then_some(self.size[0])
    }

    /// The level's regions for `centre` (in level texels), `border` and direction of motion.
    #[inline]
    pub fn frame(&self, centre: [i64; 2], border: u64, velocity: [i64; 2]) -> LevelFrame {
        if self.wrap {
            let tex = wrapping_tex_region(self.size, self.clip, centre);
            let valid = wrapping_valid_region(self.size, self.clip, border, tex);
            let mem = wrapping_mem_region(self.size, self.tile, self.grid, tex, velocity);
            return LevelFrame { centre, tex, valid, mem };
        }
        let tex = tex_region(self.size, self.clip, centre);
        let valid = valid_region(self.size, self.clip, border, tex);
        let mem = mem_region(self.size, self.tile, self.grid, tex, velocity);
        LevelFrame { centre, tex, valid, mem }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use proptest::test_runner::{Config, RngSeed};

    fn config(cases: u32) -> Config {
        Config { cases, rng_seed: RngSeed::Fixed(0x6E0), failure_persistence: None, ..Config::default() }
    }

    /// Level sizes from 1 to 2^26, biased to small and to powers of two.
    fn size() -> impl Strategy<Value = u64> {
        prop_oneof![1u64..=300, (0u32..=26).prop_map(|k| 1u64 << k), 1u64..=(1 << 26)]
    }

    /// Centres anywhere: negative, 0, the far edge, outside, extreme.
    fn centre() -> impl Strategy<Value = i64> {
        prop_oneof![-400i64..400, -(1i64 << 27)..(1i64 << 27), Just(i64::MIN), Just(i64::MAX), Just(0)]
    }

    #[test]
    fn design_example_clip_1024_tiles_256_lookahead_1_is_a_6x6_grid() {
        assert_eq!(mem_grid([1 << 20, 1 << 20], [256, 256], 1024, 1), [6, 6]);
        // docs/PERFORMER-REFERENCE.md §1.10 examples: size 8192, tile 256, tex 512, lookahead 2 → 5; size 1024 → 4.
        assert_eq!(mem_grid([8192, 8192], [256, 256], 512, 2), [5, 5]);
        assert_eq!(mem_grid([1024, 1024], [256, 256], 512, 3), [4, 4]);
    }

    #[test]
    fn windows_translate_at_the_edges_and_whole_levels_ignore_the_centre() {
        assert_eq!(tex_region([100, 100], 10, [50, 50]), Rect::new(45, 45, 55, 55));
        assert_eq!(tex_region([100, 100], 10, [-7, 99]), Rect::new(0, 90, 10, 100));
        assert_eq!(tex_region([100, 8], 10, [50, 50]), Rect::new(45, 0, 55, 8));
        assert_eq!(tex_region([1, 1], 1, [i64::MIN, i64::MAX]), Rect::new(0, 0, 1, 1));
        let tex = tex_region([100, 8], 10, [50, 50]);
        assert_eq!(valid_region([100, 8], 10, 2, tex), Rect::new(47, 0, 53, 8));
        assert_eq!(effective_size(1024, 16), 992);
        assert_eq!(default_centre([-1, 5], 1), [-1, 2]);
        assert_eq!(aligned_centre([-1, 5], 1, 1), [-1, 2]);
        assert_eq!(aligned_centre([-1, 5], 1, 0), [-1, 2]);
        assert_eq!(aligned_centre([-1, 37], 1, 8), [-8, 16]);
        assert_eq!(aligned_centre([100, -100], 2, 3), [24, -27]);
        assert_eq!(aligned_centre([i64::MIN, i64::MAX], 0, 3), [i64::MIN, i64::MAX - i64::MAX.rem_euclid(3)]);
        assert_eq!(wrap(-1, 16), 15);
        assert_eq!(window_index(-1, 17, 16, [16, 16]), 16 + 15);
    }

    #[test]
    fn mem_region_puts_spare_tiles_ahead_of_the_motion() {
        let size = [1 << 12, 1 << 12];
        let tex = Rect::new(1024, 1024, 2048, 2048); // tiles 4..8 of 256
        let grid = mem_grid(size, [256, 256], 1024, 1);
        assert_eq!(mem_region(size, [256, 256], grid, tex, [0, 0]), Rect::new(3, 3, 9, 9));
        assert_eq!(mem_region(size, [256, 256], grid, tex, [5, -5]), Rect::new(4, 2, 10, 8));
    }

    proptest! {
        #![proptest_config(config(2000))]

        #[test]
        fn tex_region_matches_brute_force_search_on_small_levels(
            sw in 1u64..=64, sh in 1u64..=64, clip in 1u64..=80, cs in -100i64..160, ct in -100i64..160,
        ) {
            let r = tex_region([sw, sh], clip, [cs, ct]);
            // Oracle: among every origin that keeps a min(clip, size) window inside the level, the
            // one nearest centre - clip/2.
            let oracle = |size: u64, c: i64| {
                let ext = clip.min(size) as i64;
                let best = (0..=(size as i64 - ext)).min_by_key(|&o| (o - (c - (clip / 2) as i64)).abs()).unwrap();
                (best, best + ext)
            };
            prop_assert_eq!((r.s0, r.s1), oracle(sw, cs));
            prop_assert_eq!((r.t0, r.t1), oracle(sh, ct));
        }

        #[test]
        fn aligned_centres_are_the_nearest_multiple_at_or_below(
            c in -5000i64..5000, k in 0u32..6, a in 0u64..40,
        ) {
            // Oracle: walk down from the level centre to the first multiple of the alignment.
            let step = a.max(1) as i64;
            let oracle = |level: i64| {
                let mut w = level;
                while w.rem_euclid(step) != 0 {
                    w -= 1;
                }
                w
            };
            prop_assert_eq!(aligned_centre([c, -c], k, a), [oracle(c >> k), oracle((-c) >> k)]);
        }

        #[test]
        fn regions_stay_inside_the_level_for_any_centre(
            sw in size(), sh in size(), clip in 1u64..=8192, cs in centre(), ct in centre(),
            border in 0u64..64, tile in 1u64..=512, look in 0u64..3, vs in -2i64..=2, vt in -2i64..=2,
        ) {
            let size = [sw, sh];
            let shape = LevelShape::new(size, [tile, tile], clip, look);
            let f = shape.frame([cs, ct], border.min((clip - 1) / 2), [vs, vt]);
            let level = Rect::new(0, 0, sw as i64, sh as i64);
            prop_assert!(level.contains_rect(&f.tex));
            prop_assert_eq!([f.tex.width(), f.tex.height()], [clip.min(sw), clip.min(sh)]);
            prop_assert!(f.tex.contains_rect(&f.valid));
            // The centre lies in the window whenever some window position could contain it.
            for (c, lo, hi, sz) in [(cs, f.tex.s0, f.tex.s1, sw), (ct, f.tex.t0, f.tex.t1, sh)] {
                if c >= 0 && (c as u64) < sz && sz > clip {
                    let half = (clip / 2) as i64;
                    let reachable = c >= half && c - half <= (sz - clip) as i64;
                    prop_assert!(!reachable || (lo <= c && c < hi));
                }
            }
            // The mem region has the grid's size, lies in the level and covers the tex region.
            let grid = mem_grid(size, [tile, tile], clip, look);
            let n = tiles_in_level(size, [tile, tile]);
            prop_assert_eq!([f.mem.width(), f.mem.height()], grid);
            prop_assert!(Rect::new(0, 0, n[0] as i64, n[1] as i64).contains_rect(&f.mem));
            prop_assert!(f.mem.contains_rect(&tiles_covering(f.tex, [tile, tile])));
        }

        #[test]
        fn mem_region_covers_every_texel_of_the_window_brute_force(
            sw in 1u64..=200, sh in 1u64..=200, clip in 1u64..=64, tw in 1u64..=40, th in 1u64..=40,
            cs in -50i64..250, ct in -50i64..250, look in 0u64..3, vs in -1i64..=1, vt in -1i64..=1,
        ) {
            let shape = LevelShape::new([sw, sh], [tw, th], clip, look);
            let f = shape.frame([cs, ct], 0, [vs, vt]);
            for t in f.tex.t0..f.tex.t1 {
                for s in f.tex.s0..f.tex.s1 {
                    let (ts, tt) = (s / tw as i64, t / th as i64);
                    prop_assert!(f.mem.contains(ts, tt), "texel ({}, {}) in tile ({}, {}) outside {:?}", s, t, ts, tt, f.mem);
                }
            }
            // Toroidal slots of the mem region are distinct.
            let mut seen = std::collections::HashSet::new();
            for tt in f.mem.t0..f.mem.t1 {
                for ts in f.mem.s0..f.mem.s1 {
                    prop_assert!(seen.insert((wrap(ts, f.mem.width()), wrap(tt, f.mem.height()))));
                }
            }
        }

        #[test]
        fn wrapping_frames_match_a_brute_force_oracle_on_small_levels(
            tiles in 2u64..=24, tw in 1u64..=12, sh in 1u64..=80, clip in 1u64..=96, cs in -400i64..400,
            ct in -100i64..160, border in 0u64..8, look in 0u64..3, vs in -2i64..=2,
        ) {
            let w = tiles * tw;
            let clip = 1 + (clip - 1) % (w - 1);
            prop_assert!(level_wraps(true, [w, sh], [tw, tw], clip));
            prop_assert!(!level_wraps(false, [w, sh], [tw, tw], clip) && !level_wraps(true, [w, sh], [tw, tw], w));
            let border = border.min((clip - 1) / 2);
            let shape = LevelShape::new([w, sh], [tw, tw], clip, look).wrapping();
            let f = shape.frame([cs, ct], border, [vs, 0]);
            // The window: clip texels along s centred on the centre, taken modulo the width.
            prop_assert!(f.tex.s0 >= 0 && (f.tex.s0 as u64) < w);
            prop_assert_eq!(f.tex.width(), clip);
            let want: Vec<u64> = (0..clip as i64).map(|i| (cs - (clip / 2) as i64 + i).rem_euclid(w as i64) as u64).collect();
            let got: Vec<u64> = (f.tex.s0..f.tex.s1).map(|s| wrap(s, w)).collect();
            prop_assert_eq!(got, want);
            // The border on both sides along s, the region starting inside the level (the same
            // columns a width to the west when the window starts within the border of the seam).
            if !f.valid.is_empty() {
                let (s0, s1) = (f.tex.s0 + border as i64, f.tex.s1 - border as i64);
                let west = if s0 >= w as i64 { w as i64 } else { 0 };
                prop_assert_eq!((f.valid.s0, f.valid.s1), (s0 - west, s1 - west));
                prop_assert!(f.valid.s0 >= 0 && (f.valid.s0 as u64) < w);
            }
            // The grid width divides the level's tiles across; the mem region is that wide.
            prop_assert_eq!(tiles % shape.grid[0], 0);
            prop_assert!(shape.grid[0] >= mem_grid([w, sh], [tw, tw], clip, look)[0]);
            prop_assert_eq!(f.mem.width(), shape.grid[0]);
            // Every texel of the window is in a tile of the mem region, taken modulo the tiles across.
            for s in f.tex.s0..f.tex.s1 {
                let real = wrap(s, w) / tw;
                prop_assert!((f.mem.s0..f.mem.s1).any(|u| wrap(u, tiles) == real), "texel {} (tile {}) outside {:?}", s, real, f.mem);
                prop_assert!(contains_wrapped(&f.mem, real as i64, f.mem.t0, Some(tiles)));
            }
            // Its tiles, taken modulo the tiles across, are distinct and take distinct slots.
            let mut real = std::collections::HashSet::new();
            let mut slots = std::collections::HashSet::new();
            for u in f.mem.s0..f.mem.s1 {
                prop_assert!(real.insert(wrap(u, tiles)));
                prop_assert!(slots.insert(wrap(wrap(u, tiles) as i64, shape.grid[0])));
                prop_assert_eq!(wrap(u, shape.grid[0]), wrap(wrap(u, tiles) as i64, shape.grid[0]), "the slot of U is the slot of U mod n");
            }
        }

        #[test]
        fn wrapped_containment_and_shifts_match_brute_force(
            s0 in -50i64..50, len in 0i64..40, t0 in -5i64..5, s in -200i64..200, t in -8i64..8, p in 1u64..=40, near in -100i64..100,
        ) {
            let len = len.min(p as i64);
            let r = Rect::new(s0, t0, s0 + len, t0 + 3);
            let oracle = (-300i64..300).any(|k| r.contains(s + k * p as i64, t));
            prop_assert_eq!(contains_wrapped(&r, s, t, Some(p)), oracle);
            prop_assert_eq!(contains_wrapped(&r, s, t, None), r.contains(s, t));
            let m = shift_near(r, p, near);
            if !r.is_empty() {
                prop_assert_eq!((m.s0 - r.s0).rem_euclid(p as i64), 0);
                prop_assert_eq!(m.width(), r.width());
                let best = (-300i64..300).map(|k| r.s0 + k * p as i64).min_by_key(|&x| ((x - near).abs(), x)).unwrap();
                prop_assert!((m.s0 - near).abs() == (best - near).abs(), "{:?} {} {}", m, best, near);
            }
        }

        #[test]
        fn wrap_grid_is_the_least_divisor_at_or_above(n in 1u64..=300, g in 0u64..=320) {
            let d = wrap_grid(n, g);
            prop_assert_eq!(n % d, 0);
            prop_assert!(d >= g.clamp(1, n));
            prop_assert!((g.clamp(1, n)..d).all(|x| n % x != 0));
        }

        #[test]
        fn wrap_is_euclidean_modulo(x in any::<i64>(), m in 1u64..=(1 << 40)) {
            let r = wrap(x, m);
            prop_assert!(r < m);
            prop_assert_eq!((x as i128 - r as i128).rem_euclid(m as i128), 0);
        }

        #[test]
        fn wrap_matches_repeated_subtraction(x in -2000i64..2000, m in 1u64..=64) {
            let mut r = x;
            while r < 0 { r += m as i64; }
            while r >= m as i64 { r -= m as i64; }
            prop_assert_eq!(wrap(x, m), r as u64);
        }

        #[test]
        fn toroidal_window_slots_are_distinct_over_any_window(
            clip in 1u64..=24, s0 in -(1i64 << 26)..(1i64 << 26), t0 in -(1i64 << 26)..(1i64 << 26),
        ) {
            let mut seen = vec![false; (clip * clip) as usize];
            for t in t0..t0 + clip as i64 {
                for s in s0..s0 + clip as i64 {
                    let i = window_index(s, t, clip, [clip, clip]);
                    prop_assert!(!seen[i]);
                    seen[i] = true;
                }
            }
        }
    }
}
