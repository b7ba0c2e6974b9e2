//! The configuration of a COG served as it is (`clipprep --input FILE.tif --config-only`,
//! docs/COG.md): the `.ct` and `.ic` files a pyramid of the COG's shape would have, each with a
//! `#clipmap cog` line naming the COG, and no tile file. The layout is the one of a texture of
//! the COG's size rounded up to powers of two (Performer's `virt_size`), in the COG's TIFF tiles
//! and texel format; the texture itself is served at the COG's own size.

use super::configfile::{ct_text, ic_text};
use super::error::PrepError;
use super::layout::Layout;
use crate::plan::HeightPlan;
use std::fs;
use std::path::{Path, PathBuf};

/// What [`write()`] wrote.
#[derive(Clone, Debug)]
pub struct CogConfig {
    /// The `.ct`'s name inside the directory.
    pub ct: PathBuf,
    /// Files written (the `.ct` and every `.ic`).
    pub files: usize,
    /// Bytes written.
    pub bytes: u64,
}

/// The `#clipmap cog` lines that name `cog` (a path or URL as the configuration reads it).
pub(crate) fn cog_lines(cog: &str) -> String {
    format!("# The texels are the COG's, served as it is (docs/COG.md); no tile file is written.\n#clipmap cog {cog}\n")
}

/// Whether `name` can be written on a `#clipmap cog` line: one word (no whitespace), not empty,
/// UTF-8 already, not read as a comment by Performer's reader (`//`) nor as a variable (`$`).
pub(crate) fn writable_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name.chars().any(char::is_whitespace) {
        return Err(format!(
            "`{name}` cannot be written on a `#clipmap cog` line, which takes one word: expected a path or URL without spaces; rename the file or link it from a path without spaces"
        ));
    }
    if name.starts_with('$') {
        return Err(format!(
            "`{name}` starts with `$`, which a configuration expands as a variable: rename the file or link it from another path"
        ));
    }
    Ok(())
}

/// Writes the configuration of `layout` into `root` (an empty directory): `NAME.ct` and one `.ic`
/// per image-cache level, each naming the COG `cog`. `description` lines become comments of the
/// `.ct`; `heights` are the COG's (`#clipmap height` lines).
pub fn write(
    layout: &Layout,
    root: &Path,
    name: &str,
    description: &[String],
    heights: Option<&HeightPlan>,
    cog: &str,
) -> Result<CogConfig, PrepError> {
    writable_name(cog).map_err(PrepError::Geometry)?;
    let lines = cog_lines(cog);
    write_lines(layout, root, name, description, heights, &lines, &lines)
}

/// The `#clipmap source` lines that name the tile pyramid `source` (`xyz:TEMPLATE`, a `.pmtiles`
/// or `.mbtiles` path or URL, as the configuration reads it).
pub(crate) fn source_lines(source: &str) -> String {
    format!(
        "# The texels are the tile source's, served as it is (docs/TILES.md); no tile file is written.\n#clipmap source {source}\n"
    )
}

/// Writes the configuration of `layout` into `root` (an empty directory): `NAME.ct`, naming the
/// tile pyramid `source` (`#clipmap source`), and one `.ic` per image-cache level.
/// `description` lines become comments of the `.ct`.
pub fn write_source(
    layout: &Layout,
    root: &Path,
    name: &str,
    description: &[String],
    source: &str,
) -> Result<CogConfig, PrepError> {
    writable_name(source).map_err(|e| PrepError::Geometry(e.replace("#clipmap cog", "#clipmap source")))?;
    write_lines(layout, root, name, description, None, &source_lines(source), "")
}

/// Writes `NAME.ct` (with `ct_lines` after its version line) and the `.ic` files of `layout`
/// (with `ic_lines`).
fn write_lines(
    layout: &Layout,
    root: &Path,
    name: &str,
    description: &[String],
    heights: Option<&HeightPlan>,
    ct_lines: &str,
    ic_lines: &str,
) -> Result<CogConfig, PrepError> {
    let ct_name = format!("{name}.ct");
    let mut files = 0;
    let mut bytes = 0;
    let mut put = |path: PathBuf, text: String| -> Result<(), PrepError> {
        fs::write(&path, &text).map_err(|e| PrepError::write(&path, e, text.len() as u64))?;
        files += 1;
        bytes += text.len() as u64;
        Ok(())
    };
    // Right after the version line: a `#clipmap` line inside a list (the `.ic`'s `tile_params`)
    // would be a comment line of the list.
    let with_lines = |text: String, lines: &str| match text.split_once('\n') {
        Some((version, rest)) => format!("{version}\n{lines}{rest}"),
        None => text + lines,
    };
    for level in layout.image_cache_levels() {
        put(root.join(Layout::ic_file(level.index)), with_lines(ic_text(layout, level, &ct_name), ic_lines))?;
    }
    put(root.join(&ct_name), with_lines(ct_text(layout, description, heights), ct_lines))?;
    Ok(CogConfig { ct: PathBuf::from(ct_name), files, bytes })
}
