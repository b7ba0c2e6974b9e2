//! The writer side: creates the texel mapping and the request mapping (owner-only unless told
//! otherwise, fully initialised before they become visible under their names), holds the
//! per-name lock, hands the engine the mapping as its image caches ([`ImageMemory`]), beats the
//! heartbeat, and reads renderers' centre requests.

use super::layout::{self, header, request, Placement, Shape};
use super::memory::{shape_error, ImageMemory};
use super::raw::Region;
use super::{check_name, io, lock_path, map_path, names, request_path, ShmError};
use crate::texel::TexelFormat;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{fence, Ordering};
use std::sync::Arc;

/// A renderer's request.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Request {
    /// Requested centre, level-0 texels.
    pub centre: [i64; 2],
    /// Velocity, level-0 texels per second.
    pub velocity: [f64; 2],
    /// Requests made so far.
    pub count: u64,
}

/// The writer of one mapping.
pub struct Writer {
    memory: Arc<ImageMemory>,
    requests: Region,
    path: PathBuf,
    req_path: PathBuf,
    lock_path: PathBuf,
    _lock: File,
    lock_id: names::Identity,
    map_id: names::Identity,
    req_id: names::Identity,
}

impl std::fmt::Debug for Writer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Writer").field("path", &self.path).field("shape", self.memory.shape()).finish()
    }
}

fn now_ms() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_millis() as u64).unwrap_or(0)
}

impl Writer {
    /// Creates the mappings of `name` in `dir` for a texture of `shape`: the texel mapping with
    /// permission bits `mode` (0o600 by default: owner only) and the request mapping with
    /// `request_mode`. Refuses when a live service holds the name; takes over cleanly from one
    /// that died (its lock died with it).
    pub fn create(
        dir: &Path,
        name: &str,
        shape: Shape,
        format: TexelFormat,
        mode: u32,
        request_mode: u32,
        tick_period_ns: u64,
    ) -> Result<Writer, ShmError> {
        check_name(name)?;
        let placement = layout::place(&shape).ok_or_else(|| ShmError::Shape(shape_error(&shape)))?;
        let lock_path = lock_path(dir, name);
        let lock = open_lock(&lock_path, mode)?;
        match lock.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => return Err(held(&lock, &lock_path, name)),
            Err(std::fs::TryLockError::Error(e)) => return Err(ShmError::Io { path: lock_path, source: e }),
        }
        // Ours (checked by `open_lock`) and locked by us: record our pid, nothing else.
        lock.set_len(0).map_err(io(&lock_path))?;
        lock.write_all_at(std::process::id().to_string().as_bytes(), 0).map_err(io(&lock_path))?;
        let lock_id = names::Identity::of(&lock.metadata().map_err(io(&lock_path))?);

        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        let generation = crate::source::procedural::splitmix64(nanos ^ ((std::process::id() as u64) << 40));

        // The request mapping first: once the texel mapping appears, its companion is there.
        let req_path = request_path(dir, name);
        let (req_tmp, req_file) = create_tmp(dir, name, "req", request_mode)?;
        let made = (|| {
            req_file.set_len(layout::REQUEST_BYTES).map_err(io(&req_tmp))?;
            let region = Region::map(&req_file).map_err(io(&req_tmp))?;
            region.write(request::VERSION, &layout::VERSION.to_le_bytes());
            region.write(request::GENERATION, &generation.to_le_bytes());
            std::sync::atomic::fence(Ordering::Release);
            region.write(request::MAGIC, &layout::REQUEST_MAGIC);
            let id = names::Identity::of(&req_file.metadata().map_err(io(&req_tmp))?);
            Ok::<_, ShmError>((region, id))
        })();
        let (requests, req_id) = match made.and_then(|r| place_file(&req_tmp, &req_path).map(|()| r)) {
            Ok(r) => r,
            Err(e) => {
                let _ = std::fs::remove_file(&req_tmp);
                return Err(e);
            }
        };

        let path = map_path(dir, name);
        let (tmp, file) = match create_tmp(dir, name, "map", mode) {
            Ok(x) => x,
            Err(e) => {
                names::remove_if_same(&req_path, req_id);
                return Err(e);
            }
        };
        let made = (|| {
            file.set_len(placement.total_bytes).map_err(io(&tmp))?;
            let region = Region::map_populated(&file).map_err(io(&tmp))?;
            let id = names::Identity::of(&file.metadata().map_err(io(&tmp))?);
            Ok::<_, ShmError>((region, id))
        })();
        let (region, map_id) = match made {
            Ok(r) => r,
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                names::remove_if_same(&req_path, req_id);
                return Err(e);
            }
        };
        let memory = ImageMemory::over(region, placement, shape);
        memory.init(format, tick_period_ns, generation);
        memory.region().store(header::HEARTBEAT_MS, now_ms(), Ordering::Relaxed);
        // Visible under its name only once complete; readers of a previous mapping keep theirs.
        if let Err(e) = place_file(&tmp, &path) {
            let _ = std::fs::remove_file(&tmp);
            names::remove_if_same(&req_path, req_id);
            // The lock file is ours and held: leave it for the next start (it is not removed,
            // so a service starting meanwhile never holds a lock on an unlinked file).
            return Err(e);
        }
        Ok(Writer {
            memory: Arc::new(memory),
            requests,
            path,
            req_path,
            lock_path,
            _lock: lock,
            lock_id,
            map_id,
            req_id,
        })
    }

    /// The texel mapping's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The request mapping's path.
    pub fn request_path(&self) -> &Path {
        &self.req_path
    }

    /// The shape.
    pub fn shape(&self) -> &Shape {
        self.memory.shape()
    }

    /// Where every level lies.
    pub fn placement(&self) -> &Placement {
        self.memory.placement()
    }

    /// The mapping as the engine's image caches ([`crate::clip::Clipmap::with_memory`]): tiles are
    /// read straight into their slots, where renderers read them.
    pub fn memory(&self) -> Arc<ImageMemory> {
        Arc::clone(&self.memory)
    }

    /// Beats the heartbeat: readers judge the service alive while it moves.
    pub fn heartbeat(&self) {
        let r = self.memory.region();
        r.fetch_add(header::HEARTBEAT, 1, Ordering::Relaxed);
        r.store(header::HEARTBEAT_MS, now_ms(), Ordering::Release);
    }

    /// How many requests renderers have made so far (one atomic load: cheap enough to poll
    /// while waiting for the next tick).
    pub fn request_count(&self) -> u64 {
        self.requests.load(request::COUNT, Ordering::Acquire)
    }

    /// Reads the latest renderer request, if a consistent one is there.
    pub fn request(&self) -> Option<Request> {
        let r = &self.requests;
        for _ in 0..layout::MAX_RETRIES {
            let s1 = r.load(request::SEQ, Ordering::Acquire);
            if s1 & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let cs = r.load(request::CENTRE_S, Ordering::Relaxed) as i64;
            let ct = r.load(request::CENTRE_T, Ordering::Relaxed) as i64;
            let vs = f64::from_bits(r.load(request::VEL_S, Ordering::Relaxed));
            let vt = f64::from_bits(r.load(request::VEL_T, Ordering::Relaxed));
            let count = r.load(request::COUNT, Ordering::Relaxed);
            fence(Ordering::Acquire);
            if r.load(request::SEQ, Ordering::Relaxed) == s1 {
                return (count > 0).then_some(Request { centre: [cs, ct], velocity: [vs, vt], count });
            }
        }
        None
    }

    /// Marks a clean shutdown and removes the names (readers keep their mappings and see the
    /// flag).
    pub fn close(self) {
        let r = self.memory.region();
        r.store(header::FLAGS, 1, Ordering::Release);
        r.store(header::HEARTBEAT_MS, now_ms(), Ordering::Release);
        names::remove_if_same(&self.path, self.map_id);
        names::remove_if_same(&self.req_path, self.req_id);
        names::remove_if_same(&self.lock_path, self.lock_id);
    }
}

/// Renames a finished temporary file into place: a previous file there is replaced only when it
/// is a regular file of this user (a dead service's); anything else is refused and left alone.
fn place_file(tmp: &Path, path: &Path) -> Result<(), ShmError> {
    match std::fs::symlink_metadata(path) {
        Ok(m) => names::check_own_file(path, &m).and_then(|()| std::fs::rename(tmp, path).map_err(io(path))),
        Err(_) => names::rename_no_replace(tmp, path).map_err(io(path)),
    }
}

/// Opens (creating it with exactly `mode` if absent) the lock file of a name: never through a
/// symbolic link, never a file that is not a regular file of this user.
fn open_lock(path: &Path, mode: u32) -> Result<File, ShmError> {
    match names::create_new(path, mode) {
        Ok(f) => Ok(f),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => names::open_own(path),
        Err(e) => Err(ShmError::Io { path: path.to_path_buf(), source: e }),
    }
}

/// The error for a lock somebody else holds: the service it names when the pid it records is a
/// live process, else a squatter that is named as such (no invented pid).
fn held(lock: &File, path: &Path, name: &str) -> ShmError {
    let mut buf = [0u8; 24];
    let n = lock.read_at(&mut buf, 0).unwrap_or(0);
    let recorded = String::from_utf8_lossy(&buf[..n]).trim().to_string();
    match recorded.parse::<u32>() {
        Ok(pid) if pid > 0 && Path::new(&format!("/proc/{pid}")).exists() => {
            ShmError::AlreadyRunning { name: name.to_string(), pid }
        }
        _ => ShmError::LockHeld { path: path.to_path_buf(), recorded },
    }
}

/// Creates a mapping's temporary file `.clipmap-NAME.EXT.PID.N` with exactly `mode`, never
/// replacing (or removing) a file that is already there: another number is tried instead.
fn create_tmp(dir: &Path, name: &str, ext: &str, mode: u32) -> Result<(PathBuf, File), ShmError> {
    let pid = std::process::id();
    let mut last = None;
    for n in 0..16 {
        let tmp = dir.join(format!(".clipmap-{name}.{ext}.{pid}.{n}"));
        match names::create_new(&tmp, mode) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some((tmp, e)),
            Err(e) => return Err(ShmError::Io { path: tmp, source: e }),
        }
    }
    let (path, source) = last.expect("tried at least once");
    Err(ShmError::Io { path, source })
}
