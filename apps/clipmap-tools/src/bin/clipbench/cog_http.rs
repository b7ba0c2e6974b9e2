//! The HTTP half of `clipbench cog`: the same COG served by nginx on loopback, read by our COG
//! source by URL, by GDAL through `/vsicurl/` and by curl, in the same run.
//!
//! Requests and bytes are counted in nginx's access log (no relay in the way of the rates):
//! - ours: `depth` threads over one remote reader, each pass on a fresh open (open timed and
//!   counted apart); every tile checked against GDAL's decode;
//! - GDAL: one `ReadRaster` a tile through `/vsicurl/`, with [`GDAL_HTTP_ENV`] (what GDAL's
//!   `/vsicurl/` documentation tells users of COGs to set), again with `GDAL_NUM_THREADS=ALL_CPUS`,
//!   and with none of them (GDAL's defaults);
//! - curl: the byte ranges our last pass fetched, exactly (from the log), `depth` transfers at
//!   once over kept connections (`curl --parallel --parallel-max DEPTH`), one run a pass;
//! - our remote reader fetching the same ranges with no decoding (where our HTTP path stands
//!   against curl's, decoding aside);
//! - faults: ours through a relay in front of nginx that answers 5 % of the requests `503` and
//!   closes the connection half way through the body of 1 %, against the same relay with no
//!   fault.

use super::cog_shared::{clip_of, gdal_passes, median, one_pass, Http, HttpRun, Spent};
use super::perf::MachineCpu;
use super::serve::{program, AccessLog, Faults, Hit, Nginx, Proxy};
use clipmap::place::RemoteName;
use clipmap::source::remote::object::Object;
use clipmap::source::remote::{Remote, RemoteOptions};
use clipmap::source::CogSource;
use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// GDAL's settings for reading a COG over HTTP, as its `/vsicurl/` documentation gives them: no
/// directory listing at open, and no probing of side-car files other than `.tif` ones.
pub const GDAL_HTTP_ENV: [(&str, &str); 2] =
    [("GDAL_DISABLE_READDIR_ON_OPEN", "EMPTY_DIR"), ("CPL_VSIL_CURL_ALLOWED_EXTENSIONS", ".tif")];

/// Loopback is not to go through a proxy the environment may name.
const NO_PROXY: [(&str, &str); 2] = [("NO_PROXY", "127.0.0.1,localhost"), ("no_proxy", "127.0.0.1,localhost")];

/// Shares of the relay's requests that fail (the COG issue's figures).
const FAULTS: Faults = Faults { unavailable: 0.05, cut: 0.01 };

/// nginx and curl, installed with `--install-peers` when missing; `None` (with a note) when
/// they are missing and not to be installed.
fn peers(install: bool) -> anyhow::Result<Option<std::path::PathBuf>> {
    let missing = |curl: &Option<std::path::PathBuf>| {
        let mut m = Vec::new();
        if super::serve::nginx_program().is_none() {
            m.push("nginx");
        }
        if curl.is_none() {
            m.push("curl");
        }
        m
    };
    let mut curl = program(&["curl"]);
    let mut m = missing(&curl);
    if !m.is_empty() && install {
        let mut args = vec!["install", "-y"];
        args.extend(&m);
        super::perf::install::run("apt-get".as_ref(), &args).map_err(|e| anyhow::anyhow!("installing {m:?}: {e}"))?;
        curl = program(&["curl"]);
        m = missing(&curl);
    }
    if !m.is_empty() {
        eprintln!(
            "clipbench cog: {} not found: the HTTP fields are null (install {}, or pass --install-peers)",
            m.join(" and "),
            m.join(" and ")
        );
        return Ok(None);
    }
    Ok(curl)
}

/// Our passes over `url`: (seconds a pass, seconds an open, texels wrong, reads failed, the
/// first failure).
struct Ours {
    seconds: Vec<f64>,
    opens: Vec<f64>,
    wrong: u64,
    failed: u64,
    first_error: Option<String>,
    /// nginx's log of the first open, and of the last pass's reads.
    open_hits: Vec<Hit>,
    pass_hits: Vec<Hit>,
    remote: Arc<Remote>,
    /// The machine's CPU over the passes.
    spent: Spent,
}

fn our_passes(run: &HttpRun, url: &str, log: &AccessLog) -> anyhow::Result<Ours> {
    let name = RemoteName::parse(url).ok_or_else(|| anyhow::anyhow!("{url}: not a remote name"))?;
    let opts = RemoteOptions::from_env().map_err(|e| anyhow::anyhow!("{e}"))?;
    // COG ranges are not kept in the disk cache (docs/COG.md), as the service reads them.
    let remote = Arc::new(Remote::new(RemoteOptions { cache_dir: None, ..opts })?);
    let mut o = Ours {
        seconds: Vec::new(),
        opens: Vec::new(),
        wrong: 0,
        failed: 0,
        first_error: None,
        open_hits: Vec::new(),
        pass_hits: Vec::new(),
        remote: remote.clone(),
        spent: Spent { busy_s: 0.0, wall_s: 0.0, tiles: 0 },
    };
    let cpu = MachineCpu::now();
    for pass in 0..run.passes {
        let before = log.settled()?.len();
        let t0 = Instant::now();
        let src = CogSource::open_remote(&name, remote.clone(), clip_of(run.n))
            .map_err(|e| anyhow::anyhow!("opening {url}: {e}"))?;
        o.opens.push(t0.elapsed().as_secs_f64());
        let opened = log.settled()?;
        if pass == 0 {
            o.open_hits = opened[before..].to_vec();
        }
        let p = one_pass(&src, run.depth, run.reference);
        o.seconds.push(p.seconds);
        o.wrong += p.wrong;
        o.failed += p.failed;
        o.first_error = o.first_error.or(p.first_error);
        o.pass_hits = log.settled()?[opened.len()..].to_vec();
    }
    o.spent = Spent::since(cpu, &o.seconds, run.passes * (run.n / run.tile) * (run.n / run.tile));
    Ok(o)
}

/// curl fetching `ranges` of `url` (both ends included), `depth` at once, once a pass; seconds
/// a pass, and the machine's CPU over them. Checks that every transfer got its
/// range's bytes.
fn curl_passes(
    curl: &Path,
    dir: &Path,
    url: &str,
    ranges: &[(u64, u64)],
    depth: u64,
    passes: u64,
    tiles: u64,
) -> anyhow::Result<(Vec<f64>, Spent)> {
    let mut config = String::new();
    for (i, (a, b)) in ranges.iter().enumerate() {
        // `next` between transfers (one after the last would be a transfer with no URL).
        if i > 0 {
            config.push_str("next\n");
        }
        let _ = writeln!(
            config,
            "url = \"{url}\"\nrange = \"{a}-{b}\"\noutput = \"/dev/null\"\nfail\nwrite-out = \"%{{http_code}} %{{size_download}}\\n\""
        );
    }
    let file = dir.join("curl_ranges.txt");
    std::fs::write(&file, config)?;
    let want: u64 = ranges.iter().map(|(a, b)| b - a + 1).sum();
    let mut times = Vec::new();
    let cpu = MachineCpu::now();
    for _ in 0..passes {
        let t = Instant::now();
        let out = Command::new(curl)
            .args([
                "--silent",
                "--show-error",
                "--no-progress-meter",
                "--noproxy",
                "*",
                "--parallel",
                "--parallel-immediate",
            ])
            .arg("--parallel-max")
            .arg(depth.to_string())
            .arg("--config")
            .arg(&file)
            .output()?;
        times.push(t.elapsed().as_secs_f64());
        let text = String::from_utf8_lossy(&out.stdout);
        let (mut n, mut got) = (0usize, 0u64);
        for line in text.lines() {
            let mut it = line.split(' ');
            let code = it.next().unwrap_or("");
            anyhow::ensure!(code == "206", "curl fetching ranges of {url}: status {code} (`{line}`), expected 206");
            got += it.next().and_then(|b| b.parse::<u64>().ok()).unwrap_or(0);
            n += 1;
        }
        anyhow::ensure!(
            out.status.success() && n == ranges.len() && got == want,
            "curl fetching {} ranges ({want} bytes) of {url}: {n} transfers, {got} bytes, {}: {}",
            ranges.len(),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    let spent = Spent::since(cpu, &times, tiles * passes);
    Ok((times, spent))
}

/// Our remote reader fetching `ranges` of `url` (both ends included) on `depth` threads, with
/// no decoding, once a pass: what our HTTP path costs where curl's does (seconds a pass, and the
/// machine's CPU over them).
fn fetch_passes(
    url: &str,
    ranges: &[(u64, u64)],
    depth: u64,
    passes: u64,
    tiles: u64,
) -> anyhow::Result<(Vec<f64>, Spent)> {
    let name = RemoteName::parse(url).ok_or_else(|| anyhow::anyhow!("{url}: not a remote name"))?;
    let opts = RemoteOptions::from_env().map_err(|e| anyhow::anyhow!("{e}"))?;
    let remote = Arc::new(Remote::new(RemoteOptions { cache_dir: None, ..opts })?);
    let (object, _) = Object::open(remote, &name, 1).map_err(|e| anyhow::anyhow!("opening {url}: {e}"))?;
    let mut times = Vec::new();
    let cpu = MachineCpu::now();
    for _ in 0..passes {
        let next = AtomicUsize::new(0);
        let t = Instant::now();
        let failed = std::thread::scope(|scope| {
            let workers: Vec<_> = (0..depth)
                .map(|_| {
                    scope.spawn(|| loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        let &(a, b) = ranges.get(i)?;
                        if let Err(e) = object.read(a, b - a + 1) {
                            return Some(format!("bytes {a}-{b}: {e}"));
                        }
                    })
                })
                .collect();
            workers.into_iter().find_map(|w| w.join().unwrap_or_else(|_| Some("a thread panicked".into())))
        });
        times.push(t.elapsed().as_secs_f64());
        if let Some(e) = failed {
            anyhow::bail!("fetching ranges of {url}: {e}");
        }
    }
    let spent = Spent::since(cpu, &times, tiles * passes);
    Ok((times, spent))
}

/// Requests a pass of a GDAL run (all its passes over their number, rounded).
fn per_pass(hits: usize, passes: u64) -> u64 {
    (hits as f64 / passes as f64).round() as u64
}

pub fn measure(run: &HttpRun) -> anyhow::Result<Option<Http>> {
    let Some(curl) = peers(run.install_peers)? else { return Ok(None) };
    let root = run.tif.parent().ok_or_else(|| anyhow::anyhow!("{}: no directory", run.tif.display()))?;
    let file = run.tif.file_name().and_then(|f| f.to_str()).ok_or_else(|| anyhow::anyhow!("the COG's name"))?;
    let log = AccessLog(run.dir.join("access.log"));
    let nginx = Nginx::serve(root, &run.dir.join("nginx"), Some(&log.0), run.link_mb_per_s.map(|m| m * 1_000_000))?;
    let url = format!("http://127.0.0.1:{}/{file}", nginx.port);
    let tiles = (run.n / run.tile) * (run.n / run.tile);
    let rate = |s: &[f64]| tiles as f64 / median(s.to_vec());

    // Ours.
    let ours = our_passes(run, &url, &log)?;
    if let Some(e) = &ours.first_error {
        anyhow::bail!("reading {url}: {} reads failed; the first: {e}", ours.failed);
    }
    let open_requests = ours.open_hits.len() as u64;
    let open_bytes: u64 = ours.open_hits.iter().map(|h| h.bytes).sum();
    let mut ranges = Vec::new();
    for h in &ours.pass_hits {
        match (h.status, h.range) {
            (206, Some(r)) => ranges.push(r),
            _ => anyhow::bail!(
                "{url}: our reads made a request nginx answered {} ({h:?}); expected 206 to a range",
                h.status
            ),
        }
    }
    let pass_bytes: u64 = ours.pass_hits.iter().map(|h| h.bytes).sum();

    // GDAL.
    let vsi = format!("/vsicurl/{url}");
    let gdal = |env: &[(&str, &str)]| -> anyhow::Result<(Vec<f64>, Vec<Hit>)> {
        let before = log.settled()?.len();
        let env: Vec<(&str, &str)> = env.iter().chain(NO_PROXY.iter()).copied().collect();
        let r = gdal_passes(run.python, run.script, &vsi, run.tile, run.passes, None, &env)?;
        anyhow::ensure!(r.tiles == tiles, "GDAL read {} tiles a pass of {vsi} where the COG has {tiles}", r.tiles);
        Ok((r.seconds, log.settled()?[before..].to_vec()))
    };
    let (gdal_s, gdal_hits) = gdal(&GDAL_HTTP_ENV)?;
    let all_cpus: Vec<(&str, &str)> = GDAL_HTTP_ENV.iter().copied().chain([("GDAL_NUM_THREADS", "ALL_CPUS")]).collect();
    let (gdal_all_s, _) = gdal(&all_cpus)?;
    let (gdal_default_s, gdal_default_hits) = gdal(&[])?;

    // curl, and our reader fetching the same ranges without decoding them.
    let (curl_s, curl_cpu) = curl_passes(&curl, run.dir, &url, &ranges, run.depth, run.passes, tiles)?;
    let (fetch_s, fetch_cpu) = fetch_passes(&url, &ranges, run.depth, run.passes, tiles)?;

    // Faults: the same relay with and without them.
    let stop = Arc::new(AtomicBool::new(false));
    let clean = Proxy::start(nginx.port, Duration::ZERO, Faults::default(), stop.clone())?;
    let faulty = Proxy::start(nginx.port, Duration::ZERO, FAULTS, stop.clone())?;
    let relay = our_passes(run, &format!("http://127.0.0.1:{}/{file}", clean.port), &log)?;
    if let Some(e) = &relay.first_error {
        anyhow::bail!("reading {file} through the relay: {} reads failed; the first: {e}", relay.failed);
    }
    let faults = our_passes(run, &format!("http://127.0.0.1:{}/{file}", faulty.port), &log)?;
    stop.store(true, Ordering::Relaxed);
    let fc = &faulty.counters;
    let requests = open_requests + ours.pass_hits.len() as u64;
    Ok(Some(Http {
        tiles_per_s_http: rate(&ours.seconds),
        tiles_per_s_gdal_http: rate(&gdal_s),
        tiles_per_s_gdal_http_all_cpus: rate(&gdal_all_s),
        tiles_per_s_gdal_http_default_env: rate(&gdal_default_s),
        curl_ceiling_tiles_per_s: rate(&curl_s),
        tiles_per_s_http_fetch_only: rate(&fetch_s),
        cores_busy_http: ours.spent.cores(),
        cores_busy_curl: curl_cpu.cores(),
        cores_busy_fetch_only: fetch_cpu.cores(),
        core_us_per_tile_http: ours.spent.core_us_per_tile(),
        core_us_per_tile_curl: curl_cpu.core_us_per_tile(),
        core_us_per_tile_fetch_only: fetch_cpu.core_us_per_tile(),
        requests,
        bytes: open_bytes + pass_bytes,
        requests_gdal: per_pass(gdal_hits.len(), run.passes),
        bytes_gdal: gdal_hits.iter().map(|h| h.bytes).sum::<u64>() / run.passes,
        requests_gdal_default_env: per_pass(gdal_default_hits.len(), run.passes),
        open_requests,
        open_bytes,
        range_bytes_max: ranges.iter().map(|(a, b)| b - a + 1).max().unwrap_or(0),
        range_bytes_mean: pass_bytes as f64 / ranges.len().max(1) as f64,
        gdal_env: GDAL_HTTP_ENV.iter().map(|(k, v)| format!("{k}={v}")).collect(),
        tiles_per_s_http_relay: rate(&relay.seconds),
        tiles_per_s_http_faults: rate(&faults.seconds),
        fault_503_share: FAULTS.unavailable,
        fault_cut_share: FAULTS.cut,
        faults_503: fc.unavailable.load(Ordering::Relaxed),
        faults_cut: fc.cut.load(Ordering::Relaxed),
        retries: faults.remote.stats().retries,
        failed_reads: faults.failed,
        wrong_texels: ours.wrong + relay.wrong + faults.wrong,
        open_s: median(ours.opens.clone()),
    }))
}
