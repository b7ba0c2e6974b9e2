//! The one way to open a file that a configuration or a command line names: configuration files,
//! `.ic` files, tiles, default tiles and input images.
//!
//! Only regular files are opened. The open itself never blocks (`O_NONBLOCK`, so a FIFO with no
//! writer or a device that waits is not a hang), then `fstat` decides: a FIFO, a device, a
//! directory or a socket is refused with [`not_regular`]'s error, naming what it is; a regular
//! file gets its blocking mode back. A "regular" file of the kernel's pseudo-filesystems (`/proc`,
//! `/sys`, debugfs, tracefs: `/proc/kmsg`, `trace_pipe`) is refused too, found by `fstatfs`:
//! such files claim a length of 0 and their reads block until the kernel has something to say
//! (or never end), and none of them holds a texture. Symbolic links are followed (tile trees are
//! often links into other disks); what they lead to is what is checked. Reads are bounded by
//! what the caller's format implies ([`read_bounded`], [`read_sized`]); nothing here reads a
//! file whole without a bound.
//!
//! What a file holds is left to the callers; names in shared directories (the service's mapping,
//! lock and socket) are `clipmap::shm::names`'s business: those are never followed at all.

use rustix::fs::OFlags;
use std::fs::{File, Metadata, OpenOptions};
use std::io::{self, Read};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// What a file that is not a regular file is, in words ("a FIFO", "a directory", ...).
pub fn kind_of(meta: &Metadata) -> &'static str {
    let t = meta.file_type();
    if t.is_file() {
        "a regular file"
    } else if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_symlink() {
        "a symbolic link"
    } else {
        "not a regular file"
    }
}

/// The error for a file that is not a regular file (kind [`io::ErrorKind::InvalidInput`]).
pub fn not_regular(meta: &Metadata) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, format!("{}, not a regular file", kind_of(meta)))
}

/// The kernel's pseudo-filesystems whose files are not data: their `statfs` magic numbers
/// (`linux/magic.h`) and names.
const PSEUDO_FILESYSTEMS: [(i64, &str); 4] =
    [(0x9fa0, "proc (/proc)"), (0x6265_6572, "sysfs (/sys)"), (0x6462_6720, "debugfs"), (0x7472_6163, "tracefs")];

/// The name of the kernel pseudo-filesystem `file` lives on, if it does.
pub fn pseudo_filesystem(file: &File) -> io::Result<Option<&'static str>> {
    let st = rustix::fs::fstatfs(file)?;
    // The field is a C long on most targets and an unsigned 32-bit number on a few.
    #[allow(clippy::unnecessary_cast)]
    let magic = st.f_type as i64;
    Ok(PSEUDO_FILESYSTEMS.iter().find(|(m, _)| *m == magic).map(|(_, name)| *name))
}

/// The error for a file of a kernel pseudo-filesystem (kind [`io::ErrorKind::InvalidInput`]).
pub fn not_data(filesystem: &str) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!(
            "a file of the kernel's {filesystem} filesystem, not a regular file of data (its reads can block or never end); name a file on a disk"
        ),
    )
}

/// Opens `path` for reading if it is (or a symbolic link leads to) a regular file; returns the
/// file and its metadata. Never blocks on a FIFO or device: those, directories and sockets are
/// refused with [`not_regular`]'s error, and files of the kernel's pseudo-filesystems
/// (`/proc/kmsg`, whose reads block) with [`not_data`]'s, before anything is read.
pub fn regular(path: &Path) -> io::Result<(File, Metadata)> {
    let file = OpenOptions::new().read(true).custom_flags(OFlags::NONBLOCK.bits() as i32).open(path)?;
    data_file(file)
}

/// The checks every open of this module ends with, on a file opened without blocking: a regular
/// file, not of a pseudo-filesystem; then blocking mode restored.
fn data_file(file: File) -> io::Result<(File, Metadata)> {
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(not_regular(&meta));
    }
    if let Some(fs) = pseudo_filesystem(&file)? {
        return Err(not_data(fs));
    }
    let flags = rustix::fs::fcntl_getfl(&file)?;
    rustix::fs::fcntl_setfl(&file, flags - OFlags::NONBLOCK)?;
    Ok((file, meta))
}

/// Refuses a `path` that exists and is not a regular file (nor a link to one), saying what it
/// is, without opening it: what a tool is asked to write as a file (opening a FIFO for writing
/// blocks until a reader comes; a device would swallow the file). Nothing there is fine.
pub fn regular_or_absent(path: &Path) -> io::Result<()> {
    match std::fs::metadata(path) {
        Ok(meta) if !meta.is_file() => Err(not_regular(&meta)),
        _ => Ok(()),
    }
}

/// Reads at most `max + 1` bytes of the regular file `path`, so that a caller can tell a file
/// longer than `max` (it then has more than `max` bytes) without reading it whole.
pub fn read_bounded(path: &Path, max: u64) -> io::Result<Vec<u8>> {
    let (file, meta) = regular(path)?;
    let mut buf = Vec::with_capacity(meta.len().min(max.saturating_add(1)).min(1 << 20) as usize);
    file.take(max.saturating_add(1)).read_to_end(&mut buf)?;
    Ok(buf)
}

/// Reads the regular file `path` when its length is one of `allowed`; any other length is an
/// error of kind [`io::ErrorKind::InvalidData`] that gives it (`len` bytes), and nothing is read.
/// Allocates no more than the largest allowed length.
pub fn read_sized(path: &Path, allowed: &[u64]) -> Result<Vec<u8>, SizedError> {
    let (file, meta) = regular(path).map_err(SizedError::Io)?;
    let len = meta.len();
    if !allowed.contains(&len) {
        return Err(SizedError::Length(len));
    }
    let mut buf = Vec::with_capacity(len as usize);
    file.take(len).read_to_end(&mut buf).map_err(SizedError::Io)?;
    if buf.len() as u64 != len {
        return Err(SizedError::Length(buf.len() as u64));
    }
    Ok(buf)
}

/// Reads the regular file `path` when it holds at most `max` bytes. A longer file is refused
/// from its length ([`SizedError::Length`]) before anything is read, so a sparse file of
/// gigabytes costs nothing; a file that grows while it is read is cut at `max + 1` bytes and
/// refused the same way. Allocates no more than the file's length (at most `max + 1` bytes).
pub fn read_capped(path: &Path, max: u64) -> Result<Vec<u8>, SizedError> {
    let (file, meta) = regular(path).map_err(SizedError::Io)?;
    read_open_capped(file, &meta, max)
}

/// [`read_capped`] for a file already opened with [`regular`] or [`regular_in`].
pub fn read_open_capped(file: File, meta: &Metadata, max: u64) -> Result<Vec<u8>, SizedError> {
    if meta.len() > max {
        return Err(SizedError::Length(meta.len()));
    }
    let mut buf = Vec::with_capacity(meta.len() as usize);
    file.take(max.saturating_add(1)).read_to_end(&mut buf).map_err(SizedError::Io)?;
    if buf.len() as u64 > max {
        return Err(SizedError::Length(buf.len() as u64));
    }
    Ok(buf)
}

/// Opens `name`, a relative path inside the directory `dir`, for reading if it is a regular file,
/// without ever leaving `dir`: `name` must be made of plain names only (no `..`, `.`, no root),
/// and no symbolic link is followed along it (every component is opened with `O_NOFOLLOW`
/// relative to the one before). `dir` itself is opened as given. Never blocks on a FIFO or a
/// device: those, directories, sockets and links are refused with an error that says what the
/// component is.
pub fn regular_in(dir: &Path, name: &Path) -> io::Result<(File, Metadata)> {
    use rustix::fs::{openat, Mode, CWD};
    use std::path::Component;
    let parts: Vec<&std::ffi::OsStr> = name
        .components()
        .map(|c| match c {
            Component::Normal(n) => Ok(n),
            _ => Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "`{}` is not a path inside the directory (only plain names: no `..`, no `.`, not absolute)",
                    name.display()
                ),
            )),
        })
        .collect::<io::Result<_>>()?;
    let Some((last, dirs)) = parts.split_last() else {
        return Err(io::Error::new(io::ErrorKind::InvalidInput, "an empty file name"));
    };
    let base = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
    let mut at = openat(CWD, base, OFlags::RDONLY | OFlags::DIRECTORY | OFlags::CLOEXEC, Mode::empty())?;
    let link = |e: rustix::io::Errno, what: &std::ffi::OsStr| -> io::Error {
        if e == rustix::io::Errno::LOOP || e == rustix::io::Errno::NOTDIR {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "`{}` is a symbolic link or not a directory; links are not followed here",
                    Path::new(what).display()
                ),
            )
        } else {
            e.into()
        }
    };
    for d in dirs {
        at = openat(&at, *d, OFlags::RDONLY | OFlags::DIRECTORY | OFlags::NOFOLLOW | OFlags::CLOEXEC, Mode::empty())
            .map_err(|e| link(e, d))?;
    }
    let fd = openat(&at, *last, OFlags::RDONLY | OFlags::NOFOLLOW | OFlags::NONBLOCK | OFlags::CLOEXEC, Mode::empty())
        .map_err(|e| {
            if e == rustix::io::Errno::LOOP {
                io::Error::new(io::ErrorKind::InvalidInput, "a symbolic link; links are not followed here")
            } else {
                e.into()
            }
        })?;
    data_file(File::from(fd))
}

/// Why [`read_sized`] read nothing.
#[derive(Debug)]
pub enum SizedError {
    /// The file could not be opened or read, or is not a regular file.
    Io(io::Error),
    /// The file holds this many bytes, none of the allowed lengths.
    Length(u64),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fifo_is_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("f");
        rustix::fs::mkfifoat(rustix::fs::CWD, &fifo, rustix::fs::Mode::from_raw_mode(0o600)).unwrap();
        let e = regular(&fifo).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput);
        assert!(e.to_string().contains("a FIFO"), "{e}");
    }

    #[test]
    fn devices_and_directories_are_refused_and_links_to_files_followed() {
        let dir = tempfile::tempdir().unwrap();
        assert!(regular(Path::new("/dev/zero")).unwrap_err().to_string().contains("a character device"));
        assert!(regular(dir.path()).unwrap_err().to_string().contains("a directory"));
        let f = dir.path().join("a");
        std::fs::write(&f, b"hello").unwrap();
        let l = dir.path().join("l");
        std::os::unix::fs::symlink(&f, &l).unwrap();
        assert_eq!(read_bounded(&l, 100).unwrap(), b"hello");
        assert_eq!(read_bounded(&l, 2).unwrap(), b"hel", "one byte past the bound, no more");
        let z = dir.path().join("z");
        std::os::unix::fs::symlink("/dev/zero", &z).unwrap();
        assert!(read_bounded(&z, 100).is_err());
    }

    #[test]
    fn files_of_proc_and_sys_are_refused_before_a_read() {
        for p in ["/proc/version", "/proc/self/status", "/sys/kernel/mm/transparent_hugepage/enabled"] {
            if !Path::new(p).exists() {
                continue;
            }
            let e = regular(Path::new(p)).unwrap_err();
            assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{p}: {e}");
            assert!(e.to_string().contains("filesystem, not a regular file of data"), "{p}: {e}");
        }
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("a");
        std::fs::write(&f, b"x").unwrap();
        assert_eq!(pseudo_filesystem(&File::open(&f).unwrap()).unwrap(), None, "a file on a disk is data");
    }

    #[test]
    fn read_capped_refuses_long_and_sparse_files_from_their_length() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("sparse");
        std::fs::File::create(&f).unwrap().set_len(2 << 30).unwrap();
        assert!(matches!(read_capped(&f, 1 << 20), Err(SizedError::Length(n)) if n == 2 << 30));
        std::fs::write(&f, b"12345").unwrap();
        assert_eq!(read_capped(&f, 5).unwrap(), b"12345");
        assert!(matches!(read_capped(&f, 4), Err(SizedError::Length(5))));
        assert!(matches!(read_capped(Path::new("/dev/zero"), 4), Err(SizedError::Io(_))));
    }

    #[test]
    fn regular_in_stays_inside_its_directory() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("sub")).unwrap();
        std::fs::write(d.join("sub/a"), b"a").unwrap();
        std::fs::write(d.join("b"), b"b").unwrap();
        assert!(regular_in(d, Path::new("sub/a")).unwrap().0.metadata().unwrap().is_file());
        assert!(regular_in(d, Path::new("b")).is_ok());
        for bad in ["../b", "/etc/hostname", "sub/../b", "./b", ""] {
            let e = regular_in(&d.join("sub"), Path::new(bad)).unwrap_err();
            assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{bad}: {e}");
        }
        std::os::unix::fs::symlink(d.join("b"), d.join("sub/l")).unwrap();
        assert!(regular_in(&d.join("sub"), Path::new("l")).unwrap_err().to_string().contains("symbolic link"));
        std::os::unix::fs::symlink(d.join("sub"), d.join("ls")).unwrap();
        assert!(regular_in(d, Path::new("ls/a")).unwrap_err().to_string().contains("symbolic link"));
        let fifo = d.join("f");
        rustix::fs::mkfifoat(rustix::fs::CWD, &fifo, rustix::fs::Mode::from_raw_mode(0o600)).unwrap();
        assert!(regular_in(d, Path::new("f")).unwrap_err().to_string().contains("a FIFO"));
    }

    #[test]
    fn read_sized_reads_only_allowed_lengths() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("a");
        std::fs::write(&f, [7u8; 10]).unwrap();
        assert_eq!(read_sized(&f, &[4, 10]).unwrap().len(), 10);
        assert!(matches!(read_sized(&f, &[4]), Err(SizedError::Length(10))));
        assert!(matches!(read_sized(Path::new("/dev/zero"), &[4]), Err(SizedError::Io(_))));
    }
}
