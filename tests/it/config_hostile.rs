//! Hostile and broken input: truncated files, non-UTF-8 bytes, overflowing and absurd numbers,
//! huge lines and words, many tokens, and special files named as configuration.

use crate::common;
use crate::common::exercise;

use clipmap::config::{FileKind, Limits, Severity};
use clipmap::plan::{self, Options};
use common::*;
use std::time::{Duration, Instant};

#[test]
#[cfg(unix)]
fn level_ic_named_dev_zero_was_read_without_a_size_limit() {
    // A level .ic was read whole, with no bound: naming /dev/zero (or any huge file) made the
    // reader loop until memory ran out. It is now read up to the file-size limit, like the .ct.
    if !std::path::Path::new("/dev/zero").exists() {
        return;
    }
    let fx = Fixture::new();
    fx.write("z.ct", format!("ct_version2.0\n{RGB8}virt_size 1024 1024 1\nclip_size 512\nicache_files /dev/zero\n"));
    let o = Options { limits: Limits { max_file_bytes: 1 << 16, ..Limits::default() }, ..opts() };
    let t = Instant::now();
    let l = plan::load_clip_texture(&fx.path("z.ct"), &o).unwrap();
    assert!(t.elapsed() < Duration::from_secs(10));
    // A device is refused before anything is read (crates/clipmap-base/src/open.rs: regular files only).
    let x = find(&l.diagnostics, "icache-file-unreadable");
    assert_eq!(x.severity, Severity::Error);
    assert!(x.message.contains("a character device, not a regular file"), "{}", x.message);
    // A regular file far over the limit is read up to the limit only.
    let big = fx.path("big.ic");
    std::fs::File::create(&big).unwrap().set_len(1 << 30).unwrap();
    fx.write("b.ct", format!("ct_version2.0\n{RGB8}virt_size 1024 1024 1\nclip_size 512\nicache_files big.ic\n"));
    let t = Instant::now();
    let l = plan::load_clip_texture(&fx.path("b.ct"), &o).unwrap();
    assert!(t.elapsed() < Duration::from_secs(10));
    let x = find(&l.diagnostics, "file-too-large");
    assert_eq!(x.severity, Severity::Error);
    assert!(x.path.ends_with("big.ic"));
    assert!(x.message.contains("65537 bytes"), "{}", x.message);
}

#[test]
fn every_truncation_of_valid_files_is_handled() {
    let fx = Fixture::new();
    fx.write_level_ics("l", 2048, 1024, 256);
    let ct_lists = format!(
        "ct_version2.0\n{RGB8}virt_size 2048 2048 1\nclip_size 512\nicache_files l.2048.ic l.1024.ic\n\
         tile_format p.%d\ntile_params PFCLIPTEX_FNAMEARG_LEVEL\n"
    );
    for text in [NO_IC_CT, SMALL_IC, ct_lists.as_str()] {
        for n in 0..=text.len() {
            exercise::exercise(&text.as_bytes()[..n], fx.dir.path());
        }
    }
}

#[test]
fn a_comment_at_the_end_of_the_file_without_a_newline_loads() {
    for tail in ["# end", "rem", "//", "comment x"] {
        let (p, d) = ct_ok(&format!("{NO_IC_CT}{tail}"));
        clean(&d);
        assert_eq!(p.levels.len(), 13);
    }
}

#[test]
fn non_utf8_bytes_are_reported_where_they_are() {
    let mut bytes = b"ct_version2.0\n\xff\xfe clip_size 512\n".to_vec();
    let (_, d) = parse(&bytes, FileKind::ClipTexture);
    expect(&d, "not-utf8", Severity::Error, Some((2, 1)), &["UTF-8"]);
    bytes.extend_from_slice(b"tile_files a\x80b c\n");
    let (f, d) = parse(&bytes, FileKind::ClipTexture);
    assert_eq!(d.items.iter().filter(|x| x.code == "not-utf8").count(), 2);
    assert_eq!(f.entries.len(), 3, "the readable entries are kept");
    // Through the whole loader and renderer.
    let fx = Fixture::new();
    exercise::exercise(&bytes, fx.dir.path());
}

#[test]
fn integer_overflow_is_an_error_not_a_wrap() {
    for n in ["9223372036854775808", "-9223372036854775809", "99999999999999999999999999"] {
        let d = ct_err(&NO_IC_CT.replace("clip_size 512", &format!("clip_size {n}")));
        expect(&d, "number-out-of-range", Severity::Error, Some((6, 11)), &["out of range"]);
    }
    // The largest i64 parses, and is refused by the size check.
    let d = ct_err(&NO_IC_CT.replace("clip_size 512", "clip_size 9223372036854775807"));
    absent(&d, "number-out-of-range");
    find(&d, "clip-size-not-power-of-two");
    // Huge offsets are valid, and a tile whose byte offset would overflow says so.
    let (p, _) = ic_ok(&format!(
        "ic_version2.0\n{RGB8}icache_size 67108864 67108864 1\ntile_size 65536 65536 1\n\
         tex_region_size 65536 65536 1\nheader_offset 9223372036854775807\n\
         tiles_in_file 1048576 1048576 1\n"
    ));
    assert_eq!(p.locate(0, 0, 0).unwrap().offset, 9223372036854775807);
    assert_eq!(p.locate(0, 1000, 0), Err(plan::TileError::Overflow { s: 0, t: 1000 }));
}

#[test]
fn absurd_sizes_are_refused() {
    let d = ct_err(&NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 1099511627776 1099511627776 1"));
    expect(&d, "size-too-large", Severity::Error, Some((5, 11)), &["limit of 4294967296"]);
    let d = ic_err(&SMALL_IC.replace("tile_size 256 256 1", "tile_size 1099511627776 256 1"));
    expect(&d, "size-too-large", Severity::Error, Some((6, 11)), &["tile_size"]);
    // The largest accepted texture, with the smallest clip size: 33 levels, nothing overflows.
    let text = format!("ct_version2.0\n{RGB8}virt_size 4294967296 4294967296 1\nclip_size 1\ninvalid_border 0\n");
    let d = ct_err(&text);
    find(&d, "border-too-wide");
    let fx = Fixture::new();
    exercise::exercise(text.as_bytes(), fx.dir.path());
    // A big, valid one: 2^32 square, clip 2^16, 65536-texel tiles at the far corner.
    let (p, _) = ct_ok(
        &NO_IC_CT
            .replace("virt_size 4096 4096 1", "virt_size 4294967296 4294967296 1")
            .replace("clip_size 512", "clip_size 65536")
            .replace("tile_size 256 256 1", "tile_size 65536 65536 1"),
    );
    assert_eq!(p.levels.len(), 33);
    let loc = p.locate(0, 65535, 65535).unwrap();
    assert_eq!(loc.length, 65536 * 65536 * 3);
}

#[test]
fn a_10_mb_line_is_a_file_too_large_error_and_is_fast() {
    let fx = Fixture::new();
    let mut text = NO_IC_CT.as_bytes().to_vec();
    text.resize(text.len() + (10 << 20), b'x');
    let p = fx.write("big.ct", &text);
    let t = Instant::now();
    let l = plan::load_clip_texture(&p, &opts()).unwrap();
    assert!(t.elapsed() < Duration::from_secs(5));
    assert!(l.plan.is_none());
    let x = expect(&l.diagnostics, "file-too-large", Severity::Error, Some((1, 1)), &["4194304 bytes"]);
    assert!(x.message.contains("4194305 bytes"), "only one byte past the limit is read: {}", x.message);
    assert_eq!(l.diagnostics.items.len(), 1);
}

#[test]
fn a_1_mb_word_is_one_error() {
    let word = "w".repeat(1 << 20);
    let (f, d) = parse_ct(&format!("tile_base {word}\nclip_size 512\n"));
    let x = expect(&d, "word-too-long", Severity::Error, Some((1, 11)), &["1048576 bytes", "4096 bytes"]);
    assert!(x.found.unwrap().len() < 100, "the word is shortened in messages");
    assert_eq!(d.items.len(), 1);
    assert_eq!(f.entries.len(), 2);
    // As a token too.
    let (_, d) = parse_ct(&format!("{word} clip_size 512\n"));
    assert_eq!(codes(&d), ["word-too-long"]);
    let (_, _l) = load_ct(&format!("{NO_IC_CT}{word}\n"));
}

#[test]
fn a_hundred_thousand_repeated_tokens_stop_at_the_limit_quickly() {
    let text = "lookahead 1\n".repeat(100_000);
    let t = Instant::now();
    let (f, d) = parse_ct(&text);
    assert!(t.elapsed() < Duration::from_secs(5));
    expect(&d, "too-many-entries", Severity::Error, Some((10_001, 1)), &["more than 10000 tokens"]);
    assert_eq!(f.entries.len(), 10_001);
    // A hundred thousand unknown words: the findings stop at the limit.
    let (_, d) = parse_ct(&"bogus ".repeat(100_000));
    assert_eq!(d.items.len(), Limits::default().max_diagnostics);
    assert_eq!(d.items.last().unwrap().code, "too-many-diagnostics");
    // And through the plan stage (1.2 MB, under the file-size limit).
    let t = Instant::now();
    let (_fx, l) = load_ct(&format!("{NO_IC_CT}{text}"));
    assert!(l.plan.is_none());
    assert!(t.elapsed() < Duration::from_secs(10));
    // A long list: items past the limit are counted once.
    let list = format!("tile_files {}\n", "f ".repeat(100_000));
    let (_, d) = parse_ct(&list);
    assert_eq!(codes(&d), ["list-too-long"]);
}
