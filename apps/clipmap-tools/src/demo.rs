//! `clipmapd --demo`: serves a built-in terrain clip texture in a private directory, flies a
//! small client over it through the shared mapping (steady flight, a jump, a turn), and writes
//! pictures of what the client saw: each level's window with its valid region outlined, a
//! perspective view as a renderer would texture it (the reference renderer's camera, trilinear,
//! LOD from each pixel's footprint), and the same view coloured by the level each pixel uses;
//! every picture captioned and its outlines and colours explained in a legend (drawn by
//! [`clipmap::report::picture`] and [`clipmap::report::label`]).
//!
//! Everything it shows is read back through [`clipmap::shm::Client`], as any renderer would: the
//! demo is a client of the library on the top floor, above the service, the sampler, the
//! accuracy study's camera and the pictures, none of which the service itself imports.

use clipmap::report::{label, picture};
use clipmap::shm::{Client, Snapshot};
use clipmap_service::{procedural_source, run, Options, Procedural, ServiceError, ServiceStats};
use image::{Rgb, RgbImage};
use std::os::unix::fs::DirBuilderExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// What the demo does.
#[derive(Clone, Debug)]
pub struct DemoOptions {
    /// Where the pictures go.
    pub out_dir: PathBuf,
    /// Texture size (texels a side).
    pub size: u64,
    /// Clip size.
    pub clip: u64,
    /// Frames the client flies (at 60 per second).
    pub frames: u32,
}

impl Default for DemoOptions {
    fn default() -> Self {
        DemoOptions { out_dir: PathBuf::from("clipmapd-demo"), size: 1 << 15, clip: 256, frames: 240 }
    }
}

/// What the demo did.
#[derive(Clone, Debug)]
pub struct DemoReport {
    /// Pictures written.
    pub pictures: Vec<PathBuf>,
    /// The service's final statistics.
    pub stats: ServiceStats,
    /// Frames flown.
    pub frames: u32,
    /// Frames at which the client found level 0 usable at the centre.
    pub frames_sharp: u32,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Runs the demo to completion (a few seconds).
pub async fn demo(o: DemoOptions) -> Result<DemoReport, ServiceError> {
    let t0 = Instant::now();
    let out_err = |path: &Path, e: &dyn std::fmt::Display| ServiceError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    std::fs::create_dir_all(&o.out_dir).map_err(|e| out_err(&o.out_dir, &e))?;
    let shm_dir = std::env::temp_dir().join(format!("clipmapd-demo-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&shm_dir);
    std::fs::DirBuilder::new().mode(0o700).create(&shm_dir).map_err(|e| out_err(&shm_dir, &e))?;
    let mut options = Options::new("demo");
    options.socket = clipmap_service::default_socket(&shm_dir, "demo");
    options.shm_dir = shm_dir.clone();
    options.tick_hz = 120.0;
    options.budget_ms = Some(3.0);
    let source = procedural_source(Procedural::Terrain, o.size, o.clip, 64)?;
    let (done_tx, done_rx) = tokio::sync::oneshot::channel();
    let (client_tx, client_rx) = std::sync::mpsc::channel();
    let flight = o.clone();
    let summary = run(
        source,
        options,
        async {
            let _ = done_rx.await;
        },
        move |_| {
            std::thread::spawn(move || {
                let r = fly(&shm_dir, &flight);
                let _ = client_tx.send(r);
                let _ = done_tx.send(());
            });
        },
    )
    .await;
    let _ = std::fs::remove_dir_all(std::env::temp_dir().join(format!("clipmapd-demo-{}", std::process::id())));
    let summary = summary?;
    let (pictures, frames_sharp) = client_rx.recv().map_err(|_| ServiceError::TickLoopDied)??;
    Ok(DemoReport {
        pictures,
        stats: summary.stats,
        frames: o.frames,
        frames_sharp,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// A level-0 point on a coast of the demo's terrain (the flight starts there: more to see).
fn coast(size: u64) -> [i64; 2] {
    let log2 = 64 - (size - 1).max(1).leading_zeros();
    let terrain = clipmap::source::procedural::Terrain::new(log2, clipmap::source::TERRAIN_SEED);
    let step = (size / 48).max(1);
    let mut best = ([size as i64 / 2; 2], f64::MAX);
    for i in 8..40 {
        for j in 8..40 {
            let (s, t) = (i * step, j * step);
            let d = (terrain.height(0, s, t) - 0.55).abs();
            if d < best.1 {
                best = ([s as i64, t as i64], d);
            }
        }
    }
    best.0
}

/// The client: requests a centre every frame and takes pictures at three moments.
fn fly(shm_dir: &Path, o: &DemoOptions) -> Result<(Vec<PathBuf>, u32), ServiceError> {
    let client = Client::attach(shm_dir, "demo")?;
    let start = coast(o.size);
    let frames = o.frames.max(3);
    let jump_at = frames * 2 / 3;
    let shots = [frames / 3, jump_at + 1, frames - 1];
    let mut pictures = Vec::new();
    let mut sharp = 0;
    let frame_time = Duration::from_secs_f64(1.0 / 60.0);
    for f in 0..frames {
        let fl = f as f64;
        // East at 12 texels a frame with a slow weave, then a jump of 1500 texels north-west.
        let mut c = [start[0] + (fl * 12.0) as i64, start[1] + ((fl * 0.03).sin() * 200.0) as i64];
        if f >= jump_at {
            c = [c[0] - 1500, c[1] + 1500];
        }
        client.request_centre(c, [12.0 * 60.0, 0.0]);
        std::thread::sleep(frame_time);
        let snap = client.snapshot();
        if snap.min_lod < 1.0 && snap.levels[0].contains(c[0], c[1]) {
            sharp += 1;
        }
        if let Some(i) = shots.iter().position(|&s| s == f) {
            let (tag, text) = [
                ("flight", "steady flight east"),
                ("after-jump", "just after a jump of 1500 texels north-west"),
                ("settled", "settled after the jump"),
            ][i];
            pictures.extend(pictures_at(&client, &snap, c, o, Moment { tag, text, frame: f })?);
        }
    }
    Ok((pictures, sharp))
}

fn save(img: &RgbImage, path: PathBuf) -> Result<PathBuf, ServiceError> {
    clipmap::save::atomically(&path, |w| img.write_to(w, image::ImageFormat::Png).map_err(clipmap::save::image_io))
        .map_err(|e| ServiceError::Output { path: path.clone(), message: e.to_string() })?;
    Ok(path)
}

fn pictures_at(
    client: &Client,
    snap: &Snapshot,
    centre: [i64; 2],
    o: &DemoOptions,
    moment: Moment,
) -> Result<Vec<PathBuf>, ServiceError> {
    use label::Swatch;
    let clip = client.clip_size as i64;
    let when = format!(
        "{} (frame {}), centre ({}, {}), min LOD {:.2}",
        moment.text, moment.frame, centre[0], centre[1], snap.min_lod
    );
    // Levels' windows side by side (stack levels, and the first pyramid level), each labelled.
    let shown: Vec<usize> = (0..client.levels.len()).take_while(|&k| k == 0 || !client.levels[k - 1].pyramid).collect();
    let tile = clip.min(256) as u32;
    let scale = (clip as u32).div_ceil(tile).max(1) as i64;
    let gap = 6;
    let label_h = label::line_height(1) + 2;
    let mut img =
        RgbImage::from_pixel(shown.len() as u32 * (tile + gap) + gap, tile + 2 * gap + label_h, Rgb(label::BACKGROUND));
    for (i, &k) in shown.iter().enumerate() {
        let (cs, ct) = (centre[0] >> k, centre[1] >> k);
        let (s0, t0) = if client.levels[k].pyramid { (0, 0) } else { (cs - clip / 2, ct - clip / 2) };
        let frame = picture::Frame { s0, t0, pixels: [tile, tile], scale };
        let x = gap + i as u32 * (tile + gap);
        picture::draw_published_level(&mut img, x, gap + label_h, frame, client, snap, k);
        let state = if client.levels[k].pyramid {
            "pyramid"
        } else if !snap.levels[k].enabled {
            "off"
        } else if (k as f64) < snap.min_lod {
            "fading"
        } else {
            "in use"
        };
        label::text(&mut img, x, gap, &format!("level {k} {state}"), [235, 235, 235], 1);
    }
    let img = label::captioned(
        &img,
        &[
            when.clone(),
            format!(
                "each level's {clip}x{clip} window around the centre, finest left (1 pixel = {scale}x{scale} texels)"
            ),
        ],
        0,
    );
    let img = label::with_legend(
        &img,
        &[
            (Swatch::Outline(picture::VALID_EDGE), "valid region: renderers may read it".into()),
            (Swatch::Outline(picture::WINDOW_EDGE), "window (tex region)".into()),
            (Swatch::Checker, "invalid border or not yet loaded".into()),
            (Swatch::Solid([0, 0, 0]), "outside the texture".into()),
        ],
    );
    let mut out = vec![save(&img, o.out_dir.join(format!("levels-{}.png", moment.tag)))?];

    // The view from above the centre, looking ahead along the flight, as a renderer draws it:
    // perspective, LOD from the pixel footprint, trilinear filtering of the published levels.
    let (view, lod) = perspective(client, centre);
    let view = label::captioned(
        &view,
        &[
            when.clone(),
            format!("the view from {EYE_HEIGHT} texels above the centre, looking east: trilinear, LOD from each pixel's footprint, from the levels as published"),
        ],
        0,
    );
    out.push(save(&view, o.out_dir.join(format!("view-{}.png", moment.tag)))?);
    let used: Vec<(Swatch, String)> = (0..client.levels.len())
        .take(picture::PALETTE.len())
        .map(|k| (Swatch::Solid(picture::PALETTE[k % picture::PALETTE.len()]), format!("level {k}")))
        .collect();
    let lod = label::captioned(&lod, &[when, "the same view coloured by the level each pixel uses".into()], 0);
    let lod = label::with_legend(&lod, &used);
    out.push(save(&lod, o.out_dir.join(format!("lod-{}.png", moment.tag)))?);
    Ok(out)
}

/// Eye height of the demo's view, in level-0 texels.
const EYE_HEIGHT: f64 = 1200.0;

/// A 480x300 perspective view from [`EYE_HEIGHT`] above `centre`, looking east (the flight's
/// heading) 22 degrees below the horizon with a 70 degree field of view, rendered by the
/// reference renderer's camera and sampled from the mapping as any reader samples it; and the
/// same view coloured by the level each pixel used (texture brightness mixed in). Sky is blue.
fn perspective(client: &Client, centre: [i64; 2]) -> (RgbImage, RgbImage) {
    use clipmap::accuracy::render::Camera;
    use clipmap::sample::{sample_mapping, Filter};
    let size = [480u32, 300u32];
    let foot = [centre[0] as f64 + 0.5, centre[1] as f64 + 0.5];
    let cam = Camera::following(foot, EYE_HEIGHT, 0.0, 22.0, 70.0, size);
    let mut view = RgbImage::from_pixel(size[0], size[1], Rgb([140, 180, 230]));
    let mut lod = RgbImage::from_pixel(size[0], size[1], Rgb([140, 180, 230]));
    for j in 0..size[1] {
        for i in 0..size[0] {
            let Some(fp) = cam.footprint(i, j) else { continue };
            let Some(sample) = sample_mapping(client, Filter::Trilinear, fp.uv[0], fp.uv[1], fp.lod) else {
                view.put_pixel(i, j, Rgb([0, 0, 0]));
                lod.put_pixel(i, j, Rgb([0, 0, 0]));
                continue;
            };
            let c = sample.rgba.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8);
            view.put_pixel(i, j, Rgb([c[0], c[1], c[2]]));
            let k = sample.lod.floor().max(0.0) as usize;
            let p = picture::PALETTE[k % picture::PALETTE.len()];
            let lum = (c[0] as u32 + c[1] as u32 + c[2] as u32) / 3;
            let mix = |a: u8| ((a as u32 * 3 + lum * 2) / 5) as u8;
            lod.put_pixel(i, j, Rgb([mix(p[0]), mix(p[1]), mix(p[2])]));
        }
    }
    (view, lod)
}

/// One of the three moments the demo pictures.
#[derive(Clone, Copy, Debug)]
struct Moment {
    /// File-name tag.
    tag: &'static str,
    /// What it shows, for the caption.
    text: &'static str,
    /// Frame number.
    frame: u32,
}
