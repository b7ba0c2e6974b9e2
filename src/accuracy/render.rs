//! The reference renderer: a pinhole camera over the ground plane z = 0, where one world unit is
//! one level-0 texel; per-pixel LOD from the screen-space derivatives of the texture coordinates;
//! trilinear filtering (or point / bilinear) through [`crate::sample`].

use crate::clip::Clipmap;
use crate::sample::{sample_clipmap, sample_mapping_held, Filter, MipmapSampler};
use crate::shm::{Client, Snapshot};
use crate::source::TileSource;
use rayon::prelude::*;

/// A camera looking at the ground.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position: ground coordinates (level-0 texels) and height above the ground.
    pub eye: [f64; 3],
    /// Heading in degrees from the +s axis.
    pub heading_deg: f64,
    /// Pitch below the horizon in degrees (90: straight down).
    pub pitch_deg: f64,
    /// Horizontal field of view in degrees.
    pub fov_deg: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

/// Where a pixel looks: texture coordinates and the ideal LOD.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    /// Texture coordinates in level-0 texel units.
    pub uv: [f64; 2],
    /// log2 of the larger screen-space derivative (texels per pixel), unclamped.
    pub lod: f64,
}

impl Camera {
    /// The forward, right and up unit vectors (right-handed, up towards +z when level).
    pub fn basis(&self) -> ([f64; 3], [f64; 3], [f64; 3]) {
        let (h, p) = (self.heading_deg.to_radians(), self.pitch_deg.to_radians());
        let forward = [h.cos() * p.cos(), h.sin() * p.cos(), -p.sin()];
        let right = [h.sin(), -h.cos(), 0.0];
        // up = right x forward
        let up = [
            right[1] * forward[2] - right[2] * forward[1],
            right[2] * forward[0] - right[0] * forward[2],
            right[0] * forward[1] - right[1] * forward[0],
        ];
        (forward, right, up)
    }

    /// Ground hit of the ray through image point (x, y) (pixel units, y down), if it hits.
    pub fn ground(&self, x: f64, y: f64) -> Option<[f64; 2]> {
        let (f, r, u) = self.basis();
        let tan = (self.fov_deg.to_radians() / 2.0).tan();
        let nx = (2.0 * x / self.width as f64 - 1.0) * tan;
        let ny = (1.0 - 2.0 * y / self.height as f64) * tan * self.height as f64 / self.width as f64;
        let d = [f[0] + nx * r[0] + ny * u[0], f[1] + nx * r[1] + ny * u[1], f[2] + nx * r[2] + ny * u[2]];
        if d[2] >= -1e-9 {
            return None;
        }
        let t = self.eye[2] / -d[2];
        Some([self.eye[0] + t * d[0], self.eye[1] + t * d[1]])
    }

    /// The footprint of pixel (i, j): coordinates at its centre, LOD from the differences to its
    /// right and lower neighbours. `None` for sky.
    pub fn footprint(&self, i: u32, j: u32) -> Option<Footprint> {
        let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
        let c = self.ground(x, y)?;
        let dx = self.ground(x + 1.0, y).or_else(|| self.ground(x - 1.0, y))?;
        let dy = self.ground(x, y + 1.0).or_else(|| self.ground(x, y - 1.0))?;
        let len = |a: [f64; 2]| ((a[0] - c[0]).powi(2) + (a[1] - c[1]).powi(2)).sqrt();
        let rho = len(dx).max(len(dy)).max(1e-12);
        Some(Footprint { uv: c, lod: rho.log2() })
    }

    /// The camera `height` above `foot`, looking along `heading_deg` and down by `pitch_deg`.
    pub fn following(
        foot: [f64; 2],
        height: f64,
        heading_deg: f64,
        pitch_deg: f64,
        fov_deg: f64,
        size: [u32; 2],
    ) -> Self {
        Camera { eye: [foot[0], foot[1], height], heading_deg, pitch_deg, fov_deg, width: size[0], height: size[1] }
    }
}

/// One rendered pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pixel {
    /// Colour quantised to 8 bits per channel (RGBA).
    pub rgba: [u8; 4],
    /// Colour quantised to 16 bits per channel (RGBA), for the comparison of 16-bit textures.
    pub rgba16: [u16; 4],
    /// LOD used.
    pub lod: f64,
    /// False for sky and for ground outside the texture.
    pub ground: bool,
}

const SKY: Pixel =
    Pixel { rgba: [140, 180, 230, 255], rgba16: [140 * 257, 180 * 257, 230 * 257, 65535], lod: 0.0, ground: false };

/// Black ground: where the clipmap has no level to sample.
const BLACK: [f32; 4] = [0.0, 0.0, 0.0, 1.0];

fn quantise(c: [f32; 4]) -> [u8; 4] {
    c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
}

fn quantise16(c: [f32; 4]) -> [u16; 4] {
    c.map(|v| (v.clamp(0.0, 1.0) as f64 * 65535.0).round() as u16)
}

fn ground(c: [f32; 4], lod: f64) -> Pixel {
    Pixel { rgba: quantise(c), rgba16: quantise16(c), lod, ground: true }
}

fn in_texture(uv: [f64; 2], size: [u64; 2]) -> bool {
    uv[0] >= 0.0 && uv[1] >= 0.0 && uv[0] < size[0] as f64 && uv[1] < size[1] as f64
}

/// Renders from the full mipmap (the ground truth).
pub(crate) fn render_mipmap(cam: &Camera, source: &dyn TileSource, filter: Filter) -> Vec<Pixel> {
    let size = source.desc().size();
    let last = source.desc().level_count() as f64 - 1.0;
    let rows: Vec<Vec<Pixel>> = (0..cam.height)
        .into_par_iter()
        .map(|j| {
            let mut sampler = MipmapSampler::new(source);
            (0..cam.width)
                .map(|i| match cam.footprint(i, j) {
                    Some(fp) if in_texture(fp.uv, size) => {
                        let lod = fp.lod.clamp(0.0, last);
                        match sampler.sample(filter, fp.uv[0], fp.uv[1], lod) {
                            Ok(c) => ground(c, lod),
                            Err(_) => SKY,
                        }
                    }
                    _ => SKY,
                })
                .collect()
        })
        .collect();
    rows.concat()
}

/// Renders from the clipmap as published (min LOD and the finest-available rule applied).
pub fn render_clipmap(cam: &Camera, map: &Clipmap, filter: Filter) -> Vec<Pixel> {
    render_clipmap_levels(cam, map, filter, None)
}

/// Renders from the clipmap seeing only the levels `lod_offset .. lod_offset + effective` (a
/// virtual clip texture, docs/PERFORMER-REFERENCE.md §2.7): the LOD asked for is clamped into that window.
pub(crate) fn render_clipmap_levels(
    cam: &Camera,
    map: &Clipmap,
    filter: Filter,
    window: Option<(u32, u32)>,
) -> Vec<Pixel> {
    let size = map.desc().size();
    let count = map.level_count() as f64;
    let (lo, last) = match window {
        Some((offset, effective)) => (offset as f64, (offset as f64 + effective.max(1) as f64 - 1.0).min(count - 1.0)),
        None => (0.0, count - 1.0),
    };
    // A texture that wraps in longitude has no west or east edge, as in `mapping_pixel`.
    let wraps = map.level(0).wrap;
    (0..cam.height)
        .flat_map(|j| (0..cam.width).map(move |i| (i, j)))
        .map(|(i, j)| match cam.footprint(i, j) {
            Some(fp) if in_texture(fp.uv, size) || wraps && fp.uv[1] >= 0.0 && fp.uv[1] < size[1] as f64 => {
                match sample_clipmap(map, filter, fp.uv[0], fp.uv[1], fp.lod.clamp(lo, last)) {
                    Some(s) => ground(s.rgba, s.lod),
                    None => ground(BLACK, last),
                }
            }
            _ => SKY,
        })
        .collect()
}

/// Renders from a service's mapping as a reader sees it in one snapshot (`snap`, taken by the
/// caller): the same camera, LOD and sampling as [`render_clipmap`], through
/// `crate::sample::sample_mapping_in`. The GPU client (`clipgpu`) compares its frames with this.
pub fn render_mapping(cam: &Camera, client: &Client, snap: &Snapshot, filter: Filter) -> Vec<Pixel> {
    let rows: Vec<Vec<Pixel>> = (0..cam.height)
        .into_par_iter()
        .map(|j| {
            (0..cam.width)
                .map(|i| match cam.footprint(i, j) {
                    Some(fp) => mapping_pixel(client, snap, None, filter, fp.uv, fp.lod),
                    None => SKY,
                })
                .collect()
        })
        .collect();
    rows.concat()
}

/// One pixel of [`render_mapping`] whose footprint is `uv` and `lod` (unclamped); `held`
/// restricts the texels available further (see `crate::sample::sample_mapping_held`).
fn mapping_pixel(
    client: &Client,
    snap: &Snapshot,
    held: Option<&(dyn Fn(u32, i64, i64) -> bool + Sync)>,
    filter: Filter,
    uv: [f64; 2],
    lod: f64,
) -> Pixel {
    let last = client.levels.len() as f64 - 1.0;
    // A texture that wraps in longitude has no west or east edge (docs/SHM.md, "How a region
    // wraps"): the ground goes on around the world, sampled at s mod width.
    let size = client.levels[0].size;
    let on = if client.wraps() { uv[1] >= 0.0 && uv[1] < size[1] as f64 } else { in_texture(uv, size) };
    if !on {
        return SKY;
    }
    let held = held.map(|h| h as &dyn Fn(u32, i64, i64) -> bool);
    match sample_mapping_held(client, snap, held, filter, uv[0], uv[1], lod.clamp(0.0, last)) {
        Some(s) => ground(s.rgba, s.lod),
        None => ground(BLACK, last),
    }
}

/// [`render_mapping`]'s pixels at footprints given rather than computed from a camera: pixel `n`
/// is sky for `None`, else shaded at `Some((uv, lod))` exactly as [`render_mapping`] shades a
/// pixel with that footprint. A renderer that computes its footprints itself (the GPU client, in
/// f32) checks its sampling with this at its own coordinates; `held` as in
/// `crate::sample::sample_mapping_held`.
pub fn render_mapping_at(
    client: &Client,
    snap: &Snapshot,
    held: Option<&(dyn Fn(u32, i64, i64) -> bool + Sync)>,
    filter: Filter,
    at: &[Option<([f64; 2], f64)>],
) -> Vec<Pixel> {
    at.par_iter()
        .map(|p| match *p {
            Some((uv, lod)) => mapping_pixel(client, snap, held, filter, uv, lod),
            None => SKY,
        })
        .collect()
}

/// Pixels to an RGBA image.
pub fn to_image(cam: &Camera, px: &[Pixel]) -> image::RgbaImage {
    let mut img = image::RgbaImage::new(cam.width, cam.height);
    for (p, out) in px.iter().zip(img.pixels_mut()) {
        out.0 = p.rgba;
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn looking_straight_down_the_centre_pixel_hits_the_foot_and_lod_follows_height() {
        let cam = Camera::following([1000.0, 2000.0], 100.0, 0.0, 90.0, 90.0, [200, 200]);
        let c = cam.ground(100.0, 100.0).unwrap();
        assert!((c[0] - 1000.0).abs() < 1e-6 && (c[1] - 2000.0).abs() < 1e-6, "{c:?}");
        // 90° over 200 px at 100 units: one pixel covers 2*100/200 = 1 texel at the centre.
        let fp = cam.footprint(100, 100).unwrap();
        assert!(fp.lod.abs() < 0.01, "{}", fp.lod);
        let high = Camera::following([1000.0, 2000.0], 800.0, 0.0, 90.0, 90.0, [200, 200]);
        assert!((high.footprint(100, 100).unwrap().lod - 3.0).abs() < 0.01);
    }

    #[test]
    fn the_horizon_is_sky_and_lod_grows_towards_it() {
        let cam = Camera::following([0.0, 0.0], 50.0, 30.0, 20.0, 60.0, [160, 120]);
        assert!(cam.footprint(80, 0).is_none(), "the top row looks above the horizon");
        let near = cam.footprint(80, 119).unwrap().lod;
        let far = cam.footprint(80, 60).unwrap().lod;
        assert!(far > near, "{far} <= {near}");
    }

    #[test]
    fn coordinates_stay_exact_near_the_far_corner_of_a_2_pow_26_texture() {
        let far = (1u64 << 26) as f64 - 10.0;
        let cam = Camera::following([far, far], 20.0, 45.0, 90.0, 60.0, [64, 64]);
        let a = cam.ground(32.0, 32.0).unwrap();
        let b = cam.ground(33.0, 32.0).unwrap();
        let step = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
        let want = 2.0 * 20.0 * (30f64).to_radians().tan() / 64.0;
        assert!((step - want).abs() / want < 1e-6, "{step} vs {want}");
    }
}
