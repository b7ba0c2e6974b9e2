//! The images of a TIFF as levels: each IFD's layout checked against what is served
//! ([`image_level`]: refusals name the IFD, the tag, the value found and what is supported), its
//! internal mask, and the full-resolution image and its usable overviews mapped to the texture's
//! levels ([`CogSource::levels_of`]), the rest built ([`Level::Built`]).

use super::error::CogError;
use super::index::array;
use super::level::{Array, Compression, IfdLevel, JpegColour, Level, LevelOrigin, MaskLevel, Samples};
use super::structure::{raw_bytes, scalar, values, Head, Image, Layout};
use super::{CogSource, MAX_BUILT_TEXELS, MAX_JPEG_TABLES};
use crate::source::{level_count, level_size, LevelDesc, TextureDesc};
use crate::texel::TexelFormat;
use std::path::Path;
use std::sync::Arc;

/// Checks one image's layout and describes it as a level: its texel format and tiles.
pub(super) fn image_level(
    path: &Path,
    file: &Head,
    layout: Layout,
    image: &Image,
) -> Result<(TexelFormat, IfdLevel), CogError> {
    let malformed = |(at, problem): (String, String)| CogError::Malformed { path: path.to_path_buf(), at, problem };
    let unsupported = |tag, found: String, supported| CogError::Unsupported {
        path: path.to_path_buf(),
        ifd: image.ifd,
        tag,
        found,
        supported,
    };
    let get = |tag: u16, name: &str| scalar(file, layout, image, tag, name).map_err(malformed);
    let required = |tag: u16, name: &str| {
        get(tag, name)?.ok_or_else(|| malformed((format!("IFD {} tag {name}", image.ifd), "missing".into())))
    };
    let width = required(256, "ImageWidth (256)")?;
    let height = required(257, "ImageLength (257)")?;
    let (Some(tw), Some(th)) = (get(322, "TileWidth (322)")?, get(323, "TileLength (323)")?) else {
        return Err(unsupported(
            "TileWidth (322)",
            "absent: the image is stored in strips".into(),
            "tiled images (gdal_translate -of COG, or -co TILED=YES)",
        ));
    };
    if width == 0 || height == 0 || tw == 0 || th == 0 {
        return Err(malformed((
            format!("IFD {}", image.ifd),
            format!("image {width} x {height} in tiles of {tw} x {th}: every size must be at least 1"),
        )));
    }
    if width > crate::source::MAX_TEXTURE_SIZE || height > crate::source::MAX_TEXTURE_SIZE {
        return Err(unsupported(
            "ImageWidth (256) x ImageLength (257)",
            format!("{width} x {height}"),
            "at most 2^30 (MAX_TEXTURE_SIZE) texels a side",
        ));
    }
    let spp = get(277, "SamplesPerPixel (277)")?.unwrap_or(1);
    if !matches!(spp, 1 | 3 | 4) {
        return Err(unsupported("SamplesPerPixel (277)", spp.to_string(), "1 (grey), 3 (RGB) or 4 (RGBA)"));
    }
    let list = |tag: u16, name: &str| values(file, layout, image, tag, name, 16).map_err(malformed);
    let bits = list(258, "BitsPerSample (258)")?.unwrap_or(vec![1]);
    let sample_format = list(339, "SampleFormat (339)")?.unwrap_or(vec![1]);
    let same = |v: &[u64]| v.iter().all(|&x| x == v[0]);
    let samples = match (bits[0], sample_format[0]) {
        _ if !same(&bits) || !same(&sample_format) => None,
        (8, 1) => Some(Samples::U8),
        (16, 1) => Some(Samples::U16),
        (16, 2) => Some(Samples::I16),
        (32, 3) => Some(Samples::F32),
        _ => None,
    };
    let Some(samples) = samples else {
        return Err(unsupported(
            "BitsPerSample (258) / SampleFormat (339)",
            format!("{bits:?} bits, sample format {sample_format:?}"),
            "the same for every sample: 8 or 16 bits unsigned (format 1), 16 bits signed (format 2) or 32-bit floats (format 3)",
        ));
    };
    let format = match (samples, spp) {
        (Samples::U8, 1) => TexelFormat::L8,
        (Samples::U8, 3) => TexelFormat::RGB8,
        (Samples::U8, _) => TexelFormat::RGBA8,
        (Samples::U16, 1) => TexelFormat::L16,
        (Samples::U16, 3) => TexelFormat::RGB16,
        (Samples::U16, _) => TexelFormat::RGBA16,
        (Samples::I16, 1) => TexelFormat::L16I,
        (Samples::F32, 1) => TexelFormat::L32F,
        (_, n) => {
            return Err(unsupported(
                "SamplesPerPixel (277)",
                n.to_string(),
                "1 with 16-bit signed or 32-bit float samples (heights: l16i, l32f)",
            ))
        }
    };
    let planar = get(284, "PlanarConfiguration (284)")?.unwrap_or(1);
    if planar != 1 && spp > 1 {
        return Err(unsupported(
            "PlanarConfiguration (284)",
            format!("{planar} (separate planes)"),
            "1 (chunky: samples of a pixel together; gdal_translate -co INTERLEAVE=PIXEL)",
        ));
    }
    let compression = match get(259, "Compression (259)")?.unwrap_or(1) {
        1 => Compression::None,
        5 => Compression::Lzw,
        7 => Compression::Jpeg,
        8 | 32946 => Compression::Deflate,
        50000 => Compression::Zstd,
        c => {
            let name = match c {
                6 => " (old-style JPEG)",
                32773 => " (PackBits)",
                34887 => " (LERC)",
                34925 => " (LZMA)",
                50001 => " (WebP)",
                _ => "",
            };
            return Err(unsupported(
                "Compression (259)",
                format!("{c}{name}"),
                "1 (none), 5 (LZW), 7 (JPEG), 8 or 32946 (DEFLATE), 50000 (ZSTD)",
            ));
        }
    };
    let photometric = get(262, "PhotometricInterpretation (262)")?;
    let jpeg = compression == Compression::Jpeg;
    let ok_photometric = match (spp, jpeg) {
        (1, _) => photometric.unwrap_or(1) == 1,
        (3, true) => matches!(photometric, Some(2 | 6)),
        (_, true) => photometric == Some(2),
        _ => photometric == Some(2),
    };
    if !ok_photometric {
        return Err(unsupported(
            "PhotometricInterpretation (262)",
            format!(
                "{}{}",
                photometric.map_or("absent".into(), |p| p.to_string()),
                if jpeg { format!(" with {spp} JPEG-compressed samples") } else { String::new() }
            ),
            if jpeg {
                "1 (grey) with 1 sample; 6 (YCbCr: gdal_translate -of COG -co COMPRESS=JPEG, or -co PHOTOMETRIC=YCBCR) with 3; 2 (RGB, no colour transform: gdal_translate -of GTiff -co TILED=YES -co COMPRESS=JPEG -co PHOTOMETRIC=RGB) with 3, or with 4 (RGBA: what the GTiff driver writes for 4 bands)"
            } else {
                "1 (grey, zero is black) with 1 sample, 2 (RGB) with 3 or 4"
            },
        ));
    }
    if jpeg && samples != Samples::U8 {
        return Err(unsupported(
            "BitsPerSample (258) / SampleFormat (339)",
            format!("{bits:?} bits, sample format {sample_format:?} with JPEG"),
            "8-bit samples with JPEG (7)",
        ));
    }
    let jpeg_tables = match jpeg {
        true => raw_bytes(file, layout, image, 347, "JPEGTables (347)", &[7], MAX_JPEG_TABLES)
            .map_err(malformed)?
            .map(Arc::from),
        false => None,
    };
    let predictor = match get(317, "Predictor (317)")?.unwrap_or(1) {
        _ if jpeg => 1,
        p @ (1 | 2) => p as u16,
        3 if samples == Samples::F32 => 3,
        p => {
            return Err(unsupported(
                "Predictor (317)",
                format!("{p} with {} samples", format),
                "1 (none), 2 (horizontal differencing), or 3 (floating point) with 32-bit float samples",
            ))
        }
    };
    let tile_bytes = tw.saturating_mul(th).saturating_mul(spp).saturating_mul(samples.bytes() as u64);
    if tile_bytes > crate::limits::MAX_TILE_BYTES {
        return Err(unsupported(
            "TileWidth (322) x TileLength (323)",
            format!("{tw} x {th} ({tile_bytes} bytes a tile)"),
            "tiles of at most MAX_TILE_BYTES (268435456) bytes: write smaller tiles (gdal_translate -co BLOCKSIZE=512, or -co BLOCKXSIZE= -co BLOCKYSIZE=)",
        ));
    }
    let across = width.div_ceil(tw);
    let tiles = across * height.div_ceil(th);
    let offsets = array(layout, image, 324, "TileOffsets (324)", tiles).map_err(malformed)?;
    let counts = array(layout, image, 325, "TileByteCounts (325)", tiles).map_err(malformed)?;
    index_in_file(file, image, &offsets, &counts, [width, height], [tw, th]).map_err(malformed)?;
    let level = IfdLevel {
        ifd: image.ifd,
        size: [width, height],
        tile: [tw, th],
        across,
        compression,
        predictor,
        jpeg_tables,
        jpeg_colour: if jpeg && photometric == Some(6) { JpegColour::YCbCr } else { JpegColour::Raw },
        samples,
        spp: spp as usize,
        offsets,
        counts,
        mask: None,
    };
    Ok((format, level))
}

/// Whether an image's tile index lies in the file: one past its end is a damaged or truncated
/// file, refused at open rather than every tile of the image failing on its own (an image
/// claiming 2^26 texels a side in a few kilobytes would have billions of tiles to try).
pub(super) fn index_in_file(
    file: &Head,
    image: &Image,
    offsets: &Array,
    counts: &Array,
    [width, height]: [u64; 2],
    [tw, th]: [u64; 2],
) -> Result<(), (String, String)> {
    let size = file.bytes.size();
    for (a, name) in [(offsets, "TileOffsets (324)"), (counts, "TileByteCounts (325)")] {
        let bytes = a.count.saturating_mul(a.size);
        if a.inline.is_none() && a.at.checked_add(bytes).is_none_or(|end| end > size) {
            return Err((
                format!("IFD {} tag {name}", image.ifd),
                format!(
                    "its {} values ({bytes} bytes, one per tile of a {width} x {height} image in tiles of {tw} x {th}) at byte {} run past the end of the file ({size} bytes)",
                    a.count, a.at
                ),
            ));
        }
    }
    Ok(())
}

/// The internal mask in IFD `image` of the image `of` (IFD `of.ifd`): one 1- or 8-bit unsigned
/// sample, the image's size and tiling; anything else is refused naming the tag, the value found
/// and what is expected.
pub(super) fn mask_level(
    path: &Path,
    file: &Head,
    layout: Layout,
    image: &Image,
    of: &IfdLevel,
) -> Result<Arc<MaskLevel>, CogError> {
    let malformed = |(at, problem): (String, String)| CogError::Malformed { path: path.to_path_buf(), at, problem };
    let refuse = |tag, found: String, expected: String| CogError::Mask {
        path: path.to_path_buf(),
        ifd: image.ifd,
        image: Some(of.ifd),
        tag,
        found,
        expected,
    };
    let get = |tag: u16, name: &str| scalar(file, layout, image, tag, name).map_err(malformed);
    let shown = |v: Option<u64>| v.map_or("absent".to_string(), |v| v.to_string());
    let (w, h) = (get(256, "ImageWidth (256)")?, get(257, "ImageLength (257)")?);
    if (w, h) != (Some(of.size[0]), Some(of.size[1])) {
        return Err(refuse(
            "ImageWidth (256) x ImageLength (257)",
            format!("{} x {}", shown(w), shown(h)),
            format!("{} x {} (its image's)", of.size[0], of.size[1]),
        ));
    }
    let (tw, th) = (get(322, "TileWidth (322)")?, get(323, "TileLength (323)")?);
    if (tw, th) != (Some(of.tile[0]), Some(of.tile[1])) {
        return Err(refuse(
            "TileWidth (322) x TileLength (323)",
            format!("{} x {}", shown(tw), shown(th)),
            format!("{} x {} (its image's tiles)", of.tile[0], of.tile[1]),
        ));
    }
    let spp = get(277, "SamplesPerPixel (277)")?.unwrap_or(1);
    if spp != 1 {
        return Err(refuse("SamplesPerPixel (277)", spp.to_string(), "1".into()));
    }
    let bits = get(258, "BitsPerSample (258)")?.unwrap_or(1);
    let sample_format = get(339, "SampleFormat (339)")?.unwrap_or(1);
    if !matches!(bits, 1 | 8) || sample_format != 1 {
        return Err(refuse(
            "BitsPerSample (258) / SampleFormat (339)",
            format!("{bits} bits, sample format {sample_format}"),
            "1 or 8 bits, unsigned (format 1)".into(),
        ));
    }
    let photometric = get(262, "PhotometricInterpretation (262)")?;
    if !matches!(photometric, None | Some(1) | Some(4)) {
        return Err(refuse(
            "PhotometricInterpretation (262)",
            shown(photometric),
            "4 (transparency mask, what GDAL writes) or 1".into(),
        ));
    }
    let fill_order = get(266, "FillOrder (266)")?.unwrap_or(1);
    if fill_order != 1 {
        return Err(refuse(
            "FillOrder (266)",
            fill_order.to_string(),
            "1 (the first pixel in the most significant bit)".into(),
        ));
    }
    let compression = match get(259, "Compression (259)")?.unwrap_or(1) {
        1 => Compression::None,
        5 => Compression::Lzw,
        8 | 32946 => Compression::Deflate,
        50000 => Compression::Zstd,
        c => {
            return Err(refuse(
                "Compression (259)",
                c.to_string(),
                "1 (none), 5 (LZW), 8 or 32946 (DEFLATE) or 50000 (ZSTD) for a mask".into(),
            ))
        }
    };
    let predictor = get(317, "Predictor (317)")?.unwrap_or(1);
    if !(predictor == 1 || predictor == 2 && bits == 8) {
        return Err(refuse(
            "Predictor (317)",
            format!("{predictor} with {bits}-bit samples"),
            "1 (none), or 2 (horizontal differencing) with 8-bit samples".into(),
        ));
    }
    let tiles = of.across * of.rows();
    let offsets = array(layout, image, 324, "TileOffsets (324)", tiles).map_err(malformed)?;
    let counts = array(layout, image, 325, "TileByteCounts (325)", tiles).map_err(malformed)?;
    index_in_file(file, image, &offsets, &counts, of.size, of.tile).map_err(malformed)?;
    let lv = IfdLevel {
        ifd: image.ifd,
        size: of.size,
        tile: of.tile,
        across: of.across,
        compression,
        predictor: predictor as u16,
        jpeg_tables: None,
        jpeg_colour: JpegColour::Raw,
        samples: Samples::U8,
        spp: 1,
        offsets,
        counts,
        mask: None,
    };
    Ok(Arc::new(MaskLevel { lv, one_bit: bits == 1 }))
}

impl CogSource {
    #[allow(clippy::type_complexity)]
    pub(super) fn levels_of(
        path: &Path,
        head: &Head,
        layout: Layout,
        images: Vec<Image>,
        clip_size: u64,
        build: bool,
    ) -> Result<(TextureDesc, Vec<Level>, Vec<LevelOrigin>, Option<String>), CogError> {
        let full = &images[0];
        let (format, mut level0) = image_level(path, head, layout, full)?;
        let size = level0.size;
        let n = level_count(size);
        // The masks: one of the full-resolution image (NewSubfileType 4), then one for each
        // overview (5), in the overviews' order (a colour image's become its alpha, a height
        // image's its nodata texels).
        let full_masks: Vec<&Image> = images.iter().skip(1).filter(|i| i.subfile & 5 == 4).collect();
        let mut overview_masks = images.iter().skip(1).filter(|i| i.subfile & 5 == 5);
        let order = |ifd: usize, found: String, expected: &str| CogError::Mask {
            path: path.to_path_buf(),
            ifd,
            image: None,
            tag: "NewSubfileType (254)",
            found,
            expected: expected.into(),
        };
        if let Some(second) = full_masks.get(1) {
            return Err(order(
                second.ifd,
                format!("4 (a mask of the full-resolution image) after IFD {}'s", full_masks[0].ifd),
                "one mask of the full-resolution image",
            ));
        }
        match full_masks.first() {
            Some(m) => level0.mask = Some(mask_level(path, head, layout, m, &level0)?),
            None => {
                if let Some(m) = images.iter().skip(1).find(|i| i.subfile & 5 == 5) {
                    return Err(order(
                        m.ifd,
                        format!("{} (an overview's mask) where the full-resolution image has no mask", m.subfile),
                        "an overview's mask (5) only beside a mask of the full-resolution image (4)",
                    ));
                }
            }
        }
        let masked = level0.mask.is_some();
        let mut levels = vec![Level::Ifd(level0)];
        let mut why = String::from("it has no overviews");
        for image in images.iter().skip(1) {
            if image.subfile & 4 != 0 || image.subfile & 1 == 0 {
                continue; // a mask or another page
            }
            let k = levels.len() as u32;
            let (f, level) = image_level(path, head, layout, image)?;
            if f != format {
                let full = match &levels[0] {
                    Level::Ifd(l) => l,
                    Level::Built => unreachable!("level 0 is an image"),
                };
                let (tag, found, expected) = if level.samples != full.samples {
                    ("BitsPerSample (258) / SampleFormat (339)", level.samples.describe(), full.samples.describe())
                } else {
                    ("SamplesPerPixel (277)", level.spp.to_string(), full.spp.to_string())
                };
                return Err(CogError::Overview {
                    path: path.to_path_buf(),
                    ifd: image.ifd,
                    tag,
                    found: format!("{found} ({f})"),
                    expected: format!("{expected} ({format})"),
                });
            }
            let expected = level_size(size, k);
            if levels.len() >= n || level.size != expected {
                why = if levels.len() >= n {
                    format!("IFD {} is an overview beyond the {n} levels of a {size:?} texture", image.ifd)
                } else {
                    format!(
                        "IFD {} (overview {k}) is {:?} texels, expected {expected:?} (level 0's halved and rounded down); it and the overviews after it are not used",
                        image.ifd, level.size
                    )
                };
                break;
            }
            let mut level = level;
            if masked {
                let Some(m) = overview_masks.next() else {
                    why = format!(
                        "IFD {} (overview {k}) has no mask (NewSubfileType 5) where the full-resolution image has one; it and the overviews after it are not used",
                        image.ifd
                    );
                    break;
                };
                level.mask = Some(mask_level(path, head, layout, m, &level)?);
            }
            levels.push(Level::Ifd(level));
            why = String::from("it has no smaller overviews");
        }
        let used = levels.len();
        if used < n {
            let base = used as u32 - 1;
            let base_size = level_size(size, base);
            if build && base_size[0] * base_size[1] > MAX_BUILT_TEXELS {
                return Err(CogError::TooLargeToBuild {
                    path: path.to_path_buf(),
                    why,
                    from: used as u32,
                    last: n as u32 - 1,
                    base,
                    base_size,
                });
            }
        }
        let mut origins = Vec::with_capacity(n);
        let mut descs = Vec::with_capacity(n);
        let mut last_tile = [1, 1];
        for k in 0..n as u32 {
            let ls = level_size(size, k);
            let origin = match levels.get(k as usize) {
                Some(Level::Ifd(l)) => {
                    last_tile = l.tile;
                    LevelOrigin::Ifd {
                        ifd: l.ifd,
                        tile: l.tile,
                        compression: l.compression,
                        predictor: l.predictor != 1,
                        predictor_tag: l.predictor,
                    }
                }
                _ => LevelOrigin::Built { from: used as u32 - 1 },
            };
            let stack = ls[0] > clip_size || ls[1] > clip_size;
            let tile = if stack { [last_tile[0].min(ls[0]), last_tile[1].min(ls[1])] } else { ls };
            descs.push(LevelDesc { size: ls, tile });
            origins.push(origin);
        }
        levels.resize(n, Level::Built);
        let desc_err = |source| CogError::Desc { path: path.to_path_buf(), source };
        let desc = TextureDesc::from_levels(size, clip_size, format, descs).map_err(desc_err)?;
        let border = (clip_size / 32).clamp(1, 16).min(clip_size.saturating_sub(1) / 2);
        let desc = desc.with_invalid_border(border).map_err(desc_err)?;
        let built_because = (used < n).then_some(why);
        Ok((desc, levels, origins, built_because))
    }
}
