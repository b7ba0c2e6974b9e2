//! A tile pyramid served as a clip texture ([`PyramidSource`]).
//!
//! The texture is `tile_size * 2^max_zoom` texels a side: level 0 is the finest zoom, level `k`
//! is zoom `max_zoom - k`. A texture tile of a stack level is one pyramid tile: texture tile
//! (s, t) of level `k` is pyramid tile x = s, y = 2^z - 1 - t (texture rows count up from the
//! south, pyramid rows down from the north). A level no larger than the clip size is one texture
//! tile, put together from the pyramid tiles it covers.
//!
//! Texel format: RGB8 when the pyramid declares JPEG tiles (JPEG has no alpha), RGBA8 otherwise
//! (PNG and WebP tiles may carry alpha; a tile without alpha gets alpha 255).
//!
//! Every tile's bytes are checked before they are decoded: their type (magic number) against the
//! declared encoding, and the decoded size against the tile size. An answer that is not the tile
//! (an HTML page, another image type, a wrong size) is an error naming the place, the tile, what
//! was found and what was expected; it never becomes texels.
//!
//! A missing tile (the archive has none, the service answers 404, 204 or an empty body, or the
//! tile lies outside the declared bounds, and is then not asked for) is [`SourceError::Missing`],
//! or the configured default tile. In a texture tile put together from several pyramid tiles,
//! the parts of missing ones are zero (transparent black) or the default tile's texels; the
//! texture tile is missing only when all of them are.
//!
//! Levels coarser than the pyramid's minimum zoom are built once, when first read, from the
//! minimum zoom's tiles with a 2x2 box filter, and kept in memory; the minimum zoom's level may
//! then hold at most [`MAX_BUILT_TEXELS`] texels.

use super::{ArchiveError, Fetched, PyramidInfo, TileAddr, TileArchive, TileEncoding, MAX_ZOOM};
use crate::source::{check_request, Delivered, FaultKind, SourceError, TextureDesc, TileId, TileSource};
use clipmap_base::texel::TexelFormat;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use thiserror::Error;

/// The most texels of the minimum zoom's level from which the coarser levels are built (4096²).
pub const MAX_BUILT_TEXELS: u64 = 1 << 24;

/// Why a pyramid cannot be served.
#[derive(Debug, Error)]
pub enum PyramidError {
    /// The pyramid's description does not make a texture.
    #[error("{place}: {problem}")]
    Info {
        /// The archive or service.
        place: String,
        /// What is wrong and how to fix it.
        problem: String,
    },
    /// The configured default tile cannot be used.
    #[error("{place}: the default tile cannot be used: {problem}")]
    DefaultTile {
        /// The archive or service.
        place: String,
        /// What was found and what was expected.
        problem: String,
    },
    /// The archive could not be opened.
    #[error(transparent)]
    Archive(#[from] ArchiveError),
}

/// How a pyramid is served.
#[derive(Clone, Debug, Default)]
pub struct PyramidOptions {
    /// The clip size; `None` for 1024 (or the texture's size when smaller).
    pub clip_size: Option<u64>,
    /// The encoded bytes (PNG, JPEG or WebP, one tile of the tile size) of the tile served in
    /// place of a missing one.
    pub default_tile: Option<Vec<u8>>,
}

/// The decoded level images built for the levels coarser than the minimum zoom: level images in
/// texture orientation (row 0 the southernmost), finest first, starting at the level of zoom
/// `min_zoom - 1`.
type Built = Vec<Vec<u8>>;

/// The built levels (or why they could not be built) and the archive's version they are of.
type BuiltFor = (u64, Result<Arc<Built>, String>);

/// A tile pyramid ([`TileArchive`]) served as a clip texture.
pub struct PyramidSource {
    archive: Arc<dyn TileArchive>,
    info: PyramidInfo,
    desc: TextureDesc,
    /// The default tile's texels, in texture orientation.
    default: Option<Vec<u8>>,
    /// The built levels and the archive's version they were built from.
    built: Mutex<Option<BuiltFor>>,
    /// Tiles fetched from the archive.
    fetched: AtomicU64,
    /// Default tiles served.
    default_tiles: AtomicU64,
}

impl std::fmt::Debug for PyramidSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PyramidSource").field("place", &self.archive.place()).field("info", &self.info).finish()
    }
}

/// The texel format of a pyramid's tiles: RGB8 for JPEG, RGBA8 otherwise.
pub fn texel_format(encoding: Option<TileEncoding>) -> TexelFormat {
    match encoding {
        Some(TileEncoding::Jpeg) => TexelFormat::RGB8,
        _ => TexelFormat::RGBA8,
    }
}

/// The tile columns and rows (XYZ, from the north) of zoom `z` that `bounds` (west, south,
/// east, north, degrees) touch, inclusive: `[x0, y0, x1, y1]`.
pub fn tile_range(bounds: &[f64; 4], z: u8) -> [u32; 4] {
    let n = TileAddr::tiles_at(z) as f64;
    let max = (TileAddr::tiles_at(z) - 1) as f64;
    let col = |lon: f64| ((lon.clamp(-180.0, 180.0) + 180.0) / 360.0 * n).floor().clamp(0.0, max) as u32;
    let row = |lat: f64| {
        let lat = lat.clamp(-85.051_128_779_806_6, 85.051_128_779_806_6).to_radians();
        let y = (1.0 - (lat.tan() + 1.0 / lat.cos()).ln() / std::f64::consts::PI) / 2.0 * n;
        y.floor().clamp(0.0, max) as u32
    };
    [col(bounds[0]), row(bounds[3]), col(bounds[2]), row(bounds[1])]
}

impl PyramidSource {
    /// Serves `archive` as a clip texture.
    pub fn new(archive: Arc<dyn TileArchive>, opts: &PyramidOptions) -> Result<Self, PyramidError> {
        let info = archive.info().clone();
        let place = archive.place().to_string();
        let bad = |problem: String| PyramidError::Info { place: place.clone(), problem };
        if info.max_zoom > MAX_ZOOM || info.min_zoom > info.max_zoom {
            return Err(bad(format!(
                "zooms {}..{}: expected a minimum zoom no greater than the maximum, and a maximum of at most {MAX_ZOOM}",
                info.min_zoom, info.max_zoom
            )));
        }
        if info.tile_size == 0 || !info.tile_size.is_power_of_two() || info.tile_size > 4096 {
            return Err(bad(format!(
                "tile size {}: expected a power of two from 1 to 4096 (most services: 256)",
                info.tile_size
            )));
        }
        if let Some(b) = info.bounds {
            if !(b.iter().all(|v| v.is_finite()) && b[0] < b[2] && b[1] < b[3]) {
                return Err(bad(format!(
                    "bounds {b:?}: expected west,south,east,north in degrees, west < east and south < north"
                )));
            }
        }
        let ts = u64::from(info.tile_size);
        let side = ts << info.max_zoom;
        if side > crate::source::MAX_TEXTURE_SIZE {
            return Err(bad(format!(
                "zoom {} at {ts}-texel tiles is {side} texels a side, more than the {} this build serves: give a lower maximum zoom (--zooms)",
                info.max_zoom,
                crate::source::MAX_TEXTURE_SIZE
            )));
        }
        let min_side = ts << info.min_zoom;
        if info.min_zoom > 0 && min_side.saturating_mul(min_side) > MAX_BUILT_TEXELS {
            return Err(bad(format!(
                "the coarser levels are built from zoom {}, {min_side}² texels, more than the {MAX_BUILT_TEXELS} texels they may be built from: give a lower minimum zoom (--zooms), one the service has",
                info.min_zoom
            )));
        }
        let clip = opts.clip_size.unwrap_or(1024).min(side);
        let desc = TextureDesc::new([side, side], clip, texel_format(info.encoding), [ts, ts])
            .map_err(|e| bad(format!("cannot make a texture of it: {e}")))?;
        let mut src = PyramidSource {
            archive,
            info,
            desc,
            default: None,
            built: Mutex::new(None),
            fetched: AtomicU64::new(0),
            default_tiles: AtomicU64::new(0),
        };
        if let Some(bytes) = &opts.default_tile {
            let texels = src
                .decode(bytes, None)
                .map_err(|problem| PyramidError::DefaultTile { place: place.clone(), problem })?;
            src.default = Some(texels);
        }
        Ok(src)
    }

    /// The archive served.
    pub fn archive(&self) -> &Arc<dyn TileArchive> {
        &self.archive
    }

    /// What the pyramid holds.
    pub fn info(&self) -> &PyramidInfo {
        &self.info
    }

    /// Tiles fetched from the archive so far (present or missing).
    pub fn fetched(&self) -> u64 {
        self.fetched.load(Ordering::Relaxed)
    }

    /// Default tiles served so far.
    pub fn default_tiles(&self) -> u64 {
        self.default_tiles.load(Ordering::Relaxed)
    }

    fn bytes_per_texel(&self) -> usize {
        self.desc.bytes_per_texel()
    }

    /// Decodes one tile's bytes into its texels, rows in texture orientation (the southernmost
    /// first), after checking its type and size. `at` names the tile in messages (`None` for
    /// the default tile).
    fn decode(&self, bytes: &[u8], at: Option<TileAddr>) -> Result<Vec<u8>, String> {
        let ts = self.info.tile_size as usize;
        let mut out = vec![0u8; ts * ts * self.bytes_per_texel()];
        self.decode_into(bytes, at, &mut out)?;
        Ok(out)
    }

    /// [`decode`](Self::decode) into `out` (one tile's texels), the slot they are published
    /// from: a plain PNG is decoded there with no copy of its own (`decode.rs`). `out` holds no
    /// texel of the tile when it fails.
    fn decode_into(&self, bytes: &[u8], at: Option<TileAddr>, out: &mut [u8]) -> Result<(), String> {
        let what = at.map(|a| format!("tile {a}")).unwrap_or_else(|| "the default tile".into());
        let found = TileEncoding::sniff(bytes);
        let Some(found) = found else {
            let head: String = bytes
                .iter()
                .take(16)
                .map(|&b| if b.is_ascii_graphic() || b == b' ' { b as char } else { '.' })
                .collect();
            return Err(format!(
                "{what}: {} bytes starting {head:?} are not an image: expected {}",
                bytes.len(),
                self.info.encoding.map_or("a PNG, JPEG or WebP tile".to_string(), |e| format!("a {} tile", e.name()))
            ));
        };
        if let Some(expected) = self.info.encoding {
            if found != expected {
                return Err(format!(
                    "{what} is {}, but the pyramid's tiles are {}: the archive or service answered with something else",
                    found.name(),
                    expected.name()
                ));
            }
        }
        // A cut answer must not decode: JPEG decoders fill what is missing with grey, so a JPEG
        // must end with its end-of-image marker, and a WebP hold the bytes its RIFF header says.
        match found {
            TileEncoding::Jpeg => {
                let end = bytes.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
                if !bytes[..end].ends_with(&[0xFF, 0xD9]) {
                    return Err(format!(
                        "{what}: the JPEG of {} bytes ends without its end-of-image marker (FF D9): it was cut short",
                        bytes.len()
                    ));
                }
            }
            TileEncoding::Webp => {
                let riff = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]) as usize;
                if riff.saturating_add(8) > bytes.len() {
                    return Err(format!(
                        "{what}: the WebP's RIFF header says {} bytes, and the tile has {}: it was cut short",
                        riff.saturating_add(8),
                        bytes.len()
                    ));
                }
            }
            TileEncoding::Png => {}
        }
        let ts = self.info.tile_size;
        let wrong_size =
            |w: u32, h: u32| format!("{what} is {w}x{h} texels: expected {ts}x{ts} (the pyramid's tile size)");
        if found == TileEncoding::Png {
            // The whole PNG is there (its chunks up to IEND), before a byte is inflated.
            let head = super::decode::png_chunks(bytes).map_err(|e| format!("{what}: {e}"))?;
            if (head.width, head.height) != (ts, ts) {
                return Err(wrong_size(head.width, head.height));
            }
            if head.plain && self.bytes_per_texel() == 4 {
                return super::decode::png_into_slot(bytes, ts as usize, out)
                    .map_err(|e| format!("{what}: the PNG image cannot be decoded: {e}"));
            }
        }
        let format = match found {
            TileEncoding::Png => image::ImageFormat::Png,
            TileEncoding::Jpeg => image::ImageFormat::Jpeg,
            TileEncoding::Webp => image::ImageFormat::WebP,
        };
        let reader = image::ImageReader::with_format(std::io::Cursor::new(bytes), format);
        let (w, h) =
            reader.into_dimensions().map_err(|e| format!("{what}: {} header cannot be read: {e}", found.name()))?;
        if (w, h) != (ts, ts) {
            return Err(wrong_size(w, h));
        }
        let img = image::load_from_memory_with_format(bytes, format)
            .map_err(|e| format!("{what}: the {} image cannot be decoded: {e}", found.name()))?;
        let raw = if self.bytes_per_texel() == 3 { img.into_rgb8().into_raw() } else { img.into_rgba8().into_raw() };
        let row = ts as usize * self.bytes_per_texel();
        if raw.len() != out.len() {
            return Err(format!("{what}: decoded to {} bytes: expected {} ({ts}x{ts} texels)", raw.len(), out.len()));
        }
        // Rows from the north as the image has them; texture rows from the south.
        for (r, src) in raw.chunks_exact(row).enumerate() {
            let dst = (ts as usize - 1 - r) * row;
            out[dst..dst + row].copy_from_slice(src);
        }
        Ok(())
    }

    /// Whether tile `at` lies within the declared bounds (always, without bounds).
    fn in_bounds(&self, at: TileAddr) -> bool {
        match &self.info.bounds {
            None => true,
            Some(b) => {
                let [x0, y0, x1, y1] = tile_range(b, at.z);
                (x0..=x1).contains(&at.x) && (y0..=y1).contains(&at.y)
            }
        }
    }

    /// The texels of pyramid tile `at` in texture orientation, or `None` when it is missing.
    fn pyramid_tile(&self, tile: TileId, at: TileAddr) -> Result<Option<Vec<u8>>, SourceError> {
        let ts = self.info.tile_size as usize;
        let mut texels = vec![0u8; ts * ts * self.bytes_per_texel()];
        Ok(self.pyramid_tile_into(tile, at, &mut texels)?.then_some(texels))
    }

    /// Pyramid tile `at` decoded into `out` (one tile's texels, texture orientation); whether it
    /// exists (`out` untouched when it is missing).
    fn pyramid_tile_into(&self, tile: TileId, at: TileAddr, out: &mut [u8]) -> Result<bool, SourceError> {
        if !self.in_bounds(at) {
            return Ok(false);
        }
        self.fetched.fetch_add(1, Ordering::Relaxed);
        match self.archive.fetch(at) {
            Ok(Fetched::Missing) => Ok(false),
            Ok(Fetched::Tile(bytes)) if bytes.is_empty() => Ok(false),
            Ok(Fetched::Tile(bytes)) => {
                self.decode_into(&bytes, Some(at), out).map(|()| true).map_err(|problem| SourceError::Pyramid {
                    tile,
                    kind: FaultKind::Corrupt,
                    problem: format!("{}: {problem}", self.archive.place()),
                })
            }
            Err(e) => Err(SourceError::Pyramid { tile, kind: e.kind, problem: e.to_string() }),
        }
    }

    /// Copies the part of `src` (a `src_w` x `src_h` image at texel `src_at` of a level) that
    /// overlaps the region `out` covers (`out_w` x `out_h` at `out_at`).
    fn blit(
        &self,
        src: &[u8],
        src_at: [u64; 2],
        src_size: [u64; 2],
        out: &mut [u8],
        out_at: [u64; 2],
        out_size: [u64; 2],
    ) {
        let b = self.bytes_per_texel();
        let s0 = src_at[0].max(out_at[0]);
        let s1 = (src_at[0] + src_size[0]).min(out_at[0] + out_size[0]);
        let t0 = src_at[1].max(out_at[1]);
        let t1 = (src_at[1] + src_size[1]).min(out_at[1] + out_size[1]);
        if s0 >= s1 || t0 >= t1 {
            return;
        }
        let n = (s1 - s0) as usize * b;
        for t in t0..t1 {
            let from = (((t - src_at[1]) * src_size[0] + (s0 - src_at[0])) as usize) * b;
            let to = (((t - out_at[1]) * out_size[0] + (s0 - out_at[0])) as usize) * b;
            out[to..to + n].copy_from_slice(&src[from..from + n]);
        }
    }

    /// Reads texture tile `tile` of a level whose zoom the pyramid has: the pyramid tiles it
    /// covers. Whether any of them exists.
    fn read_zoom(&self, tile: TileId, z: u8, out: &mut [u8]) -> Result<bool, SourceError> {
        let k = tile.level;
        let level = self.desc.level(k);
        let [tw, th] = level.tile;
        let size = level.size;
        let ts = u64::from(self.info.tile_size);
        let at = [tile.s * tw, tile.t * th];
        let region = [tw.min(size[0] - at[0]), th.min(size[1] - at[1])];
        // Texture rows at[1] .. at[1] + region[1] from the south are pyramid rows from the north
        // size - at[1] - region[1] ..= size - 1 - at[1].
        let north0 = size[1] - at[1] - region[1];
        let north1 = size[1] - 1 - at[1];
        if [tw, th] == [ts, ts] && region == [ts, ts] && at[0].is_multiple_of(ts) && north0.is_multiple_of(ts) {
            // The texture tile is one whole pyramid tile: decoded straight into `out`.
            let addr = TileAddr { z, x: (at[0] / ts) as u32, y: (north0 / ts) as u32 };
            if self.pyramid_tile_into(tile, addr, out)? {
                return Ok(true);
            }
            match &self.default {
                Some(d) => out.copy_from_slice(d),
                None => out.fill(0),
            }
            return Ok(false);
        }
        out.fill(0);
        let mut any = false;
        for y in north0 / ts..=north1 / ts {
            for x in at[0] / ts..=(at[0] + region[0] - 1) / ts {
                let addr = TileAddr { z, x: x as u32, y: y as u32 };
                let texels = match self.pyramid_tile(tile, addr)? {
                    Some(t) => {
                        any = true;
                        t
                    }
                    None => match &self.default {
                        Some(d) => d.clone(),
                        None => continue,
                    },
                };
                // The pyramid tile's texture rows: from the south, it starts at size - (y+1)*ts.
                let src_at = [x * ts, size[1] - (y + 1) * ts];
                self.blit(&texels, src_at, [ts, ts], out, at, [tw, th]);
            }
        }
        Ok(any)
    }

    /// The levels coarser than the minimum zoom, built once for each version of the archive (an
    /// archive replaced and opened again builds them anew from its new tiles).
    fn built(&self, tile: TileId) -> Result<Arc<Built>, SourceError> {
        let mut built = self.built.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut tries = 0;
        loop {
            let version = self.archive.refresh();
            match &*built {
                Some((v, r)) if *v == version => {
                    return r.clone().map_err(|problem| SourceError::Pyramid { tile, kind: FaultKind::Io, problem })
                }
                _ => {}
            }
            let r = self.build().map(Arc::new);
            tries += 1;
            if self.archive.version() != version && tries < 3 {
                // The archive changed while its tiles were read: built again from one version.
                continue;
            }
            *built = Some((version, r.clone()));
            return r.map_err(|problem| SourceError::Pyramid { tile, kind: FaultKind::Io, problem });
        }
    }

    /// Reads the whole level of the minimum zoom and box-filters it down to 1 texel.
    fn build(&self) -> Result<Built, String> {
        let z = self.info.min_zoom;
        let k = u32::from(self.info.max_zoom - z);
        let size = self.desc.level(k).size;
        let b = self.bytes_per_texel();
        let ts = u64::from(self.info.tile_size);
        let mut img = vec![0u8; (size[0] * size[1]) as usize * b];
        let n = TileAddr::tiles_at(z);
        for y in 0..n {
            for x in 0..n {
                let addr = TileAddr { z, x: x as u32, y: y as u32 };
                let id = TileId { level: k, s: x, t: n - 1 - y };
                let texels = match self.pyramid_tile(id, addr).map_err(|e| e.to_string())? {
                    Some(t) => t,
                    None => match &self.default {
                        Some(d) => d.clone(),
                        None => continue,
                    },
                };
                self.blit(&texels, [x * ts, (n - 1 - y) * ts], [ts, ts], &mut img, [0, 0], size);
            }
        }
        let mut out = Vec::new();
        let mut cur = img;
        let mut side = size[0];
        while side > 1 {
            let half = side / 2;
            let mut next = vec![0u8; (half * half) as usize * b];
            for t in 0..half {
                for s in 0..half {
                    for c in 0..b {
                        let at = |ss: u64, tt: u64| u32::from(cur[((tt * side + ss) as usize) * b + c]);
                        let sum =
                            at(2 * s, 2 * t) + at(2 * s + 1, 2 * t) + at(2 * s, 2 * t + 1) + at(2 * s + 1, 2 * t + 1);
                        next[((t * half + s) as usize) * b + c] = ((sum + 2) / 4) as u8;
                    }
                }
            }
            out.push(next.clone());
            cur = next;
            side = half;
        }
        Ok(out)
    }

    fn read(&self, tile: TileId, out: &mut [u8]) -> Result<Delivered, SourceError> {
        check_request(&self.desc, tile, out)?;
        let max = u32::from(self.info.max_zoom);
        let min = u32::from(self.info.min_zoom);
        if tile.level <= max - min {
            let z = (max - tile.level) as u8;
            if self.read_zoom(tile, z, out)? {
                return Ok(Delivered::Tile);
            }
            if self.default.is_some() {
                // `read_zoom` put the default tile's texels in place of every missing tile.
                self.default_tiles.fetch_add(1, Ordering::Relaxed);
                return Ok(Delivered::Default);
            }
            return Err(SourceError::Missing { tile });
        }
        // A level coarser than the minimum zoom: from the built levels.
        let built = self.built(tile)?;
        let level = self.desc.level(tile.level);
        let img = &built[(tile.level - (max - min) - 1) as usize];
        let at = [tile.s * level.tile[0], tile.t * level.tile[1]];
        out.fill(0);
        self.blit(img, [0, 0], level.size, out, at, level.tile);
        Ok(Delivered::Tile)
    }
}

impl TileSource for PyramidSource {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.read(tile, out).map(|_| ())
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<Delivered, SourceError> {
        self.read(tile, out)
    }

    /// EPSG:3857 WebMercatorQuad: level 0 is zoom `max_zoom`, level k zoom `max_zoom - k`.
    fn georef(&self) -> Option<crate::georef::Georef> {
        Some(crate::georef::Georef::web_mercator_quad(u32::from(self.info.max_zoom), u64::from(self.info.tile_size)))
    }

    #[cfg(feature = "remote")]
    fn remote_stats(&self) -> Option<crate::source::remote::RemoteStats> {
        self.archive.remote_stats()
    }

    fn version(&self) -> u64 {
        self.archive.version()
    }
}

#[cfg(test)]
#[path = "pyramid_tests.rs"]
mod tests;
