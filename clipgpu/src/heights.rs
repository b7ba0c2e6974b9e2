//! Height textures (docs/GPU.md, "Heights"): what the GPU holds for `l32f`, `l16` and `l16i`
//! heights, the false colour the shader draws them in, and the CPU side of the check — a sampler
//! that returns metres with the shader's level choice and weights, and the comparison of the
//! GPU's heights with it.
//!
//! The sampler here ([`sample_metres`]) is clipgpu's own, a small copy of the rule of
//! `clipmap::sample` (min LOD, the finest level whose whole filter footprint is available, the
//! same bilinear weights rounded to f32 once) returning metres in f64 instead of a colour, with
//! nodata: a filter that touches a texel without data gives no height (the pixel shows nodata);
//! a nodata texel does not make a level unavailable. It is meant to be folded into the core
//! crate's sampler once that returns metres.

use crate::diff::SamplingDiff;
use crate::gpu::{Frame, HeightPixel, LevelShape};
pub use crate::shading::{check_range, HeightShading, CONVERTED_NODATA, L32F_RANGE};
use clipmap::accuracy::render::{Camera, Pixel};
use clipmap::geom::Rect;
use clipmap::height::HeightFormat;
use clipmap::sample::Filter;
use clipmap::shm::{Client, Snapshot};
use clipmap::source::level_size;
use serde::Serialize;

/// f32's unit roundoff, 2^-24.
const U: f64 = 1.0 / (1u64 << 24) as f64;

/// The colour of sky (as the reference renderer's).
const SKY: [u8; 4] = [140, 180, 230, 255];
/// A pixel whose filter touched a nodata texel.
pub const NODATA_COLOUR: [u8; 4] = [255, 0, 255, 255];
/// Ground where no level holds the footprint.
pub const BLACK: [u8; 4] = [0, 0, 0, 255];

/// A height sample from the mapping.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sampled {
    /// The filtered height in metres (f64 arithmetic on f64 metres, the f32 weights), the
    /// largest |metres| of the texels blended, and how many blends deep the filter was (point 0,
    /// bilinear 2, trilinear across two levels 3).
    Metres {
        /// The filtered height in metres.
        metres: f64,
        /// The largest |metres| of the texels blended.
        largest: f64,
        /// How many blends deep the filter was.
        blends: u32,
    },
    /// The filter touched a texel without data.
    Nodata,
    /// No level holds the footprint.
    Nothing,
}

/// One texel: not available, without data, or metres.
#[derive(Clone, Copy)]
enum Tap {
    Missing,
    Nodata,
    Metres(f64),
}

/// A filter's result at one level: `None` when a texel it needs is not available.
type Filtered = Option<Sampled>;

struct Taps<'a> {
    client: &'a Client,
    snap: &'a Snapshot,
    held: Option<&'a dyn Fn(u32, i64, i64) -> bool>,
    format: HeightFormat,
    buf: Vec<u8>,
}

impl Taps<'_> {
    fn tap(&mut self, k: u32, s: i64, t: i64) -> Tap {
        if self.held.is_some_and(|h| !h(k, s, t)) {
            return Tap::Missing;
        }
        if self.client.read_region_in(self.snap, k as usize, Rect::new(s, t, s + 1, t + 1), &mut self.buf).is_err() {
            return Tap::Missing;
        }
        match self.format.decode(self.format.read(&self.buf)) {
            Some(m) => Tap::Metres(m),
            None => Tap::Nodata,
        }
    }

    fn size(&self, k: u32) -> [u64; 2] {
        level_size(self.client.levels[0].size, k)
    }

    /// Column `s` of level `k`: `s mod width` on a texture that wraps in longitude (docs/SHM.md,
    /// "How a region wraps"), as the shader and `clipmap::sample` take it; else clamped to the
    /// level.
    fn column(&self, k: u32, s: i64) -> i64 {
        let width = self.size(k)[0];
        if self.client.wraps() {
            clipmap::geom::wrap(s, width) as i64
        } else {
            s.clamp(0, width as i64 - 1)
        }
    }

    fn point(&mut self, k: u32, u: f64, v: f64) -> Filtered {
        let size = self.size(k);
        let scale = (1u64 << k) as f64;
        let s = self.column(k, (u / scale).floor() as i64);
        let t = ((v / scale).floor() as i64).clamp(0, size[1] as i64 - 1);
        Some(match self.tap(k, s, t) {
            Tap::Missing => return None,
            Tap::Nodata => Sampled::Nodata,
            Tap::Metres(m) => Sampled::Metres { metres: m, largest: m.abs(), blends: 0 },
        })
    }

    fn bilinear(&mut self, k: u32, u: f64, v: f64) -> Filtered {
        let size = self.size(k);
        let scale = (1u64 << k) as f64;
        let (x, y) = (u / scale - 0.5, v / scale - 0.5);
        let (x0, y0) = (x.floor(), y.floor());
        // The weights as the shader has them: exact in f64, rounded to f32 once.
        let (fx, fy) = ((x - x0) as f32 as f64, (y - y0) as f32 as f64);
        let ct = |t: i64| t.clamp(0, size[1] as i64 - 1);
        let (s0, t0) = (x0 as i64, y0 as i64);
        let (sa, sb) = (self.column(k, s0), self.column(k, s0 + 1));
        let taps = [
            self.tap(k, sa, ct(t0)),
            self.tap(k, sb, ct(t0)),
            self.tap(k, sa, ct(t0 + 1)),
            self.tap(k, sb, ct(t0 + 1)),
        ];
        let mut m = [0f64; 4];
        let mut nodata = false;
        for (i, tap) in taps.iter().enumerate() {
            match *tap {
                Tap::Missing => return None,
                Tap::Nodata => nodata = true,
                Tap::Metres(h) => m[i] = h,
            }
        }
        if nodata {
            return Some(Sampled::Nodata);
        }
        let lerp = |a: f64, b: f64, f: f64| a + (b - a) * f;
        let metres = lerp(lerp(m[0], m[1], fx), lerp(m[2], m[3], fx), fy);
        Some(Sampled::Metres { metres, largest: m.iter().fold(0f64, |a, h| a.max(h.abs())), blends: 2 })
    }

    fn filtered(&mut self, filter: Filter, u: f64, v: f64, lod: f64) -> Filtered {
        let last = self.client.levels.len() as u32 - 1;
        let lod = lod.clamp(0.0, last as f64);
        let nearest = ((lod + 0.5).floor() as u32).min(last);
        match filter {
            Filter::Point => self.point(nearest, u, v),
            Filter::Bilinear => self.bilinear(nearest, u, v),
            Filter::Trilinear => {
                let k = lod.floor() as u32;
                let f = (lod - k as f64) as f32 as f64;
                let fine = self.bilinear(k, u, v)?;
                if f == 0.0 || k == last {
                    return Some(fine);
                }
                let coarse = self.bilinear(k + 1, u, v)?;
                Some(match (fine, coarse) {
                    (
                        Sampled::Metres { metres: a, largest: la, .. },
                        Sampled::Metres { metres: b, largest: lb, .. },
                    ) => Sampled::Metres { metres: a + (b - a) * f, largest: la.max(lb), blends: 3 },
                    _ => Sampled::Nodata,
                })
            }
        }
    }
}

/// Samples the heights of the mapping under `snap` at (u, v) (level-0 texels) and `lod`, with
/// min LOD and the finest-available rule of `clipmap::sample` (the texels available: published,
/// and where `held` is given, held by it too).
pub fn sample_metres(
    client: &Client,
    snap: &Snapshot,
    held: Option<&dyn Fn(u32, i64, i64) -> bool>,
    format: HeightFormat,
    filter: Filter,
    uv: [f64; 2],
    lod: f64,
) -> Sampled {
    let mut taps = Taps { client, snap, held, format, buf: vec![0; client.bytes_per_texel] };
    let count = client.levels.len() as u32;
    let lod = lod.max(snap.min_lod).clamp(0.0, count as f64 - 1.0);
    if let Some(s) = taps.filtered(filter, uv[0], uv[1], lod) {
        return s;
    }
    let first = match filter {
        Filter::Trilinear => lod.ceil() as u32,
        _ => (lod + 0.5).floor() as u32 + 1,
    };
    (first..count).find_map(|k| taps.filtered(filter, uv[0], uv[1], k as f64)).unwrap_or(Sampled::Nothing)
}

/// The largest |GPU - reference| a sampled height may be off by (docs/GPU.md, "Heights"): each
/// f32 blend `a + (b - a) w` of values within M of zero rounds three times, at most 5 u M (u =
/// 2^-24), errors of its inputs carried through a convex combination; texels converted to f32 on
/// upload add u M. First order in u, with a margin of 2^-20 of the bound for the rest.
pub fn bound(largest: f64, blends: u32, converted: bool) -> f64 {
    (5.0 * blends as f64 + f64::from(u8::from(converted))) * U * largest * (1.0 + 1.0 / (1u64 << 20) as f64)
}

/// The GPU's heights against [`sample_metres`] at the GPU's own footprints.
#[derive(Clone, Debug, Default, Serialize)]
pub struct HeightDiff {
    /// Pixels with a height from both.
    pub compared: u64,
    /// Pixels both show as nodata.
    pub nodata: u64,
    /// Pixels for which neither has a level.
    pub nothing: u64,
    /// Ground pixels where the two disagree on what the pixel is (a height, nodata, nothing).
    pub mismatch: u64,
    /// Largest |GPU - reference| of a height, metres.
    pub max_error_m: f64,
    /// Largest error over its bound, over the pixels whose bound is above 0.
    pub bound_ratio: f64,
    /// Pixels whose error exceeds its bound (a bound of 0, point filtering of `l32f`, admits none).
    pub outside_bound: u64,
}

/// The colour the shader draws for a sample (heights as f32).
fn colour_of(sh: &HeightShading, s: HeightPixel) -> [u8; 4] {
    match s {
        HeightPixel::Sky => SKY,
        HeightPixel::Metres(h) => sh.colour(h),
        HeightPixel::Nodata => NODATA_COLOUR,
        HeightPixel::Nothing => BLACK,
    }
}

/// Checks a height frame at the GPU's own footprints, against the snapshot with its min LOD as
/// the shader saw it (f32) and only the texels the GPU's tags say it holds: every ground pixel's
/// height against [`sample_metres`] within [`bound`], and its colour against the false colour of
/// the GPU's own height (the ramp, exactly but for a driver's fused multiply-add).
pub fn check(
    client: &Client,
    snap: &Snapshot,
    levels: &[LevelShape],
    held: &[Vec<([i64; 2], bool)>],
    filter: Filter,
    sh: &HeightShading,
    frame: &Frame,
) -> (SamplingDiff, HeightDiff) {
    let mut snap32 = snap.clone();
    snap32.min_lod = snap.min_lod as f32 as f64;
    let holds = |k: u32, s: i64, t: i64| -> bool {
        let l = levels[k as usize];
        let tile = [s.div_euclid(l.tile[0] as i64), t.div_euclid(l.tile[1] as i64)];
        let slot = clipmap::shm::layout::slot_index(l.grid, tile) as usize;
        held[k as usize].get(slot) == Some(&(tile, true))
    };
    let mut c = SamplingDiff::default();
    let mut d = HeightDiff::default();
    for (n, g) in frame.rgba.chunks_exact(4).enumerate() {
        let gpu = frame.height(n).unwrap_or(HeightPixel::Nothing);
        let Some((uv, lod)) = frame.footprint(n) else {
            // Sky for the shader: its height target must say so too.
            d.mismatch += u64::from(gpu != HeightPixel::Sky);
            continue;
        };
        c.compared += 1;
        let want = colour_of(sh, gpu);
        let e = (0..4).map(|k| want[k].abs_diff(g[k]) as u16).max().unwrap_or(0);
        c.differing += u64::from(e > 0);
        c.max_error = c.max_error.max(e);
        let r = sample_metres(client, &snap32, Some(&holds), sh.format, filter, uv, lod);
        match (gpu, r) {
            (HeightPixel::Metres(h), Sampled::Metres { metres, largest, blends }) => {
                d.compared += 1;
                let err = (h as f64 - metres).abs();
                d.max_error_m = d.max_error_m.max(err);
                let b = bound(largest, blends, sh.converted());
                if b > 0.0 {
                    d.bound_ratio = d.bound_ratio.max(err / b);
                }
                d.outside_bound += u64::from(err > b);
            }
            (HeightPixel::Nodata, Sampled::Nodata) => d.nodata += 1,
            (HeightPixel::Nothing, Sampled::Nothing) => d.nothing += 1,
            _ => d.mismatch += 1,
        }
    }
    (c, d)
}

/// The reference frame of a height texture: every pixel at the f64 camera's footprint
/// (`Camera::footprint`), sampled from the mapping as published under `snap` and drawn as the
/// shader draws it, for the comparison with the f64 reference (`flight::compare_frame`).
pub fn render(cam: &Camera, client: &Client, snap: &Snapshot, filter: Filter, sh: &HeightShading) -> Vec<Pixel> {
    let size = client.levels[0].size;
    let last = client.levels.len() as f64 - 1.0;
    let pixel =
        |rgba: [u8; 4], lod: f64, ground: bool| Pixel { rgba, rgba16: rgba.map(|c| c as u16 * 257), lod, ground };
    let mut out = Vec::with_capacity((cam.width * cam.height) as usize);
    for j in 0..cam.height {
        for i in 0..cam.width {
            // A texture that wraps in longitude has no west or east edge: ground all around, as
            // the shader and `clipmap::accuracy::render::render_mapping` draw it.
            let wraps = client.wraps();
            let fp = cam.footprint(i, j).filter(|f| {
                (wraps || (f.uv[0] >= 0.0 && f.uv[0] < size[0] as f64)) && f.uv[1] >= 0.0 && f.uv[1] < size[1] as f64
            });
            let Some(fp) = fp else {
                out.push(pixel(SKY, 0.0, false));
                continue;
            };
            let lod = fp.lod.clamp(0.0, last);
            let h = match sample_metres(client, snap, None, sh.format, filter, fp.uv, lod) {
                Sampled::Metres { metres, .. } => HeightPixel::Metres(metres as f32),
                Sampled::Nodata => HeightPixel::Nodata,
                Sampled::Nothing => HeightPixel::Nothing,
            };
            out.push(pixel(colour_of(sh, h), lod, true));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use clipmap::height::{HeightFormat, HeightStorage};

    #[test]
    fn the_ramp_runs_from_its_first_stop_to_its_last_and_clamps_outside() {
        let sh = HeightShading::new(HeightFormat::VERIFICATION, None);
        assert_eq!(sh.range, L32F_RANGE);
        assert_eq!(sh.colour(-11000.0), [20, 40, 140, 255]);
        assert_eq!(sh.colour(-20000.0), [20, 40, 140, 255]);
        assert_eq!(sh.colour(8900.0), [250, 250, 250, 255]);
        assert_eq!(sh.colour(1e6), [250, 250, 250, 255]);
        // The middle of the range is the middle stop.
        assert_eq!(sh.colour(-1050.0), [60, 160, 80, 255]);
        // Never the colour of nodata or of nothing.
        for k in 0..=1000 {
            let c = sh.colour(-11000.0 + 19.9 * k as f32);
            assert!(c != NODATA_COLOUR && c != BLACK && c != SKY, "{c:?}");
        }
    }

    #[test]
    fn sixteen_bit_heights_convert_to_metres_and_nodata_to_a_value_no_height_takes() {
        let f = HeightFormat::new(HeightStorage::I16, 0.5, 100.0, Some(-32768.0)).unwrap();
        let sh = HeightShading::new(f, None);
        assert_eq!(sh.range, [-16284.0, 16483.5]);
        assert!(sh.converted());
        let mut out = Vec::new();
        let src: Vec<u8> = [-32768i16, -2, 7].iter().flat_map(|v| v.to_le_bytes()).collect();
        sh.to_gpu(&src, &mut out);
        let got: Vec<f32> = out.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        assert_eq!(got, vec![CONVERTED_NODATA, 99.0, 103.5]);
        assert_eq!(sh.uniform()[..2], [CONVERTED_NODATA, 1.0]);
        // l32f goes as it is, nodata included.
        let sh = HeightShading::new(HeightFormat::VERIFICATION, Some([0.0, 100.0]));
        let src: Vec<u8> = [-32768f32, 1.25].iter().flat_map(|v| v.to_le_bytes()).collect();
        sh.to_gpu(&src, &mut out);
        assert_eq!(out, src);
        assert_eq!(sh.uniform(), [-32768.0, 1.0, 0.0, 0.01]);
    }

    #[test]
    fn the_bound_grows_with_the_blends_and_is_zero_for_a_texel_as_published() {
        assert_eq!(bound(8900.0, 0, false), 0.0);
        assert!(bound(8900.0, 0, true) > 8900.0 * U);
        let b2 = bound(8900.0, 2, false);
        assert!(b2 > 10.0 * U * 8900.0 && b2 < 10.0 * U * 8900.0 * 1.001, "{b2}");
        assert!(bound(8900.0, 3, false) > b2);
        assert!(check_range([-1.0, 1.0]).is_ok());
        for bad in [[1.0, 1.0], [2.0, 1.0], [f64::NAN, 1.0], [0.0, 1e9]] {
            let e = check_range(bad).unwrap_err();
            assert!(e.contains("expected MIN,MAX"), "{e}");
        }
    }
}
