//! `cliptex seed`: fills the remote disk cache with the tiles of an area (a box, or a corridor
//! along a route) at some levels of a tile service or a remote tile archive, before a flight;
//! or, with `--estimate`, says what that would take (tiles, bytes, requests, time): for a
//! PMTiles, bytes and requests from the archive's own directories, exactly (each entry's length;
//! `estimate_method: "directories"`), for a tile service from a small sample of fetched tiles
//! (`"sample"`); the time at the rate the sample was fetched at, either way.
//!
//! The tiles an area touches at a zoom are those `clipmap::source::tiles::pyramid::tile_range`
//! gives (the same arithmetic the service uses to decide which tiles lie within `--bounds`).
//! Tiles the cache holds already are skipped and counted (`skipped_cached`): a seed stopped
//! (Ctrl-C, kill) and run again goes on where it stopped, since the cache keeps every tile
//! written whole (docs/TILES.md, "Cache and seeding").

use clipmap::cli::TilesArgs;
use clipmap::report::{self, exit};
use clipmap::source::remote::RemoteOptions;
use clipmap::source::tiles::pyramid::tile_range;
use clipmap::source::tiles::{Fetched, TileAddr, TileArchive};
use serde::Serialize;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// The most tiles one seed covers: more is a mistake of levels or area (at zoom 18 a box of 1°
/// is already about 530 000 tiles).
pub const MAX_SEED_TILES: u64 = 50_000_000;

/// Metres along a degree of latitude (and of longitude at the equator), WGS 84's mean.
const METRES_PER_DEGREE: f64 = 111_320.0;

/// Web Mercator's latitude limit.
const MAX_LAT: f64 = 85.051_128_779_806_6;

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("area").required(true).args(["bbox", "route"])))]
pub(crate) struct SeedArgs {
    /// The tile service or archive, as `cliptex info` takes it: `xyz:TEMPLATE` (http/https), a
    /// `.pmtiles` URL (http/https or s3://).
    source: PathBuf,
    /// The area: west, south, east, north in degrees of longitude and latitude (WGS 84).
    #[arg(long, value_name = "W,S,E,N", allow_hyphen_values = true)]
    bbox: Option<String>,
    /// The area: a corridor along a route, a text file of points, one `LON,LAT` (degrees,
    /// WGS 84) a line, in flight order; blank lines and lines starting with `#` are skipped.
    #[arg(long, value_name = "FILE")]
    route: Option<PathBuf>,
    /// The corridor's width along a --route, in kilometres (half of it on each side).
    #[arg(long, value_name = "KM", default_value_t = 2.0)]
    width_km: f64,
    /// The levels to seed, `A..B` (inclusive) or one level `A`: level 0 is the finest zoom
    /// (as `cliptex info` numbers them), level k the zoom k coarser.
    #[arg(long, value_name = "A..B")]
    levels: String,
    /// Only say what the seed would take: tiles, bytes, requests and time, measured on a sample
    /// of --sample tiles fetched (and cached); nothing else is fetched.
    #[arg(long)]
    estimate: bool,
    /// Tiles fetched by --estimate to measure sizes and the rate (0: count the tiles only).
    #[arg(long, value_name = "N", default_value_t = 8)]
    sample: u64,
    /// The cache directory (default: CLIPMAP_REMOTE_CACHE_DIR); its bound is
    /// CLIPMAP_REMOTE_CACHE_BYTES.
    #[arg(long, value_name = "DIR")]
    cache_dir: Option<PathBuf>,
    /// Tiles fetched at once (default: 16, or CLIPMAP_REMOTE_IN_FLIGHT, the cap per host, if lower).
    #[arg(long, value_name = "N")]
    jobs: Option<usize>,
    /// Print a JSON summary instead of text.
    #[arg(long)]
    json: bool,
    /// No progress (bar or lines).
    #[arg(long, short)]
    quiet: bool,
    #[command(flatten)]
    tiles: TilesArgs,
}

/// What `cliptex seed` did (`--json`).
#[derive(Serialize)]
struct Summary {
    source: String,
    levels: [u32; 2],
    zooms: [u8; 2],
    /// Tiles in the area at those levels.
    tiles: u64,
    /// Tiles fetched now (present at the source).
    fetched: u64,
    /// Bytes of the tiles fetched now.
    bytes: u64,
    /// Requests sent (retries included; a PMTiles archive's open and leaf directories too).
    requests: u64,
    /// Tiles the cache held already, not fetched.
    skipped_cached: u64,
    /// Tiles the source does not have (404, 204, no entry): nothing to cache.
    missing: u64,
    /// Tiles that could not be fetched (after retries): run the seed again.
    failed: u64,
    seconds: f64,
    cache_dir: PathBuf,
    cache_bytes: u64,
}

/// What `cliptex seed --estimate` says (`--json`).
#[derive(Serialize)]
struct Estimate {
    estimate: bool,
    source: String,
    levels: [u32; 2],
    zooms: [u8; 2],
    /// Tiles in the area at those levels.
    tiles: u64,
    /// Of those, tiles the cache holds already (when a cache is configured).
    skipped_cached: u64,
    /// How `bytes` and `requests` were found: `"directories"` (a PMTiles: each tile's length
    /// read from the archive's own directories, exactly) or `"sample"` (the sample's mean size
    /// and requests a tile, for a tile service).
    estimate_method: &'static str,
    /// Bytes of the tiles still to fetch: the sum of their entries' lengths (`directories`),
    /// else at the sample's mean size a tile.
    bytes: u64,
    /// Requests to fetch them: one a tile the archive holds plus the leaf directories read to
    /// find them (`directories`), else at the sample's requests a tile.
    requests: u64,
    /// Of the tiles still to fetch, those the archive does not hold (`directories` only: they
    /// cost no request).
    #[serde(skip_serializing_if = "Option::is_none")]
    missing: Option<u64>,
    /// Seconds to fetch them, at the sample's rate.
    seconds: f64,
    /// What was fetched to measure: the only tiles this estimate fetched.
    sample: Sample,
}

#[derive(Serialize, Default)]
struct Sample {
    tiles: u64,
    present: u64,
    missing: u64,
    bytes: u64,
    requests: u64,
    seconds: f64,
}

/// `--levels A..B` or `A`.
fn parse_levels(text: &str) -> Result<[u32; 2], String> {
    let bad = || {
        format!("--levels `{text}`: expected A..B (inclusive, A <= B) or one level A, level 0 the finest zoom (e.g. --levels 0..4)")
    };
    let (a, b) = text.split_once("..").unwrap_or((text, text));
    let (a, b): (u32, u32) = (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
    if a > b {
        return Err(bad());
    }
    Ok([a, b])
}

/// `--bbox W,S,E,N`.
fn parse_bbox(text: &str) -> Result<[f64; 4], String> {
    let how = "expected W,S,E,N in degrees (WGS 84) with -180 <= W < E <= 180 and -90 <= S < N <= 90, e.g. --bbox 13.0,52.3,13.8,52.7 (to cross the antimeridian, seed each side apart)";
    let parts: Vec<&str> = text.split(',').collect();
    let v: Vec<f64> = parts.iter().filter_map(|p| p.trim().parse::<f64>().ok()).filter(|x| x.is_finite()).collect();
    if parts.len() != 4 || v.len() != 4 {
        return Err(format!("--bbox `{text}`: found {} numbers: {how}", v.len()));
    }
    let [w, s, e, n] = [v[0], v[1], v[2], v[3]];
    if !(-180.0..=180.0).contains(&w) || !(-180.0..=180.0).contains(&e) {
        return Err(format!("--bbox `{text}`: longitudes {w} and {e}: {how}"));
    }
    if !(-90.0..=90.0).contains(&s) || !(-90.0..=90.0).contains(&n) {
        return Err(format!("--bbox `{text}`: latitudes {s} and {n}: {how} (longitude first)"));
    }
    if w >= e || s >= n {
        return Err(format!("--bbox `{text}`: west {w}, east {e}, south {s}, north {n}: {how}"));
    }
    Ok([w, s, e, n])
}

/// The points of a route file.
fn read_route(path: &Path) -> Result<Vec<[f64; 2]>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("--route {}: {e}", path.display()))?;
    let mut points = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = l.split([',', ' ', '\t']).filter(|p| !p.is_empty()).filter_map(|p| p.parse().ok()).collect();
        let ok = v.len() == 2 && (-180.0..=180.0).contains(&v[0]) && (-90.0..=90.0).contains(&v[1]);
        if !ok {
            return Err(format!(
                "{}:{}: `{l}` is not a point: expected LON,LAT in degrees (WGS 84), longitude in -180..180 first, latitude in -90..90, e.g. 13.40,52.52",
                path.display(),
                i + 1
            ));
        }
        points.push([v[0], v[1]]);
    }
    if points.is_empty() {
        return Err(format!("{}: no points: expected one LON,LAT a line, e.g. 13.40,52.52", path.display()));
    }
    Ok(points)
}

/// The tiles of zoom `z` a box touches.
fn box_tiles(b: &[f64; 4], z: u8, out: &mut BTreeSet<(u32, u32)>) {
    let [x0, y0, x1, y1] = tile_range(b, z);
    for y in y0..=y1 {
        for x in x0..=x1 {
            out.insert((x, y));
        }
    }
}

/// The tiles of zoom `z` a corridor `width_km` wide along `points` touches: boxes of the
/// corridor's width around points along each leg, spaced at most a quarter of the width or of
/// a tile apart.
fn route_tiles(points: &[[f64; 2]], width_km: f64, z: u8, out: &mut BTreeSet<(u32, u32)>) {
    let half_deg = width_km * 500.0 / METRES_PER_DEGREE;
    let tile_deg = 360.0 / TileAddr::tiles_at(z) as f64;
    let step = (half_deg / 2.0).min(tile_deg / 4.0).max(1e-7);
    let around = |lon: f64, lat: f64, out: &mut BTreeSet<(u32, u32)>| {
        let lat = lat.clamp(-MAX_LAT, MAX_LAT);
        let dlon = (half_deg / lat.to_radians().cos().max(0.01)).min(180.0);
        let b = [
            (lon - dlon).max(-180.0),
            (lat - half_deg).max(-MAX_LAT),
            (lon + dlon).min(180.0),
            (lat + half_deg).min(MAX_LAT),
        ];
        box_tiles(&b, z, out);
    };
    around(points[0][0], points[0][1], out);
    for leg in points.windows(2) {
        let (a, b) = (leg[0], leg[1]);
        let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
        let n = (len / step).ceil().max(1.0) as u64;
        for i in 1..=n {
            let f = i as f64 / n as f64;
            around(a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, out);
        }
    }
}

/// Runs `cliptex seed`.
pub(crate) fn run(args: SeedArgs) -> i32 {
    match seed(&args) {
        Ok(code) => code,
        Err((code, message)) => {
            eprintln!("cliptex seed: {message}");
            code
        }
    }
}

type Failure = (i32, String);

/// Bytes as MiB, one decimal.
fn size(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / f64::from(1u32 << 20))
}

fn bad(message: String) -> Failure {
    (exit::BAD_INPUT, message)
}

/// Every tile of the area at the levels asked, coarsest zoom first, rows from the north.
fn area_tiles(args: &SeedArgs, zooms: [u8; 2], bounds: Option<[f64; 4]>) -> Result<Vec<TileAddr>, Failure> {
    let area = match (&args.bbox, &args.route) {
        (Some(b), _) => Area::Box(parse_bbox(b).map_err(bad)?),
        (None, Some(r)) => {
            if !(args.width_km.is_finite() && args.width_km > 0.0 && args.width_km <= 1000.0) {
                return Err(bad(format!(
                    "--width-km {}: expected a corridor width in kilometres, more than 0 and at most 1000",
                    args.width_km
                )));
            }
            Area::Route(read_route(r).map_err(bad)?)
        }
        (None, None) => return Err(bad("give the area: --bbox W,S,E,N or --route FILE".into())),
    };
    let mut all = Vec::new();
    for z in zooms[0]..=zooms[1] {
        let mut set = BTreeSet::new();
        match &area {
            Area::Box(b) => {
                let [x0, y0, x1, y1] = tile_range(b, z);
                let n = u64::from(x1 - x0 + 1) * u64::from(y1 - y0 + 1);
                if all.len() as u64 + n > MAX_SEED_TILES {
                    return Err(too_many(zooms));
                }
                box_tiles(b, z, &mut set);
            }
            Area::Route(points) => route_tiles(points, args.width_km, z, &mut set),
        }
        let within = bounds.map(|b| tile_range(&b, z));
        for (x, y) in set {
            if let Some([x0, y0, x1, y1]) = within {
                if !(x0..=x1).contains(&x) || !(y0..=y1).contains(&y) {
                    continue;
                }
            }
            all.push(TileAddr { z, x, y });
        }
        if all.len() as u64 > MAX_SEED_TILES {
            return Err(too_many(zooms));
        }
    }
    Ok(all)
}

fn too_many(zooms: [u8; 2]) -> Failure {
    bad(format!(
        "the area at zooms {}..{} holds more than {MAX_SEED_TILES} tiles: seed fewer levels (a coarser finest level) or a smaller area",
        zooms[0], zooms[1]
    ))
}

enum Area {
    Box([f64; 4]),
    Route(Vec<[f64; 2]>),
}

fn seed(args: &SeedArgs) -> Result<i32, Failure> {
    let levels = parse_levels(&args.levels).map_err(bad)?;
    let text = args.source.to_string_lossy().into_owned();
    if !clipmap::source::tiles::is_pyramid(&text) {
        return Err(bad(format!(
            "{text}: not a tile service or archive: expected xyz:TEMPLATE (an http/https URL with {{z}}, {{x}}, {{y}}) or a .pmtiles URL (docs/TILES.md)"
        )));
    }
    let mut ropts = RemoteOptions::from_env().map_err(|e| bad(e.to_string()))?;
    if let Some(dir) = &args.cache_dir {
        ropts.cache_dir = Some(dir.clone());
    }
    let Some(cache_dir) = ropts.cache_dir.clone() else {
        if args.estimate {
            return estimate_without_cache(args, levels, &text, ropts);
        }
        return Err(bad(
            "no cache to fill: give --cache-dir DIR or set CLIPMAP_REMOTE_CACHE_DIR (the cache clipmapd and cliptex read)"
                .into(),
        ));
    };
    let cache_bytes = ropts.cache_bytes;
    let (archive, zooms, tiles) = open(args, levels, &text, ropts)?;
    if args.estimate {
        return estimate(args, levels, zooms, &archive, &tiles);
    }
    let started = Instant::now();
    let counts = fetch_all(args, &archive, &tiles, true, &progress(args, tiles.len() as u64));
    // Every request since the source was opened: a PMTiles archive's open and tile-size probe too.
    let requests = archive.remote_stats().unwrap_or_default().requests;
    let summary = Summary {
        source: archive.place().to_string(),
        levels,
        zooms,
        tiles: tiles.len() as u64,
        fetched: counts.fetched.load(Ordering::Relaxed),
        bytes: counts.bytes.load(Ordering::Relaxed),
        requests,
        skipped_cached: counts.cached.load(Ordering::Relaxed),
        missing: counts.missing.load(Ordering::Relaxed),
        failed: counts.failed.load(Ordering::Relaxed),
        seconds: started.elapsed().as_secs_f64(),
        cache_dir,
        cache_bytes,
    };
    report::emit(args.json, &summary, |s| {
        format!(
            "{}: levels {}..{} (zooms {}..{}): {} tiles: {} fetched ({}), {} already cached, {} missing at the source, {} failed; {} requests in {:.1} s\ncache {} (bound {})\n",
            s.source,
            s.levels[0],
            s.levels[1],
            s.zooms[1],
            s.zooms[0],
            s.tiles,
            s.fetched,
            size(s.bytes),
            s.skipped_cached,
            s.missing,
            s.failed,
            s.requests,
            s.seconds,
            s.cache_dir.display(),
            size(s.cache_bytes)
        )
    });
    let failed = summary.failed;
    if failed > 0 {
        let first = counts.first_error.lock().unwrap_or_else(|e| e.into_inner()).clone().unwrap_or_default();
        eprintln!(
            "cliptex seed: {failed} tiles could not be fetched (first: {first}); run the same command again to fetch them (cached tiles are skipped)"
        );
        return Ok(exit::COULD_NOT_RUN);
    }
    Ok(exit::OK)
}

/// An opened source: the archive, the zooms of the levels asked (coarsest first) and the
/// tiles of the area.
type Opened = (Arc<dyn TileArchive>, [u8; 2], Vec<TileAddr>);

/// Opens the source with the remote options `ropts` ([`Opened`]).
fn open(args: &SeedArgs, levels: [u32; 2], text: &str, ropts: RemoteOptions) -> Result<Opened, Failure> {
    let mut opts = args.tiles.options(Some(super::COG_CLIP)).map_err(bad)?;
    opts.template.remote = Some(ropts);
    let archive = clipmap::source::tiles::open_archive(text, &opts)
        .unwrap_or_else(|| unreachable!("checked by is_pyramid"))
        .map_err(|e| bad(e.to_string()))?;
    if archive.remote_stats().is_none() {
        return Err(bad(format!(
            "{}: a local tree or archive: there is nothing to cache (seeding fills the cache of remote sources: an http(s) template or a remote .pmtiles)",
            archive.place()
        )));
    }
    let info = archive.info().clone();
    let deepest = u32::from(info.max_zoom - info.min_zoom);
    if levels[1] > deepest {
        return Err(bad(format!(
            "--levels {}..{}: {} has levels 0..{deepest} (zooms {}..{}; level 0 = zoom {}): give levels within them (coarser levels are built from zoom {}: seed level {deepest})",
            levels[0],
            levels[1],
            archive.place(),
            info.max_zoom,
            info.min_zoom,
            info.max_zoom,
            info.min_zoom
        )));
    }
    let zooms = [info.max_zoom - levels[1] as u8, info.max_zoom - levels[0] as u8];
    let tiles = area_tiles(args, zooms, info.bounds)?;
    Ok((archive, zooms, tiles))
}

/// `--estimate` without a cache: the same sample, nothing is kept.
fn estimate_without_cache(args: &SeedArgs, levels: [u32; 2], text: &str, ropts: RemoteOptions) -> Result<i32, Failure> {
    let (archive, zooms, tiles) = open(args, levels, text, ropts)?;
    estimate(args, levels, zooms, &archive, &tiles)
}

/// The counters of a seed, shared by its workers.
#[derive(Default)]
struct Counts {
    fetched: AtomicU64,
    bytes: AtomicU64,
    cached: AtomicU64,
    missing: AtomicU64,
    failed: AtomicU64,
    first_error: Mutex<Option<String>>,
}

/// Fetches `tiles` with `--jobs` workers (skipping those the cache holds when `skip`), counting.
fn fetch_all(
    args: &SeedArgs,
    archive: &Arc<dyn TileArchive>,
    tiles: &[TileAddr],
    skip: bool,
    bar: &Progress,
) -> Counts {
    let counts = Counts::default();
    let next = AtomicUsize::new(0);
    let jobs = args
        .jobs
        .unwrap_or_else(|| {
            RemoteOptions::from_env().map_or(8, |o| o.in_flight.min(clipmap::source::remote::flight::FLOOR))
        })
        .clamp(1, 256);
    std::thread::scope(|s| {
        for _ in 0..jobs.min(tiles.len().max(1)) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(&at) = tiles.get(i) else { break };
                if skip && archive.is_cached(at) {
                    counts.cached.fetch_add(1, Ordering::Relaxed);
                } else {
                    match archive.fetch(at) {
                        Ok(Fetched::Tile(b)) => {
                            counts.fetched.fetch_add(1, Ordering::Relaxed);
                            counts.bytes.fetch_add(b.len() as u64, Ordering::Relaxed);
                        }
                        Ok(Fetched::Missing) => {
                            counts.missing.fetch_add(1, Ordering::Relaxed);
                        }
                        Err(e) => {
                            counts.failed.fetch_add(1, Ordering::Relaxed);
                            counts.first_error.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(e.to_string());
                        }
                    }
                }
                bar.inc();
            });
        }
    });
    bar.finish();
    counts
}

/// `--estimate`: a sample of tiles spread over the list fetched (with the workers a seed would
/// use), then the whole measured by it.
fn estimate(
    args: &SeedArgs,
    levels: [u32; 2],
    zooms: [u8; 2],
    archive: &Arc<dyn TileArchive>,
    tiles: &[TileAddr],
) -> Result<i32, Failure> {
    let cached: Vec<bool> = tiles.iter().map(|&at| archive.is_cached(at)).collect();
    let todo: Vec<TileAddr> = tiles.iter().zip(&cached).filter(|(_, c)| !**c).map(|(t, _)| *t).collect();
    // A PMTiles: every tile's length from its directories (before the sample, so that the
    // sample's requests are its tiles' alone).
    let exact = exact_lengths(archive, &todo)?;
    let n = (args.sample as usize).min(todo.len());
    let sample: Vec<TileAddr> = (0..n).map(|i| todo[i * todo.len() / n.max(1)]).collect();
    let before = archive.remote_stats().unwrap_or_default().requests;
    let started = Instant::now();
    let counts = fetch_all(args, archive, &sample, false, &Progress::None);
    let seconds = started.elapsed().as_secs_f64();
    let requests = archive.remote_stats().unwrap_or_default().requests - before;
    let s = Sample {
        tiles: n as u64,
        present: counts.fetched.load(Ordering::Relaxed),
        missing: counts.missing.load(Ordering::Relaxed),
        bytes: counts.bytes.load(Ordering::Relaxed),
        requests,
        seconds,
    };
    if counts.failed.load(Ordering::Relaxed) > 0 {
        let first = counts.first_error.lock().unwrap_or_else(|e| e.into_inner()).clone().unwrap_or_default();
        return Err((exit::COULD_NOT_RUN, format!("the sample could not be fetched: {first}")));
    }
    let left = todo.len() as u64;
    let per = |x: u64| if n == 0 { 0.0 } else { x as f64 / n as f64 };
    let rate = |tiles: u64| if n == 0 { 0.0 } else { seconds / n as f64 * tiles as f64 };
    let (estimate_method, bytes, requests, missing, secs) = match exact {
        Some(x) => ("directories", x.bytes, x.present + x.leaf_requests, Some(x.missing), rate(x.present)),
        None => (
            "sample",
            (per(s.bytes) * left as f64).round() as u64,
            (per(s.requests) * left as f64).round() as u64,
            None,
            rate(left),
        ),
    };
    let e = Estimate {
        estimate: true,
        source: archive.place().to_string(),
        levels,
        zooms,
        tiles: tiles.len() as u64,
        skipped_cached: tiles.len() as u64 - left,
        estimate_method,
        bytes,
        requests,
        missing,
        seconds: secs,
        sample: s,
    };
    report::emit(args.json, &e, |e| {
        let how = match e.missing {
            Some(m) => format!(
                "bytes and requests from the archive's directories, exactly ({m} of them not in the archive; leaf directories read to find them), the time at the rate"
            ),
            None => "bytes and requests at the sample's mean a tile, the time at its rate".to_string(),
        };
        format!(
            "{}: levels {}..{} (zooms {}..{}): {} tiles, {} already cached\nestimate for the {} to fetch: {}, {} requests, {:.0} s ({how})\n(measured on a sample of {} tiles fetched now: {} present, {} missing, {}, {} requests, {:.2} s; nothing else was fetched)\n",
            e.source,
            e.levels[0],
            e.levels[1],
            e.zooms[1],
            e.zooms[0],
            e.tiles,
            e.skipped_cached,
            left,
            size(e.bytes),
            e.requests,
            e.seconds,
            e.sample.tiles,
            e.sample.present,
            e.sample.missing,
            size(e.sample.bytes),
            e.sample.requests,
            e.sample.seconds
        )
    });
    Ok(exit::OK)
}

/// What an archive's directories say of the tiles to fetch ([`exact_lengths`]).
struct Exact {
    present: u64,
    missing: u64,
    bytes: u64,
    /// Requests made to read the leaf directories that lead to them.
    leaf_requests: u64,
}

/// Each tile's stored length from the archive's own index (a PMTiles' directories, leaves read
/// as needed); `None` for an archive without one (a tile service: the sample estimates).
fn exact_lengths(archive: &Arc<dyn TileArchive>, todo: &[TileAddr]) -> Result<Option<Exact>, Failure> {
    let Some(&first) = todo.first() else { return Ok(None) };
    if archive.stored_length(first).is_none() {
        return Ok(None);
    }
    let before = archive.remote_stats().unwrap_or_default().requests;
    let mut x = Exact { present: 0, missing: 0, bytes: 0, leaf_requests: 0 };
    for &at in todo {
        match archive.stored_length(at) {
            Some(Ok(Some(len))) => {
                x.present += 1;
                x.bytes += len;
            }
            Some(Ok(None)) | None => x.missing += 1,
            Some(Err(e)) => {
                return Err((exit::COULD_NOT_RUN, format!("the archive's directories could not be read: {e}")))
            }
        }
    }
    x.leaf_requests = archive.remote_stats().unwrap_or_default().requests - before;
    Ok(Some(x))
}

/// Progress: a bar on a terminal, a line every 5 % otherwise, nothing with --quiet or --json.
enum Progress {
    None,
    Bar(indicatif::ProgressBar),
    Lines { total: u64, done: AtomicU64 },
}

fn progress(args: &SeedArgs, total: u64) -> Progress {
    use std::io::IsTerminal;
    if args.quiet || args.json {
        Progress::None
    } else if std::io::stderr().is_terminal() {
        Progress::Bar(super::tile_bar(total, false))
    } else {
        Progress::Lines { total, done: AtomicU64::new(0) }
    }
}

impl Progress {
    fn inc(&self) {
        match self {
            Progress::None => {}
            Progress::Bar(b) => b.inc(1),
            Progress::Lines { total, done } => {
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                let step = (total / 20).max(1);
                if d % step == 0 || d == *total {
                    eprintln!("cliptex seed: {d}/{total} tiles");
                }
            }
        }
    }

    fn finish(&self) {
        if let Progress::Bar(b) = self {
            b.finish_and_clear();
        }
    }
}
