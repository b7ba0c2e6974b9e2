//! The errors of preparation, each saying what was found, what was expected and how to fix it.
//!
//! Every variant knows whether the input was at fault (exit code 1) or the tool could not run
//! (exit code 2); the binary maps them to exit codes and adds nothing but the program name.

use std::io;
use std::path::PathBuf;
use thiserror::Error;

/// Something that stopped a preparation.
#[derive(Debug, Error)]
pub enum PrepError {
    /// A size that must be a power of two is not.
    #[error("{what} is {found}, which is not a power of two; expected a power of two such as {next}{hint}")]
    NotPowerOfTwo {
        /// What the size is (e.g. "the image width of in.png").
        what: String,
        /// The size found.
        found: u64,
        /// The next power of two.
        next: u64,
        /// How to fix it.
        hint: &'static str,
    },
    /// The requested geometry cannot be laid out as a clip texture.
    #[error("{0}")]
    Geometry(String),
    /// The input image could not be opened.
    #[error("cannot open the input image {path}: {source}; check the path and its permissions")]
    ImageOpen {
        /// The image.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
    /// The input image could not be decoded (truncated, corrupt, or not an image).
    #[error("cannot decode the input image {path}: {message}; the file is truncated, corrupt or not a PNG, JPEG or TIFF image")]
    ImageDecode {
        /// The image.
        path: PathBuf,
        /// The decoder's words.
        message: String,
    },
    /// The image's pixel layout is not one this tool converts.
    #[error("the input image {path} has pixel format {found}; expected 8- or 16-bit grey, grey+alpha, RGB or RGBA; convert it first (e.g. to an 8-bit RGB TIFF)")]
    UnsupportedPixels {
        /// The image.
        path: PathBuf,
        /// The format found.
        found: String,
    },
    /// The image's samples are deeper than the texel format: writing them would drop bits.
    #[error("the input image {path} has {bits}-bit {layout} samples, deeper than the texel format {format}; expected samples of at most {allowed} bits for {format}; pass --format {wider} to keep all {bits} bits, or --reduce-depth to round them to {format}")]
    DeeperThanFormat {
        /// The image.
        path: PathBuf,
        /// Bits per sample found.
        bits: u32,
        /// Its pixel layout (`grey`, `RGB`, ...).
        layout: &'static str,
        /// The texel format asked for.
        format: String,
        /// The most bits per sample that format takes without a reduction.
        allowed: u32,
        /// The 16-bit format with the same components.
        wider: String,
    },
    /// The image is too large to decode into memory and cannot be streamed.
    #[error("the input image {path} is {width}x{height} ({mib} MiB decoded), over the in-memory limit of {limit_mib} MiB; raise --max-memory to at least {mib} (MiB), or convert it to a TIFF that is streamed: 8- or 16-bit grey, grey+alpha, RGB or RGBA samples, interleaved (chunky), in tiles or strips of at most {} rows", (limit_mib << 20) / (16 * (*width).max(1)))]
    ImageTooLarge {
        /// The image.
        path: PathBuf,
        /// Width in pixels.
        width: u64,
        /// Height in pixels.
        height: u64,
        /// Decoded size in MiB.
        mib: u64,
        /// The limit in MiB.
        limit_mib: u64,
    },
    /// The output directory already holds a prepared clip texture.
    #[error("the output directory {dir} already holds a clip texture ({ct}); pass --force to replace it, or choose another --out")]
    OutputHoldsPyramid {
        /// The directory.
        dir: PathBuf,
        /// The `.ct` found in it.
        ct: PathBuf,
    },
    /// The output path exists and is not an empty directory or a prepared clip texture.
    #[error("the output path {dir} exists and is not an empty directory or a prepared clip texture; refusing to replace it even with --force; choose another --out")]
    OutputOccupied {
        /// The path.
        dir: PathBuf,
    },
    /// The disk filled up.
    #[error("no space left on the device while writing {path} ({needed_mib} MiB needed in all); free space or choose another --out")]
    DiskFull {
        /// The file being written.
        path: PathBuf,
        /// The whole output size, in MiB.
        needed_mib: u64,
    },
    /// Any other failure to write the output.
    #[error("cannot write {path}: {source}; check that the directory is writable")]
    Write {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
    /// An elevation input that is not one this tool reads as heights.
    #[error("cannot read the heights of {path}: {message}")]
    HeightInput {
        /// The input.
        path: PathBuf,
        /// What was found, what was expected and how to fix it.
        message: String,
    },
    /// A pixel of an elevation input that cannot be stored in the output's height format.
    #[error("the input {path}, pixel ({x}, {y}) (column, row from the top): {message}")]
    HeightPixel {
        /// The input.
        path: PathBuf,
        /// Column.
        x: u64,
        /// Row, from the top of the image.
        y: u64,
        /// What was found, what was expected and how to fix it.
        message: String,
    },
    /// The run was interrupted (Ctrl-C or SIGTERM); nothing was left at the output path.
    #[error("interrupted; the partial output was removed and {dir} was left as it was")]
    Interrupted {
        /// The output directory.
        dir: PathBuf,
    },
}

impl PrepError {
    /// True when the input (arguments, image) is at fault rather than the environment.
    pub(crate) fn is_bad_input(&self) -> bool {
        matches!(
            self,
            PrepError::NotPowerOfTwo { .. }
                | PrepError::Geometry(_)
                | PrepError::ImageOpen { .. }
                | PrepError::ImageDecode { .. }
                | PrepError::UnsupportedPixels { .. }
                | PrepError::DeeperThanFormat { .. }
                | PrepError::ImageTooLarge { .. }
                | PrepError::OutputHoldsPyramid { .. }
                | PrepError::OutputOccupied { .. }
                | PrepError::HeightInput { .. }
                | PrepError::HeightPixel { .. }
        )
    }

    /// The documented exit code: 1 for bad input, 2 when the tool could not run.
    pub fn exit_code(&self) -> i32 {
        if self.is_bad_input() {
            1
        } else {
            2
        }
    }

    /// Wraps an I/O error on `path`, recognising a full disk.
    pub fn write(path: impl Into<PathBuf>, source: io::Error, needed_bytes: u64) -> PrepError {
        let path = path.into();
        if is_disk_full(&source) {
            PrepError::DiskFull { path, needed_mib: needed_bytes.div_ceil(1 << 20) }
        } else {
            PrepError::Write { path, source }
        }
    }
}

/// ENOSPC (28 on Linux, the BSDs and macOS) or a quota exceeded (EDQUOT: 122 on Linux, 69 on
/// the BSDs and macOS).
fn is_disk_full(e: &io::Error) -> bool {
    match e.raw_os_error() {
        Some(28) => true,
        Some(122) => cfg!(target_os = "linux"),
        Some(69) => cfg!(any(target_os = "macos", target_os = "freebsd")),
        _ => false,
    }
}

/// The next power of two at or above `n` (1 for 0).
pub fn next_power_of_two(n: u64) -> u64 {
    n.max(1).next_power_of_two()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_disk_is_named_as_such_and_is_not_bad_input() {
        let e = PrepError::write("out/L00/r000.c000.raw", io::Error::from_raw_os_error(28), 3 << 20);
        assert!(matches!(e, PrepError::DiskFull { needed_mib: 3, .. }), "{e:?}");
        assert!(e.to_string().contains("no space left") && e.to_string().contains("free space"), "{e}");
        assert_eq!(e.exit_code(), 2);
        let other = PrepError::write("x", io::Error::from_raw_os_error(13), 0);
        assert!(matches!(other, PrepError::Write { .. }));
    }
}
