//! Sizing arithmetic: clipmap against full-mipmap memory (docs/ARCHITECTURE.md §3), the stack/pyramid
//! split, update bandwidth for a centre speed, clip-size recommendations for a display, and
//! Performer's virtual clip-texture parameter rule (docs/PERFORMER-REFERENCE.md §2.8).
//!
//! Pure functions on exact integers (u128 for texel and byte counts); nothing here reads files.

use serde::Serialize;

/// Memory of a 2^a x 2^b texture with clip size 2^m (square: a = b = n).
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Memory {
    /// Level-0 width (S) in texels.
    pub width: u64,
    /// Level-0 height (T) in texels.
    pub height: u64,
    /// log2 of the texture's longer side.
    pub log2_size: u32,
    /// log2 of the clip size (clamped to the texture size).
    pub log2_clip: u32,
    /// Levels with a side larger than the clip size (only a window is resident).
    pub stack_levels: u32,
    /// Levels no larger than the clip size (resident whole).
    pub pyramid_levels: u32,
    /// Texels resident in the clipmap: for a square texture 4^m (n - m + 4/3) - 1/3; in general
    /// the sum over levels of min(W_k, C) x min(H_k, C).
    pub clipmap_texels: u128,
    /// Bytes resident in the clipmap.
    pub clipmap_bytes: u128,
    /// Texels of the full mipmap of the same levels: (4^(n+1) - 1) / 3 for a square texture;
    /// in general the sum over levels of W_k x H_k.
    pub mipmap_texels: u128,
    /// Bytes of the full mipmap.
    pub mipmap_bytes: u128,
}

/// Why sizing inputs are refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SizingError {
    /// A size that is not a power of two.
    #[error("{what} must be a power of two, found {value} (nearest: {})", nearest_powers(*value))]
    NotPowerOfTwo {
        /// Which input.
        what: &'static str,
        /// Its value.
        value: u64,
    },
    /// A value out of the supported range.
    #[error("{what} must be between {min} and {max}, found {value}")]
    OutOfRange {
        /// Which input.
        what: &'static str,
        /// Its value.
        value: u64,
        /// Smallest allowed.
        min: u64,
        /// Largest allowed.
        max: u64,
    },
}

/// The powers of two around `v`, in words: "512 or 1024", or the largest past it.
fn nearest_powers(v: u64) -> String {
    match v.checked_next_power_of_two() {
        Some(next) => format!("{} or {next}", next / 2),
        None => format!("{} (2^63, the largest)", 1u64 << 63),
    }
}

fn pow2(what: &'static str, value: u64) -> Result<u32, SizingError> {
    if value == 0 || !value.is_power_of_two() {
        return Err(SizingError::NotPowerOfTwo { what, value });
    }
    Ok(value.trailing_zeros())
}

/// Memory of a `size` x `size` texture with clip size `clip` and `texel_bytes` per texel.
/// `size` up to 2^40, `clip` a power of two (clamped to `size`).
///
/// ```
/// // The whole earth at one metre a texel, a 2048 clip, RGBA8: 261 MiB instead of 21 PiB.
/// let m = clipmap_base::sizing::memory(1 << 26, 2048, 4).unwrap();
/// assert_eq!((m.stack_levels, m.pyramid_levels), (15, 12));
/// assert_eq!(m.clipmap_texels, 68_506_965);
/// assert_eq!(m.mipmap_texels, ((1u128 << 54) - 1) / 3);
/// ```
pub fn memory(size: u64, clip: u64, texel_bytes: u64) -> Result<Memory, SizingError> {
    let n = pow2("texture size", size)?;
    let m = pow2("clip size", clip)?.min(n);
    if n > 40 {
        return Err(SizingError::OutOfRange { what: "texture size", value: size, min: 1, max: 1 << 40 });
    }
    check_texel_bytes(texel_bytes)?;
    let four = |k: u32| 1u128 << (2 * k);
    let clipmap = (n - m) as u128 * four(m) + (four(m + 1) - 1) / 3;
    let mipmap = (four(n + 1) - 1) / 3;
    let b = texel_bytes as u128;
    Ok(Memory {
        width: size,
        height: size,
        log2_size: n,
        log2_clip: m,
        stack_levels: n - m,
        pyramid_levels: m + 1,
        clipmap_texels: clipmap,
        clipmap_bytes: clipmap * b,
        mipmap_texels: mipmap,
        mipmap_bytes: mipmap * b,
    })
}

fn check_texel_bytes(texel_bytes: u64) -> Result<(), SizingError> {
    if texel_bytes == 0 || texel_bytes > 64 {
        return Err(SizingError::OutOfRange { what: "texel bytes", value: texel_bytes, min: 1, max: 64 });
    }
    Ok(())
}

/// Memory of a `width` x `height` texture (powers of two, each up to 2^40). The levels are
/// Performer's: both sides halve until the short side is 1 (8192 x 2048 ends at 4 x 1), so the
/// level count is log2(short side) + 1; level k keeps min(W_k, C) x min(H_k, C) texels. The
/// clip size is clamped to the longer side. A square size gives exactly [`memory`].
///
/// ```
/// let m = clipmap_base::sizing::memory_rect(8192, 2048, 512, 3).unwrap();
/// assert_eq!((m.stack_levels, m.pyramid_levels), (4, 8)); // 8192x2048 .. 1024x256; 512x128 .. 4x1
/// // Three levels keep 512x512, 1024x256 keeps 512x256, and 512x128 .. 4x1 stay whole.
/// assert_eq!(m.clipmap_texels, 3 * 512 * 512 + 512 * 256 + (1..=8).map(|i| 1u128 << (2 * i)).sum::<u128>());
/// ```
pub fn memory_rect(width: u64, height: u64, clip: u64, texel_bytes: u64) -> Result<Memory, SizingError> {
    if width == height {
        return memory(width, clip, texel_bytes);
    }
    let a = pow2("texture width", width)?;
    let b = pow2("texture height", height)?;
    let n = a.max(b);
    if n > 40 {
        let (what, value) = if a >= b { ("texture width", width) } else { ("texture height", height) };
        return Err(SizingError::OutOfRange { what, value, min: 1, max: 1 << 40 });
    }
    let m = pow2("clip size", clip)?.min(n);
    check_texel_bytes(texel_bytes)?;
    let c = 1u128 << m;
    let (mut clipmap, mut mipmap, mut stack) = (0u128, 0u128, 0u32);
    let levels = a.min(b) + 1;
    for k in 0..levels {
        let (w, h) = ((width >> k) as u128, (height >> k) as u128);
        clipmap += w.min(c) * h.min(c);
        mipmap += w * h;
        if w > c || h > c {
            stack += 1;
        }
    }
    let bytes = texel_bytes as u128;
    Ok(Memory {
        width,
        height,
        log2_size: n,
        log2_clip: m,
        stack_levels: stack,
        pyramid_levels: levels - stack,
        clipmap_texels: clipmap,
        clipmap_bytes: clipmap * bytes,
        mipmap_texels: mipmap,
        mipmap_bytes: mipmap * bytes,
    })
}

/// Texels per second written into the stack levels' windows when the centre moves at `speed`
/// level-0 texels per second along one axis (diagonal motion costs up to twice this): level k
/// moves `speed / 2^k` texels a second and each texel of motion brings in a strip of `clip`
/// texels. Pyramid levels are resident whole and never update.
///
/// A non-square texture: motion along S rewrites only levels wider than the clip size, each with
/// a strip of min(H_k, clip) texels (along T the same with the roles swapped); the larger of the
/// two axes is returned.
pub fn update_texels_per_second(mem: &Memory, speed: f64) -> f64 {
    let clip = 1u64 << mem.log2_clip;
    let levels = mem.stack_levels + mem.pyramid_levels;
    let axis = |along: u64, across: u64| -> f64 {
        (0..levels)
            .filter(|&k| along >> k > clip)
            .map(|k| speed / (1u64 << k) as f64 * (across >> k).min(clip) as f64)
            .sum()
    };
    axis(mem.width, mem.height).max(axis(mem.height, mem.width))
}

/// Clip sizes for a display `width` pixels wide: the usual choice (the width, rounded up to a
/// power of two) and the pixel-exact one (twice that: trilinear filtering reads two levels).
pub fn recommended_clip(width: u64) -> (u64, u64) {
    let usual = width.max(1).next_power_of_two();
    (usual, usual * 2)
}

/// Inputs of Performer's `pfuCalcVirtualClipTexParams` (docs/PERFORMER-REFERENCE.md §2.8).
#[derive(Clone, Debug)]
pub struct VirtualInputs {
    /// Levels of the virtual texture.
    pub levels: u32,
    /// Clip size.
    pub clip_size: u64,
    /// Invalid border.
    pub invalid_border: u64,
    /// Finest LOD the hardware would sample (from screen derivatives plus bias).
    pub min_lod_tex_pix: f64,
    /// Finest LOD loaded (load control's min LOD).
    pub min_lod_loaded: f64,
    /// Coarsest LOD loaded (e.g. allocated levels).
    pub max_lod_loaded: f64,
    /// Distance, in normalised texture coordinates, from the clip centre to the nearest edge of
    /// the geometry's texture bounding box (0 when the centre is inside it).
    pub bbox_min_dist: f64,
    /// Distance to the farthest edge.
    pub bbox_max_dist: f64,
    /// 0 keeps resolution, 1 keeps area.
    pub tradeoff: f64,
}

/// Outputs of the rule.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct VirtualParams {
    /// First level the renderer addresses.
    pub lod_offset: u32,
    /// Levels it addresses at once.
    pub effective_levels: u32,
    /// Finest LOD to allow.
    pub min_lod: f64,
    /// Coarsest LOD to allow.
    pub max_lod: f64,
}

/// Performer's rule with its default limits (±1000 everywhere, 16 effective levels at most).
pub fn virtual_params(i: &VirtualInputs) -> VirtualParams {
    let n = i.levels as f64;
    let tradeoff = i.tradeoff.clamp(0.0, 1.0);
    let border = (i.invalid_border as f64).clamp(0.0, i.clip_size as f64 / 2.0);
    let effective_clip = i.clip_size as f64 - border;
    let reach = i.bbox_min_dist * 2f64.powf(n - 1.0);
    let min_lod_bbox = if reach <= effective_clip / 2.0 { 0.0 } else { (reach / (effective_clip / 2.0)).log2().ceil() };
    let mut lod_offset = i.min_lod_tex_pix.max(i.min_lod_loaded).max(min_lod_bbox).max(-1000.0).floor();
    lod_offset = lod_offset.clamp(0.0, (n - 1.0).min(i.max_lod_loaded).max(0.0));
    let mut num_effective = n - lod_offset;
    if i.bbox_max_dist > 0.0 {
        let how_many = ((5.0 / 16.0) / i.bbox_max_dist).log2().floor();
        if how_many > 0.0 {
            num_effective -= how_many;
        }
    }
    num_effective = num_effective.max(12.0).min(n - lod_offset);
    let max_effective = 16.0;
    if num_effective > max_effective {
        let needed = num_effective - max_effective;
        let coarse = ((1.0 - tradeoff) * needed).round();
        let fine = needed - coarse;
        lod_offset = (lod_offset + fine).min(1000.0);
        num_effective = max_effective;
    }
    let min_lod = i.min_lod_loaded.clamp(-1000.0, 1000.0);
    let max_lod = (lod_offset + 6.0).min(i.max_lod_loaded).clamp(-1000.0, 1000.0);
    VirtualParams { lod_offset: lod_offset as u32, effective_levels: num_effective.max(1.0) as u32, min_lod, max_lod }
}

/// Finest level the renderer samples at the foot of a camera `eye_height` metres above the
/// ground, looking straight down with a horizontal field of view `fov_deg` over `width` pixels,
/// on a texture of `texel_metres` metres per level-0 texel: log2(ground footprint of a pixel /
/// texel size), at least 0.
pub fn finest_lod_at_foot(eye_height: f64, fov_deg: f64, width: u64, texel_metres: f64) -> f64 {
    let pixel_angle = fov_deg.to_radians() / width.max(1) as f64;
    let footprint = eye_height * pixel_angle;
    (footprint / texel_metres).log2().max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force: sum the resident texels level by level.
    fn brute(n: u32, m: u32) -> (u128, u128) {
        let mut clip = 0u128;
        let mut full = 0u128;
        for k in 0..=n {
            let side = 1u128 << (n - k);
            full += side * side;
            let c = side.min(1u128 << m);
            clip += c * c;
        }
        (clip, full)
    }

    #[test]
    fn closed_forms_match_the_level_by_level_sum() {
        for n in 0..=30 {
            for m in 0..=n {
                let mem = memory(1 << n, 1 << m, 4).unwrap();
                let (c, f) = brute(n, m);
                assert_eq!((mem.clipmap_texels, mem.mipmap_texels), (c, f), "n={n} m={m}");
                assert_eq!(mem.clipmap_bytes, c * 4);
                assert_eq!(mem.stack_levels + mem.pyramid_levels, n + 1);
            }
        }
    }

    #[test]
    fn non_square_textures_match_the_level_by_level_sum() {
        for a in 0..=20u32 {
            for b in 0..=20u32 {
                for m in 0..=a.max(b) {
                    let (w, h) = (1u64 << a, 1u64 << b);
                    let mem = memory_rect(w, h, 1 << m, 3).unwrap();
                    // Brute force: Performer's levels end where the short side is 1.
                    let (mut clip, mut full, mut stack) = (0u128, 0u128, 0);
                    for k in 0..=a.min(b) {
                        let (lw, lh) = ((w >> k) as u128, (h >> k) as u128);
                        clip += lw.min(1 << m) * lh.min(1 << m);
                        full += lw * lh;
                        stack += u32::from(lw > 1 << m || lh > 1 << m);
                    }
                    assert_eq!((mem.clipmap_texels, mem.mipmap_texels), (clip, full), "{w}x{h} clip 2^{m}");
                    assert_eq!((mem.stack_levels, mem.stack_levels + mem.pyramid_levels), (stack, a.min(b) + 1));
                    assert_eq!(mem.clipmap_bytes, clip * 3);
                }
            }
        }
    }

    #[test]
    fn a_non_square_update_counts_only_the_levels_clipped_along_the_motion() {
        // 8192 x 2048, clip 512: along S, levels 0..3 are clipped (8192..1024 wide) with strips of
        // 512, 512, 512 and 256 texels; along T only levels 0 and 1 (2048, 1024 high) with 512.
        let mem = memory_rect(8192, 2048, 512, 4).unwrap();
        let s = 512.0 + 512.0 / 2.0 + 512.0 / 4.0 + 256.0 / 8.0;
        assert!((update_texels_per_second(&mem, 1.0) - s).abs() < 1e-9);
        let square = memory(4096, 512, 4).unwrap();
        assert!((update_texels_per_second(&square, 1.0) - 512.0 * (1.0 + 0.5 + 0.25)).abs() < 1e-9);
    }

    #[test]
    fn earth_at_one_metre_fits_in_memory() {
        let mem = memory(1 << 26, 2048, 4).unwrap();
        // 4^11 (26 - 11 + 4/3) - 1/3 = 15 * 4^11 + (4^12 - 1) / 3 = 68_506_965 texels.
        assert_eq!(mem.clipmap_texels, 68_506_965);
        assert_eq!(mem.mipmap_texels, ((1u128 << 54) - 1) / 3);
    }

    #[test]
    fn bad_inputs_are_refused() {
        assert!(matches!(memory(1000, 256, 4), Err(SizingError::NotPowerOfTwo { what: "texture size", .. })));
        assert!(matches!(memory(1024, 0, 4), Err(SizingError::NotPowerOfTwo { .. })));
        assert!(matches!(memory(1024, 256, 0), Err(SizingError::OutOfRange { .. })));
        assert!(memory(1 << 41, 256, 4).is_err());
    }

    #[test]
    fn update_bandwidth_halves_per_level() {
        let mem = memory(1 << 16, 1024, 4).unwrap();
        // 6 stack levels: 1024 * 100 * (1 + 1/2 + ... + 1/32).
        let v = update_texels_per_second(&mem, 100.0);
        assert!((v - 1024.0 * 100.0 * (2.0 - 1.0 / 32.0)).abs() < 1e-6);
    }

    #[test]
    fn recommendations_round_up_to_powers_of_two() {
        assert_eq!(recommended_clip(1920), (2048, 4096));
        assert_eq!(recommended_clip(1024), (1024, 2048));
    }

    #[test]
    fn virtual_params_keep_sixteen_levels_and_trade_resolution_for_area() {
        let base = VirtualInputs {
            levels: 27,
            clip_size: 2048,
            invalid_border: 16,
            min_lod_tex_pix: 0.0,
            min_lod_loaded: 0.0,
            max_lod_loaded: 27.0,
            bbox_min_dist: 0.0,
            bbox_max_dist: 0.0,
            tradeoff: 1.0,
        };
        let p = virtual_params(&base);
        assert_eq!((p.lod_offset, p.effective_levels), (11, 16));
        let keep_res = virtual_params(&VirtualInputs { tradeoff: 0.0, ..base.clone() });
        assert_eq!((keep_res.lod_offset, keep_res.effective_levels), (0, 16));
        let high = virtual_params(&VirtualInputs { min_lod_tex_pix: 5.3, tradeoff: 0.0, ..base });
        assert_eq!(high.lod_offset, 5);
        assert!(high.max_lod <= 27.0);
    }

    #[test]
    fn footprint_lod_grows_with_height() {
        let low = finest_lod_at_foot(100.0, 60.0, 1024, 1.0);
        let high = finest_lod_at_foot(10_000.0, 60.0, 1024, 1.0);
        assert_eq!(low, 0.0);
        assert!((high - (10_000.0 * 60f64.to_radians() / 1024.0).log2()).abs() < 1e-9);
    }
}
