//! Mirrors an engine ([`Clipmap`]) into a mapping: at each publication it copies exactly the
//! texels that become valid and publishes the new valid regions, keeping the invariant that no
//! texel inside a published valid region is ever written.
//!
//! Per level and publication, with P the published region and N the engine's: publish P ∩ N
//! first if it is smaller than P (so no slot of the toroidal window that N needs is still
//! published for another texel), copy N \ (P ∩ N), then publish N. Only changed strips are
//! copied; a steady flight copies what the engine copied.

use super::layout::Shape;
use super::writer::{PublishedLevel, Writer};
use super::ShmError;
use crate::clip::{Clipmap, LevelView, Phase, Publisher};
use crate::geom::Rect;
use crate::source::TextureDesc;
use std::path::Path;

/// A [`Publisher`] that keeps a mapping equal to the engine's published state.
pub struct Mirror {
    writer: Writer,
    published: Vec<Rect>,
    tick: u64,
    /// True when the engine writes its windows straight into the mapping (nothing to copy).
    direct: bool,
    /// Bytes copied into the mapping so far (by the mirror, or by the engine when direct).
    pub bytes_copied: u64,
    /// Level-state publications so far.
    pub publications: u64,
}

impl std::fmt::Debug for Mirror {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Mirror").field("writer", &self.writer).field("tick", &self.tick).finish()
    }
}

/// The mapping shape of an engine.
pub fn shape_of(clipmap: &Clipmap) -> Shape {
    shape_of_desc(clipmap.desc())
}

/// The mapping shape of a texture.
pub fn shape_of_desc(d: &TextureDesc) -> Shape {
    Shape {
        bytes_per_texel: d.bytes_per_texel() as u64,
        clip_size: d.clip_size(),
        levels: d.levels().iter().map(|l| l.size).collect(),
    }
}

/// `a \ b` for `b` inside `a`, as up to four rectangles.
fn minus(a: Rect, b: Rect) -> Vec<Rect> {
    if b.is_empty() {
        return if a.is_empty() { vec![] } else { vec![a] };
    }
    let parts = [
        Rect::new(a.s0, a.t0, a.s1, b.t0),
        Rect::new(a.s0, b.t1, a.s1, a.t1),
        Rect::new(a.s0, b.t0, b.s0, b.t1),
        Rect::new(b.s1, b.t0, a.s1, b.t1),
    ];
    parts.into_iter().filter(|r| !r.is_empty()).collect()
}

impl Mirror {
    /// Creates the mapping for `clipmap` as `name` in `dir` (owner-only unless `mode` says more).
    /// The engine keeps its windows in private memory and the mirror copies what becomes valid.
    pub fn create(dir: &Path, name: &str, clipmap: &Clipmap, mode: u32) -> Result<Mirror, ShmError> {
        let shape = shape_of(clipmap);
        let writer = Writer::create(dir, name, shape, clipmap.desc().format(), mode)?;
        Self::over(writer, clipmap, false)
    }

    /// A mirror over `writer` for an engine built with the writer's own window memory
    /// ([`Writer::window_stores`] and [`Clipmap::with_windows`]): the engine writes texels into
    /// the mapping itself and the mirror only publishes, so a service copies each texel once,
    /// as the in-process engine does.
    pub fn direct(writer: Writer, clipmap: &Clipmap) -> Result<Mirror, ShmError> {
        for k in 0..clipmap.level_count() {
            if clipmap.level(k as u32).texels.as_slice().is_some() {
                return Err(ShmError::Shape(format!(
                    "level {k}: the engine keeps this window in private memory; build it with Clipmap::with_windows(.., writer.window_stores())"
                )));
            }
        }
        Self::over(writer, clipmap, true)
    }

    fn over(writer: Writer, clipmap: &Clipmap, direct: bool) -> Result<Mirror, ShmError> {
        for k in 0..clipmap.level_count() {
            let v = clipmap.level(k as u32);
            let w = writer.placement().windows[k];
            if [w.s, w.t] != v.dims {
                return Err(ShmError::Shape(format!(
                    "level {k}: engine window {:?} differs from the layout's {:?}",
                    v.dims,
                    [w.s, w.t]
                )));
            }
        }
        let n = clipmap.level_count();
        Ok(Mirror { writer, published: vec![Rect::EMPTY; n], tick: 0, direct, bytes_copied: 0, publications: 0 })
    }

    /// The writer (for requests, heartbeat and shutdown).
    pub fn writer(&self) -> &Writer {
        &self.writer
    }

    /// Consumes the mirror, returning the writer.
    pub fn into_writer(self) -> Writer {
        self.writer
    }

    fn copy_rect(&mut self, k: usize, v: &LevelView<'_>, r: Rect) {
        let clip = v.clip as i64;
        let bpt = v.bpt;
        for t in r.t0..r.t1 {
            let slot_t = t.rem_euclid(clip) as u64;
            let mut s = r.s0;
            while s < r.s1 {
                let slot_s = s.rem_euclid(clip) as u64;
                let run = ((r.s1 - s) as u64).min(v.dims[0] - slot_s);
                let off = ((slot_t * v.dims[0] + slot_s) as usize) * bpt;
                let len = run as usize * bpt;
                match v.texels.as_slice() {
                    Some(texels) => self.writer.write_window(k, off as u64, &texels[off..off + len]),
                    None => {
                        let mut run = vec![0u8; len];
                        v.texels.read(off, &mut run);
                        self.writer.write_window(k, off as u64, &run);
                    }
                }
                self.bytes_copied += len as u64;
                s += run as i64;
            }
        }
    }

    fn publish_level(&mut self, k: usize, v: &LevelView<'_>, region: Rect, border: u64) {
        self.writer.publish(
            k,
            &PublishedLevel {
                centre: v.centre,
                valid: [region.s0, region.t0, region.s1, region.t1],
                enabled: !region.is_empty(),
                invalid_border: border,
            },
        );
        self.published[k] = region;
        self.publications += 1;
    }

    /// Brings level `k` of the mapping to the engine's state.
    fn sync_level(&mut self, k: usize, clipmap: &Clipmap) {
        let v = clipmap.level(k as u32);
        let n = if v.valid.is_empty() { Rect::EMPTY } else { v.valid };
        let p = self.published[k];
        if n == p {
            return;
        }
        let keep = p.intersect(&n);
        let keep = if keep.is_empty() { Rect::EMPTY } else { keep };
        if keep != p {
            self.publish_level(k, &v, keep, clipmap.invalid_border());
        }
        for r in minus(n, keep) {
            if self.direct {
                // Already in the mapping: the engine wrote it there.
                self.bytes_copied += r.area() * v.bpt as u64;
            } else {
                self.copy_rect(k, &v, r);
            }
        }
        if n != keep {
            self.publish_level(k, &v, n, clipmap.invalid_border());
        }
    }
}

impl Publisher for Mirror {
    fn publish(&mut self, phase: Phase, clipmap: &Clipmap) {
        for k in 0..clipmap.level_count() {
            self.sync_level(k, clipmap);
        }
        if phase == Phase::AfterWrites {
            self.tick += 1;
            self.writer.publish_global(clipmap.min_lod(), self.tick);
            self.writer.heartbeat();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn difference_covers_exactly_the_outer_part() {
        let a = Rect::new(0, 0, 10, 8);
        let b = Rect::new(3, 2, 7, 5);
        let parts = minus(a, b);
        let area: u64 = parts.iter().map(|r| r.area()).sum();
        assert_eq!(area, a.area() - b.area());
        for s in 0..10 {
            for t in 0..8 {
                let n = parts.iter().filter(|r| r.contains(s, t)).count();
                assert_eq!(n, usize::from(!b.contains(s, t)), "({s},{t})");
            }
        }
        assert_eq!(minus(a, Rect::EMPTY), vec![a]);
    }
}
