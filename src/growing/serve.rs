//! Serving a growing texture while it grows: the fixed frame it is published in, the tile source
//! that cuts the frame's tiles from the store's, and the grower thread that takes patches in
//! (from the control socket and a watched directory), rebuilds, saves, and tells the service
//! which tiles changed.
//!
//! **The frame.** A clipmap has a fixed size and level count, and renderers address slots by
//! arithmetic, so a growing texture is served in a fixed frame of `2^F` level-0 texels a side
//! whose centre is the grid's origin: frame texel `(s, t)` of level `k` is store texel
//! `(s - 2^(F-k-1), t - 2^(F-k-1))` of the same level (the store's tiles split at the origin on
//! every level, and so do the frame's), and the frame's last level (1 x 1) is the average of the
//! level above's four texels that have data, as every coarser texel of the store is. Nothing moves
//! as the texture grows: growth shows as tiles that get data, and in the mapping's growth block
//! (extent, data levels). Levels above the store's top (the store stops where 2 x 2 tiles hold
//! everything) are built here by the store's own rule, from its top.
//!
//! **Tiles with and without data.** A frame tile with no data of its own is *missing* (its slot's
//! tag says so, and renderers use a coarser level for it: the tile map of the finest level that
//! exists, for every tile a renderer can see). A tile with data on some texels only is served
//! with its other texels taken from the finest coarser level that has data there (nearest), so a
//! renderer that samples it gets the finest data there is. Such a tile's texels depend only on the
//! store's data inside its own footprint, so a tile changes exactly when a store tile of its level
//! under it changes; the service replaces resident tiles in their slots then, read again through
//! the read queues like any tile ([`crate::clip::Clipmap::refresh`]).

use super::rebuild::{parent_tile, Tile, TileKey};
use super::store::{Growing, StoreError};
use super::Grid;
use super::NewPatch;
use crate::shm::layout::Growth;
use crate::source::{check_request, DescError, SourceError, TextureDesc, TileId, TileSource};
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{mpsc, Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// The fixed frame a growing texture is served in: `2^log2` level-0 texels a side, centred on the
/// grid's origin.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame {
    /// log2 of the level-0 size.
    pub log2: u32,
}

impl Frame {
    /// A frame of `size` texels a side for tiles of `tile` texels: a power of two, at least two
    /// tiles (the origin splits it) and at most [`crate::source::MAX_TEXTURE_SIZE`].
    pub fn new(size: u64, tile: u64) -> Result<Frame, String> {
        let max = crate::source::MAX_TEXTURE_SIZE;
        if !size.is_power_of_two() || size < 2 * tile.max(1) || size > max {
            return Err(format!(
                "the frame of a growing texture is {size} texels a side; expected a power of two from two tiles ({}) to {max}",
                2 * tile.max(1)
            ));
        }
        Ok(Frame { log2: size.trailing_zeros() })
    }

    /// Level-0 texels a side.
    pub fn size(&self) -> u64 {
        1 << self.log2
    }

    /// Store texel + this = frame texel, at level `k` (below the 1 x 1 level).
    pub fn offset(&self, k: u32) -> i64 {
        1i64 << (self.log2 - k - 1)
    }

    /// The frame's level-0 texels `[s0, t0, s1, t1)` of store texels `[i0, j0, i1, j1)`, clipped to
    /// the frame; `None` when nothing is left.
    pub(crate) fn clip_level0(&self, texels: [i64; 4]) -> Option<[i64; 4]> {
        let (o, n) = (self.offset(0), self.size() as i64);
        let c = |v: i64| (v.saturating_add(o)).clamp(0, n);
        let r = [c(texels[0]), c(texels[1]), c(texels[2]), c(texels[3])];
        (r[0] < r[2] && r[1] < r[3]).then_some(r)
    }
}

/// Texels cut from the store for one rectangle of one level.
struct Piece {
    w: usize,
    texels: Vec<u8>,
    /// Per texel: whether it has a value (its own data, or a coarser level's).
    has: Vec<bool>,
    /// Texels with data of their own.
    own: usize,
}

/// What a service shares with its grower: the store's tiles as last saved, and what changed.
pub struct Served {
    frame: Frame,
    grid: Grid,
    state: Mutex<State>,
}

#[derive(Default)]
struct State {
    /// Every tile with data the frame needs, store levels and the levels built above them.
    tiles: HashMap<TileKey, Arc<Tile>>,
    /// Tiles changed since the service last took them.
    changed: Vec<TileKey>,
    growth: Growth,
    /// Bumped whenever `growth` changes.
    version: u64,
    /// Frame tiles last served with some texels from a coarser level: they change when any
    /// store tile above them under their footprint does (those are rebuilt after them).
    partial: std::collections::HashSet<TileId>,
}

impl std::fmt::Debug for Served {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Served").field("frame", &self.frame).field("grid", &self.grid).finish()
    }
}

impl Served {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The frame.
    pub fn frame(&self) -> Frame {
        self.frame
    }

    /// The growth block's values now, with a version that changes whenever they do.
    pub fn growth(&self) -> (u64, Growth) {
        let s = self.lock();
        (s.version, s.growth)
    }

    /// The frame tiles whose texels changed since the last call (each once), for
    /// [`crate::clip::Clipmap::refresh`]; `desc` is the frame's texture. A changed store tile
    /// changes the frame tiles of its level under it, and any frame tile of a finer level under
    /// it that was served with texels taken from coarser levels (those are rebuilt after it).
    pub fn take_changed(&self, desc: &TextureDesc) -> Vec<TileId> {
        let (changed, partial) = {
            let mut s = self.lock();
            let changed = std::mem::take(&mut s.changed);
            let partial: Vec<TileId> =
                if changed.is_empty() { Vec::new() } else { s.partial.iter().copied().collect() };
            (changed, partial)
        };
        let mut out: Vec<TileId> = Vec::new();
        let t = self.grid.tile as i64;
        let top = self.frame.log2;
        // Each change as a rectangle of frame texels of its level.
        let mut rects: Vec<(u32, [i64; 4])> = Vec::new();
        for (k, i, j) in changed {
            if k >= top {
                continue;
            }
            let (o, n) = (self.frame.offset(k), desc.level(k).size[0] as i64);
            let r = [(i * t + o).max(0), (j * t + o).max(0), ((i + 1) * t + o).min(n), ((j + 1) * t + o).min(n)];
            if r[0] >= r[2] || r[1] >= r[3] {
                continue;
            }
            rects.push((k, r));
            if k + 1 == top {
                rects.push((top, [0, 0, 1, 1]));
            }
        }
        for &(k, [x0, y0, x1, y1]) in &rects {
            let ft = desc.level(k).tile[0] as i64;
            for ty in y0 / ft..=(y1 - 1) / ft {
                for tx in x0 / ft..=(x1 - 1) / ft {
                    out.push(TileId::new(k, tx as u64, ty as u64));
                }
            }
        }
        for p in partial {
            let l = desc.level(p.level);
            let (x0, y0) = ((p.s * l.tile[0]) as i64, (p.t * l.tile[1]) as i64);
            let (x1, y1) = (x0 + l.tile[0] as i64, y0 + l.tile[1] as i64);
            let under = rects.iter().any(|&(k, r)| {
                if k <= p.level {
                    return false;
                }
                let d = k - p.level;
                x0 >> d < r[2] && (x1 - 1) >> d >= r[0] && y0 >> d < r[3] && (y1 - 1) >> d >= r[1]
            });
            if under {
                out.push(p);
            }
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// Forgets partly served tiles `keep` says no (tiles the clipmap no longer holds).
    pub fn retain_partial(&self, keep: impl Fn(TileId) -> bool) {
        self.lock().partial.retain(|&t| keep(t));
    }

    fn tile(&self, key: TileKey) -> Option<Arc<Tile>> {
        self.lock().tiles.get(&key).cloned()
    }

    /// Level `k`'s store texels `[x0, x0 + w) x [y0, y0 + h)` that have data of their own (the
    /// 1 x 1 level at `k == log2`: the average of level `log2 - 1`'s four texels around the origin).
    fn own(&self, k: u32, x0: i64, y0: i64, w: usize, h: usize) -> Piece {
        let bpt = self.grid.bytes_per_texel;
        let mut p = Piece { w, texels: vec![0; w * h * bpt], has: vec![false; w * h], own: 0 };
        if k == self.frame.log2 {
            let below = self.own(k - 1, -1, -1, 2, 2);
            let with: Vec<&[u8]> =
                (0..4).filter(|&i| below.has[i]).map(|i| &below.texels[i * bpt..(i + 1) * bpt]).collect();
            if !with.is_empty() {
                mean(&with, self.grid.component_bytes, &mut p.texels[..bpt]);
                p.has[0] = true;
                p.own = 1;
            }
            return p;
        }
        let t = self.grid.tile as i64;
        let (x1, y1) = (x0 + w as i64, y0 + h as i64);
        for ty in y0.div_euclid(t)..=(y1 - 1).div_euclid(t) {
            for tx in x0.div_euclid(t)..=(x1 - 1).div_euclid(t) {
                let Some(tile) = self.tile((k, tx, ty)) else { continue };
                let (xa, xb) = (x0.max(tx * t), x1.min((tx + 1) * t));
                let (ya, yb) = (y0.max(ty * t), y1.min((ty + 1) * t));
                for y in ya..yb {
                    let src_row = ((y - ty * t) * t + (xa - tx * t)) as usize;
                    let dst_row = ((y - y0) as usize) * w + (xa - x0) as usize;
                    let n = (xb - xa) as usize;
                    if tile.full() {
                        p.texels[dst_row * bpt..(dst_row + n) * bpt]
                            .copy_from_slice(&tile.texels[src_row * bpt..(src_row + n) * bpt]);
                        p.has[dst_row..dst_row + n].fill(true);
                        p.own += n;
                        continue;
                    }
                    for i in 0..n {
                        if tile.has(src_row + i) {
                            let (s, d) = ((src_row + i) * bpt, (dst_row + i) * bpt);
                            p.texels[d..d + bpt].copy_from_slice(&tile.texels[s..s + bpt]);
                            p.has[dst_row + i] = true;
                            p.own += 1;
                        }
                    }
                }
            }
        }
        p
    }

    /// [`Served::own`], with every texel without data of its own taken from the finest coarser
    /// level that has data there.
    fn composed(&self, k: u32, x0: i64, y0: i64, w: usize, h: usize) -> Piece {
        let mut p = self.own(k, x0, y0, w, h);
        if p.own == w * h || k >= self.frame.log2 {
            return p;
        }
        let bpt = self.grid.bytes_per_texel;
        // The parent rectangle (floor halving), or the 1 x 1 level's only texel.
        let (px0, py0, pw, ph) = if k + 1 == self.frame.log2 {
            (0, 0, 1, 1)
        } else {
            let (px0, py0) = (x0.div_euclid(2), y0.div_euclid(2));
            let px1 = (x0 + w as i64 - 1).div_euclid(2) + 1;
            let py1 = (y0 + h as i64 - 1).div_euclid(2) + 1;
            (px0, py0, (px1 - px0) as usize, (py1 - py0) as usize)
        };
        let parent = self.composed(k + 1, px0, py0, pw, ph);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if p.has[i] {
                    continue;
                }
                let q = if pw == 1 && ph == 1 && k + 1 == self.frame.log2 {
                    0
                } else {
                    let qx = (x0 + x as i64).div_euclid(2) - px0;
                    let qy = (y0 + y as i64).div_euclid(2) - py0;
                    qy as usize * parent.w + qx as usize
                };
                if parent.has[q] {
                    p.texels[i * bpt..(i + 1) * bpt].copy_from_slice(&parent.texels[q * bpt..(q + 1) * bpt]);
                    p.has[i] = true;
                }
            }
        }
        p
    }

    /// Puts the store's tiles and the levels built above them in place; returns the keys whose
    /// tiles changed. `keys` are the store tiles that changed (`None`: all of them, at start).
    fn update(&self, store: &Growing, keys: Option<Vec<TileKey>>) -> Vec<TileKey> {
        let levels = store.levels();
        let top = self.frame.log2;
        let mut s = self.lock();
        let mut changed: Vec<TileKey> = Vec::new();
        let start = keys.is_none();
        let keys: Vec<TileKey> = match keys {
            Some(k) => k,
            None => store.rebuild().keys().copied().collect(),
        };
        for key in keys {
            if key.0 >= top {
                continue;
            }
            match store.tile(key.0, key.1, key.2) {
                Some(t) => s.tiles.insert(key, t.clone()),
                None => s.tiles.remove(&key),
            };
            changed.push(key);
        }
        // Levels above the store's top, by its own rule, up to the frame's last level but one:
        // each from the tiles below it that changed (all of them at start).
        let all = [(-1, -1), (0, -1), (-1, 0), (0, 0)];
        let mut below: Vec<TileKey> = if start { Vec::new() } else { changed.clone() };
        for k in levels.max(1)..top {
            let mut todo: Vec<(i64, i64)> = if start {
                all.to_vec()
            } else {
                below.iter().filter(|c| c.0 + 1 == k).map(|c| (c.1.div_euclid(2), c.2.div_euclid(2))).collect()
            };
            todo.sort_unstable();
            todo.dedup();
            for (i, j) in todo {
                let key = (k, i, j);
                let child = |dx: i64, dy: i64| s.tiles.get(&(k - 1, 2 * i + dx, 2 * j + dy)).cloned();
                let (a, b, c, d) = (child(0, 0), child(1, 0), child(0, 1), child(1, 1));
                let built = parent_tile(&self.grid, [[a.as_deref(), b.as_deref()], [c.as_deref(), d.as_deref()]]);
                let same = match (s.tiles.get(&key), built.any_data()) {
                    (Some(o), true) => **o == built,
                    (None, false) => true,
                    _ => false,
                };
                if same {
                    continue;
                }
                if built.any_data() {
                    s.tiles.insert(key, Arc::new(built));
                } else {
                    s.tiles.remove(&key);
                }
                changed.push(key);
                below.push(key);
            }
        }
        s.changed.extend_from_slice(&changed);
        changed
    }

    fn set_growth(&self, store: &Growing, tiles_rebuilt: u64, outside: u64) {
        let g = &self.grid;
        let extent = store.index().extent().map(|b| g.texels_in(&b)).and_then(|t| self.frame.clip_level0(t));
        let o = self.frame.offset(0) as f64;
        let growth = Growth {
            extent: extent.unwrap_or([0; 4]),
            data_levels: store.levels() as u64,
            patches: store.patches(),
            tiles_rebuilt,
            tiles_pending: store.pending() as u64,
            tiles_replaced: 0,
            world_origin: [g.origin[0] - o / g.texels_per_unit, g.origin[1] - o / g.texels_per_unit],
            texels_per_unit: g.texels_per_unit,
            outside_frame: outside,
        };
        let mut s = self.lock();
        if s.growth != growth {
            s.growth = growth;
            s.version += 1;
        }
    }
}

/// The rounded mean, per component (`cb` bytes each, little-endian), of `texels`, into `out`: the
/// rule of the store's coarser levels.
fn mean(texels: &[&[u8]], cb: usize, out: &mut [u8]) {
    let n = texels.len() as u64;
    for c in (0..out.len()).step_by(cb) {
        let v = |t: &[u8]| if cb == 1 { t[c] as u64 } else { u16::from_le_bytes([t[c], t[c + 1]]) as u64 };
        let avg = (texels.iter().map(|t| v(t)).sum::<u64>() + n / 2) / n;
        if cb == 1 {
            out[c] = avg as u8;
        } else {
            out[c..c + 2].copy_from_slice(&(avg as u16).to_le_bytes());
        }
    }
}

/// The tiles of a growing texture's frame, cut from the store's (see the module documentation).
pub struct GrowingSource {
    desc: TextureDesc,
    served: Arc<Served>,
    /// The frame's georeferencing, from the grid ([`frame_georef`]), when the grid names a CRS.
    georef: Option<crate::georef::Georef>,
}

/// The georeferencing of the frame `frame` of a grid whose world coordinates are map coordinates
/// of the CRS `epsg` (docs/GEOREF.md, "Growing textures"): level-0 frame texel (s, t) covers world
/// `[o_x + s / r, o_x + (s + 1) / r) x [o_y + t / r, o_y + (t + 1) / r)` with `o` the world point of
/// the frame's south-west corner (the grid's origin less half the frame) and r the texels per
/// unit; t counts north as world y does. So level 0's geotransform (GDAL's order, line 0 the
/// frame's north edge) is `[o_x, 1/r, 0, o_y + 2^F / r, 0, -1/r]`. `None` without a CRS, or
/// for a code this engine does not know.
pub fn frame_georef(grid: &Grid, frame: Frame, epsg: Option<u32>) -> Option<crate::georef::Georef> {
    let crs = crate::georef::Crs::epsg(epsg?).ok()?;
    let r = grid.texels_per_unit;
    let o = frame.offset(0) as f64;
    let n = frame.size() as f64;
    let sw = [grid.origin[0] - o / r, grid.origin[1] - o / r];
    let gt = crate::georef::GeoTransform([sw[0], 1.0 / r, 0.0, sw[1] + n / r, 0.0, -1.0 / r]);
    crate::georef::Georef::new(crs, gt, [frame.size(), frame.size()]).ok()
}

impl std::fmt::Debug for GrowingSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GrowingSource").field("frame", &self.served.frame).finish()
    }
}

impl GrowingSource {
    /// The frame's texture: `frame` for a store of `grid` and `format`, clip size `clip`, the
    /// store's tiles, an invalid border of `clip / 32` (1 to 16).
    pub(crate) fn desc_for(
        frame: Frame,
        grid: &Grid,
        format: crate::texel::TexelFormat,
        clip: u64,
    ) -> Result<TextureDesc, DescError> {
        let size = frame.size();
        let desc = TextureDesc::new([size, size], clip, format, [grid.tile, grid.tile])?;
        let border = (clip / 32).clamp(1, 16);
        desc.with_invalid_border(border.min(clip.saturating_sub(1) / 2))
    }

    /// What the service shares with the grower.
    pub fn served(&self) -> &Arc<Served> {
        &self.served
    }
}

impl TileSource for GrowingSource {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn georef(&self) -> Option<crate::georef::Georef> {
        self.georef.clone()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        check_request(&self.desc, tile, out)?;
        let k = tile.level;
        let l = self.desc.level(k);
        let [tw, th] = l.tile;
        let frame = self.served.frame;
        let (x0, y0) = if k < frame.log2 {
            let o = frame.offset(k);
            ((tile.s * tw) as i64 - o, (tile.t * th) as i64 - o)
        } else {
            (0, 0)
        };
        let p = self.served.composed(k, x0, y0, tw as usize, th as usize);
        let whole = p.own == p.has.len();
        {
            let mut s = self.served.lock();
            if whole || p.own == 0 {
                s.partial.remove(&tile);
            } else {
                s.partial.insert(tile);
            }
        }
        if p.own == 0 {
            return Err(SourceError::Missing { tile });
        }
        out.copy_from_slice(&p.texels);
        Ok(())
    }
}

/// What the grower is asked to do.
pub enum GrowCommand {
    /// Take a patch (acknowledged once it is durable): its id, or why it was refused.
    Add {
        /// The patch.
        patch: NewPatch,
        /// Where it came from (a watched file), recorded so that it is not added twice; `None` from
        /// the control socket.
        source: Option<String>,
        /// Answered with its id once it is durable, or why it was refused.
        reply: tokio::sync::oneshot::Sender<Result<u64, String>>,
    },
    /// Stop after the step under way.
    Stop,
}

/// How the grower works.
#[derive(Clone, Debug)]
pub struct GrowerOptions {
    /// A watched directory of sidecars (see [`super::watch`]).
    pub incoming: Option<PathBuf>,
    /// Most bytes of texels one patch may have.
    pub max_patch_bytes: u64,
    /// Most tiles rebuilt between two looks at the commands.
    pub tiles_per_step: usize,
    /// How often the watched directory is looked at.
    pub poll: Duration,
}

impl Default for GrowerOptions {
    fn default() -> Self {
        GrowerOptions {
            incoming: None,
            max_patch_bytes: 256 << 20,
            tiles_per_step: 64,
            poll: Duration::from_millis(100),
        }
    }
}

/// The unit of [`Grower::in_flight`]'s permits: one KiB.
pub const IN_FLIGHT_UNIT: u64 = 1 << 10;

/// The grower's handle: send it patches; it stops when told or when every handle is gone.
#[derive(Clone, Debug)]
pub struct Grower {
    commands: mpsc::SyncSender<GrowCommand>,
    served: Arc<Served>,
    /// Largest patch accepted, in bytes of texels.
    pub max_patch_bytes: u64,
    /// Bytes of `PATCH DATA` requests in flight, all connections together: twice
    /// `max_patch_bytes`, in permits of `IN_FLIGHT_UNIT` bytes. A request holds its share
    /// from before its first byte is read until its patch is decoded and handed over.
    pub in_flight: Arc<tokio::sync::Semaphore>,
    /// The bound `in_flight` keeps, in bytes.
    pub max_in_flight_bytes: u64,
}

impl Grower {
    /// Hands a command to the grower without blocking; `false` when it is busy or gone.
    pub fn send(&self, cmd: GrowCommand) -> bool {
        self.commands.try_send(cmd).is_ok()
    }

    /// What the service shares with it.
    pub fn served(&self) -> &Arc<Served> {
        &self.served
    }

    /// The store's grid.
    pub fn grid(&self) -> Grid {
        self.served.grid
    }
}

/// Starts serving the store: the frame's tile source, the grower's handle and thread. The store's
/// tiles are in place before this returns, so the first reads see everything saved.
pub fn start(
    mut store: Growing,
    frame: Frame,
    clip: u64,
    options: GrowerOptions,
) -> Result<(Arc<GrowingSource>, Grower, std::thread::JoinHandle<()>), String> {
    let grid = *store.grid();
    let desc = GrowingSource::desc_for(frame, &grid, store.format(), clip).map_err(|e| format!("the frame: {e}"))?;
    let served = Arc::new(Served { frame, grid, state: Mutex::new(State::default()) });
    served.update(&store, None);
    served.lock().changed.clear();
    let outside = move |store: &Growing| {
        let n = frame.size() as i64;
        let o = frame.offset(0);
        store
            .index()
            .patches()
            .iter()
            .filter(|p| {
                let [i0, j0, i1, j1] = grid.texels_in(&p.bbox);
                i0 + o < 0 || j0 + o < 0 || i1 + o > n || j1 + o > n
            })
            .count() as u64
    };
    served.set_growth(&store, 0, outside(&store));
    let (tx, rx) = mpsc::sync_channel(64);
    let georef = frame_georef(&grid, frame, store.epsg());
    let source = Arc::new(GrowingSource { desc, served: served.clone(), georef });
    let max_patch_bytes = options.max_patch_bytes.clamp(1, crate::limits::MAX_PATCH_BYTES);
    let max_in_flight_bytes = max_patch_bytes * 2;
    let handle = Grower {
        commands: tx,
        served: served.clone(),
        max_patch_bytes,
        in_flight: Arc::new(tokio::sync::Semaphore::new(max_in_flight_bytes.div_ceil(IN_FLIGHT_UNIT) as usize)),
        max_in_flight_bytes,
    };
    let join = std::thread::Builder::new()
        .name("clipmapd-grow".into())
        .spawn(move || {
            let mut rebuilt = 0u64;
            let mut outside_of = (store.patches(), outside(&store));
            let mut last_poll = Instant::now() - options.poll;
            loop {
                let busy = store.pending() > 0;
                let wait = if busy { Duration::ZERO } else { options.poll.min(Duration::from_millis(20)) };
                match rx.recv_timeout(wait) {
                    Ok(GrowCommand::Add { patch, source, reply }) => {
                        let r = store.add_from(patch, source).map_err(|e| e.to_string());
                        if let Err(e) = &r {
                            tracing::warn!("patch refused: {e}");
                        }
                        let _ = reply.send(r);
                    }
                    Ok(GrowCommand::Stop) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
                    Err(mpsc::RecvTimeoutError::Timeout) => {}
                }
                if let Some(dir) = &options.incoming {
                    if last_poll.elapsed() >= options.poll {
                        last_poll = Instant::now();
                        match super::watch::round(&mut store, dir, options.max_patch_bytes, 64) {
                            Ok(r) => {
                                for (name, why) in &r.refused {
                                    tracing::warn!("{name} refused: {why}");
                                }
                                for (name, id) in &r.added {
                                    tracing::info!("{name}: patch {id}");
                                }
                            }
                            Err(e) => tracing::warn!("the watched directory {}: {e}", dir.display()),
                        }
                    }
                }
                if store.pending() > 0 || store.applied() < store.patches() {
                    match store.step(options.tiles_per_step) {
                        Ok(done) => rebuilt += done.len() as u64,
                        Err(e @ StoreError::Io { .. }) => {
                            tracing::error!("rebuilding: {e}; trying again in a second");
                            std::thread::sleep(Duration::from_secs(1));
                        }
                        Err(e) => tracing::error!("rebuilding: {e}"),
                    }
                    let saved = store.take_saved();
                    if !saved.is_empty() {
                        served.update(&store, Some(saved));
                    }
                }
                if outside_of.0 != store.patches() {
                    outside_of = (store.patches(), outside(&store));
                }
                served.set_growth(&store, rebuilt, outside_of.1);
            }
        })
        .map_err(|e| format!("could not start the grower thread: {e}"))?;
    Ok((source, handle, join))
}
