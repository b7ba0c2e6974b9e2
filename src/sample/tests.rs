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
