//! What a renderer's request does to a clipmap, for the primary's mapping and the mappings of
//! views with grids of their own alike ([`super::views`]): its velocity in
//! texels a tick, and its LOD request applied to a view.

use super::protocol::Refusal;
use super::stats::TickStats;
use crate::clip::{Clipmap, ViewId};

/// Applies a renderer's LOD request for view `id` of `clipmap` (named `name`; docs/SHM.md,
/// "Asking for a view's levels"): its footprint moves the view's LOD offset, its effective levels
/// bound the window. A request whose numbers are unusable is refused with a warning naming the
/// view and the field, and counted in `stats`.
pub(super) fn apply_lod(
    clipmap: &mut Clipmap,
    id: ViewId,
    name: &str,
    req: &crate::shm::writer::LodRequest,
    stats: &mut TickStats,
) -> Result<crate::clip::LodWindow, Refusal> {
    let footprint = match req.footprint() {
        Ok(f) => f,
        Err(why) => {
            stats.lod_requests_refused += 1;
            tracing::warn!(view = %name, "LOD request refused: {why}");
            return Err(Refusal::LodRequest { name: name.to_string(), why });
        }
    };
    let effective = if req.effective == 0 { u32::MAX } else { req.effective as u32 };
    let lod = clipmap.view_lod(id)?;
    clipmap.set_view_lod(id, crate::clip::LodWindow { effective, ..lod })?;
    let offset = clipmap.set_view_footprint(id, footprint)?;
    stats.lod_requests += 1;
    tracing::debug!(view = %name, offset, footprint, "LOD request");
    Ok(crate::clip::LodWindow { offset, effective })
}

/// A request's velocity (level-0 texels per second, docs/SHM.md "What the service does with a
/// request") as the engine takes it: divided by the tick rate `hz` and rounded to texels per tick,
/// clamped to `MAX_TEXTURE_SIZE` (2^26) a tick, NaN and infinities read as 0. `None` when both
/// are 0: the engine then uses the centre's change since the last tick. Anything a renderer (or a
/// member of the mapping's group) wrote is bounded here, before the engine does arithmetic with it.
pub(super) fn velocity_per_tick(velocity: [f64; 2], hz: f64) -> Option<[i64; 2]> {
    let max = crate::source::MAX_TEXTURE_SIZE as f64;
    let per_tick = |v: f64| if v.is_finite() { (v / hz).round().clamp(-max, max) as i64 } else { 0 };
    let v = velocity.map(per_tick);
    (v != [0, 0]).then_some(v)
}

/// A centre asked for (a request, `CENTRE`, `VIEW CENTRE`) as every clipmap takes it: each
/// component bounded to `-2^40..=2^40` (docs/SHM.md, "Centres"). The socket's reply echoes this,
/// the centre the snapshot will publish (reached at once, or by `--max-centre-step` steps).
pub(super) fn bounded_centre(c: [i64; 2]) -> [i64; 2] {
    let far = crate::limits::MAX_CENTRE;
    c.map(|x| x.clamp(-far, far))
}
