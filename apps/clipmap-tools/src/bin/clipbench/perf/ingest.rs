//! Tile ingest: tiles per second through the engine's tile path against plain reads.
//!
//! The engine side is a clipmap over the prepared pyramid's [`FileSource`] (the read queues, the
//! file source reading each tile straight into its slot of the image caches, and the tick's
//! bookkeeping; no tick budget), jumping its centre across a grid of positions far enough apart that every jump
//! needs a new mem region at level 0; each jump is one tick plus waiting for its reads. A thin
//! wrapper records which tiles were read, in order. The baseline reads exactly those tiles' files,
//! in the same order, with `std::fs::read`. Both read the page cache (every file is read once
//! before timing); when `/proc/sys/vm/drop_caches` can be written, one cold pair is measured
//! too.
//!
//! A third side explains the first two: the same reads again, one after the other, but each into
//! its own place in a buffer as large as the engine's image caches (`pread` at the tile's place,
//! as the engine's slots are), so that every tile lands in memory that is not in the CPU caches,
//! as a tile that is kept must. `std::fs::read` instead reuses one freed buffer that stays in the
//! CPU's caches (a read that keeps nothing); the gap between the two baselines is what writing
//! the tiles where they stay costs in memory traffic, before any engine overhead.

use super::data::{shape, Prepared};
use super::{proc_self, Size, Stat};
use anyhow::Context;
use clipmap::clip::{Clipmap, Settings};
use clipmap::limits::Limits;
use clipmap::plan;
use clipmap::source::{FileSource, SourceError, TextureDesc, TileId, TileSource};
use serde::Serialize;
use std::os::unix::fs::FileExt;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// A file source that records the tiles read.
struct Recording {
    inner: Arc<FileSource>,
    log: Mutex<Vec<TileId>>,
}

impl TileSource for Recording {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.inner.read_tile(tile, out)?;
        self.log.lock().unwrap_or_else(|e| e.into_inner()).push(tile);
        Ok(())
    }

    fn stream_servers(&self) -> usize {
        self.inner.stream_servers()
    }

    fn stream_of(&self, tile: TileId, streams: usize) -> usize {
        self.inner.stream_of(tile, streams)
    }
}

/// One cold (caches dropped) pair.
#[derive(Clone, Debug, Serialize)]
pub struct Cold {
    pub engine_tiles_per_s: f64,
    pub read_tiles_per_s: f64,
    pub ratio: f64,
}

/// What the ingest comparison measured.
#[derive(Clone, Debug, Serialize)]
pub struct Ingest {
    pub texture: u64,
    pub clip: u64,
    pub tile: u64,
    /// Bytes of one image-cache tile.
    pub tile_bytes: u64,
    pub jumps_per_run: usize,
    /// Tiles read per engine run (the baseline reads the same files).
    pub tiles_per_run: usize,
    pub bytes_per_run: u64,
    pub engine_tiles_per_s: Stat,
    pub read_tiles_per_s: Stat,
    /// Per run: engine / plain reads.
    pub ratio: Stat,
    /// The same files read one after the other, each into its own place of a buffer of
    /// `in_place_buffer_bytes` (the engine's image caches' size), tiles per second.
    pub read_in_place_tiles_per_s: Stat,
    /// Per run: reads into their places / plain reads: the cost of writing tiles into memory
    /// that is not in the CPU's caches, without any engine.
    pub in_place_vs_read: Stat,
    /// Per run: engine / reads into their places.
    pub engine_vs_in_place: Stat,
    pub in_place_buffer_bytes: u64,
    /// The reads into their places shared out among `parallel_threads` threads reading at once
    /// (one a core), tiles per second, and that over plain reads: how far more reading threads
    /// can go on this machine before any engine cost.
    pub parallel_threads: usize,
    pub read_parallel_tiles_per_s: Stat,
    pub parallel_vs_read: Stat,
    /// Minor page faults and CPU time (all threads) per tile, each side (the engine's during its
    /// flight, not while its image caches are made and populated).
    pub engine_faults_per_tile: Stat,
    pub read_faults_per_tile: Stat,
    pub engine_cpu_us_per_tile: Stat,
    pub read_cpu_us_per_tile: Stat,
    /// Context switches per tile (all threads), each side: what thread hand-offs cost.
    pub engine_switches_per_tile: Stat,
    pub read_switches_per_tile: Stat,
    /// Share of the engine's flight spent in its ticks (the rest waits for reads).
    pub engine_tick_share: Stat,
    /// Whether the page cache could be dropped (`/proc/sys/vm/drop_caches` writable).
    pub drop_caches: bool,
    pub cold: Option<Cold>,
}

fn open(prepared: &Prepared) -> anyhow::Result<Arc<FileSource>> {
    let loaded = plan::load_clip_texture(&prepared.ct, &plan::Options::default())?;
    let rendered = loaded.render();
    let plan = loaded.plan.with_context(|| format!("{}: {rendered}", prepared.ct.display()))?;
    Ok(Arc::new(FileSource::new(plan, &Limits::default())?))
}

/// Centres of level 0 two clip sizes apart, so that consecutive jumps share no level-0 tile.
fn jumps(n: u64, clip: u64) -> Vec<[i64; 2]> {
    let step = (2 * clip) as i64;
    let first = (clip / 2) as i64;
    let along: Vec<i64> = (0..).map(|i| first + i * step).take_while(|&c| c < n as i64).collect();
    let mut out = Vec::new();
    for (row, &t) in along.iter().enumerate() {
        // Boustrophedon, so a jump's coarser levels stay near the last one's.
        let mut cols = along.clone();
        if row % 2 == 1 {
            cols.reverse();
        }
        out.extend(cols.into_iter().map(|s| [s, t]));
    }
    out
}

/// What one engine run measured.
struct EngineRun {
    /// Seconds of the flight (ticks and waits; the clipmap is made before and dropped after).
    secs: f64,
    /// The tiles read, in order.
    log: Vec<TileId>,
    /// Bytes of the clipmap's image caches.
    memory_bytes: u64,
    /// Minor page faults and CPU seconds (all threads) during the flight alone: making the
    /// clipmap populates its image caches (a fault a page), which is not tile ingest.
    faults: u64,
    cpu_s: f64,
    /// Context switches of the threads alive at the flight's end (the reading threads included).
    switches: u64,
    /// Seconds of the flight spent in ticks (the rest is waiting for reads).
    tick_s: f64,
}

/// One engine run.
fn engine_run(source: &Arc<FileSource>, centres: &[[i64; 2]]) -> anyhow::Result<EngineRun> {
    let rec = Arc::new(Recording { inner: Arc::clone(source), log: Mutex::new(Vec::new()) });
    // No tick budget: every finished read is taken at the next tick (nothing is copied in layout
    // 2, so the tick's work is the tile path's own bookkeeping).
    let mut settings = Settings { budget_ns: None, ..Settings::default() };
    settings.limits.max_pending_reads = 4096;
    settings.limits.max_ready_reads = 4096;
    let mut map = Clipmap::new(Arc::clone(&rec) as Arc<dyn TileSource>, settings)?;
    let p0 = proc_self();
    let t = Instant::now();
    let mut tick_s = 0.0;
    for &c in centres {
        let at = Instant::now();
        map.tick(c, Some([0, 0]));
        tick_s += at.elapsed().as_secs_f64();
        map.wait_for_reads();
    }
    // Takes the last reads into the cache.
    map.tick(*centres.last().expect("at least one jump"), Some([0, 0]));
    let secs = t.elapsed().as_secs_f64();
    let p1 = proc_self();

    let memory_bytes = map.memory().total_bytes();
    drop(map);
    let log = std::mem::take(&mut *rec.log.lock().unwrap_or_else(|e| e.into_inner()));
    Ok(EngineRun {
        secs,
        log,
        memory_bytes,
        faults: p1.minor_faults - p0.minor_faults,
        cpu_s: p1.cpu_s - p0.cpu_s,
        switches: p1.switches.saturating_sub(p0.switches),
        tick_s,
    })
}

/// Reads `paths` one after the other, tile `i` at byte `(i * tile_bytes) mod` the buffer's
/// length (rounded down to whole places of `tile_bytes`, at least each file's length) of
/// `buffer`, which is touched beforehand.
fn read_in_place_run(paths: &[PathBuf], tile_bytes: usize, buffer: &mut [u8]) -> anyhow::Result<f64> {
    let places = (buffer.len() / tile_bytes).max(1);
    anyhow::ensure!(buffer.len() >= tile_bytes, "the in-place buffer holds less than one tile");
    let t = Instant::now();
    for (i, p) in paths.iter().enumerate() {
        let at = (i % places) * tile_bytes;
        let file = std::fs::File::open(p).with_context(|| format!("opening {}", p.display()))?;
        let len = file.metadata().with_context(|| format!("reading {}", p.display()))?.len() as usize;
        anyhow::ensure!(len <= tile_bytes, "{} holds {len} bytes, more than one tile ({tile_bytes})", p.display());
        file.read_exact_at(&mut buffer[at..at + len], 0).with_context(|| format!("reading {}", p.display()))?;
    }
    std::hint::black_box(&*buffer);
    Ok(t.elapsed().as_secs_f64())
}

/// [`read_in_place_run`] shared out among `threads` threads reading at once, each its own
/// contiguous share of `paths` into its own share of `buffer`: what the machine's copies allow
/// when every core reads, without any engine.
fn read_in_place_parallel_run(
    paths: &[PathBuf],
    tile_bytes: usize,
    buffer: &mut [u8],
    threads: usize,
) -> anyhow::Result<f64> {
    let threads = threads.clamp(1, paths.len().max(1));
    let per_paths = paths.len().div_ceil(threads).max(1);
    // Each thread's share of the buffer, in whole tiles.
    let per_buffer = (buffer.len() / threads / tile_bytes).max(1) * tile_bytes;
    anyhow::ensure!(per_buffer * threads <= buffer.len(), "the in-place buffer holds less than one tile per thread");
    let t = Instant::now();
    std::thread::scope(|scope| {
        let runs: Vec<_> = paths
            .chunks(per_paths)
            .zip(buffer.chunks_mut(per_buffer))
            .map(|(paths, buffer)| scope.spawn(move || read_in_place_run(paths, tile_bytes, buffer)))
            .collect();
        runs.into_iter()
            .try_for_each(|r| r.join().map_err(|_| anyhow::anyhow!("a reading thread panicked"))?.map(|_| ()))
    })?;
    Ok(t.elapsed().as_secs_f64())
}

fn read_run(paths: &[PathBuf]) -> anyhow::Result<f64> {
    let t = Instant::now();
    let mut bytes = 0usize;
    for p in paths {
        bytes += std::fs::read(p).with_context(|| format!("reading {}", p.display()))?.len();
    }
    std::hint::black_box(bytes);
    Ok(t.elapsed().as_secs_f64())
}

fn drop_caches() -> bool {
    let _ = std::process::Command::new("sync").status();
    std::fs::write("/proc/sys/vm/drop_caches", "3\n").is_ok()
}

pub fn measure(prepared: &Prepared, size: Size, runs: usize) -> anyhow::Result<Ingest> {
    let (n, clip, tile) = shape(size);
    let source = open(prepared)?;
    let mut centres = jumps(n, clip);
    // Twice over, so that tiles evicted by the first pass are read again.
    centres.extend(centres.clone());
    let path_of = |tile: TileId| {
        let level = &prepared.layout.levels[tile.level as usize];
        prepared.root.join(prepared.layout.tile(level, tile.s, tile.t).path)
    };
    // Warm the page cache with every file the flight reads (and the engine's first run).
    let first = engine_run(&source, &centres)?;
    let (warm, memory_bytes) = (first.log, first.memory_bytes);
    let warm_paths: Vec<PathBuf> = warm.iter().map(|&t| path_of(t)).collect();
    read_run(&warm_paths)?;
    // Places as large as the largest tile of any level (the pyramid's whole levels are one tile).
    let tile_bytes = (0..source.desc().level_count() as u32).map(|k| source.desc().tile_bytes(k)).max().unwrap_or(1);
    // Touched once (as the engine's mapping is populated), so that no read faults pages in.
    let mut in_place_map =
        memmap2::MmapOptions::new().len((memory_bytes as usize).max(tile_bytes)).populate().map_anon()?;
    let in_place: &mut [u8] = &mut in_place_map;
    read_in_place_run(&warm_paths, tile_bytes, in_place)?;

    let (mut eng, mut plain, mut ratio) = (Vec::new(), Vec::new(), Vec::new());
    let (mut placed, mut placed_vs_read, mut eng_vs_placed) = (Vec::new(), Vec::new(), Vec::new());
    let (mut parallel, mut parallel_vs_read) = (Vec::new(), Vec::new());
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let (mut tiles_per_run, mut bytes_per_run) = (0, 0);
    let (mut ef, mut rf, mut ec, mut rc) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut es, mut rs, mut ts) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..runs {
        let run = engine_run(&source, &centres)?;
        let (e, log) = (run.secs, run.log);
        let paths: Vec<PathBuf> = log.iter().map(|&t| path_of(t)).collect();
        let p2 = proc_self();
        let plain_s = read_run(&paths)?;
        let p3 = proc_self();
        let placed_s = read_in_place_run(&paths, tile_bytes, in_place)?;
        let parallel_s = read_in_place_parallel_run(&paths, tile_bytes, in_place, threads)?;
        let tiles = log.len().max(1) as f64;
        ef.push(run.faults as f64 / tiles);
        rf.push((p3.minor_faults - p2.minor_faults) as f64 / tiles);
        ec.push(run.cpu_s * 1e6 / tiles);
        rc.push((p3.cpu_s - p2.cpu_s) * 1e6 / tiles);
        es.push(run.switches as f64 / tiles);
        ts.push(run.tick_s / e);
        rs.push(p3.switches.saturating_sub(p2.switches) as f64 / tiles);
        tiles_per_run = log.len();
        bytes_per_run = log.iter().map(|t| source.desc().tile_bytes(t.level) as u64).sum();
        let (e_rate, p_rate) = (log.len() as f64 / e, log.len() as f64 / plain_s);
        eng.push(e_rate);
        plain.push(p_rate);
        ratio.push(e_rate / p_rate);
        let placed_rate = log.len() as f64 / placed_s;
        placed.push(placed_rate);
        placed_vs_read.push(placed_rate / p_rate);
        eng_vs_placed.push(e_rate / placed_rate);
        let parallel_rate = log.len() as f64 / parallel_s;
        parallel.push(parallel_rate);
        parallel_vs_read.push(parallel_rate / p_rate);
    }
    drop(in_place_map);

    let drop_ok = drop_caches();
    let cold = if drop_ok {
        let run = engine_run(&source, &centres)?;
        let (e, log) = (run.secs, run.log);
        let paths: Vec<PathBuf> = log.iter().map(|&t| path_of(t)).collect();
        drop_caches();
        let p = read_run(&paths)?;
        let (e_rate, p_rate) = (log.len() as f64 / e, log.len() as f64 / p);
        // Leave the page cache warm for what follows.
        read_run(&paths)?;
        Some(Cold { engine_tiles_per_s: e_rate, read_tiles_per_s: p_rate, ratio: e_rate / p_rate })
    } else {
        None
    };
    Ok(Ingest {
        texture: n,
        clip,
        tile,
        tile_bytes: source.desc().tile_bytes(0) as u64,
        jumps_per_run: centres.len(),
        tiles_per_run,
        bytes_per_run,
        engine_tiles_per_s: Stat::of(eng),
        read_tiles_per_s: Stat::of(plain),
        ratio: Stat::of(ratio),
        read_in_place_tiles_per_s: Stat::of(placed),
        in_place_vs_read: Stat::of(placed_vs_read),
        engine_vs_in_place: Stat::of(eng_vs_placed),
        parallel_threads: threads,
        read_parallel_tiles_per_s: Stat::of(parallel),
        parallel_vs_read: Stat::of(parallel_vs_read),
        in_place_buffer_bytes: memory_bytes,
        engine_faults_per_tile: Stat::of(ef),
        read_faults_per_tile: Stat::of(rf),
        engine_cpu_us_per_tile: Stat::of(ec),
        read_cpu_us_per_tile: Stat::of(rc),
        engine_switches_per_tile: Stat::of(es),
        read_switches_per_tile: Stat::of(rs),
        engine_tick_share: Stat::of(ts),
        drop_caches: drop_ok,
        cold,
    })
}
