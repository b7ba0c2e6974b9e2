//! Georeferencing equals GDAL's (docs/GEOREF.md): COGs written by GDAL in the test in EPSG:4326,
//! EPSG:3857 and UTM zone 33N (EPSG:32633, plus one marked PixelIsPoint and one rotated, which
//! GDAL writes as a ModelTransformationTag); `cliptex info --json`'s
//! geotransform is `gdalinfo -json`'s, every level's transform is the one GDAL gives its
//! overview (`gdal_translate -ovr`), and `cliptex locate` agrees with `gdaltransform` to a
//! millionth of a texel at level 0, both ways.

use crate::common::gdal::python;
use clipmap::source::CogSource;
use std::path::Path;
use std::process::Command;

/// Writes the COGs, then prints per file one JSON line: its size, level 0's geotransform and
/// each overview's size and geotransform, as GDAL reads them.
const WRITE: &str = r#"
import json
from osgeo import gdal, osr
gdal.UseExceptions()
H = 20037508.342789244
def make(name, epsg, gt, w, h, point=False):
    d = gdal.GetDriverByName('MEM').Create('', w, h, 1, gdal.GDT_Byte)
    d.GetRasterBand(1).WriteRaster(0, 0, w, h, bytes((i * 7) % 251 for i in range(w)) * h)
    d.SetGeoTransform(gt)
    s = osr.SpatialReference(); s.ImportFromEPSG(epsg); d.SetProjection(s.ExportToWkt())
    if point:
        d.SetMetadataItem('AREA_OR_POINT', 'Point')
    gdal.Translate(name, d, format='COG', creationOptions=['BLOCKSIZE=256'])
    f = gdal.Open(name)
    b = f.GetRasterBand(1)
    levels = [[f.RasterXSize, f.RasterYSize, list(f.GetGeoTransform())]]
    for k in range(b.GetOverviewCount()):
        o = gdal.Translate('/vsimem/o.tif', f, overviewLevel=k)
        levels.append([o.RasterXSize, o.RasterYSize, list(o.GetGeoTransform())])
    print(json.dumps({"name": name, "levels": levels}))
make('g4326.tif', 4326, [-180, 360 / 2048, 0, 90, 0, -180 / 1024], 2048, 1024)
make('g3857.tif', 3857, [-H, 2 * H / 2048, 0, H, 0, -2 * H / 2048], 2048, 2048)
make('g32633.tif', 32633, [400000.5, 10.25, 0, 4700000.75, 0, -10.25], 1536, 1024)
make('p32633.tif', 32633, [400000.5, 10.25, 0, 4700000.75, 0, -10.25], 1536, 1024, point=True)
make('r32633.tif', 32633, [400000.5, 10, 2.5, 4700000.75, 1.5, -10], 1024, 1024)
# Not reported: georeferenced by ground control points, and in a CRS without an EPSG code.
d = gdal.GetDriverByName('MEM').Create('', 512, 512, 1, gdal.GDT_Byte)
s = osr.SpatialReference(); s.ImportFromEPSG(4326)
d.SetGCPs([gdal.GCP(10 + i, 50 - j, 0, 256 * i, 256 * j) for i in range(2) for j in range(2)], s.ExportToWkt())
gdal.Translate('gcps.tif', d, format='COG', creationOptions=['BLOCKSIZE=256'])
d = gdal.GetDriverByName('MEM').Create('', 512, 512, 1, gdal.GDT_Byte)
d.SetGeoTransform([3500000, 10, 0, 5500000, 0, -10])
s = osr.SpatialReference(); s.ImportFromProj4('+proj=tmerc +lat_0=0 +lon_0=9 +k=1 +x_0=3500000 +y_0=0 +ellps=bessel +units=m +no_defs')
d.SetProjection(s.ExportToWkt())
gdal.Translate('custom.tif', d, format='COG', creationOptions=['BLOCKSIZE=256'])
"#;

fn gdal_files(dir: &Path) -> Vec<serde_json::Value> {
    let mut child = Command::new(python())
        .current_dir(dir)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("python3 with GDAL's binding (python3-gdal, which .ci/run installs)");
    use std::io::Write;
    child.stdin.take().unwrap().write_all(WRITE.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "GDAL failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

fn run(program: &str, args: &[&str], dir: &Path, stdin: &str) -> String {
    let mut child = Command::new(program)
        .args(args)
        .current_dir(dir)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{program}: {e}"));
    use std::io::Write;
    child.stdin.take().unwrap().write_all(stdin.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{program} {args:?}: {text}{}", String::from_utf8_lossy(&out.stderr));
    text
}

fn numbers(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol * x.abs().max(y.abs()).max(1.0))
}

#[test]
fn every_levels_transform_and_every_located_texel_equal_gdals() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cliptex = env!("CARGO_BIN_EXE_cliptex");
    let mut worst = [0.0f64; 2];
    for file in gdal_files(d) {
        let name = file["name"].as_str().unwrap();
        let levels = file["levels"].as_array().unwrap();
        // cliptex info --json: gdalinfo -json's geoTransform, exactly.
        let gdalinfo: serde_json::Value = serde_json::from_str(&run("gdalinfo", &["-json", name], d, "")).unwrap();
        let info: serde_json::Value = serde_json::from_str(&run(cliptex, &["info", "--json", name], d, "")).unwrap();
        let ours = numbers(&info["georef"]["geotransform"]);
        assert_eq!(ours, numbers(&gdalinfo["geoTransform"]), "{name}: {info}");
        let epsg: u64 = name[1..name.len() - 4].parse().unwrap();
        assert_eq!(info["georef"]["epsg"], epsg, "{name}");
        // Every overview: GDAL's size and transform are our level's.
        let src = CogSource::open(&d.join(name), 1024).unwrap();
        let g = src.georef().unwrap().expect("georeferenced");
        assert!(levels.len() >= 3, "{name}: GDAL wrote overviews: {levels:?}");
        for (k, l) in levels.iter().enumerate() {
            let size = [l[0].as_u64().unwrap(), l[1].as_u64().unwrap()];
            assert_eq!(g.level_size(k as u32), size, "{name} level {k}");
            let ours = g.level_transform(k as u32).0;
            assert!(close(&ours, &numbers(&l[2]), 1e-15), "{name} level {k}: {ours:?} vs GDAL's {:?}", l[2]);
        }
        // Points inside: our texel is gdaltransform's (pixel, height - line).
        let [w, h] = g.size();
        let texels = [[0.5, 0.5], [w as f64 / 3.0, h as f64 * 0.7], [w as f64 - 0.25, h as f64 - 0.125], [17.3, 900.9]];
        for [s, t] in texels {
            let [lon, lat] = g.texel_to_lonlat(0, [s, t]).unwrap();
            let ll = format!("{lon},{lat}");
            let located: serde_json::Value =
                serde_json::from_str(&run(cliptex, &["locate", name, &format!("--lonlat={ll}"), "--json"], d, ""))
                    .unwrap();
            let gdal =
                run("gdaltransform", &["-i", "-t_srs", "EPSG:4326", "-output_xy", name], d, &format!("{lon} {lat}\n"));
            let px: Vec<f64> = gdal.split_whitespace().map(|v| v.parse().unwrap()).collect();
            let want = [px[0], h as f64 - px[1]];
            let got = [located["s"].as_f64().unwrap(), located["t"].as_f64().unwrap()];
            for i in 0..2 {
                worst[0] = worst[0].max((got[i] - want[i]).abs());
                assert!(
                    (got[i] - want[i]).abs() < 1e-6,
                    "{name} ({lon}, {lat}): ours {got:?}, gdaltransform's {want:?}"
                );
            }
            // The reverse: --texel gives gdaltransform's longitude / latitude of the pixel.
            let back: serde_json::Value = serde_json::from_str(&run(
                cliptex,
                &["locate", name, "--texel", &format!("{},{}", want[0], want[1]), "--json"],
                d,
                "",
            ))
            .unwrap();
            let gdal = run(
                "gdaltransform",
                &["-t_srs", "EPSG:4326", "-output_xy", name],
                d,
                &format!("{} {}\n", px[0], px[1]),
            );
            let ll: Vec<f64> = gdal.split_whitespace().map(|v| v.parse().unwrap()).collect();
            for (i, key) in ["lon", "lat"].into_iter().enumerate() {
                let ours = back[key].as_f64().unwrap();
                worst[1] = worst[1].max((ours - ll[i]).abs());
                assert!(
                    (ours - ll[i]).abs() < 1e-9,
                    "{name} texel {want:?}: {key} {ours} vs gdaltransform's {}",
                    ll[i]
                );
            }
        }
    }
    println!(
        "worst |texel - gdaltransform's| {:e}, worst |lon/lat - gdaltransform's| {:e} degrees",
        worst[0], worst[1]
    );
}

#[test]
fn a_cog_without_usable_georeferencing_says_why_and_a_user_defined_crs_keeps_map_coordinates() {
    let cliptex = env!("CARGO_BIN_EXE_cliptex");
    let plain = crate::cog::fixture("rgba_100x75.tif");
    let out = Command::new(cliptex).args(["info", "--json"]).arg(&plain).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["georef"].is_null() && v.get("georef_problem").is_none(), "{v}");
    let out = Command::new(cliptex).arg("info").arg(&plain).output().unwrap();
    assert!(String::from_utf8_lossy(&out.stdout).contains("georeferencing: none"), "{out:?}");
    let out = Command::new(cliptex).args(["locate", "--lonlat", "1,2"]).arg(&plain).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("has no georeferencing"), "{out:?}");
    // A GDAL file whose ModelPixelScale x is zeroed: still served, its georeferencing refused.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    gdal_files(d);
    let mut bytes = std::fs::read(d.join("g32633.tif")).unwrap();
    let scale: Vec<u8> = [10.25f64, 10.25, 0.0].iter().flat_map(|v| v.to_le_bytes()).collect();
    let at = bytes.windows(24).position(|w| w == scale).expect("ModelPixelScale's values");
    bytes[at..at + 8].copy_from_slice(&0f64.to_le_bytes());
    std::fs::write(d.join("zero.tif"), &bytes).unwrap();
    let out = Command::new(cliptex).args(["info", "--json", "zero.tif"]).current_dir(d).output().unwrap();
    assert!(out.status.success(), "{out:?}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["georef"].is_null(), "{v}");
    let problem = v["georef_problem"].as_str().unwrap();
    assert!(problem.contains("IFD 0 tag ModelPixelScaleTag (33550)") && problem.contains("non-zero"), "{problem}");
    // Ground control points: not read, and said so.
    let out = Command::new(cliptex).args(["info", "--json", "gcps.tif"]).current_dir(d).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let problem = v["georef_problem"].as_str().unwrap();
    assert!(problem.contains("ModelTiepointTag (33922)") && problem.contains("4 tiepoints"), "{problem}");
    // A user-defined CRS: map coordinates, no longitude / latitude, and its citation.
    let out = Command::new(cliptex).args(["info", "--json", "custom.tif"]).current_dir(d).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["georef"]["epsg"].is_null() && v["georef"]["geotransform"][0] == 3500000.0, "{v}");
    assert!(v["georef"]["crs"].as_str().unwrap().contains("user-defined (GCS Name = unknown; Datum = "), "{v}");
    let out = Command::new(cliptex)
        .args(["locate", "custom.tif", "--texel", "10,20", "--json"])
        .current_dir(d)
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!((v["x"].as_f64(), v["y"].as_f64()), (Some(3500100.0), Some(5500000.0 - 4920.0)), "{v}");
    assert!(v["lon"].is_null(), "{v}");
    let out = Command::new(cliptex).args(["locate", "custom.tif", "--lonlat", "9,45"]).current_dir(d).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no definition known here"), "{out:?}");
    // Outside the texture and beyond the projection: refused with the domain.
    let out = Command::new(cliptex).args(["locate", "g3857.tif", "--lonlat", "10,86"]).current_dir(d).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("85.05112877980659"), "{out:?}");
    let out = Command::new(cliptex).args(["locate", "g32633.tif", "--texel=-1,0"]).current_dir(d).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("outside level 0"), "{out:?}");
}

/// `CENTRE LONLAT` (and `VIEW CENTRE main LONLAT`) of each point, on the `clipmapd` answering on
/// `socket` serving `place`: the centre is the texel `cliptex locate --lonlat` gives, floored, the
/// same `CENTRE <s> <t>` of that texel sets, and `STATS` shows its longitude / latitude back
/// within a texel.
pub(crate) fn centre_lonlat_lands_on_locates_texel(place: &str, socket: &Path, dir: &Path, points: &[[f64; 2]]) {
    let cliptex = env!("CARGO_BIN_EXE_cliptex");
    let mut c = crate::common::flight::Control::open(socket);
    let locate = |lon: f64, lat: f64| -> [f64; 2] {
        let out = run(cliptex, &["locate", place, &format!("--lonlat={lon},{lat}"), "--json"], dir, "");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        [v["s"].as_f64().unwrap(), v["t"].as_f64().unwrap()]
    };
    for &[lon, lat] in points {
        let [s, t] = locate(lon, lat);
        let want = [s.floor() as i64, t.floor() as i64];
        assert_eq!(
            c.ask(&format!("CENTRE {} {}", want[0] + 3, want[1])),
            format!("OK centre {} {}", want[0] + 3, want[1])
        );
        assert_eq!(
            c.ask(&format!("CENTRE LONLAT {lon} {lat}")),
            format!("OK centre {} {}", want[0], want[1]),
            "{place} {lon},{lat}"
        );
        let (st, ok) = crate::common::flight::wait_stats(&mut c, std::time::Duration::from_secs(20), |st| {
            let tick = if st["tick"].is_object() { &st["tick"] } else { st };
            tick["centre"] == serde_json::json!(want) && tick["views"][0]["centre"] == serde_json::json!(want)
        });
        assert!(ok, "{place}: the centre never reached {want:?}: {st}");
        let tick = if st["tick"].is_object() { &st["tick"] } else { &st };
        let back = numbers(&tick["centre_lonlat"]);
        let [bs, bt] = locate(back[0], back[1]);
        assert!(
            (bs - s).abs() <= 1.0 && (bt - t).abs() <= 1.0,
            "{place}: {back:?} is texel ({bs}, {bt}), not near ({s}, {t})"
        );
        assert_eq!(
            [bs.floor() as i64, bt.floor() as i64],
            want,
            "{place}: STATS's centre_lonlat {back:?} is the centre's texel"
        );
        let main = &tick["views"][0];
        assert_eq!(main["name"], "main");
        assert_eq!(numbers(&main["centre_lonlat"]), back, "{place}: the primary view's centre_lonlat: {main}");
        assert_eq!(
            c.ask(&format!("VIEW CENTRE main LONLAT {lon} {lat}")),
            format!("OK view main centre {} {}", want[0], want[1])
        );
    }
    // Refused: beyond Web Mercator's domain (the domain said), not a number.
    let r = c.ask("CENTRE LONLAT 10 86");
    assert!(r.starts_with("ERR ") && r.contains("85.05"), "{place}: {r}");
    let r = c.ask("CENTRE LONLAT NaN 10");
    assert!(r.starts_with("ERR ") && r.contains("not a finite number"), "{place}: {r}");
    let r = c.ask("VIEW CENTRE main LONLAT 10 86");
    assert!(r.starts_with("ERR ") && r.contains("85.05"), "{place}: {r}");
    assert_eq!(c.ask("PING"), "OK pong", "the connection goes on after a refusal");
}

#[test]
fn clipmapd_takes_centres_in_lonlat_through_a_cogs_georeferencing_and_refuses_them_without_one() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    gdal_files(d);
    let points = [[13.4, 52.5], [-122.42, 37.77], [0.0001, -0.0001], [179.9, -60.0]];
    let served = crate::common::gdal::Served::start(&d.join("g3857.tif"), 256, "m", d);
    centre_lonlat_lands_on_locates_texel("g3857.tif", &d.join("m.sock"), d, &points);
    drop(served);
    let served = crate::common::gdal::Served::start(&d.join("g4326.tif"), 256, "g", d);
    let mut c = crate::common::flight::Control::open(&d.join("g.sock"));
    let want = {
        let g = CogSource::open(&d.join("g4326.tif"), 256).unwrap().georef().unwrap().cloned().unwrap();
        g.lonlat_to_texel(0, [13.4, 52.5]).unwrap().map(|x| x.floor() as i64)
    };
    assert_eq!(c.ask("center lonlat 13.4 52.5"), format!("OK centre {} {}", want[0], want[1]), "{}", served.log());
    let r = c.ask("CENTRE LONLAT 10 91");
    assert!(r.starts_with("ERR CENTRE LONLAT 10 91: "), "{r}");
    drop(served);
    // A texture without georeferencing: refused, saying which sources have it; STATS says null.
    let sock = d.join("h.sock");
    let mut child = Command::new(env!("CARGO_BIN_EXE_clipmapd"))
        .args(["--source", "hash", "--size", "4096", "--tile", "64", "--clip", "256", "--name", "h", "--shm-dir"])
        .arg(d)
        .arg("--socket")
        .arg(&sock)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t = std::time::Instant::now();
    while clipmap::shm::Client::attach(d, "h").is_err() {
        assert!(t.elapsed() < std::time::Duration::from_secs(30), "no mapping");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let mut c = crate::common::flight::Control::open(&sock);
    let r = c.ask("CENTRE LONLAT 13.4 52.5");
    assert!(r.starts_with("ERR ") && r.contains("no georeferencing") && r.contains("COG"), "{r}");
    let r = c.ask("VIEW CENTRE main LONLAT 13.4 52.5");
    assert!(r.starts_with("ERR ") && r.contains("no georeferencing"), "{r}");
    assert_eq!(c.ask("CENTRE 100 200"), "OK centre 100 200", "CENTRE <s> <t> as before");
    let st = c.stats();
    let tick = if st["tick"].is_object() { &st["tick"] } else { &st };
    assert!(tick["centre_lonlat"].is_null() && tick.get("centre_lonlat").is_some(), "{st}");
    let _ = child.kill();
    let _ = child.wait();
}

#[test]
fn clipmapd_publishes_each_levels_transform_in_the_mapping_as_gdal_gives_its_overviews() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let files = gdal_files(d);
    for (name, epsg, service) in [("g32633.tif", 32633, "u"), ("r32633.tif", 32633, "r"), ("g4326.tif", 4326, "w")] {
        let gdal = files.iter().find(|f| f["name"] == name).unwrap();
        let served = crate::common::gdal::Served::start(&d.join(name), 256, service, d);
        let client = clipmap::shm::Client::attach(d, service).unwrap();
        let g = client.georef.clone().unwrap_or_else(|| panic!("{name}: no georef block: {}", served.log()));
        assert_eq!(g.epsg, Some(epsg), "{name}");
        assert!(!g.definition.is_empty(), "{name}: the CRS's definition");
        let levels = gdal["levels"].as_array().unwrap();
        let gt0 = numbers(&levels[0][2]);
        assert_eq!(g.origin, [gt0[0], gt0[3]], "{name}: level 0's north-west corner");
        for (k, level) in levels.iter().enumerate() {
            let (w, h, gt) = (level[0].as_f64().unwrap(), level[1].as_f64().unwrap(), numbers(&level[2]));
            let terms = g.levels[k];
            assert!(
                close(&terms, &[gt[1], gt[2], gt[4], gt[5]], 1e-12),
                "{name}: level {k}: {terms:?} vs GDAL's {gt:?}"
            );
            // Texel (s, t) of level k is GDAL's pixel s, line h - t of that overview.
            for [s, t] in [[0.0, 0.0], [w, h], [w / 3.0, h / 7.0], [w - 0.5, 0.5]] {
                let (p, l) = (s, h - t);
                let want = [gt[0] + p * gt[1] + l * gt[2], gt[3] + p * gt[4] + l * gt[5]];
                let got = client.map_of_texel(k, s, t).unwrap();
                assert!(close(&got, &want, 1e-12), "{name}: level {k} texel ({s}, {t}): {got:?}, GDAL {want:?}");
            }
        }
        let attach = run(
            env!("CARGO_BIN_EXE_cliptex"),
            &["attach", service, "--shm-dir", &d.to_string_lossy(), "--once", "--json"],
            d,
            "",
        );
        let j: serde_json::Value = serde_json::from_str(&attach).unwrap();
        assert_eq!(j["georef"]["epsg"], epsg, "{name}: {attach}");
        drop(served);
    }
    // A texture without georeferencing publishes none.
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_clipmapd"))
        .args(["--source", "hash", "--size", "4096", "--tile", "64", "--clip", "256", "--name", "h", "--shm-dir"])
        .arg(dir.path())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t = std::time::Instant::now();
    let client = loop {
        if let Ok(c) = clipmap::shm::Client::attach(dir.path(), "h") {
            break c;
        }
        assert!(t.elapsed() < std::time::Duration::from_secs(30), "no mapping");
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    assert!(client.georef.is_none());
    let _ = child.kill();
    let _ = child.wait();
}
