//! `clipbench cog`: tiles per second from a Cloud-Optimized GeoTIFF served as it is, against
//! GDAL reading the same tiles of the same file, in the same run.
//!
//! The COG is written by GDAL (`gdal_translate -of COG`, LZW as GDAL's COG default unless
//! `--compression` says otherwise, 256-texel blocks) from the procedural terrain texture (smooth, so it compresses as imagery does; RGB).
//! Both sides read every level-0 tile, `passes` times, each pass on a fresh open (GDAL's block
//! cache empty, our source holding no tiles); the file is in the page cache for both.
//! - ours: `CogSource::read_tile` on `depth` threads (the engine's read queues read 4 at once),
//!   and on one thread beside it;
//! - GDAL: its Python binding, one `ReadRaster` a tile (pixel-interleaved), default settings as
//!   its users run it, and again with `GDAL_NUM_THREADS=ALL_CPUS`.
//!
//! `wrong_texels` compares every level-0 texel we decode with GDAL's own decode of the same tile
//! (an untimed pass), rows turned over (our t counts up from the image's bottom row).

use clipmap::source::{CogSource, Procedural, TextureDesc, TileId, TileSource};
use clipmap::texel::TexelFormat;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// Options of `clipbench cog`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A 4096-texel COG (about 20 s in all).
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
    /// Install GDAL (`apt-get install -y gdal-bin python3-gdal`) if it is missing; apt-get's
    /// output goes to standard error.
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
/// HTTP ones are `null` until remote COGs are served.
#[derive(Debug, Serialize)]
pub struct Report {
    /// Level-0 tiles a second, ours, `depth` threads (median pass).
    pub tiles_per_s_local: f64,
    /// Level-0 tiles a second, GDAL, one `ReadRaster` a tile, default settings (median pass).
    pub tiles_per_s_gdal_local: f64,
    /// Ours over GDAL's (goal >= 2).
    pub local_vs_gdal: f64,
    /// Ours over the HTTP stack (`null`: remote COGs are not served yet).
    pub tiles_per_s_http: Option<f64>,
    /// GDAL through `/vsicurl/` (`null`: not measured yet).
    pub tiles_per_s_gdal_http: Option<f64>,
    /// curl fetching the same ranges (`null`: not measured yet).
    pub curl_ceiling_tiles_per_s: Option<f64>,
    /// Requests (HTTP; `null` for local files).
    pub requests: Option<u64>,
    /// GDAL's requests (HTTP; `null` for local files).
    pub requests_gdal: Option<u64>,
    /// Requests to open (HTTP; `null` for local files).
    pub open_requests: Option<u64>,
    /// Bytes read to open (HTTP; `null` for local files).
    pub open_bytes: Option<u64>,
    /// Level-0 texels we decode differently from GDAL (every tile, one pass).
    pub wrong_texels: u64,
    /// Ours on one thread.
    pub tiles_per_s_local_one_thread: f64,
    /// GDAL with `GDAL_NUM_THREADS=ALL_CPUS`.
    pub tiles_per_s_gdal_local_all_cpus: f64,
    /// Seconds to open the COG, ours (median; levels past the overviews built at open).
    pub open_s: f64,
    /// The COG.
    pub cog: CogShape,
    /// GDAL's version.
    pub gdal_version: String,
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

/// Reads every level-0 tile through GDAL's binding: `time` passes timed (each on a fresh open),
/// or with `dump`, one untimed pass writing the tiles' bytes in order (t from the top, then s).
const GDAL_TILES: &str = r#"
import json, sys, time
from osgeo import gdal
gdal.UseExceptions()
tif, tile, passes, dump = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
def read_all(out=None):
    ds = gdal.Open(tif)
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
    return n
if dump != "-":
    with open(dump, "wb") as f:
        read_all(f)
times = []
tiles = 0
for _ in range(passes):
    t = time.perf_counter()
    tiles = read_all()
    times.append(time.perf_counter() - t)
print(json.dumps({"version": gdal.__version__, "tiles": tiles, "seconds": times}))
"#;

/// The clip size both sides use: level 0 is a stack level of whole tiles.
fn clip_of(n: u64) -> u64 {
    (n / 2).min(1024)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Runs the GDAL script; (version, tiles a pass, seconds a pass).
fn gdal_passes(
    python: &Path,
    script: &Path,
    tif: &Path,
    tile: u64,
    passes: u64,
    dump: Option<&Path>,
    all_cpus: bool,
) -> anyhow::Result<(String, u64, Vec<f64>)> {
    let mut cmd = Command::new(python);
    cmd.arg(script).arg(tif).arg(tile.to_string()).arg(passes.to_string());
    cmd.arg(dump.map_or_else(|| "-".into(), |d| d.as_os_str().to_owned()));
    if all_cpus {
        cmd.env("GDAL_NUM_THREADS", "ALL_CPUS");
    }
    let out = cmd.output()?;
    anyhow::ensure!(out.status.success(), "GDAL's reads failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    #[derive(serde::Deserialize)]
    struct Out {
        version: String,
        tiles: u64,
        seconds: Vec<f64>,
    }
    let o: Out = serde_json::from_slice(&out.stdout)?;
    Ok((o.version, o.tiles, o.seconds))
}

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

/// Our passes: every level-0 tile read on `depth` threads, each pass on a fresh open; (seconds
/// a pass, seconds an open).
fn our_passes(tif: &Path, n: u64, depth: u64, passes: u64) -> anyhow::Result<(Vec<f64>, Vec<f64>)> {
    let (mut times, mut opens) = (Vec::new(), Vec::new());
    for _ in 0..passes {
        let t0 = Instant::now();
        let src = Arc::new(CogSource::open(tif, clip_of(n))?);
        opens.push(t0.elapsed().as_secs_f64());
        let d = src.desc();
        let [ts, tt] = d.level(0).tiles();
        let bytes = d.tile_bytes(0);
        let next = AtomicU64::new(0);
        let t = Instant::now();
        std::thread::scope(|scope| -> anyhow::Result<()> {
            let workers: Vec<_> = (0..depth)
                .map(|_| {
                    scope.spawn(|| -> anyhow::Result<()> {
                        let mut buf = vec![0u8; bytes];
                        loop {
                            let i = next.fetch_add(1, Ordering::Relaxed);
                            if i >= ts * tt {
                                return Ok(());
                            }
                            src.read_tile(TileId { level: 0, s: i % ts, t: i / ts }, &mut buf)?;
                        }
                    })
                })
                .collect();
            for w in workers {
                w.join().map_err(|_| anyhow::anyhow!("a reading thread panicked"))??;
            }
            Ok(())
        })?;
        times.push(t.elapsed().as_secs_f64());
    }
    Ok((times, opens))
}

/// Level-0 texels of ours that differ from GDAL's dump by more than `tolerance` in some sample
/// (tiles in GDAL's order: rows of blocks from the top, each tile's rows from the top).
fn wrong_texels(tif: &Path, dump: &Path, n: u64, tile: u64, tolerance: u8) -> anyhow::Result<u64> {
    let src = CogSource::open(tif, clip_of(n))?;
    let gdal = std::fs::read(dump)?;
    let (bpt, tiles, tb) = (3usize, n / tile, 3 * (tile * tile) as usize);
    anyhow::ensure!(gdal.len() == tb * (tiles * tiles) as usize, "GDAL's dump is {} bytes", gdal.len());
    let mut wrong = 0u64;
    let mut ours = vec![0u8; tb];
    for by in 0..tiles {
        for bx in 0..tiles {
            let theirs = &gdal[(by * tiles + bx) as usize * tb..][..tb];
            src.read_tile(TileId { level: 0, s: bx, t: tiles - 1 - by }, &mut ours)?;
            let row = bpt * tile as usize;
            for r in 0..tile as usize {
                let a = &ours[r * row..(r + 1) * row];
                let b = &theirs[(tile as usize - 1 - r) * row..][..row];
                let apart = |x: &[u8], y: &[u8]| x.iter().zip(y).any(|(p, q)| p.abs_diff(*q) > tolerance);
                wrong += a.chunks(bpt).zip(b.chunks(bpt)).filter(|(x, y)| apart(x, y)).count() as u64;
            }
        }
    }
    Ok(wrong)
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
    // The untimed pass first: it also brings the file into the page cache for both sides.
    let (version, gdal_tiles, gdal_s) = gdal_passes(&gdal.python, &script, &tif, tile, passes, Some(&dump), false)?;
    let tolerance = if matches!(args.compression, Compression::Jpeg) { JPEG_TOLERANCE } else { 0 };
    let wrong = wrong_texels(&tif, &dump, n, tile, tolerance)?;
    let _ = std::fs::remove_file(&dump);
    let (_, _, gdal_all_s) = gdal_passes(&gdal.python, &script, &tif, tile, passes, None, true)?;
    let (ours_s, opens) = our_passes(&tif, n, args.depth, passes)?;
    let (one_s, _) = our_passes(&tif, n, 1, passes)?;
    let tiles = (n / tile) * (n / tile);
    anyhow::ensure!(gdal_tiles == tiles, "GDAL read {gdal_tiles} tiles a pass where the COG has {tiles}");
    let rate = |s: Vec<f64>| tiles as f64 / median(s);
    let (ours, theirs) = (rate(ours_s), rate(gdal_s));
    Ok(Report {
        tiles_per_s_local: ours,
        tiles_per_s_gdal_local: theirs,
        local_vs_gdal: ours / theirs,
        tiles_per_s_http: None,
        tiles_per_s_gdal_http: None,
        curl_ceiling_tiles_per_s: None,
        requests: None,
        requests_gdal: None,
        open_requests: None,
        open_bytes: None,
        wrong_texels: wrong,
        tiles_per_s_local_one_thread: rate(one_s),
        tiles_per_s_gdal_local_all_cpus: rate(gdal_all_s),
        open_s: median(opens),
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
        depth: args.depth,
        passes,
        nproc: std::thread::available_parallelism().map_or(1, |n| n.get()),
    })
}

fn human(r: &Report) -> String {
    format!(
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
    )
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
