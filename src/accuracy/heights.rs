//! The height study: the vertical error of the surface a renderer samples from the clipmap
//! against the full-resolution source, in metres.
//!
//! A camera flies over a height texture with the colour study's simulated disk (at most
//! `disk_tiles` tiles a frame, each one frame after it was asked for, [`super::study`]). Every
//! frame, each pixel's ground point is sampled twice, bilinearly and in metres
//! ([`crate::sample`]): from the clipmap as published at the finest level it holds there (LOD 0
//! asked for; min LOD and the finest-available rule applied, as the colour study picks levels),
//! and from level 0 of the source (the full-resolution surface). The difference is the vertical
//! error the renderer draws. Pixels where both are nodata agree; where one is nodata and the other
//! not, the pixel is counted apart (`nodata_mismatch`).
//!
//! Two surfaces, each with its coarser levels made from level 0 by the `mean` and by the `point`
//! rule ([`crate::height::HeightFormat::reduce_level`], [`HeightLevels::by_rule`]): the
//! procedural heights (the height verification texture's level 0, `l32f`, -11000 m to +8900 m,
//! one texel in sixteen nodata: white noise, the worst case) and a DEM-like surface (the terrain
//! source's smooth fractal heights scaled to 0..5000 m, stored as a DEM often is, `l16` in
//! decimetres).

use super::sweep::svg_chart;
use crate::clip::{Clipmap, Settings};
use crate::height::{HeightFormat, HeightStorage, LevelRule};
use crate::roam::Flight;
use crate::sample::{sample_clipmap_height, Filter, MipmapSampler};
use crate::source::procedural::{height_stored, Terrain};
use crate::source::{HeightLevels, TextureDesc, TileSource, TERRAIN_SEED};
use crate::texel::TexelFormat;
use rayon::prelude::*;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;

/// The surface flown over.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Surface {
    /// The height verification texture's level 0 (`l32f`, nodata -32768).
    Procedural,
    /// The terrain source's heights, 0..5000 m, in `l16` decimetres.
    Dem,
}

impl Surface {
    /// Its name in rows and reports.
    pub fn name(self) -> &'static str {
        match self {
            Surface::Procedural => "procedural",
            Surface::Dem => "dem",
        }
    }

    /// The height format its texels are stored in.
    pub fn format(self) -> HeightFormat {
        match self {
            Surface::Procedural => HeightFormat::VERIFICATION,
            Surface::Dem => HeightFormat::new(HeightStorage::U16, 0.1, -100.0, None).expect("a valid l16 format"),
        }
    }

    /// Level 0's stored values for a texture `size` texels a side, row by row.
    pub fn level0(self, size: u64) -> Vec<f64> {
        let format = self.format();
        let log2 = 64 - (size - 1).max(1).leading_zeros();
        let terrain = Terrain::new(log2, TERRAIN_SEED);
        (0..size)
            .into_par_iter()
            .flat_map_iter(|t| {
                (0..size).map(move |s| match self {
                    Surface::Procedural => height_stored(&format, 0, s, t),
                    Surface::Dem => {
                        format.encode(terrain.height(0, s, t) * 5000.0).expect("0..5000 m lies in the DEM's range")
                    }
                })
            })
            .collect()
    }
}

/// One flight of the height study.
#[derive(Clone, Debug, Serialize)]
pub struct HeightCase {
    /// The surface.
    pub surface: Surface,
    /// How its coarser levels are made.
    pub rule: LevelRule,
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
    /// Flight speed, level-0 texels per frame.
    pub speed: f64,
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
}

impl HeightCase {
    /// The flight spec (`straight:SPEED:30`).
    pub fn flight(&self) -> String {
        format!("straight:{}:30", self.speed)
    }

    /// The texture's shape (its texel format is the surface's storage).
    pub fn desc(&self) -> Result<TextureDesc, crate::source::DescError> {
        TextureDesc::new([self.size; 2], self.clip_size, TexelFormat::L32F, [self.tile; 2])?
            .with_invalid_border(self.invalid_border)
    }
}

/// The vertical error of the pixels drawn from one level.
#[derive(Clone, Debug, Serialize)]
pub struct LevelError {
    /// The level the clipmap's samples came from.
    pub level: u32,
    /// Pixels compared.
    pub pixels: u64,
    /// Mean absolute vertical error, metres.
    pub mean_m: f64,
    /// 99th percentile of the absolute vertical error, metres.
    pub p99_m: f64,
    /// Largest absolute vertical error, metres.
    pub max_m: f64,
}

/// One row of the height study (`accuracy/heights.json`, `accuracy/heights.csv`).
#[derive(Clone, Debug, Serialize)]
pub struct HeightRow {
    /// `procedural` or `dem`.
    pub surface: &'static str,
    /// Height storage (`l32f`, `l16`).
    pub format: &'static str,
    /// Level rule (`mean`, `point`).
    pub rule: &'static str,
    /// Clip size.
    pub clip_size: u64,
    /// Bytes of one level-0 tile (the disk's unit).
    pub tile_bytes: u64,
    /// Tiles the simulated disk delivers per frame; `null` for an ideal disk.
    pub disk_tiles: Option<u64>,
    /// Flight speed, level-0 texels per frame.
    pub speed: f64,
    /// Flight spec.
    pub flight: String,
    /// Frames flown.
    pub frames: u64,
    /// Pixels compared (both samples with data), all frames.
    pub pixels: u64,
    /// Mean absolute vertical error, metres.
    pub mean_m: f64,
    /// 99th percentile of the absolute vertical error, metres.
    pub p99_m: f64,
    /// Largest absolute vertical error, metres.
    pub max_m: f64,
    /// Pixels where one sample is nodata and the other is not.
    pub nodata_mismatch: u64,
    /// Share of compared pixels drawn from a level coarser than 0.
    pub coarser_pixel_share: f64,
    /// Mean min LOD after the frames' ticks.
    pub min_lod_mean: f64,
    /// Largest min LOD after the frames' ticks.
    pub min_lod_max: f64,
    /// Tiles read over the flight.
    pub tiles_read: u64,
    /// Frames on which the disk was the limit.
    pub ticks_over_budget: u64,
    /// The error of the pixels drawn from each level used.
    pub by_level: Vec<LevelError>,
}

/// Mean, 99th percentile and maximum of `errors` (sorted here); zeros when empty.
fn stats(errors: &mut [f64]) -> (f64, f64, f64) {
    if errors.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    errors.sort_by(f64::total_cmp);
    let n = errors.len();
    let mean = errors.iter().sum::<f64>() / n as f64;
    let p99 = errors[((n as f64 * 0.99).ceil() as usize).clamp(1, n) - 1];
    (mean, p99, errors[n - 1])
}

/// Flies one case over `source` (a height texture of the case's shape whose coarser levels the
/// case's rule made).
pub fn run(case: &HeightCase, source: Arc<dyn TileSource>) -> Result<HeightRow, super::study::StudyError> {
    let flight: Flight = case.flight().parse()?;
    let format = case.surface.format();
    let mut settings = Settings { budget_ns: None, ..Settings::default() };
    if let Some(n) = case.disk_tiles {
        let n = n.max(1) as usize;
        settings.limits.max_in_flight_reads = n;
        settings.limits.max_ready_reads = n;
    }
    let mut map = Clipmap::new(source.clone(), settings)?;
    let start = [case.size as f64 / 2.0; 2];
    let heading = {
        let (a, b) = (flight.position(start, 0), flight.position(start, 1));
        (b[1] - a[1]).atan2(b[0] - a[0]).to_degrees()
    };
    let first = flight.position(start, 0);
    let first = [first[0].floor() as i64, first[1].floor() as i64];
    for _ in 0..4096 {
        let r = map.tick(first, None);
        map.wait_for_reads();
        if r.min_lod == 0.0 && r.tiles_read == 0 {
            break;
        }
    }
    let size = case.size as f64;
    let mut errors: Vec<Vec<f64>> = vec![Vec::new(); map.level_count()];
    let (mut mismatch, mut tiles_read, mut over, mut min_lods) = (0u64, 0u64, 0u64, Vec::new());
    for f in 0..case.frames {
        let foot = flight.position(start, f);
        let report = map.tick([foot[0].floor() as i64, foot[1].floor() as i64], None);
        tiles_read += report.tiles_read;
        over += u64::from(case.disk_tiles.is_some_and(|n| report.tiles_read >= n.max(1)));
        map.wait_for_reads();
        min_lods.push(report.min_lod);
        let cam = super::render::Camera::following(
            foot,
            case.eye_height,
            heading,
            case.pitch_deg,
            case.fov_deg,
            case.display,
        );
        let points: Vec<[f64; 2]> = (0..cam.height)
            .flat_map(|j| (0..cam.width).map(move |i| (i, j)))
            .filter_map(|(i, j)| cam.footprint(i, j))
            .map(|fp| fp.uv)
            .filter(|uv| uv[0] >= 0.0 && uv[1] >= 0.0 && uv[0] < size && uv[1] < size)
            .collect();
        // The full-resolution surface: level 0 of the source.
        let truth: Vec<Option<f64>> = points
            .par_chunks(1024)
            .flat_map_iter(|chunk| {
                let mut full = MipmapSampler::new(source.as_ref());
                chunk
                    .iter()
                    .map(|uv| full.sample_height(Filter::Bilinear, uv[0], uv[1], 0.0).expect("an in-memory source"))
                    .collect::<Vec<_>>()
            })
            .collect();
        for (uv, want) in points.iter().zip(truth) {
            let got = sample_clipmap_height(&map, Filter::Bilinear, uv[0], uv[1], 0.0)
                .expect("the source is heights")
                .expect("the coarsest level is held after the warm-up");
            match (got.metres, want) {
                (Some(g), Some(w)) => {
                    let level = (got.lod + 0.5).floor() as usize;
                    errors[level].push((g - w).abs());
                }
                (None, None) => {}
                _ => mismatch += 1,
            }
        }
    }
    let mut by_level = Vec::new();
    let mut all = Vec::new();
    for (level, e) in errors.iter_mut().enumerate() {
        if e.is_empty() {
            continue;
        }
        all.extend_from_slice(e);
        let (mean_m, p99_m, max_m) = stats(e);
        by_level.push(LevelError { level: level as u32, pixels: e.len() as u64, mean_m, p99_m, max_m });
    }
    let pixels = all.len() as u64;
    let coarser = pixels - by_level.iter().find(|l| l.level == 0).map_or(0, |l| l.pixels);
    let (mean_m, p99_m, max_m) = stats(&mut all);
    Ok(HeightRow {
        surface: case.surface.name(),
        format: format.storage().short_name(),
        rule: case.rule.name(),
        clip_size: case.clip_size,
        tile_bytes: case.tile * case.tile * format.bytes_per_texel() as u64,
        disk_tiles: case.disk_tiles,
        speed: case.speed,
        flight: case.flight(),
        frames: case.frames,
        pixels,
        mean_m,
        p99_m,
        max_m,
        nodata_mismatch: mismatch,
        coarser_pixel_share: if pixels == 0 { 0.0 } else { coarser as f64 / pixels as f64 },
        min_lod_mean: min_lods.iter().sum::<f64>() / min_lods.len().max(1) as f64,
        min_lod_max: min_lods.iter().copied().fold(0.0, f64::max),
        tiles_read,
        ticks_over_budget: over,
        by_level,
    })
}

/// The cases of the height sweep for one surface and rule: an ideal disk at a slow flight, then
/// each disk budget at each speed.
pub fn cases(quick: bool, surface: Surface, rule: LevelRule) -> Vec<HeightCase> {
    let (size, display, frames) = if quick { (1 << 11, [192u32, 144u32], 8) } else { (1 << 12, [512, 384], 10) };
    let base = HeightCase {
        surface,
        rule,
        size,
        clip_size: 256,
        tile: 64,
        invalid_border: 8,
        disk_tiles: None,
        speed: 8.0,
        frames,
        display,
        eye_height: 24.0,
        pitch_deg: 35.0,
        fov_deg: 60.0,
    };
    let mut out = vec![base.clone()];
    let (speeds, budgets): (&[f64], &[u64]) =
        if quick { (&[16.0, 64.0], &[1, 4, 16]) } else { (&[8.0, 32.0, 128.0], &[1, 2, 4, 8, 32]) };
    for &speed in speeds {
        for &b in budgets {
            out.push(HeightCase { disk_tiles: Some(b), speed, ..base.clone() });
        }
    }
    out
}

/// Runs every case of both surfaces and both rules (each surface's level 0 made once, each rule's
/// pyramid once); `progress` is told each finished row.
pub fn sweep(
    quick: bool,
    mut progress: impl FnMut(usize, usize, &HeightRow),
) -> Result<Vec<HeightRow>, super::study::StudyError> {
    let rules = [LevelRule::Mean, LevelRule::Point];
    let surfaces = [Surface::Procedural, Surface::Dem];
    let total = surfaces.len() * rules.len() * cases(quick, Surface::Dem, LevelRule::Mean).len();
    let mut rows = Vec::new();
    for surface in surfaces {
        let sample = &cases(quick, surface, LevelRule::Mean)[0];
        let level0 = surface.level0(sample.size);
        for rule in rules {
            let all = cases(quick, surface, rule);
            let source: Arc<dyn TileSource> = Arc::new(
                HeightLevels::by_rule(all[0].desc()?, surface.format(), rule, level0.clone())
                    .map_err(super::study::StudyError::Heights)?,
            );
            for case in &all {
                let row = run(case, source.clone())?;
                progress(rows.len() + 1, total, &row);
                rows.push(row);
            }
        }
    }
    Ok(rows)
}

/// Rows as CSV.
pub fn csv(rows: &[HeightRow]) -> String {
    let mut o = String::from("surface,format,rule,clip_size,tile_bytes,disk_tiles,speed,flight,frames,pixels,mean_m,p99_m,max_m,nodata_mismatch,coarser_pixel_share,min_lod_mean,min_lod_max,tiles_read,ticks_over_budget\n");
    for r in rows {
        let _ = writeln!(
            o,
            "{},{},{},{},{},{},{},{},{},{},{:.6},{:.6},{:.6},{},{:.6},{:.4},{:.4},{},{}",
            r.surface,
            r.format,
            r.rule,
            r.clip_size,
            r.tile_bytes,
            r.disk_tiles.map(|b| b.to_string()).unwrap_or_default(),
            r.speed,
            r.flight,
            r.frames,
            r.pixels,
            r.mean_m,
            r.p99_m,
            r.max_m,
            r.nodata_mismatch,
            r.coarser_pixel_share,
            r.min_lod_mean,
            r.min_lod_max,
            r.tiles_read,
            r.ticks_over_budget
        );
    }
    o
}

/// Writes `heights.csv`, `heights.json` and one plot per surface into `dir`.
pub fn write_outputs(rows: &[HeightRow], dir: &Path) -> std::io::Result<()> {
    use super::sweep::write_whole;
    write_whole(&dir.join("heights.csv"), csv(rows))?;
    write_whole(&dir.join("heights.json"), serde_json::to_string_pretty(rows).map_err(std::io::Error::other)?)?;
    for surface in [Surface::Procedural, Surface::Dem] {
        let mut series = Vec::new();
        let mut speeds: Vec<f64> = rows.iter().filter(|r| r.disk_tiles.is_some()).map(|r| r.speed).collect();
        speeds.sort_by(f64::total_cmp);
        speeds.dedup();
        for rule in ["mean", "point"] {
            for &speed in &speeds {
                let pts: Vec<(f64, f64)> = rows
                    .iter()
                    .filter(|r| r.surface == surface.name() && r.rule == rule && r.speed == speed)
                    .filter_map(|r| r.disk_tiles.map(|b| (b as f64, r.mean_m)))
                    .collect();
                if !pts.is_empty() {
                    series.push((format!("{rule}, {speed} texels/frame"), pts));
                }
            }
        }
        write_whole(
            &dir.join(format!("heights_{}.svg", surface.name())),
            svg_chart(
                &format!("Mean vertical error against disk speed ({} heights)", surface.name()),
                "tiles the disk delivers per frame",
                "mean vertical error (m)",
                &series,
                true,
            ),
        )?;
    }
    Ok(())
}

/// The report's heights section (Markdown), `command` the command that made it.
pub fn report(rows: &[HeightRow], quick: bool, command: &str) -> String {
    let mut o = String::new();
    let c = &cases(quick, Surface::Dem, LevelRule::Mean)[0];
    let _ = writeln!(o, "## Heights: vertical error against speed\n");
    let _ = writeln!(
        o,
        "Generated by `{command}`{}, with the colour rows above. Each row flies a height texture of {} texels a side (clip {}, tiles of {} texels, border {}) along `straight:SPEED:30` from its centre, with the same simulated disk as above (each frame's reads waited for), a camera {} texels above the clip centre looking {}° down, {}x{} pixels, {} frames. Every frame, each pixel's ground point is sampled bilinearly in metres (`src/sample.rs`) from the clipmap as published at the finest level it holds there (LOD 0 asked for, min LOD and the finest-available rule applied, as the colour study picks levels) and from level 0 of the source; the rows give the absolute difference, the vertical error a renderer would draw, over every pixel of every frame where both have data (`nodata mismatch`: pixels where one is nodata and the other not). `min LOD` is the mean and largest over the frames. The code is `src/accuracy/heights.rs`; the rows are also in `accuracy/heights.csv` and `accuracy/heights.json`.\n",
        if quick { " (quick mode)" } else { "" },
        c.size,
        c.clip_size,
        c.tile,
        c.invalid_border,
        c.eye_height,
        c.pitch_deg,
        c.display[0],
        c.display[1],
        c.frames,
    );
    let _ = writeln!(o, "- **procedural**: level 0 of the height verification texture (docs/ELEVATION.md), `l32f`, -11000 m to +8900 m in 2^-10 m steps, one texel in sixteen nodata: white noise, so any coarser texel is far from the texels it stands for (the worst case);");
    let _ = writeln!(o, "- **dem**: the terrain source's smooth fractal heights scaled to 0..5000 m, stored `l16` in decimetres (scale 0.1, offset -100), as elevation models often are.\n");
    let _ = writeln!(o, "Each surface's coarser levels are made from its level 0 by the `mean` rule and, separately, by the `point` rule (docs/ELEVATION.md, \"Level rules\"). The sampler places a coarser texel at the centre of its 2x2 block, as it places every texel; a `point` texel holds the block's even-corner texel, so its bilinear surface is shifted by half a coarser texel less half a finer one against the source, and the `point` rows include that shift (a mesh client that places point-registered vertices at the even corners does not see it).\n");
    let _ = writeln!(o, "![procedural heights: mean vertical error against disk speed](accuracy/heights_procedural.svg)\n\n![dem heights: mean vertical error against disk speed](accuracy/heights_dem.svg)\n");
    let _ = writeln!(o, "| surface | rule | disk tiles/frame | disk MB/s | speed | mean m | p99 m | max m | coarser px | min LOD mean / max | nodata mismatch | tiles read | frames disk-bound |");
    let _ = writeln!(o, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let _ = writeln!(
            o,
            "| {} (`{}`) | `{}` | {} | {} | {} | {} | {} | {} | {:.2}% | {:.2} / {:.2} | {} | {} | {} |",
            r.surface,
            r.format,
            r.rule,
            r.disk_tiles.map(|b| b.to_string()).unwrap_or_else(|| "∞".into()),
            r.disk_tiles.map(|b| format!("{:.1}", (b * r.tile_bytes * 60) as f64 / 1e6)).unwrap_or_else(|| "∞".into()),
            r.speed,
            metres(r.mean_m),
            metres(r.p99_m),
            metres(r.max_m),
            r.coarser_pixel_share * 100.0,
            r.min_lod_mean,
            r.min_lod_max,
            r.nodata_mismatch,
            r.tiles_read,
            r.ticks_over_budget
        );
    }
    let _ = writeln!(o, "\nThe error by the level each pixel was drawn from, over every flight of a surface and rule (all budgets and speeds together):\n");
    let _ = writeln!(o, "| surface | rule | level | pixels | mean m | max m |\n|---|---|---:|---:|---:|---:|");
    let mut groups: Vec<(&str, &str)> = rows.iter().map(|r| (r.surface, r.rule)).collect();
    groups.dedup();
    for (surface, rule) in groups {
        for (level, pixels, mean, max) in by_level(rows, surface, rule) {
            let _ = writeln!(o, "| {surface} | `{rule}` | {level} | {pixels} | {} | {} |", metres(mean), metres(max));
        }
    }
    o
}

/// Metres for the tables: millimetres shown below a metre.
fn metres(m: f64) -> String {
    if m == 0.0 {
        "0".into()
    } else if m < 1.0 {
        format!("{m:.4}")
    } else {
        format!("{m:.1}")
    }
}

/// (level, pixels, mean, max) over every row of `surface` and `rule`: the rows' per-level figures
/// combined (means weighted by pixels).
fn by_level(rows: &[HeightRow], surface: &str, rule: &str) -> Vec<(u32, u64, f64, f64)> {
    let mut acc: std::collections::BTreeMap<u32, (u64, f64, f64)> = Default::default();
    for r in rows.iter().filter(|r| r.surface == surface && r.rule == rule) {
        for l in &r.by_level {
            let e = acc.entry(l.level).or_default();
            e.0 += l.pixels;
            e.1 += l.mean_m * l.pixels as f64;
            e.2 = e.2.max(l.max_m);
        }
    }
    acc.into_iter().map(|(k, (n, sum, max))| (k, n, sum / n.max(1) as f64, max)).collect()
}

/// What the height rows say, appended to the heights section.
pub const CONCLUSIONS: &str = "\
### What the height rows say

- Where the finest level is held, the sampled surface is the source's to the bit (error 0 at
  level 0 in the by-level table), whatever the rule: the rules differ only in what the coarser
  levels hold. With an ideal disk almost every pixel is drawn from level 0, so the mean error is
  millimetres on the DEM and the p99 is 0; the maximum comes from the few far pixels outside
  level 0's window.
- The error grows as the disk falls behind a fast flight: fewer tiles a frame leave levels
  incomplete, load control raises min LOD, more pixels are drawn from coarser levels, and a
  coarser level's surface is further from the source (`accuracy::tests::heights`).
- `mean` and `point` differ at every coarser level, and `mean` is the closer surface: on the DEM
  its error at each level is a third to a half of `point`'s. `point` keeps one texel of each block
  as it is (exact at its own position; the sampler reads it at the block's centre, so the rows
  include that half-texel shift); `mean` averages the block. `point` is for meshes that must meet
  without cracks, not for the least error.
- On the white-noise procedural heights any coarser level is kilometres off either way: a
  coarser level of noise cannot stand for it (which is why the verification texture defines each
  level on its own). Bilinear sampling reads nodata only where every weighed texel is nodata,
  so nodata disagrees with level 0 at a few dozen pixels of a flight's millions at most
  (`nodata mismatch`).
";
