//! The COG line of the `#clipmap` extension (docs/CONFIG.md §18, docs/COG.md): a `.ct` or `.ic`
//! whose texels come from a tiled GeoTIFF or Cloud-Optimized GeoTIFF served as it is, named by
//! `#clipmap cog PATH_OR_URL`. Performer 3.0 reads the line as a comment and would read the
//! tile files the rest of the configuration names (none exist for a COG), so the line is a
//! portability note (an error under `validate --strict`).
//!
//! This floor reads the line and anchors the name; opening the COG and checking the header
//! against it (`virt_size` the COG's size rounded up to powers of two, the formats, every
//! `tile_size`, the heights) is the business of the floor that reads COGs,
//! [`crate::source::configured`], whose loaders every tool uses.

use super::fields::Reader;
use super::naming::{anchor, expand_field};
use super::{portability, Options};
use crate::config::{Severity, Span, SyntaxFile};
use crate::place::Place;
use crate::texel::TexelFormat;
use serde::Serialize;
use std::any::Any;
use std::path::Path;
use std::sync::Arc;

/// The settings a COG line may give.
pub(crate) const SETTINGS: [&str; 1] = ["cog"];

/// The COG a configuration names, and (once opened and checked) what it is.
#[derive(Clone, Serialize)]
pub struct CogPlan {
    /// The name as written on the `#clipmap cog` line.
    pub written: String,
    /// Where it is: a local path (a relative one anchored to the configuration file's
    /// directory, `$VAR` expanded) or a remote location (http://, https://, s3://).
    pub place: Place,
    /// The COG's level-0 size in texels, once opened.
    pub size: Option<[u64; 2]>,
    /// The texel format it is served as, once opened.
    pub format: Option<TexelFormat>,
    /// For a standalone `.ic`: the COG level it describes (the level whose size, rounded up to
    /// powers of two, is the `icache_size`). `None` for a `.ct` (every level) and an `.ic` read
    /// as a level of a `.ct` (that level).
    pub level: Option<u32>,
    /// Where the value is written.
    #[serde(skip)]
    pub span: Span,
    /// The source the COG was opened as when the configuration was loaded and checked, kept for
    /// the source that serves it ([`crate::source::open_plan`]); `None` when not opened.
    #[serde(skip)]
    pub opened: Option<Arc<dyn Any + Send + Sync>>,
}

impl std::fmt::Debug for CogPlan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CogPlan")
            .field("place", &self.place)
            .field("size", &self.size)
            .field("format", &self.format)
            .field("level", &self.level)
            .field("opened", &self.opened.is_some())
            .finish_non_exhaustive()
    }
}

/// Reads the file's `#clipmap cog` line (lines without a value were reported by the paging
/// reader of a `.ct`, which reads every `#clipmap` line's shape). `None` when there is none.
pub(crate) fn read(r: &mut Reader<'_>, dir: &Path, opts: &Options, what: &str) -> Option<CogPlan> {
    let (value, span) = r.single_extension("cog", &format!("one COG for {what}"))?;
    let d = r
        .diag(
            Severity::Note,
            "cog-extension",
            Some(span),
            format!("`#clipmap cog` serves {what}'s texels from the COG `{}`, which Performer 3.0 does not know", value.value),
        )
        .hint("Performer reads `#clipmap` lines as comments and would read the tile files this configuration names instead (none are written for a COG); keep the line for this engine (docs/COG.md)");
    r.push(portability(d));
    let expanded = expand_field(r, &value, &opts.env);
    Some(CogPlan {
        written: value.value,
        place: anchor(dir, &expanded),
        size: None,
        format: None,
        level: None,
        span: value.span,
        opened: None,
    })
}

/// The COG the first `#clipmap cog` line of `file` names, anchored and expanded as `read`
/// does, without a word about it (for the checks of [`crate::source::configured`], which read
/// the file again whether or not it gave a plan).
pub fn named(file: &SyntaxFile, opts: &Options) -> Option<CogPlan> {
    let value = file.extensions.iter().find_map(|l| match (l.words.first(), l.words.get(1)) {
        (Some(k), Some(v)) if k.value == "cog" => Some(v.clone()),
        _ => None,
    })?;
    let dir = file.path.parent().map(Path::to_path_buf).unwrap_or_default();
    let expanded = super::env::expand(&value.value, &opts.env).value;
    Some(CogPlan {
        written: value.value,
        place: anchor(&dir, &expanded),
        size: None,
        format: None,
        level: None,
        span: value.span,
        opened: None,
    })
}

/// The size Performer needs for a COG of `size` texels: each side rounded up to a power of two.
pub fn rounded_size(size: [u64; 2]) -> [u64; 2] {
    [size[0].next_power_of_two(), size[1].next_power_of_two()]
}

/// In an `.ic` read as a level of a `.ct`: its `#clipmap cog` line, when it has one, must name
/// the `.ct`'s COG (`ct_cog`).
pub(crate) fn check_level_line(r: &mut Reader<'_>, line: Option<&CogPlan>, ct_cog: Option<&Place>, level: u32) {
    let Some(c) = line else { return };
    match ct_cog {
        Some(place) if *place != c.place => {
            let d = r
                .diag(
                    Severity::Error,
                    "cog-differs",
                    Some(c.span),
                    "`#clipmap cog` names another COG than the clip texture's",
                )
                .found(c.place.to_string())
                .expected(format!("{place} (the `.ct`'s `#clipmap cog`)"))
                .hint("name the same COG in the .ct and its .ic files, or remove the line from the .ic");
            r.push(d);
        }
        Some(_) => {}
        None => {
            let d = r
                .diag(
                    Severity::Error,
                    "cog-without-ct",
                    Some(c.span),
                    format!("`#clipmap cog` in an image cache of a clip texture that names no COG (level {level})"),
                )
                .found(c.written.clone())
                .expected("the same `#clipmap cog` line in the .ct, whose texels it serves")
                .hint("add the line to the .ct, or remove it from the .ic");
            r.push(d);
        }
    }
}
