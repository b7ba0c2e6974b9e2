//! `clipbench growing`: tile rebuilds per second while 4000 x 3000 patches stream in, for 256²
//! and 512² tiles, beside the raw decode rate of the same patches in the same run
//! (docs/BENCHMARKS.md, "Growing textures").
//!
//! The patches are a survey: a lawnmower pattern of overlapping 4000 x 3000 RGB images (a quarter
//! overlap each way), one world unit a texel, starting left of and below the grid's origin so the
//! texture grows across it, with ratings that differ so overlaps are resolved both ways. Each is
//! made once as a JPEG (quality 90, as a camera writes it). The run then
//! 1. decodes every JPEG as ingest does (`growing::input::decode_image`): the decode rate;
//! 2. for each tile size, indexes the decoded patches one by one and, after each, rebuilds at
//!    most a tick's budget of tiles, then drains what is left: every tile of every level that
//!    the patches change is rebuilt, and each rebuild counts.
//!
//! Exit status: 0 ok, 2 the benchmark could not run.

use anyhow::Context;
use clipmap::growing::index::PatchIndex;
use clipmap::growing::input::decode_image;
use clipmap::growing::rebuild::Rebuilder;
use clipmap::growing::store::Growing;
use clipmap::growing::NewPatch;
use clipmap::growing::{Grid, Patch, PatchMeta, WorldBox};
use serde::Serialize;
use std::time::Instant;

/// Options of `clipbench growing`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Four patches instead of twelve (well under a minute in a release build).
    #[arg(long)]
    quick: bool,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Tiles rebuilt per tick, between patches (a service's per-tick bound).
    #[arg(long, default_value_t = 64)]
    per_tick: usize,
    /// Patch width and height in pixels (tiny sizes are for tests only).
    #[arg(long, hide = true, num_args = 2, value_names = ["W", "H"], default_values_t = [4000u32, 3000])]
    patch_size: Vec<u32>,
}

/// One tile size's run.
#[derive(Debug, Serialize)]
pub struct Run {
    pub tile: u64,
    pub tiles_rebuilt: usize,
    pub level0_tiles: usize,
    pub levels: u32,
    pub seconds: f64,
    /// CPU seconds of the whole process over the run (all threads).
    pub cpu_seconds: f64,
    pub tiles_per_s: f64,
    /// Tiles per CPU second: what one core does, whatever else the machine runs.
    pub tiles_per_cpu_s: f64,
    /// Level-0 texels written per second (the painting rate).
    pub mtexels_per_s: f64,
    /// Against the flexible-clipmap paper's 2011 figure for this tile size.
    pub vs_paper: f64,
}

/// The run with the store on disk.
#[derive(Debug, Serialize)]
pub struct Stored {
    pub tile: u64,
    pub tiles_rebuilt: usize,
    pub seconds: f64,
    pub cpu_seconds: f64,
    pub tiles_per_s: f64,
}

/// The whole report.
#[derive(Debug, Serialize)]
pub struct Report {
    pub patches: usize,
    pub patch_width: u32,
    pub patch_height: u32,
    pub jpeg_bytes: u64,
    pub texel_bytes: u64,
    pub decode_seconds: f64,
    /// Decoded texel megabytes (10^6) per second, one thread.
    pub decode_mb_per_s: f64,
    pub tiles_per_s_256: f64,
    pub tiles_per_s_512: f64,
    /// Texel megabytes per second through decode and rebuild at 256² tiles, end to end.
    pub ingest_mb_per_s: f64,
    pub runs: Vec<Run>,
    /// 256² tiles with the store on disk (patches synced, tiles written).
    pub stored: Stored,
    pub paper_tiles_per_s_256: f64,
    pub paper_tiles_per_s_512: f64,
    pub goal_vs_paper: f64,
    pub per_tick: usize,
    pub threads: usize,
    /// One-minute load average when the run started (another build skews every figure).
    pub load_start: f64,
}

/// Runs the benchmark and prints it.
pub fn main(args: Args) -> u8 {
    match run(&args) {
        Ok(r) => {
            clipmap::report::emit(args.json, &r, print_table);
            0
        }
        Err(e) => {
            eprintln!("clipbench growing: {e:#}");
            2
        }
    }
}

/// Pixel (x, y) of survey image `n`: smooth gradients, a per-image tint and a little noise, so the
/// JPEG is of a realistic size and overlaps are visibly resolved.
fn pixel(n: u32, x: u32, y: u32) -> [u8; 3] {
    let h = (x.wrapping_mul(0x9E37_79B1) ^ y.wrapping_mul(0x85EB_CA77) ^ n.wrapping_mul(0xC2B2_AE3D)) >> 27;
    [
        ((x / 16 + n * 40) % 256) as u8 ^ h as u8,
        ((y / 12 + n * 70) % 256) as u8,
        (((x + y) / 24 + n * 90) % 256) as u8 ^ (h as u8 >> 1),
    ]
}

fn run(args: &Args) -> anyhow::Result<Report> {
    let load_start = std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|l| l.split_whitespace().next().and_then(|v| v.parse().ok()))
        .unwrap_or(f64::NAN);
    let (w, h) = (args.patch_size[0], args.patch_size[1]);
    let (cols, rows) = if args.quick { (2u32, 2u32) } else { (4, 3) };
    // A quarter overlap each way, starting left of and below the origin.
    let (step_x, step_y) = (w as f64 * 0.75, h as f64 * 0.75);
    let (x0, y0) = (-(w as f64) * 1.5, -(h as f64) * 0.75);
    let mut jpegs = Vec::new();
    for n in 0..cols * rows {
        let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb(pixel(n, x, y)));
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
            .encode_image(&img)
            .context("encoding a survey image as JPEG")?;
        let (c, r) = (n % cols, n / cols);
        let bbox = WorldBox {
            min: [x0 + c as f64 * step_x, y0 + r as f64 * step_y],
            max: [x0 + c as f64 * step_x + w as f64, y0 + r as f64 * step_y + h as f64],
        };
        jpegs.push((PatchMeta { id: n as u64, bbox, time: n as u64, rating: (n % 3) as f64 }, out));
    }
    let grid_for = |tile| Grid::new([0.0, 0.0], 1.0, tile, 3, 1).context("the benchmark's grid");
    let g256 = grid_for(256)?;
    let started = Instant::now();
    let mut decoded = Vec::new();
    for (meta, bytes) in &jpegs {
        let (pw, ph, texels) = decode_image(&g256, bytes, u64::MAX, "survey image").context("decoding")?;
        decoded.push((*meta, pw, ph, texels));
    }
    let decode_seconds = started.elapsed().as_secs_f64();
    let texel_bytes: u64 = decoded.iter().map(|d| d.3.len() as u64).sum();
    let mut runs = Vec::new();
    for tile in [256u64, 512] {
        let grid = grid_for(tile)?;
        let patches: Vec<Patch> = decoded
            .iter()
            .map(|(m, pw, ph, t)| Patch::new(&grid, *m, *pw, *ph, t.clone()))
            .collect::<Result<_, _>>()
            .context("a survey patch")?;
        let mut index = PatchIndex::new();
        let mut rb = Rebuilder::new(grid);
        let (mut tiles, mut level0) = (0, 0);
        let mut count = |done: &[(u32, i64, i64)]| {
            tiles += done.len();
            level0 += done.iter().filter(|k| k.0 == 0).count();
        };
        let (started, cpu0) = (Instant::now(), crate::perf::proc_self().cpu_s);
        for p in patches {
            let p = index.insert(p);
            rb.patch_added(&index, &p);
            count(&rb.step(&index, args.per_tick));
        }
        while rb.pending() > 0 {
            count(&rb.step(&index, args.per_tick));
        }
        let seconds = started.elapsed().as_secs_f64();
        let cpu_seconds = crate::perf::proc_self().cpu_s - cpu0;
        let paper = if tile == 256 { 428.0 } else { 151.0 };
        let tiles_per_s = tiles as f64 / seconds;
        runs.push(Run {
            tile,
            tiles_rebuilt: tiles,
            level0_tiles: level0,
            levels: rb.levels(),
            seconds,
            cpu_seconds,
            tiles_per_s,
            tiles_per_cpu_s: tiles as f64 / cpu_seconds.max(0.01),
            mtexels_per_s: (level0 as f64 * (tile * tile) as f64) / seconds / 1e6,
            vs_paper: tiles_per_s / paper,
        });
    }
    // The same at 256² with the store on disk, as `cliptex grow` keeps it: each patch synced
    // before it counts, every changed tile written, a checkpoint at the end.
    let stored = {
        let dir = std::env::temp_dir().join(format!("clipbench-growing-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut g = Growing::create(&dir, [0.0, 0.0], 1.0, 256, "rgb8").context("the store")?;
        let news: Vec<NewPatch> = decoded
            .iter()
            .zip(&jpegs)
            .map(|((m, pw, ph, t), (_, jpeg))| NewPatch {
                patch: Patch {
                    id: 0,
                    bbox: m.bbox,
                    time: m.time,
                    rating: m.rating,
                    width: *pw,
                    height: *ph,
                    texels: t.clone(),
                },
                encoded: Some(jpeg.clone()),
            })
            .collect();
        let (started, cpu0) = (Instant::now(), crate::perf::proc_self().cpu_s);
        let mut tiles = 0;
        for p in news {
            g.add(p).context("adding a patch")?;
            tiles += g.step(args.per_tick).context("a rebuild step")?.len();
        }
        tiles += g.finish(args.per_tick).context("the rebuild")?;
        let seconds = started.elapsed().as_secs_f64();
        let cpu_seconds = crate::perf::proc_self().cpu_s - cpu0;
        drop(g);
        let _ = std::fs::remove_dir_all(&dir);
        Stored { tile: 256, tiles_rebuilt: tiles, seconds, cpu_seconds, tiles_per_s: tiles as f64 / seconds }
    };
    let end_to_end = decode_seconds + runs[0].seconds;
    Ok(Report {
        patches: jpegs.len(),
        patch_width: w,
        patch_height: h,
        jpeg_bytes: jpegs.iter().map(|j| j.1.len() as u64).sum(),
        texel_bytes,
        decode_seconds,
        decode_mb_per_s: texel_bytes as f64 / decode_seconds / 1e6,
        tiles_per_s_256: runs[0].tiles_per_s,
        tiles_per_s_512: runs[1].tiles_per_s,
        ingest_mb_per_s: texel_bytes as f64 / end_to_end / 1e6,
        runs,
        stored,
        paper_tiles_per_s_256: 428.0,
        paper_tiles_per_s_512: 151.0,
        goal_vs_paper: 10.0,
        per_tick: args.per_tick,
        threads: rayon::current_num_threads(),
        load_start,
    })
}

fn print_table(r: &Report) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "{} patches of {}x{} RGB ({:.1} MB of JPEG, {:.1} MB of texels); decode {:.1} MB/s ({:.2} s, one thread)",
        r.patches,
        r.patch_width,
        r.patch_height,
        r.jpeg_bytes as f64 / 1e6,
        r.texel_bytes as f64 / 1e6,
        r.decode_mb_per_s,
        r.decode_seconds
    );
    let _ = writeln!(
        o,
        "{:>6} {:>9} {:>8} {:>7} {:>9} {:>9} {:>11} {:>11} {:>10} {:>9}",
        "tile", "rebuilt", "level 0", "levels", "seconds", "CPU s", "tiles/s", "tiles/CPU s", "Mtexel/s", "x paper"
    );
    for run in &r.runs {
        let _ = writeln!(
            o,
            "{:>6} {:>9} {:>8} {:>7} {:>9.3} {:>9.2} {:>11.0} {:>11.0} {:>10.0} {:>9.1}",
            run.tile,
            run.tiles_rebuilt,
            run.level0_tiles,
            run.levels,
            run.seconds,
            run.cpu_seconds,
            run.tiles_per_s,
            run.tiles_per_cpu_s,
            run.mtexels_per_s,
            run.vs_paper
        );
    }
    let s = &r.stored;
    let _ = writeln!(
        o,
        "with the store on disk ({}² tiles): {} rebuilt in {:.3} s ({:.2} CPU s), {:.0} tiles/s",
        s.tile, s.tiles_rebuilt, s.seconds, s.cpu_seconds, s.tiles_per_s
    );
    let _ = writeln!(
        o,
        "ingest (decode, then rebuild at 256² tiles): {:.1} MB/s of texels; goal: {}x the paper's tile rates",
        r.ingest_mb_per_s, r.goal_vs_paper
    );
    o
}
