//! How a height texture is held on the GPU and drawn (docs/GPU.md, "Heights"): the format and
//! false-colour range, the conversion of `l16` and `l16i` texels to metres on upload, and the
//! false colour as the shader computes it. Below both the GPU code and the heights check, which
//! use it.

use clipmap::height::{HeightFormat, HeightStorage, HEIGHT_LIMIT_M};
use serde::Serialize;

/// What the GPU holds for a nodata texel of an `l16` or `l16i` texture, converted to metres on
/// upload: a value no height takes (every height a format holds lies within 10^7 m of zero).
pub const CONVERTED_NODATA: f32 = -f32::MAX;

/// The false-colour range of an `l32f` texture unless told otherwise: the height verification
/// texture's, Mariana Trench to Everest.
pub const L32F_RANGE: [f64; 2] = [-11000.0, 8900.0];

/// The false-colour ramp's stops (8-bit values), low to high, every quarter of the range; as
/// `ramp_stop` in ground.wgsl.
const RAMP: [[f32; 3]; 5] =
    [[20.0, 40.0, 140.0], [40.0, 120.0, 220.0], [60.0, 160.0, 80.0], [170.0, 130.0, 70.0], [250.0, 250.0, 250.0]];

/// How a height texture is held and drawn: its format (from the mapping's heights block) and the
/// false-colour range.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct HeightShading {
    /// Storage, scale, offset, nodata value.
    pub format: HeightFormat,
    /// Heights drawn from the ramp's first colour to its last, metres (clamped outside).
    pub range: [f64; 2],
}

/// Checks a `--height-range`: finite, low below high, within the heights any format holds.
pub fn check_range(r: [f64; 2]) -> Result<[f64; 2], String> {
    let ok = r.iter().all(|x| x.is_finite() && x.abs() <= HEIGHT_LIMIT_M) && r[1] - r[0] >= 1e-3;
    if ok {
        Ok(r)
    } else {
        Err(format!(
            "{},{}: expected MIN,MAX in metres, MIN at least a millimetre below MAX, both within {HEIGHT_LIMIT_M} m of \
             zero (e.g. -11000,8900)",
            r[0], r[1]
        ))
    }
}

impl HeightShading {
    /// `format` drawn over `range`, or by default the format's whole range (`l16`, `l16i`: what
    /// the storage holds with the scale and offset; `l32f`: [`L32F_RANGE`]).
    pub fn new(format: HeightFormat, range: Option<[f64; 2]>) -> HeightShading {
        let range = range.unwrap_or_else(|| match format.storage() {
            HeightStorage::F32 => L32F_RANGE,
            _ => {
                let (lo, hi) = format.metre_bounds();
                [lo, hi]
            }
        });
        HeightShading { format, range }
    }

    /// Whether the GPU's texels are converted from the published ones (`l16`, `l16i`).
    pub fn converted(&self) -> bool {
        self.format.storage() != HeightStorage::F32
    }

    /// The nodata value as the GPU holds it, if any.
    pub fn gpu_nodata(&self) -> Option<f32> {
        let n = self.format.nodata()?;
        Some(if self.converted() { CONVERTED_NODATA } else { n as f32 })
    }

    /// The shader's `heights` uniform: nodata as held, 1 when there is one, the range's low end
    /// and 1 / (high - low), each rounded to f32 once.
    pub fn uniform(&self) -> [f32; 4] {
        let [lo, hi] = self.range;
        let nodata = self.gpu_nodata();
        [nodata.unwrap_or(0.0), if nodata.is_some() { 1.0 } else { 0.0 }, lo as f32, (1.0 / (hi - lo)) as f32]
    }

    /// Published texels to what the GPU holds: `l32f` as it is; `l16`, `l16i` to metres
    /// (`stored x scale + offset` in f64, rounded to f32 once), nodata to [`CONVERTED_NODATA`].
    pub fn to_gpu(&self, src: &[u8], out: &mut Vec<u8>) {
        out.clear();
        if !self.converted() {
            out.extend_from_slice(src);
            return;
        }
        for t in src.chunks_exact(self.format.bytes_per_texel()) {
            let v = match self.format.decode(self.format.read(t)) {
                Some(m) => m as f32,
                None => CONVERTED_NODATA,
            };
            out.extend_from_slice(&v.to_le_bytes());
        }
    }

    /// Height `h` (the shader's f32) in false colour, as `false_colour` in ground.wgsl computes
    /// it: the same f32 operations in the same order.
    pub fn colour(&self, h: f32) -> [u8; 4] {
        let u = self.uniform();
        let x = ((h - u[2]) * u[3]).clamp(0.0, 1.0) * 4.0;
        let i = (x.floor() as i32).min(3) as usize;
        let w = x - i as f32;
        let (a, b) = (RAMP[i], RAMP[i + 1]);
        let c = [0, 1, 2].map(|k| a[k] + (b[k] - a[k]) * w);
        let q = |y: f32| {
            let r = y.floor();
            r as u8 + u8::from(y - r >= 0.5)
        };
        [q(c[0]), q(c[1]), q(c[2]), 255]
    }
}
