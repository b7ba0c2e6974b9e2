//! A watched directory of incoming patches: every `*.json` sidecar that appears in it is taken
//! into a growing texture, then moved to `done/` (with its image or raw texels), or to
//! `rejected/` with a `NAME.error.txt` that says why.
//!
//! Writers put the image (or raw texels) in place first and the sidecar last, under a name that
//! does not end in `.json` until it is complete (write `NAME.json.tmp`, rename it to
//! `NAME.json`): a sidecar is taken as soon as it appears. Names starting with `.` are ignored.
//!
//! A patch is moved to `done/` only after the store acknowledged it. A crash in between leaves
//! the sidecar in place; the store records each patch's source (`NAME#DIGEST`, the digest of the
//! sidecar's bytes and the data's length), so the next round recognises it and only moves it.
//! The same sidecar, byte for byte, is therefore taken once.

use super::input::{data_file, read_sidecar, sidecar, Paths};
use super::store::{Growing, StoreError};
use std::path::{Path, PathBuf};

/// What one round did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Round {
    /// Sidecars taken: their names and the patches' ids.
    pub added: Vec<(String, u64)>,
    /// Sidecars refused: their names and why.
    pub refused: Vec<(String, String)>,
    /// Sidecars the store already had (a crash after the patch was kept, before it was moved).
    pub already: Vec<String>,
}

/// Checks that a watched directory and a growing texture's directory are apart: neither is the
/// other, nor holds it (compared by canonical path and by device and inode along both paths, so
/// links and a second mount of the same directory are seen through). A watched directory inside
/// the store would move the store's own `grid.json` and `state.json` to `rejected/`; a store
/// inside the watched directory would have its files taken for patches' data.
pub fn check_apart(store: &Path, incoming: &Path) -> Result<(), String> {
    use std::os::unix::fs::MetadataExt;
    let canon = |p: &Path| p.canonicalize().map_err(|e| format!("{}: {e}", p.display()));
    let (s, i) = (canon(store)?, canon(incoming)?);
    let id = |p: &Path| std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
    let holds = |outer: &Path, inner: &Path| {
        inner.starts_with(outer) || inner.ancestors().any(|a| id(a).is_some() && id(a) == id(outer))
    };
    if holds(&s, &i) || holds(&i, &s) {
        return Err(format!(
            "the watched directory {} and the growing texture {} are {}: the watcher would move the texture's own files (grid.json, state.json) away as refused patches; give a watched directory outside the texture's directory, and not one that holds it",
            incoming.display(),
            store.display(),
            if s == i || id(&s) == id(&i) { "the same directory" } else { "one inside the other" }
        ));
    }
    Ok(())
}

/// The sidecars waiting in `incoming`, by name.
pub fn waiting(incoming: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(incoming)?
        .filter_map(|e| e.ok())
        .filter(|e| e.file_type().map(|t| t.is_file()).unwrap_or(false))
        .map(|e| e.path())
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            !name.starts_with('.') && name.ends_with(".json")
        })
        .collect();
    out.sort();
    Ok(out)
}

/// Takes every sidecar waiting in `incoming` into `g` (at most `max` of them), moving each to
/// `done/` or `rejected/`. An error of the store's own (a disk that cannot be written) stops
/// the round and is returned, leaving the sidecar where it was.
pub fn round(g: &mut Growing, incoming: &Path, max_bytes: u64, max: usize) -> Result<Round, StoreError> {
    let io = |what: &'static str, path: &Path| {
        let path = path.to_path_buf();
        move |source| StoreError::Io { path, what, source }
    };
    let mut r = Round::default();
    for file in waiting(incoming).map_err(io("could not list the incoming directory", incoming))?.into_iter().take(max)
    {
        let name = file.file_name().and_then(|n| n.to_str()).unwrap_or("").to_string();
        // Read without following a link and from its length first: a sidecar planted as a
        // link, a FIFO or a huge file is read as whatever it is, and refused below.
        let text = match crate::open::regular_in(incoming, Path::new(&name))
            .map_err(crate::open::SizedError::Io)
            .and_then(|(f, m)| crate::open::read_open_capped(f, &m, super::input::MAX_SIDECAR_BYTES))
        {
            Ok(t) => t,
            // Taken away meanwhile (another reader of the directory): nothing to do.
            Err(crate::open::SizedError::Io(e)) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(_) => Vec::new(),
        };
        let data = sidecar(&text, &name).ok().map(|d| data_file(&file, &d));
        let data_len = data.as_ref().and_then(|d| std::fs::symlink_metadata(d).ok()).map_or(0, |m| m.len());
        let source = format!("{name}#{:016x}", super::digest_from(&data_len.to_le_bytes(), super::digest(&text)));
        if g.has_source(&source) {
            move_to(incoming, "done", &file, data.as_deref(), None)?;
            r.already.push(name);
            continue;
        }
        match read_sidecar(g.grid(), &file, max_bytes, Paths::Inside) {
            Ok(p) => match g.add_from(p, Some(source)) {
                Ok(id) => {
                    move_to(incoming, "done", &file, data.as_deref(), None)?;
                    r.added.push((name, id));
                }
                Err(e @ StoreError::Io { .. }) | Err(e @ StoreError::Busy { .. }) => return Err(e),
                Err(e) => {
                    let why = format!("{}: {e}", file.display());
                    move_to(incoming, "rejected", &file, data.as_deref(), Some(&why))?;
                    r.refused.push((name, why));
                }
            },
            Err(e) => {
                let why = e.to_string();
                move_to(incoming, "rejected", &file, data.as_deref(), Some(&why))?;
                r.refused.push((name, why));
            }
        }
    }
    Ok(r)
}

/// Moves a sidecar (and its data file, if there is one in `incoming`) to `incoming/SUB/`, with
/// `NAME.error.txt` beside it when `why` is given. The error file is written first and the sidecar
/// moved last, so a sidecar that has left `incoming` has everything beside it.
///
/// Others may write in `incoming`, so nothing here follows a link: `SUB` is opened with
/// `O_NOFOLLOW` (a link or a file planted there is refused, and the round stops with an error
/// naming it), every move is a `renameat` between the two opened directories, and the error file
/// is created under a fresh name (`O_CREAT | O_EXCL | O_NOFOLLOW`) and renamed over
/// `NAME.error.txt`, which replaces a link planted there instead of writing through it.
fn move_to(incoming: &Path, sub: &str, file: &Path, data: Option<&Path>, why: Option<&str>) -> Result<(), StoreError> {
    use rustix::fs::{mkdirat, openat, renameat, unlinkat, AtFlags, Mode, OFlags, CWD};
    use rustix::io::Errno;
    let dest_path = incoming.join(sub);
    let fail = |path: &Path, what: &'static str| {
        let path = path.to_path_buf();
        move |e: Errno| StoreError::Io { path, what, source: e.into() }
    };
    let inc = openat(CWD, incoming, OFlags::RDONLY | OFlags::DIRECTORY | OFlags::CLOEXEC, Mode::empty())
        .map_err(fail(incoming, "could not open the incoming directory"))?;
    match mkdirat(&inc, sub, Mode::from_raw_mode(0o755)) {
        Ok(()) | Err(Errno::EXIST) => {}
        Err(e) => return Err(fail(&dest_path, "could not create the directory")(e)),
    }
    let dest = openat(&inc, sub, OFlags::RDONLY | OFlags::DIRECTORY | OFlags::NOFOLLOW | OFlags::CLOEXEC, Mode::empty())
        .map_err(|e| match e {
            Errno::LOOP | Errno::NOTDIR => StoreError::Io {
                path: dest_path.clone(),
                what: "is a symbolic link or not a directory (links are not followed in a watched directory); remove it, and a directory is made there",
                source: e.into(),
            },
            e => fail(&dest_path, "could not open the directory")(e),
        })?;
    let name = file.file_name().expect("a sidecar has a name");
    if let Some(why) = why {
        let err_name = Path::new(name).with_extension("error.txt");
        let err_path = dest_path.join(&err_name);
        let tmp = format!(".{}.tmp{}", err_name.display(), std::process::id());
        let _ = unlinkat(&dest, tmp.as_str(), AtFlags::empty());
        let written = (|| -> Result<(), Errno> {
            let fd = openat(
                &dest,
                tmp.as_str(),
                OFlags::WRONLY | OFlags::CREATE | OFlags::EXCL | OFlags::NOFOLLOW | OFlags::CLOEXEC,
                Mode::from_raw_mode(0o644),
            )?;
            let mut f = std::fs::File::from(fd);
            std::io::Write::write_all(&mut f, format!("{why}\n").as_bytes())
                .map_err(|e| Errno::from_io_error(&e).unwrap_or(Errno::IO))?;
            renameat(&dest, tmp.as_str(), &dest, &err_name)
        })();
        if let Err(e) = written {
            let _ = unlinkat(&dest, tmp.as_str(), AtFlags::empty());
            return Err(fail(&err_path, "could not write")(e));
        }
    }
    if let Some(d) = data.filter(|d| d.parent() == file.parent()) {
        let dname = d.file_name().expect("a data file has a name");
        match renameat(&inc, dname, &dest, dname) {
            Ok(()) | Err(Errno::NOENT) => {}
            Err(e) => return Err(fail(d, "could not move")(e)),
        }
    }
    renameat(&inc, name, &dest, name).map_err(fail(file, "could not move"))
}
