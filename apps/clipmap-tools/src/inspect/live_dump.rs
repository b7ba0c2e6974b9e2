//! `cliptex dump --attach`: pictures of a running service, read from its shared-memory mapping
//! as any renderer reads it. One PNG per level (its window, the valid region's texels, the
//! invalid border as a dark checkerboard, the window outlined in yellow and the valid region in
//! red), `view.png` (the view around the centre as a renderer would texture it) and `rings.png`
//! (the same view coloured by the level each pixel would use: the concentric resolution bands).
//!
//! A texture of heights is drawn as `cliptex dump` draws one from disk
//! (`clipmap::report::dump::height_picture`): each level's valid region in false colour over its
//! range of heights (or `--range`), hillshaded with `--shade`, nodata transparent, its legend
//! below, the window, outlines and border around it as for colours; `view.png` uses the same
//! colours over the range of every level drawn.
//!
//! Owns choosing what to draw and naming the files; drawing is [`clipmap::report::picture`]'s and
//! [`clipmap::report::dump`]'s.

use clipmap::geom::{tex_region, Rect};
use clipmap::report::dump::{height_picture, HeightLegend, HeightView};
use clipmap::report::hypsometric::{self, Texel};
use clipmap::report::picture::{self, Frame};
use clipmap::shm::{Client, ShmError, Snapshot};
use image::{Rgb, RgbImage, RgbaImage};
use serde::Serialize;
use std::path::{Path, PathBuf};
use thiserror::Error;

pub use clipmap::limits::MAX_LEVEL_PIXELS;
/// Side of `view.png` and `rings.png` in pixels.
pub(crate) const VIEW_PIXELS: u32 = 512;
/// Pixels of margin around each level picture, where the outlines go.
const MARGIN: u32 = 2;

/// Why the pictures could not be made.
#[derive(Debug, Error)]
pub enum LiveDumpError {
    /// The mapping could not be attached.
    #[error("{0}")]
    Attach(#[from] ShmError),
    /// The output directory or a picture could not be written.
    #[error("cannot write {}: {message}", path.display())]
    Write {
        /// The directory or picture.
        path: PathBuf,
        /// Why it could not be written.
        message: String,
    },
}

/// One level's picture.
#[derive(Clone, Debug, Serialize)]
pub struct LevelPicture {
    /// Level number.
    pub level: usize,
    /// Level size.
    pub size: [u64; 2],
    /// Pyramid (resident whole) or stack level.
    pub pyramid: bool,
    /// The window (tex region) `[s0, t0, s1, t1)`.
    pub window: [i64; 4],
    /// The published valid region `[s0, t0, s1, t1)`.
    pub valid: [i64; 4],
    /// Renderers may use it.
    pub enabled: bool,
    /// Invalid border.
    pub invalid_border: u64,
    /// The PNG.
    pub png: String,
    /// Its size in pixels.
    pub pixels: [u32; 2],
    /// Texels per pixel.
    pub texels_per_pixel: i64,
    /// A texture of heights: the picture's legend (absent for colours). The picture is then the
    /// window's pixels with the legend's rows below (and at least the legend's width).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heights: Option<HeightLegend>,
}

/// How heights are drawn (`cliptex dump --attach --shade --range MIN,MAX`); colours ignore it.
#[derive(Clone, Copy, Debug, Default)]
pub struct Options {
    /// Hillshade the false-colour maps.
    pub shade: bool,
    /// The metres the colour bars span (default: each level's range; the view, every level's).
    pub range: Option<[f64; 2]>,
}

/// What was written.
#[derive(Clone, Debug, Serialize)]
pub struct LiveDump {
    /// The mapping read.
    pub mapping: String,
    /// Tick of the snapshot drawn.
    pub tick: u64,
    /// Finest level renderers may use.
    pub min_lod: f64,
    /// The service had shut down (the pictures show its last publication).
    pub closed: bool,
    /// Clip size.
    pub clip_size: u64,
    /// Texel format (`null` when the mapping's code is unknown).
    pub format: Option<String>,
    /// Level-0 centre the view is drawn around.
    pub centre: [i64; 2],
    /// Per level.
    pub levels: Vec<LevelPicture>,
    /// The view.
    pub view: String,
    /// The view coloured by level.
    pub rings: String,
    /// Level-0 texels across the view.
    pub view_extent: i64,
    /// Colour of each level in `rings.png` (`#rrggbb`, repeating after 12).
    pub ring_colours: Vec<String>,
    /// A texture of heights: the metres `view.png`'s colours span (`null`: colours, or no data).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view_range: Option<[f64; 2]>,
}

fn save(img: impl Into<image::DynamicImage>, path: PathBuf) -> Result<String, LiveDumpError> {
    let img: image::DynamicImage = img.into();
    clipmap::save::atomically(&path, |w| img.write_to(w, image::ImageFormat::Png).map_err(clipmap::save::image_io))
        .map_err(|e| LiveDumpError::Write {
            path: path.clone(),
            message: format!("{e}; check the permissions of --out-dir"),
        })?;
    Ok(path.display().to_string())
}

/// Level `k` of a height texture over `frame` ([`height_picture`]): the valid region's heights,
/// the rest as [`picture::backdrop`] draws it.
fn height_level(
    client: &Client,
    snap: &Snapshot,
    k: usize,
    frame: Frame,
    view: &HeightView,
) -> (RgbaImage, HeightLegend) {
    let st = snap.levels[k];
    let size = client.levels[k].size;
    let window = tex_region(size, client.clip_size, st.centre);
    let valid =
        st.enabled.then(|| Rect::new(st.valid[0], st.valid[1], st.valid[2], st.valid[3])).filter(|v| !v.is_empty());
    let (w, h) = (frame.pixels[0], frame.pixels[1]);
    let (f, bpt) = (view.format, client.bytes_per_texel);
    let mut map = vec![Texel::Missing; w as usize * h as usize];
    let mut line = vec![0u8; valid.map_or(0, |v| v.width() as usize) * bpt];
    for y in 0..h {
        let (_, t) = frame.texel(0, y);
        let Some(v) = valid.filter(|v| t >= v.t0 && t < v.t1) else { continue };
        if client.read_region(k, v.s0, t, v.width(), 1, &mut line).is_err() {
            continue;
        }
        for x in 0..w {
            let (s, _) = frame.texel(x, y);
            if v.contains(s, t) {
                let j = (s - v.s0) as usize * bpt;
                map[(y * w + x) as usize] = match f.decode(f.read(&line[j..j + bpt])) {
                    Some(m) if m.is_finite() => Texel::Height(m),
                    _ => Texel::Nodata,
                };
            }
        }
    }
    height_picture(&map, w, h, view, |x, y| {
        let (s, t) = frame.texel(x, y);
        let c = picture::backdrop(&frame, size, window, valid, s, t);
        [c[0], c[1], c[2], 255]
    })
}

/// Attaches to `name` in `dir` and writes the pictures of one consistent snapshot into `out_dir`
/// (created if needed); heights are drawn as `options` says.
pub fn dump(dir: &Path, name: &str, out_dir: &Path, options: &Options) -> Result<LiveDump, LiveDumpError> {
    let client = Client::attach(dir, name)?;
    std::fs::create_dir_all(out_dir).map_err(|e| LiveDumpError::Write {
        path: out_dir.to_path_buf(),
        message: format!("{e}; --out-dir must be a directory that can be created or written"),
    })?;
    let snap = client.checked_snapshot()?;
    let heights = client.heights.map(|h| HeightView { format: h.format(), range: options.range, shade: options.shade });
    let mut levels = Vec::with_capacity(client.levels.len());
    for (k, d) in client.levels.iter().enumerate() {
        let st = snap.levels[k];
        let window = tex_region(d.size, client.clip_size, st.centre);
        let frame = Frame::around(window, MAX_LEVEL_PIXELS, MARGIN);
        let path = out_dir.join(format!("level-{k:02}.png"));
        let (png, legend, pixels) = match &heights {
            Some(view) => {
                let (img, legend) = height_level(&client, &snap, k, frame, view);
                let pixels = [img.width(), img.height()];
                (save(img, path)?, Some(legend), pixels)
            }
            None => {
                let mut img = RgbImage::from_pixel(frame.pixels[0], frame.pixels[1], Rgb([0, 0, 0]));
                picture::draw_published_level(&mut img, 0, 0, frame, &client, &snap, k);
                (save(img, path)?, None, frame.pixels)
            }
        };
        levels.push(LevelPicture {
            level: k,
            size: d.size,
            pyramid: d.pyramid,
            window: [window.s0, window.t0, window.s1, window.t1],
            valid: st.valid,
            enabled: st.enabled,
            invalid_border: snap.invalid_border,
            png,
            pixels,
            texels_per_pixel: frame.scale,
            heights: legend,
        });
    }
    // Wide enough to show the first few rings: each stack level's window is twice the previous.
    let stack = client.levels.iter().filter(|l| !l.pyramid).count().min(4) as u32;
    let size0 = client.levels.first().map_or(1, |l| l.size[0].max(l.size[1])) as i64;
    let extent = ((client.clip_size as i64) << stack).min(size0).max(VIEW_PIXELS as i64);
    let centre = snap.levels.first().map_or([0, 0], |l| l.centre);
    // Heights: one colour bar over every level's range (or --range), so that a height has one
    // colour whichever level shows it.
    let view_range = options.range.or_else(|| {
        levels.iter().filter_map(|l| l.heights.as_ref()?.region_range).reduce(|a, b| [a[0].min(b[0]), a[1].max(b[1])])
    });
    // A block-compressed mapping's texels come decoded (RGBA8, or one or two bytes).
    let format = client.decoded_format().or_else(|| clipmap::shm::layout::format_from_code(client.format_code));
    let colour = |px: &[u8]| -> [u8; 3] {
        match (&heights, view_range) {
            (Some(v), Some([lo, hi])) => match v.format.decode(v.format.read(px)) {
                Some(m) if m.is_finite() => hypsometric::ramp(hypsometric::fraction(m, lo, hi)),
                _ => [0, 0, 0],
            },
            (Some(_), None) => [0, 0, 0],
            (None, _) => {
                let c = picture::texel_rgba(format, px);
                [c[0], c[1], c[2]]
            }
        }
    };
    let (view, rings) = picture::view_and_rings(&client, &snap, centre, VIEW_PIXELS, extent, &colour);
    let view = save(view, out_dir.join("view.png"))?;
    let rings = save(rings, out_dir.join("rings.png"))?;
    let ring_colours = (0..client.levels.len())
        .map(|k| {
            let c = picture::PALETTE[k % picture::PALETTE.len()];
            format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
        })
        .collect();
    Ok(LiveDump {
        mapping: client.path().display().to_string(),
        tick: snap.tick,
        min_lod: snap.min_lod,
        closed: client.closed(),
        clip_size: client.clip_size,
        format: clipmap::shm::layout::format_from_code(client.format_code).map(|f| f.short_name()),
        centre,
        levels,
        view,
        rings,
        view_extent: extent,
        ring_colours,
        view_range: view_range.filter(|_| heights.is_some()),
    })
}

/// The human form.
pub fn human(d: &LiveDump) -> String {
    let mut o = format!(
        "{}  tick {}  min LOD {:.2}  clip {}  {}{}\n\nlevel  size              window                          valid region                    use       picture\n",
        d.mapping,
        d.tick,
        d.min_lod,
        d.clip_size,
        d.format.as_deref().unwrap_or("unknown format"),
        if d.closed { "  (service stopped: its last publication)" } else { "" }
    );
    let rect = |r: &[i64; 4]| format!("[{}, {}) x [{}, {})", r[0], r[2], r[1], r[3]);
    for l in &d.levels {
        let valid = Rect::new(l.valid[0], l.valid[1], l.valid[2], l.valid[3]);
        o.push_str(&format!(
            "{:<6} {:<17} {:<31} {:<31} {:<9} {}{}\n",
            l.level,
            format!("{}x{}", l.size[0], l.size[1]),
            rect(&l.window),
            if valid.is_empty() { "(empty)".to_string() } else { rect(&l.valid) },
            if l.enabled { "yes" } else { "disabled" },
            l.png,
            if l.texels_per_pixel > 1 { format!("  (1 pixel = {} texels)", l.texels_per_pixel) } else { String::new() }
        ));
    }
    o.push_str(&format!(
        "\nview   {}  ({} level-0 texels across, centre ({}, {}))\nrings  {}  (colour = level used: {})\n",
        d.view,
        d.view_extent,
        d.centre[0],
        d.centre[1],
        d.rings,
        d.ring_colours.iter().enumerate().take(6).map(|(k, c)| format!("{k} {c}")).collect::<Vec<_>>().join(", ")
            + if d.ring_colours.len() > 6 { ", ..." } else { "" }
    ));
    if let Some(l) = d.levels.iter().find_map(|l| l.heights.as_ref()) {
        o.push_str(&format!(
            "heights {}: each level in false colour over {}{}, nodata transparent, its legend below;{}\n",
            l.storage,
            if l.range_given { "--range" } else { "its own heights" },
            if l.shaded { ", hillshaded" } else { "" },
            match d.view_range {
                Some([a, b]) => format!(" the view over {a} m to {b} m"),
                None => " no height with data to colour the view".to_string(),
            }
        ));
    }
    o.push_str("outlines: yellow = window, red = valid region; dark checkerboard = invalid border or not loaded\n");
    o
}
