//! What a renderer's request does to a clipmap, for the primary's mapping and the mappings of
//! views with grids of their own alike ([`super::views`]): its velocity in
//! texels a tick, and its LOD request applied to a view.

use super::protocol::Refusal;
use super::stats::TickStats;
use clipmap::clip::{Clipmap, ViewId};
use clipmap::georef::GeorefError;

/// Applies a renderer's LOD request for view `id` of `clipmap` (named `name`; docs/SHM.md,
/// "Asking for a view's levels"): its footprint moves the view's LOD offset, its effective levels
/// bound the window. A request whose numbers are unusable is refused with a warning naming the
/// view and the field, and counted in `stats`.
pub(super) fn apply_lod(
    clipmap: &mut Clipmap,
    id: ViewId,
    name: &str,
    req: &clipmap::shm::writer::LodRequest,
    stats: &mut TickStats,
) -> Result<clipmap::clip::LodWindow, Refusal> {
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
    clipmap.set_view_lod(id, clipmap::clip::LodWindow { effective, ..lod })?;
    let offset = clipmap.set_view_footprint(id, footprint)?;
    stats.lod_requests += 1;
    tracing::debug!(view = %name, offset, footprint, "LOD request");
    Ok(clipmap::clip::LodWindow { offset, effective })
}

/// A request's velocity (level-0 texels per second, docs/SHM.md "What the service does with a
/// request") as the engine takes it: divided by the tick rate `hz` and rounded to texels per tick,
/// clamped to `MAX_TEXTURE_SIZE` (2^30) a tick, NaN and infinities read as 0. `None` when both
/// are 0: the engine then uses the centre's change since the last tick. Anything a renderer (or a
/// member of the mapping's group) wrote is bounded here, before the engine does arithmetic with it.
pub(super) fn velocity_per_tick(velocity: [f64; 2], hz: f64) -> Option<[i64; 2]> {
    let max = clipmap::source::MAX_TEXTURE_SIZE as f64;
    let per_tick = |v: f64| if v.is_finite() { (v / hz).round().clamp(-max, max) as i64 } else { 0 };
    let v = velocity.map(per_tick);
    (v != [0, 0]).then_some(v)
}

/// A centre asked for (a request, `CENTRE`, `VIEW CENTRE`) as every clipmap takes it: each
/// component bounded to `-2^40..=2^40` (docs/SHM.md, "Centres"). The socket's reply echoes this,
/// the centre the snapshot will publish (reached at once, or by `--max-centre-step` steps).
pub(super) fn bounded_centre(c: [i64; 2]) -> [i64; 2] {
    let far = clipmap::limits::MAX_CENTRE;
    c.map(|x| x.clamp(-far, far))
}

/// Why a renderer's request for a centre by position was refused ([`request_centre`]): what was
/// found and what is expected. Its text goes to the log and to STATS
/// (`position_request_refused`).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub(super) enum PositionRefused {
    /// A coordinate is NaN or infinite.
    #[error("{what} ({}, {}): expected finite numbers", .xy[0], .xy[1])]
    NotFinite {
        /// Which coordinates: `longitude / latitude` or `map coordinates`.
        what: &'static str,
        /// The coordinates given.
        xy: [f64; 2],
    },
    /// A position on a texture without georeferencing.
    #[error(
        "the texture has no georeferencing (only GeoTIFFs / COGs with georeferencing tags, tile pyramids and procedural textures served with --georef have it; docs/GEOREF.md): give the centre in level-0 texels (coordinate kind 0)"
    )]
    NoGeoref,
    /// A longitude / latitude outside the texture or the projection's domain.
    #[error("longitude / latitude ({}, {}): {source}", .lonlat[0], .lonlat[1])]
    LonLat {
        /// The position given.
        lonlat: [f64; 2],
        /// Why the georeferencing refused it.
        source: GeorefError,
    },
    /// Map coordinates outside the texture.
    #[error("map ({}, {}) in {crs}: {source}", .xy[0], .xy[1])]
    Map {
        /// The position given.
        xy: [f64; 2],
        /// The texture's CRS, by name.
        crs: String,
        /// Why the georeferencing refused it.
        source: GeorefError,
    },
    /// A coordinate kind the layout does not define.
    #[error(
        "coordinate kind {0}: expected 0 (level-0 texels), 1 (WGS 84 longitude / latitude) or 2 (map coordinates of the texture's CRS)"
    )]
    UnknownKind(u64),
}

/// The level-0 centre a renderer's request asks for (docs/SHM.md, "Positions in longitude /
/// latitude or map coordinates"): its texel centre, or its position converted through the
/// texture's `georef` to the texel that holds it (as `CENTRE LONLAT` does), bounded as every
/// centre is. Refused, with what was found and what is expected: a position on a texture
/// without georeferencing, one outside the texture or the projection's domain, a coordinate
/// that is not a finite number, an unknown coordinate kind.
pub(super) fn request_centre(
    georef: Option<&clipmap::georef::Georef>,
    centre: [i64; 2],
    position: clipmap::shm::writer::Position,
) -> Result<[i64; 2], PositionRefused> {
    use clipmap::shm::writer::Position;
    let finite = |what: &'static str, xy: [f64; 2]| {
        if xy.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(PositionRefused::NotFinite { what, xy })
        }
    };
    let c = match position {
        Position::Texels => centre,
        Position::LonLat(ll) => {
            finite("longitude / latitude", ll)?;
            let g = georef.ok_or(PositionRefused::NoGeoref)?;
            let [s, t] = g.lonlat_to_texel(0, ll).map_err(|source| PositionRefused::LonLat { lonlat: ll, source })?;
            [s.floor() as i64, t.floor() as i64]
        }
        Position::Map(xy) => {
            finite("map coordinates", xy)?;
            let g = georef.ok_or(PositionRefused::NoGeoref)?;
            let [s, t] =
                g.map_to_texel(0, xy).map_err(|source| PositionRefused::Map { xy, crs: g.crs().name(), source })?;
            [s.floor() as i64, t.floor() as i64]
        }
        Position::Unknown(kind, _) => return Err(PositionRefused::UnknownKind(kind)),
    };
    Ok(bounded_centre(c))
}

#[cfg(test)]
mod tests {
    use super::request_centre;
    use clipmap::georef::Georef;
    use clipmap::shm::writer::Position;

    /// docs/SHM.md, "Positions in longitude / latitude or map coordinates": each coordinate kind
    /// lands on the texel that holds the point, as `CENTRE LONLAT` does; each refusal says why.
    #[test]
    fn a_requests_position_is_converted_through_the_georeferencing_or_refused_with_why() {
        // WebMercatorQuad at zoom 2, 4-texel tiles: 16 texels a side, 22.5 degrees of longitude each.
        let g = Georef::web_mercator_quad(2, 4);
        let at = |p| request_centre(Some(&g), [3, 4], p);
        assert_eq!(at(Position::Texels), Ok([3, 4]), "texels: the request's own centre");
        assert_eq!(at(Position::LonLat([0.0, 0.0])), Ok([8, 8]));
        assert_eq!(at(Position::LonLat([-1e-9, -1e-9])), Ok([7, 7]), "the texel that holds the point");
        assert_eq!(at(Position::LonLat([22.6, 0.1])), Ok([9, 8]));
        let texel = 2.0 * 20037508.342789244 / 16.0;
        assert_eq!(at(Position::Map([0.0, 0.0])), Ok([8, 8]));
        assert_eq!(
            at(Position::Map([-20037508.342789244 + 2.5 * texel, -20037508.342789244 + 0.5 * texel])),
            Ok([2, 0])
        );
        let refused = |p| at(p).unwrap_err().to_string();
        let e = refused(Position::LonLat([10.0, 86.0]));
        assert!(e.starts_with("longitude / latitude (10, 86): ") && e.contains("85.05"), "{e}");
        let e = refused(Position::Map([0.0, 3e7]));
        assert!(e.starts_with("map (0, 30000000) in EPSG:3857") && e.contains("outside level 0"), "{e}");
        let e = refused(Position::LonLat([f64::NAN, 0.0]));
        assert!(e.contains("expected finite numbers"), "{e}");
        let e = refused(Position::Unknown(7, [0.0, 0.0]));
        assert!(e.starts_with("coordinate kind 7: expected 0 (level-0 texels), 1"), "{e}");
        let e = request_centre(None, [3, 4], Position::LonLat([0.0, 0.0])).unwrap_err();
        assert_eq!(e, super::PositionRefused::NoGeoref);
        let e = e.to_string();
        assert!(e.contains("no georeferencing") && e.contains("coordinate kind 0"), "{e}");
        assert_eq!(request_centre(None, [3, 4], Position::Texels), Ok([3, 4]), "texels need no georeferencing");
        assert_eq!(
            request_centre(None, [i64::MAX, 0], Position::Texels),
            Ok([clipmap::limits::MAX_CENTRE, 0]),
            "bounded"
        );
    }
}
