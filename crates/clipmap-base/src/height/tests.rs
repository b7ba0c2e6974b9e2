//! The height encodings and level rules against brute force.

use super::*;
use proptest::prelude::*;

fn u16_fmt(scale: f64, offset: f64, nodata: Option<f64>) -> HeightFormat {
    HeightFormat::new(HeightStorage::U16, scale, offset, nodata).unwrap()
}

/// The finer texels `(x, y)` below coarser texel `(s, t)`, found by asking every finer texel
/// where it goes (not by computing the block), the even position first.
fn block_by_search(src: &[f64], w: usize, h: usize, s: usize, t: usize) -> Vec<f64> {
    let mut found = Vec::new();
    for y in 0..h {
        for x in 0..w {
            if x / 2 == s && y / 2 == t {
                found.push(((x, y) != (2 * s, 2 * t), src[y * w + x]));
            }
        }
    }
    found.sort_by_key(|&(later, _)| later);
    found.into_iter().map(|(_, v)| v).collect()
}

/// The integer mean by brute force: every stored value between the least and greatest valid one
/// is tried, the nearest to the exact mean wins (the greater on a tie), and one equal to the
/// nodata value gives way to its neighbour on the exact mean's side.
fn integer_mean_oracle(valid: &[i64], nodata: Option<i64>) -> i64 {
    let n = valid.len() as i64;
    let sum: i64 = valid.iter().sum();
    let (lo, hi) = (*valid.iter().min().unwrap(), *valid.iter().max().unwrap());
    let mut best = lo;
    for v in lo..=hi {
        // |v - sum/n| compared as |v n - sum|.
        if (v * n - sum).abs() <= (best * n - sum).abs() {
            best = v;
        }
    }
    match nodata {
        Some(nd) if best == nd => {
            if sum >= nd * n {
                nd + 1
            } else {
                nd - 1
            }
        }
        _ => best,
    }
}

/// The `f32` mean by brute force on values that are multiples of 2^-10: the nearest of the
/// neighbouring floats to the exact mean `S / (1024 n)`, compared exactly as `|c 1024 n - S|`.
fn float_mean_oracle(valid: &[f64], nodata: Option<f64>) -> f64 {
    let n = valid.len() as f64;
    let s: f64 = valid.iter().map(|v| v * 1024.0).sum(); // integers below 2^26: exact
    let guess = (s / 1024.0 / n) as f32;
    let mut cands = [guess.next_down(), guess, guess.next_up()];
    cands.sort_by(|a, b| {
        let (ea, eb) = ((*a as f64 * 1024.0 * n - s).abs(), (*b as f64 * 1024.0 * n - s).abs());
        // On a tie the even significand, as IEEE rounding does.
        ea.partial_cmp(&eb).unwrap().then((a.to_bits() & 1).cmp(&(b.to_bits() & 1)))
    });
    let best = cands[0] as f64;
    match nodata {
        Some(nd) if best == nd => {
            if s / 1024.0 >= nd * n {
                (nd as f32).next_up() as f64
            } else {
                (nd as f32).next_down() as f64
            }
        }
        _ => best,
    }
}

/// The coarser level by brute force.
fn level_oracle(fmt: &HeightFormat, rule: LevelRule, src: &[f64], w: usize, h: usize) -> Vec<f64> {
    let (cw, ch) = ((w / 2).max(1), (h / 2).max(1));
    let mut out = Vec::new();
    for t in 0..ch {
        for s in 0..cw {
            let block = block_by_search(src, w, h, s, t);
            let valid: Vec<f64> = block.iter().copied().filter(|&v| Some(v) != fmt.nodata()).collect();
            let v = match rule {
                LevelRule::Point => block[0],
                _ if valid.is_empty() => fmt.nodata().unwrap(),
                LevelRule::Min => valid.iter().copied().fold(f64::INFINITY, f64::min),
                LevelRule::Max => valid.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                LevelRule::Mean => match fmt.storage() {
                    HeightStorage::F32 => float_mean_oracle(&valid, fmt.nodata()),
                    _ => {
                        let ints: Vec<i64> = valid.iter().map(|&v| v as i64).collect();
                        integer_mean_oracle(&ints, fmt.nodata().map(|v| v as i64)) as f64
                    }
                },
            };
            out.push(v);
        }
    }
    out
}

fn any_rule() -> impl Strategy<Value = LevelRule> {
    prop::sample::select(LevelRule::ALL.to_vec())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn u16_level_rules_equal_brute_force(
        rule in any_rule(),
        nodata in prop::option::of(prop_oneof![Just(0.0), Just(65535.0), Just(500.0), (0u16..=65535).prop_map(f64::from)]),
        centre in prop_oneof![Just(0i64), Just(65535), Just(500), 0i64..=65535],
        spread in 0i64..=200,
        src in (1usize..=9, 1usize..=9).prop_flat_map(|(w, h)| (prop::collection::vec(any::<u16>(), w * h), Just(w), Just(h))),
        holes in prop::collection::vec(any::<bool>(), 81),
    ) {
        // Values within `spread` of `centre` (the nodata value, so that means straddle it, or an
        // end of the range), some texels holes.
        let fmt = u16_fmt(0.01, -11000.0, nodata);
        let (vals, w, h) = src;
        let level: Vec<f64> = vals.iter().zip(&holes).map(|(&r, &hole)| {
            let v = (centre - spread + r as i64 % (2 * spread + 1)).clamp(0, 65535) as f64;
            match nodata {
                Some(nd) if hole => nd,
                Some(nd) if v == nd => if nd < 65535.0 { nd + 1.0 } else { nd - 1.0 },
                _ => v,
            }
        }).collect();
        let got = fmt.reduce_level(rule, &level, w, h).unwrap();
        prop_assert_eq!(&got, &level_oracle(&fmt, rule, &level, w, h), "{} {}x{} {:?}", rule, w, h, level);
        for v in &got {
            prop_assert!((0.0..=65535.0).contains(v) && v.fract() == 0.0);
        }
    }

    #[test]
    fn i16_level_rules_equal_brute_force(
        rule in any_rule(),
        nodata in prop::option::of(prop_oneof![Just(-32768.0), Just(0.0), (-32768i16..=32767).prop_map(f64::from)]),
        src in (1usize..=9, 1usize..=9).prop_flat_map(|(w, h)| (prop::collection::vec(-32768i32..=32767, w * h), Just(w), Just(h))),
        holes in prop::collection::vec(any::<bool>(), 81),
    ) {
        let fmt = HeightFormat::new(HeightStorage::I16, 0.5, 0.0, nodata).unwrap();
        let (vals, w, h) = src;
        // Data values never equal the nodata value; some texels are holes.
        let level: Vec<f64> = vals.iter().zip(&holes).map(|(&v, &hole)| match nodata {
            Some(nd) if hole => nd,
            Some(nd) if v as f64 == nd => if nd < 0.0 { nd + 1.0 } else { nd - 1.0 },
            _ => v as f64,
        }).collect();
        let got = fmt.reduce_level(rule, &level, w, h).unwrap();
        prop_assert_eq!(got, level_oracle(&fmt, rule, &level, w, h));
    }

    #[test]
    fn f32_level_rules_equal_brute_force(
        rule in any_rule(),
        nodata in prop::option::of(prop_oneof![Just(-32768.0), Just(0.0), Just(-3.4e38f32 as f64), (-11_264_000i32..=9_113_600).prop_map(|k| k as f64 / 1024.0)]),
        src in (1usize..=9, 1usize..=9).prop_flat_map(|(w, h)| (prop::collection::vec(-11_264_000i32..=9_113_600, w * h), Just(w), Just(h))),
        holes in prop::collection::vec(any::<bool>(), 81),
        near in any::<bool>(),
    ) {
        // Heights of -11000 m to +8900 m in steps of 2^-10 m (about 1 mm), every one an f32;
        // `near` puts them within a few steps of the nodata value so that means straddle it.
        let fmt = HeightFormat::float(nodata).unwrap();
        let (vals, w, h) = src;
        let level: Vec<f64> = vals.iter().zip(&holes).map(|(&k, &hole)| {
            let v = match (near, nodata) {
                (true, Some(nd)) if nd.abs() < 20000.0 => nd + (k % 5) as f64 / 1024.0,
                _ => k as f64 / 1024.0,
            };
            match nodata {
                Some(nd) if hole => nd,
                Some(nd) if v == nd => nd + 1.0 / 1024.0,
                _ => v,
            }
        }).collect();
        let got = fmt.reduce_level(rule, &level, w, h).unwrap();
        let want = level_oracle(&fmt, rule, &level, w, h);
        prop_assert_eq!(&got, &want);
        for v in got {
            prop_assert_eq!(v as f32 as f64, v, "an f32 value");
        }
    }

    #[test]
    fn tile_ranges_equal_brute_force(
        storage in prop::sample::select(vec![HeightStorage::F32, HeightStorage::U16, HeightStorage::I16]),
        words in prop::collection::vec(any::<u32>(), 0..64),
        nodata_pick in any::<prop::sample::Index>(),
        with_nodata in any::<bool>(),
    ) {
        let (scale, offset) = if storage == HeightStorage::F32 { (1.0, 0.0) } else { (0.25, -1000.0) };
        // Stored values from random bits (f32: finite ones only); nodata one of them.
        let stored: Vec<f64> = words.iter().map(|&w| match storage {
            HeightStorage::F32 => { let f = f32::from_bits(w); if f.is_finite() { f as f64 } else { (w % 1000) as f64 } }
            HeightStorage::U16 => (w as u16) as f64,
            HeightStorage::I16 => (w as u16 as i16) as f64,
        }).collect();
        let nodata = if with_nodata && !stored.is_empty() { Some(stored[nodata_pick.index(stored.len())]) } else { None };
        let fmt = HeightFormat::new(storage, scale, offset, nodata).unwrap();
        let mut bytes = vec![0u8; stored.len() * fmt.bytes_per_texel()];
        for (v, out) in stored.iter().zip(bytes.chunks_exact_mut(fmt.bytes_per_texel())) {
            fmt.write(*v, out);
        }
        // Brute force: the metres of every texel that has data.
        let metres: Vec<f64> = stored.iter().filter_map(|&v| fmt.decode(v)).collect();
        let want = if metres.is_empty() {
            TileRange::Empty
        } else {
            TileRange::Heights {
                min: metres.iter().copied().fold(f64::INFINITY, f64::min),
                max: metres.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            }
        };
        prop_assert_eq!(fmt.tile_range(&bytes).unwrap(), want);
    }

    #[test]
    fn scaled_heights_round_trip(
        signed in any::<bool>(),
        scale_exp in -3i32..=1,
        scale_mant in 1u32..=9,
        offset_k in -50_000i64..=50_000,
        stored in any::<u16>(),
        frac in -0.49f64..0.49,
    ) {
        let scale = scale_mant as f64 * 10f64.powi(scale_exp);
        let offset = offset_k as f64 * 0.1;
        let storage = if signed { HeightStorage::I16 } else { HeightStorage::U16 };
        let fmt = HeightFormat::new(storage, scale, offset, None).unwrap();
        let v = if signed { stored as i16 as f64 } else { stored as f64 };
        // Stored -> metres -> stored is exact.
        let m = fmt.decode(v).unwrap();
        prop_assert_eq!(fmt.encode(m).unwrap(), v);
        // Metres within a step of a stored value come back to it: within half a step.
        let near = m + frac * scale;
        let back = fmt.decode(fmt.encode(near).unwrap()).unwrap();
        prop_assert!((back - near).abs() <= scale * 0.5 + 1e-9 * scale.max(1.0), "{near} -> {back}");
        prop_assert_eq!(fmt.encode(near).unwrap(), v);
    }

    #[test]
    fn f32_heights_round_trip(bits in any::<u32>()) {
        let f = f32::from_bits(bits);
        let fmt = HeightFormat::float(None).unwrap();
        if f.is_finite() {
            prop_assert_eq!(fmt.encode(f as f64).unwrap(), f as f64);
            let mut b = [0u8; 4];
            fmt.write(f as f64, &mut b);
            prop_assert_eq!(b, f.to_le_bytes());
            prop_assert_eq!(fmt.read(&b), f as f64);
        } else {
            let refused = fmt.encode(f as f64).is_err();
            prop_assert!(refused);
        }
    }
}

#[test]
fn a_millimetre_survives_every_level_rule_from_the_deepest_sea_to_the_highest_peak() {
    let fmt = HeightFormat::float(Some(-32768.0)).unwrap();
    for h in [-11000.0, -10999.999, -5000.0, -0.001, 0.0, 0.5, 4000.123, 8899.999, 8900.0 - 0.001] {
        let a = fmt.encode(h).unwrap();
        let b = fmt.encode(h + 0.001).unwrap();
        // f32 holds both apart, each within half its ulp (2^-11 m here) of the metres asked.
        assert!(b > a, "{h}");
        assert!((a - h).abs() <= 2f64.powi(-11) && (b - (h + 0.001)).abs() <= 2f64.powi(-11), "{h}");
        for rule in LevelRule::ALL {
            // A block of equal heights keeps its height, whole or at an edge (one, two texels).
            for others in [&[a, a, a][..], &[a][..], &[][..]] {
                assert_eq!(fmt.reduce(rule, a, others), a, "{rule} {h}");
            }
        }
        // The step between two texels survives point registration, min and max exactly.
        assert_eq!(fmt.reduce(LevelRule::Point, b, &[a, a, a]), b);
        assert_eq!(fmt.reduce(LevelRule::Point, a, &[b, b, b]), a);
        assert_eq!(fmt.reduce(LevelRule::Min, b, &[a, b, b]), a);
        assert_eq!(fmt.reduce(LevelRule::Max, a, &[a, b, -32768.0]), b);
        // And a level of equal heights all the way to 1 x 1.
        let mut level = vec![b; 64];
        let (mut w, mut hh) = (16, 4);
        while w * hh > 1 {
            level = fmt.reduce_level(LevelRule::Mean, &level, w, hh).unwrap();
            (w, hh) = ((w / 2).max(1), (hh / 2).max(1));
            assert!(level.iter().all(|&v| v == b));
        }
    }
}

#[test]
fn centimetre_u16_heights_hold_at_both_ends_of_their_range() {
    // 0.01 m steps from -11000 m: 0 is -11000 m and 65535 is -10344.65 m; and from 8000 m.
    for offset in [-11000.0, 8000.0] {
        let fmt = u16_fmt(0.01, offset, None);
        let (lo, hi) = fmt.metre_bounds();
        assert_eq!((lo, hi), (offset, offset + 655.35));
        for v in [0.0, 1.0, 2.0, 65533.0, 65534.0, 65535.0] {
            assert_eq!(fmt.encode(fmt.decode(v).unwrap()).unwrap(), v, "{offset} {v}");
        }
        assert_eq!(fmt.encode(lo - 0.004).unwrap(), 0.0);
        assert_eq!(fmt.encode(hi + 0.004).unwrap(), 65535.0);
        for past in [lo - 0.006, hi + 0.006, lo - 1e6, hi + 1e6] {
            let e = fmt.encode(past).unwrap_err();
            assert!(matches!(e, HeightError::OutOfRange { .. }), "{past}");
            assert!(e.to_string().contains("scale 0.01 and offset"), "{e}");
        }
        // Means at the ends neither wrap nor leave the range.
        assert_eq!(fmt.reduce(LevelRule::Mean, 65535.0, &[65535.0, 65535.0, 65535.0]), 65535.0);
        assert_eq!(fmt.reduce(LevelRule::Mean, 65535.0, &[65535.0, 65535.0, 65534.0]), 65535.0); // .75 up
        assert_eq!(fmt.reduce(LevelRule::Mean, 65534.0, &[65535.0]), 65535.0); // a half rounds up
        assert_eq!(fmt.reduce(LevelRule::Mean, 0.0, &[0.0, 0.0, 1.0]), 0.0); // .25 down
        assert_eq!(fmt.reduce(LevelRule::Mean, 0.0, &[1.0, 1.0, 0.0]), 1.0);
        let mut b = [0u8; 2];
        fmt.write(65535.0, &mut b);
        assert_eq!(b, [0xff, 0xff]);
        assert_eq!(fmt.read(&b), 65535.0);
    }
}

#[test]
fn nodata_is_never_averaged_in_and_a_mean_never_lands_on_it() {
    let fmt = u16_fmt(1.0, 0.0, Some(100.0));
    // Nodata left out: the mean of 10 and 20 with two holes is 15, not 57.5.
    assert_eq!(fmt.reduce(LevelRule::Mean, 100.0, &[10.0, 100.0, 20.0]), 15.0);
    assert_eq!(fmt.reduce(LevelRule::Mean, 100.0, &[100.0, 100.0, 100.0]), 100.0);
    assert_eq!(fmt.reduce(LevelRule::Min, 100.0, &[100.0, 7.0, 100.0]), 7.0);
    assert_eq!(fmt.reduce(LevelRule::Max, 100.0, &[]), 100.0);
    // Point registration keeps the even texel, nodata or not.
    assert_eq!(fmt.reduce(LevelRule::Point, 100.0, &[1.0, 2.0, 3.0]), 100.0);
    assert_eq!(fmt.reduce(LevelRule::Point, 3.0, &[100.0, 100.0, 100.0]), 3.0);
    // 99 and 101 mean to 100, the nodata value: the coarser texel takes 101 instead (the side of
    // the exact mean, up on a tie), 99 when the exact mean is below.
    assert_eq!(fmt.reduce(LevelRule::Mean, 99.0, &[101.0]), 101.0);
    assert_eq!(fmt.reduce(LevelRule::Mean, 99.0, &[99.0, 101.0, 100.0]), 99.0); // 99.67 rounds to 100
    let f = HeightFormat::float(Some(0.0)).unwrap();
    let m = f.reduce(LevelRule::Mean, -1.0, &[1.0]);
    assert!(m != 0.0 && m > 0.0 && m < 1e-40, "one ulp above zero: {m}");
    assert_eq!(f.decode(0.0), None);
    assert_eq!(f.decode(-2.5), Some(-2.5));
}

#[test]
fn non_finite_heights_are_refused_or_stored_as_nodata_as_asked() {
    let with = HeightFormat::float(Some(-32768.0)).unwrap();
    let without = HeightFormat::float(None).unwrap();
    for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let e = with.encode(v).unwrap_err();
        assert!(e.to_string().contains("not a finite number") && e.to_string().contains("nodata"), "{e}");
        assert_eq!(with.encode_with(v, NonFinite::Nodata).unwrap(), -32768.0);
        let e = without.encode_with(v, NonFinite::Nodata).unwrap_err();
        assert!(e.to_string().contains("declares no nodata value"), "{e}");
    }
    // Finite but beyond f32, and a height that is stored as nodata.
    assert!(matches!(without.encode(1e39).unwrap_err(), HeightError::OutOfRange { .. }));
    let e = with.encode(-32768.0).unwrap_err();
    assert!(e.to_string().contains("the nodata value"), "{e}");
    let u = u16_fmt(0.5, 0.0, Some(0.0));
    assert!(matches!(u.encode(0.2).unwrap_err(), HeightError::IsNodata { .. }));
    assert_eq!(u.encode(0.3).unwrap(), 1.0);
}

#[test]
fn bad_formats_are_refused_with_what_and_how() {
    use HeightStorage::*;
    let cases: Vec<(HeightStorage, f64, f64, Option<f64>, &str)> = vec![
        (U16, f64::NAN, 0.0, None, "it is NaN"),
        (U16, f64::INFINITY, 0.0, None, "finite and above zero"),
        (U16, 0.0, 0.0, None, "finite and above zero"),
        (I16, -0.01, 0.0, None, "finite and above zero"),
        (U16, 1e6, 0.0, None, "past the"),
        (U16, 0.01, f64::NEG_INFINITY, None, "not finite"),
        (U16, 0.01, 2e7, None, "height offset"),
        (U16, 1e-12, 1e6, None, "cannot be told apart"),
        (F32, 0.01, 0.0, None, "l32f stores metres"),
        (F32, 1.0, 5.0, None, "l32f stores metres"),
        (U16, 0.01, 0.0, Some(-1.0), "0..=65535"),
        (U16, 0.01, 0.0, Some(65536.0), "0..=65535"),
        (I16, 0.01, 0.0, Some(32768.0), "-32768..=32767"),
        (I16, 0.01, 0.0, Some(0.5), "whole number"),
        (U16, 0.01, 0.0, Some(f64::NAN), "whole number"),
        (F32, 1.0, 0.0, Some(f64::NAN), "NaN is never stored"),
        (F32, 1.0, 0.0, Some(0.1), "not exactly a 32-bit float"),
    ];
    for (storage, scale, offset, nodata, says) in cases {
        let e = HeightFormat::new(storage, scale, offset, nodata).unwrap_err().to_string();
        assert!(e.contains(says), "{storage} {scale} {offset} {nodata:?}: {e}");
        // Every message says how to fix it.
        assert!(e.contains("give") || e.contains("remove") || e.contains("choose"), "{e}");
    }
    assert!(HeightFormat::new(I16, 0.1, -100.0, Some(-32768.0)).is_ok());
}

#[test]
fn hostile_tiles_are_refused_not_panicked_on() {
    let f = HeightFormat::float(None).unwrap();
    let e = f.tile_range(&[0, 0, 0]).unwrap_err();
    assert_eq!(e, HeightError::TileLength { len: 3, bytes_per_texel: 4 });
    let mut bytes = Vec::new();
    for v in [1.0f32, f32::NAN, 2.0] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    let e = f.tile_range(&bytes).unwrap_err();
    assert!(matches!(e, HeightError::TileNotFinite { index: 1, .. }), "{e:?}");
    assert!(e.to_string().contains("texel 1"), "{e}");
    assert_eq!(f.tile_range(&[]).unwrap(), TileRange::Empty);
    let u = u16_fmt(0.01, -11000.0, Some(0.0));
    assert_eq!(u.tile_range(&[0, 0, 0, 0]).unwrap(), TileRange::Empty);
    assert_eq!(
        u.tile_range(&[0, 0, 0xff, 0xff, 1, 0]).unwrap(),
        TileRange::Heights { min: -11000.0 + 0.01, max: -11000.0 + 655.35 }
    );
    assert_eq!(u.reduce_level(LevelRule::Mean, &[1.0, 2.0, 3.0], 2, 2), None);
    assert_eq!(u.reduce_level(LevelRule::Mean, &[], 0, 0), None);
    assert_eq!(u.reduce_level(LevelRule::Mean, &[1.0], usize::MAX, 2), None);
}

#[test]
fn names_round_trip() {
    for s in [HeightStorage::F32, HeightStorage::U16, HeightStorage::I16] {
        assert_eq!(HeightStorage::from_short_name(s.short_name()), Some(s));
    }
    assert_eq!(HeightStorage::from_short_name("l8"), None);
    for r in LevelRule::ALL {
        assert_eq!(LevelRule::from_name(r.name()), Some(r));
    }
    assert_eq!(LevelRule::from_name("median"), None);
    let r = TileRange::Heights { min: 1.0, max: 2.0 }.union(TileRange::Heights { min: -1.0, max: 0.0 });
    assert_eq!(r, TileRange::Heights { min: -1.0, max: 2.0 });
    assert_eq!(TileRange::Empty.union(r), r);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Point-registered levels leave no crack between mesh rings: every coarser vertex is the
    /// level-0 vertex at its position (`2^k` times its index), so the shared vertices of a fine
    /// ring and the coarse ring around it are the same heights; and a fine boundary vertex
    /// between two shared ones, snapped to the midpoint of the coarse edge, lies exactly on that
    /// edge. The mean rule, by contrast, moves coarse vertices off the fine surface (checked so
    /// that the test could fail).
    #[test]
    fn point_registered_levels_meet_the_finer_mesh_without_cracks(
        log2 in 2u32..=5,
        ks in prop::collection::vec(-11_264_000i32..=9_113_600, 32 * 32),
    ) {
        let n = 1usize << log2;
        let fmt = HeightFormat::float(None).unwrap();
        let level0: Vec<f64> = ks[..n * n].iter().map(|&k| k as f64 / 1024.0).collect();
        let (mut level, mut size, mut k) = (level0.clone(), n, 0u32);
        let mut mean = level0.clone();
        let mut mean_moved = false;
        while size > 1 {
            let coarser = fmt.reduce_level(LevelRule::Point, &level, size, size).unwrap();
            mean = fmt.reduce_level(LevelRule::Mean, &mean, size, size).unwrap();
            let (fine, cs) = (size, size / 2);
            k += 1;
            for j in 0..cs {
                for i in 0..cs {
                    let v = coarser[j * cs + i];
                    // The level-0 vertex under it, and the finer level's.
                    prop_assert_eq!(v, level0[(j << k) * n + (i << k)]);
                    prop_assert_eq!(v, level[(2 * j) * fine + 2 * i]);
                    mean_moved |= mean[j * cs + i] != level0[(j << k) * n + (i << k)];
                }
            }
            // The stitch along the coarse ring's edges: a fine vertex between two coarse vertices
            // snapped to their midpoint is the coarse edge's height there (no T-junction gap).
            for j in 0..cs {
                for i in 0..cs.saturating_sub(1) {
                    let (a, b) = (coarser[j * cs + i], coarser[j * cs + i + 1]);
                    let (fa, fb) = (level[(2 * j) * fine + 2 * i], level[(2 * j) * fine + 2 * i + 2]);
                    prop_assert_eq!((fa + fb) / 2.0, (a + b) / 2.0);
                }
            }
            level = coarser;
            size = cs;
        }
        // Random heights: the mean moves some coarse vertex off the fine surface.
        prop_assert!(mean_moved);
    }
}
