//! The reader side: attach to a mapping (checking magic, version and every size before trusting
//! anything), take consistent snapshots of the level states, read texels inside published valid
//! regions, request a centre, and notice a stale or replaced service.

use super::layout::{self, desc, header, request, state};
use super::raw::Region;
use super::{check_name, map_path, ShmError};
use std::fs::OpenOptions;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{fence, Ordering};
use std::time::Duration;

/// One level's static description.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelDesc {
    /// Level size.
    pub size: [u64; 2],
    /// Window byte offset in the mapping.
    pub offset: u64,
    /// Window bytes.
    pub bytes: u64,
    /// Window size in texels.
    pub window: [u64; 2],
    /// True for pyramid levels (resident whole).
    pub pyramid: bool,
}

/// One level's published state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LevelState {
    /// Sequence number it was read at (even).
    pub seq: u64,
    /// Centre.
    pub centre: [i64; 2],
    /// Valid region `[s0, s1) x [t0, t1)`.
    pub valid: [i64; 4],
    /// Renderers may use the level.
    pub enabled: bool,
    /// Invalid border.
    pub invalid_border: u64,
    /// Tick of the last change.
    pub updated_tick: u64,
}

impl LevelState {
    /// Whether (s, t) is inside the valid region.
    pub fn contains(&self, s: i64, t: i64) -> bool {
        self.enabled && s >= self.valid[0] && s < self.valid[2] && t >= self.valid[1] && t < self.valid[3]
    }
}

/// A consistent copy of every level's state.
#[derive(Clone, Debug, Default)]
pub struct Snapshot {
    /// Finest level renderers may use.
    pub min_lod: f64,
    /// Tick of the global state.
    pub tick: u64,
    /// Per level.
    pub levels: Vec<LevelState>,
}

/// Why a read failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReadError {
    /// The level does not exist.
    #[error("level {0} does not exist")]
    NoLevel(usize),
    /// The region is not inside the published valid region (right now).
    #[error("the region is not inside level {0}'s published valid region")]
    NotValid(usize),
    /// The writer kept changing the level; try again or use a coarser level.
    #[error("level {0} kept changing while it was read")]
    Busy(usize),
}

/// A reader attached to one mapping.
pub struct Client {
    region: Region,
    path: PathBuf,
    inode: (u64, u64),
    /// Bytes per texel.
    pub bytes_per_texel: usize,
    /// Clip size.
    pub clip_size: u64,
    /// Texel format code.
    pub format_code: u32,
    /// Per level.
    pub levels: Vec<LevelDesc>,
    /// The writer's generation at attach time.
    pub generation: u64,
}

impl std::fmt::Debug for Client {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Client").field("path", &self.path).field("levels", &self.levels.len()).finish()
    }
}

fn invalid(path: &Path, reason: impl Into<String>) -> ShmError {
    ShmError::Invalid { path: path.to_path_buf(), reason: reason.into() }
}

impl Client {
    /// Attaches to the mapping `name` in `dir`.
    pub fn attach(dir: &Path, name: &str) -> Result<Client, ShmError> {
        check_name(name)?;
        let path = map_path(dir, name);
        if !path.exists() {
            return Err(ShmError::NotFound { name: name.to_string(), dir: dir.to_path_buf() });
        }
        Self::attach_path(&path)
    }

    /// Attaches to a mapping file.
    pub fn attach_path(path: &Path) -> Result<Client, ShmError> {
        let file = OpenOptions::new().read(true).write(true).open(path).map_err(super::io(path))?;
        let meta = file.metadata().map_err(super::io(path))?;
        if (meta.len() as usize) < layout::header::END {
            return Err(invalid(
                path,
                format!("truncated: {} bytes, a mapping has at least {}", meta.len(), layout::header::END),
            ));
        }
        let region = Region::map(&file).map_err(super::io(path))?;
        let mut magic = [0u8; 8];
        region.read(header::MAGIC, &mut magic);
        fence(Ordering::Acquire);
        if magic != layout::MAGIC {
            return Err(invalid(
                path,
                format!("wrong magic {magic:02x?}: not a clipmap mapping (expected \"CLIPMAP1\")"),
            ));
        }
        let version = region.read_u32(header::VERSION);
        if version != layout::VERSION {
            return Err(invalid(
                path,
                format!("layout version {version}; this client reads version {}", layout::VERSION),
            ));
        }
        let total = region.read_u64(header::TOTAL_BYTES);
        if total != meta.len() {
            return Err(invalid(path, format!("the header says {total} bytes but the file has {}", meta.len())));
        }
        let bpt = region.read_u32(header::BYTES_PER_TEXEL) as u64;
        let clip = region.read_u32(header::CLIP_SIZE) as u64;
        let count = region.read_u32(header::LEVEL_COUNT) as usize;
        if bpt == 0 || bpt > 64 || clip == 0 || count == 0 || count > layout::MAX_LEVELS {
            return Err(invalid(
                path,
                format!("implausible header: {bpt} bytes per texel, clip {clip}, {count} levels"),
            ));
        }
        let header_bytes = region.read_u32(header::HEADER_BYTES) as u64;
        let mut levels = Vec::with_capacity(count);
        for i in 0..count {
            let b = header::LEVEL_DESCS + i * layout::DESC_BYTES;
            let d = LevelDesc {
                size: [region.read_u64(b + desc::SIZE_S), region.read_u64(b + desc::SIZE_T)],
                offset: region.read_u64(b + desc::WINDOW_OFFSET),
                bytes: region.read_u64(b + desc::WINDOW_BYTES),
                window: [region.read_u64(b + desc::WINDOW_S), region.read_u64(b + desc::WINDOW_T)],
                pyramid: region.read_u64(b + desc::KIND) == 1,
            };
            let want = d.window[0].checked_mul(d.window[1]).and_then(|x| x.checked_mul(bpt));
            let end = d.offset.checked_add(d.bytes);
            let ok = want == Some(d.bytes)
                && end.is_some_and(|e| e <= total)
                && d.offset >= header_bytes
                && d.offset % layout::PAGE == 0
                && levels.last().is_none_or(|p: &LevelDesc| p.offset + p.bytes <= d.offset)
                && d.window[0] == d.size[0].min(clip)
                && d.window[1] == d.size[1].min(clip);
            if !ok {
                return Err(invalid(path, format!("level {i}'s window description is inconsistent: {d:?}")));
            }
            levels.push(d);
        }
        Ok(Client {
            inode: (meta.dev(), meta.ino()),
            generation: region.read_u64(header::GENERATION),
            format_code: region.read_u32(header::TEXEL_FORMAT),
            region,
            path: path.to_path_buf(),
            bytes_per_texel: bpt as usize,
            clip_size: clip,
            levels,
        })
    }

    /// The mapping file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Reads one level's state consistently (`None` if the writer kept it busy).
    pub fn level_state(&self, level: usize) -> Option<LevelState> {
        let b = header::LEVEL_STATES + level * layout::STATE_BYTES;
        let r = &self.region;
        for _ in 0..1000 {
            let s1 = r.load(b + state::SEQ, Ordering::Acquire);
            if s1 & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let g = |o: usize| r.load(b + o, Ordering::Relaxed);
            let st = LevelState {
                seq: s1,
                centre: [g(state::CENTRE_S) as i64, g(state::CENTRE_T) as i64],
                valid: [
                    g(state::VALID_S0) as i64,
                    g(state::VALID_T0) as i64,
                    g(state::VALID_S1) as i64,
                    g(state::VALID_T1) as i64,
                ],
                enabled: g(state::ENABLED) == 1,
                invalid_border: g(state::INVALID_BORDER),
                updated_tick: g(state::UPDATED_TICK),
            };
            fence(Ordering::Acquire);
            if r.load(b + state::SEQ, Ordering::Relaxed) == s1 {
                return Some(st);
            }
        }
        None
    }

    /// A consistent copy of every level's state (each level consistent on its own, as the writer
    /// publishes levels one by one).
    pub fn snapshot(&self) -> Snapshot {
        let r = &self.region;
        let (mut min_lod, mut tick) = (0.0, 0);
        for _ in 0..1000 {
            let s1 = r.load(header::GLOBAL_SEQ, Ordering::Acquire);
            if s1 & 1 == 1 {
                continue;
            }
            min_lod = f64::from_bits(r.load(header::MIN_LOD, Ordering::Relaxed));
            tick = r.load(header::TICK, Ordering::Relaxed);
            fence(Ordering::Acquire);
            if r.load(header::GLOBAL_SEQ, Ordering::Relaxed) == s1 {
                break;
            }
        }
        let levels = (0..self.levels.len()).map(|l| self.level_state(l).unwrap_or_default()).collect();
        Snapshot { min_lod, tick, levels }
    }

    /// Copies the `w` x `h` texels of `level` whose first is (s0, t0) into `out` (rows in
    /// increasing t, s fastest). The region must lie inside the published valid region; the copy
    /// is validated against the level's sequence counter and retried if the writer moved.
    pub fn read_region(
        &self,
        level: usize,
        s0: i64,
        t0: i64,
        w: u64,
        h: u64,
        out: &mut [u8],
    ) -> Result<LevelState, ReadError> {
        let d = *self.levels.get(level).ok_or(ReadError::NoLevel(level))?;
        let bpt = self.bytes_per_texel;
        assert_eq!(out.len() as u64, w * h * bpt as u64, "read_region: buffer size does not match the region");
        let b = header::LEVEL_STATES + level * layout::STATE_BYTES;
        for _ in 0..64 {
            let Some(st) = self.level_state(level) else { continue };
            if w == 0 || h == 0 {
                return Ok(st);
            }
            if !(st.contains(s0, t0) && st.contains(s0 + w as i64 - 1, t0 + h as i64 - 1)) {
                return Err(ReadError::NotValid(level));
            }
            let clip = self.clip_size as i64;
            for row in 0..h as i64 {
                let t = t0 + row;
                let slot_t = t.rem_euclid(clip) as u64;
                let mut s = s0;
                let mut done = 0u64;
                while done < w {
                    let slot_s = s.rem_euclid(clip) as u64;
                    let run = (w - done).min(d.window[0] - slot_s);
                    let src = d.offset + (slot_t * d.window[0] + slot_s) * bpt as u64;
                    let dst = ((row as u64 * w + done) as usize) * bpt;
                    self.region.read(src as usize, &mut out[dst..dst + run as usize * bpt]);
                    done += run;
                    s += run as i64;
                }
            }
            fence(Ordering::Acquire);
            if self.region.load(b + state::SEQ, Ordering::Relaxed) == st.seq {
                return Ok(st);
            }
        }
        Err(ReadError::Busy(level))
    }

    /// Samples the mapping with the reference sampler ([`crate::sample::sample_mapping`]): point,
    /// bilinear or trilinear at (u, v) in level-0 texel units and `lod`, raised to the published
    /// min LOD and to the finest level whose valid region holds the footprint.
    pub fn sample(&self, filter: crate::sample::Filter, u: f64, v: f64, lod: f64) -> Option<crate::sample::Sample> {
        crate::sample::sample_mapping(self, filter, u, v, lod)
    }

    /// Asks the service to centre the clipmap at `centre` (level-0 texels), with an optional
    /// velocity (level-0 texels per second).
    pub fn request_centre(&self, centre: [i64; 2], velocity: [f64; 2]) {
        let b = header::REQUEST;
        let r = &self.region;
        // Take the request seqlock (odd), write, release (even). Several renderers serialise here.
        // A renderer that died holding it (odd for longer than any write takes) is overruled: the
        // lock is reset to even, so one crashed renderer cannot silence the others.
        let mut odd_since: Option<(u64, std::time::Instant)> = None;
        loop {
            let s = r.load(b + request::SEQ, Ordering::Relaxed);
            if s & 1 == 1 {
                match odd_since {
                    Some((seen, at)) if seen == s && at.elapsed() > Duration::from_millis(100) => {
                        let _ = r.compare_exchange(b + request::SEQ, s, s + 1);
                        odd_since = None;
                    }
                    Some((seen, _)) if seen == s => {}
                    _ => odd_since = Some((s, std::time::Instant::now())),
                }
            }
            if s & 1 == 0 && r.compare_exchange(b + request::SEQ, s, s + 1).is_ok() {
                r.store(b + request::CENTRE_S, centre[0] as u64, Ordering::Relaxed);
                r.store(b + request::CENTRE_T, centre[1] as u64, Ordering::Relaxed);
                r.store(b + request::VEL_S, velocity[0].to_bits(), Ordering::Relaxed);
                r.store(b + request::VEL_T, velocity[1].to_bits(), Ordering::Relaxed);
                r.store(b + request::CLIENT_PID, std::process::id() as u64, Ordering::Relaxed);
                let c = r.load(b + request::COUNT, Ordering::Relaxed);
                r.store(b + request::COUNT, c + 1, Ordering::Relaxed);
                r.store(b + request::SEQ, s + 2, Ordering::Release);
                return;
            }
            std::hint::spin_loop();
        }
    }

    /// Ticks counted by the heartbeat.
    pub fn heartbeat(&self) -> u64 {
        self.region.load(header::HEARTBEAT, Ordering::Acquire)
    }

    /// Time since the writer's last heartbeat (by the wall clock).
    pub fn heartbeat_age(&self) -> Duration {
        let ms = self.region.load(header::HEARTBEAT_MS, Ordering::Acquire);
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_millis() as u64)
            .unwrap_or(0);
        Duration::from_millis(now.saturating_sub(ms))
    }

    /// True when the writer shut down cleanly.
    pub fn closed(&self) -> bool {
        self.region.read_u32(header::FLAGS) & 1 == 1
    }

    /// True when the name now points at another mapping (the service restarted): reattach.
    pub fn replaced(&self) -> bool {
        match std::fs::metadata(&self.path) {
            Ok(m) => (m.dev(), m.ino()) != self.inode,
            Err(_) => true,
        }
    }
}
