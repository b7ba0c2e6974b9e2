//! Names in shared directories: the mapping, the lock file and the control socket live in a
//! directory other users may write (`/dev/shm`, the temporary directory), so every name there is
//! treated as possibly planted by someone else.
//!
//! The rules: a name is never followed if it is a symbolic link; a file is created only with
//! `O_EXCL` (so nothing existing is truncated or replaced by the create) and then given exactly
//! the requested permission bits with `fchmod`, whatever the umask; an existing file is used only
//! when it is a regular file (or, for the socket, a socket) owned by this process's user, and
//! otherwise refused with [`ShmError::Foreign`], which names the file, what it is and its owner;
//! a name is removed only when it still is the very file (device and inode) this process made.
//!
//! Opening configuration files and tiles is [`clipmap_base::open`]'s business.

use super::ShmError;
use rustix::fs::OFlags;
use std::fs::{File, Metadata, OpenOptions, Permissions};
use std::io;
use std::os::unix::fs::{MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::Path;

/// This process's effective user id.
pub fn euid() -> u32 {
    rustix::process::geteuid().as_raw()
}

/// A user id in words: `uid 1001 (alice)`, the name from `/etc/passwd` when it is there.
pub fn owner(uid: u32) -> String {
    let name = clipmap_base::open::read_bounded(Path::new("/etc/passwd"), 1 << 20).ok().and_then(|b| {
        String::from_utf8_lossy(&b).lines().find_map(|l| {
            let mut f = l.split(':');
            let (name, _, id) = (f.next()?, f.next()?, f.next()?);
            (id.parse() == Ok(uid)).then(|| name.to_string())
        })
    });
    match name {
        Some(n) => format!("uid {uid} ({n})"),
        None => format!("uid {uid}"),
    }
}

/// Identity of a file: device and inode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    dev: u64,
    ino: u64,
}

impl Identity {
    /// The identity `meta` describes.
    pub fn of(meta: &Metadata) -> Identity {
        Identity { dev: meta.dev(), ino: meta.ino() }
    }
}

fn foreign(path: &Path, meta: &Metadata, what: &str) -> ShmError {
    let kind = clipmap_base::open::kind_of(meta);
    ShmError::Foreign { path: path.to_path_buf(), why: format!("it is {kind} owned by {}, {what}", owner(meta.uid())) }
}

/// Refuses an existing entry that is not a regular file owned by this user (a symbolic link
/// included: it is not followed).
pub(crate) fn check_own_file(path: &Path, meta: &Metadata) -> Result<(), ShmError> {
    if !meta.file_type().is_file() {
        return Err(foreign(path, meta, "not a regular file this service made; remove it or choose another --name"));
    }
    if meta.uid() != euid() {
        return Err(foreign(
            path,
            meta,
            &format!("not by this service's user ({}); remove it or choose another --name", owner(euid())),
        ));
    }
    Ok(())
}

/// Creates `path` (which must not exist; a symbolic link there counts as existing) read-write
/// with exactly `mode`.
pub(crate) fn create_new(path: &Path, mode: u32) -> io::Result<File> {
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create_new(true)
        .mode(mode)
        .custom_flags((OFlags::NOFOLLOW | OFlags::NONBLOCK).bits() as i32)
        .open(path)?;
    file.set_permissions(Permissions::from_mode(mode))?;
    Ok(file)
}

/// Refuses an entry that [`check_own_file`] refuses, and also one with more than one hard link:
/// a name that is only another name of some file (a victim linked into the shared directory), so
/// that writing to it would write into that file.
pub(crate) fn check_own_single_file(path: &Path, meta: &Metadata) -> Result<(), ShmError> {
    check_own_file(path, meta)?;
    if meta.nlink() != 1 {
        return Err(ShmError::Foreign {
            path: path.to_path_buf(),
            why: format!(
                "it is a regular file with {} hard links (a name linked to another file, which would be written through it), not a file this service made; remove it or choose another --name",
                meta.nlink()
            ),
        });
    }
    Ok(())
}

/// Opens the existing `path` read-write without following a symbolic link and without blocking,
/// when it is a regular file owned by this user with no other hard link (so nothing written to
/// it lands in another file); the checks are made before the open (so no device or FIFO is ever
/// opened) and again on the open file (so a swap in between is caught).
pub(crate) fn open_own(path: &Path) -> Result<File, ShmError> {
    let io_err = |source| ShmError::Io { path: path.to_path_buf(), source };
    let before = std::fs::symlink_metadata(path).map_err(io_err)?;
    check_own_single_file(path, &before)?;
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags((OFlags::NOFOLLOW | OFlags::NONBLOCK).bits() as i32)
        .open(path)
        .map_err(|e| match std::fs::symlink_metadata(path) {
            Ok(m) if e.raw_os_error() == Some(rustix::io::Errno::LOOP.raw_os_error()) => {
                foreign(path, &m, "and is not followed")
            }
            _ => io_err(e),
        })?;
    let after = file.metadata().map_err(io_err)?;
    check_own_single_file(path, &after)?;
    if Identity::of(&before) != Identity::of(&after) {
        return Err(ShmError::Foreign { path: path.to_path_buf(), why: "it was replaced while being opened".into() });
    }
    let flags = rustix::fs::fcntl_getfl(&file).map_err(|e| io_err(e.into()))?;
    rustix::fs::fcntl_setfl(&file, flags - OFlags::NONBLOCK).map_err(|e| io_err(e.into()))?;
    Ok(file)
}

/// Removes `path` only if it still is the file `id` (this process's): a name someone else has
/// taken since is left alone.
pub fn remove_if_same(path: &Path, id: Identity) {
    if let Ok(m) = std::fs::symlink_metadata(path) {
        if Identity::of(&m) == id {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// Renames `from` to `to`, failing with [`io::ErrorKind::AlreadyExists`] rather than replacing
/// anything at `to`.
pub fn rename_no_replace(from: &Path, to: &Path) -> io::Result<()> {
    use rustix::fs::{renameat_with, RenameFlags, CWD};
    match renameat_with(CWD, from, CWD, to, RenameFlags::NOREPLACE) {
        Ok(()) => Ok(()),
        // A file system without RENAME_NOREPLACE: a hard link never replaces either.
        Err(rustix::io::Errno::INVAL) => std::fs::hard_link(from, to).and_then(|()| std::fs::remove_file(from)),
        Err(e) => Err(e.into()),
    }
}
