//! `clipmapd`: the clip-texture service. Keeps a clip texture's windows filled around the centre
//! renderers ask for, publishes them in shared memory (docs/SHM.md) and answers a control socket.
//! A thin shell over [`clipmap_service`].
//!
//! Exit status: 0 ok, 1 the input is bad, 2 the service could not run.

#![forbid(unsafe_code)]

use anyhow::Context as _;
use clap::{Parser, ValueEnum};
use clipmap::cli::EnvArgs;
use clipmap::report::exit;
use clipmap_service::{self as service, ControlLimits, Options, Procedural, ViewOption};
use clipmap_tools::demo;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

#[derive(Parser)]
#[command(
    args_override_self = true,
    name = "clipmapd",
    version,
    about = "Serve a clip texture in shared memory",
    after_help = "\
Examples:
  clipmapd --demo
  clipmapd --source hash --size 65536 --clip 1024 --name verify
  clipmapd --source terrain --size 1048576 --clip 2048 --budget-ms 4 --tick-hz 60
  clipmapd --growing survey.grow --incoming drops --size 1048576 --clip 1024
  echo STATS | socat - UNIX-CONNECT:/dev/shm/clipmap-verify.sock

Environment: RUST_LOG sets the log filter (default info); logs go to standard error.
Exit status: 0 ok, 1 the input is bad, 2 the service could not run."
)]
struct Cli {
    /// A clip-texture configuration (.ct), or a tiled GeoTIFF / Cloud-Optimized GeoTIFF served
    /// as it is, a local path or an http(s):// or s3:// URL ending in .tif (a ?query is kept):
    /// 8- or 16-bit grey, RGB or RGBA, 16-bit signed or 32-bit float heights; none, LZW,
    /// DEFLATE, ZSTD or JPEG (docs/COG.md); served with --clip. Or a tile service or tree,
    /// `xyz:TEMPLATE` (docs/TILES.md), with --zooms, --bounds, --header and the like.
    config: Option<PathBuf>,
    #[command(flatten)]
    tiles: clipmap::cli::TilesArgs,
    /// Serve a procedural texture instead of a configuration.
    #[arg(long, value_enum, conflicts_with = "config")]
    source: Option<SourceArg>,
    /// With --source: place the procedural texture on the whole Earth (EPSG:4326, longitude -180
    /// to 180, latitude -90 to 90), so that it wraps in longitude as a global COG or a tile
    /// service does (docs/GEOREF.md, "The antimeridian").
    #[arg(long, requires = "source", conflicts_with = "georef")]
    global: bool,
    /// Serve a growing texture (a store made by `cliptex grow create`, docs/GROWING.md) while it
    /// grows: patches arrive on the control socket (`PATCH`) and in --incoming.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["config", "source"])]
    growing: Option<PathBuf>,
    /// With --growing: a directory watched for patches (sidecar .json files beside their
    /// images), moved to done/ or rejected/ once taken.
    #[arg(long, value_name = "DIR", requires = "growing")]
    incoming: Option<PathBuf>,
    /// With --growing: the most bytes of texels one patch may have (k, m, g suffixes; 1 to 4g).
    /// `PATCH DATA` requests in flight hold at most twice this, all connections together.
    #[arg(long, default_value = "256m", value_parser = clipmap::growing::input::parse_max_patch_bytes, requires = "growing")]
    max_patch_bytes: u64,
    /// Procedural texture size, texels a side (a power of two); with --growing, the frame the
    /// texture is served in, centred on its grid's origin.
    #[arg(long, default_value_t = 65536)]
    size: u64,
    /// Clip size of a procedural texture or a tiled GeoTIFF.
    #[arg(long, default_value_t = 1024)]
    clip: u64,
    /// Procedural tile size.
    #[arg(long, default_value_t = 128)]
    tile: u64,
    /// Georeferences a procedural texture (--source) as the whole Web Mercator square
    /// (EPSG:3857, WebMercatorQuad at zoom log2(--size) with 1-texel tiles), so that centres may
    /// be given in longitude / latitude (docs/GEOREF.md).
    #[arg(long, value_name = "web-mercator", requires = "source", value_parser = ["web-mercator"])]
    georef: Option<String>,
    /// Publication name (default: the source kind or the configuration's file stem).
    #[arg(long)]
    name: Option<String>,
    /// Directory of the mapping (default /dev/shm, else the temporary directory).
    #[arg(long)]
    shm_dir: Option<PathBuf>,
    /// Control socket path (default: clipmap-NAME.sock in the mapping's directory).
    #[arg(long)]
    socket: Option<PathBuf>,
    /// Permission bits of the texel mapping (and, unless --request-mode, of the request
    /// mapping), octal (600: owner only; 640: the group reads texels but cannot write anything).
    #[arg(long, default_value = "600", value_parser = parse_mode)]
    shm_mode: u32,
    /// Permission bits of the request mapping, octal (e.g. 660 with --shm-mode 640: the group
    /// reads texels and requests centres, but cannot write texels).
    #[arg(long, value_parser = parse_mode)]
    request_mode: Option<u32>,
    /// Bound on each tick's own work in milliseconds, or `off`.
    #[arg(long, default_value = "6", value_parser = parse_budget)]
    budget_ms: Budget,
    /// Update ticks per second.
    #[arg(long, default_value_t = 60.0)]
    tick_hz: f64,
    /// Invalid border in texels (default: the texture's).
    #[arg(long)]
    border: Option<u64>,
    /// Align each level's centre down to a multiple of this many level texels (1: texel-exact).
    /// Larger values copy column strips wider and less often, at the cost of up to
    /// ALIGNMENT - 1 texels of each level's valid region on the side the view moves towards.
    #[arg(long, default_value_t = 1)]
    centre_alignment: u64,
    /// A further view of the texture, NAME or NAME:WEIGHT (repeatable; docs/VIEWS.md): its own
    /// centre, published regions and min LOD over the shared grids. Readers attach to it by name
    /// (`main` is the primary); `VIEW ADD` on the control socket adds one at run time. `:own`
    /// gives the view grids of its own, in a mapping of its own (NAME@VIEW), for a view that flies
    /// far from the others (docs/VIEWS.md, "Views far apart").
    #[arg(long = "view", value_name = "NAME[:WEIGHT][:own]", value_parser = parse_view)]
    views: Vec<ViewOption>,
    /// Level-0 texels by which views may lie apart and all be held whole: each level's grid
    /// grows by that many texels (halved per level) per axis (0: grids for one view).
    #[arg(long, default_value_t = 0, value_name = "TEXELS")]
    view_spread: u64,
    /// Levels every view addresses at once from its LOD offset (Performer's effective levels;
    /// docs/VIEWS.md, "Virtual views"): a view holds and reads nothing outside them. Default: a
    /// `.ct`'s `effective_levels` where it writes one below its level count, else all levels.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    effective_levels: Option<u32>,
    /// Close control connections idle for this many milliseconds.
    #[arg(long, default_value_t = 30_000)]
    idle_ms: u64,
    /// Most control connections open at once.
    #[arg(long, default_value_t = 64)]
    max_connections: usize,
    /// Run the built-in demonstration and exit.
    #[arg(long, conflicts_with_all = ["config", "source"])]
    demo: bool,
    /// Where the demo writes its pictures.
    #[arg(long, default_value = "clipmapd-demo", requires = "demo")]
    out: PathBuf,
    #[command(flatten)]
    paging: clipmap::cli::PagingArgs,
    #[command(flatten)]
    env: EnvArgs,
    /// Frames the demo's client flies.
    #[arg(long, default_value_t = 240, requires = "demo", hide = true)]
    demo_frames: u32,
    /// Publish the texels block-compressed (docs/SHM.md, "Block-compressed formats"): bc1 (RGB,
    /// an eighth of RGBA8), bc4 (one channel), bc5 (two), bc7 (RGBA, a quarter of RGBA8). Each
    /// tile of any 8-bit source is encoded on the read threads after its decode, straight into
    /// its slot; tile sizes must be multiples of 4. Heights are refused.
    #[arg(long, value_name = "FORMAT", value_parser = clipmap::texel::Bc::parse)]
    format: Option<clipmap::texel::Bc>,
    /// With --format: how hard the encoder tries, fast, normal or slow (BC7's settings; BC1, BC4
    /// and BC5 have one).
    #[arg(long, value_name = "QUALITY", default_value = "normal", value_parser = clipmap::source::BcQuality::parse, requires = "format")]
    bc_quality: clipmap::source::BcQuality,
    /// Tests: every tile read waits this many milliseconds before it reaches the source (a slow
    /// disk or link in front of any source), so that load control can be seen through the service.
    #[arg(long, value_name = "MS", hide = true, value_parser = clap::value_parser!(u64).range(0..=MAX_SOURCE_DELAY_MS))]
    source_delay_ms: Option<u64>,
}

/// The most `--source-delay-ms` takes (a read queue's reads wait at most this long each).
const MAX_SOURCE_DELAY_MS: u64 = 10_000;

#[derive(Clone, Copy, ValueEnum)]
enum SourceArg {
    Hash,
    Terrain,
    /// The height verification texture: l32f metres, nodata -32768 (docs/ELEVATION.md).
    Heights,
}

/// A failure and its exit status.
struct Failure(i32, anyhow::Error);

fn bad(e: impl Into<anyhow::Error>) -> Failure {
    Failure(exit::BAD_INPUT, e.into())
}

fn options(cli: &Cli, default_name: &str) -> Result<Options, Failure> {
    let name = cli.name.clone().unwrap_or_else(|| default_name.to_string());
    let mut o = Options::new(&name);
    if let Some(d) = &cli.shm_dir {
        o.shm_dir = d.clone();
    }
    o.socket = cli.socket.clone().unwrap_or_else(|| service::default_socket(&o.shm_dir, &name));
    o.shm_mode = cli.shm_mode;
    o.request_mode = cli.request_mode;
    o.budget_ms = cli.budget_ms.0;
    o.tick_hz = cli.tick_hz;
    o.invalid_border = cli.border;
    o.centre_alignment = cli.centre_alignment;
    o.views = cli.views.clone();
    o.view_spread = cli.view_spread;
    o.effective_levels = cli.effective_levels;
    o.control = ControlLimits {
        idle: Duration::from_millis(cli.idle_ms),
        max_connections: cli.max_connections,
        ..ControlLimits::default()
    };
    Ok(o)
}

async fn shutdown_signal(mut int: tokio::signal::unix::Signal, mut term: tokio::signal::unix::Signal) {
    tokio::select! {
        _ = int.recv() => tracing::info!("SIGINT"),
        _ = term.recv() => tracing::info!("SIGTERM"),
    }
}

async fn serve(cli: Cli) -> Result<(), Failure> {
    use tokio::signal::unix::{signal, SignalKind};
    let could_not_run = |e: std::io::Error| Failure(exit::COULD_NOT_RUN, e.into());
    // Registered before anything is published, so a signal never finds the default action.
    let int = signal(SignalKind::interrupt()).map_err(could_not_run)?;
    let term = signal(SignalKind::terminate()).map_err(could_not_run)?;
    if cli.demo {
        let o = demo::DemoOptions { out_dir: cli.out.clone(), frames: cli.demo_frames, ..Default::default() };
        let r = demo::demo(o.clone()).await.map_err(|e| Failure(e.exit_code(), e.into()))?;
        let stats_path = o.out_dir.join("stats.json");
        let json = serde_json::to_string_pretty(&r.stats).map_err(|e| Failure(exit::COULD_NOT_RUN, e.into()))?;
        clipmap::save::atomically(&stats_path, |w| std::io::Write::write_all(w, json.as_bytes()))
            .with_context(|| format!("writing {}", stats_path.display()))
            .map_err(|e| Failure(exit::COULD_NOT_RUN, e))?;
        let t = &r.stats.tick;
        let e = &t.engine;
        println!(
            "clipmapd demo: served a {0}x{0} terrain texture (clip {1}) and flew a client over it for {2} frames in {3:.1} s",
            o.size, o.clip, r.frames, r.seconds
        );
        println!("pictures in {}/:", o.out_dir.display());
        for p in &r.pictures {
            println!("  {}", p.file_name().map(|n| n.to_string_lossy()).unwrap_or_default());
        }
        println!("statistics in {}", stats_path.display());
        println!(
            "ticks {}, centre requests {}, MiB published {:.1}, tiles read {}, budget overruns {}, ticks with a level disabled {}",
            e.ticks,
            t.requests_seen,
            t.bytes_published as f64 / (1 << 20) as f64,
            e.tiles_read,
            e.ticks_over_budget,
            e.ticks_with_disabled_level
        );
        println!("level 0 usable at the centre in {} of {} frames", r.frames_sharp, r.frames);
        return Ok(());
    }
    let mut grower = None;
    // The grower's thread, stopped and joined after the service: the step under way ends and the
    // store is closed before the process exits.
    let mut grower_thread = None;
    let mut ct_effective = None;
    let (source, default_name, paging) = match (&cli.config, cli.source) {
        (None, None) if cli.growing.is_some() => {
            let dir = cli.growing.clone().unwrap_or_default();
            if let Some(d) = &cli.incoming {
                if !d.is_dir() {
                    return Err(bad(anyhow::anyhow!("--incoming {}: not a directory", d.display())));
                }
                if dir.is_dir() {
                    clipmap::growing::watch::check_apart(&dir, d)
                        .map_err(|e| bad(anyhow::anyhow!("--incoming {}: {e}", d.display())))?;
                }
            }
            let store = clipmap::growing::store::Growing::open(&dir).map_err(|e| {
                let code = match e {
                    clipmap::growing::store::StoreError::Busy { .. }
                    | clipmap::growing::store::StoreError::Io { .. } => exit::COULD_NOT_RUN,
                    _ => exit::BAD_INPUT,
                };
                Failure(code, anyhow::anyhow!("{e}"))
            })?;
            let frame = clipmap::growing::serve::Frame::new(cli.size, store.grid().tile)
                .map_err(|e| bad(anyhow::anyhow!("--size {}: {e}", cli.size)))?;
            let opts = clipmap::growing::serve::GrowerOptions {
                incoming: cli.incoming.clone(),
                max_patch_bytes: cli.max_patch_bytes,
                ..Default::default()
            };
            let (src, g, join) = clipmap::growing::serve::start(store, frame, cli.clip, opts)
                .map_err(|e| bad(anyhow::anyhow!("{}: {e}", dir.display())))?;
            grower_thread = Some((g.clone(), join));
            grower = Some(g);
            let stem = dir.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "growing".into());
            (src as Arc<dyn clipmap::source::TileSource>, stem, clipmap::paging::PagingOptions::default())
        }
        // A tile service or archive (`xyz:TEMPLATE`, docs/TILES.md), served as it is.
        (Some(path), _) if clipmap::source::tiles::is_pyramid(&path.to_string_lossy()) => {
            let opts = cli.tiles.options(Some(cli.clip)).map_err(|e| bad(anyhow::anyhow!(e)))?;
            let src = match clipmap::source::tiles::open(&path.to_string_lossy(), &opts) {
                Some(Ok(src)) => src,
                Some(Err(e)) => return Err(bad(anyhow::anyhow!("{e}"))),
                None => return Err(bad(anyhow::anyhow!("{}: not a tile pyramid", path.display()))),
            };
            (
                Arc::new(src) as Arc<dyn clipmap::source::TileSource>,
                "tiles".to_string(),
                clipmap::paging::PagingOptions::default(),
            )
        }
        // A tiled GeoTIFF / COG: a local file that starts like one, or an http(s):// or s3://
        // name ending in .tif / .tiff (read in ranges, docs/COG.md).
        (Some(path), _) if clipmap::source::cog::is_tiff_place(&clipmap::place::Place::from_path(path.clone())) => {
            let place = clipmap::place::Place::from_path(path.clone());
            // A remote object replaced in its store is opened again and every tile read anew.
            let src =
                clipmap::source::CogSource::open_served(&place, cli.clip).map_err(|e| bad(anyhow::anyhow!("{e}")))?;
            let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "clip".into());
            (src, stem, clipmap::paging::PagingOptions::default())
        }
        (Some(path), _) => {
            let o = cli.env.options().map_err(|e| Failure(exit::COULD_NOT_RUN, anyhow::anyhow!(e)))?;
            // Displayed once: the error's text already holds its source.
            let loaded = clipmap::source::configured::load_clip_texture(path, &o)
                .map_err(|e| Failure(exit::COULD_NOT_RUN, anyhow::anyhow!("{e}")))?;
            eprint!("{}", loaded.render_from(clipmap::config::Severity::Warning));
            let Some(plan) = loaded.plan else {
                return Err(bad(anyhow::anyhow!("{} is not a valid clip texture configuration", path.display())));
            };
            // The configuration's `#clipmap` lines, under the command line's flags.
            let paging = plan.paging;
            // A virtual clip texture's effective levels, where the `.ct` writes them.
            if plan.is_virtual && !plan.defaulted.contains(&"effective_levels") {
                ct_effective = Some(plan.effective_levels);
            }
            let src = clipmap::source::open_plan(plan, &clipmap::limits::Limits::default())
                .map_err(|e| bad(anyhow::anyhow!("{e}")))?;
            let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "clip".into());
            (src, stem, paging)
        }
        (None, Some(kind)) => {
            let (kind, name) = match kind {
                SourceArg::Hash => (Procedural::Hash, "hash"),
                SourceArg::Terrain => (Procedural::Terrain, "terrain"),
                SourceArg::Heights => (Procedural::Heights, "heights"),
            };
            let src = service::procedural_source(kind, cli.size, cli.clip, cli.tile)
                .map_err(|e| Failure(e.exit_code(), e.into()))?;
            let src = if cli.global { Arc::new(clipmap::source::GlobalSource::new(src)) as _ } else { src };
            let src = match cli.georef {
                Some(_) => service::web_mercator_square(src),
                None => src,
            };
            (src, name.to_string(), clipmap::paging::PagingOptions::default())
        }
        (None, None) => {
            return Err(bad(anyhow::anyhow!(
                "give a configuration (CONFIG.ct), --source hash|terrain|heights, --growing DIR, or --demo"
            )))
        }
    };
    let source = match cli.source_delay_ms {
        Some(ms) if ms > 0 => {
            use clipmap::source::{Fault, FaultRule, FaultySource};
            let slow = FaultySource::new(source);
            slow.add(FaultRule::everywhere(Fault::Slow(Duration::from_millis(ms))));
            tracing::info!(delay_ms = ms, "every tile read is delayed (--source-delay-ms)");
            Arc::new(slow) as Arc<dyn clipmap::source::TileSource>
        }
        _ => source,
    };
    let source = match cli.format {
        Some(bc) => {
            let encoded = clipmap::source::BcSource::new(source, bc, cli.bc_quality)
                .map_err(|e| bad(anyhow::anyhow!("--format {}: {e}", bc.name())))?;
            tracing::info!(format = bc.name(), quality = ?cli.bc_quality, "tiles are block-compressed at ingest");
            Arc::new(encoded) as Arc<dyn clipmap::source::TileSource>
        }
        None => source,
    };
    let mut options = options(&cli, &default_name)?;
    options.paging = cli.paging.over(paging);
    options.effective_levels = cli.effective_levels.or(ct_effective);
    options.growing = grower;
    let summary = service::run(source, options, shutdown_signal(int, term), |s| {
        println!("clipmapd: serving {} ({} levels, clip {})", s.mapping.display(), s.levels, s.clip_size);
    })
    .await;
    if let Some((g, join)) = grower_thread {
        stop_grower(g, join).await;
    }
    let summary = summary.map_err(|e| Failure(e.exit_code(), e.into()))?;
    let e = &summary.stats.tick.engine;
    println!("clipmapd: stopped after {} ticks", e.ticks);
    if e.centre_clamps > 0 {
        println!("clipmapd: the centre's step was clamped on {} ticks (--max-centre-step)", e.centre_clamps);
    }
    if e.pool.budget_bytes > 0 {
        println!(
            "clipmapd: tile pool: {} hits, hit rate {:.3}, {} evicted, peak {} bytes",
            e.pool.hits,
            e.pool.hit_rate(),
            e.pool.evicted,
            e.pool.peak_bytes
        );
    }
    Ok(())
}

/// Tells the grower to stop after the step under way and waits for its thread (off the runtime's
/// workers: the step may be a long rebuild).
async fn stop_grower(g: clipmap::growing::serve::Grower, join: std::thread::JoinHandle<()>) {
    // A full command channel still stops it: the grower ends when every handle is gone.
    g.send(clipmap::growing::serve::GrowCommand::Stop);
    drop(g);
    match tokio::task::spawn_blocking(move || join.join()).await {
        Ok(Ok(())) => {}
        _ => eprintln!("clipmapd: the grower's thread ended with a panic; the store keeps its last durable state"),
    }
}

/// `--budget-ms`: milliseconds (checked against the service's bounds when it starts), or `off`.
#[derive(Clone, Copy, Debug)]
struct Budget(Option<f64>);

fn parse_budget(text: &str) -> Result<Budget, String> {
    if text.trim().eq_ignore_ascii_case("off") {
        return Ok(Budget(None));
    }
    text.trim()
        .parse::<f64>()
        .map(|ms| Budget(Some(ms)))
        .map_err(|_| format!("`{text}` is not a budget: expected milliseconds or `off`"))
}

/// `--shm-mode`: octal permission bits (checked against what the service allows when it starts).
fn parse_mode(text: &str) -> Result<u32, String> {
    u32::from_str_radix(text.trim(), 8)
        .map_err(|_| format!("`{text}` is not a mode: expected octal permission bits like 600"))
}

fn main() -> ExitCode {
    let cli: Cli = clipmap::cli::parse();
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    // Colour codes only for a person at a terminal, never into a log file or a pipe.
    use std::io::IsTerminal;
    let ansi = std::io::stderr().is_terminal();
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_ansi(ansi).init();
    // The process's one runtime: the service, its read queues and remote reads share it.
    match clipmap::runtime::block_on(serve(cli)) {
        Err(e) => {
            eprintln!("clipmapd: {e}");
            exit::status(exit::COULD_NOT_RUN)
        }
        Ok(Ok(())) => exit::status(exit::OK),
        Ok(Err(Failure(code, e))) => {
            eprintln!("clipmapd: {e:#}");
            exit::status(code)
        }
    }
}

/// `--view NAME[:WEIGHT][:own]`.
fn parse_view(s: &str) -> Result<ViewOption, String> {
    let (rest, own) = match s.strip_suffix(":own") {
        Some(r) => (r, true),
        None => (s, false),
    };
    let (name, weight) = match rest.split_once(':') {
        Some((n, w)) => {
            let w: f64 = w.parse().map_err(|_| {
                format!("weight `{w}`: expected a positive number such as 1 or 3 (NAME[:WEIGHT][:own])")
            })?;
            (n, w)
        }
        None => (rest, 1.0),
    };
    clipmap::shm::layout::views::check_name(name)?;
    if !(w_ok(weight)) {
        return Err(format!("weight {weight}: expected a positive finite number such as 1 or 3"));
    }
    Ok(ViewOption { name: name.to_string(), weight, own })
}

fn w_ok(w: f64) -> bool {
    w.is_finite() && w > 0.0
}
