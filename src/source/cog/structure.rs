//! A TIFF's structure: the header's byte order and flavour ([`Layout`]), the IFD chain and its
//! entries, GDAL's ghost area, and the reader of structure at open ([`Head`]: the first bytes,
//! then windows of the range reader), and [`Span`], a run of bytes read at once.

use super::{MAX_ENTRIES, MAX_IFDS, MAX_STRUCTURE_BYTES};
use crate::source::range::{RangeError, RangeReader};
use std::cell::RefCell;

/// Byte order and TIFF flavour of a file.
#[derive(Clone, Copy, Debug)]
pub(super) struct Layout {
    pub(super) little: bool,
    pub(super) big: bool,
}

impl Layout {
    pub(super) fn u16(&self, b: &[u8]) -> u16 {
        let a = [b[0], b[1]];
        if self.little {
            u16::from_le_bytes(a)
        } else {
            u16::from_be_bytes(a)
        }
    }

    pub(super) fn u32(&self, b: &[u8]) -> u32 {
        let a = [b[0], b[1], b[2], b[3]];
        if self.little {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        }
    }

    pub(super) fn u64(&self, b: &[u8]) -> u64 {
        let a = [b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]];
        if self.little {
            u64::from_le_bytes(a)
        } else {
            u64::from_be_bytes(a)
        }
    }

    /// An offset-sized field: 4 bytes in TIFF, 8 in BigTIFF.
    pub(super) fn offset(&self, b: &[u8]) -> u64 {
        if self.big {
            self.u64(b)
        } else {
            self.u32(b) as u64
        }
    }

    /// The value field of an entry: 4 bytes in TIFF, 8 in BigTIFF.
    pub(super) fn field(&self) -> usize {
        if self.big {
            8
        } else {
            4
        }
    }

    /// An unsigned value of TIFF type `ty` (BYTE, SHORT, LONG, LONG8) from its bytes.
    pub(super) fn value(&self, ty: u16, b: &[u8]) -> u64 {
        match ty {
            1 => b[0] as u64,
            3 => self.u16(b) as u64,
            4 | 13 => self.u32(b) as u64,
            _ => self.u64(b),
        }
    }
}

/// Bytes of one value of an unsigned integer TIFF type, `None` for other types.
pub(super) fn unsigned_size(ty: u16) -> Option<u64> {
    match ty {
        1 => Some(1),
        3 => Some(2),
        4 | 13 => Some(4),
        16 | 18 => Some(8),
        _ => None,
    }
}

/// One IFD entry: tag, type, count and its raw value field (the value itself when it fits,
/// else the offset of its values).
#[derive(Clone, Copy, Debug)]
pub(super) struct Entry {
    pub(super) tag: u16,
    pub(super) ty: u16,
    pub(super) count: u64,
    pub(super) field: [u8; 8],
}

/// What an IFD says about its image (the tags this source reads).
pub(super) struct Image {
    pub(super) ifd: usize,
    pub(super) subfile: u64,
    pub(super) entries: Vec<Entry>,
}

/// What GDAL's ghost area (structural metadata right after the header) says about the tiles'
/// framing: each tile preceded by its byte count (`BLOCK_LEADER=SIZE_AS_UINT4`, 4 bytes,
/// little-endian) and followed by its last 4 bytes again (`BLOCK_TRAILER=LAST_4_BYTES_REPEATED`),
/// unless the file was changed since (`KNOWN_INCOMPATIBLE_EDITION=YES`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Ghost {
    pub(super) leader: bool,
    pub(super) trailer: bool,
}

impl Ghost {
    /// The ghost area at `at` of the file's first bytes `prefix`, if there is one.
    pub(super) fn parse(prefix: &[u8], at: usize) -> Ghost {
        const KEY: &[u8] = b"GDAL_STRUCTURAL_METADATA_SIZE=";
        let Some(rest) = prefix.get(at..).filter(|r| r.starts_with(KEY)) else { return Ghost::default() };
        let digits = &rest[KEY.len()..];
        let n = digits.iter().take_while(|b| b.is_ascii_digit()).count();
        let Some(size) = std::str::from_utf8(&digits[..n]).ok().and_then(|d| d.parse::<usize>().ok()) else {
            return Ghost::default();
        };
        // The size counts the bytes after the first line.
        let Some(line) = rest.iter().position(|&b| b == b'\n') else { return Ghost::default() };
        let text = &rest[(line + 1).min(rest.len())..(line + 1).saturating_add(size).min(rest.len())];
        let has = |s: &[u8]| text.windows(s.len()).any(|w| w == s);
        if has(b"KNOWN_INCOMPATIBLE_EDITION=YES") {
            return Ghost::default();
        }
        Ghost { leader: has(b"BLOCK_LEADER=SIZE_AS_UINT4"), trailer: has(b"BLOCK_TRAILER=LAST_4_BYTES_REPEATED") }
    }
}

/// The structure reader at open: the first bytes, then the store.
pub(super) struct Head<'a> {
    pub(super) bytes: &'a dyn RangeReader,
    pub(super) prefix: &'a [u8],
    /// The first read that failed for another reason than the file's end (a remote object that
    /// could not be read, or changed): open says so rather than calling the file damaged.
    pub(super) failed: RefCell<Option<String>>,
    /// Runs of bytes past the prefix read so far ([`STRUCTURE_WINDOW`] at least each), so that
    /// an IFD past the first bytes costs one read, not one for its count and one for its entries.
    pub(super) windows: RefCell<Vec<(u64, Vec<u8>)>>,
}

/// The least a read of structure past the first bytes takes (one request of a remote object).
pub(super) const STRUCTURE_WINDOW: u64 = 16 << 10;

impl Head<'_> {
    /// `len` bytes at `offset`, or what is wrong (where, what).
    pub(super) fn read_at(&self, offset: u64, len: usize, what: &str) -> Result<Vec<u8>, (String, String)> {
        if let Some(b) = (Span { start: 0, bytes: self.prefix }).get(offset, len as u64) {
            return Ok(b.to_vec());
        }
        for (start, bytes) in self.windows.borrow().iter() {
            if let Some(b) = (Span { start: *start, bytes }).get(offset, len as u64) {
                return Ok(b.to_vec());
            }
        }
        // At least a window, not past the end of the file (a short read there is the error).
        let size = self.bytes.size();
        let wide = (len as u64).max(STRUCTURE_WINDOW.min(size.saturating_sub(offset)));
        let mut buf = vec![0u8; wide as usize];
        self.bytes.read_at(offset, &mut buf).map_err(|e| {
            let problem = e.problem(offset, len as u64);
            if !matches!(e, RangeError::Eof { .. }) {
                self.failed.borrow_mut().get_or_insert_with(|| problem.clone());
            }
            (what.to_string(), problem)
        })?;
        let out = buf[..len].to_vec();
        self.windows.borrow_mut().push((offset, buf));
        Ok(out)
    }
}

/// Reads the IFD chain from `first`: every IFD's entries, none of the arrays they point to.
pub(super) fn read_ifds(file: &Head, layout: Layout, first: u64) -> Result<Vec<Image>, (String, String)> {
    let mut images = Vec::new();
    let mut next = first;
    let mut seen = std::collections::HashSet::new();
    let mut read_total = 0u64;
    while next != 0 {
        let ifd = images.len();
        let at = format!("IFD {ifd} at byte {next}");
        if ifd >= MAX_IFDS {
            return Err((at, format!("the chain has more than {MAX_IFDS} IFDs")));
        }
        if !seen.insert(next) {
            return Err((at, "the IFD chain loops back to an IFD already read".into()));
        }
        let count_size = if layout.big { 8 } else { 2 };
        let head = file.read_at(next, count_size, &at)?;
        let count = if layout.big { layout.u64(&head) } else { layout.u16(&head) as u64 };
        if count == 0 || count > MAX_ENTRIES {
            return Err((at, format!("{count} entries, expected 1 to {MAX_ENTRIES}")));
        }
        let entry_size = if layout.big { 20 } else { 12 };
        let len = count * entry_size + layout.field() as u64;
        read_total += len;
        if read_total > MAX_STRUCTURE_BYTES {
            return Err((at, format!("the IFDs take more than {MAX_STRUCTURE_BYTES} bytes")));
        }
        let body = file.read_at(next + count_size as u64, len as usize, &at)?;
        let mut entries = Vec::with_capacity(count as usize);
        for e in body.chunks_exact(entry_size as usize).take(count as usize) {
            let tag = layout.u16(&e[0..]);
            let ty = layout.u16(&e[2..]);
            let (count, value) =
                if layout.big { (layout.u64(&e[4..]), &e[12..20]) } else { (layout.u32(&e[4..]) as u64, &e[8..12]) };
            let mut field = [0u8; 8];
            field[..value.len()].copy_from_slice(value);
            entries.push(Entry { tag, ty, count, field });
        }
        let mut image = Image { ifd, subfile: 0, entries };
        image.subfile = scalar(file, layout, &image, 254, "NewSubfileType (254)")?.unwrap_or(0);
        images.push(image);
        next = layout.offset(&body[(count * entry_size) as usize..]);
    }
    if images.is_empty() {
        return Err(("the header".into(), "it names no IFD (offset 0)".into()));
    }
    Ok(images)
}

/// The unsigned values of tag `tag` (at most `max` of them), `None` when the IFD lacks it.
pub(super) fn values(
    file: &Head,
    layout: Layout,
    image: &Image,
    tag: u16,
    name: &str,
    max: u64,
) -> Result<Option<Vec<u64>>, (String, String)> {
    let Some(e) = image.entries.iter().find(|e| e.tag == tag) else { return Ok(None) };
    let at = format!("IFD {} tag {name}", image.ifd);
    let Some(size) = unsigned_size(e.ty) else {
        return Err((at, format!("type {} found, expected an unsigned integer type", e.ty)));
    };
    if e.count == 0 || e.count > max {
        return Err((at, format!("{} values, expected 1 to {max}", e.count)));
    }
    let bytes = if e.count * size <= layout.field() as u64 {
        e.field[..(e.count * size) as usize].to_vec()
    } else {
        file.read_at(layout.offset(&e.field), (e.count * size) as usize, &at)?
    };
    Ok(Some(bytes.chunks_exact(size as usize).map(|b| layout.value(e.ty, b)).collect()))
}

/// The text of ASCII tag `tag` (at most `max` bytes, without its closing NUL), `None` when the
/// IFD lacks it.
pub(super) fn ascii(
    file: &Head,
    layout: Layout,
    image: &Image,
    tag: u16,
    name: &str,
    max: u64,
) -> Result<Option<String>, (String, String)> {
    let Some(bytes) = raw_bytes(file, layout, image, tag, name, &[2], max)? else { return Ok(None) };
    let text = bytes.split(|&b| b == 0).next().unwrap_or_default();
    match std::str::from_utf8(text) {
        Ok(t) => Ok(Some(t.trim().to_string())),
        Err(_) => Err((format!("IFD {} tag {name}", image.ifd), format!("bytes {text:02x?} are not ASCII text"))),
    }
}

/// The bytes of tag `tag`, of one of the byte-sized TIFF types `types` (2 ASCII, 7
/// UNDEFINED), at most `max` of them; `None` when the IFD lacks it.
pub(super) fn raw_bytes(
    file: &Head,
    layout: Layout,
    image: &Image,
    tag: u16,
    name: &str,
    types: &[u16],
    max: u64,
) -> Result<Option<Vec<u8>>, (String, String)> {
    let Some(e) = image.entries.iter().find(|e| e.tag == tag) else { return Ok(None) };
    let at = format!("IFD {} tag {name}", image.ifd);
    if !types.contains(&e.ty) {
        return Err((at, format!("type {} found, expected {types:?}", e.ty)));
    }
    if e.count == 0 || e.count > max {
        return Err((at, format!("{} bytes, expected 1 to {max}", e.count)));
    }
    let bytes = if e.count <= layout.field() as u64 {
        e.field[..e.count as usize].to_vec()
    } else {
        file.read_at(layout.offset(&e.field), e.count as usize, &at)?
    };
    Ok(Some(bytes))
}

/// The values of DOUBLE tag `tag` (TIFF type 12; at most `max` of them), `None` when the IFD
/// lacks it; a value that is not finite is refused (where, which value).
pub(super) fn doubles(
    file: &Head,
    layout: Layout,
    image: &Image,
    tag: u16,
    name: &str,
    max: u64,
) -> Result<Option<Vec<f64>>, (String, String)> {
    let Some(e) = image.entries.iter().find(|e| e.tag == tag) else { return Ok(None) };
    let at = format!("IFD {} tag {name}", image.ifd);
    if e.ty != 12 {
        return Err((at, format!("type {} found, expected 12 (DOUBLE)", e.ty)));
    }
    if e.count == 0 || e.count > max {
        return Err((at, format!("{} values, expected 1 to {max}", e.count)));
    }
    let bytes = if e.count * 8 <= layout.field() as u64 {
        e.field[..(e.count * 8) as usize].to_vec()
    } else {
        file.read_at(layout.offset(&e.field), (e.count * 8) as usize, &at)?
    };
    let v: Vec<f64> = bytes.chunks_exact(8).map(|b| f64::from_bits(layout.u64(b))).collect();
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err((at, format!("value {i} is {}, expected a finite number", v[i])));
    }
    Ok(Some(v))
}

/// The single unsigned value of tag `tag`, `None` when the IFD lacks it.
pub(super) fn scalar(
    file: &Head,
    layout: Layout,
    image: &Image,
    tag: u16,
    name: &str,
) -> Result<Option<u64>, (String, String)> {
    Ok(values(file, layout, image, tag, name, 1)?.map(|v| v[0]))
}

/// A run of a file's bytes read at once: `bytes` from byte `start`.
pub(super) struct Span<'a> {
    pub(super) start: u64,
    pub(super) bytes: &'a [u8],
}

impl Span<'_> {
    /// Bytes `[offset, offset + len)` when the span holds them all.
    pub(super) fn get(&self, offset: u64, len: u64) -> Option<&[u8]> {
        let from = offset.checked_sub(self.start)?;
        let to = from.checked_add(len)?;
        self.bytes.get(from as usize..usize::try_from(to).ok()?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ghost_area_says_whether_tiles_have_a_leader_and_a_trailer() {
        let area = |body: &str| {
            let mut v = b"II*\0\x08\0\0\0".to_vec();
            v.extend(format!("GDAL_STRUCTURAL_METADATA_SIZE={:06} bytes\n{body}", body.len()).bytes());
            v
        };
        let gdal = area("LAYOUT=IFDS_BEFORE_DATA\nBLOCK_ORDER=ROW_MAJOR\nBLOCK_LEADER=SIZE_AS_UINT4\nBLOCK_TRAILER=LAST_4_BYTES_REPEATED\nKNOWN_INCOMPATIBLE_EDITION=NO\n ");
        assert_eq!(Ghost::parse(&gdal, 8), Ghost { leader: true, trailer: true });
        let edited =
            area("BLOCK_LEADER=SIZE_AS_UINT4\nBLOCK_TRAILER=LAST_4_BYTES_REPEATED\nKNOWN_INCOMPATIBLE_EDITION=YES\n");
        assert_eq!(Ghost::parse(&edited, 8), Ghost::default(), "a file edited since GDAL wrote it");
        assert_eq!(Ghost::parse(b"II*\0\x08\0\0\0\x03\0", 8), Ghost::default(), "no ghost area");
        assert_eq!(Ghost::parse(&area("BLOCK_LEADER=SIZE_AS_UINT4\n"), 8), Ghost { leader: true, trailer: false });
    }
}
