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
//! size from its header (at most [`MAX_PATCH_PIXELS`] a side, and at most `max_bytes` of texels),
//! then the patch itself ([`Patch::new`]).

use super::{Grid, GrowError, Patch, PatchMeta, WorldBox, MAX_PATCH_PIXELS};
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
    pub width: u32,
    pub height: u32,
}

/// Why a patch could not be read.
#[derive(Debug, Error)]
pub enum InputError {
    /// The description is not valid JSON of the expected shape.
    #[error("{where_}: the patch description is not valid: {problem}; expected {{\"bbox\": [x0, y0, x1, y1], \"time\": N, \"rating\": R, \"image\": \"FILE\"}} (or \"raw\": {{\"width\": W, \"height\": H}} instead of \"image\")")]
    Sidecar { where_: String, problem: String },
    /// Both or neither of `image` and `raw`.
    #[error("{where_}: the patch description names {found}; give exactly one of \"image\" (a file) and \"raw\" (texels in the grid's format)")]
    Source { where_: String, found: &'static str },
    /// The image's format is not one this build reads.
    #[error(
        "{where_}: the image is not in a format this build reads ({problem}); give PNG, JPEG or TIFF, or raw texels"
    )]
    Format { where_: String, problem: String },
    /// The image is too large to take.
    #[error("{where_}: the image is {width}x{height} pixels, {bytes} bytes of texels; the most is {max_side} a side and {max_bytes} bytes")]
    TooLarge { where_: String, width: u32, height: u32, bytes: u64, max_side: u32, max_bytes: u64 },
    /// The image's bits per component do not fit the grid's.
    #[error("{where_}: the image has {found}; the texture's texels are {expected}: convert the image, or grow a texture of that format")]
    Depth { where_: String, found: String, expected: String },
    /// The image could not be decoded.
    #[error("{where_}: the image could not be decoded: {problem}")]
    Decode { where_: String, problem: String },
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

/// The patch a sidecar file describes, with the image (relative to the sidecar's directory) or
/// raw texels (the sidecar's name with `.raw` for `.json`) it names, read and checked against
/// `grid`; errors name the sidecar.
pub fn read_sidecar(grid: &Grid, file: &std::path::Path, max_bytes: u64) -> Result<super::store::NewPatch, InputError> {
    let where_ = file.display().to_string();
    let text = std::fs::read(file)
        .map_err(|e| InputError::Sidecar { where_: where_.clone(), problem: format!("could not read it: {e}") })?;
    let desc = sidecar(&text, &where_)?;
    let data_path = data_file(file, &desc);
    let bytes = std::fs::read(&data_path).map_err(|e| InputError::Sidecar {
        where_: where_.clone(),
        problem: format!("could not read {}: {e}", data_path.display()),
    })?;
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
) -> Result<super::store::NewPatch, InputError> {
    let p = patch(grid, 0, desc, &bytes, max_bytes, where_)?;
    let encoded = desc.image.is_some().then_some(bytes);
    Ok(super::store::NewPatch {
        bbox: p.bbox,
        time: p.time,
        rating: p.rating,
        width: p.width,
        height: p.height,
        texels: p.texels,
        encoded,
    })
}

/// The file a sidecar's data is in: its `image`, relative to the sidecar's directory, or the
/// sidecar's own name with `.raw`.
pub fn data_file(sidecar_path: &std::path::Path, desc: &Sidecar) -> std::path::PathBuf {
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
