//! How the tools take a `.tif` they are given: a GeoTIFF or COG is never read as a
//! configuration (`cliptex validate|roam|plan`), and a URL with a `?query` is a remote COG
//! wherever a `.tif` name is accepted, its query kept in every request.

use crate::common::exec;
use std::path::{Path, PathBuf};

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const CLIPPREP: &str = env!("CARGO_BIN_EXE_clipprep");

/// Writes a 512 x 512 RGB COG of the hash texture (128-texel tiles) at `dir/name`.
pub fn small_cog(dir: &Path, name: &str) -> PathBuf {
    let cog = dir.join(name);
    let out = dir.join(format!("{name}.pyr"));
    let args = [
        "--source",
        "hash",
        "--size",
        "512",
        "--tile",
        "128",
        "--clip",
        "256",
        "--format",
        "rgb8",
        "--out",
        out.to_str().unwrap(),
        "--cog",
        cog.to_str().unwrap(),
        "-q",
    ];
    let (o, desc) = exec(dir, CLIPPREP, &args);
    assert!(o.status.success(), "{desc}");
    cog
}

/// Standard output and error of a run, together.
fn said(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr)
}

/// No byte of the file's binary header in what was said (no control character but line ends).
fn no_binary(text: &str, desc: &str) {
    assert!(!text.contains("GDAL_STRUCTURAL_METADATA"), "bytes of the TIFF printed:\n{desc}");
    assert!(!text.contains('\u{fffd}'), "bytes that are no UTF-8 printed:\n{desc}");
    assert!(!text.chars().any(|c| c.is_control() && c != '\n' && c != '\t'), "control bytes printed:\n{desc}");
}

#[test]
fn cliptex_validate_roam_and_plan_of_a_tif_say_what_it_is_and_print_no_binary() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let cog = small_cog(d, "c.tif");
    let c = cog.to_str().unwrap();
    // validate: one finding that says what the file is and what to run instead.
    let (o, desc) = exec(d, CLIPTEX, &["validate", c]);
    assert_eq!(o.status.code(), Some(1), "{desc}");
    let text = said(&o);
    no_binary(&text, &desc);
    for w in
        ["a TIFF image (a GeoTIFF or COG), not a clip texture (.ct) configuration", "cliptex check", "cliptex info"]
    {
        assert!(text.contains(w), "should say `{w}`:\n{desc}");
    }
    assert_eq!(text.matches("error:").count(), 1, "one finding, not a cascade:\n{desc}");
    // roam flies the COG as clipmapd serves it.
    let (o, desc) =
        exec(d, CLIPTEX, &["roam", c, "--flight", "straight:4", "--frames", "4", "--wait-for-reads", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    no_binary(&said(&o), &desc);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}\n{desc}"));
    assert_eq!(v["size"], serde_json::json!([512, 512]), "{desc}");
    assert_eq!(v["frames"].as_array().map(Vec::len), Some(4), "{desc}");
    assert!(v["totals"]["tiles_read"].as_u64().unwrap() > 0, "{desc}");
    // plan sizes it: its size, texel bytes and clip size 1024.
    let (o, desc) = exec(d, CLIPTEX, &["plan", c, "--json"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}\n{desc}"));
    assert_eq!((v["width"].as_u64(), v["height"].as_u64()), (Some(512), Some(512)), "{desc}");
    assert_eq!(v["texel_bytes"], 3, "{desc}");
    // icache info of it is refused the same way.
    let (o, desc) = exec(d, env!("CARGO_BIN_EXE_icache"), &["info", c]);
    assert_eq!(o.status.code(), Some(1), "{desc}");
    no_binary(&said(&o), &desc);
    assert!(said(&o).contains("a TIFF image (a GeoTIFF or COG), not an image cache (.ic)"), "{desc}");
}

/// A `clipmapd` serving `args` with its names in `dir`: waits (bounded) until it answers, then
/// returns its `STATS` reply and its log (at `log_level`), and stops it.
#[cfg(feature = "remote")]
pub fn serve_once(dir: &Path, name: &str, args: &[&str], log_level: &str) -> (serde_json::Value, String) {
    serve_until(dir, name, args, log_level, |_| true)
}

/// [`serve_once`], waiting also for `done` of its STATS: a tile's texels can be in before the
/// request that brought them is counted (a merged range is counted when its stream ends).
pub fn serve_until(
    dir: &Path,
    name: &str,
    args: &[&str],
    log_level: &str,
    done: impl Fn(&serde_json::Value) -> bool,
) -> (serde_json::Value, String) {
    use std::io::{BufRead, BufReader, Write};
    use std::time::{Duration, Instant};
    let socket = dir.join(format!("{name}.sock"));
    let err = dir.join(format!("{name}.err"));
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_clipmapd"))
        .args(args)
        .args(["--clip", "128", "--tick-hz", "60", "--name", name, "--shm-dir"])
        .arg(dir)
        .arg("--socket")
        .arg(&socket)
        .env("RUST_LOG", log_level)
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&err).unwrap())
        .spawn()
        .unwrap();
    let log = || std::fs::read_to_string(&err).unwrap_or_default();
    let ask = |line: &str| -> Option<String> {
        let mut s = std::os::unix::net::UnixStream::connect(&socket).ok()?;
        s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
        writeln!(s, "{line}").ok()?;
        let mut reply = String::new();
        BufReader::new(s).read_line(&mut reply).ok()?;
        Some(reply.trim_end().to_string())
    };
    let t = Instant::now();
    let stats = loop {
        if let Ok(Some(st)) = child.try_wait() {
            panic!("clipmapd exited ({st}):\n{}", log());
        }
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "the service did not read a tile, or its STATS never showed what the test waits for:\n{}",
            log()
        );
        if let Some(r) = ask("STATS") {
            let v: serde_json::Value = serde_json::from_str(r.strip_prefix("OK ").unwrap_or("null")).unwrap();
            if v["engine"]["tiles_read"].as_u64().is_some_and(|n| n > 0) && done(&v) {
                break v;
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let _ = child.kill();
    let _ = child.wait();
    (stats, log())
}

#[cfg(feature = "remote")]
#[test]
fn a_cog_url_with_a_query_is_remote_everywhere_and_the_query_is_kept_in_every_request() {
    use crate::common::remote::PyServer;
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    small_cog(d, "c.tif");
    let server = PyServer::serve(d, true);
    let url = format!("{}/c.tif?sig=abc&x=1", server.url());
    // Before: every one of these took the URL for a local path ("No such file or directory").
    for args in [
        vec!["info", url.as_str()],
        vec!["check", url.as_str()],
        vec!["dump", url.as_str(), "--level", "1", "--out", "l1.png"],
        vec!["roam", url.as_str(), "--flight", "straight:4", "--frames", "2", "--wait-for-reads"],
    ] {
        let (o, desc) = exec(d, CLIPTEX, &args);
        assert_eq!(o.status.code(), Some(0), "{desc}");
    }
    let (o, desc) = exec(d, CLIPPREP, &["--input", &url, "--config-only", "--clip", "256", "--out", "cfg"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    let ct = std::fs::read_to_string(d.join("cfg/cfg.ct")).unwrap();
    assert!(ct.contains(&format!("#clipmap cog {url}")), "the configuration names the URL whole:\n{ct}");
    // Without --config-only a remote input is refused as such (before: "No such file").
    let (o, desc) =
        exec(d, CLIPPREP, &["--input", &url, "--tile", "128", "--clip", "256", "--format", "rgb8", "--out", "p2"]);
    assert_eq!(o.status.code(), Some(1), "{desc}");
    assert!(said(&o).contains("is a remote location") && said(&o).contains("--config-only"), "{desc}");
    let (o, desc) = exec(d, CLIPTEX, &["check", "cfg/cfg.ct"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    let (stats, log) =
        serve_until(d, "q", &[&url], "info", |v| v["remote"]["requests"].as_u64().is_some_and(|n| n >= 2));
    assert!(stats["remote"]["requests"].as_u64().unwrap() >= 2, "{stats}\n{log}");
    // Every request asked for the object with its query.
    let requests = server.requests();
    assert!(requests.len() > 10, "{requests:?}");
    for r in &requests {
        assert!(r.split(' ').nth(1) == Some("/c.tif?sig=abc&x=1"), "a request without the query: {r}\n{requests:?}");
    }
}

/// Runs `prog args` and returns what it said and its exit code, asserting that no secret of
/// `secrets` is in it.
#[cfg(feature = "remote")]
fn says_no_secret(dir: &Path, prog: &str, args: &[&str], secrets: &[&str]) -> (Option<i32>, String) {
    let (o, desc) = exec(dir, prog, args);
    let text = said(&o);
    for s in secrets {
        assert!(!text.contains(s), "`{s}` printed:\n{desc}");
    }
    (o.status.code(), text)
}

#[cfg(feature = "remote")]
#[test]
fn a_url_with_a_password_is_refused_without_printing_the_password_nor_a_signature_anywhere() {
    use crate::common::remote::PyServer;
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    small_cog(d, "c.tif");
    let server = PyServer::serve(d, true);
    let port = server.port;
    // A password: refused by every tool, the user kept and the password replaced.
    let with_password = format!("http://reader:hunter2@127.0.0.1:{port}/c.tif");
    let secrets = ["hunter2"];
    for (prog, args) in [
        (CLIPTEX, vec!["info", with_password.as_str()]),
        (CLIPTEX, vec!["check", with_password.as_str()]),
        (CLIPTEX, vec!["dump", with_password.as_str(), "--level", "0", "--out", "x.png"]),
        (CLIPTEX, vec!["roam", with_password.as_str(), "--flight", "hover", "--frames", "1"]),
        (env!("CARGO_BIN_EXE_clipmapd"), vec![with_password.as_str(), "--shm-dir", "."]),
        (CLIPPREP, vec!["--input", with_password.as_str(), "--config-only", "--clip", "256", "--out", "cfg"]),
    ] {
        // Before: "`http://reader:hunter2@127.0.0.1:.../c.tif` is not a usable remote location".
        let (code, text) = says_no_secret(d, prog, &args, &secrets);
        assert_eq!(code, Some(1), "{prog} {args:?}:\n{text}");
        assert!(text.contains("reader:***@127.0.0.1") && text.contains("credentials in the URL"), "{text}");
    }
    // Signatures in the query: requests carry them, nothing shown does.
    let signed =
        |path: &str| format!("http://127.0.0.1:{port}/{path}?X-Amz-Credential=AKIDSECRET&X-Amz-Signature=SIGSECRET");
    let secrets = ["AKIDSECRET", "SIGSECRET"];
    let missing = signed("none.tif");
    let (code, text) = says_no_secret(d, CLIPTEX, &["info", &missing], &secrets);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("X-Amz-Signature=***") && text.contains("not found"), "{text}");
    let url = signed("c.tif");
    for args in [
        vec!["info", url.as_str(), "--json"],
        vec!["info", url.as_str()],
        vec!["check", url.as_str()],
        vec!["check", url.as_str(), "--json"],
    ] {
        let (code, text) = says_no_secret(d, CLIPTEX, &args, &secrets);
        assert_eq!(code, Some(0), "{args:?}:\n{text}");
    }
    let (code, text) = says_no_secret(d, env!("CARGO_BIN_EXE_clipmapd"), &[&missing, "--shm-dir", "."], &secrets);
    assert_ne!(code, Some(0), "{text}");
    // A running service: its log (every read at debug level), STATS and attach.
    let (stats, log) = serve_once(d, "sig", &[&url], "debug");
    for s in secrets {
        assert!(!log.contains(s), "`{s}` in the log:\n{log}");
        assert!(!stats.to_string().contains(s), "`{s}` in STATS: {stats}");
    }
    assert!(server.requests().iter().any(|r| r.contains("X-Amz-Signature=SIGSECRET")), "the requests carry it");
}

#[cfg(feature = "remote")]
#[test]
fn a_server_that_ignores_range_is_said_once_in_the_log_and_counted_in_stats() {
    use crate::common::remote::PyServer;
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    small_cog(d, "c.tif");
    let warning = "the server ignores range requests";
    // A server that answers ranges: nothing said, nothing counted.
    let ranged = PyServer::serve(d, true);
    let (stats, log) = serve_once(d, "ranged", &[&format!("{}/c.tif", ranged.url())], "info");
    assert_eq!(stats["remote"]["ranges_ignored"], 0, "{stats}");
    assert!(!log.contains(warning), "{log}");
    // One that sends the whole file to every ranged GET: served right, but said once and counted.
    let whole = PyServer::serve(d, false);
    let url = format!("{}/c.tif", whole.url());
    let (stats, log) =
        serve_until(d, "whole", &[&url], "info", |v| v["remote"]["ranges_ignored"].as_u64().is_some_and(|n| n >= 2));
    // Before: used silently (29 to 46 times slower), `ranges_ignored` absent from STATS.
    let ignored = stats["remote"]["ranges_ignored"].as_u64().unwrap_or_else(|| panic!("{stats}"));
    assert!(ignored >= 2, "the open and a tile at least: {stats}");
    assert_eq!(log.matches(warning).count(), 1, "said once:\n{log}");
    assert!(log.contains("remote.ranges_ignored"), "{log}");
    // A tool reading it says so once too, and its report is right.
    let (o, desc) = exec(d, CLIPTEX, &["check", &url]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    assert_eq!(said(&o).matches(warning).count(), 1, "{desc}");
    assert!(whole.requests().iter().all(|r| !r.starts_with("GET") || !r.ends_with(" -")), "every GET was ranged");
}
