//! The service against the in-process engine, on the same flight in the same run:
//!
//! 1. latency: a renderer requests a new centre 60 times a second through the mapping and
//!    measures how long until the service publishes it (level 0's state carries the new centre)
//!    and until level 0's valid region is complete around it; then the cost of a reader's
//!    consistent snapshot of every level state;
//! 2. update throughput: texel bytes the service copies per second spent in its ticks (from its
//!    `STATS`, over the flight only), against the in-process engine (private windows, no
//!    mapping, no socket) ticking through the same centres at the same pace.
//!
//! `cargo run --release --example service_latency -- [--clip C] [--requests R] [--busy N] [--rounds K] [--json]`
//! (defaults 2048, 300, 0, 3; the rounds alternate service and engine): a hash texture of 2^20 texels a side, RGBA8, 256-texel tiles; the
//! service in this process at 60 ticks per second with the default 6 ms copy budget; the centre
//! moves 8 level-0 texels a request along +s. `--busy N` keeps N extra threads spinning for the
//! whole run (N = 2 on a 2-core machine: both cores busy).

use clipmap::clip::{Clipmap, Settings};
use clipmap::service::{procedural_source, run, Options, Procedural};
use clipmap::shm::Client;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

const SIZE: u64 = 1 << 20;
const STEP: i64 = 8;

fn pct(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn stats(socket: &Path) -> clipmap::service::ServiceStats {
    clipmap::inspect::attach::ask_stats(socket).expect("STATS reply")
}

/// (bytes copied, seconds inside ticks) between two `STATS` replies.
fn copied_between(a: &clipmap::service::ServiceStats, b: &clipmap::service::ServiceStats) -> (f64, f64) {
    let bytes = b.tick.engine.queue.bytes_read as f64 - a.tick.engine.queue.bytes_read as f64;
    let secs = b.tick.tick_busy_s - a.tick.tick_busy_s;
    (bytes, secs)
}

struct Measured {
    published_ms: Vec<f64>,
    complete_ms: Vec<f64>,
    snapshot_ns: f64,
    levels: usize,
    service_bytes: f64,
    service_secs: f64,
}

/// The in-process engine through the same centres at the same pace: (bytes, seconds in ticks).
fn engine_flight(clip: u64, requests: usize) -> (f64, f64) {
    let source = procedural_source(Procedural::Hash, SIZE, clip, 256).unwrap();
    let settings = Settings { budget_ns: Some(6_000_000), ..Settings::default() };
    let mut map = Clipmap::new(source, settings).unwrap();
    let base = [(SIZE / 2) as i64; 2];
    let t = Instant::now();
    while map.tick(base, None).min_lod > 0.0 && t.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(16));
    }
    let period = Duration::from_secs_f64(1.0 / 60.0);
    let (mut bytes, mut secs) = (0u64, 0f64);
    let start = Instant::now();
    for i in 1..=requests {
        std::thread::sleep((start + period * i as u32).saturating_duration_since(Instant::now()));
        let t0 = Instant::now();
        let r = map.tick([base[0] + STEP * i as i64, base[1]], Some([STEP, 0]));
        secs += t0.elapsed().as_secs_f64();
        bytes += r.tiles_read;
    }
    (bytes as f64, secs)
}

/// The service in this process, a renderer flying it through the mapping: latencies, snapshot
/// cost and the service's own copy throughput over the flight.
async fn service_flight(clip: u64, requests: usize) -> Measured {
    let dir = tempfile::tempdir().unwrap();
    let mut o = Options::new("latency");
    o.shm_dir = dir.path().to_path_buf();
    o.socket = dir.path().join("latency.sock");
    let socket = o.socket.clone();
    let source = procedural_source(Procedural::Hash, SIZE, clip, 256).unwrap();
    let (done_tx, done_rx) = tokio::sync::oneshot::channel::<()>();
    let (res_tx, res_rx) = std::sync::mpsc::channel();
    let shm_dir = dir.path().to_path_buf();
    run(
        source,
        o,
        async {
            let _ = done_rx.await;
        },
        move |_| {
            std::thread::spawn(move || {
                let c = Client::attach(&shm_dir, "latency").unwrap();
                let base = [(SIZE / 2) as i64; 2];
                let border = c.snapshot().invalid_border;
                let complete = |st: &clipmap::shm::LevelState| {
                    st.enabled && (st.valid[2] - st.valid[0]) as u64 + 2 * border >= clip
                };
                // Warm up: the first window fills completely.
                c.request_centre(base, [0.0, 0.0]);
                let t = Instant::now();
                while !(c.level_state(0).is_some_and(|s| s.centre == base && complete(&s)))
                    && t.elapsed() < Duration::from_secs(60)
                {
                    std::thread::sleep(Duration::from_millis(1));
                }
                let before = stats(&socket);
                let (mut published, mut full) = (Vec::new(), Vec::new());
                let period = Duration::from_secs_f64(1.0 / 60.0);
                let start = Instant::now();
                for i in 1..=requests {
                    let slot = start + period * i as u32;
                    std::thread::sleep(slot.saturating_duration_since(Instant::now()));
                    let want = [base[0] + STEP * i as i64, base[1]];
                    let t0 = Instant::now();
                    c.request_centre(want, [(STEP * 60) as f64, 0.0]);
                    let mut seen = None;
                    loop {
                        if let Some(st) = c.level_state(0) {
                            if st.centre == want && seen.is_none() {
                                seen = Some(t0.elapsed());
                            }
                            if st.centre == want && complete(&st) {
                                break;
                            }
                            if st.centre[0] > want[0] || t0.elapsed() > Duration::from_secs(2) {
                                break;
                            }
                        }
                        std::thread::sleep(Duration::from_micros(50));
                    }
                    let e = t0.elapsed();
                    published.push(seen.unwrap_or(e).as_secs_f64() * 1e3);
                    full.push(e.as_secs_f64() * 1e3);
                }
                let after = stats(&socket);
                let (service_bytes, service_secs) = copied_between(&before, &after);
                let n = 20_000;
                let t = Instant::now();
                for _ in 0..n {
                    std::hint::black_box(c.snapshot());
                }
                let snapshot_ns = t.elapsed().as_nanos() as f64 / n as f64;
                let _ = res_tx.send(Measured {
                    published_ms: published,
                    complete_ms: full,
                    snapshot_ns,
                    levels: c.levels.len(),
                    service_bytes,
                    service_secs,
                });
                let _ = done_tx.send(());
            });
        },
    )
    .await
    .unwrap();
    res_rx.recv().unwrap()
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let opt = |name: &str, default: u64| -> u64 {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .map_or(default, |v| v.parse().unwrap_or_else(|_| panic!("{name} {v}: expected a whole number")))
    };
    let clip = opt("--clip", 2048);
    let requests = opt("--requests", 300) as usize;
    let busy = opt("--busy", 0) as usize;
    let json = args.iter().any(|a| a == "--json");

    let spinning = Arc::new(AtomicBool::new(true));
    let spinners: Vec<_> = (0..busy)
        .map(|_| {
            let go = spinning.clone();
            std::thread::spawn(move || {
                let mut x = 1u64;
                while go.load(Ordering::Relaxed) {
                    for _ in 0..10_000 {
                        x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                    }
                }
            })
        })
        .collect();

    let rounds = opt("--rounds", 3).max(1) as usize;
    let mut m = Measured {
        published_ms: vec![],
        complete_ms: vec![],
        snapshot_ns: f64::INFINITY,
        levels: 0,
        service_bytes: 0.0,
        service_secs: 0.0,
    };
    let mut ratios = Vec::new();
    let (mut service_tps, mut engine_tps) = (Vec::new(), Vec::new());
    let (mut engine_bytes, mut service_bytes) = (0.0, 0.0);
    // Rounds alternate the service and the engine so that both see the same machine.
    for _ in 0..rounds {
        let r = service_flight(clip, requests).await;
        let (eb, es) = tokio::task::spawn_blocking(move || engine_flight(clip, requests)).await.unwrap();
        let (stp, etp) = (r.service_bytes / r.service_secs, eb / es);
        service_tps.push(stp);
        engine_tps.push(etp);
        ratios.push(stp / etp);
        (engine_bytes, service_bytes) = (eb, r.service_bytes);
        m.published_ms.extend(r.published_ms);
        m.complete_ms.extend(r.complete_ms);
        m.snapshot_ns = m.snapshot_ns.min(r.snapshot_ns);
        m.levels = r.levels;
    }
    spinning.store(false, Ordering::Relaxed);
    for s in spinners {
        let _ = s.join();
    }

    let service_tp = pct(&mut service_tps, 0.5);
    let engine_tp = pct(&mut engine_tps, 0.5);
    let ratio = pct(&mut ratios.clone(), 0.5);
    let (p50, p99, pmax) =
        (pct(&mut m.published_ms, 0.5), pct(&mut m.published_ms, 0.99), pct(&mut m.published_ms, 1.0));
    let (c50, c99, cmax) = (pct(&mut m.complete_ms, 0.5), pct(&mut m.complete_ms, 0.99), pct(&mut m.complete_ms, 1.0));
    let mib = |b: f64| b / (1024.0 * 1024.0);
    if json {
        let out = serde_json::json!({
            "clip_size": clip, "levels": m.levels, "requests": requests, "busy_threads": busy,
            "published_ms": {"p50": p50, "p99": p99, "max": pmax},
            "complete_ms": {"p50": c50, "p99": c99, "max": cmax},
            "snapshot_ns": m.snapshot_ns,
            "service_bytes_per_s": service_tp, "engine_bytes_per_s": engine_tp,
            "service_vs_engine": ratio, "service_vs_engine_rounds": ratios,
            "service_bytes_per_round": service_bytes, "engine_bytes_per_round": engine_bytes,
        });
        println!("{out}");
        return;
    }
    println!(
        "clip {clip}, RGBA8, {} levels, {requests} requests at 60 per second, {busy} extra spinning threads",
        m.levels
    );
    println!("request -> centre published: p50 {p50:.2} ms, p99 {p99:.2} ms, max {pmax:.2} ms");
    println!("request -> level 0 complete: p50 {c50:.2} ms, p99 {c99:.2} ms, max {cmax:.2} ms");
    println!("reader snapshot (all {} level states, seqlocked): {:.0} ns", m.levels, m.snapshot_ns);
    println!(
        "update throughput, medians of {rounds} alternating rounds: service {:.0} MiB/s, in-process engine {:.0} MiB/s ({:.1} MiB copied per round by each)",
        mib(service_tp),
        mib(engine_tp),
        mib(service_bytes)
    );
    let list: Vec<String> = ratios.iter().map(|r| format!("{r:.2}")).collect();
    println!("service / engine: median {ratio:.2} (rounds: {})", list.join(", "));
    debug_assert_eq!(service_bytes, engine_bytes);
}
