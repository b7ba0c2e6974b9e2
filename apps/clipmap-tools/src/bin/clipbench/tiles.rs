//! `clipbench tiles`: tiles per second from a tile service and from tile archives served as they
//! are (an XYZ tree over HTTP, a PMTiles over HTTP and from disk, an MBTiles), against GDAL
//! reading the same tiles and curl fetching them, in one run; and a real-time flight over the
//! XYZ service with latency added to every request (`tiles_flight.rs`). GDAL and curl are driven
//! by `tiles_peers.rs`.
//!
//! The data is made here, with no network: the procedural terrain texture (smooth, coloured like
//! land and sea, so it compresses as imagery does) as one RGB image over the whole Web Mercator
//! square, cut into an XYZ tree of 256² PNG tiles by GDAL's `gdal2tiles.py --xyz`; the same tile
//! files are then written into a PMTiles by the reference writer (Python's `pmtiles` package) and
//! into an MBTiles (SQLite, TMS rows, its `metadata` table), so every kind serves the same bytes.
//! nginx serves the tree and the PMTiles on loopback.
//!
//! Every kind reads every tile of the finest zoom (level 0), `passes` times, each pass on a fresh
//! open (nothing of ours kept from the pass before; the files in the page cache: warm disk, cold
//! source); the median pass is reported:
//! - ours: `depth` threads over one [`PyramidSource`], as the engine's read queues run them;
//! - GDAL: `depth` processes, each on its own open (before the clock starts), one `ReadRaster` a
//!   tile, the tiles dealt out in turn (the same concurrency); for XYZ its WMS driver's TMS
//!   mini-driver, for MBTiles its MBTiles driver; GDAL 3.6 reads no PMTiles (`null`);
//! - curl (HTTP kinds): the same requests our first pass made (the tile URLs; the PMTiles' byte
//!   ranges, from nginx's log), `depth` transfers at once over kept connections.
//!
//! `wrong_texels` compares every texel we read, in every pass, with GDAL's own decode of the same
//! tile file (rows turned over: our t counts up from the south); `gdal_wrong_texels` checks GDAL's
//! reads of each kind the same way (that it read the same tiles).

use super::cog_shared::{median, Spent};
use super::perf::MachineCpu;
use super::serve::{AccessLog, Hit, Nginx};
use super::tiles_cpu::{self, MemoryArchive};
use super::tiles_flight::{self, Flight};
use super::tiles_peers::{self, Gdal, Reference, Transfer, BPT};
use super::tiles_planet::{self, PlanetOpen};
use clipmap::source::remote::RemoteOptions;
use clipmap::source::tiles::{self, OpenOptions, PyramidOptions, PyramidSource, TemplateOptions, TileAddr};
use clipmap::source::{Procedural, TextureDesc, TileId, TileSource};
use clipmap::texel::TexelFormat;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Options of `clipbench tiles`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A small pyramid (zooms 0..3, 64 tiles a pass) and short flights: checks that the
    /// benchmark runs, in seconds; the figures mean little.
    #[arg(long)]
    quick: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Reads in flight: our threads, GDAL's processes, curl's transfers.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..=64))]
    depth: u64,
    /// Timed passes over every level-0 tile, each side (the median pass is reported).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=100))]
    passes: u64,
    /// Each HTTP connection limited to this many megabytes (10^6 bytes) a second (nginx's
    /// `limit_rate`), for GDAL, curl and ours alike. Unlimited when absent.
    #[arg(long, value_name = "MB_PER_S", value_parser = clap::value_parser!(u64).range(1..=100_000))]
    link_rate: Option<u64>,
    /// The flight's first speed, level-0 texels a tick at 60 ticks a second (the speed the
    /// goal is stated at); faster ones are then tried for the largest that still holds.
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(i64).range(1..=4096))]
    flight_speed: i64,
    /// Milliseconds the flight's relay holds every request.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(0..=10_000))]
    latency_ms: u64,
    /// Scratch directory (a fresh subdirectory, removed at the end).
    #[arg(long)]
    dir: Option<PathBuf>,
}

/// One kind of pyramid, as `clipbench tiles --json` prints it. The fields the tiles issue names
/// (`tiles_per_s`, `tiles_per_s_gdal`, `curl_ceiling_tiles_per_s`, `requests`, `open_requests`,
/// `open_bytes`, `wrong_texels`) are a contract; `null` where the kind has none (GDAL reads no
/// PMTiles; a local kind makes no requests).
#[derive(Debug, Serialize)]
pub struct Kind {
    /// What was opened.
    pub source: String,
    /// Level-0 tiles a pass.
    pub tiles: u64,
    /// Ours, `depth` threads, median pass (a fresh open each pass, not timed).
    pub tiles_per_s: f64,
    /// GDAL, `depth` processes, one `ReadRaster` a tile, median pass.
    pub tiles_per_s_gdal: Option<f64>,
    /// Ours over GDAL's (goal >= 2).
    pub vs_gdal: Option<f64>,
    /// GDAL's driver.
    pub gdal_driver: Option<&'static str>,
    /// GDAL in one process, as its users run it.
    pub tiles_per_s_gdal_one_process: Option<f64>,
    /// curl making the requests of our pass, `depth` at once (HTTP kinds).
    pub curl_ceiling_tiles_per_s: Option<f64>,
    /// Ours over curl's (goal >= 0.8 at `--link-rate 100`).
    pub vs_curl: Option<f64>,
    /// Requests of our first pass, open included (nginx's log; HTTP kinds).
    pub requests: Option<u64>,
    /// Requests a tile of that pass, open excluded.
    pub requests_per_tile_cold: Option<f64>,
    /// Requests a tile of a pass over the same tiles on a source already open and read once
    /// (goal <= 1).
    pub requests_per_tile_warm: Option<f64>,
    /// GDAL's requests a pass, open included (HTTP kinds).
    pub requests_gdal: Option<u64>,
    /// Requests and bytes of our open (HTTP kinds).
    pub open_requests: Option<u64>,
    pub open_bytes: Option<u64>,
    /// Ours, seconds to open (median).
    pub open_s: f64,
    /// Texels we read that differ from GDAL's decode of the tile file, over every pass.
    pub wrong_texels: u64,
    /// Texels GDAL read through this kind's driver that differ from the same decode (one pass).
    pub gdal_wrong_texels: Option<u64>,
    /// Our reads that failed.
    pub failed_reads: u64,
    /// Our time a tile that decoding the tile's bytes alone takes (the decode-only rate's share).
    pub decode_share: f64,
    /// Cores busy on average during our passes (the whole machine: ours, nginx, the kernel).
    pub cores_busy: f64,
    /// The machine's busy CPU a tile of our passes, microseconds.
    pub core_us_per_tile: f64,
    /// The same under curl (HTTP kinds).
    pub core_us_per_tile_curl: Option<f64>,
    /// Our process's CPU a tile over the timed passes (every thread), microseconds: robust to
    /// other work on the machine, unlike `core_us_per_tile`.
    pub cpu_us_per_tile: f64,
    /// Our process's CPU a tile of a pass that only fetches the tiles' bytes through this kind's
    /// archive (HTTP client, remote stack, directories), on a fresh open.
    pub cpu_us_per_tile_fetch: f64,
    /// curl's processes' CPU a tile (HTTP kinds; the kernel's 1/100 s counts).
    pub cpu_us_per_tile_curl: Option<f64>,
    /// nginx's CPU a tile while our passes ran, and while curl's did (HTTP kinds).
    pub nginx_cpu_us_per_tile: Option<f64>,
    pub nginx_cpu_us_per_tile_curl: Option<f64>,
    /// Ours over curl's rate as the CPU alone predicts on a machine both saturate: (curl +
    /// nginx under curl) / (ours + nginx under ours), a tile (HTTP kinds).
    pub vs_curl_by_cpu: Option<f64>,
    /// The most ours over curl can be while a tile's decode, checks and copies cost what they
    /// cost (`cpu.us_per_tile_memory_pass`) even if our fetch cost no more than curl's whole
    /// process: (curl + nginx) / (memory pass + curl + nginx), a tile (HTTP kinds).
    pub vs_curl_bound_by_decode: Option<f64>,
}

/// Where a tile's CPU goes that no kind changes (`tiles_cpu.rs`), microseconds a tile.
#[derive(Debug, Serialize)]
pub struct Cpu {
    /// The decode alone, each thread's CPU clock: the `image` crate (load from memory, RGBA,
    /// rows turned over into a slot), as the pyramid decoded PNG tiles before.
    pub us_per_tile_decode_image: f64,
    /// The same tiles with `zune-png` into the slot, rows turned over in place, CRC and
    /// Adler-32 checked: what the pyramid does now for plain PNG tiles.
    pub us_per_tile_decode_zune: f64,
    /// A pass of a pyramid source over the tiles' bytes in memory: the checks, the decode into
    /// the slot and any copies, our whole cost a tile apart from the fetch (process CPU).
    pub us_per_tile_memory_pass: f64,
}

/// The four kinds.
#[derive(Debug, Serialize)]
pub struct Kinds {
    pub xyz: Kind,
    pub pmtiles_http: Kind,
    pub pmtiles_local: Kind,
    pub mbtiles: Kind,
}

/// The pyramid measured.
#[derive(Debug, Serialize)]
pub struct Data {
    /// Where its texels come from.
    pub image: &'static str,
    /// Who cut it into tiles.
    pub tiler: String,
    /// Texels a side of the finest zoom.
    pub size: u64,
    pub tile: u64,
    pub max_zoom: u8,
    pub encoding: &'static str,
    /// Tiles of every zoom, and of the finest.
    pub tiles: u64,
    pub level0_tiles: u64,
    /// The level-0 tiles' bytes, mean.
    pub level0_tile_bytes_mean: f64,
    pub pmtiles_bytes: u64,
    pub mbtiles_bytes: u64,
}

/// What `clipbench tiles --json` prints.
#[derive(Debug, Serialize)]
pub struct Report {
    pub kinds: Kinds,
    /// The real-time flight over the XYZ service with latency added.
    pub flight: Flight,
    /// Decoding the level-0 tiles' bytes (held in memory) into texels in texture orientation,
    /// `depth` threads: the most any kind can read.
    pub tiles_per_s_decode_only: f64,
    /// Where a tile's CPU goes apart from the fetch.
    pub cpu: Cpu,
    /// A sparse z0..z18 planet's open over HTTP against the small archive's (`tiles_planet.rs`).
    pub sparse_planet_open: PlanetOpen,
    /// How the passes were run.
    pub state: &'static str,
    pub data: Data,
    pub gdal_version: String,
    /// `--link-rate`, megabytes a second a connection (`null`: no limit).
    pub link_rate_mb_per_s: Option<u64>,
    /// Reads in flight, each side.
    pub depth: u64,
    pub passes: u64,
    pub nproc: usize,
    /// Whether every goal of the issue that this run measures is met.
    pub goals: Goals,
}

/// The goals, each met by every kind that measures it (a kind without the figure, such
/// as a local kind's curl share, counts as meeting it).
#[derive(Debug, Serialize)]
pub struct Goals {
    /// Ours >= 2x GDAL where GDAL reads the kind.
    pub twice_gdal: bool,
    /// Ours >= 0.8 of curl (HTTP kinds; the goal is stated at `--link-rate 100`).
    pub curl_share: bool,
    /// At most one request a tile warm.
    pub one_request_warm: bool,
    pub no_wrong_texels: bool,
    /// Level 0 shown on >= 95 % of the flight's ticks at 32 texels a tick.
    pub flight: bool,
}

const STATE: &str = "each pass on a fresh open (our source, GDAL's datasets and curl hold no tile from the pass before); the files in the page cache; requests_per_tile_warm from one more pass on a source already open";

/// Writes the terrain texture's level 0 (`n`² RGB, top row first) as `terrain.png` in `dir`.
fn terrain_png(dir: &Path, n: u64) -> anyhow::Result<PathBuf> {
    let tile = 256u64;
    let desc = TextureDesc::new([n, n], (n / 2).min(1024), TexelFormat::RGB8, [tile, tile])?;
    let src = Procedural::Terrain.source(desc);
    let (row, tiles) = (3 * n as usize, n / tile);
    let mut img = vec![0u8; row * n as usize];
    let mut buf = vec![0u8; 3 * (tile * tile) as usize];
    let tr = 3 * tile as usize;
    for t in 0..tiles {
        for s in 0..tiles {
            src.read_tile(TileId { level: 0, s, t }, &mut buf)?;
            for r in 0..tile as usize {
                // Our row t*tile + r counts from the bottom; the file's rows from the top.
                let y = n as usize - 1 - (t as usize * tile as usize + r);
                let x = s as usize * tr;
                img[y * row + x..y * row + x + tr].copy_from_slice(&buf[r * tr..(r + 1) * tr]);
            }
        }
    }
    let png = dir.join("terrain.png");
    image::RgbImage::from_raw(n as u32, n as u32, img)
        .ok_or_else(|| anyhow::anyhow!("the image buffer does not match its size"))?
        .save(&png)?;
    Ok(png)
}

/// Our passes over one kind.
struct Ours {
    seconds: Vec<f64>,
    opens: Vec<f64>,
    wrong: u64,
    failed: u64,
    first_error: Option<String>,
    /// nginx's log of the first open, the first pass's reads, and the warm pass's reads.
    open_hits: Vec<Hit>,
    pass_hits: Vec<Hit>,
    warm_hits: Vec<Hit>,
    spent: Spent,
    /// Our process's CPU and nginx's over the timed passes, seconds.
    cpu_s: f64,
    nginx_s: f64,
}

/// One pass of ours: every tile of `ids` on `depth` threads, each checked against `reference`
/// (inside the timed pass: a memory compare, the same in every kind); (seconds, wrong, failed,
/// the first failure).
fn one_pass(src: &PyramidSource, ids: &[TileId], depth: u64, reference: &Reference) -> (f64, u64, u64, Option<String>) {
    let bytes = src.desc().tile_bytes(0);
    let next = AtomicU64::new(0);
    let (wrong, failed) = (AtomicU64::new(0), AtomicU64::new(0));
    let first_error = std::sync::Mutex::new(None);
    let t = Instant::now();
    std::thread::scope(|scope| {
        for _ in 0..depth {
            scope.spawn(|| {
                let mut buf = vec![0u8; bytes];
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed) as usize;
                    let Some(&id) = ids.get(i) else { return };
                    match src.read_tile(id, &mut buf) {
                        Ok(()) => {
                            wrong.fetch_add(reference.wrong(id, &buf), Ordering::Relaxed);
                        }
                        Err(e) => {
                            failed.fetch_add(1, Ordering::Relaxed);
                            let mut f = first_error.lock().unwrap_or_else(|e| e.into_inner());
                            f.get_or_insert_with(|| format!("level-0 tile ({}, {}): {e}", id.s, id.t));
                        }
                    }
                }
            });
        }
    });
    let seconds = t.elapsed().as_secs_f64();
    (seconds, wrong.into_inner(), failed.into_inner(), first_error.into_inner().unwrap_or_else(|e| e.into_inner()))
}

/// `passes` passes, each on a fresh `open()`, then a warm pass on the last source; requests
/// from `log` when the kind is served over HTTP.
fn our_passes(
    open: &dyn Fn() -> anyhow::Result<PyramidSource>,
    ids: &[TileId],
    depth: u64,
    passes: u64,
    reference: &Reference,
    log: Option<&AccessLog>,
    nginx: Option<u32>,
) -> anyhow::Result<Ours> {
    let nginx_s = || nginx.map_or(0.0, tiles_cpu::pid_s);
    let hits = || -> anyhow::Result<Vec<Hit>> { log.map_or(Ok(Vec::new()), |l| l.settled()) };
    let mut o = Ours {
        seconds: Vec::new(),
        opens: Vec::new(),
        wrong: 0,
        failed: 0,
        first_error: None,
        open_hits: Vec::new(),
        pass_hits: Vec::new(),
        warm_hits: Vec::new(),
        spent: Spent { busy_s: 0.0, wall_s: 0.0, tiles: 0 },
        cpu_s: 0.0,
        nginx_s: 0.0,
    };
    let mut last = None;
    let cpu = MachineCpu::now();
    for pass in 0..passes {
        let before = hits()?.len();
        let t0 = Instant::now();
        let src = open()?;
        o.opens.push(t0.elapsed().as_secs_f64());
        let opened = hits()?;
        let (c0, n0) = (tiles_cpu::process_s(), nginx_s());
        let (s, w, f, e) = one_pass(&src, ids, depth, reference);
        o.cpu_s += tiles_cpu::process_s() - c0;
        o.nginx_s += nginx_s() - n0;
        o.seconds.push(s);
        o.wrong += w;
        o.failed += f;
        o.first_error = o.first_error.take().or(e);
        if pass == 0 {
            o.open_hits = opened[before..].to_vec();
            o.pass_hits = hits()?[opened.len()..].to_vec();
        }
        last = Some(src);
    }
    o.spent = Spent::since(cpu, &o.seconds, passes * ids.len() as u64);
    if let Some(src) = last {
        let before = hits()?.len();
        let (_, w, f, e) = one_pass(&src, ids, depth, reference);
        o.wrong += w;
        o.failed += f;
        o.first_error = o.first_error.take().or(e);
        o.warm_hits = hits()?[before..].to_vec();
    }
    if let Some(e) = &o.first_error {
        anyhow::bail!("{} reads failed; the first: {e}", o.failed);
    }
    Ok(o)
}

/// Decodes `b` (a 256² RGBA PNG) with the `image` crate into `out`, rows from the south: the
/// pyramid's decode before `zune-png`.
fn decode_image(b: &[u8], out: &mut Vec<u8>) -> bool {
    let Ok(img) = image::load_from_memory_with_format(b, image::ImageFormat::Png) else { return false };
    let raw = img.into_rgba8();
    let row = raw.width() as usize * BPT;
    out.resize(raw.len(), 0);
    for (r, src) in raw.chunks_exact(row).rev().enumerate() {
        out[r * row..(r + 1) * row].copy_from_slice(src);
    }
    true
}

/// Decodes `b` with `zune-png` straight into `out` (`side`² RGBA), then turns its rows over in
/// place, CRC and Adler-32 checked: the pyramid's decode of a plain PNG tile.
fn decode_zune(b: &[u8], side: usize, out: &mut Vec<u8>) -> bool {
    use zune_png::zune_core::{bytestream::ZCursor, options::DecoderOptions};
    let o = DecoderOptions::default()
        .png_set_confirm_crc(true)
        .inflate_set_confirm_adler(true)
        .png_set_add_alpha_channel(true);
    out.resize(side * side * BPT, 0);
    if zune_png::PngDecoder::new_with_options(ZCursor::new(b), o).decode_into(out).is_err() {
        return false;
    }
    let row = side * BPT;
    for r in 0..side / 2 {
        let (top, bottom) = out.split_at_mut((side - 1 - r) * row);
        top[r * row..(r + 1) * row].swap_with_slice(&mut bottom[..row]);
    }
    true
}

/// Decodes every tile of `files` (PNG bytes) into RGBA rows from the south, `depth` threads,
/// `passes` times, with `zune-png` (timed: the rate of the decode alone, median pass) and then
/// with the `image` crate; each decoder's thread CPU a tile, microseconds: (rate, image, zune).
fn decode_only(files: &[Vec<u8>], side: usize, depth: u64, passes: u64) -> anyhow::Result<(f64, f64, f64)> {
    let mut times = Vec::new();
    let (mut image_s, mut zune_s) = (0.0, 0.0);
    for zune in [true, false] {
        for _ in 0..passes {
            let next = AtomicU64::new(0);
            let bad = AtomicU64::new(0);
            let cpu_ns = AtomicU64::new(0);
            let t = Instant::now();
            std::thread::scope(|scope| {
                for _ in 0..depth {
                    scope.spawn(|| {
                        let mut out = Vec::new();
                        let c0 = tiles_cpu::thread_s();
                        loop {
                            let i = next.fetch_add(1, Ordering::Relaxed) as usize;
                            let Some(b) = files.get(i) else { break };
                            let ok = if zune { decode_zune(b, side, &mut out) } else { decode_image(b, &mut out) };
                            if !ok {
                                bad.fetch_add(1, Ordering::Relaxed);
                            }
                        }
                        cpu_ns.fetch_add(((tiles_cpu::thread_s() - c0) * 1e9) as u64, Ordering::Relaxed);
                    });
                }
            });
            if zune {
                times.push(t.elapsed().as_secs_f64());
            }
            let cpu = cpu_ns.into_inner() as f64 * 1e-9;
            *(if zune { &mut zune_s } else { &mut image_s }) += cpu;
            anyhow::ensure!(bad.load(Ordering::Relaxed) == 0, "a level-0 tile file does not decode as PNG");
        }
    }
    let per_tile = |s: f64| s * 1e6 / (passes as f64 * files.len() as f64);
    Ok((files.len() as f64 / median(times), per_tile(image_s), per_tile(zune_s)))
}

/// Our process's CPU a tile, microseconds, of a pass that only fetches each tile of `ids`
/// through `src`'s archive (on a fresh open), `depth` threads.
fn fetch_only_us(src: &PyramidSource, ids: &[TileId], depth: u64) -> anyhow::Result<f64> {
    let max_zoom = src.archive().info().max_zoom;
    let side = 1u32 << max_zoom;
    let failed = AtomicU64::new(0);
    let cpu = tiles_cpu::pass_cpu(ids, depth, &|id, _| {
        let at = TileAddr { z: max_zoom, x: id.s as u32, y: side - 1 - id.t as u32 };
        if !matches!(src.archive().fetch(at), Ok(tiles::Fetched::Tile(_))) {
            failed.fetch_add(1, Ordering::Relaxed);
        }
    });
    anyhow::ensure!(failed.into_inner() == 0, "{}: a fetch-only pass missed tiles", src.archive().place());
    Ok(cpu * 1e6 / ids.len() as f64)
}

/// What a kind measured, before it is put into a [`Kind`].
struct Measured<'a> {
    source: String,
    ours: Ours,
    tiles: u64,
    gdal: Option<(Gdal, &'static str)>,
    curl: Option<(Vec<f64>, Spent)>,
    log: Option<&'a AccessLog>,
    decode_rate: f64,
    /// Our fetch-only pass, CPU microseconds a tile.
    fetch_us: f64,
    /// curl's and nginx's CPU microseconds a tile under curl (HTTP kinds).
    curl_cpu: Option<(f64, f64)>,
    /// The memory pass, CPU microseconds a tile.
    memory_us: f64,
}

fn kind(m: Measured, reference: &Reference) -> Kind {
    let rate = |s: &[f64]| m.tiles as f64 / median(s.to_vec()).max(1e-9);
    let ours = rate(&m.ours.seconds);
    let http = m.log.is_some();
    let gdal_rate = m.gdal.as_ref().map(|(g, _)| rate(&g.seconds));
    let curl_rate = m.curl.as_ref().map(|(s, _)| rate(s));
    let per_tile = |hits: &[Hit]| hits.len() as f64 / m.tiles as f64;
    let timed_tiles = (m.tiles * m.ours.seconds.len() as u64).max(1) as f64;
    let ours_us = m.ours.cpu_s * 1e6 / timed_tiles;
    let nginx_us = m.ours.nginx_s * 1e6 / timed_tiles;
    Kind {
        source: m.source,
        tiles: m.tiles,
        tiles_per_s: ours,
        tiles_per_s_gdal: gdal_rate,
        vs_gdal: gdal_rate.map(|g| ours / g),
        gdal_driver: m.gdal.as_ref().map(|(_, d)| *d),
        tiles_per_s_gdal_one_process: m.gdal.as_ref().map(|(g, _)| rate(&g.one_process_seconds)),
        curl_ceiling_tiles_per_s: curl_rate,
        vs_curl: curl_rate.map(|c| ours / c),
        requests: http.then(|| (m.ours.open_hits.len() + m.ours.pass_hits.len()) as u64),
        requests_per_tile_cold: http.then(|| per_tile(&m.ours.pass_hits)),
        requests_per_tile_warm: http.then(|| per_tile(&m.ours.warm_hits)),
        requests_gdal: m.gdal.as_ref().and_then(|(g, _)| g.requests),
        open_requests: http.then_some(m.ours.open_hits.len() as u64),
        open_bytes: http.then(|| m.ours.open_hits.iter().map(|h| h.bytes).sum()),
        open_s: median(m.ours.opens.clone()),
        wrong_texels: m.ours.wrong,
        gdal_wrong_texels: m.gdal.as_ref().map(|(g, _)| reference.wrong_dump(&g.dump)),
        failed_reads: m.ours.failed,
        decode_share: ours / m.decode_rate.max(1e-9),
        cores_busy: m.ours.spent.cores(),
        core_us_per_tile: m.ours.spent.core_us_per_tile(),
        core_us_per_tile_curl: m.curl.as_ref().map(|(_, s)| s.core_us_per_tile()),
        cpu_us_per_tile: ours_us,
        cpu_us_per_tile_fetch: m.fetch_us,
        cpu_us_per_tile_curl: m.curl_cpu.map(|(c, _)| c),
        nginx_cpu_us_per_tile: http.then_some(nginx_us),
        nginx_cpu_us_per_tile_curl: m.curl_cpu.map(|(_, n)| n),
        vs_curl_by_cpu: m.curl_cpu.map(|(c, n)| (c + n) / (ours_us + nginx_us).max(1e-9)),
        vs_curl_bound_by_decode: m.curl_cpu.map(|(c, n)| (c + n) / (m.memory_us + c + n).max(1e-9)),
    }
}

fn measure(args: &Args, dir: &Path) -> anyhow::Result<Report> {
    let gdal = super::perf::find_gdal(false).map_err(|e| anyhow::anyhow!("GDAL is needed: {e}"))?;
    let curl =
        super::serve::program(&["curl"]).ok_or_else(|| anyhow::anyhow!("curl is needed (apt-get install curl)"))?;
    let (max_zoom, passes) = if args.quick { (3u8, args.passes.min(2)) } else { (5u8, args.passes) };
    let tile = 256u64;
    let n = tile << max_zoom;
    let depth = args.depth;

    // The data: the image, GDAL's tree, the archives, GDAL's decode of every level-0 tile.
    terrain_png(dir, n)?;
    let made = tiles_peers::make_pyramid(&gdal.python, dir, max_zoom)?;
    let side = 1u64 << max_zoom;
    let reference = Reference { gdal: std::fs::read(dir.join("reference.raw"))?, tiles: side, tile };
    anyhow::ensure!(
        reference.gdal.len() == reference.tile_bytes() * (side * side) as usize,
        "GDAL's decode of the level-0 tiles is {} bytes",
        reference.gdal.len()
    );
    let ids: Vec<TileId> = (0..side * side).map(|i| TileId { level: 0, s: i % side, t: i / side }).collect();
    let mut files = Vec::new();
    for id in &ids {
        files.push(std::fs::read(dir.join(format!("xyz/{max_zoom}/{}/{}.png", id.s, side - 1 - id.t)))?);
    }
    let tiles_total: u64 = (0..=max_zoom).map(|z| 1u64 << (2 * z)).sum();
    let data = Data {
        image: "the procedural terrain texture (smooth fractal noise coloured like land and sea), one RGB image over the whole Web Mercator square",
        tiler: format!("gdal2tiles.py --xyz (GDAL {}), PNG with alpha", made.version),
        size: n,
        tile,
        max_zoom,
        encoding: "png",
        tiles: tiles_total,
        level0_tiles: ids.len() as u64,
        level0_tile_bytes_mean: files.iter().map(|f| f.len() as f64).sum::<f64>() / files.len() as f64,
        pmtiles_bytes: std::fs::metadata(dir.join("tiles.pmtiles"))?.len(),
        mbtiles_bytes: std::fs::metadata(dir.join("tiles.mbtiles"))?.len(),
    };
    let (decode_rate, decode_image_us, decode_zune_us) = decode_only(&files, tile as usize, depth, passes)?;
    // A pyramid source over the same tiles in memory: its checks, decode and copies alone. It
    // holds only the finest zoom's tiles, the only ones a pass reads; it says it has every zoom,
    // so that no coarser level is built from the finest (at full size, 8192² texels, more than a
    // source builds coarser levels from).
    let memory = MemoryArchive {
        info: tiles::PyramidInfo {
            min_zoom: 0,
            max_zoom,
            tile_size: tile as u32,
            bounds: None,
            encoding: Some(tiles::TileEncoding::Png),
        },
        tiles: ids
            .iter()
            .zip(&files)
            .map(|(id, f)| ((max_zoom, id.s as u32, (side - 1 - id.t) as u32), f.clone()))
            .collect(),
    };
    drop(files);
    let memory_src = PyramidSource::new(
        std::sync::Arc::new(memory),
        &PyramidOptions { clip_size: Some(1024.min(n / 2)), ..Default::default() },
    )
    .map_err(|e| anyhow::anyhow!("a pyramid over the tiles in memory: {e}"))?;
    let mut memory_us = Vec::new();
    for _ in 0..passes {
        let wrong = AtomicU64::new(0);
        let cpu = tiles_cpu::pass_cpu(&ids, depth, &|id, buf| {
            buf.resize(memory_src.desc().tile_bytes(0), 0);
            match memory_src.read_tile(id, buf) {
                Ok(()) => wrong.fetch_add(reference.wrong(id, buf), Ordering::Relaxed),
                Err(_) => wrong.fetch_add(1, Ordering::Relaxed),
            };
        });
        anyhow::ensure!(wrong.into_inner() == 0, "the pyramid over the tiles in memory read wrong texels");
        memory_us.push(cpu * 1e6 / ids.len() as f64);
    }
    let memory_us = median(memory_us);
    let cpu = Cpu {
        us_per_tile_decode_image: decode_image_us,
        us_per_tile_decode_zune: decode_zune_us,
        us_per_tile_memory_pass: memory_us,
    };

    let log = AccessLog(dir.join("access.log"));
    let nginx = Nginx::serve(dir, &dir.join("nginx"), Some(&log.0), args.link_rate.map(|m| m * 1_000_000))?;
    let base = format!("http://127.0.0.1:{}", nginx.port);
    let clip = 1024.min(n / 2);
    let remote = RemoteOptions { cache_dir: None, in_flight: (depth as usize).max(16), ..RemoteOptions::default() };
    let opts = |zooms: Option<[u8; 2]>| OpenOptions {
        template: TemplateOptions {
            zooms,
            tile_size: Some(tile as u32),
            remote: Some(remote.clone()),
            ..Default::default()
        },
        pyramid: PyramidOptions { clip_size: Some(clip), ..Default::default() },
    };
    let open = |text: &str, o: &OpenOptions| -> anyhow::Result<PyramidSource> {
        tiles::open(text, o)
            .ok_or_else(|| anyhow::anyhow!("{text}: not a tile pyramid"))?
            .map_err(|e| anyhow::anyhow!("opening {text}: {e}"))
    };
    let gdal_run = |name: &str, driver: &'static str, http: bool| -> anyhow::Result<(Gdal, &'static str)> {
        let g = tiles_peers::gdal_reads(&gdal.python, dir, name, tile, depth, passes, http.then_some(&log))?;
        anyhow::ensure!(
            g.tiles == ids.len() as u64,
            "GDAL's {driver} driver read {} tiles a pass of {name}, where level 0 has {}",
            g.tiles,
            ids.len()
        );
        Ok((g, driver))
    };
    let nginx_pid = nginx.pid();
    // curl's passes, and curl's and nginx's CPU microseconds a tile over them.
    // (curl's passes, and (curl's, nginx's) CPU microseconds a tile)
    type CurlRun = ((Vec<f64>, Spent), (f64, f64));
    let curl_run = |transfers: &[Transfer]| -> anyhow::Result<CurlRun> {
        let (c0, n0) = (tiles_cpu::children_s(), tiles_cpu::pid_s(nginx_pid));
        let r = tiles_peers::curl_passes(&curl, dir, transfers, depth, passes, ids.len() as u64)?;
        let per = 1e6 / (passes * ids.len() as u64) as f64;
        let cpu = ((tiles_cpu::children_s() - c0) * per, (tiles_cpu::pid_s(nginx_pid) - n0) * per);
        Ok((r, cpu))
    };
    let fetch_us = |text: &str, o: &OpenOptions| -> anyhow::Result<f64> { fetch_only_us(&open(text, o)?, &ids, depth) };

    // XYZ over nginx.
    let xyz_text = format!("xyz:{base}/xyz/{{z}}/{{x}}/{{y}}.png");
    let xyz_opts = opts(Some([0, max_zoom]));
    let ours = our_passes(&|| open(&xyz_text, &xyz_opts), &ids, depth, passes, &reference, Some(&log), Some(nginx_pid))
        .map_err(|e| anyhow::anyhow!("{xyz_text}: {e}"))?;
    let xyz_fetch = fetch_us(&xyz_text, &xyz_opts)?;
    let urls: Vec<Transfer> = ids
        .iter()
        .map(|id| Transfer { url: format!("{base}/xyz/{max_zoom}/{}/{}.png", id.s, side - 1 - id.t), range: None })
        .collect();
    let (curl_xyz, curl_xyz_cpu) = curl_run(&urls)?;
    let wms = tiles_peers::wms_xml(&base, max_zoom, tile);
    let g = gdal_run(&wms, "WMS (TMS mini-driver)", true)?;
    let version = g.0.version.clone();
    let xyz = kind(
        Measured {
            source: xyz_text.clone(),
            ours,
            tiles: ids.len() as u64,
            gdal: Some(g),
            curl: Some(curl_xyz),
            log: Some(&log),
            decode_rate,
            fetch_us: xyz_fetch,
            curl_cpu: Some(curl_xyz_cpu),
            memory_us,
        },
        &reference,
    );

    // PMTiles over nginx: curl makes the requests of our first pass (the open aside, as our
    // timed passes leave it aside).
    let pm_url = format!("{base}/tiles.pmtiles");
    let pm_opts = opts(None);
    let ours = our_passes(&|| open(&pm_url, &pm_opts), &ids, depth, passes, &reference, Some(&log), Some(nginx_pid))
        .map_err(|e| anyhow::anyhow!("{pm_url}: {e}"))?;
    let mut ranges = Vec::new();
    for h in &ours.pass_hits {
        match (h.status, h.range) {
            (206, Some(r)) => ranges.push(Transfer { url: pm_url.clone(), range: Some(r) }),
            _ => anyhow::bail!("{pm_url}: our reads made a request nginx answered {} ({h:?}); expected 206", h.status),
        }
    }
    let (curl_pm, curl_pm_cpu) = curl_run(&ranges)?;
    let pm_fetch = fetch_us(&pm_url, &pm_opts)?;
    let pmtiles_http = kind(
        Measured {
            source: pm_url.clone(),
            ours,
            tiles: ids.len() as u64,
            gdal: None,
            curl: Some(curl_pm),
            log: Some(&log),
            decode_rate,
            fetch_us: pm_fetch,
            curl_cpu: Some(curl_pm_cpu),
            memory_us,
        },
        &reference,
    );

    // The sparse planet's open against the small archive's, over the same nginx.
    let sparse_planet_open =
        tiles_planet::planet_open(&gdal.python, dir, &base, &pm_url, &log, if args.quick { 20 } else { 50 }, &|url| {
            open(url, &pm_opts).map(drop)
        })?;

    // PMTiles from disk.
    let pm_path = dir.join("tiles.pmtiles").to_string_lossy().into_owned();
    let ours = our_passes(&|| open(&pm_path, &pm_opts), &ids, depth, passes, &reference, None, None)
        .map_err(|e| anyhow::anyhow!("{pm_path}: {e}"))?;
    let fetch_us_local = fetch_us(&pm_path, &pm_opts)?;
    let pmtiles_local = kind(
        Measured {
            source: pm_path,
            ours,
            tiles: ids.len() as u64,
            gdal: None,
            curl: None,
            log: None,
            decode_rate,
            fetch_us: fetch_us_local,
            curl_cpu: None,
            memory_us,
        },
        &reference,
    );

    // MBTiles.
    let mb_path = dir.join("tiles.mbtiles").to_string_lossy().into_owned();
    let ours = our_passes(&|| open(&mb_path, &opts(None)), &ids, depth, passes, &reference, None, None)
        .map_err(|e| anyhow::anyhow!("{mb_path}: {e}"))?;
    let fetch_us_mb = fetch_us(&mb_path, &opts(None))?;
    let g = gdal_run(&mb_path, "MBTiles", false)?;
    let mbtiles = kind(
        Measured {
            source: mb_path,
            ours,
            tiles: ids.len() as u64,
            gdal: Some(g),
            curl: None,
            log: None,
            decode_rate,
            fetch_us: fetch_us_mb,
            curl_cpu: None,
            memory_us,
        },
        &reference,
    );

    // The flight over the XYZ service, through a relay holding every request.
    let flight = tiles_flight::flights(&tiles_flight::FlightRun {
        nginx_port: nginx.port,
        max_zoom,
        clip: if args.quick { 512 } else { clip },
        latency_ms: args.latency_ms,
        speed: args.flight_speed,
        quick: args.quick,
        reference: &reference,
    })?;
    drop(nginx);

    let kinds = Kinds { xyz, pmtiles_http, pmtiles_local, mbtiles };
    let all = [&kinds.xyz, &kinds.pmtiles_http, &kinds.pmtiles_local, &kinds.mbtiles];
    let goals = Goals {
        twice_gdal: all.iter().all(|k| k.vs_gdal.is_none_or(|r| r >= 2.0)),
        curl_share: all.iter().all(|k| k.vs_curl.is_none_or(|r| r >= 0.8)),
        one_request_warm: all.iter().all(|k| k.requests_per_tile_warm.is_none_or(|r| r <= 1.0)),
        no_wrong_texels: all.iter().all(|k| k.wrong_texels == 0) && flight.wrong_texels == 0,
        flight: flight.level0_shown_share >= 0.95,
    };
    Ok(Report {
        kinds,
        flight,
        tiles_per_s_decode_only: decode_rate,
        cpu,
        sparse_planet_open,
        state: STATE,
        data,
        gdal_version: version,
        link_rate_mb_per_s: args.link_rate,
        depth,
        passes,
        nproc: std::thread::available_parallelism().map_or(1, |n| n.get()),
        goals,
    })
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |x| format!("{x:.digits$}"))
}

fn human(r: &Report) -> String {
    let d = &r.data;
    let mut o = format!(
        "{} tiles of zooms 0..{} ({}² texels at zoom {}), {} a pass at level 0, {:.0} bytes a tile on average; {}; GDAL {}\n\
         {} reads in flight each side{}; {}\n\
         decode alone: {:.0} tiles/s\n\
         {:<14} {:>9} {:>9} {:>6} {:>9} {:>6} {:>9} {:>9} {:>10} {:>7}\n",
        d.tiles,
        d.max_zoom,
        d.size,
        d.max_zoom,
        d.level0_tiles,
        d.level0_tile_bytes_mean,
        d.tiler,
        r.gdal_version,
        r.depth,
        r.link_rate_mb_per_s.map_or(String::new(), |m| format!(", {m} MB/s a connection")),
        r.state,
        r.tiles_per_s_decode_only,
        "kind",
        "tiles/s",
        "GDAL",
        "x",
        "curl",
        "share",
        "req cold",
        "req warm",
        "open req/B",
        "wrong"
    );
    for (name, k) in [
        ("xyz", &r.kinds.xyz),
        ("pmtiles_http", &r.kinds.pmtiles_http),
        ("pmtiles_local", &r.kinds.pmtiles_local),
        ("mbtiles", &r.kinds.mbtiles),
    ] {
        o.push_str(&format!(
            "{:<14} {:>9.0} {:>9} {:>6} {:>9} {:>6} {:>9} {:>9} {:>10} {:>7}\n",
            name,
            k.tiles_per_s,
            opt(k.tiles_per_s_gdal, 0),
            opt(k.vs_gdal, 2),
            opt(k.curl_ceiling_tiles_per_s, 0),
            opt(k.vs_curl, 2),
            opt(k.requests_per_tile_cold, 2),
            opt(k.requests_per_tile_warm, 2),
            match (k.open_requests, k.open_bytes) {
                (Some(a), Some(b)) => format!("{a}/{b}"),
                _ => "-".into(),
            },
            k.wrong_texels
        ));
    }
    o.push_str(&format!(
        "CPU a tile, microseconds: decode alone {:.0} (image) / {:.0} (zune-png); checks, decode and copies from memory {:.0}\n",
        r.cpu.us_per_tile_decode_image, r.cpu.us_per_tile_decode_zune, r.cpu.us_per_tile_memory_pass
    ));
    for (name, k) in [("xyz", &r.kinds.xyz), ("pmtiles_http", &r.kinds.pmtiles_http)] {
        o.push_str(&format!(
            "  {name}: ours {:.0} (fetch alone {:.0}), nginx {}; curl {}, nginx {}; ours/curl by CPU {}, at most {} while the decode costs what it does\n",
            k.cpu_us_per_tile,
            k.cpu_us_per_tile_fetch,
            opt(k.nginx_cpu_us_per_tile, 0),
            opt(k.cpu_us_per_tile_curl, 0),
            opt(k.nginx_cpu_us_per_tile_curl, 0),
            opt(k.vs_curl_by_cpu, 2),
            opt(k.vs_curl_bound_by_decode, 2)
        ));
    }
    let p = &r.sparse_planet_open;
    o.push_str(&format!(
        "sparse planet ({} tiles addressed at zooms 0..18, {} bytes) opens over HTTP in {:.2} ms ({} request, {} bytes), the small archive ({} bytes) in {:.2} ms: {:.2}x (median of {})\n",
        p.addressed_tiles, p.planet_bytes, p.open_s * 1e3, p.open_requests, p.open_bytes, p.small_bytes, p.small_open_s * 1e3, p.vs_small, p.opens
    ));
    o.push_str(&tiles_flight::human(&r.flight));
    o
}

/// Runs the benchmark; the exit status (0 ok, 1 wrong texels were read, 2 could not run).
pub fn main(args: Args) -> u8 {
    super::run_in_scratch(
        "tiles",
        args.dir.as_deref(),
        args.json,
        |dir| measure(&args, dir),
        human,
        |r| !r.goals.no_wrong_texels,
    )
}
