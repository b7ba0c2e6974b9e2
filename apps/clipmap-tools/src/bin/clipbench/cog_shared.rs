//! What the two halves of `clipbench cog` share (the local one in `cog.rs`, the HTTP one in
//! `cog_http.rs`): the clip size, GDAL's timed passes, the reference decode every tile is checked
//! against, one pass of ours over every level-0 tile, the CPU a mode spent, and the HTTP half's
//! run and figures.

use super::perf::MachineCpu;
use clipmap::source::{CogSource, TileId, TileSource};
use serde::Serialize;
use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// The clip size both sides use: level 0 is a stack level of whole tiles.
pub(crate) fn clip_of(n: u64) -> u64 {
    (n / 2).min(1024)
}

pub(crate) fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// What the GDAL script measured.
pub(crate) struct GdalRun {
    pub version: String,
    /// Tiles a pass.
    pub tiles: u64,
    /// Seconds a pass, reads only.
    pub seconds: Vec<f64>,
}

/// Runs the GDAL script on `tif` (a path, or `/vsicurl/URL`) with `env` set.
pub(crate) fn gdal_passes(
    python: &Path,
    script: &Path,
    tif: &str,
    tile: u64,
    passes: u64,
    dump: Option<&Path>,
    env: &[(&str, &str)],
) -> anyhow::Result<GdalRun> {
    let mut cmd = Command::new(python);
    cmd.arg(script).arg(tif).arg(tile.to_string()).arg(passes.to_string());
    cmd.arg(dump.map_or_else(|| "-".into(), |d| d.as_os_str().to_owned()));
    cmd.envs(env.iter().copied());
    let out = cmd.output()?;
    anyhow::ensure!(
        out.status.success(),
        "GDAL's reads of {tif} failed: {}",
        String::from_utf8_lossy(&out.stderr).trim()
    );
    #[derive(serde::Deserialize)]
    struct Out {
        version: String,
        tiles: u64,
        seconds: Vec<f64>,
    }
    let o: Out = serde_json::from_slice(&out.stdout)?;
    Ok(GdalRun { version: o.version, tiles: o.tiles, seconds: o.seconds })
}

/// GDAL's decode of every level-0 tile (its dump: rows of blocks from the top, each tile's rows
/// from the top), what every tile we read is compared with.
pub(crate) struct Reference {
    /// GDAL's dump of the level-0 tiles.
    pub gdal: Vec<u8>,
    /// The image's size, texels.
    pub n: u64,
    /// Its tile size, texels.
    pub tile: u64,
    /// How far apart a sample may be (JPEG: two decoders).
    pub tolerance: u8,
}

impl Reference {
    /// Texels of our level-0 tile `id` (rows from the bottom) that differ from GDAL's by more
    /// than the tolerance in some sample.
    pub(crate) fn wrong(&self, id: TileId, ours: &[u8]) -> u64 {
        let (tiles, tile, bpt) = (self.n / self.tile, self.tile as usize, 3usize);
        let tb = bpt * tile * tile;
        let by = tiles - 1 - id.t;
        let theirs = &self.gdal[(by * tiles + id.s) as usize * tb..][..tb];
        let row = bpt * tile;
        let mut wrong = 0u64;
        for r in 0..tile {
            let a = &ours[r * row..(r + 1) * row];
            let b = &theirs[(tile - 1 - r) * row..][..row];
            if a == b {
                continue;
            }
            let apart = |x: &[u8], y: &[u8]| x.iter().zip(y).any(|(p, q)| p.abs_diff(*q) > self.tolerance);
            wrong += a.chunks(bpt).zip(b.chunks(bpt)).filter(|(x, y)| apart(x, y)).count() as u64;
        }
        wrong
    }
}

/// One pass of ours over every level-0 tile of `src`.
pub(crate) struct Pass {
    pub seconds: f64,
    /// Texels that differ from GDAL's decode.
    pub wrong: u64,
    /// Reads that failed, and the first failure.
    pub failed: u64,
    pub first_error: Option<String>,
}

/// The machine's CPU over all the passes of a mode ([`MachineCpu`]): busy seconds over the whole
/// run of passes (opens and the checks between passes included, since the kernel counts in
/// hundredths of a second), seconds of the timed passes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Spent {
    pub busy_s: f64,
    pub wall_s: f64,
    pub tiles: u64,
}

impl Spent {
    /// The CPU since `cpu` was taken, over passes of `seconds` reading `tiles` tiles in all.
    pub fn since(cpu: MachineCpu, seconds: &[f64], tiles: u64) -> Spent {
        Spent { busy_s: MachineCpu::busy_since(cpu), wall_s: seconds.iter().sum(), tiles }
    }

    /// Cores busy on average.
    pub fn cores(&self) -> f64 {
        self.busy_s / self.wall_s.max(1e-9)
    }

    /// Microseconds of busy CPU a tile cost the machine.
    pub fn core_us_per_tile(&self) -> f64 {
        self.busy_s * 1e6 / self.tiles.max(1) as f64
    }
}

/// Tiles a reading thread takes at once in [`one_pass`]: the most a run of the engine's read
/// queues takes (its `MAX_BATCH`).
const RUN: u64 = 16;

/// Reads every level-0 tile of `src` on `depth` threads, as the engine's read queues do (runs of
/// [`RUN`] tiles, announced before they are read), each tile checked against `reference` (the
/// check is inside the timed pass: a few microseconds a tile, the same in every mode).
pub(crate) fn one_pass(src: &CogSource, depth: u64, reference: &Reference) -> Pass {
    let d = src.desc();
    let [ts, tt] = d.level(0).tiles();
    let bytes = d.tile_bytes(0);
    let next = AtomicU64::new(0);
    let (wrong, failed) = (AtomicU64::new(0), AtomicU64::new(0));
    let first_error = std::sync::Mutex::new(None);
    let t = Instant::now();
    std::thread::scope(|scope| {
        for _ in 0..depth {
            scope.spawn(|| {
                let mut buf = vec![0u8; bytes];
                loop {
                    // A run of tiles a thread, announced before it is read, as the engine's read
                    // queues do (`TileSource::will_read`; a remote COG reads the announced tiles
                    // that lie side by side with one request).
                    let first = next.fetch_add(RUN, Ordering::Relaxed);
                    if first >= ts * tt {
                        return;
                    }
                    let run: Vec<TileId> = (first..(first + RUN).min(ts * tt))
                        .map(|i| TileId { level: 0, s: i % ts, t: i / ts })
                        .collect();
                    src.will_read(&run);
                    for id in run {
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
                }
            });
        }
    });
    Pass {
        seconds: t.elapsed().as_secs_f64(),
        wrong: wrong.into_inner(),
        failed: failed.into_inner(),
        first_error: first_error.into_inner().unwrap_or_else(|e| e.into_inner()),
    }
}

/// What the HTTP half needs of the run (`cog_http.rs`).
#[cfg_attr(not(feature = "remote"), allow(dead_code))]
pub(crate) struct HttpRun<'a> {
    pub dir: &'a Path,
    pub tif: &'a Path,
    pub n: u64,
    pub tile: u64,
    pub depth: u64,
    pub passes: u64,
    pub reference: &'a Reference,
    pub python: &'a Path,
    pub script: &'a Path,
    pub install_peers: bool,
    /// `--link-rate`, megabytes a second a connection.
    pub link_mb_per_s: Option<u64>,
}

/// The HTTP half's figures (`null` in the JSON when nginx or curl is missing).
#[derive(Debug, Default, Serialize)]
pub struct Http {
    /// Ours over HTTP, `depth` threads (median pass, open not included).
    pub tiles_per_s_http: f64,
    /// GDAL through `/vsicurl/`, one `ReadRaster` a tile, [`GDAL_HTTP_ENV`](crate::cog_http::GDAL_HTTP_ENV) set (median pass).
    pub tiles_per_s_gdal_http: f64,
    /// The same with `GDAL_NUM_THREADS=ALL_CPUS` too.
    pub tiles_per_s_gdal_http_all_cpus: f64,
    /// The same with none of GDAL's settings (GDAL's defaults).
    pub tiles_per_s_gdal_http_default_env: f64,
    /// curl fetching the byte ranges of our pass, `depth` transfers at once (median pass).
    pub curl_ceiling_tiles_per_s: f64,
    /// Our remote reader fetching the same ranges, the same threads, without decoding them.
    pub tiles_per_s_http_fetch_only: f64,
    /// Cores busy on average (the whole machine: ours or curl, nginx, the kernel) during our
    /// HTTP passes, curl's, and our fetch-only passes.
    pub cores_busy_http: f64,
    pub cores_busy_curl: f64,
    pub cores_busy_fetch_only: f64,
    /// The machine's busy CPU a tile cost in each, microseconds.
    pub core_us_per_tile_http: f64,
    pub core_us_per_tile_curl: f64,
    pub core_us_per_tile_fetch_only: f64,
    /// Requests of one pass of ours, open included (nginx's log).
    pub requests: u64,
    /// Bytes of one pass of ours, open included.
    pub bytes: u64,
    /// GDAL's requests a pass (open included; all passes over the number of passes).
    pub requests_gdal: u64,
    pub bytes_gdal: u64,
    /// GDAL's requests a pass with its defaults.
    pub requests_gdal_default_env: u64,
    /// Requests and bytes of our open.
    pub open_requests: u64,
    pub open_bytes: u64,
    /// The largest and mean range of our pass (open excluded).
    pub range_bytes_max: u64,
    pub range_bytes_mean: f64,
    /// What GDAL was given for `tiles_per_s_gdal_http`.
    pub gdal_env: Vec<String>,
    /// Ours through the relay the faults are injected by, with no fault (median pass).
    pub tiles_per_s_http_relay: f64,
    /// Ours through that relay injecting faults (median pass).
    pub tiles_per_s_http_faults: f64,
    /// Shares of requests answered 503, and cut (connection closed half way through the body).
    pub fault_503_share: f64,
    pub fault_cut_share: f64,
    /// Faults injected, over all passes.
    pub faults_503: u64,
    pub faults_cut: u64,
    /// Our retries and reads that failed after them, with faults.
    pub retries: u64,
    pub failed_reads: u64,
    /// Texels that differ from GDAL's decode over every HTTP pass (clean, relay, faults).
    pub wrong_texels: u64,
    /// Our open over HTTP, seconds (median).
    pub open_s: f64,
}
