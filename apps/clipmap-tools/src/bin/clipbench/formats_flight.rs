//! `clipbench formats`' real-time flight: `clipbench perf`'s 2^26 flight with every default
//! (`scale_default`: 1000 level-0 texels a tick along +s, 60 ticks a second, the default tick
//! budget, load control and adaptive paging, clip 2048, tiles of 256) over a pre-encoded BC1
//! texture, counting the ticks after the first second on which level 0 is published.
//!
//! The same flight over the same tiles in RGBA8, in the same run, says what the format changes.
//!
//! A 2^26 pyramid cannot be written to disk here, so the pre-encoded texture is the hash texture's
//! BC1 blocks encoded before the flight: per level, the blocks of its first 4 x 4 tiles (or all of
//! them, fewer), served by tile number modulo 4 along each axis. Its reads copy blocks into the
//! slots and encode nothing, as a pre-encoded pyramid's reads do (without the disk).

use clipmap::clip::Settings;
use clipmap::source::{BcQuality, BcSource, SourceError, TextureDesc, TileId, TileSource};
use clipmap::texel::Bc;
use clipmap_service::{procedural_source, Procedural};
use serde::Serialize;
use std::sync::Arc;

/// Pre-encoded blocks, per level: `tiles[level][(t % 4) * 4 + s % 4]` (fewer where the level has
/// fewer tiles, taken modulo its count).
struct PreEncoded {
    desc: TextureDesc,
    tiles: Vec<Vec<Vec<u8>>>,
    across: Vec<[u64; 2]>,
}

impl PreEncoded {
    /// `bc`'s blocks of the hash texture, or (`None`) its RGBA8 texels made before the flight
    /// likewise.
    fn new(bc: Option<Bc>, texture: u64, clip: u64, tile: u64) -> anyhow::Result<PreEncoded> {
        let hash = procedural_source(Procedural::Hash, texture, clip, tile)?;
        let blocks: Arc<dyn TileSource> = match bc {
            Some(bc) => Arc::new(BcSource::new(hash, bc, BcQuality::Normal)?),
            None => hash,
        };
        let desc = blocks.desc().clone();
        let (mut tiles, mut across) = (Vec::new(), Vec::new());
        for k in 0..desc.level_count() as u32 {
            let l = desc.level(k);
            let a = [l.size[0].div_ceil(l.tile[0]).min(4), l.size[1].div_ceil(l.tile[1]).min(4)];
            let mut level = Vec::new();
            for t in 0..a[1] {
                for s in 0..a[0] {
                    let mut out = vec![0u8; desc.tile_bytes(k)];
                    blocks.read_tile(TileId::new(k, s, t), &mut out)?;
                    level.push(out);
                }
            }
            tiles.push(level);
            across.push(a);
        }
        Ok(PreEncoded { desc, tiles, across })
    }
}

impl TileSource for PreEncoded {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        let k = tile.level as usize;
        let a = self.across[k];
        let from = &self.tiles[k][((tile.t % a[1]) * a[0] + tile.s % a[0]) as usize];
        if out.len() != from.len() {
            return Err(SourceError::BufferSize { tile, expected: from.len(), found: out.len() });
        }
        out.copy_from_slice(from);
        Ok(())
    }
}

/// What the flight measured (the fields of `clipbench perf`'s `scale_default` that say whether
/// level 0 kept up).
#[derive(Clone, Debug, Serialize)]
pub struct Flight {
    /// `bc1` (or `rgba8`, the same flight without block compression).
    pub format: &'static str,
    /// How the tiles were made (pre-encoded, see the module's documentation).
    pub source: &'static str,
    pub texture: u64,
    pub clip: u64,
    pub tile: u64,
    pub texels_per_tick: i64,
    pub tick_hz: f64,
    pub seconds: f64,
    pub ticks: u64,
    /// Share of the ticks after the first second on which level 0 is published (goal at least
    /// 0.99).
    pub level0_shown_share: f64,
    pub ticks_with_disabled_levels: u64,
    pub ticks_over_budget: u64,
    pub late_ticks: u64,
    pub mean_min_lod: f64,
    pub tick_p50_s: f64,
    pub tick_p99_s: f64,
    pub tiles_read_per_s: f64,
    /// CPU time of this process per second of the flight.
    pub cpu_cores_used: f64,
    /// Most bytes the image caches held (their whole mapping).
    pub peak_resident_bytes: u64,
}

/// Flies `seconds` in real time over the pre-encoded `bc` texture (`None`: the same tiles in
/// RGBA8, made before the flight likewise) with every default.
pub fn fly(bc: Option<Bc>, seconds: f64) -> anyhow::Result<Flight> {
    let (texture, clip, tile) = (1u64 << 26, 2048, 256);
    let source: Arc<dyn TileSource> = Arc::new(PreEncoded::new(bc, texture, clip, tile)?);
    let settings = Settings::default();
    let lookahead = settings.lookahead;
    let f = super::perf::fly_over(source, settings, lookahead, seconds)?;
    Ok(Flight {
        format: bc.map_or("rgba8", |b| b.name()),
        source: "the hash texture's tiles made (and encoded) before the flight, 4 x 4 a level",
        texture: f.texture,
        clip: f.clip,
        tile: f.tile,
        texels_per_tick: f.texels_per_tick,
        tick_hz: f.tick_hz,
        seconds: f.seconds,
        ticks: f.ticks,
        level0_shown_share: f.level0_shown_share,
        ticks_with_disabled_levels: f.ticks_with_disabled_levels,
        ticks_over_budget: f.ticks_over_budget,
        late_ticks: f.late_ticks,
        mean_min_lod: f.mean_min_lod,
        tick_p50_s: f.tick_p50_s,
        tick_p99_s: f.tick_p99_s,
        tiles_read_per_s: f.tiles_read_per_s,
        cpu_cores_used: f.cpu_cores_used,
        peak_resident_bytes: f.peak_resident_bytes,
    })
}
