//! `clipgpu`: the GPU client (docs/GPU.md). `clipgpu --demo --json` runs on its own; `clipgpu
//! --name NAME` flies against a running `clipmapd`.

#![forbid(unsafe_code)]

use clap::Parser;
use clipgpu::flight::{fly, FlightOptions};
use clipgpu::gpu::Gpu;
use clipgpu::summary::{self, Tolerance};
use clipgpu::upload::Method;
use clipgpu::{exit_code, BadInput};
use clipmap::accuracy::study::Case;
use clipmap::height::{HeightFormat, HeightStorage};
use clipmap::sample::Filter;
use clipmap::texel::TexelFormat;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum FormatArg {
    L8,
    Rgb8,
    Rgba8,
    L16,
    La16,
    Rgb16,
    Rgba16,
    /// Heights: the height verification texture in `l32f` metres, nodata -32768.
    #[value(alias = "heights")]
    L32f,
    /// Heights in `l16` steps of 0.25 m from -11000 m, nodata 0.
    HeightsL16,
    /// Heights in `l16i` steps of 0.5 m around 0 m, nodata -32768.
    L16i,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum FilterArg {
    Point,
    Bilinear,
    Trilinear,
}

/// A headless GPU renderer (wgpu, Vulkan) of a clipmapd service: uploads only the tiles that
/// entered the published valid regions, samples with the clipmap rule in a fragment shader, and
/// compares every frame with the reference software renderer.
///
/// Examples:
///   clipgpu --demo --json                        # its own service, the reference flight, JSON
///   clipgpu --name terrain --out frames          # against `clipmapd --source terrain --name terrain`
///   clipgpu --name hash --filter point --frames 30 --upload rects
///   clipgpu --name hash --view left              # draws and moves the view `left` (clipmapd --view left)
#[derive(Parser, Debug)]
#[command(name = "clipgpu", version, verbatim_doc_comment)]
struct Cli {
    /// Start a service of its own on the reference flight's procedural texture (terrain 2^16,
    /// clip 512, tiles of 128) and fly against it.
    #[arg(long, conflicts_with = "name")]
    demo: bool,
    /// The demo texture's texel format (16-bit formats upload as RGBA16); l32f (or heights),
    /// heights-l16 and l16i serve the height verification texture instead, drawn in false colour.
    #[arg(long, value_enum, default_value = "rgba8", requires = "demo")]
    demo_format: FormatArg,
    /// A height texture's false-colour range, MIN,MAX in metres (default: the heights block's
    /// range for l16 and l16i, -11000,8900 for l32f).
    #[arg(long, value_parser = parse_range, allow_hyphen_values = true)]
    height_range: Option<[f64; 2]>,
    /// The service's name (`clipmapd --name`).
    #[arg(long, required_unless_present = "demo")]
    name: Option<String>,
    /// The service's --shm-dir (default /dev/shm, else the temporary directory).
    #[arg(long)]
    shm_dir: Option<PathBuf>,
    /// The view to draw and move (docs/VIEWS.md): `main`, the primary, or a further view's name
    /// (`clipmapd --view NAME`, or `VIEW ADD NAME` on its socket).
    #[arg(long, default_value = "main", conflicts_with = "demo")]
    view: String,
    /// Print one JSON object (docs/GPU.md, "JSON") instead of a summary.
    #[arg(long)]
    json: bool,
    /// The flight (straight:SPEED[:ANGLE], circle:RADIUS:SPEED, zigzag:SPEED:PERIOD, hover,
    /// jump:EVERY:DIST; speeds in level-0 texels per frame).
    #[arg(long, default_value = "straight:8:30")]
    flight: String,
    /// Frames to fly (the accuracy study's reference flight has 6).
    #[arg(long, default_value_t = 24)]
    frames: u64,
    /// Image size WIDTHxHEIGHT in pixels (at most the adapter's largest texture side).
    #[arg(long, default_value = "256x192", value_parser = parse_size)]
    size: [u32; 2],
    /// Eye height above the ground, level-0 texels.
    #[arg(long, default_value_t = 24.0)]
    eye_height: f64,
    /// Pitch below the horizon, degrees.
    #[arg(long, default_value_t = 35.0)]
    pitch: f64,
    /// Horizontal field of view, degrees.
    #[arg(long, default_value_t = 60.0)]
    fov: f64,
    /// Where the flight starts, S,T in level-0 texels (default: the texture's centre).
    #[arg(long, value_parser = parse_point)]
    start: Option<[f64; 2]>,
    /// Texture filter.
    #[arg(long, value_enum, default_value = "trilinear")]
    filter: FilterArg,
    /// Upload method: whole tiles into their slots, or the entering strips cut from the tiles.
    #[arg(long, value_enum, default_value = "tiles")]
    upload: Method,
    /// Upload budget per frame, texel bytes (whole tiles, coarse levels first; a tile larger than
    /// the budget goes alone; with --upload tiles).
    #[arg(long)]
    upload_budget: Option<u64>,
    /// Write every frame as PNG (gpu-NNN.png, and reference-NNN.png when comparing) here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Do not render the reference frames (no comparison; for timing the GPU alone).
    #[arg(long)]
    no_compare: bool,
    /// A block-compressed texture (bc1, bc4, bc5, bc7): decode its blocks on the CPU and upload
    /// RGBA8, as on an adapter without BC textures, even where the adapter has them.
    #[arg(long)]
    decode_blocks_on_cpu: bool,
    /// Draw as soon as the service applied each frame's centre, without waiting for min LOD 0.
    #[arg(long)]
    no_settle: bool,
    /// The longest wait for a frame's snapshot, ms.
    #[arg(long, default_value_t = 5000)]
    wait_ms: u64,
    /// How long to wait for a stopped service to come back, seconds.
    #[arg(long, default_value_t = 10.0)]
    reattach_s: f64,
    /// Pause between frames, ms.
    #[arg(long, default_value_t = 0)]
    frame_ms: u64,
}

fn parse_size(s: &str) -> Result<[u32; 2], String> {
    let bad = || format!("`{s}`: expected WIDTHxHEIGHT, each 1 to 65536 pixels (e.g. 256x192)");
    let (w, h) = s.split_once('x').ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.parse().map_err(|_| bad())?, h.parse().map_err(|_| bad())?);
    // The adapter's own limit (lavapipe: 16384) is its to enforce: a larger frame is refused by
    // wgpu's validation, and the error says so.
    if !(1..=65536).contains(&w) || !(1..=65536).contains(&h) || w as u64 * h as u64 > 1 << 28 {
        return Err(bad());
    }
    Ok([w, h])
}

fn parse_point(s: &str) -> Result<[f64; 2], String> {
    let bad = || format!("`{s}`: expected S,T in level-0 texels (e.g. 32768,32768)");
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let (a, b): (f64, f64) = (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
    if !a.is_finite() || !b.is_finite() {
        return Err(bad());
    }
    Ok([a, b])
}

fn parse_range(s: &str) -> Result<[f64; 2], String> {
    let bad = || format!("`{s}`: expected MIN,MAX in metres (e.g. -11000,8900)");
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let (a, b): (f64, f64) = (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
    clipgpu::heights::check_range([a, b]).map_err(|e| format!("`{s}`: {e}"))
}

fn run(cli: Cli) -> anyhow::Result<()> {
    if cli.upload_budget.is_some() && cli.upload == Method::Rects {
        return Err(BadInput(
            "--upload-budget applies to --upload tiles (whole tiles within the budget); drop one of them".into(),
        )
        .into());
    }
    if cli.upload_budget == Some(0) {
        return Err(BadInput("--upload-budget 0: expected at least one tile's bytes".into()).into());
    }
    for (what, v, lo, hi) in
        [("--eye-height", cli.eye_height, 1e-3, 1e9), ("--pitch", cli.pitch, 1.0, 90.0), ("--fov", cli.fov, 1.0, 170.0)]
    {
        if !(v.is_finite() && (lo..=hi).contains(&v)) {
            return Err(BadInput(format!("{what} {v}: expected {lo} to {hi}")).into());
        }
    }
    if cli.frames == 0 || cli.frames > 100_000 {
        return Err(BadInput(format!("--frames {}: expected 1 to 100000", cli.frames)).into());
    }
    let filter = match cli.filter {
        FilterArg::Point => Filter::Point,
        FilterArg::Bilinear => Filter::Bilinear,
        FilterArg::Trilinear => Filter::Trilinear,
    };
    let mut case = Case::small();
    case.flight = cli.flight.clone();
    case.frames = cli.frames;
    case.display = cli.size;
    case.eye_height = cli.eye_height;
    case.pitch_deg = cli.pitch;
    case.fov_deg = cli.fov;
    let mut demo_heights = None;
    case.format = match cli.demo_format {
        FormatArg::L8 => TexelFormat::L8,
        FormatArg::Rgb8 => TexelFormat::RGB8,
        FormatArg::Rgba8 => TexelFormat::RGBA8,
        FormatArg::L16 => TexelFormat::L16,
        FormatArg::La16 => TexelFormat::LA16,
        FormatArg::Rgb16 => TexelFormat::RGB16,
        FormatArg::Rgba16 => TexelFormat::RGBA16,
        FormatArg::L32f | FormatArg::HeightsL16 | FormatArg::L16i => {
            let f = match cli.demo_format {
                FormatArg::L32f => Ok(HeightFormat::VERIFICATION),
                FormatArg::HeightsL16 => HeightFormat::new(HeightStorage::U16, 0.25, -11000.0, Some(0.0)),
                _ => HeightFormat::new(HeightStorage::I16, 0.5, 0.0, Some(-32768.0)),
            }
            .map_err(|e| anyhow::anyhow!("the demo's height format: {e}"))?;
            demo_heights = Some(f);
            TexelFormat::RGBA8
        }
    };
    let o = FlightOptions {
        case,
        filter,
        method: cli.upload,
        budget: cli.upload_budget,
        out_dir: cli.out.clone().or_else(|| cli.demo.then(|| PathBuf::from("clipgpu-demo"))),
        compare: !cli.no_compare,
        settle: !cli.no_settle,
        wait: Duration::from_millis(cli.wait_ms),
        reattach: Duration::from_secs_f64(cli.reattach_s.clamp(0.0, 3600.0)),
        frame_pause: Duration::from_millis(cli.frame_ms),
        start: cli.start,
        height_range: cli.height_range,
        view: cli.view.clone(),
    };
    if cli.view != clipmap::shm::layout::views::PRIMARY_NAME {
        clipmap::shm::layout::views::check_name(&cli.view)
            .map_err(|e| BadInput(format!("--view {}: {e}", cli.view)))?;
    }
    o.case.flight.parse::<clipmap::roam::Flight>().map_err(|e| BadInput(format!("--flight {}: {e}", o.case.flight)))?;
    let mut gpu = Gpu::new()?;
    if cli.decode_blocks_on_cpu {
        gpu.bc = false;
    }
    let report = if cli.demo {
        clipgpu::demo::demo(&gpu, &o, demo_heights)?
    } else {
        let dir = cli.shm_dir.clone().unwrap_or_else(clipmap::shm::default_dir);
        fly(&gpu, &dir, cli.name.as_deref().unwrap_or_default(), &o)?
    };
    let ctx = summary::Context {
        adapter: &gpu.adapter,
        filter,
        method: cli.upload,
        budget: cli.upload_budget,
        flight: &cli.flight,
        display: cli.size,
        compared: o.compare,
        heights: report.texture.heights.is_some(),
    };
    let j = summary::json(&ctx, &report);
    if cli.json {
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        let tol = Tolerance::for_report(filter, report.texture.heights.is_some(), report.texture.gpu_blocks());
        println!("clipgpu: {} frames on {}", report.frames.len(), gpu.adapter);
        if let Some(how) = report.texture.block_upload {
            let how = if how == "gpu" {
                "uploaded as they are, decoded by the GPU"
            } else {
                "decoded on the CPU (bcdec), uploaded as RGBA8"
            };
            println!(
                "  {} blocks {how} ({}); {:.0} bytes a frame to the GPU, {:.3} of RGBA8's",
                report.texture.format,
                report.texture.gpu_format,
                j["upload_gpu_bytes_per_frame"].as_f64().unwrap_or(0.0),
                j["upload_bytes_vs_rgba8"].as_f64().unwrap_or(0.0)
            );
        }
        println!(
            "  uploads: {:.0} bytes a frame ({}), the entering strips {:.0}, the tile-rounded bound {:.0}; first frame {}",
            j["upload_bytes_per_frame"].as_f64().unwrap_or(0.0),
            serde_json::to_string(&cli.upload)?.trim_matches('"'),
            j["theory_strip_bytes_per_frame"].as_f64().unwrap_or(0.0),
            j["tile_bound_bytes_per_frame"].as_f64().unwrap_or(0.0),
            j["first_frame_upload_bytes"]
        );
        println!(
            "  times: draw {:.2} ms, upload {:.2} ms, CPU reference {:.2} ms a frame",
            j["frame_ms"].as_f64().unwrap_or(0.0),
            j["upload_ms"].as_f64().unwrap_or(0.0),
            j["cpu_reference_ms"].as_f64().unwrap_or(0.0)
        );
        if o.compare {
            println!(
                "  against the reference renderer: PSNR min {}, max error {}; {} pixels at texel edges; off the edges PSNR min {}, max error {} ({}: PSNR >= {}, max error <= {} off the edges)\n  at the GPU's own coordinates: {} of {} pixels differ (max error {}); coordinates within {:.2e} texels, LOD within {:.2e} of the f64 camera's ({:.2} of their f32 bound)",
                j["psnr_min"].as_f64().map(|p| format!("{p:.1} dB")).unwrap_or_else(|| "identical".into()),
                j["max_error"],
                j["pixels_at_edges"],
                j["psnr_min_off_edges"].as_f64().map(|p| format!("{p:.1} dB")).unwrap_or_else(|| "identical".into()),
                j["max_error_off_edges"],
                if j["within_tolerance"].as_bool() == Some(true) { "within tolerance" } else { "OUTSIDE the tolerance" },
                tol.psnr_floor.map(|p| format!("{p} dB")).unwrap_or_else(|| "identical".into()),
                tol.max_error,
                j["pixels_differing_at_gpu_coords"],
                j["pixels_compared_at_gpu_coords"],
                j["max_error_at_gpu_coords"],
                j["max_coord_error_texels"].as_f64().unwrap_or(0.0),
                j["max_lod_error"].as_f64().unwrap_or(0.0),
                j["coord_error_bound_ratio"].as_f64().unwrap_or(0.0)
            );
        }
        if let (Some(sh), true) = (&report.texture.heights, o.compare) {
            let h = &j["heights"];
            println!(
                "  heights ({}, false colour over {} m to {} m): {} pixels compared at the GPU's coordinates, largest \
                 error {:.3e} m ({:.2} of its f32 bound, {} outside it); {} nodata in both, {} disagreeing",
                sh.format.storage(),
                sh.range[0],
                sh.range[1],
                h["compared"],
                h["max_error_m"].as_f64().unwrap_or(0.0),
                h["bound_ratio"].as_f64().unwrap_or(0.0),
                h["outside_bound"],
                h["nodata"],
                h["mismatch"]
            );
        }
        if report.reattaches > 0 {
            println!("  reattached {} time(s) after the service restarted", report.reattaches);
        }
        if !report.pictures.is_empty() {
            println!(
                "  frames written to {}",
                report.pictures[0].parent().unwrap_or(std::path::Path::new(".")).display()
            );
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli: Cli = clipmap::cli::parse();
    match run(cli) {
        Ok(()) => clipmap::report::exit::status(clipmap::report::exit::OK),
        Err(e) => {
            eprintln!("clipgpu: {e:#}");
            clipmap::report::exit::status(exit_code(&e))
        }
    }
}
