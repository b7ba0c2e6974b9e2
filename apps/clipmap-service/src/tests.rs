//! The service's procedural textures against the other tools': one terrain everywhere.

use clipmap::source::{Procedural, TileSource};

#[test]
fn the_terrain_flag_gives_the_same_texture_in_every_tool() {
    use clipmap::tile::TileId;
    // `cliptex roam --source terrain`, `clipmapd --source terrain` and the accuracy study
    // serve one texture (and `clipprep --source terrain` prepares its level 0 with the same
    // seed by default): a tile at each level-0 corner and one of a coarse level, texel for
    // texel.
    let (size, clip, tile) = (1u64 << 12, 128, 64);
    let roam = clipmap::roam::RoamOptions::procedural(
        Procedural::Terrain,
        size,
        clip,
        tile,
        0,
        clipmap::roam::Flight::Hover,
        1,
    )
    .unwrap();
    let served = crate::procedural_source(Procedural::Terrain, size, clip, tile).unwrap();
    let case =
        clipmap::accuracy::study::Case { size, clip_size: clip, tile, ..clipmap::accuracy::study::Case::small() };
    let studied = clipmap::accuracy::study::source(&case).unwrap();
    let seeded = clipmap::source::TerrainSource::new(roam.source.desc().clone(), clipmap::source::TERRAIN_SEED);
    let read = |src: &dyn TileSource, t: TileId| {
        let mut out = vec![0u8; src.desc().tile_bytes(t.level)];
        src.read_into(t, &mut out).unwrap();
        out
    };
    for t in [TileId::new(0, 0, 0), TileId::new(0, 63, 63), TileId::new(3, 2, 5)] {
        let want = read(roam.source.as_ref(), t);
        assert!(want.iter().any(|&b| b != 0), "{t}: an empty tile compares nothing");
        assert!(read(served.as_ref(), t) == want, "{t}: clipmapd's terrain differs from cliptex roam's");
        assert!(read(studied.as_ref(), t) == want, "{t}: the accuracy study's terrain differs");
        assert!(read(&seeded, t) == want, "{t}: the terrain of TERRAIN_SEED differs");
    }
}
