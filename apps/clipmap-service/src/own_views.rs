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
//! The service's views ([`super::views`]) own these grids as views of the shared grids are the
//! service's clipmap's: the tick loop ticks each after the primary, and every command for such a
//! view goes to its own clipmap.

use super::protocol::Refusal;
use clipmap::clip::{Clipmap, LodWindow, Settings, PRIMARY};
use clipmap::shm::layout::{self, views::own_mapping_name};
use clipmap::shm::{Client, Freshness, FromMapping, Writer, WriterOptions};
use clipmap::source::TileSource;
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
    /// The georef block, the primary's.
    pub(super) georef: Option<clipmap::shm::GeorefBlock>,
    pub(super) effective_levels: Option<u32>,
    /// The service's mapping: an own view's clipmap takes the tiles its slots hold from there
    /// ([`FromMapping`]) rather than reading them again.
    pub(super) main_mapping: PathBuf,
    /// What of the service's mapping is of the texels the source serves now, as the primary's
    /// clipmap said at its last tick ([`super::views::Views::tick_own`]): only such tiles are
    /// taken from it.
    pub(super) fresh: Arc<Freshness>,
    /// The service's generation (its mapping's header offset 80): every own mapping carries it,
    /// which ties it to this start of the service.
    pub(super) generation: u64,
}

/// A view's grids of its own: its clipmap over the source and its mapping
/// (`clipmap-SERVICE@NAME.map`). The view itself, its centre and requests, is a
/// [`super::views::View`].
pub(super) struct OwnGrids {
    pub(super) clipmap: Clipmap,
    pub(super) writer: Writer,
    /// Its source, taking tiles from the service's mapping (`None`: that could not be read).
    from_mapping: Option<Arc<FromMapping>>,
}

impl OwnGrids {
    /// Creates view `name`'s clipmap and mapping, published under its name. The caller then
    /// gives the view its record in the service's mapping.
    pub(super) fn new(s: &Setup, name: &str) -> Result<OwnGrids, Refusal> {
        let own = own_mapping_name(&s.service, name);
        let shape = Clipmap::shape_for(s.source.desc(), &s.settings);
        let mut writer = Writer::prepare(
            WriterOptions::new(&s.dir, &own, shape, s.source.desc().format())
                .mode(s.shm_mode)
                .request_mode(s.request_mode)
                .tick_period_ns(s.period_ns)
                .heights(s.heights)
                .georef(s.georef.clone()),
        )
        .map_err(|source| Refusal::OwnMapping { name: name.to_string(), mapping: own.clone(), source })?;
        if let Err(source) = writer.adopt_generation(s.generation).and_then(|()| writer.publish()) {
            writer.close();
            return Err(Refusal::OwnMapping { name: name.to_string(), mapping: own, source });
        }
        let from_mapping = s.shared_tiles(name);
        let source: Arc<dyn TileSource> = match &from_mapping {
            Some(f) => f.clone(),
            None => Arc::clone(&s.source),
        };
        let mut clipmap = match Clipmap::with_memory(source, s.settings.clone(), writer.memory()) {
            Ok(c) => c,
            Err(source) => {
                writer.close();
                return Err(Refusal::OwnGrids { name: name.to_string(), source });
            }
        };
        if let Some(e) = s.effective_levels {
            let _ = clipmap.set_view_lod(PRIMARY, LodWindow { offset: 0, effective: e });
        }
        tracing::info!(view = %name, mapping = %writer.path().display(), "view with grids of its own added");
        Ok(OwnGrids { clipmap, writer, from_mapping })
    }

    /// Tiles this view took from the service's mapping.
    pub(super) fn shared_reads(&self) -> u64 {
        self.from_mapping.as_ref().map_or(0, |f| f.hits())
    }

    /// Closes its mapping (marked shut down, names removed).
    pub(super) fn close(self) {
        self.writer.close();
    }
}

impl Setup {
    /// The source of view `name`'s grids: the tiles the primary's grids hold (the coarse levels
    /// at least) are taken from the service's mapping (`None`: it cannot be read; every tile is
    /// read from the source).
    fn shared_tiles(&self, name: &str) -> Option<Arc<FromMapping>> {
        match Client::attach_path(&self.main_mapping) {
            Ok(main) => Some(Arc::new(FromMapping::following(Arc::clone(&self.source), main, Arc::clone(&self.fresh)))),
            Err(e) => {
                tracing::warn!(view = %name, "the service's own mapping cannot be read ({e}): every tile of the view is read from the source");
                None
            }
        }
    }
}

#[cfg(test)]
mod tests;
