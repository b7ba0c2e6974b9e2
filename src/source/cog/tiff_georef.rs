//! The georeferencing of any local TIFF, striped or tiled: the GeoTIFF tags of its first image
//! read as a COG's are ([`super::geokeys`]), for inputs that are not served as they are
//! (`clipprep --input`, whose prepared pyramid records its input's georeferencing; docs/GEOREF.md).

use super::geokeys::{georef_of, GeoKeysError};
use super::structure::{read_ifds, Head, Layout};
use crate::georef::Georef;
use crate::source::range;
use std::cell::RefCell;
use std::path::Path;

/// The georeferencing of the TIFF `path`'s first image: `Ok(None)` when it has no transform tag
/// (or the file is no TIFF); an error names the file, where (the header, the IFD, the tag) and
/// what is wrong.
pub fn tiff_georef(path: &Path) -> Result<Option<Georef>, GeoKeysError> {
    let err = |at: &str, problem: String| GeoKeysError { path: path.to_path_buf(), at: at.into(), problem };
    let (bytes, prefix) = range::open_local(path, super::PREFIX_BYTES).map_err(|e| match e {
        range::OpenError::Io(e) => err("opening it", e.to_string()),
        range::OpenError::Remote(problem) => err("opening it", problem),
    })?;
    let got = prefix.len();
    let layout = match &prefix[..4.min(got)] {
        b"II*\0" => Layout { little: true, big: false },
        b"MM\0*" => Layout { little: false, big: false },
        b"II+\0" => Layout { little: true, big: true },
        b"MM\0+" => Layout { little: false, big: true },
        _ => return Ok(None),
    };
    if layout.big && got < 16 || !layout.big && got < 8 {
        return Err(err("the header", format!("the file has only {got} bytes")));
    }
    let first = if layout.big { layout.u64(&prefix[8..]) } else { layout.u32(&prefix[4..]) as u64 };
    let head = Head { bytes: &*bytes, prefix: &prefix, failed: RefCell::new(None), windows: RefCell::new(Vec::new()) };
    let images = read_ifds(&head, layout, first).map_err(|(at, problem)| err(&at, problem))?;
    georef_of(path, &head, layout, &images[0])
}
