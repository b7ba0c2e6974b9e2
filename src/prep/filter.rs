//! Downsampling one level into the next, row by row, with bounded memory.
//!
//! A `Downsampler` receives the rows of level k in increasing t and emits the rows of level
//! k + 1 as soon as every source row they depend on has arrived; it keeps only the few source rows
//! still needed (2 for the box filter, 12 for Lanczos-3), already reduced horizontally.
//!
//! Filtering works on the components *as stored* in level k (the quantised values), so a box
//! filtered level is exactly reproducible from the level below:
//! `out = floor((a + b + c + d + 2) / 4)` per component (the 2x2 average, halves rounded up),
//! for packed formats per packed component (5, 6 or 1 bits), for 16-bit formats per 16-bit
//! component (little-endian words). With linear light, colour components
//! (not alpha) are converted from sRGB to linear before averaging and back after.
//!
//! Edges are clamped (the texel beyond the edge repeats the edge texel).

use crate::texel::{ComponentType, PackedType, TexelFormat};
use std::collections::VecDeque;

/// The reconstruction filter used to build coarser levels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Filter {
    /// 2x2 box (the default).
    Box,
    /// Lanczos windowed sinc with three lobes, 12 taps per axis.
    Lanczos3,
}

#[derive(Clone, Copy, Debug)]
enum Packing {
    Bytes,
    /// 16-bit components, little-endian.
    Words,
    Rgb565,
    Rgba5551,
}

/// How a texel splits into components.
#[derive(Clone, Copy, Debug)]
pub struct Channels {
    packing: Packing,
    n: usize,
    bpt: usize,
    max: [f32; 4],
    colour: [bool; 4],
}

impl Channels {
    /// The components of a format, or `None` for formats this tool does not filter.
    pub fn of(f: TexelFormat) -> Option<Channels> {
        let n = f.components.count() as usize;
        let bpt = f.bytes_per_texel() as usize;
        let alpha_last = n == 2 || n == 4;
        let mut colour = [true; 4];
        if alpha_last {
            colour[n - 1] = false;
        }
        let (packing, max) = match f.ctype {
            ComponentType::U8 => (Packing::Bytes, [255.0; 4]),
            ComponentType::U16 => (Packing::Words, [65535.0; 4]),
            ComponentType::Packed(PackedType::Rgb565) => (Packing::Rgb565, [31.0, 63.0, 31.0, 0.0]),
            ComponentType::Packed(PackedType::Rgba5551) => (Packing::Rgba5551, [31.0, 31.0, 31.0, 1.0]),
            _ => return None,
        };
        Some(Channels { packing, n, bpt, max, colour })
    }

    /// Number of components (the tests check it against the format's).
    #[cfg(test)]
    pub fn count(&self) -> usize {
        self.n
    }

    /// Unpacks one texel into its integer components (as f32).
    pub(crate) fn unpack(&self, texel: &[u8], out: &mut [f32]) {
        match self.packing {
            Packing::Bytes => {
                for (o, &b) in out.iter_mut().zip(texel) {
                    *o = b as f32;
                }
            }
            Packing::Words => {
                for (o, w) in out.iter_mut().zip(texel.chunks_exact(2)) {
                    *o = u16::from_le_bytes([w[0], w[1]]) as f32;
                }
            }
            Packing::Rgb565 => {
                let v = u16::from_le_bytes([texel[0], texel[1]]);
                out[0] = (v >> 11) as f32;
                out[1] = ((v >> 5) & 63) as f32;
                out[2] = (v & 31) as f32;
            }
            Packing::Rgba5551 => {
                let v = u16::from_le_bytes([texel[0], texel[1]]);
                out[0] = (v >> 11) as f32;
                out[1] = ((v >> 6) & 31) as f32;
                out[2] = ((v >> 1) & 31) as f32;
                out[3] = (v & 1) as f32;
            }
        }
    }

    /// Packs components (rounded half up and clamped to their range) into one texel.
    pub(crate) fn pack(&self, comps: &[f32], out: &mut [u8]) {
        let q = |i: usize| (comps[i] + 0.5).floor().clamp(0.0, self.max[i]) as u16;
        match self.packing {
            Packing::Bytes => {
                for (i, o) in out.iter_mut().enumerate().take(self.n) {
                    *o = q(i) as u8;
                }
            }
            Packing::Words => {
                for (i, o) in out.chunks_exact_mut(2).enumerate().take(self.n) {
                    o.copy_from_slice(&q(i).to_le_bytes());
                }
            }
            Packing::Rgb565 => {
                let v = (q(0) << 11) | (q(1) << 5) | q(2);
                out.copy_from_slice(&v.to_le_bytes());
            }
            Packing::Rgba5551 => {
                let v = (q(0) << 11) | (q(1) << 6) | (q(2) << 1) | q(3);
                out.copy_from_slice(&v.to_le_bytes());
            }
        }
    }
}

fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

fn linear_to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

fn lanczos3(x: f32) -> f32 {
    let x = x.abs();
    if x < 1e-6 {
        return 1.0;
    }
    if x >= 3.0 {
        return 0.0;
    }
    let px = std::f32::consts::PI * x;
    3.0 * px.sin() * (px / 3.0).sin() / (px * px)
}

/// Taps of a 2:1 reduction: destination texel j reads source texels 2j + offset.
fn taps(filter: Filter) -> Vec<(i64, f32)> {
    match filter {
        Filter::Box => vec![(0, 0.5), (1, 0.5)],
        Filter::Lanczos3 => {
            // Destination centre 2j + 1 in source texel units; source texel i has centre i + 0.5.
            let raw: Vec<(i64, f32)> = (-5..=6).map(|d| (d, lanczos3((d as f32 + 0.5 - 1.0) / 2.0))).collect();
            let sum: f32 = raw.iter().map(|(_, w)| w).sum();
            raw.into_iter().map(|(d, w)| (d, w / sum)).collect()
        }
    }
}

/// Reduces one level to the next (half the width and half the height), row by row.
pub(crate) struct Downsampler {
    ch: Channels,
    linear: bool,
    src_w: u64,
    src_h: u64,
    dst_w: u64,
    dst_h: u64,
    taps: Vec<(i64, f32)>,
    /// Source rows still needed, reduced horizontally: (t, dst_w * n components).
    rows: VecDeque<(u64, Vec<f32>)>,
    next_in: u64,
    next_out: u64,
    scratch: Vec<f32>,
    /// The 2x2 box on byte or 16-bit components without linear light takes an integer path;
    /// this holds the even source row waiting for its odd partner.
    box_bytes: Option<Vec<u8>>,
}

impl Downsampler {
    /// A reducer from a `src_w` x `src_h` level (both at least 2) in format `ch`.
    pub fn new(ch: Channels, filter: Filter, linear: bool, src_w: u64, src_h: u64) -> Downsampler {
        Downsampler {
            ch,
            linear,
            src_w,
            src_h,
            dst_w: src_w / 2,
            dst_h: src_h / 2,
            taps: taps(filter),
            rows: VecDeque::new(),
            next_in: 0,
            next_out: 0,
            scratch: vec![0.0; src_w as usize * ch.n],
            box_bytes: (filter == Filter::Box
                && !linear
                && matches!(ch.packing, Packing::Bytes | Packing::Words)
                && (src_w | src_h) & 1 == 0)
                .then(Vec::new),
        }
    }

    /// Bytes of one destination row.
    pub(crate) fn dst_row_bytes(&self) -> usize {
        self.dst_w as usize * self.ch.bpt
    }

    fn max_offset(&self) -> i64 {
        self.taps.iter().map(|t| t.0).max().unwrap_or(0)
    }

    fn min_offset(&self) -> i64 {
        self.taps.iter().map(|t| t.0).min().unwrap_or(0)
    }

    /// Takes the next source row and appends every destination row it completes to `out`.
    /// Returns how many rows were appended. The last source row completes the level.
    pub fn push(&mut self, row: &[u8], out: &mut Vec<u8>) -> usize {
        if self.box_bytes.is_some() {
            return self.push_box_bytes(row, out);
        }
        let n = self.ch.n;
        let bpt = self.ch.bpt;
        debug_assert_eq!(row.len(), self.src_w as usize * bpt);
        // Unpack (and linearise) the source row.
        for (x, texel) in row.chunks_exact(bpt).enumerate() {
            let c = &mut self.scratch[x * n..x * n + n];
            self.ch.unpack(texel, c);
            if self.linear {
                for (i, v) in c.iter_mut().enumerate() {
                    if self.ch.colour[i] {
                        *v = srgb_to_linear(*v / self.ch.max[i]);
                    }
                }
            }
        }
        // Horizontal reduction.
        let mut reduced = vec![0.0f32; self.dst_w as usize * n];
        let last = self.src_w as i64 - 1;
        for x in 0..self.dst_w as i64 {
            let acc = &mut reduced[x as usize * n..x as usize * n + n];
            for &(d, w) in &self.taps {
                let sx = (2 * x + d).clamp(0, last) as usize;
                for (a, v) in acc.iter_mut().zip(&self.scratch[sx * n..sx * n + n]) {
                    *a += w * v;
                }
            }
        }
        self.rows.push_back((self.next_in, reduced));
        self.next_in += 1;
        // Emit every destination row whose source rows have all arrived.
        let mut produced = 0;
        let last_row = self.src_h as i64 - 1;
        let mut comps = vec![0.0f32; n];
        let mut texel = vec![0u8; bpt];
        while self.next_out < self.dst_h {
            let j = self.next_out as i64;
            let needed = (2 * j + self.max_offset()).min(last_row);
            if needed >= self.next_in as i64 {
                break;
            }
            let front = self.rows.front().map(|r| r.0).unwrap_or(0) as i64;
            for x in 0..self.dst_w as usize {
                comps.iter_mut().for_each(|c| *c = 0.0);
                for &(d, w) in &self.taps {
                    let sy = (2 * j + d).clamp(0, last_row);
                    let src = &self.rows[(sy - front) as usize].1;
                    for (c, v) in comps.iter_mut().zip(&src[x * n..x * n + n]) {
                        *c += w * v;
                    }
                }
                if self.linear {
                    for (i, c) in comps.iter_mut().enumerate() {
                        if self.ch.colour[i] {
                            *c = linear_to_srgb(*c) * self.ch.max[i];
                        }
                    }
                }
                self.ch.pack(&comps, &mut texel);
                out.extend_from_slice(&texel);
            }
            self.next_out += 1;
            produced += 1;
            // Drop source rows no later destination row reads.
            let keep_from = 2 * self.next_out as i64 + self.min_offset();
            while self.rows.front().is_some_and(|r| (r.0 as i64) < keep_from && (r.0 as i64) < last_row) {
                self.rows.pop_front();
            }
        }
        produced
    }

    /// The box filter on bytes or 16-bit words: `floor((a + b + c + d + 2) / 4)` per component,
    /// in integers (the general path computes the same value in f32, where every step is exact:
    /// four 16-bit values sum to less than 2^18, far inside f32's 24-bit mantissa).
    fn push_box_bytes(&mut self, row: &[u8], out: &mut Vec<u8>) -> usize {
        let pending = self.box_bytes.as_mut().expect("the integer box path is on");
        self.next_in += 1;
        if self.next_in % 2 == 1 {
            pending.clear();
            pending.extend_from_slice(row);
            return 0;
        }
        let n = self.ch.bpt;
        out.reserve(self.dst_w as usize * n);
        if matches!(self.ch.packing, Packing::Words) {
            let w = |x: &[u8], i: usize| u16::from_le_bytes([x[i], x[i + 1]]) as u32;
            for (a, b) in pending.chunks_exact(2 * n).zip(row.chunks_exact(2 * n)) {
                for c in (0..n).step_by(2) {
                    let sum = w(a, c) + w(a, n + c) + w(b, c) + w(b, n + c) + 2;
                    out.extend_from_slice(&((sum / 4) as u16).to_le_bytes());
                }
            }
        } else {
            for (a, b) in pending.chunks_exact(2 * n).zip(row.chunks_exact(2 * n)) {
                for c in 0..n {
                    let sum = a[c] as u16 + a[n + c] as u16 + b[c] as u16 + b[n + c] as u16 + 2;
                    out.push((sum / 4) as u8);
                }
            }
        }
        self.next_out += 1;
        1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_filter_rounds_halves_up_on_stored_components() {
        let ch = Channels::of(TexelFormat::L8).unwrap();
        let mut d = Downsampler::new(ch, Filter::Box, false, 4, 2);
        let mut out = Vec::new();
        assert_eq!(d.push(&[0, 1, 10, 20], &mut out), 0);
        assert_eq!(d.push(&[0, 0, 30, 41], &mut out), 1);
        // (0+1+0+0+2)/4 = 0; (10+20+30+41+2)/4 = 25.
        assert_eq!(out, vec![0, 25]);
    }

    #[test]
    fn packed_5551_averages_each_field() {
        let ch = Channels::of(TexelFormat::RGBA5551).unwrap();
        let px = |r: u16, g: u16, b: u16, a: u16| ((r << 11) | (g << 6) | (b << 1) | a).to_le_bytes();
        let row0 = [px(31, 0, 1, 1), px(30, 2, 1, 0)].concat();
        let row1 = [px(29, 4, 1, 1), px(28, 6, 2, 0)].concat();
        let mut d = Downsampler::new(ch, Filter::Box, false, 2, 2);
        let mut out = Vec::new();
        d.push(&row0, &mut out);
        d.push(&row1, &mut out);
        // r (31+30+29+28+2)/4 = 30, g (0+2+4+6+2)/4 = 3, b (1+1+1+2+2)/4 = 1, a (1+0+1+0+2)/4 = 1.
        assert_eq!(out, px(30, 3, 1, 1).to_vec());
    }

    /// Box-filters `rows` on the integer path and on the general one; asserts they agree and
    /// returns the output.
    fn box_on_both_paths(ch: Channels, w: u64, h: u64, rows: &[Vec<u8>]) -> Vec<u8> {
        let mut fast = Downsampler::new(ch, Filter::Box, false, w, h);
        let mut general = Downsampler::new(ch, Filter::Box, false, w, h);
        general.box_bytes = None;
        assert!(fast.box_bytes.is_some());
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for r in rows {
            assert_eq!(fast.push(r, &mut a), general.push(r, &mut b));
        }
        assert_eq!(a, b);
        a
    }

    #[test]
    fn the_integer_box_path_equals_the_general_path() {
        let ch = Channels::of(TexelFormat::RGBA8).unwrap();
        let (w, h) = (6u64, 4u64);
        let rows: Vec<Vec<u8>> =
            (0..h).map(|t| (0..w * 4).map(|i| ((i * 37 + t * 101) % 256) as u8).collect()).collect();
        let mut fast = Downsampler::new(ch, Filter::Box, false, w, h);
        let mut general = Downsampler::new(ch, Filter::Box, false, w, h);
        general.box_bytes = None;
        assert!(fast.box_bytes.is_some());
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for r in &rows {
            assert_eq!(fast.push(r, &mut a), general.push(r, &mut b));
        }
        assert_eq!(a.len(), 3 * 2 * 4);
        assert_eq!(a, b);
    }

    #[test]
    fn sixteen_bit_components_unpack_and_pack_exactly() {
        for f in [TexelFormat::L16, TexelFormat::LA16, TexelFormat::RGB16, TexelFormat::RGBA16] {
            let ch = Channels::of(f).expect("16-bit formats are filtered");
            let n = ch.count();
            assert_eq!(n, f.components.count() as usize);
            for v in [0u16, 1, 255, 256, 257, 0x1234, 32767, 32768, 65534, 65535] {
                let comps: Vec<u16> = (0..n as u16).map(|i| v.wrapping_add(i.wrapping_mul(4099))).collect();
                let texel: Vec<u8> = comps.iter().flat_map(|c| c.to_le_bytes()).collect();
                let mut un = vec![0f32; n];
                ch.unpack(&texel, &mut un);
                assert_eq!(un, comps.iter().map(|&c| c as f32).collect::<Vec<_>>(), "{f}");
                let mut back = vec![0u8; texel.len()];
                ch.pack(&un, &mut back);
                assert_eq!(back, texel, "{f}");
            }
        }
        // Packing rounds halves up and clamps to the 16-bit range.
        let ch = Channels::of(TexelFormat::LA16).unwrap();
        let mut t = [0u8; 4];
        ch.pack(&[1000.5, 70000.0], &mut t);
        assert_eq!(t, [0xe9, 0x03, 0xff, 0xff]);
    }

    #[test]
    fn the_sixteen_bit_box_filter_is_exact_on_both_paths() {
        let ch = Channels::of(TexelFormat::RGB16).unwrap();
        let (w, h) = (6u64, 4u64);
        let v = |i: u64, t: u64| ((i * 40_503 + t * 9_973 + 65_000) % 65_536) as u16;
        let rows: Vec<Vec<u8>> = (0..h).map(|t| (0..w * 3).flat_map(|i| v(i, t).to_le_bytes()).collect()).collect();
        let a = box_on_both_paths(ch, w, h, &rows);
        // floor((a + b + c + d + 2) / 4) of the stored components.
        let mut want = Vec::new();
        for j in 0..h / 2 {
            for x in 0..w / 2 {
                for c in 0..3 {
                    let at = |s: u64, t: u64| v(s * 3 + c, t) as u32;
                    let sum = at(2 * x, 2 * j) + at(2 * x + 1, 2 * j) + at(2 * x, 2 * j + 1) + at(2 * x + 1, 2 * j + 1);
                    want.extend_from_slice(&(((sum + 2) / 4) as u16).to_le_bytes());
                }
            }
        }
        assert_eq!(a, want);
    }

    #[test]
    fn sixteen_bit_lanczos_and_linear_light_keep_a_constant_constant() {
        for (filter, linear) in [(Filter::Lanczos3, false), (Filter::Lanczos3, true), (Filter::Box, true)] {
            let ch = Channels::of(TexelFormat::RGBA16).unwrap();
            let mut d = Downsampler::new(ch, filter, linear, 32, 32);
            let texel: Vec<u8> = [51_234u16, 1, 65_535, 40_000].iter().flat_map(|c| c.to_le_bytes()).collect();
            let row = texel.repeat(32);
            let mut out = Vec::new();
            for _ in 0..32 {
                d.push(&row, &mut out);
            }
            assert_eq!(out.len(), 16 * 16 * 8);
            for (i, got) in out.chunks_exact(8).enumerate() {
                for c in 0..4 {
                    let g = u16::from_le_bytes([got[2 * c], got[2 * c + 1]]) as i32;
                    let w = u16::from_le_bytes([texel[2 * c], texel[2 * c + 1]]) as i32;
                    // Linear light goes through f32 powers: within a few 16-bit steps.
                    let tol = if linear { 8 } else { 0 };
                    assert!((g - w).abs() <= tol, "{filter:?} linear {linear}: texel {i} component {c}: {g} vs {w}");
                }
            }
        }
    }

    #[test]
    fn lanczos_keeps_a_constant_constant() {
        let ch = Channels::of(TexelFormat::RGB8).unwrap();
        let mut d = Downsampler::new(ch, Filter::Lanczos3, true, 32, 32);
        let mut out = Vec::new();
        let row = vec![77u8; 32 * 3];
        let mut n = 0;
        for _ in 0..32 {
            n += d.push(&row, &mut out);
        }
        assert_eq!(n, 16);
        assert!(out.iter().all(|&v| v == 77), "{out:?}");
    }
}
