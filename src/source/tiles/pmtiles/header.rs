//! The 127-byte header of a PMTiles v3 archive: where the directories, the metadata and the tile
//! data lie, how directories and tiles are compressed, what the tiles are, and the zooms and
//! bounds the archive declares. Every number is checked against the file's size before use.

use super::super::{TileEncoding, MAX_ZOOM};

/// The header's length in bytes.
pub const HEADER_LEN: usize = 127;

/// The most bytes a root directory may have: the header and the root directory lie in the
/// first 16 KiB, as the specification requires.
pub const ROOT_MAX: u64 = 16384 - HEADER_LEN as u64;

/// How directories, metadata or tiles are compressed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compression {
    /// Not compressed (also the specification's "unknown", 0, for tiles; refused for
    /// directories).
    None,
    /// gzip.
    Gzip,
    /// Brotli.
    Brotli,
    /// zstd.
    Zstd,
}

/// One byte of the header, as a compression this reader undoes; the problem in words if not.
fn compression(byte: u8, what: &str) -> Result<Compression, String> {
    match byte {
        1 => Ok(Compression::None),
        2 => Ok(Compression::Gzip),
        3 => Ok(Compression::Brotli),
        4 => Ok(Compression::Zstd),
        0 => Err(format!(
            "the {what}' compression is \"unknown\" (byte 0): the archive must say none (1), gzip (2), brotli (3) or zstd (4)"
        )),
        b => Err(format!("the {what}' compression is byte {b}, which PMTiles v3 does not define (1 to 4)")),
    }
}

/// What the header says.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    /// The root directory: offset and length.
    pub root: (u64, u64),
    /// The JSON metadata: offset and length.
    pub metadata: (u64, u64),
    /// The leaf directories' section: offset and length.
    pub leaves: (u64, u64),
    /// The tile data's section: offset and length.
    pub data: (u64, u64),
    /// Tiles addressed (run-length entries counted in full), as written.
    pub addressed_tiles: u64,
    /// Directory entries, as written.
    pub tile_entries: u64,
    /// Distinct tile contents, as written.
    pub tile_contents: u64,
    /// Whether the tiles are ordered by tile id.
    pub clustered: bool,
    /// How directories and metadata are compressed.
    pub internal_compression: Compression,
    /// How tiles are compressed.
    pub tile_compression: Compression,
    /// What the tiles are.
    pub encoding: TileEncoding,
    /// The coarsest zoom.
    pub min_zoom: u8,
    /// The finest zoom.
    pub max_zoom: u8,
    /// West, south, east, north, in degrees.
    pub bounds: [f64; 4],
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

fn i32_at(b: &[u8], at: usize) -> i32 {
    i32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

impl Header {
    /// Parses the header from the file's first bytes (`first`, at least `HEADER_LEN` of them)
    /// of a file of `size` bytes; the problem in words when it is not a PMTiles v3 archive this
    /// reader can read.
    pub fn parse(first: &[u8], size: u64) -> Result<Header, String> {
        if first.len() < HEADER_LEN {
            return Err(format!(
                "the file has {} bytes, fewer than a PMTiles header's {HEADER_LEN}: it is not a PMTiles archive",
                first.len()
            ));
        }
        let b = &first[..HEADER_LEN];
        if &b[0..7] != b"PMTiles" {
            return Err(format!(
                "the file starts with {:?}, not the magic \"PMTiles\": it is not a PMTiles archive",
                String::from_utf8_lossy(&b[0..7])
            ));
        }
        if b[7] != 3 {
            return Err(format!(
                "the archive is PMTiles version {}; this reader reads version 3 (convert it with `pmtiles convert`)",
                b[7]
            ));
        }
        let section = |at: usize, name: &str| -> Result<(u64, u64), String> {
            let (offset, len) = (u64_at(b, at), u64_at(b, at + 8));
            match offset.checked_add(len) {
                Some(end) if end <= size => Ok((offset, len)),
                _ => Err(format!(
                    "the header (bytes {at}..{}) puts the {name} at bytes {offset}..+{len}, past the end of the file ({size} bytes): the archive is truncated or damaged",
                    at + 16
                )),
            }
        };
        let root = section(8, "root directory")?;
        if root.1 > ROOT_MAX || root.0 + root.1 > 16384 || root.0 < HEADER_LEN as u64 {
            return Err(format!(
                "the root directory is at bytes {}..+{}; PMTiles v3 requires it right within the first 16384 bytes, after the header",
                root.0, root.1
            ));
        }
        let metadata = section(24, "metadata")?;
        let leaves = section(40, "leaf directories")?;
        let data = section(56, "tile data")?;
        let internal_compression = compression(b[97], "directories")?;
        let tile_compression = match b[98] {
            0 => Compression::None,
            t => compression(t, "tiles")?,
        };
        let encoding = match b[99] {
            2 => TileEncoding::Png,
            3 => TileEncoding::Jpeg,
            4 => TileEncoding::Webp,
            t => {
                let name = match t {
                    0 => "unknown (0)".to_string(),
                    1 => "MVT vector tiles (1)".to_string(),
                    5 => "AVIF (5)".to_string(),
                    6 => "MLT vector tiles (6)".to_string(),
                    t => format!("type {t}, which PMTiles v3 does not define"),
                };
                return Err(format!(
                    "the tiles are {name}: only raster tiles in PNG (2), JPEG (3) or WebP (4) can be a texture"
                ));
            }
        };
        let (min_zoom, max_zoom) = (b[100], b[101]);
        if min_zoom > max_zoom || max_zoom > MAX_ZOOM {
            return Err(format!(
                "the header's zooms are {min_zoom}..{max_zoom} (bytes 100, 101); expected min <= max <= {MAX_ZOOM}"
            ));
        }
        let deg = |at: usize| f64::from(i32_at(b, at)) / 1e7;
        let bounds = [deg(102), deg(106), deg(110), deg(114)];
        let ok_lon = |v: f64| (-180.0..=180.0).contains(&v);
        let ok_lat = |v: f64| (-90.0..=90.0).contains(&v);
        if !(ok_lon(bounds[0]) && ok_lon(bounds[2]) && ok_lat(bounds[1]) && ok_lat(bounds[3]))
            || bounds[0] > bounds[2]
            || bounds[1] > bounds[3]
        {
            return Err(format!(
                "the header's bounds (bytes 102..118) are {bounds:?}; expected west <= east within ±180 and south <= north within ±90"
            ));
        }
        Ok(Header {
            root,
            metadata,
            leaves,
            data,
            addressed_tiles: u64_at(b, 72),
            tile_entries: u64_at(b, 80),
            tile_contents: u64_at(b, 88),
            clustered: b[96] == 1,
            internal_compression,
            tile_compression,
            encoding,
            min_zoom,
            max_zoom,
            bounds,
        })
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A header with the given sections, compressions, tile type and zooms.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn header_bytes(
        root: (u64, u64),
        leaves: (u64, u64),
        data: (u64, u64),
        internal: u8,
        tiles: u8,
        kind: u8,
        zooms: (u8, u8),
    ) -> Vec<u8> {
        let mut b = b"PMTiles\x03".to_vec();
        for v in [root.0, root.1, root.0 + root.1, 0, leaves.0, leaves.1, data.0, data.1, 0, 0, 0] {
            b.extend(v.to_le_bytes());
        }
        b.extend([1, internal, tiles, kind, zooms.0, zooms.1]);
        for v in [-1_800_000_000i32, -850_511_287, 1_800_000_000, 850_511_287] {
            b.extend(v.to_le_bytes());
        }
        b.push(0);
        b.extend(0i32.to_le_bytes());
        b.extend(0i32.to_le_bytes());
        assert_eq!(b.len(), HEADER_LEN);
        b
    }

    #[test]
    fn a_header_is_read_and_its_sections_checked_against_the_file() {
        let b = header_bytes((127, 10), (137, 0), (137, 100), 2, 1, 3, (0, 5));
        let h = Header::parse(&b, 237).unwrap();
        assert_eq!(
            (h.root, h.data, h.encoding, h.min_zoom, h.max_zoom),
            ((127, 10), (137, 100), TileEncoding::Jpeg, 0, 5)
        );
        assert_eq!(h.internal_compression, Compression::Gzip);
        let e = Header::parse(&b, 200).unwrap_err();
        assert!(e.contains("tile data") && e.contains("past the end of the file (200 bytes)"), "{e}");
    }

    #[test]
    fn foreign_tiles_compressions_and_versions_are_refused_naming_them() {
        let at = |internal, tiles, kind| {
            Header::parse(&header_bytes((127, 0), (127, 0), (127, 0), internal, tiles, kind, (0, 0)), 127)
        };
        assert!(at(2, 1, 1).unwrap_err().contains("MVT"));
        assert!(at(2, 1, 5).unwrap_err().contains("AVIF"));
        assert!(at(2, 1, 0).unwrap_err().contains("unknown"));
        assert_eq!(at(3, 1, 2).unwrap().internal_compression, Compression::Brotli);
        assert_eq!(at(2, 3, 2).unwrap().tile_compression, Compression::Brotli);
        assert!(at(0, 1, 2).unwrap_err().contains("unknown"));
        assert_eq!(at(4, 0, 4).unwrap().tile_compression, Compression::None);
        let mut b = header_bytes((127, 0), (127, 0), (127, 0), 2, 1, 2, (0, 0));
        b[7] = 2;
        assert!(Header::parse(&b, 127).unwrap_err().contains("version 2"));
        assert!(Header::parse(b"<html>", 6).unwrap_err().contains("not a PMTiles"));
        let b = header_bytes((127, 0), (127, 0), (127, 0), 2, 1, 2, (3, 31));
        assert!(Header::parse(&b, 127).unwrap_err().contains("zooms are 3..31"));
        let b = header_bytes((127, 20000), (127, 0), (127, 0), 2, 1, 2, (0, 0));
        assert!(Header::parse(&b, 30000).unwrap_err().contains("first 16384 bytes"));
    }
}
