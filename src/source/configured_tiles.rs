//! A `.ct` naming a tile pyramid (`#clipmap source`, docs/TILES.md) checked against the pyramid,
//! as a `.ct` naming a COG is (`cog-mismatch`, `configured.rs`): the pyramid is opened with the
//! `.ct`'s clip size, as `clipmapd` serves it, and the `.ct`'s header must describe the texture
//! served: `virt_size` the pyramid's size (the tile size times 2 to the finest zoom) and the
//! formats its texel format (RGB8 for JPEG tiles, RGBA8 otherwise). Each disagreement is a
//! `source-mismatch` error at the field, naming the value written, the pyramid's, and the line
//! to write. (`tile_size` is not compared: the pyramid is served in its own tiles whatever the
//! `.ct` says, and `clipprep --input` writes the tile of a texture no larger than its clip size
//! as that size.)
//!
//! A pyramid that cannot be opened while the configuration is read is not reported here: the
//! service says why when it opens it to serve it (`super::open_plan`), as before.

use super::tiles::{self, OpenOptions, PyramidOptions, PyramidSource};
use super::TileSource;
use crate::config::{Diagnostic, Severity, Span, SyntaxFile, TokenId, Value};
use crate::plan::source_line::SourceLine;
use crate::plan::ClipTexturePlan;
use crate::texel::TexelFormat;
use std::path::Path;
use std::sync::Arc;

/// What the `.ct` at `file` (its syntax tree `tree`, its plan `plan`) says that the pyramid its
/// `#clipmap source` line names does not serve (empty when it cannot be opened), and the pyramid
/// as opened, for the source that serves it ([`pyramid_of`]).
pub(crate) fn check(
    file: &Path,
    tree: &SyntaxFile,
    plan: &ClipTexturePlan,
    line: &SourceLine,
) -> (Vec<Diagnostic>, Option<Arc<PyramidSource>>) {
    match tiles::open(&line.name, &options(plan)) {
        Some(Ok(src)) => (mismatches(file, tree, plan, line, &src), Some(Arc::new(src))),
        _ => (Vec::new(), None),
    }
}

/// How a `.ct`'s pyramid is opened: with the `.ct`'s clip size, as `clipmapd NAME --clip
/// CLIP_SIZE` opens it.
pub(crate) fn options(plan: &ClipTexturePlan) -> OpenOptions {
    OpenOptions {
        pyramid: PyramidOptions { clip_size: Some(plan.clip_size), ..Default::default() },
        ..Default::default()
    }
}

/// The pyramid a plan's `#clipmap source` line names, when the loader that checked the `.ct`
/// opened it.
pub(crate) fn pyramid_of(line: &SourceLine) -> Option<Arc<PyramidSource>> {
    line.opened.clone()?.downcast::<PyramidSource>().ok()
}

/// The pyramid's texture as the `.ct` would have to say it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Served {
    pub size: u64,
    pub tile: u64,
    pub texel: TexelFormat,
    pub min_zoom: u8,
    pub max_zoom: u8,
}

impl Served {
    fn of(src: &PyramidSource) -> Served {
        let info = src.info();
        Served {
            size: src.desc().size()[0],
            tile: u64::from(info.tile_size),
            texel: src.desc().format(),
            min_zoom: info.min_zoom,
            max_zoom: info.max_zoom,
        }
    }
}

fn mismatches(
    file: &Path,
    tree: &SyntaxFile,
    plan: &ClipTexturePlan,
    line: &SourceLine,
    src: &PyramidSource,
) -> Vec<Diagnostic> {
    let span = |id| tree.last(id).map(|e| e.span);
    let format_span = tree.first(TokenId::ExtFormat).or(tree.first(TokenId::ImgFormat)).map(|e| e.span);
    let size_span = match tree.last(TokenId::Size).map(|e| &e.value) {
        Some(Value::Int3(_)) => span(TokenId::Size),
        _ => None,
    };
    compare(plan.virt_size, plan.texel, Served::of(src))
        .into_iter()
        .map(|m| {
            let at = match m.field {
                Field::Size => size_span,
                Field::Format => format_span,
            };
            diagnostic(file, line, at, m)
        })
        .collect()
}

/// Which header field disagrees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Field {
    Size,
    Format,
}

/// One disagreement: the field, what is written, what the pyramid serves, the line to write.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Mismatch {
    pub field: Field,
    pub written: String,
    pub has: String,
    pub fix: String,
}

/// The header fields (`virt_size`, the texel format) against `served`.
pub(crate) fn compare(virt_size: [u64; 3], texel: TexelFormat, served: Served) -> Vec<Mismatch> {
    let mut out = Vec::new();
    let n = served.size;
    if [virt_size[0], virt_size[1]] != [n, n] {
        out.push(Mismatch {
            field: Field::Size,
            written: format!("virt_size {} {} {}", virt_size[0], virt_size[1], virt_size[2]),
            has: format!(
                "virt_size {n} {n} 1 (zooms {}..{} of {}-texel tiles: {} x 2^{} texels a side)",
                served.min_zoom, served.max_zoom, served.tile, served.tile, served.max_zoom
            ),
            fix: format!(
                "write `virt_size {n} {n} 1`, or name the pyramid this configuration was made for (`clipprep --input NAME` writes a matching one)"
            ),
        });
    }
    if texel != served.texel {
        let names = crate::plan::formats::names_of(served.texel)
            .map(|(e, i, m)| format!("ext_format {e}, int_format {i}, img_format {m}"))
            .unwrap_or_default();
        out.push(Mismatch {
            field: Field::Format,
            written: format!("{texel} texels"),
            has: format!("{} texels (RGB8 for JPEG tiles, RGBA8 otherwise): {names}", served.texel),
            fix: format!("write {names}"),
        });
    }
    out
}

fn diagnostic(file: &Path, line: &SourceLine, at: Option<Span>, m: Mismatch) -> Diagnostic {
    let field = match m.field {
        Field::Size => "virt_size",
        Field::Format => "ext_format / int_format / img_format",
    };
    Diagnostic::new(
        Severity::Error,
        "source-mismatch",
        file,
        at.or(Some(line.span)),
        format!(
            "`{field}` does not describe the tile source `{}` this file serves (line {})",
            crate::place::redacted(&line.written),
            line.span.line
        ),
    )
    .found(m.written)
    .expected(m.has)
    .hint(m.fix)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SERVED: Served = Served { size: 1024, tile: 256, texel: TexelFormat::RGBA8, min_zoom: 0, max_zoom: 2 };

    #[test]
    fn a_header_describing_the_pyramid_has_no_mismatch() {
        assert!(compare([1024, 1024, 1], TexelFormat::RGBA8, SERVED).is_empty());
    }

    #[test]
    fn size_and_format_each_say_what_the_pyramid_serves() {
        let m = compare([2048, 2048, 1], TexelFormat::RGB8, SERVED);
        assert_eq!(m.iter().map(|m| m.field).collect::<Vec<_>>(), [Field::Size, Field::Format]);
        assert_eq!(m[0].written, "virt_size 2048 2048 1");
        assert!(m[0].has.starts_with("virt_size 1024 1024 1 (zooms 0..2 of 256-texel tiles"), "{}", m[0].has);
        assert!(m[0].fix.contains("`virt_size 1024 1024 1`"), "{}", m[0].fix);
        assert!(m[1].written.starts_with("rgb8") && m[1].has.starts_with("rgba8"), "{m:?}");
    }
}
