//! `clipbench perf`'s human output: a Markdown table of the five ratios with their goals,
//! medians and spreads, then one line per detail (ingest, flight, scale, service).

use super::ingest::Ingest;
use super::{Machine, Report};

fn mib(b: f64) -> String {
    format!("{:.1} MiB", b / (1u64 << 20) as f64)
}

fn ms(s: f64) -> String {
    format!("{:.3} ms", s * 1e3)
}

/// The human table: the five ratios with goals, medians and spreads, then one line per detail.
pub fn table(r: &Report) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let m = &r.machine;
    let _ = writeln!(o, "{} ({:?}, {} runs each, {:.0} s)", r.command, r.size, r.runs, r.elapsed_s);
    let _ = writeln!(
        o,
        "machine: {} cores, {}, {:.0} GiB; load average {} at the start, {} at the end",
        m.nproc, m.cpu, m.memory_gib, m.load_start, m.load_end
    );
    let _ = writeln!(o);
    let _ = writeln!(o, "| figure | ratio | goal | met | median | spread (min .. max) |");
    let _ = writeln!(o, "|---|---:|---|---|---|---|");
    let met = |ok: bool| if ok { "yes" } else { "**no**" };
    let e = &r.engine;
    let tick = |f: &serde_json::Value| f["median_tick_s"].as_f64().unwrap_or(0.0);
    let flights = e["flights"].as_array().cloned().unwrap_or_default();
    let per_flight = flights
        .iter()
        .map(|f| format!("{} {}", f["direction"].as_str().unwrap_or("?"), ms(tick(f))))
        .collect::<Vec<_>>()
        .join(", ");
    let _ = writeln!(
        o,
        "| direction_ratio (slowest / fastest median update tick) | {:.2} | <= 1.25 | {} | {} | |",
        r.direction_ratio,
        met(r.direction_ratio <= 1.25),
        per_flight
    );
    let _ = writeln!(
        o,
        "| tick_texel_bytes (texels written by ticks, not by tile reads) | {} | 0 | {} | | |",
        r.tick_texel_bytes,
        met(r.tick_texel_bytes == 0)
    );
    let i = &r.ingest;
    o.push_str(&ingest_row(i));
    let f = &r.flight;
    match (&f.speedup_vs_gdal, &f.gdal_frame_s) {
        (Some(s), Some(g)) => {
            let _ = writeln!(
                o,
                "| speedup_vs_gdal ({} frames) | {:.1} | >= 50 | {} | {} vs {} per frame | ratio {:.1} .. {:.1} |",
                f.frames,
                s.median,
                met(s.median >= 50.0),
                ms(g.median),
                ms(f.engine_frame_s.median),
                s.min,
                s.max
            );
        }
        _ => {
            let _ = writeln!(o, "| speedup_vs_gdal | - | >= 50 | not measured ({}) | | |", f.gdal_note);
        }
    }
    let s = &f.speedup_vs_full_reload;
    let _ = writeln!(
        o,
        "| speedup_vs_full_reload | {:.1} | >= 10 | {} | {} vs {} per frame | ratio {:.1} .. {:.1} |",
        s.median,
        met(s.median >= 10.0),
        ms(f.reload_frame_s.median),
        ms(f.engine_frame_s.median),
        s.min,
        s.max
    );
    let mm = &r.memory;
    let _ = writeln!(
        o,
        "| memory_vs_formula (VmHWM - VmRSS before) | {:.3} | <= 1.1 | {} | {} over formula {} (grid tiles + pyramid + header; mapping as laid out {}; layout 1's windows alone were {}) | VmHWM alone: {:.3} |",
        r.memory_vs_formula,
        met(r.memory_vs_formula <= 1.1),
        mib(mm.vm_hwm_bytes.saturating_sub(mm.vm_rss_before_bytes) as f64),
        mib(mm.formula_bytes as f64),
        mib(mm.mapping_bytes as f64),
        mib(mm.layout1_window_bytes as f64),
        mm.hwm_ratio
    );
    let _ = writeln!(
        o,
        "| memory_vs_formula_2_30 (the same at 2^30 texels a side) | {:.3} | <= 1.05 | {} | over formula {} | |",
        r.memory_vs_formula_2_30,
        met(r.memory_vs_formula_2_30 <= 1.05),
        mib(r.memory_2_30.formula_bytes as f64),
    );
    let _ = writeln!(
        o,
        "| tick_2_30_vs_2_26 (the same flights' median tick) | {:.3} | <= 1.1 | {} | | |",
        r.tick_2_30_vs_2_26,
        met(r.tick_2_30_vs_2_26 <= 1.1),
    );
    let _ = writeln!(
        o,
        "| lonlat_vs_texels (service latency, request -> published, median) | {:.3} | <= 1.05 | {} | lon/lat {:.2} ms, texels {:.2} ms | |",
        r.lonlat_vs_texels,
        met(r.lonlat_vs_texels <= 1.05),
        r.service.lonlat_published_p50_s * 1e3,
        r.service.texels_published_p50_s * 1e3,
    );
    let _ = writeln!(o);
    o.push_str(&ingest_details(i));
    let _ = writeln!(
        o,
        "flight: {} frames of ({}, {}) texels, clip {}, {} levels; engine tick alone {} of it; engine frames below level 0: {}; full reload: construct {} + fill {} per frame",
        f.frames,
        f.velocity[0],
        f.velocity[1],
        f.clip,
        f.levels,
        ms(f.engine_tick_s.median),
        f.engine_degraded_frames,
        ms(f.reload_construct_s.median),
        ms(f.reload_frame_s.median - f.reload_construct_s.median)
    );
    for sc in [&r.scale, &r.scale_default] {
        let _ = writeln!(
            o,
            "scale: 2^26 texels, clip {}, {} prefetch, lookahead {}, {} texels per tick at {} ticks/s for {:.1} s: {} ticks, level 0 shown on {:.1}% after the first second (goal >= 99%), {} over budget, {} with disabled levels (at most {}, mean min LOD {:.2}), {} late; tick p50 {} p99 {}; {} texel bytes written by ticks, {:.0} tiles/s read; {:.2} cores busy; peak {:.1} MiB of grids{}",
            sc.clip,
            sc.prefetch,
            sc.lookahead,
            sc.texels_per_tick,
            sc.tick_hz,
            sc.seconds,
            sc.ticks,
            sc.level0_shown_share * 100.0,
            sc.ticks_over_budget,
            sc.ticks_with_disabled_levels,
            sc.max_disabled_levels,
            sc.mean_min_lod,
            sc.late_ticks,
            ms(sc.tick_p50_s),
            ms(sc.tick_p99_s),
            sc.tick_texel_bytes,
            sc.tiles_read_per_s,
            sc.cpu_cores_used,
            sc.peak_resident_bytes as f64 / (1u64 << 20) as f64,
            sc.grid_budget_bytes
                .map(|b| format!(" (budget {:.1} MiB; level 0 {:?})", b as f64 / (1u64 << 20) as f64, sc.level0_paging))
                .unwrap_or_default()
        );
    }
    let sv = &r.service;
    let _ = writeln!(
        o,
        "service: clip {}, {} requests at 60/s: request -> published p50 {} p99 {}; -> level 0 complete p50 {} p99 {}; snapshot {:.0} ns",
        sv.clip,
        sv.requests,
        ms(sv.published_p50_s),
        ms(sv.published_p99_s),
        ms(sv.complete_p50_s),
        ms(sv.complete_p99_s),
        sv.snapshot_ns
    );
    o
}

/// The ingest figure's table row.
fn ingest_row(i: &Ingest) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let met = |ok: bool| if ok { "yes" } else { "**no**" };
    let _ = writeln!(
        o,
        "| ingest_vs_read ({} tiles of {} per run, page cache) | {:.2} | >= 0.9 | {} | {:.0} vs {:.0} tiles/s | ratio {:.2} .. {:.2} |",
        i.tiles_per_run,
        mib(i.tile_bytes as f64),
        i.ratio.median,
        met(i.ratio.median >= 0.9),
        i.engine_tiles_per_s.median,
        i.read_tiles_per_s.median,
        i.ratio.min,
        i.ratio.max
    );
    o
}

/// The ingest comparison's detail lines.
fn ingest_details(i: &Ingest) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "ingest: drop_caches {}{}",
        if i.cold.is_some() { "possible" } else { "not possible" },
        i.cold.as_ref().map_or(String::new(), |c| format!(
            "; cold (after dropping caches): engine {:.0} tiles/s, plain reads {:.0} tiles/s, ratio {:.2}",
            c.engine_tiles_per_s, c.read_tiles_per_s, c.ratio
        ))
    );
    let _ = writeln!(
        o,
        "ingest per tile: engine {:.0} minor faults, {:.1} µs CPU, {:.2} context switches ({:.1} % of its flight in ticks); plain reads {:.0} minor faults, {:.1} µs CPU, {:.2} context switches",
        i.engine_faults_per_tile.median,
        i.engine_cpu_us_per_tile.median,
        i.engine_switches_per_tile.median,
        i.engine_tick_share.median * 100.0,
        i.read_faults_per_tile.median,
        i.read_cpu_us_per_tile.median,
        i.read_switches_per_tile.median
    );
    let _ = writeln!(
        o,
        "ingest, reads into their places (one after the other, each tile into its own place of {}): {:.0} tiles/s, {:.2} of plain reads; the engine {:.2} of them",
        mib(i.in_place_buffer_bytes as f64),
        i.read_in_place_tiles_per_s.median,
        i.in_place_vs_read.median,
        i.engine_vs_in_place.median
    );
    let _ = writeln!(
        o,
        "ingest, the same reads into their places shared out among {} threads reading at once: {:.0} tiles/s, {:.2} of plain reads",
        i.parallel_threads,
        i.read_parallel_tiles_per_s.median,
        i.parallel_vs_read.median
    );
    o
}

/// `clipbench ingest`'s output: the ingest row of `clipbench perf`'s table, then its details.
pub fn ingest_table(i: &Ingest, m: &Machine) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "clipbench ingest ({} runs); machine: {} cores, {}; load average {} at the start, {} at the end",
        i.ratio.samples.len(),
        m.nproc,
        m.cpu,
        m.load_start,
        m.load_end
    );
    let _ = writeln!(o);
    let _ = writeln!(o, "| figure | ratio | goal | met | median | spread (min .. max) |");
    let _ = writeln!(o, "|---|---:|---|---|---|---|");
    o.push_str(&ingest_row(i));
    let _ = writeln!(o);
    o.push_str(&ingest_details(i));
    o
}
