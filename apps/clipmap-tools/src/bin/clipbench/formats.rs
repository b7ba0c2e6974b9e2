//! `clipbench formats`: what each texel format of the image caches costs and buys, on a
//! photograph no one here made (matplotlib's `grace_hopper.jpg`, shipped on PyPI and in
//! Debian's `python-matplotlib-data`, unless `--image` names another): per format (`rgba8`,
//! `bc7`, `bc1`, `bc4` on the photograph's luminance, `bc5` on its red and green), the PSNR of the
//! decoded blocks (`bcdec_rs`, not the encoder) against the uncompressed texels, the bytes of a
//! tile, the encoding time of a tile on one thread, the engine's tile ingest over a prepared RGBA8
//! pyramid of the photograph encoded at run time, and the image caches' and a renderer's upload
//! bytes against RGBA8's. Beside them, in the same run: BC1 encoding against `texpresso`'s on the
//! same tiles, and ingest with BC1 encoding against ingest without.

use crate::formats_flight;
use anyhow::{anyhow, Context, Result};
use clipmap::clip::{Clipmap, Settings};
use clipmap::limits::Limits;
use clipmap::plan;
use clipmap::prep::{self, Filter, Job, Layout, Spec};
use clipmap::source::{encode_padded, encoder_input};
use clipmap::source::{BcQuality, BcSource, SourceError, TextureDesc, TileId, TileSource};
use clipmap::texel::{Bc, TexelFormat};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// Options of `clipbench formats`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A smaller ingest texture (2048 a side rather than 4096) and shorter timings.
    #[arg(long)]
    quick: bool,
    /// One JSON object on standard output.
    #[arg(long)]
    json: bool,
    /// The photograph (any PNG, JPEG, TIFF or WebP); default: matplotlib's `grace_hopper.jpg`
    /// where Debian's python-matplotlib-data (or PyPI's matplotlib) is installed.
    #[arg(long, value_name = "IMAGE")]
    image: Option<PathBuf>,
    /// BC7's encoder setting (fast, normal, slow), as `clipmapd --bc-quality`.
    #[arg(long, default_value = "normal")]
    bc_quality: String,
    /// Where the prepared pyramid is written (a temporary directory under it, removed at the end).
    #[arg(long)]
    dir: Option<PathBuf>,
    /// The ingest texture's side (a power of two from 1024; for the tests).
    #[arg(long, hide = true, value_name = "N")]
    texture: Option<u64>,
    /// Also writes the study's format axis as an SVG chart (PSNR against bytes a tile) to FILE
    /// (docs/accuracy/formats.svg is one).
    #[arg(long, value_name = "FILE")]
    plot: Option<PathBuf>,
    /// Skips the 2^26 real-time flight (for the tests).
    #[arg(long, hide = true)]
    no_flight: bool,
}

/// Tile size of the measured tiles and the prepared pyramid.
const TILE: u64 = 128;

/// The measured image.
#[derive(Clone, Debug, Serialize)]
pub struct Imagery {
    /// The file, when a photograph was found.
    pub path: Option<PathBuf>,
    /// Where it comes from (or why there is none).
    pub source: String,
    /// Whether it is a photograph from outside this project (else the procedural terrain).
    pub photograph: bool,
    /// The measured crop, texels.
    pub size: [u64; 2],
    pub tiles: usize,
}

/// One format's figures.
#[derive(Clone, Debug, Serialize)]
pub struct FormatRow {
    pub format: &'static str,
    /// What the PSNR compares: the decoded texels against these channels of the source.
    pub channels: &'static str,
    /// PSNR of the decoded tiles against the uncompressed ones at level 0, dB (`None`: lossless).
    pub psnr_db: Option<f64>,
    /// Bytes of one 128 x 128 tile in the image caches.
    pub tile_bytes: u64,
    /// One thread, the service's path: conversion to the encoder's input (`bc4`, `bc5`) and encoding.
    pub encode_us_per_tile: f64,
    /// Encoding rate on one thread, megatexels a second (`None` for `rgba8`).
    pub encode_mpx_per_s: Option<f64>,
    /// Engine ingest of the prepared RGBA8 pyramid, encoded to this format at read time
    /// (median of the runs), tiles a second.
    pub tiles_per_s_ingest: f64,
    /// The image caches of the ingest's clipmap (levels whose tiles are whole blocks) against
    /// RGBA8's.
    pub mapping_bytes_vs_rgba8: f64,
    /// The whole image caches, the pyramid's 2 x 2 and 1 x 1 tops included (one block each).
    pub mapping_bytes: u64,
    /// A renderer that mirrors the caches uploads every ingested tile once: bytes a jump of the
    /// ingest flight.
    pub upload_bytes_per_frame: f64,
    pub upload_bytes_per_frame_vs_rgba8: f64,
}

/// BC1 encoding against texpresso's.
#[derive(Clone, Debug, Serialize)]
pub struct Texpresso {
    /// intel_tex_2's BC1 on one thread, megatexels a second.
    pub ours_mpx_per_s: f64,
    /// texpresso's BC1 (range fit, its fastest) on one thread, same tiles.
    pub texpresso_mpx_per_s: f64,
    pub ratio: f64,
    pub texpresso_psnr_db: f64,
    /// The goal: at least 2.
    pub goal: f64,
}

/// Ingest with BC1 encoding against without.
#[derive(Clone, Debug, Serialize)]
pub struct IngestComparison {
    pub texture: u64,
    pub clip: u64,
    pub tile: u64,
    pub runs: usize,
    pub jumps_per_run: usize,
    pub tiles_per_run: u64,
    pub rgba8_tiles_per_s: f64,
    pub bc1_encoded_tiles_per_s: f64,
    /// BC1 encoded at run time / RGBA8 (goal at least 0.5).
    pub bc1_encoded_vs_rgba8: f64,
    /// Where the time goes: wall time a tile of the ingest (reads run on every core), RGBA8 and
    /// BC1 encoded at run time, and BC1's encoding of a tile on one thread.
    pub rgba8_us_per_tile: f64,
    pub bc1_encoded_us_per_tile: f64,
    pub bc1_encode_us_per_tile: f64,
    /// CPU time a tile of the ingest, every thread of the process (over all runs): RGBA8, and
    /// BC1 encoded at run time...
    pub rgba8_cpu_us_per_tile: f64,
    pub bc1_encoded_cpu_us_per_tile: f64,
    /// ...and their ratio: what `bc1_encoded_vs_rgba8` is where the reads keep every core
    /// equally busy either way (the encoding then costs its CPU time in full).
    pub bc1_encoded_vs_rgba8_cpu: f64,
    /// The same photograph prepared pre-encoded to BC1 (as `clipprep --format bc1` writes it),
    /// read as it is: tiles a second.
    pub bc1_pre_encoded_tiles_per_s: f64,
    /// That / RGBA8 (goal at least 1).
    pub bc1_pre_encoded_vs_rgba8: f64,
}

/// One goal: its figure (`None`: not measured in this run), the bound and whether it is met.
#[derive(Clone, Debug, Serialize)]
pub struct Goal {
    pub figure: Option<f64>,
    /// `at least` or `exactly`.
    pub goal: &'static str,
    pub of: f64,
    pub met: Option<bool>,
}

/// What `clipbench formats` prints.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub image: Imagery,
    pub bc7_quality: BcQuality,
    pub formats: Vec<FormatRow>,
    /// `None` in a build without the `texpresso` feature (on by default).
    pub bc1_vs_texpresso: Option<Texpresso>,
    pub ingest: IngestComparison,
    /// The accuracy study's format axis over the same prepared pyramid
    /// (`clipmap::accuracy::formats`): level-0 and rendered-view PSNR, bytes, encoding time,
    /// image caches and upload bytes a frame of the study's flight.
    pub view: Vec<clipmap::accuracy::formats::FormatRow>,
    /// The flight and camera of `view` (the study's case), its `source` `"image"`: the view
    /// renders the pyramid prepared from `image`, not one of the study's procedural textures.
    pub view_case: serde_json::Value,
    /// `clipbench perf`'s 2^26 flight with every default over a pre-encoded BC1 texture (`None`
    /// with `--no-flight`).
    pub flight: Option<formats_flight::Flight>,
    /// The same flight over the same tiles in RGBA8, in the same run.
    pub flight_rgba8: Option<formats_flight::Flight>,
    /// The goals: each one's figure, its bound and whether it is met.
    pub goals: std::collections::BTreeMap<&'static str, Goal>,
    /// Debug builds' timings are not representative.
    pub build: &'static str,
    /// The machine's load average (1, 5, 15 minutes) at the start and at the end of the run, and
    /// its cores.
    pub load_average: [String; 2],
    pub cpus: usize,
}

/// matplotlib's data directory, asked of the Python that has it, and Debian's package's.
fn find_photograph() -> Result<(PathBuf, String), String> {
    let mut tried = Vec::new();
    let asked = Command::new("python3")
        .args(["-c", "import matplotlib, os; print(os.path.join(matplotlib.get_data_path(), 'sample_data'))"])
        .output();
    let mut dirs = Vec::new();
    if let Ok(out) = asked {
        if out.status.success() {
            dirs.push(PathBuf::from(String::from_utf8_lossy(&out.stdout).trim()));
        }
    }
    dirs.push(PathBuf::from("/usr/share/matplotlib/mpl-data/sample_data"));
    for d in dirs {
        let p = d.join("grace_hopper.jpg");
        if p.is_file() {
            return Ok((p, "matplotlib's sample data (Debian's python-matplotlib-data, or PyPI's matplotlib)".into()));
        }
        tried.push(p.display().to_string());
    }
    Err(format!("no grace_hopper.jpg at {} (apt-get install python-matplotlib-data, or pip install matplotlib, or pass --image)", tried.join(" or ")))
}

/// The measured texels: RGBA8, a whole number of tiles a side.
struct Picture {
    rgba: Vec<u8>,
    w: u64,
    h: u64,
}

impl Picture {
    /// Tile (i, j) of the picture, RGBA8 rows.
    fn tile(&self, i: u64, j: u64) -> Vec<u8> {
        let mut out = Vec::with_capacity((TILE * TILE * 4) as usize);
        for y in j * TILE..(j + 1) * TILE {
            let at = ((y * self.w + i * TILE) * 4) as usize;
            out.extend_from_slice(&self.rgba[at..at + (TILE * 4) as usize]);
        }
        out
    }

    fn tiles(&self) -> Vec<Vec<u8>> {
        (0..self.h / TILE).flat_map(|j| (0..self.w / TILE).map(move |i| (i, j))).map(|(i, j)| self.tile(i, j)).collect()
    }
}

/// The photograph (or, failing that, the procedural terrain), cropped about its centre to whole
/// tiles.
fn load(args: &Args) -> Result<(Picture, Imagery)> {
    let found = match &args.image {
        Some(p) => Ok((p.clone(), "--image".to_string())),
        None => find_photograph(),
    };
    let (img, path, source, photograph) = match found {
        Ok((p, source)) => {
            let img = image::open(&p).with_context(|| format!("reading the photograph {}", p.display()))?.to_rgba8();
            (img, Some(p), source, true)
        }
        Err(why) => {
            // The procedural terrain, level 0, 512 x 512: made here, so said so.
            let src = clipmap_service::procedural_source(clipmap_service::Procedural::Terrain, 4096, 512, TILE)
                .map_err(|e| anyhow!("the procedural fallback: {e}"))?;
            let mut img = image::RgbaImage::new(512, 512);
            let mut buf = vec![0u8; src.desc().tile_bytes(0)];
            for j in 0..4u64 {
                for i in 0..4u64 {
                    src.read_tile(TileId::new(0, 8 + i, 8 + j), &mut buf).map_err(|e| anyhow!("{e}"))?;
                    let f = src.desc().format();
                    for (n, px) in buf.chunks_exact(f.bytes_per_texel() as usize).enumerate() {
                        let (x, y) = (i * TILE + n as u64 % TILE, j * TILE + n as u64 / TILE);
                        let d = f.decode(px);
                        let c = |v: f32| (v * 255.0).round() as u8;
                        img.put_pixel(x as u32, y as u32, image::Rgba([c(d[0]), c(d[1]), c(d[2]), 255]));
                    }
                }
            }
            (img, None, format!("the procedural terrain, made here ({why})"), false)
        }
    };
    let (w, h) = (img.width() as u64 / TILE * TILE, img.height() as u64 / TILE * TILE);
    if w == 0 || h == 0 {
        return Err(anyhow!("{}x{} image: expected at least {TILE} texels a side", img.width(), img.height()));
    }
    let (x0, y0) = ((img.width() as u64 - w) / 2, (img.height() as u64 - h) / 2);
    let crop = image::imageops::crop_imm(&img, x0 as u32, y0 as u32, w as u32, h as u32).to_image();
    let pic = Picture { rgba: crop.into_raw(), w, h };
    let tiles = ((w / TILE) * (h / TILE)) as usize;
    Ok((pic, Imagery { path, source, photograph, size: [w, h], tiles }))
}

/// PSNR over `n` channels: `a` has `na` bytes a texel, `b` `nb`.
fn psnr(a: &[u8], na: usize, b: &[u8], nb: usize, n: usize) -> f64 {
    let (mut se, mut count) = (0f64, 0u64);
    for (p, q) in a.chunks_exact(na).zip(b.chunks_exact(nb)) {
        for c in 0..n {
            let d = p[c] as f64 - q[c] as f64;
            se += d * d;
        }
        count += n as u64;
    }
    let mse = se / count.max(1) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// The service's path for one tile: the encoder's input (when the RGBA8 tile is not it) and the
/// blocks.
fn encode(bc: Bc, quality: BcQuality, tile: &[u8], input: &mut Vec<u8>, out: &mut [u8]) {
    if matches!(bc, Bc::Bc1 | Bc::Bc7) {
        encode_padded(bc, quality, false, tile, TILE, TILE, out);
    } else {
        encoder_input(bc, TexelFormat::RGBA8, tile, TILE, TILE, input).expect("RGBA8 converts");
        encode_padded(bc, quality, false, input, TILE, TILE, out);
    }
}

/// Runs `f` over the tiles on this thread, whole passes, until `secs` have gone by; seconds a tile.
fn time_tiles(tiles: &[Vec<u8>], secs: f64, mut f: impl FnMut(&[u8])) -> f64 {
    let t = Instant::now();
    let mut n = 0u64;
    while n == 0 || t.elapsed().as_secs_f64() < secs {
        for tile in tiles {
            f(tile);
            n += 1;
        }
    }
    t.elapsed().as_secs_f64() / n as f64
}

/// A source that counts the tiles read.
struct Counting {
    inner: Arc<dyn TileSource>,
    reads: AtomicU64,
}

impl TileSource for Counting {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.inner.read_tile(tile, out)?;
        self.reads.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }
}

/// One ingest run: seconds of the flight, tiles read, the image caches' bytes (level 0's, all),
/// and the CPU seconds of every thread of the process meanwhile (the clipmap's read threads
/// outlive the run's end, so their time is in).
fn ingest_run(source: Arc<dyn TileSource>, centres: &[[i64; 2]]) -> Result<(f64, u64, u64, u64, f64)> {
    let counting = Arc::new(Counting { inner: source, reads: AtomicU64::new(0) });
    let mut settings = Settings { budget_ns: None, ..Settings::default() };
    settings.limits.max_pending_reads = 4096;
    settings.limits.max_ready_reads = 4096;
    let mut map = Clipmap::new(Arc::clone(&counting) as Arc<dyn TileSource>, settings)?;
    let (t, cpu) = (Instant::now(), crate::perf::cpu_ns());
    for &c in centres {
        map.tick(c, Some([0, 0]));
        map.wait_for_reads();
    }
    map.tick(*centres.last().expect("a jump"), Some([0, 0]));
    let secs = t.elapsed().as_secs_f64();
    let cpu_s = crate::perf::cpu_ns().saturating_sub(cpu) as f64 / 1e9;
    let p = map.memory().placement();
    let level0 = p.levels[0].slot_bytes * p.levels[0].slot_count;
    Ok((secs, counting.reads.load(Ordering::Relaxed), level0, p.slot_bytes(), cpu_s))
}

/// A scratch directory, removed with what is in it when dropped (on errors too).
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Writes the photograph mirrored out to `n` x `n` (so the repeats meet without seams) as a PNG
/// under `dir`.
fn write_png(pic: &Picture, n: u64, dir: &Path) -> Result<PathBuf> {
    let fold = |x: u64, side: u64| {
        let k = x % (2 * side);
        if k < side {
            k
        } else {
            2 * side - 1 - k
        }
    };
    let mut big = image::RgbaImage::new(n as u32, n as u32);
    for y in 0..n {
        let sy = fold(y, pic.h);
        for x in 0..n {
            let at = ((sy * pic.w + fold(x, pic.w)) * 4) as usize;
            big.put_pixel(x as u32, y as u32, image::Rgba([pic.rgba[at], pic.rgba[at + 1], pic.rgba[at + 2], 255]));
        }
    }
    let png = dir.join("photo.png");
    big.save(&png).with_context(|| format!("writing {}", png.display()))?;
    Ok(png)
}

/// Prepares the PNG's pyramid in `format` under `dir/name` (tiles of [`TILE`], clip `clip`),
/// pre-encoded to `blocks` when given (as `clipprep --format bc1` does), and opens it.
fn prepare_pyramid(
    png: &Path,
    n: u64,
    clip: u64,
    format: TexelFormat,
    blocks: Option<(Bc, BcQuality)>,
    dir: &Path,
    name: &str,
) -> Result<Arc<dyn TileSource>> {
    let mut layout = Layout::new(Spec {
        width: n,
        height: n,
        clip,
        tile: TILE,
        format,
        tiles_in_file: (1, 1),
        header_bytes: 0,
        streams: None,
        inset: None,
        compression: None,
    })?;
    if let Some((bc, quality)) = blocks {
        layout = layout.with_blocks(bc, quality)?;
    }
    let opened = prep::source::open_image(png, &prep::Limits::default())?;
    let root = dir.join(name);
    let job = Job {
        layout,
        source: prep::Source::Image(opened),
        filter: Filter::Box,
        linear_light: false,
        name: name.into(),
        description: vec!["clipbench formats".into()],
        limits: prep::Limits::default(),
    };
    let summary = prep::run(job, &root, &AtomicBool::new(false), dir, &|_| {})
        .with_context(|| format!("preparing the {name} pyramid"))?;
    let ct = root.join(&summary.ct);
    let loaded = clipmap::source::configured::load_clip_texture(&ct, &plan::Options::default())?;
    let rendered = loaded.render();
    let plan = loaded.plan.with_context(|| format!("{}: {rendered}", ct.display()))?;
    Ok(clipmap::source::open_plan(plan, &Limits::default())?)
}

/// Centres of level 0 two clip sizes apart (no level-0 tile shared between jumps).
fn jumps(n: u64, clip: u64) -> Vec<[i64; 2]> {
    let step = (2 * clip) as i64;
    let along: Vec<i64> = (0..).map(|i| (clip / 2) as i64 + i * step).take_while(|&c| c < n as i64).collect();
    along
        .iter()
        .enumerate()
        .flat_map(|(row, &t)| {
            let mut cols = along.clone();
            if row % 2 == 1 {
                cols.reverse();
            }
            cols.into_iter().map(move |s| [s, t])
        })
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

const FORMATS: [(&str, Option<Bc>, &str); 5] = [
    ("rgba8", None, "rgb"),
    ("bc7", Some(Bc::Bc7), "rgb"),
    ("bc1", Some(Bc::Bc1), "rgb"),
    ("bc4", Some(Bc::Bc4), "luminance (Rec. 709)"),
    ("bc5", Some(Bc::Bc5), "red, green"),
];

/// texpresso's BC1 (range fit, its fastest) on `tiles`, one thread: megatexels a second and PSNR
/// (decoded with bcdec_rs) over RGB.
#[cfg(feature = "texpresso")]
fn texpresso_bc1(tiles: &[Vec<u8>], secs: f64) -> Result<Option<(f64, f64)>> {
    let t = TILE as usize;
    let mut out = vec![0u8; texpresso::Format::Bc1.compressed_size(t, t)];
    let params = texpresso::Params { algorithm: texpresso::Algorithm::RangeFit, ..Default::default() };
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for tile in tiles {
        texpresso::Format::Bc1.compress(tile, t, t, params, &mut out);
        a.extend_from_slice(tile);
        b.extend(clipmap::shm::blocks::decode(Bc::Bc1, &out, TILE, TILE).map_err(|e| anyhow!(e))?);
    }
    let p = psnr(&a, 4, &b, 4, 3);
    let s = time_tiles(tiles, secs, |tile| texpresso::Format::Bc1.compress(tile, t, t, params, &mut out));
    Ok(Some(((TILE * TILE) as f64 / s / 1e6, p)))
}

#[cfg(not(feature = "texpresso"))]
fn texpresso_bc1(_: &[Vec<u8>], _: f64) -> Result<Option<(f64, f64)>> {
    Ok(None)
}

/// The first three fields of /proc/loadavg ("" where there is none).
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default()
}

/// Measures everything.
pub fn run(args: &Args) -> Result<Report> {
    let load_start = load_average();
    let quality = BcQuality::parse(&args.bc_quality).map_err(|e| anyhow!("--bc-quality: {e}"))?;
    let (pic, imagery) = load(args)?;
    let tiles = pic.tiles();
    let secs = if args.quick { 0.3 } else { 1.5 };
    let tile_px = (TILE * TILE) as f64;
    // The ingest texture.
    let (n, clip, runs) = if args.quick { (2048, 512, 3) } else { (4096, 512, 5) };
    let n = args.texture.unwrap_or(n);
    if n < 1024 || !n.is_power_of_two() {
        return Err(anyhow!("--texture {n}: expected a power of two from 1024"));
    }
    let parent = args.dir.clone().unwrap_or_else(std::env::temp_dir);
    let scratch = Scratch(parent.join(format!("clipbench-formats-{}", std::process::id())));
    std::fs::create_dir_all(&scratch.0).with_context(|| format!("making {}", scratch.0.display()))?;
    let png = write_png(&pic, n, &scratch.0)?;
    let pyramid = prepare_pyramid(&png, n, clip, TexelFormat::RGBA8, None, &scratch.0, "rgba8")?;
    let pre_encoded = prepare_pyramid(&png, n, clip, TexelFormat::RGB8, Some((Bc::Bc1, quality)), &scratch.0, "bc1")?;
    let centres = jumps(n, clip);

    // Level 0's tiles of the photograph: PSNR (decoded with bcdec_rs against the encoder's
    // input's channels) and the encoding time on one thread.
    let mut measured = Vec::new();
    for (_, bc, _) in FORMATS {
        let mut input = Vec::new();
        measured.push(match bc {
            None => (None, TILE * TILE * 4, 0.0),
            Some(bc) => {
                let bytes = (TILE / 4) * (TILE / 4) * u64::from(bc.block_bytes());
                let mut out = vec![0u8; bytes as usize];
                let (mut a, mut b) = (Vec::new(), Vec::new());
                for t in &tiles {
                    encode(bc, quality, t, &mut input, &mut out);
                    b.extend(clipmap::shm::blocks::decode(bc, &out, TILE, TILE).map_err(|e| anyhow!(e))?);
                    match bc {
                        Bc::Bc1 | Bc::Bc7 => a.extend_from_slice(t),
                        _ => a.extend_from_slice(&input),
                    }
                }
                let (stride, n) = match bc {
                    Bc::Bc1 | Bc::Bc7 => (4, 3),
                    Bc::Bc4 => (1, 1),
                    Bc::Bc5 => (2, 2),
                };
                let p = psnr(&a, stride, &b, stride, n);
                let s = time_tiles(&tiles, secs, |t| encode(bc, quality, t, &mut input, &mut out));
                (Some(p), bytes, s)
            }
        });
    }

    // Engine ingest: every format's source (and the pre-encoded BC1 pyramid, last) once a round,
    // the rounds one after the other, so a change of the machine's load falls on all of them.
    let mut sources: Vec<Arc<dyn TileSource>> = Vec::new();
    for (_, bc, _) in FORMATS {
        sources.push(match bc {
            None => pyramid.clone(),
            Some(bc) => Arc::new(BcSource::new(pyramid.clone(), bc, quality)?),
        });
    }
    sources.push(pre_encoded);
    let mut rates = vec![Vec::new(); sources.len()];
    let mut caches = vec![(0u64, 0u64, 0u64); sources.len()];
    // CPU seconds and tiles over all runs, per source.
    let mut cpu = vec![(0.0, 0u64); sources.len()];
    for _ in 0..runs {
        for (k, source) in sources.iter().enumerate() {
            let (s, read, level0, all, cpu_s) = ingest_run(source.clone(), &centres)?;
            rates[k].push(read as f64 / s);
            caches[k] = (level0, all, read);
            cpu[k].0 += cpu_s;
            cpu[k].1 += read;
        }
    }
    let cpu_us = |f: &str| {
        let k = FORMATS.iter().position(|(name, _, _)| *name == f).expect("a measured format");
        cpu[k].0 * 1e6 / cpu[k].1.max(1) as f64
    };
    let rates: Vec<f64> = rates.into_iter().map(median).collect();
    let (base_level0, _, tiles_per_run) = caches[0];
    let base_upload = (tiles_per_run * TILE * TILE * 4) as f64 / centres.len() as f64;
    let mut rows: Vec<FormatRow> = Vec::new();
    for (k, ((name, bc, channels), (psnr_db, tile_bytes, encode_s))) in FORMATS.into_iter().zip(measured).enumerate() {
        let (level0, all, read) = caches[k];
        let upload = (read * tile_bytes) as f64 / centres.len() as f64;
        rows.push(FormatRow {
            format: name,
            channels,
            psnr_db: psnr_db.filter(|p| p.is_finite()),
            tile_bytes,
            encode_us_per_tile: encode_s * 1e6,
            encode_mpx_per_s: bc.map(|_| tile_px / encode_s / 1e6),
            tiles_per_s_ingest: rates[k],
            mapping_bytes_vs_rgba8: level0 as f64 / base_level0 as f64,
            mapping_bytes: all,
            upload_bytes_per_frame: upload,
            upload_bytes_per_frame_vs_rgba8: upload / base_upload,
        });
    }

    // texpresso's BC1 on the same tiles, one thread.
    let bc1 = rows.iter().find(|r| r.format == "bc1").expect("bc1 measured");
    let ours = bc1.encode_mpx_per_s.unwrap_or(0.0);
    let tex = texpresso_bc1(&tiles, secs)?.map(|(theirs, texpresso_psnr_db)| Texpresso {
        ours_mpx_per_s: ours,
        texpresso_mpx_per_s: theirs,
        ratio: ours / theirs,
        texpresso_psnr_db,
        goal: 2.0,
    });

    let rate = |f: &str| rows.iter().find(|r| r.format == f).map(|r| r.tiles_per_s_ingest).unwrap_or(0.0);
    let pre = *rates.last().expect("the pre-encoded pyramid measured");
    let ingest = IngestComparison {
        texture: n,
        clip,
        tile: TILE,
        runs,
        jumps_per_run: centres.len(),
        tiles_per_run,
        rgba8_tiles_per_s: rate("rgba8"),
        bc1_encoded_tiles_per_s: rate("bc1"),
        bc1_encoded_vs_rgba8: rate("bc1") / rate("rgba8"),
        rgba8_us_per_tile: 1e6 / rate("rgba8"),
        bc1_encoded_us_per_tile: 1e6 / rate("bc1"),
        bc1_encode_us_per_tile: rows.iter().find(|r| r.format == "bc1").map_or(0.0, |r| r.encode_us_per_tile),
        rgba8_cpu_us_per_tile: cpu_us("rgba8"),
        bc1_encoded_cpu_us_per_tile: cpu_us("bc1"),
        bc1_encoded_vs_rgba8_cpu: cpu_us("rgba8") / cpu_us("bc1").max(1e-9),
        bc1_pre_encoded_tiles_per_s: pre,
        bc1_pre_encoded_vs_rgba8: pre / rate("rgba8"),
    };
    let (flight, flight_rgba8) = if args.no_flight {
        (None, None)
    } else {
        let secs = if args.quick { 5.0 } else { 20.0 };
        (Some(formats_flight::fly(Some(Bc::Bc1), secs)?), Some(formats_flight::fly(None, secs)?))
    };
    // The study's format axis over the photograph's pyramid: its flight and camera.
    let mut case = clipmap::accuracy::study::Case::small();
    case.size = n;
    case.clip_size = clip;
    case.tile = TILE;
    case.frames = if args.quick { 6 } else { 24 };
    let view =
        clipmap::accuracy::formats::run(&case, pyramid.clone(), &clipmap::accuracy::formats::FORMATS, quality, 16)?;
    let psnr_of = |f: &str| rows.iter().find(|r| r.format == f).and_then(|r| r.psnr_db);
    let row = |f: &str| rows.iter().find(|r| r.format == f).expect("measured");
    let mut goals = std::collections::BTreeMap::new();
    let mut goal = |name: &'static str, figure: Option<f64>, at_least: f64, exactly: bool| {
        let met = figure.map(|x| if exactly { x == at_least } else { x >= at_least });
        goals.insert(name, Goal { figure, goal: if exactly { "exactly" } else { "at least" }, of: at_least, met });
    };
    goal("bc1_psnr_db", psnr_of("bc1"), 33.0, false);
    goal("bc7_psnr_db", psnr_of("bc7"), 42.0, false);
    goal("bc1_encode_vs_texpresso", tex.as_ref().map(|t| t.ratio), 2.0, false);
    goal("bc1_encoded_ingest_vs_rgba8", Some(ingest.bc1_encoded_vs_rgba8), 0.5, false);
    goal("bc1_pre_encoded_ingest_vs_rgba8", Some(ingest.bc1_pre_encoded_vs_rgba8), 1.0, false);
    goal("bc1_mapping_bytes_vs_rgba8", Some(row("bc1").mapping_bytes_vs_rgba8), 0.125, true);
    goal("bc1_upload_bytes_per_frame_vs_rgba8", Some(row("bc1").upload_bytes_per_frame_vs_rgba8), 0.125, true);
    goal("bc7_mapping_bytes_vs_rgba8", Some(row("bc7").mapping_bytes_vs_rgba8), 0.25, true);
    goal("bc7_upload_bytes_per_frame_vs_rgba8", Some(row("bc7").upload_bytes_per_frame_vs_rgba8), 0.25, true);
    goal("flight_2_26_bc1_level0_shown_share", flight.as_ref().map(|f| f.level0_shown_share), 0.99, false);
    Ok(Report {
        image: imagery,
        bc7_quality: quality,
        formats: rows,
        bc1_vs_texpresso: tex,
        ingest,
        view,
        view_case: {
            let mut v = serde_json::to_value(&case)?;
            v["source"] = "image".into();
            v
        },
        flight,
        flight_rgba8,
        goals,
        load_average: [load_start, load_average()],
        cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
        build: if cfg!(debug_assertions) { "debug (timings not representative)" } else { "release" },
    })
}

fn human(r: &Report) -> String {
    let mut s = format!(
        "clipbench formats on {} ({}x{}, {} tiles of {TILE}; {})\n",
        r.image.path.as_ref().map(|p| p.display().to_string()).unwrap_or_else(|| "no photograph".into()),
        r.image.size[0],
        r.image.size[1],
        r.image.tiles,
        r.image.source
    );
    s += "format  PSNR dB  tile bytes  encode us/tile  Mpx/s  ingest tiles/s  mapping vs rgba8  upload vs rgba8\n";
    for f in &r.formats {
        s += &format!(
            "{:<7} {:>7} {:>11} {:>15.1} {:>6} {:>15.0} {:>17.4} {:>16.4}\n",
            f.format,
            f.psnr_db.map(|p| format!("{p:.2}")).unwrap_or_else(|| "-".into()),
            f.tile_bytes,
            f.encode_us_per_tile,
            f.encode_mpx_per_s.map(|m| format!("{m:.1}")).unwrap_or_else(|| "-".into()),
            f.tiles_per_s_ingest,
            f.mapping_bytes_vs_rgba8,
            f.upload_bytes_per_frame_vs_rgba8
        );
    }
    match &r.bc1_vs_texpresso {
        Some(t) => {
            s += &format!(
                "BC1 encoding: {:.1} Mpx/s against texpresso's {:.1} ({:.1}x; texpresso {:.2} dB)\n",
                t.ours_mpx_per_s, t.texpresso_mpx_per_s, t.ratio, t.texpresso_psnr_db
            )
        }
        None => s += "BC1 encoding against texpresso: not measured (built without the `texpresso` feature)\n",
    }
    s += "the study's format axis (clipmap::accuracy::formats) over the same pyramid:\n";
    s += &clipmap::accuracy::formats::table(&r.view);
    let i = &r.ingest;
    s += &format!(
        "ingest ({}^2, clip {}, {} tiles a run): RGBA8 {:.0} tiles/s, BC1 encoded at run time {:.0} ({:.2}x), BC1 pre-encoded {:.0} ({:.2}x)\n",
        i.texture,
        i.clip,
        i.tiles_per_run,
        i.rgba8_tiles_per_s,
        i.bc1_encoded_tiles_per_s,
        i.bc1_encoded_vs_rgba8,
        i.bc1_pre_encoded_tiles_per_s,
        i.bc1_pre_encoded_vs_rgba8
    );
    s += &format!(
        "ingest CPU a tile (every thread): RGBA8 {:.1} us, BC1 encoded at run time {:.1} us ({:.2}x: the ratio where the reads keep every core busy either way)\n",
        i.rgba8_cpu_us_per_tile, i.bc1_encoded_cpu_us_per_tile, i.bc1_encoded_vs_rgba8_cpu
    );
    for f in r.flight.iter().chain(&r.flight_rgba8) {
        s += &format!(
            "2^26 flight, defaults, {}: level 0 shown on {:.2}% of ticks ({} ticks, {} with a disabled level, {} late, tick p99 {:.2} ms)\n",
            f.format,
            f.level0_shown_share * 100.0,
            f.ticks,
            f.ticks_with_disabled_levels,
            f.late_ticks,
            f.tick_p99_s * 1e3
        );
    }
    s += "goals:\n";
    for (name, g) in &r.goals {
        s += &format!(
            "  {name}: {} ({} {}): {}\n",
            g.figure.map(|x| format!("{x:.4}")).unwrap_or_else(|| "not measured".into()),
            g.goal,
            g.of,
            match g.met {
                Some(true) => "met",
                Some(false) => "MISSED",
                None => "-",
            }
        );
    }
    s += &format!(
        "build: {}; {} cores, load average {} at the start, {} at the end\n",
        r.build, r.cpus, r.load_average[0], r.load_average[1]
    );
    s
}

/// `clipbench formats`: 0 measured, 1 bad input, 2 could not run.
pub fn main(args: Args) -> u8 {
    if let Some(p) = &args.image {
        if !p.is_file() {
            eprintln!("clipbench formats: --image {}: no such file", p.display());
            return 1;
        }
    }
    if BcQuality::parse(&args.bc_quality).is_err() {
        eprintln!("clipbench formats: --bc-quality {}: expected fast, normal or slow", args.bc_quality);
        return 1;
    }
    match run(&args) {
        Ok(r) => {
            if let Some(p) = &args.plot {
                if let Err(e) = clipmap::accuracy::sweep::write_whole(p, clipmap::accuracy::formats::plot(&r.view)) {
                    eprintln!("clipbench formats: cannot write {}: {e}", p.display());
                    return 2;
                }
            }
            clipmap::report::emit(args.json, &r, human);
            0
        }
        Err(e) => {
            eprintln!("clipbench formats: {e:#}");
            2
        }
    }
}
