//! Where a COG is on the Earth: its GeoTIFF tags read into a [`Georef`] (docs/GEOREF.md).
//!
//! The transform comes from ModelTransformationTag (34264), or from ModelTiepointTag (33922)
//! and ModelPixelScaleTag (33550), as GDAL reads them; GTRasterTypeGeoKey (1025) PixelIsPoint
//! moves it half a pixel north-west, as GDAL does (its default, `GTIFF_POINT_GEO_IGNORE=NO`).
//! The CRS comes from the GeoKeyDirectoryTag (34735): ProjectedCSTypeGeoKey (3072), else
//! GeographicTypeGeoKey (2048), with the citations of GeoAsciiParamsTag (34737) naming a
//! user-defined CRS (32767), which converts to map coordinates only. A file with no transform
//! tag has no georeferencing (`None`): nothing is invented. Every number is checked: counts,
//! finite values, non-zero scales; a refusal names the IFD and the tag.

use super::structure::{ascii, doubles, scalar, values, Head, Image, Layout};
use crate::georef::{Crs, GeoTransform, Georef, GeorefError};
use std::path::PathBuf;
use thiserror::Error;

/// The most GeoKeys read (GDAL writes about ten).
const MAX_KEYS: u64 = 1024;

/// The most tiepoints read (a georeferencing by ground control points has many).
const MAX_TIEPOINTS: u64 = 4096;

/// The most bytes of GeoAsciiParamsTag read.
const MAX_ASCII: u64 = 64 << 10;

/// GeoKey values that say "user-defined" (no EPSG code).
const USER_DEFINED: u64 = 32767;

/// Why a COG's georeferencing cannot be read: the file, where (IFD, tag, key), what is wrong.
/// The file is still served; only its georeferencing is refused.
#[derive(Clone, Debug, Error, PartialEq)]
#[error("{path}: {at}: {problem}", path = path.display())]
pub struct GeoKeysError {
    /// The file.
    pub path: PathBuf,
    /// Where: the IFD and the tag, or the GeoKey.
    pub at: String,
    /// What was found and what was expected.
    pub problem: String,
}

/// The georeferencing of IFD `image` (the full-resolution image), `None` when it has no
/// transform tag.
pub(super) fn georef_of(
    path: &std::path::Path,
    file: &Head,
    layout: Layout,
    image: &Image,
) -> Result<Option<Georef>, GeoKeysError> {
    let err = |(at, problem): (String, String)| GeoKeysError { path: path.to_path_buf(), at, problem };
    let ifd = image.ifd;
    let tag = |name: &str| format!("IFD {ifd} tag {name}");
    let Some(mut gt) = transform_of(file, layout, image).map_err(err)? else { return Ok(None) };
    let keys = GeoKeys::read(file, layout, image).map_err(err)?;
    if keys.short(1025).map_err(err)? == Some(2) {
        // PixelIsPoint: the tiepoint is a pixel's centre.
        gt[0] -= 0.5 * gt[1] + 0.5 * gt[2];
        gt[3] -= 0.5 * gt[4] + 0.5 * gt[5];
    }
    let crs = keys.crs().map_err(err)?;
    let size = |t: u16, name: &str| {
        scalar(file, layout, image, t, name).map_err(err)?.ok_or_else(|| err((tag(name), "missing".into())))
    };
    let size = [size(256, "ImageWidth (256)")?, size(257, "ImageLength (257)")?];
    Georef::new(crs, GeoTransform(gt), size).map(Some).map_err(|e| {
        err((
            tag("ModelPixelScaleTag (33550) / ModelTiepointTag (33922) / ModelTransformationTag (34264)"),
            e.to_string(),
        ))
    })
}

/// GDAL's geotransform of the transform tags, before PixelIsPoint; `None` without them.
fn transform_of(file: &Head, layout: Layout, image: &Image) -> Result<Option<[f64; 6]>, (String, String)> {
    let at = |name: &str| format!("IFD {} tag {name}", image.ifd);
    const MT: &str = "ModelTransformationTag (34264)";
    const TIE: &str = "ModelTiepointTag (33922)";
    const SCALE: &str = "ModelPixelScaleTag (33550)";
    if let Some(m) = doubles(file, layout, image, 34264, MT, 16)? {
        if m.len() != 16 {
            return Err((at(MT), format!("{} values, expected 16 (a 4 x 4 matrix)", m.len())));
        }
        return Ok(Some([m[3], m[0], m[1], m[7], m[4], m[5]]));
    }
    let tie = doubles(file, layout, image, 33922, TIE, 6 * MAX_TIEPOINTS)?;
    let scale = doubles(file, layout, image, 33550, SCALE, 3)?;
    match (tie, scale) {
        (None, None) => Ok(None),
        (None, Some(_)) => Err((at(SCALE), format!("present without {TIE}: expected both, or {MT}"))),
        (Some(t), _) if t.len() % 6 != 0 => {
            Err((at(TIE), format!("{} values, expected a multiple of 6 (I, J, K, X, Y, Z each)", t.len())))
        }
        (Some(t), None) => Err((
            at(TIE),
            format!(
                "{} tiepoints without {SCALE}: a georeferencing by ground control points, which is not read: \
                 warp the image to a grid (gdalwarp) or give it a transform (gdal_translate -a_ullr)",
                t.len() / 6
            ),
        )),
        (Some(_), Some(s)) if s.len() < 2 => Err((at(SCALE), format!("{} values, expected 3 (x, y, z)", s.len()))),
        (Some(_), Some(s)) if s[0] == 0.0 || s[1] == 0.0 => {
            Err((at(SCALE), format!("pixel scale ({}, {}), expected non-zero sizes of a pixel in x and y", s[0], s[1])))
        }
        (Some(t), Some(s)) => Ok(Some([t[3] - t[0] * s[0], s[0], 0.0, t[4] + t[1] * s[1], 0.0, -s[1]])),
    }
}

/// The GeoKeyDirectoryTag's keys and the ASCII parameters they point into.
struct GeoKeys {
    /// (key, location tag, count, value or offset), in file order.
    keys: Vec<[u64; 4]>,
    ascii: Option<String>,
    ifd: usize,
}

impl GeoKeys {
    /// The keys of `image` (none without a GeoKeyDirectoryTag).
    fn read(file: &Head, layout: Layout, image: &Image) -> Result<GeoKeys, (String, String)> {
        const DIR: &str = "GeoKeyDirectoryTag (34735)";
        let at = format!("IFD {} tag {DIR}", image.ifd);
        let Some(dir) = values(file, layout, image, 34735, DIR, 4 + 4 * MAX_KEYS)? else {
            return Ok(GeoKeys { keys: Vec::new(), ascii: None, ifd: image.ifd });
        };
        if dir.len() < 4 || dir[0] != 1 {
            return Err((at, format!("header {:?}, expected version 1 and a key count", &dir[..dir.len().min(4)])));
        }
        let n = dir[3] as usize;
        if dir.len() < 4 + 4 * n {
            return Err((at, format!("{} keys announced in {} values, expected {} values", n, dir.len(), 4 + 4 * n)));
        }
        let keys = dir[4..4 + 4 * n].chunks_exact(4).map(|k| [k[0], k[1], k[2], k[3]]).collect();
        let ascii = ascii(file, layout, image, 34737, "GeoAsciiParamsTag (34737)", MAX_ASCII)?;
        Ok(GeoKeys { keys, ascii, ifd: image.ifd })
    }

    fn find(&self, key: u64) -> Option<[u64; 4]> {
        self.keys.iter().find(|k| k[0] == key).copied()
    }

    /// The SHORT value of `key` (stored in the directory itself).
    fn short(&self, key: u64) -> Result<Option<u64>, (String, String)> {
        let Some([_, loc, count, value]) = self.find(key) else { return Ok(None) };
        if loc != 0 || count != 1 {
            return Err((
                format!("IFD {} GeoKey {key}", self.ifd),
                format!(
                    "stored in tag {loc} with count {count}, expected a SHORT in the directory (location 0, count 1)"
                ),
            ));
        }
        Ok(Some(value))
    }

    /// The ASCII value of `key` (in GeoAsciiParamsTag, `|`-terminated), if any.
    fn text(&self, key: u64) -> Option<String> {
        let [_, loc, count, offset] = self.find(key)?;
        let ascii = self.ascii.as_deref().filter(|_| loc == 34737)?;
        let text = ascii.get(offset as usize..(offset + count) as usize)?;
        // GDAL packs several fields into one citation, `|` between them.
        Some(text.trim_end_matches('|').trim().replace('|', "; "))
    }

    /// The CRS: ProjectedCSTypeGeoKey, else GeographicTypeGeoKey; a user-defined or unknown
    /// code keeps map coordinates only, named by its citation.
    fn crs(&self) -> Result<Crs, (String, String)> {
        let citation = || {
            // PCSCitation, GTCitation, GeogCitation, those that say something.
            let said = |t: &String| !t.is_empty() && !["unknown", "unnamed"].contains(&t.to_lowercase().as_str());
            let cited: Vec<String> = [3073, 1026, 2049].into_iter().filter_map(|k| self.text(k).filter(said)).collect();
            match cited.is_empty() {
                false => format!("user-defined ({})", cited.join("; ")),
                true => "user-defined, without a citation".into(),
            }
        };
        let model = self.short(1024)?;
        let projected = self.short(3072)?;
        let geographic = self.short(2048)?;
        let code = match (model, projected, geographic) {
            (Some(2), _, Some(g)) | (_, None, Some(g)) => g,
            (_, Some(p), _) => p,
            (None, None, None) if self.keys.is_empty() => {
                return Ok(Crs::unknown(None, "none given (no GeoKeyDirectoryTag)"))
            }
            _ => return Ok(Crs::unknown(None, &citation())),
        };
        if code == 0 || code >= USER_DEFINED {
            return Ok(Crs::unknown(None, &citation()));
        }
        match Crs::epsg(code as u32) {
            Ok(crs) => Ok(crs),
            Err(GeorefError::UnknownEpsg(c)) => Ok(Crs::unknown(Some(c), &format!("EPSG:{c} ({})", citation()))),
            Err(e) => Err((
                format!("IFD {} GeoKey ProjectedCSTypeGeoKey (3072) / GeographicTypeGeoKey (2048)", self.ifd),
                e.to_string(),
            )),
        }
    }
}
