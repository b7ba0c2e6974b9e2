//! Block geometry at the edges, through `clipmapd --format` (docs/SHM.md, "Block-compressed
//! formats"): a texture of odd level sizes whose last tiles are partial, a 2^26 hash texture of
//! which only the window is read, and a prepared pyramid with a missing tile and a tile covered by
//! the default tile. Every tile a reader finds ready (or default) holds exactly the blocks the
//! encoder makes of the source's tile; a missing tile is published missing, never as blocks.

use crate::bc_formats::{hex, python, unhex};
use crate::clipmapd::{c_reader, json_reply, Service};
use clipmap::shm::client::ReadError;
use clipmap::shm::layout::SlotState;
use clipmap::shm::Client;
use clipmap::source::{BcQuality, BcSource, TileId, TileSource};
use clipmap::texel::Bc;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Reads every tile under each level's published region that the service holds ready or
/// default and checks it against `encoder`'s blocks; returns the tiles read, as (level, S, T).
pub(crate) fn check_published(c: &Client, svc: &Service, encoder: &BcSource, what: &str) -> Vec<(usize, i64, i64)> {
    let snap = crate::bc_formats::all_levels(c, svc);
    let mut read = Vec::new();
    for (k, level) in c.levels.iter().enumerate() {
        assert_eq!(level.tile, encoder.desc().level(k as u32).tile, "{what} level {k}");
        let tiles = clipmap::geom::tiles_covering(snap.levels[k].rect(), level.tile);
        for ts in tiles.s0..tiles.s1 {
            for tt in tiles.t0..tiles.t1 {
                let mut got = vec![0u8; level.slot_bytes as usize];
                match c.read_tile(k, [ts, tt], &mut got) {
                    Ok(()) => {}
                    Err(ReadError::Stale(_) | ReadError::Missing { .. }) => continue,
                    Err(e) => panic!("{what} level {k} tile ({ts}, {tt}): {e}"),
                }
                let mut want = vec![0u8; encoder.desc().tile_bytes(k as u32)];
                encoder.read_tile(TileId::new(k as u32, ts as u64, tt as u64), &mut want).unwrap();
                assert!(got == want, "{what} level {k} tile ({ts}, {tt}): the published blocks are not the encoder's");
                read.push((k, ts, tt));
            }
        }
    }
    read
}

/// The C reader's `--tile` / `--decode` of one tile (its output file's bytes).
fn c_read(exe: &Path, map: &Path, how: &str, (k, s, t): (usize, i64, i64)) -> Result<Vec<u8>, String> {
    let out = map.with_extension(format!("{}-{k}-{s}-{t}", how.trim_start_matches('-')));
    let run = std::process::Command::new(exe)
        .arg(map)
        .args([how, &k.to_string(), &s.to_string(), &t.to_string()])
        .arg(&out)
        .args(["0.5"])
        .output()
        .unwrap();
    if run.status.success() {
        Ok(std::fs::read(&out).unwrap())
    } else {
        assert!(!out.exists(), "a failed read leaves no file");
        Err(format!("{} {}", run.status, String::from_utf8_lossy(&run.stderr)))
    }
}

#[test]
fn odd_level_sizes_and_partial_last_tiles_publish_the_encoders_blocks_to_every_reader() {
    // A 100 x 75 RGBA tiled GeoTIFF in 32-texel tiles served at clip 64: levels 100 x 75 (a
    // window of 64 about the centre reaches its partial last row of tiles, texels 64 to 75),
    // 50 x 37, 25 x 18, 12 x 9, 6 x 4, 3 x 2 and 1 x 1, whose last tiles are partial.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tif = crate::cog::fixture("rgba_100x75.tif");
    let inner: Arc<dyn TileSource> = Arc::new(clipmap::source::CogSource::open(&tif, 64).unwrap());
    let sizes: Vec<[u64; 2]> = inner.desc().levels().iter().map(|l| l.size).collect();
    assert_eq!(&sizes[..4], &[[100, 75], [50, 37], [25, 18], [12, 9]]);
    let exe = c_reader(d);
    for (bc, quality) in [(Bc::Bc1, "normal"), (Bc::Bc7, "fast")] {
        let name = bc.name();
        let svc = Service::spawn_with(
            d,
            name,
            &[tif.to_str().unwrap(), "--clip", "64"],
            &["--format", name, "--bc-quality", quality],
        );
        svc.wait_ready();
        let c = Client::attach(d, name).unwrap();
        let encoder = BcSource::new(inner.clone(), bc, BcQuality::parse(quality).unwrap()).unwrap();
        let read = check_published(&c, &svc, &encoder, name);
        // Partial tiles were among those read: the last row of level 0 (texels 64..75 of a
        // 32-texel tile) and tiles of levels whose sides are not whole blocks.
        let partial = |&&(k, s, t): &&(usize, i64, i64)| {
            let l = &c.levels[k];
            (s as u64 + 1) * l.tile[0] > l.size[0] || (t as u64 + 1) * l.tile[1] > l.size[1]
        };
        let partials: Vec<_> = read.iter().filter(partial).collect();
        assert!(partials.iter().any(|p| p.0 == 0), "{name}: no partial level-0 tile read: {read:?}");
        assert!(
            partials.iter().any(|p| !c.levels[p.0].size[1].is_multiple_of(4)),
            "{name}: no odd level read: {read:?}"
        );
        // The C and Python readers give the same blocks, and decode them as the Rust client does.
        let map = d.join(format!("clipmap-{name}.map"));
        let mut script = format!("m = c.Mapping({:?})\n", map.to_str().unwrap());
        for &&(k, s, t) in &partials {
            let mut want = vec![0u8; c.levels[k].slot_bytes as usize];
            c.read_tile(k, [s, t], &mut want).unwrap();
            assert!(c_read(&exe, &map, "--tile", (k, s, t)).unwrap() == want, "{name} level {k} ({s}, {t}): C");
            let rust = c.decode_tile(k, [s, t]).unwrap();
            assert!(c_read(&exe, &map, "--decode", (k, s, t)).unwrap() == rust, "{name} level {k}: C decode");
            script += &format!("print(m.read_tile({k}, {s}, {t}).hex(), m.decode_tile({k}, {s}, {t}).hex())\n");
        }
        let text = python(&script);
        for (line, &&(k, s, t)) in text.lines().zip(&partials) {
            let (blocks, decoded) = line.split_once(' ').unwrap();
            let mut want = vec![0u8; c.levels[k].slot_bytes as usize];
            c.read_tile(k, [s, t], &mut want).unwrap();
            assert_eq!(blocks, hex(&want), "{name} level {k} ({s}, {t}): Python");
            assert!(unhex(decoded) == c.decode_tile(k, [s, t]).unwrap(), "{name} level {k} ({s}, {t}): Python decode");
        }
        assert_eq!(text.lines().count(), partials.len());
    }
}

#[test]
fn a_2_26_hash_texture_in_bc1_reads_only_its_window_and_publishes_the_encoders_blocks() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let size = 1u64 << 26;
    let source = ["--source", "hash", "--size", "67108864", "--clip", "64", "--tile", "16"];
    let svc = Service::spawn_with(d, "big", &source, &["--format", "bc1"]);
    svc.wait_ready();
    let c = Client::attach(d, "big").unwrap();
    assert_eq!((c.levels.len(), c.levels[0].size), (27, [size, size]));
    let inner = clipmap_service::procedural_source(clipmap::source::Procedural::Hash, size, 64, 16).unwrap();
    let encoder = BcSource::new(inner, Bc::Bc1, BcQuality::Normal).unwrap();
    let read = check_published(&c, &svc, &encoder, "2^26");
    assert!(read.iter().filter(|r| r.0 == 0).count() >= 16, "level 0's window: {read:?}");
    // Sparse: the mapping holds the windows only (the size `cliptex plan` states), and the
    // service read no more tiles than the slots it has.
    let plan = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["plan", "--size", "67108864", "--clip", "64", "--tile", "16", "--texel-bytes", "4", "--format", "bc1"])
        .arg("--json")
        .output()
        .unwrap();
    assert!(plan.status.success(), "{}", String::from_utf8_lossy(&plan.stderr));
    let plan: serde_json::Value = serde_json::from_slice(&plan.stdout).unwrap();
    let mapped = std::fs::metadata(d.join("clipmap-big.map")).unwrap().len();
    assert_eq!(plan["image_caches"]["bytes"].as_u64(), Some(mapped));
    assert!(mapped < 4 << 20, "{mapped} bytes mapped");
    let slots: u64 = c.levels.iter().map(|l| l.grid[0] * l.grid[1]).sum();
    let tiles_read = json_reply(&svc.ask("STATS"))["engine"]["tiles_read"].as_u64().unwrap();
    assert!(tiles_read > 0 && tiles_read <= slots, "{tiles_read} tiles read for {slots} slots");
}

#[test]
fn a_missing_tile_is_published_missing_and_the_default_tile_as_its_blocks_in_a_block_format() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("pyr");
    let prep = std::process::Command::new(env!("CARGO_BIN_EXE_clipprep"))
        .args(["--source", "hash", "--size", "256", "--tile", "16", "--clip", "64", "--format", "rgba8", "-q", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(prep.status.success(), "{}", String::from_utf8_lossy(&prep.stderr));
    let ct = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "ct"))
        .unwrap();
    // Level 0's tile (8, 8) under the centre (128, 128) is absent and covered by the default tile
    // (opaque red, whose blocks decode exactly); level 1's tile (4, 4) is absent with no default.
    std::fs::remove_file(out.join("L00/r008.c008.raw")).unwrap();
    std::fs::remove_file(out.join("L01/r004.c004.raw")).unwrap();
    let ic = out.join("L00.ic");
    std::fs::write(&ic, std::fs::read_to_string(&ic).unwrap() + "default_tile red.raw\n").unwrap();
    std::fs::write(out.join("red.raw"), [255u8, 0, 0, 255].repeat(16 * 16)).unwrap();
    let svc = Service::spawn_with(d, "gaps", &[ct.to_str().unwrap()], &["--format", "bc1"]);
    svc.wait_ready();
    let c = Client::attach(d, "gaps").unwrap();
    let loaded = clipmap::source::configured::load_clip_texture(&ct, &crate::common::opts()).unwrap();
    let inner = clipmap::source::open_plan(loaded.plan.unwrap(), &Default::default()).unwrap();
    let encoder = BcSource::new(inner, Bc::Bc1, BcQuality::Normal).unwrap();
    let read = check_published(&c, &svc, &encoder, "pyramid");
    assert!(read.contains(&(0, 8, 8)), "the default-covered tile was read: {read:?}");
    // The default tile: state DEFAULT, the encoder's blocks of it, which decode to it.
    let mut blocks = vec![0u8; c.levels[0].slot_bytes as usize];
    assert_eq!(c.read_tile_state(0, [8, 8], &mut blocks).unwrap(), SlotState::Default);
    assert!(c.decode_tile(0, [8, 8]).unwrap().chunks_exact(4).all(|p| p == [255, 0, 0, 255]));
    // The missing tile: state MISSING for every reader, never blocks.
    let t = Instant::now();
    let missing = loop {
        match c.read_tile(1, [4, 4], &mut vec![0u8; c.levels[1].slot_bytes as usize]) {
            Err(ReadError::Missing { level: 1, s: 4, t: 4 }) => break true,
            Err(ReadError::Stale(_)) if t.elapsed() < Duration::from_secs(30) => {
                std::thread::sleep(Duration::from_millis(20))
            }
            other => panic!("level 1 tile (4, 4): {other:?}\n{}", svc.dump()),
        }
    };
    assert!(missing);
    let map = d.join("clipmap-gaps.map");
    let exe = c_reader(d);
    let err = c_read(&exe, &map, "--tile", (1, 4, 4)).unwrap_err();
    assert!(err.contains("level 1 tile (4, 4): the tile is missing"), "{err}");
    assert!(c_read(&exe, &map, "--tile", (0, 8, 8)).unwrap() == blocks, "C: the default tile's blocks");
    let text = python(&format!(
        "m = c.Mapping({:?})\nprint(m.read_tile(0, 8, 8).hex())\ntry:\n    m.read_tile(1, 4, 4)\nexcept c.Missing as e:\n    print('missing', e)",
        map.to_str().unwrap()
    ));
    assert_eq!(text, format!("{}\nmissing level 1 tile (4, 4) is missing\n", hex(&blocks)));
}
