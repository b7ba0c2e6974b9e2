//! Growing textures against an oracle computed here from the patches alone (no index, no tiles):
//! overlaps resolved by rating then time, growth in every direction and across the origin, new
//! levels with the top rebuilt, bounded steps, and every refused input.

use super::index::PatchIndex;
use super::rebuild::Rebuilder;
use super::*;
use proptest::prelude::*;
use std::collections::HashMap;

fn grid(tile: u64) -> Grid {
    Grid::new([0.0, 0.0], 1.0, tile, 1, 1).unwrap()
}

/// A patch of `w` x `h` pixels `fill(x, y)` with `m` = (id, box, time, rating).
fn patch(g: &Grid, m: (u64, [f64; 4], u64, f64), w: u32, h: u32, fill: impl Fn(u32, u32) -> u8) -> Patch {
    let (id, b, time, rating) = m;
    let texels = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| fill(x, y)).collect();
    let bbox = WorldBox { min: [b[0], b[1]], max: [b[2], b[3]] };
    Patch::new(g, PatchMeta { id, bbox, time, rating }, w, h, texels).unwrap()
}

fn meta(id: u64, b: [f64; 4]) -> PatchMeta {
    PatchMeta { id, bbox: WorldBox { min: [b[0], b[1]], max: [b[2], b[3]] }, time: 0, rating: 0.0 }
}

/// One random patch: x, y, width, height (world), rating, time, pixels across, down, a seed.
type Spec = (f64, f64, f64, f64, u8, u8, u32, u32, u8);

/// The oracle: level-0 texel (i, j), from every patch, without the index. A patch holds the texel
/// when the texel's centre lies in its box; the winner has the highest (rating, time, id); it is
/// sampled at column floor((cx - min x) / (max x - min x) * width) and row
/// floor((max y - cy) / (max y - min y) * height) (row 0 at the top), clamped.
fn oracle0(g: &Grid, patches: &[Patch], i: i64, j: i64) -> Option<u8> {
    let (cx, cy) =
        (g.origin[0] + (i as f64 + 0.5) / g.texels_per_unit, g.origin[1] + (j as f64 + 0.5) / g.texels_per_unit);
    let holds = |p: &&Patch| p.bbox.min[0] <= cx && cx < p.bbox.max[0] && p.bbox.min[1] <= cy && cy < p.bbox.max[1];
    let best = patches
        .iter()
        .filter(holds)
        .max_by(|a, b| (a.rating, a.time, a.id).partial_cmp(&(b.rating, b.time, b.id)).unwrap())?;
    let px = (((cx - best.bbox.min[0]) / (best.bbox.max[0] - best.bbox.min[0])) * best.width as f64).floor() as i64;
    let py = (((best.bbox.max[1] - cy) / (best.bbox.max[1] - best.bbox.min[1])) * best.height as f64).floor() as i64;
    let (px, py) = (px.clamp(0, best.width as i64 - 1), py.clamp(0, best.height as i64 - 1));
    Some(best.texels[(py * best.width as i64 + px) as usize])
}

/// The oracle at level k: the rounded average of the level k-1 texels under it that have data.
fn oracle(
    g: &Grid,
    patches: &[Patch],
    k: u32,
    i: i64,
    j: i64,
    memo: &mut HashMap<(u32, i64, i64), Option<u8>>,
) -> Option<u8> {
    if k == 0 {
        return oracle0(g, patches, i, j);
    }
    if let Some(v) = memo.get(&(k, i, j)) {
        return *v;
    }
    let below: Vec<u64> = [(0, 0), (1, 0), (0, 1), (1, 1)]
        .iter()
        .filter_map(|&(dx, dy)| oracle(g, patches, k - 1, 2 * i + dx, 2 * j + dy, memo))
        .map(u64::from)
        .collect();
    let v =
        (!below.is_empty()).then(|| ((below.iter().sum::<u64>() + below.len() as u64 / 2) / below.len() as u64) as u8);
    memo.insert((k, i, j), v);
    v
}

/// Ingests every patch, steps the rebuild to the end (at most `per_step` tiles a step), and
/// checks every tile of every level over the extent (one tile of margin) against the oracle.
fn build_and_check(g: &Grid, patches: &[Patch], per_step: usize) -> (PatchIndex, Rebuilder) {
    let mut index = PatchIndex::new();
    let mut rb = Rebuilder::new(*g);
    for p in patches {
        let p = index.insert(p.clone());
        rb.patch_added(&index, &p);
        // Steps interleave with ingest, as in the service.
        let done = rb.step(&index, per_step);
        assert!(done.len() <= per_step);
    }
    let mut steps = 0;
    while rb.pending() > 0 {
        let done = rb.step(&index, per_step);
        assert!(!done.is_empty() && done.len() <= per_step);
        assert!(done.windows(2).all(|w| w[0].0 <= w[1].0), "lower levels first within a step: {done:?}");
        steps += 1;
        assert!(steps < 100_000, "the rebuild ends");
    }
    let levels = rb.levels();
    assert_eq!(levels, index.levels(g));
    let e = index.extent().unwrap();
    let mut memo = HashMap::new();
    let n = g.tile as i64;
    for k in 0..levels {
        let [s0, t0, s1, t1] = g.tiles_over(g.texels_in(&e), k).unwrap_or([0, 0, 0, 0]);
        for t in t0 - 1..t1 + 1 {
            for s in s0 - 1..s1 + 1 {
                let tile = rb.tile(k, s, t);
                for y in 0..n {
                    for x in 0..n {
                        let want = oracle(g, patches, k, s * n + x, t * n + y, &mut memo);
                        let got = tile.and_then(|tl| {
                            let i = (y * n + x) as usize;
                            tl.has(i).then(|| tl.texels[i])
                        });
                        assert_eq!(got, want, "level {k} tile ({s}, {t}) texel ({x}, {y})");
                    }
                }
            }
        }
    }
    // The top level holds the whole extent in at most 2 x 2 tiles (one unless it crosses the origin).
    let top = g.tiles_over(g.texels_in(&e), levels - 1).unwrap();
    assert!(top[2] - top[0] <= 2 && top[3] - top[1] <= 2, "top level tiles {top:?}");
    (index, rb)
}

#[test]
fn overlaps_are_resolved_by_rating_then_time() {
    let g = grid(4);
    // Three patches over texels 0..8: a low-rated new one, a high-rated old one on the left half,
    // and an equally high-rated newer one on the right half overlapping it by two texels.
    let low = patch(&g, (1, [0.0, 0.0, 8.0, 4.0], 30, 1.0), 8, 4, |_, _| 10);
    let old = patch(&g, (2, [0.0, 0.0, 5.0, 4.0], 10, 5.0), 5, 4, |_, _| 20);
    let newer = patch(&g, (3, [3.0, 0.0, 8.0, 4.0], 20, 5.0), 5, 4, |_, _| 30);
    let (_, rb) = build_and_check(&g, &[low, old, newer], 1);
    let row: Vec<u8> = (0..8).map(|x| rb.tile(0, x / 4, 0).unwrap().texels[(x % 4) as usize]).collect();
    // Texels 0..3 only the old high-rated one and the low one: old wins; 3..5 both high: newer
    // wins the tie on time; 5..8 newer.
    assert_eq!(row, vec![20, 20, 20, 30, 30, 30, 30, 30]);
}

#[test]
fn a_patch_is_sampled_at_each_texel_centre() {
    let g = grid(4);
    // A 2x1 image over 4 texels: each pixel covers two texels.
    let p = patch(&g, (1, [0.0, 0.0, 4.0, 1.0], 0, 0.0), 2, 1, |x, _| 100 + x as u8);
    let (_, rb) = build_and_check(&g, &[p], 8);
    let t = rb.tile(0, 0, 0).unwrap();
    assert_eq!(&t.texels[..4], &[100, 100, 101, 101]);
    assert!((0..4).all(|i| t.has(i)));
    assert!(!t.has(4), "the row above has no patch");
    // Row 0 of an image is the top of its box (the largest y), as in image files.
    let p = patch(&g, (1, [0.0, 0.0, 1.0, 2.0], 0, 0.0), 1, 2, |_, y| 200 + y as u8);
    let (_, rb) = build_and_check(&g, &[p], 8);
    let t = rb.tile(0, 0, 0).unwrap();
    assert_eq!((t.texels[0], t.texels[4]), (201, 200), "texel (0, 0) from the bottom row, (0, 1) from the top");
}

#[test]
fn growth_left_right_up_down_and_across_the_origin_adds_levels_and_rebuilds_the_top() {
    let g = grid(4);
    let seed = |i: u64| move |x: u32, y: u32| (i as u32 * 37 + x * 5 + y * 11) as u8;
    let mut patches = vec![patch(&g, (0, [1.0, 1.0, 3.0, 3.0], 0, 1.0), 2, 2, seed(0))];
    let mut levels = vec![];
    for (i, b) in [
        [6.0, 1.0, 12.0, 3.0],    // right
        [-9.0, 0.0, -1.0, 2.0],   // left, across the origin
        [0.0, 10.0, 4.0, 30.0],   // up
        [2.0, -40.0, 3.0, -20.0], // down
        [-70.0, 60.0, -60.0, 70.0],
    ]
    .iter()
    .enumerate()
    {
        patches.push(patch(&g, (i as u64 + 1, *b, i as u64 + 1, 1.0), 3, 5, seed(i as u64 + 1)));
        let (index, rb) = build_and_check(&g, &patches, 3);
        levels.push(rb.levels());
        assert_eq!(index.len(), patches.len());
    }
    assert!(levels.windows(2).all(|w| w[0] <= w[1]), "levels only grow: {levels:?}");
    assert!(levels.last().unwrap() > levels.first().unwrap(), "growth added levels: {levels:?}");
}

#[test]
fn bad_patches_and_grids_are_refused_with_what_was_found() {
    let g = grid(4);
    let mk = |b: [f64; 4], w: u32, h: u32, n: usize, rating: f64| {
        Patch::new(&g, PatchMeta { rating, ..meta(7, b) }, w, h, vec![0; n])
    };
    assert!(matches!(mk([0.0, 0.0, f64::NAN, 1.0], 1, 1, 1, 0.0), Err(GrowError::NotFinite { id: 7, .. })));
    assert!(matches!(mk([0.0, 0.0, f64::INFINITY, 1.0], 1, 1, 1, 0.0), Err(GrowError::NotFinite { .. })));
    assert!(matches!(mk([1.0, 0.0, 1.0, 1.0], 1, 1, 1, 0.0), Err(GrowError::EmptyBox { axis: 'x', .. })));
    assert!(matches!(mk([0.0, 2.0, 1.0, 1.0], 1, 1, 1, 0.0), Err(GrowError::EmptyBox { axis: 'y', .. })));
    assert!(matches!(mk([0.0, 0.0, 1e9, 1.0], 1, 1, 1, 0.0), Err(GrowError::Absurd { axis: 'x', .. })));
    assert!(matches!(mk([1e13, 0.0, 1e13 + 1.0, 1.0], 1, 1, 1, 0.0), Err(GrowError::Absurd { .. })));
    assert!(matches!(mk([0.0, 0.0, 1.0, 1.0], 0, 1, 0, 0.0), Err(GrowError::ImageSize { .. })));
    assert!(matches!(mk([0.0, 0.0, 1.0, 1.0], 70_000, 1, 70_000, 0.0), Err(GrowError::ImageSize { .. })));
    let wrong = mk([0.0, 0.0, 1.0, 1.0], 2, 2, 3, 0.0);
    assert_eq!(wrong, Err(GrowError::TexelBytes { id: 7, width: 2, height: 2, bpt: 1, expected: 4, found: 3 }));
    assert!(wrong.unwrap_err().to_string().contains("expected 4"));
    assert!(matches!(mk([0.0, 0.0, 1.0, 1.0], 1, 1, 1, f64::NAN), Err(GrowError::Rating { .. })));
    // Between two texel centres: nothing would ever show.
    assert!(matches!(mk([0.6, 0.0, 1.4, 1.0], 1, 1, 1, 0.0), Err(GrowError::NoTexel { .. })));
    for bad in [
        Grid::new([f64::NAN, 0.0], 1.0, 4, 1, 1),
        Grid::new([0.0, 0.0], 0.0, 4, 1, 1),
        Grid::new([0.0, 0.0], f64::INFINITY, 4, 1, 1),
        Grid::new([0.0, 0.0], 1.0, 6, 1, 1),
        Grid::new([0.0, 0.0], 1.0, 8192, 1, 1),
        Grid::new([0.0, 0.0], 1.0, 4, 3, 2),
        Grid::new([0.0, 0.0], 1.0, 4, 0, 1),
        Grid::new([0.0, 0.0], 1.0, 4, 4, 3),
    ] {
        assert!(matches!(bad, Err(GrowError::Grid { .. })), "{bad:?}");
    }
}

#[test]
fn sixteen_bit_components_average_per_component() {
    let g = Grid::new([0.0, 0.0], 1.0, 2, 4, 2).unwrap();
    let px = |a: u16, b: u16| [a.to_le_bytes(), b.to_le_bytes()].concat();
    let texels = [px(1000, 60000), px(3001, 40000), px(2000, 0), px(4000, 1)].concat();
    let p = Patch::new(&g, meta(1, [0.0, 0.0, 2.0, 2.0]), 2, 2, texels).unwrap();
    let mut index = PatchIndex::new();
    let far = Patch::new(&g, meta(2, [6.0, 0.0, 7.0, 1.0]), 1, 1, px(9, 9)).unwrap();
    let mut rb = Rebuilder::new(g);
    for q in [p, far] {
        let q = index.insert(q);
        rb.patch_added(&index, &q);
    }
    while rb.pending() > 0 {
        rb.step(&index, 100);
    }
    // Level 1 tile (0, 0) texel (0, 0) is the average of the four 16-bit texels, per component.
    let t = rb.tile(1, 0, 0).unwrap();
    let a = u16::from_le_bytes([t.texels[0], t.texels[1]]);
    let b = u16::from_le_bytes([t.texels[2], t.texels[3]]);
    assert_eq!((a, b), ((1000 + 3001 + 2000 + 4000 + 2) / 4, ((60000u32 + 40000 + 1 + 2) / 4) as u16));
}

fn arb_patches() -> impl Strategy<Value = Vec<Spec>> {
    prop::collection::vec(
        (-24.0f64..24.0, -24.0f64..24.0, 0.5f64..12.0, 0.5f64..12.0, 0u8..3, 0u8..5, 1u32..4, 1u32..4, any::<u8>()),
        1..6,
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    #[test]
    fn every_tile_of_every_level_matches_the_oracle(
        specs in arb_patches(),
        tile in prop::sample::select(vec![1u64, 2, 4, 8]),
        res in prop::sample::select(vec![0.5f64, 1.0, 1.5]),
        origin in (-3.0f64..3.0, -3.0f64..3.0),
        per_step in 1usize..9,
    ) {
        let g = Grid::new([origin.0, origin.1], res, tile, 1, 1).unwrap();
        let mut patches = Vec::new();
        for (i, &(x, y, w, h, rating, time, pw, ph, base)) in specs.iter().enumerate() {
            let texels = (0..pw * ph).map(|n| base.wrapping_add((n % pw * 7 + n / pw * 13) as u8)).collect();
            let b = WorldBox { min: [x, y], max: [x + w, y + h] };
            match Patch::new(&g, PatchMeta { id: i as u64, bbox: b, time: time as u64, rating: rating as f64 }, pw, ph, texels) {
                Ok(p) => patches.push(p),
                // Smaller than a texel of this grid: refused, and rightly (checked below).
                Err(GrowError::NoTexel { .. }) => {
                    let [i0, j0, i1, j1] = g.texels_in(&b);
                    prop_assert!(i0 >= i1 || j0 >= j1);
                }
                Err(e) => panic!("{e}"),
            }
        }
        prop_assume!(!patches.is_empty());
        build_and_check(&g, &patches, per_step);
    }
}

/// The feathered oracle of level-0 texel (i, j), from every patch, without the index: the patches
/// holding the centre, best (rating, time, id) first, each over the next with opacity
/// min(1, d / feather) (d: texels from the centre to the patch's nearest edge; the last opaque),
/// rounded half up.
fn feathered0(g: &Grid, patches: &[Patch], i: i64, j: i64, feather: f64) -> Option<u8> {
    let c = [g.origin[0] + (i as f64 + 0.5) / g.texels_per_unit, g.origin[1] + (j as f64 + 0.5) / g.texels_per_unit];
    let mut holding: Vec<&Patch> = patches
        .iter()
        .filter(|p| p.bbox.min[0] <= c[0] && c[0] < p.bbox.max[0] && p.bbox.min[1] <= c[1] && c[1] < p.bbox.max[1])
        .collect();
    holding.sort_by(|a, b| (b.rating, b.time, b.id).partial_cmp(&(a.rating, a.time, a.id)).unwrap());
    let n = holding.len();
    if n == 0 {
        return None;
    }
    let (mut v, mut rest) = (0.0f64, 1.0f64);
    for (k, p) in holding.iter().enumerate() {
        let b = &p.bbox;
        let d = (c[0] - b.min[0]).min(b.max[0] - c[0]).min(c[1] - b.min[1]).min(b.max[1] - c[1]);
        let a = if k + 1 == n { 1.0 } else { (d * g.texels_per_unit / feather).min(1.0) };
        let px =
            (((c[0] - b.min[0]) / (b.max[0] - b.min[0])) * p.width as f64).floor().clamp(0.0, p.width as f64 - 1.0);
        let py =
            (((b.max[1] - c[1]) / (b.max[1] - b.min[1])) * p.height as f64).floor().clamp(0.0, p.height as f64 - 1.0);
        v += rest * a * p.texels[py as usize * p.width as usize + px as usize] as f64;
        rest *= 1.0 - a;
        if a >= 1.0 {
            break;
        }
    }
    Some((v + 0.5).floor() as u8)
}

#[test]
fn feathered_edges_fade_a_patch_into_what_lies_beneath_it() {
    // A dark patch under a bright one rated higher: across the bright one's left edge the texels
    // ramp from dark to bright over the feather's width, instead of a step.
    let g = grid(16);
    let under = patch(&g, (1, [0.0, -20.0, 32.0, 28.0], 0, 0.0), 32, 8, |_, _| 0);
    let over = patch(&g, (2, [8.0, -20.0, 32.0, 28.0], 0, 1.0), 24, 8, |_, _| 200);
    let mut index = PatchIndex::new();
    let mut rb = Rebuilder::new(g);
    rb.set_feather(4.0);
    for p in [under, over] {
        let p = index.insert(p);
        rb.patch_added(&index, &p);
    }
    while rb.pending() > 0 {
        rb.step(&index, 64);
    }
    let row: Vec<u8> = (0..16).map(|x| rb.tile(0, 0, 0).unwrap().texels[4 * 16 + x]).collect();
    // Texel x's centre is x + 0.5: 0.5 .. 3.5 texels inside the bright patch at x = 8 .. 11.
    assert_eq!(&row[..8], &[0; 8]);
    assert_eq!(&row[8..13], &[25, 75, 125, 175, 200]);
    // Without the feather, a step.
    let mut rb0 = Rebuilder::new(g);
    for p in index.patches() {
        rb0.patch_added(&index, p);
    }
    while rb0.pending() > 0 {
        rb0.step(&index, 64);
    }
    assert_eq!(rb0.tile(0, 0, 0).unwrap().texels[4 * 16 + 8], 200);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn feathered_level_0_matches_its_oracle(
        specs in arb_patches(),
        feather in prop::sample::select(vec![0.5f64, 2.0, 5.0]),
        res in prop::sample::select(vec![0.5f64, 1.0, 1.5]),
        origin in (-3.0f64..3.0, -3.0f64..3.0),
    ) {
        let g = Grid::new([origin.0, origin.1], res, 4, 1, 1).unwrap();
        let mut index = PatchIndex::new();
        let mut rb = Rebuilder::new(g);
        rb.set_feather(feather);
        let mut patches = Vec::new();
        for (i, &(x, y, w, h, rating, time, pw, ph, base)) in specs.iter().enumerate() {
            let texels = (0..pw * ph).map(|n| base.wrapping_add((n % pw * 37 + n / pw * 91) as u8)).collect();
            let b = WorldBox { min: [x, y], max: [x + w, y + h] };
            if let Ok(p) = Patch::new(&g, PatchMeta { id: i as u64, bbox: b, time: time as u64, rating: rating as f64 }, pw, ph, texels) {
                let p = index.insert(p);
                rb.patch_added(&index, &p);
                patches.push((*p).clone());
            }
        }
        prop_assume!(!patches.is_empty());
        while rb.pending() > 0 {
            rb.step(&index, 64);
        }
        let e = index.extent().unwrap();
        let [s0, t0, s1, t1] = g.tiles_over(g.texels_in(&e), 0).unwrap();
        for t in t0..t1 {
            for s in s0..s1 {
                let tile = rb.tile(0, s, t);
                for y in 0..4i64 {
                    for x in 0..4i64 {
                        let i = (y * 4 + x) as usize;
                        let got = tile.and_then(|tl| tl.has(i).then(|| tl.texels[i]));
                        prop_assert_eq!(got, feathered0(&g, &patches, s * 4 + x, t * 4 + y, feather), "tile ({}, {}) texel ({}, {})", s, t, x, y);
                    }
                }
            }
        }
    }
}

/// The store: what survives a restart, a crash mid-rebuild, a damaged tile, a refused patch.
mod store {
    use super::super::store::{Growing, StoreError};
    use super::super::NewPatch;
    use super::*;

    fn new_patch(b: [f64; 4], time: u64, rating: f64, w: u32, h: u32, seed: u8) -> NewPatch {
        let texels = (0..w * h).map(|n| seed.wrapping_add((n % w * 5 + n / w * 11) as u8)).collect();
        let patch = Patch {
            id: 0,
            bbox: WorldBox { min: [b[0], b[1]], max: [b[2], b[3]] },
            time,
            rating,
            width: w,
            height: h,
            texels,
        };
        NewPatch { patch, encoded: None }
    }

    /// A few overlapping patches around the origin (ids 1.. as the store gives them).
    fn patches() -> Vec<NewPatch> {
        vec![
            new_patch([-10.0, -6.0, 7.0, 5.0], 1, 1.0, 9, 7, 3),
            new_patch([0.0, 0.0, 20.0, 9.0], 2, 0.0, 13, 5, 90),
            new_patch([-30.0, 2.0, -12.0, 30.0], 3, 2.0, 6, 11, 170),
            new_patch([-4.0, -4.0, 4.0, 4.0], 4, 2.0, 4, 4, 250),
        ]
    }

    /// Every tile of every level of `got` equals what a fresh in-memory rebuild of the same
    /// patches gives (itself checked against the oracle elsewhere).
    fn same_as_in_memory(got: &Growing) {
        let g = *got.grid();
        let list: Vec<Patch> = got.index().patches().iter().map(|p| (**p).clone()).collect();
        let (_, want) = build_and_check(&g, &list, 7);
        assert_eq!(got.levels(), want.levels());
        assert_eq!(got.rebuild().len(), want.len(), "tiles with data");
        for &(k, s, t) in want.keys() {
            assert_eq!(got.tile(k, s, t).map(|t| &**t), want.tile(k, s, t).map(|t| &**t), "tile {k} ({s}, {t})");
        }
    }

    #[test]
    fn the_feather_is_kept_and_refused_out_of_range() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("f");
        let g = Growing::create_feathered(&root, [0.0, 0.0], 1.0, 4, "l8", 3.5).unwrap();
        assert_eq!(g.feather(), 3.5);
        drop(g);
        assert_eq!(Growing::open(&root).unwrap().feather(), 3.5);
        for bad in [-1.0, f64::NAN, 1e9] {
            let e = Growing::create_feathered(&dir.path().join("x"), [0.0, 0.0], 1.0, 4, "l8", bad).err().unwrap();
            assert!(e.to_string().contains("is not a width in level-0 texels"), "{e}");
        }
    }

    fn files(dir: &std::path::Path) -> Vec<String> {
        let mut out: Vec<String> =
            std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        out.sort();
        out
    }

    #[test]
    fn a_restart_keeps_every_patch_and_tile() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("tex");
        let mut g = Growing::create(&root, [0.0, 0.0], 1.0, 4, "l8").unwrap();
        for p in patches() {
            g.add(p).unwrap();
        }
        g.finish(5).unwrap();
        assert_eq!(g.applied(), 4);
        same_as_in_memory(&g);
        drop(g);
        let g = Growing::open(&root).unwrap();
        assert_eq!((g.applied(), g.replayed(), g.pending(), g.index().len()), (4, 0, 0, 4));
        same_as_in_memory(&g);
    }

    #[test]
    fn a_crash_in_the_middle_of_a_rebuild_loses_nothing_acknowledged() {
        // Stop after every number of steps: each stop is a crash (nothing more reaches the
        // directory), and the next open must still end at the full texture.
        for crash_after in 0..12 {
            let dir = tempfile::tempdir().unwrap();
            let root = dir.path().join("tex");
            let mut g = Growing::create(&root, [0.5, -0.25], 1.0, 4, "l8").unwrap();
            let mut steps = 0;
            for p in patches() {
                g.add(p).unwrap();
                if steps < crash_after {
                    g.step(3).unwrap();
                    steps += 1;
                }
            }
            while steps < crash_after && g.pending() > 0 {
                g.step(3).unwrap();
                steps += 1;
            }
            drop(g);
            let mut g = Growing::open(&root).unwrap();
            assert_eq!(g.index().len(), 4, "crash after {crash_after} steps: every acknowledged patch is back");
            g.finish(4).unwrap();
            same_as_in_memory(&g);
            // And once more, from a clean stop.
            drop(g);
            let g = Growing::open(&root).unwrap();
            assert_eq!(g.replayed(), 0);
            same_as_in_memory(&g);
        }
    }

    #[test]
    fn a_damaged_tile_file_is_rebuilt_and_an_unacknowledged_patch_is_removed() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("tex");
        let mut g = Growing::create(&root, [0.0, 0.0], 1.0, 4, "l8").unwrap();
        for p in patches() {
            g.add(p).unwrap();
        }
        g.finish(100).unwrap();
        drop(g);
        // A power cut: one tile file cut short, one patch's texels written but not its record.
        let tile = root.join("tiles/0/0_0.tile");
        let len = std::fs::metadata(&tile).unwrap().len();
        std::fs::OpenOptions::new().write(true).open(&tile).unwrap().set_len(len / 2).unwrap();
        std::fs::write(root.join("patches/0000000005.texels"), [1u8; 16]).unwrap();
        let mut g = Growing::open(&root).unwrap();
        assert!(!root.join("patches/0000000005.texels").exists());
        assert_eq!(g.pending(), 1, "the damaged tile waits to be rebuilt");
        g.finish(100).unwrap();
        same_as_in_memory(&g);
        assert_eq!(std::fs::metadata(&tile).unwrap().len(), len);
        // The next patch takes id 5.
        assert_eq!(g.add(new_patch([1.0, 1.0, 3.0, 3.0], 9, 0.0, 2, 2, 7)).unwrap(), 5);
    }

    #[test]
    fn refused_patches_and_directories_leave_nothing_behind() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("tex");
        let mut g = Growing::create(&root, [0.0, 0.0], 1.0, 4, "rgb8").unwrap();
        let before = files(&root.join("patches"));
        let bad = [
            new_patch([f64::NAN, 0.0, 4.0, 4.0], 0, 0.0, 2, 2, 0),
            new_patch([4.0, 0.0, 4.0, 4.0], 0, 0.0, 2, 2, 0),
            new_patch([0.0, 0.0, 1e300, 4.0], 0, 0.0, 2, 2, 0),
            // One byte a texel where the grid has three.
            new_patch([0.0, 0.0, 4.0, 4.0], 0, 0.0, 2, 2, 0),
        ];
        for p in bad {
            let e = g.add(p).unwrap_err();
            assert!(matches!(e, StoreError::Patch(_)), "{e}");
            assert!(e.to_string().starts_with("patch 1:"), "{e}");
        }
        assert_eq!(files(&root.join("patches")), before);
        let mut ok = new_patch([0.0, 0.0, 4.0, 4.0], 0, 0.0, 2, 2, 0);
        ok.patch.texels = vec![9; 12];
        assert_eq!(g.add(ok).unwrap(), 1, "refused patches take no id");

        let e = Growing::create(&root, [0.0, 0.0], 1.0, 4, "rgb8").err().unwrap().to_string();
        assert!(e.contains("not empty"), "{e}");
        let e = Growing::create(&dir.path().join("b"), [0.0, 0.0], 1.0, 4, "rgb5").err().unwrap().to_string();
        assert!(e.contains("\"rgb5\"") && e.contains("rgb8, rgba8"), "{e}");
        let e = Growing::create(&dir.path().join("c"), [0.0, 0.0], 0.0, 4, "l8").err().unwrap().to_string();
        assert!(e.contains("texels per unit"), "{e}");
        let e = Growing::open(dir.path()).err().unwrap().to_string();
        assert!(e.contains("no grid.json") && e.contains("cliptex grow create"), "{e}");
        // One writer at a time; lookers are welcome.
        let e = Growing::open(&root).err().unwrap();
        assert!(matches!(e, StoreError::Busy { .. }) && e.to_string().contains(&std::process::id().to_string()), "{e}");
        assert_eq!(Growing::open_read_only(&root).unwrap().index().len(), 1);
        drop(g);
        std::fs::write(root.join("state.json"), "{\"applied\": \"x\"}").unwrap();
        let e = Growing::open(&root).err().unwrap().to_string();
        assert!(e.contains("state.json") && e.contains("damaged"), "{e}");
    }
}

proptest! {
    /// Runs of flags set word by word, and the bytes tile files store, against one bool a flag.
    #[test]
    fn flags_match_one_bool_a_flag(len in 1usize..300, runs in prop::collection::vec((0usize..300, 0usize..300), 0..6)) {
        let mut f = rebuild::Flags::new(len);
        let mut want = vec![false; len];
        for (a, b) in runs {
            let (a, b) = (a.min(len), b.min(len));
            let (a, b) = (a.min(b), a.max(b));
            f.set_run(a, b);
            want[a..b].iter_mut().for_each(|w| *w = true);
        }
        prop_assert_eq!((0..len).map(|i| f.get(i)).collect::<Vec<_>>(), want.clone());
        prop_assert_eq!(f.count(), want.iter().filter(|&&w| w).count());
        let back = rebuild::Flags::from_bytes(&f.to_bytes(), len);
        prop_assert_eq!(&back, &f);
        prop_assert_eq!(f.to_bytes().len(), len.div_ceil(8));
    }
}
