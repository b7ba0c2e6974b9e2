//! `clipbench perf`: every performance comparison of the project in one run, as ratios.
//!
//! Prepares its own data in a scratch directory (a hash pyramid written with the preparation
//! library, and for GDAL a tiled GeoTIFF with overviews of the same level 0), then measures,
//! several runs each, medians and spreads:
//! - `direction_ratio`: the slowest over the fastest median update tick (the tick alone; its reads
//!   run in the background) of the +s, +t and diagonal steady flights, and `tick_texel_bytes`, texel bytes the ticks
//!   wrote other than by tile reads (`clipbench engine`, run as a child process so that its
//!   memory figures are its own);
//! - `ingest_vs_read`: tiles per second through the engine's tile path (file source, read
//!   queues, straight into the image caches' slots) against plain sequential `std::fs::read` of
//!   the same files;
//! - `speedup_vs_gdal`, `speedup_vs_full_reload`: per-frame cost of one flight with the same
//!   per-level windows, through GDAL (one Python process reading every frame) and through the
//!   engine without incremental updates (a fresh clipmap filled every frame), against the engine;
//! - `memory_vs_formula`: resident growth of the engine's process against the image caches'
//!   formula (every stack level's grid of tiles, every pyramid level whole, the header);
//! - a 2^26 texture flown in real time (`scale.level0_shown_share`), and the service's
//!   request-to-publication latency.
//!
//! What each figure means and what limits it is in `docs/BENCHMARKS.md` (## Perf).

mod data;

pub use data::find_gdal;
mod flight;
mod human;
mod ingest;
pub mod install;
mod scale;
pub(crate) use scale::fly_over;
mod service;

use anyhow::Context;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// The size, runs, output and scratch options `clipbench perf` and `clipbench ingest` share.
#[derive(clap::Args, Debug)]
pub struct Common {
    /// Small sizes and short runs (`perf`: under two minutes in all).
    #[arg(long)]
    quick: bool,
    /// Tiny sizes: checks that every comparison runs (for tests); the figures mean little.
    #[arg(long, hide = true, conflicts_with = "quick")]
    smoke: bool,
    /// Print one JSON object instead of tables.
    #[arg(long)]
    json: bool,
    /// Runs per measurement (default 5; 3 with --quick or --smoke).
    #[arg(long)]
    runs: Option<usize>,
    /// Scratch directory for the prepared data (a fresh subdirectory, removed at the end).
    #[arg(long)]
    dir: Option<PathBuf>,
}

/// Options of `clipbench perf`.
#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    common: Common,
    /// Install GDAL (`apt-get install -y gdal-bin python3-gdal`) if it is missing; apt-get's
    /// output goes to standard error (standard output carries the report alone).
    #[arg(long)]
    install_peers: bool,
    /// Skip the GDAL comparison (`speedup_vs_gdal` is then null).
    #[arg(long)]
    no_gdal: bool,
}

/// Options of `clipbench ingest`.
#[derive(clap::Args, Debug)]
pub struct IngestArgs {
    #[command(flatten)]
    common: Common,
}

/// `clipbench ingest`: exit status 0 when it measured, 2 when it could not.
pub fn ingest_main(IngestArgs { common: args }: IngestArgs) -> u8 {
    let size = Size::of(args.quick, args.smoke);
    let runs = size.runs(args.runs);
    let measured = (|| {
        let load_start = loadavg();
        let scratch = Scratch::new(args.dir.clone())?;
        let prepared = data::prepare(&scratch.0, size, None)?;
        let ingest = ingest::measure(&prepared, size, runs)?;
        anyhow::Ok((ingest, machine(load_start)))
    })();
    match measured {
        Ok((ingest, machine)) => {
            if args.json {
                let v =
                    serde_json::json!({ "ingest_vs_read": ingest.ratio.median, "ingest": ingest, "machine": machine });
                println!("{}", serde_json::to_string_pretty(&v).expect("report serialises"));
            } else {
                print!("{}", human::ingest_table(&ingest, &machine));
            }
            0
        }
        Err(e) => {
            eprintln!("clipbench ingest: {e:#}");
            2
        }
    }
}

/// How large a run is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Size {
    Full,
    Quick,
    Smoke,
}

impl Size {
    /// The size `--quick` / `--smoke` ask for (`--smoke` wins; clap refuses both together).
    fn of(quick: bool, smoke: bool) -> Size {
        if smoke {
            Size::Smoke
        } else if quick {
            Size::Quick
        } else {
            Size::Full
        }
    }

    /// Runs per measurement: `asked`, else 5 at the full size and 3 otherwise; at least 1.
    fn runs(self, asked: Option<usize>) -> usize {
        asked.unwrap_or(if self == Size::Full { 5 } else { 3 }).max(1)
    }
}

/// Median and spread of a measurement's runs.
#[derive(Clone, Debug, Serialize)]
pub struct Stat {
    pub median: f64,
    pub min: f64,
    pub max: f64,
    /// (max - min) / median: the relative spread of the runs.
    pub spread: f64,
    pub samples: Vec<f64>,
}

impl Stat {
    pub fn of(samples: Vec<f64>) -> Stat {
        let mut s = samples.clone();
        s.sort_by(f64::total_cmp);
        let n = s.len();
        let median = match n {
            0 => 0.0,
            _ if n % 2 == 1 => s[n / 2],
            _ => (s[n / 2 - 1] + s[n / 2]) / 2.0,
        };
        let (min, max) = (s.first().copied().unwrap_or(0.0), s.last().copied().unwrap_or(0.0));
        let spread = if median == 0.0 { 0.0 } else { (max - min) / median };
        Stat { median, min, max, spread, samples }
    }
}

/// The p-quantile (0..=1) of `v` by nearest rank.
pub fn quantile(v: &[f64], p: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return 0.0;
    }
    s[((s.len() - 1) as f64 * p).round() as usize]
}

/// The whole machine's CPU time so far, every core and every process (`/proc/stat`'s `cpu`
/// line; the kernel counts in 1/100 s): the seconds the cores were busy (user, nice, system,
/// interrupts, steal). Over a span, busy seconds over wall seconds is how many cores
/// were busy on average; busy seconds over tiles is what a tile cost the machine, whoever spent it
/// (our threads, nginx, curl, the kernel's network stack).
#[derive(Clone, Copy, Debug, Default)]
pub struct MachineCpu {
    pub busy_s: f64,
}

impl MachineCpu {
    pub fn now() -> MachineCpu {
        let stat = std::fs::read_to_string("/proc/stat").unwrap_or_default();
        let line = stat.lines().find(|l| l.starts_with("cpu ")).unwrap_or("");
        let f: Vec<u64> = line.split_whitespace().skip(1).map(|x| x.parse().unwrap_or(0)).collect();
        let at = |i: usize| f.get(i).copied().unwrap_or(0);
        // user nice system idle iowait irq softirq steal (guest time is within user); idle and
        // iowait are not busy.
        let busy = at(0) + at(1) + at(2) + at(5) + at(6) + at(7);
        MachineCpu { busy_s: busy as f64 / 100.0 }
    }

    /// The busy seconds since `before`.
    pub fn busy_since(before: MachineCpu) -> f64 {
        (MachineCpu::now().busy_s - before.busy_s).max(0.0)
    }
}

/// This process's counters from `/proc/self/stat`.
pub struct ProcSelf {
    /// Minor page faults (all threads).
    pub minor_faults: u64,
    /// User plus system CPU seconds (all threads; the kernel counts in 1/100 s).
    pub cpu_s: f64,
    /// Context switches, voluntary and not, summed over the threads alive now (a thread that
    /// ended took its count with it).
    pub switches: u64,
}

pub fn proc_self() -> ProcSelf {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // The command name (field 2) may hold spaces; fields after it start at field 3, so minflt
    // (field 10) is the 8th and utime, stime (fields 14, 15) the 12th and 13th.
    let f: Vec<u64> =
        stat.rsplit_once(')').map_or("", |(_, r)| r).split_whitespace().map(|x| x.parse().unwrap_or(0)).collect();
    let at = |i: usize| f.get(i).copied().unwrap_or(0);
    ProcSelf { minor_faults: at(7), cpu_s: (at(11) + at(12)) as f64 / 100.0, switches: thread_switches() }
}

/// CPU time of every live thread of this process, nanoseconds: the sum of each thread's
/// `/proc/self/task/*/schedstat` first field (time on a CPU, in ns, where `/proc/self/stat`
/// counts in hundredths of a second). A thread that ended between two readings takes its time
/// with it, so compare readings around work whose threads outlive it. 0 where it is unreadable.
pub fn cpu_ns() -> u64 {
    sum_over_threads("schedstat", |s| s.split_whitespace().next().and_then(|x| x.parse::<u64>().ok()).unwrap_or(0))
}

fn thread_switches() -> u64 {
    sum_over_threads("status", |status| {
        status
            .lines()
            .filter_map(|line| {
                line.strip_prefix("voluntary_ctxt_switches:")
                    .or_else(|| line.strip_prefix("nonvoluntary_ctxt_switches:"))
            })
            .map(|v| v.trim().parse::<u64>().unwrap_or(0))
            .sum()
    })
}

/// Sums `figure` of the file `file` of every thread of this process (`/proc/self/task/*/FILE`);
/// 0 where /proc cannot be read (a thread that ended meanwhile counts nothing).
fn sum_over_threads(file: &str, figure: impl Fn(&str) -> u64) -> u64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else { return 0 };
    tasks.flatten().filter_map(|t| std::fs::read_to_string(t.path().join(file)).ok()).map(|s| figure(&s)).sum()
}

/// The machine the figures come from.
#[derive(Clone, Debug, Serialize)]
pub struct Machine {
    pub nproc: usize,
    pub cpu: String,
    pub memory_gib: f64,
    pub load_start: String,
    pub load_end: String,
}

fn machine(load_start: String) -> Machine {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let cpu = cpuinfo
        .lines()
        .find(|l| l.starts_with("model name"))
        .and_then(|l| l.split(':').nth(1))
        .map_or_else(|| "unknown".into(), |s| s.trim().to_string());
    let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
    let kib: f64 = meminfo
        .lines()
        .find(|l| l.starts_with("MemTotal:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.0);
    Machine {
        nproc: std::thread::available_parallelism().map_or(1, |n| n.get()),
        cpu,
        memory_gib: kib / (1u64 << 20) as f64,
        load_start,
        load_end: loadavg(),
    }
}

fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default()
}

/// Memory of the engine's process against the image caches' formula.
#[derive(Clone, Debug, Serialize)]
pub struct Memory {
    /// Every stack level's grid of tiles, every pyramid level's texels, and the 8 KiB header.
    pub formula_bytes: u64,
    /// The image caches as laid out (tags and page rounding included): what a service maps.
    pub mapping_bytes: u64,
    /// What the clipmap windows of layout 1 took, for comparison: docs/ARCHITECTURE.md §3's
    /// 4^m (n - m + 4/3) - 1/3 texels times bytes per texel (held beside a tile cache then).
    pub layout1_window_bytes: u64,
    pub vm_rss_before_bytes: u64,
    pub vm_hwm_bytes: u64,
    /// (VmHWM - VmRSS before the clipmap) / formula.
    pub delta_ratio: f64,
    /// VmHWM / formula: the whole process, program included.
    pub hwm_ratio: f64,
}

/// Everything `clipbench perf` measured.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Slowest / fastest median update tick of the +s, +t and diagonal steady flights (goal <= 1.25).
    pub direction_ratio: f64,
    /// Texel bytes written by update ticks outside tile reads (goal 0).
    pub tick_texel_bytes: u64,
    /// Engine tile ingest (tiles/s) / plain sequential reads of the same files (goal >= 0.9).
    pub ingest_vs_read: f64,
    /// GDAL's per-frame time / the engine's (goal >= 50); null without GDAL.
    pub speedup_vs_gdal: Option<f64>,
    /// Full reload's per-frame time / the engine's (goal >= 10).
    pub speedup_vs_full_reload: f64,
    /// Resident growth / the image caches' formula (goal <= 1.1).
    pub memory_vs_formula: f64,
    /// The same at 2^30 texels a side (`engine_2_30`, the same clip and tiles; goal <= 1.05).
    pub memory_vs_formula_2_30: f64,
    /// The median update tick of the same flights (texels a tick, clip, tiles) at 2^30 texels a
    /// side over at 2^26 (the engine's own flights at full size, a run of its own at `--quick`
    /// and `--smoke`): the mean of the flights' medians, one over the other (goal <= 1.1).
    pub tick_2_30_vs_2_26: f64,
    /// Service latency, request to published (median), with the centre asked for in longitude /
    /// latitude (the request mapping's coordinate kind 1) over in texels, the two interleaved in
    /// one run (goal <= 1.05).
    pub lonlat_vs_texels: f64,
    pub size: Size,
    pub runs: usize,
    pub command: String,
    pub machine: Machine,
    pub elapsed_s: f64,
    pub engine: serde_json::Value,
    pub memory: Memory,
    /// `clipbench engine --size-log2 30`: the same flights at 2^30 texels a side.
    pub engine_2_30: serde_json::Value,
    pub memory_2_30: Memory,
    pub ingest: ingest::Ingest,
    pub flight: flight::Flight,
    pub scale: scale::Scale,
    /// The same flight with the default square lookahead of 1 (`scale` reads two ticks of
    /// motion ahead along it).
    pub scale_default: scale::Scale,
    pub service: service::Latency,
}

/// Runs `clipbench engine` in a child process (its `VmHWM` is then the engine's alone), at 2^N
/// texels a side when `size_log2` is given.
fn engine_child(size: Size, runs: usize, size_log2: Option<u32>) -> anyhow::Result<serde_json::Value> {
    let exe = std::env::current_exe().context("locating this program")?;
    let mut cmd = std::process::Command::new(exe);
    cmd.args(["engine", "--json", "--runs", &runs.to_string()]);
    if let Some(n) = size_log2 {
        cmd.args(["--size-log2", &n.to_string()]);
    }
    match size {
        Size::Full => {}
        Size::Quick => {
            cmd.arg("--quick");
        }
        Size::Smoke => {
            cmd.arg("--smoke");
        }
    }
    child_json(&mut cmd, "clipbench engine")
}

/// Runs a child that prints one JSON value on success; its stderr goes into the error otherwise.
fn child_json<T: serde::de::DeserializeOwned>(cmd: &mut std::process::Command, what: &str) -> anyhow::Result<T> {
    let out = cmd.output().with_context(|| format!("running {what}"))?;
    anyhow::ensure!(out.status.success(), "{what} failed ({}): {}", out.status, String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).with_context(|| format!("reading {what}'s JSON"))
}

fn field(v: &serde_json::Value, path: &[&str]) -> anyhow::Result<f64> {
    let mut at = v;
    for p in path {
        at = at.get(p).with_context(|| format!("clipbench engine's JSON has no {}", path.join(".")))?;
    }
    at.as_f64().with_context(|| format!("{} is not a number", path.join(".")))
}

/// The mean of `a`'s flights' median ticks over `b`'s (`engine.flights[].median_tick_s`).
fn tick_ratio(a: &serde_json::Value, b: &serde_json::Value) -> anyhow::Result<f64> {
    let mean = |v: &serde_json::Value| -> anyhow::Result<f64> {
        let f = v["flights"].as_array().context("clipbench engine's JSON has no flights")?;
        let m: Vec<f64> = f.iter().filter_map(|f| f["median_tick_s"].as_f64()).collect();
        anyhow::ensure!(!m.is_empty() && m.len() == f.len(), "a flight without median_tick_s");
        Ok(m.iter().sum::<f64>() / m.len() as f64)
    };
    Ok(mean(a)? / mean(b)?)
}

/// docs/ARCHITECTURE.md §3: a 2^n texture with clip 2^m holds 4^m (n - m + 4/3) - 1/3 texels.
pub fn formula_texels(size: u64, clip: u64) -> u64 {
    let (n, m) = (size.trailing_zeros() as u64, clip.min(size).trailing_zeros() as u64);
    // 4^m (n - m + 4/3) - 1/3 = (4^m (3 (n - m) + 4) - 1) / 3, exact in integers.
    ((1u64 << (2 * m)) * (3 * (n - m) + 4) - 1) / 3
}

fn memory(engine: &serde_json::Value) -> anyhow::Result<Memory> {
    let size = field(engine, &["setup", "size"])? as u64;
    let clip = field(engine, &["setup", "clip"])? as u64;
    let bpt = field(engine, &["setup", "bytes_per_texel"])? as u64;
    let formula = field(engine, &["formula_bytes"])? as u64;
    let before = field(engine, &["vm_rss_before_bytes"])? as u64;
    let hwm = field(engine, &["vm_hwm_bytes"])? as u64;
    Ok(Memory {
        formula_bytes: formula,
        mapping_bytes: field(engine, &["mapping_bytes"])? as u64,
        layout1_window_bytes: formula_texels(size, clip) * bpt,
        vm_rss_before_bytes: before,
        vm_hwm_bytes: hwm,
        delta_ratio: hwm.saturating_sub(before) as f64 / formula as f64,
        hwm_ratio: hwm as f64 / formula as f64,
    })
}

/// A scratch directory removed when dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new(parent: Option<PathBuf>) -> anyhow::Result<Scratch> {
        let parent = parent.unwrap_or_else(std::env::temp_dir);
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let dir = parent.join(format!("clipbench-perf-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        Ok(Scratch(dir))
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn progress(json: bool, what: &str) {
    if !json || std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        eprintln!("clipbench perf: {what}");
    }
}

pub fn run(args: &Args) -> anyhow::Result<Report> {
    let started = Instant::now();
    let load_start = loadavg();
    let (c, size) = (&args.common, Size::of(args.common.quick, args.common.smoke));
    let runs = size.runs(c.runs);
    let mut command = String::from("clipbench perf");
    for (on, flag) in [(c.quick, " --quick"), (c.smoke, " --smoke"), (args.no_gdal, " --no-gdal")] {
        if on {
            command.push_str(flag);
        }
    }
    if let Some(r) = c.runs {
        command.push_str(&format!(" --runs {r}"));
    }
    let gdal = if args.no_gdal { Err("--no-gdal".to_string()) } else { data::find_gdal(args.install_peers) };
    let json = c.json;

    progress(json, "engine flights by direction, memory (child process)");
    let engine = engine_child(size, runs, None)?;
    let direction_ratio = field(&engine, &["direction_ratio"])?;
    let tick_texel_bytes = field(&engine, &["tick_texel_bytes"])? as u64;
    let memory = memory(&engine)?;
    progress(json, "the same flights at 2^30 texels a side (child process)");
    let engine_2_30 = engine_child(size, runs, Some(30))?;
    let memory_2_30 = self::memory(&engine_2_30)?;
    // Against the same flights at 2^26 (the engine's own at full size; a child more otherwise).
    let tick_2_30_vs_2_26 = match size {
        Size::Full => tick_ratio(&engine_2_30, &engine)?,
        _ => tick_ratio(&engine_2_30, &engine_child(size, runs, Some(26))?)?,
    };

    let scratch = Scratch::new(c.dir.clone())?;
    progress(json, &format!("preparing data in {}", scratch.0.display()));
    let prepared = data::prepare(&scratch.0, size, gdal.as_ref().ok())?;

    progress(json, "tile ingest against plain reads");
    let ingest = ingest::measure(&prepared, size, runs)?;
    progress(json, "flight: engine, full reloads, GDAL");
    let flight = flight::measure(&prepared, size, runs, gdal.as_ref().map_err(|s| s.as_str()))?;
    drop(scratch);
    progress(json, "2^26 flight in real time");
    let (scale, scale_default) = scale::measure(size)?;
    progress(json, "service latency");
    let service = service::measure(size)?;

    Ok(Report {
        direction_ratio,
        tick_texel_bytes,
        ingest_vs_read: ingest.ratio.median,
        speedup_vs_gdal: flight.speedup_vs_gdal.as_ref().map(|s| s.median),
        speedup_vs_full_reload: flight.speedup_vs_full_reload.median,
        memory_vs_formula: memory.delta_ratio,
        memory_vs_formula_2_30: memory_2_30.delta_ratio,
        tick_2_30_vs_2_26,
        lonlat_vs_texels: service.lonlat_vs_texels,
        size,
        runs,
        command,
        machine: machine(load_start),
        elapsed_s: started.elapsed().as_secs_f64(),
        engine,
        memory,
        engine_2_30,
        memory_2_30,
        ingest,
        flight,
        scale,
        scale_default,
        service,
    })
}

/// `clipbench perf`: exit status 0 when it measured (goals met or not), 2 when it could not.
pub fn main(args: Args) -> u8 {
    match run(&args) {
        Ok(r) => {
            if args.common.json {
                println!("{}", serde_json::to_string_pretty(&r).expect("report serialises"));
            } else {
                print!("{}", human::table(&r));
            }
            0
        }
        Err(e) => {
            eprintln!("clipbench perf: {e:#}");
            2
        }
    }
}
