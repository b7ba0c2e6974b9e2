//! TIFFs that cost too much or say too little: tiles bounded by the texels served (an alpha
//! added included), a tile index past the end of the file refused at open, offsets of 2^63 and
//! more refused naming where, an overview of other samples refused naming the right tag. The
//! files are written here, by GDAL (its Python binding) or byte by byte ([`bigtiff`]).

use clipmap::source::{CogSource, TileSource};
use std::path::Path;
use std::process::Command;

/// Where [`bigtiff`] puts the bytes after its IFDs (tile data, arrays): byte 8192.
pub(crate) const DATA_AT: u64 = 8192;

/// A little-endian BigTIFF: the IFDs given, chained in order from byte 16, each entry `(tag,
/// type, count, value field)` with the value field written as a little-endian 8-byte word (the
/// value itself when it fits, else an offset), then `data` from [`DATA_AT`].
pub(crate) fn bigtiff(ifds: &[Vec<(u16, u16, u64, u64)>], data: &[u8]) -> Vec<u8> {
    let mut out = b"II+\0".to_vec();
    out.extend_from_slice(&8u16.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    out.extend_from_slice(&16u64.to_le_bytes());
    for (i, ifd) in ifds.iter().enumerate() {
        let mut entries = ifd.clone();
        entries.sort_by_key(|e| e.0);
        out.extend_from_slice(&(entries.len() as u64).to_le_bytes());
        for (tag, ty, count, value) in entries {
            out.extend_from_slice(&tag.to_le_bytes());
            out.extend_from_slice(&ty.to_le_bytes());
            out.extend_from_slice(&count.to_le_bytes());
            out.extend_from_slice(&value.to_le_bytes());
        }
        let next = if i + 1 < ifds.len() { out.len() as u64 + 8 } else { 0 };
        out.extend_from_slice(&next.to_le_bytes());
    }
    assert!(out.len() as u64 <= DATA_AT, "the IFDs fit before the data");
    out.resize(DATA_AT as usize, 0);
    out.extend_from_slice(data);
    out
}

/// The entries of a tiled, uncompressed, 8-bit grey image of `size` in tiles of `tile`, its
/// TileOffsets and TileByteCounts (LONG8) at `index` and `index + 8 * tiles`, or inline (0: sparse)
/// when there is one tile; `subfile` its NewSubfileType.
pub(crate) fn grey_ifd(size: [u64; 2], tile: [u64; 2], index: u64, subfile: u64) -> Vec<(u16, u16, u64, u64)> {
    let tiles = size[0].div_ceil(tile[0]) * size[1].div_ceil(tile[1]);
    let (offsets, counts) = if tiles == 1 { (0, 0) } else { (index, index.saturating_add(8 * tiles)) };
    vec![
        (254, 4, 1, subfile),
        (256, 16, 1, size[0]),
        (257, 16, 1, size[1]),
        (258, 3, 1, 8),
        (259, 3, 1, 1),
        (262, 3, 1, 1),
        (277, 3, 1, 1),
        (322, 16, 1, tile[0]),
        (323, 16, 1, tile[1]),
        (324, 16, tiles, offsets),
        (325, 16, tiles, counts),
    ]
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

#[test]
fn cog_tile_bound_counts_the_alpha_the_service_adds() {
    // A 16384 x 16384 grey image in one tile of 256 MiB (the bound, as stored) with GDAL_NODATA:
    // served as RGBA8, every read of a level-0 tile would take 1 GiB buffers, four times what
    // was checked. GDAL writes it in 0.25 MB (sparse tile, deflated zero overviews).
    let dir = tempfile::tempdir().unwrap();
    const WRITE: &str = r#"
from osgeo import gdal
gdal.UseExceptions()
d = gdal.GetDriverByName("GTiff").Create("big.tif", 16384, 16384, 1, gdal.GDT_Byte,
    ["TILED=YES", "BLOCKXSIZE=16384", "BLOCKYSIZE=16384", "SPARSE_OK=TRUE", "COMPRESS=DEFLATE"])
d.GetRasterBand(1).SetNoDataValue(0)
d = None
ds = gdal.Open("big.tif", gdal.GA_Update)
ds.BuildOverviews("NEAREST", [2 ** i for i in range(1, 15)])
ds = None
"#;
    crate::common::gdal::write_with(WRITE, &[], dir.path(), "a grey image in one 16384 x 16384 tile");
    let path = dir.path().join("big.tif");
    assert!(std::fs::metadata(&path).unwrap().len() < 1 << 20);
    let e = CogSource::open(&path, 1024).expect_err("1 GiB tiles as served");
    let text = e.to_string();
    assert!(text.contains(&path.display().to_string()) && text.contains("IFD 0"), "{text}");
    assert!(text.contains("TileWidth (322) x TileLength (323) is 16384 x 16384"), "{text}");
    assert!(text.contains("268435456 bytes a tile as stored, 1073741824 served as rgba8"), "{text}");
    // `cliptex info` and `clipmapd` say the same, and the service maps nothing.
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).arg("info").arg(&path).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("1073741824 served as rgba8"), "{err}");
    let out = Command::new(env!("CARGO_BIN_EXE_clipmapd"))
        .arg(&path)
        .args(["--name", "big", "--shm-dir"])
        .arg(dir.path())
        .arg("--socket")
        .arg(dir.path().join("big.sock"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("1073741824 served as rgba8"), "{err}");
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left, ["big.tif"], "nothing left beside the file");
}

#[test]
fn a_grey_tile_within_the_bound_as_rgba_is_still_served() {
    // 8192 x 8192 grey with nodata: 256 MiB as RGBA8, the bound itself.
    let dir = tempfile::tempdir().unwrap();
    let mut ifds = vec![grey_ifd([8192, 8192], [8192, 8192], 0, 0)];
    ifds[0].push((42113, 2, 2, u64::from(b'0')));
    for k in 1..=13u64 {
        ifds.push(grey_ifd([8192 >> k, 8192 >> k], [8192 >> k, 8192 >> k], 0, 1));
    }
    let path = write(dir.path(), "ok.tif", &bigtiff(&ifds, &[]));
    let src = CogSource::open(&path, 1024).unwrap();
    assert_eq!(src.desc().format(), clipmap::texel::TexelFormat::RGBA8);
    assert_eq!(src.desc().level(0).tile, [8192, 8192]);
}

/// An 8 KB BigTIFF of 2^26 x 2^26 grey texels in tiles of 256, with 26 overviews down to 1 x 1:
/// every image's tile index (LONG8) starts at byte 2^20, past the file's end.
fn index_past_the_end() -> Vec<u8> {
    let ifds: Vec<_> = (0..=26u64)
        .map(|k| {
            let side = 1u64 << (26 - k);
            grey_ifd([side, side], [256.min(side), 256.min(side)], 1 << 20, (k > 0) as u64)
        })
        .collect();
    bigtiff(&ifds, &[])
}

#[test]
fn cliptex_check_of_a_tiff_whose_tile_index_lies_past_its_end_stops_at_open() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = index_past_the_end();
    assert_eq!(bytes.len(), 8192);
    let path = write(dir.path(), "huge.tif", &bytes);
    let e = CogSource::open(&path, 1024).expect_err("an index past the end");
    let text = e.to_string();
    assert!(text.contains(&path.display().to_string()), "{text}");
    assert!(
        text.contains("IFD 0 tag TileOffsets (324): its 68719476736 values (549755813888 bytes, one per tile of a 67108864 x 67108864 image in tiles of 256 x 256) at byte 1048576 run past the end of the file (8192 bytes)"),
        "{text}"
    );
    // `cliptex check` says so and stops, rather than trying 2^36 tiles one by one (a day). The
    // child is killed after 5 minutes, so a return to the old behaviour fails rather than hangs.
    let mut child = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .arg("check")
        .arg(&path)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t.elapsed() > std::time::Duration::from_secs(300) {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("cliptex check still running after 5 minutes");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("TileOffsets (324)") && err.contains("past the end"), "{err}");
}

#[test]
fn tiff_offsets_past_2_63_are_refused_naming_file_ifd_tag_offset_and_size() {
    let dir = tempfile::tempdir().unwrap();
    let far = 1u64 << 63;
    // The first IFD there.
    let mut bytes = bigtiff(&[grey_ifd([64, 64], [64, 64], 0, 0)], &[]);
    bytes[8..16].copy_from_slice(&far.to_le_bytes());
    let path = write(dir.path(), "ifd.tif", &bytes);
    let text = CogSource::open(&path, 64).unwrap_err().to_string();
    assert!(
        text.contains(&format!(
            "{}: IFD 0 at byte {far}: 8 bytes at byte {far} run past the end of the file (8192 bytes)",
            path.display()
        )),
        "{text}"
    );
    assert!(!text.contains("os error"), "{text}");
    // A tag's values there (GDAL_NODATA, 20 bytes: not in the entry).
    let mut ifd = grey_ifd([64, 64], [64, 64], 0, 0);
    ifd.push((42113, 2, 20, far + 5));
    let path = write(dir.path(), "tag.tif", &bigtiff(&[ifd], &[]));
    let text = CogSource::open(&path, 64).unwrap_err().to_string();
    assert!(
        text.contains(&format!(
            "{}: IFD 0 tag GDAL_NODATA (42113): 20 bytes at byte {} run past the end of the file (8192 bytes)",
            path.display(),
            far + 5
        )),
        "{text}"
    );
    // The tile index there.
    let path = write(dir.path(), "index.tif", &bigtiff(&[grey_ifd([64, 64], [32, 32], far, 0)], &[]));
    let text = CogSource::open(&path, 64).unwrap_err().to_string();
    assert!(
        text.contains(&format!("IFD 0 tag TileOffsets (324): its 4 values (32 bytes, one per tile of a 64 x 64 image in tiles of 32 x 32) at byte {far} run past the end of the file (8192 bytes)")),
        "{text}"
    );
    // A tile there: that tile is short, named as such; the others are read.
    // Texture tile (0, 0) is the image's bottom-left TIFF tile, index 2.
    let mut data = vec![0u8; 32];
    for i in 0..4 {
        let at = if i == 2 { far } else { DATA_AT + 64 };
        data[i * 8..][..8].copy_from_slice(&at.to_le_bytes());
    }
    data.extend_from_slice(&[1024u64.to_le_bytes(); 4].concat());
    data.resize(64 + 1024, 7);
    // Sparse overviews down to 1 x 1: nothing is built at open.
    let mut ifds = vec![grey_ifd([64, 64], [32, 32], DATA_AT, 0)];
    ifds.extend((1..=6).map(|k| grey_ifd([64 >> k, 64 >> k], [32, 32], 0, 1)));
    let path = write(dir.path(), "tile.tif", &bigtiff(&ifds, &data));
    let src = CogSource::open(&path, 32).unwrap();
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    let e = src.read_tile(clipmap::source::TileId::new(0, 0, 0), &mut buf).unwrap_err();
    assert!(matches!(e, clipmap::source::SourceError::Short { .. }), "{e}");
    src.read_tile(clipmap::source::TileId::new(0, 1, 0), &mut buf).unwrap();
    assert!(buf.iter().all(|&b| b == 7));
}

#[test]
fn an_overview_with_another_bits_per_sample_is_refused_naming_bits_per_sample() {
    let dir = tempfile::tempdir().unwrap();
    let mut overview = grey_ifd([32, 32], [32, 32], 0, 1);
    overview.retain(|e| e.0 != 258);
    overview.push((258, 3, 1, 16));
    let ifds = vec![grey_ifd([64, 64], [64, 64], 0, 0), overview];
    let path = write(dir.path(), "bits.tif", &bigtiff(&ifds, &[]));
    let text = CogSource::open(&path, 64).unwrap_err().to_string();
    assert!(
        text.contains(&format!("{}: IFD 1 (an overview): BitsPerSample (258) / SampleFormat (339) is 16 bits, sample format 1, unsigned (l16), expected the full-resolution image's (IFD 0): 8 bits, sample format 1, unsigned (l8)", path.display())),
        "{text}"
    );
    // Another number of samples is still SamplesPerPixel's.
    let mut overview = grey_ifd([32, 32], [32, 32], 0, 1);
    overview.retain(|e| e.0 != 277 && e.0 != 262);
    overview.extend([(277, 3, 1, 3), (262, 3, 1, 2)]);
    let ifds = vec![grey_ifd([64, 64], [64, 64], 0, 0), overview];
    let path = write(dir.path(), "spp.tif", &bigtiff(&ifds, &[]));
    let text = CogSource::open(&path, 64).unwrap_err().to_string();
    assert!(text.contains("IFD 1 (an overview): SamplesPerPixel (277) is 3 (rgb8), expected the full-resolution image's (IFD 0): 1 (l8)"), "{text}");
}

#[test]
fn clipprep_config_only_writes_each_image_cache_in_its_overviews_own_tiles() {
    // Level 0 in 256 x 256 tiles, its overviews (gdaladdo --config GDAL_TIFF_OVR_BLOCKSIZE 128)
    // in 128 x 128: the configuration written must pass its own check, as clipmapd serves the
    // file.
    let dir = tempfile::tempdir().unwrap();
    const WRITE: &str = r#"
from osgeo import gdal
gdal.UseExceptions()
mem = gdal.GetDriverByName("MEM").Create("", 1024, 1024, 1, gdal.GDT_Byte)
mem.GetRasterBand(1).WriteRaster(0, 0, 1024, 1024, bytes((x * 3 + y * 5) & 255 for y in range(1024) for x in range(1024)))
gdal.Translate("ovr.tif", mem, format="GTiff", creationOptions=["TILED=YES", "BLOCKXSIZE=256", "BLOCKYSIZE=256"])
gdal.SetConfigOption("GDAL_TIFF_OVR_BLOCKSIZE", "128")
ds = gdal.Open("ovr.tif", gdal.GA_Update)
ds.BuildOverviews("AVERAGE", [2, 4, 8])
ds = None
"#;
    crate::common::gdal::write_with(WRITE, &[], dir.path(), "overviews in other tiles");
    let cog = dir.path().join("ovr.tif");
    let info = Command::new(env!("CARGO_BIN_EXE_cliptex")).arg("info").arg(&cog).output().unwrap();
    let info = String::from_utf8_lossy(&info.stdout);
    assert!(info.contains("IFD 0, 256 x 256 tiles") && info.contains("IFD 1, 128 x 128 tiles"), "{info}");
    let out = Command::new(env!("CARGO_BIN_EXE_clipprep"))
        .arg("--input")
        .arg(&cog)
        .args(["--config-only", "--clip", "256", "--out", "cfg"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{text}");
    let ic = |k: u32| std::fs::read_to_string(dir.path().join("cfg").join(format!("L{k:02}.ic"))).unwrap();
    let names: Vec<_> = std::fs::read_dir(dir.path().join("cfg")).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(names.len() >= 3, "{names:?}");
    assert!(ic(0).contains("tile_size 256 256 1"), "{}", ic(0));
    assert!(ic(1).contains("tile_size 128 128 1"), "{}", ic(1));
    let ct = dir.path().join("cfg").join("cfg.ct");
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).arg("validate").arg(&ct).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success() && !text.contains(": error:"), "{text}");
    // Served as the file is: the .ct's levels and the file's are one texture.
    let file = CogSource::open(&cog, 256).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).args(["check", "--json"]).arg(&ct).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["servable"], true, "{v}");
    assert_eq!(v["levels"].as_array().unwrap().len(), file.desc().level_count(), "{v}");
}

/// GDAL's default RGB JPEG COG (stored as YCbCr), 300 x 200 in 128 x 128 tiles, written in
/// `dir` as `ycc.tif`.
fn ycbcr_cog(dir: &Path) -> std::path::PathBuf {
    const WRITE: &str = r#"
from osgeo import gdal
gdal.UseExceptions()
mem = gdal.GetDriverByName("MEM").Create("", 300, 200, 3, gdal.GDT_Byte)
for b in range(3):
    mem.GetRasterBand(b + 1).WriteRaster(0, 0, 300, 200, bytes(((x * (b + 2) + y * 3) // 4) & 255 for y in range(200) for x in range(300)))
gdal.Translate("ycc.tif", mem, format="COG", creationOptions=["COMPRESS=JPEG", "BLOCKSIZE=128"])
"#;
    crate::common::gdal::write_with(WRITE, &[], dir, "a YCbCr JPEG COG");
    let path = dir.join("ycc.tif");
    let info = Command::new("gdalinfo").arg(&path).output().unwrap();
    assert!(String::from_utf8_lossy(&info.stdout).contains("COMPRESSION=YCbCr JPEG"));
    path
}

/// Level 0 of `src` (rows in increasing t).
fn level0(src: &CogSource) -> Vec<u8> {
    crate::cog::level(src, 0).unwrap()
}

#[test]
fn clipprep_input_takes_gdals_default_ycbcr_jpeg_cog_as_clipmapd_serves_it() {
    let dir = tempfile::tempdir().unwrap();
    let cog = ycbcr_cog(dir.path());
    let out = Command::new(env!("CARGO_BIN_EXE_clipprep"))
        .arg("--input")
        .arg(&cog)
        .args(["--format", "rgb8", "--tile", "128", "--clip", "128", "--pad", "--out", "prep"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{text}");
    // Level 0 of the pyramid is the COG's as served, texel for texel (padded with black).
    let served = level0(&CogSource::open(&cog, 128).unwrap());
    let ct = dir.path().join("prep").join("prep.ct");
    let plan = clipmap::plan::load_clip_texture(&ct, &Default::default()).unwrap().plan.unwrap();
    let prepared = clipmap::source::open_plan(plan, &Default::default()).unwrap();
    let got = crate::cog::level(prepared.as_ref(), 0).unwrap();
    let w = 512usize;
    for t in 0..200usize {
        assert_eq!(&got[t * w * 3..][..300 * 3], &served[t * 300 * 3..][..300 * 3], "row {t}");
    }
}

#[test]
fn a_growing_patch_takes_gdals_default_ycbcr_jpeg_cog_as_clipmapd_serves_it() {
    let dir = tempfile::tempdir().unwrap();
    let cog = ycbcr_cog(dir.path());
    let bytes = std::fs::read(&cog).unwrap();
    let grid = clipmap::growing::Grid::new([0.0, 0.0], 1.0, 256, 3, 1).unwrap();
    let (w, h, texels) = clipmap::growing::input::decode_image(&grid, &bytes, 1 << 20, "ycc.tif").unwrap();
    assert_eq!((w, h), (300, 200));
    // The image's rows top-down: the served level's from its top.
    let served = level0(&CogSource::open(&cog, 128).unwrap());
    for y in 0..200usize {
        assert_eq!(&texels[y * 900..][..900], &served[(199 - y) * 900..][..900], "row {y}");
    }
    // Grey from the same: the luminance, as the image decoders give it.
    let grey = clipmap::growing::Grid::new([0.0, 0.0], 1.0, 256, 1, 1).unwrap();
    let (_, _, l) = clipmap::growing::input::decode_image(&grey, &bytes, 1 << 20, "ycc.tif").unwrap();
    assert_eq!(l.len(), 300 * 200);
}

#[test]
fn clipprep_carries_the_dems_gdal_nodata_by_default() {
    let dir = tempfile::tempdir().unwrap();
    const WRITE: &str = r#"
import struct
from osgeo import gdal
gdal.UseExceptions()
mem = gdal.GetDriverByName("MEM").Create("", 64, 64, 1, gdal.GDT_Float32)
vals = [-9999.0 if (x + y) % 7 == 0 else 100.0 + x + y * 0.5 for y in range(64) for x in range(64)]
mem.GetRasterBand(1).WriteRaster(0, 0, 64, 64, struct.pack("<4096f", *vals))
mem.GetRasterBand(1).SetNoDataValue(-9999)
gdal.Translate("dem.tif", mem, format="GTiff", creationOptions=["TILED=YES", "BLOCKXSIZE=32", "BLOCKYSIZE=32"])
"#;
    crate::common::gdal::write_with(WRITE, &[], dir.path(), "a DEM with GDAL_NODATA");
    let out = Command::new(env!("CARGO_BIN_EXE_clipprep"))
        .args(["--input", "dem.tif", "--format", "l32f", "--tile", "32", "--clip", "32", "--out", "d"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{text}");
    let ct = std::fs::read_to_string(dir.path().join("d").join("d.ct")).unwrap();
    assert!(ct.contains("#clipmap height_nodata -9999"), "{ct}");
    // A nodata the output cannot store is refused, saying what to pass.
    let out = Command::new(env!("CARGO_BIN_EXE_clipprep"))
        .args(["--input", "dem.tif", "--format", "l16", "--height-scale", "0.01", "--tile", "32", "--clip", "32"])
        .args(["--out", "e"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && text.contains("its GDAL_NODATA -9999") && text.contains("--height-nodata"),
        "{text}"
    );
    assert!(!dir.path().join("e").exists());
}

#[test]
fn a_uint16_or_scaled_int16_dem_is_served_as_heights_with_gdals_scale_and_offset() {
    let dir = tempfile::tempdir().unwrap();
    const WRITE: &str = r#"
import struct
from osgeo import gdal
gdal.UseExceptions()
for name, gtype, code, scale, offset in [("u16", gdal.GDT_UInt16, "H", 0.1, -500.0), ("i16", gdal.GDT_Int16, "h", 0.5, None)]:
    mem = gdal.GetDriverByName("MEM").Create("", 64, 64, 1, gtype)
    b = mem.GetRasterBand(1)
    b.WriteRaster(0, 0, 64, 64, struct.pack("<4096" + code, *[(x * 64 + y) % 5000 for y in range(64) for x in range(64)]))
    b.SetScale(scale)
    if offset is not None:
        b.SetOffset(offset)
    b.SetNoDataValue(0)
    gdal.Translate(name + ".tif", mem, format="COG", creationOptions=["BLOCKSIZE=128"])
"#;
    crate::common::gdal::write_with(WRITE, &[], dir.path(), "scaled 16-bit DEMs");
    use clipmap::height::HeightStorage;
    let u16s = CogSource::open(&dir.path().join("u16.tif"), 64).unwrap();
    assert_eq!(u16s.desc().format(), clipmap::texel::TexelFormat::L16, "heights get no alpha");
    let h = u16s.heights().expect("a scaled UInt16 band is heights");
    assert_eq!(h.format.storage(), HeightStorage::U16);
    assert_eq!((h.format.scale(), h.format.offset(), h.format.nodata()), (0.1, -500.0, Some(0.0)));
    let i16s = CogSource::open(&dir.path().join("i16.tif"), 64).unwrap();
    let h = i16s.heights().expect("Int16 is heights");
    assert_eq!(h.format.storage(), HeightStorage::I16);
    assert_eq!((h.format.scale(), h.format.offset(), h.format.nodata()), (0.5, 0.0, Some(0.0)));
    // Texels as stored: the metres are the format's.
    let l0 = level0(&u16s);
    let v = u16::from_le_bytes([l0[2], l0[3]]);
    assert_eq!(v, 127, "texel (1, 0) is pixel (1, 63): (1 x 64 + 63) mod 5000");
}

/// A 4 x 3 image in one uncompressed tile of `bits`-bit samples of SampleFormat `format`, rows
/// top-down, with GDAL_NODATA 0 when `nodata`, and no overviews: levels 1 (2 x 1) and 2 (1 x 1)
/// are built at open.
fn four_by_three(bits: u64, format: u64, rows: [[i32; 4]; 3], nodata: bool) -> Vec<u8> {
    let n = bits / 8;
    let mut data = Vec::new();
    for row in rows {
        for v in row {
            data.extend_from_slice(&v.to_le_bytes()[..n as usize]);
        }
    }
    let mut ifd = vec![
        (256, 16, 1, 4),
        (257, 16, 1, 3),
        (258, 3, 1, bits),
        (259, 3, 1, 1),
        (262, 3, 1, 1),
        (277, 3, 1, 1),
        (322, 16, 1, 4),
        (323, 16, 1, 3),
        (324, 16, 1, DATA_AT),
        (325, 16, 1, 12 * n),
        (339, 3, 1, format),
    ];
    if nodata {
        ifd.push((42113, 2, 2, u64::from(b'0')));
    }
    bigtiff(&[ifd], &data)
}

#[test]
fn levels_built_past_the_overviews_pair_rows_from_the_bottom_and_round_as_documented() {
    let dir = tempfile::tempdir().unwrap();
    // Colour: rows paired from the texture's t = 0 (the image's bottom row); the odd top row is
    // left out; each sample floor((a + b + c + d + 2) / 4); a side of 1 pairs a row with itself.
    let path = write(dir.path(), "l8.tif", &four_by_three(8, 1, [[200; 4], [10, 11, 12, 13], [1, 2, 3, 4]], false));
    let src = CogSource::open(&path, 4).unwrap();
    assert_eq!(crate::cog::level(&src, 1).unwrap(), [6, 8], "(1 + 2 + 10 + 11 + 2) / 4, (3 + 4 + 12 + 13 + 2) / 4");
    assert_eq!(crate::cog::level(&src, 2).unwrap(), [7], "(6 + 8 + 6 + 8 + 2) / 4");
    // Heights, 16-bit signed, nodata 0: the mean of the texels with data, halves up (towards
    // +infinity: -2.5 is -2); a mean that rounds to nodata moves one step off it, up when the
    // exact mean is nodata or above, down when below.
    let rows = [[100; 4], [-2, -3, -1, 1], [0, 0, -3, 3]];
    let path = write(dir.path(), "i16.tif", &four_by_three(16, 2, rows, true));
    let src = CogSource::open(&path, 4).unwrap();
    let i16s = |b: Vec<u8>| b.chunks_exact(2).map(|c| i16::from_le_bytes([c[0], c[1]])).collect::<Vec<_>>();
    assert_eq!(i16s(crate::cog::level(&src, 1).unwrap()), [-2, 1], "mean(-2, -3) = -2.5; mean(-3, 3, -1, 1) = 0");
    assert_eq!(i16s(crate::cog::level(&src, 2).unwrap()), [-1], "mean(-2, 1) = -0.5 rounds to 0, below it");
}

/// The fault: `--nan nodata` was refused unless `--height-nodata` was given, even when the elevation
/// model carries its own nodata (GDAL_NODATA), which `clipprep` keeps by default.
#[test]
fn clipprep_nan_nodata_refused_a_dem_whose_gdal_nodata_gives_the_value() {
    let dir = tempfile::tempdir().unwrap();
    const WRITE: &str = r#"
import struct
from osgeo import gdal
gdal.UseExceptions()
for name, nodata in [("dem.tif", -9999), ("bare.tif", None)]:
    mem = gdal.GetDriverByName("MEM").Create("", 64, 64, 1, gdal.GDT_Float32)
    vals = [float("nan") if (x + y) % 9 == 0 else 100.0 + x + y * 0.5 for y in range(64) for x in range(64)]
    mem.GetRasterBand(1).WriteRaster(0, 0, 64, 64, struct.pack("<4096f", *vals))
    if nodata is not None:
        mem.GetRasterBand(1).SetNoDataValue(nodata)
    gdal.Translate(name, mem, format="GTiff", creationOptions=["TILED=YES", "BLOCKXSIZE=32", "BLOCKYSIZE=32"])
"#;
    crate::common::gdal::write_with(WRITE, &[], dir.path(), "DEMs with NaN, with and without GDAL_NODATA");
    let prep = |input: &str, out: &str| {
        Command::new(env!("CARGO_BIN_EXE_clipprep"))
            .args([
                "--input", input, "--format", "l32f", "--nan", "nodata", "--tile", "32", "--clip", "32", "--out", out,
            ])
            .current_dir(dir.path())
            .output()
            .unwrap()
    };
    let out = prep("dem.tif", "d");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{text}");
    let ct = std::fs::read_to_string(dir.path().join("d").join("d.ct")).unwrap();
    assert!(ct.contains("#clipmap height_nodata -9999"), "{ct}");
    assert!(ct.contains("non-finite input stored as nodata"), "{ct}");
    // Without a nodata anywhere, the refusal names the input and what to pass; nothing written.
    let out = prep("bare.tif", "e");
    let text = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(text.contains("bare.tif") && text.contains("--height-nodata V"), "{text}");
    assert!(!dir.path().join("e").exists());
}
