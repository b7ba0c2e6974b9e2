//! The engine on a texture that spans 360 degrees of longitude: windows across the antimeridian.

use super::*;

/// A flight of a texture that spans 360 degrees of longitude: from `start`, `steps`, each tick
/// checked; then settled at `end`.
fn wrapping_walk(
    size: [u64; 2],
    tile: u64,
    start: [i64; 2],
    steps: &[Step],
    align: u64,
) -> Result<Clipmap, TestCaseError> {
    let src = hash_source(size, 64, tile, 4, TexelFormat::RGBA8);
    let settings = Settings { wrap_longitude: true, centre_alignment: align, ..settings(Some(2_000_000)) };
    let mut map = Clipmap::new(src, settings).unwrap();
    let mut errors = Vec::new();
    let mut c = start;
    for s in steps {
        match *s {
            Step::Move(a, b) => c = [c[0] + a * 8, c[1] + b],
            Step::Jump(a, b) => c = [a, b],
            Step::Wait => map.wait_for_reads(),
        }
        tick_and_check(&mut map, c, &mut errors);
        prop_assert!(errors.is_empty(), "{:?}", errors);
    }
    map.set_budget_ns(None);
    settle(&mut map, c, 80);
    prop_assert!(check_published(&map).map_err(TestCaseError::fail)? > 0);
    prop_assert_eq!(map.stats().slots_reassigned_under_published, 0);
    Ok(map)
}

proptest! {
    #![proptest_config(Config { cases: 48, rng_seed: RngSeed::Fixed(0x3A7), failure_persistence: None, ..Config::default() })]

    /// Flights back and forth across the antimeridian of a wrapping texture (any centre, also
    /// one a level's width away, a jump, a slow read queue): every published texel is the hash
    /// texture's at s mod width, and no slot is given away under a published region.
    #[test]
    fn wrapping_flights_across_the_antimeridian_publish_only_right_texels(
        wexp in 8u32..=11, hexp in 6u32..=9, tile in prop_oneof![Just(16u64), Just(32u64)],
        start in prop_oneof![Just(0i64), Just(-3i64), Just(2040i64), -3000i64..3000],
        steps in proptest::collection::vec(step(), 1..40), align in prop_oneof![Just(1u64), Just(8u64)],
    ) {
        let size = [1u64 << wexp, 1u64 << hexp];
        wrapping_walk(size, tile, [start, 40], &steps, align)?;
    }
}

#[test]
fn a_window_at_the_antimeridian_holds_both_sides_and_a_texture_that_does_not_wrap_stops_at_its_edge() {
    let size = [1024u64, 256];
    for c in [[1020i64, 100], [-4, 100], [2044, 100]] {
        let map = wrapping_walk(size, 16, c, &[], 1).unwrap();
        let v = map.level(0);
        assert!(v.wrap);
        // The window is centred on the centre (modulo the width), the border on both sides.
        assert_eq!(v.valid, Rect::new(1020 - 32 + 4, 100 - 32 + 4, 1020 + 32 - 4, 100 + 32 - 4), "centre {c:?}");
        assert!(v.texel(1023, 100).is_some() && v.texel(0, 100).is_some() && v.texel(1024, 100).is_some());
        assert_eq!(*v.texel(1030, 100).unwrap(), *v.texel(6, 100).unwrap());
        // Levels wrap while wider than the clip size; the others hold their whole width.
        assert!(map.level(3).wrap && !map.level(4).wrap, "level 4 is 64 wide, the clip size");
        assert_eq!(
            map.cache.grid(0)[0] * (1024 / 16 / map.cache.grid(0)[0]),
            1024 / 16,
            "the grid width divides the tiles across"
        );
    }
    // The same texture not marked global: the window stops at the east edge.
    let src = hash_source(size, 64, 16, 4, TexelFormat::RGBA8);
    let mut map = Clipmap::new(src, settings(None)).unwrap();
    settle(&mut map, [1020, 100], 80);
    let v = map.level(0);
    assert!(!v.wrap);
    assert_eq!(v.valid, Rect::new(1024 - 64 + 4, 100 - 32 + 4, 1024, 100 + 32 - 4));
    assert!(v.texel(1024, 100).is_none() && v.texel(0, 100).is_none());
}
