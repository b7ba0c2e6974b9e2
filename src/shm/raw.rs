//! The only `unsafe` code of the crate: raw access to a memory mapping that other processes
//! share.
//!
//! The mapping is touched through raw pointers and atomics only, never through Rust references to
//! its bytes: another process may change any byte at any time, which no `&[u8]` may observe.
//! Every access is bounds- and alignment-checked before the `unsafe` block that performs it.

#[cfg(target_endian = "big")]
compile_error!("the shared-memory layout is little-endian; big-endian targets are not supported");

use memmap2::MmapRaw;
use std::fs::File;
use std::sync::atomic::{AtomicU64, Ordering};

/// A shared mapping of a whole file (or an anonymous one, for an engine without a service).
pub struct Region {
    map: MmapRaw,
    writable: bool,
    /// Bytes copied in by [`Region::write`] into the range `counted` (texel bytes written other
    /// than by a tile read into its slot).
    copied: AtomicU64,
    counted: std::ops::Range<usize>,
}

impl std::fmt::Debug for Region {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Region").field("len", &self.map.len()).finish()
    }
}

impl Region {
    /// Maps `file` read-write and shared.
    pub fn map(file: &File) -> std::io::Result<Region> {
        let map = MmapRaw::map_raw(file)?;
        Ok(Region { map, writable: true, copied: AtomicU64::new(0), counted: 0..0 })
    }

    /// [`map`](Self::map), with every page faulted in now (the service's texel mapping: tile
    /// reads then write into memory that is already there, instead of faulting page by page).
    pub fn map_populated(file: &File) -> std::io::Result<Region> {
        let map = memmap2::MmapOptions::new().populate().map_raw(file)?;
        Ok(Region { map, writable: true, copied: AtomicU64::new(0), counted: 0..0 })
    }

    /// Maps `file` read-only and shared: loads only (a reader of the texel mapping).
    pub fn map_read_only(file: &File) -> std::io::Result<Region> {
        let map = memmap2::MmapOptions::new().map_raw_read_only(file)?;
        Ok(Region { map, writable: false, copied: AtomicU64::new(0), counted: 0..0 })
    }

    /// A private anonymous mapping of `len` zero bytes (an engine's image caches in-process).
    pub fn anonymous(len: usize) -> std::io::Result<Region> {
        let map = MmapRaw::from(memmap2::MmapOptions::new().len(len.max(1)).populate().map_anon()?);
        Ok(Region { map, writable: true, copied: AtomicU64::new(0), counted: 0..0 })
    }

    /// Counts the bytes [`write`](Self::write) copies into `range` from now on (the texel slots),
    /// for [`copied_bytes`](Self::copied_bytes).
    pub fn count_writes_into(&mut self, range: std::ops::Range<usize>) {
        self.counted = range;
    }

    /// Bytes [`write`](Self::write) copied into the counted range so far.
    pub fn copied_bytes(&self) -> u64 {
        self.copied.load(Ordering::Relaxed)
    }

    fn check(&self, offset: usize, len: usize, align: usize) {
        let end = offset.checked_add(len).expect("shared-memory access overflows");
        assert!(
            end <= self.map.len(),
            "shared-memory access {offset}..{end} is outside the mapping of {} bytes",
            self.map.len()
        );
        assert!(
            (self.map.as_ptr() as usize + offset) % align == 0,
            "shared-memory access at {offset} is not {align}-byte aligned"
        );
    }

    fn check_writable(&self) {
        assert!(self.writable, "write to a read-only mapping");
    }

    fn atomic(&self, offset: usize) -> &AtomicU64 {
        self.check(offset, 8, 8);
        // SAFETY: `check` proved that offset..offset+8 lies inside the mapping, which stays mapped
        // for the lifetime of `self` (the returned reference borrows `self`), and that the address
        // is 8-byte aligned. An `AtomicU64` may be shared and modified concurrently by any number
        // of threads or processes; every access to these 8 bytes, in this process and (by the
        // documented protocol) in others, is atomic, so no non-atomic access races with it.
        unsafe { AtomicU64::from_ptr(self.map.as_mut_ptr().add(offset).cast::<u64>()) }
    }

    /// Atomically loads the u64 at `offset`.
    pub fn load(&self, offset: usize, order: Ordering) -> u64 {
        self.atomic(offset).load(order)
    }

    /// Atomically stores `value` at `offset`.
    pub fn store(&self, offset: usize, value: u64, order: Ordering) {
        self.check_writable();
        self.atomic(offset).store(value, order)
    }

    /// Atomically adds to the u64 at `offset`, returning the previous value.
    pub fn fetch_add(&self, offset: usize, value: u64, order: Ordering) -> u64 {
        self.check_writable();
        self.atomic(offset).fetch_add(value, order)
    }

    /// Atomic compare-and-exchange of the u64 at `offset`.
    pub fn compare_exchange(&self, offset: usize, current: u64, new: u64) -> Result<u64, u64> {
        self.check_writable();
        self.atomic(offset).compare_exchange(current, new, Ordering::AcqRel, Ordering::Acquire)
    }

    /// Copies bytes out of the mapping.
    ///
    /// The bytes may be changing under another process's writes; callers follow the seqlock
    /// protocol (docs/SHM.md) and discard what they copied when the sequence counter moved.
    pub fn read(&self, offset: usize, out: &mut [u8]) {
        self.check(offset, out.len(), 1);
        // SAFETY: `check` proved offset..offset+len lies inside the live mapping. The source is
        // read through a raw pointer (no reference to shared bytes is created); `u8` has no
        // invalid values, so whatever a concurrent writer leaves there is a valid `u8`, and the
        // protocol makes the caller discard a copy that overlapped a write. `out` is a distinct
        // private buffer, so the ranges cannot overlap.
        unsafe { std::ptr::copy_nonoverlapping(self.map.as_ptr().add(offset), out.as_mut_ptr(), out.len()) }
    }

    /// Copies bytes into the mapping. Only the writer calls this, and only for bytes outside
    /// every published valid region and outside the seqlocked fields (docs/SHM.md).
    pub fn write(&self, offset: usize, src: &[u8]) {
        self.check_writable();
        self.check(offset, src.len(), 1);
        let end = offset + src.len();
        let counted = end.min(self.counted.end).saturating_sub(offset.max(self.counted.start));
        self.copied.fetch_add(counted as u64, Ordering::Relaxed);
        // SAFETY: `check` proved offset..offset+len lies inside the live mapping, which is mapped
        // writable. The destination is written through a raw pointer (no reference is created);
        // `src` is a private buffer of this process, so the ranges cannot overlap. Readers in
        // other processes never rely on these bytes until a later seqlock publication says so.
        unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), self.map.as_mut_ptr().add(offset), src.len()) }
    }

    /// Lends the bytes `offset..offset + len` to `fill` as a mutable slice, so that a tile read
    /// (a `pread`, a decoder, a procedural generator) writes straight into the mapping.
    ///
    /// # Safety
    /// For as long as `fill` runs, no other code in this process may access these bytes (the
    /// caller holds the only claim on them: [`super::memory`] hands each slot to one read at a
    /// time through a compare-and-swap on the slot's claim), and other processes may only read
    /// them under the slot's tag protocol (they map the file read-only, and discard what they read
    /// while the tag says loading).
    pub unsafe fn fill<R>(&self, offset: usize, len: usize, fill: impl FnOnce(&mut [u8]) -> R) -> R {
        self.check_writable();
        self.check(offset, len, 1);
        // SAFETY: `check` proved offset..offset+len lies inside the live mapping, which is mapped
        // writable (`check_writable`) and stays mapped while `self` is borrowed. The caller
        // guarantees (this function's contract) that nothing else in this process reads or writes
        // these bytes while the slice lives, so the slice is the only access and may be `&mut`;
        // `u8` has no invalid values, so whatever the bytes hold is a valid `[u8]`.
        let bytes = unsafe { std::slice::from_raw_parts_mut(self.map.as_mut_ptr().add(offset), len) };
        fill(bytes)
    }

    /// Reads a little-endian u32 (static fields only).
    pub fn read_u32(&self, offset: usize) -> u32 {
        let mut b = [0u8; 4];
        self.read(offset, &mut b);
        u32::from_le_bytes(b)
    }

    /// Reads a little-endian u64 (static fields only).
    pub fn read_u64(&self, offset: usize) -> u64 {
        let mut b = [0u8; 8];
        self.read(offset, &mut b);
        u64::from_le_bytes(b)
    }
}
