//! What a comparison of the GPU's pixels with the CPU sampler counts, below every module that
//! compares (`check` for colour, `heights` for heights), so that none of them imports another
//! for it.

use serde::Serialize;

/// The sampling half: the GPU's pixels against the CPU sampler at the GPU's footprints.
#[derive(Clone, Debug, Default, Serialize)]
pub struct SamplingDiff {
    /// Ground pixels compared (drawn as ground by the GPU).
    pub compared: u64,
    /// Pixels whose colour differs at all (any of R, G, B, A).
    pub differing: u64,
    /// Largest channel difference (8-bit units).
    pub max_error: u16,
}
