//! MBTiles archives written by GDAL, read back through Python's sqlite3 module as the oracle.

use crate::common::gdal::python;
use clipmap::source::tiles::mbtiles::MbtilesArchive;
use clipmap::source::tiles::{Fetched, TileAddr, TileArchive, TileEncoding};
use std::path::Path;
use std::process::Command;

/// Has GDAL write `NAME.mbtiles` in `dir` (an RGB image over 5..15° E, 40..50° N, tiles in
/// `format`, overviews by gdaladdo), then Python's sqlite3 read every row of its `tiles` into
/// `NAME.rows` (zoom u8, column u32, TMS row u32, length u32 little-endian, then the bytes) and
/// print its metadata as `name=value` lines, returned.
fn gdal_mbtiles(dir: &Path, name: &str, format: &str) -> Vec<(String, String)> {
    let script = format!(
        r#"
import sqlite3, struct, subprocess, sys
from osgeo import gdal, osr
gdal.UseExceptions()
w, h = 600, 500
ds = gdal.GetDriverByName("GTiff").Create("{name}.tif", w, h, 3, gdal.GDT_Byte)
ds.SetGeoTransform([5.0, 10.0 / w, 0, 50.0, 0, -10.0 / h])
srs = osr.SpatialReference(); srs.ImportFromEPSG(4326); ds.SetProjection(srs.ExportToWkt())
for b in range(3):
    ds.GetRasterBand(b + 1).WriteRaster(0, 0, w, h, bytes(((x * (b + 1) + y * 3) // 2) & 255 for y in range(h) for x in range(w)))
ds = None
def run(*args):
    r = subprocess.run(args, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{{args}}: {{r.stderr}}")
run("gdal_translate", "-q", "-of", "MBTILES", "-co", "TILE_FORMAT={format}", "{name}.tif", "{name}.mbtiles")
run("gdaladdo", "-q", "-r", "average", "{name}.mbtiles", "2", "4", "8")
db = sqlite3.connect("{name}.mbtiles")
with open("{name}.rows", "wb") as out:
    for z, x, y, data in db.execute("SELECT zoom_level, tile_column, tile_row, tile_data FROM tiles"):
        out.write(struct.pack("<BIII", z, x, y, len(data)) + data)
for n, v in db.execute("SELECT name, value FROM metadata"):
    print(f"{{n}}={{v}}")
"#
    );
    let mut child = Command::new(python())
        .current_dir(dir)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .arg("-")
        .spawn()
        .unwrap();
    std::io::Write::write_all(child.stdin.as_mut().unwrap(), script.as_bytes()).unwrap();
    drop(child.stdin.take());
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "GDAL's MBTiles ({format}): {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .filter_map(|l| l.split_once('=').map(|(n, v)| (n.to_string(), v.to_string())))
        .collect()
}

/// The rows Python read: zoom, column, TMS row, bytes.
fn rows(dir: &Path, name: &str) -> Vec<(u8, u32, u32, Vec<u8>)> {
    let b = std::fs::read(dir.join(format!("{name}.rows"))).unwrap();
    let le32 = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
    let (mut at, mut out) = (0, Vec::new());
    while at < b.len() {
        let len = le32(at + 9) as usize;
        out.push((b[at], le32(at + 1), le32(at + 5), b[at + 13..at + 13 + len].to_vec()));
        at += 13 + len;
    }
    out
}

/// The XYZ row (from the north) of latitude `lat` at zoom `z`, Web Mercator.
fn xyz_row(lat: f64, z: u8) -> u32 {
    let r = lat.to_radians();
    let y = (1.0 - (r.tan() + 1.0 / r.cos()).ln() / std::f64::consts::PI) / 2.0;
    (y * f64::from(1u32 << z)).floor() as u32
}

#[test]
fn gdal_mbtiles_read_back_row_for_row_in_tms_order_with_zooms_and_bounds_from_metadata() {
    let dir = tempfile::tempdir().unwrap();
    for (name, format, encoding) in [("png", "PNG", TileEncoding::Png), ("jpeg", "JPEG", TileEncoding::Jpeg)] {
        let meta = gdal_mbtiles(dir.path(), name, format);
        let get = |k: &str| {
            meta.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone()).unwrap_or_else(|| panic!("{k}: {meta:?}"))
        };
        let a = MbtilesArchive::open(&dir.path().join(format!("{name}.mbtiles"))).unwrap();
        let info = a.info();
        assert_eq!(info.encoding, Some(encoding), "{name}");
        assert_eq!((info.min_zoom.to_string(), info.max_zoom.to_string()), (get("minzoom"), get("maxzoom")), "{name}");
        assert!(info.max_zoom > info.min_zoom, "{name}: gdaladdo's overviews are zooms of their own: {info:?}");
        let want: Vec<f64> = get("bounds").split(',').map(|v| v.parse().unwrap()).collect();
        let bounds = info.bounds.unwrap();
        assert_eq!(bounds.to_vec(), want, "{name}");
        assert!((bounds[0] - 5.0).abs() < 0.1 && (bounds[3] - 50.0).abs() < 0.1, "{name}: {bounds:?}");
        assert_eq!(info.tile_size, 256, "{name}");

        let rows = rows(dir.path(), name);
        assert!(rows.len() > 4, "{name}: {} rows", rows.len());
        let mut zooms = std::collections::BTreeSet::new();
        for (z, x, tms_row, bytes) in &rows {
            zooms.insert(*z);
            let y = (1u32 << z) - 1 - tms_row;
            let at = TileAddr { z: *z, x: *x, y };
            assert_eq!(at.tms_y(), *tms_row);
            assert_eq!(a.fetch(at).unwrap(), Fetched::Tile(bytes.clone()), "{name}: tile {at} (TMS row {tms_row})");
            // The rows are TMS: counted from the south, the tile lies between the bounds'
            // northern and southern XYZ rows (the area is north of the equator, so rows
            // counted from the north would fall outside).
            let (north, south) = (xyz_row(bounds[3], *z), xyz_row(bounds[1], *z));
            assert!((north..=south).contains(&y), "{name}: tile {at} is outside rows {north}..={south}");
            // The row below the area's southern edge has no tile.
            if south + 1 < 1 << z {
                assert_eq!(a.fetch(TileAddr { z: *z, x: *x, y: south + 1 }).unwrap(), Fetched::Missing);
            }
        }
        assert_eq!(zooms.len(), usize::from(info.max_zoom - info.min_zoom) + 1, "{name}: {zooms:?}");
    }
}
