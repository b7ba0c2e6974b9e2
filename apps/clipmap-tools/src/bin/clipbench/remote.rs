//! `clipbench remote`: tiles per second from local files, from loopback HTTP (nginx) and from a
//! loopback S3-compatible store (moto), in the same run over the same hash pyramid; and the
//! number of requests in flight that hides an added latency per request (a delaying proxy in
//! front of nginx, measured against the same proxy without the delay, so that the relay's own
//! cost is not counted as latency).
//!
//! Every tile read is checked against the hash texture at 64 texels (its corners among them);
//! `wrong_texels` counts the texels that differ, over all sources. Reads are made the way the
//! engine's read queues make them: `depth` threads, each reading one tile at a time through
//! [`TileSource::read_tile`].

use super::serve::{free_port, wait_port, Faults, Killed, Nginx, Proxy, Tail};
use clipmap::limits::Limits;
use clipmap::plan;
use clipmap::prep::{self, Filter, Job, Layout, Source, Spec};
use clipmap::source::procedural::hash;
use clipmap::source::remote::{Remote, RemoteOptions, RemoteSource};
use clipmap::source::{FileSource, TileId, TileSource};
use clipmap::texel::TexelFormat;
use serde::Serialize;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Options of `clipbench remote`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A 4096-texel texture and short runs (about a minute in all).
    #[arg(long)]
    quick: bool,
    /// A tiny texture and depths up to 16: checks that the benchmark runs (for tests); the
    /// figures mean little.
    #[arg(long, hide = true, conflicts_with = "quick")]
    smoke: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Reads in flight (threads, and requests per endpoint) for the three rates.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u64).range(1..=256))]
    depth: u64,
    /// Latency the delaying proxy adds to each request, milliseconds.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
    latency_ms: u64,
    /// Scratch directory (a fresh subdirectory, removed at the end).
    #[arg(long)]
    dir: Option<PathBuf>,
    /// Level-0 texels a tick of the real-time flight (`remote_flight`), 60 ticks a second.
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(i64).range(1..=4096))]
    flight_speed: i64,
    /// Seconds of the real-time flight (default: 20, 6 with --quick, 1.5 with --smoke).
    #[arg(long, value_parser = parse_seconds)]
    flight_seconds: Option<f64>,
    /// A tail: the delaying proxy holds `--tail-percent` of the requests this many
    /// milliseconds longer than the others (0: no tail), from the latency sweep on.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=10_000))]
    tail_ms: u64,
    /// The share of the requests the tail holds, percent.
    #[arg(long, default_value_t = 1.0, value_parser = parse_percent)]
    tail_percent: f64,
}

fn parse_percent(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (0.0..=50.0).contains(&v) => Ok(v),
        _ => Err(format!("found `{s}`, expected a percentage from 0 to 50")),
    }
}

fn parse_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (0.5..=600.0).contains(&v) => Ok(v),
        _ => Err(format!("found `{s}`, expected seconds from 0.5 to 600")),
    }
}

/// One depth of the latency sweep.
#[derive(Clone, Debug, Serialize)]
pub struct DepthRate {
    pub in_flight: u64,
    pub tiles_per_s: f64,
}

/// What `clipbench remote` measured.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub texture: u64,
    pub tile: u64,
    pub tile_bytes: u64,
    pub tiles_per_run: u64,
    /// Reads in flight for the three rates.
    pub depth: u64,
    pub tiles_per_s_local: f64,
    pub tiles_per_s_http: f64,
    pub tiles_per_s_s3: f64,
    /// HTTP rate / local rate.
    pub http_vs_local: f64,
    /// Latency added per request by the delaying proxy.
    pub added_latency_ms: u64,
    /// Tiles per second through the proxy without added latency, at `depth` (the relay's ceiling).
    pub tiles_per_s_relay: f64,
    /// Smallest number of requests in flight whose rate through the delaying proxy reached 90 %
    /// of `tiles_per_s_relay`; when none did (`latency_hidden` false), the one with the highest
    /// rate.
    pub in_flight: u64,
    /// The highest rate through the delaying proxy, over the depths tried.
    pub tiles_per_s_delayed_best: f64,
    pub latency_hidden: bool,
    pub latency_sweep: Vec<DepthRate>,
    /// Texels that differ from the hash texture, over every tile read by every source.
    pub wrong_texels: u64,
    /// Reads that failed (after retries), over every source.
    pub failed_reads: u64,
    pub requests_http: u64,
    pub merged_http: u64,
    /// A real-time flight through the delaying proxy with every default (the adaptive policy).
    pub remote_flight: RemoteFlight,
}

/// A flight of the engine over loopback HTTP with `added_latency_ms` per request, every setting
/// its default, 60 ticks a second in real time, back and forth along s.
#[derive(Clone, Debug, Serialize)]
pub struct RemoteFlight {
    pub texels_per_tick: i64,
    pub tick_hz: f64,
    /// Level-0 texels a second the centre moves.
    pub texels_per_s: f64,
    pub added_latency_ms: u64,
    pub seconds: f64,
    pub ticks: u64,
    /// Share of the ticks after the first second on which level 0 is published (goal >= 0.95).
    pub level0_shown_share: f64,
    pub mean_min_lod: f64,
    pub ticks_with_disabled_levels: u64,
    /// The prefetch policy flown (the default).
    pub prefetch: clipmap::paging::PrefetchKind,
    /// The read latency the controller planned with at the end (ticks).
    pub read_latency_ticks: f64,
    /// Published level-0 texels checked against the hash texture (five a tick), and how many
    /// differed.
    pub texels_checked: u64,
    pub wrong_texels: u64,
    /// Milliseconds from a clipmap made over a freshly opened source (through the delaying
    /// proxy) to the first tick that shows level 0 (min LOD below 1), ticking at 60 Hz; and the
    /// same on the local files (`_local`), in the same run. 30 000 when it never did.
    pub cold_start_to_level0_ms: f64,
    pub cold_start_to_level0_ms_local: f64,
    /// Milliseconds from a jump of ten clip sizes along s (fewer where the texture is smaller)
    /// to the first tick that shows level 0 again, over HTTP and on the local files.
    pub jump_to_level0_ms: f64,
    pub jump_to_level0_ms_local: f64,
    /// The same two times over the S3-compatible store (moto, no latency added: its own).
    pub cold_start_to_level0_ms_s3: f64,
    pub jump_to_level0_ms_s3: f64,
    /// The level-0 texels of that jump.
    pub jump_texels: i64,
    /// The requests in flight the source chose for the proxy's endpoint at the end of the
    /// flight, why, the most it had in flight, and its smoothed latency (ms) and read rate.
    pub in_flight_limit: u64,
    pub in_flight_reason: String,
    pub peak_in_flight: u64,
    pub store_latency_ms: f64,
    pub reads_per_s: u64,
    /// Where a request's time went (means over the flight's reads): waiting for a request slot
    /// of the endpoint, and from sent to answered (the proxy's delay, nginx, the connection).
    pub mean_slot_wait_ms: f64,
    pub mean_request_ms: f64,
    /// Share of the requests that were hedged (a second request for a slow one).
    pub hedged_share: f64,
    /// The proxy's tail: the share of the requests held longer, and by how much (0: none).
    pub tail_share: f64,
    pub tail_ms: u64,
    /// Requests the proxy held longer, from the latency sweep to the end of the run.
    pub tail_held_requests: u64,
}

/// Ticks a clipmap at 60 Hz at `at` until it shows level 0 (min LOD below 1); milliseconds from
/// the call, at most `limit`.
fn until_level0(map: &mut clipmap::clip::Clipmap, at: [i64; 2], limit: Duration) -> f64 {
    let period = Duration::from_secs_f64(1.0 / 60.0);
    let start = Instant::now();
    for i in 0u32.. {
        std::thread::sleep((start + period * i).saturating_duration_since(Instant::now()));
        if map.tick(at, None).min_lod < 1.0 {
            break;
        }
        if start.elapsed() >= limit {
            break;
        }
    }
    start.elapsed().as_secs_f64() * 1e3
}

/// The time to level 0 after a cold start over `src`, then after a jump of (up to) ten clip
/// sizes along s: milliseconds each, and the jump in texels.
fn back_to_level0(src: Arc<dyn TileSource>) -> anyhow::Result<(f64, f64, i64)> {
    use clipmap::clip::{Clipmap, Settings};
    let desc = src.desc().clone();
    let (size, clip) = (desc.size()[0] as i64, desc.clip_size() as i64);
    let limit = Duration::from_secs(30);
    let mut map = Clipmap::new(src, Settings::default())?;
    let from = [clip, size / 2];
    let cold = until_level0(&mut map, from, limit);
    let to = [(clip + 10 * clip).min((size - clip).max(clip)), size / 2];
    let jump = until_level0(&mut map, to, limit);
    Ok((cold, jump, to[0] - from[0]))
}

fn moto() -> anyhow::Result<(Killed, u16)> {
    let ok = Command::new("python3")
        .args(["-c", "import moto.server"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    anyhow::ensure!(ok, "moto is needed and was not found: install it (pip install 'moto[server]')");
    let port = free_port()?;
    let child = Command::new("python3")
        .args(["-m", "moto.server", "-H", "127.0.0.1", "-p", &port.to_string()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()?;
    let k = Killed(child);
    wait_port(port, "moto")?;
    let mut s = TcpStream::connect(("127.0.0.1", port))?;
    write!(s, "PUT /clipbench HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")?;
    let mut reply = String::new();
    s.read_to_string(&mut reply)?;
    anyhow::ensure!(reply.starts_with("HTTP/1.1 200"), "moto refused to make the bucket: {reply}");
    Ok((k, port))
}

/// A keep-alive HTTP proxy to `upstream` that holds every request `delay` before forwarding it
/// (and `tail`'s share of them `tail.hold` longer).
fn delaying_proxy(upstream: u16, delay: Duration, tail: Tail, stop: Arc<AtomicBool>) -> anyhow::Result<Proxy> {
    Proxy::start_with_tail(upstream, delay, Faults::default(), tail, stop)
}

/// Reads `tiles` with `depth` threads; returns tiles per second (of tiles read), wrong texels (64
/// checked per tile) and failed reads.
fn rate(src: &dyn TileSource, tiles: &[TileId], depth: u64, passes: usize) -> (f64, u64, u64) {
    let next = AtomicUsize::new(0);
    let wrong = AtomicU64::new(0);
    let failed = AtomicU64::new(0);
    let total = tiles.len() * passes;
    let bpt = src.desc().format().bytes_per_texel() as usize;
    let start = Instant::now();
    std::thread::scope(|s| {
        for _ in 0..depth {
            s.spawn(|| {
                let mut buf = Vec::new();
                let mut want = vec![0u8; bpt];
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= total {
                        break;
                    }
                    let id = tiles[i % tiles.len()];
                    let d = src.desc().level(id.level);
                    buf.resize(src.desc().tile_bytes(id.level), 0);
                    if src.read_tile(id, &mut buf).is_err() {
                        failed.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    let (w, h) = (d.tile[0], d.tile[1]);
                    let mut bad = 0;
                    for k in 0..64u64 {
                        let (x, y) = match k {
                            0 => (0, 0),
                            1 => (w - 1, h - 1),
                            _ => (clipmap::source::procedural::splitmix64(i as u64 * 64 + k) % w, (k * 7919) % h),
                        };
                        hash(id.level, id.s * w + x, id.t * h + y, &mut want);
                        let at = ((y * w + x) as usize) * bpt;
                        bad += (buf[at..at + bpt] != want[..]) as u64;
                    }
                    wrong.fetch_add(bad, Ordering::Relaxed);
                }
            });
        }
    });
    let secs = start.elapsed().as_secs_f64().max(1e-9);
    let ok = total as u64 - failed.load(Ordering::Relaxed);
    (ok as f64 / secs, wrong.load(Ordering::Relaxed), failed.load(Ordering::Relaxed))
}

fn open_plan(ct: &Path) -> anyhow::Result<plan::ClipTexturePlan> {
    let loaded = plan::load_clip_texture(ct, &plan::Options::default())?;
    let rendered = loaded.render();
    loaded.plan.ok_or_else(|| anyhow::anyhow!("{}: {rendered}", ct.display()))
}

fn remote_source(ct: &Path, in_flight: u64) -> anyhow::Result<RemoteSource> {
    let opts = RemoteOptions { in_flight: in_flight as usize, ..RemoteOptions::default() };
    Ok(RemoteSource::new(open_plan(ct)?, &Limits::default(), opts)?)
}

fn measure(args: &Args, dir: &Path) -> anyhow::Result<Report> {
    let (n, tile) = if args.smoke {
        (512, 64)
    } else if args.quick {
        (4096, 256)
    } else {
        (8192, 256)
    };
    let passes = if args.quick || args.smoke { 2 } else { 4 };
    let depths: &[u64] = if args.smoke { &[1, 4, 16] } else { &[1, 2, 4, 8, 16, 24, 32, 48, 64, 96, 128, 192, 256] };
    let layout = Layout::new(Spec {
        width: n,
        height: n,
        clip: if args.smoke { 128 } else { 512 },
        tile,
        format: TexelFormat::RGBA8,
        tiles_in_file: (1, 1),
        header_bytes: 0,
        streams: None,
        inset: None,
        compression: None,
    })?;
    let root = dir.join("pyramid");
    let job = Job {
        layout,
        source: Source::Hash,
        filter: Filter::Box,
        linear_light: false,
        name: "hash".into(),
        description: vec!["clipbench remote".into()],
        limits: prep::Limits::default(),
    };
    let summary = prep::run(job, &root, &AtomicBool::new(false), dir, &|_| {})?;
    let local_ct = root.join(&summary.ct);

    let nginx = Nginx::serve(&root, &dir.join("nginx"), None, None)?;
    let http_port = nginx.port;
    let (_moto, s3_port) = moto()?;
    // The benchmark's own store: these variables are this process's, set before any thread
    // reads them.
    std::env::set_var("AWS_ACCESS_KEY_ID", "clipbench");
    std::env::set_var("AWS_SECRET_ACCESS_KEY", "clipbench");
    std::env::set_var("AWS_REGION", "us-east-1");
    std::env::set_var("AWS_ENDPOINT_URL", format!("http://127.0.0.1:{s3_port}"));
    let uploader = Remote::new(RemoteOptions::default())?;
    prep::publish::upload(&root, "s3://clipbench/pyr", &uploader, &|_| {}).map_err(|e| anyhow::anyhow!(e))?;

    let http_base = format!("http://127.0.0.1:{http_port}");
    let http_ct = prep::publish::write_pointed_config(&root, &dir.join("http"), &http_base, &[])?;
    let s3_ct = prep::publish::write_pointed_config(&root, &dir.join("s3"), "s3://clipbench/pyr", &[])?;

    let local = FileSource::new(open_plan(&local_ct)?, &Limits::default())?;
    let desc = local.desc().clone();
    let tiles: Vec<TileId> = (0..desc.level_count() as u32)
        .filter(|&k| desc.level(k).tile == [tile, tile])
        .flat_map(|k| {
            let t = desc.level(k).tiles();
            (0..t[1]).flat_map(move |tt| (0..t[0]).map(move |s| TileId::new(k, s, tt)))
        })
        .collect();
    let (mut wrong, mut failed) = (0, 0);
    // Warm: every file once (page cache, connections).
    let (_, w, f) = rate(&local, &tiles, args.depth, 1);
    wrong += w;
    failed += f;
    let (local_rate, w, f) = rate(&local, &tiles, args.depth, passes);
    wrong += w;
    failed += f;
    let http = remote_source(&http_ct, args.depth)?;
    let (_, w, f) = rate(&http, &tiles, args.depth, 1);
    wrong += w;
    failed += f;
    let (http_rate, w, f) = rate(&http, &tiles, args.depth, passes);
    wrong += w;
    failed += f;
    let s3 = remote_source(&s3_ct, args.depth)?;
    let (s3_rate, w, f) = rate(&s3, &tiles, args.depth, 1);
    wrong += w;
    failed += f;

    let stop = Arc::new(AtomicBool::new(false));
    // The proxy's own ceiling: the same relay without the added latency, at `depth`.
    let direct = delaying_proxy(http_port, Duration::ZERO, Tail::default(), stop.clone())?.port;
    let direct_ct =
        prep::publish::write_pointed_config(&root, &dir.join("relay"), &format!("http://127.0.0.1:{direct}"), &[])?;
    let relay = remote_source(&direct_ct, args.depth)?;
    let (_, w, f) = rate(&relay, &tiles, args.depth, 1);
    wrong += w;
    failed += f;
    let (relay_rate, w, f) = rate(&relay, &tiles, args.depth, 1);
    wrong += w;
    failed += f;
    let tail = Tail { share: args.tail_percent / 100.0, hold: Duration::from_millis(args.tail_ms) };
    let tail = if args.tail_ms == 0 { Tail::default() } else { tail };
    let delaying = delaying_proxy(http_port, Duration::from_millis(args.latency_ms), tail, stop.clone())?;
    let proxy = delaying.port;
    let slow_ct =
        prep::publish::write_pointed_config(&root, &dir.join("slow"), &format!("http://127.0.0.1:{proxy}"), &[])?;
    let mut sweep = Vec::new();
    let mut found = None;
    for &depth in depths {
        let slow = remote_source(&slow_ct, depth)?;
        // Enough reads for every thread to wait for 16 round trips: warm-up is a small part.
        let passes = (depth as usize * 16).div_ceil(tiles.len()).max(1);
        let (r, w, f) = rate(&slow, &tiles, depth, passes);
        wrong += w;
        failed += f;
        sweep.push(DepthRate { in_flight: depth, tiles_per_s: r });
        if r >= 0.9 * relay_rate {
            found = Some(depth);
            break;
        }
    }
    let flight_s = args.flight_seconds.unwrap_or(if args.smoke {
        1.5
    } else if args.quick {
        6.0
    } else {
        20.0
    });
    let mut remote_flight = fly(&slow_ct, args.latency_ms, flight_s, args.flight_speed)?;
    let (cold, jump, texels) = back_to_level0(Arc::new(FileSource::new(open_plan(&local_ct)?, &Limits::default())?))?;
    (remote_flight.cold_start_to_level0_ms_local, remote_flight.jump_to_level0_ms_local) = (cold, jump);
    let slow: Arc<dyn TileSource> =
        Arc::new(RemoteSource::new(open_plan(&slow_ct)?, &Limits::default(), RemoteOptions::default())?);
    let (cold, jump, _) = back_to_level0(slow)?;
    (remote_flight.cold_start_to_level0_ms, remote_flight.jump_to_level0_ms, remote_flight.jump_texels) =
        (cold, jump, texels);
    let s3: Arc<dyn TileSource> =
        Arc::new(RemoteSource::new(open_plan(&s3_ct)?, &Limits::default(), RemoteOptions::default())?);
    let (cold, jump, _) = back_to_level0(s3)?;
    (remote_flight.cold_start_to_level0_ms_s3, remote_flight.jump_to_level0_ms_s3) = (cold, jump);
    (remote_flight.tail_share, remote_flight.tail_ms) = (tail.share, tail.hold.as_millis() as u64);
    remote_flight.tail_held_requests = delaying.counters.held.load(Ordering::Relaxed);
    stop.store(true, Ordering::Relaxed);
    let best = sweep
        .iter()
        .max_by(|a, b| a.tiles_per_s.total_cmp(&b.tiles_per_s))
        .cloned()
        .unwrap_or(DepthRate { in_flight: 1, tiles_per_s: 0.0 });
    let st = http.stats();
    Ok(Report {
        texture: n,
        tile,
        tile_bytes: desc.tile_bytes(0) as u64,
        tiles_per_run: (tiles.len() * passes) as u64,
        depth: args.depth,
        tiles_per_s_local: local_rate,
        tiles_per_s_http: http_rate,
        tiles_per_s_s3: s3_rate,
        http_vs_local: http_rate / local_rate.max(1e-9),
        added_latency_ms: args.latency_ms,
        tiles_per_s_relay: relay_rate,
        in_flight: found.unwrap_or(best.in_flight),
        tiles_per_s_delayed_best: best.tiles_per_s,
        latency_hidden: found.is_some(),
        latency_sweep: sweep,
        wrong_texels: wrong,
        failed_reads: failed,
        requests_http: st.requests,
        merged_http: st.merged,
        remote_flight,
    })
}

/// Flies a clipmap with every default setting over the source `ct` names (through the delaying
/// proxy) for `seconds` in real time at 60 ticks a second, `speed` level-0 texels a tick (32 by
/// default: 1920 a second), back and forth along s between a clip size from either edge; checks
/// five published level-0 texels a tick against the hash texture.
fn fly(ct: &Path, latency_ms: u64, seconds: f64, speed: i64) -> anyhow::Result<RemoteFlight> {
    use clipmap::clip::{Clipmap, Settings};
    let remote = Arc::new(RemoteSource::new(open_plan(ct)?, &Limits::default(), RemoteOptions::default())?);
    let src: Arc<dyn TileSource> = remote.clone();
    let desc = src.desc().clone();
    let settings = Settings::default();
    let prefetch = settings.prefetch;
    let mut map = Clipmap::new(src, settings)?;
    let (size, clip) = (desc.size()[0] as i64, desc.clip_size() as i64);
    let (lo, hi) = (clip, (size - clip).max(clip + 1));
    let hz = 60.0;
    let at = |i: i64| {
        let span = hi - lo;
        let x = (i * speed).rem_euclid(2 * span);
        [lo + if x <= span { x } else { 2 * span - x }, size / 2]
    };
    // Settle at the start (untimed).
    for _ in 0..3000 {
        if map.tick(at(0), Some([0, 0])).min_lod == 0.0 {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let period = Duration::from_secs_f64(1.0 / hz);
    let ticks = (seconds * hz) as u64;
    let (mut shown, mut after, mut lod_sum, mut disabled, mut checked, mut wrong) = (0u64, 0u64, 0.0, 0u64, 0u64, 0u64);
    let bpt = desc.bytes_per_texel();
    let mut want = vec![0u8; bpt];
    let start = Instant::now();
    for i in 0..ticks {
        std::thread::sleep((start + period * i as u32).saturating_duration_since(Instant::now()));
        let r = map.tick(at(i as i64 + 1), None);
        lod_sum += r.min_lod;
        disabled += u64::from(!r.disabled_levels.is_empty());
        if i >= hz as u64 {
            after += 1;
            shown += u64::from(r.min_lod < 1.0);
        }
        let v = map.level(0);
        let g = v.valid;
        if !g.is_empty() {
            let mid = [(g.s0 + g.s1) / 2, (g.t0 + g.t1) / 2];
            for [s, t] in [[g.s0, g.t0], [g.s1 - 1, g.t0], [g.s0, g.t1 - 1], [g.s1 - 1, g.t1 - 1], mid] {
                if let Some(texel) = v.texel(s, t) {
                    hash(0, s as u64, t as u64, &mut want);
                    checked += 1;
                    wrong += u64::from(texel[..] != want[..]);
                }
            }
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let st = remote.stats();
    let per = |us: u64, n: u64| us as f64 / 1e3 / n.max(1) as f64;
    Ok(RemoteFlight {
        texels_per_tick: speed,
        tick_hz: hz,
        texels_per_s: speed as f64 * hz,
        added_latency_ms: latency_ms,
        seconds: wall,
        ticks,
        level0_shown_share: if after == 0 { 0.0 } else { shown as f64 / after as f64 },
        mean_min_lod: lod_sum / ticks.max(1) as f64,
        ticks_with_disabled_levels: disabled,
        prefetch,
        read_latency_ticks: map.stats().read_latency_ticks,
        texels_checked: checked,
        wrong_texels: wrong,
        cold_start_to_level0_ms: 0.0,
        cold_start_to_level0_ms_local: 0.0,
        jump_to_level0_ms: 0.0,
        jump_to_level0_ms_local: 0.0,
        cold_start_to_level0_ms_s3: 0.0,
        jump_to_level0_ms_s3: 0.0,
        jump_texels: 0,
        in_flight_limit: st.in_flight_limit,
        in_flight_reason: st.in_flight_reason.clone(),
        peak_in_flight: st.peak_in_flight,
        store_latency_ms: st.latency_us as f64 / 1e3,
        reads_per_s: st.reads_per_s,
        mean_slot_wait_ms: per(st.slot_wait_us, st.requests.saturating_sub(st.retries)),
        mean_request_ms: per(st.request_us, st.answered),
        hedged_share: st.hedged as f64 / st.requests.max(1) as f64,
        tail_share: 0.0,
        tail_ms: 0,
        tail_held_requests: 0,
    })
}

fn human(r: &Report) -> String {
    let mut o = format!(
        "texture {0}x{0}, tiles {1}x{1} ({2} bytes), {3} tiles a run, {4} reads in flight\n\
         local files   {5:>10.0} tiles/s\nloopback HTTP {6:>10.0} tiles/s ({7:.2} of local)\nloopback S3   {8:>10.0} tiles/s\n",
        r.texture, r.tile, r.tile_bytes, r.tiles_per_run, r.depth, r.tiles_per_s_local, r.tiles_per_s_http, r.http_vs_local, r.tiles_per_s_s3
    );
    o.push_str(&format!("+{} ms per request:", r.added_latency_ms));
    for d in &r.latency_sweep {
        o.push_str(&format!(" {}:{:.0}", d.in_flight, d.tiles_per_s));
    }
    o.push_str(&format!(
        "\n{} requests in flight {} the added latency (90 % of the relay's {:.0} tiles/s without it)\nwrong texels: {}, failed reads: {}\n",
        r.in_flight,
        if r.latency_hidden { "hide" } else { "do not hide" },
        r.tiles_per_s_relay,
        r.wrong_texels,
        r.failed_reads
    ));
    let f = &r.remote_flight;
    if f.tail_ms > 0 {
        o.push_str(&format!(
            "tail: {:.1}% of the requests held {} ms longer ({} held)\n",
            f.tail_share * 100.0,
            f.tail_ms,
            f.tail_held_requests
        ));
    }
    o.push_str(&format!(
        "real-time flight through +{} ms per request, {} prefetch, {} texels a tick at {} ticks/s ({:.0} texels/s) for {:.1} s: level 0 shown on {:.1}% of the ticks after the first second (goal >= 95%), mean min LOD {:.2}, {} ticks with a disabled level, planned latency {:.1} ticks; {} of {} published texels wrong\n",
        f.added_latency_ms,
        f.prefetch,
        f.texels_per_tick,
        f.tick_hz,
        f.texels_per_s,
        f.seconds,
        f.level0_shown_share * 100.0,
        f.mean_min_lod,
        f.ticks_with_disabled_levels,
        f.read_latency_ticks,
        f.wrong_texels,
        f.texels_checked
    ));
    o.push_str(&format!(
        "requests in flight {} ({}; peak {}), store latency {:.1} ms, {} reads/s; a read waited {:.2} ms for a slot, a request took {:.1} ms; {:.1}% hedged\n\
         level 0 after a cold start {:.0} ms (local {:.0}, S3 {:.0}), after a jump of {} texels {:.0} ms (local {:.0}, S3 {:.0})\n",
        f.in_flight_limit,
        f.in_flight_reason,
        f.peak_in_flight,
        f.store_latency_ms,
        f.reads_per_s,
        f.mean_slot_wait_ms,
        f.mean_request_ms,
        f.hedged_share * 100.0,
        f.cold_start_to_level0_ms,
        f.cold_start_to_level0_ms_local,
        f.cold_start_to_level0_ms_s3,
        f.jump_texels,
        f.jump_to_level0_ms,
        f.jump_to_level0_ms_local,
        f.jump_to_level0_ms_s3
    ));
    o
}

/// Runs the benchmark; the exit status (0 ok, 1 wrong texels were read, 2 could not run).
pub fn main(args: Args) -> u8 {
    super::run_in_scratch(
        "remote",
        args.dir.as_deref(),
        args.json,
        |dir| measure(&args, dir),
        human,
        |r| r.wrong_texels > 0 || r.remote_flight.wrong_texels > 0,
    )
}
