//! Where a texture is on the Earth (docs/GEOREF.md): its [`Crs`], level 0's affine transform in
//! GDAL's geotransform order ([`GeoTransform`]), the texture's size, and every level's transform
//! derived from them ([`Georef`]); conversions texel (s, t) <-> map (x, y) <-> longitude /
//! latitude, and the WebMercatorQuad tile pyramid ([`Georef::web_mercator_quad`]).
//!
//! Texel coordinates are continuous: texel (s, t) covers [s, s + 1) x [t, t + 1), s counting
//! east from the west edge and t north from the south edge, so `t = height - line` for GDAL's
//! continuous line coordinate (line 0 is the top edge of the top row) and `s = pixel`.
//!
//! Levels: level k's size is [`crate::tile::level_size`] (each edge halved k times, rounded down, at least
//! 1), and its texel (s, t) covers level 0's texels [s 2^k, (s + 1) 2^k) x [t 2^k, (t + 1) 2^k):
//! the levels are anchored at the south-west corner, as the 2 x 2 box filter that builds them
//! pairs texels from there. So level k's geotransform is level 0's with every scale and rotation
//! term times 2^k, its origin (the north-west corner of its top row) moved south by the
//! level-0 rows the halvings dropped, `height - (height >> k) 2^k` of them (0 when the height is
//! a multiple of 2^k, as for every overview a COG serves from its file: [`Georef::level_transform`]).
//! An edge of fewer than 2^k texels still gets one texel of 2^k level-0 texels at level k.
//!
//! Nothing here reads a file: the COG source reads its GeoTIFF keys into a [`Georef`].

mod crs;
#[cfg(test)]
mod tests;

pub use crs::{Crs, WEB_MERCATOR_HALF, WEB_MERCATOR_MAX_LAT, WEB_MERCATOR_RADIUS};

use serde::Serialize;
use thiserror::Error;

/// Why a position or a georeferencing is refused.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum GeorefError {
    /// A texel position outside the level.
    #[error("texel ({s}, {t}) is outside level {level}, whose texels are s in [0, {w}] and t in [0, {h}]", w = size[0], h = size[1])]
    OutsideTexture {
        /// The level.
        level: u32,
        /// The position's s.
        s: f64,
        /// The position's t.
        t: f64,
        /// The level's size in texels.
        size: [u64; 2],
    },
    /// A point outside the projection's domain (or not a finite number).
    #[error("{what} is outside {domain}")]
    OutsideDomain {
        /// The point, in words.
        what: String,
        /// The domain, in words.
        domain: String,
    },
    /// An EPSG code without a definition known here.
    #[error("EPSG:{0} has no definition known here: longitude / latitude cannot be converted (map coordinates can)")]
    UnknownEpsg(u32),
    /// A CRS known by a description alone.
    #[error(
        "the CRS {crs} has no definition known here: longitude / latitude cannot be converted (map coordinates can)"
    )]
    NoDefinition {
        /// The CRS, in words.
        crs: String,
    },
    /// A PROJ string that `proj4rs` does not take.
    #[error("the CRS definition {definition:?} is refused: {problem}")]
    Definition {
        /// The definition.
        definition: String,
        /// Why.
        problem: String,
    },
    /// A georeferencing that cannot be: a transform that is not finite or not invertible, an
    /// empty texture, a level past the last.
    #[error("{0}")]
    Invalid(String),
}

/// An affine transform in GDAL's geotransform order: map `x = g[0] + pixel g[1] + line g[2]`,
/// `y = g[3] + pixel g[4] + line g[5]`, for continuous pixel / line coordinates whose (0, 0)
/// is the north-west corner of the image's top-left pixel (`gdalinfo`'s GeoTransform).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(transparent)]
pub struct GeoTransform(pub [f64; 6]);

impl GeoTransform {
    /// Map `[x, y]` of continuous `[pixel, line]`.
    #[inline]
    pub fn apply(&self, [p, l]: [f64; 2]) -> [f64; 2] {
        let g = &self.0;
        [g[0] + p * g[1] + l * g[2], g[3] + p * g[4] + l * g[5]]
    }

    /// Continuous `[pixel, line]` of map `[x, y]` (the transform's inverse).
    #[inline]
    pub fn invert(&self, [x, y]: [f64; 2]) -> [f64; 2] {
        let g = &self.0;
        let (dx, dy) = (x - g[0], y - g[3]);
        if g[2] == 0.0 && g[4] == 0.0 {
            return [dx / g[1], dy / g[5]];
        }
        let det = g[1] * g[5] - g[2] * g[4];
        [(dx * g[5] - dy * g[2]) / det, (dy * g[1] - dx * g[4]) / det]
    }

    /// Refuses a transform that is not finite or not invertible.
    pub fn check(&self) -> Result<(), GeorefError> {
        let g = &self.0;
        if g.iter().any(|v| !v.is_finite()) {
            return Err(GeorefError::Invalid(format!("geotransform {g:?} has a number that is not finite")));
        }
        let det = g[1] * g[5] - g[2] * g[4];
        if det == 0.0 || !det.is_finite() {
            return Err(GeorefError::Invalid(format!(
                "geotransform {g:?} is not invertible (pixel size {} x {}, rotation {} and {}): expected non-zero pixel sizes",
                g[1], g[5], g[2], g[4]
            )));
        }
        Ok(())
    }
}

/// Where a texture is: its CRS, level 0's geotransform (GDAL's order, for level 0's pixel /
/// line) and level 0's size in texels.
#[derive(Clone, Debug, PartialEq)]
pub struct Georef {
    crs: Crs,
    transform: GeoTransform,
    size: [u64; 2],
}

/// A [`Georef`] as `cliptex info --json` prints it: `epsg` (null when none is known), `crs`
/// (the definition) and `geotransform` (level 0's, GDAL's order).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GeorefSummary {
    /// The EPSG code, where known.
    pub epsg: Option<u32>,
    /// The CRS's definition.
    pub crs: String,
    /// Level 0's geotransform, GDAL's order.
    pub geotransform: GeoTransform,
}

impl Georef {
    /// The georeferencing of a texture of level-0 size `size` whose level 0 maps through
    /// `transform`; refused: an empty size, a transform not finite or not invertible.
    pub fn new(crs: Crs, transform: GeoTransform, size: [u64; 2]) -> Result<Georef, GeorefError> {
        transform.check()?;
        if size[0] == 0 || size[1] == 0 {
            return Err(GeorefError::Invalid(format!("texture size {size:?}: expected at least 1 texel a side")));
        }
        Ok(Georef { crs, transform, size })
    }

    /// A tile pyramid's WebMercatorQuad (OGC's tile matrix set, as XYZ tile services use it):
    /// EPSG:3857, level 0 is zoom `max_zoom`, `tile_size x 2^max_zoom` texels a side, origin
    /// (-20037508.342789244, 20037508.342789244), texel size 2 x 20037508.342789244 /
    /// (tile_size x 2^max_zoom). Level k is zoom `max_zoom - k`. Panics where the size overflows
    /// 64 bits (`max_zoom` past 50 at 256-texel tiles) or `tile_size` is 0.
    pub fn web_mercator_quad(max_zoom: u32, tile_size: u64) -> Georef {
        let edge = tile_size.checked_shl(max_zoom).filter(|&e| e > 0 && e >> max_zoom == tile_size);
        let edge = edge.expect("WebMercatorQuad's size fits 64 bits and the tile size is at least 1");
        let px = 2.0 * WEB_MERCATOR_HALF / edge as f64;
        let transform = GeoTransform([-WEB_MERCATOR_HALF, px, 0.0, WEB_MERCATOR_HALF, 0.0, -px]);
        Georef { crs: Crs::web_mercator(), transform, size: [edge, edge] }
    }

    /// The CRS.
    pub fn crs(&self) -> &Crs {
        &self.crs
    }

    /// Level 0's geotransform (GDAL's order, for level 0's pixel / line).
    pub fn geotransform(&self) -> GeoTransform {
        self.transform
    }

    /// Level 0's size, texels.
    pub fn size(&self) -> [u64; 2] {
        self.size
    }

    /// What `cliptex info --json` prints of it.
    pub fn summary(&self) -> GeorefSummary {
        GeorefSummary {
            epsg: self.crs.epsg_code(),
            crs: self.crs.definition().to_string(),
            geotransform: self.transform,
        }
    }

    /// Level `k`'s size: [`crate::tile::level_size`]'s rule (each edge `>> k`, at least 1),
    /// written out here because the ground floor's modules name none of each other
    /// (docs/ARCHITECTURE.md §12); a test holds the two equal.
    pub fn level_size(&self, k: u32) -> [u64; 2] {
        self.size.map(|e| (e >> k.min(63)).max(1))
    }

    /// Level `k`'s geotransform, GDAL's order for level k's own pixel / line (its line 0 the
    /// top edge of its top row): level 0's with scale and rotation terms times 2^k and the
    /// origin moved south by the level-0 rows the halvings dropped (the module's doc).
    pub fn level_transform(&self, k: u32) -> GeoTransform {
        let g = &self.transform.0;
        let f = (k.min(1023) as f64).exp2();
        let dropped = self.size[1] as f64 - self.level_size(k)[1] as f64 * f;
        GeoTransform([g[0] + dropped * g[2], g[1] * f, g[2] * f, g[3] + dropped * g[5], g[4] * f, g[5] * f])
    }

    /// Level `k`'s texel size in map units, `[east, north]` (the lengths of a texel's sides).
    pub fn texel_size(&self, k: u32) -> [f64; 2] {
        let g = self.level_transform(k).0;
        [g[1].hypot(g[4]), g[2].hypot(g[5])]
    }

    /// Map `[x, y]` of continuous texel `[s, t]` of level `k`; refused outside the level
    /// (s in [0, width], t in [0, height]).
    pub fn texel_to_map(&self, k: u32, [s, t]: [f64; 2]) -> Result<[f64; 2], GeorefError> {
        let size = self.level_size(k);
        if !(0.0..=size[0] as f64).contains(&s) || !(0.0..=size[1] as f64).contains(&t) {
            return Err(GeorefError::OutsideTexture { level: k, s, t, size });
        }
        Ok(self.texel_to_map_unchecked(k, [s, t]))
    }

    /// [`Georef::texel_to_map`] without the check that the texel is in the level.
    #[inline]
    pub fn texel_to_map_unchecked(&self, k: u32, [s, t]: [f64; 2]) -> [f64; 2] {
        let h = self.level_size(k)[1] as f64;
        self.level_transform(k).apply([s, h - t])
    }

    /// Continuous texel `[s, t]` of level `k` at map `[x, y]`, whether in the level or not.
    #[inline]
    pub fn map_to_texel_unchecked(&self, k: u32, xy: [f64; 2]) -> [f64; 2] {
        let h = self.level_size(k)[1] as f64;
        let [p, l] = self.level_transform(k).invert(xy);
        [p, h - l]
    }

    /// Continuous texel `[s, t]` of level `k` at map `[x, y]`; refused outside the level.
    pub fn map_to_texel(&self, k: u32, xy: [f64; 2]) -> Result<[f64; 2], GeorefError> {
        let [s, t] = self.map_to_texel_unchecked(k, xy);
        self.inside(k, [s, t])
    }

    /// WGS 84 `[longitude, latitude]` (degrees) of continuous texel `[s, t]` of level `k`.
    pub fn texel_to_lonlat(&self, k: u32, st: [f64; 2]) -> Result<[f64; 2], GeorefError> {
        self.crs.to_lonlat(self.texel_to_map(k, st)?)
    }

    /// Continuous texel `[s, t]` of level `k` at WGS 84 `[longitude, latitude]` (degrees);
    /// refused outside the projection's domain or the level. A texture that spans 360 degrees
    /// of longitude ([`Georef::is_global_in_longitude`]) takes a longitude 360 degrees away where
    /// the one given falls outside it.
    pub fn lonlat_to_texel(&self, k: u32, [lon, lat]: [f64; 2]) -> Result<[f64; 2], GeorefError> {
        let st = self.map_to_texel_unchecked(k, self.crs.from_lonlat([lon, lat])?);
        if self.inside(k, st).is_err() && self.is_global_in_longitude() {
            for turn in [-360.0, 360.0] {
                if let Ok(xy) = self.crs.from_lonlat([lon + turn, lat]) {
                    if let Ok(other) = self.inside(k, self.map_to_texel_unchecked(k, xy)) {
                        return Ok(other);
                    }
                }
            }
        }
        self.inside(k, st)
    }

    fn inside(&self, k: u32, [s, t]: [f64; 2]) -> Result<[f64; 2], GeorefError> {
        let size = self.level_size(k);
        if (0.0..=size[0] as f64).contains(&s) && (0.0..=size[1] as f64).contains(&t) {
            Ok([s, t])
        } else {
            Err(GeorefError::OutsideTexture { level: k, s, t, size })
        }
    }

    /// Level 0's four corners in map coordinates: south-west, south-east, north-east,
    /// north-west.
    pub fn corners(&self) -> [[f64; 2]; 4] {
        let [w, h] = [self.size[0] as f64, self.size[1] as f64];
        [[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]].map(|st| self.texel_to_map_unchecked(0, st))
    }

    /// The map bounds `[min x, min y, max x, max y]` of level 0's corners.
    pub fn bounds(&self) -> [f64; 4] {
        let c = self.corners();
        let (xs, ys) = (c.map(|p| p[0]), c.map(|p| p[1]));
        let min = |v: [f64; 4]| v.into_iter().fold(f64::INFINITY, f64::min);
        let max = |v: [f64; 4]| v.into_iter().fold(f64::NEG_INFINITY, f64::max);
        [min(xs), min(ys), max(xs), max(ys)]
    }

    /// The WGS 84 bounds `[west, south, east, north]` (degrees) of level 0's edges, each edge
    /// taken at 65 points (a projected texture's edges curve in longitude / latitude).
    pub fn lonlat_bounds(&self) -> Result<[f64; 4], GeorefError> {
        let [w, h] = [self.size[0] as f64, self.size[1] as f64];
        let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
        for i in 0..=64 {
            let f = i as f64 / 64.0;
            for st in [[f * w, 0.0], [f * w, h], [0.0, f * h], [w, f * h]] {
                let [lon, lat] = self.crs.to_lonlat(self.texel_to_map_unchecked(0, st))?;
                b = [b[0].min(lon), b[1].min(lat), b[2].max(lon), b[3].max(lat)];
            }
        }
        Ok(b)
    }

    /// Whether the texture spans 360 degrees of longitude, east to west, unrotated: a global
    /// geographic texture (width x texel size = 360 degrees) or a Web Mercator one (2 x
    /// 20037508.342789244 m), to within a millionth of a texel. A window of such a texture may
    /// wrap across the antimeridian.
    pub fn is_global_in_longitude(&self) -> bool {
        let g = &self.transform.0;
        if g[2] != 0.0 || g[4] != 0.0 {
            return false;
        }
        let span = if self.crs.is_web_mercator() {
            2.0 * WEB_MERCATOR_HALF
        } else if self.crs.is_geographic() {
            360.0
        } else {
            return false;
        };
        let width = self.size[0] as f64 * g[1].abs();
        (width - span).abs() <= 1e-6 * g[1].abs()
    }
}
