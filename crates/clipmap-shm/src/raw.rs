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
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

/// A shared mapping of a whole file (or an anonymous one, for an engine without a service).
pub struct Region {
    map: MmapRaw,
    writable: bool,
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
        Ok(Region { map, writable: true })
    }

    /// [`map`](Self::map), with every page faulted in now (the service's texel mapping: tile
    /// reads then write into memory that is already there, instead of faulting page by page).
    pub(crate) fn map_populated(file: &File) -> std::io::Result<Region> {
        let map = memmap2::MmapOptions::new().populate().map_raw(file)?;
        Ok(Region { map, writable: true })
    }

    /// Maps `file` read-only and shared: loads only (a reader of the texel mapping).
    pub(crate) fn map_read_only(file: &File) -> std::io::Result<Region> {
        let map = memmap2::MmapOptions::new().map_raw_read_only(file)?;
        Ok(Region { map, writable: false })
    }

    /// A private anonymous mapping of `len` zero bytes (an engine's image caches in-process).
    pub fn anonymous(len: usize) -> std::io::Result<Region> {
        let map = MmapRaw::from(memmap2::MmapOptions::new().len(len.max(1)).populate().map_anon()?);
        Ok(Region { map, writable: true })
    }

    fn check(&self, offset: usize, len: usize, align: usize) {
        let end = offset.checked_add(len).expect("shared-memory access overflows");
        assert!(
            end <= self.map.len(),
            "shared-memory access {offset}..{end} is outside the mapping of {} bytes",
            self.map.len()
        );
        assert!(
            (self.map.as_ptr() as usize + offset).is_multiple_of(align),
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

    fn atomic32(&self, offset: usize) -> &AtomicU32 {
        self.check(offset, 4, 4);
        // SAFETY: as in `atomic`, for 4 bytes at a 4-byte aligned address inside the mapping.
        unsafe { AtomicU32::from_ptr(self.map.as_mut_ptr().add(offset).cast::<u32>()) }
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

    /// Copies bytes out of the mapping (texels: a slot's bytes).
    ///
    /// # Safety
    /// Either nothing writes these bytes while they are copied (an in-process reader of a slot
    /// whose claim is settled, holding the memory's slot keeper, without which nothing reopens
    /// it: `memory::SlotKeeper`), or the caller is a seqlock reader: it read the slot's tag
    /// before the copy, reads it again after (acquire), and discards the copy when the tag moved,
    /// because the only writer of a slot's bytes (a tile read, in this process or the service's)
    /// moves the tag to loading first (docs/SHM.md).
    pub unsafe fn read(&self, offset: usize, out: &mut [u8]) {
        self.check(offset, out.len(), 1);
        // SAFETY: `check` proved offset..offset+len lies inside the live mapping. The source is
        // read through a raw pointer (no reference to shared bytes is created) and `u8` has no
        // invalid values, so whatever a writer leaves there is a valid `u8`; a copy that may have
        // overlapped a write is never used (the caller's contract). `out` is a distinct private
        // buffer, so the ranges cannot overlap.
        unsafe { std::ptr::copy_nonoverlapping(self.map.as_ptr().add(offset), out.as_mut_ptr(), out.len()) }
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

    /// Reads a little-endian u32 (static fields, read after the magic's acquire load): an
    /// atomic load, so that a writer that breaks the protocol cannot make it a data race.
    pub(crate) fn read_u32(&self, offset: usize) -> u32 {
        self.atomic32(offset).load(Ordering::Relaxed)
    }

    /// Reads a little-endian u64 (static fields; see [`read_u32`](Self::read_u32)).
    pub(crate) fn read_u64(&self, offset: usize) -> u64 {
        self.atomic(offset).load(Ordering::Relaxed)
    }

    /// Writes a little-endian u32 (static fields, before the magic is published): an atomic
    /// store.
    pub(crate) fn write_u32(&self, offset: usize, value: u32) {
        self.check_writable();
        self.atomic32(offset).store(value, Ordering::Relaxed)
    }
}
