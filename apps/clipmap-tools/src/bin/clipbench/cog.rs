//! `clipbench cog`: tiles per second from a Cloud-Optimized GeoTIFF served as it is, against
//! GDAL reading the same tiles of the same file, in the same run; locally, then over loopback
//! HTTP (`cog_http.rs`); what both halves share is in `cog_shared.rs`.
//!
//! The COG is written by GDAL (`gdal_translate -of COG`, LZW as GDAL's COG default unless
//! `--compression` says otherwise, 256-texel blocks) from the procedural terrain texture (smooth, so it compresses as imagery does; RGB).
//! Both sides read every level-0 tile, `passes` times, each pass on a fresh open (GDAL's block
//! cache empty, our source holding no tiles; opens timed apart); the file is in the page cache
//! for both.
//! - ours: `CogSource::read_tile` on `depth` threads (the engine's read queues read 4 at once),
//!   and on one thread beside it;
//! - GDAL: its Python binding, one `ReadRaster` a tile (pixel-interleaved), default settings as
//!   its users run it, and again with `GDAL_NUM_THREADS=ALL_CPUS`.
//!
//! `wrong_texels` compares every level-0 texel we read, in every pass of every mode, with GDAL's
//! own decode of the same tile (an untimed pass of GDAL's first), rows turned over (our t counts
//! up from the image's bottom row).

use super::cog_shared::{clip_of, gdal_passes, median, one_pass, Http, HttpRun, Reference, Spent};
use super::perf::MachineCpu;
use clipmap::source::{CogSource, Procedural, TextureDesc, TileId, TileSource};
use clipmap::texel::TexelFormat;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// Options of `clipbench cog`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A 4096-texel COG (about 40 s in all, the HTTP half included).
    #[arg(long)]
    quick: bool,
    /// A tiny COG: checks that the benchmark runs (for tests); the figures mean little.
    #[arg(long, hide = true, conflicts_with = "quick")]
    smoke: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Our reads in flight (threads), as the engine's read queues run them.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..=64))]
    depth: u64,
    /// Timed passes over every level-0 tile, each side (the median pass is reported).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=100))]
    passes: u64,
    /// Install GDAL (`apt-get install -y gdal-bin python3-gdal`), and nginx and curl for the
    /// HTTP half, if they are missing; apt-get's output goes to standard error.
    #[arg(long)]
    install_peers: bool,
    /// Scratch directory (a fresh subdirectory, removed at the end).
    #[arg(long)]
    dir: Option<PathBuf>,
    /// The COG's compression (`gdal_translate -co COMPRESS=`): GDAL's COG default is LZW.
    #[arg(long, value_enum, default_value = "lzw")]
    compression: Compression,
    /// Horizontal differencing (`-co PREDICTOR=YES`, TIFF predictor 2) before compressing.
    #[arg(long)]
    predictor: bool,
    /// Each HTTP connection limited to this many megabytes (10^6 bytes) a second (nginx's
    /// `limit_rate`), for GDAL, curl and ours alike: object storage over a network, where a
    /// connection's throughput rather than the CPU bounds the read. Unlimited when absent.
    #[arg(long, value_name = "MB_PER_S", value_parser = clap::value_parser!(u64).range(1..=100_000))]
    link_rate: Option<u64>,
}

/// A compression GDAL writes and the COG source reads.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum Compression {
    Lzw,
    Deflate,
    Zstd,
    None,
    /// JPEG, YCbCr (GDAL's COG default for RGB), quality 75: lossy, so `wrong_texels` counts
    /// texels more than [`JPEG_TOLERANCE`] apart from GDAL's decode in some sample.
    Jpeg,
}

/// How far apart two JPEG decoders' samples may be (tests/it/cog_samples.rs measures it).
const JPEG_TOLERANCE: u8 = 4;

impl Compression {
    fn gdal_name(self) -> &'static str {
        match self {
            Compression::Lzw => "LZW",
            Compression::Deflate => "DEFLATE",
            Compression::Zstd => "ZSTD",
            Compression::None => "NONE",
            Compression::Jpeg => "JPEG",
        }
    }
}

/// What `clipbench cog --json` prints. The fields the COG issue names are a contract; the
/// HTTP ones are `null` when nginx or curl is missing (or the build has no `remote` feature).
#[derive(Debug, Serialize)]
pub struct Report {
    /// Level-0 tiles a second, ours, `depth` threads (median pass).
    pub tiles_per_s_local: f64,
    /// Level-0 tiles a second, GDAL, one `ReadRaster` a tile, default settings (median pass).
    pub tiles_per_s_gdal_local: f64,
    /// Ours over GDAL's (goal >= 2).
    pub local_vs_gdal: f64,
    /// Ours over loopback HTTP (nginx), `depth` threads (median pass).
    pub tiles_per_s_http: Option<f64>,
    /// GDAL through `/vsicurl/`, one `ReadRaster` a tile (median pass).
    pub tiles_per_s_gdal_http: Option<f64>,
    /// curl fetching the byte ranges our pass fetched, `depth` transfers at once.
    pub curl_ceiling_tiles_per_s: Option<f64>,
    /// Requests of one pass of ours over HTTP, open included.
    pub requests: Option<u64>,
    /// GDAL's requests for the same pass, open included.
    pub requests_gdal: Option<u64>,
    /// Requests to open over HTTP (goal: 1).
    pub open_requests: Option<u64>,
    /// Bytes read to open over HTTP (at most 65536).
    pub open_bytes: Option<u64>,
    /// Ours over GDAL's, HTTP (goal >= 2).
    pub http_vs_gdal: Option<f64>,
    /// Ours over the curl ceiling (goal >= 0.8).
    pub http_vs_curl: Option<f64>,
    /// GDAL through `/vsicurl/` with `GDAL_NUM_THREADS=ALL_CPUS`.
    pub tiles_per_s_gdal_http_all_cpus: Option<f64>,
    /// Ours over HTTP through a relay injecting faults.
    pub tiles_per_s_http_faults: Option<f64>,
    /// `tiles_per_s_http_faults` over the same relay's rate without faults (goal >= 0.8).
    pub faults_vs_clean: Option<f64>,
    /// Level-0 texels we decode differently from GDAL, over every tile of every pass in every
    /// mode (local, HTTP, HTTP with faults).
    pub wrong_texels: u64,
    /// Ours on one thread.
    pub tiles_per_s_local_one_thread: f64,
    /// Cores busy on average during our local passes, the whole machine ([`MachineCpu`]).
    pub cores_busy_local: f64,
    /// The machine's busy CPU a tile of our local passes cost, microseconds.
    pub core_us_per_tile_local: f64,
    /// What a tile cost the machine under curl over what it cost under ours, over HTTP: the
    /// most `http_vs_curl` can be where both keep every core busy (docs/BENCHMARKS.md, COG).
    pub http_vs_curl_cpu_bound: Option<f64>,
    /// GDAL with `GDAL_NUM_THREADS=ALL_CPUS`.
    pub tiles_per_s_gdal_local_all_cpus: f64,
    /// Seconds to open the COG, ours (median; levels past the overviews built at open).
    pub open_s: f64,
    /// The HTTP half in full.
    pub http: Option<Http>,
    /// The COG.
    pub cog: CogShape,
    /// GDAL's version.
    pub gdal_version: String,
    /// `--link-rate`: megabytes a second each HTTP connection was limited to (`null`: no limit).
    pub link_rate_mb_per_s: Option<u64>,
    /// Threads of ours.
    pub depth: u64,
    /// Passes each side.
    pub passes: u64,
    /// The machine.
    pub nproc: usize,
}

/// The COG measured.
#[derive(Debug, Serialize)]
pub struct CogShape {
    pub size: u64,
    pub tile: u64,
    pub compression: &'static str,
    pub predictor: bool,
    pub bands: u32,
    pub file_bytes: u64,
    pub level0_tiles: u64,
}

/// Reads every level-0 tile through GDAL's binding: `passes` passes timed (each on a fresh open,
/// the open itself timed apart; `/vsicurl/`'s cache emptied before each), and first, with
/// `dump`, one untimed pass writing the tiles' bytes in order (t from the top, then s).
const GDAL_TILES: &str = r#"
import json, sys, time
from osgeo import gdal
gdal.UseExceptions()
tif, tile, passes, dump = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
def read_all(out=None):
    # Nothing kept from the pass before: /vsicurl/'s cache of ranges is process-wide.
    gdal.VSICurlClearCache()
    t0 = time.perf_counter()
    ds = gdal.Open(tif)
    t1 = time.perf_counter()
    w, h, b = ds.RasterXSize, ds.RasterYSize, ds.RasterCount
    n = 0
    for by in range(h // tile):
        for bx in range(w // tile):
            buf = ds.ReadRaster(bx * tile, by * tile, tile, tile, buf_pixel_space=b, buf_line_space=b * tile, buf_band_space=1)
            if len(buf) != b * tile * tile:
                sys.exit("short read")
            if out is not None:
                out.write(buf)
            n += 1
    ds = None
    return n, t1 - t0, time.perf_counter() - t1
if dump != "-":
    with open(dump, "wb") as f:
        read_all(f)
times, opens = [], []
tiles = 0
for _ in range(passes):
    tiles, o, t = read_all()
    times.append(t)
    opens.append(o)
print(json.dumps({"version": gdal.__version__, "tiles": tiles, "seconds": times, "open_seconds": opens}))
"#;

/// Writes the terrain texture's level 0 as a PNG (top row first, as image files are) and GDAL's
/// COG of it; returns the COG's path.
fn make_cog(dir: &Path, translate: &Path, n: u64, tile: u64, args: &Args) -> anyhow::Result<PathBuf> {
    let desc = TextureDesc::new([n, n], clip_of(n), TexelFormat::RGB8, [tile, tile])?;
    let src = Procedural::Terrain.source(desc);
    let (row, tiles) = (3 * n as usize, n / tile);
    let mut img = vec![0u8; row * n as usize];
    let mut buf = vec![0u8; 3 * (tile * tile) as usize];
    for t in 0..tiles {
        for s in 0..tiles {
            src.read_tile(TileId { level: 0, s, t }, &mut buf)?;
            for r in 0..tile as usize {
                // Our row t*tile + r counts from the bottom; the file's rows from the top.
                let y = n as usize - 1 - (t as usize * tile as usize + r);
                let x = 3 * s as usize * tile as usize;
                img[y * row + x..y * row + x + 3 * tile as usize]
                    .copy_from_slice(&buf[r * 3 * tile as usize..(r + 1) * 3 * tile as usize]);
            }
        }
    }
    let png = dir.join("terrain.png");
    image::RgbImage::from_raw(n as u32, n as u32, img)
        .ok_or_else(|| anyhow::anyhow!("the image buffer does not match its size"))?
        .save(&png)?;
    let tif = dir.join("terrain_cog.tif");
    let out = Command::new(translate)
        .args(["-q", "-of", "COG", "-co"])
        .arg(format!("COMPRESS={}", args.compression.gdal_name()))
        .args(["-co", if args.predictor { "PREDICTOR=YES" } else { "PREDICTOR=NO" }, "-co"])
        .arg(format!("BLOCKSIZE={tile}"))
        .arg(&png)
        .arg(&tif)
        .output()?;
    anyhow::ensure!(out.status.success(), "gdal_translate failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    Ok(tif)
}

/// Our local passes, each on a fresh open; (seconds a pass, seconds an open, wrong texels, the
/// machine's CPU over the passes).
fn our_passes(
    tif: &Path,
    n: u64,
    depth: u64,
    passes: u64,
    reference: &Reference,
) -> anyhow::Result<(Vec<f64>, Vec<f64>, u64, Spent)> {
    let (mut times, mut opens, mut wrong, mut tiles) = (Vec::new(), Vec::new(), 0, 0);
    let cpu = MachineCpu::now();
    for _ in 0..passes {
        let t0 = Instant::now();
        let src = CogSource::open(tif, clip_of(n))?;
        opens.push(t0.elapsed().as_secs_f64());
        let p = one_pass(&src, depth, reference);
        if let Some(e) = p.first_error {
            anyhow::bail!("{}: {} reads failed; the first: {e}", tif.display(), p.failed);
        }
        times.push(p.seconds);
        let [ts, tt] = src.desc().level(0).tiles();
        tiles += ts * tt;
        wrong += p.wrong;
    }
    let spent = Spent::since(cpu, &times, tiles);
    Ok((times, opens, wrong, spent))
}

fn measure(args: &Args, dir: &Path) -> anyhow::Result<Report> {
    let gdal = super::perf::find_gdal(args.install_peers).map_err(|e| anyhow::anyhow!("GDAL is needed: {e}"))?;
    let (n, tile) = if args.smoke {
        (512, 256)
    } else if args.quick {
        (4096, 256)
    } else {
        (8192, 256)
    };
    let passes = if args.smoke { 1 } else { args.passes };
    let tif = make_cog(dir, &gdal.translate, n, tile, args)?;
    let script = dir.join("gdal_tiles.py");
    std::fs::write(&script, GDAL_TILES)?;
    let dump = dir.join("gdal_tiles.raw");
    let path = tif.to_string_lossy();
    // The untimed pass first: it also brings the file into the page cache for both sides.
    let run = gdal_passes(&gdal.python, &script, &path, tile, passes, Some(&dump), &[])?;
    let (version, gdal_tiles, gdal_s) = (run.version, run.tiles, run.seconds);
    let tolerance = if matches!(args.compression, Compression::Jpeg) { JPEG_TOLERANCE } else { 0 };
    let reference = Reference { gdal: std::fs::read(&dump)?, n, tile, tolerance };
    let tb = 3 * (tile * tile) as usize;
    anyhow::ensure!(
        reference.gdal.len() == tb * ((n / tile) * (n / tile)) as usize,
        "GDAL's dump is {} bytes",
        reference.gdal.len()
    );
    let _ = std::fs::remove_file(&dump);
    let gdal_all_s =
        gdal_passes(&gdal.python, &script, &path, tile, passes, None, &[("GDAL_NUM_THREADS", "ALL_CPUS")])?.seconds;
    let (ours_s, opens, mut wrong, local_cpu) = our_passes(&tif, n, args.depth, passes, &reference)?;
    let (one_s, _, w, _) = our_passes(&tif, n, 1, passes, &reference)?;
    wrong += w;
    let tiles = (n / tile) * (n / tile);
    anyhow::ensure!(gdal_tiles == tiles, "GDAL read {gdal_tiles} tiles a pass where the COG has {tiles}");
    let http_run = HttpRun {
        dir,
        tif: &tif,
        n,
        tile,
        depth: args.depth,
        passes,
        reference: &reference,
        python: &gdal.python,
        script: &script,
        install_peers: args.install_peers,
        link_mb_per_s: args.link_rate,
    };
    let http = http_half(&http_run)?;
    wrong += http.as_ref().map_or(0, |h| h.wrong_texels);
    let rate = |s: Vec<f64>| tiles as f64 / median(s);
    let (ours, theirs) = (rate(ours_s), rate(gdal_s));
    let h = http.as_ref();
    Ok(Report {
        tiles_per_s_local: ours,
        tiles_per_s_gdal_local: theirs,
        local_vs_gdal: ours / theirs,
        tiles_per_s_http: h.map(|h| h.tiles_per_s_http),
        tiles_per_s_gdal_http: h.map(|h| h.tiles_per_s_gdal_http),
        curl_ceiling_tiles_per_s: h.map(|h| h.curl_ceiling_tiles_per_s),
        requests: h.map(|h| h.requests),
        requests_gdal: h.map(|h| h.requests_gdal),
        open_requests: h.map(|h| h.open_requests),
        open_bytes: h.map(|h| h.open_bytes),
        http_vs_gdal: h.map(|h| h.tiles_per_s_http / h.tiles_per_s_gdal_http),
        http_vs_curl: h.map(|h| h.tiles_per_s_http / h.curl_ceiling_tiles_per_s),
        tiles_per_s_gdal_http_all_cpus: h.map(|h| h.tiles_per_s_gdal_http_all_cpus),
        tiles_per_s_http_faults: h.map(|h| h.tiles_per_s_http_faults),
        faults_vs_clean: h.map(|h| h.tiles_per_s_http_faults / h.tiles_per_s_http_relay),
        wrong_texels: wrong,
        tiles_per_s_local_one_thread: rate(one_s),
        cores_busy_local: local_cpu.cores(),
        core_us_per_tile_local: local_cpu.core_us_per_tile(),
        http_vs_curl_cpu_bound: h.map(|h| h.core_us_per_tile_curl / h.core_us_per_tile_http),
        tiles_per_s_gdal_local_all_cpus: rate(gdal_all_s),
        open_s: median(opens),
        http,
        cog: CogShape {
            size: n,
            tile,
            compression: args.compression.gdal_name(),
            predictor: args.predictor,
            bands: 3,
            file_bytes: std::fs::metadata(&tif)?.len(),
            level0_tiles: tiles,
        },
        gdal_version: version,
        link_rate_mb_per_s: args.link_rate,
        depth: args.depth,
        passes,
        nproc: std::thread::available_parallelism().map_or(1, |n| n.get()),
    })
}

/// The HTTP half, or `None` (with a note on standard error) when what it needs is missing.
#[cfg(feature = "remote")]
fn http_half(run: &HttpRun) -> anyhow::Result<Option<Http>> {
    super::cog_http::measure(run)
}

#[cfg(not(feature = "remote"))]
fn http_half(_: &HttpRun) -> anyhow::Result<Option<Http>> {
    eprintln!("clipbench cog: this build reads no remote objects (the `remote` feature): the HTTP fields are null");
    Ok(None)
}

fn human(r: &Report) -> String {
    let mut o = format!(
        "COG {}x{} RGB, {}{}, {}-texel tiles ({} bytes), GDAL {}\n\
         level-0 tiles a second: ours {:.0} ({} threads; {:.0} on one), GDAL {:.0} (ALL_CPUS {:.0}): {:.2}x\n\
         open {:.3} s; texels that differ from GDAL's decode: {}\n",
        r.cog.size,
        r.cog.size,
        r.cog.compression,
        if r.cog.predictor { " with predictor 2" } else { "" },
        r.cog.tile,
        r.cog.file_bytes,
        r.gdal_version,
        r.tiles_per_s_local,
        r.depth,
        r.tiles_per_s_local_one_thread,
        r.tiles_per_s_gdal_local,
        r.tiles_per_s_gdal_local_all_cpus,
        r.local_vs_gdal,
        r.open_s,
        r.wrong_texels
    );
    match &r.http {
        None => o.push_str("HTTP: not measured (nginx or curl missing)\n"),
        Some(h) => o.push_str(&format!(
            "HTTP (nginx on loopback{}): ours {:.0}, GDAL /vsicurl/ {:.0} (ALL_CPUS {:.0}; GDAL's defaults {:.0}): {:.2}x; \
             curl, the same ranges {} at once, {:.0}: {:.2} of it (our reader fetching them without decoding: {:.0})\n\
             requests a pass: ours {} ({} bytes; open {} of {} bytes), GDAL {} ({} bytes; {} with its defaults)\n\
             faults ({:.0} % 503, {:.0} % cut): {:.0} against {:.0} through the same relay without them ({:.2}); \
             {} 503s and {} cuts injected, {} retries, {} reads failed\n\
             the machine's CPU a tile (cores busy): ours local {:.0} us ({:.2}), ours HTTP {:.0} us ({:.2}), curl {:.0} us ({:.2}), \
             ours fetching only {:.0} us ({:.2}); curl's over ours, HTTP: {:.2}, the most ours / curl can be with every core busy\n",
            r.link_rate_mb_per_s.map_or(String::new(), |m| format!(", {m} MB/s a connection")),
            h.tiles_per_s_http,
            h.tiles_per_s_gdal_http,
            h.tiles_per_s_gdal_http_all_cpus,
            h.tiles_per_s_gdal_http_default_env,
            h.tiles_per_s_http / h.tiles_per_s_gdal_http,
            r.depth,
            h.curl_ceiling_tiles_per_s,
            h.tiles_per_s_http / h.curl_ceiling_tiles_per_s,
            h.tiles_per_s_http_fetch_only,
            h.requests,
            h.bytes,
            h.open_requests,
            h.open_bytes,
            h.requests_gdal,
            h.bytes_gdal,
            h.requests_gdal_default_env,
            h.fault_503_share * 100.0,
            h.fault_cut_share * 100.0,
            h.tiles_per_s_http_faults,
            h.tiles_per_s_http_relay,
            h.tiles_per_s_http_faults / h.tiles_per_s_http_relay,
            h.faults_503,
            h.faults_cut,
            h.retries,
            h.failed_reads,
            r.core_us_per_tile_local,
            r.cores_busy_local,
            h.core_us_per_tile_http,
            h.cores_busy_http,
            h.core_us_per_tile_curl,
            h.cores_busy_curl,
            h.core_us_per_tile_fetch_only,
            h.cores_busy_fetch_only,
            h.core_us_per_tile_curl / h.core_us_per_tile_http
        )),
    }
    o
}

pub fn main(args: Args) -> u8 {
    super::run_in_scratch(
        "cog",
        args.dir.as_deref(),
        args.json,
        |dir| measure(&args, dir),
        human,
        |r| r.wrong_texels > 0,
    )
}
