//! Each crate's `pub` is a chosen API (docs/ARCHITECTURE.md, "Crates"): the public modules of
//! every library crate of the workspace (each `pub mod` reached from its `lib.rs` through public
//! modules only) and the re-exports of its `lib.rs` are the lists below. A module that no other
//! crate uses is `pub(crate)`, so a new public module or root re-export is a deliberate change:
//! it fails here until it is written in the list (and in the crate's `lib.rs` table).

use std::path::{Path, PathBuf};

/// The chosen API of each library crate: its directory, then its public modules (by path) and
/// the re-exports of its `lib.rs` (`use` and the path, groups written out one name each).
const API: &[(&str, &[&str])] = &[
    (
        "crates/clipmap-base",
        &[
            "mod geom",
            "mod georef",
            "mod height",
            "mod limits",
            "mod open",
            "mod save",
            "mod sizing",
            "mod texel",
            "mod tile",
        ],
    ),
    (
        "crates/clipmap-shm",
        &[
            "mod blocks",
            "mod client",
            "mod georef",
            "mod layout",
            "mod layout::desc",
            "mod layout::georef",
            "mod layout::growth",
            "mod layout::header",
            "mod layout::range",
            "mod layout::request",
            "mod layout::request_lock",
            "mod layout::snapshot",
            "mod layout::state",
            "mod layout::tag",
            "mod layout::views",
            "mod memory",
            "mod names",
            "mod verify",
            "mod writer",
            "use client::Client",
            "use client::LevelState",
            "use client::ReadError",
            "use client::RequestPosition",
            "use client::Snapshot",
            "use georef::GeorefBlock",
            "use memory::ImageMemory",
            "use memory::Publication",
            "use memory::PublishedLevel",
            "use memory::SlotKeeper",
            "use raw::Region",
            "use writer::Writer",
            "use writer::WriterOptions",
        ],
    ),
    (
        ".",
        &[
            "mod accuracy",
            "mod accuracy::formats",
            "mod accuracy::heights",
            "mod accuracy::render",
            "mod accuracy::study",
            "mod accuracy::sweep",
            "mod cli",
            "mod clip",
            "mod config",
            "mod config::tokens",
            "mod growing",
            "mod growing::index",
            "mod growing::input",
            "mod growing::rebuild",
            "mod growing::serve",
            "mod growing::store",
            "mod growing::watch",
            "mod paging",
            "mod paging::adaptive",
            "mod place",
            "mod plan",
            "mod plan::cog",
            "mod plan::georef",
            "mod plan::params",
            "mod plan::printf",
            "mod plan::source_line",
            "mod prep",
            "mod prep::cog",
            "mod prep::cog_config",
            "mod prep::error",
            "mod prep::jpeg_check",
            "mod prep::layout",
            "mod prep::output",
            "mod prep::publish",
            "mod prep::source",
            "mod prep::tiff_stream",
            "mod queue",
            "mod queue::priority",
            "mod report",
            "mod report::check",
            "mod report::dump",
            "mod report::exit",
            "mod report::hypsometric",
            "mod report::info",
            "mod report::label",
            "mod report::picture",
            "mod report::plan",
            "mod report::validate",
            "mod roam",
            "mod runtime",
            "mod sample",
            "mod sample::blocks",
            "mod shm",
            "mod shm::shared_reads",
            "mod source",
            "mod source::cog",
            "mod source::configured",
            "mod source::merge",
            "mod source::procedural",
            "mod source::range",
            "mod source::range::reader",
            "mod source::remote",
            "mod source::remote::disk",
            "mod source::remote::flight",
            "mod source::remote::http",
            "mod source::remote::object",
            "mod source::remote::options",
            "mod source::remote::range",
            "mod source::remote::s3",
            "mod source::remote::seen",
            "mod source::tiles",
            "mod source::tiles::mbtiles",
            "mod source::tiles::pmtiles",
            "mod source::tiles::pmtiles::directory",
            "mod source::tiles::pyramid",
            "use clipmap_base::geom",
            "use clipmap_base::georef",
            "use clipmap_base::height",
            "use clipmap_base::limits",
            "use clipmap_base::open",
            "use clipmap_base::save",
            "use clipmap_base::sizing",
            "use clipmap_base::texel",
            "use clipmap_base::tile",
        ],
    ),
    (
        "apps/clipmap-service",
        &[
            "mod stats",
            "use clipmap::source::Procedural",
            "use clipmap::source::TERRAIN_SEED",
            "use options::ControlLimits",
            "use options::Options",
            "use options::ViewOption",
            "use options::default_socket",
            "use stats::ServiceStats",
            "use ticker::Started",
        ],
    ),
    ("apps/clipmap-tools", &["mod demo", "mod inspect", "mod inspect::attach", "mod inspect::live_dump"]),
];

/// A file's text without comments (line comments and doc comments).
fn code_of(text: &str) -> String {
    text.lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .map(|l| l.split(" // ").next().unwrap())
        .collect::<Vec<_>>()
        .join("\n")
}

/// The statements of a piece of code that start with `pub mod` or `pub use` (each through its
/// `;` or, for an inline module, its `{`), whitespace squeezed out; `pub(crate)` is not `pub`.
fn pub_statements(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find("pub ") {
        let before_ok = i == 0 || !rest.as_bytes()[i - 1].is_ascii_alphanumeric() && rest.as_bytes()[i - 1] != b'_';
        let after = rest[i + 4..].trim_start();
        rest = &rest[i + 4..];
        if !before_ok || !(after.starts_with("mod ") || after.starts_with("use ")) {
            continue;
        }
        // A module ends at its `;` or, inline, its `{`; a re-export (braces and all) at its `;`.
        let end = if after.starts_with("mod ") { after.find([';', '{']) } else { after.find(';') };
        let stmt = &after[..end.unwrap_or(after.len())];
        out.push(stmt.split_whitespace().collect::<Vec<_>>().join(" ").replace(" ::", "::").replace(":: ", "::"));
    }
    out
}

/// A `use` tree written out one path each: `a::{b, c::{d, e}}` -> `a::b`, `a::c::d`, `a::c::e`.
fn expand(tree: &str) -> Vec<String> {
    let tree = tree.trim();
    let Some(open) = tree.find('{') else {
        return vec![tree.split_whitespace().collect::<Vec<_>>().join(" ")];
    };
    let prefix = tree[..open].trim().trim_end_matches("::");
    let inner = &tree[open + 1..tree.rfind('}').unwrap()];
    let (mut parts, mut depth, mut start) = (Vec::new(), 0, 0);
    for (i, c) in inner.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&inner[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push(&inner[start..]);
    parts
        .into_iter()
        .filter(|p| !p.trim().is_empty())
        .flat_map(expand)
        .map(|p| if p == "self" { prefix.to_string() } else { format!("{prefix}::{p}") })
        .collect()
}

/// The file of module `name` declared in `file` (`x.rs` or `x/mod.rs` beside a `lib.rs` or
/// `mod.rs`, under `stem/` beside any other file).
fn module_file(file: &Path, name: &str) -> Option<PathBuf> {
    let dir = file.parent().unwrap();
    let stem = file.file_stem().unwrap().to_str().unwrap();
    let base = if stem == "lib" || stem == "mod" { dir.to_path_buf() } else { dir.join(stem) };
    [base.join(format!("{name}.rs")), base.join(name).join("mod.rs")].into_iter().find(|p| p.exists())
}

/// The public API of the crate whose `lib.rs` is `lib`: `mod PATH` for each public module reached
/// through public modules, `use PATH` for each re-export of `lib.rs`, sorted.
fn api_of(lib: &Path) -> Vec<String> {
    fn walk(file: &Path, path: &str, lib: bool, out: &mut Vec<String>) {
        for stmt in pub_statements(&code_of(&std::fs::read_to_string(file).unwrap())) {
            if let Some(name) = stmt.strip_prefix("mod ") {
                let name = name.trim();
                let full = if path.is_empty() { name.to_string() } else { format!("{path}::{name}") };
                out.push(format!("mod {full}"));
                if let Some(sub) = module_file(file, name) {
                    walk(&sub, &full, false, out);
                }
            } else if lib {
                let tree = stmt.strip_prefix("use ").unwrap();
                out.extend(expand(tree).into_iter().map(|p| format!("use {}", p.split(" as ").next().unwrap())));
            }
        }
    }
    let mut out = Vec::new();
    walk(lib, "", true, &mut out);
    out.sort();
    out
}

#[test]
fn each_crate_exposes_only_its_chosen_api() {
    let root = Path::new(env!("CLIPMAP_ROOT"));
    let mut wrong = Vec::new();
    for &(dir, chosen) in API {
        let found = api_of(&root.join(dir).join("src/lib.rs"));
        let mut chosen: Vec<String> = chosen.iter().map(|s| s.to_string()).collect();
        chosen.sort();
        for f in found.iter().filter(|f| !chosen.contains(f)) {
            wrong.push(format!(
                "{dir}: `pub {f}` is public but not in the crate's chosen API: make it `pub(crate)` if no other \
                 crate needs it, or add \"{f}\" to `API` in tests/it/api.rs and say what it is for in the crate's \
                 lib.rs (and docs/ARCHITECTURE.md, \"Crates\")"
            ));
        }
        for c in chosen.iter().filter(|c| !found.contains(c)) {
            wrong.push(format!(
                "{dir}: \"{c}\" is in the chosen API (tests/it/api.rs) but the crate no longer declares it \
                 `pub`: remove it from `API` there and from the crate's lib.rs table if that is meant"
            ));
        }
    }
    assert!(wrong.is_empty(), "the crates' public APIs differ from the chosen ones:\n{}", wrong.join("\n"));
}

#[test]
fn the_api_scan_sees_modules_groups_and_skips_crate_visibility_and_comments() {
    let code = code_of(
        "//! pub mod doc;\npub mod a;\npub(crate) mod b;\nmod c;\npub mod exit {\n}\n\
         pub use x::{y, z::{self, w as v}};\npub(crate) use q::r;\n// pub use s::t;\nfn f() { let pub_x = 1; }\n",
    );
    let stmts = pub_statements(&code);
    assert_eq!(stmts, ["mod a", "mod exit", "use x::{y, z::{self, w as v}}"]);
    assert_eq!(expand("x::{y, z::{self, w as v}}"), ["x::y", "x::z", "x::z::w as v"]);
}
