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

use super::input::{data_file, read_sidecar, sidecar};
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
        let text = match std::fs::read(&file) {
            Ok(t) => t,
            // Taken away meanwhile (another reader of the directory): nothing to do.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(io("could not read", &file)(e)),
        };
        let data = sidecar(&text, &name).ok().map(|d| data_file(&file, &d));
        let data_len = data.as_ref().and_then(|d| std::fs::metadata(d).ok()).map_or(0, |m| m.len());
        let source = format!("{name}#{:016x}", super::digest_from(&data_len.to_le_bytes(), super::digest(&text)));
        if g.has_source(&source) {
            move_to(incoming, "done", &file, data.as_deref(), None)?;
            r.already.push(name);
            continue;
        }
        match read_sidecar(g.grid(), &file, max_bytes) {
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
fn move_to(incoming: &Path, sub: &str, file: &Path, data: Option<&Path>, why: Option<&str>) -> Result<(), StoreError> {
    let dest = incoming.join(sub);
    std::fs::create_dir_all(&dest).map_err(|source| StoreError::Io {
        path: dest.clone(),
        what: "could not create the directory",
        source,
    })?;
    let name = file.file_name().expect("a sidecar has a name");
    if let Some(why) = why {
        let err = dest.join(Path::new(name).with_extension("error.txt"));
        std::fs::write(&err, format!("{why}\n")).map_err(|source| StoreError::Io {
            path: err,
            what: "could not write",
            source,
        })?;
    }
    if let Some(d) = data.filter(|d| d.parent() == file.parent() && d.exists()) {
        let to = dest.join(d.file_name().expect("a data file has a name"));
        std::fs::rename(d, &to).map_err(|source| StoreError::Io {
            path: d.to_path_buf(),
            what: "could not move",
            source,
        })?;
    }
    let to = dest.join(name);
    std::fs::rename(file, &to).map_err(|source| StoreError::Io {
        path: file.to_path_buf(),
        what: "could not move",
        source,
    })
}
