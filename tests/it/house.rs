//! The floors of docs/ARCHITECTURE.md §12, checked against the code: every module of the libraries
//! and the binaries names (`crate::X`, or `clipmap::X`, `clipmap_base::X`, `clipmap_shm::`,
//! `clipmap_service::` and `clipmap_tools::X` across the crates) only modules on lower floors, so
//! there is no circle and no import climbing back up; and each crate of the workspace depends only
//! on crates on lower floors (docs/ARCHITECTURE.md, "Crates"), so the crate graph enforces the
//! floors between crates. Tests are left out (they may reach anything), as are comments (a doc
//! link is not an import).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The floor of each top-level module, as the table in docs/ARCHITECTURE.md §12 gives it.
const FLOORS: &[(&str, u32)] = &[
    ("tile", 1),
    ("texel", 1),
    ("geom", 1),
    ("georef", 1),
    ("limits", 1),
    ("open", 1),
    ("save", 1),
    ("sizing", 1),
    ("place", 1),
    ("runtime", 1),
    ("height", 1),
    ("config", 2),
    ("paging", 2),
    ("plan", 3),
    ("source", 4),
    ("shm", 5),
    ("prep", 5),
    ("cache", 6),
    ("queue", 6),
    ("growing", 6),
    ("clip", 7),
    ("sample", 8),
    ("report", 8),
    ("cli", 9),
    ("service", 9),
    ("roam", 9),
    ("inspect", 10),
    ("accuracy", 10),
    ("demo", 11),
    // The binaries (apps/clipmap-tools/src/bin), above everything they run.
    ("bin", 12),
];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The code of a file without its comments and without its `#[cfg(test)]` part.
fn code_of(text: &str) -> String {
    let mut out = String::new();
    let mut lines = text.lines().peekable();
    while let Some(line) = lines.next() {
        let t = line.trim_start();
        // An inline test module ends what is checked (`mod tests;` names a file left out
        // above, and a lone `#[cfg(test)]` item is checked like the rest).
        if t.starts_with("#[cfg(test)]")
            && lines.peek().is_some_and(|n| n.trim_start().starts_with("mod ") && n.trim_end().ends_with('{'))
        {
            break;
        }
        if t.starts_with("//") {
            continue;
        }
        out.push_str(line.split(" // ").next().unwrap());
        out.push('\n');
    }
    out
}

/// The top-level modules a piece of code names through `crate::`, including `use crate::{a, b::c}`.
fn named_modules(code: &str) -> Vec<String> {
    named_through(code, "crate::")
}

/// The top-level modules a piece of code names through `prefix` (`crate::`, `clipmap_base::`),
/// including `use PREFIX{a, b::c}`.
fn named_through(code: &str, prefix: &str) -> Vec<String> {
    let mut found = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find(prefix) {
        // `$crate::` in a macro names the crate too; another word ending in `crate` does not.
        let before = rest[..i].chars().last();
        rest = &rest[i + prefix.len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        if let Some(group) = rest.strip_prefix('{') {
            let end = group.find('}').unwrap_or(group.len());
            for part in group[..end].split(',') {
                let name: String = part.trim().chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                if !name.is_empty() {
                    found.push(name);
                }
            }
        } else {
            let name: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
            found.push(name);
        }
    }
    found
}

/// Where the modules live: the root crate's `src/`, where each top-level module is a module of the
/// table; the ground floor's crate and the tools' library, the same; the mapping's crate and the
/// service's, all of whose files are one module (`shm`, `service`: their `crate::` names their own
/// parts); and the binaries, all on the floor `bin` (a binary's `crate::` names its own files).
const SOURCES: &[(&str, Option<&str>)] = &[
    ("src", None),
    ("crates/clipmap-base/src", None),
    ("crates/clipmap-shm/src", Some("shm")),
    ("apps/clipmap-service/src", Some("service")),
    ("apps/clipmap-tools/src", None),
    ("apps/clipmap-tools/src/bin", Some("bin")),
];

/// The modules a file names: through `crate::` (unless the whole crate is one module, `whole`),
/// and through the other crates' names.
fn names_in(code: &str, whole: Option<&str>) -> Vec<String> {
    let mut names = if whole.is_some() { Vec::new() } else { named_modules(code) };
    names.extend(named_through(code, "clipmap::"));
    names.extend(named_through(code, "clipmap_base::"));
    names.extend(named_through(code, "clipmap_shm::").into_iter().map(|_| "shm".to_string()));
    names.extend(named_through(code, "clipmap_service::").into_iter().map(|_| "service".to_string()));
    // `use clipmap_service;` or `clipmap_service::{self as service, ..}` names the crate itself.
    if code.contains("use clipmap_service") {
        names.push("service".to_string());
    }
    names.extend(named_through(code, "clipmap_tools::"));
    names
}

#[test]
fn every_module_names_only_modules_on_lower_floors() {
    let floors: BTreeMap<&str, u32> = FLOORS.iter().copied().collect();
    let root = Path::new(env!("CLIPMAP_ROOT"));
    let mut wrong = Vec::new();
    let mut checked = 0;
    let mut files_seen = 0;
    for &(dir, whole) in SOURCES {
        let src = root.join(dir);
        let mut files = Vec::new();
        rust_files(&src, &mut files);
        files.sort();
        files_seen += files.len();
        for f in &files {
            let rel = f.strip_prefix(root).unwrap();
            let in_crate = f.strip_prefix(&src).unwrap();
            let first = in_crate.components().next().unwrap().as_os_str().to_str().unwrap().trim_end_matches(".rs");
            let top = whole.unwrap_or(first).to_string();
            let name = f.file_name().unwrap().to_str().unwrap();
            // The binaries are scanned as their own entry (`bin`), not as the tools' library.
            if whole.is_none() && first == "bin" && dir == "apps/clipmap-tools/src" {
                continue;
            }
            if (whole.is_none() && first == "lib")
                || name == "tests.rs"
                || name.ends_with("_tests.rs")
                || in_crate.components().any(|c| c.as_os_str() == "tests")
            {
                continue;
            }
            let Some(&mine) = floors.get(top.as_str()) else {
                wrong.push(format!("{}: module `{top}` has no floor in ARCHITECTURE.md §12's table", rel.display()));
                continue;
            };
            for used in names_in(&code_of(&std::fs::read_to_string(f).unwrap()), whole) {
                if used == top {
                    continue;
                }
                checked += 1;
                match floors.get(used.as_str()) {
                    Some(&theirs) if theirs < mine => {}
                    Some(&theirs) => wrong.push(format!(
                        "{}: `{top}` (floor {mine}) names `{used}` (floor {theirs}): an import on its own floor or above",
                        rel.display()
                    )),
                    None => wrong.push(format!("{}: names `crate::{used}`, a module with no floor", rel.display())),
                }
            }
        }
    }
    assert!(files_seen > 120, "only {files_seen} files found: the scan is broken");
    assert!(checked > 200, "only {checked} imports found: the scan is broken");
    assert!(wrong.is_empty(), "the house has imports against its floors:\n{}", wrong.join("\n"));
}

/// The floor of each crate of the workspace (docs/ARCHITECTURE.md, "Crates"): a crate depends
/// only on crates on lower floors.
const CRATE_FLOORS: &[(&str, &str, u32)] = &[
    ("clipmap-base", "crates/clipmap-base", 1),
    ("clipmap-shm", "crates/clipmap-shm", 2),
    ("clipmap", ".", 3),
    ("clipmap-service", "apps/clipmap-service", 4),
    ("clipmap-tools", "apps/clipmap-tools", 5),
    ("clipgpu", "clipgpu", 5),
];

/// The names in a `[workspace]`'s `members = [...]` list of a Cargo.toml.
fn workspace_members(toml: &str) -> Vec<String> {
    let at = toml.find("\nmembers = [").expect("a workspace members list") + "\nmembers = [".len();
    let end = at + toml[at..].find(']').expect("the list's end");
    toml[at..end].split(',').map(|m| m.trim().trim_matches('"').to_string()).filter(|m| !m.is_empty()).collect()
}

/// The crates a Cargo.toml depends on, in any dependency table (normal, dev, build, per target).
fn dependencies(toml: &str) -> Vec<String> {
    let mut deps = Vec::new();
    let mut in_deps = false;
    for line in toml.lines().map(str::trim) {
        if line.starts_with('[') {
            let table = line.trim_matches(|c| c == '[' || c == ']');
            in_deps = table.split('.').any(|part| part.ends_with("dependencies"));
            continue;
        }
        if in_deps && !line.starts_with('#') {
            if let Some((name, _)) = line.split_once('=') {
                deps.push(name.trim().trim_matches('"').to_string());
            }
        }
    }
    deps
}

#[test]
fn each_crate_depends_only_on_crates_on_lower_floors() {
    let root = Path::new(env!("CLIPMAP_ROOT"));
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).unwrap();
    let mut members = workspace_members(&manifest);
    members.sort();
    let mut known: Vec<String> = CRATE_FLOORS.iter().map(|c| c.1.to_string()).collect();
    known.sort();
    assert_eq!(members, known, "every crate of the workspace has a floor in CRATE_FLOORS (and ARCHITECTURE.md)");
    let floor_of: BTreeMap<&str, u32> = CRATE_FLOORS.iter().map(|c| (c.0, c.2)).collect();
    let mut wrong = Vec::new();
    let mut edges = Vec::new();
    for &(name, dir, mine) in CRATE_FLOORS {
        let toml = std::fs::read_to_string(root.join(dir).join("Cargo.toml")).unwrap();
        assert!(toml.contains(&format!("name = \"{name}\"")), "{dir}/Cargo.toml is crate {name}");
        for dep in dependencies(&toml) {
            let Some(&theirs) = floor_of.get(dep.as_str()) else { continue };
            edges.push(format!("{name} -> {dep}"));
            if theirs >= mine {
                wrong.push(format!(
                    "{dir}/Cargo.toml: `{name}` (floor {mine}) depends on `{dep}` (floor {theirs}): a crate on its own floor or above"
                ));
            }
        }
    }
    assert!(wrong.is_empty(), "the crates depend against their floors:\n{}", wrong.join("\n"));
    for edge in [
        "clipmap-shm -> clipmap-base",
        "clipmap -> clipmap-shm",
        "clipmap-service -> clipmap",
        "clipmap-tools -> clipmap-service",
        "clipgpu -> clipmap",
    ] {
        assert!(edges.iter().any(|e| e == edge), "`{edge}` not found in {edges:?}: the scan is broken");
    }
}

#[test]
fn the_crate_scan_sees_every_dependency_table() {
    let toml = "[package]\nname = \"x\"\n[dependencies]\nclipmap-base = { path = \"a\" }\n# clipmap = {}\n[dev-dependencies]\nclipmap-shm = \"1\"\n[target.'cfg(unix)'.dependencies]\nclipgpu = \"1\"\n[features]\nclipmap = []\n";
    assert_eq!(dependencies(toml), ["clipmap-base", "clipmap-shm", "clipgpu"]);
    assert_eq!(
        names_in("use clipmap_base::{geom, tile::TileId};\nuse crate::layout;\npub use clipmap_shm::*;\n", Some("shm")),
        ["geom", "tile", "shm"]
    );
    assert_eq!(
        names_in(
            "use clipmap::{clip, source::TileId};\nuse crate::views;\nuse clipmap_service::Options;\nuse clipmap_tools::demo;\n",
            Some("bin")
        ),
        ["clip", "source", "service", "service", "demo"]
    );
}

#[test]
fn the_scan_sees_grouped_and_plain_imports_and_skips_comments_and_tests() {
    let code = code_of(
        "use crate::{tile::TileId, geom};\nuse crate::shm::Region; // crate::demo\n/// [`crate::service`]\nfn f() { $crate::plan::x(); }\n#[cfg(test)]\nmod tests {\n    use crate::roam;\n}\n",
    );
    assert_eq!(named_modules(&code), ["tile", "geom", "shm", "plan"]);
}
