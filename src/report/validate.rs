//! `validate`: load each file, report every finding, and say whether it is usable.

use crate::config::{Diagnostic, FileKind, Severity};
use crate::plan::{self, Options};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// The validation result of one file.
#[derive(Debug, Serialize)]
pub struct FileReport {
    /// The file as given.
    pub path: PathBuf,
    /// Its kind.
    pub kind: FileKind,
    /// True when no finding is an error.
    pub valid: bool,
    /// Number of errors.
    pub errors: usize,
    /// Number of warnings.
    pub warnings: usize,
    /// Number of notes.
    pub notes: usize,
    /// Every finding.
    pub diagnostics: Vec<Diagnostic>,
    /// Why the file could not be read at all (then nothing else is known).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unreadable: Option<String>,
    /// With `--ct-only`: the `.ic` file each image-cache level names, resolved (absolute,
    /// variables expanded) but not opened. Absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub icache_files: Option<Vec<NamedIcache>>,
    #[serde(skip)]
    rendered: String,
}

/// An `.ic` file a `.ct` names, not opened (`--ct-only`).
#[derive(Debug, Serialize)]
pub struct NamedIcache {
    /// The level.
    pub level: u32,
    /// The file, absolute, variables expanded.
    pub path: PathBuf,
}

/// The `.ic` files a `.ct`-only plan names, by level.
pub(crate) fn named_icaches(plan: &plan::ClipTexturePlan) -> Vec<NamedIcache> {
    plan.levels
        .iter()
        .filter_map(|l| match &l.kind {
            plan::LevelKind::IcacheNotOpened { path } => Some(NamedIcache { level: l.level, path: path.clone() }),
            _ => None,
        })
        .collect()
}

/// The validation result of several files.
#[derive(Debug, Serialize)]
pub struct Report {
    /// True when every file is valid.
    pub valid: bool,
    /// True when some file could not be read (exit status 2).
    pub could_not_run: bool,
    /// One entry per file.
    pub files: Vec<FileReport>,
}

impl Report {
    /// Exit status: 0 every file valid, 1 some file invalid, 2 some file unreadable.
    pub fn exit_code(&self) -> i32 {
        if self.could_not_run {
            2
        } else if self.valid {
            0
        } else {
            1
        }
    }

    /// The human form: every finding with its source line, then one line per file.
    pub fn human(&self, quiet: bool) -> String {
        let mut out = String::new();
        for f in &self.files {
            if !quiet || !f.valid {
                out.push_str(&f.rendered);
            }
            let status = match (&f.unreadable, f.valid) {
                (Some(why), _) => format!("cannot be read: {why}"),
                (None, true) => "valid".to_string(),
                (None, false) => "invalid".to_string(),
            };
            let counts =
                format!("{} error{}, {} warning{}", f.errors, plural(f.errors), f.warnings, plural(f.warnings));
            if !quiet || !f.valid {
                out.push_str(&format!("{}: {status} ({counts})\n", f.path.display()));
                if let Some(ics) = &f.icache_files {
                    let opened = if ics.is_empty() { " (none: tiles named by the .ct)" } else { ", not opened:" };
                    out.push_str(&format!("  .ct only; image cache files{opened}\n"));
                    for ic in ics {
                        out.push_str(&format!("    level {:<3} {}\n", ic.level, ic.path.display()));
                    }
                }
            }
        }
        out
    }
}

fn plural(n: usize) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}

/// Adds an error when a valid plan is not one the service serves: the very checks
/// [`crate::source::FileSource::new`] and the service make when `clipmapd` starts (level chain,
/// tile size and count bounds, every default tile a regular file of one tile, the image caches within
/// [`crate::limits::Limits::cache_bytes`]), so that `validate`, `check` and `clipmapd` accept
/// the same configurations.
fn servable(l: &mut plan::Loaded<plan::ClipTexturePlan>) {
    let Some(p) = &l.plan else { return };
    if let Some(why) = unservable(p) {
        let message = format!("the service cannot serve it: {why}");
        l.diagnostics.push(crate::config::Diagnostic::new(Severity::Error, "not-servable", &p.path, None, message));
    }
}

/// Why the service would refuse to start on `plan` (see [`servable`]), or `None`.
pub(crate) fn unservable(plan: &plan::ClipTexturePlan) -> Option<String> {
    unservable_shape(plan).or_else(|| {
        crate::source::open_plan(plan.clone(), &crate::limits::Limits::default()).err().map(|e| e.to_string())
    })
}

/// Why the service would refuse the texture's shape (its levels, tiles and windows), without
/// opening any file, or `None`.
pub fn unservable_shape(plan: &plan::ClipTexturePlan) -> Option<String> {
    let limits = crate::limits::Limits::default();
    // A configuration naming a COG serves the COG's texture (not opened: the open says why).
    let desc = match &plan.cog {
        Some(cog) => Ok(crate::source::TileSource::desc(crate::source::cog_of(cog)?.as_ref()).clone()),
        None => crate::source::file::texture_desc(plan),
    };
    match desc {
        Err(e) => Some(e.to_string()),
        Ok(desc) => {
            let shape = crate::clip::Clipmap::shape_for(&desc, &crate::clip::Settings::default());
            // A height texture's mapping also holds each level's tile ranges.
            match crate::shm::layout::place_with(&shape, plan.height.is_some()) {
                None => Some(crate::clip::ClipError::Memory(crate::shm::memory::shape_error(&shape)).to_string()),
                Some(p) => {
                    let (needed, limit) = (p.total_bytes, limits.cache_bytes as u64);
                    (needed > limit).then(|| crate::clip::ClipError::CacheBytes { needed, limit }.to_string())
                }
            }
        }
    }
}

/// Validates files of one kind. `strict` turns warnings and portability findings into errors.
pub fn run(paths: &[PathBuf], kind: FileKind, strict: bool, opts: &Options) -> Report {
    let files: Vec<FileReport> = paths.iter().map(|p| one(p, kind, strict, opts)).collect();
    Report { valid: files.iter().all(|f| f.valid), could_not_run: files.iter().any(|f| f.unreadable.is_some()), files }
}

fn one(path: &Path, kind: FileKind, strict: bool, opts: &Options) -> FileReport {
    type Finished = (crate::config::Diagnostics, String, Option<Vec<NamedIcache>>);
    fn finish<T>(mut l: plan::Loaded<T>, strict: bool, named: Option<Vec<NamedIcache>>) -> Finished {
        l.diagnostics.apply_mode(strict);
        let rendered = l.render();
        (l.diagnostics, rendered, named)
    }
    let loaded = match kind {
        FileKind::ClipTexture => crate::source::configured::load_clip_texture(path, opts).map(|mut l| {
            let named = opts.ct_only.then(|| l.plan.as_ref().map(named_icaches).unwrap_or_default());
            // A .ct-only plan is never served: whether its levels can be is for the full check.
            if !opts.ct_only {
                servable(&mut l);
            }
            finish(l, strict, named)
        }),
        FileKind::ImageCache => {
            crate::source::configured::load_image_cache(path, opts).map(|l| finish(l, strict, None))
        }
    };
    match loaded {
        Err(e) => FileReport {
            path: path.to_path_buf(),
            kind,
            valid: false,
            errors: 0,
            warnings: 0,
            notes: 0,
            diagnostics: vec![],
            unreadable: Some(e.source.to_string()),
            icache_files: None,
            rendered: String::new(),
        },
        Ok((diags, rendered, icache_files)) => FileReport {
            path: path.to_path_buf(),
            kind,
            valid: !diags.has_errors(),
            errors: diags.count(Severity::Error),
            warnings: diags.count(Severity::Warning),
            notes: diags.count(Severity::Note),
            diagnostics: diags.items,
            unreadable: None,
            icache_files,
            rendered,
        },
    }
}
