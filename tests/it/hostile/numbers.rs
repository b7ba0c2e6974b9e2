//! Numbers from a user (options, socket commands, configuration values), each out of its bound.

use super::service::{fails, place, Service, CLIPMAPD, CLIPTEX, HASH};

fn clipmapd_with(d: &std::path::Path, extra: &[&str]) -> Vec<String> {
    let mut a: Vec<String> = HASH.iter().map(|s| s.to_string()).collect();
    a.extend(place(d, "n"));
    a.extend(extra.iter().map(|s| s.to_string()));
    a
}

fn refused(extra: &[&str], words: &[&str]) {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let a = clipmapd_with(d, extra);
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    fails(d, CLIPMAPD, &a, 1, words);
    assert!(!d.join("clipmap-n.map").exists(), "nothing published");
}

#[test]
fn max_connections_near_2_pow_64_is_refused_naming_the_bound() {
    refused(&["--max-connections", "18446744073709551615"], &["--max-connections", "expected 1 to 4096"]);
    refused(&["--max-connections", "0"], &["--max-connections", "expected 1 to 4096"]);
}

#[test]
fn a_budget_that_rounds_to_zero_is_refused() {
    refused(&["--budget-ms", "0.0000001"], &["--budget-ms", "at least 0.001"]);
    refused(&["--budget-ms", "0"], &["--budget-ms", "at least 0.001"]);
}

#[test]
fn a_budget_that_rounds_to_zero_is_refused_on_the_socket_too() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let s = Service::start(d, "b", &HASH, &[]);
    let r = super::service::ask(&s.socket, "BUDGET 0.0000001");
    assert!(r.starts_with("ERR") && r.contains("0.001"), "{r}");
    assert!(s.alive());
}

#[test]
fn tile_1_on_a_procedural_texture_is_refused_before_it_multiplies() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let mut a = clipmapd_with(d, &[]);
    let i = a.iter().position(|x| x == "--tile").unwrap();
    a[i + 1] = "1".into();
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    fails(d, CLIPMAPD, &a, 1, &["MAX_GRID_TILES", "choose larger tiles"]);
    fails(
        d,
        CLIPTEX,
        &[
            "roam",
            "--source",
            "hash",
            "--size",
            "65536",
            "--clip",
            "1024",
            "--tile",
            "1",
            "--flight",
            "straight:1",
            "--frames",
            "2",
        ],
        1,
        &["MAX_GRID_TILES"],
    );
}

#[test]
fn roam_frames_huge_is_refused_without_preallocating() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    fails(
        d,
        CLIPTEX,
        &[
            "roam",
            "--source",
            "hash",
            "--size",
            "4096",
            "--clip",
            "256",
            "--flight",
            "straight:1",
            "--frames",
            "18446744073709551615",
        ],
        1,
        &["--frames", "MAX_ROAM_FRAMES"],
    );
}

#[test]
fn a_tile_size_of_65536_squared_is_refused_by_validate_and_the_service_alike() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let ct = d.join("huge.ct");
    std::fs::write(
        &ct,
        "ct_version2.0\next_format PFTEX_PACK_8\nint_format PFTEX_RGB_8\nimg_format PFTEX_RGB\nvirt_size 1048576 1048576 1\nclip_size 1024\ntile_format t.%d.r%d.c%d.raw\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S\ntile_size 65536 65536 1\n",
    )
    .unwrap();
    let c = ct.to_str().unwrap();
    let out = fails(d, CLIPTEX, &["validate", c], 1, &["cannot be served", "MAX_TILE_BYTES"]);
    assert!(out.contains("invalid"), "{out}");
    let e = fails(d, CLIPMAPD, &[c, "--shm-dir", d.to_str().unwrap(), "--name", "h"], 1, &["MAX_TILE_BYTES"]);
    assert!(!e.contains("memory allocation"), "{e}");
}

#[test]
fn a_centre_at_the_ends_of_i64_on_the_socket_is_clamped_not_a_crash() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let s = Service::start(d, "c", &HASH, &[]);
    for line in [
        "CENTRE -9223372036854775808 9223372036854775807",
        "CENTRE 9223372036854775807 -9223372036854775808",
        "CENTRE 0 0",
    ] {
        let r = super::service::ask(&s.socket, line);
        assert!(r.starts_with("OK"), "{line}: {r}");
        s.wait_ticks(2); // a whole tick with that centre
        assert!(s.alive(), "{line}: {}", std::fs::read_to_string(&s.err).unwrap_or_default());
    }
}

#[test]
fn a_max_memory_that_overflows_into_bytes_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let out = d.join("o");
    let o = out.to_str().unwrap();
    let base = ["--source", "hash", "--size", "256", "--tile", "64", "--clip", "64", "--format", "rgb8", "--out", o];
    for bad in ["18446744073709551615", "0"] {
        let args: Vec<&str> = base.iter().copied().chain(["--max-memory", bad]).collect();
        fails(d, super::service::CLIPPREP, &args, 1, &["--max-memory", "16777216"]);
    }
    assert!(!out.exists());
}

#[test]
fn a_clipprep_size_beyond_2_pow_26_is_refused_not_an_overflow() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let out = d.join("o");
    let args =
        ["--source", "hash", "--size", "1099511627776", "--tile", "64", "--clip", "64", "--format", "l8", "--out"];
    let args: Vec<&str> = args.iter().copied().chain([out.to_str().unwrap()]).collect();
    let err = fails(d, super::service::CLIPPREP, &args, 1, &["MAX_TEXTURE_SIZE"]);
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out.exists());
}

#[test]
fn a_clip_size_whose_windows_exceed_the_limit_is_refused_before_anything_is_created() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let mut a = clipmapd_with(d, &[]);
    for (opt, v) in [("--size", "67108864"), ("--clip", "67108864"), ("--tile", "128")] {
        let i = a.iter().position(|x| x == opt).unwrap();
        a[i + 1] = v.into();
    }
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    fails(d, CLIPMAPD, &a, 1, &["the image caches need", "the limit is"]);
    let left: Vec<_> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(left.is_empty(), "nothing created in the shared directory: {left:?}");
}

#[test]
fn plan_with_a_size_past_the_last_power_of_two_names_a_real_one() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let err = fails(d, CLIPTEX, &["plan", "--size", "18446744073709551615", "--clip", "1024"], 1, &["power of two"]);
    assert!(err.contains("9223372036854775808 (2^63, the largest)") && !err.contains("0 or 0"), "{err}");
}
