use super::*;
use clipmap_base::geom::mem_grid;

fn shape(size: u64, clip: u64, tile: u64, bpt: u64) -> Shape {
    let levels = (0..clipmap_base::tile::level_count([size, size]))
        .map(|k| {
            let s = (size >> k).max(1);
            let t = if s <= clip { s } else { tile.min(s) };
            LevelShape { size: [s, s], tile: [t, t], grid: mem_grid([s, s], [t, t], clip, 1) }
        })
        .collect();
    Shape { bytes_per_texel: bpt, block: 1, clip_size: clip, levels }
}

#[test]
fn block_formats_have_codes_20_to_23_and_slots_of_whole_blocks() {
    use clipmap_base::texel::TexelFormat as F;
    let all = [F::BC1, F::BC4, F::BC5, F::BC7];
    assert_eq!(all.map(format_code), [20, 21, 22, 23]);
    for f in all {
        assert_eq!(format_from_code(format_code(f)), Some(f));
        assert!(is_block_code(format_code(f)));
    }
    assert!(!is_block_code(format_code(F::RGBA8)) && !is_block_code(0) && !is_block_code(24));
    assert_eq!(format_from_code(24), None);
    // 256 x 256 tiles: 64 x 64 blocks; a 3 x 1 pyramid tile is one partial block.
    assert_eq!(slot_bytes([256, 256], 4, 8), Some(32768));
    assert_eq!(slot_bytes([3, 1], 4, 16), Some(16));
    assert_eq!(slot_bytes([3, 1], 1, 4), Some(12));
    // A BC1 mapping's slots are an eighth of an RGBA8 one's on every level of 4 x 4 or more,
    // and one 8-byte block on the 2 x 2 and 1 x 1 levels.
    let rgba = place(&shape(4096, 256, 128, 4)).unwrap();
    let bc1 = place(&Shape { block: 4, ..shape(4096, 256, 128, 8) }).unwrap();
    for (k, (a, b)) in rgba.levels.iter().zip(&bc1.levels).enumerate() {
        assert_eq!(a.slot_count, b.slot_count);
        if a.slot_bytes >= 64 {
            assert_eq!(a.slot_bytes, 8 * b.slot_bytes, "level {k}");
        } else {
            assert_eq!(b.slot_bytes, 8, "level {k}");
        }
    }
    assert!(bc1.slot_bytes() * 7 < rgba.slot_bytes());
    assert_eq!(place(&Shape { block: 3, ..shape(4096, 256, 128, 8) }), None);
}

#[test]
fn header_fits_and_levels_are_page_aligned_in_order() {
    const { assert!(header::END <= 8192) };
    let p = place(&shape(16384, 1024, 256, 4)).unwrap();
    assert_eq!(p.header_bytes, 8192);
    let mut end = p.header_bytes;
    for (i, l) in p.levels.iter().enumerate() {
        assert_eq!(l.tags % PAGE, 0);
        assert_eq!(l.slots % PAGE, 0);
        assert!(l.tags >= end, "level {i} overlaps the one before");
        assert!(l.slots >= l.tags + l.slot_count * TAG_BYTES as u64);
        end = l.slots + l.slot_count * l.slot_bytes;
    }
    assert!(p.total_bytes >= end);
    // Level 0: a 6x6 grid of 256x256 RGBA tiles; level 4 (1024) is a pyramid level.
    assert_eq!(p.levels[0].slot_count, 36);
    assert_eq!(p.levels[0].slot_bytes, 256 * 256 * 4);
    assert_eq!((p.levels[3].kind, p.levels[4].kind), (0, 1));
    assert_eq!(p.levels[4].slot_count, 1);
}

#[test]
fn tile_ranges_lie_between_tags_and_slots_for_heights_only() {
    let sh = shape(16384, 1024, 256, 4);
    let plain = place(&sh).unwrap();
    let ranged = place_with(&sh, true).unwrap();
    assert!(plain.levels.iter().all(|l| l.ranges == 0 && l.range_offset(0).is_none()));
    let mut extra = 0;
    for (p, r) in plain.levels.iter().zip(&ranged.levels) {
        assert_eq!(r.ranges % PAGE, 0);
        assert!(r.ranges >= r.tags + r.slot_count * TAG_BYTES as u64, "after the tags");
        assert!(r.ranges + r.slot_count * RANGE_BYTES as u64 <= r.slots, "before the slots");
        // 16 bytes a slot, page-rounded: 36 slots take one page, as does a pyramid's one.
        assert_eq!(r.slots - r.ranges, (r.slot_count * 16).div_ceil(PAGE) * PAGE);
        assert_eq!(r.range_offset(3), Some(r.ranges + 48));
        assert_eq!((r.slot_bytes, r.slot_count, r.kind), (p.slot_bytes, p.slot_count, p.kind));
        extra += r.slots - r.ranges;
    }
    assert_eq!(ranged.total_bytes, plain.total_bytes + extra);
}

#[test]
fn too_many_levels_bad_grids_or_overflow_are_refused() {
    let mut many = shape(4, 4, 4, 4);
    many.levels = vec![many.levels[0]; 33];
    assert!(place(&many).is_none());
    let mut small = shape(4096, 1024, 256, 4);
    small.levels[0].grid = [4, 4];
    assert!(place(&small).is_none(), "a 4x4 grid cannot hold a 1024 window of 256 tiles");
    let mut huge = shape(1 << 20, 1 << 20, 1 << 20, 4);
    huge.bytes_per_texel = u64::MAX;
    assert!(place(&huge).is_none());
}

#[test]
fn the_heights_block_round_trips_and_every_bad_value_is_refused_with_its_place() {
    use clipmap_base::height::{HeightFormat, HeightStorage, LevelRule};
    const { assert!(header::HEIGHTS == 6464 && header::END <= 8192) };
    let block = |h: &Heights| HeightsBlock {
        is_heights: 1,
        rule: rule_code(h.levels),
        scale: h.scale.to_bits(),
        offset: h.offset.to_bits(),
        nodata: h.nodata.unwrap_or(f64::NAN).to_bits(),
    };
    for (code, f) in [
        (11, HeightFormat::VERIFICATION),
        (7, HeightFormat::new(HeightStorage::U16, 0.01, -11000.0, Some(0.0)).unwrap()),
        (12, HeightFormat::new(HeightStorage::I16, 0.5, 0.0, None).unwrap()),
    ] {
        for rule in LevelRule::ALL {
            let h = Heights::of(&f, rule);
            assert_eq!(check_heights(code, &block(&h)), Ok(Some(h)));
            assert_eq!(h.format(), f);
        }
    }
    assert_eq!(check_heights(4, &HeightsBlock::default()), Ok(None), "all zero: not heights");
    let good =
        block(&Heights::of(&HeightFormat::new(HeightStorage::U16, 0.01, -11000.0, None).unwrap(), LevelRule::Min));
    let refused = |code: u32, b: HeightsBlock, words: &[&str]| {
        let e = check_heights(code, &b).expect_err("refused");
        for w in words {
            assert!(e.contains(w), "{e:?} lacks {w:?}");
        }
    };
    refused(7, HeightsBlock { scale: f64::NAN.to_bits(), ..good }, &["byte 6472", "scale", "found NaN", "above zero"]);
    refused(7, HeightsBlock { scale: (-1.0f64).to_bits(), ..good }, &["byte 6472", "found -1"]);
    refused(7, HeightsBlock { scale: 0, ..good }, &["byte 6472", "found 0"]);
    refused(
        7,
        HeightsBlock { offset: f64::INFINITY.to_bits(), ..good },
        &["byte 6480", "offset", "found inf", "finite"],
    );
    refused(7, HeightsBlock { rule: 4, ..good }, &["byte 6468", "level rule", "found 4", "3 (max)"]);
    refused(7, HeightsBlock { is_heights: 2, ..good }, &["byte 6464", "found 2", "0 (not heights) or 1"]);
    refused(7, HeightsBlock { nodata: 0.5f64.to_bits(), ..good }, &["byte 6488", "nodata", "whole number"]);
    refused(4, good, &["byte 6464", "texel format code 4", "11 (l32f)"]);
    refused(11, good, &["l32f stores metres"]);
    refused(4, HeightsBlock { scale: 1, ..HeightsBlock::default() }, &["not all zero"]);
}

#[test]
fn slots_wrap_euclidean_and_regions_are_checked() {
    assert_eq!(slot_index([6, 5], [7, 11]), 6 + 1);
    assert_eq!(slot_index([6, 5], [-1, -1]), 4 * 6 + 5);
    let l = LevelShape { size: [4096, 4096], tile: [256, 256], grid: [6, 6] };
    assert!(check_region(&l, [100, 100, 1124, 1124]).is_ok());
    assert!(check_region(&l, [0, 0, 4097, 10]).is_err());
    assert!(check_region(&l, [-1, 0, 10, 10]).is_err());
    assert!(check_region(&l, [5, 5, 5, 9]).is_err());
    assert!(check_region(&l, [0, 0, 256 * 7, 10]).is_err(), "7 tiles wide in a 6-slot grid");
    assert!(check_region(&l, [i64::MIN, 0, i64::MAX, 1]).is_err());
    // A wrapping texture's level: the s-range may run past the width, by at most the width.
    assert!(check_region(&l, [3900, 0, 4200, 10]).is_err(), "past the width without wrapping");
    assert!(check_region_wrapping(&l, [3900, 0, 4200, 10], true).is_ok());
    assert!(check_region_wrapping(&l, [3900, 0, 4200, 10], false).is_err());
    assert!(check_region_wrapping(&l, [4096, 0, 4200, 10], true).is_err(), "s0 at the width");
    assert!(check_region_wrapping(&l, [-1, 0, 200, 10], true).is_err(), "s0 below 0");
    assert!(check_region_wrapping(&l, [3900, 0, 3900 + 4097, 10], true).is_err(), "wider than the level");
    assert!(check_region_wrapping(&l, [3900, 0, 3900 + 256 * 6, 10], true).is_err(), "7 tiles in a 6-slot grid");
    let odd = LevelShape { size: [4000, 4096], tile: [256, 256], grid: [6, 6] };
    assert!(check_region_wrapping(&odd, [3900, 0, 4100, 10], true).is_err(), "a width of no whole tiles never wraps");
}
