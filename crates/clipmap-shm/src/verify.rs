//! Verification of a mapping against a texel oracle (for the hash texture, docs/ARCHITECTURE.md
//! §11, the caller passes `clipmap::source::procedural::hash`): read random blocks of texels inside
//! the published valid regions and check every texel against the oracle.
//!
//! Used by `clipmap-read` and the tests; the C and Python readers do the same from the
//! documentation alone. The oracle is an argument: nothing here knows any texture's texels.

use super::client::{Client, ReadError};

/// The texel a verified texture should hold at (level, s, t), written into the buffer.
pub(crate) type Oracle<'a> = &'a dyn Fn(u32, u64, u64, &mut [u8]);

/// A small deterministic random generator for picking blocks (splitmix64 steps).
fn next(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Counts of one verifier.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct HashCheck {
    /// Texels equal to the hash texture.
    pub passed: u64,
    /// Texels that differ, plus consistently read states that break the layout's rules.
    pub failed: u64,
    /// Block reads whose level kept changing (retried later).
    pub busy: u64,
    /// Block reads given up because the slots moved on since the snapshot.
    pub moved: u64,
    /// Block reads that met a tile the service could not read (a coarser level serves it).
    pub missing: u64,
    /// Steps that found no usable level.
    pub idle: u64,
    /// Snapshots checked for consistency (every level from min LOD up published).
    pub snapshots: u64,
    /// Snapshots refused because the view read was removed from the service.
    pub view_removed: u64,
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
    /// `block` x `block` texels inside it, reads it tile by tile under the slot tags and checks
    /// every texel against `oracle`.
    pub fn step(&mut self, client: &Client, rng: &mut u64, block: u64, buf: &mut Vec<u8>, oracle: Oracle<'_>) {
        let level = (next(rng) % client.levels.len() as u64) as usize;
        let snap = match client.try_snapshot() {
            Ok(s) => s,
            Err(ReadError::Corrupt(why)) => {
                self.fail(format!("inconsistent published state: {why}"));
                return;
            }
            Err(ReadError::ViewRemoved(_)) => {
                self.view_removed += 1;
                return;
            }
            Err(_) => {
                self.busy += 1;
                return;
            }
        };
        // One snapshot, one moment: every level from min LOD up is published.
        self.snapshots += 1;
        let first = snap.min_lod.ceil() as usize;
        if let Some(k) = (first..snap.levels.len()).find(|&k| !snap.levels[k].enabled) {
            self.fail(format!(
                "inconsistent snapshot of tick {}: min LOD {} but level {k} is not published",
                snap.tick, snap.min_lod
            ));
            return;
        }
        let st = snap.levels[level];
        if !st.enabled {
            self.idle += 1;
            return;
        }
        let v = st.valid;
        let (vw, vh) = ((v[2] - v[0]) as u64, (v[3] - v[1]) as u64);
        let (w, h) = (vw.min(block), vh.min(block));
        let s0 = v[0] + (next(rng) % (vw - w + 1)) as i64;
        let t0 = v[1] + (next(rng) % (vh - h + 1)) as i64;
        let bpt = client.bytes_per_texel;
        buf.resize((w * h) as usize * bpt, 0);
        let rect = clipmap_base::geom::Rect::new(s0, t0, s0 + w as i64, t0 + h as i64);
        match client.read_region_in(&snap, level, rect, buf) {
            Ok(()) => {}
            Err(ReadError::Busy(_)) => {
                self.busy += 1;
                return;
            }
            Err(ReadError::Missing { .. }) => {
                self.missing += 1;
                return;
            }
            Err(ReadError::Corrupt(why)) => {
                self.fail(format!("level {level}: {why}"));
                return;
            }
            Err(_) => {
                self.moved += 1;
                return;
            }
        }
        let mut want = vec![0u8; bpt];
        for (i, got) in buf.chunks_exact(bpt).enumerate() {
            let (s, t) = (s0 + (i as u64 % w) as i64, (t0 + (i as u64 / w) as i64) as u64);
            // A wrapping texture's region may run past the width: texel s is texel s mod width.
            let s = client.texel_period(level).map_or(s as u64, |p| clipmap_base::geom::wrap(s, p));
            oracle(level as u32, s, t, &mut want);
            if got == want.as_slice() {
                self.passed += 1;
            } else {
                self.fail(format!("level {level} texel ({s}, {t}): read {got:02x?}, expected {want:02x?}"));
            }
        }
    }
}
