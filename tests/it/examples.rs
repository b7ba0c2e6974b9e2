//! Every example configuration validates under `--strict`: each `.ct` anywhere under
//! `config_examples/` (with the `.ic` files it names), and each `.ic` that no `.ct` names, as a
//! standalone image cache. Subdirectories, such as a `prepared/` one, are included.

use clipmap::config::Diagnostics;
use clipmap::plan::{self, Env, LevelKind, Options};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            walk(&p, out);
        } else {
            out.push(p);
        }
    }
}

fn with_ext(files: &[PathBuf], ext: &str) -> Vec<PathBuf> {
    files.iter().filter(|p| p.extension().is_some_and(|e| e == ext)).cloned().collect()
}

fn canon(p: &Path) -> PathBuf {
    std::fs::canonicalize(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn strict_errors(mut d: Diagnostics) -> Option<String> {
    d.apply_mode(true);
    d.has_errors().then(|| d.items.iter().map(|x| format!("  {x}\n")).collect::<String>())
}

#[test]
fn every_example_validates_strictly() {
    let root = Path::new(env!("CLIPMAP_ROOT")).join("config_examples");
    let mut files = Vec::new();
    walk(&root, &mut files);
    // Examples are checked as the environment leaves them: variables take their defaults.
    let opts = Options { env: Env::isolated(), ..Options::default() };
    let mut failures = String::new();
    let mut named = BTreeSet::new();
    let cts = with_ext(&files, "ct");
    for ct in &cts {
        let l = plan::load_clip_texture(ct, &opts).expect("readable");
        if let Some(p) = &l.plan {
            for level in &p.levels {
                if let LevelKind::Icache(ic) = &level.kind {
                    if let Some(path) = &ic.path {
                        named.insert(canon(path));
                    }
                }
            }
        }
        if let Some(e) = strict_errors(l.diagnostics) {
            failures.push_str(&format!("{}:\n{e}", ct.display()));
        }
    }
    let standalone: Vec<_> = with_ext(&files, "ic").into_iter().filter(|p| !named.contains(&canon(p))).collect();
    for ic in &standalone {
        let l = plan::load_image_cache(ic, &opts).expect("readable");
        if let Some(e) = strict_errors(l.diagnostics) {
            failures.push_str(&format!("{} (standalone):\n{e}", ic.display()));
        }
    }
    assert!(failures.is_empty(), "examples failing --strict:\n{failures}");
    assert!(
        cts.len() + standalone.len() >= 9,
        "expected at least nine examples, found {} .ct and {} standalone .ic",
        cts.len(),
        standalone.len()
    );
    // Every level .ic is used by some .ct: no stray files.
    assert!(named.len() >= 13, "level .ic files named: {}", named.len());
}

#[test]
fn the_readme_lists_every_top_level_example() {
    let root = Path::new(env!("CLIPMAP_ROOT")).join("config_examples");
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    for e in std::fs::read_dir(&root).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if p.is_file() && (name.ends_with(".ct") || name.ends_with(".ic")) {
            assert!(readme.contains(&format!("`{name}`")), "config_examples/README.md does not list {name}");
        }
    }
}
