//! A growing texture's georeferencing from its patches' grid (docs/GEOREF.md, "Growing
//! textures"): a store created with `cliptex grow create --crs EPSG:CODE` keeps its world
//! coordinates (the origin, the patches' boxes) as map coordinates of that CRS, and `clipmapd
//! --growing` publishes the frame's transform in the mapping: level 0's texel (s, t) where the grid
//! puts it, each level's terms level 0's doubled. A store without a CRS publishes none, and
//! `cliptex grow status` says so.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn cliptex(args: &[&str], dir: &Path) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).args(args).current_dir(dir).output().unwrap();
    assert!(
        out.status.success(),
        "cliptex {args:?}: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `clipmapd --growing STORE --size 512 --clip 64` as `name`, and its mapping.
// The child is waited for on every path: by the caller once returned, here before the panic when
// no mapping appears.
#[allow(clippy::zombie_processes)]
fn serve(dir: &Path, store: &str, name: &str) -> (Child, clipmap::shm::Client) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_clipmapd"))
        .current_dir(dir)
        .args(["--growing", store, "--size", "512", "--clip", "64", "--tick-hz", "120", "--name", name])
        .args(["--shm-dir", dir.to_str().unwrap(), "--socket", dir.join(format!("{name}.sock")).to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t = Instant::now();
    loop {
        if let Ok(c) = clipmap::shm::Client::attach(dir, name) {
            return (child, c);
        }
        if t.elapsed() > Duration::from_secs(30) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("clipmapd --growing {store}: no mapping within 30 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_growing_texture_created_in_a_crs_publishes_its_grids_transform_and_one_without_publishes_none() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // UTM zone 33N, 10 m texels (0.1 texels a metre), the grid's origin at (400000, 4700000).
    cliptex(&["grow", "create", "utm", "--origin", "400000,4700000", "--texels-per-unit", "0.1", "--tile", "16"], d);
    let made = cliptex(
        &[
            "grow",
            "create",
            "utm33",
            "--origin",
            "400000,4700000",
            "--texels-per-unit",
            "0.1",
            "--tile",
            "16",
            "--crs",
            "EPSG:32633",
        ],
        d,
    );
    assert!(made.contains("georef EPSG:32633"), "{made}");
    let status: serde_json::Value = serde_json::from_str(&cliptex(&["grow", "status", "utm33", "--json"], d)).unwrap();
    assert_eq!(status["epsg"], 32633, "{status}");
    let plain = cliptex(&["grow", "status", "utm"], d);
    assert!(plain.contains("georef none (the world units are the grid's own"), "{plain}");

    let (mut child, c) = serve(d, "utm33", "g33");
    let g = c.georef.clone().expect("the grid's CRS gives the frame a georef block");
    assert_eq!(g.epsg, Some(32633));
    // The frame (512 texels a side) is centred on the grid's origin: its south-west corner lies
    // 256 texels (2560 m) west and south of it, its north-west corner 5120 m north of that.
    assert_eq!(g.origin, [400000.0 - 2560.0, 4700000.0 - 2560.0 + 5120.0]);
    for (k, terms) in g.levels.iter().enumerate() {
        let f = 10.0 * (1u64 << k) as f64;
        assert_eq!(*terms, [f, 0.0, 0.0, -f], "level {k}");
    }
    // Frame texel (256, 256)'s lower corner is the grid's origin, and texel (256 + i, 256 + j)'s
    // lower corner is the origin plus (i, j) texels of 10 m: where the grid puts level-0 texel
    // (i, j) of the store.
    for [i, j] in [[0.0, 0.0], [3.0, -7.0], [-256.0, 255.0]] {
        let got = c.map_of_texel(0, 256.0 + i, 256.0 + j).unwrap();
        assert_eq!(got, [400000.0 + 10.0 * i, 4700000.0 + 10.0 * j], "store texel ({i}, {j})");
    }
    let _ = child.kill();
    let _ = child.wait();

    let (mut child, c) = serve(d, "utm", "gplain");
    assert!(c.georef.is_none(), "a grid without a CRS publishes no georeferencing");
    let _ = child.kill();
    let _ = child.wait();

    // An unknown code is refused at create, naming it.
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["grow", "create", "bad", "--crs", "EPSG:1"])
        .current_dir(d)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("EPSG") && err.contains('1'), "{err}");
}
