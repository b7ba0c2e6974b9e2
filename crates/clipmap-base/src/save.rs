//! Writing a result file (a picture, a report) so that it is either complete or absent: the
//! bytes go to a temporary file in the same directory, which is flushed and synced (every error
//! checked, the final flush too) and then renamed over the target. A failed or interrupted write
//! leaves the target as it was and removes the temporary file.
//!
//! A target that exists and is not a regular file (`/dev/stdout`, `/dev/full`, a FIFO) is
//! written in place instead, never replaced: the flush is still checked, so a full device is an
//! error. A file that must be a file (a COG) is written by [`atomically_regular`] instead,
//! which refuses such a target before opening it (opening a FIFO for writing blocks until a
//! reader comes). A temporary that a killed process left is removed by the next write of the
//! same target ([`remove_stale`]). Directories that tools write whole are
//! `clipmap::prep::output`'s business.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

/// Writes `path` through `fill`, completely or not at all (see the module documentation).
pub fn atomically(path: &Path, fill: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>) -> io::Result<()> {
    if let Ok(meta) = std::fs::metadata(path) {
        if !meta.is_file() {
            if meta.is_dir() {
                return Err(io::Error::new(io::ErrorKind::IsADirectory, "is a directory"));
            }
            let f = OpenOptions::new().write(true).open(path)?;
            let mut w = BufWriter::new(f);
            fill(&mut w)?;
            w.flush()?;
            return Ok(());
        }
    }
    replace(path, fill)
}

/// Writes `path` through `fill` as [`atomically`] does, but only as a regular file: an existing
/// target that is a FIFO, a device, a socket or a directory is refused before anything is
/// opened (an error of kind [`io::ErrorKind::InvalidInput`] saying what it is), never written in
/// place. A symbolic link is replaced by the file, as any rename replaces it.
pub fn atomically_regular(path: &Path, fill: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>) -> io::Result<()> {
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
        // `crate::open::regular_or_absent` says what it is; callers check with it first.
        return Err(io::Error::new(io::ErrorKind::InvalidInput, "not a regular file"));
    }
    replace(path, fill)
}

/// The temporary beside `path`, filled, synced and renamed over it.
fn replace(path: &Path, fill: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>) -> io::Result<()> {
    remove_stale(path, ".tmp.", "");
    let (tmp, file) = temporary(path)?;
    let written = (|| {
        let mut w = BufWriter::new(file);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

/// The I/O error inside an image encoder's error (so that a full disk stays `ENOSPC`).
pub fn image_io(e: image::ImageError) -> io::Error {
    match e {
        image::ImageError::IoError(e) => e,
        other => io::Error::other(other),
    }
}

/// Removes, beside `path`, the files `.NAME{infix}PID{suffix}` (and `.NAME{infix}PID.N{suffix}`)
/// that a process now gone left behind (killed before it could clean up). A live process's
/// files, this process's among them, are left alone; so is anything that is not a regular file.
pub fn remove_stale(path: &Path, infix: &str, suffix: &str) {
    let Some(name) = path.file_name().and_then(|n| n.to_str()) else { return };
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let prefix = format!(".{name}{infix}");
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let file_name = e.file_name();
        let Some(rest) = file_name.to_str().and_then(|n| n.strip_prefix(&prefix)).and_then(|r| r.strip_suffix(suffix))
        else {
            continue;
        };
        let pid = rest.split_once('.').map_or(rest, |(p, _)| p);
        let Ok(pid) = pid.parse::<u32>() else { continue };
        let is_file = e.file_type().is_ok_and(|t| t.is_file());
        if is_file && pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists() {
            tracing::info!(path = %e.path().display(), "removing the temporary of a process that was killed");
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// Creates `.NAME.tmp.PID.N` beside `path` (never an existing file).
fn temporary(path: &Path) -> io::Result<(PathBuf, File)> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut last = io::Error::other("no temporary name was free");
    for n in 0..16 {
        let tmp = dir.join(format!(".{name}.tmp.{}.{n}", std::process::id()));
        match OpenOptions::new().write(true).create_new(true).mode(0o644).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => last = e,
            Err(e) => return Err(e),
        }
    }
    Err(last)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_complete_write_replaces_and_a_failed_one_leaves_the_old_file_and_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.txt");
        atomically(&p, |w| w.write_all(b"one")).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"one");
        let e = atomically(&p, |w| {
            w.write_all(b"half")?;
            Err(io::Error::other("stopped"))
        });
        assert!(e.is_err());
        assert_eq!(std::fs::read(&p).unwrap(), b"one");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "no temporary left");
    }

    #[test]
    fn a_full_device_is_an_error() {
        if !Path::new("/dev/full").exists() {
            return;
        }
        let e = atomically(Path::new("/dev/full"), |w| w.write_all(&[0u8; 100])).unwrap_err();
        assert_eq!(e.raw_os_error(), Some(28), "ENOSPC: {e}");
    }
}
