//! Lexical rules: whole words, the five comment markers in token and value position, comments
//! inside lists and between numbers, a comment at the end of the file, and `num_streams`.

use crate::common;

use clipmap::config::{Severity, Value};
use common::*;

#[test]
fn word_tokens_are_not_comments_inside_file_names() {
    // `remote.raw` starts with `rem`; `commentary.raw` with `comment`: both are file names.
    let (f, d) = parse_ct("tile_files remote.raw commentary.raw\nclip_size 8\n");
    assert!(!d.has_errors(), "{}", listing(&d));
    let Value::List(items) = &f.entries[0].value else { panic!("a list") };
    let names: Vec<_> = items.iter().map(|i| i.value.as_str()).collect();
    assert_eq!(names, ["remote.raw", "commentary.raw"]);
    assert_eq!(f.entries[1].def.name, "clip_size");
}

#[test]
fn the_five_comment_markers_skip_to_the_end_of_the_line() {
    for c in ["#", "//", ";", "comment", "rem"] {
        let text = format!("{c} clip_size 1\nclip_size 512 {c} lookahead 3\nlookahead 2\n");
        let (f, d) = parse_ct(&text);
        assert!(d.items.is_empty(), "{c}: {}", listing(&d));
        let names: Vec<_> = f.entries.iter().map(|e| e.def.name).collect();
        assert_eq!(names, ["clip_size", "lookahead"], "{c}");
    }
}

#[test]
fn symbolic_comment_markers_work_glued_in_token_position() {
    let (f, d) = parse_ct("#note clip_size 1\n//note\n;note\nclip_size 512 #tail 3\n");
    assert!(d.items.is_empty(), "{}", listing(&d));
    assert_eq!(f.entries.len(), 1);
    let Value::Int(v) = &f.entries[0].value else { panic!() };
    assert_eq!(v.value, 512);
    // A word comment marker glued to text is no comment.
    let (_, d) = parse_ct("remark clip_size 1\n");
    expect(&d, "unknown-token", Severity::Error, Some((1, 1)), &["remark"]);
}

#[test]
fn a_comment_at_the_end_of_the_file_without_a_newline_is_fine() {
    for tail in ["# end", "#", "//", "rem", "comment", "; x"] {
        let (f, d) = parse_ct(&format!("clip_size 512 {tail}"));
        assert!(d.items.is_empty(), "{tail}: {}", listing(&d));
        assert_eq!(f.entries.len(), 1);
        let (f, d) = parse_ct(&format!("clip_size 512\n{tail}"));
        assert!(d.items.is_empty(), "{tail}: {}", listing(&d));
        assert_eq!(f.entries.len(), 1);
    }
}

#[test]
fn in_a_list_a_long_double_slash_word_is_a_value_with_a_portability_warning() {
    let (f, d) = parse_ic("s_stream //server/share /disk2/ // lone comment\ntile_size 1 1 1\n");
    let x = expect(
        &d,
        "value-starts-with-comment-marker",
        Severity::Warning,
        Some((1, 10)),
        &["//server/share", "comment"],
    );
    assert!(x.portability);
    let Value::List(items) = &f.entries[0].value else { panic!() };
    let v: Vec<_> = items.iter().map(|i| i.value.as_str()).collect();
    assert_eq!(v, ["//server/share", "/disk2/"]);
    assert_eq!(f.entries[1].def.name, "tile_size");
}

#[test]
fn in_value_position_hash_semicolon_and_the_word_markers_start_comments() {
    for c in ["#x", ";x", "//", "comment", "rem"] {
        let (f, d) = parse_ct(&format!("tile_files a.raw b.raw {c} c.raw\nclip_size 8\n"));
        assert!(d.items.is_empty(), "{c}: {}", listing(&d));
        let Value::List(items) = &f.entries[0].value else { panic!() };
        assert_eq!(items.len(), 2, "{c}");
    }
}

#[test]
fn a_comment_line_inside_a_list_is_accepted_with_a_portability_warning() {
    let (f, d) = parse_ct("tile_files a.raw\n# the small ones\n  b.raw\nclip_size 8\n");
    let x = expect(&d, "comment-inside-list", Severity::Warning, Some((2, 1)), &["tile_files", "ends the list"]);
    assert!(x.portability);
    let Value::List(items) = &f.entries[0].value else { panic!() };
    assert_eq!(items.len(), 2);
    // A comment line after the last item is not inside the list.
    let (_, d) = parse_ct("tile_files a.raw\n# done\nclip_size 8\n");
    assert!(d.items.is_empty(), "{}", listing(&d));
}

#[test]
fn a_comment_between_numbers_is_accepted_with_a_portability_warning() {
    let (f, d) = parse_ct("virt_size 4096 # width\n 4096 1\nclip_size 512\n");
    let x = expect(&d, "comment-inside-arguments", Severity::Warning, Some((1, 16)), &["virt_size", "stops reading"]);
    assert!(x.portability);
    let Value::Int3(v) = &f.entries[0].value else { panic!() };
    assert_eq!(v.iter().map(|x| x.value).collect::<Vec<_>>(), [4096, 4096, 1]);
    let (f, d) = parse_ct("clip_size # the window\n 512\n");
    expect(&d, "comment-inside-arguments", Severity::Warning, Some((1, 11)), &["clip_size"]);
    let Value::Int(v) = &f.entries[0].value else { panic!() };
    assert_eq!((v.value, v.span.line, v.span.col), (512, 2, 2));
}

#[test]
fn num_streams_takes_an_optional_integer_and_does_not_swallow_its_line() {
    let (f, d) = parse_ic("num_streams 2\ns_stream /a/ /b/\nnum_streams\ntile_size 1 1 1\n");
    assert!(!d.has_errors(), "{}", listing(&d));
    absent(&d, "num-streams-swallows-line");
    let names: Vec<_> = f.entries.iter().map(|e| e.def.name).collect();
    assert_eq!(names, ["num_streams", "s_stream", "num_streams", "tile_size"]);
    // Something after it on the same line: kept, with a portability warning.
    let (f, d) = parse_ic("num_streams 2 tile_size 1 1 1\n");
    let x = expect(&d, "num-streams-swallows-line", Severity::Warning, Some((1, 15)), &["tile_size", "comment"]);
    assert!(x.portability);
    assert_eq!(f.entries[1].def.name, "tile_size");
    // A comment after it is fine.
    let (_, d) = parse_ic("num_streams 2 # two disks\n");
    absent(&d, "num-streams-swallows-line");
}

#[test]
fn num_streams_takes_the_manuals_three_integers() {
    // The manual: "the modulo number for the s, t and r directions".
    let (f, d) = parse_ic("num_streams 3 2 1\ntile_size 1 1 1\n");
    assert!(!d.has_errors(), "{}", listing(&d));
    absent(&d, "num-streams-swallows-line");
    let names: Vec<_> = f.entries.iter().map(|e| e.def.name).collect();
    assert_eq!(names, ["num_streams", "tile_size"]);
    // Two numbers, then a token on the same line: the token is kept, with the warning.
    let (f, d) = parse_ic("num_streams 3 2 tile_size 1 1 1\n");
    expect(&d, "num-streams-swallows-line", Severity::Warning, Some((1, 17)), &["tile_size"]);
    assert_eq!(f.entries[1].def.name, "tile_size");
    // A fourth number is not num_streams' any more.
    let (_, d) = parse_ic("num_streams 3 2 1 4\n");
    expect(&d, "num-streams-swallows-line", Severity::Warning, Some((1, 19)), &["4"]);
}
