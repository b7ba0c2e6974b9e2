//! Service latency, as `examples/service_latency.rs` measures it: the service in this process
//! (its tick loop at 60 ticks a second, default budget) over a hash texture of 2^20 texels, a
//! reader attached to the mapping requesting a centre 8 texels further 60 times a second, timing
//! request → level 0's state carries the centre, and request → level 0 complete around it.
//! Requests are spread over the tick's phase (each at a pseudo-random offset within its 1/60 s
//! slot): requests in lock step with the ticks would measure only their fixed phase difference.
//! The texture is georeferenced (the Web Mercator square, `clipmapd --georef web-mercator`) and
//! every other request gives its centre in longitude / latitude (the request mapping's coordinate
//! kind 1: the middle of the same next texel) instead of in texels: `lonlat_vs_texels` is the
//! median request -> published latency of those over the texel ones, in the same run.

use super::{quantile, Size};
use anyhow::Context;
use clipmap::shm::{Client, RequestPosition};
use clipmap::source::procedural::splitmix64;
use clipmap_service::{procedural_source, run, Options, Procedural};
use serde::Serialize;
use std::time::{Duration, Instant};

/// What the latency run measured.
#[derive(Clone, Debug, Serialize)]
pub struct Latency {
    pub texture: u64,
    pub clip: u64,
    pub requests: usize,
    pub published_p50_s: f64,
    pub published_p99_s: f64,
    pub published_max_s: f64,
    pub complete_p50_s: f64,
    pub complete_p99_s: f64,
    pub complete_max_s: f64,
    /// One reader snapshot of every level's state (seqlocked).
    pub snapshot_ns: f64,
    /// The requests that gave their centre in longitude / latitude (every other one): request
    /// -> level 0's state carries the centre, median and 99th percentile.
    pub lonlat_published_p50_s: f64,
    pub lonlat_published_p99_s: f64,
    /// The requests in texels (the others), likewise.
    pub texels_published_p50_s: f64,
    pub texels_published_p99_s: f64,
    /// `lonlat_published_p50_s / texels_published_p50_s` (goal <= 1.05).
    pub lonlat_vs_texels: f64,
}

/// Request -> published and request -> complete of every request, whether each was in longitude
/// / latitude, and a snapshot's time.
type Samples = (Vec<f64>, Vec<f64>, Vec<bool>, f64);

fn reader(shm_dir: &std::path::Path, clip: u64, requests: usize) -> anyhow::Result<Samples> {
    let c = Client::attach(shm_dir, "perf").map_err(|e| anyhow::anyhow!("attaching: {e}"))?;
    let base = [1i64 << 19, 1 << 19];
    let border = c.snapshot().invalid_border;
    let complete =
        |st: &clipmap::shm::LevelState| st.enabled && (st.valid[2] - st.valid[0]) as u64 + 2 * border >= clip;
    c.request_centre(base, [0.0, 0.0]);
    let t = Instant::now();
    while !(c.level_state(0).is_some_and(|s| s.centre == base && complete(&s))) {
        anyhow::ensure!(t.elapsed() < Duration::from_secs(60), "the first window did not fill in 60 s");
        std::thread::sleep(Duration::from_millis(1));
    }
    let georef =
        clipmap::shm::georef_of(c.georef.as_ref().context("the mapping has no georef block")?, c.levels[0].size)
            .map_err(|e| anyhow::anyhow!("the mapping's georef block: {e}"))?;
    let (mut published, mut full, mut lonlat) = (Vec::new(), Vec::new(), Vec::new());
    let period = Duration::from_secs_f64(1.0 / 60.0);
    let start = Instant::now();
    for i in 1..=requests {
        let phase = (splitmix64(i as u64) >> 11) as f64 / (1u64 << 53) as f64;
        let slot = start + period * i as u32 + period.mul_f64(phase);
        std::thread::sleep(slot.saturating_duration_since(Instant::now()));
        let want = [base[0] + 8 * i as i64, base[1]];
        // Every other request by longitude / latitude: the middle of the same texel.
        let by_lonlat = i % 2 == 1;
        let ll = georef.texel_to_lonlat(0, [want[0] as f64 + 0.5, want[1] as f64 + 0.5]);
        let ll = ll.map_err(|e| anyhow::anyhow!("texel {want:?}: {e}"))?;
        let t0 = Instant::now();
        if by_lonlat {
            c.request_position(RequestPosition::LonLat(ll), [480.0, 0.0]);
        } else {
            c.request_centre(want, [480.0, 0.0]);
        }
        let mut seen = None;
        loop {
            if let Some(st) = c.level_state(0) {
                if st.centre == want && seen.is_none() {
                    seen = Some(t0.elapsed());
                }
                if st.centre == want && complete(&st) || st.centre[0] > want[0] || t0.elapsed() > Duration::from_secs(2)
                {
                    break;
                }
            }
            std::thread::sleep(Duration::from_micros(50));
        }
        let e = t0.elapsed();
        published.push(seen.unwrap_or(e).as_secs_f64());
        full.push(e.as_secs_f64());
        lonlat.push(by_lonlat);
    }
    let n = 20_000;
    let t = Instant::now();
    for _ in 0..n {
        std::hint::black_box(c.snapshot());
    }
    Ok((published, full, lonlat, t.elapsed().as_nanos() as f64 / n as f64))
}

pub fn measure(size: Size) -> anyhow::Result<Latency> {
    let (texture, clip, requests) = match size {
        Size::Full => (1u64 << 20, 2048, 600),
        Size::Quick => (1 << 20, 2048, 120),
        Size::Smoke => (1 << 20, 256, 10),
    };
    let dir = super::Scratch::new(None)?;
    let mut o = Options::new("perf");
    o.shm_dir = dir.0.clone();
    o.socket = dir.0.join("perf.sock");
    let source = clipmap_service::web_mercator_square(procedural_source(Procedural::Hash, texture, clip, 256)?);
    let (done_tx, done_rx) = tokio::sync::oneshot::channel::<()>();
    let (res_tx, res_rx) = std::sync::mpsc::channel();
    let shm_dir = dir.0.clone();
    clipmap::runtime::block_on(run(
        source,
        o,
        async {
            let _ = done_rx.await;
        },
        move |_| {
            std::thread::spawn(move || {
                let _ = res_tx.send(reader(&shm_dir, clip, requests));
                let _ = done_tx.send(());
            });
        },
    ))?
    .map_err(|e| anyhow::anyhow!("the service: {e}"))?;
    let (published, full, lonlat, snapshot_ns) =
        res_rx.recv().context("the reader thread ended without a result")??;
    let of = |want: bool| -> Vec<f64> {
        published.iter().zip(&lonlat).filter(|(_, l)| **l == want).map(|(p, _)| *p).collect()
    };
    let (by_lonlat, by_texels) = (of(true), of(false));
    Ok(Latency {
        texture,
        clip,
        requests,
        published_p50_s: quantile(&published, 0.5),
        published_p99_s: quantile(&published, 0.99),
        published_max_s: quantile(&published, 1.0),
        complete_p50_s: quantile(&full, 0.5),
        complete_p99_s: quantile(&full, 0.99),
        complete_max_s: quantile(&full, 1.0),
        snapshot_ns,
        lonlat_published_p50_s: quantile(&by_lonlat, 0.5),
        lonlat_published_p99_s: quantile(&by_lonlat, 0.99),
        texels_published_p50_s: quantile(&by_texels, 0.5),
        texels_published_p99_s: quantile(&by_texels, 0.99),
        lonlat_vs_texels: quantile(&by_lonlat, 0.5) / quantile(&by_texels, 0.5),
    })
}
