//! Feeds arbitrary bytes through every stage a user's file goes through: both parsers, both plan
//! builders (through a file, as the tools read it), the reports the tools print, and tile
//! location. Shared by the property tests, the regression replay and the fuzz target; it panics
//! only when an invariant is broken.

use clipmap::config::{self, FileKind, Limits, Severity};
use clipmap::plan::{self, Env, Options};
use clipmap::report::info;
use std::path::Path;

/// Findings of a parse are bounded by the limit (plus the one that says it stopped).
fn check_parse(bytes: &[u8], kind: FileKind, limits: &Limits) {
    let (file, d) = config::parse_bytes(bytes, Path::new("fuzz.cfg"), kind, limits);
    assert!(d.items.len() <= limits.max_diagnostics, "{} findings for {} bytes", d.items.len(), bytes.len());
    assert!(file.entries.len() <= limits.max_entries + 1);
    for x in &d.items {
        let _ = x.render(Some(bytes));
        if let Some(s) = x.span {
            assert!(s.offset <= bytes.len() && s.line >= 1 && s.col >= 1);
        }
    }
}

/// Runs `bytes` through everything, writing them as `dir/fuzz.ct` and `dir/fuzz.ic`.
/// `dir` may hold level `.ic` files for the `.ct` to name.
pub fn exercise(bytes: &[u8], dir: &Path) {
    let opts = Options {
        env: {
            let mut e = Env::isolated();
            e.set("SET", "/set").set("EMPTY", "").set("COLON", "a:b");
            e
        },
        limits: Limits::default(),
        ct_only: false,
    };
    check_parse(bytes, FileKind::ClipTexture, &opts.limits);
    check_parse(bytes, FileKind::ImageCache, &opts.limits);

    let ct = dir.join("fuzz.ct");
    std::fs::write(&ct, bytes).expect("write");
    // The .ct alone (`--ct-only`) takes the same path without opening any .ic: it must not
    // panic either, and every level it names stays addressable.
    let alone = plan::load_clip_texture(&ct, &Options { ct_only: true, ..opts.clone() }).expect("readable");
    if let Some(p) = &alone.plan {
        let _ = info::clip_texture_human(p);
        serde_json::to_string(&info::clip_texture(p, &[])).expect("serialises");
    }
    let l = plan::load_clip_texture(&ct, &opts).expect("readable");
    let _ = l.render();
    match &l.plan {
        Some(p) => {
            assert!(!l.diagnostics.has_errors());
            let warnings = info::non_errors(&l.diagnostics.items);
            let _ = info::clip_texture_human(p);
            serde_json::to_string(&info::clip_texture(p, &warnings)).expect("serialises");
            for level in 0..=p.levels.len() as u32 {
                for (s, t) in [(0, 0), (1, 1), (u64::MAX, 0), (7, 3)] {
                    if let Ok(loc) = p.locate(level, s, t) {
                        // Names are anchored, unless they are remote locations (URLs).
                        assert!(loc.path.as_local().is_none_or(|p| p.is_absolute()), "{}", loc.path);
                    }
                }
            }
        }
        None => assert!(l.diagnostics.has_errors(), "no plan but no error:\n{}", l.render()),
    }

    let ic = dir.join("fuzz.ic");
    std::fs::write(&ic, bytes).expect("write");
    let l = plan::load_image_cache(&ic, &opts).expect("readable");
    let _ = l.render();
    match &l.plan {
        Some(p) => {
            let warnings = info::non_errors(&l.diagnostics.items);
            let _ = info::image_cache_human(p);
            serde_json::to_string(&info::image_cache(p, &warnings)).expect("serialises");
            let n = p.tile_count();
            for (s, t) in [(0, 0), (n[0] - 1, n[1] - 1), (n[0], 0), (3, 5)] {
                let _ = p.locate(s, t, 0);
                let _ = p.locate_with(s, t, 0, |a, i| a * 7 + i);
            }
        }
        None => assert!(l.diagnostics.items.iter().any(|d| d.severity == Severity::Error)),
    }
}
