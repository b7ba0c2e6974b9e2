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
    let nodata = (x * 7 + y * 3).is_multiple_of(16);
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

/// The Python side of the JPEG tests: `NAME W H BANDS DRIVER OVERVIEWS OPTIONS...` writes a
/// smooth 8-bit image of `BANDS` bands (grey, RGB, or RGB and an alpha that is 0 in stripes) as
/// `NAME.tif` with the driver (`COG`, or `GTiff` then `OVERVIEWS` = `1`: internal overviews of 2
/// and 4 by `BuildOverviews`) and options given, and GDAL's decode of every IFD as `NAME.N.raw`
/// (the bands GDAL reads, interleaved) and `NAME.N.mask` (GDAL's read of band 1's mask band).
const WRITE_JPEG: &str = r#"
import math, sys
from osgeo import gdal
gdal.UseExceptions()
name, w, h, bands, driver, overviews = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5], sys.argv[6] == "1"
def value(x, y, b):
    if b == 3:
        return 0 if (x // 9 + y // 7) % 3 == 0 else 255
    return int(127.5 + 120 * math.sin(x / 17.0 + b) * math.cos(y / 23.0 - b))
mem = gdal.GetDriverByName("MEM").Create("", w, h, bands, gdal.GDT_Byte)
for b in range(bands):
    band = mem.GetRasterBand(b + 1)
    band.WriteRaster(0, 0, w, h, bytes(value(x, y, b) for y in range(h) for x in range(w)))
    if bands >= 3:
        band.SetColorInterpretation([gdal.GCI_RedBand, gdal.GCI_GreenBand, gdal.GCI_BlueBand, gdal.GCI_AlphaBand][b])
gdal.Translate(name + ".tif", mem, format=driver, creationOptions=sys.argv[7:])
if overviews:
    ds = gdal.Open(name + ".tif", gdal.GA_Update)
    ds.BuildOverviews("AVERAGE", [2, 4])
    ds = None
ds = gdal.Open(name + ".tif")
for i in range(1 + ds.GetRasterBand(1).GetOverviewCount()):
    bands_ = [ds.GetRasterBand(b + 1) if i == 0 else ds.GetRasterBand(b + 1).GetOverview(i - 1) for b in range(ds.RasterCount)]
    bw, bh = bands_[0].XSize, bands_[0].YSize
    out = bytearray(bw * bh * len(bands_))
    for b, band in enumerate(bands_):
        out[b::len(bands_)] = band.ReadRaster(0, 0, bw, bh)
    open("%s.%d.raw" % (name, i), "wb").write(out)
    open("%s.%d.mask" % (name, i), "wb").write(bands_[0].GetMaskBand().ReadRaster(0, 0, bw, bh))
    print(bw, bh, ds.RasterCount, ds.GetMetadataItem("COMPRESSION", "IMAGE_STRUCTURE"))
"#;

/// A JPEG-compressed file of the JPEG tests.
struct JpegCase {
    name: &'static str,
    /// Bands written.
    bands: usize,
    driver: &'static str,
    /// Internal overviews added by `BuildOverviews` (the GTiff driver).
    overviews: bool,
    options: &'static [&'static str],
    /// The TIFF's PhotometricInterpretation (262), as GDAL writes it.
    photometric: u64,
    /// Bytes of a texel served.
    served: usize,
    /// The served alpha is GDAL's mask band (the COG driver turns an alpha band into a mask).
    alpha_from_mask: bool,
    /// The most a sample may differ from GDAL's decode, and the share of samples at most 2 apart.
    tolerance: (u8, f64),
}

/// Two decoders of one JPEG stream agree to within a few levels, not exactly: their inverse DCTs
/// round differently (components taken as stored, grey, RGB or RGBA: at most 1 apart), and
/// YCbCr adds the chroma upsampling and colour conversion (at most 4 apart, 99.8 % of samples
/// within 2; measured with GDAL 3.6's libjpeg-turbo: 99.85 to 99.96 % within 2, max 4).
const JPEG_CASES: [JpegCase; 5] = [
    // GDAL's COG driver writes 3 bands as YCbCr (PhotometricInterpretation 6).
    JpegCase {
        name: "jpeg_ycbcr",
        bands: 3,
        driver: "COG",
        overviews: false,
        options: &["COMPRESS=JPEG", "QUALITY=90", "BLOCKSIZE=128", "OVERVIEWS=AUTO"],
        photometric: 6,
        served: 3,
        alpha_from_mask: false,
        tolerance: (4, 0.998),
    },
    JpegCase {
        name: "jpeg_grey",
        bands: 1,
        driver: "COG",
        overviews: false,
        options: &["COMPRESS=JPEG", "QUALITY=75", "BLOCKSIZE=128", "OVERVIEWS=AUTO"],
        photometric: 1,
        served: 1,
        alpha_from_mask: false,
        tolerance: (1, 1.0),
    },
    // RGB components with no colour transform (PhotometricInterpretation 2): the GTiff driver's
    // PHOTOMETRIC=RGB (the COG driver of GDAL 3.6 has no PHOTOMETRIC option).
    JpegCase {
        name: "jpeg_rgb",
        bands: 3,
        driver: "GTiff",
        overviews: true,
        options: &["COMPRESS=JPEG", "PHOTOMETRIC=RGB", "TILED=YES", "BLOCKXSIZE=128", "BLOCKYSIZE=128"],
        photometric: 2,
        served: 3,
        alpha_from_mask: false,
        tolerance: (1, 1.0),
    },
    // 4 bands with the GTiff driver: 4 JPEG components, RGB and an alpha (PhotometricInterpretation
    // 2, ExtraSamples 2), no colour transform.
    JpegCase {
        name: "jpeg_rgba",
        bands: 4,
        driver: "GTiff",
        overviews: true,
        options: &["COMPRESS=JPEG", "TILED=YES", "BLOCKXSIZE=128", "BLOCKYSIZE=128"],
        photometric: 2,
        served: 4,
        alpha_from_mask: false,
        tolerance: (1, 1.0),
    },
    // 4 bands with the COG driver: the alpha becomes an internal mask beside 3 YCbCr bands,
    // served as RGBA with the alpha from the mask.
    JpegCase {
        name: "jpeg_rgba_cog",
        bands: 4,
        driver: "COG",
        overviews: false,
        options: &["COMPRESS=JPEG", "QUALITY=90", "BLOCKSIZE=128", "OVERVIEWS=AUTO"],
        photometric: 6,
        served: 4,
        alpha_from_mask: true,
        tolerance: (4, 0.998),
    },
];

/// Has GDAL write a JPEG case in `dir`; returns each IFD's size and the bands GDAL reads.
fn write_jpeg(case: &JpegCase, dir: &Path) -> Vec<([u64; 2], usize)> {
    let mut args = vec![
        "-".to_string(),
        case.name.into(),
        "300".into(),
        "200".into(),
        case.bands.to_string(),
        case.driver.into(),
        if case.overviews { "1" } else { "0" }.into(),
    ];
    args.extend(case.options.iter().map(|s| s.to_string()));
    let mut child = Command::new(crate::common::gdal::python())
        .args(&args)
        .current_dir(dir)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write;
    child.stdin.take().unwrap().write_all(WRITE_JPEG.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{}: GDAL failed: {}", case.name, String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| {
            let v: Vec<&str> = l.splitn(4, ' ').collect();
            assert!(v[3].contains("JPEG"), "{}: {l}", case.name);
            ([v[0].parse().unwrap(), v[1].parse().unwrap()], v[2].parse().unwrap())
        })
        .collect()
}

/// The PhotometricInterpretation (262) of IFD 0 of the classic little-endian TIFF `bytes`.
fn photometric(bytes: &[u8]) -> u64 {
    assert_eq!(&bytes[..4], b"II*\0");
    let at = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes([bytes[at], bytes[at + 1]]) as usize;
    (0..n)
        .map(|i| &bytes[at + 2 + 12 * i..at + 14 + 12 * i])
        .find(|e| u16::from_le_bytes([e[0], e[1]]) == 262)
        .map(|e| u16::from_le_bytes([e[8], e[9]]) as u64)
        .expect("a PhotometricInterpretation tag")
}

#[test]
fn jpeg_cogs_grey_ycbcr_rgb_and_rgba_decode_as_gdal_does_within_the_decoders_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for case in &JPEG_CASES {
        let name = case.name;
        let ifds = write_jpeg(case, d);
        let path = d.join(format!("{name}.tif"));
        assert_eq!(photometric(&std::fs::read(&path).unwrap()), case.photometric, "{name}: GDAL wrote another kind");
        assert!(ifds.len() >= 3, "{name}: {} IFDs, expected overviews", ifds.len());
        let src = CogSource::open(&path, 64).unwrap_or_else(|e| panic!("{name}: {e}"));
        let served = case.served;
        assert_eq!(src.desc().bytes_per_texel(), served, "{name}");
        assert!(src.info().human().contains("JPEG"), "{name}: {}", src.info().human());
        for (k, &(size, bands)) in ifds.iter().enumerate() {
            let rows_up = |raw: Vec<u8>, n: usize| -> Vec<u8> {
                assert_eq!(raw.len(), (size[0] * size[1]) as usize * n, "{name} level {k}");
                raw.chunks_exact(size[0] as usize * n).rev().flatten().copied().collect()
            };
            let gdal = rows_up(std::fs::read(d.join(format!("{name}.{k}.raw"))).unwrap(), bands);
            let mask = rows_up(std::fs::read(d.join(format!("{name}.{k}.mask"))).unwrap(), 1);
            let ours = super::cog::level(&src, k as u32).unwrap_or_else(|e| panic!("{name} level {k}: {e}"));
            assert_eq!(ours.len(), mask.len() * served, "{name} level {k}");
            let (mut colour, mut alpha) = (Vec::new(), Vec::new());
            for (texel, gdal_texel) in ours.chunks_exact(served).zip(gdal.chunks_exact(bands)) {
                let n = if case.alpha_from_mask { served - 1 } else { served };
                colour.extend(texel[..n].iter().zip(gdal_texel).map(|(a, b)| a.abs_diff(*b)));
                if case.alpha_from_mask {
                    alpha.push(texel[served - 1]);
                }
            }
            let max = colour.iter().copied().max().unwrap_or(0);
            let within2 = colour.iter().filter(|&&e| e <= 2).count() as f64 / colour.len() as f64;
            let (max_ok, share_ok) = case.tolerance;
            assert!(
                max <= max_ok && within2 >= share_ok,
                "{name} level {k}: max difference {max} (at most {max_ok}), {within2:.4} within 2 (at least {share_ok})"
            );
            if case.alpha_from_mask {
                assert!(mask.contains(&0) && mask.contains(&255), "{name} level {k}: the mask has no holes");
                let differ = alpha.iter().zip(&mask).filter(|(a, m)| a != m).count();
                assert_eq!(differ, 0, "{name} level {k}: {differ} alphas differ from GDAL's mask band");
            }
        }
        // The levels past the overviews are built and read.
        for k in ifds.len()..src.desc().level_count() {
            super::cog::level(&src, k as u32).unwrap_or_else(|e| panic!("{name} level {k}: {e}"));
        }
    }
}

#[test]
fn jpeg_of_four_samples_that_are_not_rgba_is_refused_naming_the_photometric_interpretation() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // What else GDAL writes for 4 bands with JPEG: CMYK (PhotometricInterpretation 5, an Adobe
    // JPEG of 4 components) and 4 grey samples (1, ExtraSamples 0, 0, 2).
    for (name, photometric, found) in [
        ("jpeg_cmyk", "CMYK", "5 with 4 JPEG-compressed samples"),
        ("jpeg_grey4", "MINISBLACK", "1 with 4 JPEG-compressed samples"),
    ] {
        let options: &'static [&'static str] = match photometric {
            "CMYK" => &["COMPRESS=JPEG", "TILED=YES", "PHOTOMETRIC=CMYK"],
            _ => &["COMPRESS=JPEG", "TILED=YES", "PHOTOMETRIC=MINISBLACK"],
        };
        let case = JpegCase {
            name,
            bands: 4,
            driver: "GTiff",
            overviews: false,
            options,
            photometric: 0,
            served: 0,
            alpha_from_mask: false,
            tolerance: (0, 0.0),
        };
        write_jpeg(&case, d);
        let e = CogSource::open(&d.join(format!("{name}.tif")), 64).unwrap_err().to_string();
        for part in ["IFD 0", "PhotometricInterpretation (262)", found, "2 (RGB, no colour transform", "with 4 (RGBA"] {
            assert!(e.contains(part), "{name}: {part:?} not in {e}");
        }
    }
}

/// Rewrites the component ids of every tile's JPEG stream of `SRC` (3 components: 'R' 'G' 'B',
/// what libjpeg writes for RGB) to 1 2 3 (what a YCbCr stream holds) as `DST`, and prints whether
/// GDAL reads both files the same (libtiff takes the components of a PhotometricInterpretation 2
/// image as stored, whatever their ids).
const PATCH_IDS: &str = r#"
import sys, shutil
from osgeo import gdal
gdal.UseExceptions()
src, dst = sys.argv[1], sys.argv[2]
shutil.copy(src, dst)
ds = gdal.Open(src)
b = ds.GetRasterBand(1)
bw, bh = b.GetBlockSize()
data = bytearray(open(dst, "rb").read())
for ty in range((ds.RasterYSize + bh - 1) // bh):
    for tx in range((ds.RasterXSize + bw - 1) // bw):
        i = int(b.GetMetadataItem("BLOCK_OFFSET_%d_%d" % (tx, ty), "TIFF")) + 2
        while True:
            assert data[i] == 0xFF
            m, n = data[i + 1], data[i + 2] * 256 + data[i + 3]
            if m == 0xC0:
                assert bytes(data[i + 10:i + 19:3]) == b"RGB"
                for c in range(3):
                    data[i + 10 + 3 * c] = c + 1
            if m == 0xDA:
                for c in range(3):
                    data[i + 5 + 2 * c] = c + 1
                break
            i += 2 + n
open(dst, "wb").write(data)
print(1, 1 if gdal.Open(src).ReadRaster() == gdal.Open(dst).ReadRaster() else 0)
"#;

#[test]
fn jpeg_rgb_components_are_taken_as_stored_whatever_their_component_ids() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let case = &JPEG_CASES[2];
    assert_eq!(case.name, "jpeg_rgb");
    write_jpeg(case, d);
    let args = ["-".to_string(), "jpeg_rgb.tif".into(), "jpeg_rgb_ids.tif".into()];
    let same = crate::common::gdal::write_with(PATCH_IDS, &args, d, "patching the component ids");
    assert_eq!(same, [[1, 1]], "GDAL reads the file with ids 1 2 3 otherwise");
    // With ids 1 2 3 and no Adobe marker a JPEG decoder on its own takes the components for
    // YCbCr; the TIFF says RGB, so they are taken as stored: the same texels as with 'R' 'G' 'B'.
    let rgb = CogSource::open(&d.join("jpeg_rgb.tif"), 64).unwrap();
    let ids = CogSource::open(&d.join("jpeg_rgb_ids.tif"), 64).unwrap();
    for k in 0..rgb.desc().level_count() as u32 {
        let (a, b) = (super::cog::level(&rgb, k).unwrap(), super::cog::level(&ids, k).unwrap());
        let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
        assert_eq!(differ, 0, "level {k}: {differ} samples differ");
    }
}
