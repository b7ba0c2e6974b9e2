//! Tile archives written by their peers, read by ours: PMTiles written by the reference Python
//! writer (the `pmtiles` package: leaf directories, run-length entries, gzip-compressed tiles)
//! read locally, over nginx and from moto's S3 server, tile for tile equal to what was written,
//! with requests counted at a proxy in front of nginx; MBTiles written by GDAL
//! (`gdal_translate -of MBTILES` and `gdaladdo`), tile for tile equal to what Python's sqlite3
//! module reads, in TMS row order, zooms and bounds from its metadata.

mod mbtiles;
#[cfg(feature = "remote")]
mod pmtiles;
