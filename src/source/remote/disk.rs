//! The optional local disk cache of remote bytes (`CLIPMAP_REMOTE_CACHE_DIR`): one file per
//! range read (a prepared pyramid's tile file, a range of a PMTiles archive of one version) or
//! per whole object (a tile of a tile service), bounded in bytes, least recently used files
//! removed first, kept across restarts, and shared by every process of the host that opens the
//! same directory.
//!
//! A file ([`encode`]) holds a magic number, the lengths of its key and its bytes, a checksum
//! (`checksum`) of both, the key (location, offset and length; or location and `whole`) and the
//! bytes. Nothing in the directory is trusted: a hit is served only when the file is a regular
//! file of this user with one name (opened without following a symbolic link and without
//! blocking, so a FIFO or a link to `/dev/zero` is neither waited on nor read), exactly as long
//! as the range asked for needs (checked before a byte is read, and no more is ever read; an
//! object's length is bounded by the caller's maximum), with the key asked for and a checksum
//! that matches. Anything else (a collision, a torn or altered file, a stranger's file, a file
//! of an older format) is dropped: removed, counted ([`DiskCache::dropped`]) and read again from
//! the store, never served.
//!
//! **The bound, across processes.** The directory holds a ledger ([`LEDGER`], 16 bytes: a magic
//! number and the bytes the entries hold). Every change of the directory (an insert with the
//! evictions it needs, a drop) is made under an exclusive `flock` of the ledger (and a mutex for
//! the threads of one process), so an insert and its evictions are atomic with respect to every
//! other process. An insert removes least recently used entries until the new entry fits beside
//! what the ledger counts, raises the ledger by the new entry's bytes *before* its file exists,
//! writes the file under a temporary name created with `O_EXCL | O_NOFOLLOW` (mode 0600; a link
//! or file planted at that name is never written through: the next name is tried), renames it
//! over its name, and only then lowers the ledger by the entry it replaced; an eviction lowers
//! the ledger only *after* its file is gone. So at every instant the files (temporaries
//! included) hold at most what the ledger says, and the ledger at most the bound. Recency is the
//! files' modification time, set to now (to the nanosecond) by every write and every hit, so
//! every process evicts in the same order; each process keeps the entries its last scan listed,
//! least recently used first, and scans the directory again when they run out (an entry used or
//! rewritten since the scan is passed over, one another process removed is skipped).
//!
//! **Crashes (kill -9).** A writer that dies leaves at most a temporary (never a half file under
//! an entry's name: the rename is atomic) and a ledger that counts too much, never too little;
//! the kernel releases its lock. Every scan (each [`DiskCache::open`], and whenever an insert's
//! candidates run out) removes the temporaries (under the lock, any it sees is a dead writer's),
//! counts the entries' bytes from the files themselves and writes that into the ledger, so the
//! drift is repaired and cannot accumulate. The directory is made 0700 when the cache makes it.
//! The cache trusts the store not to change under it for unversioned keys (clear the directory
//! when such objects are replaced); ranges of a PMTiles archive are keyed by the version seen at
//! open ([`versioned_key`]).

use std::collections::VecDeque;
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::os::unix::fs::{DirBuilderExt, FileExt, MetadataExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::SystemTime;

use rustix::fs::{FlockOperation, OFlags};

/// The cache key of a range.
pub fn key(location: &str, offset: u64, len: u64) -> String {
    format!("{location}\n{offset}\n{len}")
}

/// The cache key of a whole object (a tile of a tile service): its URL, marked apart from the
/// keys of ranges.
pub fn object_key(location: &str) -> String {
    format!("{location}\nwhole")
}

/// The cache key of a range of one version of an object (`validator`, its `ETag` or
/// `Last-Modified`): the bytes of another version are never served for it.
pub fn versioned_key(location: &str, validator: &str, offset: u64, len: u64) -> String {
    format!("{location}\n{validator}\n{offset}\n{len}")
}

/// The first bytes of every cache file (the format's version is its last byte).
pub(crate) const MAGIC: [u8; 8] = *b"clipmapC";

/// Bytes before the key: magic, key length (u32), data length (u64), checksum (u64), all
/// little-endian.
pub(crate) const HEADER: usize = 8 + 4 + 8 + 8;

/// The ledger's name in the cache directory: the lock every process takes, and the bytes the
/// entries hold.
pub const LEDGER: &str = "cache.ledger";

/// The first bytes of the ledger; the count of bytes follows (u64, little-endian).
const LEDGER_MAGIC: [u8; 8] = *b"clipmapL";

/// Attempts at a fresh temporary name before a range is left uncached.
const TEMPORARY_ATTEMPTS: u32 = 16;

fn fnv(bytes: &[u8], seed: u64) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64 ^ seed;
    for b in bytes {
        h ^= *b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn file_name(key: &str) -> String {
    format!("{:016x}{:016x}.tile", fnv(key.as_bytes(), 0), fnv(key.as_bytes(), 0x9e37_79b9_7f4a_7c15))
}

/// The checksum of a cache file: four lanes of SplitMix64 over the little-endian 8-byte words of
/// the key and then the bytes (each zero-padded to a whole word), seeded with both lengths.
///
/// Each step of a lane is a bijection of its state, so any change confined to the words of one
/// lane always changes the checksum; any other change (bits flipped, bytes overwritten, a torn
/// write, another entry's bytes) goes unnoticed with a chance of about 2^-64. It is not a
/// cryptographic hash: someone who can write the cache directory can forge an entry.
pub(crate) fn checksum(key: &[u8], data: &[u8]) -> u64 {
    use crate::source::procedural::splitmix64;
    let mut lanes = [
        splitmix64(key.len() as u64),
        splitmix64(data.len() as u64 ^ 0x5555_5555_5555_5555),
        splitmix64(1),
        splitmix64(2),
    ];
    let mut i = 0usize;
    for part in [key, data] {
        let mut words = part.chunks_exact(8);
        for w in &mut words {
            let w = u64::from_le_bytes(w.try_into().unwrap_or([0; 8]));
            lanes[i % 4] = splitmix64(lanes[i % 4] ^ w);
            i += 1;
        }
        let rest = words.remainder();
        if !rest.is_empty() {
            let mut w = [0u8; 8];
            w[..rest.len()].copy_from_slice(rest);
            lanes[i % 4] = splitmix64(lanes[i % 4] ^ u64::from_le_bytes(w));
            i += 1;
        }
    }
    lanes.iter().fold(0u64, |h, l| splitmix64(h ^ l))
}

/// A cache file's bytes: `MAGIC`, the key's length, the data's length, `checksum`, key,
/// data.
pub fn encode(key: &str, data: &[u8]) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(HEADER + key.len() + data.len());
    bytes.extend_from_slice(&MAGIC);
    bytes.extend_from_slice(&(key.len() as u32).to_le_bytes());
    bytes.extend_from_slice(&(data.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&checksum(key.as_bytes(), data).to_le_bytes());
    bytes.extend_from_slice(key.as_bytes());
    bytes.extend_from_slice(data);
    bytes
}

/// An entry's file as a scan of the directory saw it: when it was last used (its modification
/// time), its name and its length.
type Seen = (SystemTime, String, u64);

/// What one process keeps: the entries of its last scan, least recently used first, the
/// candidates for eviction until they run out (then the directory is scanned again).
struct State {
    candidates: VecDeque<Seen>,
}

/// A bounded directory of cached ranges and objects, shared by every process that opens it.
pub struct DiskCache {
    dir: PathBuf,
    bound: u64,
    /// The ledger, open for the life of the cache: `flock`ed around every change.
    ledger: File,
    /// Serialises this process's threads (a `flock` is shared by every thread of a process).
    state: Mutex<State>,
    tmp: AtomicU64,
    dropped: AtomicU64,
}

/// The directory lock: this process's mutex and the ledger's exclusive `flock`, both released
/// on drop (the `flock` by the kernel too, should the process die holding it).
struct Locked<'a> {
    cache: &'a DiskCache,
    state: MutexGuard<'a, State>,
}

impl Drop for Locked<'_> {
    fn drop(&mut self) {
        let _ = rustix::fs::flock(&self.cache.ledger, FlockOperation::Unlock);
    }
}

impl Locked<'_> {
    /// The bytes the ledger says the entries hold, or `None` when it says nothing readable.
    fn total(&self) -> Option<u64> {
        let mut b = [0u8; 16];
        self.cache.ledger.read_exact_at(&mut b, 0).ok()?;
        (b[..8] == LEDGER_MAGIC).then(|| u64::from_le_bytes(b[8..].try_into().unwrap_or([0; 8])))
    }

    /// Writes `total` into the ledger.
    fn set_total(&self, total: u64) {
        let mut b = [0u8; 16];
        b[..8].copy_from_slice(&LEDGER_MAGIC);
        b[8..].copy_from_slice(&total.to_le_bytes());
        let _ = self.cache.ledger.write_all_at(&b, 0);
    }

    /// Scans the directory: removes the temporaries (any seen under the lock is a crashed
    /// writer's) and the cache names that are not regular files (counted as dropped), counts
    /// the entries' bytes from the files themselves into the ledger, and keeps the entries,
    /// least recently used first, as the candidates for eviction. Returns the bytes.
    fn scan(&mut self) -> u64 {
        let mut found: Vec<Seen> = Vec::new();
        let mut total = 0u64;
        if let Ok(entries) = std::fs::read_dir(&self.cache.dir) {
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                // Not followed: the entry itself.
                let Ok(meta) = e.metadata() else { continue };
                if name.contains(".tmp.") {
                    let _ = std::fs::remove_file(e.path());
                    continue;
                }
                if !name.ends_with(".tile") {
                    continue;
                }
                if !meta.is_file() {
                    self.cache.dropped.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(
                        file = %e.path().display(),
                        "remote disk cache: dropped a cached range ({}, not a regular file)",
                        crate::open::kind_of(&meta)
                    );
                    let _ = std::fs::remove_file(e.path());
                    continue;
                }
                total += meta.len();
                found.push((meta.modified().unwrap_or(SystemTime::UNIX_EPOCH), name, meta.len()));
            }
        }
        found.sort();
        self.state.candidates = found.into();
        self.set_total(total);
        total
    }

    /// Removes least recently used entries until `total + room` fits the bound; returns the
    /// bytes left. A candidate used or rewritten since the scan that listed it (its time
    /// changed) is passed over, one removed by another process is skipped; when the candidates
    /// run out the directory is scanned again, once.
    fn evict(&mut self, mut total: u64, room: u64) -> u64 {
        let mut rescanned = false;
        while total.saturating_add(room) > self.cache.bound {
            let Some((when, name, _)) = self.state.candidates.pop_front() else {
                if rescanned {
                    break;
                }
                rescanned = true;
                total = self.scan();
                continue;
            };
            let path = self.cache.dir.join(&name);
            let Ok(meta) = std::fs::symlink_metadata(&path) else { continue };
            if !meta.is_file() || meta.modified().ok() != Some(when) {
                continue;
            }
            if std::fs::remove_file(&path).is_ok() {
                // After the file is gone: a crash in between leaves the ledger high, never low.
                total = total.saturating_sub(meta.len());
                self.set_total(total);
            }
        }
        total
    }
}

impl DiskCache {
    /// Opens (making it, mode 0700, if needed) the cache in `dir`, bounded to `bound` bytes,
    /// and repairs it: under the directory lock the files are scanned, the temporaries of
    /// writers that died are removed, the ledger is set to the bytes the entries hold, and the
    /// least recently used entries are removed until they fit the bound. A cache name (`*.tile`)
    /// that is not a regular file (a link, a FIFO) is dropped: removed, never followed, and
    /// counted.
    pub fn open(dir: &Path, bound: u64) -> io::Result<DiskCache> {
        std::fs::DirBuilder::new().recursive(true).mode(0o700).create(dir)?;
        let path = dir.join(LEDGER);
        let ledger = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .mode(0o600)
            .custom_flags((OFlags::NOFOLLOW | OFlags::NONBLOCK | OFlags::CLOEXEC).bits() as i32)
            .open(&path)
            .map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
        let meta = ledger.metadata()?;
        if !meta.is_file() || meta.uid() != rustix::process::geteuid().as_raw() {
            return Err(io::Error::other(format!(
                "{}: the cache's ledger is {} of uid {}: expected a regular file of this user; remove it",
                path.display(),
                crate::open::kind_of(&meta),
                meta.uid()
            )));
        }
        let c = DiskCache {
            dir: dir.to_path_buf(),
            bound,
            ledger,
            state: Mutex::new(State { candidates: VecDeque::new() }),
            tmp: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
        };
        {
            let mut l = c.lock()?;
            let total = l.scan();
            l.evict(total, 0);
        }
        Ok(c)
    }

    /// Takes the directory lock.
    fn lock(&self) -> io::Result<Locked<'_>> {
        let state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        rustix::fs::flock(&self.ledger, FlockOperation::LockExclusive)?;
        Ok(Locked { cache: self, state })
    }

    /// The bound, in bytes.
    pub fn bound(&self) -> u64 {
        self.bound
    }

    /// Bytes the entries hold now, as the ledger says (every process's).
    pub fn bytes(&self) -> u64 {
        match self.lock() {
            Ok(mut l) => match l.total() {
                Some(t) => t,
                None => l.scan(),
            },
            Err(_) => 0,
        }
    }

    /// Cached ranges dropped since the cache was opened (by [`DiskCache::open`] too) because
    /// their file failed a check.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Fills `out` from the cache when it holds exactly this range, checked; returns whether
    /// it did. A file that fails a check is dropped (removed and counted), `out` is zeroed and
    /// the range is a miss.
    pub fn get(&self, key: &str, out: &mut [u8]) -> bool {
        let path = self.dir.join(file_name(key));
        match read_entry(&path, key, Some(out.len() as u64), out.len() as u64) {
            Ok(data) => {
                out.copy_from_slice(&data);
                true
            }
            Err(f) => {
                out.fill(0);
                self.failed(&path, f);
                false
            }
        }
    }

    /// The whole object under `key` (at most `max` bytes), checked, when the cache holds it.
    /// A file that fails a check is dropped (removed and counted) and the object is a miss.
    pub fn get_object(&self, key: &str, max: u64) -> Option<Vec<u8>> {
        let path = self.dir.join(file_name(key));
        match read_entry(&path, key, None, max) {
            Ok(data) => Some(data),
            Err(f) => {
                self.failed(&path, f);
                None
            }
        }
    }

    /// Whether the cache holds an entry under `key` (not read nor checked: a later read does).
    pub fn holds(&self, key: &str) -> bool {
        std::fs::symlink_metadata(self.dir.join(file_name(key))).is_ok_and(|m| m.is_file())
    }

    /// A read that found no good entry: an absent one is a plain miss; a bad one is removed
    /// (when what is at its name is still what was read, or not a regular file) and counted.
    fn failed(&self, path: &Path, f: Failed) {
        let Failed::Bad { why, inode } = f else { return };
        self.dropped.fetch_add(1, Ordering::Relaxed);
        tracing::warn!(file = %path.display(), "remote disk cache: dropped a cached range ({why}); it is read again");
        let Ok(l) = self.lock() else { return };
        let Ok(meta) = std::fs::symlink_metadata(path) else { return };
        if !meta.is_file() {
            let _ = std::fs::remove_file(path);
        } else if inode == Some((meta.dev(), meta.ino())) && std::fs::remove_file(path).is_ok() {
            if let Some(t) = l.total() {
                l.set_total(t.saturating_sub(meta.len()));
            }
        }
    }

    /// A new temporary file for the entry `name`: created, never opened if something (a link,
    /// a file) already has the name; the next name is tried then, a bounded number of times.
    fn temporary(&self, name: &str) -> Option<(PathBuf, File)> {
        for _ in 0..TEMPORARY_ATTEMPTS {
            let n = self.tmp.fetch_add(1, Ordering::Relaxed);
            let tmp = self.dir.join(format!("{name}.tmp.{}.{n}", std::process::id()));
            let created = OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(0o600)
                .custom_flags((OFlags::NOFOLLOW | OFlags::CLOEXEC).bits() as i32)
                .open(&tmp);
            match created {
                Ok(f) => return Some((tmp, f)),
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
                Err(_) => return None,
            }
        }
        None
    }

    /// Stores a range or an object (best effort: a full disk, or names taken by others, only
    /// mean a later miss).
    ///
    /// Under the directory lock: least recently used entries are removed until the new entry
    /// fits beside what the ledger counts (the entry it replaces still counted), the ledger is
    /// raised by the new entry's bytes, the entry is written under a temporary name and renamed
    /// over its name, and the ledger then lowered by the bytes of the entry it replaced. At
    /// every step the files hold at most what the ledger says, and the ledger at most the bound.
    pub fn put(&self, key: &str, data: &[u8]) {
        let name = file_name(key);
        let bytes = encode(key, data);
        let len = bytes.len() as u64;
        if len > self.bound {
            return;
        }
        let Ok(mut l) = self.lock() else { return };
        let total = match l.total() {
            Some(t) => t,
            None => l.scan(),
        };
        let total = l.evict(total, len);
        if total.saturating_add(len) > self.bound {
            return;
        }
        l.set_total(total + len);
        let path = self.dir.join(&name);
        let replaced = std::fs::symlink_metadata(&path).ok().filter(|m| m.is_file()).map_or(0, |m| m.len());
        let stored = match self.temporary(&name) {
            Some((tmp, mut file)) => {
                // Its time of use, to the nanosecond (a file system stamps writes more coarsely).
                let ok = file.write_all(&bytes).is_ok()
                    && file.set_modified(SystemTime::now()).is_ok()
                    && std::fs::rename(&tmp, &path).is_ok();
                if !ok {
                    let _ = std::fs::remove_file(&tmp);
                }
                ok
            }
            None => false,
        };
        l.set_total(if stored { (total + len).saturating_sub(replaced) } else { total });
    }
}

/// Why a read found no entry to serve.
enum Failed {
    /// Nothing under the name: a plain miss.
    Absent,
    /// Something that failed a check, and the file read (device, inode) when one was opened.
    Bad { why: String, inode: Option<(u64, u64)> },
}

/// Reads the entry at `path` when it passes every check: its bytes (`len` of them when given,
/// else any number up to `max`), its time of use set to now; otherwise says which check failed.
fn read_entry(path: &Path, key: &str, len: Option<u64>, max: u64) -> Result<Vec<u8>, Failed> {
    let bad = |why: String, inode: Option<(u64, u64)>| Failed::Bad { why, inode };
    let file = match OpenOptions::new()
        .read(true)
        .custom_flags((OFlags::NOFOLLOW | OFlags::NONBLOCK | OFlags::CLOEXEC).bits() as i32)
        .open(path)
    {
        Ok(f) => f,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Err(Failed::Absent),
        Err(e) => {
            return Err(bad(
                match e.raw_os_error() {
                    Some(n) if n == rustix::io::Errno::LOOP.raw_os_error() => "a symbolic link".to_string(),
                    _ => format!("cannot be opened: {e}"),
                },
                None,
            ))
        }
    };
    let meta = file.metadata().map_err(|e| bad(format!("cannot be examined: {e}"), None))?;
    let inode = Some((meta.dev(), meta.ino()));
    if !meta.is_file() {
        return Err(bad(format!("{}, not a regular file", crate::open::kind_of(&meta)), inode));
    }
    let me = rustix::process::geteuid().as_raw();
    if meta.uid() != me {
        return Err(bad(format!("owned by uid {}, not by this user (uid {me})", meta.uid()), inode));
    }
    if meta.nlink() != 1 {
        return Err(bad(format!("a file with {} names (hard links)", meta.nlink()), inode));
    }
    let head_len = (HEADER + key.len()) as u64;
    let data_len = match len {
        Some(n) if meta.len() != head_len + n => {
            return Err(bad(format!("{} bytes, expected {} for this range", meta.len(), head_len + n), inode))
        }
        Some(n) => n,
        None if meta.len() < head_len || meta.len() - head_len > max => {
            return Err(bad(
                format!("{} bytes, expected {head_len} to {} for this object", meta.len(), head_len + max),
                inode,
            ))
        }
        None => meta.len() - head_len,
    };
    let mut head = vec![0u8; head_len as usize];
    let mut out = vec![0u8; data_len as usize];
    file.read_exact_at(&mut head, 0).map_err(|e| bad(format!("cannot be read: {e}"), inode))?;
    file.read_exact_at(&mut out, head_len).map_err(|e| bad(format!("cannot be read: {e}"), inode))?;
    let u64_at = |at: usize| u64::from_le_bytes(head[at..at + 8].try_into().unwrap_or([0; 8]));
    if head[..8] != MAGIC {
        return Err(bad("not a cache file of this format".into(), inode));
    }
    let klen = u32::from_le_bytes(head[8..12].try_into().unwrap_or([0; 4])) as usize;
    if klen != key.len() || u64_at(12) != data_len || &head[HEADER..] != key.as_bytes() {
        return Err(bad("the entry of another range".into(), inode));
    }
    if u64_at(20) != checksum(key.as_bytes(), &out) {
        return Err(bad("its checksum does not match its bytes".into(), inode));
    }
    // Its time of use: eviction removes the least recently used first, across processes.
    let _ = file.set_modified(SystemTime::now());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_survive_a_reopen_and_the_bound_removes_the_least_recently_used() {
        let dir = tempfile::tempdir().unwrap();
        // Room for three files: the header, a key of up to 22 bytes, 100 bytes.
        let c = DiskCache::open(dir.path(), 3 * (HEADER as u64 + 22 + 100)).unwrap();
        let k = |i: u64| key("http://h:1/obj", i * 100, 100);
        for i in 0..3 {
            c.put(&k(i), &[i as u8; 100]);
        }
        let mut out = [0u8; 100];
        assert!(c.get(&k(0), &mut out) && out == [0u8; 100]);
        c.put(&k(3), &[3u8; 100]);
        assert!(!c.get(&k(1), &mut out), "the least recently used range went first");
        assert!(c.get(&k(0), &mut out));
        drop(c);
        let c = DiskCache::open(dir.path(), 1 << 20).unwrap();
        assert!(c.get(&k(3), &mut out) && out == [3u8; 100], "kept across a reopen");
        let mut wrong = [0u8; 99];
        assert!(!c.get(&k(3), &mut wrong), "a range of another length is a miss");
        assert!(!c.get(&k(3), &mut out), "and the file that did not fit is gone");
    }

    #[test]
    fn the_checksum_changes_with_every_byte_and_every_length() {
        let key = b"http://h:1/obj\n0\n37";
        let data: Vec<u8> = (0..37u8).collect();
        let sum = checksum(key, &data);
        for i in 0..data.len() {
            for bit in 0..8 {
                let mut d = data.clone();
                d[i] ^= 1 << bit;
                assert_ne!(checksum(key, &d), sum, "byte {i} bit {bit}");
            }
        }
        assert_ne!(checksum(key, &data[..36]), sum, "one byte shorter");
        let mut longer = data.clone();
        longer.push(0);
        assert_ne!(checksum(key, &longer), sum, "a zero byte more");
        assert_ne!(checksum(b"http://h:1/obj\n0\n38", &data), sum, "another key");
        let e = encode("k", &data);
        assert_eq!(e.len(), HEADER + 1 + data.len());
        assert_eq!(&e[..8], &MAGIC);
    }

    /// Bytes of the entries' files and temporaries in `dir`, as `du --apparent-size` counts them.
    fn dir_bytes(dir: &Path) -> u64 {
        std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy() != LEDGER)
            .filter_map(|e| e.metadata().ok())
            .filter(|m| m.is_file())
            .map(|m| m.len())
            .sum()
    }

    #[test]
    fn two_caches_on_one_directory_never_hold_more_than_the_bound_together() {
        let dir = tempfile::tempdir().unwrap();
        let entry = (HEADER + key("http://h:1/obj", 0, 1000).len() + 1000) as u64;
        let bound = 7 * entry + entry / 2;
        // Two opens of one directory: two ledger descriptions, locked as two processes lock.
        let caches = [DiskCache::open(dir.path(), bound).unwrap(), DiskCache::open(dir.path(), bound).unwrap()];
        let stop = std::sync::atomic::AtomicBool::new(false);
        let most = std::thread::scope(|s| {
            for (n, c) in caches.iter().enumerate() {
                for t in 0..2u64 {
                    s.spawn(move || {
                        for i in 0..150u64 {
                            let k = key("http://h:1/obj", (n as u64 * 1000 + t * 500 + i) * 1000, 1000);
                            c.put(&k, &[i as u8; 1000]);
                        }
                    });
                }
            }
            let (stop, path) = (&stop, dir.path());
            let sampler = s.spawn(move || {
                let mut most = 0;
                while !stop.load(Ordering::Relaxed) {
                    most = most.max(dir_bytes(path));
                }
                most
            });
            // The writers end first (the scope joins them only at its end): wait for them here.
            while caches.iter().map(|c| c.tmp.load(Ordering::Relaxed)).sum::<u64>() < 600 {
                std::thread::yield_now();
            }
            stop.store(true, Ordering::Relaxed);
            sampler.join().unwrap()
        });
        assert!(most <= bound, "{most} bytes seen in the directory, bound {bound}");
        assert!(most >= 6 * entry, "the cache did fill: {most} bytes at most");
        let held = dir_bytes(dir.path());
        assert_eq!(caches[0].bytes(), held, "the ledger counts the files' bytes");
        assert_eq!(caches[1].bytes(), held);
    }

    #[test]
    fn a_crash_between_writes_leaves_no_entry_served_and_the_ledger_repaired_at_open() {
        let dir = tempfile::tempdir().unwrap();
        let c = DiskCache::open(dir.path(), 1 << 20).unwrap();
        let k = key("http://h:1/obj", 0, 100);
        c.put(&k, &[5u8; 100]);
        let entry = (HEADER + k.len() + 100) as u64;
        assert_eq!(c.bytes(), entry);
        drop(c);
        // A writer killed after writing its temporary, and a ledger left counting nothing (as a
        // crash between a rename and a ledger update would leave an older format's).
        let torn = encode(&key("http://h:1/obj", 100, 100), &[6u8; 100]);
        std::fs::write(dir.path().join(format!("{}.tmp.999999.0", file_name(&k))), &torn[..50]).unwrap();
        std::fs::write(dir.path().join(LEDGER), [0u8; 16]).unwrap();
        let c = DiskCache::open(dir.path(), 1 << 20).unwrap();
        assert_eq!(c.bytes(), entry, "counted from the files again");
        assert_eq!(dir_bytes(dir.path()), entry, "the temporary is gone");
        let mut out = [0u8; 100];
        assert!(c.get(&k, &mut out) && out == [5u8; 100]);
        // A bound lowered at open holds at once.
        drop(c);
        let c = DiskCache::open(dir.path(), entry - 1).unwrap();
        assert_eq!((c.bytes(), dir_bytes(dir.path())), (0, 0));
    }

    #[test]
    fn whole_objects_round_trip_and_one_longer_than_asked_for_is_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let c = DiskCache::open(dir.path(), 1 << 20).unwrap();
        let k = object_key("http://h:1/3/1/2.png");
        assert_eq!(c.get_object(&k, 1000), None);
        assert!(!c.holds(&k));
        c.put(&k, b"\x89PNG tile bytes");
        assert!(c.holds(&k));
        assert_eq!(c.get_object(&k, 1000).as_deref(), Some(&b"\x89PNG tile bytes"[..]));
        assert_eq!(c.dropped(), 0);
        assert_eq!(c.get_object(&k, 4), None, "more bytes than a tile may have");
        assert_eq!((c.dropped(), c.holds(&k), c.bytes()), (1, false, 0));
        assert_ne!(file_name(&k), file_name(&key("http://h:1/3/1/2.png", 0, 17)), "a range's key differs");
    }
}
