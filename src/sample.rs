//! Reference sampler: point, bilinear and trilinear sampling of the full mipmap (read straight
//! from a [`TileSource`]) and of a [`Clipmap`] as published.
//!
//! Owns the filtering arithmetic and the finest-available rule of docs/ARCHITECTURE.md §3: the clipmap is
//! sampled at `max(lod, min LOD)` if every texel the filter touches lies in a published valid
//! region, else at the finest whole level `k` above that whose footprint does. Both paths run the
//! same code on the same texel bytes, so where the clipmap holds the texels the two results are
//! bit-identical. Rendering whole frames (perspective, derivatives, error metrics) is left to the
//! accuracy tools.
//!
//! Coordinates are level-0 texel units in f64: (u, v) = (s + 0.5, t + 0.5) is the centre of
//! level-0 texel (s, t). Addressing clamps to the level's edges (along s, a texture read from a
//! mapping that wraps in longitude takes s modulo the level's width instead).
//!
//! Heights (docs/ELEVATION.md) are sampled in metres with 64-bit arithmetic from the stored
//! values ([`crate::height::HeightFormat::decode`]), never through the normalised colour path:
//! the same texels, levels and finest-available rule, the same weights in f64, and nodata left
//! out: a bilinear or trilinear sample renormalises its weights over the texels with data and is
//! nodata only when every texel with a weight above zero is nodata.

use crate::clip::Clipmap;
use crate::height::HeightFormat;
use crate::shm::Client;
use crate::source::{level_size, SourceError, TileId, TileSource};
use crate::texel::TexelFormat;
use std::collections::HashMap;

/// Texture filter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    /// Nearest texel of the nearest level.
    Point,
    /// Bilinear within the nearest level.
    Bilinear,
    /// Bilinear within the two levels around the LOD, blended.
    Trilinear,
}

/// A sample and the LOD it was taken at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Filtered colour, components in 0..=1.
    pub rgba: [f32; 4],
    /// The LOD used (at least the one asked for).
    pub lod: f64,
}

/// A height sample in metres and the LOD it was taken at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeightSample {
    /// Metres; `None` where the texels the filter weighs are all nodata.
    pub metres: Option<f64>,
    /// The LOD used (at least the one asked for).
    pub lod: f64,
}

/// Heights asked of a texture that cannot give them.
#[derive(Debug, thiserror::Error)]
pub enum HeightSampleError {
    /// The texture states no height format.
    #[error("{what} is not a height texture: its texels are {texel} and it states no height format (heights are l32f, l16 or l16i texels with `#clipmap height` lines, docs/CONFIG.md §17, or `clipmapd --source heights`); sample its colours instead")]
    NotHeights {
        /// What was sampled (`the tile source`, `the clipmap`, `the mapping`).
        what: &'static str,
        /// Its texel format's short name.
        texel: String,
    },
    /// The height format's texel size is not the texture's.
    #[error("{what}'s height format stores {storage} ({height_bytes} bytes a texel) but its texels are {texel_bytes} bytes; the heights and the texel format must be declared together (docs/CONFIG.md §17)")]
    Mismatch {
        /// What was sampled.
        what: &'static str,
        /// The height storage.
        storage: crate::height::HeightStorage,
        /// Its bytes a texel.
        height_bytes: usize,
        /// The texture's bytes a texel.
        texel_bytes: usize,
    },
    /// A tile could not be read.
    #[error(transparent)]
    Source(#[from] SourceError),
}

/// The height format of a texture of `texel` format stating `heights`, checked against it.
fn height_format(
    what: &'static str,
    heights: Option<HeightFormat>,
    texel: TexelFormat,
) -> Result<HeightFormat, HeightSampleError> {
    let Some(format) = heights else {
        return Err(HeightSampleError::NotHeights { what, texel: texel.short_name() });
    };
    if format.bytes_per_texel() != texel.bytes_per_texel() as usize {
        return Err(HeightSampleError::Mismatch {
            what,
            storage: format.storage(),
            height_bytes: format.bytes_per_texel(),
            texel_bytes: texel.bytes_per_texel() as usize,
        });
    }
    Ok(format)
}

/// Where texels come from: `false` / `None` when a texel is not available.
trait Fetch {
    /// Level 0's size in texels.
    fn size(&self) -> [u64; 2];
    /// Number of levels.
    fn level_count(&self) -> usize;
    /// The texel format.
    fn format(&self) -> TexelFormat;
    /// Copies texel (level, s, t)'s bytes into `out` (one texel long); `false` when it is not
    /// available.
    fn raw(&mut self, level: u32, s: i64, t: i64, out: &mut [u8]) -> bool;

    /// Whether s wraps modulo each level's width (a texture that spans 360 degrees of longitude,
    /// read from a mapping whose georef block says so: docs/SHM.md, "How a region wraps"):
    /// addressing then takes s modulo the width instead of clamping it to the edges.
    fn wraps(&self) -> bool {
        false
    }

    /// The texel's colour, components normalised.
    fn texel(&mut self, level: u32, s: i64, t: i64) -> Option<[f32; 4]> {
        let format = self.format();
        let mut bytes = [0u8; 16];
        let b = &mut bytes[..format.bytes_per_texel() as usize];
        self.raw(level, s, t, b).then(|| format.decode(b))
    }

    /// The texel's height in metres (`Some(None)`: nodata).
    fn height(&mut self, format: &HeightFormat, level: u32, s: i64, t: i64) -> Option<Option<f64>> {
        let mut bytes = [0u8; 16];
        let b = &mut bytes[..format.bytes_per_texel()];
        self.raw(level, s, t, b).then(|| format.decode(format.read(b)))
    }
}

/// Column `s` of a level `width` texels wide: `s mod width` where the texture wraps, else
/// clamped to the edges.
fn column(wraps: bool, s: i64, width: u64) -> i64 {
    if wraps {
        crate::geom::wrap(s, width) as i64
    } else {
        s.clamp(0, width as i64 - 1)
    }
}

fn lerp(a: [f32; 4], b: [f32; 4], f: f32) -> [f32; 4] {
    [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f, a[3] + (b[3] - a[3]) * f]
}

fn point(src: &mut dyn Fetch, k: u32, u: f64, v: f64) -> Option<[f32; 4]> {
    let size = level_size(src.size(), k);
    let scale = (1u64 << k) as f64;
    let s = column(src.wraps(), (u / scale).floor() as i64, size[0]);
    let t = ((v / scale).floor() as i64).clamp(0, size[1] as i64 - 1);
    src.texel(k, s, t)
}

fn bilinear(src: &mut dyn Fetch, k: u32, u: f64, v: f64) -> Option<[f32; 4]> {
    let size = level_size(src.size(), k);
    let scale = (1u64 << k) as f64;
    let (x, y) = (u / scale - 0.5, v / scale - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let wraps = src.wraps();
    let cs = |s: i64| column(wraps, s, size[0]);
    let ct = |t: i64| t.clamp(0, size[1] as i64 - 1);
    let (s0, t0) = (x0 as i64, y0 as i64);
    let a = src.texel(k, cs(s0), ct(t0))?;
    let b = src.texel(k, cs(s0 + 1), ct(t0))?;
    let c = src.texel(k, cs(s0), ct(t0 + 1))?;
    let d = src.texel(k, cs(s0 + 1), ct(t0 + 1))?;
    Some(lerp(lerp(a, b, fx), lerp(c, d, fx), fy))
}

fn filtered(src: &mut dyn Fetch, filter: Filter, u: f64, v: f64, lod: f64) -> Option<[f32; 4]> {
    let last = src.level_count() as u32 - 1;
    let lod = lod.clamp(0.0, last as f64);
    let nearest = (lod + 0.5).floor() as u32;
    match filter {
        Filter::Point => point(src, nearest.min(last), u, v),
        Filter::Bilinear => bilinear(src, nearest.min(last), u, v),
        Filter::Trilinear => {
            let k = lod.floor() as u32;
            let f = (lod - k as f64) as f32;
            let fine = bilinear(src, k, u, v)?;
            if f == 0.0 || k == last {
                return Some(fine);
            }
            Some(lerp(fine, bilinear(src, k + 1, u, v)?, f))
        }
    }
}

fn point_height(src: &mut dyn Fetch, hf: &HeightFormat, k: u32, u: f64, v: f64) -> Option<Option<f64>> {
    let size = level_size(src.size(), k);
    let scale = (1u64 << k) as f64;
    let s = column(src.wraps(), (u / scale).floor() as i64, size[0]);
    let t = ((v / scale).floor() as i64).clamp(0, size[1] as i64 - 1);
    src.height(hf, k, s, t)
}

/// Adds level `k`'s bilinear footprint at (u, v) to `acc` (the sum of weight x metres and the sum
/// of weights, over the texels with data and a weight above zero), each weight times `share`;
/// `None` when a texel of the footprint is not available (all four must be, as for colours).
fn bilinear_height(
    src: &mut dyn Fetch,
    hf: &HeightFormat,
    k: u32,
    u: f64,
    v: f64,
    share: f64,
    acc: &mut [f64; 2],
) -> Option<()> {
    let size = level_size(src.size(), k);
    let scale = (1u64 << k) as f64;
    let (x, y) = (u / scale - 0.5, v / scale - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let wraps = src.wraps();
    let cs = |s: i64| column(wraps, s, size[0]);
    let ct = |t: i64| t.clamp(0, size[1] as i64 - 1);
    let (s0, t0) = (x0 as i64, y0 as i64);
    let corners = [(0, 0, (1.0 - fx) * (1.0 - fy)), (1, 0, fx * (1.0 - fy)), (0, 1, (1.0 - fx) * fy), (1, 1, fx * fy)];
    let mut found = [None; 4];
    for (slot, &(ds, dt, _)) in found.iter_mut().zip(&corners) {
        *slot = src.height(hf, k, cs(s0 + ds), ct(t0 + dt))?;
    }
    for (h, &(_, _, w)) in found.iter().zip(&corners) {
        if let Some(m) = *h {
            let w = w * share;
            if w > 0.0 {
                acc[0] += w * m;
                acc[1] += w;
            }
        }
    }
    Some(())
}

/// The metres a weighted sum stands for: nodata when no texel with data weighs anything.
fn weighted(acc: [f64; 2]) -> Option<f64> {
    // Weights summing to exactly 1 (every texel with data, dyadic fractions) leave the weighted
    // sum as it is: dividing by 1 is exact.
    (acc[1] > 0.0).then(|| acc[0] / acc[1])
}

fn filtered_height(
    src: &mut dyn Fetch,
    hf: &HeightFormat,
    filter: Filter,
    u: f64,
    v: f64,
    lod: f64,
) -> Option<Option<f64>> {
    let last = src.level_count() as u32 - 1;
    let lod = lod.clamp(0.0, last as f64);
    let nearest = ((lod + 0.5).floor() as u32).min(last);
    let mut acc = [0.0; 2];
    match filter {
        Filter::Point => return point_height(src, hf, nearest, u, v),
        Filter::Bilinear => bilinear_height(src, hf, nearest, u, v, 1.0, &mut acc)?,
        Filter::Trilinear => {
            let k = lod.floor() as u32;
            let f = lod - k as f64;
            if f == 0.0 || k == last {
                bilinear_height(src, hf, k, u, v, 1.0, &mut acc)?;
            } else {
                bilinear_height(src, hf, k, u, v, 1.0 - f, &mut acc)?;
                bilinear_height(src, hf, k + 1, u, v, f, &mut acc)?;
            }
        }
    }
    Some(weighted(acc))
}

/// The full mipmap, read tile by tile from a source (tiles are kept once read).
pub struct MipmapSampler<'a> {
    source: &'a dyn TileSource,
    format: TexelFormat,
    heights: Option<HeightFormat>,
    tiles: HashMap<TileId, Vec<u8>>,
    error: Option<SourceError>,
}

impl<'a> MipmapSampler<'a> {
    /// A sampler over every level of `source`.
    pub fn new(source: &'a dyn TileSource) -> Self {
        MipmapSampler {
            format: source.desc().format(),
            heights: source.heights().map(|h| h.format),
            source,
            tiles: HashMap::new(),
            error: None,
        }
    }

    /// Samples the heights at (u, v) (level-0 texel units) and `lod`, in metres (`None`: nodata);
    /// fails if the source is not a height texture or a tile cannot be read.
    pub fn sample_height(
        &mut self,
        filter: Filter,
        u: f64,
        v: f64,
        lod: f64,
    ) -> Result<Option<f64>, HeightSampleError> {
        let hf = height_format("the tile source", self.heights, self.format)?;
        let got = filtered_height(self, &hf, filter, u, v, lod);
        match (got, self.error.take()) {
            (_, Some(e)) => Err(e.into()),
            (Some(metres), None) => Ok(metres),
            (None, None) => unreachable!("the full mipmap has every texel"),
        }
    }

    /// Samples at (u, v) (level-0 texel units) and `lod`; fails if a tile cannot be read.
    pub fn sample(&mut self, filter: Filter, u: f64, v: f64, lod: f64) -> Result<[f32; 4], SourceError> {
        let got = filtered(self, filter, u, v, lod);
        match (got, self.error.take()) {
            (_, Some(e)) => Err(e),
            (Some(rgba), None) => Ok(rgba),
            (None, None) => unreachable!("the full mipmap has every texel"),
        }
    }
}

impl Fetch for MipmapSampler<'_> {
    fn size(&self) -> [u64; 2] {
        self.source.desc().size()
    }

    fn level_count(&self) -> usize {
        self.source.desc().level_count()
    }

    fn format(&self) -> TexelFormat {
        self.format
    }

    fn raw(&mut self, level: u32, s: i64, t: i64, out: &mut [u8]) -> bool {
        let desc = self.source.desc();
        let tile = desc.level(level).tile;
        let id = TileId::new(level, s as u64 / tile[0], t as u64 / tile[1]);
        if !self.tiles.contains_key(&id) {
            let mut buf = vec![0u8; desc.tile_bytes(level)];
            if let Err(e) = self.source.read_tile(id, &mut buf) {
                self.error = Some(e);
                return false;
            }
            self.tiles.insert(id, buf);
        }
        let bpt = desc.bytes_per_texel();
        let i = ((t as u64 % tile[1]) * tile[0] + s as u64 % tile[0]) as usize * bpt;
        out.copy_from_slice(&self.tiles[&id][i..i + bpt]);
        true
    }
}

struct ClipFetch<'a>(&'a Clipmap);

impl Fetch for ClipFetch<'_> {
    fn size(&self) -> [u64; 2] {
        self.0.desc().size()
    }

    fn level_count(&self) -> usize {
        self.0.level_count()
    }

    fn format(&self) -> TexelFormat {
        self.0.desc().format()
    }

    /// A texture that wraps in longitude (`Settings::wrap_longitude`): level 0, the widest,
    /// wraps whenever any level does.
    fn wraps(&self) -> bool {
        self.0.level(0).wrap
    }

    fn raw(&mut self, level: u32, s: i64, t: i64, out: &mut [u8]) -> bool {
        match self.0.level(level).texel(s, t) {
            Some(bytes) => {
                out.copy_from_slice(&bytes);
                true
            }
            None => false,
        }
    }
}

/// Samples the clipmap as published at (u, v) and `lod`, applying min LOD and the
/// finest-available rule; `None` when no level holds the footprint (nothing published yet).
pub fn sample_clipmap(map: &Clipmap, filter: Filter, u: f64, v: f64, lod: f64) -> Option<Sample> {
    sample_published(&mut ClipFetch(map), map.min_lod(), filter, u, v, lod)
}

/// Samples the clipmap's heights as published, in metres, exactly as [`sample_clipmap`] samples
/// colours (the same levels and footprints); `Ok(None)` when no level holds the footprint. Fails
/// when the clipmap's source is not a height texture.
pub fn sample_clipmap_height(
    map: &Clipmap,
    filter: Filter,
    u: f64,
    v: f64,
    lod: f64,
) -> Result<Option<HeightSample>, HeightSampleError> {
    let hf = height_format("the clipmap", map.heights().map(|h| h.format), map.desc().format())?;
    Ok(published_height(&mut ClipFetch(map), &hf, map.min_lod(), filter, u, v, lod))
}

/// A mapping as a reader sees it ([`Client`]): one snapshot for the whole sample, each texel read
/// under its slot's tag, and only from the published valid region (a missing tile's texels come
/// from a coarser level).
struct MappedFetch<'a> {
    client: &'a Client,
    snap: &'a crate::shm::Snapshot,
    format: TexelFormat,
    buf: Vec<u8>,
    /// A further restriction of the texels available (level, s, t), if any.
    held: Option<&'a dyn Fn(u32, i64, i64) -> bool>,
    /// A block-compressed mapping's texels, decoded (`format` is then the decoded format).
    blocks: Option<blocks::BlockTexels>,
}

impl Fetch for MappedFetch<'_> {
    fn size(&self) -> [u64; 2] {
        self.client.levels[0].size
    }

    fn level_count(&self) -> usize {
        self.client.levels.len()
    }

    fn format(&self) -> TexelFormat {
        self.format
    }

    fn wraps(&self) -> bool {
        self.client.wraps()
    }

    fn raw(&mut self, level: u32, s: i64, t: i64, out: &mut [u8]) -> bool {
        if self.held.is_some_and(|held| !held(level, s, t)) {
            return false;
        }
        if let Some(b) = &mut self.blocks {
            return b.texel(self.client, self.snap, level, s, t, out);
        }
        let texel = crate::geom::Rect::new(s, t, s + 1, t + 1);
        if self.client.read_region_in(self.snap, level as usize, texel, &mut self.buf).is_err() {
            return false;
        }
        out.copy_from_slice(&self.buf);
        true
    }
}

/// Samples a service's mapping through `client` exactly as [`sample_clipmap`] samples the engine
/// (min LOD from the mapping's global state, the finest-available rule over the published valid
/// regions); `None` when nothing holds the footprint, or the mapping's texel format is one the
/// sampler cannot decode.
pub fn sample_mapping(client: &Client, filter: Filter, u: f64, v: f64, lod: f64) -> Option<Sample> {
    let snap = client.try_snapshot().ok()?;
    sample_mapping_in(client, &snap, filter, u, v, lod)
}

/// `sample_mapping` against a snapshot the caller took (so that many samples, a whole frame,
/// see one published state, as a renderer that uploads once a frame does).
pub fn sample_mapping_in(
    client: &Client,
    snap: &crate::shm::Snapshot,
    filter: Filter,
    u: f64,
    v: f64,
    lod: f64,
) -> Option<Sample> {
    sample_mapping_held(client, snap, None, filter, u, v, lod)
}

/// [`sample_mapping_in`] where a texel is available only if, besides being published, `held`
/// says so (level, s, t): a renderer that mirrors the mapping and holds less of it for a while
/// (an upload budget, say) checks its own sampling against this with its own notion of what it
/// holds.
pub fn sample_mapping_held(
    client: &Client,
    snap: &crate::shm::Snapshot,
    held: Option<&dyn Fn(u32, i64, i64) -> bool>,
    filter: Filter,
    u: f64,
    v: f64,
    lod: f64,
) -> Option<Sample> {
    let format = crate::shm::layout::format_from_code(client.format_code)?;
    let min_lod = snap.min_lod;
    let blocks = format.block().map(blocks::BlockTexels::new);
    let format = format.block().map(blocks::decoded_format).unwrap_or(format);
    let mut src = MappedFetch { client, snap, format, buf: vec![0; client.bytes_per_texel], held, blocks };
    sample_published(&mut src, min_lod, filter, u, v, lod)
}

/// Samples a service's mapping's heights through `client`, in metres, exactly as
/// `sample_mapping` samples colours; `Ok(None)` when nothing holds the footprint (or no
/// snapshot could be taken). Fails when the mapping's heights block says its texels are not
/// heights.
pub fn sample_mapping_height(
    client: &Client,
    filter: Filter,
    u: f64,
    v: f64,
    lod: f64,
) -> Result<Option<HeightSample>, HeightSampleError> {
    let Ok(snap) = client.try_snapshot() else {
        return Ok(None);
    };
    sample_mapping_height_in(client, &snap, filter, u, v, lod)
}

/// [`sample_mapping_height`] against a snapshot the caller took.
pub fn sample_mapping_height_in(
    client: &Client,
    snap: &crate::shm::Snapshot,
    filter: Filter,
    u: f64,
    v: f64,
    lod: f64,
) -> Result<Option<HeightSample>, HeightSampleError> {
    let Some(format) = crate::shm::layout::format_from_code(client.format_code) else {
        return Err(HeightSampleError::NotHeights {
            what: "the mapping",
            texel: format!("code {}", client.format_code),
        });
    };
    let hf = height_format("the mapping", client.heights.map(|h| h.format()), format)?;
    let mut src = MappedFetch { client, snap, format, buf: vec![0; client.bytes_per_texel], held: None, blocks: None };
    Ok(published_height(&mut src, &hf, snap.min_lod, filter, u, v, lod))
}

/// The finest-available rule: `sample` at `max(lod, min LOD)`, else at the finest whole level
/// above whose footprint is available; the value and the LOD used.
fn finest_available<T>(
    src: &mut dyn Fetch,
    min_lod: f64,
    filter: Filter,
    lod: f64,
    mut sample: impl FnMut(&mut dyn Fetch, f64) -> Option<T>,
) -> Option<(T, f64)> {
    let count = src.level_count() as u32;
    let last = count as f64 - 1.0;
    let lod = lod.max(min_lod).clamp(0.0, last);
    if let Some(got) = sample(src, lod) {
        return Some((got, lod));
    }
    let first = match filter {
        Filter::Trilinear => lod.ceil() as u32,
        _ => (lod + 0.5).floor() as u32 + 1,
    };
    (first..count).find_map(|k| sample(src, k as f64).map(|got| (got, k as f64)))
}

fn sample_published(src: &mut dyn Fetch, min_lod: f64, filter: Filter, u: f64, v: f64, lod: f64) -> Option<Sample> {
    finest_available(src, min_lod, filter, lod, |src, lod| filtered(src, filter, u, v, lod))
        .map(|(rgba, lod)| Sample { rgba, lod })
}

fn published_height(
    src: &mut dyn Fetch,
    hf: &HeightFormat,
    min_lod: f64,
    filter: Filter,
    u: f64,
    v: f64,
    lod: f64,
) -> Option<HeightSample> {
    finest_available(src, min_lod, filter, lod, |src, lod| filtered_height(src, hf, filter, u, v, lod))
        .map(|(metres, lod)| HeightSample { metres, lod })
}

pub mod blocks;
#[cfg(test)]
mod tests;
