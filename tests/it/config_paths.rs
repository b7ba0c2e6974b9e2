//! File names: environment expansion through real files, relative-path anchoring, printf
//! formats, the default tile name, stream servers, and byte offsets of tiles.

use crate::common;

use clipmap::config::Severity;
use clipmap::place::Place;
use clipmap::plan::{self, LevelKind, Options};
use common::*;
use std::path::PathBuf;

fn ic(body: &str) -> String {
    format!("ic_version2.0\n{RGB8}{body}")
}

/// Loads a standalone `.ic` written at `rel` in `fx`.
fn ic_in(fx: &Fixture, rel: &str, text: &str, o: &Options) -> plan::ImageCachePlan {
    let p = fx.write(rel, text);
    let l = plan::load_image_cache(&p, o).expect("readable");
    let rendered = l.render();
    l.plan.unwrap_or_else(|| panic!("{rel} should load:\n{rendered}"))
}

fn tile0(p: &plan::ImageCachePlan) -> PathBuf {
    p.locate(0, 0, 0).unwrap().path.as_local().expect("a local name").to_path_buf()
}

const SIZE: &str = "icache_size 1024 1024 1\ntile_size 256 256 1\ntex_region_size 512 512 1\n";
const FMT: &str = "tile_format %s.%d.%d\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_CACHENAME \
                   PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T\n";

#[test]
fn the_default_tile_name_of_the_image_cache_manual() {
    // D-PIC: stream `/`, cache `usr/data/Terrain/TerrainTexture/texture`, size 16384, 512-texel
    // tiles, tile origin (8192, 2048) = tile (16, 4).
    let (p, d) = ic_ok(&ic("icache_size 16384 16384 1\ntile_size 512 512 1\ntex_region_size 1024 1024 1\n\
         tile_base usr/data/Terrain/TerrainTexture/texture\ns_stream /\n"));
    clean(&d);
    let loc = p.locate(16, 4, 0).unwrap();
    assert_eq!(
        loc.path,
        Place::Local(PathBuf::from("/usr/data/Terrain/TerrainTexture/texture.16384.r004.c016.raw888"))
    );
    assert_eq!(loc.stream, "/");
    assert_eq!((loc.offset, loc.length), (0, 512 * 512 * 3));
}

#[test]
fn tile_byte_offset_with_tiles_in_file_and_header() {
    // docs/PERFORMER-REFERENCE.md §1.12: 256x256 RGB tiles, 4x4x1 per file, header 1024, tile (6, 9)
    // -> file (1, 2), position (2, 1) -> (2 + 4*1) * 3 * 65536 + 1024 = 1180672.
    let (p, d) = ic_ok(&ic("icache_size 4096 4096 1\ntile_size 256 256 1\ntex_region_size 1024 1024 1\n\
         tiles_in_file 4 4 1\nheader_offset 1024\ntile_format f.%d.%d\n\
         tile_params PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_S PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_T\n"));
    clean(&d);
    let loc = p.locate(6, 9, 0).unwrap();
    assert_eq!(loc.offset, 1180672);
    assert_eq!(loc.length, 196608);
    assert!(loc.path.as_local().unwrap().ends_with("f.1.2"), "{}", loc.path);
    // The first tile of a file starts right after the header; the last one before the next file.
    assert_eq!(p.locate(4, 8, 0).unwrap().offset, 1024);
    assert_eq!(p.locate(7, 11, 0).unwrap().offset, 1024 + 15 * 196608);
    assert!(p.locate(16, 0, 0).is_err());
}

#[test]
fn tile_name_parameters_take_their_image_cache_meanings() {
    let (p, _) = ic_ok(&ic(
        "icache_size 2048 1024 1\ntile_size 256 128 1\ntex_region_size 512 512 1\n\
         tiles_in_file 2 2 1\ntile_base cache\n\
         tile_format %s/%d.%d.%d/%d.%d.%d/%d.%d.%d/%d.%d.%d\ntile_params \
         PFIMAGECACHE_TILE_FILENAMEARG_CACHENAME \
         PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_T PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_R \
         PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_R \
         PFIMAGECACHE_TILE_FILENAMEARG_TILEORG_S PFIMAGECACHE_TILE_FILENAMEARG_TILEORG_T PFIMAGECACHE_TILE_FILENAMEARG_TILEORG_R \
         PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_S PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_T PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_R\n",
    ));
    let loc = p.locate(5, 3, 0).unwrap();
    assert!(loc.path.as_local().unwrap().ends_with("cache/2048.1024.1/5.3.0/1280.384.0/2.1.0"), "{}", loc.path);
}

#[test]
fn printf_flags_width_and_precision_render_like_c() {
    let (p, _) = ic_ok(&ic(&format!(
        "{SIZE}tile_format r%03d_c%-3d|%5d|%x|%%\ntile_params \
         PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S \
         PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S\n"
    )));
    let loc = p.locate(2, 3, 0).unwrap();
    assert!(loc.path.as_local().unwrap().ends_with("r003_c2  | 1024|400|%"), "{}", loc.path);
}

#[test]
fn streams_are_chosen_by_tile_index_modulo_the_server_count() {
    let (p, _) = ic_ok(&ic(&format!("{SIZE}s_stream /s0/ /s1/ /s2/\nt_stream /t0/ /t1/\nr_stream /r0/\n")));
    assert_eq!(p.streams[0], ["/s0/", "/s1/", "/s2/"]);
    // Idle queues: the S proposal wins.
    for s in 0..4 {
        let loc = p.locate(s, 1, 0).unwrap();
        let want = format!("/s{}/", s % 3);
        assert_eq!(loc.stream, want);
        assert_eq!(loc.queue, Some((0, (s % 3) as usize)));
        // The default format puts the stream directly before the cache name.
        assert!(loc.path.as_local().unwrap().starts_with(&want), "{}", loc.path);
    }
}

#[test]
fn the_least_busy_proposed_stream_wins_and_ties_go_to_s_then_t() {
    let (p, _) = ic_ok(&ic(&format!("{SIZE}s_stream /s0/ /s1/\nt_stream /t0/ /t1/ /t2/\nr_stream /r0/\n")));
    // Tile (1, 2): S proposes /s1/, T proposes /t2/, R proposes /r0/.
    let busy = |s: usize, t: usize, r: usize| {
        move |axis: usize, i: usize| match (axis, i) {
            (0, 1) => s,
            (1, 2) => t,
            (2, 0) => r,
            _ => 100,
        }
    };
    let pick = |s, t, r| p.locate_with(1, 2, 0, busy(s, t, r)).unwrap().stream;
    assert_eq!(pick(0, 0, 0), "/s1/");
    assert_eq!(pick(5, 1, 3), "/t2/");
    assert_eq!(pick(5, 3, 1), "/r0/");
    assert_eq!(pick(2, 2, 2), "/s1/");
    assert_eq!(pick(3, 2, 2), "/t2/");
    // Only T servers: T's proposal whatever the load.
    let (p, _) = ic_ok(&ic(&format!("{SIZE}t_stream /a/ /b/\n")));
    assert_eq!(p.locate_with(0, 3, 0, |_, _| 9).unwrap().stream, "/b/");
    // No servers: empty stream, no queue.
    let (p, _) = ic_ok(&ic(SIZE));
    let loc = p.locate(0, 0, 0).unwrap();
    assert_eq!((loc.stream.as_str(), loc.queue), ("", None));
}

#[test]
fn the_plural_streams_spelling_is_a_real_token_with_a_portability_warning() {
    let (p, d) = ic_ok(&ic(&format!("{SIZE}s_streams /a/ /b/\n")));
    assert_eq!(p.streams[0], ["/a/", "/b/"]);
    let x = expect(&d, "plural-streams-token", Severity::Warning, Some((8, 1)), &["`s_stream`", "named `s`"]);
    assert!(x.portability);
    let (_, d) = ic_ok(&ic(&format!("{SIZE}s_stream\n")));
    expect(&d, "empty-stream-list", Severity::Warning, Some((8, 1)), &["empty"]);
}

#[test]
fn environment_expansion_in_tile_base_and_format() {
    let fx = Fixture::new();
    let o = opts_with(&[("DATA", "/mnt/terrain"), ("EMPTY", ""), ("COLON", "/a:/b")]);
    let cases = [
        ("$(DATA)/tiles", "/mnt/terrain/tiles.0.0"),
        ("${DATA}/tiles", "/mnt/terrain/tiles.0.0"),
        ("$(DATA}/tiles", "/mnt/terrain/tiles.0.0"),
        ("$DATA.d/tiles", "/mnt/terrain.d/tiles.0.0"),
        ("${UNSET:-/fallback}/tiles", "/fallback/tiles.0.0"),
        ("${EMPTY:-/fallback}/tiles", "/tiles.0.0"),
        ("$UNSET/tiles", "/tiles.0.0"),
    ];
    for (base, want) in cases {
        let p = ic_in(&fx, "e.ic", &ic(&format!("{SIZE}tile_base {base}\n{FMT}")), &o);
        assert_eq!(tile0(&p), PathBuf::from(want), "tile_base {base}");
    }
    // Only a leading `$` is expanded; the rest is anchored to the .ic's directory.
    let p = ic_in(&fx, "sub/e.ic", &ic(&format!("{SIZE}tile_base data/$DATA\n{FMT}")), &o);
    assert_eq!(tile0(&p), fx.path("sub/data/$DATA.0.0"));
    // The format is expanded too.
    let p = ic_in(
        &fx,
        "e.ic",
        &ic(&format!(
            "{SIZE}tile_format $DATA/%d.%d\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S \
             PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T\n"
        )),
        &o,
    );
    assert_eq!(tile0(&p), PathBuf::from("/mnt/terrain/0.0"));
    // A default relative to the .ic's directory.
    let p = ic_in(&fx, "e.ic", &ic(&format!("{SIZE}tile_base $HV:-rel\n{FMT}")), &o);
    assert_eq!(tile0(&p), fx.path("rel.0.0"));
}

#[test]
fn expansion_findings_point_at_the_field() {
    let fx = Fixture::new();
    let o = opts_with(&[("COLON", "/a:/b")]);
    let text = ic(&format!("{SIZE}tile_base $COLON/t\n{FMT}"));
    let l = plan::load_image_cache(&fx.write("c.ic", &text), &o).unwrap();
    let d = l.diagnostics;
    expect(&d, "variable-value-has-colon", Severity::Warning, Some((8, 11)), &["COLON", "literally"]);
    // Kept literally, `$` included, and anchored as a relative name.
    assert_eq!(tile0(l.plan.as_ref().unwrap()), fx.path("$COLON/t.0.0"));
    let text = ic(&format!("{SIZE}tile_base $UNSET/t\n{FMT}"));
    let l = plan::load_image_cache(&fx.write("u.ic", &text), &o).unwrap();
    expect(&l.diagnostics, "unset-variable", Severity::Warning, Some((8, 11)), &["UNSET", "not set"]);
    let text = ic(&format!("{SIZE}tile_base $/t\n{FMT}"));
    let l = plan::load_image_cache(&fx.write("n.ic", &text), &o).unwrap();
    expect(&l.diagnostics, "empty-variable-name", Severity::Warning, Some((8, 11)), &["no variable name"]);
    assert_eq!(tile0(l.plan.as_ref().unwrap()), fx.path("$/t.0.0"));
}

#[test]
fn default_tile_is_prefixed_by_the_base_and_not_expanded() {
    let fx = Fixture::new();
    let o = opts_with(&[("X", "/x")]);
    let p = ic_in(&fx, "a/d.ic", &ic(&format!("{SIZE}tile_base /d/elev\ndefault_tile _sea.lum\n")), &o);
    assert_eq!(p.default_tile, Some(Place::Local(PathBuf::from("/d/elev_sea.lum"))));
    let p = ic_in(&fx, "a/d.ic", &ic(&format!("{SIZE}default_tile blank.raw\n")), &o);
    assert_eq!(p.default_tile, Some(Place::Local(fx.path("a/blank.raw"))));
    let text = ic(&format!("{SIZE}default_tile $X/blank.raw\n"));
    let l = plan::load_image_cache(&fx.write("a/e.ic", &text), &o).unwrap();
    expect(
        &l.diagnostics,
        "default-tile-not-expanded",
        Severity::Warning,
        Some((8, 14)),
        &["not environment-expanded"],
    );
    assert_eq!(l.plan.unwrap().default_tile, Some(Place::Local(fx.path("a/$X/blank.raw"))));
}

/// A clip texture of 2048 with two image cache levels, written with `naming` lines.
fn ct_with(naming: &str) -> String {
    format!("ct_version2.0\n{RGB8}virt_size 2048 2048 1\nclip_size 512\n{naming}")
}

fn ic_paths(p: &plan::ClipTexturePlan) -> Vec<PathBuf> {
    p.levels
        .iter()
        .filter_map(|l| match &l.kind {
            LevelKind::Icache(ic) => ic.path.clone(),
            LevelKind::Pyramid(_) => None,
            LevelKind::IcacheNotOpened { path } => Some(path.clone()),
        })
        .collect()
}

fn pyramid_paths(p: &plan::ClipTexturePlan) -> Vec<Option<PathBuf>> {
    p.levels
        .iter()
        .filter_map(|l| match &l.kind {
            LevelKind::Pyramid(t) => Some(t.path.clone().map(|p| p.as_local().expect("a local name").to_path_buf())),
            LevelKind::Icache(_) | LevelKind::IcacheNotOpened { .. } => None,
        })
        .collect()
}

#[test]
fn relative_names_are_anchored_to_the_directory_of_the_file_that_names_them() {
    let fx = Fixture::new();
    fx.write_level_ics("conf/ic/l", 2048, 1024, 256);
    fx.write(
        "conf/x.ct",
        ct_with(
            "icache_format ic/l.%d.ic\nicache_params PFCLIPTEX_FNAMEARG_LEVEL_SIZE\n\
             tile_format ../pyr/%d.raw\ntile_params PFCLIPTEX_FNAMEARG_LEVEL\n",
        ),
    );
    let (p, d) = ct_plan_in(&fx, "conf/x.ct", &opts());
    clean(&d);
    assert_eq!(ic_paths(&p), [fx.path("conf/ic/l.2048.ic"), fx.path("conf/ic/l.1024.ic")]);
    // PFCLIPTEX_FNAMEARG_LEVEL is the level number: the first pyramid level is level 2.
    assert_eq!(pyramid_paths(&p)[0], Some(fx.path("conf/../pyr/2.raw")));
    assert_eq!(pyramid_paths(&p)[9], Some(fx.path("conf/../pyr/11.raw")));
    // The tiles of each level's .ic are anchored to the .ic's directory, not the .ct's.
    let loc = p.locate(0, 0, 0).unwrap();
    assert!(loc.path.as_local().unwrap().starts_with(fx.path("conf/ic/tiles")), "{}", loc.path);
}

#[test]
fn the_base_is_applied_to_every_list_entry_whatever_the_order() {
    let fx = Fixture::new();
    fx.write_level_ics("lv/l", 2048, 1024, 256);
    let pyr = (0..10).map(|i| format!("p{i}")).collect::<Vec<_>>().join(" ");
    let naming = format!("icache_base lv/\nicache_files l.2048.ic l.1024.ic\ntile_files {pyr}\ntile_base /abs/pyr/\n");
    fx.write("x.ct", ct_with(&naming));
    let (p, d) = ct_plan_in(&fx, "x.ct", &opts());
    assert_eq!(ic_paths(&p), [fx.path("lv/l.2048.ic"), fx.path("lv/l.1024.ic")]);
    let pyr = pyramid_paths(&p);
    assert_eq!(pyr[0], Some(PathBuf::from("/abs/pyr/p0")));
    assert_eq!(pyr[9], Some(PathBuf::from("/abs/pyr/p9")));
    let x =
        expect(&d, "base-after-files", Severity::Warning, Some((10, 1)), &["tile_base", "tile_files", "every entry"]);
    assert!(x.portability);
}

#[test]
fn env_expansion_in_ct_bases_formats_and_list_entries() {
    let fx = Fixture::new();
    fx.write_level_ics("ic/l", 2048, 1024, 256);
    let o = opts_with(&[("CONF", "ic"), ("PYR", "/data/pyr")]);
    let pyr = (0..10).map(|i| format!("$PYR/{i}.raw")).collect::<Vec<_>>().join(" ");
    fx.write("x.ct", ct_with(&format!("icache_files $CONF/l.2048.ic ${{CONF}}/l.1024.ic\ntile_files {pyr}\n")));
    let (p, _) = ct_plan_in(&fx, "x.ct", &o);
    assert_eq!(ic_paths(&p), [fx.path("ic/l.2048.ic"), fx.path("ic/l.1024.ic")]);
    assert_eq!(pyramid_paths(&p)[3], Some(PathBuf::from("/data/pyr/3.raw")));
    // The same through a base and a format; IMAGE_CACHE_BASE passes the expanded base.
    fx.write(
        "y.ct",
        ct_with(
            "icache_base $(CONF)\nicache_format %s/l.%d.ic\nicache_params \
             PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE PFCLIPTEX_FNAMEARG_LEVEL_SIZE\n\
             tile_base $PYR\ntile_format %s/%d.raw\ntile_params PFCLIPTEX_FNAMEARG_TILE_BASE \
             PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_T\n",
        ),
    );
    let (p, _) = ct_plan_in(&fx, "y.ct", &o);
    assert_eq!(ic_paths(&p), [fx.path("ic/l.2048.ic"), fx.path("ic/l.1024.ic")]);
    assert_eq!(pyramid_paths(&p)[0], Some(PathBuf::from("/data/pyr/512.raw")));
    // Changing the environment changes the names.
    let o2 = opts_with(&[("CONF", "ic"), ("PYR", "/other")]);
    let (p, _) = ct_plan_in(&fx, "y.ct", &o2);
    assert_eq!(pyramid_paths(&p)[0], Some(PathBuf::from("/other/512.raw")));
}

#[test]
fn a_relative_config_path_still_gives_absolute_names() {
    // The loader makes the config path absolute before anchoring, whatever the working directory.
    let fx = Fixture::new();
    let p = fx.write("a/b.ic", ic(&format!("{SIZE}tile_base t\n")));
    let here = std::env::current_dir().unwrap();
    let rel = pathdiff(&p, &here);
    let l = plan::load_image_cache(&rel, &opts()).unwrap();
    let plan = l.plan.unwrap();
    assert!(plan.path.as_ref().unwrap().is_absolute());
    let t = tile0(&plan);
    assert!(t.is_absolute(), "{}", t.display());
    // `..` is kept, as in Performer; the directory is the .ic's all the same.
    let dir = std::fs::canonicalize(t.parent().unwrap()).unwrap();
    assert_eq!(dir, std::fs::canonicalize(fx.path("a")).unwrap());
}

/// `to` relative to `from` (both absolute), with `..` components.
fn pathdiff(to: &std::path::Path, from: &std::path::Path) -> PathBuf {
    let t: Vec<_> = to.components().collect();
    let f: Vec<_> = from.components().collect();
    let common = t.iter().zip(&f).take_while(|(a, b)| a == b).count();
    let mut out = PathBuf::new();
    for _ in common..f.len() {
        out.push("..");
    }
    for c in &t[common..] {
        out.push(c);
    }
    out
}
