//! The tile-source line of the `#clipmap` extension (docs/CONFIG.md §19, docs/TILES.md): a
//! `.ct` whose texels come from a tile pyramid served as it is, a tile service or tree named by
//! a template (`xyz:TEMPLATE`), a PMTiles or an MBTiles archive, named by
//! `#clipmap source NAME`. Performer 3.0 reads the line as a comment and would read the tile
//! files the rest of the configuration names (none exist for a tile source), so the line is a
//! portability note (an error under `validate --strict`).
//!
//! This floor reads the line and anchors a local name to the configuration's directory; the
//! source floor opens it (`crate::source::open_plan`) with the `.ct`'s clip size.

use super::fields::Reader;
use super::{portability, Options};
use crate::config::{Severity, Span};
use crate::place::Place;
use serde::Serialize;
use std::any::Any;
use std::path::Path;
use std::sync::Arc;

/// The settings a tile-source line may give.
pub(crate) const SETTINGS: [&str; 1] = ["source"];

/// The tile pyramid a `.ct` names.
#[derive(Clone, Serialize)]
pub struct SourceLine {
    /// The name as written on the `#clipmap source` line.
    pub written: String,
    /// The name opened: `xyz:` and a template, or a `.pmtiles` / `.mbtiles` path or URL, a
    /// relative local path anchored to the configuration file's directory and `$VAR` expanded.
    pub name: String,
    /// Where the value is written.
    #[serde(skip)]
    pub span: Span,
    /// The pyramid as it was opened when the configuration was loaded and checked against it,
    /// kept for the source that serves it (`crate::source::open_plan`), so a remote archive is
    /// opened once; `None` when not opened.
    #[serde(skip)]
    pub opened: Option<Arc<dyn Any + Send + Sync>>,
}

impl std::fmt::Debug for SourceLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SourceLine")
            .field("written", &self.written)
            .field("name", &self.name)
            .field("span", &self.span)
            .field("opened", &self.opened.is_some())
            .finish()
    }
}

/// Whether `name` names a tile pyramid: `xyz:TEMPLATE`, or a name ending in `.pmtiles` or
/// `.mbtiles` (any case; a URL's query left out).
pub fn names_pyramid(name: &str) -> bool {
    name.starts_with("xyz:")
        || matches!(Place::parse(name).extension().map(str::to_ascii_lowercase).as_deref(), Some("pmtiles" | "mbtiles"))
}

/// `name` with a relative local path anchored to `dir` (a template's text before its first
/// placeholder is a path like any other).
fn anchored(dir: &Path, name: &str) -> String {
    let (prefix, rest) = match name.strip_prefix("xyz:") {
        Some(t) => ("xyz:", t),
        None => ("", name),
    };
    match Place::anchored(dir, rest) {
        Place::Local(p) => format!("{prefix}{}", p.display()),
        Place::Remote(_) => name.to_string(),
    }
}

/// Reads the file's `#clipmap source` line. `None` when there is none, or its value names no
/// tile pyramid (an error at the line); a second line is an error too.
pub(crate) fn read(r: &mut Reader<'_>, dir: &Path, opts: &Options) -> Option<SourceLine> {
    let (value, span) = r.single_extension("source", "one tile source for the clip texture")?;
    let d = r
        .diag(
            Severity::Note,
            "source-extension",
            Some(span),
            format!(
                "`#clipmap source` serves the clip texture's texels from the tile source `{}`, which Performer 3.0 does not know",
                crate::place::redacted(&value.value)
            ),
        )
        .hint("Performer reads `#clipmap` lines as comments and would read the tile files this configuration names instead (none are written for a tile source); keep the line for this engine (docs/TILES.md)");
    r.push(portability(d));
    let expanded = super::env::expand(&value.value, &opts.env).value;
    if !names_pyramid(&expanded) {
        let d = r
            .diag(
                Severity::Error,
                "bad-extension-value",
                Some(value.span),
                "`#clipmap source` names no tile source",
            )
            .found(crate::place::redacted(&value.value).into_owned())
            .expected("`xyz:` and a URL or path template (xyz:https://tile.example.org/{z}/{x}/{y}.png), or a .pmtiles or .mbtiles path or URL")
            .hint("for a GeoTIFF or COG, write `#clipmap cog PATH` instead");
        r.push(d);
        return None;
    }
    Some(SourceLine { written: value.value, name: anchored(dir, &expanded), span: value.span, opened: None })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pyramids_are_told_by_prefix_or_suffix_and_local_names_are_anchored() {
        assert!(names_pyramid("xyz:tiles/{z}/{x}/{y}.png") && names_pyramid("a.PMTiles") && names_pyramid("b.mbtiles"));
        assert!(
            names_pyramid("https://h/w.pmtiles?sig=1") && !names_pyramid("earth.tif") && !names_pyramid("tiles/{z}")
        );
        let dir = Path::new("/cfg");
        assert_eq!(anchored(dir, "xyz:tiles/{z}/{x}/{y}.png"), "xyz:/cfg/tiles/{z}/{x}/{y}.png");
        assert_eq!(anchored(dir, "xyz:/abs/{z}/{x}/{y}.png"), "xyz:/abs/{z}/{x}/{y}.png");
        assert_eq!(
            anchored(dir, "xyz:https://t.example.org/{z}/{x}/{y}.png"),
            "xyz:https://t.example.org/{z}/{x}/{y}.png"
        );
        assert_eq!(anchored(dir, "../w.pmtiles"), "/cfg/../w.pmtiles");
        assert_eq!(anchored(dir, "s3://b/w.pmtiles"), "s3://b/w.pmtiles");
    }
}
