//! Texel views of block-compressed textures (docs/SHM.md, "Block-compressed formats"): the
//! in-process view (`LevelView::texel`) and `cliptex dump` of a live mapping decode the blocks
//! they hold (with `bcdec_rs`, the Rust client's decoder) rather than reading blocks as texels.

use crate::clipmapd::Service;
use clipmap::clip::{Clipmap, Settings};
use clipmap::shm::blocks;
use clipmap::source::{BcQuality, BcSource, Procedural, TileId, TileSource};
use clipmap::texel::Bc;
use std::sync::Arc;

#[test]
fn level_view_texels_of_a_block_format_are_its_blocks_decoded() {
    let inner = clipmap_service::procedural_source(Procedural::Hash, 256, 64, 16).unwrap();
    for bc in [Bc::Bc1, Bc::Bc4, Bc::Bc7] {
        let src = Arc::new(BcSource::new(inner.clone(), bc, BcQuality::Fast).unwrap());
        let mut map = Clipmap::new(src.clone(), Settings::default()).unwrap();
        for _ in 0..100 {
            map.tick([128, 128], Some([0, 0]));
            if (0..map.level_count() as u32).all(|k| !map.level(k).valid.is_empty()) {
                break;
            }
            map.wait_for_reads();
        }
        let n = blocks::decoded_bytes(bc);
        let mut checked = 0;
        for k in 0..map.level_count() as u32 {
            let view = map.level(k);
            let [tw, th] = view.tile;
            let v = view.valid;
            for t in (v.t0..v.t1).step_by(3) {
                for s in (v.s0..v.s1).step_by(5) {
                    let Some(got) = view.texel(s, t) else { continue };
                    let tile = TileId::new(k, s as u64 / tw, t as u64 / th);
                    let mut b = vec![0u8; src.desc().tile_bytes(k)];
                    src.read_tile(tile, &mut b).unwrap();
                    let texels = blocks::decode(bc, &b, tw, th).unwrap();
                    let i = ((t as u64 % th) * tw + s as u64 % tw) as usize * n;
                    assert_eq!(&*got, &texels[i..i + n], "{bc:?} level {k} texel ({s}, {t})");
                    checked += 1;
                }
            }
        }
        assert!(checked > 200, "{bc:?}: {checked} texels checked");
    }
}

#[test]
fn cliptex_dump_of_a_live_block_mapping_draws_its_texels_decoded() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let source = ["--source", "hash", "--size", "256", "--clip", "64", "--tile", "16"];
    let svc = Service::spawn_with(d, "b7", &source, &["--format", "bc7", "--bc-quality", "fast"]);
    svc.wait_ready();
    let c = clipmap::shm::Client::attach(d, "b7").unwrap();
    let t = std::time::Instant::now();
    while !c.snapshot().levels.iter().all(|l| l.enabled) {
        assert!(t.elapsed() < std::time::Duration::from_secs(30), "{}", svc.dump());
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let out = d.join("pictures");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["dump", "--attach", "b7", "--shm-dir"])
        .arg(d)
        .arg("--out-dir")
        .arg(&out)
        .output()
        .unwrap();
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    // The hash texture is noise: its decoded texels give hundreds of colours, where a level whose
    // texels could not be read shows only the backdrop and the outlines.
    for png in ["level-00.png", "view.png"] {
        let img = image::open(out.join(png)).unwrap().to_rgb8();
        let colours: std::collections::HashSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
        assert!(colours.len() > 300, "{png}: {} colours", colours.len());
    }
}
