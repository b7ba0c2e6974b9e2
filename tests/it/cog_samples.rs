//! COGs of 16-bit and 32-bit float samples written by GDAL in the test (`gdal_translate -of
//! COG` and the GTiff driver through GDAL's Python binding; `.ci/run` installs `gdal-bin` and
//! `python3-gdal`): 16-bit unsigned colour, 16-bit signed and 32-bit float heights with
//! GDAL_NODATA, predictors 2 and 3, a big-endian file. Level 0 equals the formula texel for
//! texel; each overview equals GDAL's own decode of it; the levels built past the overviews are
//! the `mean` rule (heights, nodata left out) or the 16-bit box filter (colour).

use clipmap::height::HeightStorage;
use clipmap::source::{CogSource, TileSource};
use std::path::Path;
use std::process::Command;

/// The Python side: writes `NAME.tif` from the formula with the options given, then GDAL's
/// decode of every IFD as `NAME.N.raw` (samples interleaved, little-endian, rows top-down).
const WRITE: &str = r#"
import struct, sys
from osgeo import gdal
gdal.UseExceptions()
name, kind, w, h, bands, driver = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), sys.argv[6]
opts = sys.argv[7:]
code = {"u16": "H", "i16": "h", "f32": "f"}[kind]
gtype = {"u16": gdal.GDT_UInt16, "i16": gdal.GDT_Int16, "f32": gdal.GDT_Float32}[kind]
def value(x, y, c):
    if kind == "u16":
        return (x * 257 + y * 131 + c * 20000) & 0xFFFF
    if (x * 7 + y * 3) % 16 == 0:
        return -32768
    if kind == "i16":
        return (x * 97 + y * 61) % 60001 - 30000
    # -11000 .. 8900 m in 2^-10 m steps: exact in a 32-bit float.
    return -11000 + ((x * 7919 + y * 104729) % (19900 * 1024)) / 1024.0
mem = gdal.GetDriverByName("MEM").Create("", w, h, bands, gtype)
for b in range(bands):
    band = mem.GetRasterBand(b + 1)
    band.WriteRaster(0, 0, w, h, struct.pack("<%d%s" % (w * h, code), *[value(x, y, b) for y in range(h) for x in range(w)]))
    if kind != "u16":
        band.SetNoDataValue(-32768)
    if bands >= 3:
        band.SetColorInterpretation([gdal.GCI_RedBand, gdal.GCI_GreenBand, gdal.GCI_BlueBand, gdal.GCI_AlphaBand][b])
gdal.Translate(name + ".tif", mem, format=driver, creationOptions=opts)
ds = gdal.Open(name + ".tif")
n = 1 + ds.GetRasterBand(1).GetOverviewCount()
size = struct.calcsize(code)
for i in range(n):
    bands_ = [ds.GetRasterBand(b + 1) if i == 0 else ds.GetRasterBand(b + 1).GetOverview(i - 1) for b in range(bands)]
    bw, bh = bands_[0].XSize, bands_[0].YSize
    planes = [band.ReadRaster(0, 0, bw, bh) for band in bands_]
    out = bytearray(bw * bh * bands * size)
    for b, p in enumerate(planes):
        for k in range(bw * bh):
            out[(k * bands + b) * size:(k * bands + b + 1) * size] = p[k * size:(k + 1) * size]
    open("%s.%d.raw" % (name, i), "wb").write(out)
    print(bw, bh)
"#;

pub(crate) struct Case {
    pub(crate) name: &'static str,
    kind: &'static str,
    pub(crate) size: [u64; 2],
    bands: usize,
    driver: &'static str,
    options: &'static [&'static str],
    /// The predictor the file must use (cliptex info's words).
    predictor: &'static str,
}

pub(crate) const CASES: [Case; 5] = [
    Case {
        name: "f32_deflate_fp",
        kind: "f32",
        size: [300, 200],
        bands: 1,
        driver: "COG",
        options: &[
            "COMPRESS=DEFLATE",
            "PREDICTOR=FLOATING_POINT",
            "BLOCKSIZE=128",
            "OVERVIEWS=AUTO",
            "RESAMPLING=AVERAGE",
        ],
        predictor: ", predictor 3 (floating point)",
    },
    Case {
        name: "f32_zstd_pred2",
        kind: "f32",
        size: [130, 90],
        bands: 1,
        driver: "COG",
        options: &["COMPRESS=ZSTD", "PREDICTOR=STANDARD", "BLOCKSIZE=64", "OVERVIEWS=NONE"],
        predictor: ", predictor 2",
    },
    Case {
        name: "i16_lzw_pred2",
        kind: "i16",
        size: [300, 200],
        bands: 1,
        driver: "COG",
        options: &["COMPRESS=LZW", "PREDICTOR=YES", "BLOCKSIZE=128", "OVERVIEWS=AUTO", "RESAMPLING=NEAREST"],
        predictor: ", predictor 2",
    },
    Case {
        name: "u16_rgb_zstd_pred2",
        kind: "u16",
        size: [256, 192],
        bands: 3,
        driver: "COG",
        options: &["COMPRESS=ZSTD", "PREDICTOR=YES", "BLOCKSIZE=64", "OVERVIEWS=AUTO", "RESAMPLING=AVERAGE"],
        predictor: ", predictor 2",
    },
    Case {
        name: "f32_big_endian",
        kind: "f32",
        size: [100, 80],
        bands: 1,
        driver: "GTiff",
        // Predictor 2, not 3: GDAL 3.6 does not read back its own big-endian files with the
        // floating-point predictor (every value comes back wrong), so they are no reference.
        options: &["TILED=YES", "BLOCKXSIZE=32", "BLOCKYSIZE=32", "COMPRESS=DEFLATE", "PREDICTOR=2", "ENDIANNESS=BIG"],
        predictor: ", predictor 2",
    },
];

/// Writes the case's file with GDAL in `dir`; returns the size of every IFD GDAL decoded.
pub(crate) fn write(case: &Case, dir: &Path) -> Vec<[u64; 2]> {
    let mut args = vec![
        "-".to_string(),
        case.name.into(),
        case.kind.into(),
        case.size[0].to_string(),
        case.size[1].to_string(),
        case.bands.to_string(),
        case.driver.into(),
    ];
    args.extend(case.options.iter().map(|s| s.to_string()));
    crate::common::gdal::write_with(WRITE, &args, dir, case.name)
}

/// Sample `c` of pixel (x, y) (y from the top row), as the Python formula writes it, as bytes.
fn formula(kind: &str, x: u64, y: u64, c: u64) -> Vec<u8> {
    if kind == "u16" {
        return (((x * 257 + y * 131 + c * 20000) & 0xFFFF) as u16).to_le_bytes().to_vec();
    }
    let nodata = (x * 7 + y * 3) % 16 == 0;
    match kind {
        "i16" => (if nodata { -32768 } else { ((x * 97 + y * 61) % 60001) as i16 as i32 - 30000 } as i16)
            .to_le_bytes()
            .to_vec(),
        _ => {
            let v =
                if nodata { -32768.0 } else { -11000.0 + ((x * 7919 + y * 104729) % (19900 * 1024)) as f64 / 1024.0 };
            (v as f32).to_le_bytes().to_vec()
        }
    }
}

/// GDAL's decode of IFD `i`, rows turned to increasing t.
fn gdal_ifd(dir: &Path, case: &Case, i: usize, size: [u64; 2], bpt: usize) -> Vec<u8> {
    let raw = std::fs::read(dir.join(format!("{}.{i}.raw", case.name))).unwrap();
    let row = size[0] as usize * bpt;
    assert_eq!(raw.len(), row * size[1] as usize, "{} IFD {i}", case.name);
    raw.chunks_exact(row).rev().flatten().copied().collect()
}

/// The 16-bit box filter of `clipprep`, written out again: floor((a + b + c + d + 2) / 4) per
/// sample, edges clamped.
fn box_halve_u16(src: &[u8], [w, h]: [u64; 2], samples: usize) -> Vec<u8> {
    let mut out = Vec::new();
    for j in 0..(h / 2).max(1) {
        for i in 0..(w / 2).max(1) {
            for c in 0..samples {
                let at = |s: u64, t: u64| {
                    let p = ((t.min(h - 1) * w + s.min(w - 1)) as usize * samples + c) * 2;
                    u16::from_le_bytes([src[p], src[p + 1]]) as u32
                };
                let v =
                    (at(2 * i, 2 * j) + at(2 * i + 1, 2 * j) + at(2 * i, 2 * j + 1) + at(2 * i + 1, 2 * j + 1) + 2) / 4;
                out.extend_from_slice(&(v as u16).to_le_bytes());
            }
        }
    }
    out
}

#[test]
fn cogs_of_16_bit_and_float_samples_are_their_formula_gdals_overviews_and_the_level_rule() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for case in &CASES {
        let ifds = write(case, d);
        let path = d.join(format!("{}.tif", case.name));
        // A small clip size reads the stack levels in TIFF tiles, a large one every level whole.
        for clip in [64, 512] {
            let ctx = format!("{} (clip {clip})", case.name);
            let src = CogSource::open(&path, clip).unwrap_or_else(|e| panic!("{ctx}: {e}"));
            let bpt = src.desc().bytes_per_texel();
            let sample = if case.kind == "f32" { 4 } else { 2 };
            assert_eq!(bpt, case.bands * sample, "{ctx}");
            let info = src.info().human();
            assert!(info.contains(case.predictor), "{ctx}: {info}");
            // Heights say so, with GDAL_NODATA as their nodata; colours do not.
            match (case.kind, src.heights()) {
                ("u16", None) => {}
                ("i16", Some(p)) => {
                    assert_eq!((p.format.storage(), p.format.nodata()), (HeightStorage::I16, Some(-32768.0)), "{ctx}")
                }
                ("f32", Some(p)) => {
                    assert_eq!((p.format.storage(), p.format.nodata()), (HeightStorage::F32, Some(-32768.0)), "{ctx}")
                }
                (k, h) => panic!("{ctx}: {k} samples served with heights {h:?}"),
            }
            let [w, h] = case.size;
            let mut want = Vec::new();
            for t in 0..h {
                for s in 0..w {
                    for c in 0..case.bands as u64 {
                        want.extend(formula(case.kind, s, h - 1 - t, c));
                    }
                }
            }
            let n = src.desc().level_count();
            let mut size = [w, h];
            for k in 0..n as u32 {
                let got = super::cog::level(&src, k).unwrap_or_else(|e| panic!("{ctx}: level {k}: {e}"));
                if k > 0 {
                    want = if (k as usize) < ifds.len() {
                        assert_eq!(ifds[k as usize], src.desc().level(k).size, "{ctx}: overview {k}'s size");
                        gdal_ifd(d, case, k as usize, ifds[k as usize], bpt)
                    } else if let Some(plan) = src.heights() {
                        let f = plan.format;
                        let stored: Vec<f64> = want.chunks_exact(bpt).map(|b| f.read(b)).collect();
                        let next = f.reduce_level(plan.levels, &stored, size[0] as usize, size[1] as usize).unwrap();
                        let mut out = vec![0u8; next.len() * bpt];
                        for (v, o) in next.iter().zip(out.chunks_exact_mut(bpt)) {
                            f.write(*v, o);
                        }
                        out
                    } else {
                        box_halve_u16(&want, size, case.bands)
                    };
                    size = src.desc().level(k).size;
                }
                assert_eq!(got.len(), want.len(), "{ctx}: level {k}");
                let differ = got.chunks_exact(bpt).zip(want.chunks_exact(bpt)).filter(|(a, b)| a != b).count();
                assert_eq!(differ, 0, "{ctx}: level {k}: {differ} texels differ");
            }
        }
    }
}

#[test]
fn a_cog_whose_nodata_is_not_a_value_of_its_samples_is_refused_naming_the_tag() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let case = Case {
        name: "i16_bad_nodata",
        kind: "i16",
        size: [64, 64],
        bands: 1,
        driver: "COG",
        options: &["BLOCKSIZE=32", "OVERVIEWS=NONE"],
        predictor: "",
    };
    write(&case, d);
    // GDAL writes the nodata tag as the text it was given: make it one an i16 cannot hold.
    let out = Command::new("gdal_edit.py").args(["-a_nodata", "40000.5", "i16_bad_nodata.tif"]).current_dir(d).output();
    let Ok(out) = out else { panic!("gdal_edit.py (gdal-bin's Python scripts) is not installed") };
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let e = CogSource::open(&d.join("i16_bad_nodata.tif"), 64).unwrap_err().to_string();
    assert!(e.contains("GDAL_NODATA (42113)") && e.contains("40000.5"), "{e}");
}

#[test]
fn clipmapd_serves_a_float_dem_cog_as_heights_texel_for_texel() {
    use std::time::{Duration, Instant};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let case = &CASES[0];
    write(case, d);
    let served = crate::common::gdal::Served::start(&d.join(format!("{}.tif", case.name)), 128, "dem", d);
    let c = &served.client;
    let log = || served.log();
    let t = Instant::now();
    // The header says l32f heights with the file's GDAL_NODATA.
    let h = c.heights.unwrap_or_else(|| panic!("not heights\n{}", log()));
    assert_eq!((c.format_code, h.storage, h.nodata), (11, HeightStorage::F32, Some(-32768.0)));
    let valid = loop {
        if let Some(st) = c.level_state(0) {
            let [s0, t0, s1, t1] = st.valid;
            if st.enabled && s1 > s0 && t1 > t0 {
                break st.valid;
            }
        }
        assert!(t.elapsed() < Duration::from_secs(30), "level 0 never became valid\n{}", log());
        std::thread::sleep(Duration::from_millis(5));
    };
    let [s0, t0, s1, t1] = valid;
    let (w, hh) = ((s1 - s0) as u64, (t1 - t0) as u64);
    let mut buf = vec![0u8; (w * hh * 4) as usize];
    c.read_region(0, s0, t0, w, hh, &mut buf).expect("the valid region reads");
    for (i, texel) in buf.chunks_exact(4).enumerate() {
        let (s, t) = (s0 as u64 + i as u64 % w, t0 as u64 + i as u64 / w);
        assert_eq!(texel, &formula("f32", s, case.size[1] - 1 - t, 0)[..], "texel ({s}, {t})");
    }
}

/// The Python side of the JPEG test: a smooth 8-bit image of `bands` bands (grey or RGB) as
/// `NAME.tif` with the options given, and GDAL's decode of every IFD as `NAME.N.raw`.
const WRITE_JPEG: &str = r#"
import math, sys
from osgeo import gdal
gdal.UseExceptions()
name, w, h, bands = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
mem = gdal.GetDriverByName("MEM").Create("", w, h, bands, gdal.GDT_Byte)
for b in range(bands):
    band = mem.GetRasterBand(b + 1)
    band.WriteRaster(0, 0, w, h, bytes(int(127.5 + 120 * math.sin(x / 17.0 + b) * math.cos(y / 23.0 - b)) for y in range(h) for x in range(w)))
    if bands == 3:
        band.SetColorInterpretation([gdal.GCI_RedBand, gdal.GCI_GreenBand, gdal.GCI_BlueBand][b])
gdal.Translate(name + ".tif", mem, format="COG", creationOptions=sys.argv[5:])
ds = gdal.Open(name + ".tif")
for i in range(1 + ds.GetRasterBand(1).GetOverviewCount()):
    o = ds if i == 0 else None
    bw, bh = (ds.RasterXSize, ds.RasterYSize) if i == 0 else (ds.GetRasterBand(1).GetOverview(i - 1).XSize, ds.GetRasterBand(1).GetOverview(i - 1).YSize)
    planes = [(ds.GetRasterBand(b + 1) if i == 0 else ds.GetRasterBand(b + 1).GetOverview(i - 1)).ReadRaster(0, 0, bw, bh) for b in range(bands)]
    out = bytearray(bw * bh * bands)
    for b, p in enumerate(planes):
        out[b::bands] = p
    open("%s.%d.raw" % (name, i), "wb").write(out)
    print(bw, bh, ds.GetMetadataItem("COMPRESSION", "IMAGE_STRUCTURE"))
"#;

#[test]
fn jpeg_cogs_grey_and_ycbcr_decode_as_gdal_does_within_the_decoders_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (name, bands, extra) in [("jpeg_ycbcr", 3usize, "QUALITY=90"), ("jpeg_grey", 1, "QUALITY=75")] {
        let args =
            ["-", name, "300", "200", &bands.to_string(), "COMPRESS=JPEG", extra, "BLOCKSIZE=128", "OVERVIEWS=AUTO"];
        let mut child = Command::new(crate::common::gdal::python())
            .args(args)
            .current_dir(d)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        use std::io::Write;
        child.stdin.take().unwrap().write_all(WRITE_JPEG.as_bytes()).unwrap();
        let out = child.wait_with_output().unwrap();
        assert!(out.status.success(), "{name}: GDAL failed: {}", String::from_utf8_lossy(&out.stderr));
        let stdout = String::from_utf8(out.stdout).unwrap();
        let ifds: Vec<[u64; 2]> = stdout
            .lines()
            .map(|l| {
                let v: Vec<&str> = l.splitn(3, ' ').collect();
                assert!(v[2].contains("JPEG"), "{name}: {l}");
                [v[0].parse().unwrap(), v[1].parse().unwrap()]
            })
            .collect();
        let src = CogSource::open(&d.join(format!("{name}.tif")), 64).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(src.desc().bytes_per_texel(), bands, "{name}");
        assert!(src.info().human().contains("JPEG"), "{name}: {}", src.info().human());
        for (k, &size) in ifds.iter().enumerate() {
            let raw = std::fs::read(d.join(format!("{name}.{k}.raw"))).unwrap();
            let row = size[0] as usize * bands;
            let gdal: Vec<u8> = raw.chunks_exact(row).rev().flatten().copied().collect();
            let ours = super::cog::level(&src, k as u32).unwrap_or_else(|e| panic!("{name} level {k}: {e}"));
            assert_eq!(ours.len(), gdal.len(), "{name} level {k}");
            // Two decoders of one JPEG stream agree to within a few levels, not exactly: their
            // inverse DCTs round differently (grey: at most 1 apart), and YCbCr adds the
            // chroma upsampling and colour conversion (at most 4 apart, 99.8 % of samples
            // within 2; measured with GDAL 3.6's libjpeg-turbo: 99.93 to 99.96 % within 2, max 4).
            let diff: Vec<u8> = ours.iter().zip(&gdal).map(|(a, b)| a.abs_diff(*b)).collect();
            let max = diff.iter().copied().max().unwrap_or(0);
            let within2 = diff.iter().filter(|&&e| e <= 2).count() as f64 / diff.len() as f64;
            let (max_ok, share_ok) = if bands == 1 { (1, 1.0) } else { (4, 0.998) };
            assert!(
                max <= max_ok && within2 >= share_ok,
                "{name} level {k}: max difference {max} (at most {max_ok}), {within2:.4} within 2 (at least {share_ok})"
            );
        }
        // The levels past the overviews are built and read.
        for k in ifds.len()..src.desc().level_count() {
            super::cog::level(&src, k as u32).unwrap_or_else(|e| panic!("{name} level {k}: {e}"));
        }
    }
}
