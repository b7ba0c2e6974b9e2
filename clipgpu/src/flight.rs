//! The reference flight against a running service: every frame asks for the centre under the
//! camera, waits for the snapshot that applies it, uploads what the GPU lacks, draws, and (unless
//! told not to) renders the same snapshot with the reference renderer
//! (`clipmap::accuracy::render::render_mapping`) and compares. Notices a service that stopped or
//! was replaced and attaches to the next one.

use crate::check::{self, GeometryDiff, SamplingDiff};
use crate::gpu::{shapes, Gpu, Renderer, Texels};
use crate::heights::{self, HeightDiff, HeightShading};
use crate::upload::{check_format, on_gpu, Method, UploadStats, Uploader};
use crate::BadInput;
use anyhow::{anyhow, Context, Result};
use clipmap::accuracy::render::{render_mapping, Camera, Pixel};
use clipmap::accuracy::study::{compare, Case};
use clipmap::roam::Flight;
use clipmap::sample::Filter;
use clipmap::shm::{Client, ShmError, Snapshot};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How to fly.
#[derive(Clone, Debug)]
pub struct FlightOptions {
    /// The flight, camera and image size (the accuracy study's case; its texture fields are the
    /// service's business and ignored here).
    pub case: Case,
    /// Texture filter.
    pub filter: Filter,
    /// Upload method.
    pub method: Method,
    /// Upload budget in texel bytes per frame.
    pub budget: Option<u64>,
    /// Where frames go as PNG (GPU frames, and the reference's when comparing).
    pub out_dir: Option<PathBuf>,
    /// Render the reference too and compare.
    pub compare: bool,
    /// Wait for each frame's centre to be settled (min LOD 0) before drawing, up to `wait`.
    pub settle: bool,
    /// The longest wait for a frame's snapshot.
    pub wait: Duration,
    /// How long to wait for a stopped service to come back.
    pub reattach: Duration,
    /// Pause between frames.
    pub frame_pause: Duration,
    /// Where the flight starts (level-0 texels; `None`: the texture's centre).
    pub start: Option<[f64; 2]>,
    /// A height texture's false-colour range, metres (`None`: the format's, docs/GPU.md).
    pub height_range: Option<[f64; 2]>,
    /// The view to draw and move (docs/VIEWS.md): `main`, the primary, or a further view's name.
    pub view: String,
}

/// One frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameRecord {
    /// Frame number.
    pub frame: u64,
    /// Level-0 centre asked for.
    pub centre: [i64; 2],
    /// The snapshot's tick.
    pub tick: u64,
    /// The snapshot's min LOD.
    pub min_lod: f64,
    /// Levels disabled in the snapshot.
    pub levels_disabled: u32,
    /// The snapshot applied the centre (and, with settling, min LOD was 0).
    pub settled: bool,
    /// Against the reference renderer (all zero when not compared).
    pub diff: FrameDiff,
    /// The upload.
    pub upload: UploadStats,
    /// Drawing and reading back the frame, milliseconds.
    pub draw_ms: f64,
    /// The reference renderer on the CPU, milliseconds (0 when not compared).
    pub reference_ms: f64,
    /// The checks at the GPU's coordinates (the CPU sampler again, and the geometry),
    /// milliseconds (0 when not compared).
    pub check_ms: f64,
    /// A new service was attached before this frame.
    pub reattached: bool,
}

/// What a flight did.
#[derive(Clone, Debug, Serialize)]
pub struct FlightReport {
    /// Per frame.
    pub frames: Vec<FrameRecord>,
    /// Services attached after the first.
    pub reattaches: u32,
    /// PNG files written.
    pub pictures: Vec<PathBuf>,
    /// The mapping's levels, clip size, tile size of level 0, level-0 size.
    pub texture: TextureInfo,
}

/// The texture as the mapping describes it.
#[derive(Clone, Debug, Serialize)]
pub struct TextureInfo {
    /// Level-0 size.
    pub size: [u64; 2],
    /// Clip size.
    pub clip: u64,
    /// Tile size (level 0).
    pub tile: [u64; 2],
    /// Levels.
    pub levels: usize,
    /// Bytes per texel as published.
    pub bytes_per_texel: usize,
    /// For heights: the format (from the mapping's heights block) and the false-colour range.
    pub heights: Option<HeightShading>,
    /// The mapping's texel format (`rgba8`, `bc7`, ...).
    pub format: String,
    /// The GPU texture's format (wgpu's name: `Rgba8Uint`, `Bc7RgbaUnorm`, ...).
    pub gpu_format: String,
    /// A block-compressed mapping: `gpu` (its blocks uploaded as they are, decoded by the GPU) or
    /// `cpu` (the adapter lacks BC textures: decoded on the CPU with `bcdec_rs`, uploaded as
    /// RGBA8); `None` for other formats.
    pub block_upload: Option<&'static str>,
}

impl TextureInfo {
    /// The block format whose blocks the GPU decodes (`None`: not a block format, or decoded on
    /// the CPU).
    pub fn gpu_blocks(&self) -> Option<clipmap::texel::Bc> {
        (self.block_upload == Some("gpu")).then(|| clipmap::texel::Bc::parse(&self.format).ok()).flatten()
    }
}

/// Names of services published in `dir` (for the error that says which exist).
fn names_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .filter_map(|e| {
                    let n = e.file_name().to_string_lossy().to_string();
                    n.strip_prefix("clipmap-").and_then(|r| r.strip_suffix(".map")).map(str::to_string)
                })
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Attaches by name and binds to the view `view` (`main`: the primary); a clear error for a name
/// that is not there, a view the service does not publish (naming those it does, as every reader
/// says it), or a mapping that is refused.
pub fn attach(dir: &Path, name: &str, view: &str) -> Result<Client> {
    match Client::attach(dir, name) {
        Ok(mut c) => {
            c.bind_view(view).map_err(|e| anyhow!(e).context(format!("--view {view}")))?;
            check_format(&c).map_err(|e| anyhow!(BadInput(e.to_string())))?;
            if !c.can_request() {
                return Err(anyhow!(
                    "{}: the request mapping beside it cannot be written by this user, and clipgpu asks \
                     for its centres through it: run clipgpu as the service's user, or start clipmapd \
                     with --request-mode 660 and a shared group",
                    c.path().display()
                ));
            }
            Ok(c)
        }
        Err(ShmError::NotFound { .. }) => {
            let found = names_in(dir);
            let found = if found.is_empty() { "none".to_string() } else { found.join(", ") };
            Err(anyhow!(BadInput(format!(
                "--name {name}: no service of that name in {} (expected {}; services found there: {found}); \
                 start one with `clipmapd --source terrain --name {name}`, or pass the service's --shm-dir",
                dir.display(),
                dir.join(format!("clipmap-{name}.map")).display()
            ))))
        }
        Err(e @ ShmError::BadName(..)) => Err(anyhow!(BadInput(format!("--name {name}: {e}")))),
        Err(e) => Err(anyhow!(e).context(format!("attaching to the service {name} in {}", dir.display()))),
    }
}

fn gone(c: &Client) -> bool {
    let stale = (c.tick_period * 20).max(Duration::from_secs(1));
    c.closed() || c.replaced() || c.heartbeat_age() > stale
}

/// Waits for a new service (another generation) on the name that publishes the view `view`.
fn reattach(dir: &Path, name: &str, view: &str, old: u64, within: Duration, frame: u64) -> Result<Client> {
    let t0 = Instant::now();
    let mut missing = None;
    while t0.elapsed() < within {
        match attach(dir, name, view) {
            Ok(c) if c.generation != old && !gone(&c) => return Ok(c),
            Ok(_) => {}
            // A new service without the view (yet: it adds its `--view`s just after publishing).
            Err(e) if e.chain().any(|c| matches!(c.downcast_ref(), Some(ShmError::NoView { .. }))) => missing = Some(e),
            Err(_) => {}
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    if let Some(e) = missing {
        return Err(anyhow!(
            "the service {name} stopped at frame {frame} and the one that replaced it did not publish the view \
             `{view}` within {:.1} s ({e:#}): a view added on the control socket is gone after a restart; add it \
             again (`VIEW ADD {view}`), start clipmapd with --view {view}, or give clipgpu longer with --reattach-s",
            within.as_secs_f64()
        ));
    }
    Err(anyhow!(
        "the service {name} stopped at frame {frame} and no new one published {} within {:.1} s: \
         restart clipmapd, or give clipgpu longer with --reattach-s",
        dir.join(format!("clipmap-{name}.map")).display(),
        within.as_secs_f64()
    ))
}

/// The GPU's state for one attached service.
struct Attached {
    client: Client,
    renderer: Renderer,
    uploader: Uploader,
}

/// How a height texture is drawn (`None` for colour); `--height-range` with a colour texture is
/// bad input.
fn shading(client: &Client, texels: Texels, o: &FlightOptions) -> Result<Option<HeightShading>> {
    match (&client.heights, texels) {
        (Some(h), Texels::Float32) => Ok(Some(HeightShading::new(h.format(), o.height_range))),
        _ => match o.height_range {
            Some(r) => Err(anyhow!(BadInput(format!(
                "--height-range {},{}: {} serves colour, not heights (its heights block is zero); drop --height-range, \
                 or attach to a height texture",
                r[0],
                r[1],
                client.path().display()
            )))),
            None => Ok(None),
        },
    }
}

impl Attached {
    fn new(gpu: &Gpu, client: Client, o: &FlightOptions, reuse: Option<Renderer>) -> Result<Attached> {
        let levels = shapes(&client);
        let published = check_format(&client).map_err(|e| anyhow!(BadInput(e.to_string())))?;
        let block = match published {
            Texels::Blocks(bc) => Some(bc),
            _ => None,
        };
        if let (Some(bc), Method::Rects) = (block, o.method) {
            return Err(anyhow!(BadInput(format!(
                "--upload rects: {} is block-compressed ({}), and rects cuts texels out of its tiles; block \
                 formats go to the GPU in whole tiles: use --upload tiles",
                client.path().display(),
                bc.name()
            ))));
        }
        let texels = on_gpu(published, gpu.bc);
        let heights = shading(&client, texels, o)?;
        let mut renderer = match reuse {
            Some(r) if r.levels == levels && r.texels == texels => {
                r.clear_tags(gpu);
                r
            }
            _ => Renderer::new(gpu, levels, texels)?,
        };
        renderer.heights = heights;
        let uploader =
            Uploader::new(&renderer.levels, client.bytes_per_texel, texels, block, heights, o.method, o.budget);
        Ok(Attached { client, renderer, uploader })
    }
}

fn settled(snap: &Snapshot, centre: [i64; 2], settle: bool) -> bool {
    snap.tick > 0 && snap.centre == centre && (!settle || snap.min_lod == 0.0)
}

/// Flies `o` against the service `name` in `dir`.
pub fn fly(gpu: &Gpu, dir: &Path, name: &str, o: &FlightOptions) -> Result<FlightReport> {
    let flight: Flight = o.case.flight.parse().map_err(|e| anyhow!(BadInput(format!("--flight: {e}"))))?;
    let client = attach(dir, name, &o.view)?;
    let d0 = client.levels[0];
    let (clip, levels, bytes_per_texel) = (client.clip_size, client.levels.len(), client.bytes_per_texel);
    let format = clipmap::shm::layout::format_from_code(client.format_code)
        .map(|f| f.short_name())
        .unwrap_or_else(|| format!("code {}", client.format_code));
    let mut at = Attached::new(gpu, client, o, None)?;
    let block_upload = match at.renderer.texels {
        Texels::Blocks(_) => Some("gpu"),
        _ if at.uploader.block().is_some() => Some("cpu"),
        _ => None,
    };
    if block_upload == Some("cpu") {
        eprintln!(
            "clipgpu: the adapter {} has no BC textures (TEXTURE_COMPRESSION_BC): decoding the {format} blocks on \
             the CPU (bcdec) and uploading RGBA8",
            gpu.adapter
        );
    }
    let texture = TextureInfo {
        size: d0.size,
        clip,
        tile: d0.tile,
        levels,
        bytes_per_texel,
        heights: at.renderer.heights,
        format,
        gpu_format: at.renderer.texels.gpu_format(),
        block_upload,
    };
    let start = o.start.unwrap_or([d0.size[0] as f64 / 2.0, d0.size[1] as f64 / 2.0]);
    let heading = {
        let (a, b) = (flight.position(start, 0), flight.position(start, 1));
        if (b[0] - a[0]).abs() + (b[1] - a[1]).abs() < 1e-9 {
            0.0
        } else {
            (b[1] - a[1]).atan2(b[0] - a[0]).to_degrees()
        }
    };
    if let Some(dir) = &o.out_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("creating the picture directory {}", dir.display()))?;
    }
    let mut report = FlightReport { frames: Vec::new(), reattaches: 0, pictures: Vec::new(), texture };
    for f in 0..o.case.frames {
        let foot = flight.position(start, f);
        let centre = [foot[0].floor() as i64, foot[1].floor() as i64];
        let velocity = {
            let n = flight.position(start, f + 1);
            [(n[0] - foot[0]) * 60.0, (n[1] - foot[1]) * 60.0]
        };
        let mut reattached = false;
        at.client.request_centre(centre, velocity);
        let t0 = Instant::now();
        let mut snap;
        loop {
            if gone(&at.client) {
                let client = reattach(dir, name, &o.view, at.client.generation, o.reattach, f)?;
                let Attached { renderer, .. } = at;
                at = Attached::new(gpu, client, o, Some(renderer))?;
                report.reattaches += 1;
                reattached = true;
                at.client.request_centre(centre, velocity);
            }
            snap = at.client.snapshot();
            if settled(&snap, centre, o.settle) || t0.elapsed() > o.wait {
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        let upload = gpu.checked(
            &format!("uploading frame {f}'s texels"),
            "the texture array may be too large for this adapter's memory: use a smaller clip size",
            || at.uploader.upload(gpu, &at.renderer, &at.client, &snap),
        )??;
        let cam = Camera::following(foot, o.case.eye_height, heading, o.case.pitch_deg, o.case.fov_deg, o.case.display);
        let t = Instant::now();
        let frame = at.renderer.draw(gpu, &cam, &snap, o.filter)?;
        let draw_ms = t.elapsed().as_secs_f64() * 1000.0;
        let mut rec = FrameRecord {
            frame: f,
            centre,
            tick: snap.tick,
            min_lod: snap.min_lod,
            levels_disabled: snap.levels.iter().filter(|l| !l.enabled).count() as u32,
            settled: settled(&snap, centre, o.settle),
            diff: FrameDiff::default(),
            upload,
            draw_ms,
            reference_ms: 0.0,
            check_ms: 0.0,
            reattached,
        };
        let mut reference_img = None;
        if o.compare {
            let t = Instant::now();
            let want = match &at.renderer.heights {
                Some(sh) => heights::render(&cam, &at.client, &snap, o.filter, sh),
                None => render_mapping(&cam, &at.client, &snap, o.filter),
            };
            rec.reference_ms = t.elapsed().as_secs_f64() * 1000.0;
            rec.diff = compare_frame(&cam, at.renderer.levels.len(), o.filter, &want, &frame.rgba);
            let t = Instant::now();
            let levels = &at.renderer.levels;
            let held = at.uploader.held();
            match &at.renderer.heights {
                Some(sh) => {
                    let (colours, h) = heights::check(&at.client, &snap, levels, held, o.filter, sh, &frame);
                    rec.diff.at_gpu_coords = colours;
                    rec.diff.heights = Some(h);
                }
                None => rec.diff.at_gpu_coords = check::sampling(&at.client, &snap, levels, held, o.filter, &frame),
            }
            rec.diff.geometry = check::geometry(&cam, levels, &frame);
            rec.check_ms = t.elapsed().as_secs_f64() * 1000.0;
            reference_img = Some(clipmap::accuracy::render::to_image(&cam, &want));
        }
        if let Some(dir) = &o.out_dir {
            let path = dir.join(format!("gpu-{f:03}.png"));
            let img = image::RgbaImage::from_raw(cam.width, cam.height, frame.rgba).context("frame size")?;
            img.save(&path).with_context(|| format!("writing {}", path.display()))?;
            report.pictures.push(path);
            if let Some(img) = reference_img {
                let path = dir.join(format!("reference-{f:03}.png"));
                img.save(&path).with_context(|| format!("writing {}", path.display()))?;
                report.pictures.push(path);
            }
        }
        report.frames.push(rec);
        if !o.frame_pause.is_zero() {
            std::thread::sleep(o.frame_pause);
        }
    }
    Ok(report)
}

/// How a GPU frame differs from the reference frame of the same snapshot.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FrameDiff {
    /// PSNR over the reference's ground pixels as the accuracy study measures it (`None`: equal).
    pub psnr: Option<f64>,
    /// Largest channel difference over every pixel, sky included (8-bit units).
    pub max_error: u16,
    /// Pixels that differ at all.
    pub differing: u64,
    /// Of those, pixels whose reference coordinates lie on a texel edge (or the LOD on a level
    /// boundary) to within f32 rounding, where the shader's f32 and the reference's f64 may pick
    /// different texels.
    pub at_edges: u64,
    /// Largest channel difference over the pixels not at an edge.
    pub max_error_off_edges: u16,
    /// PSNR over the ground pixels not at an edge (`None`: those are equal).
    pub psnr_off_edges: Option<f64>,
    /// The CPU sampler at the GPU's own coordinates and LOD against the GPU's pixels.
    pub at_gpu_coords: SamplingDiff,
    /// The GPU's coordinates and LOD against the f64 camera's.
    pub geometry: GeometryDiff,
    /// For heights: the GPU's sampled heights against the CPU's at the GPU's coordinates
    /// (`None` for colour).
    pub heights: Option<HeightDiff>,
}

/// Whether pixel (i, j)'s footprint lies, to within f32 rounding, where the filter's choice of
/// texels or levels changes: a texel edge of some level (texel centres for the bilinear filters)
/// or a LOD boundary.
fn at_edge(cam: &Camera, i: u32, j: u32, levels: usize, filter: Filter) -> bool {
    let Some(fp) = cam.footprint(i, j) else { return true };
    let far = (fp.uv[0] - cam.eye[0]).hypot(fp.uv[1] - cam.eye[1]) + cam.eye[2];
    // f32 carries 24 bits: a few operations on coordinates `far` texels from the eye.
    let eps = 2e-6 * far + 1e-5;
    let off = if filter == Filter::Point { 0.0 } else { 0.5 };
    for k in 0..levels {
        let scale = (1u64 << k) as f64;
        for c in fp.uv {
            let x = c / scale - off;
            if (x - x.round()).abs() * scale < eps {
                return true;
            }
        }
    }
    // The unclamped LOD: a LOD clamped to 0 (or raised to min LOD) is the same in both.
    let lod = fp.lod;
    let boundary = if filter == Filter::Trilinear { lod.round() } else { lod.floor() + 0.5 };
    (lod - boundary).abs() < 1e-4
}

/// Compares a GPU frame (RGBA8 rows) with the reference's pixels.
pub fn compare_frame(cam: &Camera, levels: usize, filter: Filter, want: &[Pixel], got_rgba: &[u8]) -> FrameDiff {
    let got: Vec<Pixel> = want
        .iter()
        .zip(got_rgba.chunks_exact(4))
        .map(|(w, g)| {
            let rgba = [g[0], g[1], g[2], g[3]];
            Pixel { rgba, rgba16: rgba.map(|c| c as u16 * 257), lod: w.lod, ground: w.ground }
        })
        .collect();
    let (psnr, ground_max, _) = compare(want, &got);
    let mut d = FrameDiff { psnr, max_error: ground_max, ..FrameDiff::default() };
    let (mut sq, mut n) = (0f64, 0u64);
    for (idx, (w, g)) in want.iter().zip(&got).enumerate() {
        let e = (0..3).map(|c| w.rgba[c].abs_diff(g.rgba[c]) as u16).max().unwrap_or(0);
        d.max_error = d.max_error.max(e);
        let (i, j) = (idx as u32 % cam.width, idx as u32 / cam.width);
        let edge = e > 0 && at_edge(cam, i, j, levels, filter);
        d.differing += u64::from(e > 0);
        d.at_edges += u64::from(edge);
        if edge {
            continue;
        }
        d.max_error_off_edges = d.max_error_off_edges.max(e);
        if w.ground {
            for c in 0..3 {
                let x = w.rgba[c].abs_diff(g.rgba[c]) as f64;
                sq += x * x;
                n += 1;
            }
        }
    }
    d.psnr_off_edges =
        if sq == 0.0 || n == 0 { None } else { Some(10.0 * (255.0f64 * 255.0 / (sq / n as f64)).log10()) };
    d
}
