//! The floors of docs/ARCHITECTURE.md §12, checked against the code: every module of the library
//! names (`crate::X`) only modules on lower floors, so there is no circle and no import climbing
//! back up. Tests are left out (they may reach anything), as are comments (a doc link is not an
//! import).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The floor of each top-level module, as the table in docs/ARCHITECTURE.md §12 gives it.
const FLOORS: &[(&str, u32)] = &[
    ("tile", 1),
    ("texel", 1),
    ("geom", 1),
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
    let mut found = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        // `$crate::` in a macro names the crate too; another word ending in `crate` does not.
        let before = rest[..i].chars().last();
        rest = &rest[i + "crate::".len()..];
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

#[test]
fn every_module_names_only_modules_on_lower_floors() {
    let floors: BTreeMap<&str, u32> = FLOORS.iter().copied().collect();
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut wrong = Vec::new();
    let mut checked = 0;
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        let top = rel.components().next().unwrap().as_os_str().to_str().unwrap().trim_end_matches(".rs").to_string();
        let name = f.file_name().unwrap().to_str().unwrap();
        if top == "lib"
            || name == "tests.rs"
            || name.ends_with("_tests.rs")
            || rel.components().any(|c| c.as_os_str() == "tests")
        {
            continue;
        }
        let Some(&mine) = floors.get(top.as_str()) else {
            wrong.push(format!("{}: module `{top}` has no floor in ARCHITECTURE.md §12's table", rel.display()));
            continue;
        };
        for used in named_modules(&code_of(&std::fs::read_to_string(f).unwrap())) {
            if used == top {
                continue;
            }
            checked += 1;
            match floors.get(used.as_str()) {
                Some(&theirs) if theirs < mine => {}
                Some(&theirs) => wrong.push(format!(
                    "{}: `{top}` (floor {mine}) names `crate::{used}` (floor {theirs}): an import on its own floor or above",
                    rel.display()
                )),
                None => wrong.push(format!("{}: names `crate::{used}`, a module with no floor", rel.display())),
            }
        }
    }
    assert!(checked > 200, "only {checked} imports found: the scan is broken");
    assert!(wrong.is_empty(), "the house has imports against its floors:\n{}", wrong.join("\n"));
}

#[test]
fn the_scan_sees_grouped_and_plain_imports_and_skips_comments_and_tests() {
    let code = code_of(
        "use crate::{tile::TileId, geom};\nuse crate::shm::Region; // crate::demo\n/// [`crate::service`]\nfn f() { $crate::plan::x(); }\n#[cfg(test)]\nmod tests {\n    use crate::roam;\n}\n",
    );
    assert_eq!(named_modules(&code), ["tile", "geom", "shm", "plan"]);
}
