//! Further views of one clipmap: several viewers (a simulator's side windows, an overview beside a
//! detail map) that keep their own centres, windows, published valid regions and min LOD while
//! sharing the clipmap's grids, its read queues and every tile read (docs/VIEWS.md).
//!
//! The clipmap's own centre is the *primary* view (id 0), published in the mapping as always. A
//! further view is added with a weight ([`Clipmap::add_view`]) and moved with
//! [`Clipmap::move_view`]; each tick then:
//! - places each level's mem region around the primary's window grown to the bounding box of
//!   every further view's window the grid can hold with it (heaviest view first): the grid is
//!   never asked to hold more tiles than it has, and the primary's window is always held;
//! - publishes, for each view, the part of its valid region whose tiles are settled **and** stay
//!   inside the new mem region, so that the slots the tick then reassigns never lie under any
//!   view's published region (the layout-2 invariant, per view); a view whose window the grid
//!   cannot hold whole shows a coarser level there, never a wrong texel;
//! - moves each view's min LOD by its own complete levels (load control per view);
//! - orders each tile's read by the most urgent view that wants it, a lighter view's reads put
//!   [`demotion`] levels behind the heaviest view's, so that under a source too slow for all of
//!   them a light view degrades (coarser) before a heavy one.
//!
//! Views that share a centre (stereo, several windows of one eye point) are one view: a reader of
//! either reads the same publication, at no cost.

use super::{Clipmap, LevelView};
use crate::geom::{aligned_centre, tiles_covering, LevelFrame, LevelShape, Rect};
use crate::queue::Priority;
use crate::tile::TileId;

/// A view's handle: 0 is the primary view (the clipmap's own centre); further views get the
/// next free number.
pub type ViewId = u32;

/// The primary view: the clipmap's own centre ([`Clipmap::tick`]), the one the mapping publishes.
pub const PRIMARY: ViewId = 0;

pub use crate::limits::MAX_VIEWS;

/// The levels a view shows: Performer's virtual clip texture, a window of `effective` levels
/// starting at `offset` (0: the finest). A view holds, reads and publishes nothing finer than
/// `offset`, and its min LOD stays at `offset` or coarser. Levels coarser than the window are
/// held and published all the same: each is at most a clip-size square, and every reader relies
/// on every level from min LOD to the coarsest being published (docs/SHM.md); `effective` is the
/// renderer's own bound on what it addresses, kept and reported. [`LodWindow::ALL`] (the default)
/// shows every level.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LodWindow {
    /// The finest level shown (Performer's LOD offset).
    pub offset: u32,
    /// How many levels from `offset` the renderer addresses at once (Performer's effective
    /// levels; `u32::MAX`: all).
    pub effective: u32,
}

impl LodWindow {
    /// Every level.
    pub const ALL: LodWindow = LodWindow { offset: 0, effective: u32::MAX };

    /// Whether level `k` is held and published for the view: it is not finer than the offset.
    pub fn shows(&self, k: u32) -> bool {
        k >= self.offset
    }
}

impl Default for LodWindow {
    fn default() -> Self {
        LodWindow::ALL
    }
}

/// Texels of level 0 one screen pixel spans at a view's nearest ground point (its height above
/// the texture times the angle of a pixel), at which the finest level a renderer samples is
/// log2 of it. The LOD offset that follows it moves finer at once, a quarter level early (the
/// finer level is read before the renderer asks for it), and coarser half a level late, so that a
/// view hovering at a level boundary does not drop and read a level tick after tick.
pub fn offset_for_footprint(current: u32, texels_per_pixel: f64, levels: u32) -> u32 {
    let last = levels.saturating_sub(1);
    if !(texels_per_pixel.is_finite() && texels_per_pixel > 0.0) {
        return current.min(last);
    }
    let lod = texels_per_pixel.log2();
    let finer = (lod - 0.25).floor().max(0.0).min(last as f64) as u32;
    let coarser = (lod - 0.5).floor().max(0.0).min(last as f64) as u32;
    if finer < current {
        finer
    } else if coarser > current {
        coarser
    } else {
        current.min(last)
    }
}

/// Why a view could not be added, moved or weighted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ViewError {
    /// No such view.
    #[error("view {0}: no such view (views are numbered from 0, the primary, in the order they were added; removed ones are gone)")]
    Unknown(ViewId),
    /// A weight that is not a positive finite number.
    #[error("view weight {0}: expected a positive finite number, such as 1 or 3 (reads are shared out in proportion)")]
    Weight(f64),
    /// Too many views.
    #[error("{MAX_VIEWS} views already: remove one first")]
    Full,
    /// A name that is not allowed, or taken.
    #[error("{0}")]
    Name(String),
    /// A LOD window or footprint that is not allowed.
    #[error("{0}")]
    Lod(String),
    /// The view's grids are another clipmap's: it is moved there.
    #[error("view `{0}` has grids of its own, in another clipmap: move it and set its levels there")]
    Elsewhere(String),
    /// The primary view cannot be removed.
    #[error("view 0 is the primary view (the clipmap's own centre) and cannot be removed")]
    Primary,
}

/// One level of a further view.
#[derive(Clone, Debug)]
pub(super) struct ViewLevel {
    pub(super) frame: LevelFrame,
    pub(super) published: Rect,
    pub(super) updated_tick: u64,
}

/// A further view's state.
#[derive(Clone, Debug)]
pub(super) struct View {
    /// Its name in the mapping (`None`: unnamed, an engine without a service).
    pub(super) name: Option<String>,
    pub(super) weight: f64,
    /// Where the view asked to be, and its velocity (level-0 texels per tick), if it has moved.
    pub(super) want: Option<([i64; 2], Option<[i64; 2]>)>,
    pub(super) centre: Option<[i64; 2]>,
    pub(super) velocity: [i64; 2],
    pub(super) levels: Vec<ViewLevel>,
    pub(super) min_lod: f64,
    /// The levels it shows.
    pub(super) lod: LodWindow,
    /// Its grids are another clipmap's ([`Clipmap::add_view_elsewhere`]): here it only holds its
    /// name and record, and never has a centre.
    pub(super) elsewhere: bool,
}

/// The views beside the primary one, and the primary's weight and levels.
#[derive(Clone, Debug)]
pub(super) struct Views {
    pub(super) primary_weight: f64,
    pub(super) primary_lod: LodWindow,
    /// Indexed by id less one; `None` once removed.
    pub(super) others: Vec<Option<View>>,
}

impl Default for Views {
    fn default() -> Self {
        Views { primary_weight: 1.0, primary_lod: LodWindow::ALL, others: Vec::new() }
    }
}

impl Views {
    pub(super) fn live(&self) -> impl Iterator<Item = (ViewId, &View)> {
        self.others.iter().enumerate().filter_map(|(i, v)| v.as_ref().map(|v| (i as ViewId + 1, v)))
    }

    fn heaviest(&self) -> f64 {
        self.live().map(|(_, v)| v.weight).fold(self.primary_weight, f64::max)
    }
}

/// The levels a view of weight `weight` has its reads put behind those of a view of weight
/// `heaviest`: log2 of their ratio, rounded (0 for equal weights, 1 for 2:1, 2 for 3:1 and
/// 4:1). A tile of level k wanted by the light view is read with the heavy view's tiles of level
/// k − demotion, so under a source too slow for both the light view's finest levels wait and the
/// heavy view keeps its own.
pub fn demotion(weight: f64, heaviest: f64) -> u32 {
    if !(weight > 0.0 && heaviest > weight) {
        return 0;
    }
    (heaviest / weight).log2().round().clamp(0.0, 64.0) as u32
}

fn check_weight(weight: f64) -> Result<f64, ViewError> {
    if weight.is_finite() && weight > 0.0 {
        Ok(weight)
    } else {
        Err(ViewError::Weight(weight))
    }
}

impl Clipmap {
    /// Adds a view of weight `weight` (relative to the others'; the primary's is 1 unless
    /// [`set_view_weight`](Self::set_view_weight) says otherwise). It has no centre, and
    /// publishes nothing, until [`move_view`](Self::move_view) gives it one.
    pub fn add_view(&mut self, weight: f64) -> Result<ViewId, ViewError> {
        self.add_view_as(None, weight, false)
    }

    /// [`add_view`](Self::add_view) named `name` (1 to 31 of `A-Z a-z 0-9 - _ .`, not `main`,
    /// not another live view's): the mapping's record of the view carries the name, and readers
    /// find the view by it.
    pub fn add_named_view(&mut self, name: &str, weight: f64) -> Result<ViewId, ViewError> {
        self.check_new_name(name)?;
        self.add_view_as(Some(name.to_string()), weight, false)
    }

    /// Names a view whose grids are elsewhere: another clipmap of the same source, published in
    /// the mapping [`own_mapping_name`](crate::shm::layout::views::own_mapping_name) beside this
    /// one, holds them (docs/VIEWS.md, "Views far apart"). Here the view has a record that says
    /// so (state 2), under the same rules of names as [`add_named_view`](Self::add_named_view);
    /// it holds no tile, reads nothing and cannot be moved.
    pub fn add_view_elsewhere(&mut self, name: &str, weight: f64) -> Result<ViewId, ViewError> {
        self.check_new_name(name)?;
        self.add_view_as(Some(name.to_string()), weight, true)
    }

    /// Whether view `id` has its grids elsewhere ([`add_view_elsewhere`](Self::add_view_elsewhere)).
    pub fn view_elsewhere(&self, id: ViewId) -> bool {
        id != PRIMARY && self.view(id).is_ok_and(|v| v.elsewhere)
    }

    /// Whether `name` may be given to a new view: an allowed name no live view has.
    pub fn check_new_name(&self, name: &str) -> Result<(), ViewError> {
        crate::shm::layout::views::check_name(name).map_err(ViewError::Name)?;
        if self.views.live().any(|(_, v)| v.name.as_deref() == Some(name)) {
            return Err(ViewError::Name(format!(
                "view `{name}` exists already: remove it first or choose another name"
            )));
        }
        Ok(())
    }

    /// A view's id by name (`main`: the primary).
    pub fn view_named(&self, name: &str) -> Option<ViewId> {
        if name == crate::shm::layout::views::PRIMARY_NAME {
            return Some(PRIMARY);
        }
        self.views.live().find(|(_, v)| v.name.as_deref() == Some(name)).map(|(id, _)| id)
    }

    /// A view's name (`main` for the primary; `None` for an unnamed or unknown view).
    pub fn view_name(&self, id: ViewId) -> Option<&str> {
        if id == PRIMARY {
            return Some(crate::shm::layout::views::PRIMARY_NAME);
        }
        self.view(id).ok().and_then(|v| v.name.as_deref())
    }

    fn add_view_as(&mut self, name: Option<String>, weight: f64, elsewhere: bool) -> Result<ViewId, ViewError> {
        let weight = check_weight(weight)?;
        let view = View {
            name,
            weight,
            want: None,
            centre: None,
            velocity: [0, 0],
            levels: Vec::new(),
            min_lod: self.levels.len() as f64,
            lod: LodWindow::ALL,
            elsewhere,
        };
        let id = match self.views.others.iter().position(Option::is_none) {
            Some(i) => i + 1,
            None if self.views.others.len() + 1 >= MAX_VIEWS => return Err(ViewError::Full),
            None => {
                self.views.others.push(None);
                self.views.others.len()
            }
        };
        if let Some(name) = &view.name {
            self.cache.memory().open_view(id, name, view.weight, elsewhere);
        }
        self.views.others[id - 1] = Some(view);
        Ok(id as ViewId)
    }

    /// Removes a further view: from the next tick its windows no longer hold tiles in the grids.
    pub fn remove_view(&mut self, id: ViewId) -> Result<(), ViewError> {
        if id == PRIMARY {
            return Err(ViewError::Primary);
        }
        self.view_mut(id)?;
        self.views.others[id as usize - 1] = None;
        // Its regions stop protecting slots only now: its record says free first.
        self.cache.memory().close_view(id as usize);
        while matches!(self.views.others.last(), Some(None)) {
            self.views.others.pop();
        }
        Ok(())
    }

    /// Asks the next tick to move view `id` to `centre` (level-0 texels), moving at `velocity`
    /// level-0 texels per tick if given (else its change since the view's last tick). The primary
    /// view moves with [`tick`](Self::tick).
    pub fn move_view(&mut self, id: ViewId, centre: [i64; 2], velocity: Option<[i64; 2]>) -> Result<(), ViewError> {
        let far = crate::limits::MAX_CENTRE;
        let view = self.view_mut(id)?;
        if view.elsewhere {
            return Err(ViewError::Elsewhere(view.name.clone().unwrap_or_default()));
        }
        view.want = Some((centre.map(|c| c.clamp(-far, far)), velocity.map(|v| v.map(|x| x.clamp(-far, far)))));
        Ok(())
    }

    /// Sets a view's weight (the primary's too).
    pub fn set_view_weight(&mut self, id: ViewId, weight: f64) -> Result<(), ViewError> {
        let weight = check_weight(weight)?;
        if id == PRIMARY {
            self.views.primary_weight = weight;
        } else {
            self.view_mut(id)?.weight = weight;
            self.cache.memory().set_view_weight(id as usize, weight);
        }
        Ok(())
    }

    /// Sets the levels view `id` shows (the primary's too) from the next tick: it then holds and
    /// reads nothing for levels outside `lod`, and its min LOD stays at `lod.offset` or coarser.
    pub fn set_view_lod(&mut self, id: ViewId, lod: LodWindow) -> Result<(), ViewError> {
        if lod.effective == 0 {
            return Err(ViewError::Lod("effective levels 0: expected at least 1".into()));
        }
        let levels = self.levels.len() as u32;
        if lod.offset >= levels {
            return Err(ViewError::Lod(format!(
                "LOD offset {}: expected 0 to {} (the texture has {levels} levels, 0 the finest)",
                lod.offset,
                levels - 1
            )));
        }
        if id == PRIMARY {
            self.views.primary_lod = lod;
        } else {
            self.view_mut(id)?.lod = lod;
        }
        Ok(())
    }

    /// The levels view `id` shows.
    pub fn view_lod(&self, id: ViewId) -> Result<LodWindow, ViewError> {
        if id == PRIMARY {
            return Ok(self.views.primary_lod);
        }
        Ok(self.view(id)?.lod)
    }

    /// Moves view `id`'s LOD offset to follow its height above the texture: `texels_per_pixel`
    /// is the level-0 texels one screen pixel spans at its nearest ground point
    /// ([`offset_for_footprint`]); its effective levels stay as they are. Returns the offset.
    pub fn set_view_footprint(&mut self, id: ViewId, texels_per_pixel: f64) -> Result<u32, ViewError> {
        if !(texels_per_pixel.is_finite() && texels_per_pixel > 0.0) {
            return Err(ViewError::Lod(format!(
                "texels per pixel {texels_per_pixel}: expected a positive finite number (height above the texture in level-0 texels times the angle of a pixel in radians)"
            )));
        }
        let lod = self.view_lod(id)?;
        let offset = offset_for_footprint(lod.offset, texels_per_pixel, self.levels.len() as u32);
        self.set_view_lod(id, LodWindow { offset, ..lod })?;
        Ok(offset)
    }

    /// The levels view `id` holds now: those it shows whose grid holds part of its window.
    pub fn view_resident_levels(&self, id: ViewId) -> Result<Vec<u32>, ViewError> {
        let lod = self.view_lod(id)?;
        let windows: Vec<Rect> = if id == PRIMARY {
            self.levels.iter().map(|l| l.frame.tex).collect()
        } else {
            self.view(id)?.levels.iter().map(|l| l.frame.tex).collect()
        };
        Ok((0..self.levels.len() as u32)
            .filter(|&k| lod.shows(k))
            .filter(|&k| {
                let l = &self.levels[k as usize];
                let w = windows.get(k as usize).copied().unwrap_or(Rect::EMPTY);
                !w.is_empty() && !tiles_covering(w, l.shape.tile).intersect(&l.frame.mem).is_empty()
            })
            .collect())
    }

    /// The ids of the views, the primary first.
    pub fn view_ids(&self) -> Vec<ViewId> {
        std::iter::once(PRIMARY).chain(self.views.live().map(|(id, _)| id)).collect()
    }

    /// A view's weight.
    pub fn view_weight(&self, id: ViewId) -> Result<f64, ViewError> {
        if id == PRIMARY {
            return Ok(self.views.primary_weight);
        }
        Ok(self.view(id)?.weight)
    }

    /// A view's min LOD (the level count until it has a complete level).
    pub fn view_min_lod(&self, id: ViewId) -> Result<f64, ViewError> {
        if id == PRIMARY {
            return Ok(self.min_lod);
        }
        Ok(self.view(id)?.min_lod)
    }

    /// A view's level-0 centre as the last tick applied it.
    pub fn view_centre(&self, id: ViewId) -> Result<Option<[i64; 2]>, ViewError> {
        if id == PRIMARY {
            return Ok(self.centre);
        }
        Ok(self.view(id)?.centre)
    }

    /// Level `k` of view `id` as published: its valid region and centre, over the shared grids.
    pub fn view_level(&self, id: ViewId, k: u32) -> Result<LevelView<'_>, ViewError> {
        if id == PRIMARY {
            return Ok(self.level(k));
        }
        let view = self.view(id)?;
        let mut out = self.level(k);
        match view.levels.get(k as usize) {
            Some(l) => {
                out.valid = l.published;
                out.centre = l.frame.centre;
            }
            None => {
                out.valid = Rect::EMPTY;
                out.centre = [0, 0];
            }
        }
        Ok(out)
    }

    fn view(&self, id: ViewId) -> Result<&View, ViewError> {
        (id as usize)
            .checked_sub(1)
            .and_then(|i| self.views.others.get(i))
            .and_then(Option::as_ref)
            .ok_or(ViewError::Unknown(id))
    }

    fn view_mut(&mut self, id: ViewId) -> Result<&mut View, ViewError> {
        (id as usize)
            .checked_sub(1)
            .and_then(|i| self.views.others.get_mut(i))
            .and_then(Option::as_mut)
            .ok_or(ViewError::Unknown(id))
    }

    /// Moves every further view's frames to its asked-for centre (before the mem regions are
    /// placed, so that they hold the views' windows).
    pub(super) fn move_view_frames(&mut self) {
        let (border, align) = (self.border, self.settings.centre_alignment);
        let shapes: Vec<_> = self.levels.iter().map(|l| l.shape).collect();
        for view in self.views.others.iter_mut().flatten() {
            let Some((centre, velocity)) = view.want else { continue };
            let velocity =
                velocity.unwrap_or_else(|| view.centre.map_or([0, 0], |c| [centre[0] - c[0], centre[1] - c[1]]));
            view.centre = Some(centre);
            view.velocity = velocity;
            if view.levels.len() != shapes.len() {
                view.levels = shapes
                    .iter()
                    .map(|_| ViewLevel {
                        frame: LevelFrame { centre: [0, 0], tex: Rect::EMPTY, valid: Rect::EMPTY, mem: Rect::EMPTY },
                        published: Rect::EMPTY,
                        updated_tick: 0,
                    })
                    .collect();
            }
            for (k, (level, shape)) in view.levels.iter_mut().zip(&shapes).enumerate() {
                let k = k as u32;
                let v = velocity.map(|x| if x != 0 && (x >> k.min(63)) == 0 { x.signum() } else { x >> k.min(63) });
                level.frame = shape.frame(aligned_centre(centre, k, align), border, v);
            }
        }
    }

    /// Each level's further views' windows, heaviest view first (ties: in id order).
    pub(super) fn views_windows(&self) -> Vec<Vec<Rect>> {
        let mut live: Vec<(ViewId, &View)> = self.views.live().filter(|(_, v)| v.centre.is_some()).collect();
        live.sort_by(|a, b| b.1.weight.total_cmp(&a.1.weight).then(a.0.cmp(&b.0)));
        (0..self.levels.len())
            .map(|k| {
                live.iter()
                    .filter(|(_, v)| v.lod.shows(k as u32))
                    .filter_map(|(_, v)| v.levels.get(k).map(|l| l.frame.tex))
                    .filter(|r| !r.is_empty())
                    .collect()
            })
            .collect()
    }

    /// Publishes each further view's settled part of its valid regions, restricted to the new mem
    /// regions, and moves its min LOD.
    pub(super) fn publish_views(&mut self) {
        let fade = self.settings.fade_ticks;
        let count = self.levels.len();
        let mut updates = Vec::new();
        for (id, view) in self.views.live() {
            if view.centre.is_none() {
                continue;
            }
            let regions: Vec<Rect> = (0..count)
                .map(|k| if view.lod.shows(k as u32) { self.settled_in(k, &view.levels[k].frame) } else { Rect::EMPTY })
                .collect();
            updates.push((id, regions));
        }
        let tick = self.tick;
        for (id, regions) in updates {
            let view = self.views.others[id as usize - 1].as_mut().expect("a live view");
            let mut complete = Vec::with_capacity(count);
            let lod = view.lod;
            for (k, (level, region)) in view.levels.iter_mut().zip(regions).enumerate() {
                let k = k as u32;
                complete.push(if lod.shows(k) {
                    region == level.frame.valid || level.frame.valid.is_empty()
                } else {
                    false
                });
                if region != level.published {
                    level.published = region;
                    level.updated_tick = tick;
                }
            }
            let target = super::target_min_lod(&complete);
            let fade = if view.min_lod >= count as f64 { 0 } else { fade };
            view.min_lod = super::next_min_lod(view.min_lod, target, fade);
        }
    }

    /// Stores every further view's publication in the image memory (its mapping record), before
    /// the tick reassigns any slot.
    pub(super) fn store_view_publications(&self) {
        for (id, view) in self.views.live() {
            let Some(centre) = view.centre else { continue };
            let p = crate::shm::Publication {
                min_lod: view.min_lod,
                tick: self.tick,
                invalid_border: self.border,
                centre,
                levels: view
                    .levels
                    .iter()
                    .map(|l| crate::shm::PublishedLevel {
                        centre: l.frame.centre,
                        valid: l.published,
                        updated_tick: l.updated_tick,
                    })
                    .collect(),
            };
            self.cache.memory().publish_view(id as usize, &p);
        }
    }

    /// The most urgent priority any view gives `tile` (of level `k`, covering `texels`), each
    /// view's put behind by its [`demotion`]: `primary` is the primary view's own.
    pub(super) fn view_priority(&self, k: usize, texels: Rect, primary: Priority, adaptive: bool) -> Priority {
        let count = self.levels.len();
        let heaviest = self.views.heaviest();
        let demote = |p: Priority, w: f64| Priority { rank: p.rank.saturating_add(demotion(w, heaviest)), ..p };
        let mut best = None;
        if self.views.primary_lod.shows(k as u32) {
            best = Some(demote(primary, self.views.primary_weight));
        }
        let clip = self.levels[k].shape.clip;
        for (_, view) in self.views.live() {
            if !view.lod.shows(k as u32) {
                continue;
            }
            let Some(l) = view.levels.get(k).filter(|_| view.centre.is_some()) else { continue };
            let k32 = k as u32;
            let v =
                view.velocity.map(|x| if x != 0 && (x >> k32.min(63)) == 0 { x.signum() } else { x >> k32.min(63) });
            let p = if adaptive {
                crate::queue::soonest_first(k32, count, texels, l.frame.valid, clip, v)
            } else {
                crate::queue::priority(k32, count, texels, l.frame.valid, clip, v)
            };
            let p = demote(p, view.weight);
            best = Some(best.map_or(p, |b: Priority| b.min(p)));
        }
        // A tile no view shows is not in any mem region; the primary's rank stands in.
        best.unwrap_or(primary)
    }

    /// Slots about to leave level `k`'s mem region `mem` whose tiles lie under a further view's
    /// published region (always 0: the regions are restricted to the new mem regions).
    pub(super) fn under_views_leaving(&self, k: usize, mem: Rect) -> u64 {
        let old = self.cache.mem_region(k as u32);
        if old == mem {
            return 0;
        }
        let tile = self.levels[k].shape.tile;
        let period = self.levels[k].shape.tile_period();
        let mut n = 0;
        for (_, view) in self.views.live() {
            let Some(l) = view.levels.get(k) else { continue };
            let r = tiles_covering(l.published, tile);
            let r = match period {
                Some(p) => crate::geom::shift_near(r, p, old.s0),
                None => r,
            }
            .intersect(&old);
            for t in r.t0..r.t1 {
                for s in r.s0..r.s1 {
                    let real = period.map_or(s, |p| crate::geom::wrap(s, p) as i64);
                    let settled = self.cache.state(TileId::new(k as u32, real as u64, t as u64)).settled();
                    if settled && !crate::geom::contains_wrapped(&mem, real, t, period) {
                        n += 1;
                    }
                }
            }
        }
        n
    }
}

/// The window a level's mem region is placed around: the primary's window `tex`, grown to the
/// bounding box of each further view's window in `others` (heaviest first) that the grid still
/// holds with those before it. The primary's window is always held (the primary view first); a
/// view left out shows the part of its window the grid holds, at a coarser level elsewhere.
pub(super) fn mem_window(shape: &LevelShape, tex: Rect, others: &[Rect]) -> Rect {
    let fits = |r: Rect| {
        let need = tiles_covering(r, shape.tile);
        need.width() <= shape.grid[0] && need.height() <= shape.grid[1]
    };
    let mut union = tex;
    for &r in others {
        // On a wrapping level, another view's window where it lies nearest the primary's.
        let r = match shape.texel_period() {
            Some(w) if !tex.is_empty() => crate::geom::shift_near(r, w, tex.s0),
            _ => r,
        };
        let grown = bbox(union, r);
        if fits(grown) {
            union = grown;
        }
    }
    union
}

/// The smallest rectangle holding both (either may be empty).
fn bbox(a: Rect, b: Rect) -> Rect {
    if a.is_empty() {
        return b;
    }
    if b.is_empty() {
        return a;
    }
    Rect::new(a.s0.min(b.s0), a.t0.min(b.t0), a.s1.max(b.s1), a.t1.max(b.t1))
}

/// `grids` (one per level of `desc`) widened to hold views whose level-0 windows lie up to
/// `spread` texels apart: `ceil((spread >> k) / tile)` more tiles per axis at level k, no more
/// than the level has.
pub(super) fn spread_grids(desc: &crate::source::TextureDesc, mut grids: Vec<[u64; 2]>, spread: u64) -> Vec<[u64; 2]> {
    if spread == 0 {
        return grids;
    }
    for (k, g) in grids.iter_mut().enumerate() {
        let l = desc.level(k as u32);
        let n = crate::geom::tiles_in_level(l.size, l.tile);
        let extra = spread >> (k as u32).min(63);
        for a in 0..2 {
            g[a] = g[a].saturating_add(extra.div_ceil(l.tile[a])).min(n[a]);
        }
    }
    grids
}

#[cfg(test)]
mod tests;
