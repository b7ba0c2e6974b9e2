//! Block-compressed formats through the service (docs/SHM.md, "Block-compressed formats"):
//! `clipmapd --format bc1|bc4|bc5|bc7` publishes, for every tile a reader finds ready, exactly the
//! blocks the encoder makes of the source's tile; an independent decoder (`bcdec_rs`, behind
//! `Client::decode_tile`) gives back texels close to the source's; slots are laid out in whole
//! blocks, down to the pyramid's 2 x 2 and 1 x 1 tiles (partial blocks); and what cannot be
//! encoded is refused at start, saying why. The C and Python readers read the same blocks on
//! every level and decode them to the Rust client's texels bit for bit (the C reader BC1, BC4
//! and BC5, Python all four); both refuse texel reads of a block mapping.

use crate::clipmapd::{c_reader, Service};
use clipmap::shm::client::ReadError;
use clipmap::shm::Client;
use clipmap::source::{BcQuality, BcSource, Procedural, TileId, TileSource};
use clipmap::texel::Bc;
use std::sync::Arc;
use std::time::{Duration, Instant};

const SOURCE: [&str; 8] = ["--source", "hash", "--size", "256", "--clip", "64", "--tile", "16"];

/// The service's source: the hash texture of `SOURCE`, uncompressed.
fn hash() -> Arc<dyn TileSource> {
    clipmap_service::procedural_source(Procedural::Hash, 256, 64, 16).unwrap()
}

/// Waits until every level of `c` is enabled and published whole (min LOD 0), and returns the
/// snapshot.
pub(crate) fn all_levels(c: &Client, svc: &Service) -> clipmap::shm::client::Snapshot {
    let t = Instant::now();
    loop {
        let snap = c.snapshot();
        // Min LOD 0: every level's published region is its whole valid region (docs/SHM.md);
        // a level is enabled while its region still grows, which a slow machine shows.
        if !snap.levels.is_empty() && snap.levels.iter().all(|l| l.enabled) && snap.min_lod == 0.0 {
            return snap;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "levels never all published: {snap:?}\n{}", svc.dump());
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Mean absolute difference of channel 0 between `a` (RGBA8 texels) and `b` (`n` bytes each).
fn mean_error(a: &[u8], b: &[u8], n: usize) -> f64 {
    let e: f64 = a.chunks_exact(4).zip(b.chunks_exact(n)).map(|(a, b)| (a[0] as f64 - b[0] as f64).abs()).sum();
    e / (b.len() / n) as f64
}

/// Bytes as lowercase hex.
pub(crate) fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// Lowercase hex as bytes.
pub(crate) fn unhex(s: &str) -> Vec<u8> {
    (0..s.len() / 2).map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap()).collect()
}

/// Runs `script` with the Python reader importable as `c`, and returns its standard output.
pub(crate) fn python(script: &str) -> String {
    let script = format!(
        "import sys; sys.path.insert(0, {:?}); import clipmap_shm as c\n{script}",
        format!("{}/clients/python", crate::clipmapd::ROOT)
    );
    let out = std::process::Command::new("python3").args(["-c", &script]).output().unwrap();
    assert!(out.status.success(), "python: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

/// The C reader's `--tile` or `--decode` of tile `tile` of `level`: the bytes it writes.
fn c_tile(exe: &std::path::Path, map: &std::path::Path, how: &str, level: usize, tile: [i64; 2]) -> Vec<u8> {
    let out = map.with_extension(format!("{how}-{level}-{}-{}", tile[0], tile[1]).trim_start_matches('-'));
    let run = std::process::Command::new(exe)
        .arg(map)
        .args([how, &level.to_string(), &tile[0].to_string(), &tile[1].to_string()])
        .arg(&out)
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&run.stdout), String::from_utf8_lossy(&run.stderr));
    assert!(run.status.success(), "c reader {how} level {level} tile {tile:?}: {text}");
    let bytes = std::fs::read(&out).unwrap();
    assert_eq!(text.trim(), format!("level {level} tile {} {} bytes {}", tile[0], tile[1], bytes.len()));
    bytes
}

#[test]
fn every_block_format_publishes_the_encoders_blocks_bit_for_bit_and_they_decode_to_the_source() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let src = hash();
    let rgba = Service::spawn_with(d, "plain", &SOURCE, &[]);
    rgba.wait_ready();
    let plain = Client::attach(d, "plain").unwrap();
    let creader = c_reader(d);
    for (bc, quality) in [(Bc::Bc1, "normal"), (Bc::Bc4, "normal"), (Bc::Bc5, "normal"), (Bc::Bc7, "fast")] {
        let name = bc.name();
        let svc = Service::spawn_with(d, name, &SOURCE, &["--format", name, "--bc-quality", quality]);
        svc.wait_ready();
        let c = Client::attach(d, name).unwrap();
        let code = match bc {
            Bc::Bc1 => 20,
            Bc::Bc4 => 21,
            Bc::Bc5 => 22,
            Bc::Bc7 => 23,
        };
        assert_eq!((c.format_code, c.bytes_per_texel, c.block), (code, bc.block_bytes() as usize, 4));
        let encoder = BcSource::new(src.clone(), bc, BcQuality::parse(quality).unwrap()).unwrap();
        let snap = all_levels(&c, &svc);
        // One tile each level read ready, for the C and Python readers below.
        let mut ready: Vec<[i64; 2]> = Vec::new();
        for (k, level) in c.levels.iter().enumerate() {
            // Slots in whole blocks: a 16 x 16 tile is 4 x 4 blocks, the pyramid's 2 x 2 and 1 x 1
            // tiles one (partial) block; RGBA8 takes 16 texels x 4 bytes for the same 16 texels.
            let blocks = level.tile[0].div_ceil(4) * level.tile[1].div_ceil(4);
            assert_eq!(level.slot_bytes, blocks * u64::from(bc.block_bytes()), "{name} level {k}");
            assert_eq!(plain.levels[k].tile, level.tile);
            if level.tile[0] >= 4 {
                let ratio = plain.levels[k].slot_bytes / level.slot_bytes;
                assert_eq!(ratio, if bc.block_bytes() == 8 { 8 } else { 4 }, "{name} level {k}: bytes against RGBA8");
            }
            let tiles = clipmap::geom::tiles_covering(snap.levels[k].rect(), level.tile);
            let mut read = 0;
            for ts in tiles.s0..tiles.s1 {
                for tt in tiles.t0..tiles.t1 {
                    let mut got = vec![0u8; level.slot_bytes as usize];
                    match c.read_tile(k, [ts, tt], &mut got) {
                        Ok(()) => {}
                        // The window moved on meanwhile: that slot holds another tile now.
                        Err(ReadError::Stale(_)) => continue,
                        Err(e) => panic!("{name} level {k} tile ({ts}, {tt}): {e}"),
                    }
                    let id = TileId::new(k as u32, ts as u64, tt as u64);
                    let mut want = vec![0u8; encoder.desc().tile_bytes(k as u32)];
                    encoder.read_tile(id, &mut want).unwrap();
                    assert!(
                        got == want,
                        "{name} level {k} tile ({ts}, {tt}): the published blocks are not the encoder's"
                    );
                    // Decoded independently, the blocks give the tile back far closer than a
                    // neighbour's texels (hash texels are noise: the worst case for any encoder).
                    let decoded = c.decode_tile(k, [ts, tt]).unwrap();
                    let n = clipmap::shm::blocks::decoded_bytes(bc);
                    assert_eq!(decoded.len() as u64, level.tile[0] * level.tile[1] * n as u64);
                    let mut texels = vec![0u8; src.desc().tile_bytes(k as u32)];
                    src.read_tile(id, &mut texels).unwrap();
                    if bc != Bc::Bc4 && level.size[0] / level.tile[0] > 1 {
                        let other_id =
                            TileId::new(k as u32, (ts as u64 + 1) % (level.size[0] / level.tile[0]), tt as u64);
                        let mut other = vec![0u8; texels.len()];
                        src.read_tile(other_id, &mut other).unwrap();
                        let (near, far) = (mean_error(&texels, &decoded, n), mean_error(&other, &decoded, n));
                        assert!(
                            near < 0.8 * far,
                            "{name} level {k}: error {near} against its tile, {far} against another"
                        );
                    }
                    if level.tile == [1, 1] && bc != Bc::Bc4 {
                        // One texel in a partial block: BC1, BC5 and BC7 keep a lone colour closely.
                        assert!((texels[0] as i32 - decoded[0] as i32).abs() <= 8, "{name}: {texels:?} {decoded:?}");
                    }
                    if read == 0 {
                        ready.push([ts, tt]);
                    }
                    read += 1;
                }
            }
            assert!(read > 0, "{name} level {k}: no tile was read ready");
        }
        // The C reader reads the same blocks on every level, the pyramid's partial 2 x 2 and 1 x 1
        // blocks included, and decodes all four formats to the Rust client's texels bit for bit.
        let map = d.join(format!("clipmap-{name}.map"));
        for (k, &tile) in ready.iter().enumerate() {
            let mut want = vec![0u8; c.levels[k].slot_bytes as usize];
            c.read_tile(k, tile, &mut want).unwrap();
            assert!(c_tile(&creader, &map, "--tile", k, tile) == want, "{name} level {k}: the C reader's blocks");
            let rust = c.decode_tile(k, tile).unwrap();
            assert!(c_tile(&creader, &map, "--decode", k, tile) == rust, "{name} level {k}: the C reader's decode");
        }
        // The Python reader too, and it decodes all four formats (BC7 in pure Python by the
        // format's definition) to the Rust client's texels bit for bit.
        let tiles: Vec<String> = ready.iter().enumerate().map(|(k, t)| format!("({k}, {}, {})", t[0], t[1])).collect();
        let text = python(&format!(
            "m = c.Mapping({:?})\n\
             for k, s, t in [{}]:\n    print(m.read_tile(k, s, t).hex(), m.decode_tile(k, s, t).hex())",
            map.to_str().unwrap(),
            tiles.join(", ")
        ));
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), ready.len(), "{text}");
        for (k, (line, &tile)) in lines.iter().zip(&ready).enumerate() {
            let (blocks, decoded) = line.split_once(' ').unwrap();
            let mut want = vec![0u8; c.levels[k].slot_bytes as usize];
            c.read_tile(k, tile, &mut want).unwrap();
            assert_eq!(blocks, hex(&want), "{name} level {k}: the Python reader's blocks");
            assert!(
                unhex(decoded) == c.decode_tile(k, tile).unwrap(),
                "{name} level {k}: Python's decode is not bcdec's"
            );
        }
        // Texel reads of a block format are refused, saying what to use instead.
        let e = c.read_region(0, 100, 100, 4, 4, &mut [0u8; 64]).unwrap_err();
        assert!(e.to_string().contains("block-compressed: read whole tiles"), "{e}");
    }
    // The C reader's --decode refuses a texel format, saying why and writing nothing.
    let out = std::process::Command::new(&creader)
        .arg(d.join("clipmap-plain.map"))
        .args(["--decode", "0", "0", "0"])
        .arg(d.join("x"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("texel format 4 is not decoded here") && !d.join("x").exists(), "{err}");
}

#[test]
fn texel_reads_of_blocks_and_sources_that_cannot_be_encoded_are_refused_saying_why() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::spawn_with(d, "b1", &SOURCE, &["--format", "bc1"]);
    svc.wait_ready();
    // The C and Python readers' texel reads refuse the mapping's blocks, saying what to use
    // instead, never misreading blocks as texels.
    let map = d.join("clipmap-b1.map");
    let exe = c_reader(d);
    for args in [&["10", "1", "1"][..], &["--dump", "0", "0,0,4,4"]] {
        let c = std::process::Command::new(&exe).arg(&map).args(args).arg(d.join("out.raw")).output().unwrap();
        let err = String::from_utf8_lossy(&c.stderr);
        assert_eq!(c.status.code(), Some(2), "c {args:?}: {err}");
        assert!(err.contains("texel format 20 is block-compressed") && err.contains("--tile or --decode"), "c: {err}");
    }
    let py = crate::clipmapd::python_reader().arg(&map).args(["10", "1", "1"]).output().unwrap();
    let err = String::from_utf8_lossy(&py.stderr);
    assert_eq!(py.status.code(), Some(2), "python: {err}");
    assert!(err.contains("block-compressed"), "python: {err}");
    // A tile size off the block grid, heights, and an unknown format or quality.
    let refused = |source: &[&str], extra: &[&str], want: &str| {
        let mut s = Service::spawn_with(d, "no", source, extra);
        let st = s.child.wait().unwrap();
        let text = s.dump();
        assert_eq!(st.code(), Some(1), "{text}");
        assert!(text.contains(want), "wanted {want:?}\n{text}");
    };
    let hash2 = ["--source", "hash", "--size", "256", "--clip", "64", "--tile", "2"];
    refused(&hash2, &["--format", "bc7"], "multiple of 4");
    let heights = ["--source", "heights", "--size", "256", "--clip", "64", "--tile", "16"];
    refused(&heights, &["--format", "bc4"], "block formats are for colours and grey images only");
    refused(&SOURCE, &["--format", "dxt1"], "expected bc1, bc4, bc5 or bc7");
    refused(&SOURCE, &["--format", "bc1", "--bc-quality", "best"], "expected fast, normal or slow");
}

#[test]
fn cliptex_plan_format_bc1_states_the_slot_formula_and_sizes_the_mapping_as_the_service_maps_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let plan = |format: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex"))
            .args(["plan", "--size", "256", "--clip", "64", "--tile", "16", "--texel-bytes", "4", "--json"])
            .args(format)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()["image_caches"].clone()
    };
    let (rgba, bc1, bc7) = (plan(&[]), plan(&["--format", "bc1"]), plan(&["--format", "bc7"]));
    assert_eq!((rgba.get("slot_formula"), rgba.get("format")), (None, None), "{rgba}");
    assert_eq!(bc1["slot_formula"], "ceil(16 / 4) x ceil(16 / 4) blocks x 8 bytes = 128");
    assert_eq!(bc7["slot_formula"], "ceil(16 / 4) x ceil(16 / 4) blocks x 16 bytes = 256");
    assert_eq!((bc1["format"].as_str(), bc7["format"].as_str()), (Some("bc1"), Some("bc7")));
    for (format, caches) in [("bc1", &bc1), ("bc7", &bc7)] {
        let svc = Service::spawn_with(d, format, &SOURCE, &["--format", format]);
        svc.wait_ready();
        let mapped = std::fs::metadata(d.join(format!("clipmap-{format}.map"))).unwrap().len();
        assert_eq!(caches["bytes"].as_u64(), Some(mapped), "{format}: {caches}");
    }
    // The slots: an eighth (BC1) and a quarter (BC7) of RGBA8's but for the pyramid's 2 x 2 and
    // 1 x 1 tiles, one whole block each.
    let slots = |c: &serde_json::Value| c["slot_bytes"].as_u64().unwrap();
    assert_eq!(slots(&rgba) - 4 * 4 - 4, 8 * (slots(&bc1) - 8 - 8));
    assert_eq!(slots(&rgba) - 4 * 4 - 4, 4 * (slots(&bc7) - 16 - 16));
    let human = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["plan", "--size", "256", "--clip", "64", "--tile", "16", "--format", "bc1"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&human.stdout);
    assert!(text.contains("slots        bc1: level 0's ceil(16 / 4) x ceil(16 / 4) blocks x 8 bytes = 128"), "{text}");
}
