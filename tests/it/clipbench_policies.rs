//! `clipbench policies --smoke --json` keeps its JSON contract: one row per flight and
//! combination of policies, each with `prefetch`, `eviction`, `flight`, `tiles_read`,
//! `hit_rate`, `peak_resident_bytes`, `ticks_with_disabled_level` and `mean_min_lod`; the
//! simulation is deterministic (two runs print the same rows), and the figures are consistent
//! with each other (no pool: no hits and nothing resident beyond the grids).

fn run(extra: &[&str]) -> serde_json::Value {
    let args: Vec<&std::ffi::OsStr> =
        ["policies", "--smoke", "--json"].iter().chain(extra).map(|a| a.as_ref()).collect();
    crate::common::clipbench_json(&args)
}

#[test]
fn policies_json_has_a_row_per_flight_and_combination() {
    let v = run(&[]);
    let rows = v["rows"].as_array().expect("rows");
    let flights = ["straight", "turning", "zigzag", "hover", "fast_straight", "jumps", "turn_around"];
    assert_eq!(
        rows.len(),
        flights.len() * 4 * 3,
        "7 flights x (ring, direction, ahead, adaptive) x (none, lru, shift)"
    );
    let fixed_grid = v["setup"]["grid_bytes"].as_u64().expect("setup.grid_bytes");
    let adaptive_grid = v["setup"]["adaptive_grid_bytes"].as_u64().expect("setup.adaptive_grid_bytes");
    let pool = v["setup"]["pool_bytes"].as_u64().expect("setup.pool_bytes");
    assert!(fixed_grid > 0 && pool > 0);
    assert!(adaptive_grid > fixed_grid && adaptive_grid <= 2 * fixed_grid, "{adaptive_grid} against {fixed_grid}");
    for f in flights {
        for p in ["ring", "direction", "ahead", "adaptive"] {
            let grid = if p == "adaptive" { adaptive_grid } else { fixed_grid };
            for e in ["none", "lru", "shift"] {
                let row = rows
                    .iter()
                    .find(|r| r["flight"] == f && r["prefetch"] == p && r["eviction"] == e)
                    .unwrap_or_else(|| panic!("no row for {f} {p} {e}"));
                for field in ["tiles_read", "peak_resident_bytes", "ticks_with_disabled_level"] {
                    assert!(row[field].is_u64(), "{f} {p} {e}: {field} = {}", row[field]);
                }
                let hit = row["hit_rate"].as_f64().expect("hit_rate");
                let lod = row["mean_min_lod"].as_f64().expect("mean_min_lod");
                assert!((0.0..=1.0).contains(&hit), "{hit}");
                assert!(lod >= 0.0 && lod.is_finite(), "{lod}");
                let peak = row["peak_resident_bytes"].as_u64().unwrap();
                assert!(
                    peak >= grid && peak <= grid + pool,
                    "{f} {p} {e}: peak {peak} outside grid {grid} + pool {pool}"
                );
                if e == "none" {
                    assert_eq!(hit, 0.0);
                    assert_eq!(peak, grid, "no pool: the grids alone");
                }
            }
        }
    }
    // A flight that moves reads tiles; the jumps outrun the disk.
    let jumps = rows.iter().find(|r| r["flight"] == "jumps").unwrap();
    assert!(jumps["tiles_read"].as_u64().unwrap() > 0);
    assert!(jumps["ticks_with_disabled_level"].as_u64().unwrap() > 0, "{jumps}");
}

#[test]
fn policies_runs_are_deterministic_and_the_clamp_is_reported() {
    let args = ["--prefetch", "direction", "--eviction", "shift", "--max-centre-step", "2"];
    let a = run(&args);
    let b = run(&args);
    assert_eq!(a["rows"], b["rows"], "the same rows twice");
    let rows = a["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 7);
    let fast = rows.iter().find(|r| r["flight"] == "fast_straight").unwrap();
    assert!(fast["centre_clamps"].as_u64().unwrap() > 0, "{fast}");
    let hover = rows.iter().find(|r| r["flight"] == "hover").unwrap();
    assert!(hover["centre_clamps"].as_u64().is_some());
}
