//! The writer side: creates the texel mapping and the request mapping (owner-only unless told
//! otherwise, fully initialised before they become visible under their names), holds the
//! per-name lock, hands the engine the mapping as its image caches ([`ImageMemory`]), beats the
//! heartbeat, and reads renderers' centre requests.

use super::layout::{self, header, request, Placement, Shape};
use super::memory::{shape_error, ImageMemory};
use super::raw::Region;
use super::{check_name, io, lock_path, map_path, names, request_path, ShmError};
use clipmap_base::texel::TexelFormat;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// A renderer's request.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Request {
    /// Requested centre, level-0 texels (used when [`position`](Self::position) is
    /// [`Position::Texels`]).
    pub centre: [i64; 2],
    /// Where the centre is asked for: in texels (`centre`), or a position to convert.
    pub position: Position,
    /// Velocity, level-0 texels per second.
    pub velocity: [f64; 2],
    /// Requests made so far.
    pub count: u64,
    /// The primary view's latest LOD request, if one was made.
    pub lod: Option<LodRequest>,
}

/// The coordinate kind of a request's centre (docs/SHM.md, "Positions in longitude / latitude or
/// map coordinates"), as found in its position record: the service converts the last two
/// through the texture's georeferencing, and refuses an unknown kind.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Position {
    /// The request's own centre fields, level-0 texels (kind 0, or a record of an earlier
    /// request: an older renderer writes no position record).
    Texels,
    /// WGS 84 `[longitude, latitude]`, degrees (kind 1).
    LonLat([f64; 2]),
    /// Map `[x, y]` in the texture's CRS (kind 2).
    Map([f64; 2]),
    /// A kind this service does not know (the value found), with its coordinates.
    Unknown(u64, [f64; 2]),
}

/// The position record at `at` of a copy of the request mapping, for a request whose count is
/// `count`: [`Position::Texels`] unless the record was written with that request.
fn position_at(buf: &[u8], at: usize, count: u64) -> Position {
    use layout::views as v;
    let word = |o: usize| u64::from_le_bytes(buf[at + o..at + o + 8].try_into().expect("8 bytes"));
    if count == 0 || word(v::POS_FOR_COUNT) != count {
        return Position::Texels;
    }
    let xy = [f64::from_bits(word(v::POS_X)), f64::from_bits(word(v::POS_Y))];
    match word(v::POS_KIND) {
        v::KIND_TEXELS => Position::Texels,
        v::KIND_LONLAT => Position::LonLat(xy),
        v::KIND_MAP => Position::Map(xy),
        other => Position::Unknown(other, xy),
    }
}

/// A renderer's LOD request for a view (docs/SHM.md, "Asking for a view's levels"), as found:
/// the service checks the numbers before use ([`LodRequest::footprint`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LodRequest {
    /// Height above the texture, level-0 texels.
    pub height: f64,
    /// Radians one screen pixel spans.
    pub pixel_angle: f64,
    /// Levels the renderer addresses at once (0: all).
    pub effective: u64,
    /// LOD requests made to this record.
    pub count: u64,
}

impl LodRequest {
    /// The level-0 texels one pixel spans at the view's nearest ground point, or why the request
    /// cannot be used (what was found and what is expected).
    pub fn footprint(&self) -> Result<f64, String> {
        let (h, a) = (self.height, self.pixel_angle);
        if !(h.is_finite() && h > 0.0) {
            return Err(format!("height {h}: expected a finite number of level-0 texels above 0"));
        }
        if !(a.is_finite() && a > 0.0 && a < std::f64::consts::PI) {
            return Err(format!("pixel angle {a}: expected radians above 0 and below pi"));
        }
        if self.effective > u64::from(u32::MAX) {
            return Err(format!("effective levels {}: expected 0 (all) to {}", self.effective, u32::MAX));
        }
        let f = h * a;
        if f.is_finite() {
            Ok(f)
        } else {
            Err(format!("height {h} x pixel angle {a} is not finite"))
        }
    }
}

/// The LOD request record at `at` of a copy of the request mapping (`None` before any).
fn lod_at(buf: &[u8], at: usize) -> Option<LodRequest> {
    use layout::views as v;
    let word = |o: usize| u64::from_le_bytes(buf[at + o..at + o + 8].try_into().expect("8 bytes"));
    let count = word(v::LOD_COUNT);
    (count > 0).then(|| LodRequest {
        height: f64::from_bits(word(v::LOD_HEIGHT)),
        pixel_angle: f64::from_bits(word(v::LOD_PIXEL_ANGLE)),
        effective: word(v::LOD_EFFECTIVE),
        count,
    })
}

/// The writer of one mapping.
pub struct Writer {
    memory: Arc<ImageMemory>,
    requests: File,
    request_fault: std::sync::Mutex<RequestFault>,
    path: PathBuf,
    req_path: PathBuf,
    lock_path: PathBuf,
    _lock: File,
    lock_id: names::Identity,
    map_id: names::Identity,
    req_id: names::Identity,
    /// The texel mapping's temporary name while it is not yet published under `path`
    /// ([`prepare`](Writer::prepare), [`publish`](Writer::publish)).
    pending: Option<PathBuf>,
}

/// A renderer's request for a further view's centre, as read from its request record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewRequest {
    /// Level-0 centre.
    pub centre: [i64; 2],
    /// Where the centre is asked for (as [`Request::position`]).
    pub position: Position,
    /// Velocity, level-0 texels per second.
    pub velocity: [f64; 2],
    /// Requests made to this record.
    pub count: u64,
    /// The view incarnation it is for.
    pub incarnation: u64,
    /// The view's latest LOD request, if one was made.
    pub lod: Option<LodRequest>,
}

impl std::fmt::Debug for Writer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Writer").field("path", &self.path).field("shape", self.memory.shape()).finish()
    }
}

/// What went wrong reading the request mapping.
#[derive(Debug, Default)]
struct RequestFault {
    /// The file is not whole now (reported when it became so).
    now: bool,
    /// Times it was found not whole.
    count: u64,
    /// The first report.
    first: Option<String>,
}

fn now_ms() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_millis() as u64).unwrap_or(0)
}

/// What a [`Writer`] is made from: where and under which name, the texture's shape and texel
/// format, the files' permission bits, the tick period and the heights block. Built with
/// [`new`](Self::new) and the setters (every other field has a default).
#[derive(Clone, Debug)]
pub struct WriterOptions {
    /// The shared directory the mappings are made in.
    pub dir: PathBuf,
    /// The name the mappings are published under (`clipmap-NAME.map`, `.req`, `.lock`).
    pub name: String,
    /// The texture's shape.
    pub shape: Shape,
    /// The texel format.
    pub format: TexelFormat,
    /// Permission bits of the texel mapping (and the lock file): 0o600 (owner only) by default.
    pub mode: u32,
    /// Permission bits of the request mapping: 0o600 by default.
    pub request_mode: u32,
    /// The service's tick period in nanoseconds (the header's, readers judge liveness by it):
    /// one sixtieth of a second by default.
    pub tick_period_ns: u64,
    /// The texels are heights, with their scale, offset, nodata value and level rule (the
    /// header's heights block); `None` (the default) for a colour texture.
    pub heights: Option<layout::Heights>,
    /// Where the texture lies on the Earth (the header's georef block and each level's affine
    /// terms); `None` (the default) for a texture without georeferencing.
    pub georef: Option<crate::GeorefBlock>,
}

impl WriterOptions {
    /// The options of a mapping of `name` in `dir` for a texture of `shape` and `format`, every
    /// other field at its default.
    pub fn new(dir: impl Into<PathBuf>, name: impl Into<String>, shape: Shape, format: TexelFormat) -> Self {
        WriterOptions {
            dir: dir.into(),
            name: name.into(),
            shape,
            format,
            mode: 0o600,
            request_mode: 0o600,
            tick_period_ns: 16_666_667,
            heights: None,
            georef: None,
        }
    }

    /// The texel mapping's (and lock file's) permission bits.
    pub fn mode(mut self, mode: u32) -> Self {
        self.mode = mode;
        self
    }

    /// The request mapping's permission bits.
    pub fn request_mode(mut self, mode: u32) -> Self {
        self.request_mode = mode;
        self
    }

    /// The tick period in nanoseconds.
    pub fn tick_period_ns(mut self, ns: u64) -> Self {
        self.tick_period_ns = ns;
        self
    }

    /// The heights block (`None`: a colour texture).
    pub fn heights(mut self, heights: Option<layout::Heights>) -> Self {
        self.heights = heights;
        self
    }

    /// The georef block (`None`: no georeferencing), checked by the writer before it makes
    /// anything ([`crate::GeorefBlock::check`]).
    pub fn georef(mut self, georef: Option<crate::GeorefBlock>) -> Self {
        self.georef = georef;
        self
    }
}

/// What a start has made so far, removed when it is dropped armed (a start that fails part-way)
/// and left in place once [`disarm`](Self::disarm)ed: a lock file it created (never one that was
/// there before), its temporary files, and a request mapping only while the name still is its
/// own.
struct Unwind {
    /// The lock file and its identity, when this start created it.
    lock: Option<(PathBuf, names::Identity)>,
    /// Temporary files made and not yet renamed into place.
    temporaries: Vec<PathBuf>,
    /// Names put in place, with the identity of the file put there.
    placed: Vec<(PathBuf, names::Identity)>,
    armed: bool,
}

impl Unwind {
    fn new() -> Self {
        Unwind { lock: None, temporaries: Vec::new(), placed: Vec::new(), armed: true }
    }

    /// A temporary file made.
    fn temporary(&mut self, tmp: &Path) {
        self.temporaries.push(tmp.to_path_buf());
    }

    /// The temporary `tmp` renamed to `path` (holding the file `id`).
    fn placed(&mut self, tmp: &Path, path: &Path, id: names::Identity) {
        self.temporaries.retain(|t| t != tmp);
        self.placed.push((path.to_path_buf(), id));
    }

    /// Everything made stays: the start succeeded.
    fn disarm(mut self) {
        self.armed = false;
    }
}

impl Drop for Unwind {
    fn drop(&mut self) {
        if !self.armed {
            return;
        }
        for tmp in &self.temporaries {
            let _ = std::fs::remove_file(tmp);
        }
        for (path, id) in &self.placed {
            names::remove_if_same(path, *id);
        }
        if let Some((path, id)) = &self.lock {
            names::remove_if_same(path, *id);
        }
    }
}

impl Writer {
    /// Creates the mappings `options` describe: the texel mapping with permission bits
    /// `options.mode` and the request mapping with `options.request_mode`. Refuses when a live
    /// service holds the name; takes over cleanly from one that died (its lock died with it).
    /// A start that fails part-way leaves nothing of its own behind.
    pub fn create(options: WriterOptions) -> Result<Writer, ShmError> {
        let mut w = Writer::prepare(options)?;
        match w.publish() {
            Ok(()) => Ok(w),
            Err(e) => {
                w.close();
                Err(e)
            }
        }
    }

    /// As [`create`](Self::create), but the texel mapping stays under its temporary name (the
    /// lock taken, the request mapping in place) until [`publish`](Self::publish): what must be
    /// in the mapping when readers first find it (a service's views) is written before.
    pub fn prepare(options: WriterOptions) -> Result<Writer, ShmError> {
        let WriterOptions { dir, name, shape, format, mode, request_mode, tick_period_ns, heights, georef } = options;
        let (dir, name) = (dir.as_path(), name.as_str());
        check_name(name)?;
        if let Some(g) = &georef {
            g.check(shape.levels.len()).map_err(ShmError::Georef)?;
        }
        // Every mapping of the service has a views block, one record per further view the engine
        // may keep (docs/SHM.md, "Views").
        let placement = layout::place_with(&shape, heights.is_some())
            .and_then(|p| layout::with_views(p, layout::views::SERVICE_RECORDS))
            .ok_or_else(|| ShmError::Shape(shape_error(&shape)))?;
        let lock_path = lock_path(dir, name);
        let (lock, lock_made) = open_lock(&lock_path, mode)?;
        let lock_id = names::Identity::of(&lock.metadata().map_err(io(&lock_path))?);
        // From here on a failed start removes what it made, and only that (`Unwind`).
        let mut unwind = Unwind::new();
        match lock.try_lock() {
            Ok(()) => {}
            // Someone else holds it (even one we just created: a start racing this one), so it is
            // theirs: left in place, or they would hold a lock on a removed file.
            Err(std::fs::TryLockError::WouldBlock) => return Err(held(&lock, &lock_path, name)),
            Err(std::fs::TryLockError::Error(e)) => {
                if lock_made {
                    names::remove_if_same(&lock_path, lock_id);
                }
                return Err(ShmError::Io { path: lock_path, source: e });
            }
        }
        if lock_made {
            unwind.lock = Some((lock_path.clone(), lock_id));
        }
        // A live service whose lock file was removed still holds its lock on the removed file,
        // so taking the new one proves nothing: its mapping says whether it runs. Such a start
        // is refused before it changes anything.
        let path = map_path(dir, name);
        if let Some(pid) = live_publisher(&path) {
            return Err(ShmError::AlreadyRunning { name: name.to_string(), pid });
        }
        // Ours (checked by `open_lock`) and locked by us: record our pid, nothing else.
        lock.set_len(0)
            .and_then(|()| lock.write_all_at(std::process::id().to_string().as_bytes(), 0))
            .map_err(io(&lock_path))?;

        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        let generation = clipmap_base::tile::splitmix64(nanos ^ ((std::process::id() as u64) << 40));

        // The request mapping first: once the texel mapping appears, its companion is there.
        // The service never maps it: it reads it with `pread` (see `request`), so a writer of
        // the file that truncates it cannot make the service fault.
        let req_path = request_path(dir, name);
        let (req_tmp, req_file) = create_tmp(dir, name, "req", request_mode)?;
        unwind.temporary(&req_tmp);
        req_file.set_len(layout::REQUEST_BYTES).map_err(io(&req_tmp))?;
        // Renderers map it and write it: its page must be there.
        reserve(&req_file, &req_tmp, &req_path, dir, layout::REQUEST_BYTES)?;
        req_file.write_all_at(&layout::VERSION.to_le_bytes(), request::VERSION as u64).map_err(io(&req_tmp))?;
        req_file.write_all_at(&generation.to_le_bytes(), request::GENERATION as u64).map_err(io(&req_tmp))?;
        req_file.write_all_at(&layout::REQUEST_MAGIC, request::MAGIC as u64).map_err(io(&req_tmp))?;
        let req_id = names::Identity::of(&req_file.metadata().map_err(io(&req_tmp))?);
        place_file(&req_tmp, &req_path)?;
        unwind.placed(&req_tmp, &req_path, req_id);

        let (tmp, file) = create_tmp(dir, name, "map", mode)?;
        unwind.temporary(&tmp);
        file.set_len(placement.total_bytes).map_err(io(&tmp))?;
        reserve(&file, &tmp, &path, dir, placement.total_bytes)?;
        let region = Region::map_populated(&file).map_err(io(&tmp))?;
        let map_id = names::Identity::of(&file.metadata().map_err(io(&tmp))?);
        let memory = ImageMemory::over(region, placement, shape, heights.map(|h| h.format()));
        memory.init(format, tick_period_ns, generation, heights.as_ref(), georef.as_ref());
        memory.region().store(header::HEARTBEAT_MS, now_ms(), Ordering::Relaxed);
        // Whole: what was made is the writer's now (`close` removes it).
        unwind.disarm();
        Ok(Writer {
            memory: Arc::new(memory),
            requests: req_file,
            request_fault: std::sync::Mutex::new(RequestFault::default()),
            path,
            req_path,
            lock_path,
            _lock: lock,
            lock_id,
            map_id,
            req_id,
            pending: Some(tmp),
        })
    }

    /// Puts the texel mapping under its name (a [`prepare`](Self::prepare)d one; nothing to do
    /// for a published one), its heartbeat time now. Visible only once complete; readers of a
    /// previous mapping keep theirs. On failure the temporary file is removed; [`close`](Self::close)
    /// then removes the rest.
    pub fn publish(&mut self) -> Result<(), ShmError> {
        let Some(tmp) = self.pending.take() else { return Ok(()) };
        self.memory.region().store(header::HEARTBEAT_MS, now_ms(), Ordering::Release);
        place_file(&tmp, &self.path).inspect_err(|_| {
            let _ = std::fs::remove_file(&tmp);
        })
    }

    /// The generation of this start (header offset 80; the request mapping's offset 16).
    pub fn generation(&self) -> u64 {
        self.memory.region().load(header::GENERATION, Ordering::Acquire)
    }

    /// Gives a [`prepare`](Self::prepare)d mapping and its request mapping the generation
    /// `generation` instead of their own: a view's own mapping carries its service's, which ties
    /// it to that start of the service (docs/SHM.md, "A view with grids of its own"). Nothing is
    /// changed once the mapping is published (an error).
    pub fn adopt_generation(&self, generation: u64) -> Result<(), ShmError> {
        if self.pending.is_none() {
            return Err(ShmError::Invalid {
                path: self.path.clone(),
                reason: "the generation of a published mapping cannot change".into(),
            });
        }
        self.requests
            .write_all_at(&generation.to_le_bytes(), request::GENERATION as u64)
            .map_err(io(&self.req_path))?;
        self.memory.region().store(header::GENERATION, generation, Ordering::Release);
        Ok(())
    }

    /// Where the texel mapping's file is now: its temporary name until it is
    /// [published](Self::publish), then [`path`](Self::path).
    pub fn file_path(&self) -> &Path {
        self.pending.as_deref().unwrap_or(&self.path)
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

    /// The mapping as the engine's image caches (`clipmap::clip::Clipmap::with_memory`): tiles are
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

    /// Stores the heartbeat time (header offset 72) without counting a tick: the service is
    /// alive within a long tick or command, so that readers do not judge it stale meanwhile
    /// (docs/SHM.md, "Liveness and restarts").
    pub fn alive(&self) {
        self.memory.region().store(header::HEARTBEAT_MS, now_ms(), Ordering::Release);
    }

    /// How many requests renderers have made so far (one 8-byte `pread`: cheap enough to poll
    /// while waiting for the next tick). The value only says whether to tick early; the request
    /// itself is read consistently by [`request`](Self::request).
    pub fn request_count(&self) -> u64 {
        let mut b = [0u8; 8];
        match self.requests.read_at(&mut b, request::COUNT as u64) {
            Ok(8) => u64::from_le_bytes(b),
            _ => 0,
        }
    }

    /// Reads the latest renderer request, if a consistent one is there.
    ///
    /// The request mapping is writable by every renderer allowed to request (a group with
    /// `--request-mode 660`), so the service never maps it: it copies the whole 4096 bytes with
    /// `pread` (a file that shrank gives a short read, never a fault), twice, and takes the
    /// request only when both copies hold the same even sequence counter and the same fields
    /// (a renderer's write overlapping either copy changes the counter). A file that is not
    /// whole is reported once ([`request_faults`](Self::request_faults) and a warning in the
    /// log) and its requests are ignored until it is whole again.
    pub fn request(&self) -> Option<Request> {
        let fields = request::SEQ..request::COUNT + 8;
        let lod = layout::views::lod(0)..layout::views::lod(1);
        let pos = layout::views::position(0)..layout::views::position(1);
        let mut a = [0u8; layout::REQUEST_BYTES as usize];
        let mut b = [0u8; layout::REQUEST_BYTES as usize];
        for _ in 0..layout::MAX_RETRIES {
            if let Err(why) = self.read_requests(&mut a).and_then(|()| self.read_requests(&mut b)) {
                self.fault(why);
                return None;
            }
            self.fault_cleared();
            let word = |buf: &[u8], o: usize| u64::from_le_bytes(buf[o..o + 8].try_into().expect("8 bytes"));
            if word(&a, request::SEQ) & 1 == 1
                || a[fields.clone()] != b[fields.clone()]
                || a[lod.clone()] != b[lod.clone()]
                || a[pos.clone()] != b[pos.clone()]
            {
                std::thread::yield_now();
                continue;
            }
            let count = word(&a, request::COUNT);
            let lod_request = lod_at(&a, lod.start);
            return (count > 0 || lod_request.is_some()).then(|| Request {
                centre: [word(&a, request::CENTRE_S) as i64, word(&a, request::CENTRE_T) as i64],
                position: position_at(&a, pos.start, count),
                velocity: [f64::from_bits(word(&a, request::VEL_S)), f64::from_bits(word(&a, request::VEL_T))],
                count,
                lod: lod_request,
            });
        }
        None
    }

    /// Each view request record's latest consistent request (docs/SHM.md, "Asking for a view's
    /// centre"), in record order (`None`: no request yet, or it was being written both times it
    /// was read). Read with `pread`, twice, as [`request`](Self::request) reads the main one.
    pub fn view_requests(&self) -> Vec<Option<ViewRequest>> {
        use layout::views as v;
        let n = (self.memory.placement().view_records as usize).min(v::MAX_REQUEST_RECORDS);
        let mut a = [0u8; layout::REQUEST_BYTES as usize];
        let mut b = [0u8; layout::REQUEST_BYTES as usize];
        if n == 0 || self.read_requests(&mut a).and_then(|()| self.read_requests(&mut b)).is_err() {
            return vec![None; n];
        }
        let word = |buf: &[u8], o: usize| u64::from_le_bytes(buf[o..o + 8].try_into().expect("8 bytes"));
        (0..n)
            .map(|r| {
                let base = v::request(r);
                let fields = base..base + v::REQUEST_RECORD_BYTES;
                let lod = v::lod(1 + r)..v::lod(2 + r);
                let pos = v::position(1 + r)..v::position(2 + r);
                if word(&a, base + v::REQ_SEQ) & 1 == 1
                    || a[fields.clone()] != b[fields]
                    || a[lod.clone()] != b[lod.clone()]
                    || a[pos.clone()] != b[pos.clone()]
                {
                    return None;
                }
                let count = word(&a, base + v::REQ_COUNT);
                let lod_request = lod_at(&a, lod.start);
                (count > 0 || lod_request.is_some()).then(|| ViewRequest {
                    lod: lod_request,
                    centre: [word(&a, base + v::REQ_CENTRE_S) as i64, word(&a, base + v::REQ_CENTRE_T) as i64],
                    position: position_at(&a, pos.start, count),
                    velocity: [
                        f64::from_bits(word(&a, base + v::REQ_VEL_S)),
                        f64::from_bits(word(&a, base + v::REQ_VEL_T)),
                    ],
                    count,
                    incarnation: word(&a, base + v::REQ_INCARNATION),
                })
            })
            .collect()
    }

    /// One whole copy of the request mapping, or why there is none.
    fn read_requests(&self, buf: &mut [u8; layout::REQUEST_BYTES as usize]) -> Result<(), String> {
        let mut done = 0;
        while done < buf.len() {
            match self.requests.read_at(&mut buf[done..], done as u64) {
                Ok(0) => {
                    return Err(format!(
                        "{}: {done} bytes, expected {} (a process that can write it truncated it); renderers' requests are ignored until it is whole again, the control socket's CENTRE still works",
                        self.req_path.display(),
                        layout::REQUEST_BYTES
                    ))
                }
                Ok(n) => done += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(format!("{}: cannot be read: {e}", self.req_path.display())),
            }
        }
        Ok(())
    }

    fn fault(&self, why: String) {
        let mut f = self.request_fault.lock().unwrap_or_else(|p| p.into_inner());
        if !f.now {
            f.now = true;
            f.count += 1;
            tracing::warn!("request mapping {why}");
            f.first.get_or_insert(why);
        }
    }

    fn fault_cleared(&self) {
        let mut f = self.request_fault.lock().unwrap_or_else(|p| p.into_inner());
        if f.now {
            f.now = false;
            tracing::warn!(
                "request mapping {}: whole again; renderers' requests are read again",
                self.req_path.display()
            );
        }
    }

    /// How many times the request mapping was found not whole (each time reported once, not
    /// every tick), and the first report.
    pub fn request_faults(&self) -> (u64, Option<String>) {
        let f = self.request_fault.lock().unwrap_or_else(|p| p.into_inner());
        (f.count, f.first.clone())
    }

    /// Marks a clean shutdown and removes the names (readers keep their mappings and see the
    /// flag).
    pub fn close(self) {
        let r = self.memory.region();
        r.store(header::FLAGS, 1, Ordering::Release);
        r.store(header::HEARTBEAT_MS, now_ms(), Ordering::Release);
        match &self.pending {
            // Never published: the temporary file is ours alone.
            Some(tmp) => {
                let _ = std::fs::remove_file(tmp);
            }
            None => names::remove_if_same(&self.path, self.map_id),
        }
        names::remove_if_same(&self.req_path, self.req_id);
        names::remove_if_same(&self.lock_path, self.lock_id);
    }
}

/// Removes what a dead predecessor of the service named `service` left of its views' own
/// mappings (`DIR/clipmap-SERVICE@VIEW.map`, `.req` and `.lock`; docs/SHM.md, "A view with grids
/// of its own"): a view added on the socket is not there after a restart, and its files would
/// otherwise stay in the shared directory. Only names whose lock nobody holds and whose mapping
/// no live process publishes are removed, and only regular files of this user; anything else is
/// left alone. Call it while holding the service's own lock, before adding views. Returns the
/// views whose files were removed.
pub fn remove_dead_own_mappings(dir: &Path, service: &str) -> Vec<String> {
    let prefix = format!("clipmap-{service}@");
    let Ok(entries) = std::fs::read_dir(dir) else { return Vec::new() };
    let mut removed = Vec::new();
    for entry in entries.flatten() {
        let file = entry.file_name();
        let Some(view) = file.to_str().and_then(|f| f.strip_prefix(&prefix)).and_then(|r| r.strip_suffix(".lock"))
        else {
            continue;
        };
        if layout::views::check_name(view).is_err() {
            continue;
        }
        let own = layout::views::own_mapping_name(service, view);
        let lock_path = lock_path(dir, &own);
        let Ok(lock) = names::open_own(&lock_path) else { continue };
        if lock.try_lock().is_err() {
            continue;
        }
        let map = map_path(dir, &own);
        if live_publisher(&map).is_some() {
            continue;
        }
        for p in [map, request_path(dir, &own)] {
            if std::fs::symlink_metadata(&p).is_ok_and(|m| names::check_own_file(&p, &m).is_ok()) {
                let _ = std::fs::remove_file(&p);
            }
        }
        if let Ok(m) = lock.metadata() {
            names::remove_if_same(&lock_path, names::Identity::of(&m));
        }
        removed.push(view.to_string());
    }
    removed.sort();
    removed
}

/// Reserves the first `len` bytes of `file` (the temporary `tmp`, to appear as `path` in `dir`)
/// on its file system before any of its pages is touched: a shared mapping of a file whose pages
/// the file system cannot supply (a full tmpfs: any local user can fill `/dev/shm`) faults with
/// SIGBUS at the first store there, which kills the process without a word. A file system
/// without room refuses the reservation, which is reported ([`ShmError::NoRoom`]) instead.
/// One that cannot reserve (`fallocate` unsupported) has its blocks written with zeros, which
/// allocates them just as well.
fn reserve(file: &File, tmp: &Path, path: &Path, dir: &Path, len: u64) -> Result<(), ShmError> {
    use rustix::io::Errno;
    let no_room = || ShmError::NoRoom {
        path: path.to_path_buf(),
        dir: dir.to_path_buf(),
        needed: len,
        available: rustix::fs::fstatvfs(file).map_or(0, |v| v.f_bavail.saturating_mul(v.f_frsize)),
    };
    match rustix::fs::fallocate(file, rustix::fs::FallocateFlags::empty(), 0, len) {
        Ok(()) => Ok(()),
        Err(Errno::NOSPC | Errno::DQUOT | Errno::FBIG) => Err(no_room()),
        Err(Errno::OPNOTSUPP | Errno::NOSYS) => {
            let zeros = vec![0u8; 1 << 20];
            let mut at = 0;
            while at < len {
                let n = (len - at).min(zeros.len() as u64);
                file.write_all_at(&zeros[..n as usize], at).map_err(|e| match e.raw_os_error() {
                    Some(c) if [Errno::NOSPC.raw_os_error(), Errno::DQUOT.raw_os_error()].contains(&c) => no_room(),
                    _ => ShmError::Io { path: tmp.to_path_buf(), source: e },
                })?;
                at += n;
            }
            Ok(())
        }
        Err(e) => Err(ShmError::Io { path: tmp.to_path_buf(), source: e.into() }),
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
/// Also says whether this call created it. An existing one with another hard link is refused
/// too: the pid written into it would land in the file it is linked to.
fn open_lock(path: &Path, mode: u32) -> Result<(File, bool), ShmError> {
    match names::create_new(path, mode) {
        Ok(f) => Ok((f, true)),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => names::open_own(path).map(|f| (f, false)),
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

/// How long a mapping's heartbeat may stand still while its writer still counts as running, at
/// least: a live service's heartbeat has been seen to pause for a quarter of a second, and one
/// ticking slowly beats once a period (ten periods are allowed when that is longer).
pub const LIVE_HEARTBEAT_MS: u64 = 10_000;

/// The process id of a service that still publishes the mapping at `path`: a regular file of
/// this user with this layout's magic, not marked closed, whose writer (not this process) is a
/// live process and whose heartbeat moved within [`LIVE_HEARTBEAT_MS`] (or ten tick periods).
/// Read with `pread` from a descriptor opened without following links or blocking, so nothing
/// planted there can fault or hang the check; anything else is `None` (a dead service's mapping,
/// which is replaced, or something `place_file` refuses).
fn live_publisher(path: &Path) -> Option<u32> {
    use std::os::unix::fs::OpenOptionsExt;
    let meta = std::fs::symlink_metadata(path).ok()?;
    names::check_own_file(path, &meta).ok()?;
    let flags = rustix::fs::OFlags::NOFOLLOW | rustix::fs::OFlags::NONBLOCK;
    let file = std::fs::OpenOptions::new().read(true).custom_flags(flags.bits() as i32).open(path).ok()?;
    let mut h = [0u8; 104];
    file.read_exact_at(&mut h, 0).ok()?;
    let u64_at = |o: usize| u64::from_le_bytes(h[o..o + 8].try_into().expect("8 bytes"));
    let pid = u32::from_le_bytes(h[header::WRITER_PID..header::WRITER_PID + 4].try_into().expect("4 bytes"));
    if h[..8] != layout::MAGIC || u64_at(header::FLAGS) & 1 == 1 || pid == 0 || pid == std::process::id() {
        return None;
    }
    let window = LIVE_HEARTBEAT_MS.max(u64_at(header::TICK_PERIOD_NS).saturating_mul(10) / 1_000_000);
    let fresh = now_ms().saturating_sub(u64_at(header::HEARTBEAT_MS)) <= window;
    (fresh && Path::new(&format!("/proc/{pid}")).exists()).then_some(pid)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Client, GeorefBlock};

    /// Three levels under a clip of 128: 512 and 256 texels a side in 64 x 64 tiles, then a
    /// pyramid level of 128.
    fn shape() -> Shape {
        let levels = (0..3u32)
            .map(|k| {
                let s = 512u64 >> k;
                let t = if s <= 128 { s } else { 64 };
                layout::LevelShape {
                    size: [s, s],
                    tile: [t, t],
                    grid: clipmap_base::geom::mem_grid([s, s], [t, t], 128, 1),
                }
            })
            .collect();
        Shape { bytes_per_texel: 4, block: 1, clip_size: 128, levels }
    }

    fn web_mercator() -> GeorefBlock {
        let half = 20_037_508.342_789_244;
        GeorefBlock {
            epsg: Some(3857),
            wraps: true,
            definition: "+proj=merc +a=6378137 +b=6378137 +lat_ts=0 +lon_0=0 +x_0=0 +y_0=0 +k=1 +units=m +nadgrids=@null +no_defs".into(),
            origin: [-half, half],
            levels: (0..3).map(|k| 2.0 * half / f64::from(512 >> k)).map(|r| [r, 0.0, 0.0, -r]).collect(),
        }
    }

    #[test]
    fn the_georef_block_given_to_the_writer_is_what_a_client_reads() {
        let dir = tempfile::tempdir().unwrap();
        let opts = WriterOptions::new(dir.path(), "geo", shape(), TexelFormat::RGBA8).georef(Some(web_mercator()));
        let w = Writer::create(opts).unwrap();
        let c = Client::attach(dir.path(), "geo").unwrap();
        assert_eq!(c.georef, Some(web_mercator()));
        drop(c);
        w.close();
        // Without one: none, and the block and the descriptors' terms are all zero.
        let w = Writer::create(WriterOptions::new(dir.path(), "plain", shape(), TexelFormat::RGBA8)).unwrap();
        let c = Client::attach(dir.path(), "plain").unwrap();
        assert_eq!(c.georef, None);
        let bytes = std::fs::read(map_path(dir.path(), "plain")).unwrap();
        assert!(bytes[header::GEOREF..header::END].iter().all(|&b| b == 0));
        w.close();
    }

    #[test]
    fn a_bad_georef_block_is_refused_before_anything_is_made() {
        let dir = tempfile::tempdir().unwrap();
        let mut g = web_mercator();
        g.levels.pop();
        let e = Writer::create(WriterOptions::new(dir.path(), "geo", shape(), TexelFormat::RGBA8).georef(Some(g)));
        let Err(e) = e else { panic!("refused") };
        let e = e.to_string();
        assert!(e.contains("georeferencing") && e.contains("2 levels") && e.contains("3 levels"), "{e}");
        let mut g = web_mercator();
        g.origin[1] = f64::NAN;
        let e = Writer::create(WriterOptions::new(dir.path(), "geo", shape(), TexelFormat::RGBA8).georef(Some(g)));
        let Err(e) = e else { panic!("refused") };
        assert!(e.to_string().contains("origin y"), "{e}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "nothing made");
    }
}
