//! The shared-memory access layer (docs/ARCHITECTURE.md §5, `docs/SHM.md`): the `clipmap-shm`
//! crate, re-exported whole (its layout, writer, client and the only `unsafe` code), and what
//! needs the engine besides: tiles a source takes from a mapping ([`shared_reads`]).

pub use clipmap_shm::*;

pub mod shared_reads;

#[cfg(test)]
mod tests;

pub use shared_reads::{Freshness, FromMapping};

/// The texture's georeferencing as the engine's [`crate::georef::Georef`], from a mapping's georef
/// block and its level-0 size (`Client::georef`, `Client::levels[0].size`): level 0's
/// geotransform, the CRS from the EPSG code (else the block's PROJ definition; a CRS known by
/// neither converts map coordinates only). `Err` says why a block cannot be used.
pub fn georef_of(block: &GeorefBlock, size0: [u64; 2]) -> Result<crate::georef::Georef, String> {
    use crate::georef::{Crs, GeoTransform, Georef};
    let g = block.geotransform(0, size0[1], size0[1]).ok_or("the georef block has no level 0")?;
    let crs = match (block.epsg, block.definition.as_str()) {
        (Some(code), d) => Crs::epsg(code).unwrap_or_else(|_| Crs::unknown(Some(code), d)),
        (None, "") => Crs::unknown(None, "a CRS the mapping does not name"),
        (None, d) => Crs::from_proj_string(d).unwrap_or_else(|_| Crs::unknown(None, d)),
    };
    Georef::new(crs, GeoTransform(g), size0).map_err(|e| e.to_string())
}

/// The WGS 84 `[longitude, latitude]` of level-0 centre `c` as `STATS` shows it
/// (`centre_lonlat`: its texel's middle, `(s + 0.5, t + 0.5)`), through a mapping's georef block;
/// `None` without georeferencing, outside the texture or for a CRS without a known definition.
pub fn centre_lonlat(block: Option<&GeorefBlock>, size0: [u64; 2], c: [i64; 2]) -> Option<[f64; 2]> {
    georef_of(block?, size0).ok()?.texel_to_lonlat(0, [c[0] as f64 + 0.5, c[1] as f64 + 0.5]).ok()
}
