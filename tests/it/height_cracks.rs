//! The crack test of point-registered heights, through the engine over a flight: wherever two
//! adjacent levels are both published, every coarser texel equals the finer texel at its even
//! position (the vertex a renderer's coarser mesh ring shares with the finer ring), frame after
//! frame as the window moves. The `mean` rule, flown the same way, differs there (the test
//! could fail).

use clipmap::clip::{Clipmap, Settings};
use clipmap::height::{HeightFormat, LevelRule};
use clipmap::source::procedural::height_stored;
use clipmap::source::{HeightLevels, TextureDesc};
use clipmap::texel::TexelFormat;
use std::sync::Arc;

/// Flies a 1024-texel height texture whose levels `rule` made from level 0 (the height
/// verification texture's level 0, nodata included) and returns (shared positions compared,
/// positions whose heights differ) over every frame and every pair of adjacent levels.
fn fly(rule: LevelRule) -> (u64, u64) {
    let size = 1024u64;
    let f = HeightFormat::VERIFICATION;
    let desc = TextureDesc::new([size; 2], 128, TexelFormat::L32F, [32, 32]).unwrap();
    let level0: Vec<f64> = (0..size * size).map(|i| height_stored(&f, 0, i % size, i / size)).collect();
    let src = Arc::new(HeightLevels::by_rule(desc, f, rule, level0).unwrap());
    let mut map = Clipmap::new(src, Settings { budget_ns: None, ..Settings::default() }).unwrap();
    let (mut compared, mut differ) = (0u64, 0u64);
    for frame in 0..40i64 {
        // Diagonally across the texture at 17 texels a frame, turning back half way.
        let along = if frame < 20 { frame } else { 40 - frame };
        let centre = [200 + 17 * along, 300 + 11 * along];
        map.tick(centre, None);
        map.wait_for_reads();
        map.tick(centre, None);
        let mut frame_compared = 0;
        for k in 0..map.level_count() as u32 - 1 {
            let (fine, coarse) = (map.level(k), map.level(k + 1));
            let v = coarse.valid;
            for t in v.t0..v.t1 {
                for s in v.s0..v.s1 {
                    let (Some(c), Some(x)) = (coarse.texel(s, t), fine.texel(2 * s, 2 * t)) else { continue };
                    frame_compared += 1;
                    differ += u64::from(c != x);
                }
            }
        }
        assert!(frame_compared > 1000, "frame {frame}: only {frame_compared} shared positions published");
        compared += frame_compared;
    }
    (compared, differ)
}

#[test]
fn point_registered_levels_meet_the_finer_level_at_every_shared_position_over_a_flight() {
    let (compared, differ) = fly(LevelRule::Point);
    assert_eq!(differ, 0, "{differ} of {compared} shared positions differ");
    // The same flight with the mean rule: coarser texels are averages, and differ.
    let (compared, differ) = fly(LevelRule::Mean);
    assert!(differ * 2 > compared, "mean: only {differ} of {compared} differ");
}
