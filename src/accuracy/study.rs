//! One flight of the study: move the clipmap's centre along a flight, keep the camera above the
//! centre, render every frame from the full mipmap and from the clipmap, and measure.
//!
//! What limits the service once nothing is copied is tile delivery. The study models storage as a
//! simulated disk that delivers at most `disk_tiles` tiles per frame, each one frame after it was
//! asked for (the read queues' bound on delivered reads, with the study waiting for the reads each
//! frame), so a case means the same on every machine and the study is reproducible. At 60 frames
//! a second a disk of `n` tiles per frame of `b` bytes each reads `60 n b` bytes a second.

use super::cache::CachedSource;
use super::render::{render_clipmap_levels, render_mipmap, Camera, Pixel};
use crate::clip::{Clipmap, Settings};
use crate::roam::{Flight, Procedural};
use crate::sample::Filter;
use crate::source::{TextureDesc, TileSource};
use crate::texel::TexelFormat;
use serde::Serialize;
use std::sync::Arc;

/// What to fly and how to look.
#[derive(Clone, Debug, Serialize)]
pub struct Case {
    /// Texture content.
    pub source: Procedural,
    /// Texture size (texels a side).
    pub size: u64,
    /// Clip size.
    pub clip_size: u64,
    /// Tile size.
    pub tile: u64,
    /// Invalid border.
    pub invalid_border: u64,
    /// Tiles the simulated disk delivers per frame (`None`: every tile asked for, at once).
    pub disk_tiles: Option<u64>,
    /// The flight (speed in level-0 texels per frame).
    pub flight: String,
    /// Frames.
    pub frames: u64,
    /// Image size in pixels.
    pub display: [u32; 2],
    /// Eye height above the ground (level-0 texels).
    pub eye_height: f64,
    /// Pitch below the horizon (degrees).
    pub pitch_deg: f64,
    /// Horizontal field of view (degrees).
    pub fov_deg: f64,
    /// Wait for every tile read before rendering (an ideally fast disk).
    pub wait_for_reads: bool,
    /// A virtual clip texture: the renderer addresses only this many levels at once, from a LOD
    /// offset chosen each frame from the eye height (Performer's rule, keeping resolution).
    pub effective_levels: Option<u32>,
    /// Texel format of the texture (RGBA8 by default). With a 16-bit format the frames are
    /// compared at 16 bits per channel: PSNR against a peak of 65535, errors in 16-bit units.
    #[serde(serialize_with = "format_name")]
    pub format: TexelFormat,
}

fn format_name<S: serde::Serializer>(f: &TexelFormat, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&f.short_name())
}

impl Case {
    /// A small default case: terrain 2^16, clip 512, 256x192 pixels, an ideal disk.
    pub fn small() -> Self {
        Case {
            source: Procedural::Terrain,
            size: 1 << 16,
            clip_size: 512,
            tile: 128,
            invalid_border: 8,
            disk_tiles: None,
            flight: "straight:8:30".into(),
            frames: 6,
            display: [256, 192],
            eye_height: 24.0,
            pitch_deg: 35.0,
            fov_deg: 60.0,
            wait_for_reads: true,
            effective_levels: None,
            format: TexelFormat::RGBA8,
        }
    }
}

/// Metrics of one frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameMetrics {
    /// Frame number.
    pub frame: u64,
    /// PSNR over RGB of ground pixels, dB; `None` when identical to the reference.
    pub psnr: Option<f64>,
    /// Largest absolute channel difference (8-bit units; 16-bit units for a 16-bit format).
    pub max_error: u16,
    /// Share of ground pixels drawn from a coarser level than the reference used.
    pub coarser_pixel_share: f64,
    /// Bytes copied into windows this frame.
    pub bytes_read: u64,
    /// Tiles read this frame.
    pub tiles_read: u64,
    /// The disk delivered as many tiles as it can this frame (more were waiting).
    pub over_budget: bool,
    /// Min LOD after the tick.
    pub min_lod: f64,
}

/// The outcome of a case.
#[derive(Clone, Debug, Serialize)]
pub struct Outcome {
    /// The case.
    pub case: Case,
    /// Per frame.
    pub frames: Vec<FrameMetrics>,
    /// The flight's figures.
    #[serde(flatten)]
    pub summary: Summary,
}

/// A flight's figures, summed or worst over its frames (an [`Outcome`]'s, and a sweep row's).
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Worst PSNR in dB (`None` when every frame is identical to the reference).
    pub psnr_min: Option<f64>,
    /// Worst channel error (8-bit units; 16-bit units for a 16-bit format).
    pub max_error: u16,
    /// Mean share of pixels from a coarser level than ideal.
    pub coarser_pixel_share: f64,
    /// Bytes copied over the flight.
    pub bytes_read: u64,
    /// Tiles read over the flight.
    pub tiles_read: u64,
    /// Frames on which the disk was the limit.
    pub ticks_over_budget: u64,
    /// Engine resident bytes at the end.
    pub resident_bytes: u64,
}

/// Why a case could not run.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// Bad texture description.
    #[error("{0}")]
    Desc(#[from] crate::source::DescError),
    /// The engine refused the settings.
    #[error("{0}")]
    Clip(#[from] crate::clip::ClipError),
    /// Bad flight.
    #[error("{0}")]
    Flight(#[from] crate::roam::FlightError),
    /// An output could not be written.
    #[error("cannot write a picture: {0}")]
    Io(String),
    /// A height texture could not be made.
    #[error("height texture: {0}")]
    Heights(String),
    /// A tile could not be read (the format axis reads its sources directly).
    #[error("{0}")]
    Source(#[from] crate::source::SourceError),
    /// A texel format the format axis cannot measure, or encode into.
    #[error("texel format: {0}")]
    Format(String),
}

/// Compares a frame with its reference at 8 bits per channel: (PSNR, largest channel error,
/// share of ground pixels drawn coarser).
pub fn compare(reference: &[Pixel], test: &[Pixel]) -> (Option<f64>, u16, f64) {
    compare_at(reference, test, 8)
}

/// Compares a frame with its reference at `bits` (8 or 16) per channel: PSNR against the peak
/// of that depth (255 or 65535), the largest channel error in its units.
pub(crate) fn compare_at(reference: &[Pixel], test: &[Pixel], bits: u32) -> (Option<f64>, u16, f64) {
    let deep = bits >= 16;
    let peak = if deep { 65535.0f64 } else { 255.0 };
    let (mut sq, mut n, mut max, mut coarser, mut ground) = (0f64, 0u64, 0u16, 0u64, 0u64);
    for (r, t) in reference.iter().zip(test) {
        if !r.ground {
            continue;
        }
        ground += 1;
        if t.lod > r.lod + 1e-9 {
            coarser += 1;
        }
        for c in 0..3 {
            let d = if deep { r.rgba16[c].abs_diff(t.rgba16[c]) } else { r.rgba[c].abs_diff(t.rgba[c]) as u16 };
            max = max.max(d);
            sq += (d as f64) * (d as f64);
            n += 1;
        }
    }
    let psnr = if sq == 0.0 || n == 0 { None } else { Some(10.0 * (peak * peak / (sq / n as f64)).log10()) };
    (psnr, max, if ground == 0 { 0.0 } else { coarser as f64 / ground as f64 })
}

/// The source of a case (behind a tile cache for the reference renders).
pub fn source(case: &Case) -> Result<Arc<dyn TileSource>, StudyError> {
    let desc = TextureDesc::new([case.size, case.size], case.clip_size, case.format, [case.tile, case.tile])?
        .with_invalid_border(case.invalid_border)?;
    Ok(case.source.source(desc))
}

/// Runs one case; `keep` receives (frame, reference, clipmap render) for pictures.
pub fn run(case: &Case, mut keep: impl FnMut(u64, &Camera, &[Pixel], &[Pixel])) -> Result<Outcome, StudyError> {
    let flight: Flight = case.flight.parse()?;
    let src = source(case)?;
    let reference = CachedSource::new(src.clone(), 512);
    let mut settings = Settings { budget_ns: None, ..Settings::default() };
    if let Some(n) = case.disk_tiles {
        let n = n.max(1) as usize;
        settings.limits.max_in_flight_reads = n;
        settings.limits.max_ready_reads = n;
    }
    let mut map = Clipmap::new(src, settings)?;
    let start = [case.size as f64 / 2.0, case.size as f64 / 2.0];
    let heading = {
        let a = flight.position(start, 0);
        let b = flight.position(start, 1);
        if (b[0] - a[0]).abs() + (b[1] - a[1]).abs() < 1e-9 {
            0.0
        } else {
            (b[1] - a[1]).atan2(b[0] - a[0]).to_degrees()
        }
    };
    // Warm up at the start until nothing more arrives, so frame 0 shows the steady state.
    let first = flight.position(start, 0);
    let first = [first[0].floor() as i64, first[1].floor() as i64];
    for _ in 0..4096 {
        let r = map.tick(first, None);
        map.wait_for_reads();
        if r.min_lod == 0.0 && r.tiles_read == 0 {
            break;
        }
    }
    let mut frames = Vec::new();
    for f in 0..case.frames {
        let foot = flight.position(start, f);
        let centre = [foot[0].floor() as i64, foot[1].floor() as i64];
        let report = map.tick(centre, None);
        let disk_limited = case.disk_tiles.is_some_and(|n| report.tiles_read >= n.max(1));
        if case.wait_for_reads {
            map.wait_for_reads();
        }
        let cam = Camera::following(foot, case.eye_height, heading, case.pitch_deg, case.fov_deg, case.display);
        let want = render_mipmap(&cam, &reference, Filter::Trilinear);
        let window = case.effective_levels.map(|eff| {
            let levels = map.level_count() as u32;
            let lod = crate::sizing::finest_lod_at_foot(case.eye_height, case.fov_deg, case.display[0] as u64, 1.0);
            let v = crate::sizing::virtual_params(&crate::sizing::VirtualInputs {
                levels,
                clip_size: case.clip_size,
                invalid_border: case.invalid_border,
                min_lod_tex_pix: lod,
                min_lod_loaded: map.min_lod(),
                max_lod_loaded: levels as f64,
                bbox_min_dist: 0.0,
                bbox_max_dist: 0.0,
                tradeoff: 0.0,
            });
            (v.lod_offset, eff.min(v.effective_levels))
        });
        let got = render_clipmap_levels(&cam, &map, Filter::Trilinear, window);
        let (psnr, max_error, coarser) = compare_at(&want, &got, case.format.component_bits());
        keep(f, &cam, &want, &got);
        frames.push(FrameMetrics {
            frame: f,
            psnr,
            max_error,
            coarser_pixel_share: coarser,
            bytes_read: report.tiles_read * map.desc().tile_bytes(0) as u64,
            tiles_read: report.tiles_read,
            over_budget: disk_limited,
            min_lod: report.min_lod,
        });
    }
    let psnr_min = frames.iter().filter_map(|f| f.psnr).min_by(|a, b| a.total_cmp(b));
    let summary = Summary {
        psnr_min,
        max_error: frames.iter().map(|f| f.max_error).max().unwrap_or(0),
        coarser_pixel_share: frames.iter().map(|f| f.coarser_pixel_share).sum::<f64>() / frames.len().max(1) as f64,
        bytes_read: frames.iter().map(|f| f.bytes_read).sum(),
        tiles_read: frames.iter().map(|f| f.tiles_read).sum(),
        ticks_over_budget: frames.iter().filter(|f| f.over_budget).count() as u64,
        resident_bytes: map.resident_bytes(),
    };
    Ok(Outcome { summary, frames, case: case.clone() })
}
