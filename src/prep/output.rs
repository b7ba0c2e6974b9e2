//! The output directory: checks before writing, a temporary sibling to write into, and the
//! final rename, so an interrupted or failed run never leaves a half-written pyramid at the
//! requested path.
//!
//! An existing directory is replaced only when it is empty, or holds a clip texture (a `.ct` at
//! its top) and `force` was given; anything else is never touched.

use super::error::PrepError;
use std::fs;
use std::path::{Path, PathBuf};

/// A temporary directory that becomes the output directory on [`Staging::commit`], and is
/// removed if dropped before that.
#[derive(Debug)]
pub struct Staging {
    target: PathBuf,
    tmp: PathBuf,
    force: bool,
    committed: bool,
}

fn write_err(path: &Path, e: std::io::Error) -> PrepError {
    PrepError::write(path, e, 0)
}

/// What is at the output path now.
enum Existing {
    Nothing,
    Empty,
    ClipTexture(PathBuf),
    Other,
}

fn existing(dir: &Path) -> Existing {
    let Ok(meta) = fs::symlink_metadata(dir) else {
        return Existing::Nothing;
    };
    if !meta.is_dir() {
        return Existing::Other;
    }
    let Ok(entries) = fs::read_dir(dir) else {
        return Existing::Other;
    };
    let mut any = false;
    for e in entries.flatten() {
        any = true;
        let p = e.path();
        if p.extension().is_some_and(|x| x == "ct") && p.is_file() {
            return Existing::ClipTexture(p);
        }
    }
    if any {
        Existing::Other
    } else {
        Existing::Empty
    }
}

fn check(dir: &Path, force: bool) -> Result<(), PrepError> {
    match existing(dir) {
        Existing::Nothing | Existing::Empty => Ok(()),
        Existing::ClipTexture(_) if force => Ok(()),
        Existing::ClipTexture(ct) => Err(PrepError::OutputHoldsPyramid { dir: dir.into(), ct }),
        Existing::Other => Err(PrepError::OutputOccupied { dir: dir.into() }),
    }
}

fn sibling(dir: &Path, tag: &str) -> PathBuf {
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    parent.join(format!(".{name}.clipprep-{tag}-{}", std::process::id()))
}

/// Removes what killed runs for the same output left beside it: `.NAME.clipprep-partial-PID`
/// directories whose process is gone (a live one, another run in progress, is left alone).
fn remove_stale(parent: &Path, dir: &Path) {
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    let prefix = format!(".{name}.clipprep-partial-");
    let Ok(entries) = fs::read_dir(parent) else { return };
    for e in entries.flatten() {
        let file_name = e.file_name();
        let Some(pid) = file_name.to_str().and_then(|n| n.strip_prefix(&prefix)) else { continue };
        let Ok(pid) = pid.parse::<u32>() else { continue };
        let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
        if is_dir && pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists() {
            tracing::info!(path = %e.path().display(), "removing the partial output of a run that was killed");
            let _ = fs::remove_dir_all(e.path());
        }
    }
}

impl Staging {
    /// Checks that `dir` may be written and creates the temporary sibling directory.
    pub fn begin(dir: &Path, force: bool) -> Result<Staging, PrepError> {
        check(dir, force)?;
        let tmp = sibling(dir, "partial");
        if let Some(parent) = tmp.parent() {
            fs::create_dir_all(parent).map_err(|e| write_err(parent, e))?;
            remove_stale(parent, dir);
        }
        if tmp.exists() {
            fs::remove_dir_all(&tmp).map_err(|e| write_err(&tmp, e))?;
        }
        fs::create_dir(&tmp).map_err(|e| write_err(&tmp, e))?;
        Ok(Staging { target: dir.into(), tmp, force, committed: false })
    }

    /// The directory to write into.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// Moves the finished output into place (replacing what [`Staging::begin`] accepted).
    pub fn commit(mut self) -> Result<(), PrepError> {
        check(&self.target, self.force)?;
        match existing(&self.target) {
            Existing::Nothing => {}
            Existing::Empty => fs::remove_dir(&self.target).map_err(|e| write_err(&self.target, e))?,
            _ => {
                let old = sibling(&self.target, "old");
                fs::rename(&self.target, &old).map_err(|e| write_err(&self.target, e))?;
                fs::rename(&self.tmp, &self.target).map_err(|e| write_err(&self.target, e))?;
                self.committed = true;
                fs::remove_dir_all(&old).map_err(|e| write_err(&old, e))?;
                return Ok(());
            }
        }
        fs::rename(&self.tmp, &self.target).map_err(|e| write_err(&self.target, e))?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
}
