//! Whole-output snapshots of every `cliptex` and `icache` subcommand whose output is
//! deterministic: the real binaries run from the repository root on `config_examples/` (and on a
//! temporary directory), and their exit status, stdout and stderr are compared with
//! `tests/snapshots/NAME.txt`. The temporary directory and the repository root are written as
//! `<TMP>` and `<ROOT>`, so the snapshots are the same on every machine.
//!
//! After an intended change of output, rewrite the snapshots and review the diff:
//! `UPDATE_SNAPSHOTS=1 cargo test --test cli_snapshots`, then `git diff tests/snapshots`.
//! Outputs that are not deterministic (a running service, timings) are checked by value in
//! `cli_dump.rs` and `cli_attach.rs`.

use std::path::Path;
use std::process::Command;

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const ICACHE: &str = env!("CARGO_BIN_EXE_icache");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The lines of `a` and `b` as a minimal edit script: `  ` kept, `- ` only in a (the snapshot),
/// `+ ` only in b (the output), with two lines of context around each change.
fn diff(a: &str, b: &str) -> String {
    let (a, b): (Vec<&str>, Vec<&str>) = (a.lines().collect(), b.lines().collect());
    let mut lcs = vec![vec![0u32; b.len() + 1]; a.len() + 1];
    for i in (0..a.len()).rev() {
        for j in (0..b.len()).rev() {
            lcs[i][j] = if a[i] == b[j] { lcs[i + 1][j + 1] + 1 } else { lcs[i + 1][j].max(lcs[i][j + 1]) };
        }
    }
    let mut ops = Vec::new();
    let (mut i, mut j) = (0, 0);
    while i < a.len() || j < b.len() {
        if i < a.len() && j < b.len() && a[i] == b[j] {
            ops.push(("  ", a[i]));
            i += 1;
            j += 1;
        } else if i < a.len() && (j == b.len() || lcs[i + 1][j] >= lcs[i][j + 1]) {
            ops.push(("- ", a[i]));
            i += 1;
        } else {
            ops.push(("+ ", b[j]));
            j += 1;
        }
    }
    let changed: Vec<usize> = ops.iter().enumerate().filter(|(_, o)| o.0 != "  ").map(|(k, _)| k).collect();
    let mut out = String::new();
    let mut last = None;
    for (k, (tag, line)) in ops.iter().enumerate() {
        if changed.iter().any(|&c| c.abs_diff(k) <= 2) {
            if last.is_some_and(|l: usize| l + 1 != k) {
                out.push_str("  ...\n");
            }
            out.push_str(&format!("{tag}{line}\n"));
            last = Some(k);
        }
    }
    out
}

/// Compares `actual` with `tests/snapshots/NAME.txt`, or writes it there when the environment
/// has `UPDATE_SNAPSHOTS=1`.
fn snapshot(name: &str, actual: &str) {
    let path = Path::new(ROOT).join("tests/snapshots").join(format!("{name}.txt"));
    if std::env::var("UPDATE_SNAPSHOTS").as_deref() == Ok("1") {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, actual).unwrap();
        return;
    }
    let expected = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "snapshot {}: {e}\nthe output was:\n{actual}\nwrite it with UPDATE_SNAPSHOTS=1 cargo test --test cli_snapshots",
            path.display()
        )
    });
    if expected != actual {
        panic!(
            "output differs from snapshot {} (- snapshot, + output):\n{}\nif the change is intended: UPDATE_SNAPSHOTS=1 cargo test --test cli_snapshots",
            path.display(),
            diff(&expected, actual)
        );
    }
}

/// Runs `prog args` in the repository root; returns `$ command`, exit status, stdout and stderr
/// as one text with `tmp` and the root replaced by `<TMP>` and `<ROOT>`.
fn run(prog: &str, args: &[&str], tmp: &Path) -> String {
    let out = Command::new(prog).current_dir(ROOT).args(args).output().expect("the binary runs");
    let name = Path::new(prog).file_name().unwrap().to_string_lossy();
    let text = format!(
        "$ {name} {}\n(exit status {})\n--- stdout\n{}--- stderr\n{}",
        args.join(" "),
        out.status.code().map_or("none".to_string(), |c| c.to_string()),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let tmp_text = tmp.to_str().unwrap();
    let canon = tmp.canonicalize().unwrap();
    text.replace(canon.to_str().unwrap(), "<TMP>").replace(tmp_text, "<TMP>").replace(ROOT, "<ROOT>")
}

fn check(name: &str, prog: &str, args: &[&str], tmp: &Path) {
    snapshot(name, &run(prog, args, tmp));
}

#[test]
fn the_diff_shows_changed_lines_with_context() {
    let d = diff("a\nb\nc\nd\ne\nf\ng\nh\n", "a\nb\nc\nD\ne\nf\ng\nh\n");
    assert_eq!(d, "  b\n  c\n- d\n+ D\n  e\n  f\n");
    assert_eq!(diff("x\n", "x\n"), "");
    assert_eq!(diff("", "new\n"), "+ new\n");
}

#[test]
fn cliptex_validate_info_and_tile() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let broken = t.join("broken.ct");
    std::fs::write(
        &broken,
        "ct_version2.0\next_format PFTEX_PACK_8\nint_format PFTEX_RGB_8\nimg_format PFTEX_RBG\nvirt_size 4096 4096\nclip_size512\ninvalid_border 4\n",
    )
    .unwrap();
    let b = broken.to_str().unwrap();
    check(
        "cliptex_validate",
        CLIPTEX,
        &["validate", "config_examples/v2_format_params.ct", "config_examples/streams.ct"],
        t,
    );
    check("cliptex_validate_broken", CLIPTEX, &["validate", b], t);
    check("cliptex_validate_broken_json", CLIPTEX, &["validate", "--json", b], t);
    check("cliptex_info", CLIPTEX, &["info", "config_examples/v1_file_lists.ct"], t);
    check("cliptex_info_json", CLIPTEX, &["info", "config_examples/prepared/hash256.ct", "--json"], t);
    check("cliptex_info_invalid", CLIPTEX, &["info", b], t);
    check(
        "cliptex_tile_json",
        CLIPTEX,
        &["tile", "config_examples/multi_tile_files.ct", "--level", "0", "--s", "6", "--t", "9", "--json"],
        t,
    );
    check(
        "cliptex_tile",
        CLIPTEX,
        &["tile", "config_examples/prepared/hash256.ct", "--level", "1", "--s", "1", "--t", "0"],
        t,
    );
    check(
        "cliptex_tile_out_of_range",
        CLIPTEX,
        &["tile", "config_examples/prepared/hash256.ct", "--level", "0", "--s", "9", "--t", "0"],
        t,
    );
}

#[test]
fn cliptex_plan_in_every_mode() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let p = |v: &[&'static str]| [&["plan"], v].concat();
    check(
        "cliptex_plan",
        CLIPTEX,
        &p(&["--size", "67108864", "--clip", "2048", "--texel-bytes", "4", "--display", "1920", "--speed", "2000"]),
        t,
    );
    check("cliptex_plan_json", CLIPTEX, &p(&["--size", "65536", "--clip", "1024", "--texel-bytes", "3", "--json"]), t);
    check(
        "cliptex_plan_eye_height",
        CLIPTEX,
        &p(&[
            "--size",
            "67108864",
            "--clip",
            "2048",
            "--texel-bytes",
            "4",
            "--display",
            "1920",
            "--eye-height",
            "3000",
        ]),
        t,
    );
    check("cliptex_plan_table", CLIPTEX, &p(&["--table", "--clip", "2048", "--texel-bytes", "4"]), t);
    check("cliptex_plan_table_json", CLIPTEX, &p(&["--table", "--clip", "1024", "--texel-bytes", "3", "--json"]), t);
    check("cliptex_plan_not_a_power_of_two", CLIPTEX, &p(&["--size", "65535", "--clip", "1024"]), t);
}

#[test]
fn cliptex_check_roam_and_dump_from_disk() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let png = |n: &str| t.join(n).to_str().unwrap().to_string();
    let ct = "config_examples/prepared/hash256.ct";
    check("cliptex_check", CLIPTEX, &["check", ct], t);
    check("cliptex_check_json", CLIPTEX, &["check", ct, "--json"], t);
    check(
        "cliptex_roam",
        CLIPTEX,
        &[
            "roam",
            "--source",
            "hash",
            "--size",
            "16384",
            "--clip",
            "256",
            "--tile",
            "64",
            "--flight",
            "straight:16:30",
            "--frames",
            "5",
            "--wait-for-reads",
            "--budget-ms",
            "inf",
        ],
        t,
    );
    check("cliptex_roam_bad_flight", CLIPTEX, &["roam", ct, "--flight", "spiral:3", "--frames", "2"], t);
    check("cliptex_dump", CLIPTEX, &["dump", ct, "--level", "1", "--out", &png("l1.png")], t);
    check(
        "cliptex_dump_json",
        CLIPTEX,
        &["dump", ct, "--level", "0", "--region", "10,20,74,60", "--out", &png("r.png"), "--json"],
        t,
    );
    check("cliptex_dump_quiet", CLIPTEX, &["dump", ct, "--level", "8", "--out", &png("q.png"), "--quiet"], t);
    check(
        "cliptex_dump_too_large",
        CLIPTEX,
        &["dump", "config_examples/v2_format_params.ct", "--out", &png("x.png")],
        t,
    );
    check(
        "cliptex_dump_region_outside",
        CLIPTEX,
        &["dump", ct, "--level", "2", "--region", "0,0,65,8", "--out", &png("x.png")],
        t,
    );
    check("cliptex_dump_bad_region", CLIPTEX, &["dump", ct, "--region", "1,2,3", "--out", &png("x.png")], t);
    check("cliptex_dump_no_level", CLIPTEX, &["dump", ct, "--level", "9", "--out", &png("x.png")], t);
    check(
        "cliptex_dump_missing_tiles",
        CLIPTEX,
        &["dump", "config_examples/v1_file_lists.ct", "--level", "3", "--out", &png("m.png")],
        t,
    );
    check(
        "cliptex_dump_attach_absent",
        CLIPTEX,
        &["dump", "--attach", "absent", "--shm-dir", t.to_str().unwrap(), "--out-dir", &png("pictures")],
        t,
    );
    check("cliptex_dump_unwritable", CLIPTEX, &["dump", ct, "--level", "8", "--out", &png("no/such/dir/x.png")], t);
}

#[test]
fn icache_validate_info_tile_and_dump() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let png = |n: &str| t.join(n).to_str().unwrap().to_string();
    let ic = "config_examples/prepared/L00.ic";
    check(
        "icache_validate",
        ICACHE,
        &["validate", "config_examples/standalone.ic", "config_examples/sparse_default_tile.ic", ic],
        t,
    );
    check("icache_info", ICACHE, &["info", "config_examples/standalone.ic"], t);
    check("icache_info_json", ICACHE, &["info", ic, "--json"], t);
    check("icache_tile_json", ICACHE, &["tile", ic, "--s", "3", "--t", "2", "--json"], t);
    check("icache_tile", ICACHE, &["tile", ic, "--s", "1", "--t", "0"], t);
    check("icache_dump", ICACHE, &["dump", "config_examples/prepared/L01.ic", "--out", &png("l1.png")], t);
    check("icache_dump_json", ICACHE, &["dump", ic, "--region", "60,60,70,70", "--out", &png("r.png"), "--json"], t);
    check("icache_dump_too_large", ICACHE, &["dump", "config_examples/standalone.ic", "--out", &png("x.png")], t);
    check(
        "icache_dump_missing_tiles",
        ICACHE,
        &["dump", "config_examples/standalone.ic", "--region", "250,250,262,262", "--out", &png("m.png")],
        t,
    );
}

#[test]
fn help_texts_with_their_examples() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    check("cliptex_help", CLIPTEX, &["--help"], t);
    check("cliptex_dump_help", CLIPTEX, &["dump", "--help"], t);
    check("cliptex_attach_help", CLIPTEX, &["attach", "--help"], t);
    check("icache_help", ICACHE, &["--help"], t);
    check("icache_dump_help", ICACHE, &["dump", "--help"], t);
}
