//! One input through the TIFF / COG reader as the tools and the service take a file: its
//! structure opened (header, IFD chain, every image's tags, the levels past the overviews built),
//! its description and `cliptex info`'s text, and every tile of every level read, a bounded
//! number of them. Shared by the fuzz target `fuzz/fuzz_targets/tiff_structure.rs` and the
//! property tests `tiff_fuzz_props.rs`: nothing may panic, hang or allocate past the bounds, and
//! what is opened must keep the reader's promises (below).

use clipmap::source::cog::LevelOrigin;
use clipmap::source::{CogSource, TileId, TileSource};
use std::path::Path;
use std::sync::Arc;

/// The most tile reads one input makes.
pub const MAX_READS: u64 = 2048;

/// The largest tile buffer read (bigger tiles are legal up to MAX_TILE_BYTES, but one of them
/// would make every input slow): such levels are described and not read.
pub const MAX_READ_TILE_BYTES: usize = 4 << 20;

/// Opens `data` as a TIFF served at a clip size its first byte picks (32 to 4096) and reads it.
pub fn exercise_tiff(data: &[u8]) {
    let clip = 32u64 << (data.first().copied().unwrap_or(0) % 8);
    let name = Path::new("fuzz.tif");
    let bytes: Arc<[u8]> = Arc::from(data);
    // The full-resolution reader (clipprep's and patches' path) must agree on what it opens.
    let full = CogSource::from_bytes_full_resolution(name, Arc::clone(&bytes));
    let src = match CogSource::from_bytes(name, bytes, clip) {
        Ok(s) => s,
        Err(e) => {
            let text = e.to_string();
            assert!(text.contains("fuzz.tif"), "an error names the file: {text}");
            return;
        }
    };
    let full = full.expect("what opens whole opens at full resolution");
    assert_eq!(full.desc().format(), src.desc().format());
    let desc = src.desc().clone();
    assert_eq!(desc.level_count(), src.origins().len());
    let _ = src.info().human();
    let _ = serde_json::to_string(&src.info()).expect("info serialises");
    // An image's tile index lies in the file: its tile count is bounded by the file's size (the
    // index of up to four tiles fits in its IFD entry).
    for (k, o) in src.origins().iter().enumerate() {
        if let LevelOrigin::Ifd { tile, .. } = o {
            let size = desc.level(k as u32).size;
            let tiles = size[0].div_ceil(tile[0]) * size[1].div_ceil(tile[1]);
            assert!(tiles <= (data.len() as u64 / 2).max(4), "level {k}: {tiles} tiles in {} bytes", data.len());
        }
    }
    let mut reads = 0u64;
    for k in 0..desc.level_count() as u32 {
        let bytes = desc.tile_bytes(k);
        if bytes > MAX_READ_TILE_BYTES {
            continue;
        }
        let mut buf = vec![0u8; bytes];
        let [ts, tt] = desc.level(k).tiles();
        for t in 0..tt {
            for s in 0..ts {
                if reads >= MAX_READS {
                    return;
                }
                reads += 1;
                let _ = src.read_tile(TileId::new(k, s, t), &mut buf);
            }
        }
    }
    // Level 0 through the full-resolution reader, a bounded region.
    let [w, h] = desc.size();
    let (w, h) = (w.min(64), h.min(64));
    let mut out = vec![0u8; (w * h) as usize * desc.bytes_per_texel()];
    let _ = full.read_full_resolution([0, 0], [w, h], &mut out);
}
