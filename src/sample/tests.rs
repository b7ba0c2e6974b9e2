//! Sampling identity: the clipmap samples like the full mipmap wherever it holds the texels.

use super::*;
use crate::clip::Settings;
use crate::source::{Fault, FaultRule, FaultySource, HashSource, TextureDesc};
use std::sync::Arc;

fn setup(size: u64, clip: u64, centre: [i64; 2]) -> (Arc<dyn TileSource>, Clipmap) {
    let desc =
        TextureDesc::new([size, size], clip, TexelFormat::RGBA8, [16, 16]).unwrap().with_invalid_border(2).unwrap();
    let src: Arc<dyn TileSource> = Arc::new(HashSource::new(desc));
    let settings = Settings { budget_ns: None, ..Settings::default() };
    let mut map = Clipmap::new(src.clone(), settings).unwrap();
    for _ in 0..8 {
        map.tick(centre, Some([0, 0]));
        map.wait_for_reads();
    }
    map.tick(centre, Some([0, 0]));
    assert_eq!(map.min_lod(), 0.0);
    (src, map)
}

const FILTERS: [Filter; 3] = [Filter::Point, Filter::Bilinear, Filter::Trilinear];

#[test]
fn where_the_clip_covers_the_view_the_clipmap_samples_bit_for_bit_like_the_mipmap() {
    let (src, map) = setup(1024, 64, [500, 300]);
    let mut mip = MipmapSampler::new(src.as_ref());
    // A view of level-0 texels 480..520 x 280..320: inside level 0's valid region (470..530).
    let mut compared = 0;
    for j in 0..40 {
        for i in 0..40 {
            let (u, v) = (480.0 + i as f64 + 0.37 * (j % 3) as f64, 280.0 + j as f64 + 0.21 * (i % 4) as f64);
            for (n, filter) in FILTERS.into_iter().enumerate() {
                let lod = ((i + j + n) % 9) as f64 * 0.5;
                let got = sample_clipmap(&map, filter, u, v, lod).unwrap();
                assert_eq!(got.lod, lod, "{filter:?} at ({u}, {v}) fell back");
                let want = mip.sample(filter, u, v, lod).unwrap();
                assert_eq!(got.rgba.map(f32::to_bits), want.map(f32::to_bits), "{filter:?} ({u}, {v}) lod {lod}");
                compared += 1;
            }
        }
    }
    assert_eq!(compared, 4800);
}

#[test]
fn outside_the_clip_the_clipmap_samples_like_the_mipmap_at_the_finest_available_level() {
    let (src, map) = setup(1024, 32, [100, 100]);
    let mut mip = MipmapSampler::new(src.as_ref());
    let mut coarser = 0;
    for i in 0..64 {
        let (u, v) = (5.5 + 15.9 * i as f64, 1000.0 - 15.3 * i as f64);
        for filter in FILTERS {
            let got = sample_clipmap(&map, filter, u, v, 0.0).unwrap();
            let want = mip.sample(filter, u, v, got.lod).unwrap();
            assert_eq!(got.rgba.map(f32::to_bits), want.map(f32::to_bits), "{filter:?} ({u}, {v}) at {}", got.lod);
            // The level used holds the texel; a finer whole level would not have.
            let k = got.lod as u32;
            let (s, t) = ((u as i64) >> k, (v as i64) >> k);
            assert!(map.level(k).valid.contains(s, t));
            if got.lod > 0.0 {
                coarser += 1;
                let finer = k - 1;
                let (s, t) = ((u as i64) >> finer, (v as i64) >> finer);
                let fp = map.level(finer).valid;
                let footprint_inside = fp.contains(s - 1, t - 1) && fp.contains(s + 1, t + 1);
                assert!(!footprint_inside, "level {finer} could have served ({u}, {v})");
            }
        }
    }
    assert!(coarser > 100, "most of the view lies outside the clip: {coarser}");
}

#[test]
fn missing_tiles_are_never_sampled() {
    let desc = TextureDesc::new([512, 512], 32, TexelFormat::RGBA8, [16, 16]).unwrap();
    let inner: Arc<dyn TileSource> = Arc::new(HashSource::new(desc));
    let src = Arc::new(FaultySource::new(inner.clone()));
    let settings = Settings { budget_ns: None, ..Settings::default() };
    let mut map = Clipmap::new(src.clone(), settings).unwrap();
    src.add(FaultRule::level(0, Fault::Missing));
    for _ in 0..6 {
        map.tick([256, 256], Some([0, 0]));
        map.wait_for_reads();
    }
    // Level 0 is published with every tile missing: each sample falls back, tile by tile.
    assert!(!map.level(0).valid.is_empty());
    let mut mip = MipmapSampler::new(inner.as_ref());
    let got = sample_clipmap(&map, Filter::Trilinear, 256.5, 256.5, 0.0).unwrap();
    assert!(got.lod >= 1.0);
    let want = mip.sample(Filter::Trilinear, 256.5, 256.5, got.lod).unwrap();
    assert_eq!(got.rgba.map(f32::to_bits), want.map(f32::to_bits));
}

fn mapped_desc() -> TextureDesc {
    TextureDesc::new([1 << 12; 2], 128, TexelFormat::RGBA8, [32, 32]).unwrap().with_invalid_border(4).unwrap()
}

/// A service's engine without the service: its image caches in a mapping `name` in `dir`.
fn mapped_service(dir: &std::path::Path, name: &str) -> (Clipmap, crate::shm::Writer) {
    let settings = Settings { budget_ns: None, fade_ticks: 1, ..Settings::default() };
    let source: Arc<dyn TileSource> = Arc::new(HashSource::new(mapped_desc()));
    let shape = Clipmap::shape_for(source.desc(), &settings);
    let w =
        crate::shm::Writer::create(crate::shm::WriterOptions::new(dir, name, shape, source.desc().format())).unwrap();
    let map = Clipmap::with_memory(source, settings, w.memory()).unwrap();
    (map, w)
}

#[test]
fn a_client_samples_the_mapping_exactly_as_the_engine_is_sampled() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, _w) = mapped_service(dir.path(), "smp");
    let client = Client::attach(dir.path(), "smp").unwrap();
    let full_source = HashSource::new(mapped_desc());
    let mut full = MipmapSampler::new(&full_source);
    let mut c = [1500i64, 2500];
    let mut rng = 3u64;
    let mut next = || {
        rng = crate::source::procedural::splitmix64(rng);
        rng
    };
    let (mut compared, mut coarser) = (0, 0);
    for tick in 0..30 {
        c = [c[0] + 11, c[1] - 9];
        map.tick(c, None);
        map.wait_for_reads();
        if tick < 5 {
            continue;
        }
        for _ in 0..100 {
            let u = c[0] as f64 + (next() % 1200) as f64 - 600.0 + (next() % 1000) as f64 / 1000.0;
            let v = c[1] as f64 + (next() % 1200) as f64 - 600.0 + (next() % 1000) as f64 / 1000.0;
            let lod = (next() % 600) as f64 / 100.0;
            let filter = [Filter::Point, Filter::Bilinear, Filter::Trilinear][(next() % 3) as usize];
            let from_engine = sample_clipmap(&map, filter, u, v, lod).expect("the engine holds every footprint");
            let from_mapping = sample_mapping(&client, filter, u, v, lod).expect("the mapping holds every footprint");
            assert_eq!(from_mapping, from_engine, "{filter:?} at ({u}, {v}) lod {lod}");
            let reference = full.sample(filter, u, v, from_mapping.lod).unwrap();
            assert_eq!(from_mapping.rgba, reference, "{filter:?} at ({u}, {v}) lod {}", from_mapping.lod);
            compared += 1;
            coarser += usize::from(from_mapping.lod > lod);
        }
    }
    assert_eq!(compared, 2500);
    assert!(coarser > 0, "some samples fall outside the finer windows and use a coarser level");
}

#[test]
fn a_missing_tile_in_the_mapping_is_sampled_from_the_next_level_its_neighbours_not() {
    let dir = tempfile::tempdir().unwrap();
    let settings = Settings { budget_ns: None, ..Settings::default() };
    let faulty = Arc::new(FaultySource::new(Arc::new(HashSource::new(mapped_desc()))));
    faulty.add(FaultRule::tile(crate::source::TileId::new(0, 63, 63), Fault::Missing));
    let shape = Clipmap::shape_for(faulty.desc(), &settings);
    let w = crate::shm::Writer::create(
        crate::shm::WriterOptions::new(dir.path(), "hole", shape, TexelFormat::RGBA8).tick_period_ns(1_000_000),
    )
    .unwrap();
    let mut map = Clipmap::with_memory(faulty, settings, w.memory()).unwrap();
    for _ in 0..10 {
        map.tick([2040, 2040], None);
        map.wait_for_reads();
    }
    let client = crate::shm::Client::attach(dir.path(), "hole").unwrap();
    let (hole, beside) = ((63.0 * 32.0 + 5.5, 63.0 * 32.0 + 5.5), (64.0 * 32.0 + 1.5, 63.0 * 32.0 + 1.5));
    let at = |(u, v): (f64, f64)| sample_mapping(&client, Filter::Point, u, v, 0.0).unwrap();
    assert_eq!((at(hole).lod, at(beside).lod), (1.0, 0.0));
    // The engine samples the same.
    let engine = |(u, v): (f64, f64)| sample_clipmap(&map, Filter::Point, u, v, 0.0).unwrap();
    assert_eq!((engine(hole), engine(beside)), (at(hole), at(beside)));
}

#[test]
fn a_frame_rendered_from_one_snapshot_of_the_mapping_equals_the_engine_render() {
    use crate::accuracy::render::{render_clipmap, render_mapping, Camera};
    let dir = tempfile::tempdir().unwrap();
    let (mut map, _w) = mapped_service(dir.path(), "frame");
    let client = Client::attach(dir.path(), "frame").unwrap();
    for i in 0..12 {
        map.tick([1800 + 13 * i, 2100 - 7 * i], None);
        map.wait_for_reads();
    }
    let snap = client.try_snapshot().unwrap();
    let cam = Camera::following([1956.0, 2016.0], 20.0, 30.0, 40.0, 60.0, [64, 48]);
    for filter in [Filter::Point, Filter::Trilinear] {
        let engine = render_clipmap(&cam, &map, filter);
        let mapped = render_mapping(&cam, &client, &snap, filter);
        assert_eq!(mapped, engine, "{filter:?}");
        assert!(mapped.iter().filter(|p| p.ground).count() > 64 * 20, "the camera sees the ground");
    }
}

#[test]
fn a_frame_rendered_at_given_footprints_equals_the_camera_render_and_held_texels_restrict_it() {
    use crate::accuracy::render::{render_mapping, render_mapping_at, Camera};
    let dir = tempfile::tempdir().unwrap();
    let (mut map, _w) = mapped_service(dir.path(), "at");
    let client = Client::attach(dir.path(), "at").unwrap();
    for i in 0..12 {
        map.tick([1800 + 13 * i, 2100 - 7 * i], None);
        map.wait_for_reads();
    }
    let snap = client.try_snapshot().unwrap();
    let cam = Camera::following([1956.0, 2016.0], 20.0, 30.0, 40.0, 60.0, [64, 48]);
    let at: Vec<_> = (0..48)
        .flat_map(|j| (0..64).map(move |i| (i, j)))
        .map(|(i, j)| cam.footprint(i, j).map(|f| (f.uv, f.lod)))
        .collect();
    for filter in [Filter::Point, Filter::Trilinear] {
        let want = render_mapping(&cam, &client, &snap, filter);
        assert_eq!(render_mapping_at(&client, &snap, None, filter, &at), want, "{filter:?}");
        // Holding nothing of level 0: every pixel from level 1 or coarser.
        let no_level_0 = |k: u32, _s: i64, _t: i64| k > 0;
        let coarser = render_mapping_at(&client, &snap, Some(&no_level_0), filter, &at);
        let finest = |lod: f64| if filter == Filter::Point { (lod + 0.5).floor() } else { lod.floor() };
        assert!(coarser.iter().filter(|p| p.ground).all(|p| finest(p.lod) >= 1.0), "{filter:?}");
        assert!(coarser.iter().zip(&want).any(|(c, w)| c.rgba != w.rgba), "{filter:?}: level 0 was used");
        let (u, v, lod) = (1960.25, 2030.5, 0.0);
        let held = sample_mapping_held(&client, &snap, Some(&no_level_0), filter, u, v, lod).unwrap();
        assert_eq!(Some(held), sample_mapping_in(&client, &snap, filter, u, v, 1.0), "{filter:?}");
    }
}

// Heights in metres.

use crate::height::{HeightFormat, HeightStorage, LevelRule};
use crate::source::{HeightLevels, HeightSource};
use proptest::prelude::*;

/// A height texture `w x h` whose every level holds `levels[k]` (stored values).
fn height_levels(w: u64, h: u64, tile: u64, format: HeightFormat, levels: Vec<Vec<f64>>) -> HeightLevels {
    let desc = TextureDesc::new([w, h], 16, TexelFormat::L32F, [tile, tile]).unwrap();
    HeightLevels::new(desc, format, LevelRule::Mean, levels).unwrap()
}

/// Brute force: every texel of level `k` weighs its share of the tent around (x, y) (in level
/// texel units, centres at whole numbers), each edge-clamped position counted where it lands;
/// weights renormalised over the texels with data and a weight above zero. Returns (sum of
/// weight x metres, sum of weights).
fn oracle_level(src: &HeightLevels, k: u32, u: f64, v: f64, share: f64) -> (f64, f64) {
    let size = src.desc().level(k).size;
    let scale = (1u64 << k) as f64;
    let (x, y) = (u / scale - 0.5, v / scale - 0.5);
    // The weight a texel index gets along one axis: the tent 1 - |x - i| over the two lattice
    // positions around x, each moved to the nearest texel of the level.
    let axis = |c: f64, n: u64, i: u64| -> f64 {
        let lo = c.floor();
        [lo, lo + 1.0]
            .iter()
            .filter(|&&p| (p.max(0.0).min(n as f64 - 1.0)) as u64 == i)
            .map(|&p| 1.0 - (c - p).abs())
            .sum()
    };
    let (mut sum, mut weights) = (0.0, 0.0);
    for t in 0..size[1] {
        for s in 0..size[0] {
            let w = axis(x, size[0], s) * axis(y, size[1], t) * share;
            let stored = src.stored(k, s, t);
            if w > 0.0 && !src.format().is_nodata(stored) {
                sum += w * src.format().decode(stored).unwrap();
                weights += w;
            }
        }
    }
    (sum, weights)
}

fn oracle(src: &HeightLevels, filter: Filter, u: f64, v: f64, lod: f64) -> Option<f64> {
    let last = src.desc().level_count() as u32 - 1;
    let lod = lod.clamp(0.0, last as f64);
    let nearest = ((lod + 0.5).floor() as u32).min(last);
    let ratio = |(a, b): (f64, f64)| if b > 0.0 { Some(a / b) } else { None };
    match filter {
        Filter::Point => {
            let size = src.desc().level(nearest).size;
            let scale = (1u64 << nearest) as f64;
            let s = ((u / scale).floor().max(0.0) as u64).min(size[0] - 1);
            let t = ((v / scale).floor().max(0.0) as u64).min(size[1] - 1);
            src.format().decode(src.stored(nearest, s, t))
        }
        Filter::Bilinear => ratio(oracle_level(src, nearest, u, v, 1.0)),
        Filter::Trilinear => {
            let k = lod.floor() as u32;
            let f = lod - k as f64;
            if f == 0.0 || k == last {
                return ratio(oracle_level(src, k, u, v, 1.0));
            }
            let (a, b) = oracle_level(src, k, u, v, 1.0 - f);
            let (c, d) = oracle_level(src, k + 1, u, v, f);
            ratio((a + c, b + d))
        }
    }
}

fn close(got: Option<f64>, want: Option<f64>) -> bool {
    match (got, want) {
        (Some(g), Some(w)) => (g - w).abs() <= 1e-9 * w.abs().max(1.0),
        (g, w) => g == w,
    }
}

prop_compose! {
    /// A height format of each storage, with a nodata value or none.
    fn any_format()(storage in 0..3u8, nodata in any::<bool>()) -> HeightFormat {
        match storage {
            0 => HeightFormat::float(nodata.then_some(-32768.0)).unwrap(),
            1 => HeightFormat::new(HeightStorage::U16, 0.01, -11000.0, nodata.then_some(0.0)).unwrap(),
            _ => HeightFormat::new(HeightStorage::I16, 0.5, 100.0, nodata.then_some(-32768.0)).unwrap(),
        }
    }
}

/// A stored value of `format` from random bits: one in four the nodata value (when it has one).
fn stored_from(format: &HeightFormat, bits: u64) -> f64 {
    if let Some(nd) = format.nodata() {
        if bits.is_multiple_of(4) {
            return nd;
        }
    }
    let v = match format.storage() {
        HeightStorage::F32 => ((bits >> 8) % 20_377_601) as f64 / 1024.0 - 11000.0,
        HeightStorage::U16 => ((bits >> 8) % 65536) as f64,
        HeightStorage::I16 => ((bits >> 8) % 65536) as f64 - 32768.0,
    };
    if format.is_nodata(v) {
        v + 1.0
    } else {
        v
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn heights_sample_like_a_brute_force_f64_oracle(
        format in any_format(),
        w in 1u64..24,
        h in 1u64..24,
        seed in any::<u64>(),
        points in proptest::collection::vec((-3.0f64..27.0, -3.0f64..27.0, 0.0f64..6.0, 0usize..3), 24),
    ) {
        let desc = TextureDesc::new([w, h], 16, TexelFormat::L32F, [4, 4]).unwrap();
        let mut rng = seed;
        let levels: Vec<Vec<f64>> = (0..desc.level_count() as u32)
            .map(|k| {
                let size = desc.level(k).size;
                (0..size[0] * size[1])
                    .map(|_| {
                        rng = crate::source::procedural::splitmix64(rng);
                        stored_from(&format, rng)
                    })
                    .collect()
            })
            .collect();
        let src = height_levels(w, h, 4, format, levels);
        let mut mip = MipmapSampler::new(&src);
        for (u, v, lod, f) in points {
            let filter = FILTERS[f];
            let got = mip.sample_height(filter, u, v, lod).unwrap();
            let want = oracle(&src, filter, u, v, lod);
            prop_assert!(close(got, want), "{filter:?} at ({u}, {v}) lod {lod}: {got:?}, oracle {want:?}");
        }
    }
}

#[test]
fn a_bilinear_height_is_nodata_only_where_every_weighed_texel_is() {
    let f = HeightFormat::float(Some(-32768.0)).unwrap();
    let nd = -32768.0;
    // 2 x 2 texels: (0, 0) 100 m, the rest nodata; level 1 nodata.
    let src = height_levels(2, 2, 2, f, vec![vec![100.0, nd, nd, nd], vec![nd]]);
    let mut mip = MipmapSampler::new(&src);
    // Anywhere the texel with data weighs anything, the sample is its height (renormalised).
    for (u, v) in [(0.5, 0.5), (1.0, 1.0), (1.49, 0.5), (0.2, 1.4)] {
        assert_eq!(mip.sample_height(Filter::Bilinear, u, v, 0.0).unwrap(), Some(100.0), "({u}, {v})");
    }
    // At the centre of a nodata texel only it weighs: nodata; so at level 1, and point too.
    assert_eq!(mip.sample_height(Filter::Bilinear, 1.5, 1.5, 0.0).unwrap(), None);
    assert_eq!(mip.sample_height(Filter::Bilinear, 1.0, 1.0, 1.0).unwrap(), None);
    assert_eq!(mip.sample_height(Filter::Point, 1.2, 0.2, 0.0).unwrap(), None);
    // Trilinear halfway between: level 1 is nodata, so level 0's data alone.
    assert_eq!(mip.sample_height(Filter::Trilinear, 0.5, 0.5, 0.5).unwrap(), Some(100.0));
}

#[test]
fn a_one_millimetre_step_at_the_deepest_sea_and_the_highest_peak_survives_every_rule_and_the_sampler() {
    let f = HeightFormat::float(Some(-32768.0)).unwrap();
    for base in [-11000.0, 8900.0] {
        let (lo, hi) = (f.encode(base).unwrap(), f.encode(base + 0.001).unwrap());
        assert!(hi > lo, "{base}: 1 mm is stored apart");
        // Level 0: 4 x 2 texels, the left 2 x 2 block `lo`, the right `hi`; each rule makes level 1.
        let level0 = vec![lo, lo, hi, hi, lo, lo, hi, hi];
        for rule in LevelRule::ALL {
            let desc = TextureDesc::new([4, 2], 16, TexelFormat::L32F, [4, 4]).unwrap();
            let src = HeightLevels::by_rule(desc, f, rule, level0.clone()).unwrap();
            let mut mip = MipmapSampler::new(&src);
            for lod in [0.0, 1.0] {
                let scale = if lod == 0.0 { 1.0 } else { 2.0 };
                // Point: each side its own height, exactly.
                let left = mip.sample_height(Filter::Point, 0.5 * scale, 0.5, lod).unwrap().unwrap();
                let right = mip.sample_height(Filter::Point, 3.5, 0.5, lod).unwrap().unwrap();
                assert_eq!((left, right), (lo, hi), "{base} m {rule} lod {lod} point");
                // Bilinear across the step: from `lo` to `hi`, strictly rising, within both.
                let (a, b) = if lod == 0.0 { (1.5, 2.5) } else { (1.0, 3.0) };
                let mut last = lo;
                for i in 0..=8 {
                    let u = a + (b - a) * i as f64 / 8.0;
                    let m = mip.sample_height(Filter::Bilinear, u, 1.0, lod).unwrap().unwrap();
                    assert!(m >= lo && m <= hi, "{base} m {rule} lod {lod} at {u}: {m}");
                    if i > 0 {
                        assert!(m > last, "{base} m {rule} lod {lod} at {u}: {m} after {last}");
                    }
                    last = m;
                }
                assert_eq!(last, hi);
                assert!(hi - lo > 0.0009 && hi - lo < 0.0011, "{base}: the step is about 1 mm: {}", hi - lo);
            }
        }
    }
}

#[test]
fn heights_of_a_2_26_texture_sample_exactly_at_its_far_corner() {
    use crate::source::procedural::height_stored;
    let f = HeightFormat::VERIFICATION;
    let desc = TextureDesc::new([1 << 26; 2], 256, TexelFormat::L32F, [64, 64]).unwrap();
    let src: Arc<dyn TileSource> = Arc::new(HeightSource::new(desc, f));
    let far = (1u64 << 26) - 1;
    let def = |s: u64, t: u64| f.decode(height_stored(&f, 0, s, t));
    // Through the full mipmap and through a clipmap centred on the corner.
    let settings = Settings { budget_ns: None, ..Settings::default() };
    let mut map = Clipmap::new(src.clone(), settings).unwrap();
    let corner = [far as i64, far as i64];
    for _ in 0..64 {
        if map.tick(corner, Some([0, 0])).min_lod == 0.0 {
            break;
        }
        map.wait_for_reads();
    }
    assert_eq!(map.min_lod(), 0.0);
    let mut mip = MipmapSampler::new(src.as_ref());
    let (mut with_data, mut mixed) = (0, 0);
    for ds in 0..6u64 {
        for dt in 0..6u64 {
            let (s, t) = (far - ds, far - dt);
            let (u, v) = (s as f64 + 0.5, t as f64 + 0.5);
            let want = def(s, t);
            assert_eq!(mip.sample_height(Filter::Point, u, v, 0.0).unwrap(), want, "point ({s}, {t})");
            let got = sample_clipmap_height(&map, Filter::Point, u, v, 0.0).unwrap().unwrap();
            assert_eq!((got.metres, got.lod), (want, 0.0), "clipmap point ({s}, {t})");
            // Bilinear a quarter and three quarters of the way to the next texel: the four
            // texels (s - 1 .. s, t - 1 .. t), weights 1/16 .. 9/16 (exact), renormalised over
            // those with data by one division.
            let (x, y) = (u - 0.75, v - 0.25);
            let (fx, fy) = (0.25, 0.75);
            let four = [
                (s - 1, t - 1, (1.0 - fx) * (1.0 - fy)),
                (s, t - 1, fx * (1.0 - fy)),
                (s - 1, t, (1.0 - fx) * fy),
                (s, t, fx * fy),
            ];
            let (mut sum, mut weights) = (0.0f64, 0.0f64);
            for (a, b, w) in four {
                if let Some(m) = def(a, b) {
                    sum += w * m;
                    weights += w;
                }
            }
            let want = (weights > 0.0).then(|| sum / weights);
            if weights == 1.0 {
                with_data += 1;
            } else if weights > 0.0 {
                mixed += 1;
            }
            let got = mip.sample_height(Filter::Bilinear, x, y, 0.0).unwrap();
            assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "bilinear ({x}, {y})");
            let got = sample_clipmap_height(&map, Filter::Bilinear, x, y, 0.0).unwrap().unwrap();
            assert_eq!(
                (got.metres.map(f64::to_bits), got.lod),
                (want.map(f64::to_bits), 0.0),
                "clipmap bilinear ({x}, {y})"
            );
        }
    }
    assert!(with_data > 10 && mixed > 0, "footprints with every texel and with some nodata: {with_data}, {mixed}");
}

#[test]
fn the_clipmap_and_the_mapping_sample_heights_exactly_as_the_full_mipmap() {
    let desc =
        TextureDesc::new([1 << 12; 2], 128, TexelFormat::L32F, [32, 32]).unwrap().with_invalid_border(4).unwrap();
    let source: Arc<dyn TileSource> = Arc::new(HeightSource::new(desc, HeightFormat::VERIFICATION));
    let dir = tempfile::tempdir().unwrap();
    let settings = Settings { budget_ns: None, fade_ticks: 1, ..Settings::default() };
    let shape = Clipmap::shape_for(source.desc(), &settings);
    let heights = source.heights().map(|h| crate::shm::layout::Heights::of(&h.format, h.levels));
    let w = crate::shm::Writer::create(
        crate::shm::WriterOptions::new(dir.path(), "hts", shape, source.desc().format()).heights(heights),
    )
    .unwrap();
    let mut map = Clipmap::with_memory(source.clone(), settings, w.memory()).unwrap();
    let client = Client::attach(dir.path(), "hts").unwrap();
    let mut full = MipmapSampler::new(source.as_ref());
    let mut c = [2000i64, 2100];
    let mut rng = 7u64;
    let mut next = || {
        rng = crate::source::procedural::splitmix64(rng);
        rng
    };
    let (mut compared, mut coarser, mut nodata) = (0, 0, 0);
    for tick in 0..20 {
        c = [c[0] + 11, c[1] - 9];
        map.tick(c, None);
        map.wait_for_reads();
        if tick < 5 {
            continue;
        }
        for _ in 0..100 {
            let u = c[0] as f64 + (next() % 1200) as f64 - 600.0 + (next() % 1000) as f64 / 1000.0;
            let v = c[1] as f64 + (next() % 1200) as f64 - 600.0 + (next() % 1000) as f64 / 1000.0;
            let lod = (next() % 600) as f64 / 100.0;
            let filter = FILTERS[(next() % 3) as usize];
            let engine = sample_clipmap_height(&map, filter, u, v, lod).unwrap().expect("the engine holds it");
            let mapped = sample_mapping_height(&client, filter, u, v, lod).unwrap().expect("the mapping holds it");
            assert_eq!(mapped, engine, "{filter:?} at ({u}, {v}) lod {lod}");
            // The same level as colours pick, and the full mipmap's metres there.
            let colour = sample_clipmap(&map, filter, u, v, lod).unwrap();
            assert_eq!(engine.lod, colour.lod, "{filter:?} at ({u}, {v}) lod {lod}");
            let want = full.sample_height(filter, u, v, engine.lod).unwrap();
            assert_eq!(
                engine.metres.map(f64::to_bits),
                want.map(f64::to_bits),
                "{filter:?} ({u}, {v}) lod {}",
                engine.lod
            );
            compared += 1;
            coarser += usize::from(engine.lod > lod);
            nodata += usize::from(engine.metres.is_none());
        }
    }
    assert_eq!(compared, 1500);
    assert!(coarser > 0 && nodata > 0, "coarser levels used {coarser}, nodata samples {nodata}");
    // A colour texture is refused, saying so.
    let (colour_map, _cw) = mapped_service(dir.path(), "rgba");
    let e = sample_clipmap_height(&colour_map, Filter::Point, 5.5, 5.5, 0.0).unwrap_err();
    assert!(e.to_string().contains("the clipmap is not a height texture: its texels are rgba8"), "{e}");
    let e =
        MipmapSampler::new(&HashSource::new(mapped_desc())).sample_height(Filter::Point, 0.5, 0.5, 0.0).unwrap_err();
    assert!(e.to_string().contains("the tile source is not a height texture"), "{e}");
    let colour_client = Client::attach(dir.path(), "rgba").unwrap();
    let e = sample_mapping_height(&colour_client, Filter::Point, 5.5, 5.5, 0.0).unwrap_err();
    assert!(e.to_string().contains("the mapping is not a height texture"), "{e}");
}

/// A clipmap that wraps in longitude (`Settings::wrap_longitude`) is sampled across its
/// antimeridian as the mapping's readers sample it: column s is column `s mod width`, so a
/// footprint just past the east edge takes the westmost texels and one just west of s = 0 the
/// eastmost, where a texture that does not wrap clamps to its edge.
#[test]
fn a_wrapping_clipmap_samples_across_the_antimeridian_at_s_mod_width() {
    let size = 1024u64;
    let desc =
        TextureDesc::new([size, size], 64, TexelFormat::RGBA8, [16, 16]).unwrap().with_invalid_border(2).unwrap();
    let src: Arc<dyn TileSource> = Arc::new(HashSource::new(desc));
    let settings = Settings { budget_ns: None, wrap_longitude: true, ..Settings::default() };
    let mut map = Clipmap::new(src.clone(), settings).unwrap();
    let centre = [size as i64 - 2, 500];
    for _ in 0..8 {
        map.tick(centre, Some([0, 0]));
        map.wait_for_reads();
    }
    map.tick(centre, Some([0, 0]));
    assert_eq!(map.min_lod(), 0.0);
    let mut mip = MipmapSampler::new(src.as_ref());
    let w = size as f64;
    for (u, at) in [(w + 0.5, 0.5), (w + 7.25, 7.25), (w - 0.5, w - 0.5), (-0.5, w - 0.5), (-3.75, w - 3.75)] {
        let v = 500.5;
        let got = sample_clipmap(&map, Filter::Point, u, v, 0.0).unwrap();
        assert_eq!(got.lod, 0.0, "({u}, {v}): level 0 holds it");
        let want = mip.sample(Filter::Point, at, v, 0.0).unwrap();
        assert_eq!(got.rgba.map(f32::to_bits), want.map(f32::to_bits), "({u}, {v}) against ({at}, {v})");
    }
    // Bilinear at the seam blends column width - 1 with column 0.
    let got = sample_clipmap(&map, Filter::Bilinear, w, 500.5, 0.0).unwrap().rgba;
    let (east, west) =
        (mip.sample(Filter::Point, w - 0.5, 500.5, 0.0).unwrap(), mip.sample(Filter::Point, 0.5, 500.5, 0.0).unwrap());
    for c in 0..4 {
        let want = east[c] + (west[c] - east[c]) * 0.5;
        assert!((got[c] - want).abs() < 1e-6, "component {c}: {} against {want}", got[c]);
    }
}
