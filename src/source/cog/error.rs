//! Why a file cannot be served as a COG: [`CogError`], each refusal naming the file, where in it
//! (IFD, tag, byte) and what was found and expected.

use super::MAX_BUILT_TEXELS;
use crate::source::{DescError, SourceError};
use std::io;
use std::path::PathBuf;
use thiserror::Error;

/// Why a file cannot be served as a COG.
#[derive(Debug, Error)]
pub enum CogError {
    /// The file cannot be opened or read.
    #[error("{path}: {source}", path = path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// Not a TIFF.
    #[error("{path}: not a TIFF: it starts with {found}, expected II*\\0 or MM\\0* (TIFF) or II+\\0 or MM\\0+ (BigTIFF)", path = path.display())]
    NotTiff {
        /// The file.
        path: PathBuf,
        /// Its first bytes.
        found: String,
    },
    /// The TIFF structure is damaged.
    #[error("{path}: {at}: {problem}; the file is damaged or truncated: restore it or write it again (gdal_translate -of COG)", path = path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// Where (the header, an IFD, a tag).
        at: String,
        /// What is wrong.
        problem: String,
    },
    /// A layout this source does not serve.
    #[error("{path}: IFD {ifd}: {tag} is {found}: supported: {supported}", path = path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// The IFD (0 the full-resolution image).
        ifd: usize,
        /// The tag, by name and number.
        tag: &'static str,
        /// The value found.
        found: String,
        /// What is served.
        supported: &'static str,
    },
    /// An overview whose samples are not the full-resolution image's.
    #[error("{path}: IFD {ifd} (an overview): {tag} is {found}, expected the full-resolution image's (IFD 0): {expected}; write the overviews from the same bands (gdaladdo, or gdal_translate -of COG)", path = path.display())]
    Overview {
        /// The file.
        path: PathBuf,
        /// The overview's IFD.
        ifd: usize,
        /// The tag that differs, by name and number.
        tag: &'static str,
        /// The overview's value.
        found: String,
        /// The full-resolution image's.
        expected: String,
    },
    /// Coarser levels that would have to be built from too large an image.
    #[error("{path}: {why}; levels {from} to {last} would be built at open from level {base} ({base_size:?} texels), more than {MAX_BUILT_TEXELS} texels: add overviews whose sizes are level 0's halved and rounded down (gdaladdo, or gdal_translate -of COG from a size that halves evenly)", path = path.display())]
    TooLargeToBuild {
        /// The file.
        path: PathBuf,
        /// Why the overviews stop ("IFD 3 (overview 3) is [125, 88] texels, expected [125, 87]", or
        /// "it has no overviews").
        why: String,
        /// The first level to build.
        from: u32,
        /// The last level.
        last: u32,
        /// The level they would be built from.
        base: u32,
        /// Its size.
        base_size: [u64; 2],
    },
    /// A tile of the image the coarser levels are built from could not be read.
    #[error("{path}: building levels {from}.. at open: {source}", path = path.display())]
    Build {
        /// The file.
        path: PathBuf,
        /// The first level built.
        from: u32,
        /// Why.
        #[source]
        source: SourceError,
    },
    /// An internal mask that does not fit its image, or masks in an order this source does not
    /// read.
    #[error("{path}: IFD {ifd} (a mask{of}): {tag} is {found}, expected {expected}", path = path.display(), of = image.map_or(String::new(), |i| format!(" of IFD {i}")))]
    Mask {
        /// The file.
        path: PathBuf,
        /// The mask's IFD.
        ifd: usize,
        /// Its image's IFD, when it has one.
        image: Option<usize>,
        /// The tag, by name and number.
        tag: &'static str,
        /// The value found.
        found: String,
        /// What was expected.
        expected: String,
    },
    /// A remote object cannot be read, or this build cannot read remote objects.
    #[error("{problem}")]
    Remote {
        /// The object.
        path: PathBuf,
        /// What happened, naming the object.
        problem: String,
    },
    /// The levels do not form a texture the engine serves.
    #[error("{path}: the levels cannot be served: {source}", path = path.display())]
    Desc {
        /// The file.
        path: PathBuf,
        /// What is wrong with them.
        #[source]
        source: DescError,
    },
}
