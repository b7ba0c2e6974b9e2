//! A prepared pyramid's georeferencing from its input (docs/GEOREF.md, "Prepared pyramids"):
//! `clipprep --input` of a GeoTIFF that GDAL writes records the input's CRS and transform in the
//! `.ct`, `cliptex info` shows it and `clipmapd` publishes it in the mapping like a COG's: level 0's
//! geotransform is `gdalinfo`'s and each level's terms are its halvings. An input padded north to
//! the texture's size keeps every pixel where GDAL puts it. A procedural or non-georeferenced input
//! publishes none, and says so.

use crate::common::gdal::{python, Served};
use serde_json::Value;
use std::path::Path;
use std::process::Command;

/// Writes two GeoTIFFs (plain strips, as `gdal_translate` writes them by default): 512 x 512 in
/// UTM zone 33N, and 384 x 192 in EPSG:4326 (padded to 512 x 256 by `clipprep --pad`).
const WRITE: &str = r#"
from osgeo import gdal, osr
gdal.UseExceptions()
def make(name, epsg, gt, w, h):
    d = gdal.GetDriverByName('MEM').Create('', w, h, 3, gdal.GDT_Byte)
    for b in range(3):
        d.GetRasterBand(b + 1).WriteRaster(0, 0, w, h, bytes((i * 7 + b) % 251 for i in range(w)) * h)
    d.SetGeoTransform(gt)
    s = osr.SpatialReference(); s.ImportFromEPSG(epsg); d.SetProjection(s.ExportToWkt())
    gdal.Translate(name, d, format='GTiff')
make('utm.tif', 32633, [400000.5, 10.25, 0, 4700000.75, 0, -10.25], 512, 512)
make('wgs.tif', 4326, [10.0, 0.01, 0, 50.0, 0, -0.0125], 384, 192)
d = gdal.GetDriverByName('MEM').Create('', 256, 256, 3, gdal.GDT_Byte)
gdal.Translate('plain.tif', d, format='GTiff')
"#;

fn ok(program: &str, args: &[&str], dir: &Path) -> String {
    let out = Command::new(program).args(args).current_dir(dir).output().unwrap_or_else(|e| panic!("{program}: {e}"));
    assert!(
        out.status.success(),
        "{program} {args:?}: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `gdalinfo -json`'s geotransform of `file`.
fn gdalinfo(file: &Path) -> Vec<f64> {
    let j: Value = serde_json::from_str(&ok("gdalinfo", &["-json", file.to_str().unwrap()], Path::new("."))).unwrap();
    j["geoTransform"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
}

/// `clipprep --input FILE ... --out DIR`; the `.ct`.
fn prep(d: &Path, input: &str, out: &str, extra: &[&str]) -> std::path::PathBuf {
    let mut args = vec!["--tile", "64", "--clip", "64", "--format", "rgb8", "--out", out, "--json"];
    args.extend(extra);
    if !input.is_empty() {
        args.extend(["--input", input]);
    }
    let j: Value = serde_json::from_str(&ok(env!("CARGO_BIN_EXE_clipprep"), &args, d)).unwrap();
    d.join(j["ct"].as_str().unwrap())
}

fn info(ct: &Path, json: bool) -> String {
    let mut args = vec!["info", ct.to_str().unwrap()];
    if json {
        args.push("--json");
    }
    ok(env!("CARGO_BIN_EXE_cliptex"), &args, Path::new("."))
}

#[test]
fn a_pyramid_prepared_from_a_geotiff_publishes_gdals_transform_and_its_halvings_and_other_inputs_none() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut child = Command::new(python())
        .current_dir(d)
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("python3 with GDAL's binding (python3-gdal)");
    use std::io::Write;
    child.stdin.take().unwrap().write_all(WRITE.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "GDAL: {}", String::from_utf8_lossy(&out.stderr));

    // (input, EPSG, clipprep's options, level 0's size, the input's height).
    for (input, epsg, extra, size, image_h) in
        [("utm.tif", 32633, &[][..], [512u64, 512u64], 512u64), ("wgs.tif", 4326, &["--pad"][..], [512, 256], 192)]
    {
        let gt = gdalinfo(&d.join(input));
        let ct = prep(d, input, &format!("p-{epsg}"), extra);
        let text = std::fs::read_to_string(&ct).unwrap();
        assert!(text.contains(&format!("#clipmap georef_epsg {epsg}\n")), "{text}");
        // The texture's transform: GDAL's, its origin moved north over the rows padded above the
        // image (none for utm.tif).
        let pad = (size[1] - image_h) as f64;
        let want0 = [gt[0] - pad * gt[2], gt[1], gt[2], gt[3] - pad * gt[5], gt[4], gt[5]];
        let j: Value = serde_json::from_str(&info(&ct, true)).unwrap();
        assert_eq!(j["georef"]["epsg"], epsg, "{input}: {}", j["georef"]);
        let got: Vec<f64> =
            j["georef"]["geotransform"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        assert_eq!(got, want0, "{input}: cliptex info --json's geotransform against gdalinfo's {gt:?}");
        if pad == 0.0 {
            assert_eq!(got, gt, "{input}: gdalinfo's geotransform exactly");
        }
        assert!(info(&ct, false).contains(&format!("georef         EPSG:{epsg}")), "{}", info(&ct, false));

        // clipmapd publishes it in the mapping: level 0's origin and each level's halvings.
        let name = format!("prep{epsg}");
        let served = Served::start(&ct, 64, &name, d);
        let client = clipmap::shm::Client::attach(d, &name).unwrap();
        let g = client.georef.clone().unwrap_or_else(|| panic!("{input}: no georef block: {}", served.log()));
        assert_eq!(g.epsg, Some(epsg), "{input}");
        assert_eq!(g.origin, [want0[0], want0[3]], "{input}: level 0's north-west corner");
        assert_eq!(client.levels.len(), g.levels.len());
        for (k, terms) in g.levels.iter().enumerate() {
            let f = (1u64 << k) as f64;
            assert_eq!(*terms, [gt[1] * f, gt[2] * f, gt[4] * f, gt[5] * f], "{input}: level {k}");
        }
        // Every image pixel is where GDAL puts it: texel (s, t) of level 0 is the image's pixel s,
        // line image_h - t.
        for [s, t] in [[0.0, 0.0], [100.5, 17.25], [(size[0] - 1) as f64, (image_h - 1) as f64]] {
            let (p, l) = (s, image_h as f64 - t);
            let want = [gt[0] + p * gt[1] + l * gt[2], gt[3] + p * gt[4] + l * gt[5]];
            let got = client.map_of_texel(0, s, t).unwrap();
            for i in 0..2 {
                assert!(
                    (got[i] - want[i]).abs() <= 1e-9 * want[i].abs().max(1.0),
                    "{input} ({s}, {t}): {got:?} {want:?}"
                );
            }
        }
        drop(served);
    }

    // A GeoTIFF without georeferencing, and a procedural texture: none, said so.
    for (input, extra, out) in
        [("plain.tif", &[][..], "p-plain"), ("", &["--source", "hash", "--size", "512"][..], "p-hash")]
    {
        let ct = prep(d, input, out, extra);
        let text = std::fs::read_to_string(&ct).unwrap();
        assert!(!text.contains("#clipmap georef"), "{text}");
        assert!(text.contains("# Georeferencing: none"), "{text}");
        let j: Value = serde_json::from_str(&info(&ct, true)).unwrap();
        assert_eq!(j["georef"], Value::Null, "{out}");
        let human = info(&ct, false);
        assert!(human.contains("georef         none (no `#clipmap georef_` lines"), "{human}");
        let name = out.replace('-', "");
        let served = Served::start(&ct, 64, &name, d);
        let client = clipmap::shm::Client::attach(d, &name).unwrap();
        assert!(client.georef.is_none(), "{out}: {}", served.log());
        drop(served);
    }
}
