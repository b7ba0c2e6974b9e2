//! Heights (docs/ELEVATION.md): level 0 of a height texture in stored values of its format
//! (`l32f`, `l16`, `l16i`), from the height verification texture or a single-band elevation
//! TIFF ([`super::tiff_stream::HeightTiff`]), and each coarser level made from the finer one by
//! the texture's level rule ([`HeightFormat::reduce`]: nodata never averaged in; `point` takes
//! the finer texel at the even position), row by row like the colour filters.
//!
//! The encodings and rules are [`crate::height`]'s; this module only moves rows.

use super::band::BandSource;
use super::error::PrepError;
use crate::height::{HeightFormat, LevelRule, NonFinite};
use crate::plan::HeightPlan;
use crate::source::procedural::height_stored;
use rayon::prelude::*;

/// What a height preparation writes: the format, the level rule and what non-finite input becomes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeightPrep {
    /// Storage, scale, offset and nodata value of the output.
    pub format: HeightFormat,
    /// How each coarser level is made from the finer one.
    pub rule: LevelRule,
    /// What NaN and infinite input heights become (refused, or the nodata value).
    pub non_finite: NonFinite,
}

impl HeightPrep {
    /// The `#clipmap height` settings the `.ct` carries.
    pub fn plan(&self) -> HeightPlan {
        HeightPlan { format: self.format, levels: self.rule }
    }
}

/// Where level-0 heights come from.
pub enum HeightInput {
    /// The height verification texture's level 0 (`source::procedural::height_stored`) in the
    /// output format: the texels `clipmapd --source heights` serves at level 0 when the format is
    /// `l32f` with nodata -32768.
    Verification,
    /// A single-band elevation TIFF, streamed, padded with nodata up to the layout's size.
    Tiff(Box<super::tiff_stream::HeightTiff>),
}

/// Level 0 of the height verification texture in `format`.
pub(crate) struct VerificationLevel0 {
    /// The output format.
    pub format: HeightFormat,
    /// Level-0 width.
    pub width: u64,
}

impl BandSource for VerificationLevel0 {
    fn fill(&mut self, t0: u64, _rows: usize, out: &mut [u8]) -> Result<(), PrepError> {
        let bpt = self.format.bytes_per_texel();
        let row_bytes = self.width as usize * bpt;
        let f = self.format;
        out.par_chunks_mut(row_bytes).enumerate().for_each(|(i, row)| {
            for (s, texel) in row.chunks_exact_mut(bpt).enumerate() {
                f.write(height_stored(&f, 0, s as u64, t0 + i as u64), texel);
            }
        });
        Ok(())
    }
}

/// Builds level k + 1 of heights from the rows of level k (twice as wide and tall: the layout's
/// levels halve exactly), one coarser row for each pair of finer rows.
pub(crate) struct HeightReducer {
    format: HeightFormat,
    rule: LevelRule,
    src_w: usize,
    /// The even row, waiting for its odd partner.
    even: Option<Vec<u8>>,
}

impl HeightReducer {
    /// A reducer from a level `src_w` texels wide (even).
    pub fn new(format: HeightFormat, rule: LevelRule, src_w: u64) -> HeightReducer {
        HeightReducer { format, rule, src_w: src_w as usize, even: None }
    }

    /// Bytes of one coarser row.
    pub fn dst_row_bytes(&self) -> usize {
        self.src_w / 2 * self.format.bytes_per_texel()
    }

    /// Takes the next finer row; appends the coarser row it completes (every second one) to `out`.
    pub fn push(&mut self, row: &[u8], out: &mut Vec<u8>) -> usize {
        let Some(even) = self.even.take() else {
            self.even = Some(row.to_vec());
            return 0;
        };
        let (f, b) = (self.format, self.format.bytes_per_texel());
        let at = |r: &[u8], s: usize| f.read(&r[s * b..]);
        let start = out.len();
        out.resize(start + self.dst_row_bytes(), 0);
        for (s, texel) in out[start..].chunks_exact_mut(b).enumerate() {
            let (s0, s1) = (2 * s, 2 * s + 1);
            let v = f.reduce(self.rule, at(&even, s0), &[at(&even, s1), at(row, s0), at(row, s1)]);
            f.write(v, texel);
        }
        1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::height::HeightStorage;

    #[test]
    fn the_reducer_is_the_level_rule_of_height_rs() {
        let f = HeightFormat::new(HeightStorage::I16, 0.5, 0.0, Some(-32768.0)).unwrap();
        let (w, h) = (8usize, 4usize);
        let v: Vec<f64> =
            (0..w * h).map(|i| if i % 7 == 3 { -32768.0 } else { ((i * 7919) % 60_001) as f64 - 30_000.0 }).collect();
        for rule in LevelRule::ALL {
            let want = f.reduce_level(rule, &v, w, h).unwrap();
            let mut r = HeightReducer::new(f, rule, w as u64);
            let mut out = Vec::new();
            let mut produced = 0;
            for row in v.chunks_exact(w) {
                let mut bytes = vec![0u8; w * 2];
                for (x, t) in row.iter().zip(bytes.chunks_exact_mut(2)) {
                    f.write(*x, t);
                }
                produced += r.push(&bytes, &mut out);
            }
            assert_eq!(produced, h / 2);
            let got: Vec<f64> = out.chunks_exact(2).map(|t| f.read(t)).collect();
            assert_eq!(got, want, "{rule}");
        }
    }
}
