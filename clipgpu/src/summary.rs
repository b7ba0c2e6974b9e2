//! The flight in one JSON object (`--json`) or a few lines, and the tolerance frames are held to.

use crate::flight::{FlightReport, FrameRecord};
use crate::upload::Method;
use clipmap::sample::Filter;
use serde_json::{json, Value};

/// How far a GPU frame may be from the reference renderer's frame of the same snapshot
/// (docs/GPU.md, "Tolerance", says how these were chosen from measured differences). Pixels
/// whose footprint lies on a texel edge or a LOD boundary to within f32 rounding are counted
/// apart (`at_edges`): there the shader's f32 and the reference's f64 may pick another texel.
/// Those pixels are not let off: the same frame is also checked at the GPU's own coordinates
/// (every pixel, `sampling_max_error`) and the coordinates against their f32 bound.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Tolerance {
    /// Lowest PSNR of a frame over its ground pixels off the edges, dB (`None`: they must be
    /// identical).
    pub psnr_floor: Option<f64>,
    /// Largest channel difference of a pixel off the edges, 8-bit units.
    pub max_error: u16,
    /// Largest channel difference of any pixel from the CPU sampler run at the GPU's own
    /// coordinates and LOD (0: bit-exact on every pixel); for heights, from the false colour of
    /// the GPU's own height.
    pub sampling_max_error: u16,
    /// Heights: every ground pixel's sampled height within its f32 bound of the CPU's at the
    /// GPU's coordinates, and the two agreeing on which pixels are nodata (docs/GPU.md, "Heights").
    pub heights: bool,
}

/// The largest difference allowed at the GPU's coordinates with the bilinear filters (8-bit
/// units), where the shader's blends may be fused into multiply-adds (docs/GPU.md).
pub const SAMPLING_FILTERED: u16 = 1;

/// What a GPU's decode of a `bc1`, `bc4` or `bc5` texel may differ from the independent CPU
/// decoder's (`bcdec_rs`), 8-bit units: those formats leave the rounding of interpolated palette
/// entries to the implementation (docs/GPU.md, "Block-compressed textures"; lavapipe's BC1
/// differs by up to 2). BC7's decode is specified in integers, and is held to be exact.
pub const BLOCK_DECODE: u16 = 2;

/// The PSNR floor of a frame whose blocks the GPU decoded, dB (measured on lavapipe's BC1 of the
/// hash texture, the worst case: 53 dB).
pub const BLOCK_DECODE_PSNR: f64 = 45.0;

impl Tolerance {
    /// Nearest sampling: identical off the edges. Filtered: the rounding of f32 filter weights.
    pub fn for_filter(filter: Filter) -> Tolerance {
        match filter {
            Filter::Point => Tolerance { psnr_floor: None, max_error: 0, sampling_max_error: 0, heights: false },
            Filter::Bilinear | Filter::Trilinear => Tolerance {
                psnr_floor: Some(70.0),
                max_error: 2,
                sampling_max_error: SAMPLING_FILTERED,
                heights: false,
            },
        }
    }

    /// For a colour texture [`for_filter`](Self::for_filter); for heights, the heights within
    /// their bound and the false colour within one unit (its blend may be fused), against the
    /// f64 reference off the edges as a filtered colour texture (point included: the ramp's
    /// blend).
    pub fn for_texture(filter: Filter, heights: bool) -> Tolerance {
        if !heights {
            return Tolerance::for_filter(filter);
        }
        let max_error = if filter == Filter::Point { 1 } else { 2 };
        Tolerance { psnr_floor: Some(70.0), max_error, sampling_max_error: SAMPLING_FILTERED, heights: true }
    }

    /// [`for_texture`](Self::for_texture), widened by [`BLOCK_DECODE`] where the GPU decoded the
    /// blocks of a `bc1`, `bc4` or `bc5` texture (`gpu_blocks`: the format whose blocks the GPU
    /// decoded); `bc7` and blocks decoded on the CPU are held to the texture's own tolerance.
    pub fn for_report(filter: Filter, heights: bool, gpu_blocks: Option<clipmap::texel::Bc>) -> Tolerance {
        let t = Tolerance::for_texture(filter, heights);
        if matches!(gpu_blocks, None | Some(clipmap::texel::Bc::Bc7)) {
            return t;
        }
        Tolerance {
            psnr_floor: Some(t.psnr_floor.unwrap_or(f64::INFINITY).min(BLOCK_DECODE_PSNR)),
            max_error: t.max_error + BLOCK_DECODE,
            sampling_max_error: t.sampling_max_error + BLOCK_DECODE,
            heights: t.heights,
        }
    }

    /// Whether every frame is within: off the edges against the f64 reference, on every pixel
    /// at the GPU's coordinates, and the coordinates within their f32 bound.
    pub fn holds(&self, frames: &[FrameRecord]) -> bool {
        frames.iter().all(|f| {
            let psnr_ok = match (f.diff.psnr_off_edges, self.psnr_floor) {
                (None, _) => true,
                (Some(_), None) => false,
                (Some(p), Some(floor)) => p >= floor,
            };
            psnr_ok
                && f.diff.max_error_off_edges <= self.max_error
                && f.diff.at_gpu_coords.max_error <= self.sampling_max_error
                && f.diff.geometry.bound_ratio <= 1.0
                && (!self.heights || f.diff.heights.as_ref().is_some_and(|h| h.mismatch == 0 && h.outside_bound == 0))
        })
    }
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0u64);
    for x in v {
        s += x;
        n += 1;
    }
    if n == 0 {
        0.0
    } else {
        s / n as f64
    }
}

/// Filter name as the command line spells it.
pub fn filter_name(f: Filter) -> &'static str {
    match f {
        Filter::Point => "point",
        Filter::Bilinear => "bilinear",
        Filter::Trilinear => "trilinear",
    }
}

/// Everything `--json` prints.
pub struct Context<'a> {
    /// Adapter description.
    pub adapter: &'a str,
    /// Filter.
    pub filter: Filter,
    /// Upload method.
    pub method: Method,
    /// Upload budget.
    pub budget: Option<u64>,
    /// Flight spec.
    pub flight: &'a str,
    /// Image size.
    pub display: [u32; 2],
    /// Compared with the reference.
    pub compared: bool,
    /// The texture is heights.
    pub heights: bool,
}

/// The JSON summary. Per-frame means leave out frame 0, which uploads everything (and on some
/// drivers compiles the pipeline at its first draw).
pub fn json(c: &Context, r: &FlightReport) -> Value {
    let frames = &r.frames;
    let steady: Vec<_> = if frames.len() > 1 { frames[1..].iter().collect() } else { frames.iter().collect() };
    let psnr_min = frames.iter().filter_map(|f| f.diff.psnr).min_by(|a, b| a.total_cmp(b));
    let psnr_off = frames.iter().filter_map(|f| f.diff.psnr_off_edges).min_by(|a, b| a.total_cmp(b));
    let max_error = frames.iter().map(|f| f.diff.max_error).max().unwrap_or(0);
    let tol = Tolerance::for_report(c.filter, c.heights, r.texture.gpu_blocks());
    let hd: Vec<_> = frames.iter().filter_map(|f| f.diff.heights.as_ref()).collect();
    let heights = (c.heights && c.compared).then(|| {
        json!({
            "compared": hd.iter().map(|h| h.compared).sum::<u64>(),
            "nodata": hd.iter().map(|h| h.nodata).sum::<u64>(),
            "nothing": hd.iter().map(|h| h.nothing).sum::<u64>(),
            "mismatch": hd.iter().map(|h| h.mismatch).sum::<u64>(),
            "max_error_m": hd.iter().map(|h| h.max_error_m).fold(0.0, f64::max),
            "bound_ratio": hd.iter().map(|h| h.bound_ratio).fold(0.0, f64::max),
            "outside_bound": hd.iter().map(|h| h.outside_bound).sum::<u64>(),
        })
    });
    let mut j = json!({
        "adapter": c.adapter,
        "frames": frames.len(),
        "psnr_min": psnr_min,
        "max_error": max_error,
        "compared": c.compared,
        "tolerance": tol,
        "within_tolerance": c.compared && tol.holds(frames),
        "psnr_min_off_edges": psnr_off,
        "max_error_off_edges": frames.iter().map(|f| f.diff.max_error_off_edges).max().unwrap_or(0),
        "pixels_differing_max": frames.iter().map(|f| f.diff.differing).max().unwrap_or(0),
        "pixels_at_edges": frames.iter().map(|f| f.diff.at_edges).sum::<u64>(),
        "pixels_compared_at_gpu_coords": frames.iter().map(|f| f.diff.at_gpu_coords.compared).sum::<u64>(),
        "pixels_differing_at_gpu_coords": frames.iter().map(|f| f.diff.at_gpu_coords.differing).sum::<u64>(),
        "max_error_at_gpu_coords": frames.iter().map(|f| f.diff.at_gpu_coords.max_error).max().unwrap_or(0),
        "max_coord_error_texels": frames.iter().map(|f| f.diff.geometry.max_coord_error).fold(0.0, f64::max),
        "max_lod_error": frames.iter().map(|f| f.diff.geometry.max_lod_error).fold(0.0, f64::max),
        "coord_error_bound_ratio": frames.iter().map(|f| f.diff.geometry.bound_ratio).fold(0.0, f64::max),
        "pixels_ground_mismatch": frames.iter().map(|f| f.diff.geometry.ground_mismatch).sum::<u64>(),
        "upload_method": c.method,
        "upload_budget": c.budget,
        "upload_bytes_per_frame": mean(steady.iter().map(|f| f.upload.bytes as f64)),
        "theory_strip_bytes_per_frame": mean(steady.iter().map(|f| f.upload.theory_bytes as f64)),
        "tile_bound_bytes_per_frame": mean(steady.iter().map(|f| f.upload.bound_bytes as f64)),
        "upload_writes_per_frame": mean(steady.iter().map(|f| f.upload.writes as f64)),
        "first_frame_upload_bytes": frames.first().map(|f| f.upload.bytes).unwrap_or(0),
        "frames_over_bound": frames.iter().skip(1).filter(|f| f.upload.bytes > f.upload.bound_bytes).count(),
        "frames_over_budget": frames.iter().filter(|f| c.budget.is_some_and(|b| f.upload.bytes > b && f.upload.writes > 1)).count(),
        "upload_ms": mean(steady.iter().map(|f| f.upload.ms)),
        "frame_ms": mean(steady.iter().map(|f| f.draw_ms)),
        "first_frame_ms": frames.first().map(|f| f.draw_ms),
        "cpu_reference_ms": if c.compared { Some(mean(steady.iter().map(|f| f.reference_ms))) } else { None },
        "check_ms": if c.compared { Some(mean(steady.iter().map(|f| f.check_ms))) } else { None },
        "reattaches": r.reattaches,
        "frames_with_disabled_level": frames.iter().filter(|f| f.levels_disabled > 0).count(),
        "frames_unsettled": frames.iter().filter(|f| !f.settled).count(),
        "filter": filter_name(c.filter),
        "flight": c.flight,
        "display": c.display,
        "texture": r.texture,
        "pictures": r.pictures,
        "per_frame": frames,
    });
    j["heights"] = heights.unwrap_or(Value::Null);
    // What went to the GPU texture (blocks as they are, or widened texels) against RGBA8, frame 0
    // left out as in the means (it also uploads the pyramid's tops, a whole block each).
    let (gpu, rgba8) = steady.iter().fold((0u64, 0u64), |(g, r), f| (g + f.upload.gpu_bytes, r + f.upload.rgba8_bytes));
    j["upload_gpu_bytes_per_frame"] = json!(mean(steady.iter().map(|f| f.upload.gpu_bytes as f64)));
    j["upload_rgba8_bytes_per_frame"] = json!(mean(steady.iter().map(|f| f.upload.rgba8_bytes as f64)));
    j["upload_bytes_vs_rgba8"] = json!((rgba8 > 0).then(|| gpu as f64 / rgba8 as f64));
    j
}
