//! The optional local disk cache of remote tiles (`CLIPMAP_REMOTE_CACHE_DIR`): one file per
//! range read, bounded in bytes, least recently used files removed first, kept across restarts.
//!
//! A file ([`encode`]) holds a magic number, the lengths of its key and its bytes, a checksum
//! (`checksum`) of both, the key (location, offset and length) and the bytes. Nothing in the
//! directory is trusted: a hit is served only when the file is a regular file of this user with
//! one name (opened without following a symbolic link and without blocking, so a FIFO or a link
//! to `/dev/zero` is neither waited on nor read), exactly as long as the range asked for needs
//! (checked before a byte is read, and no more is ever read), with the key asked for and a
//! checksum that matches. Anything else (a collision, a torn or altered file, a stranger's file,
//! a file of an older format) is dropped: removed, counted ([`DiskCache::dropped`]) and read
//! again from the store, never served.
//!
//! Files are written under a temporary name created with `O_EXCL | O_NOFOLLOW` (mode 0600), so
//! that a link or file planted at that name is never written through (the next name is tried),
//! then renamed, so a crash leaves no half file under a cache name. The directory is made 0700
//! when the cache makes it. The cache trusts the store not to change under it: clear the
//! directory when the objects are replaced.

use std::collections::HashMap;
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::os::unix::fs::{DirBuilderExt, FileExt, MetadataExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use rustix::fs::OFlags;

/// The cache key of a range.
pub fn key(location: &str, offset: u64, len: u64) -> String {
    format!("{location}\n{offset}\n{len}")
}

/// The first bytes of every cache file (the format's version is its last byte).
pub(crate) const MAGIC: [u8; 8] = *b"clipmapC";

/// Bytes before the key: magic, key length (u32), data length (u64), checksum (u64), all
/// little-endian.
pub(crate) const HEADER: usize = 8 + 4 + 8 + 8;

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

struct State {
    files: HashMap<String, (u64, u64)>,
    total: u64,
    clock: u64,
}

/// A bounded directory of cached ranges.
pub struct DiskCache {
    dir: PathBuf,
    bound: u64,
    state: Mutex<State>,
    tmp: AtomicU64,
    dropped: AtomicU64,
}

impl DiskCache {
    /// Opens (making it, mode 0700, if needed) the cache in `dir`, bounded to `bound` bytes;
    /// the regular files already there count, oldest first to go. A cache name (`*.tile`) that
    /// is not a regular file (a link, a FIFO) is dropped: removed, never followed, and counted.
    pub fn open(dir: &Path, bound: u64) -> io::Result<DiskCache> {
        std::fs::DirBuilder::new().recursive(true).mode(0o700).create(dir)?;
        let mut found = Vec::new();
        let mut dropped = 0;
        for e in std::fs::read_dir(dir)? {
            let e = e?;
            let name = e.file_name().to_string_lossy().into_owned();
            // Not followed: the entry itself.
            let meta = e.metadata()?;
            if !meta.is_file() {
                if name.ends_with(".tile") {
                    dropped += 1;
                    tracing::warn!(
                        file = %e.path().display(),
                        "remote disk cache: dropped a cached range ({}, not a regular file)",
                        crate::open::kind_of(&meta)
                    );
                    let _ = std::fs::remove_file(e.path());
                }
                continue;
            }
            if name.contains(".tmp.") {
                let _ = std::fs::remove_file(e.path());
                continue;
            }
            if name.ends_with(".tile") {
                let when = meta.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok());
                found.push((when.unwrap_or_default(), name, meta.len()));
            }
        }
        found.sort();
        let mut st = State { files: HashMap::new(), total: 0, clock: 0 };
        for (_, name, len) in found {
            st.clock += 1;
            st.total += len;
            st.files.insert(name, (len, st.clock));
        }
        let c = DiskCache {
            dir: dir.to_path_buf(),
            bound,
            state: Mutex::new(st),
            tmp: AtomicU64::new(0),
            dropped: AtomicU64::new(dropped),
        };
        c.evict(&mut c.state.lock().unwrap_or_else(|e| e.into_inner()));
        Ok(c)
    }

    /// Bytes held now.
    pub fn bytes(&self) -> u64 {
        self.state.lock().unwrap_or_else(|e| e.into_inner()).total
    }

    /// Cached ranges dropped since the cache was opened (by [`DiskCache::open`] too) because
    /// their file failed a check.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    fn evict(&self, st: &mut State) {
        while st.total > self.bound {
            let Some(oldest) = st.files.iter().min_by_key(|(_, (_, used))| *used).map(|(n, _)| n.clone()) else {
                break;
            };
            if let Some((len, _)) = st.files.remove(&oldest) {
                st.total -= len;
            }
            let _ = std::fs::remove_file(self.dir.join(&oldest));
        }
    }

    /// Fills `out` from the cache when it holds exactly this range, checked; returns whether
    /// it did. A file that fails a check is dropped (removed and counted), `out` is zeroed and
    /// the range is a miss.
    pub fn get(&self, key: &str, out: &mut [u8]) -> bool {
        let name = file_name(key);
        {
            let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
            st.clock += 1;
            let now = st.clock;
            match st.files.get_mut(&name) {
                Some(e) => e.1 = now,
                None => return false,
            }
        }
        let path = self.dir.join(&name);
        let Err(why) = read_entry(&path, key, out) else { return true };
        out.fill(0);
        self.dropped.fetch_add(1, Ordering::Relaxed);
        tracing::warn!(file = %path.display(), "remote disk cache: dropped a cached range ({why}); it is read again");
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((len, _)) = st.files.remove(&name) {
            st.total -= len;
        }
        let _ = std::fs::remove_file(&path);
        false
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

    /// Stores a range (best effort: a full disk, or names taken by others, only mean a later
    /// miss).
    pub fn put(&self, key: &str, data: &[u8]) {
        let name = file_name(key);
        let bytes = encode(key, data);
        if bytes.len() as u64 > self.bound {
            return;
        }
        let Some((tmp, mut file)) = self.temporary(&name) else { return };
        let written = file.write_all(&bytes).is_ok();
        drop(file);
        if !written || std::fs::rename(&tmp, self.dir.join(&name)).is_err() {
            let _ = std::fs::remove_file(&tmp);
            return;
        }
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        st.clock += 1;
        let now = st.clock;
        if let Some((old, _)) = st.files.insert(name, (bytes.len() as u64, now)) {
            st.total -= old;
        }
        st.total += bytes.len() as u64;
        self.evict(&mut st);
    }
}

/// Reads the entry at `path` into `out` when it passes every check; otherwise says which failed.
fn read_entry(path: &Path, key: &str, out: &mut [u8]) -> Result<(), String> {
    let file = OpenOptions::new()
        .read(true)
        .custom_flags((OFlags::NOFOLLOW | OFlags::NONBLOCK | OFlags::CLOEXEC).bits() as i32)
        .open(path)
        .map_err(|e| match e.raw_os_error() {
            Some(n) if n == rustix::io::Errno::LOOP.raw_os_error() => "a symbolic link".to_string(),
            _ => format!("cannot be opened: {e}"),
        })?;
    let meta = file.metadata().map_err(|e| format!("cannot be examined: {e}"))?;
    if !meta.is_file() {
        return Err(format!("{}, not a regular file", crate::open::kind_of(&meta)));
    }
    let me = rustix::process::geteuid().as_raw();
    if meta.uid() != me {
        return Err(format!("owned by uid {}, not by this user (uid {me})", meta.uid()));
    }
    if meta.nlink() != 1 {
        return Err(format!("a file with {} names (hard links)", meta.nlink()));
    }
    let want = (HEADER + key.len() + out.len()) as u64;
    if meta.len() != want {
        return Err(format!("{} bytes, expected {want} for this range", meta.len()));
    }
    let mut head = vec![0u8; HEADER + key.len()];
    file.read_exact_at(&mut head, 0).map_err(|e| format!("cannot be read: {e}"))?;
    file.read_exact_at(out, head.len() as u64).map_err(|e| format!("cannot be read: {e}"))?;
    let u64_at = |at: usize| u64::from_le_bytes(head[at..at + 8].try_into().unwrap_or([0; 8]));
    if head[..8] != MAGIC {
        return Err("not a cache file of this format".into());
    }
    let klen = u32::from_le_bytes(head[8..12].try_into().unwrap_or([0; 4])) as usize;
    if klen != key.len() || u64_at(12) != out.len() as u64 || &head[HEADER..] != key.as_bytes() {
        return Err("the entry of another range".into());
    }
    if u64_at(20) != checksum(key.as_bytes(), out) {
        return Err("its checksum does not match its bytes".into());
    }
    Ok(())
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
}
