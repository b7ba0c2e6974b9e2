//! Writes the `.ct` and `.ic` text of a [`Layout`].
//!
//! Follows docs/PERFORMER-REFERENCE.md §1: version token first, `.ct` tokens in the manual's documented order,
//! formats as names, every comment on a line of its own (never inside a list or between numbers),
//! relative paths only (so the directory can be moved), and the singular `s_stream` spelling
//! (Performer 3.0 reads the documented `s_streams` as `s_stream` plus a bogus stream `s`).
//!
//! No `*_base` token is written: 3.0 anchors only the first entry of a file list that follows a
//! base, so a base would break the relative paths. Nothing here touches the file system.

use super::layout::{Layout, Level, LevelKind};
use crate::height::HeightStorage;
use crate::plan::HeightPlan;
use crate::texel::TexelFormat;
use std::fmt::Write;

/// The `ext_format`, `int_format` and `img_format` names this tool writes a texel format with
/// ([`crate::plan::formats::names_of`]).
pub(crate) use crate::plan::formats::names_of as format_names;

fn formats(out: &mut String, f: TexelFormat) {
    let (ext, int, img) = format_names(f).expect("the layout was built with a writable format");
    let _ = writeln!(out, "ext_format {ext}");
    let _ = writeln!(out, "int_format {int}");
    let _ = writeln!(out, "img_format {img}");
}

/// The `.ct` text. `description` lines become comments (one `#` line each); a height texture's
/// `#clipmap height` lines (docs/CONFIG.md §17) come last.
pub fn ct_text(layout: &Layout, description: &[String], heights: Option<&HeightPlan>) -> String {
    let spec = &layout.spec;
    let mut out = String::new();
    out.push_str("ct_version2.0\n");
    for line in description {
        let _ = writeln!(out, "# {line}");
    }
    let _ = writeln!(
        out,
        "# {} levels: {} image cache levels (one .ic each), {} pyramid levels (one file each).",
        layout.levels.len(),
        layout.image_cache_levels().count(),
        layout.pyramid_levels().count()
    );
    match layout.blocks {
        None => out.push_str("# Texel (s, t) of a tile is at byte ((t mod tile height) * tile width + (s mod tile width)) * bytes per texel.\n"),
        Some((bc, _)) => {
            let _ = writeln!(
                out,
                "# Tiles are {} blocks (an extension of this format): ceil(tile width / 4) x ceil(tile height / 4) blocks of {} bytes, in rows of increasing t.",
                bc.name(),
                bc.block_bytes()
            );
        }
    }
    if let Some(i) = &spec.inset {
        let _ = writeln!(
            out,
            "# Sparse: levels 0 to {} exist only inside the level-0 region [{}, {}) x [{}, {}) and a border at least clip_size wide; their other tiles are absent (each .ic names a default tile).",
            i.level - 1,
            i.s0,
            i.s1,
            i.t0,
            i.t1
        );
    }
    formats(&mut out, layout.disk_format());
    let _ = writeln!(out, "virt_size {} {} 1", spec.width, spec.height);
    let _ = writeln!(out, "clip_size {}", spec.clip);
    if !layout.smallest_icache_is_default {
        out.push_str("# Not Performer's default smallest_icache, which does not fit this texture's shape.\n");
        let _ = writeln!(out, "smallest_icache {} {} 1", layout.smallest_icache.0, layout.smallest_icache.1);
    }
    let ics: Vec<&Level> = layout.image_cache_levels().collect();
    if !ics.is_empty() {
        out.push_str("icache_files\n");
        for l in ics {
            let _ = writeln!(out, "\t{}", Layout::ic_file(l.index));
        }
    }
    out.push_str("tile_files\n");
    for l in layout.pyramid_levels() {
        let _ = writeln!(out, "\t{}", Layout::pyramid_file(l.index));
    }
    let _ = writeln!(out, "tile_size {} {} 1", spec.tile, spec.tile);
    if let Some(h) = heights {
        let f = &h.format;
        out.push_str("# Heights (docs/ELEVATION.md): metres = stored x scale + offset; nodata is a stored value.\n");
        let _ = writeln!(out, "#clipmap height {}", f.storage());
        if f.storage() != HeightStorage::F32 {
            let _ = writeln!(out, "#clipmap height_scale {}", f.scale());
            let _ = writeln!(out, "#clipmap height_offset {}", f.offset());
        }
        match f.nodata() {
            Some(v) => {
                let _ = writeln!(out, "#clipmap height_nodata {v}");
            }
            None => out.push_str("#clipmap height_nodata none\n"),
        }
        let _ = writeln!(out, "#clipmap height_levels {}", h.levels);
    }
    out
}

/// The `.ic` text of an image-cache level.
pub(crate) fn ic_text(layout: &Layout, level: &Level, ct_name: &str) -> String {
    assert_eq!(level.kind, LevelKind::ImageCache, "only image-cache levels have an .ic");
    let spec = &layout.spec;
    let mut out = String::new();
    out.push_str("ic_version2.0\n");
    let _ = writeln!(
        out,
        "# Level {} ({}x{} texels) of {ct_name}: {}x{} tiles of {}x{} texels.",
        level.index,
        level.width,
        level.height,
        level.tiles_s(),
        level.tiles_t(),
        level.tile_w,
        level.tile_h
    );
    formats(&mut out, layout.disk_format());
    let _ = writeln!(out, "icache_size {} {} 1", level.width, level.height);
    let _ = writeln!(out, "tex_region_size {} {} 1", spec.clip.min(level.width), spec.clip.min(level.height));
    if spec.header_bytes > 0 {
        let _ = writeln!(out, "header_offset {}", spec.header_bytes);
    }
    if spec.tiles_in_file != (1, 1) {
        let _ = writeln!(out, "tiles_in_file {} {} 1", spec.tiles_in_file.0, spec.tiles_in_file.1);
    }
    let _ = writeln!(out, "tile_size {} {} 1", level.tile_w, level.tile_h);
    let _ = writeln!(out, "tile_format {}", layout.tile_format(level.index));
    out.push_str("tile_params");
    for p in layout.tile_params() {
        let _ = write!(out, " {p}");
    }
    out.push('\n');
    if let Some(sp) = layout.sparse(level) {
        let (i, w) = (sp.inset, sp.written);
        let _ = writeln!(
            out,
            "# Sparse level: tiles [{}, {}) x [{}, {}) hold the inset, tiles [{}, {}) x [{}, {}) around them texels of level {} magnified; all others are absent.",
            i.s0, i.s1, i.t0, i.t1, w.s0, w.s1, w.t0, w.t1, layout.spec.inset.map_or(0, |x| x.level)
        );
        let _ = writeln!(out, "default_tile {}", Layout::default_tile_file(level.index));
    }
    if let Some(n) = spec.streams {
        out.push_str("# Stream servers, chosen by tile column modulo their number.\n");
        out.push_str("s_stream");
        for i in 0..n {
            let _ = write!(out, " {}", Layout::stream_name(i));
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::formats::{resolve, texel_format, Which};

    #[test]
    fn every_written_format_reads_back_as_itself() {
        use TexelFormat as F;
        for f in
            [F::L8, F::RGB8, F::RGBA8, F::RGB565, F::RGBA5551, F::L16, F::LA16, F::RGB16, F::RGBA16, F::L32F, F::L16I]
        {
            let (ext, int, img) = format_names(f).unwrap_or_else(|| panic!("{f} is written"));
            let e = resolve(Which::Ext, ext).unwrap().value;
            resolve(Which::Int, int).unwrap();
            let i = resolve(Which::Img, img).unwrap().value;
            assert_eq!(texel_format(e, i), Some(f), "{ext} {int} {img}");
        }
    }
}
