//! The writer side: creates the mapping (owner-only, fully initialised before it becomes visible
//! under its name), holds the per-name lock, publishes level states under seqlocks, writes texels
//! outside published regions, beats the heartbeat, and reads renderers' centre requests.

use super::layout::{self, desc, header, request, state, Placement, Shape};
use super::raw::Region;
use super::{check_name, io, lock_path, map_path, names, ShmError};
use crate::clip::WindowStore;
use crate::texel::TexelFormat;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{fence, Ordering};
use std::sync::Arc;

/// What a level state says.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PublishedLevel {
    /// Level centre.
    pub centre: [i64; 2],
    /// Valid region, half-open `[s0, s1) x [t0, t1)`.
    pub valid: [i64; 4],
    /// Renderers may use the level.
    pub enabled: bool,
    /// Invalid border in use.
    pub invalid_border: u64,
}

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
    region: Arc<Region>,
    placement: Placement,
    shape: Shape,
    path: PathBuf,
    lock_path: PathBuf,
    _lock: File,
    lock_id: names::Identity,
    map_id: names::Identity,
    tick: u64,
}

impl std::fmt::Debug for Writer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Writer").field("path", &self.path).field("shape", &self.shape).finish()
    }
}

fn now_ms() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_millis() as u64).unwrap_or(0)
}

impl Writer {
    /// Creates the mapping `name` in `dir` for a texture of `shape`, with permission bits `mode`
    /// (0o600 by default: owner only). Refuses when a live service holds the name; takes over
    /// cleanly from one that died (its lock died with it).
    pub fn create(dir: &Path, name: &str, shape: Shape, format: TexelFormat, mode: u32) -> Result<Writer, ShmError> {
        check_name(name)?;
        let placement = layout::place(&shape).ok_or_else(|| {
            ShmError::Shape(format!(
                "{} levels, clip {}, {} bytes per texel",
                shape.levels.len(),
                shape.clip_size,
                shape.bytes_per_texel
            ))
        })?;
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

        let path = map_path(dir, name);
        let (tmp, file) = create_tmp(dir, name, mode)?;
        let made = (|| {
            file.set_len(placement.total_bytes).map_err(io(&tmp))?;
            let region = Region::map(&file).map_err(io(&tmp))?;
            let id = names::Identity::of(&file.metadata().map_err(io(&tmp))?);
            Ok::<_, ShmError>((region, id))
        })();
        let (region, map_id) = match made {
            Ok(r) => r,
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                return Err(e);
            }
        };
        let w = Writer {
            region: Arc::new(region),
            placement,
            shape,
            path: path.clone(),
            lock_path,
            _lock: lock,
            lock_id,
            map_id,
            tick: 0,
        };
        w.init(format);
        // Visible under its name only once complete; readers of a previous mapping keep theirs.
        // A previous mapping is replaced only when it is a regular file of this user (a dead
        // service's); anything else there is refused and left alone.
        let placed = match std::fs::symlink_metadata(&path) {
            Ok(m) => names::check_own_file(&path, &m).and_then(|()| std::fs::rename(&tmp, &path).map_err(io(&path))),
            Err(_) => names::rename_no_replace(&tmp, &path).map_err(io(&path)),
        };
        if let Err(e) = placed {
            let _ = std::fs::remove_file(&tmp);
            // The lock file is ours and held: leave it for the next start (it is not removed,
            // so a service starting meanwhile never holds a lock on an unlinked file).
            return Err(e);
        }
        Ok(w)
    }

    fn init(&self, format: TexelFormat) {
        let r = &self.region;
        let put32 = |off: usize, v: u32| r.write(off, &v.to_le_bytes());
        let put64 = |off: usize, v: u64| r.write(off, &v.to_le_bytes());
        put32(header::VERSION, layout::VERSION);
        put32(header::HEADER_BYTES, self.placement.header_bytes as u32);
        put64(header::TOTAL_BYTES, self.placement.total_bytes);
        put32(header::TEXEL_FORMAT, layout::format_code(format));
        put32(header::BYTES_PER_TEXEL, self.shape.bytes_per_texel as u32);
        put32(header::CLIP_SIZE, self.shape.clip_size as u32);
        put32(header::LEVEL_COUNT, self.shape.levels.len() as u32);
        put64(header::LEVEL0_S, self.shape.levels[0][0]);
        put64(header::LEVEL0_T, self.shape.levels[0][1]);
        put32(header::WRITER_PID, std::process::id());
        put32(header::FLAGS, 0);
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        let generation = crate::source::procedural::splitmix64(nanos ^ ((std::process::id() as u64) << 40));
        put64(header::GENERATION, generation);
        for (i, (lvl, w)) in self.shape.levels.iter().zip(&self.placement.windows).enumerate() {
            let base = header::LEVEL_DESCS + i * layout::DESC_BYTES;
            put64(base + desc::SIZE_S, lvl[0]);
            put64(base + desc::SIZE_T, lvl[1]);
            put64(base + desc::WINDOW_OFFSET, w.offset);
            put64(base + desc::WINDOW_BYTES, w.bytes);
            put64(base + desc::WINDOW_S, w.s);
            put64(base + desc::WINDOW_T, w.t);
            put64(base + desc::KIND, w.kind);
        }
        r.store(header::HEARTBEAT_MS, now_ms(), Ordering::Relaxed);
        fence(Ordering::Release);
        r.write(header::MAGIC, &layout::MAGIC);
    }

    /// The mapping's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The shape.
    pub fn shape(&self) -> &Shape {
        &self.shape
    }

    /// The placement of every window.
    pub fn placement(&self) -> &Placement {
        &self.placement
    }

    fn state_base(level: usize) -> usize {
        header::LEVEL_STATES + level * layout::STATE_BYTES
    }

    /// Publishes a level's state under its seqlock.
    pub fn publish(&self, level: usize, st: &PublishedLevel) {
        let base = Self::state_base(level);
        let r = &self.region;
        let seq = r.load(base + state::SEQ, Ordering::Relaxed);
        r.store(base + state::SEQ, seq.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        let clip = self.shape.clip_size;
        r.store(base + state::CENTRE_S, st.centre[0] as u64, Ordering::Relaxed);
        r.store(base + state::CENTRE_T, st.centre[1] as u64, Ordering::Relaxed);
        for (i, v) in st.valid.iter().enumerate() {
            r.store(base + state::VALID_S0 + 8 * i, *v as u64, Ordering::Relaxed);
        }
        r.store(base + state::ENABLED, u64::from(st.enabled), Ordering::Relaxed);
        r.store(base + state::INVALID_BORDER, st.invalid_border, Ordering::Relaxed);
        r.store(base + state::UPDATED_TICK, self.tick, Ordering::Relaxed);
        r.store(base + state::ORIGIN_S, st.valid[0].rem_euclid(clip as i64) as u64, Ordering::Relaxed);
        r.store(base + state::ORIGIN_T, st.valid[1].rem_euclid(clip as i64) as u64, Ordering::Relaxed);
        r.store(base + state::SEQ, seq.wrapping_add(2), Ordering::Release);
    }

    /// Publishes the global state (min LOD) for `tick`.
    pub fn publish_global(&mut self, min_lod: f64, tick: u64) {
        let r = &self.region;
        let seq = r.load(header::GLOBAL_SEQ, Ordering::Relaxed);
        r.store(header::GLOBAL_SEQ, seq.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        r.store(header::MIN_LOD, min_lod.to_bits(), Ordering::Relaxed);
        r.store(header::TICK, tick, Ordering::Relaxed);
        r.store(header::GLOBAL_SEQ, seq.wrapping_add(2), Ordering::Release);
        self.tick = tick;
    }

    /// Writes texels into a level's window at a byte offset within the window. The caller
    /// guarantees the bytes lie outside the level's published valid region.
    pub fn write_window(&self, level: usize, byte_offset: u64, src: &[u8]) {
        let w = &self.placement.windows[level];
        assert!(byte_offset + src.len() as u64 <= w.bytes, "write outside level {level}'s window");
        self.region.write((w.offset + byte_offset) as usize, src);
    }

    /// One store per level that writes straight into the level's window of the mapping, for the
    /// engine to keep its windows in ([`crate::clip::Clipmap::with_windows`]): texels are then
    /// written once, where readers read them. The engine keeps the invariant (it writes only
    /// outside what it has published, and [`super::mirror::Mirror`] publishes no more than the
    /// engine).
    pub fn window_stores(&self) -> Vec<Box<dyn WindowStore>> {
        self.placement
            .windows
            .iter()
            .map(|w| {
                Box::new(SharedWindow {
                    region: Arc::clone(&self.region),
                    offset: w.offset as usize,
                    len: w.bytes as usize,
                }) as Box<dyn WindowStore>
            })
            .collect()
    }

    /// Beats the heartbeat: readers judge the service alive while it moves.
    pub fn heartbeat(&self) {
        self.region.fetch_add(header::HEARTBEAT, 1, Ordering::Relaxed);
        self.region.store(header::HEARTBEAT_MS, now_ms(), Ordering::Release);
    }

    /// How many requests renderers have made so far (one atomic load: cheap enough to poll
    /// while waiting for the next tick).
    pub fn request_count(&self) -> u64 {
        self.region.load(header::REQUEST + request::COUNT, Ordering::Acquire)
    }

    /// Reads the latest renderer request, if a consistent one is there.
    pub fn request(&self) -> Option<Request> {
        let r = &self.region;
        let b = header::REQUEST;
        for _ in 0..64 {
            let s1 = r.load(b + request::SEQ, Ordering::Acquire);
            if s1 & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let cs = r.load(b + request::CENTRE_S, Ordering::Relaxed) as i64;
            let ct = r.load(b + request::CENTRE_T, Ordering::Relaxed) as i64;
            let vs = f64::from_bits(r.load(b + request::VEL_S, Ordering::Relaxed));
            let vt = f64::from_bits(r.load(b + request::VEL_T, Ordering::Relaxed));
            let count = r.load(b + request::COUNT, Ordering::Relaxed);
            fence(Ordering::Acquire);
            if r.load(b + request::SEQ, Ordering::Relaxed) == s1 {
                return (count > 0).then_some(Request { centre: [cs, ct], velocity: [vs, vt], count });
            }
        }
        None
    }

    /// Marks a clean shutdown and removes the name (readers keep their mapping and see the flag).
    pub fn close(self) {
        self.region.write(header::FLAGS, &1u32.to_le_bytes());
        self.region.store(header::HEARTBEAT_MS, now_ms(), Ordering::Release);
        names::remove_if_same(&self.path, self.map_id);
        names::remove_if_same(&self.lock_path, self.lock_id);
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

/// Creates the mapping's temporary file `.clipmap-NAME.map.PID.N` with exactly `mode`, never
/// replacing (or removing) a file that is already there: another number is tried instead.
fn create_tmp(dir: &Path, name: &str, mode: u32) -> Result<(PathBuf, File), ShmError> {
    let pid = std::process::id();
    let mut last = None;
    for n in 0..16 {
        let tmp = dir.join(format!(".clipmap-{name}.map.{pid}.{n}"));
        match names::create_new(&tmp, mode) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some((tmp, e)),
            Err(e) => return Err(ShmError::Io { path: tmp, source: e }),
        }
    }
    let (path, source) = last.expect("tried at least once");
    Err(ShmError::Io { path, source })
}

/// A level's window inside the mapping, as engine memory.
struct SharedWindow {
    region: Arc<Region>,
    offset: usize,
    len: usize,
}

impl std::fmt::Debug for SharedWindow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SharedWindow").field("offset", &self.offset).field("len", &self.len).finish()
    }
}

impl WindowStore for SharedWindow {
    fn len(&self) -> usize {
        self.len
    }

    fn write(&mut self, at: usize, src: &[u8]) {
        assert!(at + src.len() <= self.len, "write outside a window of {} bytes", self.len);
        self.region.write(self.offset + at, src);
    }

    fn read(&self, at: usize, out: &mut [u8]) {
        assert!(at + out.len() <= self.len, "read outside a window of {} bytes", self.len);
        self.region.read(self.offset + at, out);
    }
}
