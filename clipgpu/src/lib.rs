//! `clipgpu`: a headless GPU renderer (wgpu, Vulkan) of a `clipmapd` service's clip texture.
//! It attaches by name, keeps one texture array layer per level mirroring the level's image
//! cache, uploads each frame only the tiles that entered the published valid regions, draws the
//! accuracy study's reference flight over a textured ground plane with a fragment shader that
//! applies the clipmap sampling rule (published valid regions, slot tags, min LOD; trilinear), and
//! compares every frame with the reference software renderer on the same snapshot
//! (docs/GPU.md). Height textures (`l32f`, `l16`, `l16i`) are drawn in false colour and their
//! sampled heights compared in metres.

#![forbid(unsafe_code)]

pub mod check;
pub mod coords;
pub mod demo;
pub mod diff;
pub mod flight;
pub mod gpu;
pub mod heights;
pub mod shading;
pub mod summary;
pub mod upload;

/// An error in what the user gave (exit status 1); every other error is "could not run" (2).
#[derive(Debug)]
pub struct BadInput(pub String);

impl std::fmt::Display for BadInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BadInput {}

/// The exit status for an error, by the tools' rule (`clipmap::report::exit`): bad input, or
/// anything that kept clipgpu from running.
pub fn exit_code(e: &anyhow::Error) -> i32 {
    use clipmap::report::exit;
    if e.chain().any(|c| c.is::<BadInput>()) {
        exit::BAD_INPUT
    } else {
        exit::COULD_NOT_RUN
    }
}
