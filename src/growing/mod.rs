//! Growing textures (the flexible clipmap): georeferenced patches that arrive at run time,
//! resolved into a fixed tile grid that can grow in every direction.
//!
//! Owns the arithmetic of a growing texture, apart from any service or file: what a patch is and
//! when it is refused ([`Patch::new`]), the fixed tile grid anchored at a world origin
//! ([`Grid`]: a tile's index never changes as the texture grows, negative indices included), the
//! index of patches by bounding box ([`index::PatchIndex`], an R*-tree), and the rebuild of tiles
//! from the patches that cover them ([`rebuild`]: level 0 from the patches, best rating first and
//! ties to the newest, coarser levels by averaging their four children, in increasing level order
//! and a bounded number per step). The service side (ingest over the control socket and a watched
//! directory, persistence, publication) builds on it.
//!
//! Conventions. World coordinates are `f64` in the user's units; the grid has `texels_per_unit`
//! level-0 texels per unit along both axes, and texel (0, 0) of level 0 has its lower corner at
//! `origin`. Texel (i, j) of level 0 covers world `[origin + i / r, origin + (i + 1) / r)` per
//! axis; a patch supplies the texel when the texel's **centre** lies in the patch's box, and the
//! patch is sampled at that centre (nearest texel of the patch image, whose first row is the top
//! of the box, its largest y, and first column its left edge, as in image files and GeoTIFFs). Level k texel (i, j) is the
//! average of level k-1 texels (2i..2i+2, 2j..2j+2) that have data, per component; a texel with
//! no data below it has none. Tile (S, T) of level k holds level-k texels
//! `[S * tile, (S + 1) * tile)` per axis, so a tile of level k covers 2 x 2 tiles of level k-1.

pub mod index;
pub mod input;
pub mod rebuild;
pub mod serve;
pub mod store;
pub mod watch;

#[cfg(test)]
mod tests;

use thiserror::Error;

/// Largest number of level-0 texels a patch may cover along an axis of the grid: larger would
/// mean an absurd resolution (or box) for one image.
pub(crate) const MAX_PATCH_SPAN_TEXELS: f64 = (1u64 << 26) as f64;

/// Farthest (in level-0 texels) a patch may lie from the grid's origin along an axis.
pub(crate) const MAX_GRID_EXTENT_TEXELS: f64 = (1u64 << 40) as f64;

/// Largest patch image side, in pixels.
pub(crate) const MAX_PATCH_PIXELS: u32 = 1 << 16;

/// A stable 64-bit digest (the same in every build and version, unlike std's hasher) for
/// recognising bytes again; not for security. FNV-1a's step taken a little-endian 64-bit word at a
/// time (the last word zero-padded), then the length mixed in, so a patch's 36 MB of texels take
/// milliseconds.
pub(crate) fn digest(bytes: &[u8]) -> u64 {
    digest_from(bytes, 0xCBF2_9CE4_8422_2325)
}

/// [`digest`] continued from an earlier digest `h`.
pub(crate) fn digest_from(bytes: &[u8], mut h: u64) -> u64 {
    const PRIME: u64 = 0x0000_0100_0000_01B3;
    let mut words = bytes.chunks_exact(8);
    for w in &mut words {
        h = (h ^ u64::from_le_bytes(w.try_into().expect("8 bytes"))).wrapping_mul(PRIME);
    }
    let rest = words.remainder();
    if !rest.is_empty() {
        let mut last = [0u8; 8];
        last[..rest.len()].copy_from_slice(rest);
        h = (h ^ u64::from_le_bytes(last)).wrapping_mul(PRIME);
    }
    crate::tile::mix64(h ^ bytes.len() as u64)
}

/// A patch as handed in, before the store gives it an id: the patch (its `id` is not used: the
/// store gives the next one, and checks the rest again against its own grid), and the image file
/// its texels were decoded from, if any.
#[derive(Clone, Debug)]
pub struct NewPatch {
    /// The patch.
    pub patch: Patch,
    /// The image file the texels were decoded from, kept instead of the texels (a JPEG is a
    /// tenth of its texels: a tenth of the bytes to sync before the patch is acknowledged).
    pub encoded: Option<Vec<u8>>,
}

/// An axis-aligned box in world units: `min` inclusive, `max` exclusive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldBox {
    /// Lower corner (x, y).
    pub min: [f64; 2],
    /// Upper corner (x, y).
    pub max: [f64; 2],
}

impl WorldBox {
    /// Whether `p` lies in the box.
    pub fn contains(&self, p: [f64; 2]) -> bool {
        (0..2).all(|a| self.min[a] <= p[a] && p[a] < self.max[a])
    }
}

/// The fixed tile grid of a growing texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// World coordinates of the lower corner of level-0 texel (0, 0).
    pub origin: [f64; 2],
    /// Level-0 texels per world unit (both axes).
    pub texels_per_unit: f64,
    /// Tile edge in texels (every level).
    pub tile: u64,
    /// Bytes per texel.
    pub bytes_per_texel: usize,
    /// Bytes per component: 1 (8-bit) or 2 (16-bit, little-endian); averaging is per component.
    pub component_bytes: usize,
}

/// Why a grid or a patch is refused.
#[derive(Debug, Error, PartialEq)]
pub enum GrowError {
    /// A grid parameter is out of range.
    #[error("grid: {what} is {found}; expected {expected}")]
    Grid {
        /// The parameter.
        what: &'static str,
        /// Its value.
        found: String,
        /// The values it may take.
        expected: &'static str,
    },
    /// The box has a coordinate that is NaN or infinite.
    #[error(
        "patch {id}: its box {bbox:?} has a coordinate that is not a finite number; give finite world coordinates"
    )]
    NotFinite {
        /// The patch's id.
        id: u64,
        /// Its box.
        bbox: WorldBox,
    },
    /// The box is empty or inverted along an axis.
    #[error("patch {id}: its box is empty or inverted along {axis} (min {min}, max {max}); min must be less than max")]
    EmptyBox {
        /// The patch's id.
        id: u64,
        /// The axis, `x` or `y`.
        axis: char,
        /// The box's minimum along it.
        min: f64,
        /// The box's maximum along it.
        max: f64,
    },
    /// The patch would cover an absurd number of texels, or lie absurdly far from the origin.
    #[error("patch {id}: it spans {span:.3e} level-0 texels along {axis} ({what}); the most is {limit:.3e}: check the box's units against the grid's texels per unit")]
    Absurd {
        /// The patch's id.
        id: u64,
        /// The axis, `x` or `y`.
        axis: char,
        /// The level-0 texels it spans or lies away.
        span: f64,
        /// Which of the two.
        what: &'static str,
        /// The most taken.
        limit: f64,
    },
    /// The image has no pixels, or too many.
    #[error("patch {id}: its image is {width}x{height} pixels; each side must be 1 to {max}")]
    ImageSize {
        /// The patch's id.
        id: u64,
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
        /// The most pixels a side.
        max: u32,
    },
    /// The texel bytes do not match the image size.
    #[error(
        "patch {id}: {found} bytes of texels for a {width}x{height} image of {bpt} bytes a texel; expected {expected}"
    )]
    TexelBytes {
        /// The patch's id.
        id: u64,
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
        /// The grid's bytes per texel.
        bpt: usize,
        /// The bytes the image takes.
        expected: usize,
        /// The bytes given.
        found: usize,
    },
    /// The box holds no texel centre of the grid: its data would never show.
    #[error("patch {id}: its box {bbox:?} holds the centre of no level-0 texel ({per_unit} texels a unit); it is smaller than a texel there: give a larger box or a finer grid")]
    NoTexel {
        /// The patch's id.
        id: u64,
        /// Its box.
        bbox: WorldBox,
        /// The grid's level-0 texels per world unit.
        per_unit: f64,
    },
    /// The rating is not a finite number.
    #[error("patch {id}: its rating {rating} is not a finite number")]
    Rating {
        /// The patch's id.
        id: u64,
        /// The rating given.
        rating: f64,
    },
}

impl Grid {
    /// A grid, checked: a finite origin, a finite positive resolution, a power-of-two tile of 1 to
    /// 4096 texels, 1 to 16 bytes a texel made of whole components of 1 or 2 bytes.
    pub fn new(
        origin: [f64; 2],
        texels_per_unit: f64,
        tile: u64,
        bytes_per_texel: usize,
        component_bytes: usize,
    ) -> Result<Grid, GrowError> {
        let bad = |what, found: String, expected| Err(GrowError::Grid { what, found, expected });
        if !origin.iter().all(|v| v.is_finite()) {
            return bad("the origin", format!("{origin:?}"), "finite world coordinates");
        }
        if !(texels_per_unit.is_finite() && texels_per_unit > 0.0) {
            return bad("texels per unit", texels_per_unit.to_string(), "a finite number above 0");
        }
        if !(tile.is_power_of_two() && tile <= 4096) {
            return bad("the tile size", tile.to_string(), "a power of two from 1 to 4096");
        }
        if !matches!(component_bytes, 1 | 2) {
            return bad("bytes per component", component_bytes.to_string(), "1 or 2");
        }
        if !(1..=16).contains(&bytes_per_texel) || !bytes_per_texel.is_multiple_of(component_bytes) {
            return bad("bytes per texel", bytes_per_texel.to_string(), "1 to 16, whole components");
        }
        Ok(Grid { origin, texels_per_unit, tile, bytes_per_texel, component_bytes })
    }

    /// Bytes of one tile.
    pub fn tile_bytes(&self) -> usize {
        (self.tile * self.tile) as usize * self.bytes_per_texel
    }

    /// World coordinates of the centre of level-0 texel (i, j).
    pub(crate) fn texel_centre(&self, i: i64, j: i64) -> [f64; 2] {
        [
            self.origin[0] + (i as f64 + 0.5) / self.texels_per_unit,
            self.origin[1] + (j as f64 + 0.5) / self.texels_per_unit,
        ]
    }

    /// The level-0 texels whose centres lie in `b`: `[i0, i1) x [j0, j1)` (empty when none).
    pub fn texels_in(&self, b: &WorldBox) -> [i64; 4] {
        // Centre of texel i is in [min, max) iff i >= ceil(x(min) - 0.5) and i < ceil(x(max) - 0.5).
        let lo = |a: usize, v: f64| ((v - self.origin[a]) * self.texels_per_unit - 0.5).ceil() as i64;
        [lo(0, b.min[0]), lo(1, b.min[1]), lo(0, b.max[0]), lo(1, b.max[1])]
    }

    /// The tiles of level `k` holding any of level-0 texels `[i0, i1) x [j0, j1)`:
    /// `[s0, s1) x [t0, t1)`, or `None` when the range is empty.
    pub fn tiles_over(&self, texels: [i64; 4], k: u32) -> Option<[i64; 4]> {
        let [i0, j0, i1, j1] = texels;
        if i0 >= i1 || j0 >= j1 {
            return None;
        }
        let span = (self.tile as i64) << k;
        Some([i0.div_euclid(span), j0.div_euclid(span), (i1 - 1).div_euclid(span) + 1, (j1 - 1).div_euclid(span) + 1])
    }

    /// The world box of tile (s, t) of level `k` (what patches it may need).
    pub(crate) fn tile_box(&self, k: u32, s: i64, t: i64) -> WorldBox {
        let span = ((self.tile as i64) << k) as f64 / self.texels_per_unit;
        WorldBox {
            min: [self.origin[0] + s as f64 * span, self.origin[1] + t as f64 * span],
            max: [self.origin[0] + (s + 1) as f64 * span, self.origin[1] + (t + 1) as f64 * span],
        }
    }
}

/// What a patch says of itself besides its image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PatchMeta {
    /// Caller's identifier.
    pub id: u64,
    /// Where it lies, world units.
    pub bbox: WorldBox,
    /// When it was taken.
    pub time: u64,
    /// Its quality.
    pub rating: f64,
}

/// One georeferenced image.
#[derive(Clone, Debug, PartialEq)]
pub struct Patch {
    /// Caller's identifier (in errors; the last tie-break: higher wins).
    pub id: u64,
    /// Where it lies, world units.
    pub bbox: WorldBox,
    /// When it was taken (any monotonic unit): among equal ratings, the newest wins.
    pub time: u64,
    /// Its quality: the highest rating wins.
    pub rating: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Row-major texels, the first row along the box's top edge (largest y), each row from its
    /// left edge (smallest x), as image files store them: `width * height * bytes_per_texel` bytes.
    pub texels: Vec<u8>,
}

impl Patch {
    /// A patch, checked against `grid`: a finite, non-empty box within reach of the origin,
    /// spanning a sane number of texels and at least one texel centre; an image of 1 to 65536
    /// pixels a side with exactly its texels; a finite rating. Nothing is kept of a refused patch.
    pub fn new(grid: &Grid, meta: PatchMeta, width: u32, height: u32, texels: Vec<u8>) -> Result<Patch, GrowError> {
        let PatchMeta { id, bbox, time, rating } = meta;
        if !bbox.min.iter().chain(&bbox.max).all(|v| v.is_finite()) {
            return Err(GrowError::NotFinite { id, bbox });
        }
        for (a, axis) in [(0, 'x'), (1, 'y')] {
            let (min, max) = (bbox.min[a], bbox.max[a]);
            if min >= max {
                return Err(GrowError::EmptyBox { id, axis, min, max });
            }
            let span = (max - min) * grid.texels_per_unit;
            if span > MAX_PATCH_SPAN_TEXELS {
                return Err(GrowError::Absurd {
                    id,
                    axis,
                    span,
                    what: "its width in texels",
                    limit: MAX_PATCH_SPAN_TEXELS,
                });
            }
            let far = ((min - grid.origin[a]).abs().max((max - grid.origin[a]).abs())) * grid.texels_per_unit;
            if far > MAX_GRID_EXTENT_TEXELS {
                return Err(GrowError::Absurd {
                    id,
                    axis,
                    span: far,
                    what: "its distance from the origin",
                    limit: MAX_GRID_EXTENT_TEXELS,
                });
            }
        }
        let [i0, j0, i1, j1] = grid.texels_in(&bbox);
        if i0 >= i1 || j0 >= j1 {
            return Err(GrowError::NoTexel { id, bbox, per_unit: grid.texels_per_unit });
        }
        if width == 0 || height == 0 || width > MAX_PATCH_PIXELS || height > MAX_PATCH_PIXELS {
            return Err(GrowError::ImageSize { id, width, height, max: MAX_PATCH_PIXELS });
        }
        let expected = width as usize * height as usize * grid.bytes_per_texel;
        if texels.len() != expected {
            return Err(GrowError::TexelBytes {
                id,
                width,
                height,
                bpt: grid.bytes_per_texel,
                expected,
                found: texels.len(),
            });
        }
        if !rating.is_finite() {
            return Err(GrowError::Rating { id, rating });
        }
        Ok(Patch { id, bbox, time, rating, width, height, texels })
    }

    /// The patch's texel nearest to world point `p` (which must lie in its box).
    pub fn sample(&self, p: [f64; 2], bpt: usize) -> &[u8] {
        let u = ((p[0] - self.bbox.min[0]) / (self.bbox.max[0] - self.bbox.min[0]) * self.width as f64) as i64;
        let v = ((self.bbox.max[1] - p[1]) / (self.bbox.max[1] - self.bbox.min[1]) * self.height as f64) as i64;
        let (u, v) = (u.clamp(0, self.width as i64 - 1) as usize, v.clamp(0, self.height as i64 - 1) as usize);
        let at = (v * self.width as usize + u) * bpt;
        &self.texels[at..at + bpt]
    }

    /// Whether `self` wins over `other` where both cover a texel: higher rating, then newer,
    /// then the higher id.
    pub fn beats(&self, other: &Patch) -> bool {
        (self.rating, self.time, self.id) > (other.rating, other.time, other.id)
    }
}
