//! Procedural tile sources: the verification texture ([`HashSource`], docs/ARCHITECTURE.md §11) and smooth
//! terrain ([`TerrainSource`]), any size up to 2^30 texels a side, no files.
//!
//! Owns cutting the per-texel functions of [`super::procedural`] into tiles; the texel values
//! themselves are defined there.

use super::procedural::{hash_region, height_stored, Terrain};
use super::{check_request, SourceError, TextureDesc, TileId, TileSource};
use crate::height::HeightFormat;
use crate::texel::TexelFormat;
use serde::Serialize;
use std::sync::Arc;

/// The seed of the built-in terrain, the same in every tool (`clipmapd --source terrain`,
/// `cliptex roam --source terrain`, `clipprep --source terrain` without `--seed`, the demo, the
/// accuracy study): one flag, one texture.
pub const TERRAIN_SEED: u64 = 1;

/// A built-in procedural texture.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Procedural {
    /// The verification texture (docs/ARCHITECTURE.md §11): every texel checkable by any reader.
    Hash,
    /// Smooth fractal terrain ([`TERRAIN_SEED`]), for pictures and accuracy studies.
    Terrain,
    /// The height verification texture in `l32f` with nodata -32768 ([`HeightSource`],
    /// docs/ELEVATION.md): every height checkable by any reader.
    Heights,
}

impl Procedural {
    /// The texture of this kind with the shape `desc`.
    pub fn source(self, desc: TextureDesc) -> Arc<dyn TileSource> {
        match self {
            Procedural::Hash => Arc::new(HashSource::new(desc)),
            Procedural::Terrain => Arc::new(TerrainSource::new(desc, TERRAIN_SEED)),
            Procedural::Heights => Arc::new(HeightSource::new(desc, HeightFormat::VERIFICATION)),
        }
    }

    /// The texel format the kind is served in.
    pub fn texel_format(self) -> TexelFormat {
        match self {
            Procedural::Hash | Procedural::Terrain => TexelFormat::RGBA8,
            Procedural::Heights => TexelFormat::L32F,
        }
    }
}

/// The height verification texture ([`super::procedural::height_stored`]) in a height format:
/// a tile is the stored values of its texels, the texels outside the level zero.
#[derive(Clone, Debug)]
pub struct HeightSource {
    desc: TextureDesc,
    format: HeightFormat,
}

impl HeightSource {
    /// Heights of `format` in the shape of `desc` (served in the storage's texel format, `l32f`,
    /// `l16` or `l16i`, whatever `desc` says).
    pub fn new(desc: TextureDesc, format: HeightFormat) -> Self {
        let texel = crate::plan::height_texel(format.storage());
        // A one-component format of 2 or 4 bytes: always within a desc's 1..=16.
        let desc = desc.clone().with_format(texel).unwrap_or(desc);
        HeightSource { desc, format }
    }

    /// The height format.
    pub fn format(&self) -> &HeightFormat {
        &self.format
    }
}

impl TileSource for HeightSource {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    /// Its levels are each defined on their own (not made by a rule): it states the default
    /// rule, `mean`.
    fn heights(&self) -> Option<crate::plan::HeightPlan> {
        Some(crate::plan::HeightPlan { format: self.format, levels: crate::height::LevelRule::default() })
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        check_request(&self.desc, tile, out)?;
        let bpt = self.desc.bytes_per_texel();
        for_each_row(&self.desc, tile, out, |t, s0, _w, bytes| {
            for (i, texel) in bytes.chunks_exact_mut(bpt).enumerate() {
                let v = height_stored(&self.format, tile.level, s0 + i as u64, t);
                self.format.write(v, texel);
            }
        });
        Ok(())
    }
}

/// A height texture held in memory, every level's stored values given (row by row, `t` the row),
/// or level 0 given and the coarser levels made by a level rule ([`HeightFormat::reduce_level`]):
/// for tests and the height accuracy study (a surface whose pyramid each rule builds).
#[derive(Clone, Debug)]
pub struct HeightLevels {
    desc: TextureDesc,
    format: HeightFormat,
    rule: crate::height::LevelRule,
    levels: Vec<Vec<f64>>,
}

impl HeightLevels {
    /// Heights of `format` in the shape of `desc` (served in the storage's texel format), level
    /// `k` holding `levels[k]`, stored values, `width x height` of that level. `rule` is what the
    /// source states ([`TileSource::heights`]). Refused: a level count or a level's length other
    /// than `desc`'s, and a value that is not a value of the storage.
    pub fn new(
        desc: TextureDesc,
        format: HeightFormat,
        rule: crate::height::LevelRule,
        levels: Vec<Vec<f64>>,
    ) -> Result<Self, String> {
        let texel = crate::plan::height_texel(format.storage());
        let desc = desc.with_format(texel).map_err(|e| e.to_string())?;
        if levels.len() != desc.level_count() {
            return Err(format!(
                "height levels: {} levels given, the texture of {}x{} texels has {}; give one per level, finest first",
                levels.len(),
                desc.size()[0],
                desc.size()[1],
                desc.level_count()
            ));
        }
        for (k, level) in levels.iter().enumerate() {
            let size = desc.level(k as u32).size;
            if level.len() as u64 != size[0] * size[1] {
                return Err(format!(
                    "height levels: level {k} holds {} values, expected {}x{} = {}",
                    level.len(),
                    size[0],
                    size[1],
                    size[0] * size[1]
                ));
            }
            if let Some((i, v)) = level.iter().enumerate().find(|&(_, &v)| !is_stored_value(&format, v)) {
                return Err(format!(
                    "height levels: level {k} texel ({}, {}) holds {v}, which {} does not store; give stored values ({})",
                    i as u64 % size[0],
                    i as u64 / size[0],
                    format.storage(),
                    "HeightFormat::encode"
                ));
            }
        }
        Ok(HeightLevels { desc, format, rule, levels })
    }

    /// Level 0's stored values given (`width x height`, row by row), each coarser level made from
    /// the finer one by `rule`.
    pub fn by_rule(
        desc: TextureDesc,
        format: HeightFormat,
        rule: crate::height::LevelRule,
        level0: Vec<f64>,
    ) -> Result<Self, String> {
        let mut levels = vec![level0];
        for k in 1..desc.level_count() {
            let finer = desc.level(k as u32 - 1).size;
            let next =
                format.reduce_level(rule, &levels[k - 1], finer[0] as usize, finer[1] as usize).ok_or_else(|| {
                    format!(
                        "height levels: level {} holds {} values, expected {}x{}",
                        k - 1,
                        levels[k - 1].len(),
                        finer[0],
                        finer[1]
                    )
                })?;
            levels.push(next);
        }
        HeightLevels::new(desc, format, rule, levels)
    }

    /// The stored value of texel (s, t) of `level`.
    pub fn stored(&self, level: u32, s: u64, t: u64) -> f64 {
        let w = self.desc.level(level).size[0];
        self.levels[level as usize][(t * w + s) as usize]
    }

    /// The height format.
    pub fn format(&self) -> &HeightFormat {
        &self.format
    }
}

/// Whether `v` is a value `format`'s storage holds.
fn is_stored_value(format: &HeightFormat, v: f64) -> bool {
    use crate::height::HeightStorage;
    match format.storage() {
        HeightStorage::F32 => v.is_finite() && v as f32 as f64 == v,
        HeightStorage::U16 => v.fract() == 0.0 && (0.0..=65535.0).contains(&v),
        HeightStorage::I16 => v.fract() == 0.0 && (-32768.0..=32767.0).contains(&v),
    }
}

impl TileSource for HeightLevels {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn heights(&self) -> Option<crate::plan::HeightPlan> {
        Some(crate::plan::HeightPlan { format: self.format, levels: self.rule })
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        check_request(&self.desc, tile, out)?;
        let bpt = self.desc.bytes_per_texel();
        for_each_row(&self.desc, tile, out, |t, s0, _w, bytes| {
            for (i, texel) in bytes.chunks_exact_mut(bpt).enumerate() {
                self.format.write(self.stored(tile.level, s0 + i as u64, t), texel);
            }
        });
        Ok(())
    }
}

/// Visits the part of `tile` that lies inside its level: calls `row(t, s0, width, bytes)` for each
/// texel row, where `bytes` is the row's slice of `out`. Texels outside the level are zeroed.
fn for_each_row(desc: &TextureDesc, tile: TileId, out: &mut [u8], mut row: impl FnMut(u64, u64, usize, &mut [u8])) {
    let level = desc.level(tile.level);
    let bpt = desc.bytes_per_texel();
    let [tw, th] = level.tile;
    let (s0, t0) = (tile.s * tw, tile.t * th);
    let w = (level.size[0] - s0).min(tw) as usize;
    let h = (level.size[1] - t0).min(th) as usize;
    let stride = tw as usize * bpt;
    if w < tw as usize || h < th as usize {
        out.fill(0);
    }
    for (r, line) in out.chunks_exact_mut(stride).take(h).enumerate() {
        row(t0 + r as u64, s0, w, &mut line[..w * bpt]);
    }
}

/// The verification texture: texel (L, s, t) is the low bytes of
/// `splitmix64((L << 58) | (t << 29) | s)`, so any texel can be checked without a reference copy.
#[derive(Clone, Debug)]
pub struct HashSource {
    desc: TextureDesc,
}

impl HashSource {
    /// A hash texture of the given shape.
    pub fn new(desc: TextureDesc) -> Self {
        HashSource { desc }
    }
}

impl TileSource for HashSource {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        check_request(&self.desc, tile, out)?;
        let bpt = self.desc.bytes_per_texel();
        for_each_row(&self.desc, tile, out, |t, s0, w, bytes| hash_region(tile.level, s0, t, w, 1, bpt, bytes));
        Ok(())
    }
}

/// Smooth fractal terrain, for pictures and accuracy studies.
#[derive(Clone, Debug)]
pub struct TerrainSource {
    desc: TextureDesc,
    terrain: Terrain,
}

impl TerrainSource {
    /// A terrain texture of the given shape (the noise spans the larger level-0 edge).
    pub fn new(desc: TextureDesc, seed: u64) -> Self {
        let edge = desc.size()[0].max(desc.size()[1]);
        let log2 = 64 - (edge - 1).max(1).leading_zeros();
        TerrainSource { terrain: Terrain::new(log2, seed), desc }
    }
}

impl TileSource for TerrainSource {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        check_request(&self.desc, tile, out)?;
        let bpt = self.desc.bytes_per_texel();
        let format = self.desc.format();
        for_each_row(&self.desc, tile, out, |t, s0, _w, bytes| {
            for (i, texel) in bytes.chunks_exact_mut(bpt).enumerate() {
                self.terrain.texel(tile.level, s0 + i as u64, t, format, texel);
            }
        });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::procedural::hash;
    use super::*;
    use crate::source::FaultKind;
    use crate::texel::TexelFormat;

    #[test]
    fn hash_tiles_hold_the_verification_texels_in_performer_order() {
        let desc = TextureDesc::new([100, 60], 16, TexelFormat::RGB8, [32, 16]).unwrap();
        let src = HashSource::new(desc.clone());
        let mut buf = vec![0u8; desc.tile_bytes(0)];
        // Edge tile (3, 3): texels 96..100 x 48..60, the rest zero.
        src.read_tile(TileId::new(0, 3, 3), &mut buf).unwrap();
        let mut want = [0u8; 3];
        hash(0, 99, 59, &mut want);
        let at = ((59 - 48) * 32 + (99 - 96)) * 3;
        assert_eq!(&buf[at..at + 3], &want);
        assert_eq!(&buf[at + 3..at + 6], &[0, 0, 0], "outside the level");
        let e = src.read_tile(TileId::new(0, 4, 0), &mut buf).unwrap_err();
        assert_eq!(e.kind(), FaultKind::BadRequest);
        assert!(e.to_string().contains("level 0 tile (4, 0)"), "{e}");
        let e = src.read_tile(TileId::new(0, 0, 0), &mut buf[1..]).unwrap_err();
        assert!(matches!(e, SourceError::BufferSize { expected: 1536, found: 1535, .. }));
    }

    #[test]
    fn height_tiles_hold_the_verification_heights_to_the_far_corner_of_a_2_26_texture() {
        use crate::height::{HeightFormat, HeightStorage};
        // Made with a colour format of the same shape: served as l16i all the same.
        let desc = TextureDesc::new([1 << 26, 1 << 26], 1024, TexelFormat::RGBA8, [64, 64]).unwrap();
        let f = HeightFormat::new(HeightStorage::I16, 0.5, 100.0, Some(-32768.0)).unwrap();
        let src = HeightSource::new(desc, f);
        assert_eq!(src.desc().format(), TexelFormat::L16I);
        assert_eq!(src.format(), &f);
        let mut buf = vec![0u8; src.desc().tile_bytes(0)];
        let last = (1 << 26) / 64 - 1;
        src.read_tile(TileId::new(0, last, last), &mut buf).unwrap();
        let far = (1u64 << 26) - 1;
        let at = (63 * 64 + 63) * 2;
        let got = i16::from_le_bytes([buf[at], buf[at + 1]]) as f64;
        assert_eq!(got, height_stored(&f, 0, far, far), "texel ({far}, {far})");
        // And every texel of the tile, against the definition.
        for (i, texel) in buf.chunks_exact(2).enumerate() {
            let (s, t) = (last * 64 + i as u64 % 64, last * 64 + i as u64 / 64);
            assert_eq!(f.read(texel), height_stored(&f, 0, s, t), "({s}, {t})");
        }
    }

    #[test]
    fn terrain_tiles_are_defined_at_the_far_corner_of_a_huge_texture() {
        let desc = TextureDesc::new([1 << 26, 1 << 26], 1024, TexelFormat::RGBA8, [64, 64]).unwrap();
        let src = TerrainSource::new(desc.clone(), 3);
        let mut buf = vec![0u8; desc.tile_bytes(0)];
        let last = (1 << 26) / 64 - 1;
        src.read_tile(TileId::new(0, last, last), &mut buf).unwrap();
        assert!(buf.chunks_exact(4).all(|px| px[3] == 255), "opaque everywhere");
    }
}
