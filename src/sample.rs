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
//! level-0 texel (s, t). Addressing clamps to the level's edges.

use crate::clip::Clipmap;
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

/// Where texels come from: `None` when a texel is not available.
trait Fetch {
    /// Level 0's size in texels.
    fn size(&self) -> [u64; 2];
    /// Number of levels.
    fn level_count(&self) -> usize;
    fn texel(&mut self, level: u32, s: i64, t: i64) -> Option<[f32; 4]>;
}

fn lerp(a: [f32; 4], b: [f32; 4], f: f32) -> [f32; 4] {
    [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f, a[3] + (b[3] - a[3]) * f]
}

fn point(src: &mut dyn Fetch, k: u32, u: f64, v: f64) -> Option<[f32; 4]> {
    let size = level_size(src.size(), k);
    let scale = (1u64 << k) as f64;
    let s = ((u / scale).floor() as i64).clamp(0, size[0] as i64 - 1);
    let t = ((v / scale).floor() as i64).clamp(0, size[1] as i64 - 1);
    src.texel(k, s, t)
}

fn bilinear(src: &mut dyn Fetch, k: u32, u: f64, v: f64) -> Option<[f32; 4]> {
    let size = level_size(src.size(), k);
    let scale = (1u64 << k) as f64;
    let (x, y) = (u / scale - 0.5, v / scale - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let cs = |s: i64| s.clamp(0, size[0] as i64 - 1);
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

/// The full mipmap, read tile by tile from a source (tiles are kept once read).
pub struct MipmapSampler<'a> {
    source: &'a dyn TileSource,
    format: TexelFormat,
    tiles: HashMap<TileId, Vec<u8>>,
    error: Option<SourceError>,
}

impl<'a> MipmapSampler<'a> {
    /// A sampler over every level of `source`.
    pub fn new(source: &'a dyn TileSource) -> Self {
        MipmapSampler { format: source.desc().format(), source, tiles: HashMap::new(), error: None }
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

    fn texel(&mut self, level: u32, s: i64, t: i64) -> Option<[f32; 4]> {
        let desc = self.source.desc();
        let tile = desc.level(level).tile;
        let id = TileId::new(level, s as u64 / tile[0], t as u64 / tile[1]);
        if !self.tiles.contains_key(&id) {
            let mut buf = vec![0u8; desc.tile_bytes(level)];
            if let Err(e) = self.source.read_tile(id, &mut buf) {
                self.error = Some(e);
                return None;
            }
            self.tiles.insert(id, buf);
        }
        let bpt = desc.bytes_per_texel();
        let i = ((t as u64 % tile[1]) * tile[0] + s as u64 % tile[0]) as usize * bpt;
        Some(self.format.decode(&self.tiles[&id][i..i + bpt]))
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

    fn texel(&mut self, level: u32, s: i64, t: i64) -> Option<[f32; 4]> {
        self.0.level(level).texel(s, t).map(|bytes| self.0.desc().format().decode(&bytes))
    }
}

/// Samples the clipmap as published at (u, v) and `lod`, applying min LOD and the
/// finest-available rule; `None` when no level holds the footprint (nothing published yet).
pub fn sample_clipmap(map: &Clipmap, filter: Filter, u: f64, v: f64, lod: f64) -> Option<Sample> {
    sample_published(&mut ClipFetch(map), map.min_lod(), filter, u, v, lod)
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
}

impl Fetch for MappedFetch<'_> {
    fn size(&self) -> [u64; 2] {
        self.client.levels[0].size
    }

    fn level_count(&self) -> usize {
        self.client.levels.len()
    }

    fn texel(&mut self, level: u32, s: i64, t: i64) -> Option<[f32; 4]> {
        if self.held.is_some_and(|held| !held(level, s, t)) {
            return None;
        }
        let texel = crate::geom::Rect::new(s, t, s + 1, t + 1);
        self.client.read_region_in(self.snap, level as usize, texel, &mut self.buf).ok()?;
        Some(self.format.decode(&self.buf))
    }
}

/// Samples a service's mapping through `client` exactly as [`sample_clipmap`] samples the engine
/// (min LOD from the mapping's global state, the finest-available rule over the published valid
/// regions); `None` when nothing holds the footprint, or the mapping's texel format is one the
/// sampler cannot decode.
pub(crate) fn sample_mapping(client: &Client, filter: Filter, u: f64, v: f64, lod: f64) -> Option<Sample> {
    let snap = client.try_snapshot().ok()?;
    sample_mapping_in(client, &snap, filter, u, v, lod)
}

/// [`sample_mapping`] against a snapshot the caller took (so that many samples, a whole frame,
/// see one published state, as a renderer that uploads once a frame does).
pub(crate) fn sample_mapping_in(
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
pub(crate) fn sample_mapping_held(
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
    let mut src = MappedFetch { client, snap, format, buf: vec![0; client.bytes_per_texel], held };
    sample_published(&mut src, min_lod, filter, u, v, lod)
}

fn sample_published(src: &mut dyn Fetch, min_lod: f64, filter: Filter, u: f64, v: f64, lod: f64) -> Option<Sample> {
    let count = src.level_count() as u32;
    let last = count as f64 - 1.0;
    let lod = lod.max(min_lod).clamp(0.0, last);
    if let Some(rgba) = filtered(src, filter, u, v, lod) {
        return Some(Sample { rgba, lod });
    }
    let first = match filter {
        Filter::Trilinear => lod.ceil() as u32,
        _ => (lod + 0.5).floor() as u32 + 1,
    };
    (first..count).find_map(|k| filtered(src, filter, u, v, k as f64).map(|rgba| Sample { rgba, lod: k as f64 }))
}

#[cfg(test)]
mod tests;
