//! The plan stage's numbers: every default (docs/PERFORMER-REFERENCE.md §1.4, §1.5, §1.10, §1.14, §2.10), the
//! level layout, tex and mem regions, no-`.ic` mode and virtual clip textures.

use crate::common;

use clipmap::config::Severity;
use clipmap::plan::{self, GroupMode, LevelKind};
use common::*;

fn ct(body: &str) -> String {
    format!("ct_version2.0\n{RGB8}{body}")
}

fn ic(body: &str) -> String {
    format!("ic_version2.0\n{RGB8}{body}")
}

fn sizes(p: &plan::ClipTexturePlan) -> Vec<[u64; 2]> {
    p.levels.iter().map(|l| l.size).collect()
}

fn kinds(p: &plan::ClipTexturePlan) -> (usize, usize) {
    let n = p.icache_levels();
    (n, p.levels.len() - n)
}

#[test]
fn clip_texture_defaults() {
    let (p, d) = ct_ok(NO_IC_CT);
    clean(&d);
    assert_eq!(p.invalid_border, 8);
    assert_eq!(p.clip_size - 2 * p.invalid_border, 496);
    assert_eq!(p.effective_levels, 16);
    assert_eq!(p.allocated_levels, 1000);
    assert_eq!(p.lookahead, 1);
    assert_eq!(p.header_offset, 0);
    assert_eq!(p.page_size, -1);
    assert_eq!(p.smallest_icache, [1024, 1024, 1]);
    assert_eq!(p.version.as_deref(), Some("ct_version2.0"));
    assert!(!p.is_virtual);
    for key in [
        "invalid_border",
        "effective_levels",
        "allocated_levels",
        "header_offset",
        "page_size",
        "lookahead",
        "smallest_icache",
    ] {
        assert!(p.defaulted.contains(&key), "{key} should be marked defaulted");
    }
}

#[test]
fn given_values_are_not_marked_defaulted() {
    let (p, _) = ct_ok(&format!(
        "{NO_IC_CT}invalid_border 16\neffective_levels 13\nallocated_levels 13\nheader_offset 64\n\
         page_size 0\nlookahead 2\nsmallest_icache 1024 1024 1\n"
    ));
    assert_eq!((p.invalid_border, p.effective_levels, p.allocated_levels), (16, 13, 13));
    assert_eq!((p.header_offset, p.page_size, p.lookahead), (64, 0, 2));
    assert!(p.defaulted.is_empty(), "{:?}", p.defaulted);
}

#[test]
fn invalid_border_below_8_is_raised_to_8_with_a_warning() {
    let (p, d) = ct_ok(&format!("{NO_IC_CT}invalid_border 4\n"));
    assert_eq!(p.invalid_border, 8);
    expect(&d, "border-raised", Severity::Warning, Some((10, 16)), &["raised to 8"]);
}

#[test]
fn image_cache_defaults() {
    let (p, d) = ic_ok(SMALL_IC);
    clean(&d);
    assert_eq!(p.tiles_in_file, [1, 1, 1]);
    assert_eq!(p.header_offset, 0);
    assert_eq!(p.lookahead, 1);
    assert_eq!(p.page_size, -1);
    assert_eq!(p.tex_region, [512, 512, 1]);
    assert_eq!(p.tex_size, [512, 512, 1]);
    // ceil(512 / 256) + 1 + lookahead 1 = 4, at most the 4 tiles of the cache.
    assert_eq!(p.mem_region, [4, 4, 1]);
    assert!(p.naming.default_format);
    assert_eq!(p.naming.format, "%s%s.%d.r%03d.c%03d.raw888");
    assert_eq!(p.streams, [vec![], vec![], vec![]] as [Vec<String>; 3]);
    assert_eq!(p.default_tile, None);
    for key in ["tiles_in_file", "header_offset", "lookahead", "page_size", "tex_size", "mem_region", "tile_format"] {
        assert!(p.defaulted.contains(&key), "{key} should be marked defaulted");
    }
}

#[test]
fn mem_region_formula_worked_examples() {
    // 8192, tile 256, tex 512, lookahead 2: min(2 + 1 + 2, 32) = 5.
    let (p, _) = ic_ok(&ic("icache_size 8192 8192 1\ntile_size 256 256 1\ntex_region_size 512 512 1\nlookahead 2\n"));
    assert_eq!(p.mem_region, [5, 5, 1]);
    // 1024, tile 256, tex 512, lookahead 3: min(2 + 1 + 3, 4) = 4.
    let (p, _) = ic_ok(&ic("icache_size 1024 1024 1\ntile_size 256 256 1\ntex_region_size 512 512 1\nlookahead 3\n"));
    assert_eq!(p.mem_region, [4, 4, 1]);
    // A tile as large as the cache: one tile.
    let (p, _) = ic_ok(&ic("icache_size 512 512 1\ntile_size 512 512 1\ntex_region_size 512 512 1\n"));
    assert_eq!(p.mem_region, [1, 1, 1]);
    // Non-square tex region: per axis.
    let (p, _) = ic_ok(&ic(
        "icache_size 8192 8192 1\ntile_size 256 128 1\ntex_region_size 512 1024 1\ntex_size 1024 1024 1\nlookahead 0\n",
    ));
    assert_eq!(p.mem_region, [3, 9, 1]);
    assert_eq!(p.tex_size, [1024, 1024, 1]);
}

#[test]
fn a_given_mem_region_is_used_and_its_alias_too() {
    for tok in ["mem_region_size", "cache_size"] {
        let (p, d) = ic_ok(&format!("{SMALL_IC}{tok} 3 3 1\n"));
        assert_eq!(p.mem_region, [3, 3, 1], "{tok}");
        assert!(!p.defaulted.contains(&"mem_region"));
        // 3 tiles for a 2-tile tex region: fewer than ceil(tex/tile) + 2, a warning.
        expect(&d, "mem-region-tight", Severity::Warning, Some((8, 1)), &["move freely"]);
    }
}

#[test]
fn tex_region_and_tex_size_aliases() {
    let (p, _) = ic_ok(&ic(
        "icache_size 1024 1024 1\ntile_size 256 256 1\nvalid_region 256 256 1\nvalid_region_dst 512 512 1\n",
    ));
    assert_eq!(p.tex_region, [256, 256, 1]);
    // valid_region_dst works here (3.0 can never match it).
    assert_eq!(p.tex_size, [512, 512, 1]);
}

#[test]
fn level_layout_4096_clip_512_is_3_icache_and_10_pyramid_levels() {
    let (p, _) = ct_ok(NO_IC_CT);
    assert_eq!(kinds(&p), (3, 10));
    assert_eq!(p.levels.len(), 13);
    let s = sizes(&p);
    assert_eq!(s[0], [4096, 4096]);
    assert_eq!(s[2], [1024, 1024]);
    assert_eq!(s[3], [512, 512]);
    assert_eq!(s[12], [1, 1]);
    for (i, l) in p.levels.iter().enumerate() {
        assert_eq!(l.level as usize, i);
    }
}

#[test]
fn smallest_icache_default_rules() {
    // Square: 2 x clip_size.
    let (p, _) = ct_ok(&NO_IC_CT.replace("clip_size 512", "clip_size 256"));
    assert_eq!(p.smallest_icache, [512, 512, 1]);
    assert_eq!(kinds(&p), (4, 9));
}

#[test]
fn non_square_default_smallest_icache_is_not_refused_by_the_2x_clip_check() {
    // S > T: S = clip x ratio, T = clip (2048 > 2 x 512, but it is the default, not a value
    // from the file, so the 2 x clip_size check does not apply).
    let wide = NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 8192 2048 1");
    let (p, d) = ct_ok(&wide);
    assert_eq!(p.smallest_icache, [2048, 512, 1]);
    // T > S.
    let tall = NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 2048 8192 1");
    let (p2, _) = ct_ok(&tall);
    assert_eq!(p2.smallest_icache, [512, 2048, 1]);
    // 8192 x 2048: image caches 8192, 4096, 2048 wide; the pyramid ends at 4x1.
    assert_eq!(kinds(&p), (3, 9));
    let s = sizes(&p);
    assert_eq!(&s[..3], &[[8192, 2048], [4096, 1024], [2048, 512]]);
    assert_eq!(s[3], [1024, 256]);
    assert_eq!(*s.last().unwrap(), [4, 1]);
    expect(&d, "non-square-pyramid-end", Severity::Note, Some((5, 1)), &["4x1", "not 1x1"]);
    assert_eq!(*sizes(&p2).last().unwrap(), [1, 4]);
}

#[test]
fn smallest_icache_given_and_copied_between_axes() {
    let (p, _) = ct_ok(&format!("{NO_IC_CT}smallest_icache 512 512 1\n"));
    assert_eq!(p.smallest_icache, [512, 512, 1]);
    // 4096, 2048, 1024, 512 are image caches; then 256 .. 1.
    assert_eq!(kinds(&p), (4, 9));
    let (p, _) = ct_ok(&format!("{NO_IC_CT}smallest_icache 512 -1 1\n"));
    assert_eq!(p.smallest_icache, [512, 512, 1]);
    let (p, _) = ct_ok(&format!("{NO_IC_CT}smallest_icache -1 512 1\n"));
    assert_eq!(p.smallest_icache, [512, 512, 1]);
    // Below the clip size is legal: those image caches' tex region is the whole level.
    let (p, _) = ct_ok(&format!("{NO_IC_CT}smallest_icache 256 256 1\n"));
    let LevelKind::Icache(last) = &p.levels[4].kind else { panic!("level 4 is an image cache") };
    assert_eq!(last.size, [256, 256, 1]);
    assert_eq!(last.tex_region, [256, 256, 1]);
}

#[test]
fn no_ic_mode_synthesises_each_image_cache_from_the_ct() {
    let (p, _) = ct_ok(&format!("{NO_IC_CT}header_offset 128\nlookahead 2\npage_size 8192\n"));
    assert_eq!(p.icache_mode, GroupMode::None);
    assert_eq!(p.tile_mode, GroupMode::Format);
    let LevelKind::Icache(l0) = &p.levels[0].kind else { panic!() };
    assert_eq!(l0.path, None);
    assert_eq!(l0.size, [4096, 4096, 1]);
    assert_eq!(l0.tile_size, [256, 256, 1]);
    assert_eq!(l0.tex_region, [512, 512, 1]);
    // ceil(512/256) + 1 + 2 = 5.
    assert_eq!(l0.mem_region, [5, 5, 1]);
    assert_eq!((l0.header_offset, l0.lookahead, l0.page_size), (128, 2, 8192));
    let loc = p.locate(0, 3, 5).unwrap();
    assert!(loc.path.as_local().unwrap().ends_with("t.4096.r5.c3.raw"), "{}", loc.path);
    assert_eq!(loc.offset, 128);
    assert_eq!(loc.length, 256 * 256 * 3);
    let loc = p.locate(2, 1, 2).unwrap();
    assert!(loc.path.as_local().unwrap().ends_with("t.1024.r2.c1.raw"));
    // Pyramid files: the same format, tile numbers 0, header offset of the .ct.
    let loc = p.locate(3, 0, 0).unwrap();
    assert!(loc.path.as_local().unwrap().ends_with("t.512.r0.c0.raw"));
    assert_eq!((loc.offset, loc.length), (128, 512 * 512 * 3));
}

#[test]
fn no_ic_mode_without_tile_format_uses_the_default_name_format() {
    let text = ct("virt_size 2048 2048 1\nclip_size 512\ntile_size 512 512 1\n");
    let (p, d) = ct_ok(&text);
    expect(&d, "no-ic-default-format", Severity::Warning, Some((1, 1)), &["%s%s.%d.r%03d.c%03d.raw888"]);
    expect(&d, "pyramid-unnamed", Severity::Warning, Some((1, 1)), &["10 pyramid levels", "blank"]);
    let LevelKind::Icache(l0) = &p.levels[0].kind else { panic!() };
    // CACHENAME is "./" when the base is empty.
    assert_eq!(l0.naming.cache_name, "./");
    let loc = p.locate(0, 2, 1).unwrap();
    assert!(loc.path.as_local().unwrap().ends_with(".2048.r001.c002.raw888"), "{}", loc.path);
    assert!(matches!(p.locate(2, 0, 0), Err(plan::TileError::Unnamed { level: 2 })));
}

#[test]
fn a_virtual_clip_texture_of_2_to_the_26() {
    let text = ct("virt_size 67108864 67108864 1\nclip_size 2048\neffective_levels 16\n\
         tile_format v.%d.%d.%d\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S \
         PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T\n\
         tile_size 512 512 1\n");
    let (p, d) = ct_ok(&text);
    clean(&d);
    assert_eq!(p.levels.len(), 27);
    assert_eq!(kinds(&p), (15, 12));
    assert_eq!(p.effective_levels, 16);
    assert!(p.is_virtual);
    let LevelKind::Icache(l0) = &p.levels[0].kind else { panic!() };
    assert_eq!(l0.tile_count(), [131072, 131072, 1]);
    let loc = p.locate(0, 131071, 131071).unwrap();
    assert!(loc.path.as_local().unwrap().ends_with("v.67108864.131071.131071"));
    // effective_levels as large as the level count: not virtual.
    let (p, _) = ct_ok(&text.replace("effective_levels 16", "effective_levels 27"));
    assert!(!p.is_virtual);
}

#[test]
fn the_explicit_file_list_example_of_the_manual() {
    // docs/PERFORMER-REFERENCE.md §1.14 / D-CT example 1: virt 4096, clip 512 -> 3 .ic files + 10 tile files.
    let fx = Fixture::new();
    fx.write_level_ics("ic/l", 4096, 1024, 256);
    let pyr: Vec<String> = (0..10).map(|i| format!("pyr/{}.raw", 512 >> i)).collect();
    fx.write(
        "d.ct",
        format!(
            "ct_version1.0\n{RGB8}virt_size 4096 4096 1\nclip_size 512\n\
             icache_files ic/l.4096.ic ic/l.2048.ic ic/l.1024.ic\ntile_files {}\n",
            pyr.join(" ")
        ),
    );
    let (p, d) = ct_plan_in(&fx, "d.ct", &opts());
    clean(&d);
    assert_eq!((p.icache_mode, p.tile_mode), (GroupMode::FileList, GroupMode::FileList));
    assert_eq!(kinds(&p), (3, 10));
    let LevelKind::Icache(l1) = &p.levels[1].kind else { panic!() };
    assert_eq!(l1.path.as_deref(), Some(fx.path("ic/l.2048.ic").as_path()));
    assert_eq!(l1.tex_region, [512, 512, 1]);
    assert_eq!(l1.mem_region, [4, 4, 1]);
    // tile_files entry i is the pyramid level of size smallest / 2^(i+1).
    for (i, name) in pyr.iter().enumerate() {
        let LevelKind::Pyramid(t) = &p.levels[3 + i].kind else { panic!() };
        assert_eq!(t.path.as_ref().and_then(|p| p.as_local()), Some(fx.path(name).as_path()));
        assert_eq!(p.levels[3 + i].size, [512 >> i, 512 >> i]);
    }
}

#[test]
fn level_ics_inherit_lookahead_and_page_size_unless_they_set_their_own() {
    let fx = Fixture::new();
    fx.write_level_ics("ic/l", 2048, 1024, 256);
    fx.write("ic/l.1024.ic", format!("{}lookahead 0\npage_size 512\n", level_ic(1024, 1024, 256)));
    fx.write(
        "x.ct",
        ct("virt_size 2048 2048 1\nclip_size 512\nicache_format ic/l.%d.ic\n\
            icache_params PFCLIPTEX_FNAMEARG_LEVEL_SIZE\nlookahead 3\npage_size 16384\n"),
    );
    let (p, _) = ct_plan_in(&fx, "x.ct", &opts());
    let LevelKind::Icache(a) = &p.levels[0].kind else { panic!() };
    let LevelKind::Icache(b) = &p.levels[1].kind else { panic!() };
    assert_eq!((a.lookahead, a.page_size), (3, 16384));
    // 2048 / 256 = 8 tiles; min(2 + 1 + 3, 8) = 6.
    assert_eq!(a.mem_region, [6, 6, 1]);
    assert_eq!((b.lookahead, b.page_size), (0, 512));
    assert_eq!(b.mem_region, [3, 3, 1]);
}

#[test]
fn inside_a_clip_texture_the_tex_region_is_min_of_clip_and_level() {
    let fx = Fixture::new();
    fx.write_level_ics("l", 2048, 1024, 256);
    fx.write("l.2048.ic", format!("{}tex_region_size 256 256 1\n", level_ic(2048, 2048, 256)));
    fx.write(
        "x.ct",
        ct("virt_size 2048 2048 1\nclip_size 1024\nsmallest_icache 1024 1024 1\n\
            icache_files l.2048.ic l.1024.ic\n"),
    );
    let (p, d) = ct_plan_in(&fx, "x.ct", &opts());
    let LevelKind::Icache(a) = &p.levels[0].kind else { panic!() };
    assert_eq!(a.tex_region, [1024, 1024, 1]);
    let x = expect(&d, "tex-region-replaced", Severity::Note, Some((8, 1)), &["1024x1024"]);
    assert!(x.path.ends_with("l.2048.ic"));
}

#[test]
fn repeated_scalars_last_wins_with_a_warning() {
    let (p, d) = ct_ok(&format!("{NO_IC_CT}lookahead 2\nlookahead 3\n"));
    assert_eq!(p.lookahead, 3);
    expect(&d, "repeated-token", Severity::Warning, Some((11, 1)), &["lookahead", "2 times", "line 10"]);
    // In an .ic a second tile_format replaces the first.
    let (p, d) = ic_ok(&format!(
        "{SMALL_IC}tile_format a%d\ntile_format b%d\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S\n"
    ));
    assert_eq!(p.naming.format, "b%d");
    expect(&d, "repeated-token", Severity::Warning, Some((9, 1)), &["tile_format"]);
}

#[test]
fn two_number_sizes_take_r_1_with_a_portability_warning() {
    let (p, d) = ct_ok(&NO_IC_CT.replace("virt_size 4096 4096 1", "virt_size 4096 4096"));
    assert_eq!(p.virt_size, [4096, 4096, 1]);
    let x =
        expect(&d, "size-missing-r", Severity::Warning, Some((5, 1)), &["R is taken as 1", "`virt_size 4096 4096 1`"]);
    assert!(x.portability);
}

#[test]
fn the_texel_size_follows_the_formats() {
    for (ext, img, bytes) in [
        ("PFTEX_PACK_8", "PFTEX_RGB", 3),
        ("PFTEX_UNSIGNED_SHORT_5_5_5_1", "PFTEX_RGBA", 2),
        ("GL_UNSIGNED_SHORT", "PFTEX_RGBA", 8),
        ("5121", "PFTEX_LUMINANCE", 1),
        ("PFTEX_FLOAT", "GL_LUMINANCE_ALPHA", 8),
    ] {
        let text = SMALL_IC.replace("PFTEX_PACK_8", ext).replace("img_format PFTEX_RGB", &format!("img_format {img}"));
        let (p, _) = ic_ok(&text);
        assert_eq!(p.bytes_per_texel, bytes, "{ext} {img}");
        assert_eq!(p.tile_bytes(), 256 * 256 * bytes as u64);
    }
}

#[test]
fn int_format_accepts_any_number_and_img_format_numbers_are_a_portability_note() {
    let text = SMALL_IC.replace("PFTEX_RGB_8", "12345").replace("img_format PFTEX_RGB", "img_format 6407");
    let (p, d) = ic_ok(&text);
    assert_eq!((p.int_format.value, p.img_format.value), (12345, 6407));
    let x = expect(&d, "numeric-img-format", Severity::Warning, Some((4, 12)), &["number"]);
    assert!(x.portability);
}
