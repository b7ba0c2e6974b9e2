//! Numerical stability at the extremes (the accuracy issue): textures of 2^26 texels a side,
//! clip sizes from 1 to 8192, centres at 0, at the far edge, outside the texture, negative and
//! crossing wrap boundaries, 1x1 levels, non-square textures, texture coordinates computed in f64
//! near the far corner. Every case: no panic, every published texel right, and the sampling
//! identity (the clipmap sample equals the full-mipmap sample at the level the clipmap used).

use clipmap::clip::{Clipmap, Settings};
use clipmap::sample::{sample_clipmap, Filter, MipmapSampler};
use clipmap::source::procedural::{hash, splitmix64};
use clipmap::source::{HashSource, TextureDesc, TileSource};
use clipmap::texel::TexelFormat;
use std::sync::Arc;

fn engine(size: [u64; 2], clip: u64, tile: u64, format: TexelFormat) -> (Clipmap, Arc<HashSource>) {
    let border = ((clip - 1) / 2).min(4);
    let desc = TextureDesc::new(size, clip, format, [tile, tile]).unwrap().with_invalid_border(border).unwrap();
    let src = Arc::new(HashSource::new(desc));
    let settings = Settings { budget_ns: None, fade_ticks: 1, ..Settings::default() };
    (Clipmap::new(src.clone(), settings).unwrap(), src)
}

fn settle(map: &mut Clipmap, centre: [i64; 2]) {
    for _ in 0..40 {
        let r = map.tick(centre, None);
        map.wait_for_reads();
        if r.tiles_read == 0 && r.min_lod == 0.0 {
            return;
        }
    }
}

/// Every published texel of every level equals the hash texel (sampled on big windows).
fn check_texels(map: &Clipmap) -> u64 {
    let bpt = map.desc().bytes_per_texel();
    let mut want = vec![0u8; bpt];
    let mut n = 0;
    for k in 0..map.level_count() as u32 {
        let v = map.level(k);
        let r = v.valid;
        let step = ((r.width().max(r.height()) / 64).max(1)) as i64;
        let mut t = r.t0;
        while t < r.t1 {
            let mut s = r.s0;
            while s < r.s1 {
                hash(k, s as u64, t as u64, &mut want);
                assert_eq!(&*v.texel(s, t).unwrap(), &want[..], "level {k} texel ({s}, {t})");
                n += 1;
                s += step;
            }
            t += step;
        }
    }
    n
}

/// The clipmap's sample equals the full mipmap's at the LOD the clipmap used.
fn check_identity(map: &Clipmap, src: &dyn TileSource, centre: [i64; 2], seed: u64) {
    let mut reference = MipmapSampler::new(src);
    let size = map.desc().size();
    if map.desc().clip_size() >= 64 {
        // At the centre the finest level is available: the identity is not met by falling back.
        let (u, v) = (centre[0] as f64 + 0.5, centre[1] as f64 + 0.5);
        let got = sample_clipmap(map, Filter::Bilinear, u, v, 0.0).unwrap();
        assert_eq!(got.lod, 0.0, "level 0 must hold the centre {centre:?}");
        assert_eq!(got.rgba, reference.sample(Filter::Bilinear, u, v, 0.0).unwrap());
    }
    let mut rng = seed;
    for i in 0..200 {
        rng = splitmix64(rng);
        let radius = 1u64 << (rng % 24);
        let du = (splitmix64(rng) % (2 * radius)) as f64 - radius as f64 + 0.37;
        let dv = (splitmix64(rng ^ 1) % (2 * radius)) as f64 - radius as f64 + 0.61;
        // Texture coordinates in f64 from an integer centre: exact for 2^26 + fractions.
        let u = (centre[0] as f64 + du).clamp(0.0, size[0] as f64 - 0.5);
        let v = (centre[1] as f64 + dv).clamp(0.0, size[1] as f64 - 0.5);
        let lod = (i % 7) as f64 * 1.3;
        let filter = [Filter::Point, Filter::Bilinear, Filter::Trilinear][i % 3];
        let got = sample_clipmap(map, filter, u, v, lod).expect("the pyramid always holds a sample");
        let want = reference.sample(filter, u, v, got.lod).unwrap();
        assert_eq!(got.rgba, want, "({u}, {v}) lod {lod} -> {}, {filter:?}", got.lod);
    }
}

#[test]
fn a_2_pow_26_texture_at_every_extreme_centre_and_clip_size() {
    let size = 1u64 << 26;
    let far = size as i64 - 1;
    for (clip, tile) in [(1u64, 1u64), (2, 2), (8, 8), (64, 32), (1024, 256)] {
        let (mut map, src) = engine([size, size], clip, tile, TexelFormat::RGBA8);
        for centre in [[0, 0], [far, far], [far, 0], [-5000, far + 5000], [-(1 << 40), 1 << 40], [size as i64 / 2, 7]] {
            settle(&mut map, centre);
            assert!(check_texels(&map) > 0);
            check_identity(
                &map,
                src.as_ref(),
                [centre[0].clamp(0, far), centre[1].clamp(0, far)],
                clip ^ centre[0] as u64,
            );
        }
        // Crossing wrap boundaries (multiples of the clip size) in both directions.
        let c = clip as i64;
        for step in [c - 1, c, c + 1, -c - 1, 3 * c / 2 + 1] {
            let centre = [size as i64 / 2 + step, size as i64 / 2 - step];
            settle(&mut map, centre);
            check_texels(&map);
            check_identity(&map, src.as_ref(), centre, step as u64);
        }
        assert_eq!(map.level(map.level_count() as u32 - 1).size, [1, 1], "the 1x1 level exists");
    }
}

#[test]
fn non_square_and_the_largest_clip_size() {
    // 8192-texel clip on a texture whose level 0 is one window wider than the clip (L8 keeps the
    // windows at 64 MiB each).
    let (mut map, src) = engine([16384, 16384], 8192, 1024, TexelFormat::L8);
    for centre in [[0, 0], [16383, 16383], [8192, 8191]] {
        settle(&mut map, centre);
        check_texels(&map);
        check_identity(&map, src.as_ref(), centre, 3);
    }
    let (mut map, src) = engine([1 << 26, 1 << 12], 256, 64, TexelFormat::RGB8);
    for centre in [[0, 0], [(1 << 26) - 1, (1 << 12) - 1], [1 << 25, -40]] {
        settle(&mut map, centre);
        check_texels(&map);
        check_identity(&map, src.as_ref(), [centre[0], centre[1].max(0)], 9);
    }
}
