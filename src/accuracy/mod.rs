//! The accuracy study: a reference software renderer draws a perspective view of a textured
//! ground plane twice per frame, from the full mipmap (ground truth, straight from the tile
//! source) and from the clipmap as published, and measures the difference (docs/ARCHITECTURE.md §10).
//!
//! Owns the camera and per-pixel LOD ([`render`]), the per-frame metrics and flights over a
//! clipmap ([`study`]), the parameter sweep ([`sweep`]) and the vertical error of height
//! textures ([`heights`]). Sampling itself is
//! [`crate::sample`]'s; moving the clipmap is [`crate::clip`]'s.
//!
//! Numerics: texel addressing is integer (i64/u64) everywhere; world positions, ray directions
//! and texture coordinates are f64 (a 2^26 texture needs 26 bits of integer part plus the
//! fraction, beyond f32's 24-bit mantissa); colours are f32 in 0..=1 and compared after
//! quantising to 8 bits per channel, or to 16 for a case with a 16-bit texel format
//! ([`study::Case::format`]; PSNR then against a peak of 65535).

pub(crate) mod cache;
pub mod formats;
pub mod heights;
pub mod render;
pub mod study;
pub mod sweep;

#[cfg(test)]
mod tests;
