//! The token table and the lexical rules: every token and alias of both file kinds, whole-word
//! matching, comments in every position, and the argument shapes.

use crate::common;

use clipmap::config::tokens::{self, ArgShape, TOKENS};
use clipmap::config::{FileKind, Severity, TokenId, Value};
use common::*;

/// Every spelling the reader knows, in table order (docs/PERFORMER-REFERENCE.md §1.4, §1.5).
const ALL_NAMES: &[&str] = &[
    "ct_version1.0",
    "ct_version2.0",
    "ic_version1.0",
    "ic_version2.0",
    "ext_format",
    "int_format",
    "img_format",
    "virt_size",
    "icache_size",
    "clip_size",
    "effective_levels",
    "allocated_levels",
    "invalid_border",
    "smallest_icache",
    "phase_shift",
    "phase_margin",
    "icache_base",
    "icache_format",
    "num_icache_params",
    "icache_params",
    "header_offset",
    "tile_base",
    "tile_format",
    "num_tile_params",
    "tile_params",
    "icache_files",
    "tile_files",
    "tile_size",
    "page_size",
    "read_func",
    "lookahead",
    "mem_region_size",
    "cache_size",
    "tex_region_size",
    "valid_region",
    "tex_size",
    "valid_region_dst",
    "tiles_in_file",
    "s_streams",
    "s_stream",
    "t_streams",
    "t_stream",
    "r_streams",
    "r_stream",
    "num_streams",
    "default_tile",
];

/// Tokens that are legal in the table but fatal in a `.ct` (docs/PERFORMER-REFERENCE.md §1.4).
const FATAL_IN_CT: &[&str] = &[
    "ic_version1.0",
    "ic_version2.0",
    "cache_size",
    "mem_region_size",
    "valid_region",
    "valid_region_dst",
    "tex_size",
    "tex_region_size",
    "tiles_in_file",
    "s_stream",
    "s_streams",
    "t_stream",
    "t_streams",
    "r_stream",
    "r_streams",
    "default_tile",
    "num_streams",
];

/// Tokens fatal in an `.ic` (docs/PERFORMER-REFERENCE.md §1.5).
const FATAL_IN_IC: &[&str] = &[
    "ct_version1.0",
    "ct_version2.0",
    "clip_size",
    "invalid_border",
    "effective_levels",
    "allocated_levels",
    "smallest_icache",
    "icache_base",
    "icache_format",
    "num_icache_params",
    "icache_params",
    "icache_files",
    "tile_files",
    "phase_shift",
    "phase_margin",
];

/// A valid argument text for a token.
fn sample_args(name: &str, shape: ArgShape) -> &'static str {
    match (name, shape) {
        ("ext_format", _) => "PFTEX_PACK_8",
        ("int_format", _) => "PFTEX_RGB_8",
        ("img_format", _) => "PFTEX_RGB",
        (_, ArgShape::None) => "",
        (_, ArgShape::Int) => "4",
        (_, ArgShape::Int3) => "4 4 1",
        (_, ArgShape::Format) => "5121",
        (_, ArgShape::Word) => "name.%d",
        (_, ArgShape::Base) => "base/",
        (_, ArgShape::List) => "a b",
        (_, ArgShape::ReadFunc) => "lib.so sym",
        (_, ArgShape::SkipWords) => "1 2",
        (_, ArgShape::NumStreams) => "2",
    }
}

#[test]
fn the_table_holds_exactly_the_documented_spellings() {
    let names: Vec<&str> = TOKENS.iter().map(|d| d.name).collect();
    assert_eq!(names, ALL_NAMES);
    for name in ALL_NAMES {
        assert_eq!(tokens::lookup(name).map(|d| d.name), Some(*name));
    }
}

#[test]
fn fatal_tokens_match_performer_per_file_kind() {
    for d in TOKENS {
        assert_eq!(!d.in_ct, FATAL_IN_CT.contains(&d.name), "{} in a .ct", d.name);
        assert_eq!(!d.in_ic, FATAL_IN_IC.contains(&d.name), "{} in an .ic", d.name);
    }
}

#[test]
fn every_token_parses_with_its_arguments_where_it_is_allowed() {
    for d in TOKENS {
        let text = format!("{} {}\n", d.name, sample_args(d.name, d.args));
        for kind in [FileKind::ClipTexture, FileKind::ImageCache] {
            let allowed = match kind {
                FileKind::ClipTexture => d.in_ct,
                FileKind::ImageCache => d.in_ic,
            };
            let (file, diags) = parse(text.as_bytes(), kind);
            if allowed {
                assert!(!diags.has_errors(), "{text} in {kind:?}:\n{}", listing(&diags));
                assert_eq!(file.entries.len(), 1, "{text}");
                let e = &file.entries[0];
                assert_eq!((e.def.name, e.span.line, e.span.col), (d.name, 1, 1));
                match (d.args, &e.value) {
                    (ArgShape::None, Value::None) => {}
                    (ArgShape::Int, Value::Int(v)) => assert_eq!(v.value, 4),
                    (ArgShape::Int3, Value::Int3(v)) => assert_eq!(v.len(), 3),
                    (ArgShape::Format | ArgShape::Word, Value::Word(w)) => {
                        assert_eq!(w.value, sample_args(d.name, d.args))
                    }
                    (ArgShape::Base, Value::Base(Some(b))) => assert_eq!(b.value, "base/"),
                    (ArgShape::List | ArgShape::ReadFunc, Value::List(v)) => {
                        assert_eq!(v.len(), 2)
                    }
                    (ArgShape::SkipWords | ArgShape::NumStreams, Value::Ignored) => {}
                    (shape, v) => panic!("{}: shape {shape:?} gave {v:?}", d.name),
                }
                if d.obsolete {
                    expect(&diags, "obsolete-token", Severity::Note, Some((1, 1)), &[d.name]);
                }
            } else {
                let code = if matches!(d.id, TokenId::CtVersion | TokenId::IcVersion) {
                    "wrong-file-kind"
                } else {
                    "token-not-allowed"
                };
                expect(&diags, code, Severity::Error, Some((1, 1)), &[d.name, "belongs in"]);
                assert!(file.entries.is_empty(), "{text}: a refused token makes no entry");
            }
        }
    }
}

#[test]
fn aliases_share_the_identity_of_their_preferred_spelling() {
    let pairs = [
        ("cache_size", "mem_region_size", TokenId::MemRegionSize),
        ("valid_region", "tex_region_size", TokenId::TexRegionSize),
        ("valid_region_dst", "tex_size", TokenId::TexSize),
        ("s_stream", "s_streams", TokenId::SStreams),
        ("t_stream", "t_streams", TokenId::TStreams),
        ("r_stream", "r_streams", TokenId::RStreams),
    ];
    for (alias, preferred, id) in pairs {
        let a = tokens::lookup(alias).unwrap();
        assert_eq!((a.id, a.alias_of), (id, Some(preferred)));
        assert_eq!(tokens::lookup(preferred).unwrap().id, id);
        assert_eq!(tokens::preferred_name(id, FileKind::ImageCache), preferred);
    }
    // virt_size and icache_size are each other's alias: the preferred name depends on the kind.
    assert_eq!(tokens::lookup("virt_size").unwrap().id, TokenId::Size);
    assert_eq!(tokens::lookup("icache_size").unwrap().id, TokenId::Size);
    assert_eq!(tokens::preferred_name(TokenId::Size, FileKind::ClipTexture), "virt_size");
    assert_eq!(tokens::preferred_name(TokenId::Size, FileKind::ImageCache), "icache_size");
    for v in ["ct_version1.0", "ct_version2.0"] {
        assert_eq!(tokens::lookup(v).unwrap().id, TokenId::CtVersion);
    }
    for v in ["ic_version1.0", "ic_version2.0"] {
        assert_eq!(tokens::lookup(v).unwrap().id, TokenId::IcVersion);
    }
}

#[test]
fn token_names_are_case_sensitive() {
    let (_, d) = parse_ct("CLIP_SIZE 512\n");
    expect(&d, "unknown-token", Severity::Error, Some((1, 1)), &["CLIP_SIZE"]);
}

#[test]
fn tokens_match_whole_words_and_a_glued_value_gets_a_hint() {
    let (f, d) = parse_ct("ct_version2.0\nclip_size512\n");
    let x = expect(&d, "unknown-token", Severity::Error, Some((2, 1)), &["clip_size512"]);
    assert!(x.hint.unwrap().contains("`clip_size 512`"));
    assert_eq!(f.entries.len(), 1);
    // Performer would read `invalid_borderline` as invalid_border + "line"; we do not.
    let (_, d) = parse_ct("invalid_borderline 8\n");
    expect(&d, "unknown-token", Severity::Error, Some((1, 1)), &["put a space"]);
}

#[test]
fn a_misspelled_token_gets_a_did_you_mean() {
    let (_, d) = parse_ct("ct_version2.0\n  clip_sise 512\n");
    expect(&d, "unknown-token", Severity::Error, Some((2, 3)), &["did you mean `clip_size`?"]);
    let (_, d) = parse_ic("ic_version2.0\ntile_sze 1 1 1\n");
    expect(&d, "unknown-token", Severity::Error, Some((2, 1)), &["did you mean `tile_size`?"]);
    // A stray number: the previous token took fewer values than written.
    let (_, d) = parse_ct("clip_size 512 1024\n");
    expect(&d, "unknown-token", Severity::Error, Some((1, 15)), &["more values"]);
}

#[test]
fn obsolete_phase_tokens_skip_their_words() {
    let (f, d) = parse_ct("phase_shift 1 2 3\nphase_margin 4\nclip_size 512\n");
    assert!(!d.has_errors(), "{}", listing(&d));
    expect(&d, "obsolete-token", Severity::Note, Some((1, 1)), &["phase_shift", "obsolete"]);
    assert_eq!(f.last(TokenId::ClipSize).map(|e| e.span.line), Some(3));
}

#[test]
fn a_base_without_a_word_is_the_empty_base() {
    let (f, d) = parse_ct("tile_base\nicache_base\nclip_size 8\n");
    assert!(!d.has_errors(), "{}", listing(&d));
    assert!(matches!(f.entries[0].value, Value::Base(None)));
    assert!(matches!(f.entries[1].value, Value::Base(None)));
    let (f, _) = parse_ct("tile_base");
    assert!(matches!(f.entries[0].value, Value::Base(None)));
}

#[test]
fn a_format_token_does_not_swallow_the_next_token() {
    // Performer takes the next word even if it is a token; we report the missing value.
    let (f, d) = parse_ct("ext_format\nclip_size 512\n");
    expect(&d, "missing-value", Severity::Error, Some((1, 1)), &["ext_format", "clip_size"]);
    assert_eq!(f.last(TokenId::ClipSize).map(|e| e.span.line), Some(2));
    let (_, d) = parse_ic("tile_format");
    expect(&d, "missing-value", Severity::Error, Some((1, 1)), &["end of file"]);
}

#[test]
fn integer_arguments_are_c_decimal_integers() {
    let (f, d) = parse_ct("clip_size +512\ninvalid_border -3\n");
    assert!(!d.has_errors(), "{}", listing(&d));
    let vals: Vec<i64> = f
        .entries
        .iter()
        .map(|e| match &e.value {
            Value::Int(v) => v.value,
            _ => panic!(),
        })
        .collect();
    assert_eq!(vals, [512, -3]);
    let (_, d) = parse_ct("clip_size 512abc\n");
    let x = expect(&d, "expected-integer", Severity::Error, Some((1, 11)), &["clip_size", "512abc"]);
    assert!(x.hint.unwrap().contains("`512`"));
    let (_, d) = parse_ct("clip_size 0x200\n");
    expect(&d, "expected-integer", Severity::Error, Some((1, 11)), &["integer"]);
    let (_, d) = parse_ct("clip_size\n");
    expect(&d, "missing-value", Severity::Error, Some((1, 1)), &["clip_size", "end of file"]);
    let (_, d) = parse_ct("lookahead clip_size 512\n");
    expect(&d, "missing-value", Severity::Error, Some((1, 1)), &["lookahead", "clip_size"]);
}

#[test]
fn three_number_tokens_take_up_to_three_numbers() {
    let (f, d) = parse_ct("virt_size 8 8\nclip_size 4\n");
    assert!(!d.has_errors(), "{}", listing(&d));
    let Value::Int3(v) = &f.entries[0].value else { panic!() };
    assert_eq!(v.len(), 2);
    let (_, d) = parse_ct("virt_size\nclip_size 4\n");
    expect(&d, "missing-value", Severity::Error, Some((1, 1)), &["three integers"]);
    let (_, d) = parse_ct("virt_size big 1 1\n");
    expect(&d, "expected-integer", Severity::Error, Some((1, 11)), &["virt_size"]);
    let (_, d) = parse_ct("virt_size 1 2 3 4\n");
    expect(&d, "unknown-token", Severity::Error, Some((1, 17)), &["4"]);
}

#[test]
fn read_func_takes_one_or_two_words_on_its_line() {
    let (f, d) = parse_ct("read_func mylib.so myread\nclip_size 8\n");
    assert!(!d.has_errors(), "{}", listing(&d));
    let Value::List(v) = &f.entries[0].value else { panic!() };
    assert_eq!(v.len(), 2);
    let (f, _) = parse_ct("read_func myread\n8\n");
    let Value::List(v) = &f.entries[0].value else { panic!() };
    assert_eq!(v.len(), 1);
    let (_, d) = parse_ct("read_func\nclip_size 8\n");
    expect(&d, "missing-value", Severity::Error, Some((1, 1)), &["read_func", "function name"]);
}

#[test]
fn a_list_item_that_looks_like_a_misspelled_token_is_flagged() {
    let (_, d) = parse_ct("tile_files a.raw b.raw\ncip_size 512\n");
    expect(&d, "list-item-looks-like-token", Severity::Warning, Some((2, 1)), &["cip_size", "clip_size"]);
    // File names with dots, slashes or variables are not suspected.
    let (_, d) = parse_ct("tile_files clip_size.raw $X/tile_size\n");
    absent(&d, "list-item-looks-like-token");
}

#[test]
fn lists_run_until_the_next_token_and_may_be_empty() {
    let (f, d) = parse_ct("tile_files\nicache_files a b\n  c\nclip_size 8\n");
    assert!(!d.has_errors(), "{}", listing(&d));
    let lens: Vec<usize> = f
        .entries
        .iter()
        .filter_map(|e| match &e.value {
            Value::List(v) => Some(v.len()),
            _ => None,
        })
        .collect();
    assert_eq!(lens, [0, 3]);
}

#[test]
fn positions_count_lines_from_one_and_columns_in_bytes() {
    let (f, _) = parse_ct("\n\n\t  clip_size   512\r\n");
    let e = &f.entries[0];
    assert_eq!((e.span.line, e.span.col), (3, 4));
    let Value::Int(v) = &e.value else { panic!() };
    assert_eq!((v.span.line, v.span.col), (3, 16));
}

#[test]
fn v1_vocabulary_reads_like_v2() {
    let v1 = "ic_version1.0\nvirt_size 1024 1024 1\ncache_size 4 4 1\nvalid_region 512 512 1\n\
              valid_region_dst 512 512 1\ns_stream /a/\nt_stream /b/\nr_stream /c/\n";
    let v2 = "ic_version2.0\nicache_size 1024 1024 1\nmem_region_size 4 4 1\n\
              tex_region_size 512 512 1\ntex_size 512 512 1\ns_streams /a/\nt_streams /b/\nr_streams /c/\n";
    let (a, da) = parse_ic(v1);
    let (b, db) = parse_ic(v2);
    assert!(!da.has_errors() && !db.has_errors());
    let ids = |f: &clipmap::config::SyntaxFile| f.entries.iter().map(|e| e.id()).collect::<Vec<_>>();
    assert_eq!(ids(&a), ids(&b));
    let vals = |f: &clipmap::config::SyntaxFile| {
        f.entries.iter().map(|e| format!("{:?}", strip(&e.value))).collect::<Vec<_>>()
    };
    assert_eq!(vals(&a), vals(&b));
}

fn strip(v: &Value) -> Vec<String> {
    match v {
        Value::Int3(x) => x.iter().map(|i| i.value.to_string()).collect(),
        Value::List(x) => x.iter().map(|i| i.value.clone()).collect(),
        _ => vec![],
    }
}
