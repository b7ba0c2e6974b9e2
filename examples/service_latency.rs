//! Service latency: a renderer requests a new centre 60 times a second through the mapping and
//! measures how long until the service publishes it (level 0's state carries the new centre) and
//! until level 0's valid region is complete around it; then the cost of a reader's snapshot.
//!
//! `cargo run --release --example service_latency [clip] [requests]` (defaults 2048, 300): the
//! service in this process (tick loop thread, 60 ticks per second, 6 ms budget), a hash texture
//! of 2^20 texels a side, RGBA8, 256-texel tiles; the centre moves 8 level-0 texels a request.

use clipmap::service::{procedural_source, run, Options, Procedural};
use clipmap::shm::Client;
use std::time::{Duration, Instant};

fn pct(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[((v.len() - 1) as f64 * p).round() as usize]
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let args: Vec<String> = std::env::args().collect();
    let clip: u64 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(2048);
    let requests: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(300);
    let dir = tempfile::tempdir().unwrap();
    let mut o = Options::new("latency");
    o.shm_dir = dir.path().to_path_buf();
    o.socket = dir.path().join("latency.sock");
    let source = procedural_source(Procedural::Hash, 1 << 20, clip, 256).unwrap();
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
                let base = [1 << 19, 1 << 19];
                let complete = |st: &clipmap::shm::LevelState| {
                    st.enabled && (st.valid[2] - st.valid[0]) as u64 + 2 * st.invalid_border >= clip
                };
                // Warm up: the first window fills completely.
                c.request_centre(base, [0.0, 0.0]);
                let t = Instant::now();
                while !(c.level_state(0).is_some_and(|s| s.centre == base && complete(&s)))
                    && t.elapsed() < Duration::from_secs(60)
                {
                    std::thread::sleep(Duration::from_millis(1));
                }
                let (mut published, mut full) = (Vec::new(), Vec::new());
                let period = Duration::from_secs_f64(1.0 / 60.0);
                let start = Instant::now();
                for i in 1..=requests {
                    let slot = start + period * i as u32;
                    std::thread::sleep(slot.saturating_duration_since(Instant::now()));
                    let want = [base[0] + 8 * i as i64, base[1]];
                    let t0 = Instant::now();
                    c.request_centre(want, [480.0, 0.0]);
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
                let n = 20_000;
                let t = Instant::now();
                for _ in 0..n {
                    std::hint::black_box(c.snapshot());
                }
                let snap_ns = t.elapsed().as_nanos() as f64 / n as f64;
                let _ = res_tx.send((published, full, snap_ns, c.levels.len()));
                let _ = done_tx.send(());
            });
        },
    )
    .await
    .unwrap();
    let (mut p, mut f, snap_ns, levels) = res_rx.recv().unwrap();
    println!("clip {clip}, RGBA8, {levels} levels, {requests} requests at 60 per second, 60 ticks per second");
    println!(
        "request -> centre published: p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
        pct(&mut p, 0.5),
        pct(&mut p, 0.99),
        pct(&mut p, 1.0)
    );
    println!(
        "request -> level 0 complete: p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
        pct(&mut f, 0.5),
        pct(&mut f, 0.99),
        pct(&mut f, 1.0)
    );
    println!("reader snapshot (all {levels} level states, seqlocked): {snap_ns:.0} ns");
}
