//! A `.ct` / `.ic` naming a COG (`#clipmap cog`, docs/COG.md "A configuration naming a COG"):
//! `clipprep --input FILE.tif --config-only` writes one and no tile; `cliptex validate` accepts
//! it (`--strict` says Performer would ignore the line); `clipmapd`, `cliptex check|dump|info`
//! and `icache dump` serve the COG's texels exactly as `clipmapd FILE.tif` does; a header field
//! that disagrees with the COG, and a COG that is not there, are refused naming the line, the
//! field, the value written and the COG's.

use crate::cog::{fixture, gdal_level, level};
use crate::common::gdal::Served;
use clipmap::source::{CogSource, TileSource};
use std::path::Path;
use std::time::{Duration, Instant};

fn run<S: AsRef<std::ffi::OsStr>>(program: &str, args: &[S], dir: &Path) -> (std::process::ExitStatus, String) {
    let out = std::process::Command::new(program).args(args).current_dir(dir).output().unwrap();
    (out.status, format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr)))
}

const CLIPPREP: &str = env!("CARGO_BIN_EXE_clipprep");
const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const ICACHE: &str = env!("CARGO_BIN_EXE_icache");

/// `clipprep --input COG --config-only --clip CLIP --out OUT` in `dir`; panics when it fails.
fn config_only(cog: &Path, clip: u64, out: &str, dir: &Path) -> String {
    let clip = clip.to_string();
    let args = ["--input".as_ref(), cog.as_os_str(), "--config-only".as_ref(), "--clip".as_ref(), clip.as_ref()];
    let (status, text) = run(CLIPPREP, &[&args[..], &["--out".as_ref(), out.as_ref()]].concat(), dir);
    assert!(status.success(), "{text}");
    text
}

/// Every file under `dir`, relative.
fn files(dir: &Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            if e.file_type().unwrap().is_dir() {
                stack.push(e.path());
            } else {
                out.push(e.path().strip_prefix(dir).unwrap().to_string_lossy().into_owned());
            }
        }
    }
    out.sort();
    out
}

/// Waits until level `k` of `c` has a valid region (the whole level when `whole`), and returns
/// it with its texels.
fn valid_texels(served: &Served, k: usize, size: [u64; 2], whole: bool) -> ([i64; 4], Vec<u8>) {
    let c = &served.client;
    let t = Instant::now();
    loop {
        if let Some(st) = c.level_state(k) {
            let [s0, t0, s1, t1] = st.valid;
            let full = [s0, t0, s1, t1] == [0, 0, size[0] as i64, size[1] as i64];
            if st.enabled && s1 > s0 && t1 > t0 && (full || !whole) {
                let (w, h) = ((s1 - s0) as u64, (t1 - t0) as u64);
                let mut buf = vec![0u8; (w * h) as usize * c.bytes_per_texel];
                if c.read_region(k, s0, t0, w, h, &mut buf).is_ok() {
                    return (st.valid, buf);
                }
            }
        }
        assert!(t.elapsed() < Duration::from_secs(30), "level {k} never became valid\n{}", served.log());
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Both services publish the texture of `src` (the COG opened in this process as `clipmapd
/// FILE.tif` opens it): the same format and levels, and every texel of each level's valid
/// region (the whole level when `whole`) equal to the COG's.
fn assert_served_as_the_cog(ct: &Served, tif: &Served, src: &CogSource, whole: bool) {
    let (a, b) = (&ct.client, &tif.client);
    assert_eq!(a.format_code, b.format_code, "the texel format");
    assert_eq!(a.bytes_per_texel, src.desc().bytes_per_texel());
    let n = src.desc().level_count();
    assert_eq!(a.snapshot().levels.len(), n, "the COG's levels, not the .ct's\n{}", ct.log());
    let bpt = src.desc().bytes_per_texel();
    for k in 0..n {
        let size = src.desc().level(k as u32).size;
        let want = level(src, k as u32).unwrap();
        for served in [ct, tif] {
            let ([s0, t0, s1, _], texels) = valid_texels(served, k, size, whole);
            let w = (s1 - s0) as usize;
            for (i, texel) in texels.chunks_exact(bpt).enumerate() {
                let (s, t) = (s0 as usize + i % w, t0 as usize + i / w);
                let at = (t * size[0] as usize + s) * bpt;
                assert_eq!(texel, &want[at..at + bpt], "level {k} texel ({s}, {t})\n{}", served.log());
            }
        }
    }
}

#[test]
fn clipprep_config_only_writes_a_ct_clipmapd_serves_as_the_cog_itself_texel_for_texel() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cog = fixture("grey_1000x700.tif");
    // Clip 1024: the whole of every level is resident, every texel compared; clip 256: stack
    // levels read in the COG's TIFF tiles, the windows compared.
    for (clip, whole) in [(1024, true), (256, false)] {
        let out = format!("g{clip}");
        let text = config_only(&cog, clip, &out, d);
        assert!(text.contains("(1000 x 700 texels, l8, virt_size 1024 x 1024); no tile written"), "{text}");
        // Only the configuration: the .ct and one .ic per image-cache level, no tile.
        let written = files(&d.join(&out));
        assert!(written.iter().all(|f| f.ends_with(".ct") || f.ends_with(".ic")), "{written:?}");
        let ct = d.join(&out).join(format!("{out}.ct"));
        let text = std::fs::read_to_string(&ct).unwrap();
        assert!(text.contains("virt_size 1024 1024 1\n"), "rounded up to powers of two:\n{text}");
        assert!(text.contains(&format!("\n#clipmap cog {}\n", cog.display())), "{text}");
        // The same COG served directly and through the .ct: GDAL's level 0, every level the COG's.
        let src = CogSource::open(&cog, clip).unwrap();
        let (gdal, size) = gdal_level("grey_1000x700", 0, 1);
        assert_eq!(size, [1000, 700]);
        assert!(level(&src, 0).unwrap() == gdal, "the COG's level 0 is GDAL's decode");
        let by_ct = Served::start(&ct, clip, &format!("ct{clip}"), d);
        let by_tif = Served::start(&cog, clip, &format!("tif{clip}"), d);
        assert_served_as_the_cog(&by_ct, &by_tif, &src, whole);
    }
}

#[test]
fn a_ct_naming_a_cog_validates_and_strict_says_performer_would_ignore_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    config_only(&fixture("rgb_512x384.tif"), 128, "rgb", d);
    let (status, text) = run(CLIPTEX, &["validate", "rgb/rgb.ct"], d);
    assert!(status.success(), "{text}");
    assert!(text.contains("rgb/rgb.ct: valid (0 errors, 0 warnings)"), "{text}");
    assert!(text.contains("note: `#clipmap cog` serves the clip texture's texels from the COG"), "{text}");
    // --strict: an error, saying Performer 3.0 does not know the line, in the .ct and each .ic.
    let (status, text) = run(CLIPTEX, &["validate", "--strict", "rgb/rgb.ct"], d);
    assert_eq!(status.code(), Some(1), "{text}");
    assert!(
        text.contains("rgb.ct:3:10: error: `#clipmap cog` serves the clip texture's texels from the COG"),
        "{text}"
    );
    assert!(text.contains("which Performer 3.0 does not know"), "{text}");
    assert!(text.contains("L00.ic:3:10: error: `#clipmap cog` serves the image cache's texels"), "{text}");
    let (status, text) = run(ICACHE, &["validate", "--strict", "rgb/L00.ic"], d);
    assert_eq!(status.code(), Some(1), "{text}");
    assert!(text.contains("which Performer 3.0 does not know"), "{text}");
    // JSON: the finding's code, a portability finding.
    let (_, text) = run(CLIPTEX, &["validate", "--strict", "--json", "rgb/rgb.ct"], d);
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let codes: Vec<&str> =
        v["files"][0]["diagnostics"].as_array().unwrap().iter().filter_map(|d| d["code"].as_str()).collect();
    assert!(codes.contains(&"cog-extension"), "{v}");
}

#[test]
fn every_tool_reads_a_ct_naming_a_cog_by_a_relative_path_as_the_cog() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("data")).unwrap();
    std::fs::copy(fixture("rgb_512x384.tif"), d.join("data/rgb.tif")).unwrap();
    config_only(&d.join("data/rgb.tif"), 128, "pyr", d);
    // Named relative to the configuration's directory instead.
    for f in ["pyr/pyr.ct", "pyr/L00.ic", "pyr/L01.ic"] {
        let text = std::fs::read_to_string(d.join(f)).unwrap();
        let text: String = text
            .lines()
            .map(|l| if l.starts_with("#clipmap cog ") { "#clipmap cog ../data/rgb.tif".into() } else { l.to_string() })
            .map(|l| l + "\n")
            .collect();
        std::fs::write(d.join(f), text).unwrap();
    }
    let (status, text) = run(CLIPTEX, &["info", "--json", "pyr/pyr.ct"], d);
    assert!(status.success(), "{text}");
    let v: serde_json::Value =
        serde_json::from_str(text.lines().skip_while(|l| !l.starts_with('{')).collect::<Vec<_>>().join("\n").as_str())
            .unwrap_or_else(|e| panic!("{e}: {text}"));
    assert_eq!(v["cog"]["size"], serde_json::json!([512, 384]), "{v}");
    assert_eq!(v["cog"]["clip_size"], 128, "{v}");
    // check: every tile of the COG, as the service reads it.
    let (status, text) = run(CLIPTEX, &["check", "--json", "pyr/pyr.ct"], d);
    assert!(status.success(), "{text}");
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["servable"], true, "{v}");
    assert_eq!(v["totals"]["present"], v["totals"]["tiles"], "{v}");
    // dump: the .ct's level is the COG's, GDAL's decode where it is an image of the file.
    for k in ["0", "1"] {
        let png = format!("ct{k}.png");
        let (status, text) = run(CLIPTEX, &["dump", "pyr/pyr.ct", "--level", k, "--out", &png], d);
        assert!(status.success(), "{text}");
        let ours = image::open(d.join(&png)).unwrap().to_rgb8();
        let gdal = image::open(fixture(&format!("rgb_512x384.{k}.png"))).unwrap().to_rgb8();
        assert!(ours == gdal, "level {k}: the .ct's dump differs from GDAL's decode of the COG");
    }
    // icache: a standalone .ic finds its level of the COG by its size, and dumps it.
    let (status, text) = run(ICACHE, &["dump", "pyr/L01.ic", "--out", "ic1.png"], d);
    assert!(status.success(), "{text}");
    assert!(image::open(d.join("ic1.png")).unwrap().to_rgb8() == image::open(d.join("ct1.png")).unwrap().to_rgb8());
    let (status, text) = run(ICACHE, &["info", "pyr/L01.ic"], d);
    assert!(status.success(), "{text}");
    assert!(text.contains("(512 x 384 texels at level 0), its level 1: tiles are read from it"), "{text}");
    // tile: the tiles are the COG's, not files of the configuration.
    let (status, text) = run(CLIPTEX, &["tile", "pyr/pyr.ct", "--level", "0", "--s", "0", "--t", "0"], d);
    assert_eq!(status.code(), Some(1), "{text}");
    assert!(text.contains("is read from the COG") && text.contains("data/rgb.tif"), "{text}");
}

#[test]
fn a_header_field_that_disagrees_with_the_cog_is_refused_naming_line_field_found_and_expected() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    config_only(&fixture("grey_1000x700.tif"), 256, "g", d);
    let ct = d.join("g/g.ct");
    let good = std::fs::read_to_string(&ct).unwrap();
    let line_of = |text: &str, start: &str| text.lines().position(|l| l.starts_with(start)).unwrap() + 1;
    for (from, to, words) in [
        (
            "virt_size 1024 1024 1",
            "virt_size 2048 2048 1",
            vec![
                "error: `virt_size` does not describe the COG",
                "found `virt_size 2048 2048 1`",
                "expected virt_size 1024 1024 1 (its 1000 x 700 texels rounded up to powers of two",
                "hint: write `virt_size 1024 1024 1`",
            ],
        ),
        (
            "tile_size 256 256 1",
            "tile_size 128 128 1",
            vec![
                "error: `tile_size` does not describe the COG",
                "found `tile_size 128 128 1`",
                "expected tile_size 256 256 1 (the COG's TIFF tiles of level 0)",
            ],
        ),
        (
            "ext_format PFTEX_UNSIGNED_BYTE",
            "ext_format PFTEX_UNSIGNED_SHORT",
            vec![
                "error: `ext_format / int_format / img_format` does not describe the COG",
                "found `l16 texels`",
                "expected l8 texels: ext_format PFTEX_UNSIGNED_BYTE, int_format GL_LUMINANCE8_EXT, img_format PFTEX_LUMINANCE",
            ],
        ),
    ] {
        assert!(good.contains(from), "{good}");
        let bad = good.replace(from, to);
        std::fs::write(&ct, &bad).unwrap();
        let (status, text) = run(CLIPTEX, &["validate", "g/g.ct"], d);
        assert_eq!(status.code(), Some(1), "{to}: {text}");
        let at = format!("g.ct:{}:1: ", line_of(&bad, to));
        assert!(text.contains(&at), "{to}: the line {at}\n{text}");
        for w in &words {
            assert!(text.contains(w), "{to}: {w}\n{text}");
        }
        // The service refuses it too, with the same words.
        let (status, text) = run(env!("CARGO_BIN_EXE_clipmapd"), &["g/g.ct", "--shm-dir", "."], d);
        assert_eq!(status.code(), Some(1), "{to}: {text}");
        assert!(text.contains(words[0]), "{to}: {text}");
    }
    // An .ic's tile_size, reported in the .ic at its line.
    std::fs::write(&ct, &good).unwrap();
    let ic = std::fs::read_to_string(d.join("g/L00.ic")).unwrap();
    let bad = ic.replace("tile_size 256 256 1", "tile_size 512 512 1");
    std::fs::write(d.join("g/L00.ic"), &bad).unwrap();
    let (status, text) = run(CLIPTEX, &["validate", "g/g.ct"], d);
    assert_eq!(status.code(), Some(1), "{text}");
    let at = format!("L00.ic:{}:1: error: `tile_size` does not describe the COG", line_of(&bad, "tile_size"));
    assert!(text.contains(&at), "{at}\n{text}");
    assert!(
        text.contains("expected tile_size 256 256 1 (the COG's TIFF tiles of level 0, cut to the level)"),
        "{text}"
    );
    // Checked too in an .ic without the line: the COG is the .ct's.
    let bare: String = bad.lines().filter(|l| !l.starts_with("#clipmap cog ")).map(|l| format!("{l}\n")).collect();
    std::fs::write(d.join("g/L00.ic"), &bare).unwrap();
    let (status, text) = run(CLIPTEX, &["validate", "g/g.ct"], d);
    assert_eq!(status.code(), Some(1), "{text}");
    let at = format!("L00.ic:{}:1: error: `tile_size` does not describe the COG", line_of(&bare, "tile_size"));
    assert!(text.contains(&at) && text.contains("its clip texture serves"), "{at}\n{text}");
}

#[test]
fn a_ct_naming_a_cog_that_is_not_there_is_refused_naming_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    config_only(&fixture("grey_500x350.tif"), 128, "g", d);
    let ct = d.join("g/g.ct");
    let text = std::fs::read_to_string(&ct).unwrap();
    let text: String = text
        .lines()
        .map(|l| if l.starts_with("#clipmap cog ") { "#clipmap cog moved/away.tif".into() } else { l.to_string() } + "\n")
        .collect();
    std::fs::write(&ct, text).unwrap();
    let anchored = d.join("g/moved/away.tif");
    for (program, args) in
        [(CLIPTEX, vec!["validate", "g/g.ct"]), (env!("CARGO_BIN_EXE_clipmapd"), vec!["g/g.ct", "--shm-dir", "."])]
    {
        let (status, text) = run(program, &args, d);
        assert_eq!(status.code(), Some(1), "{text}");
        assert!(text.contains("g.ct:3:14: error: the COG `moved/away.tif` cannot be served"), "{text}");
        assert!(text.contains(&format!("{}: No such file or directory", anchored.display())), "{text}");
        assert!(text.contains("a relative path is taken from the directory of"), "{text}");
    }
}

#[test]
fn clipprep_config_only_refuses_what_it_cannot_honour_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cog = fixture("rgb_512x384.tif");
    let c = cog.to_str().unwrap();
    let png = fixture("rgb_512x384.0.png");
    let p = png.to_str().unwrap();
    for (args, words) in [
        (
            vec!["--input", c, "--config-only", "--clip", "128", "--pad"],
            "--pad asks for a conversion, and --config-only writes only the configuration",
        ),
        (vec!["--input", c, "--config-only", "--clip", "128", "--zstd", "3"], "--zstd asks for a conversion"),
        (vec!["--input", c, "--config-only", "--clip", "128", "--format", "rgba8"], "--format rgba8: "),
        (vec!["--input", c, "--config-only", "--clip", "128", "--tile", "256"], "--tile 256: "),
        (
            vec!["--input", p, "--config-only", "--clip", "128"],
            "--config-only serves a tiled GeoTIFF or COG as it is, and",
        ),
        (vec!["--input", c, "--config-only", "--clip", "100"], "the clip size is 100, which is not a power of two"),
    ] {
        let (status, text) = run(CLIPPREP, &[&args[..], &["--out", "x"]].concat(), d);
        assert_eq!(status.code(), Some(1), "{args:?}: {text}");
        assert!(text.contains(words), "{args:?}: {words}\n{text}");
        assert!(!d.join("x").exists(), "{args:?}: nothing written");
    }
    let (status, text) =
        run(CLIPPREP, &["--input", c, "--config-only", "--clip", "128", "--format", "rgba8", "--out", "x"], d);
    assert!(!status.success());
    assert!(text.contains("is served as rgb8 texels"), "{text}");
    // Without --config-only a TIFF is still prepared into a pyramid, and --tile and --format
    // are still required then.
    let (status, text) = run(CLIPPREP, &["--input", c, "--clip", "128", "--out", "y"], d);
    assert_eq!(status.code(), Some(1), "{text}");
    assert!(text.contains("--tile"), "{text}");
    // An existing configuration is replaced only with --force.
    config_only(&cog, 128, "z", d);
    let (status, text) = run(CLIPPREP, &["--input", c, "--config-only", "--clip", "128", "--out", "z"], d);
    assert_eq!(status.code(), Some(1), "{text}");
    assert!(text.contains("already holds a clip texture"), "{text}");
}

#[test]
fn a_gdal_written_height_cog_gets_its_height_lines_and_is_served_as_heights_texel_for_texel() {
    use clipmap::height::HeightStorage;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 32-bit float heights with GDAL_NODATA -32768, DEFLATE with predictor 3, written by GDAL.
    let case = &crate::cog_samples::CASES[0];
    crate::cog_samples::write(case, d);
    let cog = d.join(format!("{}.tif", case.name));
    config_only(&cog, 128, "dem", d);
    let text = std::fs::read_to_string(d.join("dem/dem.ct")).unwrap();
    for line in
        ["ext_format GL_FLOAT\n", "virt_size 512 256 1\n", "#clipmap height l32f\n", "#clipmap height_nodata -32768\n"]
    {
        assert!(text.contains(line), "{line}{text}");
    }
    let (status, out) = run(CLIPTEX, &["validate", "dem/dem.ct"], d);
    assert!(status.success(), "{out}");
    // Heights the COG does not have: refused at the height line.
    let wrong = text.replace("#clipmap height_nodata -32768", "#clipmap height_nodata -9999");
    std::fs::write(d.join("dem/wrong.ct"), &wrong).unwrap();
    let (status, out) = run(CLIPTEX, &["validate", "dem/wrong.ct"], d);
    assert_eq!(status.code(), Some(1), "{out}");
    assert!(out.contains("error: `#clipmap height` does not describe the COG"), "{out}");
    assert!(out.contains("nodata -9999") && out.contains("nodata -32768"), "{out}");
    let src = CogSource::open(&cog, 128).unwrap();
    let by_ct = Served::start(&d.join("dem/dem.ct"), 128, "demct", d);
    let by_tif = Served::start(&cog, 128, "demtif", d);
    for c in [&by_ct.client, &by_tif.client] {
        let h = c.heights.unwrap_or_else(|| panic!("not heights\n{}", by_ct.log()));
        assert_eq!((c.format_code, h.storage, h.nodata), (11, HeightStorage::F32, Some(-32768.0)));
    }
    assert_served_as_the_cog(&by_ct, &by_tif, &src, false);
}
