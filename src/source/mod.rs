//! Tile sources: where texels come from (files described by a plan, or procedural textures).
//!
//! This module owns texel *values*; residency, queues and windows belong to later modules.

pub mod procedural;
