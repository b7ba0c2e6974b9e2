//! `clipmapd --growing`: a growing texture served while it grows. Patches arrive on the control
//! socket (raw texels and PNGs) and in a watched directory while a reader in this process flies
//! fast over the texture; every texel it reads is checked against what the patches imply,
//! computed here from the patches alone (no library code), through the mapping's tile map (a tile
//! without data is missing; a tile with some data has its other texels from the finest coarser
//! level with data there). Then every texel of every published level is checked once the service
//! has caught up, again after kill -9 and a restart, and the growth block is checked against the
//! patches.

use crate::common::{exec, Fixture};
use crate::growing::{coarser, oracle0, patch, write, P};
use clipmap::geom::Rect;
use clipmap::shm::{Client, ReadError};
use std::collections::HashSet;
use std::io::{BufRead, BufReader, Write as _};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

const CLIPMAPD: &str = env!("CARGO_BIN_EXE_clipmapd");
const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");

/// Frame 512 texels a side, store tiles of 16, clip 64: levels 512 .. 1, three of them stack
/// levels (tiles of 16), the rest pyramid levels (one tile each).
const FRAME: usize = 512;
const TILE: usize = 16;
const CLIP: usize = 64;
const ORIGIN: [f64; 2] = [3.5, -2.25];

struct Service {
    child: Child,
    socket: PathBuf,
    err: PathBuf,
}

impl Service {
    fn start(dir: &Path, name: &str) -> Service {
        Service::start_with(dir, name, &[])
    }

    /// Started with further options (`extra`).
    fn start_with(dir: &Path, name: &str, extra: &[&str]) -> Service {
        let socket = dir.join(format!("{name}.sock"));
        let err = dir.join(format!("{name}-{}.err", std::process::id()));
        let child = Command::new(CLIPMAPD)
            .current_dir(dir)
            .args(["--growing", "tex", "--incoming", "inc", "--size", &FRAME.to_string()])
            .args(["--clip", &CLIP.to_string(), "--tick-hz", "120", "--name", name])
            .args(["--shm-dir", dir.to_str().unwrap(), "--socket", socket.to_str().unwrap()])
            .args(extra)
            .env("RUST_LOG", "info")
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap();
        let s = Service { child, socket, err };
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(30) {
            if UnixStream::connect(&s.socket).is_ok() && s.ask("PING") == "OK pong" {
                return s;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("the service did not come up\n{}", s.log());
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.err).unwrap_or_default()
    }

    fn ask(&self, line: &str) -> String {
        self.send(line.as_bytes(), &[])
    }

    fn send(&self, line: &[u8], bytes: &[u8]) -> String {
        let Ok(mut s) = UnixStream::connect(&self.socket) else { return String::new() };
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        s.write_all(line).unwrap();
        s.write_all(b"\n").unwrap();
        s.write_all(bytes).unwrap();
        let mut reply = String::new();
        let _ = BufReader::new(s).read_line(&mut reply);
        reply.trim_end().to_string()
    }

    /// `PATCH DATA` with raw texels.
    fn patch(&self, p: &P) -> String {
        let b = p.bbox;
        let json = format!(
            "{{\"bbox\": [{}, {}, {}, {}], \"time\": {}, \"rating\": {}, \"raw\": {{\"width\": {}, \"height\": {}}}}}",
            b[0], b[1], b[2], b[3], p.time, p.rating, p.w, p.h
        );
        self.send(format!("PATCH DATA {} {json}", p.texels.len()).as_bytes(), &p.texels)
    }

    fn growth(&self) -> serde_json::Value {
        let r = self.ask("STATUS");
        let v: serde_json::Value = serde_json::from_str(r.strip_prefix("OK ").unwrap_or("null")).unwrap();
        v["growth"].clone()
    }

    fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        self.kill9();
    }
}

/// What the mapping must hold after the first `m` patches, computed from the patches alone.
struct Want {
    /// Per level, (FRAME >> k)² texels of its own data (frame texels; None: no data).
    levels: Vec<Vec<Option<u8>>>,
    /// Per level, the tiles with data of their own.
    tiles: Vec<HashSet<(usize, usize)>>,
}

fn tile_of(k: usize) -> usize {
    let n = FRAME >> k;
    if n > CLIP {
        TILE
    } else {
        n
    }
}

impl Want {
    fn new(ps: &[P]) -> Want {
        let h = (FRAME / 2) as i64;
        let mut levels = vec![oracle0(ps, ORIGIN, 1.0, -h, -h, FRAME, FRAME)];
        while levels.last().unwrap().len() > 1 {
            let n = FRAME >> (levels.len() - 1);
            levels.push(coarser(levels.last().unwrap(), n, n));
        }
        let tiles = levels
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let (n, t) = (FRAME >> k, tile_of(k));
                (0..l.len()).filter(|&i| l[i].is_some()).map(|i| ((i % n) / t, (i / n) / t)).collect()
            })
            .collect();
        Want { levels, tiles }
    }

    /// The texel a reader must get at (k, s, t): `None` when its tile is missing (no data of its
    /// own), else its own data or the finest coarser level's at that place.
    fn served(&self, k: usize, s: usize, t: usize) -> Option<u8> {
        let tk = tile_of(k);
        if !self.tiles[k].contains(&(s / tk, t / tk)) {
            return None;
        }
        (k..self.levels.len()).find_map(|m| {
            let (d, n) = (m - k, FRAME >> m);
            self.levels[m][(t >> d) * n + (s >> d)]
        })
    }

    /// Own data of (k, s, t) and of its ancestors, finest first.
    fn chain(&self, k: usize, s: usize, t: usize) -> impl Iterator<Item = Option<u8>> + '_ {
        (k..self.levels.len()).map(move |m| {
            let (d, n) = (m - k, FRAME >> m);
            self.levels[m][(t >> d) * n + (s >> d)]
        })
    }

    /// Level-0 texels with data: `[s0, t0, s1, t1)`.
    fn extent(&self) -> [i64; 4] {
        let l = &self.levels[0];
        let (mut e, mut any) = ([i64::MAX, i64::MAX, i64::MIN, i64::MIN], false);
        for (i, v) in l.iter().enumerate() {
            if v.is_some() {
                let (s, t) = ((i % FRAME) as i64, (i / FRAME) as i64);
                e = [e[0].min(s), e[1].min(t), e[2].max(s + 1), e[3].max(t + 1)];
                any = true;
            }
        }
        if any {
            e
        } else {
            [0; 4]
        }
    }
}

/// One texel through the reader: `Ok(Some(v))`, `Ok(None)` for a missing tile, `Err` when the
/// read must be retried (the slot moved on or kept changing).
fn read(c: &Client, snap: &clipmap::shm::Snapshot, k: usize, s: i64, t: i64) -> Result<Option<u8>, ReadError> {
    let mut b = [0u8; 1];
    match c.read_region_in(snap, k, Rect::new(s, t, s + 1, t + 1), &mut b) {
        Ok(()) => Ok(Some(b[0])),
        Err(ReadError::Missing { .. }) => Ok(None),
        Err(e) => Err(e),
    }
}

/// Checks every texel of every enabled level against `want`; returns how many had data.
fn check_all(c: &Client, want: &Want) -> usize {
    let snap = c.try_snapshot().unwrap();
    let mut with_data = 0;
    for (k, l) in snap.levels.iter().enumerate() {
        if !l.enabled || (k as f64) < snap.min_lod.floor() {
            continue;
        }
        let [s0, t0, s1, t1] = l.valid;
        for t in t0..t1 {
            for s in s0..s1 {
                let got = loop {
                    match read(c, &snap, k, s, t) {
                        Ok(v) => break v,
                        Err(ReadError::Busy(_)) => continue,
                        Err(e) => panic!("level {k} texel ({s}, {t}): {e}"),
                    }
                };
                assert_eq!(got, want.served(k, s as usize, t as usize), "level {k} texel ({s}, {t})");
                with_data += got.is_some() as usize;
            }
        }
    }
    with_data
}

/// Waits until the service has taken `n` patches, rebuilt everything, and replaced what it holds.
fn settle(svc: &Service, c: &Client, n: u64) {
    let t = Instant::now();
    let mut last = serde_json::Value::Null;
    let mut same = 0;
    while t.elapsed() < Duration::from_secs(60) {
        let g = svc.growth();
        if g["patches"] == n && g["tiles_pending"] == 0 && g == last {
            same += 1;
            // Unchanged for a while, and the snapshot is complete at the centre.
            if same >= 5 && c.try_snapshot().is_ok_and(|s| s.min_lod == 0.0) {
                return;
            }
        } else {
            same = 0;
        }
        last = g;
        std::thread::sleep(Duration::from_millis(50));
    }
    panic!("the service did not catch up: {last}\n{}", svc.log());
}

/// The C and Python readers and `cliptex attach` show the growth block as the Rust reader reads it.
fn readers_show_the_growth(fx: &Fixture, svc: &Service, g: &clipmap::shm::layout::Growth) {
    let root = Path::new(env!("CLIPMAP_ROOT"));
    let mapping = fx.path("clipmap-grow.map");
    // Numbers compared as numbers (C prints 1 where serde writes 1.0).
    fn numbers(v: serde_json::Value) -> serde_json::Value {
        match v {
            serde_json::Value::Number(n) => serde_json::json!(n.as_f64().unwrap()),
            serde_json::Value::Array(a) => a.into_iter().map(numbers).collect(),
            serde_json::Value::Object(o) => o.into_iter().map(|(k, v)| (k, numbers(v))).collect(),
            other => other,
        }
    }
    let want = numbers(serde_json::to_value(g).unwrap());
    let py = Command::new("python3")
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .arg(root.join("clients/python/clipmap_shm.py"))
        .arg(&mapping)
        .arg("--growth")
        .output()
        .unwrap();
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    let got: serde_json::Value = serde_json::from_slice(&py.stdout).unwrap();
    assert_eq!(numbers(got), want, "Python");
    let exe = fx.path("growth");
    let cc = Command::new("cc")
        .args(["-O2", "-Wall", "-Werror", "-std=c11", "-I"])
        .arg(root.join("include"))
        .arg(root.join("clients/c/growth.c"))
        .arg("-o")
        .arg(&exe)
        .output()
        .unwrap();
    assert!(cc.status.success(), "{}", String::from_utf8_lossy(&cc.stderr));
    let c = Command::new(&exe).arg(&mapping).output().unwrap();
    assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
    let got: serde_json::Value = serde_json::from_slice(&c.stdout).unwrap();
    assert_eq!(numbers(got), want, "C");
    // A copy with an impossible growth block: both readers refuse it (exit 2) and say why.
    let mut bytes = std::fs::read(&mapping).unwrap();
    let at = clipmap::shm::layout::header::GROWTH + clipmap::shm::layout::growth::EXTENT_S1;
    bytes[at..at + 8].copy_from_slice(&5000u64.to_le_bytes());
    let bad = fx.path("clipmap-bad.map");
    std::fs::write(&bad, &bytes).unwrap();
    for (what, out) in [
        ("C", Command::new(&exe).arg(&bad).output().unwrap()),
        (
            "Python",
            Command::new("python3")
                .env("PYTHONDONTWRITEBYTECODE", "1")
                .arg(root.join("clients/python/clipmap_shm.py"))
                .arg(&bad)
                .arg("--growth")
                .output()
                .unwrap(),
        ),
    ] {
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{what}: {err}");
        assert!(err.contains("not inside the 512x512 frame"), "{what}: {err}");
    }
    let dir = fx.dir.path().to_str().unwrap();
    let sock = svc.socket.to_str().unwrap();
    let (out, d) = exec(
        fx.dir.path(),
        CLIPTEX,
        &["attach", "grow", "--shm-dir", dir, "--socket", sock, "--json", "--interval", "0.1"],
    );
    assert!(out.status.success(), "{d}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["growth"]["patches"], g.patches, "{v}");
    assert_eq!(numbers(v["growth"]["extent"].clone()), want["extent"], "{v}");
    let (out, d) = exec(
        fx.dir.path(),
        CLIPTEX,
        &["attach", "grow", "--shm-dir", dir, "--socket", sock, "--once", "--interval", "0.1"],
    );
    assert!(out.status.success(), "{d}");
    let e = g.extent;
    let line = format!(
        "growing: data over [{}, {}) x [{}, {})  {} data levels  {} patches",
        e[0], e[2], e[1], e[3], g.data_levels, g.patches
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains(&line), "{line}\n{d}");
}

fn survey() -> Vec<P> {
    vec![
        patch([-20.0, -10.0, 25.0, 18.0], 1, 1.0, 30, 20, 1),
        patch([10.0, 5.0, 70.0, 30.0], 2, 1.0, 40, 16, 2),
        patch([-90.0, -5.0, -15.0, 12.0], 3, 0.0, 25, 9, 3),
        patch([-30.0, -160.0, 0.0, -2.0], 4, 2.0, 12, 30, 4),
        patch([-5.0, 20.0, 15.0, 175.0], 5, 0.5, 10, 28, 5),
        // Newer but rated lower than the first: loses where they overlap; beyond the frame's
        // right edge (x from 252.5 on): those texels are not served.
        patch([-8.0, -8.0, 300.0, 8.0], 6, 0.5, 80, 8, 6),
        // Rated higher: wins over everything below it.
        patch([-40.0, -40.0, -10.0, 40.0], 0, 3.0, 15, 40, 7),
    ]
}

#[test]
fn a_growing_texture_is_served_while_it_grows_and_every_texel_read_matches_the_patches() {
    let fx = Fixture::new();
    let (out, d) = exec(
        fx.dir.path(),
        CLIPTEX,
        &["grow", "create", "tex", "--origin", "3.5,-2.25", "--texels-per-unit", "1", "--tile", "16", "--format", "l8"],
    );
    assert!(out.status.success(), "{d}");
    std::fs::create_dir(fx.path("inc")).unwrap();
    let ps = survey();
    let wants: Vec<Want> = (0..=ps.len()).map(|m| Want::new(&ps[..m])).collect();
    let svc = Service::start(fx.dir.path(), "grow");
    let c = Client::attach(fx.dir.path(), "grow").unwrap();
    assert_eq!(c.levels.len(), 10);
    assert!(c.growth().unwrap().is_some_and(|g| g.patches == 0 && g.extent == [0; 4]));

    // A fast flight (24 texels a frame on a circle over the data), patches arriving meanwhile.
    let (mut checked, mut at_level0, mut missing, mut retried) = (0u64, 0u64, 0u64, 0u64);
    let mut rng = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    let mut frame = 0u64;
    let mut acked;
    let mut levels_seen = Vec::new();
    for (n, p) in ps.iter().enumerate() {
        // Every other patch through the socket; the others dropped into the watched directory
        // as PNGs.
        if n % 2 == 0 {
            let r = svc.patch(p);
            assert_eq!(r, format!("OK patch {}", n + 1), "{}", svc.log());
        } else {
            write(&fx, &format!("inc/.p{n}"), p, true);
            std::fs::rename(fx.path(&format!("inc/.p{n}.png")), fx.path(&format!("inc/p{n}.png"))).unwrap();
            let json = std::fs::read_to_string(fx.path(&format!("inc/.p{n}.json"))).unwrap();
            std::fs::write(
                fx.path(&format!("inc/.p{n}.json")),
                json.replace(&format!("inc/.p{n}.png"), &format!("p{n}.png")),
            )
            .unwrap();
            std::fs::rename(fx.path(&format!("inc/.p{n}.json")), fx.path(&format!("inc/p{n}.json"))).unwrap();
            // Taken in order, so that what is served is always what a prefix of `ps` implies.
            let t = Instant::now();
            while svc.growth()["patches"] != n as u64 + 1 {
                assert!(t.elapsed() < Duration::from_secs(20), "p{n}.json was not taken\n{}", svc.log());
                std::thread::sleep(Duration::from_millis(10));
            }
        }
        acked = n + 1;
        for _ in 0..30 {
            frame += 1;
            let a = frame as f64 * 0.15;
            let centre = [(256.0 + 120.0 * a.cos()) as i64, (256.0 + 120.0 * a.sin()) as i64];
            assert!(c.request_centre(centre, [0.0, 0.0]));
            std::thread::sleep(Duration::from_millis(6));
            let Ok(snap) = c.try_snapshot() else { continue };
            for (k, l) in snap.levels.iter().enumerate() {
                if !l.enabled {
                    continue;
                }
                let [s0, t0, s1, t1] = l.valid;
                for _ in 0..24 {
                    let s = s0 + (next() % (s1 - s0) as u64) as i64;
                    let t = t0 + (next() % (t1 - t0) as u64) as i64;
                    match read(&c, &snap, k, s, t) {
                        Ok(got) => {
                            // Rebuilds run while the reader reads, level by level: a texel is the
                            // data of its own level or, where that has none, of a coarser one at
                            // its place, as some prefix of the patches acknowledged so far implies
                            // (each level from its own moment); never anything else.
                            let (su, tu) = (s as usize, t as usize);
                            let ok =
                                got.is_none() || wants[..=acked].iter().any(|w| w.chain(k, su, tu).any(|v| v == got));
                            assert!(
                                ok,
                                "level {k} texel ({s}, {t}) read {got:?}; after {acked} patches it may be one of {:?}",
                                wants[..=acked]
                                    .iter()
                                    .map(|w| w.chain(k, su, tu).collect::<Vec<_>>())
                                    .collect::<Vec<_>>()
                            );
                            checked += 1;
                            missing += got.is_none() as u64;
                            at_level0 += (k == 0 && got.is_some()) as u64;
                        }
                        Err(ReadError::Stale(_) | ReadError::Busy(_)) => retried += 1,
                        Err(e) => panic!("level {k} texel ({s}, {t}): {e}"),
                    }
                }
            }
        }
        if let Ok(Some(g)) = c.growth() {
            levels_seen.push(g.data_levels);
        }
    }
    assert!(
        checked > 5000 && at_level0 > 100 && missing > 0,
        "checked {checked}, level 0 {at_level0}, missing {missing}, retried {retried}"
    );

    // Caught up: every texel of every published level, at a few places.
    settle(&svc, &c, ps.len() as u64);
    let want = &wants[ps.len()];
    for centre in [[256, 256], [150, 260], [256, 120], [300, 300]] {
        assert!(c.request_centre(centre, [0.0, 0.0]));
        // Until level 0 is published at the new centre (bounded), then settled there.
        let t = Instant::now();
        while c.level_state(0).is_none_or(|l| l.centre != centre) {
            assert!(t.elapsed() < Duration::from_secs(20), "{centre:?} was never published\n{}", svc.log());
            std::thread::sleep(Duration::from_millis(10));
        }
        settle(&svc, &c, ps.len() as u64);
        assert!(check_all(&c, want) > 0, "data around {centre:?}");
    }
    let g = c.growth().unwrap().unwrap();
    assert_eq!(g.extent, want.extent(), "{g:?}");
    assert_eq!((g.patches, g.outside_frame, g.tiles_pending), (ps.len() as u64, 1, 0), "{g:?}");
    assert_eq!(g.world_origin, [ORIGIN[0] - 256.0, ORIGIN[1] - 256.0]);
    assert!(g.tiles_replaced > 0, "rebuilt tiles were replaced in their slots: {g:?}");
    assert!(levels_seen.first() < levels_seen.last(), "the data grew levels: {levels_seen:?}");
    assert_eq!(std::fs::read_dir(fx.path("inc/done")).unwrap().count(), 6, "three sidecars and their PNGs");
    readers_show_the_growth(&fx, &svc, &g);

    // kill -9 and a restart: everything acknowledged is served again, texel for texel.
    let mut svc = svc;
    svc.kill9();
    drop(c);
    let svc = Service::start(fx.dir.path(), "grow");
    let c = Client::attach(fx.dir.path(), "grow").unwrap();
    assert!(c.request_centre([256, 256], [0.0, 0.0]));
    settle(&svc, &c, ps.len() as u64);
    assert!(check_all(&c, want) > 0);

    // A bad patch on the socket is refused with what was wrong, and nothing changes.
    let bad = patch([0.0, 9.0, 4.0, 2.0], 0, 0.0, 1, 1, 1);
    let r = svc.patch(&bad);
    assert!(
        r.starts_with("ERR PATCH: ") && r.contains("empty or inverted along y") && r.contains("nothing was taken"),
        "{r}"
    );
    let r = svc.send(b"PATCH DATA 999999999999 {\"bbox\": [0, 0, 1, 1], \"raw\": {\"width\": 1, \"height\": 1}}", &[]);
    assert!(r.contains("the most is"), "{r}");
    assert_eq!(svc.growth()["patches"], ps.len());
}

/// Texels of every enabled level of `c`'s view that differ from `want` (level, texel, got,
/// wanted; the first few), and how many had data; `None` while the snapshot cannot be read.
fn differences(c: &Client, want: &Want) -> Option<(Vec<String>, usize)> {
    let snap = c.try_snapshot().ok()?;
    let (mut wrong, mut with_data) = (Vec::new(), 0);
    for (k, l) in snap.levels.iter().enumerate() {
        if !l.enabled || (k as f64) < snap.min_lod.floor() {
            continue;
        }
        let [s0, t0, s1, t1] = l.valid;
        for t in t0..t1 {
            for s in s0..s1 {
                let got = read(c, &snap, k, s, t).ok()?;
                let w = want.served(k, s as usize, t as usize);
                if got != w && wrong.len() < 5 {
                    wrong.push(format!("level {k} ({s}, {t}): {got:?}, expected {w:?}"));
                }
                with_data += got.is_some() as usize;
            }
        }
    }
    Some((wrong, with_data))
}

/// The fault: a view with grids of its own never read a patched tile again (only the primary's
/// clipmap was told of the change), so it kept the old texels (here: none, the tile missing) for
/// good while the primary showed the patch.
#[test]
fn own_view_never_receives_growing_patches() {
    let fx = Fixture::new();
    let (out, d) = exec(
        fx.dir.path(),
        CLIPTEX,
        &["grow", "create", "tex", "--origin", "3.5,-2.25", "--texels-per-unit", "1", "--tile", "16", "--format", "l8"],
    );
    assert!(out.status.success(), "{d}");
    std::fs::create_dir(fx.path("inc")).unwrap();
    let ps = survey();
    let svc = Service::start_with(fx.dir.path(), "grown", &["--view", "far:own"]);
    let main = Client::attach(fx.dir.path(), "grown").unwrap();
    let own = Client::attach_view(fx.dir.path(), "grown", "far").unwrap();
    assert!(own.reads_own_grids());
    // Its own view of the same place, settled before any patch: every tile missing.
    let t = Instant::now();
    while own.try_snapshot().map_or(true, |s| s.min_lod != 0.0) {
        assert!(t.elapsed() < Duration::from_secs(20), "the own view never settled\n{}", svc.log());
        std::thread::sleep(Duration::from_millis(20));
    }
    for (n, p) in ps.iter().enumerate() {
        assert_eq!(svc.patch(p), format!("OK patch {}", n + 1), "{}", svc.log());
        // Two patches over the same tiles, the second while the first is being served.
        std::thread::sleep(Duration::from_millis(30));
    }
    settle(&svc, &main, ps.len() as u64);
    let want = Want::new(&ps);
    assert!(check_all(&main, &want) > 0, "the primary shows the patches");
    let t = Instant::now();
    loop {
        match differences(&own, &want) {
            Some((wrong, with_data)) if wrong.is_empty() && with_data > 0 => break,
            got => assert!(
                t.elapsed() < Duration::from_secs(20),
                "after 20 s the own view still differs from the patches: {got:?}\n{}",
                svc.log()
            ),
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}
