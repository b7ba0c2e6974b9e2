//! The georeferencing against brute force: the slippy-map formulas of WebMercatorQuad, exact
//! values where the arithmetic is exact (the prime meridian, the equator, the antimeridian), at
//! 2^26, 2^28 and 2^30 texels a side.

use super::*;
use proptest::prelude::*;

/// Level-0 edges under test and their zoom at 256-texel tiles.
const ZOOMS: [u32; 3] = [18, 20, 22];

/// The slippy-map texel of (lon, lat) at `n` texels a side, t from the south: the textbook
/// formulas (OSM's wiki), a different path from the module's.
fn brute(n: f64, lon: f64, lat: f64) -> [f64; 2] {
    let r = lat.to_radians();
    let s = (lon + 180.0) / 360.0 * n;
    // The slippy-map formula ln(tan + sec), taken on |lat| and given lat's sign (the projection is
    // odd): south of the equator tan + sec cancels (0.04 at -85 degrees, from 11.4 and 11.4), which
    // would leave this oracle 1e-5 texel off at 2^30 rather than the code under test.
    let y = (r.abs().tan() + 1.0 / r.abs().cos()).ln().copysign(r);
    let from_north = (1.0 - y / std::f64::consts::PI) / 2.0 * n;
    [s, n - from_north]
}

#[test]
fn web_mercator_quad_is_exact_at_the_prime_meridian_the_equator_and_the_antimeridian() {
    for z in ZOOMS {
        let g = Georef::web_mercator_quad(z, 256);
        let n = (256u64 << z) as f64;
        assert_eq!(g.size(), [256 << z, 256 << z]);
        assert_eq!(g.lonlat_to_texel(0, [0.0, 0.0]).unwrap(), [n / 2.0, n / 2.0], "zoom {z}");
        assert_eq!(g.lonlat_to_texel(0, [-180.0, 0.0]).unwrap(), [0.0, n / 2.0]);
        assert_eq!(g.lonlat_to_texel(0, [180.0, 0.0]).unwrap(), [n, n / 2.0]);
        assert_eq!(g.texel_to_lonlat(0, [n / 2.0, n / 2.0]).unwrap(), [0.0, 0.0]);
        assert_eq!(g.texel_to_lonlat(0, [0.0, n / 2.0]).unwrap(), [-180.0, 0.0]);
        // The square's edges are +-85.0511...: the corners, to a millionth of a texel.
        let [s, t] = g.lonlat_to_texel(0, [180.0, WEB_MERCATOR_MAX_LAT]).unwrap();
        assert_eq!(s, n);
        assert!((t - n).abs() < 1e-6, "zoom {z}: t {t} at the north edge, expected {n}");
        let [_, t] = g.lonlat_to_texel(0, [-180.0, -WEB_MERCATOR_MAX_LAT]).unwrap();
        assert!(t.abs() < 1e-6, "zoom {z}: t {t} at the south edge");
        let [_, lat] = g.texel_to_lonlat(0, [0.0, n]).unwrap();
        assert!((lat - WEB_MERCATOR_MAX_LAT).abs() < 1e-12, "{lat}");
        assert!(g.is_global_in_longitude());
    }
}

#[test]
fn beyond_web_mercators_latitudes_and_outside_the_texture_is_refused_with_the_domain() {
    let g = Georef::web_mercator_quad(22, 256);
    let e = g.lonlat_to_texel(0, [10.0, 85.06]).unwrap_err();
    assert!(matches!(e, GeorefError::OutsideDomain { .. }), "{e}");
    assert!(e.to_string().contains("[-85.05112877980659, 85.05112877980659]"), "{e}");
    assert!(g.lonlat_to_texel(0, [10.0, -85.0512]).is_err());
    assert!(g.lonlat_to_texel(0, [f64::NAN, 0.0]).is_err());
    let n = (256u64 << 22) as f64;
    let e = g.texel_to_lonlat(0, [n + 1.0, 0.0]).unwrap_err();
    assert!(e.to_string().contains("outside level 0, whose texels are s in [0, 1073741824]"), "{e}");
    assert!(g.texel_to_lonlat(3, [0.0, -0.5]).is_err());
    // A regional texture: outside its extent.
    let utm = Georef::new(
        Crs::epsg(32633).unwrap(),
        GeoTransform([400_000.0, 10.0, 0.0, 4_700_000.0, 0.0, -10.0]),
        [1000, 1000],
    )
    .unwrap();
    assert!(!utm.is_global_in_longitude());
    let e = utm.lonlat_to_texel(0, [0.0, 0.0]).unwrap_err();
    assert!(matches!(e, GeorefError::OutsideTexture { .. }), "{e}");
}

#[test]
fn tile_corners_are_web_mercator_quads() {
    // Tile (z, x, y): x east from -180, y south from the north edge, 2^z a side.
    for max in ZOOMS {
        let g = Georef::web_mercator_quad(max, 256);
        for z in [0u32, 1, 7, max / 2, max - 1, max] {
            let k = max - z;
            let tiles = 1u64 << z;
            let span = 2.0 * WEB_MERCATOR_HALF / tiles as f64;
            for (x, y) in [(0, 0), (tiles - 1, tiles - 1), (tiles / 2, tiles / 3), (tiles / 5, tiles - 1)] {
                let west_north = g.texel_to_map(k, [(x * 256) as f64, ((tiles - y) * 256) as f64]).unwrap();
                let east_south = g.texel_to_map(k, [((x + 1) * 256) as f64, ((tiles - y - 1) * 256) as f64]).unwrap();
                let want = [
                    -WEB_MERCATOR_HALF + x as f64 * span,
                    WEB_MERCATOR_HALF - y as f64 * span,
                    -WEB_MERCATOR_HALF + (x + 1) as f64 * span,
                    WEB_MERCATOR_HALF - (y + 1) as f64 * span,
                ];
                let got = [west_north[0], west_north[1], east_south[0], east_south[1]];
                for (a, b) in got.iter().zip(want) {
                    assert!((a - b).abs() <= 1e-8, "max zoom {max}, tile ({z}, {x}, {y}): {got:?} vs {want:?}");
                }
            }
        }
    }
}

#[test]
fn a_levels_transform_is_level_zeros_halved_anchored_at_the_south_west() {
    let g = Georef::new(Crs::wgs84(), GeoTransform([10.0, 0.5, 0.0, 50.0, 0.0, -0.25]), [1024, 512]).unwrap();
    assert_eq!(g.level_transform(0), g.geotransform());
    assert_eq!(g.level_transform(3).0, [10.0, 4.0, 0.0, 50.0, 0.0, -2.0]);
    assert_eq!(g.texel_size(3), [4.0, 2.0]);
    // 100 x 75: level 1 is 50 x 37, its top row one level-0 row south of level 0's top edge.
    let g = Georef::new(Crs::wgs84(), GeoTransform([0.0, 1.0, 0.0, 75.0, 0.0, -1.0]), [100, 75]).unwrap();
    assert_eq!(g.level_size(1), [50, 37]);
    assert_eq!(g.level_transform(1).0, [0.0, 2.0, 0.0, 74.0, 0.0, -2.0]);
    // Level 1's texel (3, 5) is level 0's (6, 10) to (8, 12): the same map points.
    assert_eq!(g.texel_to_map(1, [3.0, 5.0]).unwrap(), g.texel_to_map(0, [6.0, 10.0]).unwrap());
    assert_eq!(g.texel_to_map(1, [4.0, 6.0]).unwrap(), g.texel_to_map(0, [8.0, 12.0]).unwrap());
    // A rotated transform inverts.
    let g = Georef::new(Crs::wgs84(), GeoTransform([5.0, 0.01, 0.002, 40.0, 0.003, -0.01]), [300, 200]).unwrap();
    let st = g.map_to_texel(2, g.texel_to_map(2, [10.25, 20.5]).unwrap()).unwrap();
    assert!((st[0] - 10.25).abs() < 1e-9 && (st[1] - 20.5).abs() < 1e-9, "{st:?}");
    assert!(Georef::new(Crs::wgs84(), GeoTransform([0.0, 0.0, 0.0, 0.0, 0.0, -1.0]), [1, 1]).is_err());
    assert!(Georef::new(Crs::wgs84(), GeoTransform([0.0, f64::NAN, 0.0, 0.0, 0.0, -1.0]), [1, 1]).is_err());
}

#[test]
fn level_sizes_are_the_tiles_level_sizes() {
    for size in [[1u64, 1], [100, 75], [1536, 1024], [1 << 30, 3], [(1 << 26) + 1, 7]] {
        let g = Georef::new(Crs::wgs84(), GeoTransform([0.0, 1.0, 0.0, 0.0, 0.0, -1.0]), size).unwrap();
        for k in [0, 1, 2, 5, 13, 31, 40, 63, 64, 99] {
            assert_eq!(g.level_size(k), crate::tile::level_size(size, k), "{size:?} level {k}");
        }
    }
}

#[test]
fn a_global_geographic_texture_wraps_its_longitudes() {
    // 0..360 degrees east: -10 degrees is at 350.
    let g =
        Georef::new(Crs::wgs84(), GeoTransform([0.0, 360.0 / 4096.0, 0.0, 90.0, 0.0, -180.0 / 2048.0]), [4096, 2048])
            .unwrap();
    assert!(g.is_global_in_longitude());
    let [s, t] = g.lonlat_to_texel(0, [-10.0, 0.0]).unwrap();
    assert_eq!([s, t], [4096.0 * 350.0 / 360.0, 1024.0]);
    let half = Georef::new(Crs::wgs84(), GeoTransform([0.0, 0.1, 0.0, 90.0, 0.0, -0.1]), [1800, 1800]).unwrap();
    assert!(!half.is_global_in_longitude());
}

#[test]
fn utm_through_proj4rs_puts_the_central_meridian_at_500_km() {
    let crs = Crs::epsg(32633).unwrap();
    assert_eq!(crs.definition(), "+proj=utm +zone=33 +datum=WGS84 +units=m +no_defs");
    let [x, y] = crs.from_lonlat([15.0, 0.0]).unwrap();
    assert!((x - 500_000.0).abs() < 1e-6 && y.abs() < 1e-6, "{x} {y}");
    let [lon, lat] = crs.to_lonlat(crs.from_lonlat([13.4, 52.5]).unwrap()).unwrap();
    assert!((lon - 13.4).abs() < 1e-10 && (lat - 52.5).abs() < 1e-10, "{lon} {lat}");
    let south = Crs::epsg(32733).unwrap();
    let [_, y] = south.from_lonlat([15.0, -10.0]).unwrap();
    assert!(y > 8_000_000.0 && y < 10_000_000.0, "{y}");
    assert_eq!(Crs::epsg(3857).unwrap(), Crs::web_mercator());
    assert!(matches!(Crs::epsg(1), Err(GeorefError::UnknownEpsg(1))));
    let unknown = Crs::unknown(None, "a local grid");
    assert!(matches!(unknown.to_lonlat([0.0, 0.0]), Err(GeorefError::NoDefinition { .. })));
}

/// Cases per property: enough to land near each extreme many times.
fn config() -> ProptestConfig {
    ProptestConfig { cases: 2000, ..ProptestConfig::default() }
}

/// Longitudes and latitudes near the extremes as often as anywhere.
fn lon() -> impl Strategy<Value = f64> {
    prop_oneof![-180.0..=180.0f64, -180.0..-179.999f64, 179.999..=180.0f64, -1e-6..1e-6f64]
}

fn lat() -> impl Strategy<Value = f64> {
    let m = WEB_MERCATOR_MAX_LAT;
    prop_oneof![-m..=m, (m - 1e-3)..=m, -m..(-m + 1e-3), -1e-6..1e-6f64]
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn lonlat_to_texel_agrees_with_the_slippy_map_formulas(lon in lon(), lat in lat(), z in 0usize..3) {
        let g = Georef::web_mercator_quad(ZOOMS[z], 256);
        let n = g.size()[0] as f64;
        let got = g.lonlat_to_texel(0, [lon, lat]).unwrap();
        let want = brute(n, lon, lat);
        // Two paths through f64 at up to 2^30: a few ulps of 2^30 apart (1.2e-7 each).
        prop_assert!((got[0] - want[0]).abs() < 1e-6, "s {} vs {}", got[0], want[0]);
        prop_assert!((got[1] - want[1]).abs() < 1e-5, "t {} vs {}", got[1], want[1]);
    }

    #[test]
    fn lonlat_texel_lonlat_drifts_less_than_a_thousandth_of_a_texel_at_2_30(lon in lon(), lat in lat(), k in 0u32..4) {
        let g = Georef::web_mercator_quad(22, 256);
        let st = g.lonlat_to_texel(k, [lon, lat]).unwrap();
        let back = g.texel_to_lonlat(k, st).unwrap();
        let again = g.lonlat_to_texel(k, back).unwrap();
        prop_assert!((st[0] - again[0]).abs() < 1e-3 && (st[1] - again[1]).abs() < 1e-3, "{st:?} -> {back:?} -> {again:?}");
        prop_assert!((back[0] - lon).abs() < 1e-9, "{lon} -> {}", back[0]);
    }

    #[test]
    fn texel_lonlat_texel_is_the_texel_at_2_30(s in 0.0..=1073741824.0f64, t in 0.0..=1073741824.0f64) {
        let g = Georef::web_mercator_quad(22, 256);
        let back = g.lonlat_to_texel(0, g.texel_to_lonlat(0, [s, t]).unwrap()).unwrap();
        prop_assert!((back[0] - s).abs() < 1e-3 && (back[1] - t).abs() < 1e-3, "({s}, {t}) -> {back:?}");
    }
}

#[test]
fn the_round_trip_drift_at_2_30_over_a_sweep_to_the_edges_stays_under_a_thousandth_of_a_texel() {
    let g = Georef::web_mercator_quad(22, 256);
    let mut worst = 0.0f64;
    for i in 0..=400 {
        let lon = -180.0 + 360.0 * i as f64 / 400.0;
        for j in 0..=400 {
            let lat = WEB_MERCATOR_MAX_LAT * (2.0 * j as f64 / 400.0 - 1.0);
            let st = g.lonlat_to_texel(0, [lon, lat]).unwrap();
            let again = g.lonlat_to_texel(0, g.texel_to_lonlat(0, st).unwrap()).unwrap();
            worst = worst.max((st[0] - again[0]).abs()).max((st[1] - again[1]).abs());
        }
    }
    println!("round trip lon/lat -> texel -> lon/lat -> texel at 2^30: worst drift {worst:e} texel");
    assert!(worst < 1e-3, "{worst}");
}
