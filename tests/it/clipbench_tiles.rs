//! `clipbench tiles --quick --json` cuts an image into an XYZ tree with GDAL's `gdal2tiles.py`,
//! writes the same tiles into a PMTiles (the reference writer) and an MBTiles, serves the tree
//! and the PMTiles with nginx, reads every level-0 tile of each kind with ours, GDAL and curl, and
//! flies over the XYZ service with latency added; it keeps its JSON contract: every field the
//! tiles issue names is there with its type (`null` exactly where a kind has none), no texel
//! differs from GDAL's decode of its tile, a warm pass costs at most one request a tile, and a
//! PMTiles over HTTP opens with one request of at most 16 KiB. No timing is asserted. Needs
//! GDAL, Python's `pmtiles`, nginx and curl (`.ci/run` installs them).

use serde_json::Value;

fn number(v: &Value, what: &str) -> f64 {
    let x = v.as_f64().unwrap_or_else(|| panic!("{what} is not a number: {v}"));
    assert!(x.is_finite() && x >= 0.0, "{what} = {x}");
    x
}

#[test]
fn tiles_json_has_the_contract_fields_and_every_texel_is_gdals() {
    let dir = tempfile::tempdir().unwrap();
    let args: [&std::ffi::OsStr; 5] =
        ["tiles".as_ref(), "--quick".as_ref(), "--json".as_ref(), "--dir".as_ref(), dir.path().as_os_str()];
    let v = crate::common::clipbench_json(&args);
    let level0 = v["data"]["level0_tiles"].as_u64().unwrap();
    assert_eq!(level0, 64, "quick: zoom 3 is level 0: {v}");
    // (kind, read by GDAL, over HTTP)
    for (name, gdal, http) in
        [("xyz", true, true), ("pmtiles_http", false, true), ("pmtiles_local", false, false), ("mbtiles", true, false)]
    {
        let k = &v["kinds"][name];
        let what = |f: &str| format!("{name}.{f}");
        assert_eq!(k["tiles"].as_u64(), Some(level0), "{name}: {k}");
        assert!(number(&k["tiles_per_s"], &what("tiles_per_s")) > 0.0, "{name}: {k}");
        for (field, present) in [
            ("tiles_per_s_gdal", gdal),
            ("vs_gdal", gdal),
            ("tiles_per_s_gdal_one_process", gdal),
            ("gdal_wrong_texels", gdal),
            ("curl_ceiling_tiles_per_s", http),
            ("vs_curl", http),
            ("requests", http),
            ("requests_per_tile_cold", http),
            ("requests_per_tile_warm", http),
            ("requests_gdal", gdal && http),
            ("open_requests", http),
            ("open_bytes", http),
            ("core_us_per_tile_curl", http),
        ] {
            assert!(k.get(field).is_some(), "{name}: no field {field}: {k}");
            if present {
                number(&k[field], &what(field));
            } else {
                assert!(k[field].is_null(), "{name}.{field} should be null: {k}");
            }
        }
        for field in ["open_s", "decode_share", "cores_busy", "core_us_per_tile"] {
            number(&k[field], &what(field));
        }
        assert_eq!(k["wrong_texels"].as_u64(), Some(0), "{name}: a texel differs from GDAL's decode: {k}");
        assert_eq!(k["failed_reads"].as_u64(), Some(0), "{name}: {k}");
        if gdal {
            assert_eq!(k["gdal_wrong_texels"].as_u64(), Some(0), "{name}: GDAL read other tiles than ours: {k}");
            let want = number(&k["tiles_per_s"], "") / number(&k["tiles_per_s_gdal"], "");
            assert!((number(&k["vs_gdal"], "") - want).abs() <= 1e-9 * want, "{name}: {k}");
        }
        if http {
            // The requests of a pass are counted at the server: one a tile, cold and warm.
            let warm = number(&k["requests_per_tile_warm"], "");
            assert!(warm > 0.0 && warm <= 1.0, "{name}: {warm} requests a tile warm: {k}");
            let cold = number(&k["requests_per_tile_cold"], "");
            assert!((1.0..=2.0).contains(&cold), "{name}: {cold} requests a tile cold: {k}");
            let open = k["open_requests"].as_u64().unwrap();
            assert_eq!(k["requests"].as_u64(), Some(open + (cold * level0 as f64).round() as u64), "{name}: {k}");
        }
    }
    let x = &v["kinds"]["xyz"];
    assert_eq!((x["open_requests"].as_u64(), x["open_bytes"].as_u64()), (Some(0), Some(0)), "{x}");
    assert_eq!(x["requests_per_tile_cold"].as_f64(), Some(1.0), "a template fetches each tile once: {x}");
    let p = &v["kinds"]["pmtiles_http"];
    assert_eq!(p["open_requests"].as_u64(), Some(1), "a PMTiles opens with one request: {p}");
    let open_bytes = p["open_bytes"].as_u64().unwrap();
    assert!((1..=16384).contains(&open_bytes), "the open read {open_bytes} bytes: {p}");
    // GDAL 3.6 has no PMTiles driver.
    assert!(v["kinds"]["pmtiles_local"]["gdal_driver"].is_null() && p["gdal_driver"].is_null(), "{v}");

    let f = &v["flight"];
    assert_eq!(f["texels_per_tick"].as_i64(), Some(32), "{f}");
    assert_eq!(f["added_latency_ms"].as_u64(), Some(20), "{f}");
    let share = number(&f["level0_shown_share"], "flight.level0_shown_share");
    assert!(share <= 1.0, "{f}");
    let legs = f["legs"].as_array().unwrap();
    assert!(!legs.is_empty() && legs[0]["texels_per_tick"].as_i64() == Some(32), "{f}");
    assert_eq!(legs[0]["level0_shown_share"].as_f64(), Some(share), "{f}");
    // The largest speed holding 95 % is one of the legs that held it, or null when none did.
    match f["max_texels_per_tick"].as_i64() {
        Some(s) => assert!(
            legs.iter()
                .any(|l| l["texels_per_tick"].as_i64() == Some(s) && l["level0_shown_share"].as_f64().unwrap() >= 0.95),
            "{f}"
        ),
        None => assert!(f["max_texels_per_tick"].is_null() && share < 0.95, "{f}"),
    }
    assert!(f["texels_checked"].as_u64().unwrap() > 0, "the flight published level-0 texels: {f}");
    assert_eq!(f["wrong_texels"].as_u64(), Some(0), "{f}");
    assert_eq!(v["goals"]["no_wrong_texels"].as_bool(), Some(true), "{v}");
    assert!(v["tiles_per_s_decode_only"].as_f64().unwrap() > 0.0, "{v}");
}
