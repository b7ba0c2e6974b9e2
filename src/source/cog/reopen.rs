//! A remote COG opened again when its object is replaced in the store (docs/COG.md, "One
//! version of the object, checked on every range").
//!
//! [`CogSource`] reads every range of the version it opened and refuses a range of another
//! version: it never mixes bytes of two versions. [`Reopening`] stands in front of it for a
//! service: when a read is refused because the object changed, it opens the object again (one
//! ranged GET, as the first open), and if the new version is the same texture (size, texel
//! format, tile size, levels, heights) it serves the new version from then on, the refused read
//! included, and moves its [`version`](TileSource::version) on. A clipmap that sees the version
//! move reads every tile it holds again ([`crate::clip::Clipmap`]), so that the texture shown
//! becomes the new object's everywhere; until a tile's new read lands, readers see the old
//! version's texels of it whole, or (while its slot is refilled) a coarser level, never bytes of
//! two versions in one tile.
//!
//! A new version that is another texture is not served: the reads go on being refused with the
//! reason logged (restart the service to serve it). Opening again is tried at most every
//! [`RETRY_GAP`], so that an object being rewritten is not asked for its header with every read.

use super::{CogError, CogSource};
use crate::place::RemoteName;
use crate::source::remote::object::Object;
use crate::source::remote::Remote;
use crate::source::{Delivered, SourceError, TextureDesc, TileId, TileSource};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError, RwLock};
use std::time::{Duration, Instant};

/// The least time between two attempts at opening a changed object again.
pub const RETRY_GAP: Duration = Duration::from_millis(200);

impl CogSource {
    /// Opens the remote object `name` through `remote` with one ranged read of its first
    /// [`PREFIX_BYTES`](super::PREFIX_BYTES) (more only for structure that lies past them); the
    /// tile index is read in chunks as tiles are first read, and the levels past the overviews
    /// are built when one is first read.
    pub fn open_remote(name: &RemoteName, remote: Arc<Remote>, clip_size: u64) -> Result<Self, CogError> {
        let path = PathBuf::from(crate::place::redacted(name.as_str()).as_ref());
        let (bytes, prefix) = crate::source::remote::range::open_with(name, remote, super::PREFIX_BYTES)
            .map_err(|problem| CogError::Remote { path: path.clone(), problem })?;
        CogSource::open_ranges(path, bytes, prefix, clip_size)
    }
}

/// A remote COG that follows its object's new versions (module docs).
pub struct Reopening {
    name: RemoteName,
    remote: Arc<Remote>,
    clip: u64,
    desc: TextureDesc,
    current: RwLock<Arc<CogSource>>,
    version: AtomicU64,
    /// The last attempt at opening again, and why the last new version was not served.
    attempt: Mutex<Attempt>,
}

#[derive(Default)]
struct Attempt {
    at: Option<Instant>,
    refused: Option<String>,
}

impl std::fmt::Debug for Reopening {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reopening")
            .field("name", &self.name.as_str())
            .field("version", &self.version.load(Ordering::Relaxed))
            .finish_non_exhaustive()
    }
}

impl Reopening {
    /// Opens `name` through `remote` ([`CogSource::open_remote`]: one ranged GET).
    pub fn open(name: &RemoteName, remote: Arc<Remote>, clip_size: u64) -> Result<Reopening, CogError> {
        Ok(Reopening::from_first(name, CogSource::open_remote(name, remote, clip_size)?, clip_size))
    }

    /// Serves `first`, the object `name` opened with clip size `clip_size`, and its later versions
    /// (opened again through `first`'s remote reader).
    pub(super) fn from_first(name: &RemoteName, first: CogSource, clip_size: u64) -> Reopening {
        Reopening::serving(name, Arc::new(first), clip_size).expect("a remote name opens a remote object")
    }

    /// Serves `first` (the object `name`, opened with clip size `clip_size`, as a configuration's
    /// `#clipmap cog` line opens it) and its later versions; `None` when `first` is not a remote
    /// object's source.
    pub fn serving(name: &RemoteName, first: Arc<CogSource>, clip_size: u64) -> Option<Reopening> {
        let object = first.bytes.as_any().downcast_ref::<Object>()?;
        let remote = Arc::clone(object.remote());
        Some(Reopening {
            name: name.clone(),
            remote,
            clip: clip_size,
            desc: first.desc().clone(),
            current: RwLock::new(first),
            version: AtomicU64::new(0),
            attempt: Mutex::new(Attempt::default()),
        })
    }

    /// The version served now.
    pub fn current(&self) -> Arc<CogSource> {
        Arc::clone(&self.current.read().unwrap_or_else(PoisonError::into_inner))
    }

    /// `f` of the version served now, without taking a reference count (the queues ask per
    /// tile).
    fn with<R>(&self, f: impl FnOnce(&CogSource) -> R) -> R {
        f(&self.current.read().unwrap_or_else(PoisonError::into_inner))
    }

    /// Times the object was opened again and its new version served.
    pub fn reopened(&self) -> u64 {
        self.version.load(Ordering::Relaxed)
    }

    /// Why the last new version seen was not served (another texture), if it was not.
    pub fn refused(&self) -> Option<String> {
        self.attempt.lock().unwrap_or_else(PoisonError::into_inner).refused.clone()
    }

    /// After `old` refused a read because the object changed: the version to read now, opened
    /// again if need be; `None` while none can be served.
    fn renew(&self, old: &Arc<CogSource>) -> Option<Arc<CogSource>> {
        let mut attempt = self.attempt.lock().unwrap_or_else(PoisonError::into_inner);
        let now = self.current();
        if !Arc::ptr_eq(&now, old) {
            // Another read opened it again meanwhile.
            return Some(now);
        }
        if attempt.at.is_some_and(|at| at.elapsed() < RETRY_GAP) {
            return None;
        }
        attempt.at = Some(Instant::now());
        let fresh = match CogSource::open_remote(&self.name, Arc::clone(&self.remote), self.clip) {
            Ok(fresh) => fresh,
            Err(e) => {
                // An object half rewritten, a store that answers later: tried again later.
                tracing::warn!(object = %crate::place::redacted(self.name.as_str()), "the object changed and could not be opened again yet: {e}");
                return None;
            }
        };
        if let Some(why) = differs(&self.desc, old, &fresh) {
            let text = format!(
                "{}: the object changed into another texture ({why}); it is not served: restart the service to serve it, or put the earlier version back",
                crate::place::redacted(self.name.as_str())
            );
            if attempt.refused.as_deref() != Some(text.as_str()) {
                tracing::error!("{text}");
            }
            attempt.refused = Some(text);
            return None;
        }
        attempt.refused = None;
        let fresh = Arc::new(fresh);
        *self.current.write().unwrap_or_else(PoisonError::into_inner) = Arc::clone(&fresh);
        let v = self.version.fetch_add(1, Ordering::AcqRel) + 1;
        tracing::info!(object = %crate::place::redacted(self.name.as_str()), version = v, "the object changed: opened again, every tile is read anew");
        Some(fresh)
    }
}

/// How `fresh` differs from the texture served (`desc`, and `old`'s heights and alpha), if it does.
fn differs(desc: &TextureDesc, old: &CogSource, fresh: &CogSource) -> Option<String> {
    let d = fresh.desc();
    if d.size() != desc.size() {
        return Some(format!("{:?} texels, expected {:?}", d.size(), desc.size()));
    }
    if d.format() != desc.format() {
        return Some(format!("texel format {}, expected {}", d.format().short_name(), desc.format().short_name()));
    }
    if d != desc {
        return Some(format!("tiles or levels {:?}, expected {:?}", d.levels(), desc.levels()));
    }
    if fresh.heights() != old.heights() {
        return Some(format!("heights {:?}, expected {:?}", fresh.heights(), old.heights()));
    }
    None
}

impl TileSource for Reopening {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.read_into(tile, out).map(|_| ())
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<Delivered, SourceError> {
        let src = self.current();
        match src.read_into(tile, out) {
            Err(e) if src.object_changed() => match self.renew(&src) {
                Some(fresh) => fresh.read_into(tile, out),
                None => Err(e),
            },
            r => r,
        }
    }

    fn heights(&self) -> Option<crate::plan::HeightPlan> {
        self.with(|s| s.heights())
    }

    fn georef(&self) -> Option<crate::georef::Georef> {
        self.with(TileSource::georef)
    }

    fn remote_stats(&self) -> Option<crate::source::remote::RemoteStats> {
        self.with(|s| s.remote_stats())
    }

    fn stream_servers(&self) -> usize {
        self.with(|s| s.stream_servers())
    }

    fn stream_of(&self, tile: TileId, streams: usize) -> usize {
        self.with(|s| s.stream_of(tile, streams))
    }

    fn will_read(&self, tiles: &[TileId]) {
        self.with(|s| s.will_read(tiles));
    }

    fn withdraw(&self, tile: TileId) {
        self.with(|s| s.withdraw(tile));
    }

    fn version(&self) -> u64 {
        self.version.load(Ordering::Acquire)
    }
}
