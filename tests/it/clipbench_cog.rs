//! `clipbench cog --smoke --json` writes a COG with GDAL, reads every level-0 tile with the COG
//! source and with GDAL, locally and over loopback HTTP (nginx; GDAL through `/vsicurl/`, curl
//! fetching the same ranges, faults injected by a relay), and keeps its JSON contract: the fields
//! the COG issue names are numbers, the ratios are the ratios of the rates, open is one request
//! of at most 64 KiB, and no texel differs from GDAL's own decode, in each compression the source
//! reads. No timing is asserted. Needs GDAL, nginx and curl (`.ci/run` installs them).

fn run_cog(extra: &[&str]) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let head: [&std::ffi::OsStr; 4] = ["cog".as_ref(), "--smoke".as_ref(), "--json".as_ref(), "--dir".as_ref()];
    let args: Vec<&std::ffi::OsStr> =
        head.into_iter().chain([dir.path().as_os_str()]).chain(extra.iter().map(|a| a.as_ref())).collect();
    crate::common::clipbench_json(&args)
}

#[test]
fn cog_json_has_the_contract_fields_and_no_texel_differs_from_gdal() {
    for extra in [
        &[][..],
        &["--compression", "zstd", "--predictor"][..],
        &["--compression", "deflate", "--link-rate", "1000"][..],
    ] {
        let v = run_cog(extra);
        for field in ["tiles_per_s_local", "tiles_per_s_gdal_local", "local_vs_gdal", "tiles_per_s_gdal_local_all_cpus"]
        {
            let x = v[field].as_f64().unwrap_or_else(|| panic!("{extra:?}: {field} is not a number: {}", v[field]));
            assert!(x.is_finite() && x > 0.0, "{extra:?}: {field} = {x}");
        }
        for field in [
            "tiles_per_s_http",
            "tiles_per_s_gdal_http",
            "tiles_per_s_gdal_http_all_cpus",
            "curl_ceiling_tiles_per_s",
            "tiles_per_s_http_faults",
        ] {
            let x = v[field].as_f64().unwrap_or_else(|| panic!("{extra:?}: {field} is not a number: {}", v[field]));
            assert!(x.is_finite() && x > 0.0, "{extra:?}: {field} = {x}");
        }
        let f = |k: &str| v[k].as_f64().unwrap();
        let h = &v["http"];
        for (ratio, over, under) in [
            ("http_vs_curl", f("tiles_per_s_http"), f("curl_ceiling_tiles_per_s")),
            ("http_vs_gdal", f("tiles_per_s_http"), f("tiles_per_s_gdal_http")),
            ("faults_vs_clean", f("tiles_per_s_http_faults"), h["tiles_per_s_http_relay"].as_f64().unwrap()),
        ] {
            let want = over / under;
            assert!((f(ratio) - want).abs() <= 1e-9 * want, "{extra:?}: {ratio} is not {over} / {under}: {v}");
        }
        // The machine's CPU, from the kernel's count in hundredths of a second (a smoke run's
        // figures are coarse, often 0): each cost times the tiles read is a whole number of
        // hundredths, and the bound is the ratio of the costs, `null` where ours is 0.
        let read = v["cog"]["level0_tiles"].as_f64().unwrap() * v["passes"].as_f64().unwrap();
        for (busy, cost) in [
            (&v["cores_busy_local"], &v["core_us_per_tile_local"]),
            (&h["cores_busy_http"], &h["core_us_per_tile_http"]),
            (&h["cores_busy_curl"], &h["core_us_per_tile_curl"]),
            (&h["cores_busy_fetch_only"], &h["core_us_per_tile_fetch_only"]),
        ] {
            let (busy, cost) = (busy.as_f64().unwrap(), cost.as_f64().unwrap());
            assert!(busy.is_finite() && busy >= 0.0, "{extra:?}: {busy} cores busy: {v}");
            let hundredths = cost * read / 10_000.0;
            assert!(
                hundredths >= 0.0 && (hundredths - hundredths.round()).abs() < 1e-6,
                "{extra:?}: {cost} us a tile: {v}"
            );
        }
        let (ours, curl) = (h["core_us_per_tile_http"].as_f64().unwrap(), h["core_us_per_tile_curl"].as_f64().unwrap());
        if ours > 0.0 {
            let got = v["http_vs_curl_cpu_bound"].as_f64().unwrap();
            assert!((got - curl / ours).abs() <= 1e-9 * (curl / ours).max(1e-9), "{v}");
        } else {
            assert!(v["http_vs_curl_cpu_bound"].is_null(), "{v}");
        }
        let link = extra.iter().position(|a| *a == "--link-rate").map(|i| extra[i + 1].parse::<u64>().unwrap());
        assert_eq!(v["link_rate_mb_per_s"].as_u64(), link, "{extra:?}: {v}");
        assert_eq!(v["open_requests"], 1, "{extra:?}: open is one request: {v}");
        let open_bytes = v["open_bytes"].as_u64().unwrap();
        assert!((1..=65536).contains(&open_bytes), "{extra:?}: open read {open_bytes} bytes");
        // A pass: the open, then at most a request a tile (the tile index lies in the first
        // 64 KiB of so small a COG); every tile's bytes at least once.
        let (requests, tiles) = (v["requests"].as_u64().unwrap(), v["cog"]["level0_tiles"].as_u64().unwrap());
        assert!((2..=1 + tiles).contains(&requests), "{extra:?}: {requests} requests for {tiles} tiles: {v}");
        assert!(h["bytes"].as_u64().unwrap() >= open_bytes, "{v}");
        assert!(v["requests_gdal"].as_u64().unwrap() >= 1, "{v}");
        assert_eq!(h["wrong_texels"], 0, "{extra:?}: {v}");
        assert_eq!(h["failed_reads"], 0, "{extra:?}: {v}");
        assert_eq!(v["wrong_texels"], 0, "{extra:?}: {v}");
        assert_eq!(v["cog"]["level0_tiles"], 4, "{extra:?}: a 512-texel COG of 256-texel tiles");
        let ratio = v["tiles_per_s_local"].as_f64().unwrap() / v["tiles_per_s_gdal_local"].as_f64().unwrap();
        assert!((v["local_vs_gdal"].as_f64().unwrap() - ratio).abs() <= 1e-9 * ratio, "{v}");
    }
}
