//! The two halves of the comparison with the reference renderer (docs/GPU.md, "What is
//! bit-exact"):
//!
//! - **sampling**: the CPU reference sampler run at the very coordinates and LOD the shader
//!   used (read back with the frame), against the same snapshot and the texels the GPU holds,
//!   must give the GPU's pixel; with point filtering on every pixel.
//! - **geometry**: how far the shader's f32 footprints are from the f64 camera's, against a
//!   per-pixel bound derived from f32 rounding.

pub use crate::diff::SamplingDiff;
use crate::gpu::{Frame, LevelShape};
use clipmap::accuracy::render::{render_mapping_at, Camera};
use clipmap::sample::Filter;
use clipmap::shm::{Client, Snapshot};
use serde::Serialize;

/// The unit roundoff of f32 (half an ulp of 1).
const EPS: f64 = 1.0 / (1u64 << 24) as f64;

/// The geometry half: the GPU's footprints against the f64 camera's.
#[derive(Clone, Debug, Default, Serialize)]
pub struct GeometryDiff {
    /// Pixels that are ground in both and were compared.
    pub compared: u64,
    /// Pixels that are ground for one and sky (or off the texture) for the other.
    pub ground_mismatch: u64,
    /// Largest |Δu|, |Δv|, level-0 texels.
    pub max_coord_error: f64,
    /// Largest |Δ LOD| (both clamped to the levels).
    pub max_lod_error: f64,
    /// Largest ratio of an error to its bound (coordinates or LOD): at most 1 when the bound
    /// holds.
    pub bound_ratio: f64,
}

/// Runs the CPU sampler at the GPU's footprints (`render_mapping_at`) under `snap` with its min
/// LOD as the shader saw it (f32), seeing only texels the GPU's slot tags say it holds, and
/// compares with the GPU's pixels.
pub fn sampling(
    client: &Client,
    snap: &Snapshot,
    levels: &[LevelShape],
    held: &[Vec<([i64; 2], bool)>],
    filter: Filter,
    frame: &Frame,
) -> SamplingDiff {
    let mut snap32 = snap.clone();
    snap32.min_lod = snap.min_lod as f32 as f64;
    let at: Vec<Option<([f64; 2], f64)>> = (0..frame.lod.len()).map(|n| frame.footprint(n)).collect();
    let holds = |k: u32, s: i64, t: i64| -> bool {
        let l = levels[k as usize];
        let tile = [s.div_euclid(l.tile[0] as i64), t.div_euclid(l.tile[1] as i64)];
        let slot = clipmap::shm::layout::slot_index(l.grid, tile) as usize;
        held[k as usize].get(slot) == Some(&(tile, true))
    };
    let want = render_mapping_at(client, &snap32, Some(&holds), filter, &at);
    let mut d = SamplingDiff::default();
    for ((w, g), a) in want.iter().zip(frame.rgba.chunks_exact(4)).zip(&at) {
        d.compared += u64::from(a.is_some());
        let e = (0..4).map(|c| w.rgba[c].abs_diff(g[c]) as u16).max().unwrap_or(0);
        d.differing += u64::from(e > 0);
        d.max_error = d.max_error.max(e);
    }
    d
}

/// A ray's ground hit relative to the eye's foot in f64, and a first-order bound on how far the
/// shader's f32 evaluation of the same formula (`ground()` in ground.wgsl) may be from it, per
/// component, before the eye's position is added (docs/GPU.md derives it).
fn hit(cam: &Camera, x: f64, y: f64) -> Option<([f64; 2], [f64; 2])> {
    let (f, r, u) = cam.basis();
    let tan = (cam.fov_deg.to_radians() / 2.0).tan();
    let (w, h) = (cam.width as f64, cam.height as f64);
    let (a, b) = (2.0 * x / w, 2.0 * y / h);
    let nx = (a - 1.0) * tan;
    let ny = (1.0 - b) * tan * h / w;
    // nx: a division (2.5 ulp, Vulkan's bound), a subtraction, tan rounded, a product (0.5 ulp
    // each). ny: the same and two more products or divisions.
    let dnx = tan * (3.0 * a + (1.0 + a)) * EPS + 2.0 * nx.abs() * EPS;
    let dny = tan * h / w * (3.0 * b + (1.0 + b)) * EPS + 6.0 * ny.abs() * EPS;
    let d = [0, 1, 2].map(|i| f[i] + nx * r[i] + ny * u[i]);
    if d[2] >= -1e-9 {
        return None;
    }
    // d = f + nx r + ny u: the basis rounded, two products, two sums.
    let dd = [0, 1, 2].map(|i| {
        dnx * r[i].abs() + dny * u[i].abs() + 4.0 * EPS * (f[i].abs() + (nx * r[i]).abs() + (ny * u[i]).abs())
    });
    let t = cam.eye[2] / -d[2];
    // t = height / -d.z: the height rounded, a division.
    let rel_t = 4.0 * EPS + dd[2] / -d[2];
    let c = [t * d[0], t * d[1]];
    // c = t d: a product.
    let dc = [0, 1].map(|i| c[i].abs() * (rel_t + EPS) + t * dd[i]);
    Some((c, dc))
}

/// The footprint of pixel (i, j) as the shader computes it, in f64 (`Camera::footprint`'s
/// arithmetic, relative to the eye's foot), with bounds on the shader's errors: (uv, bound on
/// |Δu|, |Δv|; lod unclamped, bound on |Δ lod|).
fn footprint_bound(cam: &Camera, i: u32, j: u32) -> Option<([f64; 2], [f64; 2], f64, f64)> {
    let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
    let (c, dc) = hit(cam, x, y)?;
    let dx = hit(cam, x + 1.0, y).or_else(|| hit(cam, x - 1.0, y))?;
    let dy = hit(cam, x, y + 1.0).or_else(|| hit(cam, x, y - 1.0))?;
    let uv = [cam.eye[0] + c[0], cam.eye[1] + c[1]];
    let frac = [cam.eye[0] - cam.eye[0].floor(), cam.eye[1] - cam.eye[1].floor()];
    // rel = frac + c (frac rounded to f32, a sum), then rounded down to a multiple of 2^-24.
    let duv = [0, 1].map(|k| dc[k] + EPS * frac[k] + EPS * (frac[k] + c[k]).abs() + EPS);
    // rho = the larger |n - c| over the two neighbours: their errors, the subtraction's, and
    // length() (a dot product and Vulkan's sqrt, inherited from 1 / inversesqrt: 8 ulp in all).
    let mut rho = 0f64;
    let mut drho = 0f64;
    for (n, dn) in [dx, dy] {
        let e = [n[0] - c[0], n[1] - c[1]];
        let len = e[0].hypot(e[1]);
        let de = [0, 1].map(|k| dn[k] + dc[k] + EPS * e[k].abs());
        rho = rho.max(len);
        drho = drho.max(de[0].hypot(de[1]) + 8.0 * EPS * len);
    }
    let rho = rho.max(1e-12);
    let lod = rho.log2();
    // log2: absolute error 2^-21 on [0.5, 2], 3 ulp elsewhere (Vulkan).
    let dlod = drho / (rho * std::f64::consts::LN_2) + (2f64).powi(-21) + 6.0 * EPS * lod.abs();
    Some((uv, duv, lod, dlod))
}

/// The geometry half for one frame: every pixel that is ground (on the texture) for both.
pub fn geometry(cam: &Camera, levels: &[LevelShape], frame: &Frame) -> GeometryDiff {
    let last = levels.len() as f64 - 1.0;
    let s0 = levels[0].size;
    // A texture that wraps in longitude has no west or east edge.
    let wraps = levels[0].wraps;
    let on_texture =
        |uv: [f64; 2]| (wraps || (uv[0] >= 0.0 && uv[0] < s0[0] as f64)) && uv[1] >= 0.0 && uv[1] < s0[1] as f64;
    let mut g = GeometryDiff::default();
    for j in 0..cam.height {
        for i in 0..cam.width {
            let gpu = frame.footprint((j * cam.width + i) as usize);
            // The reference's own footprint (`Camera::footprint`), and the bounds for this pixel.
            let cpu = cam.footprint(i, j).filter(|f| on_texture(f.uv));
            let (Some((guv, glod)), Some(fp)) = (gpu, cpu) else {
                g.ground_mismatch += u64::from(gpu.is_some() != cpu.is_some());
                continue;
            };
            let Some((_, duv, _, dlod)) = footprint_bound(cam, i, j) else {
                g.ground_mismatch += 1;
                continue;
            };
            let (uv, lod) = (fp.uv, fp.lod);
            g.compared += 1;
            for k in 0..2 {
                let e = (guv[k] - uv[k]).abs();
                g.max_coord_error = g.max_coord_error.max(e);
                g.bound_ratio = g.bound_ratio.max(e / duv[k]);
            }
            let e = (glod - lod.clamp(0.0, last)).abs();
            g.max_lod_error = g.max_lod_error.max(e);
            g.bound_ratio = g.bound_ratio.max(e / dlod);
        }
    }
    g
}
