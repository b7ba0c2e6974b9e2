//! # clipmap-shm
//!
//! The shared-memory access layer of `clipmap`: one mapping per clip texture, which any renderer
//! process reads without copies or locks (docs/ARCHITECTURE.md §5, `docs/SHM.md`).
//!
//! **This is the crate a renderer depends on alone** to read a service's mapping: it links no
//! async runtime, no network stack and no engine (no tokio, reqwest or object_store; only
//! `clipmap-base` of the workspace), beside the C header (`include/clipmap_shm.h`) and the Python
//! reader (`clients/python/clipmap_shm.py`). The `clipmap` crate re-exports it whole as
//! `clipmap::shm`.
//!
//! Owns the layout ([`layout`], version 2), the only `unsafe` code of the workspace (the private
//! `raw` module), the image caches' memory with the writer's side of the slot protocol
//! ([`memory`]), the mappings' names and files ([`writer`], [`names`]), the reader side used by
//! clients ([`client`]) and the check of a mapping against a texel oracle ([`verify`]). It leaves
//! deciding *what* to hold and publish to the engine (`clipmap::clip`).
//!
//! The invariant every part keeps: a slot's bytes are written only while its tag says loading,
//! and no published valid region covers a slot that is not settled.

#![deny(unsafe_code)]

pub mod blocks;
pub mod client;
mod client_views;
pub mod georef;
pub mod layout;
pub mod memory;
pub mod names;
#[allow(unsafe_code)] // the one module of raw pointer access; each block argues its SAFETY
mod raw;
pub mod verify;
mod view_block;
pub mod writer;

/// The raw mapping, for the tests of the `clipmap` crate that plant states by hand (the
/// `test-hooks` feature; not for use elsewhere).
#[cfg(feature = "test-hooks")]
#[doc(hidden)]
pub use raw::Region;

pub use client::{Client, LevelState, ReadError, RequestPosition, Snapshot};
pub use georef::GeorefBlock;
pub use memory::{ImageMemory, Publication, PublishedLevel, SlotKeeper};
pub use writer::{Writer, WriterOptions};

use std::path::{Path, PathBuf};

/// Errors of the shared-memory layer.
#[derive(Debug, thiserror::Error)]
pub enum ShmError {
    /// A service already publishes this name.
    #[error("a service already publishes `{name}` (process {pid}); stop it first or choose another --name")]
    AlreadyRunning {
        /// The name.
        name: String,
        /// Its process id, as recorded in the lock file (0 when unknown).
        pid: u32,
    },
    /// The name's lock file is locked by a process that records no live process id: not a
    /// service of ours (a squatter), so no pid is given.
    #[error("{}: locked by another process that is not a running service (the file records {}); stop that process or choose another --name", path.display(), if recorded.is_empty() { "nothing".to_string() } else { format!("`{recorded}`") })]
    LockHeld {
        /// The lock file.
        path: PathBuf,
        /// What the file records (at most a few bytes).
        recorded: String,
    },
    /// A name in the shared directory is taken by something the service will not use or remove.
    #[error("{}: {why}", path.display())]
    Foreign {
        /// The file.
        path: PathBuf,
        /// What it is and who owns it.
        why: String,
    },
    /// The name is not usable in a file name.
    #[error("invalid name `{0}`: use 1 to 64 letters, digits, `-`, `_` or `.`")]
    BadName(String),
    /// The mapping publishes no view of that name (yet: a service adds its `--view`s just after
    /// it publishes the mapping).
    #[error("{}: no view `{view}`: the service publishes {}", path.display(), views.join(", "))]
    NoView {
        /// The mapping.
        path: PathBuf,
        /// The view asked for.
        view: String,
        /// The views there are.
        views: Vec<String>,
    },
    /// A view with grids of its own whose mapping is not there (yet, or any more).
    #[error("view `{view}` has grids of its own, but its mapping {} is not there: the view is being added or removed, or its service restarted; try again", path.display())]
    OwnMissing {
        /// The view.
        view: String,
        /// Its mapping's file.
        path: PathBuf,
    },
    /// A view with grids of its own whose mapping under its name is another start's: its
    /// generation is not the service mapping's (docs/SHM.md, "A view with grids of its own").
    #[error("view `{view}` has grids of its own, but its mapping {} has generation {found:#x} where the service's mapping has {expected:#x}: it belongs to another start of the service; attach to the service again and look the view up", path.display())]
    OwnOfAnotherStart {
        /// The view.
        view: String,
        /// Its mapping's file.
        path: PathBuf,
        /// The own mapping's generation.
        found: u64,
        /// The generation of the service's mapping the view was found in.
        expected: u64,
    },
    /// No mapping of this name exists.
    #[error("no clip texture `{name}` is published in {}: is the service running (and is --shm-dir the same)?", dir.display())]
    NotFound {
        /// The name.
        name: String,
        /// Where it was looked for.
        dir: PathBuf,
    },
    /// The mapping is not one of ours, or of another layout version, or truncated.
    #[error("{}: {reason}", path.display())]
    Invalid {
        /// The mapping file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The writer kept its published state locked through every attempt for a second.
    #[error("{}: the service kept its published state locked for {ms} ms (it may be stuck or overloaded); try again", path.display())]
    Busy {
        /// The mapping file.
        path: PathBuf,
        /// How long it was tried.
        ms: u64,
    },
    /// The file system of the shared directory has no room for a mapping: refused before a byte
    /// of it was touched (a page the file system cannot supply would kill the service with
    /// SIGBUS instead of giving an error).
    #[error("{}: no room for a mapping of {needed} bytes: the file system of {} has {available} bytes free; free space there (any process may have filled it: `df {}`), make it larger (a tmpfs: `mount -o remount,size=... {}`) or point --shm-dir at a file system with room", path.display(), dir.display(), dir.display(), dir.display())]
    NoRoom {
        /// The file being made (a temporary, removed since).
        path: PathBuf,
        /// The shared directory.
        dir: PathBuf,
        /// The bytes the file needs.
        needed: u64,
        /// The bytes free for this user in that file system when it was refused (0 when unknown).
        available: u64,
    },
    /// The shape cannot be laid out.
    #[error("cannot lay out the mapping: {0}")]
    Shape(String),
    /// The georeferencing given to the writer cannot be published (checked before anything is
    /// made).
    #[error("cannot publish the georeferencing: {0}")]
    Georef(String),
    /// An I/O error.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        #[source]
        source: std::io::Error,
    },
}

/// Where mappings live by default: `/dev/shm` when it exists, else the temporary directory.
pub fn default_dir() -> PathBuf {
    let shm = Path::new("/dev/shm");
    if shm.is_dir() {
        shm.to_path_buf()
    } else {
        std::env::temp_dir()
    }
}

/// Checks a publication name.
pub fn check_name(name: &str) -> Result<(), ShmError> {
    let plain = |name: &str| {
        !name.is_empty()
            && name.len() <= 64
            && name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
            && !name.starts_with('.')
    };
    // A view's own mapping (`SERVICE@VIEW`, layout::views::own_mapping_name): a service's name
    // and a view's.
    let ok = match name.split_once('@') {
        None => plain(name),
        Some((service, view)) => plain(service) && layout::views::check_name(view).is_ok(),
    };
    if ok {
        Ok(())
    } else {
        Err(ShmError::BadName(name.to_string()))
    }
}

/// The mapping file of a name.
pub fn map_path(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("clipmap-{name}.map"))
}

/// The request mapping of a name (written by renderers).
pub fn request_path(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("clipmap-{name}.req"))
}

/// The lock file of a name (held by the running service).
pub fn lock_path(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("clipmap-{name}.lock"))
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ShmError + '_ {
    move |source| ShmError::Io { path: path.to_path_buf(), source }
}
