//! The paging options every command that runs a clipmap shares (`clipmapd`, `cliptex roam`):
//! `--prefetch`, `--eviction`, `--pool-bytes`, `--max-centre-step`, `--grid-budget`, each overriding what a
//! configuration's paging extension says (docs/CONFIG.md §16).

use crate::paging::{parse_bytes, EvictionKind, PagingOptions, PrefetchKind};

/// `--prefetch`, `--eviction`, `--pool-bytes`, `--max-centre-step`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct PagingArgs {
    /// Where each level's tile grid puts its spare tiles: `adaptive` (the default: read-ahead
    /// sized each tick from the measured motion and read latency, in grids sized from
    /// `--grid-budget`), `ring` (around the window), `direction` (ahead, moved when the centre
    /// crosses a tile boundary) or `ahead` (ahead at every moving tick, the former placement).
    #[arg(long, value_name = "adaptive|ring|direction|ahead")]
    pub prefetch: Option<PrefetchKind>,
    /// Which tile the second-level pool gives up first: `lru` (least recently used; the
    /// default) or `shift` (farthest behind the direction of motion).
    #[arg(long, value_name = "lru|shift")]
    pub eviction: Option<EvictionKind>,
    /// Hard budget of the second-level tile pool kept in process memory beyond the grids, bytes
    /// (k, m, g suffixes: KiB, MiB, GiB); 0: no pool.
    #[arg(long, value_name = "BYTES", value_parser = parse_bytes)]
    pub pool_bytes: Option<u64>,
    /// Most level-0 texels the centre may move per tick along each axis (the offset clamp;
    /// counted as centre clamps when it acts).
    #[arg(long, value_name = "TEXELS", value_parser = clap::value_parser!(u64).range(1..))]
    pub max_centre_step: Option<u64>,
    /// Bytes the adaptive policy's grids may take, all levels together (k, m, g suffixes);
    /// default twice the bytes of lookahead-1 grids. Levels whose `.ic` fixes a mem region keep
    /// it. Ignored by the fixed policies.
    #[arg(long, value_name = "BYTES", value_parser = parse_bytes)]
    pub grid_budget: Option<u64>,
}

impl PagingArgs {
    /// The options: each given flag over `base` (the configuration's, or the defaults).
    pub fn over(&self, base: PagingOptions) -> PagingOptions {
        PagingOptions {
            prefetch: self.prefetch.unwrap_or(base.prefetch),
            eviction: self.eviction.unwrap_or(base.eviction),
            pool_bytes: self.pool_bytes.unwrap_or(base.pool_bytes),
            max_centre_step: self.max_centre_step.or(base.max_centre_step),
            grid_budget: self.grid_budget.or(base.grid_budget),
        }
    }
}
