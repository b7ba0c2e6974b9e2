//! Parse-stage errors of docs/PERFORMER-REFERENCE.md §1.15, each with its code, severity, place and message, and
//! the strict/portability reporting modes.

use crate::common;

use clipmap::config::{Diagnostics, FileKind, Limits, Severity};
use clipmap::plan;
use common::*;

fn ct(body: &str) -> String {
    format!("ct_version2.0\n{RGB8}{body}")
}

#[test]
fn a_missing_config_file_cannot_be_loaded() {
    let fx = Fixture::new();
    let e = plan::load_clip_texture(&fx.path("nope.ct"), &opts()).unwrap_err();
    assert_eq!(e.source.kind(), std::io::ErrorKind::NotFound);
    assert!(e.to_string().contains("nope.ct"));
    let e = plan::load_image_cache(&fx.path("nope.ic"), &opts()).unwrap_err();
    assert!(e.to_string().contains("cannot read"));
}

#[test]
fn a_missing_level_ic_is_reported_at_the_name_that_gave_it() {
    let fx = Fixture::new();
    fx.write_level_ics("l", 2048, 2048, 256);
    fx.write("x.ct", ct("virt_size 2048 2048 1\nclip_size 512\nicache_files l.2048.ic gone.ic\n"));
    let l = plan::load_clip_texture(&fx.path("x.ct"), &opts()).unwrap();
    assert!(l.plan.is_none());
    let x = expect(
        &l.diagnostics,
        "icache-file-unreadable",
        Severity::Error,
        Some((7, 24)),
        &["level 1", "not found", "gone.ic"],
    );
    assert!(x.path.ends_with("x.ct"));
}

#[test]
fn an_unknown_word_where_a_token_is_expected() {
    let d = ct_err(&format!("{NO_IC_CT}clip_window 512\n"));
    expect(&d, "unknown-token", Severity::Error, Some((10, 1)), &["clip_window", "not a clip texture (.ct) token"]);
    // Its value is a stray word too, reported as such, and nothing else cascades.
    assert!(codes(&d).iter().all(|c| *c == "unknown-token"), "{}", listing(&d));
}

#[test]
fn a_token_of_the_other_file_kind() {
    let d = ct_err(&format!("{NO_IC_CT}tiles_in_file 2 2 1\n"));
    expect(&d, "token-not-allowed", Severity::Error, Some((10, 1)), &["tiles_in_file", "image cache (.ic)"]);
    let d = ct_err(&format!("ic_version2.0\n{}", &NO_IC_CT["ct_version2.0\n".len()..]));
    expect(&d, "wrong-file-kind", Severity::Error, Some((1, 1)), &["ic_version2.0", "icache validate"]);
    let d = ic_err(&format!("{SMALL_IC}clip_size 512\n"));
    expect(&d, "token-not-allowed", Severity::Error, Some((8, 1)), &["clip_size", "clip texture (.ct)"]);
    let d = ic_err(&SMALL_IC.replace("ic_version2.0", "ct_version1.0"));
    expect(&d, "wrong-file-kind", Severity::Error, Some((1, 1)), &["ct_version1.0", "cliptex validate"]);
}

#[test]
fn the_version_token_missing_or_not_first_is_a_warning() {
    let (_, d) = ct_ok(&NO_IC_CT.replace("ct_version2.0\n", ""));
    expect(&d, "missing-version", Severity::Warning, Some((1, 1)), &["ct_version2.0"]);
    let (_, d) = ct_ok(&NO_IC_CT.replace("ct_version2.0\n", "# a comment\nclip_size 512\nct_version2.0\n"));
    expect(&d, "version-not-first", Severity::Warning, Some((3, 1)), &["must begin the file"]);
    let (_, d) = ic_ok(&SMALL_IC.replace("ic_version2.0\n", ""));
    expect(&d, "missing-version", Severity::Warning, Some((1, 1)), &["ic_version2.0"]);
    // A comment before the version token is fine.
    let (_, d) = ic_ok(&format!("# header\n{SMALL_IC}"));
    absent(&d, "version-not-first");
}

#[test]
fn unknown_or_negative_format_values() {
    let d = ct_err(&NO_IC_CT.replace("PFTEX_PACK_8", "PFTEX_PAK_8"));
    expect(
        &d,
        "unknown-format",
        Severity::Error,
        Some((2, 12)),
        &["PFTEX_PAK_8", "ext_format", "did you mean `PFTEX_PACK_8`?"],
    );
    let d = ct_err(&NO_IC_CT.replace("PFTEX_RGB_8", "-5"));
    expect(&d, "unknown-format", Severity::Error, Some((3, 12)), &["-5", "int_format", "non-negative"]);
    let d = ct_err(&NO_IC_CT.replace("img_format PFTEX_RGB", "img_format SOMETHING"));
    expect(&d, "unknown-format", Severity::Error, Some((4, 12)), &["SOMETHING", "img_format"]);
    let d = ic_err(&SMALL_IC.replace("img_format PFTEX_RGB", "img_format 77"));
    expect(&d, "unknown-format", Severity::Error, Some((4, 12)), &["77"]);
    let d = ic_err(&SMALL_IC.replace("PFTEX_PACK_8", "GL_BITMAP"));
    expect(&d, "unsupported-texel-format", Severity::Error, Some((2, 1)), &["GL_BITMAP"]);
}

#[test]
fn bases_formats_and_file_lists_given_twice() {
    let d = ct_err(&format!("{NO_IC_CT}tile_base a/\ntile_base b/\n"));
    expect(&d, "duplicate-token", Severity::Error, Some((11, 1)), &["tile_base", "a base", "line 10"]);
    let d = ct_err(&format!("{NO_IC_CT}icache_base\nicache_base x\n"));
    expect(&d, "duplicate-token", Severity::Error, Some((11, 1)), &["icache_base"]);
    let d = ct_err(&format!("{NO_IC_CT}tile_format x%d\n"));
    expect(&d, "duplicate-token", Severity::Error, Some((10, 1)), &["tile_format", "a format"]);
    let d = ct_err(&ct("virt_size 2048 2048 1\nclip_size 512\nicache_files a b\nicache_files c d\n"));
    expect(&d, "duplicate-token", Severity::Error, Some((8, 1)), &["icache_files", "a file list"]);
    let d = ct_err(&ct("virt_size 2048 2048 1\nclip_size 512\ntile_files a\ntile_files b\n"));
    let x = expect(&d, "duplicate-token", Severity::Error, Some((8, 1)), &["tile_files", "file list"]);
    // 3.0's message named the format for both; ours does not.
    assert!(!x.message.contains("format"));
    let d = ic_err(&format!("{SMALL_IC}tile_base a\ntile_base b\n"));
    expect(&d, "duplicate-token", Severity::Error, Some((9, 1)), &["tile_base"]);
}

#[test]
fn unknown_or_misplaced_parameter_names() {
    let d =
        ct_err(&NO_IC_CT.replace("PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T", "PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_Q"));
    expect(&d, "unknown-param", Severity::Error, Some((8, 51)), &["TILENUM_Q", "did you mean"]);
    // PFCLIPTEX names in an .ic.
    let d = ic_err(&format!("{SMALL_IC}tile_format %d\ntile_params PFCLIPTEX_FNAMEARG_LEVEL\n"));
    expect(&d, "param-not-allowed", Severity::Error, Some((9, 13)), &["PFCLIPTEX", ".ic"]);
}

#[test]
fn too_many_parameters() {
    let seven = ["PFCLIPTEX_FNAMEARG_LEVEL"; 7].join(" ");
    let d = ct_err(&ct(&format!(
        "virt_size 2048 2048 1\nclip_size 512\nicache_format {}\nicache_params {seven}\n",
        "%d".repeat(7)
    )));
    expect(&d, "too-many-params", Severity::Error, Some((8, 1)), &["7 parameters", "at most 6", ".ct"]);
    let seventeen = ["PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S"; 17].join(" ");
    let d = ic_err(&format!("{SMALL_IC}tile_format {}\ntile_params {seventeen}\n", "%d".repeat(17)));
    expect(&d, "too-many-params", Severity::Error, Some((9, 1)), &["17 parameters", "at most 16", ".ic"]);
    // 16 is fine.
    let sixteen = ["PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S"; 16].join(" ");
    ic_ok(&format!("{SMALL_IC}tile_format {}\ntile_params {sixteen}\n", "%d".repeat(16)));
}

#[test]
fn a_format_and_a_file_list_for_the_same_group() {
    let d = ct_err(&format!("{NO_IC_CT}tile_files a b c\n"));
    expect(&d, "format-and-file-list", Severity::Error, Some((10, 1)), &["both `tile_format` and `tile_files`"]);
    let d =
        ct_err(&ct("virt_size 2048 2048 1\nclip_size 512\nicache_params PFCLIPTEX_FNAMEARG_LEVEL\nicache_files a b\n"));
    expect(&d, "format-and-file-list", Severity::Error, Some((8, 1)), &["icache"]);
}

#[test]
fn params_without_format() {
    // In a .ct: an error (Performer 3.0 crashes).
    let d = ct_err(&ct(
        "virt_size 2048 2048 1\nclip_size 512\ntile_size 256 256 1\nicache_params PFCLIPTEX_FNAMEARG_LEVEL\n",
    ));
    expect(
        &d,
        "params-without-format",
        Severity::Error,
        Some((8, 1)),
        &["`icache_params` without `icache_format`", "crashes"],
    );
    // In an .ic: ignored with a warning; the default format is used.
    let (p, d) = ic_ok(&format!("{SMALL_IC}tile_params PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S\n"));
    expect(&d, "params-without-format", Severity::Warning, Some((8, 1)), &["ignored"]);
    assert!(p.naming.default_format);
}

#[test]
fn page_size_and_lookahead_must_be_integers() {
    // Performer warns and takes the default; we refuse (the word would be an invalid token there).
    let d = ct_err(&format!("{NO_IC_CT}page_size big\n"));
    expect(&d, "expected-integer", Severity::Error, Some((10, 11)), &["page_size", "big"]);
    let d = ic_err(&format!("{SMALL_IC}lookahead one\n"));
    expect(&d, "expected-integer", Severity::Error, Some((8, 11)), &["lookahead"]);
    let d = ct_err(&format!("{NO_IC_CT}lookahead -1\n"));
    expect(&d, "negative-value", Severity::Error, Some((10, 11)), &["lookahead", "negative"]);
    let d = ct_err(&format!("{NO_IC_CT}page_size -2\n"));
    expect(&d, "bad-page-size", Severity::Error, Some((10, 11)), &["-1 (default), 0"]);
    let (p, d) = ct_ok(&format!("{NO_IC_CT}page_size 1000\n"));
    expect(&d, "page-size-not-power-of-two", Severity::Warning, Some((10, 11)), &["power of two"]);
    assert_eq!(p.page_size, 1000);
}

#[test]
fn read_func_is_recorded_but_not_loaded() {
    let (p, d) = ct_ok(&format!("{NO_IC_CT}read_func libmine.so myread\n"));
    expect(&d, "read-func-unsupported", Severity::Warning, Some((10, 1)), &["myread", "not loaded", "default reader"]);
    let rf = p.read_func.unwrap();
    assert_eq!((rf.library.as_deref(), rf.symbol.as_str()), (Some("libmine.so"), "myread"));
    let (p, _) = ic_ok(&format!("{SMALL_IC}read_func myread\n"));
    assert_eq!(p.read_func.unwrap().library, None);
    let d = ct_err(&format!("{NO_IC_CT}read_func\n"));
    expect(&d, "missing-value", Severity::Error, Some((10, 1)), &["read_func"]);
}

#[test]
fn obsolete_tokens_are_notes() {
    let (_, d) = ct_ok(&format!("{NO_IC_CT}num_tile_params 3\nphase_shift 1 1\nphase_margin 2\n"));
    let notes: Vec<_> = d.items.iter().filter(|x| x.code == "obsolete-token").collect();
    assert_eq!(notes.len(), 3, "{}", listing(&d));
    assert!(notes.iter().all(|x| x.severity == Severity::Note));
    let (_, d) = ic_ok(&format!("{SMALL_IC}num_tile_params 1\nnum_streams 4\n"));
    expect(&d, "obsolete-token", Severity::Note, Some((8, 1)), &["num_tile_params"]);
    // As the manual writes it: three integers, the S, T and R modulo counts.
    let (_, d) = ic_ok(&format!("{SMALL_IC}num_streams 3 2 1\n"));
    assert!(!d.has_errors(), "{}", listing(&d));
}

#[test]
fn numbers_out_of_range_and_not_utf8() {
    let d = ct_err(&NO_IC_CT.replace("clip_size 512", "clip_size 99999999999999999999"));
    expect(&d, "number-out-of-range", Severity::Error, Some((6, 11)), &["clip_size", "out of range"]);
    let mut bytes = NO_IC_CT.as_bytes().to_vec();
    bytes.extend_from_slice(b"tile_base caf\xe9/\n");
    let (_, d) = parse(&bytes, FileKind::ClipTexture);
    expect(&d, "not-utf8", Severity::Error, Some((10, 11)), &["UTF-8", "caf"]);
}

#[test]
fn limits_are_reported_as_errors() {
    let limits = Limits {
        max_word_bytes: 16,
        max_list_items: 3,
        max_entries: 5,
        max_file_bytes: 200,
        max_diagnostics: 4,
        ..Limits::default()
    };
    let p = |t: &str| clipmap::config::parse_bytes(t.as_bytes(), "x.ct".as_ref(), FileKind::ClipTexture, &limits).1;
    let d = p("tile_base aaaaaaaaaaaaaaaaaaaaaaaa\n");
    expect(&d, "word-too-long", Severity::Error, Some((1, 11)), &["24 bytes", "16 bytes"]);
    let d = p("tile_files a b c d e\n");
    expect(&d, "list-too-long", Severity::Error, Some((1, 18)), &["tile_files", "3 items"]);
    let d = p("lookahead 1\nlookahead 1\nlookahead 1\nlookahead 1\nlookahead 1\nlookahead 1\nlookahead 1\n");
    expect(&d, "too-many-entries", Severity::Error, Some((6, 1)), &["more than 5 tokens"]);
    let d = p(&"x ".repeat(120));
    expect(&d, "file-too-large", Severity::Error, Some((1, 1)), &["240 bytes", "200 bytes"]);
    let d: Diagnostics = p("a b c d e f g\n");
    assert_eq!(d.items.len(), 4, "{}", listing(&d));
    expect(&d, "too-many-diagnostics", Severity::Error, Some((1, 7)), &["too many problems"]);
}

#[test]
fn strict_mode_turns_warnings_and_portability_findings_into_errors() {
    let text = format!("{NO_IC_CT}invalid_border 4\n").replace("virt_size 4096 4096 1", "virt_size 4096 4096");
    let (_fx, l) = load_ct(&text);
    let mut relaxed = l.diagnostics.clone();
    relaxed.apply_mode(false);
    // Portability findings are notes; plain warnings stay warnings.
    assert_eq!(find(&relaxed, "size-missing-r").severity, Severity::Note);
    assert_eq!(find(&relaxed, "border-raised").severity, Severity::Warning);
    assert!(!relaxed.has_errors());
    let mut strict = l.diagnostics.clone();
    strict.apply_mode(true);
    assert_eq!(find(&strict, "size-missing-r").severity, Severity::Error);
    assert_eq!(find(&strict, "border-raised").severity, Severity::Error);
    // Notes that are not about portability stay notes.
    let (_fx, l) = load_ct(&format!("{NO_IC_CT}phase_shift 1\n"));
    let mut strict = l.diagnostics.clone();
    strict.apply_mode(true);
    assert_eq!(find(&strict, "obsolete-token").severity, Severity::Note);
}

#[test]
fn out_of_order_tokens_are_a_portability_finding() {
    let (_, d) = ct_ok(
        &NO_IC_CT
            .replace("clip_size 512\n", "")
            .replace("tile_size 256 256 1\n", "tile_size 256 256 1\nclip_size 512\n"),
    );
    let x = expect(&d, "out-of-order", Severity::Warning, Some((9, 1)), &["`clip_size` comes after `tile_size`"]);
    assert!(x.portability);
}

#[test]
fn rendering_gives_path_line_col_the_source_line_a_caret_and_the_hint() {
    let (_fx, l) = load_ct(&format!("{NO_IC_CT}  clip_sise 512\n"));
    let out = l.render();
    let first = out.lines().next().unwrap();
    assert!(first.ends_with("t.ct:10:3: error: `clip_sise` is not a clip texture (.ct) token (found `clip_sise`, expected a token name)"), "{out}");
    assert!(out.contains("  10 |   clip_sise 512\n"), "{out}");
    assert!(out.contains("       |   ^^^^^^^^^\n"), "{out}");
    assert!(out.contains("  = hint: did you mean `clip_size`?\n"), "{out}");
}

#[test]
fn manual_misspelling_icache_base_suggests_image_cache_base_not_tile_base() {
    // D-CT's examples use PFCLIPTEX_FNAMEARG_ICACHE_BASE, which is not a token; string
    // similarity alone suggested PFCLIPTEX_FNAMEARG_TILE_BASE, which names the other group.
    let d = ct_err(&ct("virt_size 2048 2048 1\nclip_size 512\nicache_format %s%d.ic\n\
         icache_params PFCLIPTEX_FNAMEARG_ICACHE_BASE PFCLIPTEX_FNAMEARG_LEVEL\n"));
    let x = expect(&d, "unknown-param", Severity::Error, Some((8, 15)), &["PFCLIPTEX_FNAMEARG_ICACHE_BASE"]);
    assert_eq!(x.hint.as_deref(), Some("did you mean `PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE`?"));
}

#[test]
fn paging_extension_lines_are_read_and_performer_sees_comments() {
    use clipmap::paging::{EvictionKind, PrefetchKind};
    let (p, d) = ct_ok(&format!(
        "{NO_IC_CT}#clipmap prefetch direction\n#clipmap eviction shift\n#clipmap pool_bytes 64m\n#clipmap max_centre_step 32\n# clipmap prefetch ahead\n"
    ));
    clean(&d);
    assert_eq!(p.paging.prefetch, PrefetchKind::Direction, "`# clipmap` (with a space) is a plain comment");
    assert_eq!(p.paging.eviction, EvictionKind::Shift);
    assert_eq!(p.paging.pool_bytes, 64 << 20);
    assert_eq!(p.paging.max_centre_step, Some(32));
    // Without any: the defaults (the comparison's winners).
    let (p, _) = ct_ok(NO_IC_CT);
    assert_eq!(p.paging, clipmap::paging::PagingOptions::default());
    assert_eq!(p.paging.prefetch, PrefetchKind::Adaptive);
    assert_eq!(p.paging.pool_bytes, 0);
}

#[test]
fn paging_extension_errors_say_where_and_what_was_expected() {
    let d = ct_err(&format!("{NO_IC_CT}#clipmap prefetch sideways\n"));
    expect(
        &d,
        "bad-extension-value",
        Severity::Error,
        Some((10, 19)),
        &["sideways", "`ring`, `direction`, `ahead` or `adaptive`"],
    );
    let d = ct_err(&format!("{NO_IC_CT}#clipmap evicton lru\n"));
    expect(&d, "unknown-extension", Severity::Error, Some((10, 10)), &["evicton", "did you mean `eviction`?"]);
    let d = ct_err(&format!("{NO_IC_CT}#clipmap pool_bytes lots\n"));
    expect(&d, "bad-extension-value", Severity::Error, Some((10, 21)), &["lots", "byte count"]);
    let d = ct_err(&format!("{NO_IC_CT}#clipmap pool_bytes\n"));
    expect(&d, "missing-value", Severity::Error, Some((10, 10)), &["pool_bytes"]);
    let d = ct_err(&format!("{NO_IC_CT}#clipmap\n"));
    expect(&d, "extension-empty", Severity::Error, Some((10, 1)), &["pool_bytes"]);
    let d = ct_err(&format!("{NO_IC_CT}#clipmap eviction lru shift\n"));
    expect(&d, "extension-extra-words", Severity::Error, Some((10, 23)), &["shift", "one setting"]);
    let d = ct_err(&format!("{NO_IC_CT}#clipmap max_centre_step 0\n"));
    expect(&d, "bad-extension-value", Severity::Error, Some((10, 26)), &["above 0"]);
}
