//! Shared code of the configuration tests: files in a temporary directory, an isolated
//! environment, and assertions on diagnostics (code, severity, line, column, key words).
#![allow(dead_code)]

pub mod exercise;
pub mod flight;
pub mod gdal;
pub mod mutate;
pub mod patch_exercise;
pub mod remote;
pub mod tiff_exercise;

use clipmap::config::{self, Diagnostic, Diagnostics, FileKind, Limits, Severity, SyntaxFile};
use clipmap::plan::{self, ClipTexturePlan, Env, ImageCachePlan, Loaded, Options};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The three format lines of an RGB, one byte per component texture.
pub const RGB8: &str = "ext_format PFTEX_PACK_8\nint_format PFTEX_RGB_8\nimg_format PFTEX_RGB\n";

/// A small valid clip texture in no-`.ic` mode: 4096 square, clip 512, 256-texel tiles, one
/// format naming both the image cache tiles and the pyramid files. 13 levels.
pub const NO_IC_CT: &str = "ct_version2.0
ext_format PFTEX_PACK_8
int_format PFTEX_RGB_8
img_format PFTEX_RGB
virt_size 4096 4096 1
clip_size 512
tile_format t.%d.r%d.c%d.raw
tile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S
tile_size 256 256 1
";

/// A small valid standalone image cache: 1024 square, 256-texel tiles, tex region 512.
pub const SMALL_IC: &str = "ic_version2.0
ext_format PFTEX_PACK_8
int_format PFTEX_RGB_8
img_format PFTEX_RGB
icache_size 1024 1024 1
tile_size 256 256 1
tex_region_size 512 512 1
";

/// A temporary directory holding configuration files.
pub struct Fixture {
    pub dir: tempfile::TempDir,
}

impl Default for Fixture {
    fn default() -> Self {
        Self::new()
    }
}

impl Fixture {
    pub fn new() -> Self {
        Fixture { dir: tempfile::tempdir().expect("temporary directory") }
    }

    /// The absolute path of `rel` inside the fixture.
    pub fn path(&self, rel: &str) -> PathBuf {
        self.dir.path().join(rel)
    }

    /// Writes `text` to `rel` (creating directories) and returns its path.
    pub fn write(&self, rel: &str, text: impl AsRef<[u8]>) -> PathBuf {
        let p = self.path(rel);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).expect("create directories");
        }
        std::fs::write(&p, text).expect("write file");
        p
    }

    /// Writes one `.ic` per image cache level of a square clip texture, named `stem.SIZE.ic`
    /// (relative to the fixture), for sizes `top`, `top/2`, ... down to `smallest`.
    pub fn write_level_ics(&self, stem: &str, top: u64, smallest: u64, tile: u64) {
        let mut s = top;
        while s >= smallest {
            self.write(&format!("{stem}.{s}.ic"), level_ic(s, s, tile));
            s /= 2;
        }
    }
}

/// The text of a level `.ic` of size `s` x `t` with square tiles of `tile`.
pub fn level_ic(s: u64, t: u64, tile: u64) -> String {
    format!("ic_version2.0\n{RGB8}icache_size {s} {t} 1\ntile_size {tile} {tile} 1\ntile_base tiles/l{s}\n")
}

/// Reader options with an empty environment.
pub fn opts() -> Options {
    Options { env: Env::isolated(), ..Options::default() }
}

/// Reader options with an environment holding exactly `vars`.
pub fn opts_with(vars: &[(&str, &str)]) -> Options {
    let mut env = Env::isolated();
    for (k, v) in vars {
        env.set(k, v);
    }
    Options { env, ..Options::default() }
}

/// Loads a `.ct` written to `name` in a fresh fixture (the fixture is returned so that it lives).
pub fn load_ct(text: &str) -> (Fixture, Loaded<ClipTexturePlan>) {
    let fx = Fixture::new();
    let p = fx.write("t.ct", text);
    let l = plan::load_clip_texture(&p, &opts()).expect("readable");
    (fx, l)
}

/// Loads a standalone `.ic` written in a fresh fixture.
pub fn load_ic(text: &str) -> (Fixture, Loaded<ImageCachePlan>) {
    let fx = Fixture::new();
    let p = fx.write("t.ic", text);
    let l = plan::load_image_cache(&p, &opts()).expect("readable");
    (fx, l)
}

/// Loads a `.ct` from a fixture with options, panicking with every finding when it has no plan.
pub fn ct_plan_in(fx: &Fixture, rel: &str, o: &Options) -> (ClipTexturePlan, Diagnostics) {
    let l = plan::load_clip_texture(&fx.path(rel), o).expect("readable");
    match l.plan {
        Some(p) => (p, l.diagnostics),
        None => panic!("{rel} should load; findings:\n{}", l.render()),
    }
}

/// A `.ct` that must load; returns the plan and its findings.
pub fn ct_ok(text: &str) -> (ClipTexturePlan, Diagnostics) {
    let (_fx, l) = load_ct(text);
    match l.plan {
        Some(p) => (p, l.diagnostics),
        None => panic!("the .ct should load; findings:\n{}\n--- text:\n{text}", l.render()),
    }
}

/// A standalone `.ic` that must load.
pub fn ic_ok(text: &str) -> (ImageCachePlan, Diagnostics) {
    let (_fx, l) = load_ic(text);
    match l.plan {
        Some(p) => (p, l.diagnostics),
        None => panic!("the .ic should load; findings:\n{}\n--- text:\n{text}", l.render()),
    }
}

/// A `.ct` that must fail; returns its findings.
pub fn ct_err(text: &str) -> Diagnostics {
    let (_fx, l) = load_ct(text);
    assert!(l.plan.is_none(), "the .ct should be refused; findings:\n{}\n--- text:\n{text}", l.render());
    l.diagnostics
}

/// A standalone `.ic` that must fail; returns its findings.
pub fn ic_err(text: &str) -> Diagnostics {
    let (_fx, l) = load_ic(text);
    assert!(l.plan.is_none(), "the .ic should be refused; findings:\n{}\n--- text:\n{text}", l.render());
    l.diagnostics
}

/// Syntax only.
pub fn parse(text: &[u8], kind: FileKind) -> (SyntaxFile, Diagnostics) {
    config::parse_bytes(text, Path::new("x.cfg"), kind, &Limits::default())
}

/// Syntax only, a `.ct`.
pub fn parse_ct(text: &str) -> (SyntaxFile, Diagnostics) {
    parse(text.as_bytes(), FileKind::ClipTexture)
}

/// Syntax only, an `.ic`.
pub fn parse_ic(text: &str) -> (SyntaxFile, Diagnostics) {
    parse(text.as_bytes(), FileKind::ImageCache)
}

/// One line per finding, for failure messages.
pub fn listing(d: &Diagnostics) -> String {
    d.items
        .iter()
        .map(|x| {
            let (l, c) = x.span.map_or((0, 0), |s| (s.line, s.col));
            format!(
                "  {}:{l}:{c} {} [{}] {}\n",
                x.path.file_name().map_or("?".into(), |f| f.to_string_lossy()),
                x.severity,
                x.code,
                x.message
            )
        })
        .collect()
}

/// The first finding with `code`, or a panic listing every finding.
pub fn find<'a>(d: &'a Diagnostics, code: &str) -> &'a Diagnostic {
    d.items.iter().find(|x| x.code == code).unwrap_or_else(|| panic!("no `{code}` finding; findings:\n{}", listing(d)))
}

/// Asserts a finding: code, severity, place (line, column; `None` for a finding without place)
/// and words that its message (or found/expected/hint) contains.
pub fn expect(d: &Diagnostics, code: &str, sev: Severity, at: Option<(u32, u32)>, words: &[&str]) -> Diagnostic {
    let x = find(d, code);
    assert_eq!(x.severity, sev, "severity of `{code}`:\n{}", listing(d));
    assert_eq!(x.span.map(|s| (s.line, s.col)), at, "place of `{code}`:\n{}", listing(d));
    let all = format!(
        "{} {} {} {}",
        x.message,
        x.found.clone().unwrap_or_default(),
        x.expected.clone().unwrap_or_default(),
        x.hint.clone().unwrap_or_default()
    );
    for w in words {
        assert!(all.contains(w), "`{code}` should mention `{w}`: {all}\n{}", listing(d));
    }
    x.clone()
}

/// Asserts that no finding has `code`.
pub fn absent(d: &Diagnostics, code: &str) {
    assert!(d.items.iter().all(|x| x.code != code), "unexpected `{code}` finding:\n{}", listing(d));
}

/// Asserts that there are no findings of at least warning severity.
pub fn clean(d: &Diagnostics) {
    assert!(d.items.iter().all(|x| x.severity < Severity::Warning), "expected no warnings or errors:\n{}", listing(d));
}

/// Codes of all findings, in order.
pub fn codes(d: &Diagnostics) -> Vec<&'static str> {
    d.items.iter().map(|x| x.code).collect()
}

/// Runs `prog args` in `cwd`; returns the output and a description (command, status, stdout,
/// stderr) for failure messages. Used by the tests that drive the real binaries.
pub fn exec(cwd: &Path, prog: &str, args: &[&str]) -> (Output, String) {
    let out = Command::new(prog).current_dir(cwd).args(args).output().expect("the binary runs");
    let d = describe(prog, args, &out);
    (out, d)
}

/// Command, status, stdout and stderr of a finished run, for failure messages.
pub fn describe(prog: &str, args: &[&str], out: &Output) -> String {
    format!(
        "command: {prog} {}\nstatus: {:?}\nstdout:\n{}\nstderr:\n{}",
        args.join(" "),
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Like [`exec`], but the program is killed after `limit` and the test fails saying it hung, so
/// that a regression to a hang fails instead of hanging the suite. `envs` are set for it.
pub fn exec_bounded(
    cwd: &Path,
    prog: &str,
    args: &[&str],
    envs: &[(&str, &str)],
    limit: std::time::Duration,
) -> (Output, String) {
    use std::process::Stdio;
    let mut child = Command::new(prog)
        .current_dir(cwd)
        .args(args)
        .envs(envs.iter().copied())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the binary runs");
    // Drained while it runs, so that a chatty program never blocks on a full pipe.
    let drain = |r: Option<Box<dyn std::io::Read + Send>>| {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            if let Some(mut r) = r {
                let _ = r.read_to_end(&mut v);
            }
            v
        })
    };
    let so = drain(child.stdout.take().map(|r| Box::new(r) as Box<dyn std::io::Read + Send>));
    let se = drain(child.stderr.take().map(|r| Box::new(r) as Box<dyn std::io::Read + Send>));
    let start = std::time::Instant::now();
    let (status, hung) = loop {
        if let Some(st) = child.try_wait().expect("wait") {
            break (st, false);
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            break (child.wait().expect("wait"), true);
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    };
    let out = Output { status, stdout: so.join().unwrap_or_default(), stderr: se.join().unwrap_or_default() };
    let d = describe(prog, args, &out);
    assert!(!hung, "hung for more than {limit:?}:\n{d}");
    (out, d)
}

/// Runs `clipbench ARGS`, insists that it succeeds and prints one JSON value, and returns it;
/// on failure the panic shows the command, its status and both outputs.
pub fn clipbench_json(args: &[&std::ffi::OsStr]) -> serde_json::Value {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_clipbench"));
    cmd.args(args);
    let out = cmd.output().expect("clipbench runs");
    let show = format!(
        "command: {cmd:?}\nstatus: {}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{show}");
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("not JSON: {e}\n{show}"))
}
