//! MBTiles archives of raster tiles: an SQLite file (read through `rusqlite`, read-only) whose
//! `tiles` table (or view, as GDAL writes it) holds each tile's bytes by zoom, column and row,
//! rows counted from the south (TMS), and whose `metadata` table says the format, bounds and
//! zooms (the zooms are read from the tiles when it does not).

use super::pmtiles::archive::tile_dimensions;
use super::reopen::{Renewable, Watched};
use super::{ArchiveError, Fetched, PyramidInfo, TileAddr, TileArchive, TileEncoding, MAX_ZOOM};
use crate::source::FaultKind;
use rusqlite::{Connection, OpenFlags, OptionalExtension};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Mutex;

/// An MBTiles archive of PNG, JPEG or WebP tiles. One read-only connection, one query at a time.
pub struct MbtilesArchive {
    place: String,
    db: Mutex<Connection>,
    info: PyramidInfo,
    /// The file as it was opened, to tell when it is replaced or rewritten.
    watched: Watched,
}

/// The tile size when the archive has no tile to read it from.
const DEFAULT_TILE_SIZE: u32 = 256;

impl MbtilesArchive {
    /// Opens the MBTiles file at `path` read-only and reads its metadata; the tile size is read
    /// from the first tile of the coarsest zoom (256 when there is none).
    pub fn open(path: &Path) -> Result<MbtilesArchive, ArchiveError> {
        let place = path.display().to_string();
        let fail = |kind, problem: String| ArchiveError { place: place.clone(), at: None, kind, problem };
        // Stamped before it is read: a change while it is opened shows at the first read.
        let watched = Watched::stamp(path).map_err(|e| {
            let kind = if e.kind() == std::io::ErrorKind::NotFound { FaultKind::Missing } else { FaultKind::Io };
            fail(kind, format!("cannot open it: {e}"))
        })?;
        let db = Connection::open_with_flags(path, OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX)
            .map_err(|e| fail(FaultKind::Io, format!("cannot open it as SQLite: {e}")))?;
        let not_sqlite = |e: rusqlite::Error| match e.sqlite_error_code() {
            Some(rusqlite::ErrorCode::NotADatabase) => fail(
                FaultKind::Corrupt,
                "it is not an SQLite database (an MBTiles archive is one): check that the file is an .mbtiles".into(),
            ),
            _ => fail(FaultKind::Io, format!("cannot read its tables: {e}")),
        };
        let has = |name: &str| -> Result<bool, ArchiveError> {
            db.query_row(
                "SELECT count(*) FROM sqlite_master WHERE name = ?1 AND type IN ('table', 'view')",
                [name],
                |r| r.get::<_, i64>(0),
            )
            .map(|n| n > 0)
            .map_err(not_sqlite)
        };
        if !has("tiles")? {
            return Err(fail(
                FaultKind::Corrupt,
                "it is an SQLite database without a `tiles` table or view: not an MBTiles archive (expected tiles(zoom_level, tile_column, tile_row, tile_data))".into(),
            ));
        }
        let mut meta: HashMap<String, String> = HashMap::new();
        if has("metadata")? {
            let mut q = db.prepare("SELECT name, value FROM metadata").map_err(not_sqlite)?;
            let rows = q
                .query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, Option<String>>(1)?)))
                .map_err(not_sqlite)?;
            for row in rows {
                let (name, value) = row.map_err(not_sqlite)?;
                meta.insert(name, value.unwrap_or_default());
            }
        }
        let encoding = match meta.get("format").map(|f| f.trim().to_ascii_lowercase()) {
            None => None,
            Some(f) => Some(match f.as_str() {
                "png" => TileEncoding::Png,
                "jpg" | "jpeg" => TileEncoding::Jpeg,
                "webp" => TileEncoding::Webp,
                "pbf" | "mvt" => {
                    return Err(fail(FaultKind::Corrupt, format!(
                        "its metadata says format `{f}`: vector tiles, which cannot be a texture (expected png, jpg or webp)"
                    )))
                }
                _ => {
                    return Err(fail(FaultKind::Corrupt, format!(
                        "its metadata says format `{f}`; only raster tiles in png, jpg or webp can be a texture"
                    )))
                }
            }),
        };
        let zoom_of = |name: &str| -> Result<Option<u8>, ArchiveError> {
            let Some(v) = meta.get(name) else { return Ok(None) };
            match v.trim().parse::<u8>() {
                Ok(z) if z <= MAX_ZOOM => Ok(Some(z)),
                _ => Err(fail(
                    FaultKind::Corrupt,
                    format!(
                        "its metadata says {name} `{v}`; expected a zoom from 0 to {MAX_ZOOM} (fix or delete the row)"
                    ),
                )),
            }
        };
        let (mut min_zoom, mut max_zoom) = (zoom_of("minzoom")?, zoom_of("maxzoom")?);
        if min_zoom.is_none() || max_zoom.is_none() {
            let (lo, hi): (Option<i64>, Option<i64>) = db
                .query_row("SELECT min(zoom_level), max(zoom_level) FROM tiles", [], |r| Ok((r.get(0)?, r.get(1)?)))
                .map_err(not_sqlite)?;
            let check = |z: Option<i64>| -> Result<u8, ArchiveError> {
                z.and_then(|z| u8::try_from(z).ok()).filter(|&z| z <= MAX_ZOOM).ok_or_else(|| {
                    fail(FaultKind::Corrupt, format!(
                        "its metadata gives no zooms and its tiles' zoom_level is {z:?}; expected tiles of zooms 0 to {MAX_ZOOM}"
                    ))
                })
            };
            min_zoom = min_zoom.or(Some(check(lo)?));
            max_zoom = max_zoom.or(Some(check(hi)?));
        }
        let (min_zoom, max_zoom) = (min_zoom.unwrap_or(0), max_zoom.unwrap_or(0));
        if min_zoom > max_zoom {
            return Err(fail(
                FaultKind::Corrupt,
                format!("its zooms are {min_zoom}..{max_zoom}; expected minzoom <= maxzoom"),
            ));
        }
        let bounds = match meta.get("bounds") {
            None => None,
            Some(text) => {
                let v: Vec<f64> = text.split(',').filter_map(|s| s.trim().parse().ok()).collect();
                let ok = v.len() == 4
                    && (-180.0..=180.0).contains(&v[0])
                    && (-180.0..=180.0).contains(&v[2])
                    && (-90.0..=90.0).contains(&v[1])
                    && (-90.0..=90.0).contains(&v[3])
                    && v[0] <= v[2]
                    && v[1] <= v[3];
                if !ok {
                    return Err(fail(
                        FaultKind::Corrupt,
                        format!("its metadata says bounds `{text}`; expected `west,south,east,north` in degrees"),
                    ));
                }
                let b = [v[0], v[1], v[2], v[3]];
                let whole = b[0] <= -180.0 + 1e-4 && b[2] >= 180.0 - 1e-4 && b[1] <= -85.0511 && b[3] >= 85.0511;
                (!whole).then_some(b)
            }
        };
        let first: Option<Vec<u8>> = db
            .query_row("SELECT tile_data FROM tiles WHERE zoom_level = ?1 LIMIT 1", [min_zoom], |r| r.get(0))
            .optional()
            .map_err(not_sqlite)?;
        let tile_size = match first.as_deref().map(tile_dimensions) {
            None => DEFAULT_TILE_SIZE,
            Some(Some((w, h))) if w == h && w > 0 => w,
            Some(Some((w, h))) => {
                return Err(fail(
                    FaultKind::Corrupt,
                    format!("its first tile of zoom {min_zoom} is {w} x {h} texels; tiles must be square"),
                ))
            }
            Some(None) => {
                return Err(fail(
                    FaultKind::Corrupt,
                    format!("its first tile of zoom {min_zoom} is not PNG, JPEG or WebP (its size cannot be read)"),
                ))
            }
        };
        Ok(MbtilesArchive {
            place: place.clone(),
            db: Mutex::new(db),
            info: PyramidInfo { min_zoom, max_zoom, tile_size, bounds, encoding },
            watched,
        })
    }
}

impl TileArchive for MbtilesArchive {
    fn place(&self) -> &str {
        &self.place
    }

    fn info(&self) -> &PyramidInfo {
        &self.info
    }

    fn fetch(&self, at: TileAddr) -> Result<Fetched, ArchiveError> {
        let fail = |kind, problem: String| ArchiveError { place: self.place.clone(), at: Some(at), kind, problem };
        if !at.is_valid() {
            return Err(fail(
                FaultKind::BadRequest,
                format!("no such tile: zoom {} has 2^{} columns and rows", at.z, at.z),
            ));
        }
        let db = self.db.lock().map_err(|_| fail(FaultKind::Io, "an earlier query panicked".into()))?;
        let mut q = db
            .prepare_cached("SELECT tile_data FROM tiles WHERE zoom_level = ?1 AND tile_column = ?2 AND tile_row = ?3")
            .map_err(|e| fail(FaultKind::Io, format!("cannot query its tiles: {e}")))?;
        let bytes: Option<Option<Vec<u8>>> =
            q.query_row((at.z, at.x, at.tms_y()), |r| r.get(0)).optional().map_err(|e| {
                fail(
                    FaultKind::Io,
                    format!("cannot read row (zoom {}, column {}, TMS row {}): {e}", at.z, at.x, at.tms_y()),
                )
            })?;
        Ok(match bytes.flatten() {
            Some(b) if !b.is_empty() => Fetched::Tile(b),
            _ => Fetched::Missing,
        })
    }
}

impl Renewable for MbtilesArchive {
    /// The file replaced or rewritten since it was opened (one `stat`): SQLite reads the new
    /// file's pages through the connection of the old one's, so its rows are not trusted.
    fn stale(&self) -> Option<String> {
        self.watched.changed()
    }

    fn renew(&self) -> Result<MbtilesArchive, ArchiveError> {
        MbtilesArchive::open(self.watched.path())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(tag: u8) -> Vec<u8> {
        let mut b = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR\0\0\x01\0\0\0\x01\0".to_vec();
        b.push(tag);
        b
    }

    fn write(path: &Path, meta: &[(&str, &str)], tiles: &[(u8, u32, u32, Vec<u8>)]) {
        let db = Connection::open(path).unwrap();
        db.execute_batch(
            "CREATE TABLE metadata (name text, value text);
             CREATE TABLE tiles (zoom_level integer, tile_column integer, tile_row integer, tile_data blob);",
        )
        .unwrap();
        for (n, v) in meta {
            db.execute("INSERT INTO metadata VALUES (?1, ?2)", [n, v]).unwrap();
        }
        for (z, x, row, b) in tiles {
            db.execute("INSERT INTO tiles VALUES (?1, ?2, ?3, ?4)", (z, x, row, b)).unwrap();
        }
    }

    #[test]
    fn rows_count_from_the_south_and_zooms_come_from_the_tiles_when_metadata_has_none() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.mbtiles");
        // TMS row 0 of zoom 1 is the southern row: XYZ row 1.
        write(&path, &[("format", "png")], &[(1, 0, 0, png(1)), (1, 1, 1, png(2)), (2, 3, 0, png(3))]);
        let a = MbtilesArchive::open(&path).unwrap();
        assert_eq!(
            a.info(),
            &PyramidInfo { min_zoom: 1, max_zoom: 2, tile_size: 256, bounds: None, encoding: Some(TileEncoding::Png) }
        );
        let at = |z, x, y| TileAddr { z, x, y };
        assert_eq!(a.fetch(at(1, 0, 1)).unwrap(), Fetched::Tile(png(1)));
        assert_eq!(a.fetch(at(1, 1, 0)).unwrap(), Fetched::Tile(png(2)));
        assert_eq!(a.fetch(at(2, 3, 3)).unwrap(), Fetched::Tile(png(3)));
        assert_eq!(a.fetch(at(1, 0, 0)).unwrap(), Fetched::Missing);
        assert_eq!(a.fetch(at(5, 0, 0)).unwrap(), Fetched::Missing);
        assert_eq!(a.fetch(at(1, 2, 0)).unwrap_err().kind, FaultKind::BadRequest);
        // Several threads at once.
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| assert_eq!(a.fetch(at(1, 1, 0)).unwrap(), Fetched::Tile(png(2))));
            }
        });
    }

    #[test]
    fn foreign_and_damaged_files_are_refused_saying_what_they_are() {
        let dir = tempfile::tempdir().unwrap();
        let vector = dir.path().join("v.mbtiles");
        write(&vector, &[("format", "pbf")], &[]);
        let e = MbtilesArchive::open(&vector).err().unwrap();
        assert!(e.problem.contains("`pbf`") && e.problem.contains("vector"), "{e}");
        let text = dir.path().join("t.mbtiles");
        std::fs::write(&text, "this is not a database, just a text file long enough to have a header........").unwrap();
        let e = MbtilesArchive::open(&text).err().unwrap();
        assert!(e.problem.contains("not an SQLite database"), "{e}");
        let empty = dir.path().join("e.mbtiles");
        Connection::open(&empty).unwrap().execute_batch("CREATE TABLE other (a);").unwrap();
        let e = MbtilesArchive::open(&empty).err().unwrap();
        assert!(e.problem.contains("without a `tiles` table"), "{e}");
        let e = MbtilesArchive::open(&dir.path().join("absent.mbtiles")).err().unwrap();
        assert_eq!(e.kind, FaultKind::Missing);
        assert!(!dir.path().join("absent.mbtiles").exists(), "opening must not create the file");
        let bad = dir.path().join("b.mbtiles");
        write(&bad, &[("format", "png"), ("bounds", "10,20,5,30")], &[(0, 0, 0, png(0))]);
        assert!(MbtilesArchive::open(&bad).err().unwrap().problem.contains("bounds `10,20,5,30`"));
    }
}
