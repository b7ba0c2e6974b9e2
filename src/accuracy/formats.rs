//! The study's texel-format axis: what a block-compressed format (`bc7`, `bc1`, `bc4`; docs/SHM.md,
//! "Block-compressed formats") costs in accuracy against the uncompressed texels it was encoded
//! from, beside the bytes and time it buys.
//!
//! Per format, over any 8-bit RGBA source (the study's terrain, or `clipbench formats`' prepared
//! pyramid of a photograph): PSNR of level 0's decoded tiles against the uncompressed ones; PSNR
//! of the flight's frames rendered (trilinear) from the format's pyramid, decoded, against the
//! same frames rendered from the uncompressed pyramid (the clipmap itself adds nothing with an
//! ideal disk: it shows the full mipmap's texels); bytes a tile; encoding time a tile on one
//! thread; the image caches' bytes; and the bytes a renderer that mirrors the caches uploads a
//! frame (the tiles the clipmap reads in the flight, each once, at the format's bytes).
//!
//! Blocks are encoded exactly as the service encodes them ([`crate::source::BcSource`]) and
//! decoded with the independent decoder (`crate::shm::blocks`, `bcdec_rs`). `bc4` is measured on
//! the luminance the service encodes for it (a grey image), against that luminance uncompressed.

use super::cache::CachedSource;
use super::render::{render_mipmap, Camera};
use super::study::{compare, StudyError};
use crate::clip::{Clipmap, Settings};
use crate::roam::Flight;
use crate::sample::Filter;
use crate::source::bc::encoder_input;
use crate::source::{BcQuality, BcSource, SourceError, TextureDesc, TileId, TileSource};
use crate::texel::{Bc, TexelFormat};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

/// A block format's tiles decoded back to texels (`bcdec_rs`): what a renderer samples.
struct Decoded {
    blocks: BcSource,
    desc: TextureDesc,
}

impl TileSource for Decoded {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        let mut b = vec![0u8; self.blocks.desc().tile_bytes(tile.level)];
        self.blocks.read_tile(tile, &mut b)?;
        let [w, h] = self.desc.level(tile.level).tile;
        let texels = crate::shm::blocks::decode(self.blocks.bc(), &b, w, h).map_err(|e| SourceError::Pyramid {
            tile,
            kind: crate::source::FaultKind::Corrupt,
            problem: format!("decoding {} blocks: {e}", self.blocks.bc().name()),
        })?;
        out.copy_from_slice(&texels);
        Ok(())
    }
}

/// An RGBA8 source's luminance (L8), as the service computes it for `bc4`.
struct Grey {
    inner: Arc<dyn TileSource>,
    desc: TextureDesc,
}

impl TileSource for Grey {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        let mut rgba = vec![0u8; self.inner.desc().tile_bytes(tile.level)];
        self.inner.read_tile(tile, &mut rgba)?;
        let [w, h] = self.desc.level(tile.level).tile;
        let mut input = Vec::new();
        encoder_input(Bc::Bc4, self.inner.desc().format(), &rgba, w, h, &mut input).expect("8-bit texels");
        // The encoder's input is padded to whole blocks: its first w texels of each of h rows.
        let pw = w.div_ceil(4) as usize * 4;
        for (y, row) in out.chunks_exact_mut(w as usize).enumerate() {
            row.copy_from_slice(&input[y * pw..y * pw + w as usize]);
        }
        Ok(())
    }
}

/// One format's figures.
#[derive(Clone, Debug, Serialize)]
pub struct FormatRow {
    /// `rgba8`, `bc7`, `bc1`, `bc4`.
    pub format: String,
    /// The channels compared (`rgb`, or `grey` for `bc4`).
    pub channels: &'static str,
    /// Level 0's decoded tiles against the uncompressed ones, dB (`None`: identical).
    pub psnr_level0_db: Option<f64>,
    /// The rendered frames: the lowest PSNR of a frame, dB (`None`: identical).
    pub psnr_view_min_db: Option<f64>,
    /// The rendered frames: PSNR over all of them together, dB.
    pub psnr_view_db: Option<f64>,
    /// Bytes of a level-0 tile.
    pub tile_bytes: u64,
    /// Encoding a level-0 tile on one thread (the service's path), microseconds.
    pub encode_us_per_tile: f64,
    /// The image caches' bytes (every level's slots).
    pub mapping_bytes: u64,
    /// Level 0's image cache against RGBA8's (the pyramid's 2 x 2 and 1 x 1 tops take a whole
    /// block each, so the whole caches are a little above this).
    pub mapping_bytes_vs_rgba8: f64,
    /// Bytes a renderer that mirrors the caches uploads a frame of the flight.
    pub upload_bytes_per_frame: f64,
    /// That against RGBA8's.
    pub upload_bytes_per_frame_vs_rgba8: f64,
}

/// PSNR over `n` channels of texels of `stride` bytes, and the squared error and count.
fn squared(a: &[u8], b: &[u8], stride: usize, n: usize) -> (f64, u64) {
    let mut se = 0.0;
    for (p, q) in a.chunks_exact(stride).zip(b.chunks_exact(stride)) {
        for c in 0..n {
            let d = p[c] as f64 - q[c] as f64;
            se += d * d;
        }
    }
    (se, (a.len() / stride * n) as u64)
}

fn psnr(se: f64, n: u64) -> Option<f64> {
    (se > 0.0 && n > 0).then(|| 10.0 * (255.0f64 * 255.0 / (se / n as f64)).log10())
}

/// The formats measured: `None` is RGBA8 itself.
pub const FORMATS: [Option<Bc>; 4] = [None, Some(Bc::Bc7), Some(Bc::Bc1), Some(Bc::Bc4)];

/// The flight and camera of `case` over `src` (8-bit RGBA), for each of `formats`, BC7 at
/// `quality`. `tiles`: how many level-0 tiles (from the flight's start) the level-0 PSNR and the
/// encoding time are taken over.
pub fn run(
    case: &super::study::Case,
    src: Arc<dyn TileSource>,
    formats: &[Option<Bc>],
    quality: BcQuality,
    tiles: usize,
) -> Result<Vec<FormatRow>, StudyError> {
    if src.desc().format() != TexelFormat::RGBA8 {
        return Err(StudyError::Format(format!(
            "the format axis measures an rgba8 source, not {}",
            src.desc().format().short_name()
        )));
    }
    let flight: Flight = case.flight.parse()?;
    let size = src.desc().size();
    let start = [size[0] as f64 / 2.0, size[1] as f64 / 2.0];
    let heading = {
        let (a, b) = (flight.position(start, 0), flight.position(start, 1));
        if (b[0] - a[0]).abs() + (b[1] - a[1]).abs() < 1e-9 {
            0.0
        } else {
            (b[1] - a[1]).atan2(b[0] - a[0]).to_degrees()
        }
    };
    let cams: Vec<Camera> = (0..case.frames)
        .map(|f| {
            let foot = flight.position(start, f);
            Camera::following(foot, case.eye_height, heading, case.pitch_deg, case.fov_deg, case.display)
        })
        .collect();
    // The tiles the clipmap reads in the flight (an ideal disk), the same for every format.
    let mut map = Clipmap::new(src.clone(), Settings { budget_ns: None, ..Settings::default() })?;
    let mut read = 0u64;
    for f in 0..case.frames {
        let foot = flight.position(start, f);
        let r = map.tick([foot[0].floor() as i64, foot[1].floor() as i64], None);
        map.wait_for_reads();
        read += r.tiles_read;
    }
    let tiles_a_frame = read as f64 / case.frames.max(1) as f64;
    let rgba8_cache = map.memory().placement().levels[0].slot_bytes * map.memory().placement().levels[0].slot_count;
    drop(map);
    // Level-0 tiles from the flight's start outwards.
    let d0 = src.desc().level(0);
    let across = [d0.size[0].div_ceil(d0.tile[0]), d0.size[1].div_ceil(d0.tile[1])];
    let (cs, ct) =
        ((start[0] as u64 / d0.tile[0]).min(across[0] - 1), (start[1] as u64 / d0.tile[1]).min(across[1] - 1));
    let side = (tiles as f64).sqrt().ceil() as u64;
    let ids: Vec<TileId> = (0..side)
        .flat_map(|j| (0..side).map(move |i| (i, j)))
        .map(|(i, j)| TileId::new(0, (cs + i).min(across[0] - 1), (ct + j).min(across[1] - 1)))
        .take(tiles.max(1))
        .collect();

    let rgb_ref: Arc<dyn TileSource> = Arc::new(CachedSource::new(src.clone(), 512));
    let grey = || -> Result<Arc<dyn TileSource>, StudyError> {
        let desc = src.desc().clone().with_format(TexelFormat::L8)?;
        Ok(Arc::new(Grey { inner: src.clone(), desc }))
    };
    let grey_ref: Option<Arc<dyn TileSource>> =
        if formats.contains(&Some(Bc::Bc4)) { Some(Arc::new(CachedSource::new(grey()?, 512))) } else { None };
    let mut rows = Vec::new();
    let mut base_upload = 0.0;
    for &bc in formats {
        let reference = if bc == Some(Bc::Bc4) { grey_ref.clone().expect("made for bc4") } else { rgb_ref.clone() };
        let (stride, n) = if bc == Some(Bc::Bc4) { (1, 1) } else { (4, 3) };
        let (test, tile_bytes, mapping_bytes, level0_cache): (Arc<dyn TileSource>, u64, u64, u64) = match bc {
            None => {
                let map = Clipmap::new(src.clone(), Settings::default())?;
                let all = map.memory().placement().slot_bytes();
                (rgb_ref.clone(), src.desc().tile_bytes(0) as u64, all, rgba8_cache)
            }
            Some(bc) => {
                let blocks = BcSource::new(src.clone(), bc, quality).map_err(|e| StudyError::Format(e.to_string()))?;
                let map = Clipmap::new(
                    Arc::new(BcSource::new(src.clone(), bc, quality).map_err(|e| StudyError::Format(e.to_string()))?),
                    Settings::default(),
                )?;
                let p = map.memory().placement();
                let (all, l0) = (p.slot_bytes(), p.levels[0].slot_bytes * p.levels[0].slot_count);
                let tile_bytes = blocks.desc().tile_bytes(0) as u64;
                let decoded_format = crate::sample::blocks::decoded_format(bc);
                let desc = src.desc().clone().with_format(decoded_format)?;
                (Arc::new(CachedSource::new(Arc::new(Decoded { blocks, desc }), 512)), tile_bytes, all, l0)
            }
        };
        // Level 0.
        let (mut se, mut count) = (0.0, 0u64);
        let mut want = vec![0u8; reference.desc().tile_bytes(0)];
        let mut got = vec![0u8; test.desc().tile_bytes(0)];
        for &id in &ids {
            reference.read_tile(id, &mut want)?;
            test.read_tile(id, &mut got)?;
            let (s, c) = squared(&want, &got, stride, n);
            se += s;
            count += c;
        }
        // Encoding time, one thread, the service's path.
        let encode_us = match bc {
            None => 0.0,
            Some(bc) => {
                let blocks = BcSource::new(src.clone(), bc, quality).map_err(|e| StudyError::Format(e.to_string()))?;
                let mut rgba: Vec<Vec<u8>> = Vec::new();
                for &id in &ids {
                    let mut t = vec![0u8; src.desc().tile_bytes(0)];
                    src.read_tile(id, &mut t)?;
                    rgba.push(t);
                }
                let [w, h] = d0.tile;
                let mut out = vec![0u8; blocks.desc().tile_bytes(0)];
                let mut input = Vec::new();
                let t = Instant::now();
                for tile in &rgba {
                    if matches!(bc, Bc::Bc1 | Bc::Bc7) {
                        crate::source::bc::encode_padded(bc, quality, false, tile, w, h, &mut out);
                    } else {
                        encoder_input(bc, TexelFormat::RGBA8, tile, w, h, &mut input).expect("8-bit texels");
                        crate::source::bc::encode_padded(bc, quality, false, &input, w, h, &mut out);
                    }
                }
                t.elapsed().as_secs_f64() * 1e6 / rgba.len() as f64
            }
        };
        // The rendered view.
        let (mut vse, mut vcount, mut vmin) = (0.0, 0u64, None::<f64>);
        for cam in &cams {
            let a = render_mipmap(cam, &*reference, Filter::Trilinear);
            let b = render_mipmap(cam, &*test, Filter::Trilinear);
            let (p, _, _) = compare(&a, &b);
            if let Some(p) = p {
                vmin = Some(vmin.map_or(p, |m: f64| m.min(p)));
            }
            for (x, y) in a.iter().zip(&b).filter(|(x, _)| x.ground) {
                for c in 0..n {
                    let d = x.rgba[c] as f64 - y.rgba[c] as f64;
                    vse += d * d;
                }
                vcount += n as u64;
            }
        }
        let upload = tiles_a_frame * tile_bytes as f64;
        if bc.is_none() {
            base_upload = upload;
        }
        rows.push(FormatRow {
            format: bc.map(|b| b.name().to_string()).unwrap_or_else(|| "rgba8".into()),
            channels: if bc == Some(Bc::Bc4) { "grey" } else { "rgb" },
            psnr_level0_db: psnr(se, count),
            psnr_view_min_db: vmin,
            psnr_view_db: psnr(vse, vcount),
            tile_bytes,
            encode_us_per_tile: encode_us,
            mapping_bytes,
            mapping_bytes_vs_rgba8: level0_cache as f64 / rgba8_cache as f64,
            upload_bytes_per_frame: upload,
            upload_bytes_per_frame_vs_rgba8: if base_upload > 0.0 { upload / base_upload } else { f64::NAN },
        });
    }
    Ok(rows)
}

/// The rows as a Markdown table.
pub fn table(rows: &[FormatRow]) -> String {
    let db = |p: Option<f64>| p.map(|p| format!("{p:.2}")).unwrap_or_else(|| "∞".into());
    let mut s = String::from(
        "| format | PSNR level 0 dB | PSNR view dB (all frames / worst frame) | bytes a tile | encode µs a tile | \
         image caches bytes | vs RGBA8 | upload bytes a frame | vs RGBA8 |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        s += &format!(
            "| {}{} | {} | {} / {} | {} | {:.0} | {} | {} | {:.0} | {} |\n",
            r.format,
            if r.channels == "grey" { " (grey)" } else { "" },
            db(r.psnr_level0_db),
            db(r.psnr_view_db),
            db(r.psnr_view_min_db),
            r.tile_bytes,
            r.encode_us_per_tile,
            r.mapping_bytes,
            r.mapping_bytes_vs_rgba8,
            r.upload_bytes_per_frame,
            r.upload_bytes_per_frame_vs_rgba8
        );
    }
    s
}

/// PSNR against bytes a tile as an SVG chart: level 0 and the rendered view for the RGB formats
/// (`bc1`, `bc7`), and `bc4`'s on the grey image. RGBA8 (the reference, identical) has no point.
pub fn plot(rows: &[FormatRow]) -> String {
    let points = |grey: bool, view: bool| -> Vec<(f64, f64)> {
        let mut p: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| (r.channels == "grey") == grey)
            .filter_map(|r| {
                let db = if view { r.psnr_view_db } else { r.psnr_level0_db };
                db.map(|d| (r.tile_bytes as f64, d))
            })
            .collect();
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        p
    };
    let series = vec![
        ("bc1, bc7: level 0".to_string(), points(false, false)),
        ("bc1, bc7: view".to_string(), points(false, true)),
        ("bc4 grey: level 0".to_string(), points(true, false)),
        ("bc4 grey: view".to_string(), points(true, true)),
    ];
    super::sweep::svg_chart("PSNR against bytes a tile", "bytes a tile", "PSNR dB", &series, true)
}

/// The heading of the format axis' section of `ACCURACY.md`, written from `clipbench formats`'
/// figures (docs/BENCHMARKS.md): `clipbench accuracy` regenerates the sections above it and keeps
/// this one as it finds it.
pub const SECTION: &str = "## The texel format axis: block compression";

/// The format axis' section of an `ACCURACY.md` (from its heading to the end), if it has one.
pub fn kept_section(report: &str) -> Option<&str> {
    let at = report.match_indices(SECTION).find(|(i, _)| *i == 0 || report[..*i].ends_with('\n'))?.0;
    Some(&report[at..])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_format_section_is_kept_from_its_heading_to_the_end() {
        let report = format!("# Accuracy\n\nsweep\n\n{SECTION}\n\n| format |\n|---|\n| bc1 |\n");
        assert_eq!(kept_section(&report), Some(&report[report.find("## The texel").unwrap()..]));
        assert_eq!(kept_section("# Accuracy\n\nsweep only\n"), None);
        // Named inside a line (not a heading): not the section.
        assert_eq!(kept_section(&format!("see `{SECTION}` below\n")), None);
    }

    #[test]
    fn the_plot_has_a_point_for_each_measured_block_format() {
        let row = |format: &str, channels: &'static str, tile_bytes: u64, db: Option<f64>| FormatRow {
            format: format.into(),
            channels,
            psnr_level0_db: db,
            psnr_view_min_db: db,
            psnr_view_db: db,
            tile_bytes,
            encode_us_per_tile: 0.0,
            mapping_bytes: 0,
            mapping_bytes_vs_rgba8: 1.0,
            upload_bytes_per_frame: 0.0,
            upload_bytes_per_frame_vs_rgba8: 1.0,
        };
        let rows = [
            row("rgba8", "rgb", 65536, None),
            row("bc7", "rgb", 16384, Some(44.0)),
            row("bc1", "rgb", 8192, Some(34.5)),
            row("bc4", "grey", 8192, Some(41.0)),
        ];
        let svg = plot(&rows);
        assert!(svg.starts_with("<svg") && svg.contains("bytes a tile"));
        // bc7 and bc1 twice (level 0, view), bc4 twice; RGBA8 none.
        assert_eq!(svg.matches("<circle").count(), 6, "{svg}");
    }

    #[test]
    fn psnr_is_none_for_identical_texels_and_falls_with_the_error() {
        let a = [10u8, 20, 30, 255, 40, 50, 60, 255];
        let (se, n) = squared(&a, &a, 4, 3);
        assert_eq!((se, n), (0.0, 6));
        assert_eq!(psnr(se, n), None);
        let b = [11u8, 20, 30, 0, 40, 50, 60, 0];
        let (se, n) = squared(&a, &b, 4, 3);
        // One unit of error over six channels (alpha not compared): 10 log10(255^2 * 6).
        assert!((psnr(se, n).unwrap() - 10.0 * (255.0f64 * 255.0 * 6.0).log10()).abs() < 1e-9);
        let c = [14u8, 20, 30, 0, 40, 50, 60, 0];
        assert!(psnr(squared(&a, &c, 4, 3).0, 6).unwrap() < psnr(se, n).unwrap());
    }
}
