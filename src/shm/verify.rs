//! Verification of a mapping that serves the hash texture (docs/ARCHITECTURE.md §11): read random blocks of
//! texels inside the published valid regions and check every texel, and every consistently read
//! level state, against what the texture and the layout allow.
//!
//! Used by `clipmap-read` and the tests; the C and Python readers do the same from the
//! documentation alone.

use super::client::{Client, ReadError};
use crate::source::procedural::{hash, hash_value, splitmix64};

/// Counts of one verifier.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct HashCheck {
    /// Texels equal to the hash texture.
    pub passed: u64,
    /// Texels that differ, plus consistently read states that break the layout's rules.
    pub failed: u64,
    /// Block reads whose level kept changing (retried later).
    pub busy: u64,
    /// Block reads given up because the region left the valid region meanwhile.
    pub moved: u64,
    /// Steps that found no usable level.
    pub idle: u64,
    /// The first failure, described.
    pub first_failure: Option<String>,
}

impl HashCheck {
    fn fail(&mut self, what: String) {
        self.failed += 1;
        if self.first_failure.is_none() {
            self.first_failure = Some(what);
        }
    }

    /// One step: picks a random level with a published region, a random block of at most
    /// `block` x `block` texels inside it, reads it under the seqlock and checks every texel.
    pub fn step(&mut self, client: &Client, rng: &mut u64, block: u64, buf: &mut Vec<u8>) {
        let mut next = || {
            *rng = splitmix64(*rng);
            *rng
        };
        let level = (next() % client.levels.len() as u64) as usize;
        let Some(st) = client.level_state(level) else {
            self.busy += 1;
            return;
        };
        let d = client.levels[level];
        let v = st.valid;
        if st.enabled {
            let sane = v[0] >= 0
                && v[1] >= 0
                && v[0] < v[2]
                && v[1] < v[3]
                && v[2] as u64 <= d.size[0]
                && v[3] as u64 <= d.size[1]
                && ((v[2] - v[0]) as u64) <= d.window[0]
                && ((v[3] - v[1]) as u64) <= d.window[1];
            if !sane {
                self.fail(format!("level {level}: inconsistent published state {st:?}"));
                return;
            }
        } else {
            self.idle += 1;
            return;
        }
        let (vw, vh) = ((v[2] - v[0]) as u64, (v[3] - v[1]) as u64);
        let (w, h) = (vw.min(block), vh.min(block));
        let s0 = v[0] + (next() % (vw - w + 1)) as i64;
        let t0 = v[1] + (next() % (vh - h + 1)) as i64;
        let bpt = client.bytes_per_texel;
        buf.resize((w * h) as usize * bpt, 0);
        match client.read_region(level, s0, t0, w, h, buf) {
            Ok(_) => {}
            Err(ReadError::Busy(_)) => {
                self.busy += 1;
                return;
            }
            Err(_) => {
                self.moved += 1;
                return;
            }
        }
        let mut want = vec![0u8; bpt];
        for (i, got) in buf.chunks_exact(bpt).enumerate() {
            let (s, t) = ((s0 + (i as u64 % w) as i64) as u64, (t0 + (i as u64 / w) as i64) as u64);
            let ok = if bpt <= 8 {
                got == &hash_value(level as u32, s, t).to_le_bytes()[..bpt]
            } else {
                hash(level as u32, s, t, &mut want);
                got == want.as_slice()
            };
            if ok {
                self.passed += 1;
            } else {
                self.fail(format!("level {level} texel ({s}, {t}): read {got:02x?}"));
            }
        }
    }
}
