//! `clipgpu` end to end on whatever Vulkan adapter the machine has (lavapipe in CI): the real
//! binary against its own demo service and against the real `clipmapd` on the hash texture —
//! frames against the reference renderer, uploads against the strips, a restart, a level
//! disabled mid-flight, an upload budget, and bad input. A machine without a Vulkan driver fails
//! these tests with clipgpu's message saying how to install one.

#![forbid(unsafe_code)]

use serde_json::Value;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const CLIPGPU: &str = env!("CARGO_BIN_EXE_clipgpu");

/// The workspace's `clipmapd` (built beside this test's binaries; built here if it is not).
fn clipmapd() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().and_then(Path::parent).unwrap().to_path_buf();
    let bin = dir.join("clipmapd");
    if !bin.exists() {
        let st = Command::new(env!("CARGO"))
            .args(["build", "-p", "clipmap", "--bin", "clipmapd"])
            .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
            .status()
            .unwrap();
        assert!(st.success(), "building clipmapd for the tests failed");
    }
    assert!(bin.exists(), "no clipmapd at {}", bin.display());
    bin
}

/// A running `clipmapd` (`--source hash` unless told), killed on drop.
struct Service {
    child: Child,
    socket: PathBuf,
}

impl Service {
    fn start(dir: &Path, name: &str, extra: &[&str]) -> Service {
        Service::start_source(dir, name, "hash", extra)
    }

    /// A running `clipmapd --source SOURCE` (hash, terrain or heights).
    fn start_source(dir: &Path, name: &str, source: &str, extra: &[&str]) -> Service {
        Service::start_sized(dir, name, source, "8192", extra)
    }

    /// A running `clipmapd --source SOURCE --size SIZE`.
    fn start_sized(dir: &Path, name: &str, source: &str, size: &str, extra: &[&str]) -> Service {
        let socket = dir.join(format!("{name}.sock"));
        let mut args: Vec<String> =
            ["--source", source, "--size", size, "--clip", "256", "--tile", "64", "--tick-hz", "120"]
                .iter()
                .map(|s| s.to_string())
                .collect();
        args.extend(["--name".into(), name.into(), "--shm-dir".into(), dir.to_str().unwrap().into()]);
        args.extend(["--socket".into(), socket.to_str().unwrap().into()]);
        args.extend(extra.iter().map(|s| s.to_string()));
        let child = Command::new(clipmapd()).args(&args).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
        let s = Service { child, socket };
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(30) {
            if let Ok(mut c) = UnixStream::connect(&s.socket) {
                if writeln!(c, "PING").is_ok() {
                    let mut line = String::new();
                    let _ = BufReader::new(c).read_line(&mut line);
                    if line.starts_with("OK pong") {
                        return s;
                    }
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("clipmapd {args:?} did not answer on its socket within 30 s");
    }

    /// Waits until a renderer's requests have reached the service (clipgpu is flying).
    fn wait_for_requests(&self) {
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(30) {
            if let Ok(mut c) = UnixStream::connect(&self.socket) {
                if writeln!(c, "STATS").is_ok() {
                    let mut line = String::new();
                    let _ = BufReader::new(c).read_line(&mut line);
                    let stats: Value =
                        serde_json::from_str(line.trim_start_matches("OK ").trim()).unwrap_or(Value::Null);
                    if stats["requests_seen"].as_u64().unwrap_or(0) > 2 {
                        return;
                    }
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("no renderer's request reached the service within 30 s");
    }

    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        self.kill();
    }
}

fn clipgpu(args: &[&str]) -> Output {
    Command::new(CLIPGPU).args(args).output().unwrap()
}

/// Runs clipgpu with `--json`, asserts it succeeded and returns the JSON.
fn json(args: &[&str]) -> Value {
    let mut all = args.to_vec();
    all.push("--json");
    let out = clipgpu(&all);
    assert!(
        out.status.success(),
        "clipgpu {all:?} exited {:?}\nstderr:\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("clipgpu printed no JSON ({e}):\n{}", String::from_utf8_lossy(&out.stdout)))
}

fn frames(j: &Value) -> &Vec<Value> {
    j["per_frame"].as_array().expect("per_frame")
}

fn assert_within_tolerance(j: &Value) {
    assert_eq!(
        j["within_tolerance"],
        true,
        "off the texel edges: psnr_min {} max_error {}; at the GPU's coordinates: max error {}; coordinates: {} \
         of their bound (tolerance {}); per frame {}",
        j["psnr_min_off_edges"],
        j["max_error_off_edges"],
        j["max_error_at_gpu_coords"],
        j["coord_error_bound_ratio"],
        j["tolerance"],
        j["per_frame"]
    );
    // The checks ran on every ground pixel of every frame, and the geometry held its bound.
    assert!(j["pixels_compared_at_gpu_coords"].as_u64().unwrap() > 0, "{}", j["per_frame"]);
    let ratio = j["coord_error_bound_ratio"].as_f64().unwrap();
    assert!(ratio > 0.0 && ratio <= 1.0, "coordinates against their f32 bound: {ratio}");
    assert!(j["max_coord_error_texels"].as_f64().unwrap() < 0.01, "{}", j["max_coord_error_texels"]);
}

/// With point filtering the CPU sampler at the GPU's coordinates gives the GPU's frame on every
/// pixel of every frame, texel edges included.
fn assert_bit_exact_at_gpu_coords(j: &Value) {
    assert_eq!(j["pixels_differing_at_gpu_coords"], 0, "{}", j["per_frame"]);
    assert_eq!(j["max_error_at_gpu_coords"], 0);
    for f in frames(j) {
        let d = &f["diff"];
        assert!(
            d["at_gpu_coords"]["compared"].as_u64() >= d["geometry"]["compared"].as_u64(),
            "frame {}: every pixel that is ground for both is checked: {d}",
            f["frame"]
        );
    }
}

#[test]
fn the_demo_prints_its_json_and_matches_the_reference_renderer_within_the_strips() {
    let out = tempfile::tempdir().unwrap();
    let o = out.path().join("frames");
    let j = json(&["--demo", "--frames", "8", "--size", "128x96", "--out", o.to_str().unwrap()]);
    for key in [
        "adapter",
        "frames",
        "psnr_min",
        "max_error",
        "upload_bytes_per_frame",
        "theory_strip_bytes_per_frame",
        "pixels_differing_at_gpu_coords",
        "max_coord_error_texels",
        "max_lod_error",
    ] {
        assert!(j.get(key).is_some(), "no `{key}` in {j}");
    }
    assert!(!j["adapter"].as_str().unwrap().is_empty());
    assert_eq!(j["frames"], 8);
    assert_within_tolerance(&j);
    assert_eq!(j["frames_unsettled"], 0);
    assert!(j["theory_strip_bytes_per_frame"].as_f64().unwrap() > 0.0, "the flight moves");
    assert!(j["first_frame_upload_bytes"].as_u64().unwrap() > 0);
    // Whole tiles: within the tiles the entering strips touch, every frame.
    for f in frames(&j).iter().skip(1) {
        let u = &f["upload"];
        assert!(u["bytes"].as_u64() <= u["bound_bytes"].as_u64(), "frame {}: {u}", f["frame"]);
    }
    let img = image::open(o.join("gpu-007.png")).unwrap();
    assert_eq!((img.width(), img.height()), (128, 96));
    assert!(o.join("reference-007.png").exists());
}

#[test]
fn nearest_filtering_is_bit_exact_against_the_reference_on_the_hash_texture() {
    let dir = tempfile::tempdir().unwrap();
    let _s = Service::start(dir.path(), "near", &[]);
    let d = dir.path().to_str().unwrap();
    let j = json(&["--name", "near", "--shm-dir", d, "--filter", "point", "--frames", "6", "--size", "128x96"]);
    // Against the f64 reference: identical but where a pixel's footprint lies on a texel edge to
    // within f32 rounding.
    assert_within_tolerance(&j);
    assert_eq!(j["psnr_min_off_edges"], Value::Null, "{}", j["per_frame"]);
    assert_eq!(j["max_error_off_edges"], 0);
    assert!(j["pixels_at_edges"].as_u64().unwrap() <= 6, "{}", j["pixels_at_edges"]);
    // At the GPU's own coordinates: identical on every pixel, those included.
    assert_bit_exact_at_gpu_coords(&j);
    // This camera sees no sky: every pixel of the 6 frames was checked.
    assert_eq!(j["pixels_compared_at_gpu_coords"], 6 * 128 * 96);
}

#[test]
fn trilinear_frames_match_the_reference_on_the_hash_texture() {
    let dir = tempfile::tempdir().unwrap();
    let _s = Service::start(dir.path(), "tri", &[]);
    let d = dir.path().to_str().unwrap();
    let j = json(&["--name", "tri", "--shm-dir", d, "--frames", "6", "--size", "128x96", "--flight", "circle:300:12"]);
    assert_within_tolerance(&j);
    // The tolerance allows one unit at the GPU's coordinates for a driver that fuses the blends
    // into multiply-adds; lavapipe does not, and is bit-exact there too (docs/GPU.md).
    assert_eq!(j["pixels_differing_at_gpu_coords"], 0, "{}", j["per_frame"]);
    assert_eq!(j["frames_over_bound"], 0);
}

#[test]
fn rects_upload_exactly_the_entering_strips() {
    let dir = tempfile::tempdir().unwrap();
    let _s = Service::start(dir.path(), "rects", &[]);
    let d = dir.path().to_str().unwrap();
    let j = json(&["--name", "rects", "--shm-dir", d, "--upload", "rects", "--frames", "6", "--size", "128x96"]);
    assert_within_tolerance(&j);
    for f in frames(&j) {
        let u = &f["upload"];
        assert_eq!(u["bytes"], u["theory_bytes"], "frame {}: {u}", f["frame"]);
    }
}

#[test]
fn an_upload_budget_is_never_exceeded_and_the_frames_fall_back_until_the_tiles_arrive() {
    let dir = tempfile::tempdir().unwrap();
    let _s = Service::start(dir.path(), "budget", &[]);
    let d = dir.path().to_str().unwrap();
    let budget = 8 * 64 * 64 * 4;
    let b = budget.to_string();
    let j = json(&[
        "--name",
        "budget",
        "--shm-dir",
        d,
        "--upload-budget",
        &b,
        "--frames",
        "30",
        "--size",
        "128x96",
        "--flight",
        "hover",
        "--filter",
        "point",
    ]);
    assert_eq!(j["frames_over_budget"], 0);
    let fr = frames(&j);
    assert!(fr[0]["upload"]["over_budget"].as_u64().unwrap() > 0, "the first frame needs more than the budget");
    assert!(
        fr[0]["diff"]["max_error"].as_u64().unwrap() > 0,
        "without all its tiles the first frame is coarser than the reference"
    );
    let last = fr.last().unwrap();
    assert_eq!(last["upload"]["over_budget"], 0, "hovering, every tile has arrived by the last frame");
    assert_eq!(last["diff"]["max_error_off_edges"], 0, "{last}");
    // While tiles are late the frame is coarser than the reference, but exactly what the clipmap
    // rule gives over the tiles the GPU holds: bit-exact at its coordinates on every frame.
    assert_bit_exact_at_gpu_coords(&j);
}

#[test]
fn it_reattaches_when_clipmapd_restarts_and_keeps_matching() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = Service::start(dir.path(), "again", &[]);
    let d = dir.path().to_str().unwrap().to_string();
    let gpu = Command::new(CLIPGPU)
        .args(["--name", "again", "--shm-dir", &d, "--frames", "40", "--frame-ms", "40", "--size", "128x96", "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    s.wait_for_requests();
    s.kill();
    std::thread::sleep(Duration::from_millis(300));
    let _s2 = Service::start(dir.path(), "again", &[]);
    let out = gpu.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["frames"], 40);
    assert!(j["reattaches"].as_u64().unwrap() >= 1, "{}", j["reattaches"]);
    assert_within_tolerance(&j);
}

#[test]
fn a_level_disabled_mid_flight_falls_back_to_coarser_levels_with_no_stale_texels() {
    let dir = tempfile::tempdir().unwrap();
    // A tiny tick budget: after each jump the finer levels wait, disabled, for their tiles.
    let _s = Service::start(dir.path(), "jump", &["--budget-ms", "0.001"]);
    let d = dir.path().to_str().unwrap();
    let j = json(&[
        "--name",
        "jump",
        "--shm-dir",
        d,
        "--flight",
        "jump:3:1500",
        "--no-settle",
        "--frames",
        "12",
        "--size",
        "128x96",
    ]);
    assert!(j["frames_with_disabled_level"].as_u64().unwrap() >= 1, "{}", j["per_frame"]);
    assert_within_tolerance(&j);
}

#[test]
fn bad_input_and_a_service_that_never_comes_back_are_explained() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let out = clipgpu(&["--name", "nobody", "--shm-dir", d]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no service of that name") && err.contains("clipmap-nobody.map") && err.contains("clipmapd"),
        "{err}"
    );
    let out = clipgpu(&["--name", "x", "--frames", "zero"]);
    assert_eq!(out.status.code(), Some(1));
    let out = clipgpu(&["--demo", "--upload", "rects", "--upload-budget", "1000"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--upload tiles"));
    let out = clipgpu(&["--demo", "--flight", "sideways:3"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown flight"));
    let out = clipgpu(&[]);
    assert_eq!(out.status.code(), Some(1), "neither --name nor --demo");

    let mut s = Service::start(dir.path(), "gone", &[]);
    let gpu = Command::new(CLIPGPU)
        .args([
            "--name",
            "gone",
            "--shm-dir",
            d,
            "--frames",
            "200",
            "--frame-ms",
            "20",
            "--size",
            "64x48",
            "--reattach-s",
            "1",
            "--no-compare",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    s.wait_for_requests();
    s.kill();
    let out = gpu.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("stopped at frame") && err.contains("--reattach-s"), "{err}");
}

#[test]
fn a_gpu_validation_error_is_an_error_message_and_exit_status_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let _s = Service::start(dir.path(), "big", &[]);
    let d = dir.path().to_str().unwrap();
    // Wider than any adapter's textures (lavapipe's limit is 16384): wgpu's validation refuses
    // the render target.
    let out = clipgpu(&["--name", "big", "--shm-dir", d, "--size", "40000x2", "--frames", "1", "--no-compare"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        err.contains("drawing a frame of 40000x2 pixels failed") && err.contains("validation error"),
        "where and what: {err}"
    );
    assert!(err.contains("use a smaller --size") && err.contains("at most"), "how to fix: {err}");
}

#[test]
fn a_16_bit_texture_uploads_as_rgba16_and_samples_exactly() {
    // --out: the demo writes its pictures somewhere, by default into the working directory.
    let out = tempfile::tempdir().unwrap();
    let o = out.path().to_str().unwrap();
    let j = json(&[
        "--demo",
        "--demo-format",
        "rgba16",
        "--filter",
        "point",
        "--frames",
        "3",
        "--size",
        "96x64",
        "--out",
        o,
    ]);
    assert_eq!(j["texture"]["bytes_per_texel"], 8);
    assert_within_tolerance(&j);
    assert_bit_exact_at_gpu_coords(&j);
    assert_eq!(j["max_error_off_edges"], 0);
    // L16 and RGB8 widen to four components (L, L, L, 1) and (R, G, B, 1), as the CPU decodes them.
    for (format, bytes) in [("l16", 2), ("rgb8", 3)] {
        let j = json(&["--demo", "--demo-format", format, "--frames", "3", "--size", "96x64", "--out", o]);
        assert_eq!(j["texture"]["bytes_per_texel"], bytes);
        assert_within_tolerance(&j);
        assert_eq!(j["pixels_differing_at_gpu_coords"], 0, "{format}: {}", j["per_frame"]);
        assert!(j["theory_strip_bytes_per_frame"].as_f64().unwrap() > 0.0);
    }
}

/// The upload's bytes of every frame: (sent to the GPU, the same texels as RGBA8).
fn upload_bytes(j: &Value) -> Vec<(u64, u64)> {
    frames(j)
        .iter()
        .map(|f| (f["upload"]["gpu_bytes"].as_u64().unwrap(), f["upload"]["rgba8_bytes"].as_u64().unwrap()))
        .collect()
}

#[test]
fn block_compressed_textures_upload_their_blocks_and_match_the_reference_decoded_independently() {
    // The same hash texture and flight as RGBA8, BC1 and BC7 (`clipmapd --format`): the blocks go
    // to the GPU as they are where the adapter has BC textures (lavapipe has), the reference
    // decodes them with bcdec_rs, and the frames are held to the criteria of the uncompressed ones.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let run = |name: &str, extra: &[&str]| {
        let mut a = vec!["--name", name, "--shm-dir", d, "--frames", "6", "--size", "128x96"];
        a.extend_from_slice(extra);
        json(&a)
    };
    let _plain = Service::start(dir.path(), "plain", &[]);
    let plain = run("plain", &["--filter", "point"]);
    assert_bit_exact_at_gpu_coords(&plain);
    assert_eq!(plain["texture"]["block_upload"], Value::Null);
    let plain_bytes: u64 = upload_bytes(&plain).iter().map(|b| b.0).sum();
    assert!(plain_bytes > 0);
    for (bc, ratio) in [("bc1", 8), ("bc7", 4)] {
        let _s = Service::start(dir.path(), bc, &["--format", bc, "--bc-quality", "fast"]);
        let j = run(bc, &["--filter", "point"]);
        assert_eq!(j["texture"]["format"], bc);
        let gpu = j["texture"]["block_upload"].as_str().unwrap();
        if gpu == "gpu" {
            let want = if bc == "bc1" { "Bc1RgbaUnorm" } else { "Bc7RgbaUnorm" };
            assert_eq!(j["texture"]["gpu_format"], want);
            // Counted by the client, frame by frame: an eighth (BC1) or a quarter (BC7) of what
            // the same tiles cost as RGBA8, and of what the RGBA8 service's same flight sent.
            // Frame 0 also uploads the pyramid's 2 x 2 and 1 x 1 tops, a whole block each
            // (RGBA8: 16 and 4 bytes).
            let block = if bc == "bc1" { 8 } else { 16 };
            let bytes = upload_bytes(&j);
            assert_eq!((bytes[0].0 - 2 * block) * ratio, bytes[0].1 - 20, "{bc} frame 0");
            for (n, &(sent, rgba8)) in bytes.iter().enumerate().skip(1) {
                assert_eq!(sent * ratio, rgba8, "{bc} frame {n}");
            }
            assert!(bytes.iter().skip(1).any(|b| b.0 > 0), "{bc}: the flight uploads after frame 0");
            assert_eq!(j["upload_bytes_vs_rgba8"].as_f64(), Some(1.0 / ratio as f64));
            let sent: u64 = bytes.iter().map(|b| b.0).sum();
            assert_eq!((sent - 2 * block) * ratio, plain_bytes - 20, "{bc}: bytes against the RGBA8 flight's");
        } else {
            assert_eq!(gpu, "cpu", "{}", j["texture"]);
        }
        assert_within_tolerance(&j);
        if bc == "bc7" || gpu == "cpu" {
            // BC7's decode is specified in integers: the GPU's equals bcdec_rs's, so the frames
            // are held to the uncompressed texture's criteria.
            assert_bit_exact_at_gpu_coords(&j);
            assert_eq!(j["max_error_off_edges"], 0);
        } else {
            // BC1 leaves the rounding of its interpolated colours to the implementation: within
            // the decoding tolerance of bcdec_rs's (docs/GPU.md, "Block-compressed textures"),
            // and not everywhere identical (the comparison does see the GPU's own decode).
            assert_eq!(j["tolerance"]["sampling_max_error"], 2, "{}", j["tolerance"]);
            assert!(j["max_error_at_gpu_coords"].as_u64().unwrap() <= 2, "{}", j["per_frame"]);
        }
        let j = run(bc, &["--flight", "circle:300:12"]);
        assert_within_tolerance(&j);
        if bc == "bc7" || gpu == "cpu" {
            assert_eq!(j["pixels_differing_at_gpu_coords"], 0, "{bc}: {}", j["per_frame"]);
        }
        // Decoded on the CPU instead (as on an adapter without BC textures): said so, RGBA8 sent,
        // the same frames.
        let out = clipgpu(&[
            "--name",
            bc,
            "--shm-dir",
            d,
            "--frames",
            "3",
            "--size",
            "96x64",
            "--decode-blocks-on-cpu",
            "--filter",
            "point",
            "--json",
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{err}");
        assert!(err.contains("no BC textures") && err.contains("decoding the") && err.contains("on the CPU"), "{err}");
        let j: Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(j["texture"]["block_upload"], "cpu");
        assert_eq!(j["texture"]["gpu_format"], "Rgba8Uint");
        assert_eq!(j["upload_bytes_vs_rgba8"].as_f64(), Some(1.0));
        assert_within_tolerance(&j);
        assert_bit_exact_at_gpu_coords(&j);
        // Rects cut texels out of tiles: refused for blocks, saying what to use.
        let out = clipgpu(&["--name", bc, "--shm-dir", d, "--frames", "1", "--upload", "rects"]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains("block-compressed") && err.contains("--upload tiles"), "{err}");
    }
}

#[test]
fn without_a_vulkan_driver_the_error_says_how_to_get_one() {
    let out = Command::new(CLIPGPU)
        .args(["--demo"])
        .env("VK_ICD_FILENAMES", "/nonexistent/none.json")
        .env("VK_DRIVER_FILES", "/nonexistent/none.json")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("no Vulkan adapter") && err.contains("mesa-vulkan-drivers"), "{err}");
}

/// The distinct colours of a picture.
fn colours(path: &Path) -> std::collections::HashSet<[u8; 4]> {
    image::open(path).unwrap().to_rgba8().pixels().map(|p| p.0).collect()
}

/// Every ground pixel's height within its f32 bound of the CPU's at the GPU's coordinates, the
/// two agreeing on every pixel without data, and some of those (the verification texture has
/// nodata in one texel in sixteen).
fn assert_heights_match(j: &Value) {
    let h = &j["heights"];
    assert!(h["compared"].as_u64().unwrap() > 1000, "{h}");
    assert_eq!(h["mismatch"], 0, "{h}");
    assert_eq!(h["outside_bound"], 0, "{h}");
    assert!(h["nodata"].as_u64().unwrap() > 0, "nodata pixels, shown by both: {h}");
    assert!(h["bound_ratio"].as_f64().unwrap() <= 1.0, "{h}");
    // Every frame was checked, and every ground pixel of it.
    for f in frames(j) {
        let d = &f["diff"];
        let hd = &d["heights"];
        let checked =
            hd["compared"].as_u64().unwrap() + hd["nodata"].as_u64().unwrap() + hd["nothing"].as_u64().unwrap();
        assert_eq!(Some(checked), d["at_gpu_coords"]["compared"].as_u64(), "frame {}: {d}", f["frame"]);
    }
    // The colour of each pixel is the false colour of the GPU's own height.
    assert_eq!(j["pixels_differing_at_gpu_coords"], 0, "{}", j["per_frame"]);
}

#[test]
fn a_height_texture_is_drawn_in_false_colour_and_its_heights_match_the_reference() {
    let out = tempfile::tempdir().unwrap();
    let o = out.path().to_str().unwrap();
    let j = json(&["--demo", "--demo-format", "heights", "--frames", "3", "--size", "96x64", "--out", o]);
    assert_eq!(j["texture"]["bytes_per_texel"], 4);
    assert_eq!(j["texture"]["heights"]["format"]["storage"], "f32", "{}", j["texture"]);
    assert_eq!(j["texture"]["heights"]["range"], serde_json::json!([-11000.0, 8900.0]));
    assert_within_tolerance(&j);
    assert_heights_match(&j);
    // Trilinear: blended heights, so not all exact, but within the bound.
    assert!(j["heights"]["max_error_m"].as_f64().unwrap() > 0.0, "{}", j["heights"]);
    // Texels go up as published: the upload counts 4 bytes a texel.
    let first_l32f = j["first_frame_upload_bytes"].as_u64().unwrap();
    assert!(first_l32f > 0 && first_l32f.is_multiple_of(4), "{first_l32f}");
    // Not uniform: many false colours, and the colour of nodata (magenta) among them.
    let c = colours(&out.path().join("gpu-002.png"));
    assert!(c.len() > 100, "{} distinct colours", c.len());
    assert!(c.contains(&[255, 0, 255, 255]), "no nodata pixel drawn");
    assert!(!c.contains(&[0, 0, 0, 255]), "every level was published: no black ground");

    // Point filtering: each height is a texel as published, exactly.
    let j =
        json(&["--demo", "--demo-format", "l32f", "--filter", "point", "--frames", "2", "--size", "96x64", "--out", o]);
    assert_within_tolerance(&j);
    assert_heights_match(&j);
    assert_eq!(j["heights"]["max_error_m"], 0.0, "{}", j["heights"]);

    // l16i converted to metres on upload (2 bytes a texel published, counted as such), over a
    // range of its own.
    let j = json(&[
        "--demo",
        "--demo-format",
        "l16i",
        "--height-range",
        "-2000,2000",
        "--frames",
        "2",
        "--size",
        "96x64",
        "--out",
        o,
    ]);
    assert_eq!(j["texture"]["bytes_per_texel"], 2);
    assert_eq!(j["texture"]["heights"]["range"], serde_json::json!([-2000.0, 2000.0]));
    // The same tiles as l32f's first frame, at 2 bytes a texel as published.
    assert_eq!(j["first_frame_upload_bytes"].as_u64().unwrap() * 2, first_l32f);
    assert_within_tolerance(&j);
    assert_heights_match(&j);
}

#[test]
fn the_height_verification_texture_of_clipmapd_matches_in_metres() {
    let dir = tempfile::tempdir().unwrap();
    let _s = Service::start_source(dir.path(), "dem", "heights", &[]);
    let d = dir.path().to_str().unwrap();
    let j = json(&["--name", "dem", "--shm-dir", d, "--frames", "3", "--size", "96x64", "--filter", "bilinear"]);
    assert_eq!(j["texture"]["heights"]["format"]["nodata"], -32768.0, "{}", j["texture"]);
    assert_within_tolerance(&j);
    assert_heights_match(&j);
}

#[test]
fn a_format_clipgpu_does_not_draw_is_refused_naming_what_it_found_and_what_it_accepts() {
    use clipmap::source::{HashSource, TextureDesc};
    use clipmap::texel::TexelFormat;
    use std::sync::Arc;
    // Packed RGB565, and 32-bit floats whose heights block says they are not heights.
    for (format, found) in [(TexelFormat::RGB565, "rgb565"), (TexelFormat::L32F, "l32f is drawn only as heights")] {
        let desc = TextureDesc::new([4096, 4096], 256, format, [64, 64]).unwrap();
        let name = format!("refused-{}", format.short_name());
        let out = clipgpu::demo::with_service(Arc::new(HashSource::new(desc)), &name, |dir, name| {
            Ok(clipgpu(&["--name", name, "--shm-dir", dir.to_str().unwrap(), "--frames", "1"]))
        })
        .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains(&format!("clipmap-{name}.map")), "where: {err}");
        assert!(err.contains(found), "what it found: {err}");
        assert!(err.contains("RGBA16") && err.contains("l32f, l16 or l16i") && err.contains("heights block"), "{err}");
    }
    // A height range for a colour texture.
    let out = clipgpu(&["--demo", "--height-range", "0,100", "--frames", "1", "--size", "32x32", "--no-compare"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("--height-range 0,100") && err.contains("serves colour"), "{err}");
    let out = clipgpu(&["--demo", "--demo-format", "heights", "--height-range", "5,5"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("expected MIN,MAX"), "{err}");
}

/// Sends one line to the service's socket and returns the reply line.
fn ask(socket: &Path, line: &str) -> String {
    let mut c = UnixStream::connect(socket).unwrap();
    writeln!(c, "{line}").unwrap();
    let mut reply = String::new();
    BufReader::new(c).read_line(&mut reply).unwrap();
    reply.trim_end().to_string()
}

#[test]
fn a_further_view_is_drawn_and_moved_bit_exact_while_main_stays_and_an_unknown_view_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    // A view `side`; grids widened so that it and main, 700 texels apart, are both held whole.
    let s = Service::start(dir.path(), "views", &["--view", "side", "--view-spread", "1024"]);
    let d = dir.path().to_str().unwrap();
    let views = |s: &Service| -> Value {
        serde_json::from_str(ask(&s.socket, "VIEWS").strip_prefix("OK ").expect("VIEWS answers OK")).unwrap()
    };
    // A view's centre is `null` until the first tick applies it.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    let mut main_before = views(&s)[0]["centre"].clone();
    while main_before.is_null() && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(10));
        main_before = views(&s)[0]["centre"].clone();
    }
    assert_eq!(main_before, serde_json::json!([4096, 4096]), "{}", views(&s));
    let args = [
        "--name",
        "views",
        "--shm-dir",
        d,
        "--view",
        "side",
        "--start",
        "4800,4096",
        "--flight",
        "straight:8:90",
        "--filter",
        "point",
        "--frames",
        "6",
        "--size",
        "128x96",
    ];
    let j = json(&args);
    // Every frame drew the view's own snapshot, settled at its own centre, and matched the
    // reference on it: identical off the texel edges, identical on every pixel at the GPU's
    // coordinates.
    assert_eq!(j["frames_unsettled"], 0, "{}", j["per_frame"]);
    assert_within_tolerance(&j);
    assert_eq!(j["max_error_off_edges"], 0);
    assert_bit_exact_at_gpu_coords(&j);
    assert_eq!(j["pixels_compared_at_gpu_coords"], 6 * 128 * 96);
    let last = frames(&j).last().unwrap()["centre"].clone();
    assert_eq!(last[0], 4800, "the flight goes along T: {last}");
    // The requests moved `side`, not main.
    let after = views(&s);
    assert_eq!(after[1]["name"], "side", "{after}");
    assert_eq!(after[1]["centre"], last, "{after}");
    assert_eq!(after[0]["centre"], main_before, "main stays where it was: {after}");
    // An unknown view: the readers' error, naming the views there are (exit 2, as they exit).
    let out = clipgpu(&["--name", "views", "--shm-dir", d, "--view", "nobody", "--frames", "1"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--view nobody") && err.contains("no view `nobody`: the service publishes main, side"),
        "{err}"
    );
    // A name no view may have is bad input.
    let out = clipgpu(&["--name", "views", "--shm-dir", d, "--view", "a/b"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("--view a/b") && err.contains("expected 1 to 31 of"), "{err}");
}

#[test]
fn a_flight_across_the_antimeridian_of_a_global_texture_shows_no_seam_and_stays_bit_exact() {
    // Eastwards from 42 texels west of the east edge of an 8192-wide texture: the camera looks
    // across the edge every frame, and the eye crosses it.
    let args = |name: &'static str, d: &'static str| {
        vec![
            "--name",
            name,
            "--shm-dir",
            d,
            "--filter",
            "point",
            "--frames",
            "6",
            "--size",
            "128x96",
            "--start",
            "8150,4096",
            "--flight",
            "straight:8:0",
        ]
    };
    let dir = tempfile::tempdir().unwrap();
    let _s = Service::start(dir.path(), "globe", &["--global"]);
    let d: &'static str = Box::leak(dir.path().to_str().unwrap().to_string().into_boxed_str());
    let j = json(&args("globe", d));
    assert_within_tolerance(&j);
    assert_bit_exact_at_gpu_coords(&j);
    // No sky past the antimeridian: every pixel of every frame is ground, sampled at s mod width.
    assert_eq!(j["pixels_compared_at_gpu_coords"], 6 * 128 * 96, "{}", j["per_frame"]);
    // The same texture not marked global ends at its edge: sky past it.
    let flat = tempfile::tempdir().unwrap();
    let _f = Service::start(flat.path(), "flat", &[]);
    let d: &'static str = Box::leak(flat.path().to_str().unwrap().to_string().into_boxed_str());
    let j = json(&args("flat", d));
    assert_bit_exact_at_gpu_coords(&j);
    assert!(j["pixels_compared_at_gpu_coords"].as_u64().unwrap() < 6 * 128 * 96, "sky past the edge");
}

/// docs/GPU.md, "Exact at 2^30 texels a side": a flight through `clipmapd` on the hash texture
/// 2^30 texels a side (WebMercatorQuad zoom 22 at 256-texel tiles, georeferenced as the Web
/// Mercator square, so it wraps in longitude), drawn by the GPU client at the origin and at the far
/// corner, there also across the antimeridian: the frames equal the reference renderer's by the
/// same criteria at every place, point filtering bit-exact at the GPU's coordinates and identical
/// off the texel edges, trilinear bit-exact at the GPU's coordinates.
#[test]
fn at_2_30_texels_a_side_the_frames_equal_the_reference_at_the_far_corner_as_at_the_origin() {
    let n = 1u64 << 30;
    let dir = tempfile::tempdir().unwrap();
    let size = n.to_string();
    let _s = Service::start_sized(dir.path(), "huge", "hash", &size, &["--georef", "web-mercator"]);
    let d = dir.path().to_str().unwrap();
    let far = (n - 200).to_string();
    let seam_t = (n - 300).to_string();
    let seam_s = (n - 42).to_string();
    // (where, start, flight): the origin looking north-east into the texture, the far corner
    // looking back south-west the same way, and the far corner's east edge flown across eastwards.
    let places = [
        ("origin", "200,200".to_string(), "straight:8:30"),
        ("far corner", format!("{far},{far}"), "straight:8:210"),
        ("antimeridian at the far corner", format!("{seam_s},{seam_t}"), "straight:8:0"),
    ];
    let mut pixels_at_edges = Vec::new();
    for (place, start, flight) in &places {
        let j = json(&[
            "--name",
            "huge",
            "--shm-dir",
            d,
            "--filter",
            "point",
            "--frames",
            "6",
            "--size",
            "128x96",
            "--start",
            start,
            "--flight",
            flight,
        ]);
        assert_eq!(j["frames_unsettled"], 0, "{place}: {}", j["per_frame"]);
        assert_within_tolerance(&j);
        assert_eq!(j["psnr_min_off_edges"], Value::Null, "{place}: {}", j["per_frame"]);
        assert_eq!(j["max_error_off_edges"], 0, "{place}");
        assert_bit_exact_at_gpu_coords(&j);
        // No sky anywhere: every pixel of the 6 frames was ground, checked at the GPU's coordinates.
        assert_eq!(j["pixels_compared_at_gpu_coords"], 6 * 128 * 96, "{place}: {}", j["per_frame"]);
        let first = frames(&j)[0]["centre"].clone();
        let want: Vec<i64> = start.split(',').map(|c| c.parse().unwrap()).collect();
        assert_eq!(first, serde_json::json!(want), "{place}: the flight starts where asked");
        pixels_at_edges.push(j["pixels_at_edges"].as_u64().unwrap());
    }
    // Pixels whose footprint lies on a texel edge to within f32 rounding (where the f64 reference
    // may pick the neighbour): as few at the far corner as at the origin.
    assert!(pixels_at_edges.iter().all(|&e| e <= 6), "{pixels_at_edges:?}");
    // Trilinear at the far corner: bit-exact at the GPU's coordinates as at the origin.
    for start in ["200,200".to_string(), format!("{far},{far}")] {
        let flight = if start.starts_with("200,") { "straight:8:30" } else { "straight:8:210" };
        let j = json(&[
            "--name",
            "huge",
            "--shm-dir",
            d,
            "--frames",
            "4",
            "--size",
            "128x96",
            "--start",
            &start,
            "--flight",
            flight,
        ]);
        assert_within_tolerance(&j);
        assert_eq!(j["pixels_differing_at_gpu_coords"], 0, "{start}: {}", j["per_frame"]);
        assert_eq!(j["frames_over_bound"], 0, "{start}");
    }
}

/// docs/GPU.md, "Heights", on a texture that wraps in longitude: the height verification texture
/// of `clipmapd --global` flown across its east edge. The CPU height reference takes columns
/// modulo the width as the shader does, so every pixel is ground and every height agrees across
/// the antimeridian, as the same flight's colours do (above).
#[test]
fn heights_across_the_antimeridian_of_a_global_texture_match_the_cpu_reference_with_no_seam() {
    let dir = tempfile::tempdir().unwrap();
    let _s = Service::start_source(dir.path(), "demglobe", "heights", &["--global"]);
    let d = dir.path().to_str().unwrap();
    for filter in ["point", "bilinear"] {
        let j = json(&[
            "--name",
            "demglobe",
            "--shm-dir",
            d,
            "--filter",
            filter,
            "--frames",
            "6",
            "--size",
            "96x64",
            "--start",
            "8160,4096",
            "--flight",
            "straight:8:0",
        ]);
        assert_within_tolerance(&j);
        assert_heights_match(&j);
        // No sky past the antimeridian: every pixel was ground and checked.
        assert_eq!(j["pixels_compared_at_gpu_coords"], 6 * 96 * 64, "{filter}: {}", j["per_frame"]);
        assert!(frames(&j).last().unwrap()["centre"][0].as_i64().unwrap() >= 8192, "the eye crossed the edge");
    }
}
