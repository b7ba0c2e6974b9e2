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
        crate::shm::Writer::create(dir, name, shape, source.desc().format(), 0o600, 0o600, 16_666_667, None).unwrap();
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
    let w = crate::shm::Writer::create(dir.path(), "hole", shape, TexelFormat::RGBA8, 0o600, 0o600, 1_000_000, None)
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
