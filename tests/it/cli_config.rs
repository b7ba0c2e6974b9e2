//! The `cliptex` and `icache` binaries, run for real from a working directory other than the
//! configuration's: exit statuses, `--strict`, `--json`, `info`, `tile`, `--env`/`--unset`, and the
//! human diagnostic format.

use crate::common;

use common::*;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const ICACHE: &str = env!("CARGO_BIN_EXE_icache");

struct Out {
    cmd: String,
    code: i32,
    stdout: String,
    stderr: String,
}

impl Out {
    fn context(&self) -> String {
        format!(
            "command: {}\nexit: {}\n--- stdout:\n{}\n--- stderr:\n{}",
            self.cmd, self.code, self.stdout, self.stderr
        )
    }

    fn status(&self, want: i32) -> &Self {
        assert_eq!(self.code, want, "unexpected exit status\n{}", self.context());
        self
    }

    fn json(&self) -> Value {
        serde_json::from_str(&self.stdout).unwrap_or_else(|e| panic!("stdout is not JSON ({e})\n{}", self.context()))
    }

    fn check(&self, ok: bool, what: &str) {
        assert!(ok, "{what}\n{}", self.context());
    }
}

/// Runs `bin args` in `cwd`, with `vars` set in the child's environment.
fn run_env(bin: &str, args: &[&str], cwd: &Path, vars: &[(&str, &str)]) -> Out {
    let mut c = Command::new(bin);
    c.args(args).current_dir(cwd);
    for (k, v) in vars {
        c.env(k, v);
    }
    let o = c.output().expect("the binary runs");
    Out {
        cmd: format!(
            "(cd {} && {} {})",
            cwd.display(),
            Path::new(bin).file_name().unwrap().to_string_lossy(),
            args.join(" ")
        ),
        code: o.status.code().unwrap_or(-1),
        stdout: String::from_utf8_lossy(&o.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&o.stderr).into_owned(),
    }
}

fn run(bin: &str, args: &[&str], cwd: &Path) -> Out {
    run_env(bin, args, cwd, &[])
}

/// A configuration directory and a separate working directory.
struct Setup {
    conf: Fixture,
    cwd: Fixture,
}

impl Setup {
    fn new() -> Self {
        Setup { conf: Fixture::new(), cwd: Fixture::new() }
    }

    /// The path of a configuration file relative to the working directory (`../xxx/name`).
    fn rel(&self, name: &str) -> String {
        let dir = self.conf.dir.path().file_name().unwrap().to_string_lossy();
        assert_eq!(self.conf.dir.path().parent(), self.cwd.dir.path().parent());
        format!("../{dir}/{name}")
    }

    fn cwd(&self) -> &Path {
        self.cwd.dir.path()
    }
}

/// `p` with its directory resolved (`..` and symbolic links); the directory must exist.
fn canon(p: impl AsRef<Path>) -> PathBuf {
    let p = p.as_ref();
    let dir = std::fs::canonicalize(p.parent().unwrap()).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    dir.join(p.file_name().unwrap())
}

/// A path from a JSON string, resolved with [`canon`].
fn jpath(v: &Value) -> PathBuf {
    canon(v.as_str().unwrap_or_else(|| panic!("a path, found {v}")))
}

/// A clip texture with level `.ic` files and pyramid files in subdirectories.
fn write_ct(s: &Setup) {
    s.conf.write_level_ics("ic/l", 2048, 1024, 256);
    std::fs::create_dir_all(s.conf.path("ic/tiles")).unwrap();
    std::fs::create_dir_all(s.conf.path("pyr")).unwrap();
    s.conf.write(
        "x.ct",
        format!(
            "ct_version2.0\n{RGB8}virt_size 2048 2048 1\nclip_size 512\n\
             icache_format ic/l.%d.ic\nicache_params PFCLIPTEX_FNAMEARG_LEVEL_SIZE\n\
             header_offset 32\ntile_base ${{PYR:-pyr}}\ntile_format %s/%d.raw\n\
             tile_params PFCLIPTEX_FNAMEARG_TILE_BASE PFCLIPTEX_FNAMEARG_LEVEL_SIZE\n"
        ),
    );
}

#[test]
fn validate_exit_statuses() {
    let s = Setup::new();
    write_ct(&s);
    let out = run(CLIPTEX, &["validate", &s.rel("x.ct")], s.cwd());
    out.status(0);
    out.check(out.stdout.contains("valid (0 errors, 0 warnings)"), "says valid");
    s.conf.write("bad.ct", "ct_version2.0\nclip_size 500\n");
    run(CLIPTEX, &["validate", &s.rel("bad.ct")], s.cwd()).status(1);
    // A missing file: the tool could not run, whatever the other files.
    let out = run(CLIPTEX, &["validate", &s.rel("x.ct"), &s.rel("missing.ct")], s.cwd());
    out.status(2);
    out.check(out.stdout.contains("cannot be read"), "says why");
    run(CLIPTEX, &["info", &s.rel("missing.ct")], s.cwd()).status(2);
    run(ICACHE, &["validate", "nope.ic"], s.cwd()).status(2);
    // Bad arguments: the command line is input too (docs/RELIABILITY.md).
    run(CLIPTEX, &["validate"], s.cwd()).status(1);
    run(CLIPTEX, &["info", &s.rel("x.ct"), "--env", "NOEQUALS"], s.cwd()).status(1);
}

#[test]
fn validate_strict_fails_on_portability_findings_and_warnings() {
    let s = Setup::new();
    let text = NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 4096 4096");
    s.conf.write("p.ct", text);
    let out = run(CLIPTEX, &["validate", "--json", &s.rel("p.ct")], s.cwd());
    out.status(0);
    let j = out.json();
    let d = &j["files"][0]["diagnostics"][0];
    assert_eq!(d["code"], "size-missing-r", "{}", out.context());
    assert_eq!(d["severity"], "note");
    assert_eq!(d["portability"], true);
    let out = run(CLIPTEX, &["validate", "--strict", "--json", &s.rel("p.ct")], s.cwd());
    out.status(1);
    let j = out.json();
    assert_eq!(j["valid"], false);
    assert_eq!(j["files"][0]["errors"], 1);
    assert_eq!(j["files"][0]["diagnostics"][0]["severity"], "error");
    // A plain warning: exit 0 without --strict, 1 with it.
    s.conf.write("w.ic", format!("{SMALL_IC}lookahead 1\nlookahead 2\n"));
    run(ICACHE, &["validate", &s.rel("w.ic")], s.cwd()).status(0);
    run(ICACHE, &["validate", "--strict", &s.rel("w.ic")], s.cwd()).status(1);
}

#[test]
fn validate_json_describes_every_finding() {
    let s = Setup::new();
    s.conf.write("e.ct", format!("{NO_IC_CT}  clip_sise 512\n"));
    let out = run(CLIPTEX, &["validate", "--json", &s.rel("e.ct")], s.cwd());
    out.status(1);
    let j = out.json();
    assert_eq!((j["valid"].clone(), j["could_not_run"].clone()), (false.into(), false.into()));
    let f = &j["files"][0];
    assert_eq!(f["kind"], "clip_texture");
    assert_eq!(f["valid"], false);
    assert_eq!(f["errors"], 2, "{}", out.context());
    let d = &f["diagnostics"][0];
    assert_eq!(d["code"], "unknown-token");
    assert_eq!(d["severity"], "error");
    assert_eq!((d["line"].clone(), d["col"].clone()), (10.into(), 3.into()));
    assert_eq!(d["found"], "clip_sise");
    assert_eq!(d["hint"], "did you mean `clip_size`?");
    assert!(d["path"].as_str().unwrap().ends_with("e.ct"));
    // A file that cannot be read.
    let out = run(CLIPTEX, &["validate", "--json", "gone.ct"], s.cwd());
    out.status(2);
    let j = out.json();
    assert_eq!(j["could_not_run"], true);
    out.check(j["files"][0]["unreadable"].is_string(), "unreadable says why");
}

#[test]
fn human_diagnostics_have_place_source_line_caret_and_hint() {
    let s = Setup::new();
    s.conf.write("e.ct", format!("{NO_IC_CT}  clip_sise 512\n"));
    let out = run(CLIPTEX, &["validate", &s.rel("e.ct")], s.cwd());
    out.status(1);
    // The path is made absolute by joining the working directory (`..` kept, as Performer keeps
    // the path under which it found a file).
    let first = out.stdout.lines().next().unwrap_or_default();
    let want = format!("{}:10:3: error: `clip_sise` is not a clip texture (.ct) token", s.rel("e.ct"));
    out.check(first.starts_with('/') && first.contains(&want), "path:line:col: error: message");
    out.check(out.stdout.contains("  10 |   clip_sise 512\n"), "source line");
    out.check(out.stdout.contains("       |   ^^^^^^^^^\n"), "caret line");
    out.check(out.stdout.contains("= hint: did you mean `clip_size`?"), "hint");
    out.check(out.stdout.contains("invalid (2 errors, 0 warnings)"), "summary");
    // info on an invalid file prints the findings on stderr.
    let out = run(CLIPTEX, &["info", &s.rel("e.ct")], s.cwd());
    out.status(1);
    out.check(out.stderr.contains(":10:3: error:"), "stderr has findings");
    out.check(out.stderr.contains("is not a valid clip texture configuration"), "and a verdict");
}

#[test]
fn info_json_gives_the_contract_fields() {
    let s = Setup::new();
    write_ct(&s);
    let out = run(CLIPTEX, &["info", "--json", &s.rel("x.ct")], s.cwd());
    out.status(0);
    let j = out.json();
    assert_eq!(j["virt_size"], serde_json::json!([2048, 2048, 1]));
    assert_eq!(j["clip_size"], 512);
    assert_eq!(j["invalid_border"], 8);
    assert_eq!(j["effective_levels"], 16);
    assert_eq!(j["allocated_levels"], 1000);
    assert_eq!(j["smallest_icache"], serde_json::json!([1024, 1024, 1]));
    assert_eq!(j["bytes_per_texel"], 3);
    assert_eq!(j["warnings"], serde_json::json!([]));
    let levels = j["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 12);
    let l0 = &levels[0];
    assert_eq!(l0["level"], 0);
    assert_eq!(l0["size"], serde_json::json!([2048, 2048]));
    assert_eq!(l0["kind"], "icache");
    let icp = PathBuf::from(l0["icache_config"].as_str().unwrap());
    assert!(icp.is_absolute(), "{}", out.context());
    assert_eq!(canon(icp), canon(s.conf.path("ic/l.2048.ic")));
    assert_eq!(l0["tile_file"], Value::Null);
    assert_eq!(l0["tile_size"], serde_json::json!([256, 256]));
    assert_eq!(l0["tex_region"], serde_json::json!([512, 512]));
    assert_eq!(l0["mem_region"], serde_json::json!([4, 4]));
    assert_eq!(l0["header_offset"], 0);
    let l2 = &levels[2];
    assert_eq!(l2["kind"], "pyramid");
    assert_eq!(l2["icache_config"], Value::Null);
    assert!(l2["tile_file"].as_str().unwrap().starts_with('/'));
    assert_eq!(jpath(&l2["tile_file"]), canon(s.conf.path("pyr/512.raw")));
    assert_eq!(l2["tile_size"], serde_json::json!([512, 512]));
    assert_eq!(l2["header_offset"], 32);
    assert_eq!(levels[11]["size"], serde_json::json!([1, 1]));
}

#[test]
fn info_json_lists_warnings_and_the_human_form_marks_defaults() {
    let s = Setup::new();
    s.conf.write("w.ct", format!("{NO_IC_CT}invalid_border 2\n"));
    let out = run(CLIPTEX, &["info", "--json", &s.rel("w.ct")], s.cwd());
    out.status(0);
    let j = out.json();
    let codes: Vec<&str> = j["warnings"].as_array().unwrap().iter().map(|w| w["code"].as_str().unwrap()).collect();
    out.check(codes.contains(&"border-raised"), "warning listed");
    assert_eq!(j["invalid_border"], 8);
    assert_eq!(j["levels"][0]["icache_config"], Value::Null, "no-.ic mode");
    let out = run(CLIPTEX, &["info", &s.rel("w.ct")], s.cwd());
    out.status(0);
    out.check(out.stdout.contains("effective      16  (default)"), "defaults marked");
    out.check(out.stdout.contains("levels         13 (3 image cache, 10 pyramid)"), "level counts");
    out.check(out.stderr.contains("warning: `invalid_border` 2 is below the minimum"), "warning on stderr");
}

#[test]
fn tile_json_locates_image_cache_and_pyramid_tiles() {
    let s = Setup::new();
    write_ct(&s);
    let out = run(CLIPTEX, &["tile", "--json", &s.rel("x.ct"), "--level", "0", "--s", "3", "--t", "5"], s.cwd());
    out.status(0);
    let j = out.json();
    assert_eq!(jpath(&j["path"]), canon(s.conf.path("ic/tiles/l2048.2048.r005.c003.raw888")));
    assert_eq!((j["offset"].clone(), j["length"].clone()), (0.into(), (256 * 256 * 3).into()));
    assert_eq!(j["stream"], "");
    let out = run(CLIPTEX, &["tile", "--json", &s.rel("x.ct"), "--level", "3", "--s", "0", "--t", "0"], s.cwd());
    let j = out.status(0).json();
    assert_eq!(jpath(&j["path"]), canon(s.conf.path("pyr/256.raw")));
    assert_eq!((j["offset"].clone(), j["length"].clone()), (32.into(), (256 * 256 * 3).into()));
    // Out of range: the input is bad.
    let out = run(CLIPTEX, &["tile", &s.rel("x.ct"), "--level", "0", "--s", "8", "--t", "0"], s.cwd());
    out.status(1);
    out.check(out.stderr.contains("outside the cache"), "says why");
    run(CLIPTEX, &["tile", &s.rel("x.ct"), "--level", "3", "--s", "1", "--t", "0"], s.cwd()).status(1);
    run(CLIPTEX, &["tile", &s.rel("x.ct"), "--level", "12", "--s", "0", "--t", "0"], s.cwd()).status(1);
}

#[test]
fn icache_tile_json_with_streams_files_and_header() {
    let s = Setup::new();
    s.conf.write(
        "s.ic",
        format!(
            "ic_version2.0\n{RGB8}icache_size 4096 4096 1\ntile_size 256 256 1\n\
             tex_region_size 1024 1024 1\ntiles_in_file 4 4 1\nheader_offset 1024\n\
             tile_base data\ns_stream /d0/ /d1/\ntile_format %s%s.%d.%d\ntile_params \
             PFIMAGECACHE_TILE_FILENAMEARG_STREAMSERVERNAME PFIMAGECACHE_TILE_FILENAMEARG_CACHENAME \
             PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_S PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_T\n"
        ),
    );
    let out = run(ICACHE, &["tile", "--json", &s.rel("s.ic"), "--s", "6", "--t", "9"], s.cwd());
    let j = out.status(0).json();
    assert_eq!(j["path"], "/d0/data.1.2");
    assert_eq!(j["offset"], 1180672);
    assert_eq!(j["length"], 196608);
    assert_eq!(j["stream"], "/d0/");
    let out = run(ICACHE, &["tile", "--json", &s.rel("s.ic"), "--s", "7", "--t", "9"], s.cwd());
    assert_eq!(out.status(0).json()["stream"], "/d1/");
    let out = run(ICACHE, &["info", "--json", &s.rel("s.ic")], s.cwd());
    let j = out.status(0).json();
    assert_eq!(j["tiles_in_file"], serde_json::json!([4, 4, 1]));
    assert_eq!(j["mem_region"], serde_json::json!([6, 6, 1]));
    assert_eq!(j["first_tile"]["offset"], 1024);
    run(ICACHE, &["validate", "--strict", &s.rel("s.ic")], s.cwd()).status(0);
}

#[test]
fn env_and_unset_change_the_resolved_paths() {
    let s = Setup::new();
    write_ct(&s);
    let tile3 = |extra: &[&str], vars: &[(&str, &str)]| {
        let r = s.rel("x.ct");
        let mut args = vec!["tile", "--json", r.as_str(), "--level", "3", "--s", "0", "--t", "0"];
        args.extend_from_slice(extra);
        let out = run_env(CLIPTEX, &args, s.cwd(), vars);
        let p = PathBuf::from(out.status(0).json()["path"].as_str().unwrap());
        if p.starts_with(s.cwd()) {
            canon(p)
        } else {
            p
        }
    };
    let pyr = canon(s.conf.path("pyr/256.raw"));
    // Unset: the default of `${PYR:-pyr}`, relative to the .ct's directory.
    assert_eq!(tile3(&[], &[]), pyr);
    assert_eq!(tile3(&["--env", "PYR=/mnt/p"], &[]), PathBuf::from("/mnt/p/256.raw"));
    // The process environment is used, and --env wins over it.
    assert_eq!(tile3(&[], &[("PYR", "/proc/env")]), PathBuf::from("/proc/env/256.raw"));
    assert_eq!(tile3(&["--env", "PYR=/arg"], &[("PYR", "/proc/env")]), PathBuf::from("/arg/256.raw"));
    // --unset hides the process environment's value.
    assert_eq!(tile3(&["--unset", "PYR"], &[("PYR", "/proc/env")]), pyr);
    // Set but empty: no default (Performer's rule), so `/256.raw`.
    assert_eq!(tile3(&["--env", "PYR="], &[]), PathBuf::from("/256.raw"));
    // validate takes them too.
    run(CLIPTEX, &["validate", "--env", "PYR=/x", "--unset", "HOME", &s.rel("x.ct")], s.cwd()).status(0);
}

#[test]
fn icache_validate_strict_and_quiet() {
    let s = Setup::new();
    s.conf.write("a.ic", SMALL_IC);
    s.conf.write("b.ic", format!("{SMALL_IC}s_streams /a/\n"));
    let out = run(ICACHE, &["validate", &s.rel("a.ic"), &s.rel("b.ic")], s.cwd());
    out.status(0);
    let out = run(ICACHE, &["validate", "--strict", "--quiet", &s.rel("a.ic"), &s.rel("b.ic")], s.cwd());
    out.status(1);
    out.check(!out.stdout.contains("a.ic: valid"), "quiet hides valid files");
    out.check(out.stdout.contains("b.ic:8:1: error: Performer 3.0 reads `s_streams`"), "strict finding");
    // A .ct given to icache is refused as the wrong kind.
    write_ct(&s);
    let out = run(ICACHE, &["validate", &s.rel("x.ct")], s.cwd());
    out.status(1);
    out.check(out.stdout.contains("wrong-file-kind") || out.stdout.contains("cliptex validate"), "points at cliptex");
}

#[test]
fn ct_only_checks_a_ct_whose_ic_files_are_absent_and_lists_them_resolved() {
    // Three image-cache levels named three ways: a relative list entry, an absolute one and a
    // `$VAR` one; none of the .ic files exists (the data volume is not mounted here).
    let s = Setup::new();
    let abs = s.conf.path("elsewhere/l.1024.ic");
    s.conf.write(
        "x.ct",
        format!(
            "ct_version2.0\n{RGB8}virt_size 4096 4096 1\nclip_size 512\n\
             icache_files ic/l.4096.ic {} $DATA/l.2048.ic\n\
             tile_format pyr/%d.raw\ntile_params PFCLIPTEX_FNAMEARG_LEVEL_SIZE\n",
            abs.display()
        ),
    );
    let data = s.conf.path("data");
    for d in ["ic", "elsewhere", "data"] {
        std::fs::create_dir_all(s.conf.path(d)).unwrap(); // the directories, not the files
    }
    let env = format!("DATA={}", data.display());
    let ct = s.rel("x.ct");
    // Without --ct-only: the first absent .ic is an error, and the hint names --ct-only.
    let out = run(CLIPTEX, &["validate", &ct, "--env", &env], s.cwd());
    out.status(1);
    out.check(out.stdout.contains("--ct-only"), "the hint names --ct-only");
    // With it: valid, and every resolved name printed, in text and in JSON.
    let out = run(CLIPTEX, &["validate", "--ct-only", &ct, "--env", &env], s.cwd());
    out.status(0);
    let want = [canon(s.conf.path("ic/l.4096.ic")), canon(&abs), canon(data.join("l.2048.ic"))];
    for name in ["ic/l.4096.ic", "elsewhere/l.1024.ic", "data/l.2048.ic"] {
        out.check(out.stdout.contains(name), &format!("lists {name}"));
    }
    let j = run(CLIPTEX, &["validate", "--ct-only", "--json", &ct, "--env", &env], s.cwd()).status(0).json();
    let files = j["files"][0]["icache_files"].as_array().expect("icache_files listed");
    let got: Vec<(u64, PathBuf)> =
        files.iter().map(|f| (f["level"].as_u64().unwrap(), PathBuf::from(f["path"].as_str().unwrap()))).collect();
    assert_eq!(got.len(), 3, "{j}");
    for (i, (level, path)) in got.iter().enumerate() {
        assert_eq!(*level, i as u64);
        assert!(path.is_absolute(), "{}", path.display());
        assert_eq!(canon(path), want[i]);
    }
    // The expansion follows --env: another value, another name.
    let j =
        run(CLIPTEX, &["validate", "--ct-only", "--json", &ct, "--env", "DATA=/mnt/other"], s.cwd()).status(0).json();
    assert_eq!(j["files"][0]["icache_files"][2]["path"], "/mnt/other/l.2048.ic");
    // Without DATA set at all: a warning about the variable (it expands to nothing), an error
    // with --strict.
    let out = run(CLIPTEX, &["validate", "--ct-only", &ct, "--unset", "DATA"], s.cwd());
    out.status(0);
    out.check(out.stdout.contains("`DATA` is not set"), "names the unset variable");
    run(CLIPTEX, &["validate", "--ct-only", "--strict", &ct, "--unset", "DATA"], s.cwd()).status(1);

    // info --ct-only: the level table with resolved names; what only an .ic gives is unknown.
    let out = run(CLIPTEX, &["info", "--ct-only", &ct, "--env", &env], s.cwd());
    out.status(0);
    out.check(out.stdout.contains("not opened"), "marks the .ic as not opened");
    out.check(out.stdout.contains("ic/l.4096.ic"), "shows the relative name as resolved");
    let level0 = out.stdout.lines().find(|l| l.starts_with("0 ")).expect("a row for level 0");
    out.check(level0.contains("4096x4096") && level0.contains('?'), "level 0: size known, tile unknown");
    let j = run(CLIPTEX, &["info", "--ct-only", "--json", &ct, "--env", &env], s.cwd()).status(0).json();
    let levels = j["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 13, "{j}");
    for (i, l) in levels.iter().take(3).enumerate() {
        assert_eq!(l["kind"], "icache");
        assert_eq!(l["icache_opened"], false);
        assert!(l["tile_size"].is_null() && l["mem_region"].is_null(), "{l}");
        assert_eq!(jpath(&l["icache_config"]), want[i]);
    }
    assert_eq!(levels[3]["kind"], "pyramid");
    assert_eq!(levels[3]["tile_size"], serde_json::json!([512, 512]));
    assert_eq!(levels[3]["icache_opened"], true);
    // A .ct-only plan is never served or walked: `check` opens every .ic and says what is missing.
    run(CLIPTEX, &["check", &ct, "--env", &env], s.cwd()).status(1);
}

#[test]
fn info_ct_only_gives_the_tex_region_the_ct_fixes() {
    // Inside a clip texture an image cache level's tex region is min(clip_size, level size),
    // whatever its .ic says: `info --ct-only` once left it null (`?`) with the other .ic values,
    // for levels smaller than the clip size too. It must equal what the full `info` reports.
    let s = Setup::new();
    s.conf.write_level_ics("ic/l", 2048, 256, 128);
    s.conf.write(
        "x.ct",
        format!(
            "ct_version2.0\n{RGB8}virt_size 2048 2048 1\nclip_size 512\nsmallest_icache 256 256 1\n\
             icache_format ic/l.%d.ic\nicache_params PFCLIPTEX_FNAMEARG_LEVEL_SIZE\n\
             tile_format pyr/%d.raw\ntile_params PFCLIPTEX_FNAMEARG_LEVEL_SIZE\n"
        ),
    );
    let ct = s.rel("x.ct");
    let full = run(CLIPTEX, &["info", "--json", &ct], s.cwd()).status(0).json();
    let only = run(CLIPTEX, &["info", "--ct-only", "--json", &ct], s.cwd()).status(0).json();
    let (full, only) = (full["levels"].as_array().unwrap(), only["levels"].as_array().unwrap());
    assert_eq!(full.len(), only.len());
    let want = [[512, 512], [512, 512], [512, 512], [256, 256]];
    for (i, w) in want.iter().enumerate() {
        assert_eq!(only[i]["kind"], "icache", "{}", only[i]);
        assert_eq!(only[i]["icache_opened"], false, "{}", only[i]);
        assert_eq!(full[i]["tex_region"], serde_json::json!(w), "level {i}, full: {}", full[i]);
        assert_eq!(only[i]["tex_region"], full[i]["tex_region"], "level {i}, .ct only: {}", only[i]);
        // What only the .ic gives stays unknown.
        assert!(only[i]["tile_size"].is_null() && only[i]["mem_region"].is_null(), "{}", only[i]);
    }
    // The level table shows it too: level 3 (256x256) has its tex region, its tile is `?`.
    let out = run(CLIPTEX, &["info", "--ct-only", &ct], s.cwd());
    out.status(0);
    let row = out.stdout.lines().find(|l| l.starts_with("3 ")).expect("a row for level 3");
    let cols: Vec<&str> = row.split_whitespace().collect();
    out.check(cols[1..5] == ["256x256", "icache", "?", "256x256"], &format!("level 3 row: {row}"));
}

#[test]
fn plan_of_a_non_square_texture_equals_the_level_by_level_formula() {
    let s = Setup::new();
    // Brute force: Performer's levels halve both sides until the short side is 1; level k keeps
    // min(W_k, C) x min(H_k, C) texels; the full mipmap keeps W_k x H_k.
    let formula = |w: u64, h: u64, c: u64| {
        let (mut clip, mut full, mut levels) = (0u128, 0u128, 0u64);
        let mut k = 0;
        while w >> k >= 1 && h >> k >= 1 {
            let (lw, lh) = ((w >> k) as u128, (h >> k) as u128);
            clip += lw.min(c as u128) * lh.min(c as u128);
            full += lw * lh;
            levels += 1;
            k += 1;
        }
        (clip, full, levels)
    };
    for (w, h, c, b) in
        [(8192u64, 2048u64, 512u64, 3u64), (2048, 65536, 1024, 4), (1 << 26, 1 << 20, 2048, 2), (4, 1, 1, 1)]
    {
        let size = format!("{w}x{h}");
        let (clip, c_s, b_s) = (c, c.to_string(), b.to_string());
        let j = run(CLIPTEX, &["plan", "--size", &size, "--clip", &c_s, "--texel-bytes", &b_s, "--json"], s.cwd())
            .status(0)
            .json();
        let (want_clip, want_full, levels) = formula(w, h, clip);
        let num = |v: &Value| v.as_u64().map(u128::from).unwrap_or_else(|| v.as_str().unwrap().parse().unwrap());
        assert_eq!(num(&j["clipmap_texels"]), want_clip, "{size}: {j}");
        assert_eq!(num(&j["clipmap_bytes"]), want_clip * b as u128, "{size}: {j}");
        assert_eq!(num(&j["mipmap_texels"]), want_full, "{size}: {j}");
        assert_eq!(j["levels"].as_u64().unwrap(), levels, "{size}: {j}");
        assert_eq!((j["width"].as_u64().unwrap(), j["height"].as_u64().unwrap()), (w, h));
    }
    // A side that is not a power of two names the side.
    let out = run(CLIPTEX, &["plan", "--size", "8192x2000"], s.cwd());
    out.status(1);
    out.check(out.stderr.contains("texture height"), "names the height");
    run(CLIPTEX, &["plan", "--size", "8192y2048"], s.cwd()).status(1);

    // `plan FILE.ct`: the .ct's sizes, clip and texel bytes, its .ic files not needed.
    let ct = format!("{ROOT}/config_examples/non_square.ct");
    let j = run(CLIPTEX, &["plan", &ct, "--json"], s.cwd()).status(0).json();
    let (want_clip, _, levels) = formula(8192, 2048, 512);
    assert_eq!(
        (j["width"].as_u64(), j["height"].as_u64(), j["clip_size"].as_u64()),
        (Some(8192), Some(2048), Some(512))
    );
    assert_eq!(j["texel_bytes"].as_u64(), Some(3));
    assert_eq!(num_u128(&j["clipmap_texels"]), want_clip);
    assert_eq!(j["levels"].as_u64(), Some(levels));
    assert!(j["from"].as_str().unwrap().ends_with("non_square.ct"), "{j}");
    // An option overrides what the .ct says.
    let j = run(CLIPTEX, &["plan", &ct, "--clip", "256", "--json"], s.cwd()).status(0).json();
    assert_eq!(num_u128(&j["clipmap_texels"]), formula(8192, 2048, 256).0);
    // A .ct and --size together are a usage error; an invalid .ct is bad input (both exit 1).
    run(CLIPTEX, &["plan", &ct, "--size", "1024"], s.cwd()).status(1);
    s.conf.write("bad.ct", "ct_version2.0\nclip_size 500\n");
    run(CLIPTEX, &["plan", &s.rel("bad.ct")], s.cwd()).status(1);
}

const ROOT: &str = env!("CLIPMAP_ROOT");

fn num_u128(v: &Value) -> u128 {
    v.as_u64().map(u128::from).unwrap_or_else(|| v.as_str().unwrap().parse().unwrap())
}

#[test]
fn info_shows_the_paging_extension_and_validate_strict_accepts_it() {
    let s = Setup::new();
    write_ct(&s);
    let before = run(CLIPTEX, &["validate", "--strict", "--json", &s.rel("x.ct")], s.cwd());
    let path = s.conf.path("x.ct");
    let text = std::fs::read_to_string(&path).unwrap();
    let text =
        text.replacen("ct_version2.0\n", "ct_version2.0\n#clipmap prefetch direction\n#clipmap pool_bytes 64m\n", 1);
    std::fs::write(&path, text).unwrap();
    let out = run(CLIPTEX, &["info", &s.rel("x.ct")], s.cwd());
    out.status(0);
    out.check(
        out.stdout.contains(
            "paging         prefetch direction, pool 67108864 bytes (lru eviction), centre step off  (#clipmap)",
        ),
        "the paging line",
    );
    let j = run(CLIPTEX, &["info", "--json", &s.rel("x.ct")], s.cwd()).json();
    assert_eq!(j["paging"]["prefetch"], "direction");
    assert_eq!(j["paging"]["pool_bytes"], 64 << 20);
    // Performer reads the lines as comments: nothing more for --strict to say.
    let after = run(CLIPTEX, &["validate", "--strict", "--json", &s.rel("x.ct")], s.cwd());
    after.status(before.code);
    let count = |o: &Out| o.json().to_string().matches("\"code\"").count();
    assert_eq!(count(&after), count(&before), "no new finding\n{}", after.context());
}
