//! Pre-encoded pyramids (docs/CONFIG.md, "Block-compressed tiles"): `clipprep --format
//! bc1|bc4|bc5|bc7` (with or without `--zstd`) writes each tile as the encoder's blocks of the
//! texels it would otherwise write, names the format in the `.ct` and `.ic` files with this
//! crate's extension names, `cliptex validate`, `info` and `check` read them, and `clipmapd`
//! serves the blocks as they are on disk, encoding nothing.

use crate::clipmapd::Service;
use clipmap::shm::Client;
use clipmap::source::{BcQuality, BcSource, TileSource};
use clipmap::texel::Bc;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs `clipprep` on the hash texture (256 square, tiles of 16, clip 64) with `extra`; returns
/// the `.ct` and the JSON summary.
fn prepare(out: &Path, extra: &[&str]) -> (PathBuf, serde_json::Value) {
    let run = Command::new(env!("CARGO_BIN_EXE_clipprep"))
        .args(["--source", "hash", "--size", "256", "--tile", "16", "--clip", "64", "--json", "-q"])
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(run.status.success(), "clipprep {extra:?}: {}", String::from_utf8_lossy(&run.stderr));
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let ct = PathBuf::from(v["ct"].as_str().unwrap());
    (if ct.is_absolute() { ct } else { out.join(ct) }, v)
}

/// `cliptex ARGS`: exit code and standard output.
fn cliptex(args: &[&str]) -> (i32, String) {
    let run = Command::new(env!("CARGO_BIN_EXE_cliptex")).args(args).output().unwrap();
    let text = String::from_utf8_lossy(&run.stdout).into_owned();
    (run.status.code().unwrap(), text + &String::from_utf8_lossy(&run.stderr))
}

/// The bytes of tile (S, T) of `level` as the prepared files hold them (zstd frames unpacked).
fn file_tile(root: &Path, level: usize, s: i64, t: i64, pyramid: bool) -> Vec<u8> {
    if pyramid {
        return std::fs::read(root.join(format!("pyramid/L{level:02}.raw"))).unwrap();
    }
    let raw = root.join(format!("L{level:02}/r{t:03}.c{s:03}.raw"));
    match std::fs::read(&raw) {
        Ok(b) => b,
        Err(_) => zstd::decode_all(&std::fs::read(raw.with_extension("raw.zst")).unwrap()[..]).unwrap(),
    }
}

#[test]
fn clipprep_writes_block_compressed_pyramids_that_clipmapd_serves_without_encoding() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let formats = [
        (Bc::Bc1, "rgb8", &["--zstd", "3"][..]),
        (Bc::Bc7, "rgba8", &["--bc-quality", "fast"][..]),
        (Bc::Bc4, "l8", &[][..]),
    ];
    for (bc, texels, extra) in formats {
        let name = bc.name();
        // The same texels prepared plain (the encoder's input: RGB8 for bc1, RGBA8 for bc7, L8 for
        // bc4), to encode in the test as the service would at run time.
        let (plain_ct, _) = prepare(&d.join(texels), &["--format", texels]);
        let loaded = clipmap::source::configured::load_clip_texture(&plain_ct, &crate::common::opts()).unwrap();
        let plain: std::sync::Arc<dyn TileSource> =
            clipmap::source::open_plan(loaded.plan.unwrap(), &Default::default()).unwrap();
        let root = d.join(name);
        let args: Vec<&str> = ["--format", name].iter().copied().chain(extra.iter().copied()).collect();
        let (ct, summary) = prepare(&root, &args);
        assert_eq!(summary["format"], name, "{summary}");
        let ic = std::fs::read_to_string(root.join("L00.ic")).unwrap();
        let ext = format!("ext_format CLIPMAP_{}", name.to_uppercase());
        assert!(ic.contains(&ext), "{ic}");
        // A level-0 tile of 16 x 16 texels is 4 x 4 blocks.
        assert_eq!(file_tile(&root, 0, 0, 0, false).len(), 16 * bc.block_bytes() as usize, "{name}");
        let ct_s = ct.to_str().unwrap();
        let (code, text) = cliptex(&["validate", ct_s]);
        assert_eq!(code, 0, "{name}: {text}");
        // The block format is this crate's extension: a portability finding (tests/it/bc_strict.rs).
        let (code, text) = cliptex(&["validate", "--strict", ct_s]);
        assert!(code != 0 && text.contains("Performer 3.0 would not read it"), "{name}: {text}");
        let (code, text) = cliptex(&["info", ct_s]);
        assert_eq!(code, 0, "{text}");
        assert!(text.contains(&format!("texel          {name} ({} bytes a 4 x 4 block", bc.block_bytes())), "{text}");
        let (code, text) = cliptex(&["check", ct_s, "--json"]);
        assert_eq!(code, 0, "{name}: {text}");
        // Served as it is: format code 20..23, and every tile ready in the windows holds the
        // file's blocks, which are the encoder's blocks of the plain texels.
        let svc = Service::spawn_with(d, name, &[ct_s], &[]);
        svc.wait_ready();
        let c = Client::attach(d, name).unwrap();
        assert_eq!(c.format_code, clipmap::shm::layout::format_code(bc.format()), "{name}");
        let quality = if bc == Bc::Bc7 { BcQuality::Fast } else { BcQuality::Normal };
        let encoder = BcSource::new(plain.clone(), bc, quality).unwrap();
        // Once every level is published whole (a slow machine shows levels enabled while their
        // regions still grow), every tile under the regions holds the encoder's blocks of the
        // plain texels (`check_published`), and those are the file's bytes.
        let read = crate::bc_edges::check_published(&c, &svc, &encoder, name);
        for &(k, ts, tt) in &read {
            let mut got = vec![0u8; c.levels[k].slot_bytes as usize];
            c.read_tile(k, [ts, tt], &mut got).unwrap();
            let pyramid = c.levels[k].size[0] <= 64;
            assert!(got == file_tile(&root, k, ts, tt, pyramid), "{name} level {k} ({ts}, {tt}): not the file's");
        }
        assert!(read.len() > 20, "{name}: {} tiles read", read.len());
        // Blocks are not encoded again.
        let mut again = Service::spawn_with(d, "again", &[ct_s], &["--format", "bc1"]);
        assert_eq!(again.child.wait().unwrap().code(), Some(1), "{}", again.dump());
        assert!(again.dump().contains(&format!("texel format {name} cannot be encoded")), "{}", again.dump());
    }
}

#[test]
fn clipprep_refuses_block_formats_it_cannot_write_saying_why() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fails = |args: &[&str], want: &str| {
        let run =
            Command::new(env!("CARGO_BIN_EXE_clipprep")).args(args).arg("--out").arg(d.join("x")).output().unwrap();
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: wanted {want:?} in {err}");
        assert!(!d.join("x").exists(), "nothing is left behind");
    };
    let hash = ["--source", "hash", "--size", "256", "--clip", "64"];
    fails(&[&hash[..], &["--tile", "2", "--format", "bc1"]].concat(), "do not start on 4 x 4 blocks");
    fails(
        &[&hash[..], &["--tile", "16", "--format", "bc7", "--cog"]]
            .concat()
            .iter()
            .copied()
            .chain([d.join("c.tif").to_str().unwrap()])
            .collect::<Vec<_>>(),
        "a COG holds texels",
    );
    fails(
        &["--source", "heights", "--size", "256", "--clip", "64", "--tile", "16", "--format", "bc4"],
        "holds colours",
    );
}
