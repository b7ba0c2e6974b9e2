//! The sweep: cases over clip size, invalid border, disk speed, flight speed and shape; the
//! rows `clipbench accuracy` prints, a CSV, SVG plots and the generated `docs/ACCURACY.md`.
//!
//! Plots are written as SVG by hand (a few lines of markup) rather than through a plotting crate:
//! they need axes, labels and lines only, and SVG keeps text sharp in the documentation.

use super::study::{self, Case, Outcome, StudyError};
use crate::texel::TexelFormat;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// One row of the sweep (the `--json` contract).
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// Clip size.
    pub clip_size: u64,
    /// Image width in pixels.
    pub display_width: u32,
    /// Invalid border.
    pub invalid_border: u64,
    /// Tiles the simulated disk delivers per frame; `null` for an ideal disk.
    pub disk_tiles: Option<u64>,
    /// Bytes of one level-0 tile (the disk's unit).
    pub tile_bytes: u64,
    /// Flight speed, level-0 texels per frame.
    pub speed: f64,
    /// Flight spec.
    pub flight: String,
    /// The flight's figures (worst PSNR, errors, reads, resident bytes).
    #[serde(flatten)]
    pub summary: study::Summary,
    /// Frames flown.
    pub frames: u64,
    /// Levels addressable at once (virtual clip texture), `null` for all.
    pub effective_levels: Option<u32>,
    /// Texel format of the texture (`rgba8`, or a 16-bit format compared at 16 bits).
    pub format: String,
}

impl Row {
    pub(crate) fn from(o: &Outcome, speed: f64) -> Row {
        Row {
            clip_size: o.case.clip_size,
            display_width: o.case.display[0],
            invalid_border: o.case.invalid_border,
            disk_tiles: o.case.disk_tiles,
            tile_bytes: o.case.tile * o.case.tile * o.case.format.bytes_per_texel() as u64,
            speed,
            flight: o.case.flight.clone(),
            summary: o.summary.clone(),
            frames: o.case.frames,
            effective_levels: o.case.effective_levels,
            format: o.case.format.short_name(),
        }
    }
}

/// The cases of a sweep: each knob varied around a base case, the texture in `format`.
pub fn cases(quick: bool, format: TexelFormat) -> Vec<(Case, f64)> {
    let (display, frames) = if quick { ([192u32, 144u32], 8) } else { ([512, 384], 10) };
    let base = Case { display, frames, format, ..Case::small() };
    let mut out = Vec::new();
    let flight = |shape: &str, speed: f64| match shape {
        "circle" => format!("circle:{}:{speed}", 400.0),
        "zigzag" => format!("zigzag:{speed}:8"),
        _ => format!("straight:{speed}:30"),
    };
    let clips: &[u64] = if quick { &[64, 128, 256, 512] } else { &[64, 128, 256, 512, 1024] };
    for &clip in clips {
        out.push((Case { clip_size: clip, flight: flight("straight", 8.0), ..base.clone() }, 8.0));
    }
    for &border in &[8u64, 16, 32] {
        out.push((
            Case { invalid_border: border, clip_size: 256, flight: flight("straight", 8.0), ..base.clone() },
            8.0,
        ));
    }
    let budgets: &[u64] = if quick { &[1, 8] } else { &[1, 2, 8, 32] };
    // The quick sweep's speeds carry its short flights across tile columns of the finest levels,
    // so its finite disks are asked for tiles (at 4 and 32 texels a frame its 4 frames stayed
    // inside the warmed-up mem regions and read nothing).
    for &speed in if quick { &[32.0, 128.0][..] } else { &[2.0, 8.0, 32.0, 128.0][..] } {
        for &b in budgets {
            out.push((
                Case { disk_tiles: Some(b), wait_for_reads: true, flight: flight("straight", speed), ..base.clone() },
                speed,
            ));
        }
    }
    for eff in [16u32, 3] {
        out.push((
            Case { effective_levels: Some(eff), pitch_deg: 15.0, flight: flight("straight", 8.0), ..base.clone() },
            8.0,
        ));
    }
    // Fast enough that the quick sweep's turning flights reach past their mem regions too.
    let turning = if quick { 64.0 } else { 16.0 };
    for shape in ["circle", "zigzag"] {
        out.push((Case { flight: flight(shape, turning), disk_tiles: Some(2), ..base.clone() }, turning));
    }
    out
}

/// Runs every case; `progress` is told each finished row.
pub fn run(
    quick: bool,
    format: TexelFormat,
    mut progress: impl FnMut(usize, usize, &Row),
) -> Result<Vec<Row>, StudyError> {
    let all = cases(quick, format);
    let mut rows = Vec::new();
    for (i, (case, speed)) in all.iter().enumerate() {
        let o = study::run(case, |_, _, _, _| {})?;
        let row = Row::from(&o, *speed);
        progress(i + 1, all.len(), &row);
        rows.push(row);
    }
    Ok(rows)
}

/// Rows as CSV.
pub(crate) fn csv(rows: &[Row]) -> String {
    let mut o = String::from("clip_size,display_width,invalid_border,disk_tiles,speed,flight,psnr_min,max_error,coarser_pixel_share,bytes_read,tiles_read,ticks_over_budget,resident_bytes,frames,effective_levels\n");
    for r in rows {
        let _ = writeln!(
            o,
            "{},{},{},{},{},{},{},{},{:.6},{},{},{},{},{},{}",
            r.clip_size,
            r.display_width,
            r.invalid_border,
            r.disk_tiles.map(|b| b.to_string()).unwrap_or_default(),
            r.speed,
            r.flight,
            r.summary.psnr_min.map(|p| format!("{p:.3}")).unwrap_or_else(|| "inf".into()),
            r.summary.max_error,
            r.summary.coarser_pixel_share,
            r.summary.bytes_read,
            r.summary.tiles_read,
            r.summary.ticks_over_budget,
            r.summary.resident_bytes,
            r.frames,
            r.effective_levels.map(|e| e.to_string()).unwrap_or_default()
        );
    }
    o
}

/// A line chart as SVG: one series per (label, points).
pub(crate) fn svg_chart(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[(String, Vec<(f64, f64)>)],
    log_x: bool,
) -> String {
    let (w, h, l, r, t, b) = (640.0, 400.0, 70.0, 160.0, 40.0, 50.0);
    let tx = |x: f64| if log_x { x.max(1e-9).log2() } else { x };
    let pts: Vec<(f64, f64)> = series.iter().flat_map(|s| s.1.iter().map(|&(x, y)| (tx(x), y))).collect();
    let (mut x0, mut x1) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (mut y0, mut y1) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    if pts.is_empty() {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if x1 - x0 < 1e-9 {
        x1 = x0 + 1.0;
    }
    if y1 - y0 < 1e-9 {
        y1 = y0 + 1.0;
    }
    let px = |x: f64| l + (x - x0) / (x1 - x0) * (w - l - r);
    let py = |y: f64| h - b - (y - y0) / (y1 - y0) * (h - t - b);
    let mut s = format!("<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n");
    let _ = writeln!(s, "<text x=\"{}\" y=\"22\" font-size=\"15\">{title}</text>", l);
    let _ = writeln!(s, "<line x1=\"{l}\" y1=\"{}\" x2=\"{}\" y2=\"{}\" stroke=\"black\"/>", h - b, w - r, h - b);
    let _ = writeln!(s, "<line x1=\"{l}\" y1=\"{t}\" x2=\"{l}\" y2=\"{}\" stroke=\"black\"/>", h - b);
    for i in 0..=4 {
        let fx = x0 + (x1 - x0) * i as f64 / 4.0;
        let fy = y0 + (y1 - y0) * i as f64 / 4.0;
        let xl = if log_x { format!("{:.0}", 2f64.powf(fx)) } else { format!("{fx:.3}") };
        let _ = writeln!(s, "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">{xl}</text>", px(fx), h - b + 18.0);
        let _ = writeln!(s, "<text x=\"{}\" y=\"{:.1}\" text-anchor=\"end\">{fy:.2}</text>", l - 6.0, py(fy) + 4.0);
    }
    let _ =
        writeln!(s, "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">{x_label}</text>", (l + w - r) / 2.0, h - 10.0);
    let _ = writeln!(
        s,
        "<text x=\"16\" y=\"{:.1}\" transform=\"rotate(-90 16 {:.1})\" text-anchor=\"middle\">{y_label}</text>",
        (t + h - b) / 2.0,
        (t + h - b) / 2.0
    );
    const COLOURS: [&str; 6] = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf"];
    for (i, (label, points)) in series.iter().enumerate() {
        let c = COLOURS[i % COLOURS.len()];
        let path: Vec<String> = points.iter().map(|&(x, y)| format!("{:.1},{:.1}", px(tx(x)), py(y))).collect();
        let _ =
            writeln!(s, "<polyline fill=\"none\" stroke=\"{c}\" stroke-width=\"2\" points=\"{}\"/>", path.join(" "));
        for p in &path {
            let (x, y) = p.split_once(',').unwrap_or(("0", "0"));
            let _ = writeln!(s, "<circle cx=\"{x}\" cy=\"{y}\" r=\"3\" fill=\"{c}\"/>");
        }
        let ly = t + 10.0 + i as f64 * 18.0;
        let _ = writeln!(
            s,
            "<line x1=\"{}\" y1=\"{ly}\" x2=\"{}\" y2=\"{ly}\" stroke=\"{c}\" stroke-width=\"2\"/>",
            w - r + 10.0,
            w - r + 30.0
        );
        let _ = writeln!(s, "<text x=\"{}\" y=\"{}\">{label}</text>", w - r + 36.0, ly + 4.0);
    }
    s.push_str("</svg>\n");
    s
}

/// What the numbers say, appended to the generated report (kept in code so the report is whole).
pub const CONCLUSIONS: &str = "\
## Conclusions

- **Identity.** With a clip size at least twice the image width and the clip centre at the
  viewer's foot, every frame is bit-identical to the full-mipmap render (PSNR infinite, maximum
  error 0, no pixel coarser than ideal), for terrain and for the verification texture. The tests
  `accuracy::tests::with_clip_twice_the_display_every_frame_is_bit_identical` and
  `tests/it/stability.rs` hold this.
- **Clip size.** Below that, the share of pixels drawn from a coarser level grows as the clip
  shrinks (never the reverse: `a_smaller_clip_size_never_improves_the_picture`); the errors stay
  small on smooth terrain because a coarser level of a filtered pyramid is a blur, not a wrong
  texel.
- **Storage and speed.** Nothing is copied once tiles go straight into the image caches, so
  what limits the service is tile delivery: a slower disk (fewer tiles a frame) or a faster
  flight leaves levels incomplete; load control then raises min LOD, so those frames are
  blurrier, never wrong (`a_slower_disk_or_a_faster_flight_draws_more_pixels_coarser`). The
  table's `disk MB/s` column is what the storage must deliver at 60 frames a second for that
  row's accuracy at that flight speed and clip size.
- **Invalid border.** A wider border shrinks the readable window by twice its width; for a given
  clip size it trades a little resolution near the window's edge for more slack while roaming.
- **Virtual clip textures.** A renderer that addresses only a window of levels (a LOD offset
  from the eye height by Performer's rule, keeping resolution) matches the reference when the
  window holds every level the view needs; with too few effective levels the far field is drawn
  from too fine a level (aliased): the `levels 3` row.
- **Planning.** `cliptex plan --display W` recommends clip = W rounded up to a power of two as
  the usual choice and twice that as pixel-exact; the identity row above is the pixel-exact
  recommendation at work.

## Numbers: what is an integer, what is a float

- Texel and tile addressing, level sizes, windows, valid regions, toroidal slots and byte offsets
  are 64-bit integers (Euclidean modulo for negative coordinates); overflow is checked where a
  product could exceed 64 bits (configuration sizes, byte offsets).
- World positions, ray directions and texture coordinates are f64: a 2^26 texture needs 26 bits
  of integer part plus the sub-texel fraction, more than f32's 24-bit mantissa.
- Colours are f32 in 0..1 and are compared after quantising to 8 bits per channel.
- `tests/it/stability.rs` flies 2^26 textures with clip sizes from 1 to 8192, centres at 0, at the
  far edge, outside the texture and at ±2^40, across wrap boundaries, on non-square textures and
  down to the 1x1 level, and checks every published texel and the sampling identity.
";

/// PSNR for the chart: identical frames (infinite PSNR) are drawn at 60 dB.
fn psnr_plot(p: Option<f64>) -> f64 {
    p.unwrap_or(60.0).min(60.0)
}

/// Sample frames of the interesting cases: the reference, the clipmap render, their difference
/// (amplified 32 times) and the level each clipmap pixel used (one hue per level), as PNG.
pub fn write_samples(dir: &Path, quick: bool) -> Result<Vec<String>, StudyError> {
    let (display, frames) = if quick { ([192u32, 144u32], 3) } else { ([512, 384], 6) };
    let base = Case { display, frames, ..Case::small() };
    let picks = [
        ("small_clip", Case { clip_size: 64, ..base.clone() }),
        ("slow_disk_fast", Case { disk_tiles: Some(1), flight: "straight:128:30".into(), ..base.clone() }),
        ("identical", Case { clip_size: 1024, ..base.clone() }),
    ];
    let mut written = Vec::new();
    for (name, case) in picks {
        let last = case.frames - 1;
        let mut images = None;
        study::run(&case, |f, cam, want, got| {
            if f == last {
                let mut diff = image::RgbaImage::new(cam.width, cam.height);
                let mut levels = image::RgbaImage::new(cam.width, cam.height);
                for (i, (w, g)) in want.iter().zip(got).enumerate() {
                    let d = |c: usize| (w.rgba[c].abs_diff(g.rgba[c]) as u32 * 32).min(255) as u8;
                    let (x, y) = (i as u32 % cam.width, i as u32 / cam.width);
                    diff.put_pixel(x, y, image::Rgba([d(0), d(1), d(2), 255]));
                    let hue = if g.ground { (g.lod * 47.0) % 360.0 } else { 0.0 };
                    let rgb = hsv(hue, if g.ground { 0.8 } else { 0.0 }, if g.ground { 0.9 } else { 0.2 });
                    levels.put_pixel(x, y, image::Rgba([rgb[0], rgb[1], rgb[2], 255]));
                }
                images = Some((super::render::to_image(cam, want), super::render::to_image(cam, got), diff, levels));
            }
        })?;
        if let Some((want, got, diff, levels)) = images {
            for (suffix, img) in [("reference", want), ("clipmap", got), ("diff32", diff), ("levels", levels)] {
                let file = format!("{name}_{suffix}.png");
                crate::save::atomically(&dir.join(&file), |w| {
                    img.write_to(w, image::ImageFormat::Png).map_err(crate::save::image_io)
                })
                .map_err(|e| StudyError::Io(e.to_string()))?;
                written.push(file);
            }
        }
    }
    Ok(written)
}

fn hsv(h: f64, s: f64, v: f64) -> [u8; 3] {
    let c = v * s;
    let x = c * (1.0 - ((h / 60.0) % 2.0 - 1.0).abs());
    let (r, g, b) = match (h / 60.0) as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    [((r + m) * 255.0) as u8, ((g + m) * 255.0) as u8, ((b + m) * 255.0) as u8]
}

/// Writes `text` to `path` completely or not at all ([`crate::save::atomically`]).
pub fn write_whole(path: &Path, text: impl AsRef<[u8]>) -> std::io::Result<()> {
    use std::io::Write;
    crate::save::atomically(path, |w| w.write_all(text.as_ref()))
}

/// Writes CSV, plots and the report into `dir`; returns the report text.
pub fn write_outputs(rows: &[Row], dir: &Path, quick: bool, command: &str) -> std::io::Result<String> {
    std::fs::create_dir_all(dir)?;
    write_whole(&dir.join("accuracy.csv"), csv(rows))?;
    let base_clip: Vec<&Row> = rows
        .iter()
        .filter(|r| r.disk_tiles.is_none() && r.invalid_border == 8 && r.flight.starts_with("straight"))
        .collect();
    let by_clip: Vec<(f64, f64)> =
        base_clip.iter().map(|r| (r.clip_size as f64, psnr_plot(r.summary.psnr_min))).collect();
    let coarser_clip: Vec<(f64, f64)> =
        base_clip.iter().map(|r| (r.clip_size as f64, r.summary.coarser_pixel_share * 100.0)).collect();
    write_whole(
        &dir.join("psnr_vs_clip.svg"),
        svg_chart(
            "Worst-frame PSNR against clip size (ideal disk)",
            "clip size (texels)",
            "PSNR dB (60 = identical)",
            &[("PSNR".into(), by_clip), ("% coarser".into(), coarser_clip)],
            true,
        ),
    )?;
    let mut speeds: Vec<f64> =
        rows.iter().filter(|r| r.disk_tiles.is_some() && r.flight.starts_with("straight")).map(|r| r.speed).collect();
    speeds.sort_by(|a, b| a.total_cmp(b));
    speeds.dedup();
    let series: Vec<(String, Vec<(f64, f64)>)> = speeds
        .iter()
        .map(|&sp| {
            let pts = rows
                .iter()
                .filter(|r| r.speed == sp && r.flight.starts_with("straight") && r.disk_tiles.is_some())
                .map(|r| (r.disk_tiles.unwrap_or(0) as f64, r.summary.coarser_pixel_share * 100.0))
                .collect();
            (format!("{sp} texels/frame"), pts)
        })
        .collect();
    write_whole(
        &dir.join("coarser_vs_disk.svg"),
        svg_chart(
            "Pixels drawn coarser than ideal against disk speed",
            "tiles the disk delivers per frame",
            "% of ground pixels",
            &series,
            true,
        ),
    )?;
    Ok(report(rows, quick, command))
}

/// The Markdown report.
pub fn report(rows: &[Row], quick: bool, command: &str) -> String {
    let mut o = String::new();
    let _ = writeln!(o, "# Accuracy against speed\n");
    let _ = writeln!(o, "Generated by `{command}`{}. Every row flies a terrain texture of 2^16 texels a side with a camera above the clip centre (the viewer's foot), renders each frame from the full mipmap and from the clipmap (trilinear, LOD from screen-space derivatives), and compares them. The storage is a simulated disk that delivers at most `disk tiles/frame` tiles each frame, each one frame after it is asked for (`src/accuracy/study.rs`), so a row means the same on every machine; `disk MB/s` is that rate at 60 frames a second. Images are {}x{} pixels.\n", if quick { " (quick mode)" } else { "" }, rows.first().map(|r| r.display_width).unwrap_or(0), rows.first().map(|r| r.display_width * 3 / 4).unwrap_or(0));
    let _ = writeln!(o, "![PSNR against clip size](accuracy/psnr_vs_clip.svg)\n\n![coarser pixels against disk speed](accuracy/coarser_vs_disk.svg)\n");
    let _ = writeln!(o, "Sample frames (last frame of each flight; `diff32` is the difference amplified 32 times, `levels` colours each pixel by the level it was drawn from):\n");
    let _ = writeln!(o, "| case | reference | clipmap | difference x32 | levels used |\n|---|---|---|---|---|");
    for name in ["small_clip", "slow_disk_fast", "identical"] {
        let _ = writeln!(o, "| `{name}` | ![](accuracy/{name}_reference.png) | ![](accuracy/{name}_clipmap.png) | ![](accuracy/{name}_diff32.png) | ![](accuracy/{name}_levels.png) |");
    }
    let _ = writeln!(o);
    let _ = writeln!(o, "| clip | border | disk tiles/frame | disk MB/s | speed | flight | levels | PSNR min dB | max error | coarser px | MB read | tiles read | frames disk-bound |");
    let _ = writeln!(o, "|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} | {} | `{}` | {} | {} | {} | {:.2}% | {:.1} | {} | {} |",
            r.clip_size,
            r.invalid_border,
            r.disk_tiles.map(|b| b.to_string()).unwrap_or_else(|| "∞".into()),
            r.disk_tiles.map(|b| format!("{:.1}", (b * r.tile_bytes * 60) as f64 / 1e6)).unwrap_or_else(|| "∞".into()),
            r.speed,
            r.flight,
            r.effective_levels.map(|e| format!("{e} (virtual, pitch 15°)")).unwrap_or_else(|| "all".into()),
            r.summary.psnr_min.map(|p| format!("{p:.1}")).unwrap_or_else(|| "∞ (identical)".into()),
            r.summary.max_error,
            r.summary.coarser_pixel_share * 100.0,
            r.summary.bytes_read as f64 / 1e6,
            r.summary.tiles_read,
            r.summary.ticks_over_budget
        );
    }
    o
}
