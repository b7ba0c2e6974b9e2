//! `clipbench formats --quick --json` keeps its contract: one row per texel format with its PSNR,
//! tile bytes, encoding time, ingest rate and bytes against RGBA8 (exactly an eighth for BC1 and
//! BC4, a quarter for BC7 and BC5), texpresso's BC1 beside ours, the ingest comparison, the 2^26
//! flight over a pre-encoded BC1 texture, and every goal with its figure. No timing is asserted:
//! the imagery is matplotlib's photograph where it is installed, else the procedural terrain,
//! and the report says which.

#[test]
fn formats_json_has_every_format_with_exact_byte_ratios_and_sane_psnr() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("formats.svg");
    let mut args: Vec<&std::ffi::OsStr> =
        ["formats", "--quick", "--json", "--plot"].iter().map(|a| a.as_ref()).collect();
    args.push(svg.as_os_str());
    let v = crate::common::clipbench_json(&args);
    // The chart: a point for level 0 and one for the view of each block format.
    let chart = std::fs::read_to_string(&svg).unwrap();
    assert_eq!(chart.matches("<circle").count(), 6, "{chart}");
    let rows = v["formats"].as_array().unwrap_or_else(|| panic!("formats in {v}"));
    let names: Vec<&str> = rows.iter().map(|r| r["format"].as_str().unwrap()).collect();
    assert_eq!(names, ["rgba8", "bc7", "bc1", "bc4", "bc5"]);
    for (r, (bytes, ratio)) in
        rows.iter().zip([(65536, 1.0), (16384, 0.25), (8192, 0.125), (8192, 0.125), (16384, 0.25)])
    {
        let f = r["format"].as_str().unwrap();
        for field in [
            "psnr_db",
            "tile_bytes",
            "encode_us_per_tile",
            "tiles_per_s_ingest",
            "mapping_bytes_vs_rgba8",
            "upload_bytes_per_frame_vs_rgba8",
        ] {
            assert!(r.get(field).is_some(), "{f}: no {field} in {r}");
        }
        assert_eq!(r["tile_bytes"], bytes, "{f}");
        assert_eq!(r["mapping_bytes_vs_rgba8"].as_f64(), Some(ratio), "{f}: {r}");
        assert_eq!(r["upload_bytes_per_frame_vs_rgba8"].as_f64(), Some(ratio), "{f}: {r}");
        assert!(r["tiles_per_s_ingest"].as_f64().unwrap() > 0.0, "{f}: {r}");
        if f == "rgba8" {
            assert_eq!(r["psnr_db"], serde_json::Value::Null, "lossless: {r}");
            assert_eq!(r["encode_us_per_tile"].as_f64(), Some(0.0));
        } else {
            let p = r["psnr_db"].as_f64().unwrap();
            assert!(p.is_finite() && (25.0..70.0).contains(&p), "{f}: PSNR {p} dB");
            assert!(r["encode_us_per_tile"].as_f64().unwrap() > 0.0, "{f}: {r}");
        }
    }
    let psnr = |i: usize| rows[i]["psnr_db"].as_f64().unwrap();
    assert!(psnr(1) > psnr(2), "BC7 ({}) is closer to the source than BC1 ({})", psnr(1), psnr(2));
    let t = &v["bc1_vs_texpresso"];
    for field in ["ours_mpx_per_s", "texpresso_mpx_per_s", "ratio", "texpresso_psnr_db"] {
        assert!(t[field].as_f64().is_some_and(|x| x.is_finite() && x > 0.0), "{field} in {t}");
    }
    let i = &v["ingest"];
    for field in [
        "bc1_encoded_vs_rgba8",
        "bc1_pre_encoded_vs_rgba8",
        "rgba8_cpu_us_per_tile",
        "bc1_encoded_cpu_us_per_tile",
        "bc1_encoded_vs_rgba8_cpu",
    ] {
        assert!(i[field].as_f64().is_some_and(|x| x.is_finite() && x > 0.0), "{field} in {i}");
    }
    assert!(i["tiles_per_run"].as_u64().unwrap() > 0, "{i}");
    // The study's format axis: the same byte ratios, and a finite PSNR in the view for each block
    // format (none for RGBA8, which is the reference).
    let view = v["view"].as_array().unwrap();
    let names: Vec<&str> = view.iter().map(|r| r["format"].as_str().unwrap()).collect();
    assert_eq!(names, ["rgba8", "bc7", "bc1", "bc4"]);
    for (r, ratio) in view.iter().zip([1.0, 0.25, 0.125, 0.125]) {
        assert_eq!(r["mapping_bytes_vs_rgba8"].as_f64(), Some(ratio), "{r}");
        assert_eq!(r["upload_bytes_per_frame_vs_rgba8"].as_f64(), Some(ratio), "{r}");
        assert_eq!(r["psnr_view_db"].is_null(), r["format"] == "rgba8", "{r}");
    }
    // Its case renders the pyramid prepared from the image, not a procedural texture.
    let case = &v["view_case"];
    assert_eq!(case["source"], "image", "{case}");
    assert!(case["frames"].as_u64().is_some_and(|f| f > 0), "{case}");
    // The 2^26 flight over the pre-encoded BC1 texture.
    let fl = &v["flight"];
    assert_eq!(fl["format"], "bc1", "{fl}");
    assert!(fl["level0_shown_share"].as_f64().is_some_and(|x| (0.0..=1.0).contains(&x)), "{fl}");
    // Every goal has its figure and says whether it is met; the byte goals are met exactly.
    let goals = v["goals"].as_object().unwrap();
    assert_eq!(goals.len(), 10, "{goals:?}");
    for (name, g) in goals {
        assert!(g["figure"].as_f64().is_some() && g["met"].is_boolean(), "{name}: {g}");
    }
    for name in [
        "bc1_mapping_bytes_vs_rgba8",
        "bc1_upload_bytes_per_frame_vs_rgba8",
        "bc7_mapping_bytes_vs_rgba8",
        "bc7_upload_bytes_per_frame_vs_rgba8",
    ] {
        assert_eq!(goals[name]["met"], true, "{name}: {}", goals[name]);
    }
    // Which imagery: a photograph found on this machine, or the fallback, said so.
    let img = &v["image"];
    assert!(img["photograph"].is_boolean() && !img["source"].as_str().unwrap().is_empty(), "{img}");
    assert_eq!(img["photograph"].as_bool(), Some(img["path"].is_string()), "{img}");
}
