//! `clipbench views --quick --json` keeps its JSON contract: one row per scenario and design with
//! `name`, `views`, `tiles_read`, `peak_resident_bytes`, `settle_ticks` and the ratios against
//! one view alone, consistent with the figures they come from; a `goals` object saying for each
//! goal whether it is met (not asserted here: the figures are the output); no slot under any
//! view's published region ever went to another tile; and the simulation is deterministic.

fn run(size: &str) -> serde_json::Value {
    let args: Vec<&std::ffi::OsStr> = ["views", size, "--json"].into_iter().map(|a| a.as_ref()).collect();
    crate::common::clipbench_json(&args)
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0)
}

#[test]
fn views_json_has_every_scenario_its_ratios_consistent_and_the_goals() {
    let v = run("--quick");
    let rows = v["scenarios"].as_array().expect("scenarios");
    let find = |name: &str, design: &str| {
        rows.iter()
            .find(|r| r["name"] == name && r["design"] == design)
            .unwrap_or_else(|| panic!("no row {name} {design} in {rows:?}"))
    };
    for (name, design) in [
        ("near", "one_view"),
        ("near", "views_spread_0"),
        ("near", "views_spread_clip"),
        ("near", "separate_grids"),
        ("near", "separate_grids_shared_pool"),
        ("near", "own_grids"),
        ("near", "one_view_ring"),
        ("near", "views_spread_0_ring"),
        ("near", "views_spread_clip_ring"),
        ("far", "one_view"),
        ("far", "views_spread_0"),
        ("far", "separate_grids"),
        ("far", "separate_grids_shared_pool"),
        ("far", "own_grids"),
        ("weighted", "one_view"),
        ("weighted", "one_view_same_grids"),
        ("weighted", "weights_3_1"),
        ("weighted", "weights_1_1"),
        ("weighted_tight", "one_view"),
        ("weighted_tight", "weights_3_1"),
        ("weighted_tight", "weights_1_1"),
    ] {
        find(name, design);
    }
    let clip = v["setup"]["clip"].as_u64().expect("setup.clip");
    for r in rows {
        let what = format!("{} {}", r["name"], r["design"]);
        let name = r["name"].as_str().unwrap();
        let one = find(name, r["baseline"].as_str().expect("baseline"));
        let n = r["views"].as_u64().unwrap_or_else(|| panic!("{what}: views")) as usize;
        let expected = match (name, r["design"].as_str().unwrap()) {
            (_, d) if d.starts_with("one_view") => 1,
            ("near" | "far", _) => 4,
            _ => 2,
        };
        assert_eq!(n, expected, "{what}");
        for field in ["tiles_read", "peak_resident_bytes", "window_tiles", "mapping_bytes"] {
            assert!(r[field].as_u64().is_some_and(|x| x > 0), "{what}: {field} = {}", r[field]);
        }
        assert_eq!(r["slots_reassigned_under_views"], 0, "{what}");
        assert_eq!(r["slots_reassigned_under_published"], 0, "{what}");
        // The ratios are the figures over the baseline's, measured in the same run.
        let ratio = |field: &str, of: &str| {
            let x = r[field].as_f64().unwrap_or_else(|| panic!("{what}: {field}"));
            assert!(x.is_finite() && x > 0.0, "{what}: {field} = {x}");
            let want = r[of].as_f64().unwrap() / one[of].as_f64().unwrap();
            assert!(close(x, want), "{what}: {field} {x}, {of} over the baseline's {want}");
        };
        ratio("tiles_read_vs_one", "tiles_read");
        ratio("resident_vs_one", "peak_resident_bytes");
        ratio("window_tiles_vs_one", "window_tiles");
        // Settle ticks: each view's mean over the events, the row's the slowest view's per event.
        let events = r["view_settle_events"].as_array().unwrap();
        let mine = r["view_settle_ticks"].as_array().unwrap();
        let alone = r["view_settle_alone_ticks"].as_array().unwrap();
        let lods = r["view_mean_min_lod"].as_array().unwrap();
        assert_eq!((events.len(), mine.len(), alone.len(), lods.len()), (n, n, n, n), "{what}");
        let mut never = 0;
        let mut worst = vec![0u64; events[0].as_array().unwrap().len()];
        let mut all = true;
        let mut most = 0.0f64;
        let mut ratios_known = true;
        for ((e, m), a) in events.iter().zip(mine).zip(alone) {
            let e: Vec<Option<u64>> = e.as_array().unwrap().iter().map(|x| x.as_u64()).collect();
            assert_eq!(e.len(), worst.len(), "{what}: every view has every event");
            if e.iter().all(Option::is_some) {
                let mean = e.iter().map(|x| x.unwrap()).sum::<u64>() as f64 / e.len() as f64;
                assert!(close(m.as_f64().unwrap(), mean), "{what}: {m} against {mean}");
                for (w, x) in worst.iter_mut().zip(&e) {
                    *w = (*w).max(x.unwrap());
                }
                match a.as_f64() {
                    Some(a) => most = most.max(mean / a),
                    None => ratios_known = false,
                }
            } else {
                assert!(m.is_null(), "{what}: a view that did not settle has no mean");
                never += 1;
                all = false;
                ratios_known = false;
            }
        }
        assert_eq!(r["views_never_settled"], never, "{what}");
        if all {
            let want = worst.iter().sum::<u64>() as f64 / worst.len() as f64;
            assert!(close(r["settle_ticks"].as_f64().unwrap(), want), "{what}: settle_ticks");
        } else {
            assert!(r["settle_ticks"].is_null(), "{what}: settle_ticks with a view unsettled");
        }
        if ratios_known {
            let x = r["settle_vs_alone"].as_f64().unwrap_or_else(|| panic!("{what}: settle_vs_alone"));
            assert!(x.is_finite() && close(x, most), "{what}: settle_vs_alone {x}, expected {most}");
        } else {
            assert!(r["settle_vs_alone"].is_null(), "{what}");
        }
        for l in lods {
            let l = l.as_f64().unwrap();
            assert!(l.is_finite() && l >= 0.0, "{what}: min LOD {l}");
        }
        if name.starts_with("weighted") {
            let d = r["heavy_min_lod_delta"].as_f64().unwrap_or_else(|| panic!("{what}: heavy_min_lod_delta"));
            let want = lods[0].as_f64().unwrap() - one["view_mean_min_lod"][0].as_f64().unwrap();
            assert!(close(d, want), "{what}: delta {d}, expected {want}");
        } else {
            assert!(r["heavy_min_lod_delta"].is_null(), "{what}");
        }
    }
    // The baselines are themselves, and the designs are what they say.
    let one = find("near", "one_view");
    assert_eq!(one["tiles_read_vs_one"], 1.0);
    assert_eq!(find("near", "views_spread_clip")["view_spread"], clip);
    assert_eq!(find("far", "separate_grids")["clipmaps"], 4);
    assert!(find("far", "separate_grids_shared_pool")["pool_hits"].as_u64().is_some());
    // Grids of their own (the service's `:own` views): a clipmap a view, each with an equal share
    // of the disk; far apart, that settles every view as fast as alone (the goal is met by it),
    // at four views' memory.
    let own = find("far", "own_grids");
    assert_eq!(own["clipmaps"].as_u64(), Some(4), "{own}");
    assert!(own["resident_vs_one"].as_f64().is_some_and(|x| (4.0..=4.1).contains(&x)), "{own}");
    assert!(own["settle_vs_alone"].as_f64().is_some_and(|x| x <= 1.25), "{own}");
    assert!(v["goals"]["far"]["met_by"].as_array().unwrap().contains(&"own_grids".into()), "{}", v["goals"]["far"]);
    assert_eq!(find("weighted", "weights_3_1")["weights"], serde_json::json!([3.0, 1.0]));
    let disk = &v["weighted_disk"];
    assert_eq!(find("weighted", "weights_3_1")["disk_tiles_per_tick"], disk["disk_tiles_per_tick"]);
    assert_eq!(find("weighted_tight", "weights_3_1")["disk_tiles_per_tick"], disk["tight_disk_tiles_per_tick"]);
    assert!(disk["one_view_need_per_tick"].as_f64().unwrap() > 0.0);
    // Every goal is there, with a verdict for each design it was checked against.
    for goal in ["near", "far", "weighted"] {
        let g = &v["goals"][goal];
        assert!(g["met"].is_boolean(), "{goal}: {g}");
        assert!(g["goal"].is_string(), "{goal}");
        let designs = g["designs"].as_array().unwrap_or_else(|| panic!("{goal}: designs"));
        assert!(!designs.is_empty(), "{goal}");
        for d in designs {
            assert!(d["met"].is_boolean() && d["all_views_at_level_0"].is_boolean(), "{goal}: {d}");
            find(goal, d["design"].as_str().unwrap());
            assert_eq!(d["met"].as_bool().unwrap(), d["why"].as_str().unwrap().is_empty(), "{goal}: {d}");
        }
    }
}

#[test]
fn views_runs_are_deterministic() {
    let a = run("--smoke");
    let b = run("--smoke");
    assert_eq!(a, b, "the same figures twice");
}
