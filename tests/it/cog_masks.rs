//! Colour COGs with an internal mask or GDAL_NODATA, written by GDAL in the test (its Python
//! binding, `python3-gdal`): served as the RGBA variant of their format, the colour samples as
//! stored and the alpha 0 where the mask is 0 or every colour sample is the nodata value. Level 0
//! is checked texel for texel against the values written; each overview's colour against GDAL's
//! decode of its bands and its alpha against GDAL's read of its mask band.

use clipmap::source::{CogSource, TileSource};
use clipmap::texel::TexelFormat;
use std::path::Path;
use std::process::Command;

/// The Python side: `NAME KIND W H BANDS NODATA MASK OPTIONS...` writes `NAME.tif` (GDAL's COG
/// driver) from the formula, with the nodata value (`-`: none) and a mask (`1`: a per-dataset
/// mask band from the mask formula), then writes each IFD's bands (`NAME.N.raw`: samples
/// interleaved, little-endian, rows top-down) and mask (`NAME.N.mask`: GDAL's mask band read,
/// one byte a pixel), printing each IFD's size.
const WRITE: &str = r#"
import struct, sys
from osgeo import gdal
gdal.UseExceptions()
name, kind, w, h, bands, nodata, mask = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), sys.argv[6], sys.argv[7] == "1"
opts = sys.argv[8:]
code = {"u8": "B", "u16": "H"}[kind]
gtype = {"u8": gdal.GDT_Byte, "u16": gdal.GDT_UInt16}[kind]
top = 255 if kind == "u8" else 65535
def value(x, y, c):
    if nodata != "-" and (x * 7 + y * 3) % 11 == 0:
        return int(nodata)
    return (x * 37 + y * 11 + c * 90) % (top + 1) if kind == "u8" else (x * 257 + y * 131 + c * 20000) & 0xFFFF
def masked(x, y):
    return 0 if (x // 5 + y // 3) % 4 == 0 or (x - 40) ** 2 + (y - 30) ** 2 < 200 else 255
mem = gdal.GetDriverByName("MEM").Create("", w, h, bands, gtype)
for b in range(bands):
    band = mem.GetRasterBand(b + 1)
    band.WriteRaster(0, 0, w, h, struct.pack("<%d%s" % (w * h, code), *[value(x, y, b) for y in range(h) for x in range(w)]))
    if nodata != "-":
        band.SetNoDataValue(int(nodata))
    if bands >= 3:
        band.SetColorInterpretation([gdal.GCI_RedBand, gdal.GCI_GreenBand, gdal.GCI_BlueBand][b])
if mask:
    mem.CreateMaskBand(gdal.GMF_PER_DATASET)
    m = mem.GetRasterBand(1).GetMaskBand()
    m.WriteRaster(0, 0, w, h, bytes(masked(x, y) for y in range(h) for x in range(w)))
gdal.Translate(name + ".tif", mem, format="COG", creationOptions=opts)
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
    open("%s.%d.mask" % (name, i), "wb").write(bands_[0].GetMaskBand().ReadRaster(0, 0, bw, bh))
    print(bw, bh)
"#;

pub(crate) struct Case {
    pub(crate) name: &'static str,
    kind: &'static str,
    size: [u64; 2],
    bands: usize,
    nodata: Option<u16>,
    mask: bool,
    options: &'static [&'static str],
    /// The format served.
    format: TexelFormat,
}

pub(crate) const CASES: [Case; 4] = [
    // (a) RGB with an internal mask, no overviews.
    Case {
        name: "rgb_mask",
        kind: "u8",
        size: [200, 150],
        bands: 3,
        nodata: None,
        mask: true,
        options: &["COMPRESS=DEFLATE", "BLOCKSIZE=64", "OVERVIEWS=NONE"],
        format: TexelFormat::RGBA8,
    },
    // (b) grey with GDAL_NODATA, 8- and 16-bit.
    Case {
        name: "grey_nodata",
        kind: "u8",
        size: [130, 90],
        bands: 1,
        nodata: Some(7),
        mask: false,
        options: &["COMPRESS=LZW", "BLOCKSIZE=64", "OVERVIEWS=NONE"],
        format: TexelFormat::RGBA8,
    },
    Case {
        name: "grey16_nodata",
        kind: "u16",
        size: [130, 90],
        bands: 1,
        nodata: Some(40000),
        mask: false,
        options: &["COMPRESS=ZSTD", "PREDICTOR=YES", "BLOCKSIZE=64", "OVERVIEWS=NONE"],
        format: TexelFormat::RGBA16,
    },
    // (c) RGB with overviews and a mask.
    Case {
        name: "rgb_mask_overviews",
        kind: "u8",
        size: [300, 200],
        bands: 3,
        nodata: None,
        mask: true,
        options: &["COMPRESS=LZW", "BLOCKSIZE=64", "OVERVIEWS=AUTO", "RESAMPLING=AVERAGE"],
        format: TexelFormat::RGBA8,
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
        case.nodata.map_or("-".into(), |v| v.to_string()),
        if case.mask { "1" } else { "0" }.into(),
    ];
    args.extend(case.options.iter().map(|s| s.to_string()));
    crate::common::gdal::write_with(WRITE, &args, dir, case.name)
}

/// Sample `c` of pixel (x, y) (y from the top row) as the Python formula writes it.
fn value(case: &Case, x: u64, y: u64, c: u64) -> u16 {
    if let Some(v) = case.nodata {
        if (x * 7 + y * 3).is_multiple_of(11) {
            return v;
        }
    }
    match case.kind {
        "u8" => ((x * 37 + y * 11 + c * 90) % 256) as u16,
        _ => ((x * 257 + y * 131 + c * 20000) & 0xFFFF) as u16,
    }
}

/// The mask written for pixel (x, y) (0 no data).
fn masked(x: u64, y: u64) -> bool {
    let (dx, dy) = (x as i64 - 40, y as i64 - 30);
    (x / 5 + y / 3).is_multiple_of(4) || dx * dx + dy * dy < 200
}

/// Appends one RGBA texel of `n`-byte samples.
fn push(out: &mut Vec<u8>, rgba: [u16; 4], n: usize) {
    for v in rgba {
        if n == 1 {
            out.push(v as u8);
        } else {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
}

/// Level 0 by the definition: colour samples as written (grey replicated), alpha 0 where the
/// mask is 0 or every colour sample is the nodata value, else full; rows in increasing t.
fn level0(case: &Case) -> Vec<u8> {
    let n = if case.kind == "u8" { 1 } else { 2 };
    let full = if n == 1 { 255 } else { 65535 };
    let [w, h] = case.size;
    let mut out = Vec::new();
    for t in 0..h {
        let y = h - 1 - t;
        for x in 0..w {
            let c: Vec<u16> = (0..case.bands as u64).map(|c| value(case, x, y, c)).collect();
            let colour = if case.bands >= 3 { [c[0], c[1], c[2]] } else { [c[0]; 3] };
            let nodata = case.nodata.is_some_and(|v| colour.iter().all(|&s| s == v));
            let alpha = if nodata || case.mask && masked(x, y) { 0 } else { full };
            push(&mut out, [colour[0], colour[1], colour[2], alpha], n);
        }
    }
    out
}

/// IFD `i` as GDAL reads it: its bands' colour with its mask band's verdict as the alpha (0
/// where GDAL's mask is 0, else full), rows in increasing t.
fn gdal_ifd(dir: &Path, case: &Case, i: usize, [w, h]: [u64; 2]) -> Vec<u8> {
    let n = if case.kind == "u8" { 1 } else { 2 };
    let full = if n == 1 { 255 } else { 65535 };
    let raw = std::fs::read(dir.join(format!("{}.{i}.raw", case.name))).unwrap();
    let mask = std::fs::read(dir.join(format!("{}.{i}.mask", case.name))).unwrap();
    let px = case.bands * n;
    assert_eq!((raw.len(), mask.len()), ((w * h) as usize * px, (w * h) as usize), "{} IFD {i}", case.name);
    let mut out = Vec::new();
    for t in 0..h {
        let y = h - 1 - t;
        for x in 0..w {
            let k = (y * w + x) as usize;
            let p = &raw[k * px..(k + 1) * px];
            let get = |c: usize| if n == 1 { p[c] as u16 } else { u16::from_le_bytes([p[2 * c], p[2 * c + 1]]) };
            let colour = if case.bands >= 3 { [get(0), get(1), get(2)] } else { [get(0); 3] };
            push(&mut out, [colour[0], colour[1], colour[2], if mask[k] == 0 { 0 } else { full }], n);
        }
    }
    out
}

#[test]
fn colour_cogs_with_a_mask_or_nodata_are_served_rgba_with_their_alpha() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for case in &CASES {
        let ifds = write(case, d);
        let path = d.join(format!("{}.tif", case.name));
        for clip in [64, 512] {
            let ctx = format!("{} (clip {clip})", case.name);
            let src = CogSource::open(&path, clip).unwrap_or_else(|e| panic!("{ctx}: {e}"));
            assert_eq!(src.desc().format(), case.format, "{ctx}");
            assert!(src.heights().is_none(), "{ctx}");
            let alpha = src.info().alpha.unwrap_or_default();
            let says = if case.mask { "internal mask" } else { "GDAL_NODATA" };
            assert!(alpha.contains(says), "{ctx}: {alpha}");
            let bpt = src.desc().bytes_per_texel();
            let want0 = level0(case);
            // Some texels of each kind, so that the checks below can fail.
            let alpha_at = |texels: &[u8], i: usize| texels[i * bpt + bpt - 1];
            let holes = (0..want0.len() / bpt).filter(|&i| alpha_at(&want0, i) == 0).count();
            assert!(holes > 100 && holes < want0.len() / bpt / 2, "{ctx}: {holes} texels without data");
            let n = src.desc().level_count();
            let mut overviews = 0;
            for k in 0..n as u32 {
                let got = super::cog::level(&src, k).unwrap_or_else(|e| panic!("{ctx}: level {k}: {e}"));
                let want = if k == 0 {
                    want0.clone()
                } else if (k as usize) < ifds.len() {
                    overviews += 1;
                    assert_eq!(ifds[k as usize], src.desc().level(k).size, "{ctx}: overview {k}'s size");
                    gdal_ifd(d, case, k as usize, ifds[k as usize])
                } else {
                    continue;
                };
                assert_eq!(got.len(), want.len(), "{ctx}: level {k}");
                let differ: Vec<usize> = (0..got.len() / bpt)
                    .filter(|&i| got[i * bpt..(i + 1) * bpt] != want[i * bpt..(i + 1) * bpt])
                    .collect();
                assert!(
                    differ.is_empty(),
                    "{ctx}: level {k}: {} texels differ, the first {:?}: {:?}, expected {:?}",
                    differ.len(),
                    differ[0],
                    &got[differ[0] * bpt..(differ[0] + 1) * bpt],
                    &want[differ[0] * bpt..(differ[0] + 1) * bpt]
                );
            }
            if case.name == "rgb_mask_overviews" {
                assert_eq!(overviews, 3, "{ctx}: the three overviews GDAL wrote are used");
            }
        }
    }
}

#[test]
fn clipmapd_serves_a_masked_cog_as_rgba_and_cliptex_info_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let case = &CASES[3];
    write(case, d);
    let tif = d.join(format!("{}.tif", case.name));
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).arg("info").arg(&tif).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{out:?}");
    assert!(text.contains("300 x 200 texels, rgba8"), "{text}");
    assert!(text.contains("alpha: 0 where the internal mask is 0 (IFD 1 for level 0), else full"), "{text}");
    let served = crate::common::gdal::Served::start(&tif, 128, "masked", d);
    let c = &served.client;
    let log = || served.log();
    assert_eq!(c.bytes_per_texel, 4, "{}", log());
    assert!(c.heights.is_none());
}

#[test]
fn a_mask_that_does_not_fit_its_image_or_a_colour_nodata_out_of_range_is_refused_naming_the_tag() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let case = &CASES[0];
    write(case, d);
    let tif = d.join(format!("{}.tif", case.name));
    // The mask IFD's TileWidth changed from 64 to 32 in place (its entry's value).
    let mut bytes = std::fs::read(&tif).unwrap();
    let ifds = ifd_offsets(&bytes);
    assert!(ifds.len() >= 2, "{ifds:?}");
    let mask = ifds[1];
    let count = u16::from_le_bytes([bytes[mask], bytes[mask + 1]]) as usize;
    let mut changed = false;
    for e in 0..count {
        let at = mask + 2 + e * 12;
        if u16::from_le_bytes([bytes[at], bytes[at + 1]]) == 322 {
            bytes[at + 8..at + 10].copy_from_slice(&32u16.to_le_bytes());
            changed = true;
        }
    }
    assert!(changed);
    let bad = d.join("bad_mask.tif");
    std::fs::write(&bad, &bytes).unwrap();
    let e = CogSource::open(&bad, 64).unwrap_err().to_string();
    assert!(
        e.contains("IFD 1 (a mask of IFD 0): TileWidth (322) x TileLength (323) is 32 x 64, expected 64 x 64"),
        "{e}"
    );
    // A colour nodata that is not a value of the samples.
    let grey = &CASES[1];
    write(grey, d);
    let name = format!("{}.tif", grey.name);
    let out = Command::new("gdal_edit.py").args(["-a_nodata", "300", &name]).current_dir(d).output();
    assert!(out.as_ref().is_ok_and(|o| o.status.success()), "gdal_edit.py: {out:?}");
    let e = CogSource::open(&d.join(&name), 64).unwrap_err().to_string();
    assert!(e.contains("GDAL_NODATA (42113) is \"300\""), "{e}");
}

/// The offsets of a little-endian classic TIFF's IFDs, in chain order.
fn ifd_offsets(b: &[u8]) -> Vec<usize> {
    assert_eq!(&b[..4], b"II*\0");
    let mut at = u32::from_le_bytes(b[4..8].try_into().unwrap()) as usize;
    let mut out = Vec::new();
    while at != 0 {
        out.push(at);
        let n = u16::from_le_bytes([b[at], b[at + 1]]) as usize;
        let next = at + 2 + n * 12;
        at = u32::from_le_bytes(b[next..next + 4].try_into().unwrap()) as usize;
    }
    out
}

/// The Python side of the height tests: `NAME KIND W H NODATA OPTIONS...` writes `NAME.tif`
/// (GDAL's COG driver), one band of 16-bit signed (`i16`) or 32-bit float (`f32`) heights from
/// the formula, with the nodata value (`-`: none) and a per-dataset mask band from the mask
/// formula, then each IFD's band (`NAME.N.raw`, little-endian, rows top-down) and GDAL's read of
/// its mask band (`NAME.N.mask`), printing each IFD's size.
const WRITE_HEIGHTS: &str = r#"
import struct, sys
from osgeo import gdal
gdal.UseExceptions()
name, kind, w, h, nodata = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
opts = sys.argv[6:]
code = {"i16": "h", "f32": "f"}[kind]
gtype = {"i16": gdal.GDT_Int16, "f32": gdal.GDT_Float32}[kind]
def value(x, y):
    if nodata != "-" and (x * 7 + y * 3) % 16 == 0:
        return int(nodata) if kind == "i16" else float(nodata)
    if kind == "i16":
        return (x * 97 + y * 61) % 60001 - 30000
    return -11000 + ((x * 7919 + y * 104729) % (19900 * 1024)) / 1024.0
def masked(x, y):
    return 0 if (x // 5 + y // 3) % 4 == 0 or (x - 40) ** 2 + (y - 30) ** 2 < 200 else 255
mem = gdal.GetDriverByName("MEM").Create("", w, h, 1, gtype)
band = mem.GetRasterBand(1)
band.WriteRaster(0, 0, w, h, struct.pack("<%d%s" % (w * h, code), *[value(x, y) for y in range(h) for x in range(w)]))
if nodata != "-":
    band.SetNoDataValue(float(nodata))
mem.CreateMaskBand(gdal.GMF_PER_DATASET)
band.GetMaskBand().WriteRaster(0, 0, w, h, bytes(masked(x, y) for y in range(h) for x in range(w)))
gdal.Translate(name + ".tif", mem, format="COG", creationOptions=opts)
ds = gdal.Open(name + ".tif")
for i in range(1 + ds.GetRasterBand(1).GetOverviewCount()):
    b = ds.GetRasterBand(1) if i == 0 else ds.GetRasterBand(1).GetOverview(i - 1)
    raw = b.ReadRaster(0, 0, b.XSize, b.YSize)
    open("%s.%d.raw" % (name, i), "wb").write(struct.pack("<%d%s" % (b.XSize * b.YSize, code), *struct.unpack("=%d%s" % (b.XSize * b.YSize, code), raw)))
    open("%s.%d.mask" % (name, i), "wb").write(b.GetMaskBand().ReadRaster(0, 0, b.XSize, b.YSize))
    print(b.XSize, b.YSize)
"#;

/// A height COG with an internal mask.
struct HeightCase {
    name: &'static str,
    kind: &'static str,
    size: [u64; 2],
    /// GDAL_NODATA, as written (`None`: none).
    nodata: Option<&'static str>,
    options: &'static [&'static str],
    /// The nodata value served.
    served_nodata: f64,
}

const HEIGHT_CASES: [HeightCase; 3] = [
    // 16-bit signed, no GDAL_NODATA: the mask's texels are -32768; GDAL's overviews and masks.
    HeightCase {
        name: "dem_i16_mask",
        kind: "i16",
        size: [300, 200],
        nodata: None,
        options: &["COMPRESS=LZW", "PREDICTOR=YES", "BLOCKSIZE=64", "OVERVIEWS=AUTO", "RESAMPLING=AVERAGE"],
        served_nodata: -32768.0,
    },
    // 32-bit float with GDAL_NODATA: nodata where the mask is 0 as well as where the samples are
    // -9999.
    HeightCase {
        name: "dem_f32_mask_nodata",
        kind: "f32",
        size: [300, 200],
        nodata: Some("-9999"),
        options: &["COMPRESS=DEFLATE", "PREDICTOR=FLOATING_POINT", "BLOCKSIZE=128", "OVERVIEWS=AUTO"],
        served_nodata: -9999.0,
    },
    // 32-bit float, no GDAL_NODATA, no overviews: the least finite float where the mask is 0,
    // every coarser level built by the `mean` rule with those texels left out.
    HeightCase {
        name: "dem_f32_mask",
        kind: "f32",
        size: [200, 150],
        nodata: None,
        options: &["COMPRESS=ZSTD", "BLOCKSIZE=64", "OVERVIEWS=NONE"],
        served_nodata: f32::MIN as f64,
    },
];

/// Writes a height case with GDAL in `dir`; returns the size of every IFD GDAL decoded.
fn write_heights(case: &HeightCase, dir: &Path) -> Vec<[u64; 2]> {
    let mut args = vec![
        "-".to_string(),
        case.name.into(),
        case.kind.into(),
        case.size[0].to_string(),
        case.size[1].to_string(),
        case.nodata.unwrap_or("-").into(),
    ];
    args.extend(case.options.iter().map(|s| s.to_string()));
    crate::common::gdal::write_with(WRITE_HEIGHTS, &args, dir, case.name)
}

/// A height as stored (little-endian `i16` or `f32`).
fn height_bytes(kind: &str, v: f64) -> Vec<u8> {
    match kind {
        "i16" => (v as i16).to_le_bytes().to_vec(),
        _ => (v as f32).to_le_bytes().to_vec(),
    }
}

/// Level 0 of a height case by the definition: the height written, or the nodata served where
/// the mask is 0 (or the height is GDAL_NODATA); rows in increasing t.
fn height_level0(case: &HeightCase) -> Vec<u8> {
    let [w, h] = case.size;
    let mut out = Vec::new();
    for t in 0..h {
        let y = h - 1 - t;
        for x in 0..w {
            let written = match (case.nodata, case.kind) {
                (Some(v), _) if (x * 7 + y * 3).is_multiple_of(16) => v.parse().unwrap(),
                (_, "i16") => ((x * 97 + y * 61) % 60001) as f64 - 30000.0,
                _ => -11000.0 + ((x * 7919 + y * 104729) % (19900 * 1024)) as f64 / 1024.0,
            };
            out.extend(height_bytes(case.kind, if masked(x, y) { case.served_nodata } else { written }));
        }
    }
    out
}

/// IFD `i` of a height case as GDAL reads it: its band, nodata where GDAL's read of its mask
/// band is 0; rows in increasing t.
fn gdal_heights(dir: &Path, case: &HeightCase, i: usize, [w, h]: [u64; 2]) -> Vec<u8> {
    let n = if case.kind == "i16" { 2 } else { 4 };
    let raw = std::fs::read(dir.join(format!("{}.{i}.raw", case.name))).unwrap();
    let mask = std::fs::read(dir.join(format!("{}.{i}.mask", case.name))).unwrap();
    assert_eq!((raw.len(), mask.len()), ((w * h) as usize * n, (w * h) as usize), "{} IFD {i}", case.name);
    let nodata = height_bytes(case.kind, case.served_nodata);
    let mut out = Vec::new();
    for y in (0..h).rev() {
        for x in 0..w {
            let k = (y * w + x) as usize;
            out.extend_from_slice(if mask[k] == 0 { &nodata } else { &raw[k * n..(k + 1) * n] });
        }
    }
    out
}

#[test]
fn height_cogs_with_a_mask_serve_nodata_where_the_mask_is_zero() {
    use clipmap::height::HeightStorage;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for case in &HEIGHT_CASES {
        let ifds = write_heights(case, d);
        let path = d.join(format!("{}.tif", case.name));
        // GDAL's read of the full-resolution mask is the mask written.
        let [w, h] = case.size;
        let mask0 = std::fs::read(d.join(format!("{}.0.mask", case.name))).unwrap();
        let written: Vec<u8> = (0..h).flat_map(|y| (0..w).map(move |x| if masked(x, y) { 0 } else { 255 })).collect();
        assert!(mask0 == written, "{}: GDAL's mask band is not the mask written", case.name);
        for clip in [64, 512] {
            let ctx = format!("{} (clip {clip})", case.name);
            let src = CogSource::open(&path, clip).unwrap_or_else(|e| panic!("{ctx}: {e}"));
            let plan = src.heights().unwrap_or_else(|| panic!("{ctx}: not heights"));
            let storage = if case.kind == "i16" { HeightStorage::I16 } else { HeightStorage::F32 };
            assert_eq!((plan.format.storage(), plan.format.nodata()), (storage, Some(case.served_nodata)), "{ctx}");
            assert!(src.info().alpha.is_none(), "{ctx}");
            let says = src.info().nodata.unwrap_or_default();
            assert!(says.contains("where the internal mask is 0 (IFD 1 for level 0"), "{ctx}: {says}");
            assert_eq!(says.contains("GDAL_NODATA)"), case.nodata.is_some(), "{ctx}: {says}");
            let bpt = src.desc().bytes_per_texel();
            let nodata = height_bytes(case.kind, case.served_nodata);
            let mut want = height_level0(case);
            // Some texels of each kind, so that the checks below can fail.
            let holes = want.chunks_exact(bpt).filter(|t| *t == &nodata[..]).count();
            assert!(holes > 100 && holes < want.len() / bpt / 2, "{ctx}: {holes} texels without data");
            let mut size = case.size;
            for k in 0..src.desc().level_count() as u32 {
                let got = super::cog::level(&src, k).unwrap_or_else(|e| panic!("{ctx}: level {k}: {e}"));
                if k > 0 {
                    want = if (k as usize) < ifds.len() {
                        assert_eq!(ifds[k as usize], src.desc().level(k).size, "{ctx}: overview {k}'s size");
                        gdal_heights(d, case, k as usize, ifds[k as usize])
                    } else {
                        // The `mean` rule, nodata left out.
                        let f = plan.format;
                        let stored: Vec<f64> = want.chunks_exact(bpt).map(|b| f.read(b)).collect();
                        let next = f.reduce_level(plan.levels, &stored, size[0] as usize, size[1] as usize).unwrap();
                        next.iter().flat_map(|v| height_bytes(case.kind, *v)).collect()
                    };
                    size = src.desc().level(k).size;
                }
                assert_eq!(got.len(), want.len(), "{ctx}: level {k}");
                let differ: Vec<usize> = (0..got.len() / bpt)
                    .filter(|&i| got[i * bpt..(i + 1) * bpt] != want[i * bpt..(i + 1) * bpt])
                    .collect();
                assert!(
                    differ.is_empty(),
                    "{ctx}: level {k}: {} texels differ, the first {:?}: {:?}, expected {:?}",
                    differ.len(),
                    differ.first(),
                    differ.first().map(|&i| &got[i * bpt..(i + 1) * bpt]),
                    differ.first().map(|&i| &want[i * bpt..(i + 1) * bpt])
                );
            }
            if case.name == "dem_i16_mask" {
                assert_eq!(ifds.len(), 4, "{ctx}: GDAL wrote three overviews");
                assert!(src.info().built_because.is_some_and(|b| b.contains("no smaller overviews")), "{ctx}");
            }
        }
    }
}

#[test]
fn clipmapd_serves_a_masked_height_cog_with_the_nodata_in_its_heights_block() {
    use clipmap::height::HeightStorage;
    use std::time::{Duration, Instant};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let case = &HEIGHT_CASES[0];
    write_heights(case, d);
    let tif = d.join(format!("{}.tif", case.name));
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).arg("info").arg(&tif).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{out:?}");
    assert!(text.contains("300 x 200 texels, l16i"), "{text}");
    assert!(text.contains("nodata: -32768 where the internal mask is 0 (IFD 1 for level 0;"), "{text}");
    let served = crate::common::gdal::Served::start(&tif, 128, "dem_mask", d);
    let c = &served.client;
    let log = || served.log();
    let h = c.heights.unwrap_or_else(|| panic!("not heights\n{}", log()));
    assert_eq!((h.storage, h.nodata), (HeightStorage::I16, Some(-32768.0)), "{}", log());
    let t = Instant::now();
    let [s0, t0, s1, t1] = loop {
        if let Some(st) = c.level_state(0) {
            let [s0, t0, s1, t1] = st.valid;
            if st.enabled && s1 > s0 && t1 > t0 {
                break st.valid;
            }
        }
        assert!(t.elapsed() < Duration::from_secs(30), "level 0 never became valid\n{}", log());
        std::thread::sleep(Duration::from_millis(5));
    };
    let (w, hh) = ((s1 - s0) as u64, (t1 - t0) as u64);
    let mut buf = vec![0u8; (w * hh * 2) as usize];
    c.read_region(0, s0, t0, w, hh, &mut buf).expect("the valid region reads");
    let want = height_level0(case);
    let mut holes = 0;
    for (i, texel) in buf.chunks_exact(2).enumerate() {
        let (s, t) = (s0 as u64 + i as u64 % w, t0 as u64 + i as u64 / w);
        let k = (t * case.size[0] + s) as usize * 2;
        assert_eq!(texel, &want[k..k + 2], "texel ({s}, {t})");
        holes += (texel == (-32768i16).to_le_bytes()) as usize;
    }
    assert!(holes > 0, "no nodata texel in the valid region");
}
