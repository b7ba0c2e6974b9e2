//! One preparation run: configuration files, then every level's tiles, generated or filtered
//! in bands of tile rows cascading down the levels, so memory is bounded by a few bands of
//! level-0 width, never by the texture size.

use super::band::BandSource;
use super::border::write_borders;
use super::configfile::{ct_text, ic_text};
use super::error::PrepError;
use super::filter::{Channels, Downsampler, Filter};
use super::heights::{HeightInput, HeightPrep, HeightReducer, VerificationLevel0};
use super::inset::TileRole;
use super::layout::{Layout, Level, LevelKind};
use super::sink::write_tile_part;
use super::sink::LevelWriter;
use super::source::{HashLevel, OpenedImage, TerrainLevel0};
use super::Limits;
use crate::source::procedural::{hash_region, Terrain};
use rayon::prelude::*;
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// Where level texels come from.
pub enum Source {
    /// The verification texture, generated per level (not filtered).
    Hash,
    /// Fractal terrain at level 0; coarser levels filtered.
    Terrain {
        /// Seed of the noise.
        seed: u64,
    },
    /// An input image at level 0 (padded with zeros to the layout size); coarser levels filtered.
    Image(OpenedImage),
    /// Heights (docs/ELEVATION.md): level 0 from `input` in the format of `prep`, coarser
    /// levels made by its level rule (never the colour filter); the `.ct` carries the
    /// `#clipmap height` lines. The layout's texel format is the storage's.
    Heights {
        /// Format, level rule and the handling of non-finite input.
        prep: HeightPrep,
        /// Where level-0 heights come from.
        input: HeightInput,
    },
}

/// Builds level k + 1 from the rows of level k: a colour filter, or a height level rule.
enum Reducer {
    Colour(Downsampler),
    Height(HeightReducer),
}

impl Reducer {
    fn dst_row_bytes(&self) -> usize {
        match self {
            Reducer::Colour(d) => d.dst_row_bytes(),
            Reducer::Height(h) => h.dst_row_bytes(),
        }
    }

    fn push(&mut self, row: &[u8], out: &mut Vec<u8>) -> usize {
        match self {
            Reducer::Colour(d) => d.push(row, out),
            Reducer::Height(h) => h.push(row, out),
        }
    }
}

/// Everything one run needs.
pub struct Job {
    /// The level table and naming.
    pub layout: Layout,
    /// The texel source.
    pub source: Source,
    /// Filter for coarser levels (ignored by the hash source).
    pub filter: Filter,
    /// Average in linear light (sRGB-decoded) rather than on stored values.
    pub linear_light: bool,
    /// File stem of the `.ct` (`NAME.ct`).
    pub name: String,
    /// Lines for the `.ct`'s leading comment.
    pub description: Vec<String>,
    /// Memory bounds.
    pub limits: Limits,
}

/// What a run wrote.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    /// The `.ct`, relative to the output directory.
    pub ct: PathBuf,
    /// Levels written.
    pub levels: usize,
    /// Image-cache levels.
    pub image_cache_levels: usize,
    /// Pyramid levels.
    pub pyramid_levels: usize,
    /// Files written (configuration and tiles).
    pub files: u64,
    /// Bytes written (configuration and tiles).
    pub bytes: u64,
    /// Texels written over all levels.
    pub texels: u64,
    /// Tiles of sparse levels that hold the source's texels (0 without an inset).
    pub inset_tiles: u64,
    /// Border tiles of sparse levels (magnified from the inset level).
    pub border_tiles: u64,
    /// Tiles of sparse levels left absent (the default tile stands in).
    pub absent_tiles: u64,
    /// The most memory the run's buffers took, by `buffer_memory`'s accounting.
    pub buffer_bytes: u64,
}

fn create_dir(path: &Path, total: u64) -> Result<(), PrepError> {
    fs::create_dir_all(path).map_err(|e| PrepError::write(path, e, total))
}

fn write_file(path: &Path, text: &str, total: u64) -> Result<(), PrepError> {
    fs::write(path, text).map_err(|e| PrepError::write(path, e, total))
}

/// Memory one band of level-0 rows takes in the cascade (source band, level-0 writer band, and
/// the halving bands below), checked against the limit before anything is written.
pub(crate) fn band_memory(layout: &Layout) -> u64 {
    let l0 = &layout.levels[0];
    3 * l0.tile_h * l0.width * layout.bpt()
}

/// Bytes of a pyramid level's band (what its [`LevelWriter`] buffers).
fn pyramid_band(layout: &Layout, level: &Level, limits: &Limits) -> u64 {
    let row = level.width * layout.bpt();
    (limits.pyramid_band_bytes / row).clamp(1, level.height) * row
}

/// The most memory a run's buffers take, by the library's own accounting, checked against
/// [`Limits::max_memory_bytes`] before anything is written and reported in the [`Summary`].
///
/// The hash source writes image-cache levels tile by tile (a tile per worker thread) and pyramid
/// levels in bands, so its memory does not grow with the texture's width. Filtered sources run
/// the band cascade: [`band_memory`], which grows with the level-0 width.
pub(crate) fn buffer_memory(layout: &Layout, source: &Source, limits: &Limits) -> u64 {
    let pyramid: u64 = layout.pyramid_levels().map(|l| pyramid_band(layout, l, limits)).sum();
    match source {
        Source::Hash => {
            let tile = layout.image_cache_levels().map(|l| l.tile_w * l.tile_h * layout.bpt()).max().unwrap_or(0);
            tile * rayon::current_num_threads() as u64 + pyramid
        }
        _ => band_memory(layout) + pyramid,
    }
}

/// Writes every tile of an image-cache level of the hash source, one row of tiles at a time,
/// the tiles of a row generated and written in parallel (one tile buffer per worker).
fn write_hash_tiles(
    root: &Path,
    layout: &Layout,
    level: &Level,
    cancel: &AtomicBool,
    interrupted: &(dyn Fn() -> PrepError + Sync),
    total: u64,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(), PrepError> {
    let (tw, th) = (level.tile_w as usize, level.tile_h as usize);
    let bpt = layout.bpt() as usize;
    for t in 0..level.tiles_t() {
        if cancel.load(Ordering::Relaxed) {
            return Err(interrupted());
        }
        (0..level.tiles_s())
            .into_par_iter()
            .filter(|&s| layout.tile_role(level, s, t) == TileRole::Source)
            .try_for_each_init(
                || vec![0u8; tw * th * bpt],
                |tile, s| {
                    hash_region(level.index, s * tw as u64, t * th as u64, tw, th, bpt, tile);
                    write_tile_part(root, layout, level, s, t, 0, tile, total)
                },
            )?;
        progress(level.width * th as u64);
    }
    Ok(())
}

/// Writes the whole prepared texture under `root` (an empty directory). `progress` receives the
/// number of texels written since its last call; `cancel` is polled between bands.
pub fn run(
    job: Job,
    root: &Path,
    cancel: &AtomicBool,
    interrupted_dir: &Path,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Summary, PrepError> {
    let layout = &job.layout;
    let total = layout.total_texels() * layout.bpt();
    let need = buffer_memory(layout, &job.source, &job.limits);
    if need > job.limits.max_memory_bytes {
        if matches!(job.source, Source::Hash) {
            return Err(PrepError::Geometry(format!(
                "the tile buffers ({} MiB) are over the memory limit of {} MiB; pass a smaller --tile or raise --max-memory",
                need >> 20,
                job.limits.max_memory_bytes >> 20
            )));
        }
        return Err(PrepError::Geometry(format!(
            "one row of level-0 tiles ({} rows of {} texels) needs about {} MiB in the filter cascade, over the memory limit of {} MiB; pass a smaller --tile or raise --max-memory",
            layout.levels[0].tile_h,
            layout.levels[0].width,
            need >> 20,
            job.limits.max_memory_bytes >> 20
        )));
    }
    for d in layout.directories() {
        create_dir(&root.join(d), total)?;
    }
    let ct_name = format!("{}.ct", job.name);
    for level in layout.image_cache_levels() {
        if layout.sparse(level).is_some() {
            let zeros = vec![0u8; (level.tile_w * level.tile_h * layout.bpt()) as usize];
            let path = root.join(Layout::default_tile_file(level.index));
            fs::write(&path, super::sink::on_disk(layout, level, &zeros))
                .map_err(|e| PrepError::write(&path, e, total))?;
        }
    }
    let interrupted = || PrepError::Interrupted { dir: interrupted_dir.to_path_buf() };
    let mut writers: Vec<LevelWriter> =
        layout.levels.iter().map(|l| LevelWriter::new(root, layout, l, job.limits.pyramid_band_bytes)).collect();
    let bpt = layout.bpt() as usize;
    let height_plan = match &job.source {
        Source::Heights { prep, .. } => Some(prep.plan()),
        _ => None,
    };
    // Where the texture is on the Earth: an input image's georeferencing, shifted for the
    // padding (docs/GEOREF.md, "Prepared pyramids"); none for the other sources.
    let georef_lines = match &job.source {
        Source::Image(image) => image
            .texture_georef([layout.spec.width, layout.spec.height])
            .map(|g| crate::plan::georef::lines(&g))
            .unwrap_or_default(),
        _ => String::new(),
    };
    match job.source {
        Source::Hash => {
            for (w, level) in writers.iter_mut().zip(&layout.levels) {
                if level.kind == LevelKind::ImageCache {
                    write_hash_tiles(root, layout, level, cancel, &interrupted, total, progress)?;
                    continue;
                }
                let mut src = HashLevel { level: level.index, width: level.width, bpt };
                let mut band = Vec::new();
                let mut t = 0;
                while t < level.height {
                    if cancel.load(Ordering::Relaxed) {
                        return Err(interrupted());
                    }
                    let rows = (w.band_rows() as u64).min(level.height - t) as usize;
                    band.resize(rows * w.row_bytes(), 0);
                    src.fill(t, rows, &mut band)?;
                    progress(w.push(&band)?);
                    t += rows as u64;
                }
                progress(w.finish()?);
            }
        }
        Source::Terrain { .. } | Source::Image(_) | Source::Heights { .. } => {
            let heights = match &job.source {
                Source::Heights { prep, .. } => Some(*prep),
                _ => None,
            };
            let mut src: Box<dyn BandSource> = match job.source {
                Source::Terrain { seed } => {
                    let log2 = layout.spec.width.max(layout.spec.height).trailing_zeros();
                    Box::new(TerrainLevel0 {
                        terrain: Terrain::new(log2, seed),
                        width: layout.spec.width,
                        format: layout.spec.format,
                    })
                }
                Source::Image(img) => img.into_source(layout.spec.format, layout.spec.width)?,
                Source::Heights { prep, input: HeightInput::Verification } => {
                    Box::new(VerificationLevel0 { format: prep.format, width: layout.spec.width })
                }
                Source::Heights { prep, input: HeightInput::Tiff(tiff) } => {
                    Box::new(tiff.into_source(prep.format, prep.non_finite, layout.spec.width))
                }
                Source::Hash => unreachable!("handled above"),
            };
            let finer = &layout.levels[..layout.levels.len() - 1];
            let mut downs: Vec<Reducer> = match heights {
                Some(h) => {
                    let texel = crate::plan::height_texel(h.format.storage());
                    if texel != layout.spec.format {
                        return Err(PrepError::Geometry(format!(
                            "heights stored as {} are {texel} texels, but the layout is of {} texels",
                            h.format.storage(),
                            layout.spec.format
                        )));
                    }
                    finer.iter().map(|l| Reducer::Height(HeightReducer::new(h.format, h.rule, l.width))).collect()
                }
                None => {
                    let ch = Channels::of(layout.spec.format).ok_or_else(|| {
                        PrepError::Geometry(format!("texel format {} cannot be filtered", layout.spec.format))
                    })?;
                    finer
                        .iter()
                        .map(|l| Reducer::Colour(Downsampler::new(ch, job.filter, job.linear_light, l.width, l.height)))
                        .collect()
                }
            };
            let l0 = &layout.levels[0];
            let band_rows = writers[0].band_rows();
            let row_bytes = writers[0].row_bytes();
            let mut band = Vec::new();
            let mut t = 0;
            while t < l0.height {
                if cancel.load(Ordering::Relaxed) {
                    return Err(interrupted());
                }
                let rows = (band_rows as u64).min(l0.height - t) as usize;
                band.resize(rows * row_bytes, 0);
                src.fill(t, rows, &mut band)?;
                for row in band.chunks_exact(row_bytes) {
                    feed(0, row, &mut writers, &mut downs, progress)?;
                }
                t += rows as u64;
            }
            for w in &mut writers {
                progress(w.finish()?);
            }
        }
    }
    drop(writers);
    let border_tiles = write_borders(root, layout, total)?;
    // The configuration files last, once every tile is written: a run stopped before this point
    // leaves no `.ct` or `.ic` that would validate over missing tiles.
    for level in layout.image_cache_levels() {
        write_file(&root.join(Layout::ic_file(level.index)), &ic_text(layout, level, &ct_name), total)?;
    }
    let ct = ct_text(layout, &job.description, height_plan.as_ref()) + &georef_lines;
    write_file(&root.join(&ct_name), &ct, total)?;
    let (mut inset_tiles, mut absent_tiles) = (0, 0);
    for level in &layout.levels {
        if let Some(sp) = layout.sparse(level) {
            inset_tiles += sp.inset.count();
            absent_tiles += level.tiles_s() * level.tiles_t() - sp.written.count();
        }
    }
    let (files, bytes) = tally(root).map_err(|e| PrepError::write(root, e, total))?;
    Ok(Summary {
        ct: PathBuf::from(ct_name),
        levels: layout.levels.len(),
        image_cache_levels: layout.image_cache_levels().count(),
        pyramid_levels: layout.pyramid_levels().count(),
        files,
        bytes,
        texels: layout.written_texels(),
        inset_tiles,
        border_tiles,
        absent_tiles,
        buffer_bytes: need,
    })
}

/// Hands one row of level `k` to its writer and to the reducer that builds level k + 1.
fn feed(
    k: usize,
    row: &[u8],
    writers: &mut [LevelWriter],
    downs: &mut [Reducer],
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(), PrepError> {
    progress(writers[k].push(row)?);
    if k < downs.len() {
        let row_bytes = downs[k].dst_row_bytes();
        let mut out = Vec::with_capacity(row_bytes);
        downs[k].push(row, &mut out);
        for r in out.chunks_exact(row_bytes) {
            feed(k + 1, r, writers, downs, progress)?;
        }
    }
    Ok(())
}

/// Counts the files and bytes under `dir`.
fn tally(dir: &Path) -> std::io::Result<(u64, u64)> {
    let (mut files, mut bytes) = (0, 0);
    for e in fs::read_dir(dir)? {
        let e = e?;
        let meta = e.metadata()?;
        if meta.is_dir() {
            let (f, b) = tally(&e.path())?;
            files += f;
            bytes += b;
        } else {
            files += 1;
            bytes += meta.len();
        }
    }
    Ok((files, bytes))
}
