//! Stage two: syntax tree → validated, immutable plan.
pub fn _placeholder() {}
