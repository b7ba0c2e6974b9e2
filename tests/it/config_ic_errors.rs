//! Image cache build-stage errors of docs/PERFORMER-REFERENCE.md §1.15 (checks 1-6), plus the checks this reader
//! adds (tile size dividing the cache, tiles per file, header offset).

use crate::common;

use clipmap::config::Severity;
use common::*;

fn ic(body: &str) -> String {
    format!("ic_version2.0\n{RGB8}{body}")
}

#[test]
fn ic1_formats_are_mandatory() {
    let d = ic_err(&SMALL_IC.replace("int_format PFTEX_RGB_8\n", ""));
    expect(&d, "missing-mandatory", Severity::Error, Some((1, 1)), &["int_format"]);
}

#[test]
fn ic2_icache_size_unset_zero_or_not_a_power_of_two() {
    let d = ic_err(&SMALL_IC.replace("icache_size 1024 1024 1\n", ""));
    expect(&d, "missing-mandatory", Severity::Error, Some((1, 1)), &["`icache_size` is missing"]);
    let d = ic_err(&SMALL_IC.replace("icache_size 1024 1024 1", "icache_size 1024 0 1"));
    expect(&d, "size-not-positive", Severity::Error, Some((5, 18)), &["T of `icache_size`"]);
    let d = ic_err(&SMALL_IC.replace("icache_size 1024 1024 1", "icache_size 1000 1024 1"));
    expect(&d, "size-not-power-of-two", Severity::Error, Some((5, 13)), &["S of `icache_size`"]);
    // The v1.0 spelling reports under its own name.
    let (_, d) = ic_ok(&SMALL_IC.replace("icache_size 1024 1024 1", "virt_size 1024 1024"));
    expect(&d, "size-missing-r", Severity::Warning, Some((5, 1)), &["icache_size"]);
}

#[test]
fn ic3_mem_region_checks() {
    let d = ic_err(&format!("{SMALL_IC}mem_region_size 0 4 1\n"));
    expect(&d, "mem-region-zero", Severity::Error, Some((8, 1)), &["cannot be 0"]);
    let d = ic_err(&format!("{SMALL_IC}mem_region_size 1 4 1\n"));
    expect(&d, "mem-region-too-small", Severity::Error, Some((8, 1)), &["S:", "smaller than the tex region (512)"]);
    let d =
        ic_err(&ic("icache_size 1024 1024 1\ntile_size 512 512 1\ntex_region_size 512 512 1\nmem_region_size 1 1 1\n"));
    expect(&d, "mem-region-one-tile", Severity::Error, Some((8, 1)), &["one tile must cover the whole cache"]);
    let (_, d) = ic_ok(&format!("{SMALL_IC}mem_region_size 8 4 1\n"));
    expect(&d, "mem-region-larger-than-cache", Severity::Warning, Some((8, 1)), &["8 tiles", "4 tiles"]);
    let d = ic_err(&ic("icache_size 65536 65536 1\ntile_size 16 16 1\ntex_region_size 4096 4096 1\n"));
    expect(&d, "mem-region-too-many-tiles", Severity::Error, Some((6, 1)), &["258x258x1", "at most 128"]);
}

#[test]
fn ic4_a_standalone_cache_needs_a_tex_region() {
    let d = ic_err(&SMALL_IC.replace("tex_region_size 512 512 1\n", ""));
    expect(&d, "missing-mandatory", Severity::Error, Some((1, 1)), &["`tex_region_size`", "standalone"]);
    let d = ic_err(&SMALL_IC.replace("tex_region_size 512 512 1", "tex_region_size 2048 512 1"));
    expect(&d, "tex-region-too-large", Severity::Error, Some((7, 1)), &["2048x512", "1024x1024"]);
}

#[test]
fn ic5_destination_tex_size() {
    let d = ic_err(&format!("{SMALL_IC}tex_size 256 512 1\n"));
    expect(&d, "tex-size-too-small", Severity::Error, Some((8, 1)), &["256x512", "512x512"]);
    let d = ic_err(&format!("{SMALL_IC}tex_size 768 768 1\n"));
    expect(&d, "size-not-power-of-two", Severity::Error, Some((8, 10)), &["tex_size"]);
    let d = ic_err(&SMALL_IC.replace("tex_region_size 512 512 1", "tex_region_size 384 384 1"));
    expect(&d, "tex-size-not-power-of-two", Severity::Error, Some((7, 1)), &["384x384", "`tex_size 512 512 1`"]);
    ic_ok(&format!(
        "{}tex_size 512 512 1\n",
        SMALL_IC.replace("tex_region_size 512 512 1", "tex_region_size 384 384 1")
    ));
}

#[test]
fn ic6_tile_size_present_and_dividing_the_cache() {
    // Performer checks neither; a missing tile_size showed up as a mem region error.
    let d = ic_err(&SMALL_IC.replace("tile_size 256 256 1\n", ""));
    expect(&d, "missing-mandatory", Severity::Error, Some((1, 1)), &["`tile_size` is missing", "memregion"]);
    let d = ic_err(&SMALL_IC.replace("tile_size 256 256 1", "tile_size 384 256 1"));
    expect(&d, "tile-does-not-divide", Severity::Error, Some((6, 1)), &["S of `tile_size` (384)", "(1024)"]);
    let d = ic_err(&SMALL_IC.replace("tile_size 256 256 1", "tile_size 2048 256 1"));
    expect(&d, "tile-does-not-divide", Severity::Error, Some((6, 1)), &["2048"]);
    let d = ic_err(&SMALL_IC.replace("tile_size 256 256 1", "tile_size 0 256 1"));
    expect(&d, "size-not-positive", Severity::Error, Some((6, 11)), &["S of `tile_size`"]);
}

#[test]
fn ic_tiles_in_file_and_header_offset_checks() {
    let d = ic_err(&format!("{SMALL_IC}tiles_in_file 0 1 1\n"));
    expect(&d, "size-not-positive", Severity::Error, Some((8, 15)), &["tiles_in_file"]);
    let d = ic_err(&format!("{SMALL_IC}header_offset -1\n"));
    expect(&d, "negative-value", Severity::Error, Some((8, 15)), &["header_offset"]);
    // R may be more than 1 in tiles_in_file.
    let (p, _) = ic_ok(&format!("{SMALL_IC}tiles_in_file 2 2 4\n"));
    assert_eq!(p.tiles_in_file, [2, 2, 4]);
}

#[test]
fn every_error_is_reported_not_only_the_first() {
    let d = ic_err(&ic("icache_size 1000 1024 1\ntile_size 0 256 1\nlookahead -1\n"));
    for code in ["size-not-power-of-two", "size-not-positive", "negative-value", "missing-mandatory"] {
        find(&d, code);
    }
}

#[test]
fn huge_mem_region_size_overflowed_the_tight_region_check() {
    // mem_region x tile overflowed 64 bits (a panic) before the "too many tiles" check.
    let d = ic_err(&format!("{SMALL_IC}mem_region_size 4611686018427387904 4 1\n"));
    expect(&d, "mem-region-too-many-tiles", Severity::Error, Some((8, 1)), &["at most 128"]);
}

#[test]
fn huge_mem_region_r_overflowed_the_tile_count_in_icache_info() {
    // R of mem_region_size was never bounded; `icache info` multiplied the three axes and
    // overflowed (a panic). It is now held to the same per-axis limit as S and T.
    let d = ic_err(&format!("{SMALL_IC}mem_region_size 4 4 4611686018427387904\n"));
    expect(&d, "mem-region-too-many-tiles", Severity::Error, Some((8, 1)), &["4x4x4611686018427387904", "at most 128"]);
}
