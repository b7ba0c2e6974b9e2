//! Tile pyramids addressed by zoom, column and row: tile services (XYZ, TMS, quadkey and WMTS
//! templates) and tile archives (PMTiles, MBTiles), served as they are.
//!
//! A tile pyramid in Web Mercator (WebMercatorQuad) with square tiles of `n` texels is a virtual
//! clip texture: zoom `z` is a level of `n * 2^z` texels a side, so the finest zoom `Z` is level 0
//! and zoom `Z - k` is level `k`. This room holds the seam every such pyramid stands on: a
//! [`TileArchive`] answers the encoded bytes of one tile ([`TileAddr`], rows counted from the
//! north as XYZ and WMTS count them) or says that the tile does not exist; the pyramid source
//! decodes those bytes into a slot, in texture orientation (t counts up from the south).

mod decode;
pub mod pyramid;
pub(crate) mod reopen;
pub(crate) mod template;

pub use pyramid::{PyramidError, PyramidOptions, PyramidSource};
pub use template::{Template, TemplateArchive, TemplateOptions};

use super::FaultKind;
use crate::place::Place;
use mbtiles::MbtilesArchive;
use pmtiles::PmtilesArchive;
use reopen::Reopening;
use serde::Serialize;
use std::fmt;
use std::sync::Arc;
use thiserror::Error;

pub mod mbtiles;
pub mod pmtiles;

/// The deepest zoom a pyramid may have: 2^30 texels a side at 256-texel tiles is zoom 22, and
/// a column or row must fit `u32`.
pub const MAX_ZOOM: u8 = 30;

/// A tile's place in a pyramid: its zoom, its column counted from the west and its row counted
/// from the north (the XYZ and WMTS order; [`TileAddr::tms_y`] gives TMS's row from the south).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub struct TileAddr {
    /// Zoom, 0 for the one tile of the whole world.
    pub z: u8,
    /// Column, 0 at the west edge.
    pub x: u32,
    /// Row, 0 at the north edge.
    pub y: u32,
}

impl TileAddr {
    /// The tiles of zoom `z` along each axis (`2^z`).
    pub fn tiles_at(z: u8) -> u64 {
        1u64 << z
    }

    /// Whether the column and row lie within zoom `z` and the zoom within [`MAX_ZOOM`].
    pub(crate) fn is_valid(&self) -> bool {
        self.z <= MAX_ZOOM && u64::from(self.x) < Self::tiles_at(self.z) && u64::from(self.y) < Self::tiles_at(self.z)
    }

    /// The row counted from the south, as TMS (and MBTiles) number rows.
    pub fn tms_y(&self) -> u32 {
        (Self::tiles_at(self.z) - 1 - u64::from(self.y)) as u32
    }

    /// The Bing Maps quadkey of the tile: one digit a zoom, most significant first (empty at
    /// zoom 0).
    pub fn quadkey(&self) -> String {
        (1..=self.z)
            .rev()
            .map(|i| {
                let bit = 1u32 << (i - 1);
                let digit = u8::from(self.x & bit != 0) + 2 * u8::from(self.y & bit != 0);
                char::from(b'0' + digit)
            })
            .collect()
    }
}

impl fmt::Display for TileAddr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}/{}", self.z, self.x, self.y)
    }
}

/// How a tile's bytes are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TileEncoding {
    /// PNG.
    Png,
    /// JPEG (baseline or progressive).
    Jpeg,
    /// WebP (lossy or lossless).
    Webp,
}

impl TileEncoding {
    /// The encoding `bytes` start with (their magic number), if any of these.
    pub fn sniff(bytes: &[u8]) -> Option<TileEncoding> {
        if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
            Some(TileEncoding::Png)
        } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
            Some(TileEncoding::Jpeg)
        } else if bytes.len() >= 12 && &bytes[0..4] == b"RIFF" && &bytes[8..12] == b"WEBP" {
            Some(TileEncoding::Webp)
        } else {
            None
        }
    }

    /// The usual name (`png`, `jpeg`, `webp`).
    pub fn name(self) -> &'static str {
        match self {
            TileEncoding::Png => "png",
            TileEncoding::Jpeg => "jpeg",
            TileEncoding::Webp => "webp",
        }
    }
}

/// What a pyramid holds, as its archive or service declares it (or as its configuration says).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PyramidInfo {
    /// The coarsest zoom that has tiles.
    pub min_zoom: u8,
    /// The finest zoom that has tiles: level 0 of the texture.
    pub max_zoom: u8,
    /// Tile width and height in texels (256 for most services).
    pub tile_size: u32,
    /// The area the tiles cover, in degrees: west, south, east, north; `None` for the whole
    /// WebMercatorQuad.
    pub bounds: Option<[f64; 4]>,
    /// The encoding the archive declares for its tiles, if it declares one; each tile's own bytes
    /// are checked ([`TileEncoding::sniff`]) before one is decoded either way.
    pub encoding: Option<TileEncoding>,
}

/// What an archive answered for one tile.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Fetched {
    /// The tile's encoded bytes (after any archive-level compression is undone).
    Tile(Vec<u8>),
    /// The tile does not exist (an archive without an entry, a service's 404, 204 or empty body).
    Missing,
}

/// Why an archive could not answer for a tile (or could not be opened).
#[derive(Debug, Error)]
#[error("{place}{at}: {problem}", at = at.map(|a| format!(": tile {a}")).unwrap_or_default())]
pub struct ArchiveError {
    /// The archive or service, as written by the user (with any secret left out).
    pub place: String,
    /// The tile, when the error is about one.
    pub at: Option<TileAddr>,
    /// The kind of failure, for statistics and the read queue's retry rules.
    pub kind: FaultKind,
    /// What was found, what was expected and how to fix it.
    pub problem: String,
}

/// A source of encoded tiles addressed by zoom, column and row.
pub trait TileArchive: Send + Sync {
    /// The archive or service as the user wrote it, for messages (no secrets).
    fn place(&self) -> &str;

    /// What the pyramid holds.
    fn info(&self) -> &PyramidInfo;

    /// The encoded bytes of tile `at`, or [`Fetched::Missing`]. Blocks (disk, network).
    fn fetch(&self, at: TileAddr) -> Result<Fetched, ArchiveError>;

    /// The counters of the archive's remote reads, for one that reads over the network.
    #[cfg(feature = "remote")]
    fn remote_stats(&self) -> Option<super::remote::RemoteStats> {
        None
    }

    /// Whether the remote disk cache holds tile `at` already (`cliptex seed` skips it); `false`
    /// for an archive read without one.
    fn is_cached(&self, at: TileAddr) -> bool {
        let _ = at;
        false
    }

    /// Where tile `at` is, as messages may show it (a URL with its secrets replaced, a path), for
    /// an archive that keeps each tile apart; `None` by default.
    fn locate(&self, at: TileAddr) -> Option<String> {
        let _ = at;
        None
    }

    /// The bytes tile `at` takes in the archive, as its own index says, without reading the tile
    /// (`cliptex seed --estimate`): `Some(Ok(None))` for a tile it does not hold, `None` for an
    /// archive with no such index (a tile service). May read directories (network, disk).
    fn stored_length(&self, at: TileAddr) -> Option<Result<Option<u64>, ArchiveError>> {
        let _ = at;
        None
    }

    /// A number that changes each time tiles may have changed at once (an archive replaced in
    /// its store and opened again); 0 for an archive whose tiles never change so.
    fn version(&self) -> u64 {
        0
    }

    /// Checks whether the archive changed since it was opened (opening it again if so, as a
    /// read would) and returns its [`version`](TileArchive::version) then: what a reader asks
    /// before using what it built from the archive's tiles. May block (disk, network).
    fn refresh(&self) -> u64 {
        self.version()
    }
}

/// How a tile pyramid named on a command line or in a configuration is served.
#[derive(Clone, Debug, Default)]
pub struct OpenOptions {
    /// A template's zooms, bounds, subdomains, User-Agent and headers.
    pub template: TemplateOptions,
    /// The clip size and default tile.
    pub pyramid: PyramidOptions,
}

/// The opener of one kind of archive or service.
type Opener = fn(&str, &OpenOptions) -> Result<Arc<dyn TileArchive>, PyramidError>;

fn open_template(text: &str, opts: &OpenOptions) -> Result<Arc<dyn TileArchive>, PyramidError> {
    let template = text.strip_prefix("xyz:").unwrap_or(text);
    Ok(Arc::new(TemplateArchive::open(template, &opts.template)?))
}

/// A PMTiles archive (a path, an http(s) URL or an `s3://` name), with its tile size read from
/// its first tile unless `--tile-size` gives it.
fn open_pmtiles(text: &str, opts: &OpenOptions) -> Result<Arc<dyn TileArchive>, PyramidError> {
    #[cfg(feature = "remote")]
    let mut archive = match &opts.template.remote {
        Some(remote) => PmtilesArchive::open_with(&Place::parse(text), remote.clone())?,
        None => PmtilesArchive::open(&Place::parse(text))?,
    };
    #[cfg(not(feature = "remote"))]
    let mut archive = PmtilesArchive::open(&Place::parse(text))?;
    match opts.template.tile_size {
        Some(size) => archive.set_tile_size(size),
        None => {
            archive.probe_tile_size()?;
        }
    }
    Ok(Arc::new(Reopening::new(archive)))
}

/// An MBTiles archive: a local SQLite file.
fn open_mbtiles(text: &str, _opts: &OpenOptions) -> Result<Arc<dyn TileArchive>, PyramidError> {
    match Place::parse(text) {
        Place::Local(path) => Ok(Arc::new(Reopening::new(MbtilesArchive::open(&path)?))),
        Place::Remote(_) => Err(PyramidError::Info {
            place: text.to_string(),
            problem: "an MBTiles archive is an SQLite file and is read from a local disk only; download it first, or convert it to PMTiles (`pmtiles convert`) to serve it over HTTP or S3".into(),
        }),
    }
}

/// The opener of the kind of archive or service `text` names, one arm a kind: `xyz:TEMPLATE`,
/// a name ending in `.pmtiles` or `.mbtiles` (any case).
fn opener(text: &str) -> Option<Opener> {
    if text.starts_with("xyz:") {
        return Some(open_template);
    }
    match Place::parse(text).extension().map(str::to_ascii_lowercase).as_deref() {
        Some("pmtiles") => Some(open_pmtiles),
        Some("mbtiles") => Some(open_mbtiles),
        _ => None,
    }
}

/// Whether `text` names a tile pyramid [`open`] serves (`xyz:TEMPLATE`, `.pmtiles`, `.mbtiles`).
pub fn is_pyramid(text: &str) -> bool {
    opener(text).is_some()
}

/// The archive or service `text` names: `xyz:TEMPLATE` (an XYZ, TMS, quadkey or WMTS template,
/// docs/TILES.md), a PMTiles or an MBTiles archive; `None` when `text` names none of them.
pub fn open_archive(text: &str, opts: &OpenOptions) -> Option<Result<Arc<dyn TileArchive>, PyramidError>> {
    opener(text).map(|open| open(text, opts))
}

/// The tile pyramid `text` names ([`open_archive`]) served as a clip texture; `None` when
/// `text` names none.
pub fn open(text: &str, opts: &OpenOptions) -> Option<Result<PyramidSource, PyramidError>> {
    let archive = open_archive(text, opts)?;
    Some(archive.and_then(|a| PyramidSource::new(a, &opts.pyramid)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn open_recognises_templates_only() {
        assert!(open("tiles/{z}/{x}/{y}.png", &OpenOptions::default()).is_none());
        assert!(open("my.ct", &OpenOptions::default()).is_none());
        let e = open("xyz:tiles/{z}/{x}.png", &OpenOptions::default()).unwrap().unwrap_err().to_string();
        assert!(e.contains("does not name every tile"), "{e}");
        let opts = OpenOptions {
            template: TemplateOptions { zooms: Some([0, 18]), ..Default::default() },
            ..Default::default()
        };
        let src = open("xyz:https://tile.example.org/{z}/{x}/{y}.jpg", &opts).unwrap().unwrap();
        assert_eq!(src.info().encoding, Some(TileEncoding::Jpeg));
        assert!(is_pyramid("xyz:a/{z}/{x}/{y}.png") && !is_pyramid("a.ct"));
        assert!(
            is_pyramid("world.pmtiles") && is_pyramid("https://h/w.PMTiles?sig=1") && is_pyramid("s3://b/w.pmtiles")
        );
        assert!(is_pyramid("ortho.mbtiles") && !is_pyramid("ortho.tif"));
        let e = open("https://h/ortho.mbtiles", &OpenOptions::default()).unwrap().unwrap_err().to_string();
        assert!(e.contains("local disk only"), "{e}");
    }

    #[test]
    fn quadkeys_match_bing_maps_examples() {
        // Bing Maps Tile System: tile (3, 5) at level 3 is quadkey "213".
        assert_eq!(TileAddr { z: 3, x: 3, y: 5 }.quadkey(), "213");
        assert_eq!(TileAddr { z: 0, x: 0, y: 0 }.quadkey(), "");
        assert_eq!(TileAddr { z: 1, x: 1, y: 1 }.quadkey(), "3");
    }

    #[test]
    fn tms_rows_count_from_the_south() {
        assert_eq!(TileAddr { z: 0, x: 0, y: 0 }.tms_y(), 0);
        assert_eq!(TileAddr { z: 2, x: 1, y: 0 }.tms_y(), 3);
        assert_eq!(TileAddr { z: 30, x: 0, y: (1 << 30) - 1 }.tms_y(), 0);
        assert!(!TileAddr { z: 2, x: 4, y: 0 }.is_valid());
        assert!(TileAddr { z: 30, x: (1 << 30) - 1, y: 0 }.is_valid());
    }

    #[test]
    fn encodings_are_told_by_their_magic_numbers() {
        assert_eq!(TileEncoding::sniff(b"\x89PNG\r\n\x1a\n...."), Some(TileEncoding::Png));
        assert_eq!(TileEncoding::sniff(&[0xFF, 0xD8, 0xFF, 0xE0]), Some(TileEncoding::Jpeg));
        assert_eq!(TileEncoding::sniff(b"RIFF\0\0\0\0WEBPVP8 "), Some(TileEncoding::Webp));
        assert_eq!(TileEncoding::sniff(b"<!DOCTYPE html>"), None);
        assert_eq!(TileEncoding::sniff(b""), None);
    }
}
