//! Procedural textures defined per level, for textures up to 2^30 texels a side without a file.
//!
//! * [`hash`]: the verification texture of docs/ARCHITECTURE.md §11. The texel at level L, column s, row t is
//!   the little-endian bytes of `splitmix64((L << 58) | (t << 29) | s)`; a format of `n` bytes per
//!   texel takes bytes `0..n` of that 64-bit value (cycling for formats wider than 8 bytes). Any
//!   reader can check any texel it reads without a reference copy. Each level is defined on its
//!   own, so a pyramid of it is *not* a filtered pyramid.
//! * [`Terrain`]: smooth fractal value noise coloured like land and sea. Level k is band-limited
//!   analytically (octaves finer than two level-k texels are dropped), so any texel of any level of
//!   a 2^30 texture costs the same few dozen operations. All lattice arithmetic is integer; only
//!   the fractional position inside a lattice cell is a float, so precision does not degrade at
//!   the far corner of the texture.
//!
//! This module only computes texel values; reading them through tiles is the engine's business.

use crate::texel::TexelFormat;

pub use crate::tile::{hash_value, splitmix64};

/// Writes the verification texel at (level, s, t) into `out` (any length: byte i is byte i mod 8
/// of [`hash_value`], little-endian).
#[inline]
pub fn hash(level: u32, s: u64, t: u64, out: &mut [u8]) {
    let bytes = hash_value(level, s, t).to_le_bytes();
    for (i, b) in out.iter_mut().enumerate() {
        *b = bytes[i & 7];
    }
}

/// Fills a `w` x `h` region of level `level` whose lower-left texel is (s0, t0) with the
/// verification texture, rows in increasing t, s fastest, `bpt` bytes per texel.
pub fn hash_region(level: u32, s0: u64, t0: u64, w: usize, h: usize, bpt: usize, out: &mut [u8]) {
    assert_eq!(out.len(), w * h * bpt, "hash_region: buffer size does not match the region");
    for (row, line) in out.chunks_exact_mut(w * bpt.max(1)).enumerate() {
        let t = t0 + row as u64;
        match bpt {
            // The common sizes as whole stores (a tile read is this loop: it sets how fast the
            // verification texture can be flown).
            4 => {
                for (col, texel) in line.chunks_exact_mut(4).enumerate() {
                    texel.copy_from_slice(&(hash_value(level, s0 + col as u64, t) as u32).to_le_bytes());
                }
            }
            8 => {
                for (col, texel) in line.chunks_exact_mut(8).enumerate() {
                    texel.copy_from_slice(&hash_value(level, s0 + col as u64, t).to_le_bytes());
                }
            }
            _ => {
                for (col, texel) in line.chunks_exact_mut(bpt.max(1)).enumerate() {
                    hash(level, s0 + col as u64, t, texel);
                }
            }
        }
    }
}

/// Smooth fractal noise ("terrain"), defined for every level of a square texture of
/// `size` = 2^n texels a side.
#[derive(Clone, Copy, Debug)]
pub struct Terrain {
    /// log2 of the level-0 size.
    pub log2_size: u32,
    /// Seed mixed into every lattice hash.
    pub seed: u64,
}

impl Terrain {
    /// Finest octave's wavelength, in level-0 texels (log2).
    const FINEST_LOG2: u32 = 2;

    /// A terrain for a 2^`log2_size` texture.
    pub fn new(log2_size: u32, seed: u64) -> Self {
        Terrain { log2_size, seed }
    }

    /// Height in 0..=1 at level `level`, texel (s, t): the sum of value-noise octaves evaluated at
    /// the texel's centre, leaving out octaves shorter than two texels of that level.
    pub fn height(&self, level: u32, s: u64, t: u64) -> f64 {
        // Texel centre in units of half level-0 texels: exact integers up to 2^(26+1+level).
        let shift = level;
        let x = (2 * s + 1) << shift;
        let y = (2 * t + 1) << shift;
        let coarsest = self.log2_size.saturating_sub(1).max(Self::FINEST_LOG2);
        let finest = Self::FINEST_LOG2.max(level + 1);
        let mut sum = 0.0;
        let mut norm = 0.0;
        let mut amp = 1.0;
        let mut j = coarsest;
        loop {
            if j < finest {
                break;
            }
            sum += amp * self.octave(j, x, y);
            norm += amp;
            amp *= 0.55;
            if j == 0 {
                break;
            }
            j -= 1;
        }
        if norm == 0.0 {
            // A level so coarse that every octave is filtered out: the mean.
            return 0.5;
        }
        sum / norm
    }

    /// One octave of wavelength 2^j level-0 texels at (x, y) in half-texel units.
    fn octave(&self, j: u32, x: u64, y: u64) -> f64 {
        self.octave_salted(j, x, y, 0)
    }

    /// An octave of an independent noise field per `salt`.
    fn octave_salted(&self, j: u32, x: u64, y: u64, salt: u64) -> f64 {
        let cell_shift = j + 1;
        let (cx, cy) = (x >> cell_shift, y >> cell_shift);
        let scale = (1u64 << cell_shift) as f64;
        let fx = (x & ((1u64 << cell_shift) - 1)) as f64 / scale;
        let fy = (y & ((1u64 << cell_shift) - 1)) as f64 / scale;
        let smooth = |f: f64| f * f * (3.0 - 2.0 * f);
        let (sx, sy) = (smooth(fx), smooth(fy));
        let v = |i: u64, k: u64| self.lattice(j, i, k, salt);
        let a = v(cx, cy) + (v(cx + 1, cy) - v(cx, cy)) * sx;
        let b = v(cx, cy + 1) + (v(cx + 1, cy + 1) - v(cx, cy + 1)) * sx;
        a + (b - a) * sy
    }

    fn lattice(&self, j: u32, i: u64, k: u64, salt: u64) -> f64 {
        let h = splitmix64(self.seed ^ salt ^ splitmix64(((j as u64) << 58) ^ (k << 29) ^ i));
        (h >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Colour for a height: deep and shallow water, sand, grass, rock, snow.
    pub fn colour(height: f64) -> [f32; 4] {
        const STOPS: [(f64, [f32; 3]); 6] = [
            (0.00, [0.02, 0.10, 0.35]),
            (0.45, [0.10, 0.35, 0.65]),
            (0.50, [0.80, 0.75, 0.55]),
            (0.58, [0.20, 0.55, 0.20]),
            (0.72, [0.45, 0.40, 0.35]),
            (0.85, [0.95, 0.95, 0.97]),
        ];
        let h = height.clamp(0.0, 1.0);
        for w in STOPS.windows(2) {
            let (h0, c0) = w[0];
            let (h1, c1) = w[1];
            if h <= h1 {
                let f = ((h - h0) / (h1 - h0)) as f32;
                return [c0[0] + (c1[0] - c0[0]) * f, c0[1] + (c1[1] - c0[1]) * f, c0[2] + (c1[2] - c0[2]) * f, 1.0];
            }
        }
        let c = STOPS[STOPS.len() - 1].1;
        [c[0], c[1], c[2], 1.0]
    }

    /// Surface detail in -1..=1 at (level, s, t): the four finest octaves (wavelengths 4 to 32
    /// level-0 texels) at equal weight, band-limited like [`height`](Self::height), so the texture
    /// shows structure at every viewing distance. 0 where a level filters them all out.
    pub fn detail(&self, level: u32, s: u64, t: u64) -> f64 {
        let x = (2 * s + 1) << level;
        let y = (2 * t + 1) << level;
        let (mut sum, mut n) = (0.0, 0.0);
        for j in Self::FINEST_LOG2..Self::FINEST_LOG2 + 4 {
            if j < level + 1 {
                continue;
            }
            sum += self.octave_salted(j, x, y, 0x00D3_7A11) - 0.5;
            n += 1.0;
        }
        if n == 0.0 {
            0.0
        } else {
            (2.0 * sum / n).clamp(-1.0, 1.0)
        }
    }

    /// Writes the texel at (level, s, t) in `format` into `out`: the height's colour, shaded by
    /// the surface detail.
    pub fn texel(&self, level: u32, s: u64, t: u64, format: TexelFormat, out: &mut [u8]) {
        let c = Self::colour(self.height(level, s, t));
        let shade = (1.0 + 0.35 * self.detail(level, s, t)) as f32;
        format.encode([c[0] * shade, c[1] * shade, c[2] * shade, c[3]], out);
    }
}

/// The height verification texture (docs/ELEVATION.md, "The height verification texture"):
/// the stored value at (level, s, t) in `format`, computable by any reader from
/// `h = hash_value(level, s, t)` alone, each level on its own like [`hash`]:
///
/// - nodata when the format has a nodata value and the top four bits of `h` are 0 (one texel in
///   sixteen);
/// - `l32f`: `k = h mod 20377601`, metres `(k - 11264000) / 1024`: -11000 m to +8900 m in steps of
///   2^-10 m, every one exactly an `f32`;
/// - `l16`, `l16i`: the low 16 bits of `h` (unsigned or signed);
/// - a data value equal to the nodata value moves one step (to `k - 1`, or `k + 1` at `k = 0`;
///   the low bit flipped for the 16-bit storages), so data never reads as nodata.
pub fn height_stored(format: &crate::height::HeightFormat, level: u32, s: u64, t: u64) -> f64 {
    use crate::height::HeightStorage;
    const STEPS: u64 = 19_900 * 1024 + 1;
    const BELOW: i64 = 11_000 * 1024;
    let h = hash_value(level, s, t);
    if let Some(nd) = format.nodata() {
        if h >> 60 == 0 {
            return nd;
        }
    }
    match format.storage() {
        HeightStorage::F32 => {
            let k = (h % STEPS) as i64;
            let v = (k - BELOW) as f64 / 1024.0;
            if format.is_nodata(v) {
                (if k > 0 { k - 1 - BELOW } else { k + 1 - BELOW }) as f64 / 1024.0
            } else {
                v
            }
        }
        storage => {
            let low = h as u16;
            let v = |b: u16| if storage == HeightStorage::U16 { b as f64 } else { b as i16 as f64 };
            if format.is_nodata(v(low)) {
                v(low ^ 1)
            } else {
                v(low)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn height_texels_are_in_range_exact_and_never_data_equal_to_nodata() {
        use crate::height::{HeightFormat, HeightStorage};
        let f = HeightFormat::float(Some(-32768.0)).unwrap();
        let (mut nodata, mut lo, mut hi) = (0, f64::INFINITY, f64::NEG_INFINITY);
        for i in 0..20_000u64 {
            let v = height_stored(&f, (i % 5) as u32, i * 7919 % 100_003, i);
            if f.is_nodata(v) {
                nodata += 1;
                continue;
            }
            assert_eq!(v as f32 as f64, v, "an f32");
            assert_eq!((v * 1024.0).fract(), 0.0, "a 2^-10 step");
            (lo, hi) = (lo.min(v), hi.max(v));
        }
        assert!((-11000.0..-10900.0).contains(&lo) && (8800.0..=8900.0).contains(&hi), "{lo} {hi}");
        assert!((1000..1500).contains(&nodata), "about one in sixteen: {nodata}");
        // The definition, by hand, for one texel.
        let h = hash_value(3, 17, 5);
        let want = if h >> 60 == 0 { -32768.0 } else { ((h % 20_377_601) as i64 - 11_264_000) as f64 / 1024.0 };
        assert_eq!(height_stored(&f, 3, 17, 5), want);
        // A nodata value among the data: every texel with data avoids it.
        for storage in [HeightStorage::U16, HeightStorage::I16] {
            let nd = (hash_value(0, 1, 1) as u16) as f64;
            let nd = if storage == HeightStorage::I16 { (nd as u16 as i16) as f64 } else { nd };
            let g = HeightFormat::new(storage, 0.01, 0.0, Some(nd)).unwrap();
            let v = height_stored(&g, 0, 1, 1);
            if hash_value(0, 1, 1) >> 60 != 0 {
                assert_ne!(v, nd);
                assert_eq!((v as i64 ^ nd as i64).abs(), 1, "the low bit flipped");
            }
        }
        let f = HeightFormat::float(Some(height_stored(&HeightFormat::float(None).unwrap(), 0, 2, 2))).unwrap();
        if hash_value(0, 2, 2) >> 60 != 0 {
            assert!(!f.is_nodata(height_stored(&f, 0, 2, 2)));
        }
    }

    #[test]
    fn hash_texel_is_the_low_bytes_of_the_key() {
        let mut four = [0u8; 4];
        hash(3, 17, 5, &mut four);
        let v = splitmix64((3u64 << 58) | (5 << 29) | 17);
        assert_eq!(four, (v as u32).to_le_bytes());
        let mut three = [0u8; 3];
        hash(3, 17, 5, &mut three);
        assert_eq!(three, four[..3]);
    }

    #[test]
    fn hash_region_matches_texel_by_texel() {
        let mut buf = vec![0u8; 5 * 3 * 4];
        hash_region(2, 100, 200, 5, 3, 4, &mut buf);
        let mut one = [0u8; 4];
        hash(2, 104, 202, &mut one);
        assert_eq!(&buf[(2 * 5 + 4) * 4..(2 * 5 + 5) * 4], &one);
    }

    #[test]
    fn terrain_is_smooth_and_in_range_even_at_the_far_corner() {
        let t = Terrain::new(26, 7);
        let far = (1u64 << 26) - 1;
        for level in [0, 1, 10, 25, 26] {
            let size = 1u64 << (26 - level);
            let s = far >> level;
            let h = t.height(level, s.min(size - 1), s.min(size - 1));
            assert!((0.0..=1.0).contains(&h), "level {level}: {h}");
        }
        // Neighbouring level-0 texels differ little (smoothness).
        let a = t.height(0, 1 << 25, 1 << 25);
        let b = t.height(0, (1 << 25) + 1, 1 << 25);
        assert!((a - b).abs() < 0.05, "{a} vs {b}");
    }
}
