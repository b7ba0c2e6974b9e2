//! Clip texture build-stage errors of docs/PERFORMER-REFERENCE.md §1.15 (checks 1-12), plus the extra checks
//! this reader makes (formats, sizes, naming).

use crate::common;

use clipmap::config::Severity;
use clipmap::plan;
use common::*;

fn ct(body: &str) -> String {
    format!("ct_version2.0\n{RGB8}{body}")
}

const NAMING: &str = "tile_size 256 256 1\n";

// ---- clip texture build stage ----

#[test]
fn ct1_smallest_icache_more_than_twice_the_clip_size() {
    let d = ct_err(&format!("{NO_IC_CT}smallest_icache 2048 2048 1\n"));
    expect(&d, "smallest-icache-too-large", Severity::Error, Some((10, 1)), &["2048", "twice `clip_size` (512)"]);
}

#[test]
fn ct1_quirk_a_missing_clip_size_is_reported_as_missing() {
    // 3.0 says "clip size too small relative to minimum image cache size" here.
    let d = ct_err(&NO_IC_CT.replace("clip_size 512\n", ""));
    expect(&d, "missing-mandatory", Severity::Error, Some((1, 1)), &["`clip_size` is missing"]);
    absent(&d, "smallest-icache-too-large");
}

#[test]
fn ct2_formats_are_mandatory() {
    for (line, name) in [(2, "ext_format"), (3, "int_format"), (4, "img_format")] {
        let text: String =
            NO_IC_CT.lines().enumerate().filter(|(i, _)| *i + 1 != line).map(|(_, l)| format!("{l}\n")).collect();
        let d = ct_err(&text);
        expect(&d, "missing-mandatory", Severity::Error, Some((1, 1)), &[name, "mandatory"]);
    }
}

#[test]
fn ct3_virt_size_unset_zero_negative_or_short() {
    let d = ct_err(&NO_IC_CT.replace("virt_size 4096 4096 1\n", ""));
    expect(&d, "missing-mandatory", Severity::Error, Some((1, 1)), &["`virt_size` is missing"]);
    let d = ct_err(&NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 4096 0 1"));
    expect(&d, "size-not-positive", Severity::Error, Some((5, 16)), &["T of `virt_size`", "positive"]);
    let d = ct_err(&NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size -4096 4096 1"));
    expect(&d, "size-not-positive", Severity::Error, Some((5, 11)), &["S of `virt_size`"]);
    let d = ct_err(&NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 4096"));
    expect(&d, "size-needs-three", Severity::Error, Some((5, 1)), &["1 number"]);
    let d = ct_err(&NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 4096 4096 2"));
    expect(&d, "three-dimensional", Severity::Error, Some((5, 21)), &["R of `virt_size` is 2"]);
}

#[test]
fn ct5_smallest_icache_zero() {
    let d = ct_err(&format!("{NO_IC_CT}smallest_icache 0 1024 1\n"));
    expect(&d, "smallest-icache-zero", Severity::Error, Some((10, 17)), &["cannot be 0"]);
}

#[test]
fn ct6_clip_size_zero_or_negative_is_an_error() {
    // 3.0 only warns about 0 and then divides by zero.
    let d = ct_err(&NO_IC_CT.replace("clip_size 512", "clip_size 0"));
    expect(&d, "clip-size-not-positive", Severity::Error, Some((6, 11)), &["positive"]);
    let d = ct_err(&NO_IC_CT.replace("clip_size 512", "clip_size -512"));
    expect(&d, "clip-size-not-positive", Severity::Error, Some((6, 11)), &["-512"]);
}

#[test]
fn ct7_sizes_must_be_powers_of_two() {
    let d = ct_err(&NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 4000 4096 1"));
    expect(&d, "size-not-power-of-two", Severity::Error, Some((5, 11)), &["S of `virt_size`", "2048 and 4096"]);
    let d = ct_err(&NO_IC_CT.replace("clip_size 512", "clip_size 500"));
    expect(&d, "clip-size-not-power-of-two", Severity::Error, Some((6, 11)), &["power of two", "256 and 512"]);
}

#[test]
fn ct8_clip_size_larger_than_the_texture_warns_then_the_default_smallest_fails() {
    let d = ct_err(&NO_IC_CT.replace("clip_size 512", "clip_size 8192"));
    expect(&d, "clip-larger-than-texture", Severity::Warning, Some((6, 1)), &["8192", "4096"]);
    expect(&d, "smallest-icache-larger-than-texture", Severity::Error, Some((6, 1)), &["16384", "2 x clip_size"]);
}

#[test]
fn ct9_invalid_border_negative_or_too_wide() {
    let d = ct_err(&format!("{NO_IC_CT}invalid_border -8\n"));
    expect(&d, "negative-value", Severity::Error, Some((10, 16)), &["invalid_border"]);
    let d = ct_err(&format!("{NO_IC_CT}invalid_border 256\n"));
    expect(&d, "border-too-wide", Severity::Error, Some((10, 1)), &["256", "512-texel"]);
}

#[test]
fn ct10_smallest_icache_not_proportional() {
    let d = ct_err(&format!("{NO_IC_CT}smallest_icache 1024 512 1\n"));
    expect(&d, "smallest-icache-not-proportional", Severity::Error, Some((10, 1)), &["1024x512", "4096x4096"]);
    let d = ct_err(&format!("{NO_IC_CT}smallest_icache 768 768 1\n"));
    expect(&d, "smallest-icache-not-proportional", Severity::Error, Some((10, 1)), &["768x768"]);
}

#[test]
fn ct11_a_level_ic_error_fails_the_clip_texture_and_is_reported_in_the_ic() {
    let fx = Fixture::new();
    fx.write_level_ics("l", 2048, 1024, 256);
    // Level 1 describes the wrong size.
    fx.write("l.1024.ic", level_ic(512, 512, 256));
    fx.write("x.ct", ct("virt_size 2048 2048 1\nclip_size 512\nicache_files l.2048.ic l.1024.ic\n"));
    let l = plan::load_clip_texture(&fx.path("x.ct"), &opts()).unwrap();
    assert!(l.plan.is_none());
    let x = expect(
        &l.diagnostics,
        "icache-size-mismatch",
        Severity::Error,
        Some((5, 1)),
        &["512x512", "level 1", "1024x1024"],
    );
    assert!(x.path.ends_with("l.1024.ic"));
    // Every file read is kept for rendering.
    assert_eq!(l.sources.len(), 3);
    assert!(l.render().contains("l.1024.ic:5:1: error:"));
}

#[test]
fn ct11_level_ics_must_use_the_clip_textures_texel_format() {
    let fx = Fixture::new();
    fx.write_level_ics("l", 2048, 1024, 256);
    fx.write("l.2048.ic", level_ic(2048, 2048, 256).replace("PFTEX_RGB\n", "PFTEX_RGBA\n"));
    fx.write("l.1024.ic", level_ic(1024, 1024, 256).replace("PFTEX_RGB_8", "PFTEX_RGBA_8"));
    fx.write("x.ct", ct("virt_size 2048 2048 1\nclip_size 512\nicache_files l.2048.ic l.1024.ic\n"));
    let l = plan::load_clip_texture(&fx.path("x.ct"), &opts()).unwrap();
    expect(&l.diagnostics, "format-mismatch", Severity::Error, Some((2, 1)), &["4 bytes", "3 bytes"]);
    // Same texel size, different int_format only: no difference in the texel.
    absent(&l.diagnostics, "format-differs");
}

#[test]
fn ct12_pyramid_file_list_too_short_or_too_long() {
    let files = |n: usize| (0..n).map(|i| format!("p{i}")).collect::<Vec<_>>().join(" ");
    let d = ct_err(&ct(&format!("virt_size 2048 2048 1\nclip_size 512\n{NAMING}tile_files {}\n", files(9))));
    expect(&d, "file-list-too-short", Severity::Error, Some((8, 1)), &["9 entries", "10 pyramid levels", "512x512"]);
    let (_, d) = ct_ok(&ct(&format!("virt_size 2048 2048 1\nclip_size 512\n{NAMING}tile_files {}\n", files(11))));
    expect(&d, "file-list-too-long", Severity::Warning, Some((8, 42)), &["11 entries", "only 10"]);
    let d = ct_err(&ct("virt_size 2048 2048 1\nclip_size 512\nicache_files a.ic\n"));
    expect(&d, "file-list-too-short", Severity::Error, Some((7, 1)), &["1 entry", "2 image cache levels"]);
}

#[test]
fn ct12_a_stream_parameter_in_a_ct_format() {
    let d = ct_err(&ct(&format!(
        "virt_size 2048 2048 1\nclip_size 512\n{NAMING}tile_format %s%d\ntile_params \
         PFIMAGECACHE_TILE_FILENAMEARG_STREAMSERVERNAME PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S\n"
    )));
    expect(&d, "param-not-allowed", Severity::Error, Some((9, 13)), &["stream servers are not supported"]);
}

#[test]
fn cross_group_and_no_ic_parameter_refusals() {
    let d = ct_err(&ct(
        "virt_size 2048 2048 1\nclip_size 512\nicache_format %s\nicache_params PFCLIPTEX_FNAMEARG_TILE_BASE\n",
    ));
    expect(&d, "param-not-allowed", Severity::Error, Some((8, 15)), &["tile base", "icache_params"]);
    let d = ct_err(&ct(
        "virt_size 2048 2048 1\nclip_size 512\nicache_files a b\ntile_format %s\ntile_params PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE\n",
    ));
    expect(&d, "param-not-allowed", Severity::Error, Some((9, 13)), &["IMAGE_CACHE_BASE", "tile_params"]);
    // LEVEL in no-.ic mode would also name image cache tiles, where it means nothing.
    let d = ct_err(&ct(&format!(
        "virt_size 2048 2048 1\nclip_size 512\ntile_format %d\ntile_params PFCLIPTEX_FNAMEARG_LEVEL\n{NAMING}"
    )));
    expect(&d, "param-not-allowed", Severity::Error, Some((8, 13)), &["no-.ic mode", "VSIZE_S"]);
}

#[test]
fn format_conversions_are_counted_and_typed() {
    let base = "virt_size 2048 2048 1\nclip_size 512\ntile_size 256 256 1\n";
    let d = ct_err(&ct(&format!("{base}tile_format p.%d.%d\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S\n")));
    expect(&d, "param-count-mismatch", Severity::Error, Some((8, 13)), &["2 conversions", "1 parameter"]);
    let d = ct_err(&ct(&format!("{base}tile_format p.%s\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S\n")));
    expect(&d, "param-type-mismatch", Severity::Error, Some((9, 13)), &["`%s`", "VSIZE_S", "an integer"]);
    let d = ct_err(&ct(&format!("{base}tile_format p.%q\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S\n")));
    expect(&d, "bad-format", Severity::Error, Some((8, 13)), &["character 3", "%q"]);
    // `%%` takes no parameter.
    let (p, _) = ct_ok(&ct(&format!("{base}tile_format p%%.%d\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S\n")));
    assert!(p.locate(4, 0, 0).unwrap().path.as_local().unwrap().ends_with("p%.128"));
}

#[test]
fn no_ic_mode_needs_a_tile_size() {
    let d = ct_err(&ct("virt_size 2048 2048 1\nclip_size 512\ntile_files a b c d e f g h i j\n"));
    expect(&d, "no-ic-needs-tile-size", Severity::Error, Some((1, 1)), &["`tile_size` is required"]);
    let d = ct_err(&ct("virt_size 2048 2048 1\nclip_size 512\ntile_size 384 384 1\n"));
    expect(&d, "tile-does-not-divide", Severity::Error, None, &["384x384", "level 0"]);
}

#[test]
fn level_counts_and_limits() {
    let d = ct_err(&format!("{NO_IC_CT}effective_levels 0\n"));
    expect(&d, "level-count-not-positive", Severity::Error, Some((10, 18)), &["effective_levels"]);
    let d = ct_err(&format!("{NO_IC_CT}allocated_levels -1\n"));
    expect(&d, "level-count-not-positive", Severity::Error, Some((10, 18)), &["allocated_levels"]);
    let d = ct_err(&NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 8589934592 8589934592 1"));
    expect(&d, "size-too-large", Severity::Error, Some((5, 11)), &["4294967296"]);
    let d = ct_err(&NO_IC_CT.replace("clip_size 512", "clip_size 8589934592"));
    expect(&d, "clip-size-too-large", Severity::Error, Some((6, 11)), &["limit"]);
}

#[test]
fn huge_pyramid_level_overflowed_its_byte_length() {
    // A 2^31-square pyramid level of 16-byte texels is 2^66 bytes: the length multiplication
    // overflowed (a panic) instead of being reported.
    let d = ct_err(
        "ct_version2.0\next_format PFTEX_FLOAT\nint_format PFTEX_RGBA_8\nimg_format PFTEX_RGBA\n\
         virt_size 4294967296 4294967296 1\nclip_size 2147483648\n\
         smallest_icache 4294967296 4294967296 1\ntile_size 65536 65536 1\n",
    );
    expect(&d, "level-too-large", Severity::Error, Some((5, 1)), &["pyramid level 1", "2147483648x2147483648"]);
}
