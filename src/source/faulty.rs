//! [`FaultySource`]: a wrapper that makes chosen tiles fail, for tests of the engine's fault
//! handling.
//!
//! Owns the fault rules (per level and/or per tile: missing, short, corrupt, permission denied,
//! I/O error, slow) and a run-time switch. It delegates every healthy read to the wrapped source.
//! Reads run on many threads at once, so the rules sit behind a read-write lock; this is a test
//! tool, not part of the paging path.

use super::{SourceError, TextureDesc, TileId, TileSource};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, RwLock};
use std::time::Duration;

/// One way of failing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// The tile does not exist.
    Missing,
    /// Only half the tile arrives.
    Short,
    /// The stored tile has the wrong size.
    Corrupt,
    /// The tile may not be read.
    PermissionDenied,
    /// A generic I/O error.
    Io,
    /// The read succeeds after this delay.
    Slow(Duration),
}

/// Which reads a fault applies to: every tile of `level` (or of every level when `None`), or one
/// tile (`tile` = [S, T]) of it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FaultRule {
    /// Level the rule applies to, or every level.
    pub level: Option<u32>,
    /// Tile [S, T] the rule applies to, or every tile of the level(s).
    pub tile: Option<[u64; 2]>,
    /// What happens.
    pub fault: Fault,
}

impl FaultRule {
    /// A fault on every tile of one level.
    pub fn level(level: u32, fault: Fault) -> Self {
        FaultRule { level: Some(level), tile: None, fault }
    }

    /// A fault on one tile.
    pub fn tile(tile: TileId, fault: Fault) -> Self {
        FaultRule { level: Some(tile.level), tile: Some([tile.s, tile.t]), fault }
    }

    /// A fault on every tile of every level.
    pub fn everywhere(fault: Fault) -> Self {
        FaultRule { level: None, tile: None, fault }
    }

    fn matches(&self, tile: TileId) -> bool {
        self.level.is_none_or(|l| l == tile.level) && self.tile.is_none_or(|st| st == [tile.s, tile.t])
    }
}

/// Wraps a source and injects faults according to rules that can be changed while reads run.
pub struct FaultySource {
    inner: Arc<dyn TileSource>,
    rules: RwLock<Vec<FaultRule>>,
    enabled: AtomicBool,
    reads: AtomicU64,
    injected: AtomicU64,
}

impl FaultySource {
    /// A wrapper with no rules, enabled.
    pub fn new(inner: Arc<dyn TileSource>) -> Self {
        FaultySource {
            inner,
            rules: RwLock::new(Vec::new()),
            enabled: AtomicBool::new(true),
            reads: AtomicU64::new(0),
            injected: AtomicU64::new(0),
        }
    }

    /// Adds a rule; the first matching rule wins.
    pub fn add(&self, rule: FaultRule) {
        self.rules.write().unwrap_or_else(|e| e.into_inner()).push(rule);
    }

    /// Removes every rule.
    pub fn clear(&self) {
        self.rules.write().unwrap_or_else(|e| e.into_inner()).clear();
    }

    /// Turns fault injection on or off without forgetting the rules.
    pub fn set_enabled(&self, on: bool) {
        self.enabled.store(on, Ordering::SeqCst);
    }

    /// Reads attempted so far.
    pub fn reads(&self) -> u64 {
        self.reads.load(Ordering::SeqCst)
    }

    /// Faults injected so far (slow reads included).
    pub fn injected(&self) -> u64 {
        self.injected.load(Ordering::SeqCst)
    }

    fn fault_for(&self, tile: TileId) -> Option<Fault> {
        if !self.enabled.load(Ordering::SeqCst) {
            return None;
        }
        let rules = self.rules.read().unwrap_or_else(|e| e.into_inner());
        rules.iter().find(|r| r.matches(tile)).map(|r| r.fault)
    }
}

impl TileSource for FaultySource {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn wrapped(&self) -> Option<&dyn TileSource> {
        Some(&*self.inner)
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.read_into(tile, out).map(|_| ())
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<super::Delivered, SourceError> {
        self.reads.fetch_add(1, Ordering::SeqCst);
        let Some(fault) = self.fault_for(tile) else {
            return self.inner.read_into(tile, out);
        };
        self.injected.fetch_add(1, Ordering::SeqCst);
        let expected = out.len() as u64;
        match fault {
            Fault::Missing => Err(SourceError::Missing { tile }),
            Fault::Short => {
                // Deliver a torn tile, as a real short read would, and report it.
                self.inner.read_tile(tile, out)?;
                let half = out.len() / 2;
                out[half..].fill(0xAB);
                Err(SourceError::Short { tile, expected, got: expected / 2 })
            }
            Fault::Corrupt => {
                out.fill(0xCD);
                Err(SourceError::Corrupt { tile, expected, found: expected + 7 })
            }
            Fault::PermissionDenied => Err(SourceError::PermissionDenied { tile }),
            Fault::Io => Err(SourceError::Io { tile, source: std::io::Error::other("injected I/O error") }),
            Fault::Slow(delay) => {
                std::thread::sleep(delay);
                self.inner.read_into(tile, out)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::{FaultKind, HashSource};
    use crate::texel::TexelFormat;

    #[test]
    fn rules_match_by_level_and_tile_and_can_be_switched_off() {
        let desc = TextureDesc::new([64, 64], 16, TexelFormat::L8, [8, 8]).unwrap();
        let src = FaultySource::new(Arc::new(HashSource::new(desc.clone())));
        src.add(FaultRule::tile(TileId::new(0, 1, 2), Fault::PermissionDenied));
        src.add(FaultRule::level(1, Fault::Short));
        let mut buf = vec![0u8; 64];
        let kind = |src: &FaultySource, tile, buf: &mut Vec<u8>| src.read_tile(tile, buf).err().map(|e| e.kind());
        assert_eq!(kind(&src, TileId::new(0, 1, 2), &mut buf), Some(FaultKind::PermissionDenied));
        assert_eq!(kind(&src, TileId::new(0, 2, 1), &mut buf), None);
        assert_eq!(kind(&src, TileId::new(1, 2, 1), &mut buf), Some(FaultKind::Short));
        src.set_enabled(false);
        assert_eq!(kind(&src, TileId::new(1, 2, 1), &mut buf), None);
        src.set_enabled(true);
        src.clear();
        assert_eq!(kind(&src, TileId::new(0, 1, 2), &mut buf), None);
        assert_eq!((src.reads(), src.injected()), (5, 2));
    }
}
