//! The optional local disk cache of remote tiles (`CLIPMAP_REMOTE_CACHE_DIR`): one file per
//! range read, bounded in bytes, least recently used files removed first, kept across restarts.
//!
//! A file holds the length of its key, the key (location, offset and length) and the bytes; a
//! hit is served only when the stored key is the one asked for and the bytes are exactly one
//! range long, so a collision, a torn file or a stranger's file is a miss (and is removed).
//! Files are written under a temporary name and renamed, so a crash leaves no half file under a
//! cache name. The cache trusts the store not to change under it: clear the directory when
//! the objects are replaced.

use std::collections::HashMap;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

/// The cache key of a range.
pub fn key(location: &str, offset: u64, len: u64) -> String {
    format!("{location}\n{offset}\n{len}")
}

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
}

impl DiskCache {
    /// Opens (making it if needed) the cache in `dir`, bounded to `bound` bytes; the files
    /// already there count, oldest first to go.
    pub fn open(dir: &Path, bound: u64) -> io::Result<DiskCache> {
        std::fs::create_dir_all(dir)?;
        let mut found = Vec::new();
        for e in std::fs::read_dir(dir)? {
            let e = e?;
            let name = e.file_name().to_string_lossy().into_owned();
            let meta = e.metadata()?;
            if !meta.is_file() {
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
        let c = DiskCache { dir: dir.to_path_buf(), bound, state: Mutex::new(st), tmp: AtomicU64::new(0) };
        c.evict(&mut c.state.lock().unwrap_or_else(|e| e.into_inner()));
        Ok(c)
    }

    /// Bytes held now.
    pub fn bytes(&self) -> u64 {
        self.state.lock().unwrap_or_else(|e| e.into_inner()).total
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

    /// Fills `out` from the cache when it holds exactly this range.
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
        let ok = std::fs::read(&path).ok().is_some_and(|bytes| {
            let klen = bytes.get(..4).map_or(usize::MAX, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize);
            let body = 4usize.saturating_add(klen);
            let matches = bytes.len() == body.saturating_add(out.len()) && bytes.get(4..body) == Some(key.as_bytes());
            if matches {
                out.copy_from_slice(&bytes[body..]);
            }
            matches
        });
        if !ok {
            let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
            if let Some((len, _)) = st.files.remove(&name) {
                st.total -= len;
            }
            let _ = std::fs::remove_file(&path);
        }
        ok
    }

    /// Stores a range (best effort: a full disk only means a later miss).
    pub fn put(&self, key: &str, data: &[u8]) {
        let name = file_name(key);
        let mut bytes = Vec::with_capacity(4 + key.len() + data.len());
        bytes.extend_from_slice(&(key.len() as u32).to_le_bytes());
        bytes.extend_from_slice(key.as_bytes());
        bytes.extend_from_slice(data);
        if bytes.len() as u64 > self.bound {
            return;
        }
        let n = self.tmp.fetch_add(1, Ordering::Relaxed);
        let tmp = self.dir.join(format!("{name}.tmp.{}.{n}", std::process::id()));
        if std::fs::write(&tmp, &bytes).is_err() || std::fs::rename(&tmp, self.dir.join(&name)).is_err() {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_survive_a_reopen_and_the_bound_removes_the_least_recently_used() {
        let dir = tempfile::tempdir().unwrap();
        // Room for three files: 4 bytes of key length, a key of up to 22 bytes, 100 bytes.
        let c = DiskCache::open(dir.path(), 3 * (4 + 22 + 100)).unwrap();
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
}
