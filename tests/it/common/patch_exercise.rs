//! One hostile patch through everything a growing texture does with a patch before it keeps it,
//! the way the service does: the sidecar parsed, the payload decoded and checked as `PATCH DATA`
//! takes it, and the same sidecar and payload read back from files as a watched directory reads
//! them (paths confined to the sidecar's directory). Nothing may panic, hang or allocate beyond
//! the bound given (a MiB of texels here). Shared by the fuzz target
//! (`fuzz/fuzz_targets/patch_input.rs`) and the property test (`patch_fuzz_props.rs`).
//!
//! The input: its first byte picks the grid's texel format, then the sidecar's JSON up to the
//! first newline, then the payload.
#![allow(dead_code)]

use clipmap::growing::input::{self, Paths};
use clipmap::growing::Grid;
use std::path::Path;

/// The texel formats tried: bytes a texel, bytes a component.
const FORMATS: [(usize, usize); 6] = [(1, 1), (3, 1), (4, 1), (2, 2), (6, 2), (8, 2)];

/// Most bytes of texels a patch may have here.
pub const MAX_BYTES: u64 = 1 << 20;

/// Runs one input (see the module documentation); `dir` is a scratch directory of its own.
pub fn exercise_patch(data: &[u8], dir: &Path) {
    let Some((&sel, rest)) = data.split_first() else { return };
    let (bpt, cb) = FORMATS[sel as usize % FORMATS.len()];
    let grid = Grid::new([0.0, 0.0], 1.0, 16, bpt, cb).expect("a valid grid");
    let cut = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
    let (json, payload) = (&rest[..cut], rest.get(cut + 1..).unwrap_or(&[]));

    // As PATCH DATA: the sidecar on the line, the payload after it.
    let taken = input::sidecar(json, "the request")
        .and_then(|d| input::new_patch(&grid, &d, payload.to_vec(), MAX_BYTES, "the request").map(|p| (d, p)));
    if let Ok((d, p)) = &taken {
        assert_eq!(
            p.patch.texels.len(),
            p.patch.width as usize * p.patch.height as usize * bpt,
            "texels of the size the patch says"
        );
        assert!(p.patch.texels.len() as u64 <= MAX_BYTES, "no more texels than the bound");
        if d.image.is_some() && clipmap::prep::jpeg_check::is_jpeg(payload) {
            assert!(clipmap::prep::jpeg_check::check(payload).is_ok(), "a cut JPEG is never taken");
        }
    }
    // The payload as an image on its own, whatever the sidecar said.
    if let Ok((w, h, t)) = input::decode_image(&grid, payload, MAX_BYTES, "the image") {
        assert_eq!(t.len(), w as usize * h as usize * bpt);
    }

    // As a watched directory reads it: the sidecar and its data as files.
    let side = dir.join("p.json");
    if std::fs::write(&side, json).is_err() {
        return;
    }
    let name = input::sidecar(json, "p.json").ok().and_then(|d| d.image.clone());
    let data_name = match &name {
        Some(n) if !n.is_empty() && Path::new(n).components().all(|c| matches!(c, std::path::Component::Normal(_))) => {
            Some(n.clone())
        }
        Some(_) => None,
        None => Some("p.raw".to_string()),
    };
    if let Some(n) = &data_name {
        let target = dir.join(n);
        if target.parent() == Some(dir) {
            let _ = std::fs::write(&target, payload);
        }
    }
    let read = input::read_sidecar(&grid, &side, MAX_BYTES, Paths::Inside);
    if let (Ok(_), Some(n)) = (&read, &name) {
        let p = Path::new(n);
        assert!(
            !p.is_absolute() && p.components().all(|c| matches!(c, std::path::Component::Normal(_))),
            "an image outside the sidecar's directory is never read: {n:?}"
        );
    }
    if let Some(n) = &data_name {
        let target = dir.join(n);
        if target.parent() == Some(dir) && target != side {
            let _ = std::fs::remove_file(&target);
        }
    }
}
