//! Patches as users hand them in: an image file (any format the `image` crate reads here: PNG,
//! JPEG, TIFF; 8 or 16 bits a component) or raw texels, with a small JSON description of where
//! it lies (the sidecar a watched directory takes beside each image, and the body of an ingest
//! request):
//!
//! ```json
//! {"bbox": [x0, y0, x1, y1], "time": 1733011200, "rating": 2.5,
//!  "image": "strip-0042.png"}
//! ```
//!
//! or, for raw texels in the grid's own format, `"raw": {"width": W, "height": H}` instead of
//! `"image"`. Everything is checked before anything is decoded or kept: the description's fields
//! (unknown ones are refused, so a misspelt `ratng` is not silently the default), the image's
//! size from its header (at most `MAX_PATCH_PIXELS` a side, and at most `max_bytes` of texels),
//! then the patch itself ([`Patch::new`]).

use super::{Grid, GrowError, NewPatch, Patch, PatchMeta, WorldBox, MAX_PATCH_PIXELS};
use serde::Deserialize;
use std::io::Cursor;
use thiserror::Error;

/// The description of one patch.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Sidecar {
    /// World box: x0, y0, x1, y1 (min inclusive, max exclusive).
    pub bbox: [f64; 4],
    /// When it was taken (any unit that grows with time); newer wins among equal ratings.
    #[serde(default)]
    pub time: u64,
    /// Quality; the highest wins.
    #[serde(default)]
    pub rating: f64,
    /// The image file, relative to the description's directory.
    #[serde(default)]
    pub image: Option<String>,
    /// Raw texels in the grid's format instead of an image.
    #[serde(default)]
    pub raw: Option<RawSize>,
}

/// The size of raw texels.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct RawSize {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
}

/// Why a patch could not be read.
#[derive(Debug, Error)]
pub enum InputError {
    /// The description is not valid JSON of the expected shape.
    #[error("{where_}: the patch description is not valid: {problem}; expected {{\"bbox\": [x0, y0, x1, y1], \"time\": N, \"rating\": R, \"image\": \"FILE\"}} (or \"raw\": {{\"width\": W, \"height\": H}} instead of \"image\")")]
    Sidecar {
        /// Where the patch came from (its file or description).
        where_: String,
        /// The JSON parser's complaint.
        problem: String,
    },
    /// Both or neither of `image` and `raw`.
    #[error("{where_}: the patch description names {found}; give exactly one of \"image\" (a file) and \"raw\" (texels in the grid's format)")]
    Source {
        /// Where the patch came from (its file or description).
        where_: String,
        /// What the description names: both or neither.
        found: &'static str,
    },
    /// The image's format is not one this build reads.
    #[error(
        "{where_}: the image is not in a format this build reads ({problem}); give PNG, JPEG or TIFF, or raw texels"
    )]
    Format {
        /// Where the patch came from (its file or description).
        where_: String,
        /// The image decoder's complaint.
        problem: String,
    },
    /// The image is too large to take.
    #[error("{where_}: the image is {width}x{height} pixels, {bytes} bytes of texels; the most is {max_side} a side and {max_bytes} bytes")]
    TooLarge {
        /// Where the patch came from (its file or description).
        where_: String,
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
        /// Its bytes of texels.
        bytes: u64,
        /// The most pixels a side.
        max_side: u32,
        /// The most bytes of texels.
        max_bytes: u64,
    },
    /// The image file itself is larger than a patch may be.
    #[error("{where_}: the image file has {bytes} bytes; the most taken is {max_bytes} (--max-patch-bytes)")]
    FileTooLarge {
        /// Where the patch came from (its file or description).
        where_: String,
        /// The file's bytes.
        bytes: u64,
        /// The most taken (`--max-patch-bytes`).
        max_bytes: u64,
    },
    /// The image's bits per component do not fit the grid's.
    #[error("{where_}: the image has {found}; the texture's texels are {expected}: convert the image, or grow a texture of that format")]
    Depth {
        /// Where the patch came from (its file or description).
        where_: String,
        /// The image's bits per component.
        found: String,
        /// The texture's texels.
        expected: String,
    },
    /// The image could not be decoded.
    #[error("{where_}: the image could not be decoded: {problem}")]
    Decode {
        /// Where the patch came from (its file or description).
        where_: String,
        /// The decoder's complaint.
        problem: String,
    },
    /// The patch itself is refused (a patch read here has no id yet: id 0 is not named).
    #[error("{where_}: {}", without_id(.0), where_ = .1)]
    Patch(GrowError, String),
}

/// A refusal's text without "patch 0: " (a patch being read has no id yet; its file names it).
fn without_id(e: &GrowError) -> String {
    let text = e.to_string();
    text.strip_prefix("patch 0: ").map(str::to_string).unwrap_or(text)
}

/// Reads a description (`where_` names it in errors: a file path, or "the request").
pub fn sidecar(text: &[u8], where_: &str) -> Result<Sidecar, InputError> {
    let s: Sidecar = serde_json::from_slice(text)
        .map_err(|e| InputError::Sidecar { where_: where_.to_string(), problem: e.to_string() })?;
    match (&s.image, &s.raw) {
        (Some(_), None) | (None, Some(_)) => Ok(s),
        (Some(_), Some(_)) => Err(InputError::Source { where_: where_.to_string(), found: "both" }),
        (None, None) => Err(InputError::Source { where_: where_.to_string(), found: "neither" }),
    }
}

/// Decodes `bytes` (an image file's content) into texels of `grid`'s format: as many components
/// as a texel has (1 grey, 2 grey and alpha, 3 RGB, 4 RGBA), 8 or 16 bits each as the grid's are.
/// An image of another depth is refused rather than scaled; so is one larger than `max_bytes` of
/// texels, before it is decoded.
pub fn decode_image(
    grid: &Grid,
    bytes: &[u8],
    max_bytes: u64,
    where_: &str,
) -> Result<(u32, u32, Vec<u8>), InputError> {
    let w = || where_.to_string();
    // The JPEG decoder fills what a cut file lacks with grey and reports success: walk it from
    // its SOI to its EOI marker first, as `clipprep` does.
    if crate::prep::jpeg_check::is_jpeg(bytes) {
        crate::prep::jpeg_check::check(bytes).map_err(|e| InputError::Decode {
            where_: w(),
            problem: format!("{e}; the JPEG is truncated or corrupt"),
        })?;
    }
    match decode_with_image(grid, bytes, max_bytes, where_) {
        Err(e @ (InputError::Decode { .. } | InputError::Format { .. })) if is_tiff_bytes(bytes) => {
            decode_tiff_by_cog_reader(grid, bytes, max_bytes, where_).unwrap_or(Err(e))
        }
        r => r,
    }
}

/// An image decoded: its width, height and texels.
type Decoded = (u32, u32, Vec<u8>);

/// Whether `bytes` start like a TIFF or BigTIFF.
fn is_tiff_bytes(bytes: &[u8]) -> bool {
    matches!(bytes.get(..4), Some(b"II*\0" | b"MM\0*" | b"II+\0" | b"MM\0+"))
}

/// A tiled TIFF the `image` crate does not decode (GDAL's default RGB JPEG, stored as YCbCr),
/// read by the COG reader as `clipmapd` serves it; `None` when that reader does not take it as
/// colour either (the first decoder's refusal then stands).
fn decode_tiff_by_cog_reader(
    grid: &Grid,
    bytes: &[u8],
    max_bytes: u64,
    where_: &str,
) -> Option<Result<Decoded, InputError>> {
    use crate::source::TileSource;
    use crate::texel::ComponentType;
    let w = || where_.to_string();
    let src =
        crate::source::CogSource::from_bytes_full_resolution(std::path::Path::new(where_), std::sync::Arc::from(bytes))
            .ok()?;
    let f = src.desc().format();
    if src.heights().is_some() || !matches!(f.ctype, ComponentType::U8 | ComponentType::U16) {
        return None;
    }
    let [width, height] = src.desc().size();
    let texel_bytes = width * height * grid.bytes_per_texel as u64;
    let served = width * height * src.desc().bytes_per_texel() as u64;
    if width > MAX_PATCH_PIXELS as u64
        || height > MAX_PATCH_PIXELS as u64
        || texel_bytes > max_bytes
        || served > max_bytes.saturating_mul(4).max(1 << 20)
    {
        return Some(Err(InputError::TooLarge {
            where_: w(),
            width: width as u32,
            height: height as u32,
            bytes: texel_bytes,
            max_side: MAX_PATCH_PIXELS,
            max_bytes,
        }));
    }
    let wide = f.ctype == ComponentType::U16;
    let want16 = grid.component_bytes == 2;
    if wide != want16 {
        return Some(Err(InputError::Depth {
            where_: w(),
            found: format!("{f} texels"),
            expected: format!("{} bits a component", grid.component_bytes * 8),
        }));
    }
    let mut texels = vec![0u8; served as usize];
    if let Err(e) = src.read_full_resolution([0, 0], [width, height], &mut texels) {
        return Some(Err(InputError::Decode { where_: w(), problem: e.to_string() }));
    }
    let (n, sb) = (f.components.count() as usize, if wide { 2 } else { 1 });
    let comps = grid.bytes_per_texel / grid.component_bytes;
    if !(1..=4).contains(&comps) {
        return Some(Err(InputError::Depth {
            where_: w(),
            found: format!("{f} texels"),
            expected: format!("{comps} components a texel (images give 1 to 4)"),
        }));
    }
    let max = if wide { u16::MAX } else { 255 };
    let mut out = Vec::with_capacity(texel_bytes as usize);
    // The source's rows count t up from the bottom; an image's rows go top-down.
    for t in (0..height as usize).rev() {
        let line = &texels[t * width as usize * n * sb..][..width as usize * n * sb];
        for px in line.chunks_exact(n * sb) {
            let get = |k: usize| if wide { u16::from_le_bytes([px[2 * k], px[2 * k + 1]]) } else { px[k] as u16 };
            let [r, g, b, a] = match n {
                1 => [get(0), get(0), get(0), max],
                2 => [get(0), get(0), get(0), get(1)],
                3 => [get(0), get(1), get(2), max],
                _ => [get(0), get(1), get(2), get(3)],
            };
            // Luminance as the `image` crate takes it (Rec. 709 weights; a grey pixel's value).
            let luma = || {
                if r == g && g == b {
                    r
                } else {
                    ((2126 * r as u32 + 7152 * g as u32 + 722 * b as u32 + 5000) / 10000) as u16
                }
            };
            let values: &[u16] = match comps {
                1 => &[luma()],
                2 => &[luma(), a],
                3 => &[r, g, b],
                _ => &[r, g, b, a],
            };
            for &v in values {
                if wide {
                    out.extend_from_slice(&v.to_le_bytes());
                } else {
                    out.push(v as u8);
                }
            }
        }
    }
    Some(Ok((width as u32, height as u32, out)))
}

/// [`decode_image`] by the `image` crate's decoders.
fn decode_with_image(
    grid: &Grid,
    bytes: &[u8],
    max_bytes: u64,
    where_: &str,
) -> Result<(u32, u32, Vec<u8>), InputError> {
    let w = || where_.to_string();
    let reader = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| InputError::Format { where_: w(), problem: e.to_string() })?;
    if reader.format().is_none() {
        return Err(InputError::Format { where_: w(), problem: "its first bytes match no known format".into() });
    }
    let (width, height) =
        reader.into_dimensions().map_err(|e| InputError::Format { where_: w(), problem: e.to_string() })?;
    let texel_bytes = width as u64 * height as u64 * grid.bytes_per_texel as u64;
    if width > MAX_PATCH_PIXELS || height > MAX_PATCH_PIXELS || texel_bytes > max_bytes {
        return Err(InputError::TooLarge {
            where_: w(),
            width,
            height,
            bytes: texel_bytes,
            max_side: MAX_PATCH_PIXELS,
            max_bytes,
        });
    }
    let mut reader = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| InputError::Format { where_: w(), problem: e.to_string() })?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_PATCH_PIXELS);
    limits.max_image_height = Some(MAX_PATCH_PIXELS);
    limits.max_alloc = Some(max_bytes.saturating_mul(4).max(1 << 20));
    reader.limits(limits);
    let img = reader.decode().map_err(|e| InputError::Decode { where_: w(), problem: e.to_string() })?;
    let wide = matches!(
        img.color(),
        image::ColorType::L16 | image::ColorType::La16 | image::ColorType::Rgb16 | image::ColorType::Rgba16
    );
    let eight = matches!(
        img.color(),
        image::ColorType::L8 | image::ColorType::La8 | image::ColorType::Rgb8 | image::ColorType::Rgba8
    );
    let want16 = grid.component_bytes == 2;
    if (want16 && !wide) || (!want16 && !eight) {
        return Err(InputError::Depth {
            where_: w(),
            found: format!("{:?} texels", img.color()),
            expected: format!("{} bits a component", grid.component_bytes * 8),
        });
    }
    let comps = grid.bytes_per_texel / grid.component_bytes;
    let texels: Vec<u8> = match (comps, want16) {
        (1, false) => img.into_luma8().into_raw(),
        (2, false) => img.into_luma_alpha8().into_raw(),
        (3, false) => img.into_rgb8().into_raw(),
        (4, false) => img.into_rgba8().into_raw(),
        (1, true) => img.to_luma16().into_raw().iter().flat_map(|v| v.to_le_bytes()).collect(),
        (2, true) => img.to_luma_alpha16().into_raw().iter().flat_map(|v| v.to_le_bytes()).collect(),
        (3, true) => img.to_rgb16().into_raw().iter().flat_map(|v| v.to_le_bytes()).collect(),
        (4, true) => img.to_rgba16().into_raw().iter().flat_map(|v| v.to_le_bytes()).collect(),
        _ => {
            return Err(InputError::Depth {
                where_: w(),
                found: format!("{:?} texels", img.color()),
                expected: format!("{comps} components a texel (images give 1 to 4)"),
            })
        }
    };
    Ok((width, height, texels))
}

/// A whole patch from its description and the bytes it names (the image file's content, or the
/// raw texels), checked.
pub fn patch(
    grid: &Grid,
    id: u64,
    desc: &Sidecar,
    bytes: &[u8],
    max_bytes: u64,
    where_: &str,
) -> Result<Patch, InputError> {
    let (width, height, texels) = match desc.raw {
        Some(RawSize { width, height }) => {
            let need = width as u64 * height as u64 * grid.bytes_per_texel as u64;
            if width > MAX_PATCH_PIXELS || height > MAX_PATCH_PIXELS || need > max_bytes {
                return Err(InputError::TooLarge {
                    where_: where_.to_string(),
                    width,
                    height,
                    bytes: need,
                    max_side: MAX_PATCH_PIXELS,
                    max_bytes,
                });
            }
            (width, height, bytes.to_vec())
        }
        None => decode_image(grid, bytes, max_bytes, where_)?,
    };
    let [x0, y0, x1, y1] = desc.bbox;
    let meta = PatchMeta { id, bbox: WorldBox { min: [x0, y0], max: [x1, y1] }, time: desc.time, rating: desc.rating };
    Patch::new(grid, meta, width, height, texels).map_err(|e| InputError::Patch(e, where_.to_string()))
}

/// Parses a `--max-patch-bytes` value (a byte count, `k`, `m`, `g` suffixes allowed) and checks it
/// against [`crate::limits::MAX_PATCH_BYTES`]: 1 byte to 4 GiB.
pub fn parse_max_patch_bytes(text: &str) -> Result<u64, String> {
    let n = crate::paging::parse_bytes(text)?;
    let max = crate::limits::MAX_PATCH_BYTES;
    if n == 0 || n > max {
        return Err(format!(
            "{n} bytes is not a patch size this build takes: expected 1 to {max} ({} GiB, MAX_PATCH_BYTES); a patch is held in memory whole while it is checked",
            max >> 30
        ));
    }
    Ok(n)
}

pub use crate::limits::MAX_SIDECAR_BYTES;

/// Where the files a sidecar names may be.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Paths {
    /// Inside the sidecar's own directory: its `image` is a relative path of plain names (no
    /// `..`, not absolute), and no symbolic link is followed, neither to the sidecar nor along
    /// its data's path. For every sidecar someone else may have written (a watched directory,
    /// `cliptex grow add`).
    Inside,
    /// Anywhere this process can read, links followed: the owner's own request on the control
    /// socket (`PATCH FILE`).
    Anywhere,
}

/// Most bytes an image file may have for `texel_bytes` bytes of texels: twice its texels and a
/// MiB (a PNG or TIFF of noise is a little larger than its texels, a JPEG at quality 100 up to
/// about 1.5 times). Checked when a patch is added and when a store reads it back.
pub(crate) fn max_image_file_bytes(texel_bytes: u64) -> u64 {
    texel_bytes.saturating_mul(2).saturating_add(1 << 20)
}

/// The patch a sidecar file describes, with the image (relative to the sidecar's directory) or
/// raw texels (the sidecar's name with `.raw` for `.json`) it names, read and checked against
/// `grid`; errors name the sidecar. Every file is opened with the one checked open
/// ([`crate::open`]: regular files only, never blocking on a FIFO or device) and its length is
/// checked before it is read: the sidecar at most [`MAX_SIDECAR_BYTES`], an image at most
/// `max_bytes`, raw texels exactly their size. `paths` says where its files may be.
pub fn read_sidecar(grid: &Grid, file: &std::path::Path, max_bytes: u64, paths: Paths) -> Result<NewPatch, InputError> {
    use crate::open::SizedError;
    let where_ = file.display().to_string();
    let dir = file.parent().unwrap_or(std::path::Path::new("."));
    let open = |path: &std::path::Path| -> std::io::Result<(std::fs::File, std::fs::Metadata)> {
        match paths {
            Paths::Anywhere => crate::open::regular(path),
            Paths::Inside => {
                let rel = path.strip_prefix(dir).unwrap_or(path);
                crate::open::regular_in(dir, rel)
            }
        }
    };
    let read = |path: &std::path::Path, max: u64, what: &str| -> Result<Vec<u8>, InputError> {
        let problem =
            match open(path).map_err(SizedError::Io).and_then(|(f, m)| crate::open::read_open_capped(f, &m, max)) {
                Ok(bytes) => return Ok(bytes),
                Err(SizedError::Io(e)) => format!("could not read {what} {}: {e}", path.display()),
                Err(SizedError::Length(n)) => {
                    format!("{what} {} holds {n} bytes; the most taken is {max}", path.display())
                }
            };
        Err(InputError::Sidecar { where_: where_.clone(), problem })
    };
    let text = match paths {
        Paths::Anywhere => read(file, MAX_SIDECAR_BYTES, "the description")?,
        Paths::Inside => {
            let name = std::path::Path::new(file.file_name().unwrap_or_default());
            read(&dir.join(name), MAX_SIDECAR_BYTES, "the description")?
        }
    };
    let desc = sidecar(&text, &where_)?;
    if let (Paths::Inside, Some(image)) = (paths, &desc.image) {
        let p = std::path::Path::new(image);
        if !p.components().all(|c| matches!(c, std::path::Component::Normal(_))) || image.is_empty() {
            return Err(InputError::Sidecar {
                where_,
                problem: format!(
                    "its \"image\" {image:?} is not a path inside the sidecar's directory; give a file name relative to it, without `..` (images elsewhere are taken only by `PATCH FILE` on the control socket)"
                ),
            });
        }
    }
    let data_path = data_file(file, &desc);
    let max = match desc.raw {
        Some(RawSize { width, height }) => (width as u64 * height as u64 * grid.bytes_per_texel as u64).min(max_bytes),
        None => max_bytes,
    };
    let what = if desc.raw.is_some() { "the raw texels" } else { "the image" };
    let bytes = read(&data_path, max, what)?;
    new_patch(grid, &desc, bytes, max_bytes, &where_)
}

/// The patch `desc` describes, from `bytes` (its image file's content, or its raw texels),
/// checked against `grid`; errors say `where_`.
pub fn new_patch(
    grid: &Grid,
    desc: &Sidecar,
    bytes: Vec<u8>,
    max_bytes: u64,
    where_: &str,
) -> Result<NewPatch, InputError> {
    if desc.image.is_some() && bytes.len() as u64 > max_bytes {
        return Err(InputError::FileTooLarge { where_: where_.to_string(), bytes: bytes.len() as u64, max_bytes });
    }
    let p = patch(grid, 0, desc, &bytes, max_bytes, where_)?;
    if desc.image.is_some() && bytes.len() as u64 > max_image_file_bytes(p.texels.len() as u64) {
        return Err(InputError::Decode {
            where_: where_.to_string(),
            problem: format!(
                "the image file has {} bytes for {} bytes of texels; the most kept is {} (twice its texels and a MiB)",
                bytes.len(),
                p.texels.len(),
                max_image_file_bytes(p.texels.len() as u64)
            ),
        });
    }
    let encoded = desc.image.is_some().then_some(bytes);
    Ok(NewPatch { patch: p, encoded })
}

/// The file a sidecar's data is in: its `image`, relative to the sidecar's directory, or the
/// sidecar's own name with `.raw`.
pub(crate) fn data_file(sidecar_path: &std::path::Path, desc: &Sidecar) -> std::path::PathBuf {
    match &desc.image {
        Some(name) => sidecar_path.parent().unwrap_or(std::path::Path::new(".")).join(name),
        None => sidecar_path.with_extension("raw"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(img: image::DynamicImage) -> Vec<u8> {
        let mut out = Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png).unwrap();
        out.into_inner()
    }

    fn desc(json: &str) -> Result<Sidecar, InputError> {
        sidecar(json.as_bytes(), "d.json")
    }

    #[test]
    fn an_8_bit_rgb_png_becomes_rgb_texels_and_a_16_bit_grey_one_little_endian_words() {
        let rgb = Grid::new([0.0, 0.0], 1.0, 4, 3, 1).unwrap();
        let img = image::RgbImage::from_fn(3, 2, |x, y| image::Rgb([x as u8, y as u8, 7]));
        let d = desc(r#"{"bbox": [0, 0, 3, 2], "time": 5, "rating": 1.5, "image": "a.png"}"#).unwrap();
        let p = patch(&rgb, 9, &d, &png(img.into()), 1 << 20, "a.png").unwrap();
        assert_eq!((p.width, p.height, p.time, p.rating, p.id), (3, 2, 5, 1.5, 9));
        assert_eq!(&p.texels[..6], &[0, 0, 7, 1, 0, 7]);
        assert_eq!(&p.texels[9..12], &[0, 1, 7]);

        let grey16 = Grid::new([0.0, 0.0], 1.0, 4, 2, 2).unwrap();
        let img =
            image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(2, 1, |x, _| image::Luma([1000 + x as u16]));
        let (w, h, t) = decode_image(&grey16, &png(img.into()), 1 << 20, "g.png").unwrap();
        assert_eq!((w, h, t), (2, 1, vec![0xe8, 0x03, 0xe9, 0x03]));
    }

    #[test]
    fn wrong_depth_garbage_too_large_and_bad_descriptions_are_refused_with_where() {
        let rgb = Grid::new([0.0, 0.0], 1.0, 4, 3, 1).unwrap();
        let img16 = image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_fn(2, 2, |_, _| image::Rgb([1, 2, 3]));
        let e = decode_image(&rgb, &png(img16.into()), 1 << 20, "deep.png").unwrap_err();
        assert!(matches!(e, InputError::Depth { .. }) && e.to_string().starts_with("deep.png: "), "{e}");
        let e = decode_image(&rgb, b"not an image at all", 1 << 20, "junk.bin").unwrap_err();
        assert!(matches!(e, InputError::Format { .. }), "{e}");
        let big = image::RgbImage::new(64, 64);
        let e = decode_image(&rgb, &png(big.into()), 1000, "big.png").unwrap_err();
        assert!(matches!(e, InputError::TooLarge { width: 64, height: 64, bytes: 12288, .. }), "{e}");
        let mut cut = png(image::RgbImage::new(8, 8).into());
        cut.truncate(cut.len() - 20);
        assert!(matches!(decode_image(&rgb, &cut, 1 << 20, "cut.png"), Err(InputError::Decode { .. })));

        assert!(matches!(desc(r#"{"bbox": [0, 0, 1, 1], "ratng": 3, "image": "a"}"#), Err(InputError::Sidecar { .. })));
        assert!(matches!(desc(r#"{"bbox": [0, 0, 1], "image": "a"}"#), Err(InputError::Sidecar { .. })));
        assert!(matches!(desc(r#"{"bbox": [0, 0, 1, 1]}"#), Err(InputError::Source { found: "neither", .. })));
        let both = r#"{"bbox": [0, 0, 1, 1], "image": "a", "raw": {"width": 1, "height": 1}}"#;
        assert!(matches!(desc(both), Err(InputError::Source { found: "both", .. })));
        let e = desc("{").unwrap_err().to_string();
        assert!(e.starts_with("d.json: ") && e.contains("\"bbox\""), "{e}");
    }

    fn jpeg(w: u32, h: u32) -> Vec<u8> {
        let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 5) as u8, (y * 3) as u8, 90]));
        let mut out = Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
        out.into_inner()
    }

    #[test]
    fn a_jpeg_without_its_end_marker_or_cut_short_is_refused_not_filled_with_grey() {
        let rgb = Grid::new([0.0, 0.0], 1.0, 4, 3, 1).unwrap();
        let j = jpeg(64, 48);
        assert_eq!(decode_image(&rgb, &j, 1 << 20, "a.jpg").unwrap().0, 64);
        for cut in [j.len() - 2, j.len() - 40, j.len() * 3 / 4] {
            let e = decode_image(&rgb, &j[..cut], 1 << 20, "cut.jpg").unwrap_err();
            assert!(matches!(e, InputError::Decode { .. }) && e.to_string().contains("ends early"), "{cut}: {e}");
        }
    }

    #[test]
    fn a_sidecar_image_with_dotdot_or_absolute_is_refused_unless_the_owner_asks() {
        let rgb = Grid::new([0.0, 0.0], 1.0, 4, 3, 1).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("in")).unwrap();
        std::fs::write(d.join("secret.jpg"), jpeg(8, 8)).unwrap();
        let abs = d.join("secret.jpg").display().to_string();
        for image in ["../secret.jpg", abs.as_str(), "./../secret.jpg", ""] {
            let side = d.join("in/s.json");
            std::fs::write(&side, format!(r#"{{"bbox": [0, 0, 8, 8], "image": "{image}"}}"#)).unwrap();
            let e = read_sidecar(&rgb, &side, 1 << 20, Paths::Inside).unwrap_err().to_string();
            assert!(e.contains("not a path inside the sidecar's directory"), "{image}: {e}");
        }
        let side = d.join("in/own.json");
        std::fs::write(&side, format!(r#"{{"bbox": [0, 0, 8, 8], "image": "{abs}"}}"#)).unwrap();
        assert_eq!(read_sidecar(&rgb, &side, 1 << 20, Paths::Anywhere).unwrap().patch.width, 8);
    }

    #[test]
    fn max_patch_bytes_is_bounded() {
        assert_eq!(parse_max_patch_bytes("256m").unwrap(), 256 << 20);
        assert_eq!(parse_max_patch_bytes("4g").unwrap(), crate::limits::MAX_PATCH_BYTES);
        for bad in ["0", "4294967297", "18446744073709551615", "1099511627776"] {
            assert!(parse_max_patch_bytes(bad).unwrap_err().contains("MAX_PATCH_BYTES"), "{bad}");
        }
    }

    #[test]
    fn raw_texels_are_checked_for_size_before_they_are_kept() {
        let g = Grid::new([0.0, 0.0], 1.0, 4, 1, 1).unwrap();
        let d = desc(r#"{"bbox": [0, 0, 2, 2], "raw": {"width": 2, "height": 2}}"#).unwrap();
        assert_eq!(patch(&g, 1, &d, &[1, 2, 3, 4], 16, "r").unwrap().texels, vec![1, 2, 3, 4]);
        let e = patch(&g, 1, &d, &[1, 2, 3], 16, "r").unwrap_err();
        assert!(matches!(e, InputError::Patch(GrowError::TexelBytes { expected: 4, found: 3, .. }, _)), "{e}");
        assert!(matches!(patch(&g, 1, &d, &[0; 4], 3, "r"), Err(InputError::TooLarge { .. })));
        let inverted = desc(r#"{"bbox": [2, 0, 0, 2], "raw": {"width": 2, "height": 2}}"#).unwrap();
        let e = patch(&g, 1, &inverted, &[0; 4], 16, "r").unwrap_err().to_string();
        assert!(e.starts_with("r: patch 1: its box is empty or inverted along x"), "{e}");
    }
}
