//! Whole-output snapshots of every `cliptex` and `icache` subcommand whose output is
//! deterministic: the real binaries run from the repository root on `config_examples/` (and on a
//! temporary directory), and their exit status, stdout and stderr are compared with
//! `tests/snapshots/NAME.snap` by `insta`. The temporary directory and the repository root are
//! written as `<TMP>` and `<ROOT>`, so the snapshots are the same on every machine.
//!
//! After an intended change of output, review the changed snapshots one at a time: run
//! `INSTA_UPDATE=new cargo test --test it cli_snapshots::`, which leaves each changed output
//! beside its snapshot as `NAME.snap.new`; compare each pair (`cargo insta review` does it
//! interactively, or `diff tests/snapshots/NAME.snap tests/snapshots/NAME.snap.new`) and accept
//! one by renaming it over the `.snap`. Under CI (`CI` set) a mismatch only fails.
//! Outputs that are not deterministic (a running service, timings) are checked by value in
//! `cli_dump.rs` and `cli_attach.rs`.

use std::path::Path;
use std::process::Command;

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const ICACHE: &str = env!("CARGO_BIN_EXE_icache");
const ROOT: &str = env!("CLIPMAP_ROOT");

/// Compares `actual` with the snapshot `tests/snapshots/NAME.snap` (insta).
fn snapshot(name: &str, actual: &str) {
    insta::with_settings!({
        snapshot_path => "../snapshots",
        prepend_module_to_snapshot => false,
        omit_expression => true,
    }, {
        insta::assert_snapshot!(name, actual);
    });
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
    check("cliptex_plan_non_square", CLIPTEX, &p(&["--size", "8192x2048", "--clip", "512", "--texel-bytes", "3"]), t);
    check("cliptex_plan_ct", CLIPTEX, &p(&["config_examples/non_square.ct", "--speed", "1000"]), t);
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

/// The subcommands a `--help` lists under `Commands:` (without `help`).
fn subcommands(help: &str) -> Vec<String> {
    help.lines()
        .skip_while(|l| l.trim() != "Commands:")
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|w| *w != "help")
        .map(str::to_string)
        .collect()
}

#[test]
fn every_help_of_every_tool_has_an_examples_section() {
    let bins = [
        CLIPTEX,
        ICACHE,
        env!("CARGO_BIN_EXE_clipprep"),
        env!("CARGO_BIN_EXE_clipbench"),
        env!("CARGO_BIN_EXE_clipmapd"),
        env!("CARGO_BIN_EXE_clipmap-read"),
    ];
    let help = |bin: &str, args: &[&str]| {
        let o = Command::new(bin).args(args).output().expect("the binary runs");
        assert_eq!(o.status.code(), Some(0), "{bin} {args:?} --help");
        String::from_utf8(o.stdout).unwrap()
    };
    let mut checked = 0;
    for bin in bins {
        let top = help(bin, &["--help"]);
        assert!(top.contains("\nExamples:\n"), "{bin} --help has no Examples: section\n{top}");
        checked += 1;
        for sub in subcommands(&top) {
            let text = help(bin, &[&sub, "--help"]);
            assert!(text.contains("\nExamples:\n"), "{bin} {sub} --help has no Examples: section\n{text}");
            // Every example names the tool it is an example of (or a tool it works with).
            let examples = text.split("\nExamples:\n").nth(1).unwrap();
            let name = Path::new(bin).file_name().unwrap().to_str().unwrap();
            assert!(examples.lines().next().is_some_and(|l| l.contains(name)), "{name} {sub}: {examples}");
            checked += 1;
        }
    }
    // cliptex 8, icache 4, clipbench 3 subcommands, and six tools.
    assert!(checked >= 6 + 8 + 4 + 3, "{checked} helps checked: the Commands: lists were not found");
}
