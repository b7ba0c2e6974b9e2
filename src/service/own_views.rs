//! Views with grids of their own (docs/VIEWS.md, "Views far apart"): a view that flies far from
//! the others is held by a clipmap of its own over the same source, published as `main` of a
//! mapping of its own, `NAME@VIEW` beside the service's (docs/SHM.md, "A view with grids of its
//! own"). The service's mapping keeps the view's record (state 2: its name, weight and
//! incarnation), so readers find it by name as any view and follow it there.
//!
//! Why: one set of grids that holds views far apart must span all of them (a view spread of the
//! distance between them: gigabytes for views a texture apart), while grids of their own cost each
//! such view one view's mapping. Each own clipmap has its own read queues, so the source serves
//! the grid sets side by side (each has the same reads in flight) rather than one set's
//! read-ahead before another's window.
//!
//! The tick loop ([`super::ticker`]) owns these clipmaps as it owns the primary one, ticks each
//! after the primary, and routes every command for such a view here by name.

use super::stats::TickStats;
use crate::clip::{Clipmap, LodWindow, Settings, PRIMARY};
use crate::shm::layout::{self, views::own_mapping_name};
use crate::shm::{Client, Freshness, FromMapping, Writer, WriterOptions};
use crate::source::{TileId, TileSource};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

/// What a new own view's clipmap and mapping are made of: the primary's.
pub(super) struct Setup {
    pub(super) source: Arc<dyn TileSource>,
    pub(super) settings: Settings,
    pub(super) dir: PathBuf,
    pub(super) service: String,
    pub(super) shm_mode: u32,
    pub(super) request_mode: u32,
    pub(super) period_ns: u64,
    pub(super) heights: Option<layout::Heights>,
    pub(super) effective_levels: Option<u32>,
    /// The service's mapping: an own view's clipmap takes the tiles its slots hold from there
    /// ([`FromMapping`]) rather than reading them again.
    pub(super) main_mapping: PathBuf,
    /// What of the service's mapping is of the texels the source serves now, as the primary's
    /// clipmap said at its last tick ([`OwnViews::tick`]): only such tiles are taken from it.
    pub(super) fresh: Arc<Freshness>,
    /// The service's generation (its mapping's header offset 80): every own mapping carries it,
    /// which ties it to this start of the service.
    pub(super) generation: u64,
}

/// One view with grids of its own.
pub(super) struct OwnView {
    pub(super) clipmap: Clipmap,
    writer: Writer,
    /// Its source, taking tiles from the service's mapping (`None`: that could not be read).
    from_mapping: Option<Arc<FromMapping>>,
    pub(super) centre: [i64; 2],
    pub(super) velocity: Option<[i64; 2]>,
    last_request: u64,
    last_lod: u64,
}

impl OwnView {
    /// Tiles this view took from the service's mapping.
    pub(super) fn shared_reads(&self) -> u64 {
        self.from_mapping.as_ref().map_or(0, |f| f.hits())
    }
}

/// Every view with grids of its own, by name.
pub(super) struct OwnViews {
    setup: Setup,
    views: BTreeMap<String, OwnView>,
}

impl OwnViews {
    pub(super) fn new(setup: Setup) -> OwnViews {
        OwnViews { setup, views: BTreeMap::new() }
    }

    /// Creates view `name`'s clipmap and mapping (`clipmap-SERVICE@NAME.map`), centred at
    /// `centre`. The caller has given the view its record in the service's mapping.
    pub(super) fn add(&mut self, name: &str, centre: [i64; 2]) -> Result<(), String> {
        let s = &self.setup;
        let own = own_mapping_name(&s.service, name);
        let shape = Clipmap::shape_for(s.source.desc(), &s.settings);
        let mut writer = Writer::prepare(
            WriterOptions::new(&s.dir, &own, shape, s.source.desc().format())
                .mode(s.shm_mode)
                .request_mode(s.request_mode)
                .tick_period_ns(s.period_ns)
                .heights(s.heights),
        )
        .map_err(|e| format!("view {name}: its own mapping {own}: {e}"))?;
        if let Err(e) = writer.adopt_generation(s.generation).and_then(|()| writer.publish()) {
            writer.close();
            return Err(format!("view {name}: its own mapping {own}: {e}"));
        }
        // Tiles the primary's grids hold (the coarse levels at least) are taken from them.
        let from_mapping = match Client::attach_path(&s.main_mapping) {
            Ok(main) => Some(Arc::new(FromMapping::following(Arc::clone(&s.source), main, Arc::clone(&s.fresh)))),
            Err(e) => {
                tracing::warn!(view = %name, "the service's own mapping cannot be read ({e}): every tile of the view is read from the source");
                None
            }
        };
        let source: Arc<dyn TileSource> = match &from_mapping {
            Some(f) => f.clone(),
            None => Arc::clone(&s.source),
        };
        let mut clipmap = match Clipmap::with_memory(source, s.settings.clone(), writer.memory()) {
            Ok(c) => c,
            Err(e) => {
                writer.close();
                return Err(format!("view {name}: its own grids: {e}"));
            }
        };
        if let Some(e) = s.effective_levels {
            let _ = clipmap.set_view_lod(PRIMARY, LodWindow { offset: 0, effective: e });
        }
        tracing::info!(view = %name, mapping = %writer.path().display(), "view with grids of its own added");
        self.views.insert(
            name.to_string(),
            OwnView { clipmap, writer, from_mapping, centre, velocity: None, last_request: 0, last_lod: 0 },
        );
        Ok(())
    }

    /// The service's mapping is under its name `path` now: views added from now on take tiles
    /// from it there (those added before keep the mapping they opened), and every own mapping's
    /// heartbeat is beaten (its views may have been made a while before).
    pub(super) fn published(&mut self, path: &std::path::Path) {
        self.setup.main_mapping = path.to_path_buf();
        for v in self.views.values() {
            v.writer.heartbeat();
        }
    }

    /// Removes view `name`'s clipmap and closes its mapping (marked shut down, names removed).
    pub(super) fn remove(&mut self, name: &str) -> bool {
        match self.views.remove(name) {
            Some(v) => {
                v.writer.close();
                true
            }
            None => false,
        }
    }

    pub(super) fn get_mut(&mut self, name: &str) -> Option<&mut OwnView> {
        self.views.get_mut(name)
    }

    pub(super) fn get(&self, name: &str) -> Option<&OwnView> {
        self.views.get(name)
    }

    /// Whether a renderer made a new request in any own mapping (the loop then ticks early).
    pub(super) fn requests_changed(&self) -> bool {
        self.views.values().any(|v| v.writer.request_count() != v.last_request)
    }

    /// Says that the source's texels of `tiles` changed (a growing texture's patch): every own
    /// view reads those it holds again, as the primary does ([`Clipmap::refresh`]).
    pub(super) fn refresh(&mut self, tiles: &[TileId]) {
        for v in self.views.values_mut() {
            v.clipmap.refresh(tiles.iter().copied());
        }
    }

    /// Whether any own view holds `tile`.
    pub(super) fn holds(&self, tile: TileId) -> bool {
        self.views.values().any(|v| v.clipmap.holds(tile))
    }

    /// One tick of every own view, after the primary's (`primary`): first what of the service's
    /// mapping may be taken now (the source version the primary followed, the tiles it is still
    /// replacing), then for each view its newest request (centre, velocity, levels), its
    /// engine's tick, its heartbeat.
    ///
    /// The service's mapping (`service`) says it is alive after each view's tick: a tick of
    /// many views is many pieces of work, and its heartbeat time stands still for the longest
    /// of them only.
    pub(super) fn tick(&mut self, primary: &Clipmap, service: &Writer, hz: f64, stats: &mut TickStats) {
        self.setup.fresh.set(primary.followed_version(), primary.tiles_being_replaced());
        for (name, v) in self.views.iter_mut() {
            if let Some(req) = v.writer.request() {
                if req.count != v.last_request {
                    v.last_request = req.count;
                    v.centre = req.centre;
                    v.velocity = super::requests::velocity_per_tick(req.velocity, hz);
                }
                if let Some(lod) = req.lod.filter(|l| l.count != v.last_lod) {
                    v.last_lod = lod.count;
                    let _ = super::requests::apply_lod(&mut v.clipmap, PRIMARY, name, &lod, stats);
                }
            }
            v.clipmap.tick(v.centre, v.velocity);
            v.writer.heartbeat();
            service.alive();
        }
    }

    /// Every own mapping says it is alive (after a long command: a view added).
    pub(super) fn alive(&self) {
        for v in self.views.values() {
            v.writer.alive();
        }
    }

    /// Bytes of tiles every own view holds.
    pub(super) fn resident_bytes(&self) -> u64 {
        self.views.values().map(|v| v.clipmap.resident_bytes()).sum()
    }

    /// Closes every own mapping (the service stops).
    pub(super) fn close_all(&mut self) {
        for (_, v) in std::mem::take(&mut self.views) {
            v.writer.close();
        }
    }
}

#[cfg(test)]
mod tests;
