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

/// A shared mapping of a whole file.
pub struct Region {
    map: MmapRaw,
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
        Ok(Region { map })
    }

    /// Length in bytes.
    pub fn len(&self) -> usize {
        self.map.len()
    }

    /// True for an empty mapping.
    pub fn is_empty(&self) -> bool {
        self.map.len() == 0
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
        self.atomic(offset).store(value, order)
    }

    /// Atomically adds to the u64 at `offset`, returning the previous value.
    pub fn fetch_add(&self, offset: usize, value: u64, order: Ordering) -> u64 {
        self.atomic(offset).fetch_add(value, order)
    }

    /// Atomic compare-and-exchange of the u64 at `offset`.
    pub fn compare_exchange(&self, offset: usize, current: u64, new: u64) -> Result<u64, u64> {
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
        self.check(offset, src.len(), 1);
        // SAFETY: `check` proved offset..offset+len lies inside the live mapping, which is mapped
        // writable. The destination is written through a raw pointer (no reference is created);
        // `src` is a private buffer of this process, so the ranges cannot overlap. Readers in
        // other processes never rely on these bytes until a later seqlock publication says so.
        unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), self.map.as_mut_ptr().add(offset), src.len()) }
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

    /// Makes the mapping's contents durable for other processes that map the file later.
    pub fn flush(&self) -> std::io::Result<()> {
        self.map.flush()
    }
}
