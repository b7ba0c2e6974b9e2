//! A view with grids of its own over a source whose texels change: it must end up showing the
//! texels the source serves, not those it copied from the primary's mapping before the primary
//! read them again.

use crate::protocol::ViewCommand;
use crate::ticker::{Command, Ticker};
use crate::Options;
use clipmap::shm::Client;
use clipmap::source::{HashSource, SourceError, TextureDesc, TileId, TileSource};
use clipmap::texel::TexelFormat;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::oneshot;

/// A hash texture replaced as a whole by a new version (as a remote COG replaced in its store
/// and opened again): every byte of version `v` is the hash's XOR `v * 0x5b`, and each read takes
/// `delay`, so that the primary's re-reads of its hundreds of tiles take many ticks. A version
/// `armed` comes into force right after the next look at the version: the primary's clipmap,
/// which looks first in a tick, sees the old one, and the own view's, which looks next, the new
/// one (as when the object is opened again by a read between the two looks).
struct Versioned {
    inner: HashSource,
    version: AtomicU64,
    armed: AtomicU64,
    delay: Duration,
}

impl Versioned {
    fn tile(&self, tile: TileId, version: u64) -> Vec<u8> {
        let mut out = vec![0; self.inner.desc().tile_bytes(tile.level)];
        self.inner.read_tile(tile, &mut out).unwrap();
        out.iter_mut().for_each(|b| *b ^= (version as u8).wrapping_mul(0x5b));
        out
    }
}

impl TileSource for Versioned {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        std::thread::sleep(self.delay);
        let v = self.version.load(Ordering::Acquire);
        self.inner.read_tile(tile, out)?;
        out.iter_mut().for_each(|b| *b ^= (v as u8).wrapping_mul(0x5b));
        Ok(())
    }

    fn version(&self) -> u64 {
        let v = self.version.load(Ordering::Acquire);
        let armed = self.armed.swap(0, Ordering::AcqRel);
        if armed != 0 {
            self.version.store(armed, Ordering::Release);
        }
        v
    }
}

/// The tiles under every enabled level's published region of `client`'s view, read whole from
/// their slots: how many are version `new`'s, how many `old`'s (tiles being refilled skipped).
/// Panics on a tile of neither.
fn tally(client: &Client, src: &Versioned, old: u64, new: u64) -> [u64; 2] {
    let Ok(snap) = client.try_snapshot() else { return [0, 0] };
    let mut n = [0; 2];
    let mut buf = Vec::new();
    for (k, l) in snap.levels.iter().enumerate() {
        if !l.enabled {
            continue;
        }
        let d = src.desc().level(k as u32);
        let [s0, t0, s1, t1] = l.valid;
        let (ts, tt) = (d.tile[0] as i64, d.tile[1] as i64);
        for t in t0 / tt..(t1 + tt - 1) / tt {
            for s in s0 / ts..(s1 + ts - 1) / ts {
                buf.resize(src.desc().tile_bytes(k as u32), 0);
                if client.read_tile(k, [s, t], &mut buf).is_err() {
                    continue;
                }
                let id = TileId::new(k as u32, s as u64, t as u64);
                if buf == src.tile(id, new) {
                    n[0] += 1;
                } else if buf == src.tile(id, old) {
                    n[1] += 1;
                } else {
                    panic!("{id:?}: texels of neither version {old} nor {new}");
                }
            }
        }
    }
    n
}

fn ask<T>(ticker: &Ticker, cmd: impl FnOnce(oneshot::Sender<T>) -> Command) -> T {
    let (tx, rx) = oneshot::channel();
    ticker.send(cmd(tx)).unwrap();
    rx.blocking_recv().unwrap()
}

/// The fault: a view with grids of its own read every tile again when the source's version
/// moved, but took most of them from the primary's mapping before the primary had read them
/// again, and so kept the old version's texels for good.
#[test]
fn own_view_refresh_keeps_replaced_source_version() {
    let dir = tempfile::tempdir().unwrap();
    let desc = TextureDesc::new([8192, 8192], 256, TexelFormat::RGBA8, [32, 32]).unwrap();
    let src = Arc::new(Versioned {
        inner: HashSource::new(desc),
        version: AtomicU64::new(0),
        armed: AtomicU64::new(0),
        delay: Duration::from_micros(1500),
    });
    let options = Options { shm_dir: dir.path().to_path_buf(), tick_hz: 30.0, ..Options::new("fresh") };
    let (ticker, _, join) = Ticker::start(src.clone(), &options).unwrap();
    let view = ViewCommand::Add { name: "far".into(), weight: 1.0, own: true };
    let r = ask(&ticker, |reply| Command::View { view, reply });
    assert!(r.is_ok(), "{r:?}");
    // Near main, not on it: the coarse levels are the primary's tiles, the fine ones its own.
    let view = ViewCommand::Centre { name: "far".into(), centre: [4096 + 900, 4096 - 600] };
    let r = ask(&ticker, |reply| Command::View { view, reply });
    assert!(r.is_ok(), "{r:?}");
    let client = Client::attach_view(dir.path(), "fresh", "far").unwrap();
    let far = |t: &Ticker| t.stats().views.into_iter().find(|v| v.name == "far").unwrap();
    let settled = |what: &str, old: u64, new: u64| {
        let t = Instant::now();
        loop {
            let n = tally(&client, &src, old, new);
            let stats = ticker.stats();
            if n[1] == 0 && n[0] > 0 && far(&ticker).min_lod == 0.0 && stats.min_lod == 0.0 {
                return n;
            }
            assert!(
                t.elapsed() < Duration::from_secs(20),
                "{what}: after 20 s the own view still shows {} tiles of version {old} ({} of {new}); {:?}",
                n[1],
                n[0],
                far(&ticker)
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    settled("version 0", 0, 0);
    assert!(far(&ticker).shared_reads > 0, "tiles were taken from the primary's mapping: {:?}", far(&ticker));
    for v in 1..=2 {
        src.armed.store(v, Ordering::Release);
        let n = settled(&format!("version {v}"), v - 1, v);
        assert!(n[0] > 100, "{n:?}");
    }
    assert_eq!(ticker.stats().engine.source_versions, 2);
    ticker.send(Command::Stop).unwrap();
    join.join().unwrap();
}
