//! PMTiles v3 directories: tile ids along the Hilbert curve of each zoom, and the varint-encoded
//! directories of entries (delta tile ids, run lengths, lengths, offsets where 0 continues the
//! previous entry) that map tile ids to tiles or to leaf directories.

use super::super::{TileAddr, MAX_ZOOM};
use super::header::Compression;
use std::io::Read;

/// The tile id of the first tile of zoom `z`: the tiles of all coarser zooms, `(4^z - 1) / 3`.
fn zoom_base(z: u8) -> u64 {
    ((1u64 << (2 * u32::from(z))) - 1) / 3
}

/// Rotates and flips a quadrant of side `n` as the Hilbert curve turns.
fn rotate(n: u64, x: &mut u64, y: &mut u64, rx: u64, ry: u64) {
    if ry == 0 {
        if rx != 0 {
            *x = n - 1 - *x;
            *y = n - 1 - *y;
        }
        std::mem::swap(x, y);
    }
}

/// The PMTiles tile id of `at` (a valid address: zoom at most [`MAX_ZOOM`]).
pub fn tile_id(at: TileAddr) -> u64 {
    let (mut x, mut y) = (u64::from(at.x), u64::from(at.y));
    let n = 1u64 << at.z;
    let mut d = 0u64;
    let mut s = n >> 1;
    while s > 0 {
        let rx = u64::from(x & s > 0);
        let ry = u64::from(y & s > 0);
        d += s * s * ((3 * rx) ^ ry);
        rotate(n, &mut x, &mut y, rx, ry);
        s >>= 1;
    }
    zoom_base(at.z) + d
}

/// The address of tile id `id`, or `None` past zoom [`MAX_ZOOM`].
pub fn tile_addr(id: u64) -> Option<TileAddr> {
    let z = (0..=MAX_ZOOM).take_while(|&z| zoom_base(z) <= id).last()?;
    if z == MAX_ZOOM && id >= zoom_base(MAX_ZOOM + 1) {
        return None;
    }
    let n = 1u64 << z;
    let mut t = id - zoom_base(z);
    let (mut x, mut y) = (0u64, 0u64);
    let mut s = 1u64;
    while s < n {
        let rx = 1 & (t / 2);
        let ry = 1 & (t ^ rx);
        rotate(s, &mut x, &mut y, rx, ry);
        x += s * rx;
        y += s * ry;
        t /= 4;
        s *= 2;
    }
    Some(TileAddr { z, x: x as u32, y: y as u32 })
}

/// One directory entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Entry {
    /// The first tile id it covers.
    pub tile_id: u64,
    /// Offset: into the tile data for a tile, into the leaf directories' section for a leaf.
    pub offset: u64,
    /// Length in bytes.
    pub length: u32,
    /// Tiles it covers (consecutive ids of the same bytes); 0 for a leaf directory.
    pub run_length: u32,
}

/// Where a tile id leads in one directory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Found {
    /// The tile's bytes: offset in the tile data and length.
    Tile(u64, u32),
    /// A leaf directory to read next: offset in the leaf section and length.
    Leaf(u64, u32),
    /// No tile.
    Missing,
}

/// Looks tile id `id` up among `entries` (sorted by tile id).
pub fn find(entries: &[Entry], id: u64) -> Found {
    let i = entries.partition_point(|e| e.tile_id <= id);
    let Some(e) = i.checked_sub(1).map(|i| entries[i]) else { return Found::Missing };
    if e.run_length == 0 {
        Found::Leaf(e.offset, e.length)
    } else if id - e.tile_id < u64::from(e.run_length) {
        Found::Tile(e.offset, e.length)
    } else {
        Found::Missing
    }
}

/// Undoes `compression` of `bytes`, refusing more than `limit` bytes out; the problem in words.
pub fn decompress(bytes: &[u8], compression: Compression, limit: u64) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let read = match compression {
        Compression::None => {
            out.extend_from_slice(bytes);
            Ok(bytes.len())
        }
        Compression::Gzip => flate2::read::GzDecoder::new(bytes).take(limit + 1).read_to_end(&mut out),
        Compression::Zstd => {
            zstd::stream::read::Decoder::new(bytes).and_then(|d| d.take(limit + 1).read_to_end(&mut out))
        }
        Compression::Brotli => {
            brotli_decompressor::Decompressor::new(bytes, 4096).take(limit + 1).read_to_end(&mut out)
        }
    };
    read.map_err(|e| format!("cannot undo its {compression:?} compression: {e}"))?;
    if out.len() as u64 > limit {
        return Err(format!("it inflates to more than {limit} bytes, more than this reader accepts"));
    }
    Ok(out)
}

/// Reads one varint at `*at` of `b`.
fn varint(b: &[u8], at: &mut usize) -> Result<u64, String> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let Some(&byte) = b.get(*at) else {
            return Err(format!("a number runs past the directory's end ({} bytes)", b.len()));
        };
        *at += 1;
        v |= u64::from(byte & 0x7f) << shift;
        if byte & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err(format!("a number at byte {} of the directory is longer than 64 bits", *at - 10))
}

/// Parses a decompressed directory; every entry is checked: ids increasing within the zooms
/// this reader reads, tiles within `data_len` bytes of tile data, leaves within `leaves_len`
/// bytes of leaf directories, lengths nonzero. The problem in words when one is not.
pub fn parse(b: &[u8], data_len: u64, leaves_len: u64) -> Result<Vec<Entry>, String> {
    let mut at = 0;
    let n = varint(b, &mut at)?;
    // Each entry takes at least four bytes: a count past that is a damaged directory.
    if n > (b.len() as u64) / 4 {
        return Err(format!("it says {n} entries, more than its {} bytes can hold", b.len()));
    }
    let n = n as usize;
    let mut entries = vec![Entry { tile_id: 0, offset: 0, length: 0, run_length: 0 }; n];
    let mut id = 0u64;
    for (i, e) in entries.iter_mut().enumerate() {
        let delta = varint(b, &mut at)?;
        if i > 0 && delta == 0 {
            return Err(format!("entry {i} repeats tile id {id}: ids must increase"));
        }
        id = id
            .checked_add(delta)
            .filter(|&id| id < zoom_base(MAX_ZOOM + 1))
            .ok_or_else(|| format!("entry {i}'s tile id lies past zoom {MAX_ZOOM}, the deepest this reader reads"))?;
        e.tile_id = id;
    }
    let small = |v: u64, what: &str, i: usize| {
        u32::try_from(v).map_err(|_| format!("entry {i}'s {what} is {v}, more than 2^32 - 1"))
    };
    for (i, e) in entries.iter_mut().enumerate() {
        e.run_length = small(varint(b, &mut at)?, "run length", i)?;
    }
    for (i, e) in entries.iter_mut().enumerate() {
        e.length = small(varint(b, &mut at)?, "length", i)?;
        if e.length == 0 {
            return Err(format!("entry {i} (tile id {}) has length 0", e.tile_id));
        }
    }
    for i in 0..n {
        let v = varint(b, &mut at)?;
        let offset = if v == 0 && i > 0 {
            entries[i - 1].offset + u64::from(entries[i - 1].length)
        } else if v == 0 {
            return Err("entry 0's offset is 0 (\"continues the previous entry\"), but there is none".into());
        } else {
            v - 1
        };
        let e = &mut entries[i];
        e.offset = offset;
        let (section, name) =
            if e.run_length == 0 { (leaves_len, "leaf directories") } else { (data_len, "tile data") };
        if offset.checked_add(u64::from(e.length)).is_none_or(|end| end > section) {
            return Err(format!(
                "entry {i} (tile id {}) points at bytes {offset}..+{} of the {name}, which has {section} bytes",
                e.tile_id, e.length
            ));
        }
    }
    Ok(entries)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Writes `v` as a varint.
    pub(crate) fn put_varint(out: &mut Vec<u8>, mut v: u64) {
        while v >= 0x80 {
            out.push((v as u8) | 0x80);
            v >>= 7;
        }
        out.push(v as u8);
    }

    /// Serializes `entries` as PMTiles v3 does (uncompressed), offsets continuing where they can.
    pub(crate) fn serialize(entries: &[Entry]) -> Vec<u8> {
        let mut b = Vec::new();
        put_varint(&mut b, entries.len() as u64);
        let mut last = 0;
        for e in entries {
            put_varint(&mut b, e.tile_id - last);
            last = e.tile_id;
        }
        entries.iter().for_each(|e| put_varint(&mut b, e.run_length.into()));
        entries.iter().for_each(|e| put_varint(&mut b, e.length.into()));
        for (i, e) in entries.iter().enumerate() {
            let cont = i > 0 && e.offset == entries[i - 1].offset + u64::from(entries[i - 1].length);
            put_varint(&mut b, if cont { 0 } else { e.offset + 1 });
        }
        b
    }

    /// The tiles of zoom `z` in the order of the Hilbert curve, built by recursive subdivision
    /// of the square (the curve's definition), independently of the bit arithmetic above.
    fn hilbert_order(z: u8) -> Vec<(u32, u32)> {
        // A square with corner (x0, y0) and axes (xi, xj), (yi, yj), in units of half a tile.
        #[allow(clippy::too_many_arguments)]
        fn go(out: &mut Vec<(u32, u32)>, x0: i64, y0: i64, xi: i64, xj: i64, yi: i64, yj: i64, n: u8) {
            if n == 0 {
                let (x, y) = (x0 + (xi + yi) / 2, y0 + (xj + yj) / 2);
                out.push(((x / 2) as u32, (y / 2) as u32));
                return;
            }
            go(out, x0, y0, yi / 2, yj / 2, xi / 2, xj / 2, n - 1);
            go(out, x0 + xi / 2, y0 + xj / 2, xi / 2, xj / 2, yi / 2, yj / 2, n - 1);
            go(out, x0 + xi / 2 + yi / 2, y0 + xj / 2 + yj / 2, xi / 2, xj / 2, yi / 2, yj / 2, n - 1);
            go(out, x0 + xi / 2 + yi, y0 + xj / 2 + yj, -yi / 2, -yj / 2, -xi / 2, -xj / 2, n - 1);
        }
        let side = 2i64 << z;
        let mut out = Vec::new();
        // The first step goes from (0, 0) to (0, 1) (row 1, south of the north-west tile), as
        // the specification's tile ids 1..4 are z1 (0,0), (0,1), (1,1), (1,0).
        go(&mut out, 0, 0, 0, side, side, 0, z);
        out
    }

    #[test]
    fn tile_ids_follow_the_specification_s_first_ids() {
        let addr = |z, x, y| TileAddr { z, x, y };
        let want = [
            (0, addr(0, 0, 0)),
            (1, addr(1, 0, 0)),
            (2, addr(1, 0, 1)),
            (3, addr(1, 1, 1)),
            (4, addr(1, 1, 0)),
            (5, addr(2, 0, 0)),
        ];
        for (id, at) in want {
            assert_eq!(tile_id(at), id, "{at}");
            assert_eq!(tile_addr(id), Some(at));
        }
        // The last tile of the deepest zoom, and the first id past it.
        let last = TileAddr { z: MAX_ZOOM, x: (1 << MAX_ZOOM) - 1, y: 0 };
        assert_eq!(tile_addr(tile_id(last)), Some(last));
        assert_eq!(tile_id(last), zoom_base(MAX_ZOOM + 1) - 1);
        assert_eq!(tile_addr(zoom_base(MAX_ZOOM + 1)), None);
    }

    #[test]
    fn tile_ids_equal_a_brute_force_walk_of_the_hilbert_curve() {
        for z in 0..=6u8 {
            let order = hilbert_order(z);
            assert_eq!(order.len() as u64, 1 << (2 * z));
            for (i, &(x, y)) in order.iter().enumerate() {
                let at = TileAddr { z, x, y };
                assert_eq!(tile_id(at), zoom_base(z) + i as u64, "{at}");
                assert_eq!(tile_addr(zoom_base(z) + i as u64), Some(at));
            }
        }
    }

    proptest! {
        #[test]
        fn tile_ids_and_addresses_are_inverse(z in 0..=MAX_ZOOM, x in any::<u32>(), y in any::<u32>()) {
            let mask = ((1u64 << z) - 1) as u32;
            let at = TileAddr { z, x: x & mask, y: y & mask };
            let id = tile_id(at);
            prop_assert!(id >= zoom_base(z) && id < zoom_base(z + 1));
            prop_assert_eq!(tile_addr(id), Some(at));
        }

        #[test]
        fn directories_read_back_as_written(gaps in proptest::collection::vec((1u64..1000, 0u32..5, 1u32..5000, any::<bool>()), 1..200)) {
            let mut entries = Vec::new();
            let (mut id, mut offset) = (0u64, 0u64);
            for (gap, run, len, jump) in gaps {
                id += gap;
                if jump { offset += 7; }
                entries.push(Entry { tile_id: id, offset, length: len, run_length: run });
                offset += u64::from(len);
            }
            let got = parse(&serialize(&entries), offset, offset).unwrap();
            prop_assert_eq!(got, entries);
        }
    }

    #[test]
    fn lookups_find_tiles_runs_leaves_and_gaps() {
        let e = |tile_id, offset, length, run_length| Entry { tile_id, offset, length, run_length };
        let dir = [e(5, 0, 10, 1), e(10, 10, 20, 3), e(20, 0, 100, 0)];
        assert_eq!(find(&dir, 4), Found::Missing);
        assert_eq!(find(&dir, 5), Found::Tile(0, 10));
        assert_eq!(find(&dir, 6), Found::Missing);
        assert_eq!(find(&dir, 12), Found::Tile(10, 20));
        assert_eq!(find(&dir, 13), Found::Missing);
        assert_eq!(find(&dir, 1 << 40), Found::Leaf(0, 100));
    }

    #[test]
    fn damaged_directories_are_refused_saying_what_is_wrong() {
        let e = |tile_id, offset, length, run_length| Entry { tile_id, offset, length, run_length };
        let b = serialize(&[e(1, 0, 10, 1), e(2, 10, 10, 1)]);
        assert!(parse(&b, 19, 0).unwrap_err().contains("bytes 10..+10 of the tile data, which has 19 bytes"));
        assert!(parse(&b[..b.len() - 1], 20, 0).unwrap_err().contains("past the directory's end"));
        let mut huge = Vec::new();
        put_varint(&mut huge, 1 << 40);
        assert!(parse(&huge, 0, 0).unwrap_err().contains("more than its"));
        let b = serialize(&[e(1, 0, 10, 1), e(1, 10, 10, 1)]);
        assert!(parse(&b, 100, 0).unwrap_err().contains("repeats tile id"));
        let b = serialize(&[e(1, 0, 10, 0)]);
        assert!(parse(&b, 100, 5).unwrap_err().contains("leaf directories"));
        let bomb = {
            let mut g = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
            std::io::Write::write_all(&mut g, &vec![0u8; 1 << 20]).unwrap();
            g.finish().unwrap()
        };
        assert!(decompress(&bomb, Compression::Gzip, 1000).unwrap_err().contains("more than 1000 bytes"));
        let z = zstd::encode_all(&b"abc"[..], 3).unwrap();
        assert_eq!(decompress(&z, Compression::Zstd, 10).unwrap(), b"abc");
    }
}
