//! The `#clipmap` extension of a `.ct` (docs/CONFIG.md §16): paging settings Performer 3.0
//! reads as a comment. Turns the syntax tree's extension lines into [`PagingOptions`], reporting
//! every line that says something this engine cannot use.

use super::fields::Reader;
use crate::config::{Severity, Span};
use crate::paging::{parse_bytes, EvictionKind, PagingOptions, PrefetchKind};

/// The settings an extension line may give.
pub(crate) const SETTINGS: [&str; 4] = ["prefetch", "eviction", "pool_bytes", "max_centre_step"];

/// The paging options of the file's `#clipmap` lines (the defaults where none is given; the
/// last of repeated settings wins).
pub fn read(r: &mut Reader<'_>) -> PagingOptions {
    let mut out = PagingOptions::default();
    let lines = r.file.extensions.clone();
    for line in &lines {
        let Some(key) = line.words.first() else {
            let d = r
                .diag(Severity::Error, "extension-empty", Some(line.span), "`#clipmap` without a setting")
                .expected(format!("one of {}", SETTINGS.join(", ")))
                .hint("write `#clipmap SETTING VALUE`, e.g. `#clipmap pool_bytes 256m`, or remove the line");
            r.push(d);
            continue;
        };
        let span = key.span;
        let Some(value) = line.words.get(1) else {
            let d = r
                .diag(Severity::Error, "missing-value", Some(span), format!("`#clipmap {}` has no value", key.value))
                .hint(format!("write `#clipmap {} VALUE` on one line", key.value));
            r.push(d);
            continue;
        };
        if let Some(extra) = line.words.get(2) {
            let d = r
                .diag(
                    Severity::Error,
                    "extension-extra-words",
                    Some(extra.span),
                    format!("`#clipmap {}` takes one value", key.value),
                )
                .found(extra.value.clone())
                .hint("one setting per `#clipmap` line");
            r.push(d);
        }
        let bad = |r: &mut Reader<'_>, at: Span, expected: String| {
            let d = r
                .diag(
                    Severity::Error,
                    "bad-extension-value",
                    Some(at),
                    format!("`{}` is no value for `#clipmap {}`", value.value, key.value),
                )
                .found(value.value.clone())
                .expected(expected);
            r.push(d);
        };
        match key.value.as_str() {
            "prefetch" => match value.value.parse::<PrefetchKind>() {
                Ok(p) => out.prefetch = p,
                Err(e) => bad(r, value.span, e.expected.to_string()),
            },
            "eviction" => match value.value.parse::<EvictionKind>() {
                Ok(e) => out.eviction = e,
                Err(e) => bad(r, value.span, e.expected.to_string()),
            },
            "pool_bytes" => match parse_bytes(&value.value) {
                Ok(n) => out.pool_bytes = n,
                Err(_) => bad(
                    r,
                    value.span,
                    "a byte count, optionally with k, m or g (KiB, MiB, GiB): 268435456 or 256m".into(),
                ),
            },
            "max_centre_step" => match value.value.parse::<u64>() {
                Ok(n) if n > 0 => out.max_centre_step = Some(n),
                _ if value.value == "off" => out.max_centre_step = None,
                _ => bad(r, value.span, "a whole number of level-0 texels above 0, or `off`".into()),
            },
            // The height lines (docs/CONFIG.md §17), read by `super::height`.
            other if super::height::SETTINGS.contains(&other) => {}
            // The COG line (docs/COG.md), read by `super::cog`.
            other if super::cog::SETTINGS.contains(&other) => {}
            // The tile-source line (docs/TILES.md), read by `super::source_line`.
            other if super::source_line::SETTINGS.contains(&other) => {}
            // The georeferencing lines (docs/GEOREF.md), read by `super::georef`.
            other if super::georef::SETTINGS.contains(&other) => {}
            other => {
                let mut d = r
                    .diag(
                        Severity::Error,
                        "unknown-extension",
                        Some(span),
                        format!("`{other}` is not a `#clipmap` setting"),
                    )
                    .found(other.to_string())
                    .expected(format!(
                        "one of {}, {}, {}, {}, {}",
                        SETTINGS.join(", "),
                        super::height::SETTINGS.join(", "),
                        super::cog::SETTINGS.join(", "),
                        super::source_line::SETTINGS.join(", "),
                        super::georef::SETTINGS.join(", ")
                    ));
                let best = SETTINGS
                    .iter()
                    .chain(&super::height::SETTINGS)
                    .chain(&super::cog::SETTINGS)
                    .chain(&super::source_line::SETTINGS)
                    .chain(&super::georef::SETTINGS)
                    .map(|s| (strsim::jaro_winkler(other, s), s))
                    .filter(|(score, _)| *score > 0.85)
                    .max_by(|a, b| a.0.total_cmp(&b.0));
                if let Some((_, s)) = best {
                    d = d.hint(format!("did you mean `{s}`?"));
                }
                r.push(d);
            }
        }
    }
    out
}
