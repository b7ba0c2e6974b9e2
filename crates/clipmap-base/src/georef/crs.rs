//! A coordinate reference system ([`Crs`]): its EPSG code where known, its definition, and the
//! conversion between its map coordinates and longitude / latitude.
//!
//! Web Mercator (EPSG:3857, spherical, R = 6378137 m) and WGS 84 longitude / latitude
//! (EPSG:4326) convert in closed form. Every other CRS converts through `proj4rs`, a pure-Rust
//! port of PROJ.4 (no C library to find, a few seconds of build): its extended transverse
//! Mercator is PROJ's own algorithm for UTM, and its datum shifts follow the definition's
//! `+towgs84`. An EPSG code becomes a definition through `crs-definitions`, the table of PROJ
//! strings `proj4rs` itself offers as its EPSG lookup (every EPSG code of the EPSG registry's
//! export, national grids included), rather than UTM strings built here, which would cover UTM
//! zones alone. Longitude and latitude are WGS 84 degrees.

use super::GeorefError;
use std::sync::Arc;

/// Earth's radius of the spherical Web Mercator, metres.
pub const WEB_MERCATOR_RADIUS: f64 = 6_378_137.0;

/// Half the extent of Web Mercator's square world, metres (pi x [`WEB_MERCATOR_RADIUS`]).
pub const WEB_MERCATOR_HALF: f64 = 20_037_508.342_789_244;

/// The latitude at the north and south edges of Web Mercator's square world, degrees
/// (atan(sinh(pi))): points beyond it are outside the projection's domain.
pub const WEB_MERCATOR_MAX_LAT: f64 = 85.051_128_779_806_59;

/// The WGS 84 definition longitude / latitude are given in.
const WGS84: &str = "+proj=longlat +datum=WGS84 +no_defs";

/// Web Mercator's definition, as PROJ gives it for EPSG:3857.
const WEB_MERCATOR: &str =
    "+proj=merc +a=6378137 +b=6378137 +lat_ts=0 +lon_0=0 +x_0=0 +y_0=0 +k=1 +units=m +nadgrids=@null +wktext +no_defs";

/// How a CRS's map coordinates become longitude / latitude.
#[derive(Clone)]
enum Kind {
    /// WGS 84 longitude / latitude: map x is longitude, y latitude, in degrees.
    Geographic,
    /// Spherical Web Mercator, closed form.
    WebMercator,
    /// Through `proj4rs`: the CRS, and WGS 84 longitude / latitude.
    Proj { crs: Arc<proj4rs::Proj>, wgs84: Arc<proj4rs::Proj> },
    /// A CRS without a definition known here: map coordinates only.
    Unknown,
}

/// A coordinate reference system: an EPSG code where known and a definition (a PROJ string, or
/// the words a file gives for a CRS without one known here).
#[derive(Clone)]
pub struct Crs {
    epsg: Option<u32>,
    definition: String,
    kind: Kind,
}

impl std::fmt::Debug for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Crs").field("epsg", &self.epsg).field("definition", &self.definition).finish()
    }
}

impl PartialEq for Crs {
    fn eq(&self, other: &Crs) -> bool {
        self.epsg == other.epsg && self.definition == other.definition
    }
}

impl Crs {
    /// WGS 84 longitude / latitude (EPSG:4326), map x the longitude.
    pub fn wgs84() -> Crs {
        Crs { epsg: Some(4326), definition: WGS84.into(), kind: Kind::Geographic }
    }

    /// Web Mercator (EPSG:3857).
    pub fn web_mercator() -> Crs {
        Crs { epsg: Some(3857), definition: WEB_MERCATOR.into(), kind: Kind::WebMercator }
    }

    /// The CRS of EPSG code `code`: 4326 and 3857 (and its old aliases 3785 and 900913) in
    /// closed form, every other code through its PROJ definition. A code without a definition
    /// known here is refused ([`Crs::unknown`] keeps map coordinates only).
    pub fn epsg(code: u32) -> Result<Crs, GeorefError> {
        match code {
            4326 => return Ok(Crs::wgs84()),
            3857 | 3785 | 900913 => return Ok(Crs { epsg: Some(code), ..Crs::web_mercator() }),
            _ => {}
        }
        let def =
            u16::try_from(code).ok().and_then(crs_definitions::from_code).ok_or(GeorefError::UnknownEpsg(code))?;
        let mut crs = Crs::from_proj_string(def.proj4)?;
        crs.epsg = Some(code);
        Ok(crs)
    }

    /// The CRS of a PROJ string (`+proj=utm +zone=33 +datum=WGS84`).
    pub fn from_proj_string(definition: &str) -> Result<Crs, GeorefError> {
        let bad = |e: proj4rs::errors::Error| GeorefError::Definition {
            definition: definition.to_string(),
            problem: e.to_string(),
        };
        let crs = proj4rs::Proj::from_proj_string(definition).map_err(bad)?;
        let wgs84 = proj4rs::Proj::from_proj_string(WGS84).map_err(bad)?;
        Ok(Crs {
            epsg: None,
            definition: definition.trim().to_string(),
            kind: Kind::Proj { crs: Arc::new(crs), wgs84: Arc::new(wgs84) },
        })
    }

    /// A CRS known by `description` alone (a file's citation of a user-defined CRS): texels
    /// convert to its map coordinates, and conversions to longitude / latitude are refused.
    pub fn unknown(epsg: Option<u32>, description: &str) -> Crs {
        Crs { epsg, definition: description.to_string(), kind: Kind::Unknown }
    }

    /// The EPSG code, where known.
    pub fn epsg_code(&self) -> Option<u32> {
        self.epsg
    }

    /// The definition: a PROJ string, or a description of a CRS without one.
    pub fn definition(&self) -> &str {
        &self.definition
    }

    /// `EPSG:3857`, or the definition where no code is known.
    pub fn name(&self) -> String {
        match self.epsg {
            Some(c) => format!("EPSG:{c}"),
            None => self.definition.clone(),
        }
    }

    /// Whether map coordinates are longitude / latitude degrees (WGS 84 in closed form, or a
    /// geographic PROJ definition).
    pub fn is_geographic(&self) -> bool {
        match &self.kind {
            Kind::Geographic => true,
            Kind::Proj { crs, .. } => crs.is_latlong(),
            _ => false,
        }
    }

    /// Whether this is spherical Web Mercator in closed form.
    pub fn is_web_mercator(&self) -> bool {
        matches!(self.kind, Kind::WebMercator)
    }

    /// Map coordinates `[x, y]` as WGS 84 `[longitude, latitude]`, degrees. Refused: points
    /// outside the projection's domain (Web Mercator's |y| beyond [`WEB_MERCATOR_HALF`],
    /// latitudes beyond 90 degrees), and a CRS without a known definition.
    pub fn to_lonlat(&self, [x, y]: [f64; 2]) -> Result<[f64; 2], GeorefError> {
        finite("map coordinates", [x, y])?;
        match &self.kind {
            Kind::Geographic => {
                if y.abs() > 90.0 {
                    return Err(outside(format!("latitude {y}"), "latitudes in [-90, 90] degrees"));
                }
                Ok([x, y])
            }
            Kind::WebMercator => {
                if y.abs() > WEB_MERCATOR_HALF {
                    return Err(outside(format!("map y {y} m"), WEB_MERCATOR_DOMAIN_Y));
                }
                // In units of the half extent (pi R): the edges and the centre exact.
                let lon = 180.0 * (x / WEB_MERCATOR_HALF);
                let lat = (std::f64::consts::PI * (y / WEB_MERCATOR_HALF)).sinh().atan().to_degrees();
                Ok([lon, lat])
            }
            Kind::Proj { crs, wgs84 } => {
                let mut p = if crs.is_latlong() { (x.to_radians(), y.to_radians(), 0.0) } else { (x, y, 0.0) };
                proj4rs::transform::transform(crs, wgs84, &mut p).map_err(|e| {
                    outside(format!("map point ({x}, {y})"), &format!("the domain of {} ({e})", self.definition))
                })?;
                Ok([p.0.to_degrees(), p.1.to_degrees()])
            }
            Kind::Unknown => Err(GeorefError::NoDefinition { crs: self.name() }),
        }
    }

    /// WGS 84 `[longitude, latitude]` (degrees) as map coordinates `[x, y]`. Refused: latitudes
    /// beyond 90 degrees (beyond [`WEB_MERCATOR_MAX_LAT`] in Web Mercator), longitudes beyond
    /// 360 degrees, points the projection cannot take, and a CRS without a known definition.
    pub fn from_lonlat(&self, [lon, lat]: [f64; 2]) -> Result<[f64; 2], GeorefError> {
        finite("longitude / latitude", [lon, lat])?;
        if lon.abs() > 360.0 {
            return Err(outside(format!("longitude {lon}"), "longitudes in [-360, 360] degrees"));
        }
        match &self.kind {
            Kind::Geographic => {
                if lat.abs() > 90.0 {
                    return Err(outside(format!("latitude {lat}"), "latitudes in [-90, 90] degrees"));
                }
                Ok([lon, lat])
            }
            Kind::WebMercator => {
                if lat.abs() > WEB_MERCATOR_MAX_LAT {
                    return Err(outside(format!("latitude {lat}"), WEB_MERCATOR_DOMAIN_LAT));
                }
                let x = WEB_MERCATOR_HALF * (lon / 180.0);
                // R asinh(tan(lat)) = R ln(tan(pi/4 + lat/2)), without the loss near the equator.
                let y = WEB_MERCATOR_HALF * (lat.to_radians().tan().asinh() / std::f64::consts::PI);
                Ok([x, y.clamp(-WEB_MERCATOR_HALF, WEB_MERCATOR_HALF)])
            }
            Kind::Proj { crs, wgs84 } => {
                if lat.abs() > 90.0 {
                    return Err(outside(format!("latitude {lat}"), "latitudes in [-90, 90] degrees"));
                }
                let mut p = (lon.to_radians(), lat.to_radians(), 0.0);
                proj4rs::transform::transform(wgs84, crs, &mut p).map_err(|e| {
                    outside(
                        format!("longitude {lon}, latitude {lat}"),
                        &format!("the domain of {} ({e})", self.definition),
                    )
                })?;
                if crs.is_latlong() {
                    p = (p.0.to_degrees(), p.1.to_degrees(), p.2);
                }
                finite("the projected point", [p.0, p.1]).map_err(|_| {
                    outside(format!("longitude {lon}, latitude {lat}"), &format!("the domain of {}", self.definition))
                })?;
                Ok([p.0, p.1])
            }
            Kind::Unknown => Err(GeorefError::NoDefinition { crs: self.name() }),
        }
    }
}

/// Web Mercator's domain in latitude, in words.
const WEB_MERCATOR_DOMAIN_LAT: &str =
    "Web Mercator's domain: latitudes in [-85.05112877980659, 85.05112877980659] degrees";

/// Web Mercator's domain in map y, in words.
const WEB_MERCATOR_DOMAIN_Y: &str =
    "Web Mercator's domain: map y in [-20037508.342789244, 20037508.342789244] m (latitudes within 85.05112877980659 degrees)";

fn outside(what: String, domain: &str) -> GeorefError {
    GeorefError::OutsideDomain { what, domain: domain.to_string() }
}

fn finite(what: &str, [a, b]: [f64; 2]) -> Result<(), GeorefError> {
    if a.is_finite() && b.is_finite() {
        Ok(())
    } else {
        Err(GeorefError::OutsideDomain { what: format!("{what} ({a}, {b})"), domain: "finite numbers".into() })
    }
}
