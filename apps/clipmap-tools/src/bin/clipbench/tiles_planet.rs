//! `clipbench tiles`: a PMTiles of a sparse z0..z18 planet (millions of addressed tiles, leaf
//! directories, run-length entries) opened over HTTP against the benchmark's small archive, in
//! the same run: the issue's "opens as fast as a small one", as a ratio of median open times.
//!
//! The planet is written by the reference writer (Python's `pmtiles`), as the archive tests'
//! `planet.pmtiles`: a few tiles at every zoom 0..18, 40 000 scattered tiles at zoom 14 (which
//! the writer puts in leaf directories), and runs of a million and two million equal tiles (an
//! ocean) at zooms 17 and 18; every tile is the signature and header of one of the benchmark's
//! PNG tiles and a tag (its tiles are addressed, never decoded, here).

use super::cog_shared::median;
use super::serve::AccessLog;
use serde::Serialize;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// Run in the scratch directory: writes `planet.pmtiles` (tiles made from the first 33 bytes of
/// `xyz/0/0/0.png`) and prints the tiles it addresses.
const PLANET: &str = r#"
import random
from pmtiles.tile import zxy_to_tileid, TileType, Compression
from pmtiles.writer import Writer
rng = random.Random(47)
# A tile's signature and header chunk (its first 33 bytes) and a tag of its own: the planet's
# tiles are never decoded here, only addressed, and the file stays small.
png = open("xyz/0/0/0.png", "rb").read()[:33]
own = lambda tid: png + tid.to_bytes(8, "little")
ids = set()
for z in range(19):
    for _ in range(3):
        ids.add(zxy_to_tileid(z, rng.randrange(1 << z), rng.randrange(1 << z)))
tid = zxy_to_tileid(14, 0, 0)
for _ in range(40000):
    tid += rng.randint(1, 2000)
    ids.add(tid)
ocean = [(zxy_to_tileid(17, 0, 0) + 1000, 1_000_000), (zxy_to_tileid(18, 0, 0) + 5000, 2_000_000)]
ids = [t for t in ids if not any(f <= t < f + n for f, n in ocean)]
items = sorted([(t, 1, own(t)) for t in ids] + [(f, n, png) for f, n in ocean])
with open("planet.pmtiles", "wb") as f:
    w = Writer(f)
    for first, n, data in items:
        for k in range(n):
            w.write_tile(first + k, data)
    w.finalize({"tile_type": TileType.PNG, "tile_compression": Compression.NONE, "min_zoom": 0, "max_zoom": 18,
                "min_lon_e7": int(-180e7), "min_lat_e7": int(-85.0511287e7), "max_lon_e7": int(180e7),
                "max_lat_e7": int(85.0511287e7), "center_zoom": 0, "center_lon_e7": 0, "center_lat_e7": 0},
               {"name": "planet"})
print(sum(n for _, n, _ in items))
"#;

/// The sparse planet's open against the small archive's, as `clipbench tiles --json` prints it.
#[derive(Debug, Serialize)]
pub struct PlanetOpen {
    /// Tiles the planet addresses (zooms 0..18).
    pub addressed_tiles: u64,
    pub planet_bytes: u64,
    /// The small archive (the benchmark's own PMTiles) and its bytes.
    pub small_bytes: u64,
    /// Opens of each, taken in turn.
    pub opens: u64,
    /// Median seconds to open over HTTP: the planet, the small archive.
    pub open_s: f64,
    pub small_open_s: f64,
    /// The planet's median open over the small one's (the goal: about 1, "as fast").
    pub vs_small: f64,
    /// Requests and bytes of one open of each (nginx's log).
    pub open_requests: u64,
    pub open_bytes: u64,
    pub small_open_requests: u64,
    pub small_open_bytes: u64,
}

/// Writes the planet into `dir` (served by nginx at `base`), then opens it and `small_url`
/// `opens` times each, in turn, with `open`.
pub fn planet_open(
    python: &Path,
    dir: &Path,
    base: &str,
    small_url: &str,
    log: &AccessLog,
    opens: u64,
    open: &dyn Fn(&str) -> anyhow::Result<()>,
) -> anyhow::Result<PlanetOpen> {
    let file = dir.join("clipbench_planet.py");
    std::fs::write(&file, PLANET)?;
    let out = Command::new(python).arg(&file).current_dir(dir).output()?;
    anyhow::ensure!(
        out.status.success(),
        "writing the sparse planet with the reference PMTiles writer failed: {}",
        String::from_utf8_lossy(&out.stderr).trim()
    );
    let addressed_tiles: u64 = String::from_utf8_lossy(&out.stdout).trim().parse()?;
    let planet_url = format!("{base}/planet.pmtiles");
    // One open of each, counted at nginx.
    let counted = |url: &str| -> anyhow::Result<(u64, u64)> {
        let before = log.settled()?.len();
        open(url)?;
        let hits = log.settled()?;
        Ok((hits.len().saturating_sub(before) as u64, hits[before.min(hits.len())..].iter().map(|h| h.bytes).sum()))
    };
    let (open_requests, open_bytes) = counted(&planet_url)?;
    let (small_open_requests, small_open_bytes) = counted(small_url)?;
    let (mut planet, mut small) = (Vec::new(), Vec::new());
    for _ in 0..opens {
        for (url, times) in [(&planet_url[..], &mut planet), (small_url, &mut small)] {
            let t = Instant::now();
            open(url)?;
            times.push(t.elapsed().as_secs_f64());
        }
    }
    let (open_s, small_open_s) = (median(planet), median(small));
    Ok(PlanetOpen {
        addressed_tiles,
        planet_bytes: std::fs::metadata(dir.join("planet.pmtiles"))?.len(),
        small_bytes: std::fs::metadata(dir.join("tiles.pmtiles"))?.len(),
        opens,
        open_s,
        small_open_s,
        vs_small: open_s / small_open_s.max(1e-9),
        open_requests,
        open_bytes,
        small_open_requests,
        small_open_bytes,
    })
}
