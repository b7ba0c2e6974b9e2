//! The shared-memory layout, version 1: every offset and size, as pure arithmetic.
//!
//! `docs/SHM.md` documents the same table for readers in other languages; `include/clipmap_shm.h`
//! and `clients/python/clipmap_shm.py` mirror it, and a test checks that they agree with this file.
//! All integers are little-endian. Every field the writer changes while readers run is 8 bytes,
//! naturally aligned, and accessed atomically.

/// Magic bytes at offset 0.
pub const MAGIC: [u8; 8] = *b"CLIPMAP1";
/// Layout version.
pub const VERSION: u32 = 1;
/// Alignment of every window (a page).
pub const PAGE: u64 = 4096;
/// Most levels a mapping describes.
pub const MAX_LEVELS: usize = 32;

/// Header field offsets.
pub mod header {
    /// `[u8; 8]` magic.
    pub const MAGIC: usize = 0;
    /// `u32` layout version.
    pub const VERSION: usize = 8;
    /// `u32` bytes before the first window (a multiple of 4096).
    pub const HEADER_BYTES: usize = 12;
    /// `u64` size of the whole mapping.
    pub const TOTAL_BYTES: usize = 16;
    /// `u32` texel format code (see [`super::format_code`]).
    pub const TEXEL_FORMAT: usize = 24;
    /// `u32` bytes per texel.
    pub const BYTES_PER_TEXEL: usize = 28;
    /// `u32` clip size.
    pub const CLIP_SIZE: usize = 32;
    /// `u32` number of levels.
    pub const LEVEL_COUNT: usize = 36;
    /// `u64` level-0 width.
    pub const LEVEL0_S: usize = 40;
    /// `u64` level-0 height.
    pub const LEVEL0_T: usize = 48;
    /// `u32` process id of the writer.
    pub const WRITER_PID: usize = 56;
    /// `u32` flags (bit 0: the writer shut down cleanly).
    pub const FLAGS: usize = 60;
    /// `u64` (atomic) tick counter, incremented every update tick.
    pub const HEARTBEAT: usize = 64;
    /// `u64` (atomic) wall-clock time of the last tick, milliseconds since the Unix epoch.
    pub const HEARTBEAT_MS: usize = 72;
    /// `u64` a number unique to each start of the writer.
    pub const GENERATION: usize = 80;
    /// `u64` (atomic) sequence counter of the global state (even: stable).
    pub const GLOBAL_SEQ: usize = 88;
    /// `f64` bits (atomic): the finest level renderers may use (fractional while fading).
    pub const MIN_LOD: usize = 96;
    /// `u64` (atomic): the tick the global state belongs to.
    pub const TICK: usize = 104;
    /// Request block (written by a renderer, read by the writer).
    pub const REQUEST: usize = 128;
    /// Level descriptors (static after creation), [`super::DESC_BYTES`] each.
    pub const LEVEL_DESCS: usize = 192;
    /// Level states (seqlocked), [`super::STATE_BYTES`] each.
    pub const LEVEL_STATES: usize = LEVEL_DESCS + super::MAX_LEVELS * super::DESC_BYTES;
    /// End of the fixed header.
    pub const END: usize = LEVEL_STATES + super::MAX_LEVELS * super::STATE_BYTES;
}

/// Request block fields, relative to [`header::REQUEST`]; every field 8 bytes.
pub mod request {
    /// `u64` (atomic) sequence counter (even: stable); a renderer bumps it to odd, writes, bumps
    /// it to even.
    pub const SEQ: usize = 0;
    /// `i64` requested centre, level-0 texels.
    pub const CENTRE_S: usize = 8;
    /// `i64`.
    pub const CENTRE_T: usize = 16;
    /// `f64` bits: velocity, level-0 texels per second (0 when unknown).
    pub const VEL_S: usize = 24;
    /// `f64` bits.
    pub const VEL_T: usize = 32;
    /// `u64` process id of the requester.
    pub const CLIENT_PID: usize = 40;
    /// `u64` number of requests made (monotonic).
    pub const COUNT: usize = 48;
}

/// Bytes of one level descriptor.
pub const DESC_BYTES: usize = 64;
/// Level descriptor fields, relative to the descriptor; every field 8 bytes.
pub mod desc {
    /// `u64` level width in texels.
    pub const SIZE_S: usize = 0;
    /// `u64` level height.
    pub const SIZE_T: usize = 8;
    /// `u64` byte offset of the window from the start of the mapping.
    pub const WINDOW_OFFSET: usize = 16;
    /// `u64` bytes of the window.
    pub const WINDOW_BYTES: usize = 24;
    /// `u64` window width in texels (min(clip, level width)).
    pub const WINDOW_S: usize = 32;
    /// `u64` window height.
    pub const WINDOW_T: usize = 40;
    /// `u64` 0: stack level (toroidal window), 1: pyramid level (resident whole).
    pub const KIND: usize = 48;
}

/// Bytes of one level state.
pub const STATE_BYTES: usize = 128;
/// Level state fields, relative to the state; every field 8 bytes, all atomic.
pub mod state {
    /// `u64` sequence counter (even: stable).
    pub const SEQ: usize = 0;
    /// `i64` level centre, level texels.
    pub const CENTRE_S: usize = 8;
    /// `i64`.
    pub const CENTRE_T: usize = 16;
    /// `i64` valid region, half-open: s0 <= s < s1, t0 <= t < t1 (level texels).
    pub const VALID_S0: usize = 24;
    /// `i64`.
    pub const VALID_T0: usize = 32;
    /// `i64`.
    pub const VALID_S1: usize = 40;
    /// `i64`.
    pub const VALID_T1: usize = 48;
    /// `u64` 1 when renderers may use the level.
    pub const ENABLED: usize = 56;
    /// `u64` invalid border in use.
    pub const INVALID_BORDER: usize = 64;
    /// `u64` tick of the last change.
    pub const UPDATED_TICK: usize = 72;
    /// `i64` toroidal origin: the window slot of the valid region's first texel, S.
    pub const ORIGIN_S: usize = 80;
    /// `i64` toroidal origin, T.
    pub const ORIGIN_T: usize = 88;
}

/// Texel format codes in the header.
pub fn format_code(f: crate::texel::TexelFormat) -> u32 {
    use crate::texel::TexelFormat as F;
    match f {
        x if x == F::L8 => 1,
        x if x == F::RGB8 => 3,
        x if x == F::RGBA8 => 4,
        x if x == F::RGB565 => 5,
        x if x == F::RGBA5551 => 6,
        x if x == F::L16 => 7,
        x if x == F::LA16 => 8,
        x if x == F::RGB16 => 9,
        x if x == F::RGBA16 => 10,
        _ => 0,
    }
}

/// The texel format of a `TEXEL_FORMAT` code; `None` for 0 (other) or an unknown code.
pub fn format_from_code(code: u32) -> Option<crate::texel::TexelFormat> {
    use crate::texel::TexelFormat as F;
    [F::L8, F::RGB8, F::RGBA8, F::RGB565, F::RGBA5551, F::L16, F::LA16, F::RGB16, F::RGBA16]
        .into_iter()
        .find(|&f| format_code(f) == code)
}

/// The static shape of a mapping.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Shape {
    /// Bytes per texel.
    pub bytes_per_texel: u64,
    /// Clip size.
    pub clip_size: u64,
    /// Level sizes, finest first.
    pub levels: Vec<[u64; 2]>,
}

/// Where each level's window lies, and the whole size.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Placement {
    /// Bytes before the first window.
    pub header_bytes: u64,
    /// Per level: (offset, bytes, window width, window height, kind).
    pub windows: Vec<WindowPlace>,
    /// Whole mapping.
    pub total_bytes: u64,
}

/// One level's window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WindowPlace {
    /// Byte offset from the start of the mapping.
    pub offset: u64,
    /// Bytes.
    pub bytes: u64,
    /// Width in texels.
    pub s: u64,
    /// Height in texels.
    pub t: u64,
    /// 0 stack, 1 pyramid.
    pub kind: u64,
}

/// Lays a shape out. `None` when it has too many levels or overflows.
pub fn place(shape: &Shape) -> Option<Placement> {
    if shape.levels.is_empty() || shape.levels.len() > MAX_LEVELS || shape.bytes_per_texel == 0 || shape.clip_size == 0
    {
        return None;
    }
    let round = |v: u64| v.checked_add(PAGE - 1).map(|x| x / PAGE * PAGE);
    let header_bytes = round(header::END as u64)?;
    let mut at = header_bytes;
    let mut windows = Vec::new();
    for l in &shape.levels {
        let (s, t) = (l[0].min(shape.clip_size), l[1].min(shape.clip_size));
        let kind = u64::from(l[0] <= shape.clip_size && l[1] <= shape.clip_size);
        let bytes = s.checked_mul(t)?.checked_mul(shape.bytes_per_texel)?;
        windows.push(WindowPlace { offset: at, bytes, s, t, kind });
        at = round(at.checked_add(bytes)?)?;
    }
    Some(Placement { header_bytes, windows, total_bytes: at })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_fits_and_windows_are_page_aligned() {
        assert!(header::END <= 8192);
        let shape =
            Shape { bytes_per_texel: 4, clip_size: 1024, levels: (0..15).map(|k| [16384 >> k, 16384 >> k]).collect() };
        let p = place(&shape).unwrap();
        assert_eq!(p.header_bytes, 8192);
        for (i, w) in p.windows.iter().enumerate() {
            assert_eq!(w.offset % PAGE, 0);
            assert_eq!(w.s, (16384u64 >> i).min(1024));
            if i > 0 {
                let prev = p.windows[i - 1];
                assert!(w.offset >= prev.offset + prev.bytes);
            }
        }
        assert_eq!(p.windows[4].kind, 1);
        assert_eq!(p.windows[3].kind, 0);
        assert!(p.total_bytes >= p.windows[14].offset + p.windows[14].bytes);
    }

    #[test]
    fn too_many_levels_or_overflow_is_refused() {
        let many = Shape { bytes_per_texel: 4, clip_size: 1, levels: vec![[1, 1]; 33] };
        assert!(place(&many).is_none());
        let huge = Shape { bytes_per_texel: u64::MAX, clip_size: 1 << 20, levels: vec![[1 << 30, 1 << 30]] };
        assert!(place(&huge).is_none());
    }
}
