//! The reader side: attach to a texel mapping read-only (checking magic, version and every size
//! before trusting anything), take consistent snapshots of the published state (checked before
//! any address arithmetic), read texels from ready slots under their tags, request a centre
//! through the request mapping, and notice a stale or replaced service.

mod attach;
mod decoded;

use super::layout::{
    self, desc, header, request, snapshot, state, tag, views as v, LevelShape, SlotState, MAX_RETRIES,
};
use super::raw::Region;
use super::{check_name, map_path, request_path, ShmError};
use clipmap_base::geom::Rect;
use std::fs::OpenOptions;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{fence, Ordering};
use std::time::Duration;

/// This thread's seqlocked reads so far, for the tests of "Reading consistently" (docs/SHM.md):
/// attempts at the snapshot or the growth block and the yields between them, attempts at a tag
/// and the pause hints between them. Only in this crate's tests and with the `test-hooks` feature
/// (the `clipmap` crate's tests drive the engine against this layer).
#[cfg(any(test, feature = "test-hooks"))]
#[doc(hidden)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tally {
    /// Attempts at the snapshot or the growth block.
    pub locked_attempts: u64,
    /// `std::thread::yield_now()` calls between those attempts.
    pub yields: u64,
    /// Attempts at a slot's tag.
    pub tag_attempts: u64,
    /// Pause hints (`std::hint::spin_loop()`) between those attempts.
    pub spins: u64,
}

#[cfg(any(test, feature = "test-hooks"))]
thread_local! {
    #[doc(hidden)]
    pub static TALLY: std::cell::Cell<Tally> = std::cell::Cell::new(Tally::default());
}

/// Counts one event of `Tally` on this thread (tests only; nothing in other builds).
macro_rules! tally {
    ($field:ident) => {
        #[cfg(any(test, feature = "test-hooks"))]
        TALLY.with(|t| {
            let mut n = t.get();
            n.$field += 1;
            t.set(n);
        });
    };
}

/// One level's static description.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelDesc {
    /// Level size.
    pub size: [u64; 2],
    /// Tile size.
    pub tile: [u64; 2],
    /// Slots per axis.
    pub grid: [u64; 2],
    /// Bytes of one slot.
    pub slot_bytes: u64,
    /// Byte offset of the tags.
    pub tags: u64,
    /// Byte offset of the slots.
    pub slots: u64,
    /// True for pyramid levels (resident whole).
    pub pyramid: bool,
    /// Byte offset of the tile ranges (0: none; a height texture's levels have them).
    pub ranges: u64,
}

impl LevelDesc {
    fn shape(&self) -> LevelShape {
        LevelShape { size: self.size, tile: self.tile, grid: self.grid }
    }
}

/// One level's published state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LevelState {
    /// Centre.
    pub centre: [i64; 2],
    /// Valid region `[s0, s1) x [t0, t1)` (all 0 when disabled).
    pub valid: [i64; 4],
    /// Renderers may use the level.
    pub enabled: bool,
    /// Tick of the last change.
    pub updated_tick: u64,
}

impl LevelState {
    /// Whether (s, t) is inside the valid region of an enabled level.
    pub fn contains(&self, s: i64, t: i64) -> bool {
        self.enabled && s >= self.valid[0] && s < self.valid[2] && t >= self.valid[1] && t < self.valid[3]
    }

    /// The valid region as a rectangle (empty when disabled).
    pub fn rect(&self) -> Rect {
        if self.enabled {
            Rect::new(self.valid[0], self.valid[1], self.valid[2], self.valid[3])
        } else {
            Rect::EMPTY
        }
    }
}

/// A consistent copy of the whole published state (one seqlock: every level and min LOD from the
/// same tick).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Snapshot {
    /// Sequence number it was read at (even).
    pub seq: u64,
    /// Finest level renderers may use.
    pub min_lod: f64,
    /// Tick of the snapshot (0 before the first).
    pub tick: u64,
    /// Invalid border in use.
    pub invalid_border: u64,
    /// Level-0 centre of that tick.
    pub centre: [i64; 2],
    /// Per level.
    pub levels: Vec<LevelState>,
}

/// Why a read failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReadError {
    /// The level does not exist.
    #[error("level {0} does not exist")]
    NoLevel(usize),
    /// The region is not inside the level's valid region in the snapshot.
    #[error("the region is not inside level {0}'s published valid region")]
    NotValid(usize),
    /// A tile under the region could not be read by the service: use a coarser level there.
    #[error("level {level} tile ({s}, {t}) is missing: use a coarser level for its texels")]
    Missing {
        /// Level.
        level: usize,
        /// Tile column.
        s: i64,
        /// Tile row.
        t: i64,
    },
    /// A slot no longer holds what the snapshot says: take a new snapshot.
    #[error("level {0} moved on since the snapshot: take a new one")]
    Stale(usize),
    /// The writer kept changing what was read; try again next frame or use a coarser level.
    #[error("level {0} kept changing while it was read")]
    Busy(usize),
    /// The published state is outside its bounds: the mapping is corrupt or hostile.
    #[error("corrupt mapping: {0}")]
    Corrupt(String),
    /// The view the client is bound to was removed from the service (its record freed or given
    /// to another view): bind to a view again ([`Client::bind_view`]).
    #[error("view `{0}` was removed from the service: bind to a view that exists (Client::view_names)")]
    ViewRemoved(String),
}

/// A reader attached to one mapping.
pub struct Client {
    pub(super) region: Region,
    pub(super) request: Option<Region>,
    path: PathBuf,
    inode: (u64, u64),
    /// The mapping file's owner: a view's own mapping must have the same.
    pub(super) uid: u32,
    /// Bytes per texel; for a block-compressed format the bytes of one 4 x 4 block.
    pub bytes_per_texel: usize,
    /// Texels a side of a slot's unit of storage: 1, or 4 for a block-compressed format (its
    /// tiles are read whole, [`read_tile`](Self::read_tile), or decoded,
    /// [`decode_tile`](Self::decode_tile)).
    pub block: u64,
    /// Clip size.
    pub clip_size: u64,
    /// Texel format code.
    pub format_code: u32,
    /// Per level.
    pub levels: Vec<LevelDesc>,
    /// The writer's generation at attach time.
    pub generation: u64,
    /// The service's tick period (0 when the writer did not say).
    pub tick_period: Duration,
    /// Whether the texels are heights, and their scale, offset, nodata value and level rule (the
    /// header's heights block, checked at attach); `None` for a texture that is not heights.
    pub heights: Option<layout::Heights>,
    /// Where the texture lies on the Earth (the header's georef block and each level's affine
    /// terms, checked at attach); `None` for a texture without georeferencing, or a mapping of a
    /// writer from before the block.
    pub georef: Option<crate::GeorefBlock>,
    /// The views block, as checked at attach.
    pub(super) views: super::view_block::ViewsBlock,
    /// The view the snapshot is read from (`None`: the primary, `main`).
    pub(super) view: Option<super::view_block::Binding>,
    /// The view whose own mapping this is (docs/SHM.md, "A view with grids of its own"): the
    /// client reads its `main` and answers to the view's name.
    pub(super) own_view: Option<String>,
}

impl std::fmt::Debug for Client {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Client").field("path", &self.path).field("levels", &self.levels.len()).finish()
    }
}

/// Opens `path` (read-only, or read-write) without blocking and checks on the open descriptor
/// that it is a regular file: a FIFO planted at a mapping's name would otherwise block the open
/// until someone writes to it, and a device would be mapped.
///
/// With `owner` (a name the reader derived itself, a view's own mapping: docs/SHM.md, "Where"),
/// the name is also not followed when it is a symbolic link, and the file must be owned by that
/// user (the owner of the service's mapping): anyone may plant a name in the shared directory.
fn open_regular(path: &Path, write: bool, owner: Option<u32>) -> Result<std::fs::File, ShmError> {
    use rustix::fs::OFlags;
    use std::os::unix::fs::OpenOptionsExt;
    let flags = if owner.is_some() { OFlags::NONBLOCK | OFlags::NOFOLLOW } else { OFlags::NONBLOCK };
    let file =
        OpenOptions::new().read(true).write(write).custom_flags(flags.bits() as i32).open(path).map_err(|e| match e
            .raw_os_error()
        {
            Some(c) if owner.is_some() && c == rustix::io::Errno::LOOP.raw_os_error() => invalid(
                path,
                "a symbolic link: expected the mapping itself (a name the service publishes is never a link, and \
                 readers do not follow one); remove it",
            ),
            _ => ShmError::Io { path: path.to_path_buf(), source: e },
        })?;
    let meta = file.metadata().map_err(super::io(path))?;
    if !meta.is_file() {
        return Err(invalid(
            path,
            format!(
                "it is {}, not a regular file: not a mapping (something else took the name)",
                clipmap_base::open::kind_of(&meta)
            ),
        ));
    }
    if let Some(want) = owner.filter(|&w| w != meta.uid()) {
        return Err(invalid(
            path,
            format!(
                "owned by {}, expected {}, the owner of the service's mapping: not a file the service published (remove it, or ask its owner)",
                super::names::owner(meta.uid()),
                super::names::owner(want)
            ),
        ));
    }
    Ok(file)
}

/// Whether `pid` names a live process (0 never does).
pub(super) fn process_alive(pid: u32) -> bool {
    pid != 0 && Path::new(&format!("/proc/{pid}")).exists()
}

pub(super) fn invalid(path: &Path, reason: impl Into<String>) -> ShmError {
    ShmError::Invalid { path: path.to_path_buf(), reason: reason.into() }
}

/// The raw mappings, for the tests of the `clipmap` crate (the `test-hooks` feature).
#[cfg(feature = "test-hooks")]
#[doc(hidden)]
impl Client {
    /// The texel mapping.
    pub fn raw_region(&self) -> &Region {
        &self.region
    }

    /// The request mapping, when the client could open it.
    pub fn raw_request(&self) -> Option<&Region> {
        self.request.as_ref()
    }
}

impl Client {
    /// The mapping file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The map coordinates of the continuous texel position (s, t) of `level` ([`crate::GeorefBlock::map_of_texel`]
    /// with this mapping's level-0 height); `None` without georeferencing or for a level past the
    /// level count.
    pub fn map_of_texel(&self, level: usize, s: f64, t: f64) -> Option<[f64; 2]> {
        self.georef.as_ref()?.map_of_texel(level, self.levels.first()?.size[1], s, t)
    }

    /// True when requests can be made through the request mapping.
    pub fn can_request(&self) -> bool {
        self.request.is_some()
    }

    /// A consistent, checked copy of the whole published state; `Busy` when the writer kept it
    /// locked for [`MAX_RETRIES`] attempts, `Corrupt` when what is published is outside its
    /// bounds.
    pub fn try_snapshot(&self) -> Result<Snapshot, ReadError> {
        let r = &self.region;
        let b = self.snapshot_base();
        let read = || {
            let g = |o: usize| r.load(b + o, Ordering::Relaxed);
            let mut snap = Snapshot {
                seq: 0,
                min_lod: f64::from_bits(g(snapshot::MIN_LOD)),
                tick: g(snapshot::TICK),
                invalid_border: g(snapshot::INVALID_BORDER),
                centre: [g(snapshot::CENTRE_S) as i64, g(snapshot::CENTRE_T) as i64],
                levels: Vec::with_capacity(self.levels.len()),
            };
            let mut enabled_codes = Vec::with_capacity(self.levels.len());
            for k in 0..self.levels.len() {
                let o = snapshot::LEVELS + k * layout::STATE_BYTES;
                let e = g(o + state::ENABLED);
                enabled_codes.push(e);
                snap.levels.push(LevelState {
                    centre: [g(o + state::CENTRE_S) as i64, g(o + state::CENTRE_T) as i64],
                    valid: [
                        g(o + state::VALID_S0) as i64,
                        g(o + state::VALID_T0) as i64,
                        g(o + state::VALID_S1) as i64,
                        g(o + state::VALID_T1) as i64,
                    ],
                    enabled: e == 1,
                    updated_tick: g(o + state::UPDATED_TICK),
                });
            }
            (snap, enabled_codes)
        };
        let (seq, (mut snap, enabled_codes)) = self.seqlocked(b + snapshot::SEQ, read).ok_or(ReadError::Busy(0))?;
        snap.seq = seq;
        // A view's snapshot counts only while the view is still the one bound (read after it).
        self.check_bound()?;
        self.check_snapshot(&snap, &enabled_codes)?;
        Ok(snap)
    }

    /// Runs `read` under the seqlock whose counter is at `seq`: between an even counter and the
    /// same counter again after an acquire fence. `None` after [`MAX_RETRIES`] attempts (the
    /// writer kept it locked); else the counter it read at and what `read` returned.
    ///
    /// Between two attempts that found the counter odd it gives the processor away
    /// (`yield_now`): the writer may have been descheduled while it holds the lock.
    pub(super) fn seqlocked<T>(&self, seq: usize, mut read: impl FnMut() -> T) -> Option<(u64, T)> {
        let r = &self.region;
        for _ in 0..MAX_RETRIES {
            tally!(locked_attempts);
            let s1 = r.load(seq, Ordering::Acquire);
            if s1 & 1 == 1 {
                tally!(yields);
                std::thread::yield_now();
                continue;
            }
            let v = read();
            fence(Ordering::Acquire);
            if r.load(seq, Ordering::Relaxed) == s1 {
                return Some((s1, v));
            }
        }
        None
    }

    fn check_snapshot(&self, snap: &Snapshot, enabled: &[u64]) -> Result<(), ReadError> {
        let n = self.levels.len() as f64;
        if !snap.min_lod.is_finite() || snap.min_lod < 0.0 || snap.min_lod > n {
            return Err(ReadError::Corrupt(format!("min LOD {} outside 0..={n}", snap.min_lod)));
        }
        for (k, (l, &e)) in snap.levels.iter().zip(enabled).enumerate() {
            if e > 1 {
                return Err(ReadError::Corrupt(format!("level {k}: enabled is {e}, expected 0 or 1")));
            }
            if l.enabled {
                layout::check_region_wrapping(&self.levels[k].shape(), l.valid, self.wraps())
                    .map_err(|why| ReadError::Corrupt(format!("level {k}: {why}")))?;
            }
        }
        Ok(())
    }

    /// A consistent snapshot whose published state passes every check, for the tools that show
    /// or draw it (`cliptex attach`, `cliptex dump --attach`): a writer that is busy is tried
    /// again for up to a second, and published state outside its bounds (a NaN min LOD, a region
    /// outside its level) refuses the mapping, as the C and Python readers refuse it, instead of
    /// being shown as "every level disabled".
    pub fn checked_snapshot(&self) -> Result<Snapshot, ShmError> {
        let start = std::time::Instant::now();
        loop {
            match self.try_snapshot() {
                Ok(s) => return Ok(s),
                Err(ReadError::Corrupt(why)) => {
                    return Err(invalid(&self.path, format!("published state outside its bounds: {why}; the mapping is corrupt or was written by something other than clipmapd")))
                }
                Err(_) if start.elapsed() < Duration::from_secs(1) => std::thread::sleep(Duration::from_millis(1)),
                Err(_) => return Err(ShmError::Busy { path: self.path.clone(), ms: start.elapsed().as_millis() as u64 }),
            }
        }
    }

    /// [`try_snapshot`](Self::try_snapshot), or an empty snapshot (nothing usable: min LOD the
    /// level count) when the writer is busy or the state is corrupt.
    pub fn snapshot(&self) -> Snapshot {
        self.try_snapshot().unwrap_or_else(|_| Snapshot {
            min_lod: self.levels.len() as f64,
            levels: vec![LevelState::default(); self.levels.len()],
            ..Snapshot::default()
        })
    }

    /// A growing texture's growth block (docs/SHM.md, "Growth block"), read consistently and
    /// checked: `Ok(None)` for a texture that does not grow, `Busy` when the writer kept it locked
    /// for [`MAX_RETRIES`] attempts, `Corrupt` when its values are impossible. Readers follow
    /// growth without reattaching: the frame, and so every address, never changes.
    pub fn growth(&self) -> Result<Option<layout::Growth>, ReadError> {
        use layout::growth as g;
        let r = &self.region;
        let b = header::GROWTH;
        let read = || {
            let v = |o: usize| r.load(b + o, Ordering::Relaxed);
            let out = layout::Growth {
                extent: [
                    v(g::EXTENT_S0) as i64,
                    v(g::EXTENT_T0) as i64,
                    v(g::EXTENT_S1) as i64,
                    v(g::EXTENT_T1) as i64,
                ],
                data_levels: v(g::DATA_LEVELS),
                patches: v(g::PATCHES),
                tiles_rebuilt: v(g::TILES_REBUILT),
                tiles_pending: v(g::TILES_PENDING),
                tiles_replaced: v(g::TILES_REPLACED),
                world_origin: [f64::from_bits(v(g::WORLD_S0)), f64::from_bits(v(g::WORLD_T0))],
                texels_per_unit: f64::from_bits(v(g::TEXELS_PER_UNIT)),
                outside_frame: v(g::OUTSIDE_FRAME),
            };
            (v(g::GROWING), out)
        };
        let (_, (growing, out)) = self.seqlocked(b + g::SEQ, read).ok_or(ReadError::Busy(0))?;
        match growing {
            0 => Ok(None),
            1 => self.check_growth(&out).map(|()| Some(out)),
            other => Err(ReadError::Corrupt(format!("growth block: growing is {other}, expected 0 or 1"))),
        }
    }

    fn check_growth(&self, g: &layout::Growth) -> Result<(), ReadError> {
        let [w, h] = self.levels[0].size;
        let [s0, t0, s1, t1] = g.extent;
        let inside = 0 <= s0 && s0 < s1 && s1 as u64 <= w && 0 <= t0 && t0 < t1 && t1 as u64 <= h;
        if !(g.extent == [0; 4] || inside) {
            return Err(ReadError::Corrupt(format!(
                "growth block: extent {:?} is not empty and not inside the {w}x{h} frame",
                g.extent
            )));
        }
        if !(g.world_origin.iter().all(|v| v.is_finite()) && g.texels_per_unit.is_finite() && g.texels_per_unit > 0.0) {
            return Err(ReadError::Corrupt(format!(
                "growth block: world origin {:?} and {} texels per unit are not finite and positive",
                g.world_origin, g.texels_per_unit
            )));
        }
        if g.data_levels > 64 {
            return Err(ReadError::Corrupt(format!(
                "growth block: {} data levels, expected at most 64",
                g.data_levels
            )));
        }
        Ok(())
    }

    /// One level's state from a fresh snapshot.
    pub fn level_state(&self, level: usize) -> Option<LevelState> {
        self.try_snapshot().ok()?.levels.get(level).copied()
    }

    /// One attempt at reading a slot's tag consistently: (sequence, tile, state), or `None` when
    /// the writer holds the tag (odd) or changed it while it was read.
    fn tag_once(&self, d: &LevelDesc, slot: u64) -> Option<(u64, [i64; 2], Option<SlotState>)> {
        let b = (d.tags + slot * layout::TAG_BYTES as u64) as usize;
        let r = &self.region;
        let s1 = r.load(b + tag::SEQ, Ordering::Acquire);
        if s1 & 1 == 1 {
            return None;
        }
        let tile =
            [r.load(b + tag::TILE_S, Ordering::Relaxed) as i64, r.load(b + tag::TILE_T, Ordering::Relaxed) as i64];
        let st = SlotState::from_code(r.load(b + tag::STATE, Ordering::Relaxed));
        fence(Ordering::Acquire);
        (r.load(b + tag::SEQ, Ordering::Relaxed) == s1).then_some((s1, tile, st))
    }

    /// Whether the slot of tile `tile` (S, T) of `level` holds that tile ready (or as the default
    /// tile) now, by its tag alone (no texel is copied): a hint that may be stale the moment it
    /// is given (the writer may reassign the slot), for deciding what to ask of a source;
    /// [`read_tile`](Self::read_tile) decides what is read. False for a level or tile outside
    /// the mapping, and when the writer kept the tag locked through [`MAX_RETRIES`] attempts.
    pub fn holds_tile(&self, level: usize, tile: [i64; 2]) -> bool {
        let Some(d) = self.levels.get(level).copied() else { return false };
        let across = [d.size[0].div_ceil(d.tile[0]) as i64, d.size[1].div_ceil(d.tile[1]) as i64];
        if tile[0] < 0 || tile[1] < 0 || tile[0] >= across[0] || tile[1] >= across[1] {
            return false;
        }
        let slot = layout::slot_index(d.grid, tile);
        for _ in 0..MAX_RETRIES {
            if let Some((_, held, state)) = self.tag_once(&d, slot) {
                return held == tile && state.is_some_and(SlotState::readable);
            }
            std::hint::spin_loop();
        }
        false
    }

    /// The range of heights of tile `tile` (S, T) of `level` as the service published it beside
    /// the slot's tag (docs/SHM.md, "Tile ranges"), read under the tag like texels: `Ok(None)` when
    /// the texels are not heights (or the mapping has no ranges), or the slot does not hold the
    /// tile ready or default (loading, missing, another tile: use a coarser level's range);
    /// `Busy` when the writer kept the tag locked through [`MAX_RETRIES`] attempts. The range is
    /// in metres, nodata excluded ([`TileRange::Empty`](clipmap_base::height::TileRange::Empty) when
    /// every texel of the tile is nodata; -inf..inf for a tile holding a texel that is not a
    /// finite height).
    pub fn tile_range(
        &self,
        level: usize,
        tile: [i64; 2],
    ) -> Result<Option<clipmap_base::height::TileRange>, ReadError> {
        let d = *self.levels.get(level).ok_or(ReadError::NoLevel(level))?;
        if d.ranges == 0 || self.heights.is_none() {
            return Ok(None);
        }
        let slot = layout::slot_index(d.grid, tile);
        let b = (d.tags + slot * layout::TAG_BYTES as u64) as usize;
        let e = (d.ranges + slot * layout::RANGE_BYTES as u64) as usize;
        for _ in 0..MAX_RETRIES {
            tally!(tag_attempts);
            let Some((seq, held, state)) = self.tag_once(&d, slot) else {
                tally!(spins);
                std::hint::spin_loop();
                continue;
            };
            if held != tile || !state.is_some_and(SlotState::readable) {
                return Ok(None);
            }
            let min = f64::from_bits(self.region.load(e + layout::range::MIN, Ordering::Relaxed));
            let max = f64::from_bits(self.region.load(e + layout::range::MAX, Ordering::Relaxed));
            fence(Ordering::Acquire);
            if self.region.load(b + tag::SEQ, Ordering::Relaxed) == seq {
                return Ok(Some(if min.is_nan() || max.is_nan() {
                    clipmap_base::height::TileRange::Empty
                } else {
                    clipmap_base::height::TileRange::Heights { min, max }
                }));
            }
        }
        Err(ReadError::Busy(level))
    }

    /// The published range of every tile `level`'s slots hold ready or default, in slot order
    /// (each read under its tag with [`tile_range`](Self::tile_range); a slot whose tag is
    /// locked, loading or changing meanwhile is left out). Empty when the texels are not heights.
    pub fn tile_ranges(&self, level: usize) -> Vec<([i64; 2], clipmap_base::height::TileRange)> {
        let Some(d) = self.levels.get(level).copied() else { return Vec::new() };
        if d.ranges == 0 || self.heights.is_none() {
            return Vec::new();
        }
        (0..d.grid[0] * d.grid[1])
            .filter_map(|slot| {
                let (_, tile, _) = self.tag_once(&d, slot)?;
                let r = self.tile_range(level, tile).ok()??;
                Some((tile, r))
            })
            .collect()
    }

    /// Copies the texels of `rect` of `level` (rows in increasing t, s fastest, row pitch
    /// `rect.width()` texels) into `out`, tile by tile, each copy checked against its slot's tag.
    /// The region must lie inside the level's valid region in `snap`.
    pub fn read_region_in(&self, snap: &Snapshot, level: usize, rect: Rect, out: &mut [u8]) -> Result<(), ReadError> {
        let d = *self.levels.get(level).ok_or(ReadError::NoLevel(level))?;
        let st = snap.levels.get(level).ok_or(ReadError::NoLevel(level))?;
        let bpt = self.bytes_per_texel;
        if self.block > 1 {
            return Err(ReadError::Corrupt(format!(
                "texel format code {} is block-compressed: read whole tiles (read_tile) or decode a region (decode_tile)",
                self.format_code
            )));
        }
        let (w, h) = (rect.width(), rect.height());
        if out.len() as u64 != w * h * bpt as u64 {
            return Err(ReadError::Corrupt(format!("buffer of {} bytes for a {w}x{h} region", out.len())));
        }
        if w == 0 || h == 0 {
            return Ok(());
        }
        let Some(period) = self.texel_period(level) else {
            if !st.rect().contains_rect(&rect) {
                return Err(ReadError::NotValid(level));
            }
            return self.copy_rect(&d, level, rect, rect, out);
        };
        // A wrapping texture (docs/SHM.md, "How a region wraps"): texel s is texel s mod width.
        // The rectangle must lie in the region taken modulo the width; it is read in pieces that
        // do not cross a multiple of the width, each where the level itself has it.
        let region = st.rect();
        let w = period as i64;
        let inside = |r: Rect| {
            let at = region.s0 + clipmap_base::geom::wrap(r.s0 - region.s0, period) as i64;
            r.width() <= period && at + r.width() as i64 <= region.s1 && r.t0 >= region.t0 && r.t1 <= region.t1
        };
        if region.is_empty() || !inside(rect) {
            return Err(ReadError::NotValid(level));
        }
        let mut s = rect.s0;
        while s < rect.s1 {
            let lap = s.div_euclid(w);
            let end = rect.s1.min((lap + 1) * w);
            let shift = -lap * w;
            let piece = Rect::new(s + shift, rect.t0, end + shift, rect.t1);
            let whole = Rect::new(rect.s0 + shift, rect.t0, rect.s1 + shift, rect.t1);
            self.copy_rect(&d, level, piece, whole, out)?;
            s = end;
        }
        Ok(())
    }

    /// Whether the texture wraps in longitude (the georef block's flag bit 0): texel s of every
    /// level is texel `s mod width`, and a level's region may run past its width
    /// ([`layout::region_may_wrap`]).
    pub fn wraps(&self) -> bool {
        self.georef.as_ref().is_some_and(|g| g.wraps)
    }

    /// `Some(width)` of `level` when the texture wraps ([`wraps`](Self::wraps)), else `None`.
    pub fn texel_period(&self, level: usize) -> Option<u64> {
        self.levels.get(level).filter(|_| self.wraps()).map(|d| d.size[0])
    }

    /// Copies `part` (inside the level) of `rect` tile by tile into `out`, laid out as `rect`.
    fn copy_rect(&self, d: &LevelDesc, level: usize, part: Rect, rect: Rect, out: &mut [u8]) -> Result<(), ReadError> {
        let tiles = clipmap_base::geom::tiles_covering(part, d.tile);
        let (tw, th) = (d.tile[0] as i64, d.tile[1] as i64);
        for ts in tiles.s0..tiles.s1 {
            for tt in tiles.t0..tiles.t1 {
                let part = part.intersect(&Rect::new(ts * tw, tt * th, (ts + 1) * tw, (tt + 1) * th));
                let slot = layout::slot_index(d.grid, [ts, tt]);
                self.copy_from_slot(d, level, slot, [ts, tt], part, rect, out)?;
            }
        }
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    #[allow(unsafe_code)] // the seqlocked copy of a tile's texels (SAFETY below)
    fn copy_from_slot(
        &self,
        d: &LevelDesc,
        level: usize,
        slot: u64,
        tile: [i64; 2],
        part: Rect,
        rect: Rect,
        out: &mut [u8],
    ) -> Result<SlotState, ReadError> {
        let bpt = self.bytes_per_texel;
        let (tw, th) = (d.tile[0] as i64, d.tile[1] as i64);
        let b = (d.tags + slot * layout::TAG_BYTES as u64) as usize;
        let base = d.slots + slot * d.slot_bytes;
        // One budget of [`MAX_RETRIES`] attempts per tile, whether the tag was held or the copy
        // raced a reload; a tag held by the writer (stored in nanoseconds) costs a pause hint.
        for _ in 0..MAX_RETRIES {
            tally!(tag_attempts);
            let Some((seq, held, state)) = self.tag_once(d, slot) else {
                tally!(spins);
                std::hint::spin_loop();
                continue;
            };
            if held != tile {
                return Err(ReadError::Stale(level));
            }
            let state = match state {
                Some(s) if s.readable() => s,
                Some(SlotState::Missing) => return Err(ReadError::Missing { level, s: tile[0], t: tile[1] }),
                // Loading (for a growing texture, the tile rebuilt in place), empty or unknown:
                // never waited for; the caller takes a new snapshot or uses a coarser level.
                _ => return Err(ReadError::Stale(level)),
            };
            if self.block > 1 {
                // A block format: whole tiles only (`read_tile_state`), the slot copied as it is.
                // SAFETY: as for the rows below: a copy that overlapped a write sees `seq` move
                // and is discarded; `out` is a private buffer of the slot's length.
                unsafe { self.region.read(base as usize, &mut out[..d.slot_bytes as usize]) };
            }
            let run = part.width() as usize * bpt;
            for t in (part.t0..part.t1).filter(|_| self.block == 1) {
                let src = base + (((t - tile[1] * th) * tw + (part.s0 - tile[0] * tw)) as u64) * bpt as u64;
                let dst = (((t - rect.t0) as u64 * rect.width() + (part.s0 - rect.s0) as u64) as usize) * bpt;
                // SAFETY: the tag said this tile, readable, under sequence `seq`; the writer (the
                // service's thread or process) writes a slot's bytes only after moving its tag to
                // loading, so a copy that overlapped a write sees `seq` moved below and is
                // discarded, never returned. The copy itself goes through raw pointers into `out`,
                // a private buffer (`Region::read`'s contract).
                unsafe { self.region.read(src as usize, &mut out[dst..dst + run]) };
            }
            fence(Ordering::Acquire);
            if self.region.load(b + tag::SEQ, Ordering::Relaxed) == seq {
                return Ok(state);
            }
        }
        Err(ReadError::Busy(level))
    }

    /// Copies the whole tile `tile` (S, T) of `level` into `out` (TW x TH texels in the slot's
    /// own order, row pitch TW) under its slot's tag, whether or not the tile lies inside a
    /// published valid region: for renderers that mirror the image cache slot for slot (the GPU
    /// client, `clipgpu`). `Stale` when the slot holds another tile or is not ready, `Missing`
    /// when the service could not read the tile, `NotValid` for a tile outside the level.
    pub fn read_tile(&self, level: usize, tile: [i64; 2], out: &mut [u8]) -> Result<(), ReadError> {
        self.read_tile_state(level, tile, out).map(|_| ())
    }

    /// [`read_tile`](Self::read_tile), saying what the slot held: the tile's own texels
    /// ([`SlotState::Ready`]) or the configuration's default tile in its place
    /// ([`SlotState::Default`]).
    pub fn read_tile_state(&self, level: usize, tile: [i64; 2], out: &mut [u8]) -> Result<SlotState, ReadError> {
        let d = *self.levels.get(level).ok_or(ReadError::NoLevel(level))?;
        if out.len() as u64 != d.slot_bytes {
            return Err(ReadError::Corrupt(format!("buffer of {} bytes for a {}-byte tile", out.len(), d.slot_bytes)));
        }
        let across = [d.size[0].div_ceil(d.tile[0]) as i64, d.size[1].div_ceil(d.tile[1]) as i64];
        if tile[0] < 0 || tile[1] < 0 || tile[0] >= across[0] || tile[1] >= across[1] {
            return Err(ReadError::NotValid(level));
        }
        let (tw, th) = (d.tile[0] as i64, d.tile[1] as i64);
        let rect = Rect::new(tile[0] * tw, tile[1] * th, (tile[0] + 1) * tw, (tile[1] + 1) * th);
        self.copy_from_slot(&d, level, layout::slot_index(d.grid, tile), tile, rect, rect, out)
    }

    /// Decodes tile `tile` (S, T) of `level` of a block-compressed mapping with an independent
    /// decoder ([`crate::blocks::decode`]): the tile's width x height texels, RGBA8 for `bc1` and
    /// `bc7`, one byte for `bc4`, two for `bc5`, rows in increasing t. Errors as
    /// [`read_tile`](Self::read_tile); `Corrupt` when the mapping's format is not a block format.
    pub fn decode_tile(&self, level: usize, tile: [i64; 2]) -> Result<Vec<u8>, ReadError> {
        let bc = layout::format_from_code(self.format_code).and_then(|f| f.block()).ok_or_else(|| {
            ReadError::Corrupt(format!("texel format code {} is not block-compressed", self.format_code))
        })?;
        let d = *self.levels.get(level).ok_or(ReadError::NoLevel(level))?;
        let mut blocks = vec![0u8; d.slot_bytes as usize];
        self.read_tile(level, tile, &mut blocks)?;
        crate::blocks::decode(bc, &blocks, d.tile[0], d.tile[1]).map_err(ReadError::Corrupt)
    }

    /// Copies the `w` x `h` texels of `level` whose first is (s0, t0) into `out` from a fresh
    /// snapshot (taking one more if the first is stale), returning the snapshot used.
    pub fn read_region(
        &self,
        level: usize,
        s0: i64,
        t0: i64,
        w: u64,
        h: u64,
        out: &mut [u8],
    ) -> Result<Snapshot, ReadError> {
        let far = 1i64 << 40;
        if !(-far..far).contains(&s0) || !(-far..far).contains(&t0) || w > 1 << 30 || h > 1 << 30 {
            return Err(ReadError::NotValid(level));
        }
        let rect = Rect::new(s0, t0, s0 + w as i64, t0 + h as i64);
        let mut last = ReadError::Busy(level);
        for _ in 0..4 {
            // A snapshot the writer kept locked makes this level busy for now (a coarser one, or
            // the next frame).
            let snap =
                self.try_snapshot().map_err(|e| if let ReadError::Busy(_) = e { ReadError::Busy(level) } else { e })?;
            match self.read_region_in(&snap, level, rect, out) {
                Ok(()) => return Ok(snap),
                Err(ReadError::Stale(_)) => last = ReadError::Stale(level),
                Err(e) => return Err(e),
            }
        }
        Err(last)
    }

    /// The bytes of texel (s, t) of `level` from a fresh snapshot.
    pub fn texel(&self, level: usize, s: i64, t: i64) -> Result<Vec<u8>, ReadError> {
        let mut out = vec![0u8; self.bytes_per_texel];
        self.read_region(level, s, t, 1, 1, &mut out)?;
        Ok(out)
    }

    /// Asks the service to centre the clipmap at `centre` (level-0 texels), with an optional
    /// velocity (level-0 texels per second). `false` when this client cannot write requests
    /// (the request mapping is missing or not writable: use the control socket's `CENTRE`), or
    /// when another renderer that is still alive held the request lock for
    /// [`request_lock::WAIT_MS`](layout::request_lock::WAIT_MS) (try again next frame).
    pub fn request_centre(&self, centre: [i64; 2], velocity: [f64; 2]) -> bool {
        self.request_position(RequestPosition::Texels(centre), velocity)
    }

    /// [`request_centre`](Self::request_centre) with the centre in any coordinate kind
    /// (docs/SHM.md, "Positions in longitude / latitude or map coordinates"): level-0 texels,
    /// WGS 84 longitude / latitude, or map coordinates of the texture's CRS. The service converts
    /// a position through the texture's georeferencing (the georef block's, [`Client::georef`]);
    /// it refuses (counts in `STATS` `position_requests_refused`, logs why) a texture without one
    /// or a position outside the texture or the projection's domain, and the view stays where it
    /// was. The velocity is in level-0 texels per second whatever the kind. A position request
    /// leaves the texel centre fields as they were: a service older than the position records
    /// takes it as the previous texel centre.
    pub fn request_position(&self, position: RequestPosition, velocity: [f64; 2]) -> bool {
        match &self.view {
            Some(b) => self.request_view_centre(b, position, velocity),
            // The main request's fields lie as a view request record's, from its lock word on.
            None => self.request_at(request::SEQ, None, Fields::Centre(position, v::position(0), velocity)),
        }
    }

    /// Ticks counted by the heartbeat.
    pub fn heartbeat(&self) -> u64 {
        self.region.load(header::HEARTBEAT, Ordering::Acquire)
    }

    /// Time since the writer's last heartbeat (by the wall clock).
    pub fn heartbeat_age(&self) -> Duration {
        let ms = self.region.load(header::HEARTBEAT_MS, Ordering::Acquire);
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_millis() as u64)
            .unwrap_or(0);
        Duration::from_millis(now.saturating_sub(ms))
    }

    /// True when the writer shut down cleanly.
    pub fn closed(&self) -> bool {
        self.region.load(header::FLAGS, Ordering::Acquire) & 1 == 1
    }

    /// True when the name now points at another mapping (the service restarted): reattach.
    pub fn replaced(&self) -> bool {
        match std::fs::metadata(&self.path) {
            Ok(m) => (m.dev(), m.ino()) != self.inode,
            Err(_) => true,
        }
    }
}

impl Client {
    /// One request under the lock word at `base` of the request mapping (docs/SHM.md, "Request
    /// mapping"), its fields at the offsets of a view request record (the main request's lie
    /// the same way from its lock word at 64): take the word odd with our pid, store, release to
    /// the next epoch. A word left odd by a renderer that died (its pid is no live process) is
    /// advanced after a while; a live owner is waited for, never overruled. `incarnation` is
    /// stored for a view's request.
    pub(super) fn request_at(&self, base: usize, incarnation: Option<u64>, fields: Fields) -> bool {
        use layout::request_lock as lock;
        let Some(r) = &self.request else { return false };
        let pid = std::process::id();
        let start = std::time::Instant::now();
        let mut odd_since: Option<(u64, std::time::Instant)> = None;
        loop {
            let w = r.load(base + v::REQ_SEQ, Ordering::Relaxed);
            let mine = if w & 1 == 1 {
                match odd_since {
                    Some((seen, at)) if seen == w && at.elapsed() > Duration::from_millis(lock::TAKEOVER_MS) => {
                        // Straight from the dead renderer's odd word to our own at the next epoch:
                        // the word is never even over its partial fields, so the service never
                        // takes them (docs/SHM.md, "The lock word").
                        let mine = lock::locked(lock::released(w), pid);
                        if !process_alive(lock::owner(w)) && r.compare_exchange(base + v::REQ_SEQ, w, mine).is_ok() {
                            note_lock_word(mine);
                            Some(mine)
                        } else {
                            odd_since = Some((w, std::time::Instant::now()));
                            None
                        }
                    }
                    Some((seen, _)) if seen == w => None,
                    _ => {
                        odd_since = Some((w, std::time::Instant::now()));
                        None
                    }
                }
            } else {
                let mine = lock::locked(w, pid);
                let taken = r.compare_exchange(base + v::REQ_SEQ, w, mine).is_ok();
                if taken {
                    note_lock_word(mine);
                } else {
                    std::hint::spin_loop();
                }
                taken.then_some(mine)
            };
            let Some(mine) = mine else {
                if w & 1 == 1 {
                    if start.elapsed() > Duration::from_millis(lock::WAIT_MS) {
                        return false;
                    }
                    std::thread::yield_now();
                }
                continue;
            };
            // The field stores below must not become visible before the odd word.
            fence(Ordering::Release);
            let count = match fields {
                Fields::Centre(position, at, velocity) => {
                    let (kind, xy) = match position {
                        RequestPosition::Texels(centre) => {
                            r.store(base + v::REQ_CENTRE_S, centre[0] as u64, Ordering::Relaxed);
                            r.store(base + v::REQ_CENTRE_T, centre[1] as u64, Ordering::Relaxed);
                            (v::KIND_TEXELS, [0.0, 0.0])
                        }
                        RequestPosition::LonLat(ll) => (v::KIND_LONLAT, ll),
                        RequestPosition::Map(xy) => (v::KIND_MAP, xy),
                    };
                    // The position record belongs to this request: the count it will have.
                    let next = r.load(base + v::REQ_COUNT, Ordering::Relaxed).wrapping_add(1);
                    r.store(at + v::POS_KIND, kind, Ordering::Relaxed);
                    r.store(at + v::POS_X, xy[0].to_bits(), Ordering::Relaxed);
                    r.store(at + v::POS_Y, xy[1].to_bits(), Ordering::Relaxed);
                    r.store(at + v::POS_FOR_COUNT, next, Ordering::Relaxed);
                    r.store(base + v::REQ_VEL_S, velocity[0].to_bits(), Ordering::Relaxed);
                    r.store(base + v::REQ_VEL_T, velocity[1].to_bits(), Ordering::Relaxed);
                    base + v::REQ_COUNT
                }
                Fields::Lod { at, height, pixel_angle, effective } => {
                    r.store(at + v::LOD_HEIGHT, height.to_bits(), Ordering::Relaxed);
                    r.store(at + v::LOD_PIXEL_ANGLE, pixel_angle.to_bits(), Ordering::Relaxed);
                    r.store(at + v::LOD_EFFECTIVE, u64::from(effective), Ordering::Relaxed);
                    at + v::LOD_COUNT
                }
            };
            r.store(base + v::REQ_CLIENT_PID, u64::from(pid), Ordering::Relaxed);
            if let Some(i) = incarnation {
                r.store(base + v::REQ_INCARNATION, i, Ordering::Relaxed);
            }
            let c = r.load(count, Ordering::Relaxed);
            r.store(count, c.wrapping_add(1), Ordering::Relaxed);
            // Release (compare-and-swap: never over a word someone else stored).
            let released = r.compare_exchange(base + v::REQ_SEQ, mine, lock::released(mine)).is_ok();
            if released {
                note_lock_word(lock::released(mine));
            }
            return released;
        }
    }
}

#[cfg(any(test, feature = "test-hooks"))]
thread_local! {
    /// Every value this thread stored into a request lock word, in order (tests of the lock; the
    /// `test-hooks` feature).
    #[doc(hidden)]
    pub static LOCK_WORDS: std::cell::RefCell<Vec<u64>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Notes a value this thread stored into a request lock word (`LOCK_WORDS`; nothing in other
/// builds).
fn note_lock_word(_word: u64) {
    #[cfg(any(test, feature = "test-hooks"))]
    LOCK_WORDS.with(|w| w.borrow_mut().push(_word));
}

/// What one request writes under its lock word: a centre (the request record's fields and count)
/// or a LOD request (the fields and count of its LOD record, at `at` in the request mapping).
#[derive(Clone, Copy, Debug)]
pub(super) enum Fields {
    /// A centre, the offset of the request's position record, the velocity.
    Centre(RequestPosition, usize, [f64; 2]),
    Lod {
        at: usize,
        height: f64,
        pixel_angle: f64,
        effective: u32,
    },
}

/// Where a renderer asks for a centre ([`Client::request_position`]; docs/SHM.md, "Positions in
/// longitude / latitude or map coordinates").
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RequestPosition {
    /// Level-0 texels (coordinate kind 0, as [`Client::request_centre`]).
    Texels([i64; 2]),
    /// WGS 84 `[longitude, latitude]`, degrees (kind 1).
    LonLat([f64; 2]),
    /// Map `[x, y]` in the texture's CRS (kind 2).
    Map([f64; 2]),
}
