//! The service's views (docs/VIEWS.md): the primary (`main`, the clipmap's own centre) and the
//! further ones, each one [`View`] whether its grids are the service's (shared) or its own
//! ([`super::own_views`]). Everything a view is told arrives here: the socket's `CENTRE` and
//! `VIEW` commands, and the renderers' requests in the request mappings (the service's request
//! block for the primary, its request records for the further views, an own mapping's request
//! block for a view with grids of its own).
//!
//! A view's published regions and LOD window are the engine's ([`Clipmap`]'s view of that id,
//! in the clipmap that holds its grids): [`View::grids`] says which, and [`Views::stats`] reads
//! them from there.

use super::own_views::{OwnGrids, Setup};
use super::protocol::{Refusal, Reply, ViewCommand};
use super::requests::{apply_lod, bounded_centre, request_centre, velocity_per_tick};
use super::stats::{TickStats, ViewStats};
use clipmap::clip::{Clipmap, LodWindow, ViewId, PRIMARY};
use clipmap::georef::Georef;
use clipmap::shm::writer::{LodRequest, Position};
use clipmap::shm::Writer;
use clipmap::source::TileId;
use std::collections::BTreeMap;

/// Where a view's grids are.
enum Grids {
    /// The service's: the view is one of its clipmap's views.
    Shared,
    /// A clipmap and mapping of its own (docs/VIEWS.md, "Views far apart"); the service's
    /// clipmap keeps its record only.
    Own(Box<OwnGrids>),
}

/// One view of the service.
pub(super) struct View {
    /// Its id in the service's clipmap (the primary: [`PRIMARY`]).
    id: ViewId,
    /// Where it is asked to be, level-0 texels.
    centre: [i64; 2],
    /// Its velocity in texels a tick, from its last request (`None`: the engine follows the
    /// centre's change).
    velocity: Option<[i64; 2]>,
    /// Its last request's count, as taken.
    last_request: u64,
    /// Its last LOD request's count, as taken.
    last_lod: u64,
    grids: Grids,
}

impl View {
    fn new(id: ViewId, centre: [i64; 2], grids: Grids) -> View {
        View { id, centre, velocity: None, last_request: 0, last_lod: 0, grids }
    }

    /// The clipmap that holds its grids (`shared`, the service's, or its own), and its id there.
    fn grids<'a>(&'a mut self, shared: &'a mut Clipmap) -> (&'a mut Clipmap, ViewId) {
        match &mut self.grids {
            Grids::Own(g) => (&mut g.clipmap, PRIMARY),
            Grids::Shared => (shared, self.id),
        }
    }

    fn own(&self) -> Option<&OwnGrids> {
        match &self.grids {
            Grids::Own(g) => Some(g.as_ref()),
            Grids::Shared => None,
        }
    }

    /// Moved by the socket: its velocity is forgotten.
    fn place(&mut self, centre: [i64; 2]) {
        self.centre = centre;
        self.velocity = None;
    }

    /// Takes a renderer's request (`count` made so far): a new one moves the view. Returns
    /// whether it was new, and the LOD request if that is new.
    #[cfg(test)]
    fn take_request(
        &mut self,
        centre: [i64; 2],
        velocity: [f64; 2],
        count: u64,
        lod: Option<LodRequest>,
        hz: f64,
    ) -> (bool, Option<LodRequest>) {
        self.take_request_at(Ok(centre), velocity, count, lod, hz)
    }

    /// [`take_request`](Self::take_request) of a centre that may have been refused (a position
    /// the georeferencing could not place): a refused one is taken (not looked at again) and
    /// moves nothing.
    fn take_request_at(
        &mut self,
        centre: Result<[i64; 2], ()>,
        velocity: [f64; 2],
        count: u64,
        lod: Option<LodRequest>,
        hz: f64,
    ) -> (bool, Option<LodRequest>) {
        let new = count != self.last_request;
        if new {
            self.last_request = count;
            if let Ok(centre) = centre {
                self.centre = centre;
                self.velocity = velocity_per_tick(velocity, hz);
            }
        }
        let lod = lod.filter(|l| l.count != self.last_lod);
        if let Some(l) = &lod {
            self.last_lod = l.count;
        }
        (new, lod)
    }
}

/// Every view of the service, by its id in the service's clipmap, the primary first.
pub(super) struct Views {
    views: BTreeMap<ViewId, View>,
    /// What a view with grids of its own is made of.
    setup: Setup,
    /// The texture's georeferencing: centres given and shown in longitude / latitude.
    georef: Option<Georef>,
}

/// The level-0 centre of a `CENTRE LONLAT`: the point's continuous level-0 texel coordinates
/// through `georef`, floored to the texel that holds it (as `CENTRE <s> <t>` names a texel).
/// Refused: no georeferencing, a point outside the projection's domain or the texture.
pub(super) fn lonlat_centre(georef: Option<&Georef>, [lon, lat]: [f64; 2]) -> Result<[i64; 2], Refusal> {
    let g = georef.ok_or(Refusal::NoGeoref)?;
    let [s, t] = g.lonlat_to_texel(0, [lon, lat]).map_err(|e| Refusal::LonLat { lon, lat, why: e.to_string() })?;
    Ok([s.floor() as i64, t.floor() as i64])
}

/// The longitude / latitude `STATS` shows of level-0 centre `c`: that of its texel's middle
/// `(s + 0.5, t + 0.5)`, so that `CENTRE LONLAT` of it lands on `c` again; `None` without
/// georeferencing or outside the texture.
pub(super) fn centre_lonlat(georef: Option<&Georef>, c: [i64; 2]) -> Option<[f64; 2]> {
    georef?.texel_to_lonlat(0, [c[0] as f64 + 0.5, c[1] as f64 + 0.5]).ok()
}

impl Views {
    /// The primary alone, at `centre`.
    pub(super) fn new(setup: Setup, centre: [i64; 2]) -> Views {
        Views { views: BTreeMap::from([(PRIMARY, View::new(PRIMARY, centre, Grids::Shared))]), setup, georef: None }
    }

    /// Takes the texture's georeferencing ([`clipmap::source::TileSource::georef`]).
    pub(super) fn set_georef(&mut self, georef: Option<Georef>) {
        self.georef = georef;
    }

    /// The texture's georeferencing.
    pub(super) fn georef(&self) -> Option<&Georef> {
        self.georef.as_ref()
    }

    /// The centre of a new request (`count`, not yet taken by a view whose last is `last`) of
    /// view `name`: [`request_centre`] of its position, counted in `stats` when the position was
    /// not in texels, and logged with why when refused. `Ok` of anything for a request already
    /// taken (it moves nothing then).
    fn resolve(
        georef: Option<&Georef>,
        name: &str,
        (centre, position, count, last): ([i64; 2], Position, u64, u64),
        stats: &mut TickStats,
    ) -> Result<[i64; 2], ()> {
        if count == last || position == Position::Texels {
            return Ok(centre);
        }
        match request_centre(georef, centre, position) {
            Ok(c) => {
                stats.position_requests += 1;
                Ok(c)
            }
            Err(why) => {
                stats.position_requests_refused += 1;
                tracing::warn!(view = %name, "centre request refused: {why}");
                stats.position_request_refused = Some(format!("view {name}: {why}"));
                Err(())
            }
        }
    }

    /// `CENTRE LONLAT`: the primary at the texel of a longitude / latitude ([`lonlat_centre`]).
    pub(super) fn centre_primary_lonlat(
        &mut self,
        lonlat: [f64; 2],
        stats: &mut TickStats,
    ) -> Result<[i64; 2], Refusal> {
        let c = lonlat_centre(self.georef.as_ref(), lonlat)?;
        Ok(self.centre_primary(c, stats))
    }

    /// The primary view.
    pub(super) fn primary(&self) -> &View {
        &self.views[&PRIMARY]
    }

    fn primary_mut(&mut self) -> &mut View {
        self.views.get_mut(&PRIMARY).expect("the primary view is never removed")
    }

    /// The primary's centre and velocity, for the engine's tick.
    pub(super) fn primary_motion(&self) -> ([i64; 2], Option<[i64; 2]>) {
        let p = self.primary();
        (p.centre, p.velocity)
    }

    /// Moves the primary (`CENTRE`, `VIEW CENTRE main`): bounded, without velocity. Returns the
    /// centre the snapshot will publish.
    pub(super) fn centre_primary(&mut self, centre: [i64; 2], stats: &mut TickStats) -> [i64; 2] {
        let c = bounded_centre(centre);
        self.primary_mut().place(c);
        stats.request_velocity = None;
        stats.socket_centres += 1;
        c
    }

    /// Carries out a `VIEW` command on the views of `clipmap` (the service's).
    pub(super) fn command(
        &mut self,
        clipmap: &mut Clipmap,
        stats: &mut TickStats,
        cmd: ViewCommand,
    ) -> Result<Reply, Refusal> {
        match cmd {
            ViewCommand::Add { name, weight, own } => self.add(clipmap, &name, weight, own),
            ViewCommand::Remove { name } => self.remove(clipmap, name),
            ViewCommand::Centre { name, centre } => {
                let id = named(clipmap, &name)?;
                let centre = match id {
                    PRIMARY => self.centre_primary(centre, stats),
                    _ => {
                        let c = bounded_centre(centre);
                        self.get_mut(clipmap, id, &name)?.place(c);
                        stats.socket_centres += 1;
                        c
                    }
                };
                Ok(Reply::ViewCentre { name, centre })
            }
            ViewCommand::CentreLonLat { name, lonlat } => {
                let centre = lonlat_centre(self.georef.as_ref(), lonlat)?;
                self.command(clipmap, stats, ViewCommand::Centre { name, centre })
            }
            ViewCommand::Weight { name, weight } => {
                clipmap.set_view_weight(named(clipmap, &name)?, weight)?;
                Ok(Reply::ViewWeight { name, weight })
            }
            ViewCommand::Lod { name, offset, effective } => {
                let lod = LodWindow { offset, effective: effective.unwrap_or(u32::MAX) };
                let id = named(clipmap, &name)?;
                let (map, id) = self.get_mut(clipmap, id, &name)?.grids(clipmap);
                map.set_view_lod(id, lod)?;
                Ok(Reply::ViewLod { name, lod })
            }
            ViewCommand::Height { name, height, pixel_angle, effective } => {
                let req = LodRequest { height, pixel_angle, effective: u64::from(effective), count: 0 };
                let id = named(clipmap, &name)?;
                let (map, id) = self.get_mut(clipmap, id, &name)?.grids(clipmap);
                let lod = apply_lod(map, id, &name, &req, stats)?;
                Ok(Reply::ViewLod { name, lod })
            }
        }
    }

    /// View `id` (named `name` in `clipmap`).
    fn get_mut(&mut self, clipmap: &Clipmap, id: ViewId, name: &str) -> Result<&mut View, Refusal> {
        self.views.get_mut(&id).ok_or_else(|| no_view(clipmap, name))
    }

    /// Adds a named view to `clipmap` (the service's), centred where the primary is until it is
    /// told otherwise, in the shared grids or (`own`) with grids of its own.
    pub(super) fn add(&mut self, clipmap: &mut Clipmap, name: &str, weight: f64, own: bool) -> Result<Reply, Refusal> {
        let centre = self.primary().centre;
        let added = Reply::ViewAdded { name: name.to_string(), weight, own };
        if own {
            // Its own mapping first, then the record that sends readers there: a reader never
            // finds the record without the mapping.
            clipmap.check_new_name(name)?;
            let grids = OwnGrids::new(&self.setup, name)?;
            let id = match clipmap.add_view_elsewhere(name, weight) {
                Ok(id) => id,
                Err(e) => {
                    grids.close();
                    return Err(e.into());
                }
            };
            self.views.insert(id, View::new(id, centre, Grids::Own(Box::new(grids))));
            return Ok(added);
        }
        let id = clipmap.add_named_view(name, weight)?;
        if let Some(e) = self.setup.effective_levels {
            let _ = clipmap.set_view_lod(id, LodWindow { offset: 0, effective: e });
        }
        self.views.insert(id, View::new(id, centre, Grids::Shared));
        tracing::info!(view = %name, weight, "view added");
        Ok(added)
    }

    fn remove(&mut self, clipmap: &mut Clipmap, name: String) -> Result<Reply, Refusal> {
        let id = clipmap.view_named(&name).filter(|&id| id != PRIMARY).ok_or_else(|| no_view(clipmap, &name))?;
        let view = self.views.remove(&id);
        // The record first (readers see the view removed), then its own mapping.
        let removed = clipmap.remove_view(id);
        if let Some(View { grids: Grids::Own(g), .. }) = view {
            g.close();
        }
        removed?;
        tracing::info!(view = %name, "view removed");
        Ok(Reply::ViewRemoved { name })
    }

    /// Whether a renderer made a new request for the primary or a view with grids of its own
    /// (the loop then ticks early).
    pub(super) fn requests_changed(&self, service: &Writer) -> bool {
        self.views.values().any(|v| match &v.grids {
            Grids::Own(g) => g.writer.request_count() != v.last_request,
            Grids::Shared => v.id == PRIMARY && service.request_count() != v.last_request,
        })
    }

    /// Takes the newest request of the primary from the service's request block (`service`):
    /// its centre, velocity and levels.
    pub(super) fn take_primary_request(
        &mut self,
        clipmap: &mut Clipmap,
        service: &Writer,
        hz: f64,
        stats: &mut TickStats,
    ) {
        let Some(req) = service.request() else { return };
        let last = self.primary().last_request;
        let name = clipmap::shm::layout::views::PRIMARY_NAME;
        let centre = Self::resolve(self.georef.as_ref(), name, (req.centre, req.position, req.count, last), stats);
        let primary = self.primary_mut();
        let (new, lod) = primary.take_request_at(centre, req.velocity, req.count, req.lod, hz);
        if new {
            stats.request_velocity = primary.velocity;
            stats.requests_seen = req.count;
        }
        if let Some(lod) = lod {
            let _ = apply_lod(clipmap, PRIMARY, clipmap::shm::layout::views::PRIMARY_NAME, &lod, stats);
        }
    }

    /// Takes each further view's request record (docs/SHM.md, "Asking for a view's centre"):
    /// a new request for the view's current incarnation moves it. Then moves every further view
    /// of the shared grids where it is asked to be.
    pub(super) fn take_further_requests(
        &mut self,
        clipmap: &mut Clipmap,
        service: &Writer,
        hz: f64,
        stats: &mut TickStats,
    ) {
        let reqs = service.view_requests();
        for (&id, v) in self.views.iter_mut().filter(|(_, v)| v.id != PRIMARY && v.own().is_none()) {
            let Some(req) = reqs.get(id as usize - 1).copied().flatten() else { continue };
            if Some(req.incarnation) != service.memory().view_incarnation(id as usize) {
                continue;
            }
            let name = clipmap.view_name(id).unwrap_or("?").to_string();
            let at = (req.centre, req.position, req.count, v.last_request);
            let centre = Self::resolve(self.georef.as_ref(), &name, at, stats);
            if let (_, Some(lod)) = v.take_request_at(centre, req.velocity, req.count, req.lod, hz) {
                let _ = apply_lod(clipmap, id, &name, &lod, stats);
            }
        }
        for v in self.views.values().filter(|v| v.id != PRIMARY && v.own().is_none()) {
            let _ = clipmap.move_view(v.id, v.centre, v.velocity);
        }
    }

    /// One tick of every view with grids of its own, after the primary's (`primary`): first
    /// what of the service's mapping may be taken now (the source version the primary
    /// followed, the tiles it is still replacing), then for each view its newest request
    /// (centre, velocity, levels), its engine's tick, its heartbeat.
    ///
    /// The service's mapping (`service`) says it is alive after each view's tick: a tick of
    /// many views is many pieces of work, and its heartbeat time stands still for the longest
    /// of them only.
    pub(super) fn tick_own(&mut self, primary: &Clipmap, service: &Writer, hz: f64, stats: &mut TickStats) {
        self.setup.fresh.set(primary.followed_version(), primary.tiles_being_replaced());
        for v in self.views.values_mut() {
            let Some(req) = v.own().map(|g| g.writer.request()) else { continue };
            let lod = req.and_then(|r| {
                let name = primary.view_name(v.id).unwrap_or("?").to_string();
                let at = (r.centre, r.position, r.count, v.last_request);
                let centre = Self::resolve(self.georef.as_ref(), &name, at, stats);
                v.take_request_at(centre, r.velocity, r.count, r.lod, hz).1
            });
            let (id, centre, velocity) = (v.id, v.centre, v.velocity);
            let Grids::Own(g) = &mut v.grids else { continue };
            if let Some(lod) = lod {
                let name = primary.view_name(id).unwrap_or("?").to_string();
                let _ = apply_lod(&mut g.clipmap, PRIMARY, &name, &lod, stats);
            }
            g.clipmap.tick(centre, velocity);
            g.writer.heartbeat();
            service.alive();
        }
    }

    /// The service's mapping is under its name `path` now: views added from now on take tiles
    /// from it there (those added before keep the mapping they opened), and every own mapping's
    /// heartbeat is beaten (its views may have been made a while before).
    pub(super) fn published(&mut self, path: &std::path::Path) {
        self.setup.main_mapping = path.to_path_buf();
        self.own_grids().for_each(|g| g.writer.heartbeat());
    }

    fn own_grids(&self) -> impl Iterator<Item = &OwnGrids> {
        self.views.values().filter_map(View::own)
    }

    /// Says that the source's texels of `tiles` changed (a growing texture's patch): every own
    /// view reads those it holds again, as the primary does ([`Clipmap::refresh`]).
    pub(super) fn refresh(&mut self, tiles: &[TileId]) {
        for v in self.views.values_mut() {
            if let Grids::Own(g) = &mut v.grids {
                g.clipmap.refresh(tiles.iter().copied());
            }
        }
    }

    /// Whether any view with grids of its own holds `tile`.
    pub(super) fn own_holds(&self, tile: TileId) -> bool {
        self.own_grids().any(|g| g.clipmap.holds(tile))
    }

    /// Every own mapping says it is alive (after a long command: a view added).
    pub(super) fn alive(&self) {
        self.own_grids().for_each(|g| g.writer.alive());
    }

    /// Bytes of tiles the views with grids of their own hold.
    pub(super) fn own_resident_bytes(&self) -> u64 {
        self.own_grids().map(|g| g.clipmap.resident_bytes()).sum()
    }

    /// Closes every own mapping (the service stops).
    pub(super) fn close_all(&mut self) {
        for (_, v) in std::mem::take(&mut self.views) {
            if let Grids::Own(g) = v.grids {
                g.close();
            }
        }
    }

    /// Each view's figures, the primary first: a view with grids of its own's are its own
    /// clipmap's primary's.
    pub(super) fn stats(&self, main: &Clipmap) -> Vec<ViewStats> {
        main.view_ids()
            .into_iter()
            .map(|vid| {
                let own = self.views.get(&vid).and_then(View::own).filter(|_| main.view_elsewhere(vid));
                let (m, id) = match own {
                    Some(g) => (&g.clipmap, PRIMARY),
                    None => (main, vid),
                };
                let levels = m.level_count();
                let min_lod = m.view_min_lod(id).unwrap_or(levels as f64);
                ViewStats {
                    name: main.view_name(vid).unwrap_or("").to_string(),
                    grids: if own.is_some() { "own" } else { "shared" }.to_string(),
                    shared_reads: own.map_or(0, |g| g.shared_reads()),
                    weight: main.view_weight(vid).unwrap_or(1.0),
                    centre: m.view_centre(id).ok().flatten(),
                    centre_lonlat: m
                        .view_centre(id)
                        .ok()
                        .flatten()
                        .and_then(|c| centre_lonlat(self.georef.as_ref(), c)),
                    min_lod,
                    levels_disabled: (0..levels as u32).filter(|&k| ((k + 1) as f64) <= min_lod).count() as u64,
                    lod_offset: m.view_lod(id).map_or(0, |l| l.offset),
                    effective_levels: m
                        .view_lod(id)
                        .map_or(levels as u32, |l| l.effective.min(levels as u32 - l.offset.min(levels as u32))),
                    resident_levels: m.view_resident_levels(id).unwrap_or_default(),
                    valid: (0..levels as u32)
                        .map(|k| m.view_level(id, k).map(|l| l.valid).unwrap_or(clipmap::geom::Rect::EMPTY))
                        .map(|r| [r.s0, r.t0, r.s1, r.t1])
                        .collect(),
                }
            })
            .collect()
    }
}

/// The id of the view named `name` in `clipmap`.
fn named(clipmap: &Clipmap, name: &str) -> Result<ViewId, Refusal> {
    clipmap.view_named(name).ok_or_else(|| no_view(clipmap, name))
}

/// The refusal for a view name no view has, naming those that exist.
fn no_view(clipmap: &Clipmap, name: &str) -> Refusal {
    let views = clipmap.view_ids().into_iter().filter_map(|id| clipmap.view_name(id)).map(String::from);
    Refusal::NoView { name: name.to_string(), views: views.collect() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clipmap::clip::Settings;
    use clipmap::source::{HashSource, TextureDesc, TileSource};
    use clipmap::texel::TexelFormat;
    use std::sync::Arc;

    /// A clipmap of the shared grids without a mapping, and its views (the primary at the
    /// texture's middle).
    fn shared(dir: &std::path::Path) -> (Clipmap, Views) {
        let desc = TextureDesc::new([4096, 4096], 128, TexelFormat::RGBA8, [32, 32]).unwrap();
        let source: Arc<dyn TileSource> = Arc::new(HashSource::new(desc));
        let clipmap = Clipmap::new(Arc::clone(&source), Settings::default()).unwrap();
        let setup = Setup {
            source,
            settings: Settings::default(),
            dir: dir.to_path_buf(),
            service: "views".into(),
            shm_mode: 0o600,
            request_mode: 0o600,
            period_ns: 1_000_000,
            heights: None,
            georef: None,
            effective_levels: None,
            main_mapping: dir.join("clipmap-views.map"),
            fresh: Default::default(),
            generation: 1,
        };
        (clipmap, Views::new(setup, [2048, 2048]))
    }

    #[test]
    fn a_request_moves_a_view_once_per_count_and_its_lod_request_is_taken_once_per_its_count() {
        let mut v = View::new(1, [0, 0], Grids::Shared);
        let lod = |count| Some(LodRequest { height: 100.0, pixel_angle: 0.001, effective: 0, count });
        assert_eq!(v.take_request([10, 20], [120.0, -60.0], 1, None, 60.0), (true, None));
        assert_eq!((v.centre, v.velocity), ([10, 20], Some([2, -1])));
        assert_eq!(v.take_request([99, 99], [0.0, 0.0], 1, lod(1), 60.0), (false, lod(1)), "the same request again");
        assert_eq!((v.centre, v.velocity), ([10, 20], Some([2, -1])), "not moved by a request already taken");
        assert_eq!(v.take_request([99, 99], [0.0, 0.0], 1, lod(1), 60.0), (false, None), "a LOD request once");
        assert_eq!(v.take_request([5, 6], [0.0, 0.0], 2, lod(1), 60.0), (true, None));
        assert_eq!((v.centre, v.velocity), ([5, 6], None), "no velocity: the engine follows the centre");
        v.velocity = Some([3, 3]);
        v.place([7, 8]);
        assert_eq!((v.centre, v.velocity), ([7, 8], None), "moved by the socket: the velocity is forgotten");
    }

    #[test]
    fn view_commands_add_move_weight_set_levels_and_remove_views_and_an_unknown_name_is_told_the_views_there_are() {
        let dir = tempfile::tempdir().unwrap();
        let (mut clipmap, mut views) = shared(dir.path());
        let mut stats = TickStats::default();
        let mut run = |views: &mut Views, clipmap: &mut Clipmap, cmd| views.command(clipmap, &mut stats, cmd);
        let add = ViewCommand::Add { name: "left".into(), weight: 2.0, own: false };
        assert_eq!(
            run(&mut views, &mut clipmap, add).unwrap(),
            Reply::ViewAdded { name: "left".into(), weight: 2.0, own: false }
        );
        let id = clipmap.view_named("left").unwrap();
        assert_eq!(views.views[&id].centre, [2048, 2048], "a new view starts where the primary is");
        let far = clipmap::limits::MAX_CENTRE;
        let centre = ViewCommand::Centre { name: "left".into(), centre: [i64::MAX, -5] };
        assert_eq!(
            run(&mut views, &mut clipmap, centre).unwrap(),
            Reply::ViewCentre { name: "left".into(), centre: [far, -5] },
            "bounded"
        );
        assert_eq!(views.views[&id].centre, [far, -5]);
        let main = ViewCommand::Centre { name: "main".into(), centre: [100, 200] };
        assert_eq!(
            run(&mut views, &mut clipmap, main).unwrap(),
            Reply::ViewCentre { name: "main".into(), centre: [100, 200] }
        );
        assert_eq!(views.primary_motion(), ([100, 200], None));
        let weight = ViewCommand::Weight { name: "left".into(), weight: 0.5 };
        assert_eq!(
            run(&mut views, &mut clipmap, weight).unwrap(),
            Reply::ViewWeight { name: "left".into(), weight: 0.5 }
        );
        assert_eq!(clipmap.view_weight(id).unwrap(), 0.5);
        let lod = ViewCommand::Lod { name: "left".into(), offset: 1, effective: None };
        let reply = run(&mut views, &mut clipmap, lod).unwrap();
        assert_eq!(reply, Reply::ViewLod { name: "left".into(), lod: LodWindow { offset: 1, effective: u32::MAX } });
        assert_eq!(clipmap.view_lod(id).unwrap().offset, 1);
        let remove = || ViewCommand::Remove { name: "left".into() };
        assert_eq!(run(&mut views, &mut clipmap, remove()).unwrap(), Reply::ViewRemoved { name: "left".into() });
        assert!(!views.views.contains_key(&id) && clipmap.view_named("left").is_none());
        let gone = run(&mut views, &mut clipmap, remove()).unwrap_err();
        assert!(matches!(&gone, Refusal::NoView { name, views } if name == "left" && views == &["main"]), "{gone}");
        let weight = ViewCommand::Weight { name: "left".into(), weight: 1.0 };
        assert!(matches!(run(&mut views, &mut clipmap, weight), Err(Refusal::NoView { .. })));
        assert_eq!(stats.socket_centres, 2);
    }
}

#[cfg(test)]
mod lonlat_tests {
    use super::*;

    #[test]
    fn a_lonlat_centre_is_the_texel_holding_the_point_and_its_lonlat_lands_there_again() {
        // WebMercatorQuad at zoom 2, 4-texel tiles: 16 texels a side, 22.5 degrees of longitude each.
        let g = Georef::web_mercator_quad(2, 4);
        assert_eq!(lonlat_centre(Some(&g), [0.0, 0.0]).unwrap(), [8, 8]);
        // Just west and south of the centre: the texel west and south of it (floor, not round).
        assert_eq!(lonlat_centre(Some(&g), [-1e-9, -1e-9]).unwrap(), [7, 7]);
        assert_eq!(lonlat_centre(Some(&g), [22.4, 0.1]).unwrap(), [8, 8]);
        assert_eq!(lonlat_centre(Some(&g), [22.6, 0.1]).unwrap(), [9, 8]);
        for c in [[0, 0], [8, 8], [15, 3], [3, 15]] {
            let ll = centre_lonlat(Some(&g), c).unwrap();
            assert_eq!(lonlat_centre(Some(&g), ll).unwrap(), c, "{ll:?}");
        }
        assert!((centre_lonlat(Some(&g), [8, 8]).unwrap()[0] - 11.25).abs() < 1e-9);
        assert_eq!(centre_lonlat(None, [8, 8]), None);
        assert_eq!(centre_lonlat(Some(&g), [16, 0]), None, "outside the texture");
    }

    #[test]
    fn a_lonlat_centre_is_refused_without_georeferencing_or_outside_the_domain() {
        assert!(matches!(lonlat_centre(None, [1.0, 2.0]), Err(Refusal::NoGeoref)));
        let e = lonlat_centre(Some(&Georef::web_mercator_quad(2, 4)), [10.0, 86.0]).unwrap_err().to_string();
        assert!(e.starts_with("CENTRE LONLAT 10 86: ") && e.contains("85.05"), "{e}");
        assert!(Refusal::NoGeoref.to_string().contains("no georeferencing"));
    }
}
