//! Tile archives opened again when their file or object is replaced ([`Reopening`]).
//!
//! A PMTiles or MBTiles archive reads its tiles through directories (or metadata) read at open:
//! bytes of a newer version of the file read through an older version's directories would be
//! another tile, or no tile at all. So an archive says when it is no longer the version it
//! opened ([`Renewable::stale`]): a remote object whose `ETag` (or size) changed, a read refused
//! for it; a local file whose path now names another file, or whose size or modification time
//! moved. [`Reopening`] asks before each read and again after it: a read made while the
//! archive changed is dropped (its bytes may be of two versions), the archive is opened again,
//! and the tile is read from the new version; its [`version`](TileArchive::version) moves on, so
//! that a clipmap serving it reads every tile it holds anew. A new version that is another
//! pyramid (other zooms, tile size, encoding or bounds) is not served: its tiles are errors
//! saying so until the service is started again. Opening again is tried at most every
//! [`RETRY_GAP`], so that a file being rewritten is not opened with every read.

use super::{ArchiveError, Fetched, PyramidInfo, TileAddr, TileArchive};
use crate::source::FaultKind;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError, RwLock};
use std::time::{Duration, Instant};

/// The least time between two attempts at opening a changed archive again.
pub const RETRY_GAP: Duration = Duration::from_millis(200);

/// An archive that can tell that it is no longer the version it opened, and open the current
/// version of the same file or object.
pub trait Renewable: TileArchive + Sized {
    /// Why the archive is not the version it opened any more (replaced, rewritten, a read
    /// refused because the object changed), or `None` while it is.
    fn stale(&self) -> Option<String>;

    /// The same file or object opened again, as this one was (the same tile size).
    fn renew(&self) -> Result<Self, ArchiveError>;
}

/// What a local file was when it was opened: its device, inode, size and modification time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FileStamp {
    dev: u64,
    ino: u64,
    len: u64,
    mtime_ns: i128,
}

impl FileStamp {
    /// The stamp of `meta`.
    pub fn of(meta: &std::fs::Metadata) -> FileStamp {
        use std::os::unix::fs::MetadataExt;
        FileStamp {
            dev: meta.dev(),
            ino: meta.ino(),
            len: meta.len(),
            mtime_ns: i128::from(meta.mtime()) * 1_000_000_000 + i128::from(meta.mtime_nsec()),
        }
    }
}

/// A local file watched for replacement: the path and its stamp at open.
#[derive(Clone, Debug)]
pub struct Watched {
    path: PathBuf,
    at_open: FileStamp,
}

impl Watched {
    /// Stamps `path` now (before it is opened: a change while it is being opened shows at the
    /// first check).
    pub fn stamp(path: &Path) -> std::io::Result<Watched> {
        Ok(Watched { path: path.to_path_buf(), at_open: FileStamp::of(&std::fs::metadata(path)?) })
    }

    /// The path watched.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Why the path is not the file opened any more, if it is not: one `stat`.
    pub fn changed(&self) -> Option<String> {
        match std::fs::metadata(&self.path) {
            Err(e) => Some(format!("{} cannot be read now ({e})", self.path.display())),
            Ok(m) => {
                let now = FileStamp::of(&m);
                if now == self.at_open {
                    None
                } else if (now.dev, now.ino) != (self.at_open.dev, self.at_open.ino) {
                    Some(format!("{} was replaced by another file since it was opened", self.path.display()))
                } else {
                    Some(format!(
                        "{} was rewritten since it was opened ({} bytes then, {} now)",
                        self.path.display(),
                        self.at_open.len,
                        now.len
                    ))
                }
            }
        }
    }
}

/// An archive served across its new versions (module docs).
pub struct Reopening<A: Renewable> {
    place: String,
    info: PyramidInfo,
    current: RwLock<Arc<A>>,
    version: AtomicU64,
    /// The last attempt at opening again.
    attempt: Mutex<Option<Instant>>,
}

impl<A: Renewable> Reopening<A> {
    /// Serves `first` and its later versions.
    pub fn new(first: A) -> Reopening<A> {
        Reopening {
            place: first.place().to_string(),
            info: first.info().clone(),
            current: RwLock::new(Arc::new(first)),
            version: AtomicU64::new(0),
            attempt: Mutex::new(None),
        }
    }

    /// The version served now.
    pub fn current(&self) -> Arc<A> {
        Arc::clone(&self.current.read().unwrap_or_else(PoisonError::into_inner))
    }

    fn error(&self, at: TileAddr, kind: FaultKind, problem: String) -> ArchiveError {
        ArchiveError { place: self.place.clone(), at: Some(at), kind, problem }
    }

    /// Opens the archive again in place of `stale` (which changed: `why`), unless another read
    /// did already; the version served then.
    fn renew(&self, stale: &Arc<A>, at: TileAddr, why: &str) -> Result<Arc<A>, ArchiveError> {
        let mut last = self.attempt.lock().unwrap_or_else(PoisonError::into_inner);
        let now = self.current();
        if !Arc::ptr_eq(&now, stale) {
            return Ok(now);
        }
        if last.is_some_and(|t| t.elapsed() < RETRY_GAP) {
            return Err(self.error(
                at,
                FaultKind::Io,
                format!(
                    "{why}; it was opened again less than {} ms ago and is tried again soon",
                    RETRY_GAP.as_millis()
                ),
            ));
        }
        *last = Some(Instant::now());
        let fresh = stale
            .renew()
            .map_err(|e| self.error(at, e.kind, format!("{why}, and opening it again failed: {}", e.problem)))?;
        if fresh.info() != &self.info {
            return Err(self.error(
                at,
                FaultKind::Corrupt,
                format!(
                    "{why}, and the new version is another pyramid ({:?}, served: {:?}): it is not mixed with the one served; restart to serve it",
                    fresh.info(),
                    self.info
                ),
            ));
        }
        let fresh = Arc::new(fresh);
        *self.current.write().unwrap_or_else(PoisonError::into_inner) = Arc::clone(&fresh);
        self.version.fetch_add(1, Ordering::SeqCst);
        tracing::info!(archive = %self.place, "{why}: opened again, serving the new version");
        Ok(fresh)
    }
}

impl<A: Renewable> TileArchive for Reopening<A> {
    fn place(&self) -> &str {
        &self.place
    }

    fn info(&self) -> &PyramidInfo {
        &self.info
    }

    fn fetch(&self, at: TileAddr) -> Result<Fetched, ArchiveError> {
        let mut cur = self.current();
        // Twice at most: a version that changes again while its first read runs is an error.
        for _ in 0..2 {
            if let Some(why) = cur.stale() {
                cur = self.renew(&cur, at, &why)?;
            }
            let got = cur.fetch(at);
            match cur.stale() {
                // Read from one version throughout.
                None => return got,
                // The bytes read may be of two versions: dropped, read again from the new one.
                Some(why) => cur = self.renew(&cur, at, &why)?,
            }
        }
        Err(self.error(
            at,
            FaultKind::Io,
            "the archive changed again while its new version was read; the tile is read again later".into(),
        ))
    }

    #[cfg(feature = "remote")]
    fn remote_stats(&self) -> Option<crate::source::remote::RemoteStats> {
        self.current().remote_stats()
    }

    fn is_cached(&self, at: TileAddr) -> bool {
        self.current().is_cached(at)
    }

    fn locate(&self, at: TileAddr) -> Option<String> {
        self.current().locate(at)
    }

    fn stored_length(&self, at: TileAddr) -> Option<Result<Option<u64>, ArchiveError>> {
        self.current().stored_length(at)
    }

    fn version(&self) -> u64 {
        self.version.load(Ordering::SeqCst)
    }

    fn refresh(&self) -> u64 {
        let cur = self.current();
        if let Some(why) = cur.stale() {
            // A failure is the next read's to report.
            let _ = self.renew(&cur, TileAddr { z: 0, x: 0, y: 0 }, &why);
        }
        self.version()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicBool;

    /// An archive whose tiles are `[generation, z]`, that turns stale when told to.
    struct Fake {
        generation: u8,
        info: PyramidInfo,
        source: Arc<Source>,
    }

    struct Source {
        generation: AtomicU64,
        /// The next renewed version's max zoom.
        next_max_zoom: AtomicU64,
        /// Turns the archive stale during its next read.
        change_during_read: AtomicBool,
    }

    impl TileArchive for Fake {
        fn place(&self) -> &str {
            "fake"
        }
        fn info(&self) -> &PyramidInfo {
            &self.info
        }
        fn fetch(&self, at: TileAddr) -> Result<Fetched, ArchiveError> {
            if self.source.change_during_read.swap(false, Ordering::SeqCst) {
                self.source.generation.fetch_add(1, Ordering::SeqCst);
            }
            Ok(Fetched::Tile(vec![self.generation, at.z]))
        }
    }

    impl Renewable for Fake {
        fn stale(&self) -> Option<String> {
            let now = self.source.generation.load(Ordering::SeqCst) as u8;
            (now != self.generation).then(|| format!("generation {} now", now))
        }
        fn renew(&self) -> Result<Self, ArchiveError> {
            let mut info = self.info.clone();
            info.max_zoom = self.source.next_max_zoom.load(Ordering::SeqCst) as u8;
            Ok(Fake {
                generation: self.source.generation.load(Ordering::SeqCst) as u8,
                info,
                source: self.source.clone(),
            })
        }
    }

    fn fake() -> (Reopening<Fake>, Arc<Source>) {
        let source = Arc::new(Source {
            generation: AtomicU64::new(0),
            next_max_zoom: AtomicU64::new(3),
            change_during_read: AtomicBool::new(false),
        });
        let info = PyramidInfo { min_zoom: 0, max_zoom: 3, tile_size: 256, bounds: None, encoding: None };
        (Reopening::new(Fake { generation: 0, info, source: source.clone() }), source)
    }

    const AT: TileAddr = TileAddr { z: 2, x: 1, y: 1 };

    #[test]
    fn a_replaced_archive_is_opened_again_and_its_version_moves_on() {
        let (r, source) = fake();
        assert_eq!(r.fetch(AT).unwrap(), Fetched::Tile(vec![0, 2]));
        assert_eq!(r.version(), 0);
        source.generation.store(1, Ordering::SeqCst);
        assert_eq!(r.fetch(AT).unwrap(), Fetched::Tile(vec![1, 2]));
        assert_eq!(r.version(), 1);
        // A change while a tile is read: that read is dropped and made again from the new one.
        source.change_during_read.store(true, Ordering::SeqCst);
        std::thread::sleep(RETRY_GAP);
        assert_eq!(r.fetch(AT).unwrap(), Fetched::Tile(vec![2, 2]));
        assert_eq!(r.version(), 2);
        // A refresh opens a changed archive again without a read.
        std::thread::sleep(RETRY_GAP);
        source.generation.store(3, Ordering::SeqCst);
        assert_eq!(r.refresh(), 3);
        assert_eq!(r.current().generation, 3);
    }

    #[test]
    fn a_new_version_that_is_another_pyramid_is_refused_and_reopening_waits_its_gap() {
        let (r, source) = fake();
        source.next_max_zoom.store(4, Ordering::SeqCst);
        source.generation.store(1, Ordering::SeqCst);
        let e = r.fetch(AT).unwrap_err();
        assert!(e.problem.contains("another pyramid") && e.problem.contains("generation 1 now"), "{e}");
        let e = r.fetch(AT).unwrap_err();
        assert!(e.problem.contains("tried again soon"), "{e}");
        assert_eq!(r.version(), 0);
        source.next_max_zoom.store(3, Ordering::SeqCst);
        std::thread::sleep(RETRY_GAP);
        assert_eq!(r.fetch(AT).unwrap(), Fetched::Tile(vec![1, 2]));
        assert_eq!(r.version(), 1);
    }

    #[test]
    fn a_file_stamp_tells_a_replaced_file_from_a_rewritten_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.bin");
        std::fs::write(&path, b"one").unwrap();
        let w = Watched::stamp(&path).unwrap();
        assert_eq!(w.changed(), None);
        std::fs::write(dir.path().join("b.bin"), b"two!").unwrap();
        std::fs::rename(dir.path().join("b.bin"), &path).unwrap();
        assert!(w.changed().unwrap().contains("replaced by another file"));
        let w = Watched::stamp(&path).unwrap();
        std::fs::OpenOptions::new().append(true).open(&path).unwrap();
        assert_eq!(w.changed(), None, "opening alone changes nothing");
        std::io::Write::write_all(&mut std::fs::OpenOptions::new().append(true).open(&path).unwrap(), b"!").unwrap();
        assert!(w.changed().unwrap().contains("rewritten"));
        std::fs::remove_file(&path).unwrap();
        assert!(w.changed().unwrap().contains("cannot be read now"));
    }
}
