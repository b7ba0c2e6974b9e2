//! Where a tile's CPU goes in `clipbench tiles` (`tiles.rs`): CPU time, not wall time, so that
//! the figures hold on a machine other work shares.
//!
//! - ours: this process's CPU clock (every thread, those that ended included; nanoseconds) over
//!   the timed passes;
//! - its stages: a pass that only fetches each tile's bytes through the kind's archive (the
//!   HTTP client, the remote stack, the archive's directories), and a pass of the same pyramid
//!   source over the tiles' bytes held in memory (`MemoryArchive`: the checks, the decode into
//!   the slot, the copies), each on a fresh open, `depth` threads, this process's CPU clock;
//! - the decode alone, each thread's own CPU clock around the decoder call;
//! - curl: its processes' CPU (the children's user and system time that the kernel adds up when
//!   they end, in 1/100 s);
//! - nginx: its one process's CPU (user and system, 1/100 s) while ours or curl's pass runs.

use clipmap::source::tiles::{ArchiveError, Fetched, PyramidInfo, TileAddr, TileArchive};
use clipmap::source::TileId;
use rustix::time::{clock_gettime, ClockId};
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};

fn seconds(t: rustix::time::Timespec) -> f64 {
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

/// This process's CPU seconds so far (all threads).
pub fn process_s() -> f64 {
    seconds(clock_gettime(ClockId::ProcessCPUTime))
}

/// The calling thread's CPU seconds so far.
pub fn thread_s() -> f64 {
    seconds(clock_gettime(ClockId::ThreadCPUTime))
}

/// User plus system seconds of `/proc/PID/stat` (`self` or a pid): fields `first` and
/// `first + 1` after the command's closing parenthesis (utime/stime at 14, cutime/cstime at 16).
fn stat_s(pid: &str, first: usize) -> f64 {
    let text = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let after = text.rfind(')').map_or("", |i| &text[i + 1..]);
    // After ")": field 3 (state) is the first word.
    let f: Vec<u64> = after.split_whitespace().map(|x| x.parse().unwrap_or(0)).collect();
    let at = |n: usize| f.get(n - 3).copied().unwrap_or(0);
    (at(first) + at(first + 1)) as f64 / 100.0
}

/// CPU seconds of this process's children that have ended (curl's runs).
pub fn children_s() -> f64 {
    stat_s("self", 16)
}

/// CPU seconds of process `pid` (nginx).
pub fn pid_s(pid: u32) -> f64 {
    stat_s(&pid.to_string(), 14)
}

/// Runs `each` over every tile of `ids` on `depth` threads, each thread with a buffer of its own
/// (kept from tile to tile, as the engine's read queues keep theirs); this process's CPU seconds.
pub fn pass_cpu(ids: &[TileId], depth: u64, each: &(dyn Fn(TileId, &mut Vec<u8>) + Sync)) -> f64 {
    let next = AtomicU64::new(0);
    let c0 = process_s();
    std::thread::scope(|scope| {
        for _ in 0..depth {
            scope.spawn(|| {
                let mut buf = Vec::new();
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed) as usize;
                    let Some(&id) = ids.get(i) else { return };
                    each(id, &mut buf);
                }
            });
        }
    });
    process_s() - c0
}

/// Tiles held in memory, served as an archive: a pyramid source over it costs only its checks,
/// decode and copies.
pub struct MemoryArchive {
    pub info: PyramidInfo,
    pub tiles: HashMap<(u8, u32, u32), Vec<u8>>,
}

impl TileArchive for MemoryArchive {
    fn place(&self) -> &str {
        "the tiles in memory"
    }

    fn info(&self) -> &PyramidInfo {
        &self.info
    }

    fn fetch(&self, at: TileAddr) -> Result<Fetched, ArchiveError> {
        Ok(self.tiles.get(&(at.z, at.x, at.y)).map_or(Fetched::Missing, |b| Fetched::Tile(b.clone())))
    }
}
