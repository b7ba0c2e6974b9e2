//! What goes to the GPU each frame. Two methods (docs/GPU.md says which is the default and why):
//!
//! - **tiles**: the GPU layer of a level mirrors its image cache: every tile under the published
//!   valid region that the GPU slot does not hold yet is copied whole, from its slot in the
//!   mapping into the GPU slot `(S mod GW, T mod GH)`, and the slot's tag on the GPU names it.
//!   An upload budget is a whole number of tiles: coarse levels first, nearest the centre first
//!   (a tile larger than the budget goes alone in a frame of its own).
//! - **rects**: only the texels entering the valid region since the last frame (the strips of
//!   the new region less the old), cut tile by tile from the published slots with the tile's row
//!   pitch, at the same texel positions (the texture is toroidal per texel, period GW TW x GH TH).
//!
//! Both leave the GPU holding, for each enabled level, every texel of the published valid region
//! (or, under a budget, tell the shader through the tags which tiles it does not hold yet).

use crate::gpu::{Gpu, LevelShape, Renderer, Texels};
use crate::heights::HeightShading;
use anyhow::{anyhow, Result};
use clipmap::geom::{tiles_covering, Rect};
use clipmap::shm::{Client, ReadError, Snapshot};
use clipmap::texel::Bc;
use std::time::Instant;

/// The upload method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Whole tiles into their slots.
    Tiles,
    /// The entering strips, cut from the tiles.
    Rects,
}

/// What one frame's upload did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct UploadStats {
    /// Texel bytes sent to the GPU (as published: bytes per texel of the mapping; for a
    /// block-compressed mapping, the tiles' blocks).
    pub bytes: u64,
    /// Bytes written to the GPU texture: as published, widened to four components (the GPU's
    /// texels); a block-compressed mapping's blocks as they are, or their RGBA8 decode where the
    /// adapter lacks BC textures.
    pub gpu_bytes: u64,
    /// What the same texels would have cost as RGBA8 (4 bytes a texel): the base of
    /// `upload_bytes_vs_rgba8`.
    pub rgba8_bytes: u64,
    /// Texel bytes of the strips that entered the valid regions since the last frame.
    pub theory_bytes: u64,
    /// The tile-rounded bound of the tiles method: the tiles each strip touches, whole.
    pub bound_bytes: u64,
    /// `write_texture` calls.
    pub writes: u64,
    /// Tiles (or tile pieces, for rects) that could not be read this frame (stale, busy).
    pub deferred: u64,
    /// Tiles the budget left for a later frame.
    pub over_budget: u64,
    /// Tiles the service could not read (their texels come from a coarser level).
    pub missing: u64,
    /// Bytes of slot tags written.
    pub tag_bytes: u64,
    /// Wall-clock milliseconds: reading the mapping, converting, queueing and submitting.
    pub ms: f64,
}

/// The GPU's copy of each level, as far as this client knows.
pub struct Uploader {
    method: Method,
    budget: Option<u64>,
    /// Per level, per slot: the tile held and whether its texels are there.
    held: Vec<Vec<([i64; 2], bool)>>,
    /// Per level: the region whose texels the GPU holds (rects).
    region: Vec<Rect>,
    /// Per level: the valid region of the previous frame's snapshot (for the strips).
    previous: Vec<Rect>,
    bpt: usize,
    /// Bytes of one published component (1 or 2).
    component: usize,
    /// Heights: how their texels go to the GPU.
    heights: Option<HeightShading>,
    tile_buf: Vec<u8>,
    rgba: Vec<u8>,
    /// A block-compressed mapping's format.
    block: Option<Bc>,
    /// Its blocks go to the GPU as they are (else decoded on the CPU to RGBA8).
    gpu_blocks: bool,
}

/// `a` less `b` as at most four rectangles (above, below, left, right of their intersection).
pub fn minus(a: Rect, b: Rect) -> Vec<Rect> {
    let i = a.intersect(&b);
    if i.is_empty() {
        return if a.is_empty() { vec![] } else { vec![a] };
    }
    [
        Rect::new(a.s0, a.t0, a.s1, i.t0),
        Rect::new(a.s0, i.t1, a.s1, a.t1),
        Rect::new(a.s0, i.t0, i.s0, i.t1),
        Rect::new(i.s1, i.t0, a.s1, i.t1),
    ]
    .into_iter()
    .filter(|r| !r.is_empty())
    .collect()
}

/// Published texels (`bpt` bytes, components of `component` bytes, little-endian) to four
/// components of the same width for the GPU (RGBA8 or RGBA16), as
/// `clipmap::texel::TexelFormat::decode` reads them: L is (L, L, L, 1), LA is (L, L, L, A), RGB is
/// (R, G, B, 1).
fn expand(bpt: usize, component: usize, src: &[u8], out: &mut Vec<u8>) {
    out.clear();
    let n = bpt / component;
    if n == 4 {
        out.extend_from_slice(src);
        return;
    }
    let one = [0xffu8; 2];
    let one = &one[..component];
    for t in src.chunks_exact(bpt) {
        let c = |i: usize| &t[i * component..(i + 1) * component];
        let (l, a) = (c(0), if n == 2 { c(1) } else { one });
        match n {
            3 => [c(0), c(1), c(2), one].iter().for_each(|x| out.extend_from_slice(x)),
            _ => [l, l, l, a].iter().for_each(|x| out.extend_from_slice(x)),
        }
    }
}

/// What the GPU holds for a block-compressed mapping on `gpu`: its blocks as they are where the
/// adapter decodes BC textures, else RGBA8 decoded on the CPU ([`Texels::Bits8`]); other texels
/// as `texels` says.
pub fn on_gpu(texels: Texels, gpu_bc: bool) -> Texels {
    match texels {
        Texels::Blocks(_) if !gpu_bc => Texels::Bits8,
        t => t,
    }
}

/// What the GPU holds for a mapping's texel format: heights (the mapping's heights block says
/// so: `l32f`, `l16`, `l16i`) as `R32Float` metres, colours as RGBA8 or RGBA16; the error says
/// what it found when clipgpu cannot upload it, and what it accepts.
pub fn check_format(client: &Client) -> Result<Texels> {
    use clipmap::texel::ComponentType;
    if client.heights.is_some() {
        return Ok(Texels::Float32);
    }
    match clipmap::shm::layout::format_from_code(client.format_code) {
        Some(f) if f.block().is_some() => Ok(Texels::Blocks(f.block().expect("a block format"))),
        Some(f) if f.ctype == ComponentType::U8 && (1..=4).contains(&f.components.count()) => Ok(Texels::Bits8),
        Some(f) if f.ctype == ComponentType::U16 && (1..=4).contains(&f.components.count()) => Ok(Texels::Bits16),
        found => {
            let name = found.map(|f| f.short_name()).unwrap_or_else(|| format!("code {}", client.format_code));
            let float = if matches!(found, Some(f) if f.ctype == ComponentType::F32 || f.ctype == ComponentType::I16) {
                format!(" ({name} is drawn only as heights, and the mapping's heights block says these texels are not)")
            } else {
                String::new()
            };
            Err(anyhow!(
                "{}: texel format {name} is not one clipgpu uploads{float}; expected colour of 8 or 16 bits a \
                 component (L8, RGB8, RGBA8, L16, LA16, RGB16 or RGBA16), block-compressed colour (bc1, bc4, bc5, \
                 bc7), or heights (l32f, l16 or l16i with the \
                 mapping's heights block, docs/ELEVATION.md); serve the texture in one of those",
                client.path().display()
            ))
        }
    }
}

impl Uploader {
    /// Nothing held yet. `heights`: the height texture's shading (its texels go to the GPU by
    /// [`HeightShading::to_gpu`]); `None` for colour.
    /// `block`: the mapping's block format, if it is one (its tiles' blocks go to the GPU as they
    /// are when `texels` is [`Texels::Blocks`], else decoded on the CPU).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        levels: &[LevelShape],
        bpt: usize,
        texels: Texels,
        block: Option<Bc>,
        heights: Option<HeightShading>,
        method: Method,
        budget: Option<u64>,
    ) -> Uploader {
        Uploader {
            method,
            budget,
            held: levels
                .iter()
                .map(|l| vec![([i64::MIN, i64::MIN], false); (l.grid[0] * l.grid[1]) as usize])
                .collect(),
            region: vec![Rect::EMPTY; levels.len()],
            previous: vec![Rect::EMPTY; levels.len()],
            bpt,
            component: texels.bytes() as usize / 4,
            heights,
            tile_buf: Vec::new(),
            rgba: Vec::new(),
            block,
            gpu_blocks: matches!(texels, Texels::Blocks(_)),
        }
    }

    /// Bytes of one tile of level shape `l` as published: its texels, or its blocks.
    fn tile_bytes(&self, l: &LevelShape) -> u64 {
        match self.block {
            Some(_) => l.tile[0].div_ceil(4) * l.tile[1].div_ceil(4) * self.bpt as u64,
            None => l.tile[0] * l.tile[1] * self.bpt as u64,
        }
    }

    /// The texels read (`tile_buf`, a `size` tile) as the GPU holds them (`rgba`): a block
    /// mapping's blocks as they are, or decoded (`bcdec_rs`) and widened as the CPU reads them.
    fn convert(&mut self, size: [u64; 2]) {
        match (&self.heights, self.block) {
            (Some(h), _) => h.to_gpu(&self.tile_buf, &mut self.rgba),
            (None, Some(_)) if self.gpu_blocks => {
                self.rgba.clear();
                self.rgba.extend_from_slice(&self.tile_buf);
            }
            (None, Some(bc)) => {
                let texels = clipmap::shm::blocks::decode(bc, &self.tile_buf, size[0], size[1])
                    .expect("a tile read whole is its blocks");
                expand(clipmap::shm::blocks::decoded_bytes(bc), 1, &texels, &mut self.rgba);
            }
            (None, None) => expand(self.bpt, self.component, &self.tile_buf, &mut self.rgba),
        }
    }

    /// The mapping's block format, if it is one.
    pub fn block(&self) -> Option<Bc> {
        self.block
    }

    /// Per level, per slot: the tile the GPU slot holds and whether its texels are there (the
    /// GPU's tags).
    pub fn held(&self) -> &[Vec<([i64; 2], bool)>] {
        &self.held
    }

    /// Brings the GPU up to `snap`: uploads what it lacks of every enabled level's valid region.
    pub fn upload(&mut self, gpu: &Gpu, r: &Renderer, client: &Client, snap: &Snapshot) -> Result<UploadStats> {
        let t0 = Instant::now();
        let mut st = UploadStats::default();
        let bpt = self.bpt as u64;
        for (k, l) in r.levels.iter().enumerate() {
            let now = snap.levels[k].rect();
            for strip in minus(now, self.previous[k]) {
                // A block format: bpt bytes a block of 16 texels.
                st.theory_bytes += if self.block.is_some() { strip.area() * bpt / 16 } else { strip.area() * bpt };
                st.bound_bytes += tiles_covering(strip, l.tile).area() * self.tile_bytes(l);
            }
            self.previous[k] = now;
        }
        let mut changed: Vec<(usize, usize)> = Vec::new();
        match self.method {
            Method::Tiles => self.tiles(gpu, r, client, snap, &mut st, &mut changed),
            Method::Rects => self.rects(gpu, r, client, snap, &mut st, &mut changed),
        }
        for (k, slot) in changed {
            let first = r.levels[k].tag_base as usize + slot;
            r.write_tags(gpu, first, &self.held[k][slot..slot + 1]);
            st.tag_bytes += 16;
        }
        r.flush(gpu);
        gpu.wait()?;
        st.ms = t0.elapsed().as_secs_f64() * 1000.0;
        Ok(st)
    }

    fn tiles(
        &mut self,
        gpu: &Gpu,
        r: &Renderer,
        client: &Client,
        snap: &Snapshot,
        st: &mut UploadStats,
        changed: &mut Vec<(usize, usize)>,
    ) {
        let mut spent = 0u64;
        // Coarse levels first: under a budget the finer ones fall back on them.
        for k in (0..r.levels.len()).rev() {
            let l = r.levels[k];
            let state = snap.levels[k];
            if !state.enabled {
                continue;
            }
            let tiles = tiles_covering(state.rect(), l.tile);
            let mut order: Vec<[i64; 2]> =
                (tiles.t0..tiles.t1).flat_map(|t| (tiles.s0..tiles.s1).map(move |s| [s, t])).collect();
            let (ts, tt) = (l.tile[0] as i64, l.tile[1] as i64);
            let c = state.centre;
            let c = [l.near_window(c[0], state.rect()), c[1]];
            order.sort_by_key(|&[s, t]| (s * ts + ts / 2 - c[0]).abs().max((t * tt + tt / 2 - c[1]).abs()));
            // A region past the width (a texture that wraps in longitude) names tiles past the
            // level's: tile S is tile S mod the tiles across.
            let order: Vec<[i64; 2]> = order.into_iter().map(|[s, t]| [l.real_tile(s), t]).collect();
            let tile_bytes = self.tile_bytes(&l);
            for tile in order {
                let slot = clipmap::shm::layout::slot_index(l.grid, tile) as usize;
                if self.held[k][slot] == (tile, true) {
                    continue;
                }
                // A tile larger than the whole budget still goes, alone, so that every tile arrives.
                if self.budget.is_some_and(|b| spent > 0 && spent + tile_bytes > b) {
                    st.over_budget += 1;
                    continue;
                }
                self.tile_buf.resize(tile_bytes as usize, 0);
                match client.read_tile(k, tile, &mut self.tile_buf) {
                    Ok(()) => {
                        self.convert(l.tile);
                        let at = [(slot as u64 % l.grid[0]) * l.tile[0], (slot as u64 / l.grid[0]) * l.tile[1]];
                        r.write_texels(
                            gpu,
                            k,
                            [at[0] as u32, at[1] as u32],
                            [l.tile[0] as u32, l.tile[1] as u32],
                            &self.rgba,
                        );
                        st.bytes += tile_bytes;
                        st.gpu_bytes += self.rgba.len() as u64;
                        st.rgba8_bytes += l.tile[0] * l.tile[1] * 4;
                        st.writes += 1;
                        spent += tile_bytes;
                        self.held[k][slot] = (tile, true);
                    }
                    Err(ReadError::Missing { .. }) => {
                        st.missing += 1;
                        if self.held[k][slot] == (tile, false) {
                            continue;
                        }
                        self.held[k][slot] = (tile, false);
                    }
                    Err(_) => {
                        st.deferred += 1;
                        if !self.held[k][slot].1 {
                            continue;
                        }
                        self.held[k][slot] = ([i64::MIN, i64::MIN], false);
                    }
                }
                changed.push((k, slot));
            }
        }
    }

    fn rects(
        &mut self,
        gpu: &Gpu,
        r: &Renderer,
        client: &Client,
        snap: &Snapshot,
        st: &mut UploadStats,
        changed: &mut Vec<(usize, usize)>,
    ) {
        for (k, l) in r.levels.iter().enumerate() {
            let state = snap.levels[k];
            if !state.enabled {
                continue;
            }
            let now = state.rect();
            let (tw, th) = (l.tile[0] as i64, l.tile[1] as i64);
            let period = [l.tile[0] * l.grid[0], l.tile[1] * l.grid[1]];
            let mut failed = false;
            for strip in minus(now, self.region[k]) {
                let tiles = tiles_covering(strip, l.tile);
                for tt in tiles.t0..tiles.t1 {
                    for ts in tiles.s0..tiles.s1 {
                        let piece = strip.intersect(&Rect::new(ts * tw, tt * th, (ts + 1) * tw, (tt + 1) * th));
                        let slot = clipmap::shm::layout::slot_index(l.grid, [ts, tt]) as usize;
                        self.tile_buf.resize((piece.area() as usize) * self.bpt, 0);
                        let ok = match client.read_region_in(snap, k, piece, &mut self.tile_buf) {
                            Ok(()) => {
                                self.convert([piece.width(), piece.height()]);
                                let at = [piece.s0 as u64 % period[0], piece.t0 as u64 % period[1]];
                                r.write_texels(
                                    gpu,
                                    k,
                                    [at[0] as u32, at[1] as u32],
                                    [piece.width() as u32, piece.height() as u32],
                                    &self.rgba,
                                );
                                st.bytes += piece.area() * self.bpt as u64;
                                st.gpu_bytes += self.rgba.len() as u64;
                                st.rgba8_bytes += piece.area() * 4;
                                st.writes += 1;
                                true
                            }
                            Err(ReadError::Missing { .. }) => {
                                st.missing += 1;
                                false
                            }
                            Err(_) => {
                                st.deferred += 1;
                                failed = true;
                                false
                            }
                        };
                        let tag = ([l.real_tile(ts), tt], ok);
                        if self.held[k][slot] != tag {
                            self.held[k][slot] = tag;
                            changed.push((k, slot));
                        }
                    }
                }
            }
            // A piece that could not be read is tried again with the whole region next frame.
            self.region[k] = if failed { Rect::EMPTY } else { now };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_region_less_another_is_the_strips_that_entered() {
        let a = Rect::new(10, 10, 30, 30);
        assert_eq!(minus(a, a), vec![]);
        assert_eq!(minus(a, Rect::EMPTY), vec![a]);
        assert_eq!(minus(a, Rect::new(100, 100, 120, 120)), vec![a]);
        // Moved by (+3, -2): a strip of 3 columns on the right, 2 rows at the top.
        let old = Rect::new(7, 12, 27, 32);
        let strips = minus(a, old);
        assert_eq!(strips.iter().map(|r| r.area()).sum::<u64>(), a.area() - a.intersect(&old).area());
        assert_eq!(strips, vec![Rect::new(10, 10, 30, 12), Rect::new(27, 12, 30, 30)]);
    }

    #[test]
    fn published_texels_expand_to_rgba_as_the_cpu_decodes_them() {
        let mut out = Vec::new();
        expand(3, 1, &[1, 2, 3, 4, 5, 6], &mut out);
        assert_eq!(out, vec![1, 2, 3, 255, 4, 5, 6, 255]);
        expand(1, 1, &[9, 8], &mut out);
        assert_eq!(out, vec![9, 9, 9, 255, 8, 8, 8, 255]);
        expand(4, 1, &[1, 2, 3, 4], &mut out);
        assert_eq!(out, vec![1, 2, 3, 4]);
        // 16 bits a component, little-endian components kept whole: L16, LA16, RGB16, RGBA16.
        expand(2, 2, &[0x34, 0x12, 0xff, 0xee], &mut out);
        assert_eq!(
            out,
            vec![0x34, 0x12, 0x34, 0x12, 0x34, 0x12, 255, 255, 0xff, 0xee, 0xff, 0xee, 0xff, 0xee, 255, 255]
        );
        expand(4, 2, &[1, 2, 3, 4], &mut out);
        assert_eq!(out, vec![1, 2, 1, 2, 1, 2, 3, 4]);
        expand(6, 2, &[1, 2, 3, 4, 5, 6], &mut out);
        assert_eq!(out, vec![1, 2, 3, 4, 5, 6, 255, 255]);
        expand(8, 2, &[1, 2, 3, 4, 5, 6, 7, 8], &mut out);
        assert_eq!(out, vec![1, 2, 3, 4, 5, 6, 7, 8]);
        // Each as the CPU decodes it.
        use clipmap::texel::TexelFormat as F;
        for (f, texel, component) in [
            (F::L8, vec![77u8], 1),
            (F::RGB8, vec![1, 2, 3], 1),
            (F::L16, vec![0x34, 0x12], 2),
            (F::LA16, vec![0x34, 0x12, 7, 9], 2),
            (F::RGB16, vec![1, 2, 3, 4, 5, 6], 2),
        ] {
            expand(texel.len(), component, &texel, &mut out);
            let max = if component == 1 { 255.0 } else { 65535.0 };
            let got: Vec<f32> = out
                .chunks_exact(component)
                .map(|c| if component == 1 { c[0] as f32 } else { u16::from_le_bytes([c[0], c[1]]) as f32 } / max)
                .collect();
            assert_eq!(got, f.decode(&texel).to_vec(), "{f}");
        }
    }
}
