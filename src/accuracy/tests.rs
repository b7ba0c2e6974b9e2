//! Headline checks of the study: with a clip size at least twice the display and the centre at
//! the viewer's foot, every frame is bit-identical to the full-mipmap render; quality degrades
//! in the expected direction for each knob.

use super::study::{run, Case};
use crate::roam::Procedural;

fn case(clip: u64, display: u32) -> Case {
    Case { clip_size: clip, display: [display, display * 3 / 4], frames: 3, ..Case::small() }
}

#[test]
fn with_clip_twice_the_display_every_frame_is_bit_identical() {
    for (source, flight) in [(Procedural::Terrain, "straight:8:30"), (Procedural::Hash, "circle:300:12")] {
        let c = Case { source, flight: flight.into(), ..case(256, 128) };
        let o = run(&c, |_, _, _, _| {}).unwrap();
        for f in &o.frames {
            assert_eq!(
                (f.psnr, f.max_error, f.coarser_pixel_share),
                (None, 0, 0.0),
                "{source:?} frame {}: {f:?}",
                f.frame
            );
        }
    }
}

#[test]
fn a_smaller_clip_size_never_improves_the_picture() {
    let mut last_share = -1.0;
    for clip in [512u64, 128, 32] {
        let o = run(&case(clip, 128), |_, _, _, _| {}).unwrap();
        assert!(
            o.summary.coarser_pixel_share >= last_share,
            "clip {clip}: {} < {last_share}",
            o.summary.coarser_pixel_share
        );
        last_share = o.summary.coarser_pixel_share;
    }
    assert!(last_share > 0.01, "a 32-texel clip for a 128-pixel view must draw some pixels coarser");
}

#[test]
fn a_slower_disk_or_a_faster_flight_draws_more_pixels_coarser() {
    let at = |tiles: u64, speed: f64| {
        let c = Case {
            disk_tiles: Some(tiles),
            wait_for_reads: true,
            flight: format!("straight:{speed}:30"),
            frames: 6,
            ..case(256, 128)
        };
        run(&c, |_, _, _, _| {}).unwrap().summary.coarser_pixel_share
    };
    let (loose, tight) = (at(64, 64.0), at(1, 64.0));
    assert!(tight > loose, "tight {tight} <= loose {loose}");
    assert!(tight > 0.0, "one tile a frame cannot keep up with 64 texels per frame");
    let (slow, fast) = (at(2, 2.0), at(2, 128.0));
    assert!(fast > slow, "fast {fast} <= slow {slow}");
}

#[test]
fn a_virtual_clip_texture_with_few_effective_levels_loses_the_far_field() {
    // Looking towards the horizon needs every level; a window of 2 levels cannot reach the
    // coarse ones, so far pixels are drawn too sharp (aliased) and differ from the reference.
    let all = Case { effective_levels: Some(32), pitch_deg: 15.0, ..case(256, 128) };
    let few = Case { effective_levels: Some(2), pitch_deg: 15.0, ..case(256, 128) };
    let o_all = run(&all, |_, _, _, _| {}).unwrap();
    let o_few = run(&few, |_, _, _, _| {}).unwrap();
    assert_eq!((o_all.summary.psnr_min, o_all.summary.max_error), (None, 0), "all levels addressable: identical");
    assert!(
        o_few.summary.max_error > 0 && o_few.summary.psnr_min.is_some(),
        "{:?}",
        (o_few.summary.psnr_min, o_few.summary.max_error)
    );
}

#[test]
fn a_wider_invalid_border_never_improves_the_picture() {
    let mut last = -1.0;
    for border in [8u64, 16, 32] {
        let o = run(&Case { invalid_border: border, ..case(128, 128) }, |_, _, _, _| {}).unwrap();
        assert!(o.summary.coarser_pixel_share >= last, "border {border}: {} < {last}", o.summary.coarser_pixel_share);
        last = o.summary.coarser_pixel_share;
    }
    let narrow =
        run(&Case { invalid_border: 8, ..case(128, 128) }, |_, _, _, _| {}).unwrap().summary.coarser_pixel_share;
    assert!(last > narrow, "a 32-texel border must cost more than an 8-texel one: {last} vs {narrow}");
}

#[test]
fn a_sixteen_bit_texture_is_compared_at_sixteen_bits() {
    use super::study::compare_at;
    use crate::texel::TexelFormat;
    // Identical frames stay identical at 16 bits; a case that differs measures against 65535.
    let same = Case { format: TexelFormat::L16, ..case(256, 128) };
    let o = run(&same, |_, _, _, _| {}).unwrap();
    assert_eq!((o.summary.psnr_min, o.summary.max_error), (None, 0), "{:?}", o.frames);
    let few = Case { effective_levels: Some(2), pitch_deg: 15.0, format: TexelFormat::RGBA16, ..case(256, 128) };
    let mut pairs = Vec::new();
    let o = run(&few, |_, _, want, got| pairs.push((want.to_vec(), got.to_vec()))).unwrap();
    assert!(o.summary.max_error > 255, "errors in 16-bit units: {}", o.summary.max_error);
    // The same frames at 8 bits: errors 257 times smaller (within rounding), and the PSNR nearly
    // the same, the peak scaling with the errors.
    let (want, got) = &pairs[0];
    let (p16, e16, _) = compare_at(want, got, 16);
    let (p8, e8, _) = compare_at(want, got, 8);
    assert!((e16 as f64 / 257.0 - e8 as f64).abs() <= 1.0, "{e16} vs {e8}");
    let (p16, p8) = (p16.unwrap(), p8.unwrap());
    assert!((p16 - p8).abs() < 0.5, "{p16} dB at 16 bits, {p8} dB at 8");
    assert_eq!(serde_json::to_value(&few).unwrap()["format"], "rgba16");
}

#[test]
fn the_quick_sweep_reads_from_its_disk_and_a_slower_disk_draws_more_pixels_coarser() {
    use super::sweep::{cases, Row};
    // What a user runs first must show the trade: every finite-disk row reads tiles, and at the
    // quick sweep's highest speed the slowest disk reads fewer of them and draws more pixels
    // coarser than the fastest.
    let disk: Vec<_> =
        cases(true, crate::texel::TexelFormat::RGBA8).into_iter().filter(|(c, _)| c.disk_tiles.is_some()).collect();
    let straight = |c: &super::study::Case| c.flight.starts_with("straight");
    let top = disk.iter().filter(|(c, _)| straight(c)).map(|(_, s)| *s).fold(0.0, f64::max);
    let mut at_top = Vec::new();
    for (c, speed) in &disk {
        let row = Row::from(&run(c, |_, _, _, _| {}).unwrap(), *speed);
        assert!(row.summary.tiles_read > 0, "{} at {speed} texels a frame read no tile", c.flight);
        if straight(c) && *speed == top {
            at_top.push((c.disk_tiles.unwrap(), row.summary.tiles_read, row.summary.coarser_pixel_share));
        }
    }
    at_top.sort_by_key(|r| r.0);
    let (slow, fast) = (at_top.first().unwrap(), at_top.last().unwrap());
    assert!(slow.0 < fast.0, "the quick sweep must have two disks at its top speed: {at_top:?}");
    assert!(slow.1 < fast.1, "the slower disk read no fewer tiles: {at_top:?}");
    assert!(slow.2 > fast.2, "the slower disk drew no more pixels coarser: {at_top:?}");
}

mod heights {
    use crate::accuracy::heights::{run, HeightCase, HeightRow, Surface};
    use crate::height::LevelRule;
    use crate::source::{HeightLevels, TileSource};
    use std::sync::Arc;

    fn case(surface: Surface, rule: LevelRule, disk_tiles: Option<u64>, speed: f64) -> HeightCase {
        HeightCase {
            surface,
            rule,
            size: 1 << 10,
            clip_size: 128,
            tile: 32,
            invalid_border: 4,
            disk_tiles,
            speed,
            frames: 4,
            display: [64, 48],
            eye_height: 24.0,
            pitch_deg: 35.0,
            fov_deg: 60.0,
        }
    }

    fn fly(surface: Surface, rule: LevelRule, flights: &[(Option<u64>, f64)]) -> Vec<HeightRow> {
        let c = case(surface, rule, None, 8.0);
        let source: Arc<dyn TileSource> =
            Arc::new(HeightLevels::by_rule(c.desc().unwrap(), surface.format(), rule, surface.level0(c.size)).unwrap());
        flights.iter().map(|&(disk, speed)| run(&case(surface, rule, disk, speed), source.clone()).unwrap()).collect()
    }

    #[test]
    fn heights_drawn_from_level_0_are_the_source_and_a_slow_disk_at_speed_draws_them_further_off() {
        let flights = [(None, 8.0), (Some(64), 64.0), (Some(1), 64.0)];
        let dem_mean = fly(Surface::Dem, LevelRule::Mean, &flights);
        let dem_point = fly(Surface::Dem, LevelRule::Point, &flights);
        let noise_point = fly(Surface::Procedural, LevelRule::Point, &flights[2..]);
        for r in dem_mean.iter().chain(&dem_point).chain(&noise_point) {
            let what = format!("{} {} disk {:?} speed {}", r.surface, r.rule, r.disk_tiles, r.speed);
            // Wherever level 0 is drawn, the surface is the source's exactly, whatever the rule.
            let level0 = r.by_level.iter().find(|l| l.level == 0).expect("some pixels from level 0");
            assert!(level0.pixels > 0 && level0.max_m == 0.0, "{what}: {level0:?}");
            assert!(r.pixels > 1000, "{what}: the camera sees the ground: {}", r.pixels);
            // Every coarser level drawn is off the source somewhere.
            for l in r.by_level.iter().filter(|l| l.level > 0 && l.pixels > 100) {
                assert!(l.max_m > 0.0, "{what}: level {} equals the source: {l:?}", l.level);
            }
        }
        for rows in [&dem_mean, &dem_point] {
            let (loose, tight) = (&rows[1], &rows[2]);
            // The simulated disk is exercised: one tile a frame bounds the reads and lags.
            assert!(tight.tiles_read > 0 && tight.ticks_over_budget > 0, "{tight:?}");
            assert!(tight.tiles_read < loose.tiles_read, "{} < {}", tight.tiles_read, loose.tiles_read);
            assert!(tight.min_lod_max > loose.min_lod_max, "{} {}", tight.min_lod_max, loose.min_lod_max);
            let mean_level = |r: &HeightRow| {
                r.by_level.iter().map(|l| l.level as f64 * l.pixels as f64).sum::<f64>() / r.pixels as f64
            };
            assert!(mean_level(tight) > mean_level(loose), "{tight:?}\n{loose:?}");
            assert!(tight.mean_m > loose.mean_m, "{}: {} <= {}", tight.rule, tight.mean_m, loose.mean_m);
        }
        // The two rules' surfaces differ where a coarser level is drawn, on the same flight.
        let (m, p) = (&dem_mean[2], &dem_point[2]);
        assert_eq!(
            m.by_level.iter().map(|l| l.pixels).collect::<Vec<_>>(),
            p.by_level.iter().map(|l| l.pixels).collect::<Vec<_>>(),
            "the same levels drawn"
        );
        assert!(m.mean_m != p.mean_m && m.max_m != p.max_m, "mean {m:?}\npoint {p:?}");
        // White noise: coarser levels are kilometres off.
        let n = &noise_point[0];
        assert!(n.by_level.iter().any(|l| l.level > 0 && l.mean_m > 1000.0), "{n:?}");
    }
}
