//! `cliptex plan`: memory of a clipmap against the full mipmap, the stack/pyramid split, update
//! bandwidth, clip-size recommendations for a display, and virtual-level parameters.

use super::human_bytes;
use crate::sizing::{self, Memory, SizingError, VirtualInputs, VirtualParams};
use serde::Serialize;

/// What the user asked for.
#[derive(Clone, Debug)]
pub struct Request {
    /// Texture size (texels, S and T; powers of two).
    pub size: [u64; 2],
    /// Clip size.
    pub clip: u64,
    /// Bytes per texel.
    pub texel_bytes: u64,
    /// Display width in pixels, for recommendations.
    pub display: Option<u64>,
    /// Horizontal field of view (degrees).
    pub fov_deg: f64,
    /// Centre speed in level-0 texels per second.
    pub speed: Option<f64>,
    /// Eye height in metres, for the virtual-level parameters.
    pub eye_height: Option<f64>,
    /// Metres per level-0 texel.
    pub texel_metres: f64,
    /// 0 keeps resolution, 1 keeps area (Performer's tradeoff).
    pub tradeoff: f64,
    /// Invalid border.
    pub invalid_border: u64,
    /// The `.ct` the sizes came from (`cliptex plan FILE.ct`).
    pub from: Option<std::path::PathBuf>,
    /// Tile size of the stack levels (texels, square), for the image caches.
    pub tile: u64,
    /// Spare tile rows and columns each stack level's grid keeps beyond its window (fixed
    /// grids), or `None`: the grids the default adaptive policy sizes from its default budget.
    pub lookahead: Option<u64>,
    /// The texels are heights: the mapping also holds each level's tile ranges (16 bytes a
    /// slot, page-rounded; docs/SHM.md).
    pub heights: bool,
    /// Level-0 texels views may lie apart and be held whole (`clipmapd --view-spread`; 0: none).
    pub view_spread: u64,
    /// Views with grids of their own (`clipmapd --view NAME:W:own`; docs/VIEWS.md, "Views far
    /// apart"): each a mapping of one view's grids beside the service's.
    pub own_views: u64,
    /// The block format the service publishes (`clipmapd --format`): the image caches hold
    /// tiles of 4 x 4 blocks instead of `texel_bytes` texels (docs/SHM.md).
    pub format: Option<crate::texel::Bc>,
    /// The texture spans 360 degrees of longitude (a global COG, a `.ct` whose georeferencing
    /// does, `--global`): its levels wider than the clip wrap, their grids widened to a divisor
    /// of their tiles across as the engine widens them (docs/GEOREF.md, "The antimeridian").
    pub global: bool,
}

/// The image caches the engine and `clipmapd` keep (layout 2): every stack level a grid of whole
/// tiles, every pyramid level whole, a tag per slot and the header, as the mapping lays them out.
#[derive(Clone, Debug, Serialize)]
pub struct ImageCaches {
    /// Stack levels' tile size (clamped to each level).
    pub tile_size: u64,
    /// Spare tile rows and columns beyond the window (1 under the adaptive policy: its budget
    /// is counted from the lookahead-1 grids).
    pub lookahead: u64,
    /// `adaptive` (the default: grids sized from the budget) or `fixed` (`--lookahead` given).
    pub grids: &'static str,
    /// The adaptive grids' budget, bytes of slots (null for fixed grids).
    pub grid_budget_bytes: Option<u64>,
    /// Level-0 texels further views may lie apart and still be held whole (`--view-spread`;
    /// 0: grids for one view): every level's grid is the engine's for this spread.
    pub view_spread: u64,
    /// Level 0's grid of slots (tiles across, down).
    pub level0_grid: [u64; 2],
    /// The block format the slots hold (`bc1`, ...; `cliptex plan --format`), absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub format: Option<String>,
    /// With a block format: how level 0's slot bytes follow from its tile, `ceil(W / 4) x
    /// ceil(H / 4) blocks x B bytes = N`; every slot of the mapping is sized so, and `bytes` is
    /// the sum over the grids, page-rounded, plus the header.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub slot_formula: Option<String>,
    /// Bytes of the slots (the texels).
    pub slot_bytes: u64,
    /// Bytes of the whole mapping (slots, tags, tile ranges, header, page rounding).
    pub bytes: u64,
    /// Bytes of the levels' tile ranges (a height texture: 16 a slot, each level's page-rounded;
    /// 0 otherwise), included in `bytes`.
    pub tile_range_bytes: u64,
    /// Bytes of the views block (one record for each further view the service may keep;
    /// docs/VIEWS.md), included in `bytes`: the only cost of views that share the grids.
    pub views_block_bytes: u64,
    /// Views with grids of their own (`--own-views`; docs/VIEWS.md, "Views far apart").
    pub own_views: u64,
    /// Bytes of one such view's mapping (`clipmap-NAME@VIEW.map`: one view's grids, never
    /// widened), 0 without such views.
    pub own_view_bytes: u64,
    /// Bytes of every mapping together: `bytes + own_views x own_view_bytes`.
    pub all_bytes: u64,
    /// The levels that wrap in longitude (a global texture: [`Request::global`]), whose grid
    /// widths the engine raises to a divisor of their tiles across; empty otherwise.
    pub wrapping_levels: Vec<u32>,
}

/// The answer.
#[derive(Clone, Debug, Serialize)]
pub struct Plan {
    /// The `.ct` the sizes came from, when one was given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub from: Option<std::path::PathBuf>,
    /// Texture size: the longer side (the side, for a square texture).
    pub size: u64,
    /// Clip size used (clamped to the size).
    pub clip_size: u64,
    /// Bytes per texel.
    pub texel_bytes: u64,
    /// Levels in all.
    pub levels: u32,
    /// Memory figures.
    #[serde(flatten)]
    pub memory: Memory,
    /// Update bandwidth, when a speed was given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub update: Option<Update>,
    /// Recommendations, when a display width was given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub display: Option<Display>,
    /// Virtual-level parameters, when an eye height was given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub virtual_levels: Option<VirtualParams>,
    /// What the engine would hold (`null` when it cannot serve the texture: larger than 2^30
    /// texels a side, or more levels than a mapping describes).
    pub image_caches: Option<ImageCaches>,
    /// Why there are no image caches (absent when there are).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub no_image_caches: Option<String>,
}

/// The texel format the image caches are sized with: any of `bytes` bytes a texel (the grids and
/// the mapping depend on the bytes alone), `None` when no texel format has that many.
fn format_of(bytes: u64) -> Option<crate::texel::TexelFormat> {
    use crate::texel::{ComponentType, Components, TexelFormat};
    let components = [Components::One, Components::Two, Components::Three, Components::Four];
    [(ComponentType::U8, 1), (ComponentType::U16, 2), (ComponentType::F32, 4)].into_iter().find_map(|(ctype, b)| {
        let n = components.iter().find(|c| u64::from(c.count()) * b == bytes)?;
        Some(TexelFormat { components: *n, ctype })
    })
}

/// The image caches of a `size` texture with clip size `clip` (layout 2), as `clipmapd` maps them
/// for a procedural source: the grids are the engine's own (`Clipmap::grids`) under the settings
/// the options give: `lookahead` fixed grids, without it the adaptive policy's grids from its
/// default budget, each widened for views up to `view_spread` level-0 texels apart
/// (`Settings::view_spread`). `Err` says why the engine cannot lay them out.
#[allow(clippy::too_many_arguments)] // the plan's inputs, each a number of its own
pub fn image_caches(
    size: [u64; 2],
    clip: u64,
    texel_bytes: u64,
    tile: u64,
    lookahead: Option<u64>,
    heights: bool,
    view_spread: u64,
    block: Option<crate::texel::Bc>,
    global: bool,
) -> Result<ImageCaches, String> {
    use crate::clip::{Clipmap, Settings};
    use crate::paging::PrefetchKind;
    let format = match block {
        Some(bc) => bc.format(),
        None => format_of(texel_bytes)
            .ok_or_else(|| format!("no texel format has {texel_bytes} bytes: expected 1, 2, 3, 4, 6, 8, 12 or 16"))?,
    };
    let texel_bytes = u64::from(format.bytes_per_texel());
    let desc = crate::source::TextureDesc::new(size, clip, format, [tile, tile]).map_err(|e| e.to_string())?;
    let settings = Settings {
        lookahead: lookahead.unwrap_or(1),
        prefetch: if lookahead.is_some() { PrefetchKind::Ring } else { PrefetchKind::Adaptive },
        view_spread,
        wrap_longitude: global,
        ..Settings::default()
    };
    if view_spread > crate::limits::MAX_TEXTURE_SIZE {
        return Err(format!(
            "--view-spread {view_spread}: expected 0 to {} level-0 texels",
            crate::limits::MAX_TEXTURE_SIZE
        ));
    }
    let grids = Clipmap::grids(&desc, &settings);
    let shape = crate::clip::memory_shape(&desc, &grids);
    let level0_grid = grids[0];
    use crate::shm::layout::{check_level, place_with, views::SERVICE_RECORDS, with_views, MAX_LEVELS};
    if shape.levels.len() > MAX_LEVELS {
        return Err(format!("{} levels: a mapping describes at most {MAX_LEVELS}", shape.levels.len()));
    }
    for (k, l) in shape.levels.iter().enumerate() {
        check_level(l, clip, texel_bytes).map_err(|why| format!("level {k}: {why}"))?;
    }
    let placed = place_with(&shape, heights)
        .and_then(|p| with_views(p, SERVICE_RECORDS))
        .ok_or_else(|| "the mapping would be larger than 2^64 bytes".to_string())?;
    let tile_range_bytes = placed.levels.iter().map(|l| if l.ranges == 0 { 0 } else { l.slots - l.ranges }).sum();
    let [tw, th] = shape.levels[0].tile;
    let slot0 = placed.levels[0].slot_bytes;
    let slot_formula = block.map(|_| format!("ceil({tw} / 4) x ceil({th} / 4) blocks x {texel_bytes} bytes = {slot0}"));
    Ok(ImageCaches {
        format: block.map(|b| b.name().to_string()),
        slot_formula,
        tile_size: tile,
        lookahead: lookahead.unwrap_or(1),
        grids: if lookahead.is_some() { "fixed" } else { "adaptive" },
        grid_budget_bytes: Clipmap::grid_budget(&desc, &settings),
        view_spread,
        level0_grid,
        slot_bytes: placed.slot_bytes(),
        bytes: placed.total_bytes,
        tile_range_bytes,
        views_block_bytes: placed.total_bytes - placed.views,
        own_views: 0,
        own_view_bytes: 0,
        all_bytes: placed.total_bytes,
        wrapping_levels: (0..desc.level_count() as u32)
            .filter(|&k| Clipmap::level_wraps(&desc, &settings, k))
            .collect(),
    })
}

/// Update bandwidth at a centre speed.
#[derive(Clone, Debug, Serialize)]
pub struct Update {
    /// Level-0 texels per second of centre motion (one axis).
    pub speed: f64,
    /// Texels written into the windows per second.
    pub texels_per_second: f64,
    /// Bytes written into the windows per second.
    pub bytes_per_second: f64,
}

/// Recommendations for a display.
#[derive(Clone, Debug, Serialize)]
pub struct Display {
    /// Display width.
    pub width: u64,
    /// The usual clip size (the width rounded up to a power of two).
    pub usual_clip: u64,
    /// The pixel-exact clip size (twice the usual).
    pub exact_clip: u64,
    /// Memory with the usual clip size.
    pub usual_bytes: u128,
    /// Memory with the pixel-exact clip size.
    pub exact_bytes: u128,
}

/// Computes the plan.
pub fn compute(r: &Request) -> Result<Plan, SizingError> {
    let [w, h] = r.size;
    let memory = sizing::memory_rect(w, h, r.clip, r.texel_bytes)?;
    let levels = memory.stack_levels + memory.pyramid_levels;
    let long = w.max(h);
    let update = r.speed.map(|speed| {
        let t = sizing::update_texels_per_second(&memory, speed);
        Update { speed, texels_per_second: t, bytes_per_second: t * r.texel_bytes as f64 }
    });
    let display = match r.display {
        Some(display) => {
            let (usual, exact) = sizing::recommended_clip(display);
            Some(Display {
                width: display,
                usual_clip: usual,
                exact_clip: exact,
                usual_bytes: sizing::memory_rect(w, h, usual.min(long), r.texel_bytes)?.clipmap_bytes,
                exact_bytes: sizing::memory_rect(w, h, exact.min(long), r.texel_bytes)?.clipmap_bytes,
            })
        }
        None => None,
    };
    let virtual_levels = r.eye_height.map(|h| {
        let lod = sizing::finest_lod_at_foot(h, r.fov_deg, r.display.unwrap_or(1024), r.texel_metres);
        sizing::virtual_params(&VirtualInputs {
            levels,
            clip_size: 1 << memory.log2_clip,
            invalid_border: r.invalid_border,
            min_lod_tex_pix: lod,
            min_lod_loaded: 0.0,
            max_lod_loaded: levels as f64,
            bbox_min_dist: 0.0,
            bbox_max_dist: 0.0,
            tradeoff: r.tradeoff,
        })
    });
    let clip = 1u64 << memory.log2_clip;
    let caches =
        |spread| image_caches(r.size, clip, r.texel_bytes, r.tile, r.lookahead, r.heights, spread, r.format, r.global);
    let (image_caches, no_image_caches) = match caches(r.view_spread) {
        Ok(mut ic) if r.own_views > 0 => {
            let own = caches(0).map_or(0, |o| o.bytes);
            ic.own_views = r.own_views;
            ic.own_view_bytes = own;
            ic.all_bytes = ic.bytes.saturating_add(own.saturating_mul(r.own_views));
            (Some(ic), None)
        }
        Ok(ic) => (Some(ic), None),
        Err(why) => (None, Some(why)),
    };

    Ok(Plan {
        image_caches,
        no_image_caches,
        from: r.from.clone(),
        size: long,
        clip_size: 1 << memory.log2_clip,
        texel_bytes: r.texel_bytes,
        levels,
        memory,
        update,
        display,
        virtual_levels,
    })
}

/// Groups digits in threes for reading.
pub(crate) fn grouped(v: u128) -> String {
    let s = v.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// The human form.
pub fn human(p: &Plan, r: &Request) -> String {
    let m = &p.memory;
    let mut o = String::new();
    if let Some(ct) = &p.from {
        o.push_str(&format!("from         {}\n", ct.display()));
    }
    let powers = if m.width == m.height {
        format!("2^{}", m.log2_size)
    } else {
        format!("2^{} x 2^{}", m.width.trailing_zeros(), m.height.trailing_zeros())
    };
    o.push_str(&format!(
        "texture      {} x {} texels ({powers}), {} levels, {} bytes per texel\n",
        m.width, m.height, p.levels, p.texel_bytes
    ));
    let first = m.stack_levels;
    let last = p.levels - 1;
    let (fw, fh) = (m.width >> first, m.height >> first);
    let (lw, lh) = (m.width >> last, m.height >> last);
    let c = p.clip_size;
    // A non-square stack level whose short side is below the clip size keeps that side whole.
    let window = if m.width == m.height { format!("a {c}x{c} window") } else { format!("at most a {c}x{c} window") };
    o.push_str(&format!(
        "clip size    {c}: {} stack level{} keep {window}; {} pyramid level{} ({fw}x{fh} down to {lw}x{lh}) stay whole\n",
        m.stack_levels,
        if m.stack_levels == 1 { "" } else { "s" },
        m.pyramid_levels,
        if m.pyramid_levels == 1 { "" } else { "s" },
    ));
    o.push_str(&format!("clipmap      {} texels, {}\n", grouped(m.clipmap_texels), human_bytes(m.clipmap_bytes)));
    match &p.image_caches {
        Some(ic) => o.push_str(&format!(
            "image caches {} mapped by clipmapd ({} of texels{}): {}-texel tiles, {}{}, level 0 a {}x{} grid of whole tiles, pyramid levels whole\n",
            human_bytes(ic.bytes as u128),
            human_bytes(ic.slot_bytes as u128),
            if ic.tile_range_bytes > 0 {
                format!(", {} of tile height ranges", human_bytes(ic.tile_range_bytes as u128))
            } else {
                String::new()
            },
            ic.tile_size,
            match ic.grid_budget_bytes {
                Some(b) => format!("adaptive grids within a budget of {} (twice lookahead 1)", human_bytes(b as u128)),
                None => format!("lookahead {}", ic.lookahead),
            },
            if ic.view_spread > 0 {
                format!(", widened for views up to {} level-0 texels apart (view spread)", ic.view_spread)
            } else {
                String::new()
            },
            ic.level0_grid[0],
            ic.level0_grid[1]
        )),
        None => o.push_str(&format!(
            "image caches none: the engine cannot serve this texture: {}\n",
            p.no_image_caches.as_deref().unwrap_or("unknown")
        )),
    }
    if let Some(ic) = p.image_caches.as_ref().filter(|ic| !ic.wrapping_levels.is_empty()) {
        let w = &ic.wrapping_levels;
        o.push_str(&format!(
            "             levels {} to {} wrap in longitude (a global texture): their grids are as wide as a divisor of their tiles across, counted above\n",
            w[0],
            w[w.len() - 1]
        ));
    }
    if let Some((f, formula)) =
        p.image_caches.as_ref().and_then(|ic| Some((ic.format.as_ref()?, ic.slot_formula.as_ref()?)))
    {
        o.push_str(&format!("slots        {f}: level 0's {formula}\n"));
    }
    if let Some(ic) = p.image_caches.as_ref().filter(|ic| ic.own_views > 0) {
        o.push_str(&format!(
            "own grids    {} view{} with grids of their own: a mapping of {} each beside the service's; all mappings {}\n",
            ic.own_views,
            if ic.own_views == 1 { "" } else { "s" },
            human_bytes(ic.own_view_bytes as u128),
            human_bytes(ic.all_bytes as u128)
        ));
    }
    o.push_str(&format!("full mipmap  {} texels, {}\n", grouped(m.mipmap_texels), human_bytes(m.mipmap_bytes)));
    o.push_str(&format!(
        "saving       the clipmap is 1/{:.0} of the mipmap\n",
        m.mipmap_texels as f64 / m.clipmap_texels as f64
    ));
    if let Some(u) = &p.update {
        o.push_str(&format!("update       at {} texels/s of centre motion: {:.3} Mtexel/s, {}/s of new texels entering the windows, read as whole tiles (diagonal motion up to twice)\n", u.speed, u.texels_per_second / 1e6, human_bytes(u.bytes_per_second as u128)));
    }
    if let Some(d) = &p.display {
        o.push_str(&format!("display      {} px wide: clip {} is the usual choice ({}), clip {} is pixel-exact with trilinear filtering ({})\n", d.width, d.usual_clip, human_bytes(d.usual_bytes), d.exact_clip, human_bytes(d.exact_bytes)));
    }
    if let Some(v) = &p.virtual_levels {
        o.push_str(&format!(
            "virtual      eye at {} m, {} m texels, {}° over {} px: levels {}..{} ({} effective from LOD offset {}), LOD range {:.2}..{:.2}\n",
            r.eye_height.unwrap_or(0.0),
            r.texel_metres,
            r.fov_deg,
            r.display.unwrap_or(1024),
            v.lod_offset,
            v.lod_offset + v.effective_levels - 1,
            v.effective_levels,
            v.lod_offset,
            v.min_lod,
            v.max_lod
        ));
    }
    o
}

/// A table of memory for several texture sizes with one clip size.
pub fn table(clip: u64, texel_bytes: u64, from_log2: u32, to_log2: u32) -> Result<(String, Vec<Memory>), SizingError> {
    let mut rows = Vec::new();
    let mut o =
        format!("{:>12} {:>7} {:>7} {:>14} {:>14} {:>10}\n", "size", "stack", "pyramid", "clipmap", "mipmap", "ratio");
    for n in from_log2..=to_log2 {
        let m = sizing::memory(1 << n, clip, texel_bytes)?;
        o.push_str(&format!(
            "{:>12} {:>7} {:>7} {:>14} {:>14} {:>10}\n",
            format!("2^{n}"),
            m.stack_levels,
            m.pyramid_levels,
            human_bytes(m.clipmap_bytes),
            human_bytes(m.mipmap_bytes),
            format!("1/{:.0}", m.mipmap_texels as f64 / m.clipmap_texels as f64)
        ));
        rows.push(m);
    }
    Ok((o, rows))
}
