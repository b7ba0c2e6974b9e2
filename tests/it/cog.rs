//! COGs and tiled GeoTIFFs written by GDAL (tests/fixtures/cog, README.md there) served by
//! `CogSource`: level 0 is the image bottom-up, texel for texel; overview levels are GDAL's own
//! decode of the overviews; coarser levels are the box filter of the last one; sparse tiles are
//! missing; refused layouts name the tag; a truncated file gives errors, never wrong texels.

use clipmap::source::cog::LevelOrigin;
use clipmap::source::{CogError, CogSource, SourceError, TileId, TileSource};
use std::path::{Path, PathBuf};

pub(crate) fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CLIPMAP_ROOT")).join("tests/fixtures/cog").join(name)
}

/// Sample `c` of pixel `(x, y)` (y from the top row) of every fixture image (README.md).
fn formula(x: u64, y: u64, c: usize) -> u8 {
    (match c {
        0 => (x + 2 * y) & 255,
        1 => ((x >> 4) * 16 + (y >> 4) * 7) & 255,
        2 => (x ^ y) & 255,
        _ => 255 - ((x + y) >> 2 & 255),
    }) as u8
}

/// Level `k` of `src`, read tile by tile, as whole rows in increasing t; the first error of a
/// tile that cannot be read. Texels of edge tiles outside the level must be zero.
pub(crate) fn level(src: &dyn TileSource, k: u32) -> Result<Vec<u8>, SourceError> {
    let desc = src.desc();
    let l = *desc.level(k);
    let bpt = desc.bytes_per_texel();
    let (w, h) = (l.size[0] as usize, l.size[1] as usize);
    let mut texels = vec![0u8; w * h * bpt];
    let mut buf = vec![0u8; desc.tile_bytes(k)];
    let tiles = l.tiles();
    for tt in 0..tiles[1] {
        for ts in 0..tiles[0] {
            buf.fill(0xa5);
            src.read_tile(TileId::new(k, ts, tt), &mut buf)?;
            let [tw, th] = [l.tile[0] as usize, l.tile[1] as usize];
            for r in 0..th {
                for c in 0..tw {
                    let (s, t) = (ts as usize * tw + c, tt as usize * th + r);
                    let texel = &buf[(r * tw + c) * bpt..][..bpt];
                    if s < w && t < h {
                        texels[(t * w + s) * bpt..][..bpt].copy_from_slice(texel);
                    } else {
                        assert!(
                            texel.iter().all(|&b| b == 0),
                            "level {k} texel ({s}, {t}) outside the level: {texel:?}"
                        );
                    }
                }
            }
        }
    }
    Ok(texels)
}

/// GDAL's decode of IFD `i` of `name` (NAME.i.png) as `bpt`-byte texels, rows in increasing t.
pub(crate) fn gdal_level(name: &str, i: usize, bpt: usize) -> (Vec<u8>, [u64; 2]) {
    let img = image::open(fixture(&format!("{name}.{i}.png"))).unwrap();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let bytes = match bpt {
        1 => img.to_luma8().into_raw(),
        3 => img.to_rgb8().into_raw(),
        _ => img.to_rgba8().into_raw(),
    };
    let row = w * bpt;
    let flipped = (0..h).rev().flat_map(|y| bytes[y * row..(y + 1) * row].to_vec()).collect();
    (flipped, [w as u64, h as u64])
}

/// The 2 x 2 box filter of `clipprep`, written out again: floor((a + b + c + d + 2) / 4).
fn box_halve(src: &[u8], [w, h]: [u64; 2], bpt: usize) -> Vec<u8> {
    let (w2, h2) = ((w / 2).max(1), (h / 2).max(1));
    let mut out = Vec::new();
    for j in 0..h2 {
        for i in 0..w2 {
            for b in 0..bpt {
                let at = |s: u64, t: u64| src[((t.min(h - 1) * w + s.min(w - 1)) as usize) * bpt + b] as u32;
                let sum = at(2 * i, 2 * j) + at(2 * i + 1, 2 * j) + at(2 * i, 2 * j + 1) + at(2 * i + 1, 2 * j + 1);
                out.push(((sum + 2) / 4) as u8);
            }
        }
    }
    out
}

pub(crate) struct Case {
    pub(crate) name: &'static str,
    pub(crate) bpt: usize,
    /// IFDs that are levels 0, 1, ...
    pub(crate) ifd_levels: usize,
}

pub(crate) const CASES: [Case; 6] = [
    Case { name: "rgb_512x384", bpt: 3, ifd_levels: 3 },
    Case { name: "grey_1000x700", bpt: 1, ifd_levels: 3 },
    Case { name: "grey_500x350", bpt: 1, ifd_levels: 3 },
    // Tiles decoded in place (the height is a multiple of 128), the last column partial.
    Case { name: "grey_200x256", bpt: 1, ifd_levels: 2 },
    Case { name: "bigtiff_200x256", bpt: 1, ifd_levels: 2 },
    // Overview 1 is 50 x 38 (gdaladdo rounds up), level 1 is 50 x 37: everything past level 0
    // is built.
    Case { name: "rgba_100x75", bpt: 4, ifd_levels: 1 },
];

#[test]
fn cog_levels_are_the_image_bottom_up_gdal_overviews_and_box_filtered_rest() {
    for case in &CASES {
        // A small clip size reads stack levels in TIFF tiles; a large one reads every level as
        // one tile (assembled from several TIFF tiles).
        for clip in [64, 4096] {
            let src = CogSource::open(&fixture(&format!("{}.tif", case.name)), clip)
                .unwrap_or_else(|e| panic!("{}: {e}", case.name));
            let desc = src.desc().clone();
            assert_eq!(desc.bytes_per_texel(), case.bpt, "{}", case.name);
            let ctx = format!("{} clip {clip}", case.name);
            // Level 0: the formula, image row H - 1 - t, and GDAL's decode.
            let [w, h] = desc.size();
            let l0 = level(&src, 0).unwrap_or_else(|e| panic!("{ctx}: {e}"));
            for t in 0..h {
                for s in 0..w {
                    for c in 0..case.bpt {
                        let got = l0[((t * w + s) as usize) * case.bpt + c];
                        assert_eq!(got, formula(s, h - 1 - t, c), "{ctx}: texel ({s}, {t}) sample {c}");
                    }
                }
            }
            let (gdal0, size0) = gdal_level(case.name, 0, case.bpt);
            assert_eq!((size0, &gdal0), ([w, h], &l0), "{ctx}: level 0 against GDAL");
            let mut prev = l0;
            for k in 1..desc.level_count() as u32 {
                let got = level(&src, k).unwrap_or_else(|e| panic!("{ctx} level {k}: {e}"));
                let size = desc.level(k).size;
                if (k as usize) < case.ifd_levels {
                    assert!(matches!(src.origins()[k as usize], LevelOrigin::Ifd { ifd, .. } if ifd == k as usize));
                    let (gdal, gsize) = gdal_level(case.name, k as usize, case.bpt);
                    assert_eq!(gsize, size, "{ctx}: overview {k} size");
                    assert!(gdal == got, "{ctx}: level {k} differs from GDAL's overview");
                } else {
                    let from = case.ifd_levels as u32 - 1;
                    assert_eq!(src.origins()[k as usize], LevelOrigin::Built { from }, "{ctx}: level {k}");
                    let want = box_halve(&prev, desc.level(k - 1).size, case.bpt);
                    assert!(want == got, "{ctx}: level {k} is not the box filter of level {}", k - 1);
                }
                prev = got;
            }
        }
    }
}

#[test]
fn cog_sparse_tiles_are_missing_and_built_levels_read_them_as_zero() {
    let src = CogSource::open(&fixture("sparse_512x512.tif"), 128).unwrap();
    let desc = src.desc().clone();
    assert_eq!(desc.level(0).tile, [128, 128]);
    let mut buf = vec![0u8; desc.tile_bytes(0)];
    for tt in 0..4 {
        for ts in 0..4 {
            let r = src.read_tile(TileId::new(0, ts, tt), &mut buf);
            // Pixels x >= 256, y < 256 are zero, left out: texture tiles S >= 2, T >= 2.
            if ts >= 2 && tt >= 2 {
                assert!(matches!(r, Err(SourceError::Missing { .. })), "tile ({ts}, {tt}): {r:?}");
                continue;
            }
            r.unwrap_or_else(|e| panic!("tile ({ts}, {tt}): {e}"));
            for (i, &v) in buf.iter().enumerate() {
                let (s, t) = (ts * 128 + i as u64 % 128, tt * 128 + i as u64 / 128);
                let y = 511 - t;
                let want = if s >= 256 && y < 256 { 0 } else { formula(s, y, 0) };
                assert_eq!(v, want, "texel ({s}, {t})");
            }
        }
    }
    // Level 1 is built from level 0, its sparse quarter as zeros.
    assert_eq!(src.origins()[1], LevelOrigin::Built { from: 0 });
    let l1 = level(&src, 1).unwrap();
    assert_eq!(l1[200 * 256 + 200], 0, "top-right quarter");
    assert_ne!(l1[10 * 256 + 10], 0, "bottom-left quarter");
}

#[test]
fn cog_refuses_what_it_does_not_serve_naming_the_tag() {
    let e = CogSource::open(&fixture("i32_64x64.tif"), 64).unwrap_err();
    assert!(matches!(e, CogError::Unsupported { ifd: 0, .. }), "{e}");
    assert!(
        e.to_string().contains(
            "IFD 0: BitsPerSample (258) / SampleFormat (339) is [32] bits, sample format [2]: supported: the same for every sample"
        ),
        "{e}"
    );
    let e = CogSource::open(&fixture("strips_64x64.tif"), 64).unwrap_err();
    assert!(
        e.to_string()
            .contains("IFD 0: TileWidth (322) is absent: the image is stored in strips: supported: tiled images"),
        "{e}"
    );
    let e = CogSource::open(&fixture("README.md"), 64).unwrap_err();
    assert!(matches!(e, CogError::NotTiff { .. }), "{e}");
    assert!(e.to_string().contains("not a TIFF: it starts with [23, 20, 43, 4f]"), "{e}");
}

#[test]
fn cog_16_bit_grey_is_served_as_l16_sample_for_sample() {
    let src = CogSource::open(&fixture("u16_64x64.tif"), 64).unwrap();
    assert_eq!(src.desc().format(), clipmap::texel::TexelFormat::L16);
    assert!(src.heights().is_none(), "16-bit unsigned samples are grey, not heights");
    let l0 = level(&src, 0).unwrap();
    for t in 0..64u64 {
        for s in 0..64u64 {
            let i = ((t * 64 + s) * 2) as usize;
            let want = formula(s, 63 - t, 0) as u16;
            assert_eq!(u16::from_le_bytes([l0[i], l0[i + 1]]), want, "texel ({s}, {t})");
        }
    }
}

#[test]
fn cog_truncated_files_give_errors_never_wrong_texels() {
    let name = "rgb_512x384";
    let full = std::fs::read(fixture(&format!("{name}.tif"))).unwrap();
    let reference = CogSource::open(&fixture(&format!("{name}.tif")), 64).unwrap();
    let want: Vec<Vec<u8>> =
        (0..reference.desc().level_count() as u32).map(|k| level(&reference, k).unwrap()).collect();
    let dir = tempfile::tempdir().unwrap();
    let len = full.len();
    let mut opened = 0;
    let mut failed_reads = 0;
    for cut in [0, 3, 8, 100, 200, 300, 500, 800, 1000, 4000, len / 4, len / 2, 3 * len / 4, len - 1] {
        let path = dir.path().join(format!("cut{cut}.tif"));
        std::fs::write(&path, &full[..cut]).unwrap();
        let src = match CogSource::open(&path, 64) {
            Ok(s) => s,
            Err(e) => {
                let text = e.to_string();
                assert!(text.contains(&path.display().to_string()), "{text}");
                continue;
            }
        };
        opened += 1;
        let desc = src.desc().clone();
        for k in 0..desc.level_count() as u32 {
            let l = *desc.level(k);
            let mut buf = vec![0u8; desc.tile_bytes(k)];
            let whole = &want[k as usize];
            let bpt = desc.bytes_per_texel();
            for tt in 0..l.tiles()[1] {
                for ts in 0..l.tiles()[0] {
                    match src.read_tile(TileId::new(k, ts, tt), &mut buf) {
                        Err(e) => {
                            failed_reads += 1;
                            assert!(
                                matches!(e, SourceError::Short { .. } | SourceError::Chunk { .. }),
                                "cut {cut}: {e}"
                            );
                        }
                        Ok(()) => {
                            // Every delivered texel is the full file's.
                            let [tw, th] = [l.tile[0] as usize, l.tile[1] as usize];
                            for r in 0..th.min(l.size[1] as usize - tt as usize * th) {
                                let t = tt as usize * th + r;
                                let cols = tw.min(l.size[0] as usize - ts as usize * tw);
                                let at = (t * l.size[0] as usize + ts as usize * tw) * bpt;
                                let got = &buf[r * tw * bpt..][..cols * bpt];
                                assert!(got == &whole[at..at + cols * bpt], "cut {cut}: level {k} tile ({ts}, {tt})");
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(opened > 0 && failed_reads > 0, "some cuts open, and their lost tiles fail: {opened} {failed_reads}");
}

#[test]
fn cliptex_info_shows_where_each_level_of_a_cog_comes_from() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["info"])
        .arg(fixture("rgba_100x75.tif"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{out:?}");
    assert!(text.contains("100 x 75 texels, rgba8, clip size 1024"), "{text}");
    assert!(text.contains("0      100 x 75      100 x 75      IFD 0, 32 x 32 tiles, uncompressed"), "{text}");
    assert!(text.contains("1      50 x 37       50 x 37       built at open from level 0 (2 x 2 box)"), "{text}");
    assert!(text.contains("IFD 1 (overview 1) is [50, 38] texels, expected [50, 37]"), "{text}");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["info", "--json"])
        .arg(fixture("grey_1000x700.tif"))
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["levels"][2]["origin"]["ifd"]["compression"], "deflate", "{v}");
    assert_eq!(v["levels"][3]["origin"]["built"]["from"], 2, "{v}");
}

fn cliptex(args: &[&std::ffi::OsStr]) -> (std::process::ExitStatus, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex")).args(args).output().unwrap();
    (out.status, String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn cliptex_check_reads_every_tile_of_a_cog_and_names_what_is_wrong() {
    // Whole and served: every level present, exit 0.
    let f = fixture("rgb_512x384.tif");
    let (status, out, err) = cliptex(&["check".as_ref(), "--json".as_ref(), f.as_os_str()]);
    assert!(status.success(), "{out}{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["servable"], true, "{v}");
    assert_eq!(v["totals"]["present"], v["totals"]["tiles"], "{v}");
    assert_eq!(v["levels"][0]["kind"], "ifd", "{v}");
    let last = v["levels"].as_array().unwrap().last().unwrap().clone();
    assert_eq!(last["kind"], "built", "{v}");
    // Sparse tiles: missing, said to be sparse, exit 1.
    let f = fixture("sparse_512x512.tif");
    let (status, out, err) = cliptex(&["check".as_ref(), f.as_os_str()]);
    assert_eq!(status.code(), Some(1), "{out}{err}");
    assert!(out.contains("level 0 tile (0, 0): Missing:") && out.contains("sparse: the file holds no bytes"), "{out}");
    assert!(out.contains("some tiles cannot be served"), "{out}");
    // A file cut in the middle of its tiles: each unreadable tile named with the reader's words.
    let full = std::fs::read(fixture("rgb_512x384.tif")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cut = dir.path().join("cut.tif");
    std::fs::write(&cut, &full[..full.len() / 2]).unwrap();
    let (status, out, err) = cliptex(&["check".as_ref(), "--json".as_ref(), cut.as_os_str()]);
    assert_eq!(status.code(), Some(1), "{out}{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["servable"], false, "{v}");
    let p = &v["problems"][0];
    assert!(p["problem"] == "short" || p["problem"] == "corrupt", "{v}");
    assert!(p["detail"].as_str().is_some_and(|d| !d.is_empty()), "{v}");
}

#[test]
fn cliptex_dump_of_a_cog_level_is_gdals_own_decode() {
    let dir = tempfile::tempdir().unwrap();
    for (name, k) in [("rgb_512x384", 0), ("rgb_512x384", 1), ("grey_500x350", 0)] {
        let png = dir.path().join(format!("{name}.{k}.png"));
        let f = fixture(&format!("{name}.tif"));
        let level = k.to_string();
        let (status, out, err) = cliptex(&[
            "dump".as_ref(),
            f.as_os_str(),
            "--level".as_ref(),
            level.as_ref(),
            "--out".as_ref(),
            png.as_os_str(),
        ]);
        assert!(status.success(), "{name} level {k}: {out}{err}");
        let ours = image::open(&png).unwrap().to_rgb8();
        let gdal = image::open(fixture(&format!("{name}.{k}.png"))).unwrap().to_rgb8();
        assert_eq!(ours.dimensions(), gdal.dimensions(), "{name} level {k}");
        let differ = ours.pixels().zip(gdal.pixels()).filter(|(a, b)| a != b).count();
        assert_eq!(differ, 0, "{name} level {k}: pixels that differ from GDAL's decode");
    }
}

fn run<S: AsRef<std::ffi::OsStr>>(program: &str, args: &[S], dir: &Path) -> (std::process::ExitStatus, String) {
    let out = std::process::Command::new(program).args(args).current_dir(dir).output().unwrap();
    (out.status, format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr)))
}

fn pixels(path: &Path) -> image::RgbaImage {
    image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgba8()
}

#[test]
fn clipprep_cog_writes_a_cog_gdal_calls_one_and_every_reader_decodes_as_the_pyramid() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let prep = env!("CARGO_BIN_EXE_clipprep");
    let cliptex = env!("CARGO_BIN_EXE_cliptex");
    for (format, compression) in [("rgb8", "deflate"), ("rgba8", "zstd"), ("l8", "none")] {
        let out = format!("pyr_{format}");
        let cog = format!("{format}.tif");
        let args = [
            "--source",
            "hash",
            "--size",
            "1024x512",
            "--tile",
            "128",
            "--clip",
            "256",
            "--format",
            format,
            "--out",
            &out,
            "--cog",
            &cog,
            "--cog-compression",
            compression,
        ];
        let (status, text) = run(prep, &args, d);
        assert!(status.success(), "{format}: {text}");
        assert!(text.contains(&format!("wrote {cog}: a COG of 4 images (43 tiles")), "{format}: {text}");
        // GDAL calls it a COG, with the overviews halved down to one tile.
        let (status, info) = run("gdalinfo", &[&cog], d);
        assert!(status.success(), "{info}");
        assert!(info.contains("LAYOUT=COG"), "{format}: {info}");
        assert!(info.contains("Overviews: 512x256, 256x128, 128x64"), "{format}: {info}");
        // Level 0 and each overview: GDAL's decode, our COG source's and the pyramid's are one picture.
        let ct = format!("{out}/{out}.ct");
        for k in 0..4u32 {
            let level = k.to_string();
            let (gdal, ours, pyramid) = (format!("g{k}.png"), format!("c{k}.png"), format!("p{k}.png"));
            let mut args = vec!["-q".to_string(), "-of".into(), "PNG".into()];
            if k > 0 {
                args.extend(["-ovr".to_string(), (k - 1).to_string()]);
            }
            args.extend([cog.clone(), gdal.clone()]);
            let (status, text) = run("gdal_translate", &args, d);
            assert!(status.success(), "{text}");
            for (file, png) in [(&cog, &ours), (&ct, &pyramid)] {
                let (status, text) = run(cliptex, &["dump", file, "--level", &level, "--out", png], d);
                assert!(status.success(), "{text}");
            }
            let (g, c, p) = (pixels(&d.join(&gdal)), pixels(&d.join(&ours)), pixels(&d.join(&pyramid)));
            assert_eq!(g.dimensions(), p.dimensions(), "{format} level {k}");
            assert!(g == p, "{format} level {k}: GDAL's decode of the COG differs from the pyramid");
            assert!(c == p, "{format} level {k}: our decode of the COG differs from the pyramid");
        }
    }
    // Refused before any work: a format a COG is not written from.
    let args = [
        "--source", "hash", "--size", "256", "--tile", "64", "--clip", "128", "--format", "rgb565", "--out", "x",
        "--cog", "x.tif",
    ];
    let (status, text) = run(prep, &args, d);
    assert_eq!(status.code(), Some(1), "{text}");
    assert!(text.contains("--cog x.tif: texel format rgb565: a COG is written from l8, rgb8 or rgba8"), "{text}");
    assert!(!d.join("x").exists(), "nothing is prepared when --cog is refused");
}

#[test]
fn cog_tiles_whose_gdal_leader_or_trailer_disagrees_are_refused_naming_it() {
    let full = std::fs::read(fixture("grey_1000x700.tif")).unwrap();
    // IFD 0's first tile (the image's top-left) is 1298 bytes at byte 4671, GDAL's leader (its
    // byte count, 4 bytes little-endian) before it and its last 4 bytes again after it.
    let (at, len) = (4671usize, 1298usize);
    assert_eq!(full[at - 4..at], (len as u32).to_le_bytes(), "the fixture's layout");
    assert_eq!(full[at + len..at + len + 4], full[at + len - 4..at + len], "the fixture's layout");
    let dir = tempfile::tempdir().unwrap();
    for (what, byte, name) in [("leader", at - 4, "BLOCK_LEADER"), ("trailer", at + len + 1, "BLOCK_TRAILER")] {
        let mut bytes = full.clone();
        bytes[byte] ^= 0x01;
        let path = dir.path().join(format!("{what}.tif"));
        std::fs::write(&path, &bytes).unwrap();
        let src = CogSource::open(&path, 64).unwrap();
        let desc = src.desc().clone();
        let l = *desc.level(0);
        let mut buf = vec![0u8; desc.tile_bytes(0)];
        let mut refused = Vec::new();
        for tt in 0..l.tiles()[1] {
            for ts in 0..l.tiles()[0] {
                if let Err(e) = src.read_tile(TileId::new(0, ts, tt), &mut buf) {
                    assert!(matches!(e, SourceError::Chunk { .. }) && e.to_string().contains(name), "{what}: {e}");
                    refused.push((ts, tt));
                }
            }
        }
        // Only texture tiles that hold texels of the top-left TIFF tile (t counted from the
        // bottom: image row 699 - t).
        let LevelOrigin::Ifd { tile: [tw, th], .. } = src.origins()[0] else { panic!("IFD 0") };
        let [w, h] = l.tile;
        let touches = |s: u64, t: u64| s * w < tw && 699 - (t * h + h - 1).min(699) < th;
        assert!(!refused.is_empty() && refused.iter().all(|&(s, t)| touches(s, t)), "{what}: {refused:?}");
    }
}
