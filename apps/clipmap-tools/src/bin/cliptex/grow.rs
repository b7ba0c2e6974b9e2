//! `cliptex grow`: a growing texture kept in a directory (docs/GROWING.md). Create one on a fixed
//! tile grid, add georeferenced patches (images with a JSON sidecar each, or a directory of them),
//! rebuild, look at its state, and picture a level.
//!
//! Exit status: 0 ok, 1 a bad input (a refused patch, a bad option, not a growing texture),
//! 2 the tool could not run (an unreadable or unwritable directory).

use clap::Subcommand;
use clipmap::growing::input;
use clipmap::growing::store::{Growing, StoreError};
use clipmap::report::exit;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// The subcommands of `cliptex grow`.
#[derive(Subcommand, Debug)]
pub enum GrowCommand {
    /// Start a growing texture in an empty (or new) directory, on a fixed grid: tile (0, 0) of
    /// level 0 has its lower corner at the origin, whatever is added later.
    #[command(after_help = "\
Examples:
  cliptex grow create survey --origin 0,0 --texels-per-unit 1 --tile 256 --format rgb8
  cliptex grow create scan --origin -5000,-5000 --texels-per-unit 20 --tile 512 --format l16")]
    Create {
        /// The directory (created; must be empty if it exists).
        dir: PathBuf,
        /// World coordinates of the lower corner of level-0 texel (0, 0): X,Y.
        #[arg(long, value_parser = parse_pair, allow_hyphen_values = true, default_value = "0,0")]
        origin: [f64; 2],
        /// Level-0 texels per world unit (both axes).
        #[arg(long, default_value_t = 1.0)]
        texels_per_unit: f64,
        /// Tile edge in texels (a power of two up to 4096).
        #[arg(long, default_value_t = 256)]
        tile: u64,
        /// Texel format: l8, rgb8, rgba8, l16, la16, rgb16, rgba16.
        #[arg(long, default_value = "rgb8")]
        format: String,
        /// Blend patch edges over this many level-0 texels (each patch fades into what lies
        /// beneath it towards its box's edge; 0: the best patch wins each texel outright).
        #[arg(long, default_value_t = 0.0)]
        feather: f64,
        /// The CRS the world coordinates (origin, the patches' boxes) are map coordinates of,
        /// EPSG:CODE (e.g. EPSG:32633): the texture is then georeferenced by its grid
        /// (docs/GEOREF.md); without it the units are your own and the texture has none.
        #[arg(long, value_name = "EPSG:CODE", value_parser = parse_epsg)]
        crs: Option<u32>,
    },
    /// Add patches: each a JSON sidecar naming its image (PNG, JPEG, TIFF) or raw texels, or a
    /// directory whose *.json sidecars are all taken. Each patch is on disk before it is
    /// counted as added; the tiles it changes are rebuilt before the command returns (unless
    /// --no-rebuild).
    #[command(after_help = "\
A sidecar:
  {\"bbox\": [x0, y0, x1, y1], \"time\": 1733011200, \"rating\": 2.5, \"image\": \"strip-0042.png\"}
(\"raw\": {\"width\": W, \"height\": H} instead of \"image\" for texels in the texture's format, in
a file named like the sidecar with .raw for .json). Unknown fields are refused.

Examples:
  cliptex grow add survey flight1/*.json
  cliptex grow add survey incoming/ --json
  cliptex grow add survey big.json --no-rebuild && cliptex grow rebuild survey

A refused patch is reported with its file and why, and nothing of it is kept; the others are
still added (exit status 1 if any was refused).")]
    Add {
        /// The growing texture's directory.
        dir: PathBuf,
        /// Sidecars (*.json) or directories of them.
        #[arg(required = true)]
        patches: Vec<PathBuf>,
        /// Only keep and index the patches; rebuild later (`cliptex grow rebuild`).
        #[arg(long)]
        no_rebuild: bool,
        /// Largest patch, in bytes of texels (k, m, g suffixes; 1 to 4g).
        #[arg(long, default_value = "1g", value_parser = clipmap::growing::input::parse_max_patch_bytes)]
        max_patch_bytes: u64,
        /// Tiles rebuilt per step.
        #[arg(long, default_value_t = 256)]
        per_step: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Watch a directory for patches: every *.json sidecar that appears is taken, then moved to
    /// INCOMING/done/ (or INCOMING/rejected/ with NAME.error.txt saying why), and the tiles are
    /// rebuilt a bounded number per round, until SIGINT or SIGTERM (or, with --once, until
    /// nothing waits).
    #[command(after_help = "\
Examples:
  cliptex grow watch survey incoming &
  cp strip-0042.png incoming/ && cp strip-0042.json incoming/.strip-0042.json && mv incoming/.strip-0042.json incoming/strip-0042.json
  cliptex grow watch survey incoming --once     # take what is there, rebuild, exit

Put the image first and the sidecar last (renamed into place): a sidecar is taken as soon as it
appears. The same sidecar, byte for byte, is taken once, even across a crash.")]
    Watch {
        /// The growing texture's directory.
        dir: PathBuf,
        /// The directory to watch (created if needed).
        incoming: PathBuf,
        /// Seconds between looks when idle.
        #[arg(long, default_value_t = 0.2)]
        interval: f64,
        /// Tiles rebuilt per round.
        #[arg(long, default_value_t = 256)]
        per_step: usize,
        /// Sidecars taken per round.
        #[arg(long, default_value_t = 16)]
        per_round: usize,
        /// Largest patch, in bytes of texels (k, m, g suffixes; 1 to 4g).
        #[arg(long, default_value = "1g", value_parser = clipmap::growing::input::parse_max_patch_bytes)]
        max_patch_bytes: u64,
        /// Take what waits, rebuild everything, and exit.
        #[arg(long)]
        once: bool,
    },
    /// Rebuild whatever waits (after --no-rebuild, or after a crash).
    Rebuild {
        dir: PathBuf,
        /// Tiles rebuilt per step.
        #[arg(long, default_value_t = 256)]
        per_step: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Write a set of overlapping aerial-style PNG patches with their sidecars (a strip survey
    /// over a procedural terrain, and one re-shot with a better rating) to try the rest on.
    #[command(after_help = "\
Examples:
  cliptex grow example patches
  cliptex grow example patches --count 10 --size 640x480")]
    Example {
        /// Directory for patch-NN.png and patch-NN.json (created).
        out: PathBuf,
        /// How many patches in the strip (a re-shot patch comes on top).
        #[arg(long, default_value_t = 6)]
        count: u32,
        /// Pixels of each patch, WxH (one world unit a pixel).
        #[arg(long, default_value = "512x384", value_parser = parse_size)]
        size: [u32; 2],
    },
    /// The grid, patches, levels, extent, tiles and what waits.
    Status {
        dir: PathBuf,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// A level over the texture's extent as a PNG (RGBA; texels without data transparent).
    #[command(after_help = "\
Examples:
  cliptex grow dump survey --level 0 --out level0.png
  cliptex grow dump survey --level 3 --out top.png")]
    Dump {
        dir: PathBuf,
        #[arg(long, default_value_t = 0)]
        level: u32,
        #[arg(long)]
        out: PathBuf,
        /// Refuse pictures larger than this many pixels a side.
        #[arg(long, default_value_t = 16384)]
        max_side: u64,
    },
}

/// What `status` (and `add`, `rebuild` with --json) print.
#[derive(Debug, Serialize)]
pub struct Status {
    pub dir: String,
    pub format: String,
    pub tile: u64,
    pub origin: [f64; 2],
    pub texels_per_unit: f64,
    /// Level-0 texels over which patch edges are blended (0: off).
    pub feather: f64,
    /// The EPSG code of the CRS the world coordinates are in (null: the user's own units, no
    /// georeferencing).
    pub epsg: Option<u32>,
    pub patches: usize,
    pub levels: u32,
    /// The union of the patches' boxes, world units (null while empty).
    pub extent: Option<[f64; 4]>,
    /// Level-0 tiles under the extent: s0, t0, s1, t1 (half-open).
    pub extent_tiles: Option<[i64; 4]>,
    /// Tiles with data, every level.
    pub tiles: usize,
    /// Tiles per level, finest first.
    pub tiles_per_level: Vec<usize>,
    pub pending: usize,
    /// Every patch up to this id is in the tiles on disk.
    pub applied: u64,
    /// Patches whose rebuild had to be redone when the directory was opened (after a crash).
    pub replayed: usize,
}

/// What `add` prints with --json.
#[derive(Debug, Serialize)]
struct AddReport {
    added: Vec<Added>,
    refused: Vec<Refused>,
    tiles_rebuilt: usize,
    status: Status,
}

#[derive(Debug, Serialize)]
struct Added {
    file: String,
    id: u64,
}

#[derive(Debug, Serialize)]
struct Refused {
    file: String,
    error: String,
}

fn parse_size(text: &str) -> Result<[u32; 2], String> {
    let bad = || format!("`{text}` is not WxH (e.g. 512x384), each side 8 to 8192");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.trim().parse().map_err(|_| bad())?, h.trim().parse().map_err(|_| bad())?);
    if (8..=8192).contains(&w) && (8..=8192).contains(&h) {
        Ok([w, h])
    } else {
        Err(bad())
    }
}

fn parse_pair(text: &str) -> Result<[f64; 2], String> {
    let bad = || format!("`{text}` is not X,Y (two finite numbers, e.g. -120.5,40)");
    let (a, b) = text.split_once(',').ok_or_else(bad)?;
    let (a, b): (f64, f64) = (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
    if a.is_finite() && b.is_finite() {
        Ok([a, b])
    } else {
        Err(bad())
    }
}

/// The status of an open texture.
pub fn status(g: &Growing) -> Status {
    let grid = g.grid();
    let extent = g.index().extent();
    let mut per_level = vec![0usize; g.levels() as usize];
    for &(k, _, _) in g.rebuild().keys() {
        if let Some(n) = per_level.get_mut(k as usize) {
            *n += 1;
        }
    }
    Status {
        dir: g.dir().display().to_string(),
        format: g.format().short_name(),
        tile: grid.tile,
        origin: grid.origin,
        texels_per_unit: grid.texels_per_unit,
        feather: g.feather(),
        epsg: g.epsg(),
        patches: g.index().len(),
        levels: g.levels(),
        extent: extent.map(|e| [e.min[0], e.min[1], e.max[0], e.max[1]]),
        extent_tiles: extent.and_then(|e| grid.tiles_over(grid.texels_in(&e), 0)),
        tiles: g.rebuild().len(),
        tiles_per_level: per_level,
        pending: g.pending(),
        applied: g.applied(),
        replayed: g.replayed(),
    }
}

fn human(s: &Status) -> String {
    let ext =
        s.extent.map_or("none yet".to_string(), |e| format!("[{}, {}) x [{}, {}) world units", e[0], e[2], e[1], e[3]));
    format!(
        "{}: {} texels, {}² tiles, origin ({}, {}), {} texels a unit{}\n  georef {}\n  patches {}  levels {}  extent {}\n  tiles {} (per level {:?})  waiting {}  applied up to patch {}{}\n",
        s.dir,
        s.format,
        s.tile,
        s.origin[0],
        s.origin[1],
        s.texels_per_unit,
        if s.feather > 0.0 { format!(", edges feathered over {} texels", s.feather) } else { String::new() },
        match s.epsg {
            Some(code) => format!("EPSG:{code}: world units are its map coordinates, the grid places every texel"),
            None => "none (the world units are the grid's own: create with --crs EPSG:CODE to georeference)".into(),
        },
        s.patches,
        s.levels,
        ext,
        s.tiles,
        s.tiles_per_level,
        s.pending,
        s.applied,
        if s.replayed > 0 { format!("  (replayed {} after a crash)", s.replayed) } else { String::new() }
    )
}

/// The exit status of a store error: the input's fault (1) or the machine's (2).
fn store_exit(e: &StoreError) -> i32 {
    match e {
        StoreError::Io { .. } => exit::COULD_NOT_RUN,
        _ => exit::BAD_INPUT,
    }
}

fn open(dir: &Path) -> Result<Growing, i32> {
    Growing::open(dir).map_err(|e| {
        eprintln!("cliptex grow: {e}");
        store_exit(&e)
    })
}

fn open_to_look(dir: &Path) -> Result<Growing, i32> {
    Growing::open_read_only(dir).map_err(|e| {
        eprintln!("cliptex grow: {e}");
        store_exit(&e)
    })
}

/// Runs one `cliptex grow` subcommand; returns the exit status.
pub fn run(cmd: GrowCommand) -> i32 {
    match cmd {
        GrowCommand::Create { dir, origin, texels_per_unit, tile, format, feather, crs } => {
            match Growing::create_georeferenced(&dir, origin, texels_per_unit, tile, &format, feather, crs) {
                Ok(g) => {
                    print!("{}", human(&status(&g)));
                    exit::OK
                }
                Err(e) => {
                    eprintln!("cliptex grow create: {e}");
                    store_exit(&e)
                }
            }
        }
        GrowCommand::Add { dir, patches, no_rebuild, max_patch_bytes, per_step, json } => {
            let mut g = match open(&dir) {
                Ok(g) => g,
                Err(c) => return c,
            };
            let files = match sidecars(&patches) {
                Ok(f) => f,
                Err(e) => {
                    eprintln!("cliptex grow add: {e}");
                    return exit::BAD_INPUT;
                }
            };
            let (mut added, mut refused) = (Vec::new(), Vec::new());
            for file in files {
                let shown = file.display().to_string();
                match input::read_sidecar(g.grid(), &file, max_patch_bytes, input::Paths::Inside)
                    .map_err(|e| e.to_string())
                    .and_then(|p| {
                        g.add(p).map_err(|e| match e {
                            StoreError::Io { .. } => format!("could not keep it: {e}"),
                            e => format!("{shown}: {e}"),
                        })
                    }) {
                    Ok(id) => {
                        if !json {
                            println!("{shown}: added as patch {id}");
                        }
                        added.push(Added { file: shown, id });
                    }
                    Err(error) => {
                        eprintln!("cliptex grow add: {error}");
                        refused.push(Refused { file: shown, error });
                    }
                }
            }
            let mut rebuilt = 0;
            if !no_rebuild {
                match g.finish(per_step) {
                    Ok(n) => rebuilt = n,
                    Err(e) => {
                        eprintln!("cliptex grow add: the patches are kept, the rebuild stopped: {e}");
                        return exit::COULD_NOT_RUN;
                    }
                }
            }
            let s = status(&g);
            if json {
                let r = AddReport { added, tiles_rebuilt: rebuilt, status: s, refused };
                println!("{}", serde_json::to_string_pretty(&r).expect("reports serialise"));
                return if r.refused.is_empty() { exit::OK } else { exit::BAD_INPUT };
            }
            print!("{}", human(&s));
            if refused.is_empty() {
                exit::OK
            } else {
                exit::BAD_INPUT
            }
        }
        GrowCommand::Watch { dir, incoming, interval, per_step, per_round, max_patch_bytes, once } => {
            let mut g = match open(&dir) {
                Ok(g) => g,
                Err(c) => return c,
            };
            if let Err(e) = std::fs::create_dir_all(&incoming) {
                eprintln!("cliptex grow watch: {}: could not create: {e}", incoming.display());
                return exit::COULD_NOT_RUN;
            }
            if let Err(e) = clipmap::growing::watch::check_apart(&dir, &incoming) {
                eprintln!("cliptex grow watch: {e}");
                return exit::BAD_INPUT;
            }
            watch(&mut g, &incoming, interval, per_step, per_round.max(1), max_patch_bytes, once)
        }
        GrowCommand::Rebuild { dir, per_step, json } => {
            let mut g = match open(&dir) {
                Ok(g) => g,
                Err(c) => return c,
            };
            for (path, problem) in g.damaged() {
                eprintln!("cliptex grow rebuild: {}: damaged ({problem}); rebuilding it", path.display());
            }
            if let Err(e) = g.finish(per_step) {
                eprintln!("cliptex grow rebuild: {e}");
                return store_exit(&e);
            }
            clipmap::report::emit(json, &status(&g), human);
            exit::OK
        }
        GrowCommand::Example { out, count, size } => match example(&out, count, size) {
            Ok(n) => {
                println!(
                    "{}: {n} patches (patch-00.json ...); add them with `cliptex grow add DIR {}`",
                    out.display(),
                    out.display()
                );
                exit::OK
            }
            Err(e) => {
                eprintln!("cliptex grow example: {e}");
                exit::COULD_NOT_RUN
            }
        },
        GrowCommand::Status { dir, json } => match open_to_look(&dir) {
            Ok(g) => {
                clipmap::report::emit(json, &status(&g), human);
                exit::OK
            }
            Err(c) => c,
        },
        GrowCommand::Dump { dir, level, out, max_side } => match open_to_look(&dir) {
            Ok(g) => dump(&g, level, &out, max_side),
            Err(c) => c,
        },
    }
}

/// The sidecars named, directories expanded to their *.json files (sorted).
fn sidecars(paths: &[PathBuf]) -> Result<Vec<PathBuf>, String> {
    let mut out = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(|e| format!("{}: could not list: {e}", p.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| f.extension().is_some_and(|x| x == "json"))
                .collect();
            found.sort();
            if found.is_empty() {
                return Err(format!("{}: no *.json sidecars in this directory", p.display()));
            }
            out.extend(found);
        } else {
            out.push(p.clone());
        }
    }
    Ok(out)
}

fn dump(g: &Growing, level: u32, out: &Path, max_side: u64) -> i32 {
    let grid = g.grid();
    if level >= g.levels().max(1) {
        eprintln!(
            "cliptex grow dump: level {level} does not exist; the texture has {} (0 to {})",
            g.levels(),
            g.levels().saturating_sub(1)
        );
        return exit::BAD_INPUT;
    }
    let Some(e) = g.index().extent() else {
        eprintln!("cliptex grow dump: {}: no patches yet, nothing to picture", g.dir().display());
        return exit::BAD_INPUT;
    };
    let [s0, t0, s1, t1] = grid.tiles_over(grid.texels_in(&e), level).expect("a texture with patches covers a texel");
    let n = grid.tile as i64;
    let (w, h) = ((s1 - s0) * n, (t1 - t0) * n);
    if w as u64 > max_side || h as u64 > max_side {
        eprintln!("cliptex grow dump: level {level} is {w}x{h} texels over the extent; the most is {max_side} a side (--max-side), or picture a coarser level");
        return exit::BAD_INPUT;
    }
    let bpt = grid.bytes_per_texel;
    let format = Some(g.format());
    // Row 0 of the picture is the top (largest t).
    let img = image::RgbaImage::from_fn(w as u32, h as u32, |x, y| {
        let (i, j) = (s0 * n + x as i64, t0 * n + (h - 1 - y as i64));
        let Some(tile) = g.tile(level, i.div_euclid(n), j.div_euclid(n)) else { return image::Rgba([0, 0, 0, 0]) };
        let at = (j.rem_euclid(n) * n + i.rem_euclid(n)) as usize;
        if !tile.has(at) {
            return image::Rgba([0, 0, 0, 0]);
        }
        image::Rgba(clipmap::report::picture::texel_rgba(format, &tile.texels[at * bpt..(at + 1) * bpt]))
    });
    match clipmap::save::atomically(out, |f| img.write_to(f, image::ImageFormat::Png).map_err(clipmap::save::image_io))
    {
        Ok(()) => {
            println!(
                "{}: level {level}, {w}x{h} texels from tile ({s0}, {t0}) (picture row 0 is the top)",
                out.display()
            );
            exit::OK
        }
        Err(e) => {
            eprintln!("cliptex grow dump: {}: could not write: {e}", out.display());
            exit::COULD_NOT_RUN
        }
    }
}

/// The example survey: `count` patches along a strip that crosses the origin, alternately
/// shifted up and down, each overlapping the last by about a third; then one re-shot over the
/// middle of the strip, later and with a better rating, in warmer colours so that it shows where
/// it won. Pixels are a procedural terrain, one world unit a pixel. Returns the patches written.
fn example(out: &Path, count: u32, [w, h]: [u32; 2]) -> Result<u32, String> {
    use clipmap::source::procedural::Terrain;
    use clipmap::texel::TexelFormat;
    std::fs::create_dir_all(out).map_err(|e| format!("{}: could not create: {e}", out.display()))?;
    let terrain = Terrain::new(14, clipmap::source::TERRAIN_SEED);
    let step = (w as i64 * 2) / 3;
    let x_start = -(step * count as i64) / 2;
    let mut boxes: Vec<([i64; 2], u64, f64, bool)> = (0..count as i64)
        .map(|i| {
            ([x_start + i * step, -(h as i64) / 2 + if i % 2 == 0 { 0 } else { h as i64 / 4 }], i as u64, 1.0, false)
        })
        .collect();
    boxes.push(([-(w as i64) / 2, -(h as i64) / 3], count as u64, 2.0, true));
    for (n, &([x0, y0], time, rating, warm)) in boxes.iter().enumerate() {
        let img = image::RgbImage::from_fn(w, h, |x, y| {
            // Row 0 is the top of the box (its largest y).
            let (s, t) = ((x0 + x as i64 + 8192) as u64, (y0 + (h - 1 - y) as i64 + 8192) as u64);
            let mut px = [0u8; 3];
            terrain.texel(0, s, t, TexelFormat::RGB8, &mut px);
            if warm {
                px = [px[0].saturating_add(60), px[1], px[2] / 2];
            }
            image::Rgb(px)
        });
        let name = format!("patch-{n:02}");
        let png = out.join(format!("{name}.png"));
        clipmap::save::atomically(&png, |f| img.write_to(f, image::ImageFormat::Png).map_err(clipmap::save::image_io))
            .map_err(|e| format!("{}: could not write: {e}", png.display()))?;
        let side = serde_json::json!({
            "bbox": [x0, y0, x0 + w as i64, y0 + h as i64],
            "time": time,
            "rating": rating,
            "image": format!("{name}.png"),
        });
        let json = out.join(format!("{name}.json"));
        let text = serde_json::to_string_pretty(&side).expect("a sidecar serialises") + "\n";
        clipmap::save::atomically(&json, |f| std::io::Write::write_all(f, text.as_bytes()))
            .map_err(|e| format!("{}: could not write: {e}", json.display()))?;
    }
    Ok(boxes.len() as u32)
}

/// The watch loop: rounds of intake and bounded rebuilds, a pause when idle, until a signal (or,
/// with `once`, until nothing waits).
fn watch(
    g: &mut Growing,
    incoming: &Path,
    interval: f64,
    per_step: usize,
    per_round: usize,
    max_bytes: u64,
    once: bool,
) -> i32 {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    // The process's one runtime: the signal watcher runs on its workers, the rounds on this thread.
    let rt = match clipmap::runtime::shared() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("cliptex grow watch: could not start: {e}");
            return exit::COULD_NOT_RUN;
        }
    };
    let stop = Arc::new(AtomicBool::new(false));
    let idle = std::time::Duration::from_secs_f64(interval.clamp(0.01, 60.0));
    println!("watching {} for patches into {} (SIGINT or SIGTERM stops)", incoming.display(), g.dir().display());
    rt.block_on(async {
        let flag = Arc::clone(&stop);
        tokio::spawn(async move {
            let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                Ok(t) => t,
                Err(_) => return,
            };
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
            flag.store(true, Ordering::SeqCst);
        });
        loop {
            tokio::task::yield_now().await;
            if stop.load(Ordering::SeqCst) {
                break;
            }
            let r = match clipmap::growing::watch::round(g, incoming, max_bytes, per_round) {
                Ok(r) => r,
                Err(e) => {
                    eprintln!("cliptex grow watch: {e}");
                    return exit::COULD_NOT_RUN;
                }
            };
            for (name, id) in &r.added {
                println!("{name}: added as patch {id}");
            }
            for name in &r.already {
                println!("{name}: already added (moved to done/)");
            }
            for (_, why) in &r.refused {
                eprintln!("cliptex grow watch: refused: {why}");
            }
            let busy = g.pending() > 0 || g.applied() < g.index().len() as u64;
            if busy {
                if let Err(e) = g.step(per_step.max(1)) {
                    eprintln!("cliptex grow watch: {e}");
                    return exit::COULD_NOT_RUN;
                }
            } else if r.added.is_empty() && r.refused.is_empty() && r.already.is_empty() {
                if once {
                    break;
                }
                tokio::time::sleep(idle).await;
            }
        }
        print!("{}", human(&status(g)));
        exit::OK
    })
}

/// `EPSG:CODE` (or the code alone).
fn parse_epsg(s: &str) -> Result<u32, String> {
    let code = s.strip_prefix("EPSG:").or_else(|| s.strip_prefix("epsg:")).unwrap_or(s);
    code.parse().map_err(|_| format!("`{s}`: expected EPSG:CODE, e.g. EPSG:32633"))
}
