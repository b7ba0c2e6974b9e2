//! `clipbench cog --smoke --json` writes a COG with GDAL, reads every level-0 tile with the COG
//! source and with GDAL, and keeps its JSON contract: the fields the COG issue names are there
//! (numbers, or `null` for the HTTP ones not measured yet), and no texel differs from GDAL's own
//! decode, in each compression the source reads. No timing is asserted. Needs GDAL (`.ci/run`
//! installs `gdal-bin` and `python3-gdal`).

fn run_cog(extra: &[&str]) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let head: [&std::ffi::OsStr; 4] = ["cog".as_ref(), "--smoke".as_ref(), "--json".as_ref(), "--dir".as_ref()];
    let args: Vec<&std::ffi::OsStr> =
        head.into_iter().chain([dir.path().as_os_str()]).chain(extra.iter().map(|a| a.as_ref())).collect();
    crate::common::clipbench_json(&args)
}

#[test]
fn cog_json_has_the_contract_fields_and_no_texel_differs_from_gdal() {
    for extra in [&[][..], &["--compression", "zstd", "--predictor"][..], &["--compression", "deflate"][..]] {
        let v = run_cog(extra);
        for field in ["tiles_per_s_local", "tiles_per_s_gdal_local", "local_vs_gdal", "tiles_per_s_gdal_local_all_cpus"]
        {
            let x = v[field].as_f64().unwrap_or_else(|| panic!("{extra:?}: {field} is not a number: {}", v[field]));
            assert!(x.is_finite() && x > 0.0, "{extra:?}: {field} = {x}");
        }
        for field in [
            "tiles_per_s_http",
            "tiles_per_s_gdal_http",
            "curl_ceiling_tiles_per_s",
            "requests",
            "requests_gdal",
            "open_requests",
            "open_bytes",
        ] {
            assert!(v.get(field).is_some(), "{extra:?}: no field {field}: {v}");
        }
        assert_eq!(v["wrong_texels"], 0, "{extra:?}: {v}");
        assert_eq!(v["cog"]["level0_tiles"], 4, "{extra:?}: a 512-texel COG of 256-texel tiles");
        let ratio = v["tiles_per_s_local"].as_f64().unwrap() / v["tiles_per_s_gdal_local"].as_f64().unwrap();
        assert!((v["local_vs_gdal"].as_f64().unwrap() - ratio).abs() <= 1e-9 * ratio, "{v}");
    }
}
