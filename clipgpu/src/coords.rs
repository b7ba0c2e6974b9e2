//! The ground coordinates the shader works with, emulated on the CPU in the same IEEE
//! operations (docs/GPU.md, "Exact at 2^30 texels a side"): texture coordinates relative to the
//! eye. The CPU splits the eye's level-0 position (f64) into an integer texel (i32 on the GPU)
//! and a fraction in [0, 1) (f32); the shader adds the ray's offset from the eye (f32, small) to
//! the fraction, and splits the sum again into an integer and a fraction rounded down to a
//! multiple of 2^-24 (`split` in ground.wgsl). Every quantity in f32 is then at most the offset's
//! size, never the position's, so the result does not depend on where the eye is: a frame at the
//! far corner of a 2^30 texture is the frame at its origin, translated by whole texels.
//!
//! Plain f32 texture coordinates (the position itself in f32) keep 24 significant bits: at
//! 2^30 texels a side their spacing is 2^(30-23) = 128 texels. `tests` measures both against an
//! f64 / integer oracle; docs/GPU.md has the table.

/// The eye's level-0 position as the CPU hands it to the shader: the integer texel (floor) and
/// the fraction in [0, 1) rounded to f32 (`Renderer::frame_bytes`).
pub fn eye_split(eye: f64) -> (i64, f32) {
    let i = eye.floor();
    (i as i64, (eye - i) as f32)
}

/// The shader's ground coordinate of a point `offset` level-0 texels from the eye (f32, as the
/// ray's intersection gives it): `(i, q)`, the level-0 texel `i` and the fraction `q / 2^24`,
/// computed in the shader's f32 operations (`split(eye_int, eye_frac + offset)`).
pub fn relative(eye: f64, offset: f32) -> (i64, u32) {
    let (ei, frac) = eye_split(eye);
    let rel = frac + offset;
    let fl = rel.floor();
    let q = ((rel - fl) * 16_777_216.0).floor();
    (ei + fl as i64, q as u32)
}

/// The same coordinate with plain f32 texture coordinates: the position itself rounded to f32,
/// plus the offset in f32.
pub fn plain(eye: f64, offset: f32) -> f64 {
    ((eye as f32) + offset) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The largest error, in level-0 texels, of each method over offsets of up to `reach` texels
    /// from eyes near `at`, against an exact oracle: everything is measured from the eye's
    /// integer texel, so the exact position `frac + offset` is a sum of two small numbers, exact
    /// in f64 (an f64 sum of the whole position and an offset would itself round at 2^30).
    fn errors(at: i64, reach: f32) -> (f64, f64) {
        let (mut rel_err, mut plain_err) = (0.0f64, 0.0f64);
        for e in 0..64 {
            let eye = at as f64 + e as f64 * 0.3671875;
            let (ei, _) = eye_split(eye);
            let frac = eye - ei as f64;
            for o in -200..=200 {
                let offset = reach * o as f32 / 200.0 + 0.0009765625 * (o % 7) as f32;
                let exact = frac + offset as f64;
                let (i, q) = relative(eye, offset);
                let got = (i - ei) as f64 + q as f64 / 16_777_216.0;
                rel_err = rel_err.max((got - exact).abs());
                plain_err = plain_err.max(((plain(eye, offset) - ei as f64) - exact).abs());
            }
        }
        (rel_err, plain_err)
    }

    #[test]
    fn eye_relative_coordinates_are_as_exact_at_2_30_as_at_the_origin_and_plain_f32_is_not() {
        for reach in [64.0f32, 4096.0] {
            let (origin, plain_origin) = errors(1000, reach);
            let mut rows = Vec::new();
            for bits in [26u32, 28, 30] {
                let far = (1i64 << bits) - 5000;
                let (rel, plain) = errors(far, reach);
                rows.push((bits, rel, plain));
                // The method's error does not grow with the position: the same as at the origin.
                assert_eq!(rel, origin, "2^{bits}, offsets within {reach} texels");
                // Bounded by the fraction's rounding (2^-24) and the offset's own f32 rounding.
                let ulp = (reach as f64).max(1.0) * f32::EPSILON as f64;
                assert!(rel <= ulp + 2f64.powi(-24), "2^{bits}: {rel}");
                assert!(plain > 1000.0 * rel, "2^{bits}: plain f32 {plain} vs relative {rel}");
            }
            let (_, _, p30) = rows[2];
            assert!(p30 >= 16.0, "plain f32 at 2^30 misses by tens of texels: {p30}");
            // The table of docs/GPU.md ("Exact at 2^30 texels a side").
            eprintln!("offsets within {reach} texels: origin relative {origin:e} plain {plain_origin:e}");
            for (bits, rel, plain) in rows {
                eprintln!("  2^{bits}: relative to the eye {rel:e} texels, plain f32 {plain:e} texels");
            }
        }
    }

    #[test]
    fn a_frame_at_the_far_corner_is_the_frame_at_the_origin_translated_by_whole_texels() {
        // Every eye fraction and offset: the fraction the shader keeps is the same at both ends of
        // a 2^30 texture, and the integer texel differs by exactly the translation.
        let shift = (1i64 << 30) - 4096;
        for e in 0..256 {
            let eye = 100.0 + e as f64 / 256.0 + 1.0 / 4096.0;
            for o in -300..=300 {
                let offset = o as f32 * 3.3203125 + (o % 5) as f32 * 0.0625;
                let (i0, q0) = relative(eye, offset);
                let (i1, q1) = relative(eye + shift as f64, offset);
                assert_eq!((i1 - i0, q1), (shift, q0), "eye {eye}, offset {offset}");
                // Texel indices stay inside the shader's i32 at the far corner.
                assert!(i1 < i32::MAX as i64);
            }
        }
    }
}
