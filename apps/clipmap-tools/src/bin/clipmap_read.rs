//! `clipmap-read`: a reader of a published clip texture that serves the hash texture. Reads random
//! blocks of texels inside the published valid regions and checks every one; optionally asks for
//! centres (a fast flight with jumps and reversals) and follows the service across restarts.
//!
//! `--dump-level L --region S0,T0,S1,T1 --out FILE` instead writes a region of any texture (not
//! only the hash texture) to `FILE.raw` (the stored bytes) or `FILE.png` (as `cliptex dump`
//! draws it) and prints one JSON line saying what was written.
//!
//! Prints one JSON line of counts, then `N passed, M failed`.
//! Exit status: 0 every texel matched, 1 a mismatch (or a bad command line), 2 the mapping could
//! not be read, or (`--follow`) the service came back after a restart without the view read: a
//! view added only on the control socket is not there after a restart until it is added again
//! (docs/VIEWS.md); the reader waits for it until its time is up, then says so.

#![forbid(unsafe_code)]

use clap::Parser;
use clipmap::report::exit;
use clipmap::shm::verify::HashCheck;
use clipmap::shm::{Client, ShmError};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    name = "clipmap-read",
    version,
    about = "Read and verify a clip texture published by clipmapd --source hash",
    after_help = "\
Every texel read is checked against the verification texture (hash); any wrong texel fails.

Examples:
  clipmapd --source hash --size 65536 --clip 512 --name hash &
  clipmap-read --name hash --reads 1000000
  clipmap-read --name hash --follow --seconds 60      # keeps reading through service restarts
  clipmap-read --name hash --drive --seconds 10       # also requests a fast flight with jumps
  clipmap-read --name hash --lonlat 13.4,52.5         # centred there first (a georeferenced texture)
  clipmap-read --name terrain --dump-level 2 --region 100,200,356,456 --out part.png
  clipmap-read --name terrain --dump-level 0 --region 0,0,64,64 --out part.raw

--dump-level writes a region of any texture instead of checking the hash texture: FILE.raw holds
the stored texel bytes (rows in increasing t, s fastest, no header); FILE.png is drawn as `cliptex
dump` draws a level (t upwards; 16-bit formats as 16-bit PNGs of the stored values; heights in
false colour with a legend). The region must lie inside the level's published valid region; the
reader waits for it up to --seconds while the service is still loading it."
)]
struct Cli {
    /// Publication name.
    #[arg(long, default_value = "hash")]
    name: String,
    /// Directory of the mapping.
    #[arg(long)]
    shm_dir: Option<PathBuf>,
    /// A mapping file to read instead of a name.
    #[arg(long, conflicts_with_all = ["name", "follow"])]
    path: Option<PathBuf>,
    /// Stop after checking this many texels.
    #[arg(long, default_value_t = 1_000_000)]
    reads: u64,
    /// Stop after this many seconds in any case.
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// Edge of the blocks read at once.
    #[arg(long, default_value_t = 16)]
    block: u64,
    /// Follow the service: notice a stale heartbeat, reattach when the name is republished.
    #[arg(long)]
    follow: bool,
    /// Heartbeat age (ms) after which the service is considered stale.
    #[arg(long, default_value_t = 500)]
    stale_ms: u64,
    /// Also request centres: a fast flight with jumps and reversals.
    #[arg(long)]
    drive: bool,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The view to read (docs/VIEWS.md): `main`, the primary, or a further view's name.
    #[arg(long, default_value = "main")]
    view: String,
    /// Also ask for the view's levels from HEIGHT level-0 texels above the texture, one screen
    /// pixel spanning ANGLE radians, addressing EFFECTIVE levels at once (0 or omitted: all):
    /// the service moves the view's LOD offset to match (docs/VIEWS.md, "Virtual views").
    #[arg(long, value_name = "HEIGHT,ANGLE[,EFFECTIVE]", value_parser = parse_lod)]
    lod: Option<(f64, f64, u32)>,
    /// First ask for the view's centre at this WGS 84 longitude / latitude (degrees) through the
    /// request mapping (coordinate kind 1, docs/SHM.md) and wait until level 0 is centred on the
    /// texel that holds it (through the mapping's georef block), then read there. A texture
    /// without georeferencing, or a point outside it, is refused (exit 1).
    #[arg(long, value_name = "LON,LAT", allow_hyphen_values = true, value_parser = parse_lonlat, conflicts_with = "drive")]
    lonlat: Option<[f64; 2]>,
    /// Write a region of this level to --out instead of checking the hash texture.
    #[arg(long, value_name = "LEVEL", requires_all = ["region", "out"], conflicts_with_all = ["drive", "follow", "lod"])]
    dump_level: Option<usize>,
    /// The region to write (with --dump-level): S0,T0,S1,T1 in level texels, half-open.
    #[arg(long, value_name = "S0,T0,S1,T1", value_parser = clipmap::report::dump::parse_region, requires = "dump_level")]
    region: Option<[u64; 4]>,
    /// The file to write (with --dump-level): FILE.raw (the stored bytes) or FILE.png.
    #[arg(long, value_name = "FILE", requires = "dump_level")]
    out: Option<PathBuf>,
}

/// `--lonlat LON,LAT`.
fn parse_lonlat(s: &str) -> Result<[f64; 2], String> {
    let bad = || format!("`{s}`: expected LON,LAT in degrees, such as 13.4,52.5 or -122.42,37.77");
    match s.split(',').map(|w| w.trim().parse::<f64>()).collect::<Vec<_>>().as_slice() {
        [Ok(lon), Ok(lat)] if lon.is_finite() && lat.is_finite() => Ok([*lon, *lat]),
        _ => Err(bad()),
    }
}

/// `--lonlat`: asks for the centre at `ll` and waits (until `deadline`) for level 0 to be
/// centred on the texel that holds it; returns that texel. `Err` carries the exit status.
fn centre_at(client: &Client, ll: [f64; 2], deadline: Instant) -> Result<[i64; 2], (i32, String)> {
    let size0 = client.levels[0].size;
    let block = client.georef.as_ref().ok_or_else(|| {
        (exit::BAD_INPUT, "--lonlat: the texture has no georeferencing (its mapping has no georef block; docs/GEOREF.md): read at texels instead".to_string())
    })?;
    let g = clipmap::shm::georef_of(block, size0).map_err(|e| (exit::BAD_INPUT, format!("--lonlat: {e}")))?;
    let [s, t] =
        g.lonlat_to_texel(0, ll).map_err(|e| (exit::BAD_INPUT, format!("--lonlat {},{}: {e}", ll[0], ll[1])))?;
    let want = [s.floor() as i64, t.floor() as i64];
    let mut asked = false;
    loop {
        if !asked {
            asked = client.request_position(clipmap::shm::RequestPosition::LonLat(ll), [0.0, 0.0]);
        }
        if asked && client.level_state(0).is_some_and(|st| st.centre == want) {
            return Ok(want);
        }
        if Instant::now() >= deadline {
            return Err((
                exit::COULD_NOT_RUN,
                format!("--lonlat {},{}: level 0 was not centred on texel {want:?} within --seconds (request made: {asked})", ll[0], ll[1]),
            ));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// `--lod HEIGHT,ANGLE[,EFFECTIVE]`.
fn parse_lod(s: &str) -> Result<(f64, f64, u32), String> {
    let parts: Vec<&str> = s.split(',').collect();
    let num = |w: &str, what: &str| match w.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(format!("{what} `{w}`: expected a positive finite number")),
    };
    match parts.as_slice() {
        [h, a] | [h, a, _] => {
            let (h, a) = (num(h, "height")?, num(a, "pixel angle")?);
            if a >= std::f64::consts::PI {
                return Err(format!("pixel angle {a}: expected radians below pi, such as 0.001"));
            }
            let e = match parts.get(2) {
                Some(e) => {
                    e.trim().parse::<u32>().map_err(|_| format!("effective levels `{e}`: expected 0 (all) or more"))?
                }
                None => 0,
            };
            Ok((h, a, e))
        }
        _ => Err(format!("`{s}`: expected HEIGHT,ANGLE or HEIGHT,ANGLE,EFFECTIVE, such as 40000,0.001")),
    }
}

#[derive(Default, serde::Serialize)]
struct Counts {
    #[serde(flatten)]
    check: HashCheck,
    view: String,
    stale_seen: u64,
    reattached: u64,
    /// Texels checked since the last reattach (all of them when never reattached).
    passed_since_reattach: u64,
    /// Following: the service was republished without the view read and the run ended before
    /// the view came back.
    view_missing: bool,
    requests: u64,
    seconds: f64,
    /// With --lonlat: the level-0 texel the centre was asked for and reached.
    #[serde(skip_serializing_if = "Option::is_none")]
    lonlat_centre: Option<[i64; 2]>,
}

fn attach(cli: &Cli) -> Result<Client, ShmError> {
    let mut c = match &cli.path {
        Some(p) => Client::attach_path(p),
        None => Client::attach(&cli.shm_dir.clone().unwrap_or_else(clipmap::shm::default_dir), &cli.name),
    }?;
    c.bind_view(&cli.view)?;
    Ok(c)
}

/// The driver's flight: fast steps, a reversal every 150 requests and a jump every 400.
fn flight(i: u64, size: [u64; 2]) -> ([i64; 2], [f64; 2]) {
    let phase = i % 400;
    let dir = if (i / 150).is_multiple_of(2) { 1 } else { -1 };
    let jump = (i / 400) as i64 * 7919;
    let (w, h) = (size[0] as i64, size[1] as i64);
    let s = (w / 2 + jump * 3 + dir * (phase as i64) * 37).rem_euclid(w);
    let t = (h / 2 - jump * 2 + (phase as i64) * 23).rem_euclid(h);
    ([s, t], [dir as f64 * 37.0 * 240.0, 23.0 * 240.0])
}

fn main() -> ExitCode {
    // The tools' rule: a usage error is bad input (1), as a wrong texel is.
    let cli: Cli = clipmap::cli::parse();
    let start = Instant::now();
    let deadline = start + Duration::from_secs_f64(cli.seconds);
    let mut client = loop {
        match attach(&cli) {
            Ok(c) => break c,
            Err(
                ShmError::NotFound { .. }
                | ShmError::NoView { .. }
                | ShmError::OwnMissing { .. }
                | ShmError::OwnOfAnotherStart { .. },
            ) if cli.follow && Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => {
                eprintln!("clipmap-read: {e}");
                return exit::status(exit::COULD_NOT_RUN);
            }
        }
    };
    let lonlat_centre = match cli.lonlat.map(|ll| centre_at(&client, ll, deadline)) {
        Some(Ok(c)) => Some(c),
        Some(Err((code, e))) => {
            eprintln!("clipmap-read: {e}");
            return exit::status(code);
        }
        None => None,
    };
    if let (Some(level), Some(region), Some(out)) = (cli.dump_level, cli.region, &cli.out) {
        return match dump::write(&client, level, region, out, deadline) {
            Ok(report) => {
                println!("{}", serde_json::to_string(&report).unwrap_or_default());
                exit::status(exit::OK)
            }
            Err((code, e)) => {
                eprintln!("clipmap-read: {e}");
                exit::status(code)
            }
        };
    }
    let mut counts = Counts { view: cli.view.clone(), lonlat_centre, ..Counts::default() };
    let mut rng = clipmap::source::procedural::splitmix64(cli.seed ^ std::process::id() as u64);
    let mut buf = Vec::new();
    let mut stale = false;
    let mut last_request = Instant::now();
    let mut step = 0u64;
    let mut lod_asked = 0u64;
    let mut passed_at_reattach = 0u64;
    // Following: since when the republished mapping has lacked the view, whether that was said,
    // and the last such refusal.
    let mut missing: Option<(Instant, bool, ShmError)> = None;
    while counts.check.passed + counts.check.failed < cli.reads && Instant::now() < deadline {
        step += 1;
        counts.check.step(&client, &mut rng, cli.block.max(1), &mut buf, &clipmap::source::procedural::hash);
        if cli.drive && last_request.elapsed() >= Duration::from_millis(4) {
            let size = client.levels[0].size;
            let (c, v) = flight(counts.requests, size);
            client.request_centre(c, v);
            counts.requests += 1;
            last_request = Instant::now();
        }
        // The LOD request, again every 64 steps (a restarted service hears it too).
        if let Some((h, a, e)) = cli.lod.filter(|_| step.is_multiple_of(64) || lod_asked == 0) {
            if client.request_lod(h, a, e) {
                lod_asked += 1;
            }
        }
        if cli.follow && step.is_multiple_of(64) {
            let now_stale = client.heartbeat_age() > Duration::from_millis(cli.stale_ms) || client.closed();
            if now_stale && !stale {
                counts.stale_seen += 1;
            }
            stale = now_stale;
            if stale {
                if client.replaced() {
                    match attach(&cli) {
                        Ok(c) if c.generation != client.generation => {
                            client = c;
                            counts.reattached += 1;
                            passed_at_reattach = counts.check.passed;
                            stale = false;
                            if let Some((_, true, _)) = missing {
                                eprintln!("clipmap-read: view `{}` is back", cli.view);
                            }
                            missing = None;
                        }
                        Ok(_) => {}
                        Err(e @ ShmError::NoView { .. }) => {
                            // A restarted service's mapping has its `--view`s from the moment it
                            // appears: a view missing was added on the socket and may come back.
                            // Missing longer than the stale time is said once.
                            let since = missing.as_ref().map_or_else(Instant::now, |m| m.0);
                            let mut said = missing.as_ref().is_some_and(|m| m.1);
                            if !said && since.elapsed() > Duration::from_millis(cli.stale_ms) {
                                eprintln!("clipmap-read: the service was restarted without the view read: {e}; waiting for `{}` to be added again", cli.view);
                                said = true;
                            }
                            missing = Some((since, said, e));
                        }
                        // A view being added or removed, or the service restarted again
                        // between the look at its mapping and the view's own one.
                        Err(
                            ShmError::NotFound { .. }
                            | ShmError::OwnMissing { .. }
                            | ShmError::OwnOfAnotherStart { .. },
                        ) => {}
                        Err(e) => {
                            eprintln!("clipmap-read: reattaching: {e}");
                            return exit::status(exit::COULD_NOT_RUN);
                        }
                    }
                }
                std::thread::sleep(Duration::from_millis(2));
            }
        }
    }
    counts.seconds = start.elapsed().as_secs_f64();
    counts.passed_since_reattach = counts.check.passed - passed_at_reattach;
    let lost = missing.filter(|_| stale).map(|m| m.2);
    counts.view_missing = lost.is_some();
    println!("{}", serde_json::to_string(&counts).unwrap_or_default());
    println!("{} passed, {} failed", counts.check.passed, counts.check.failed);
    if let Some(f) = &counts.check.first_failure {
        eprintln!("clipmap-read: first failure: {f}");
    }
    if counts.check.failed != 0 {
        return exit::status(exit::BAD_INPUT);
    }
    if let Some(e) = lost {
        eprintln!("clipmap-read: view `{}` did not come back after the service restarted: {e}", cli.view);
        return exit::status(exit::COULD_NOT_RUN);
    }
    exit::status(exit::OK)
}

/// `--dump-level`: a region of any texture, written as its stored bytes or as a PNG.
mod dump {
    use clipmap::geom::{tex_region, Rect};
    use clipmap::report::dump::{self as pictures, HeightView, LevelTiles};
    use clipmap::report::exit;
    use clipmap::shm::{Client, ReadError};
    use clipmap::source::TileId;
    use std::path::Path;
    use std::time::{Duration, Instant};

    /// What was written.
    #[derive(serde::Serialize)]
    pub struct Written {
        level: usize,
        /// `[s0, t0, s1, t1)`, level texels.
        region: [u64; 4],
        /// The mapping's texel format (`null` for a code the table does not name).
        format: Option<String>,
        bytes_per_texel: usize,
        /// `raw` or `png`.
        kind: &'static str,
        out: String,
        bytes: u64,
        /// The tick of the snapshot the texels were read under.
        tick: u64,
    }

    /// Reads `region` of `level` (waiting until `deadline` while it is still being published)
    /// and writes it to `out`; an error carries its exit status.
    pub fn write(
        client: &Client,
        level: usize,
        region: [u64; 4],
        out: &Path,
        deadline: Instant,
    ) -> Result<Written, (i32, String)> {
        let bad = |e: String| (exit::BAD_INPUT, e);
        let kind = match out.extension().and_then(|e| e.to_str()) {
            Some("raw") => "raw",
            Some("png") => "png",
            _ => return Err(bad(format!("--out {}: expected a name ending in .raw or .png", out.display()))),
        };
        let Some(d) = client.levels.get(level) else {
            return Err(bad(format!("--dump-level {level}: the texture has levels 0 to {}", client.levels.len() - 1)));
        };
        let [s0, t0, s1, t1] = region;
        if s0 >= s1 || t0 >= t1 || s1 > d.size[0] || t1 > d.size[1] {
            return Err(bad(format!(
                "--region {s0},{t0},{s1},{t1} does not fit level {level} ({}x{} texels): expected 0 <= S0 < S1 <= {} and 0 <= T0 < T1 <= {}",
                d.size[0], d.size[1], d.size[0], d.size[1]
            )));
        }
        let (w, h) = (s1 - s0, t1 - t0);
        if w.saturating_mul(h) > pictures::MAX_DUMP_TEXELS {
            return Err(bad(format!(
                "--region {s0},{t0},{s1},{t1} is {w}x{h} texels, more than one dump writes ({} texels, as 4096x4096 does)",
                pictures::MAX_DUMP_TEXELS
            )));
        }
        let bpt = client.bytes_per_texel;
        let mut texels = vec![0u8; (w * h) as usize * bpt];
        let rect = Rect::new(s0 as i64, t0 as i64, s1 as i64, t1 as i64);
        let snap = loop {
            let e = match client.read_region(level, rect.s0, rect.t0, w, h, &mut texels) {
                Ok(snap) => break snap,
                Err(e) => e,
            };
            let snap = client.snapshot();
            let st = snap.levels[level];
            // A region inside the level's window is published once its tiles are read; one
            // outside it never is until the centre moves.
            let window = tex_region(d.size, client.clip_size, st.centre);
            let waiting = match &e {
                ReadError::Stale(_) | ReadError::Busy(_) => true,
                ReadError::NotValid(_) => {
                    let inside =
                        window.s0 <= rect.s0 && rect.s1 <= window.s1 && window.t0 <= rect.t0 && rect.t1 <= window.t1;
                    snap.tick == 0 || inside
                }
                _ => false,
            };
            if !waiting || Instant::now() >= deadline {
                let published = if st.enabled {
                    format!("[{}, {}) x [{}, {})", st.valid[0], st.valid[2], st.valid[1], st.valid[3])
                } else {
                    "nothing (the level is disabled)".to_string()
                };
                let hint = match e {
                    ReadError::NotValid(_) => {
                        "; choose a region inside it, or move the centre there first (CENTRE on the control socket)"
                    }
                    ReadError::Missing { .. } => {
                        "; the service could not read that tile: choose another region or level"
                    }
                    _ => "",
                };
                return Err((
                    exit::COULD_NOT_RUN,
                    format!(
                        "{}: level {level} region [{s0}, {s1}) x [{t0}, {t1}): {e}; the level publishes {published} (window [{}, {}) x [{}, {})){hint}",
                        client.path().display(),
                        window.s0,
                        window.s1,
                        window.t0,
                        window.t1
                    ),
                ));
            }
            std::thread::sleep(Duration::from_millis(10));
        };
        let format = clipmap::shm::layout::format_from_code(client.format_code);
        let fail = |e: String| (exit::COULD_NOT_RUN, format!("cannot write {}: {e}", out.display()));
        if kind == "raw" {
            clipmap::save::atomically(out, |f| std::io::Write::write_all(f, &texels))
                .map_err(|e| fail(e.to_string()))?;
        } else {
            // The region as one tile of a level its size, drawn as `cliptex dump` draws a level.
            let Some(format) = format else {
                return Err(bad(format!(
                    "texel format code {} is not one the PNG pictures know; write --out FILE.raw instead",
                    client.format_code
                )));
            };
            let read = |_: TileId, buf: &mut [u8]| {
                buf.copy_from_slice(&texels);
                Ok(())
            };
            let file_of = |_: TileId| None;
            let tiles = LevelTiles {
                level: Some(level as u32),
                size: [w, h],
                tile: [w, h],
                format,
                read: &read,
                file_of: &file_of,
            };
            let written = match &client.heights {
                Some(hts) => {
                    let view = HeightView { format: hts.format(), range: None, shade: false };
                    pictures::dump_heights(client.path(), &tiles, &view, None, out)
                }
                None => pictures::dump(client.path(), &tiles, None, out),
            };
            written.map_err(|e| fail(e.to_string()))?;
        }
        Ok(Written {
            level,
            region,
            format: format.map(|f| f.short_name()),
            bytes_per_texel: bpt,
            kind,
            out: out.display().to_string(),
            bytes: std::fs::metadata(out).map_or(0, |m| m.len()),
            tick: snap.tick,
        })
    }
}
