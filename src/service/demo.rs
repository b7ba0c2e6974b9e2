//! `clipmapd --demo`: serves a built-in terrain clip texture in a private directory, flies a
//! small client over it through the shared mapping (steady flight, a jump, a turn), and writes
//! pictures of what the client saw: each level's window with its valid region outlined, the view
//! as a renderer would texture it (finest available level per pixel), and the same view coloured
//! by the level each pixel uses (drawn by [`crate::report::picture`]).
//!
//! Everything it shows is read back through [`crate::shm::Client`], as any renderer would.

use super::{procedural_source, run, Options, Procedural, ServiceError, ServiceStats};
use crate::report::picture;
use crate::shm::{Client, Snapshot};
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
    options.socket = super::default_socket(&shm_dir, "demo");
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
    let terrain = crate::source::procedural::Terrain::new(log2, super::TERRAIN_SEED);
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
            let tag = ["flight", "after-jump", "settled"][i];
            pictures.extend(pictures_at(&client, &snap, c, o, tag)?);
        }
    }
    Ok((pictures, sharp))
}

fn save(img: &RgbImage, path: PathBuf) -> Result<PathBuf, ServiceError> {
    crate::save::atomically(&path, |w| img.write_to(w, image::ImageFormat::Png).map_err(crate::save::image_io))
        .map_err(|e| ServiceError::Output { path: path.clone(), message: e.to_string() })?;
    Ok(path)
}

fn pictures_at(
    client: &Client,
    snap: &Snapshot,
    centre: [i64; 2],
    o: &DemoOptions,
    tag: &str,
) -> Result<Vec<PathBuf>, ServiceError> {
    let clip = client.clip_size as i64;
    // Levels' windows side by side (stack levels, and the first pyramid level).
    let shown: Vec<usize> = (0..client.levels.len()).take_while(|&k| k == 0 || !client.levels[k - 1].pyramid).collect();
    let tile = clip.min(256) as u32;
    let scale = (clip as u32).div_ceil(tile).max(1) as i64;
    let gap = 6;
    let mut img = RgbImage::from_pixel(shown.len() as u32 * (tile + gap) + gap, tile + 2 * gap, Rgb([24, 24, 24]));
    for (i, &k) in shown.iter().enumerate() {
        let (cs, ct) = (centre[0] >> k, centre[1] >> k);
        let (s0, t0) = if client.levels[k].pyramid { (0, 0) } else { (cs - clip / 2, ct - clip / 2) };
        let frame = picture::Frame { s0, t0, pixels: [tile, tile], scale };
        picture::draw_published_level(&mut img, gap + i as u32 * (tile + gap), gap, frame, client, snap, k);
    }
    let mut out = vec![save(&img, o.out_dir.join(format!("levels-{tag}.png")))?];

    // The view around the centre, 4 clip sizes of level 0 across: texture and level used.
    let (view, lod) = picture::view_and_rings(client, snap, centre, 384, clip * 4);
    out.push(save(&view, o.out_dir.join(format!("view-{tag}.png")))?);
    out.push(save(&lod, o.out_dir.join(format!("lod-{tag}.png")))?);
    Ok(out)
}
