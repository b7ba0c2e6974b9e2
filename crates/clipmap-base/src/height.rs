//! Heights: the elevation encodings (`l32f` metres in 32-bit floats; `l16` and `l16i`, unsigned
//! and signed 16-bit steps with a scale and an offset), the nodata value, the level rules that
//! build a coarser level of heights from a finer one, and the range of heights a tile holds
//! (docs/ELEVATION.md).
//!
//! Everything here works on **stored values** (`f64` holding the stored number exactly: an `f32`
//! for `l32f`, an integer for `l16` and `l16i`) and turns them into metres only on request
//! (`metres = stored x scale + offset`), so that a level rule never rounds twice. It knows
//! nothing of files, levels or the plan (a room of the ground floor, docs/ARCHITECTURE.md §12).

use std::fmt;

/// How heights are stored, one value a texel, little-endian.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum HeightStorage {
    /// `l32f`: an IEEE 754 32-bit float, metres (scale 1, offset 0).
    F32,
    /// `l16`: an unsigned 16-bit integer, `metres = v x scale + offset`.
    U16,
    /// `l16i`: a signed 16-bit integer, `metres = v x scale + offset`.
    I16,
}

impl HeightStorage {
    /// Bytes one texel takes.
    pub fn bytes(self) -> usize {
        match self {
            HeightStorage::F32 => 4,
            HeightStorage::U16 | HeightStorage::I16 => 2,
        }
    }

    /// The short name the tools use (the texel format's: `l32f`, `l16`, `l16i`).
    pub fn short_name(self) -> &'static str {
        match self {
            HeightStorage::F32 => "l32f",
            HeightStorage::U16 => "l16",
            HeightStorage::I16 => "l16i",
        }
    }

    /// From a short name (`l32f`, `l16`, `l16i`).
    pub fn from_short_name(name: &str) -> Option<Self> {
        Some(match name {
            "l32f" => HeightStorage::F32,
            "l16" => HeightStorage::U16,
            "l16i" => HeightStorage::I16,
            _ => return None,
        })
    }

    /// The smallest and largest stored values of an integer storage (`None` for `l32f`).
    fn integer_bounds(self) -> Option<(i64, i64)> {
        match self {
            HeightStorage::F32 => None,
            HeightStorage::U16 => Some((0, u16::MAX as i64)),
            HeightStorage::I16 => Some((i16::MIN as i64, i16::MAX as i64)),
        }
    }
}

impl fmt::Display for HeightStorage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.short_name())
    }
}

/// How a coarser level of heights is made from the 2 x 2 block of finer texels below each texel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LevelRule {
    /// The mean of the texels of the block that have data, rounded to the nearest stored value
    /// (halves up for the 16-bit storages); nodata only when every texel of the block is.
    #[default]
    Mean,
    /// Point-registered: the finer texel at the even position `(2s, 2t)`, as it is (nodata
    /// included), so that a coarser mesh ring's vertices lie exactly on the finer one's.
    Point,
    /// The least height of the block (nodata excluded): a surface never above the finer one.
    Min,
    /// The greatest height of the block (nodata excluded): a surface never below the finer one.
    Max,
}

impl LevelRule {
    /// Every rule, in the order the documentation gives them.
    pub const ALL: [LevelRule; 4] = [LevelRule::Mean, LevelRule::Point, LevelRule::Min, LevelRule::Max];

    /// The name configuration and the tools use.
    pub fn name(self) -> &'static str {
        match self {
            LevelRule::Mean => "mean",
            LevelRule::Point => "point",
            LevelRule::Min => "min",
            LevelRule::Max => "max",
        }
    }

    /// From its name (`mean`, `point`, `min`, `max`).
    pub fn from_name(name: &str) -> Option<Self> {
        LevelRule::ALL.into_iter().find(|r| r.name() == name)
    }
}

impl fmt::Display for LevelRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// What to do with a height that is NaN or infinite in the input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NonFinite {
    /// Refuse it: an error that says which value and where.
    #[default]
    Refuse,
    /// Store the nodata value (the format must have one).
    Nodata,
}

/// Every height a format can hold lies within this many metres of zero (ten thousand
/// kilometres: any planet's relief, with room for offsets), so that metres stay far from the
/// limits of the readers' arithmetic.
pub const HEIGHT_LIMIT_M: f64 = 1.0e7;

/// Why a height format, a height or a tile of heights was refused. Each message says what was
/// found, what was expected and how to fix it; where it happened is the caller's to add (a
/// configuration line, an input pixel) or is given (a texel of a tile).
#[derive(Clone, Debug, PartialEq)]
pub enum HeightError {
    /// The scale is not a finite positive number, or is too fine for the offset.
    Scale {
        /// The scale given.
        scale: f64,
        /// What is wrong with it.
        why: String,
    },
    /// The offset is not finite, or puts heights past [`HEIGHT_LIMIT_M`].
    Offset {
        /// The offset given.
        offset: f64,
        /// What is wrong with it.
        why: String,
    },
    /// `l32f` was given a scale or offset other than 1 and 0.
    FloatScaled {
        /// The scale given.
        scale: f64,
        /// The offset given.
        offset: f64,
    },
    /// The nodata value is not a value of the storage.
    Nodata {
        /// The nodata value given.
        nodata: f64,
        /// The storage it must be a value of.
        storage: HeightStorage,
        /// What is wrong with it.
        why: String,
    },
    /// A height to store is NaN or infinite and non-finite heights are refused (or there is no
    /// nodata value to map them to).
    NotFinite {
        /// The height.
        value: f64,
        /// Whether the format declares a nodata value.
        nodata_declared: bool,
    },
    /// A height to store lies outside what the format holds.
    OutOfRange {
        /// The height, metres.
        metres: f64,
        /// The least height the format holds, metres.
        lo: f64,
        /// The greatest height the format holds, metres.
        hi: f64,
        /// The format, as a configuration names it.
        format: String,
    },
    /// A height to store encodes to the nodata value.
    IsNodata {
        /// The height, metres.
        metres: f64,
        /// The nodata value it encodes to.
        nodata: f64,
    },
    /// A tile's bytes are not a whole number of texels.
    TileLength {
        /// The tile's length, bytes.
        len: usize,
        /// The bytes of one texel.
        bytes_per_texel: usize,
    },
    /// A stored `l32f` texel of a tile is NaN or infinite.
    TileNotFinite {
        /// The texel's index in the tile.
        index: usize,
        /// Its stored bits.
        bits: u32,
    },
}

impl fmt::Display for HeightError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HeightError::Scale { scale, why } => write!(
                f,
                "height scale {scale} is not usable: {why}; give the metres one stored step is, a finite number above zero (e.g. 0.01 for centimetres)"
            ),
            HeightError::Offset { offset, why } => write!(
                f,
                "height offset {offset} is not usable: {why}; give the metres a stored 0 is, a finite number within {HEIGHT_LIMIT_M} m of zero"
            ),
            HeightError::FloatScaled { scale, offset } => write!(
                f,
                "l32f stores metres, so it takes no scale or offset (found scale {scale}, offset {offset}); remove them, or store l16/l16i steps if the values are steps"
            ),
            HeightError::Nodata { nodata, storage, why } => write!(
                f,
                "nodata value {nodata} is not a {storage} value: {why}; give the stored value (not metres) that marks a texel without data, e.g. {}",
                match storage {
                    HeightStorage::F32 => "-32768 or -3.4e38",
                    HeightStorage::U16 => "0 or 65535",
                    HeightStorage::I16 => "-32768",
                }
            ),
            HeightError::NotFinite { value, nodata_declared: true } => write!(
                f,
                "height {value} is not a finite number; expected metres; fix the input, or map such heights to the nodata value (non-finite = nodata)"
            ),
            HeightError::NotFinite { value, nodata_declared: false } => write!(
                f,
                "height {value} is not a finite number and the format declares no nodata value to map it to; fix the input, or declare a nodata value and map non-finite heights to it"
            ),
            HeightError::OutOfRange { metres, lo, hi, format } => write!(
                f,
                "height {metres} m is outside what {format} holds ({lo} m to {hi} m); choose a scale and offset whose range covers the data, or store l32f"
            ),
            HeightError::IsNodata { metres, nodata } => write!(
                f,
                "height {metres} m is stored as {nodata}, the nodata value, so it would read back as no data; choose a nodata value outside the data's range"
            ),
            HeightError::TileLength { len, bytes_per_texel } => write!(
                f,
                "a tile of {len} bytes is not a whole number of {bytes_per_texel}-byte height texels; the tile file is truncated or of another format"
            ),
            HeightError::TileNotFinite { index, bits } => write!(
                f,
                "texel {index} of the tile is not a finite height (bits {bits:#010x}); l32f tiles hold finite metres or the nodata value: prepare the tile again, mapping non-finite heights to nodata"
            ),
        }
    }
}

impl std::error::Error for HeightError {}

/// A validated height format: storage, scale, offset and nodata value.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct HeightFormat {
    storage: HeightStorage,
    scale: f64,
    offset: f64,
    nodata: Option<f64>,
}

impl HeightFormat {
    /// The format of the height verification texture (`clipmapd --source heights`,
    /// docs/ELEVATION.md): `l32f` metres, nodata -32768.
    pub const VERIFICATION: HeightFormat =
        HeightFormat { storage: HeightStorage::F32, scale: 1.0, offset: 0.0, nodata: Some(-32768.0) };

    /// `l32f` metres, with an optional nodata value (a finite `f32`; NaN is never stored).
    pub fn float(nodata: Option<f64>) -> Result<Self, HeightError> {
        HeightFormat::new(HeightStorage::F32, 1.0, 0.0, nodata)
    }

    /// A height format. `scale` is the metres of one stored step and `offset` the metres of a
    /// stored 0 (`l32f`: 1 and 0); `nodata` is a stored value (not metres).
    ///
    /// Refused: a scale not finite and above zero, an offset not finite, heights the format
    /// holds past [`HEIGHT_LIMIT_M`], a scale too fine for its offset (two steps would not be
    /// told apart in 64-bit arithmetic), `l32f` with another scale or offset, and a nodata value
    /// that is not a value of the storage.
    pub fn new(storage: HeightStorage, scale: f64, offset: f64, nodata: Option<f64>) -> Result<Self, HeightError> {
        if !scale.is_finite() || scale <= 0.0 {
            let why =
                if scale.is_nan() { "it is NaN".to_string() } else { "it must be finite and above zero".to_string() };
            return Err(HeightError::Scale { scale, why });
        }
        if !offset.is_finite() {
            return Err(HeightError::Offset { offset, why: "it is not finite".into() });
        }
        match storage.integer_bounds() {
            None => {
                if scale != 1.0 || offset != 0.0 {
                    return Err(HeightError::FloatScaled { scale, offset });
                }
            }
            Some((lo, hi)) => {
                let (m_lo, m_hi) = (lo as f64 * scale + offset, hi as f64 * scale + offset);
                if m_hi.abs() > HEIGHT_LIMIT_M || m_lo.abs() > HEIGHT_LIMIT_M {
                    let why = format!(
                        "{storage} then holds {m_lo} m to {m_hi} m, past the {HEIGHT_LIMIT_M} m every height format stays within"
                    );
                    return if offset.abs() > HEIGHT_LIMIT_M {
                        Err(HeightError::Offset { offset, why })
                    } else {
                        Err(HeightError::Scale { scale, why })
                    };
                }
                // Two neighbouring steps must stay apart, and every stored value must come back
                // from its metres: the step must be far above the rounding of the largest metres.
                let big = m_lo.abs().max(m_hi.abs()).max(offset.abs());
                if scale < big * f64::EPSILON * 64.0 {
                    return Err(HeightError::Scale {
                        scale,
                        why: format!("steps that small cannot be told apart at {big} m from zero in 64-bit arithmetic"),
                    });
                }
            }
        }
        if let Some(v) = nodata {
            let bad = |why: &str| Err(HeightError::Nodata { nodata: v, storage, why: why.to_string() });
            match storage.integer_bounds() {
                None => {
                    if !v.is_finite() {
                        return bad("it must be a finite number (NaN is never stored)");
                    }
                    if v as f32 as f64 != v {
                        return bad("it is not exactly a 32-bit float");
                    }
                }
                Some((lo, hi)) => {
                    if !v.is_finite() || v.fract() != 0.0 {
                        return bad("it must be a whole number");
                    }
                    if v < lo as f64 || v > hi as f64 {
                        return bad(&format!("it must lie in {lo}..={hi}"));
                    }
                }
            }
        }
        Ok(HeightFormat { storage, scale, offset, nodata })
    }

    /// The storage.
    pub fn storage(&self) -> HeightStorage {
        self.storage
    }

    /// Metres of one stored step.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// Metres of a stored 0.
    pub fn offset(&self) -> f64 {
        self.offset
    }

    /// The stored value that marks a texel without data, if any.
    pub fn nodata(&self) -> Option<f64> {
        self.nodata
    }

    /// Bytes one texel takes.
    pub fn bytes_per_texel(&self) -> usize {
        self.storage.bytes()
    }

    /// Whether a stored value is the nodata value.
    pub fn is_nodata(&self, stored: f64) -> bool {
        self.nodata == Some(stored)
    }

    /// The least and greatest heights the format holds, in metres (`l32f`: the `f32` range).
    pub fn metre_bounds(&self) -> (f64, f64) {
        match self.storage.integer_bounds() {
            None => (f32::MIN as f64, f32::MAX as f64),
            Some((lo, hi)) => (lo as f64 * self.scale + self.offset, hi as f64 * self.scale + self.offset),
        }
    }

    /// Reads the stored value of one texel (`bytes` at least [`bytes_per_texel`](Self::bytes_per_texel) long; more is ignored).
    pub fn read(&self, bytes: &[u8]) -> f64 {
        match self.storage {
            HeightStorage::F32 => f32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as f64,
            HeightStorage::U16 => u16::from_le_bytes([bytes[0], bytes[1]]) as f64,
            HeightStorage::I16 => i16::from_le_bytes([bytes[0], bytes[1]]) as f64,
        }
    }

    /// Writes a stored value (one of the storage's: [`encode`](Self::encode) and the level
    /// rules give only such) into `out`, [`bytes_per_texel`](Self::bytes_per_texel) long.
    pub fn write(&self, stored: f64, out: &mut [u8]) {
        match self.storage {
            HeightStorage::F32 => out[..4].copy_from_slice(&(stored as f32).to_le_bytes()),
            HeightStorage::U16 => out[..2].copy_from_slice(&(stored as u16).to_le_bytes()),
            HeightStorage::I16 => out[..2].copy_from_slice(&(stored as i16).to_le_bytes()),
        }
    }

    /// The metres of a stored value, or `None` for the nodata value.
    pub fn decode(&self, stored: f64) -> Option<f64> {
        if self.is_nodata(stored) {
            None
        } else {
            Some(self.to_metres(stored))
        }
    }

    /// The metres of a stored value, nodata or not.
    fn to_metres(self, stored: f64) -> f64 {
        match self.storage {
            HeightStorage::F32 => stored,
            _ => stored * self.scale + self.offset,
        }
    }

    /// The stored value of a height in metres: the nearest one (`l32f`: the nearest `f32`;
    /// 16-bit: the nearest step, halves away from zero). Refused: NaN and infinities, heights
    /// outside what the format holds, and a height that would be stored as the nodata value.
    pub fn encode(&self, metres: f64) -> Result<f64, HeightError> {
        self.encode_with(metres, NonFinite::Refuse)
    }

    /// [`encode`](Self::encode), with NaN and infinities refused or stored as nodata, as asked.
    pub fn encode_with(&self, metres: f64, non_finite: NonFinite) -> Result<f64, HeightError> {
        if !metres.is_finite() {
            return match (non_finite, self.nodata) {
                (NonFinite::Nodata, Some(n)) => Ok(n),
                (_, n) => Err(HeightError::NotFinite { value: metres, nodata_declared: n.is_some() }),
            };
        }
        let stored = match self.storage.integer_bounds() {
            None => {
                let v = metres as f32;
                if !v.is_finite() {
                    return Err(self.out_of_range(metres));
                }
                v as f64
            }
            Some((lo, hi)) => {
                let v = ((metres - self.offset) / self.scale).round();
                if !(v >= lo as f64 && v <= hi as f64) {
                    return Err(self.out_of_range(metres));
                }
                v
            }
        };
        if self.is_nodata(stored) {
            return Err(HeightError::IsNodata { metres, nodata: stored });
        }
        Ok(stored)
    }

    fn out_of_range(&self, metres: f64) -> HeightError {
        let (lo, hi) = self.metre_bounds();
        let format = match self.storage {
            HeightStorage::F32 => "l32f".to_string(),
            s => format!("{s} with scale {} and offset {}", self.scale, self.offset),
        };
        HeightError::OutOfRange { metres, lo, hi, format }
    }

    /// The coarser texel `rule` makes of a block of finer stored values: `first` is the texel at
    /// the even position `(2s, 2t)`, `others` the rest of the block that exists (none, one or
    /// three of `(2s+1, 2t)`, `(2s, 2t+1)`, `(2s+1, 2t+1)`; fewer at a level's edge of one texel).
    pub fn reduce(&self, rule: LevelRule, first: f64, others: &[f64]) -> f64 {
        if rule == LevelRule::Point {
            return first;
        }
        let valid = || std::iter::once(first).chain(others.iter().copied()).filter(|&v| !self.is_nodata(v));
        // Without a nodata value every texel has data, so the fallback is never taken.
        let nodata_or_any = self.nodata.unwrap_or(first);
        match rule {
            LevelRule::Point => first,
            LevelRule::Min => valid().reduce(f64::min).unwrap_or(nodata_or_any),
            LevelRule::Max => valid().reduce(f64::max).unwrap_or(nodata_or_any),
            LevelRule::Mean => {
                let (n, sum) = valid().fold((0u32, 0.0f64), |(n, s), v| (n + 1, s + v));
                if n == 0 {
                    return nodata_or_any;
                }
                // The sum of at most four stored values is exact in f64 (24- or 16-bit
                // significands), so the mean is rounded once.
                match self.storage {
                    HeightStorage::F32 => {
                        let exact = sum / n as f64;
                        let m = exact as f32;
                        match self.nodata {
                            Some(nd) if m as f64 == nd => {
                                // The block's heights straddle the nodata value: one ulp off it,
                                // on the side of the exact mean.
                                (if exact >= nd { m.next_up() } else { m.next_down() }) as f64
                            }
                            _ => m as f64,
                        }
                    }
                    _ => {
                        let (sum, n) = (sum as i64, n as i64);
                        // Halves up: floor((2 sum + n) / 2n).
                        let m = (2 * sum + n).div_euclid(2 * n) as f64;
                        match self.nodata {
                            // Heights on both sides of the nodata value (integers cannot mean to
                            // it from one side), so both neighbours are in range and in the block's.
                            Some(nd) if m == nd => {
                                if sum >= nd as i64 * n {
                                    nd + 1.0
                                } else {
                                    nd - 1.0
                                }
                            }
                            _ => m,
                        }
                    }
                }
            }
        }
    }

    /// The next coarser level of a level of stored values, `width` x `height` texels, row by row
    /// (`t` the row): each coarser texel [`reduce`](Self::reduce)s its block. The coarser level is
    /// `max(1, width / 2)` x `max(1, height / 2)` (the crate's level sizes, `tile::level_size`).
    /// `None` when `src` is not `width x height` long.
    pub fn reduce_level(&self, rule: LevelRule, src: &[f64], width: usize, height: usize) -> Option<Vec<f64>> {
        if width.checked_mul(height)? != src.len() || src.is_empty() {
            return None;
        }
        let (cw, ch) = ((width / 2).max(1), (height / 2).max(1));
        let mut out = Vec::with_capacity(cw * ch);
        let mut others = Vec::with_capacity(3);
        for t in 0..ch {
            for s in 0..cw {
                let (s0, t0) = (2 * s, 2 * t);
                others.clear();
                for (ds, dt) in [(1, 0), (0, 1), (1, 1)] {
                    if s0 + ds < width && t0 + dt < height {
                        others.push(src[(t0 + dt) * width + s0 + ds]);
                    }
                }
                out.push(self.reduce(rule, src[t0 * width + s0], &others));
            }
        }
        Some(out)
    }

    /// The range of heights a tile's bytes hold, nodata excluded: [`TileRange::Empty`] when
    /// every texel is nodata (or the tile has none). Refused: bytes that are not whole texels
    /// and, for `l32f`, a texel that is NaN or infinite (a corrupt or foreign tile).
    pub fn tile_range(&self, bytes: &[u8]) -> Result<TileRange, HeightError> {
        let b = self.bytes_per_texel();
        if !bytes.len().is_multiple_of(b) {
            return Err(HeightError::TileLength { len: bytes.len(), bytes_per_texel: b });
        }
        let mut range: Option<(f64, f64)> = None;
        for (index, texel) in bytes.chunks_exact(b).enumerate() {
            let v = self.read(texel);
            if !v.is_finite() {
                let bits = u32::from_le_bytes([texel[0], texel[1], texel[2], texel[3]]);
                return Err(HeightError::TileNotFinite { index, bits });
            }
            if self.is_nodata(v) {
                continue;
            }
            range = Some(match range {
                None => (v, v),
                Some((lo, hi)) => (lo.min(v), hi.max(v)),
            });
        }
        // Scale is above zero, so the least stored value is the lowest height.
        Ok(match range {
            None => TileRange::Empty,
            Some((lo, hi)) => TileRange::Heights { min: self.to_metres(lo), max: self.to_metres(hi) },
        })
    }
}

/// The heights of a tile, nodata excluded.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum TileRange {
    /// Every texel is nodata.
    Empty,
    /// The least and greatest height, metres.
    Heights {
        /// The least height, metres.
        min: f64,
        /// The greatest height, metres.
        max: f64,
    },
}

impl TileRange {
    /// The range holding both.
    pub fn union(self, other: TileRange) -> TileRange {
        match (self, other) {
            (TileRange::Empty, r) | (r, TileRange::Empty) => r,
            (TileRange::Heights { min: a, max: b }, TileRange::Heights { min: c, max: d }) => {
                TileRange::Heights { min: a.min(c), max: b.max(d) }
            }
        }
    }
}

#[cfg(test)]
mod tests;
