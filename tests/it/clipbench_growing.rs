//! `clipbench growing --quick --json` keeps its contract: `tiles_per_s_256`, `tiles_per_s_512`
//! and `ingest_mb_per_s`, each run's tiles and seconds, consistent with each other (run here on
//! tiny patches through the hidden `--patch-size`, so the figures mean little).

#[test]
fn growing_json_has_the_rates_and_runs_that_explain_them() {
    let args: Vec<&std::ffi::OsStr> =
        ["growing", "--quick", "--json", "--patch-size", "400", "300"].iter().map(|a| a.as_ref()).collect();
    let v = crate::common::clipbench_json(&args);
    for field in ["tiles_per_s_256", "tiles_per_s_512", "ingest_mb_per_s", "decode_mb_per_s"] {
        let x = v[field].as_f64().unwrap_or_else(|| panic!("{field} in {v}"));
        assert!(x.is_finite() && x > 0.0, "{field} = {x}");
    }
    assert_eq!(v["patches"], 4);
    assert_eq!(v["texel_bytes"], 4 * 400 * 300 * 3);
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.iter().map(|r| r["tile"].as_u64().unwrap()).collect::<Vec<_>>(), vec![256, 512]);
    for (run, field) in runs.iter().zip(["tiles_per_s_256", "tiles_per_s_512"]) {
        let (tiles, l0, secs) = (
            run["tiles_rebuilt"].as_f64().unwrap(),
            run["level0_tiles"].as_f64().unwrap(),
            run["seconds"].as_f64().unwrap(),
        );
        assert!(l0 >= 1.0 && tiles > l0, "parents are rebuilt too: {run}");
        assert!((tiles / secs - v[field].as_f64().unwrap()).abs() < 1e-6 * tiles / secs, "{field} is tiles / seconds");
        assert!(run["levels"].as_u64().unwrap() >= 2, "{run}");
    }
}
