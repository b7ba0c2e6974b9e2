//! The reader's side of views (docs/SHM.md, "Views"): checking the views block at attach, finding
//! a view by name, reading its snapshot instead of the primary's, noticing that it was removed,
//! and asking for its centre through its request record.

use super::client::{invalid, Client, Fields, ReadError, RequestPosition};
use super::layout::{self, header, views as v};
use super::view_block::{Binding, ViewsBlock};
use super::ShmError;
use std::path::Path;
use std::sync::atomic::Ordering;

/// One view record's fields 0..128, as read under its seqlock.
#[derive(Clone, Debug, PartialEq)]
struct Record {
    live: bool,
    /// The view has grids of its own, in the mapping [`v::own_mapping_name`] (state 2).
    own: bool,
    incarnation: u64,
    weight: f64,
    name: String,
}

impl Client {
    /// Attaches to the mapping `name` in `dir` and binds to its view `view` (`main`: the primary).
    pub fn attach_view(dir: &Path, name: &str, view: &str) -> Result<Client, ShmError> {
        let mut c = Client::attach(dir, name)?;
        c.bind_view(view)?;
        Ok(c)
    }

    /// Reads snapshots (and makes requests) for the view named `view` from now on: `main` is the
    /// primary view (the header's snapshot); another name must be a live view's, else the error
    /// names the views there are.
    pub fn bind_view(&mut self, view: &str) -> Result<(), ShmError> {
        if view == v::PRIMARY_NAME {
            self.view = None;
            return Ok(());
        }
        v::check_name(view).map_err(|why| invalid(self.path(), why))?;
        let found = self.records()?.into_iter().find(|(_, r)| r.live && r.name == view);
        match found {
            Some((_, r)) if r.own => {
                let own = self.own_mapping(view)?;
                own.check_own_view(view)?;
                *self = own;
                Ok(())
            }
            Some((record, r)) => {
                self.view = Some(Binding { name: view.to_string(), record, incarnation: r.incarnation });
                Ok(())
            }
            None => Err(ShmError::NoView {
                path: self.path().to_path_buf(),
                view: view.to_string(),
                views: self.view_names()?,
            }),
        }
    }

    /// The view the client reads (`main` for the primary).
    pub fn view_name(&self) -> &str {
        match (&self.own_view, &self.view) {
            (Some(own), _) => own,
            (None, Some(b)) => &b.name,
            (None, None) => v::PRIMARY_NAME,
        }
    }

    /// Whether the client reads a view with grids of its own (docs/SHM.md, "A view with grids of
    /// its own"): it then reads and requests `main` of the view's own mapping.
    pub fn reads_own_grids(&self) -> bool {
        self.own_view.is_some()
    }

    /// Attaches to the own mapping of view `view` (checked) of the service whose mapping this
    /// client attached to: `clipmap-SERVICE@VIEW.map` beside it, the name derived from the two
    /// names, never read from the mapping.
    fn own_mapping(&self, view: &str) -> Result<Client, ShmError> {
        let path = self.path();
        let file = path.file_name().and_then(|f| f.to_str()).unwrap_or_default();
        let service = file.strip_prefix("clipmap-").and_then(|f| f.strip_suffix(".map")).filter(|s| !s.contains('@'));
        let (Some(service), Some(dir)) = (service, path.parent()) else {
            return Err(invalid(
                path,
                format!(
                    "view `{view}` has grids of its own, in the mapping beside the service's named clipmap-SERVICE@{view}.map, but this mapping's file name is not clipmap-SERVICE.map: attach by the service's name (--name) in its directory"
                ),
            ));
        };
        let own = v::own_mapping_name(service, view);
        let map = super::map_path(dir, &own);
        // A name the reader derived itself in a directory anyone may write: never followed as a
        // symbolic link, and the service's user's (docs/SHM.md, "Where"), as the C and Python
        // readers open it.
        if std::fs::symlink_metadata(&map).is_err() {
            return Err(ShmError::OwnMissing { view: view.to_string(), path: map });
        }
        let not_own = |e: ShmError| match e {
            ShmError::Invalid { path, reason } => ShmError::Invalid {
                path,
                reason: format!("the mapping of view `{view}`, which has grids of its own: {reason}"),
            },
            e => e,
        };
        let mut client = Client::attach_path_owned(&map, Some(self.uid)).map_err(not_own)?;
        // The own mapping of this start of the service: it carries the service's generation.
        if client.generation != self.generation {
            return Err(ShmError::OwnOfAnotherStart {
                view: view.to_string(),
                path: client.path().to_path_buf(),
                found: client.generation,
                expected: self.generation,
            });
        }
        client.open_requests(&super::request_path(dir, &own), Some(self.uid));
        client.own_view = Some(view.to_string());
        Ok(client)
    }

    /// Checks that this own mapping publishes one view, its `main`: a views block with a live
    /// record would mean a mapping that is not a view's own.
    fn check_own_view(&self, view: &str) -> Result<(), ShmError> {
        let others = self.records()?.into_iter().filter(|(_, r)| r.live).count();
        if others > 0 {
            return Err(invalid(
                self.path(),
                format!("the own mapping of view `{view}`: found {others} live view records, expected none (it publishes the view as main)"),
            ));
        }
        Ok(())
    }

    /// The names of the views the service publishes now, `main` first, then each live record's
    /// in record order.
    pub fn view_names(&self) -> Result<Vec<String>, ShmError> {
        let mut out = vec![v::PRIMARY_NAME.to_string()];
        out.extend(self.records()?.into_iter().filter(|(_, r)| r.live).map(|(_, r)| r.name));
        Ok(out)
    }

    /// The views now live, with their weights: `(name, weight)`, `main` first (its weight is not
    /// in the mapping: reported as 1).
    pub fn view_weights(&self) -> Result<Vec<(String, f64)>, ShmError> {
        let mut out = vec![(v::PRIMARY_NAME.to_string(), 1.0)];
        out.extend(self.records()?.into_iter().filter(|(_, r)| r.live).map(|(_, r)| (r.name, r.weight)));
        Ok(out)
    }

    /// The byte offset of the snapshot the client reads: the header's, or its view record's.
    pub(super) fn snapshot_base(&self) -> usize {
        match (&self.view, &self.views) {
            (Some(b), ViewsBlock::Known { at, .. }) => at + v::record(b.record) + v::SNAPSHOT,
            _ => header::SNAPSHOT,
        }
    }

    /// `Err(ViewRemoved)` when the bound view's record is no longer live with the incarnation it
    /// had at binding; `Ok` for the primary.
    pub(super) fn check_bound(&self) -> Result<(), ReadError> {
        let Some(b) = &self.view else { return Ok(()) };
        match self.record(b.record) {
            Ok(Some(r)) if r.live && r.incarnation == b.incarnation => Ok(()),
            Ok(_) => Err(ReadError::ViewRemoved(b.name.clone())),
            Err(ReadError::Corrupt(why)) => Err(ReadError::Corrupt(why)),
            Err(e) => Err(e),
        }
    }

    /// Every record, checked.
    fn records(&self) -> Result<Vec<(usize, Record)>, ShmError> {
        let n = match &self.views {
            ViewsBlock::Absent => return Ok(Vec::new()),
            ViewsBlock::Unknown(why) => return Err(invalid(self.path(), why.clone())),
            ViewsBlock::Known { records, .. } => *records,
        };
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            match self.record(i) {
                Ok(Some(r)) => out.push((i, r)),
                Ok(None) => {}
                Err(ReadError::Corrupt(why)) => return Err(invalid(self.path(), why)),
                Err(_) => return Err(ShmError::Busy { path: self.path().to_path_buf(), ms: 0 }),
            }
        }
        Ok(out)
    }

    /// Record `i` read under its seqlock and checked (`Ok(None)`: no views block or no such
    /// record).
    fn record(&self, i: usize) -> Result<Option<Record>, ReadError> {
        let ViewsBlock::Known { at, records: n, version } = self.views else { return Ok(None) };
        if i >= n {
            return Ok(None);
        }
        let rec = at + v::record(i);
        let r = &self.region;
        let read = || {
            let g = |o: usize| r.load(rec + o, Ordering::Relaxed);
            let name: Vec<u8> = (0..v::NAME_BYTES / 8).flat_map(|w| g(v::NAME + 8 * w).to_le_bytes()).collect();
            (g(v::STATE), g(v::INCARNATION), g(v::WEIGHT), name)
        };
        let (_, (state, incarnation, weight, name)) = self.seqlocked(rec + v::SEQ, read).ok_or(ReadError::Busy(0))?;
        let at_field = |o: usize, what: &str| format!("view record {i}, byte {} ({what})", rec + o);
        let own = match state {
            v::STATE_FREE => {
                return Ok(Some(Record { live: false, own: false, incarnation, weight: 0.0, name: String::new() }))
            }
            v::STATE_LIVE => false,
            v::STATE_OWN if version >= 2 => true,
            other => {
                let expected = if version >= 2 {
                    "0 (free), 1 (live) or 2 (live, grids of its own)"
                } else {
                    "0 (free) or 1 (live) in a version-1 block"
                };
                return Err(ReadError::Corrupt(format!(
                    "{}: found {other}, expected {expected}",
                    at_field(v::STATE, "state")
                )));
            }
        };
        let weight = f64::from_bits(weight);
        if !weight.is_finite() || weight <= 0.0 {
            return Err(ReadError::Corrupt(format!(
                "{}: found {weight}, expected a finite number above 0",
                at_field(v::WEIGHT, "weight")
            )));
        }
        let len = name.iter().position(|&c| c == 0).unwrap_or(name.len());
        let text = std::str::from_utf8(&name[..len])
            .ok()
            .filter(|t| v::check_name(t).is_ok() && name[len..].iter().all(|&c| c == 0));
        let Some(text) = text else {
            return Err(ReadError::Corrupt(format!(
                "{}: found {:?}, expected 1 to {} of A-Z a-z 0-9 - _ . (not main) followed by NULs only",
                at_field(v::NAME, "name"),
                String::from_utf8_lossy(&name),
                v::MAX_NAME
            )));
        };
        Ok(Some(Record { live: true, own, incarnation, weight, name: text.to_string() }))
    }

    /// [`Client::request_centre`] for a bound view: its request record, with the view's
    /// incarnation.
    pub(super) fn request_view_centre(&self, b: &Binding, position: RequestPosition, velocity: [f64; 2]) -> bool {
        if b.record >= v::MAX_REQUEST_RECORDS {
            return false;
        }
        let fields = Fields::Centre(position, v::position(1 + b.record), velocity);
        self.request_at(v::request(b.record), Some(b.incarnation), fields)
    }

    /// Asks the service to show the levels the bound view (`main` too) can use from
    /// `height` level-0 texels above the texture, where one screen pixel spans `pixel_angle`
    /// radians, addressing at most `effective` levels at once (0: all): the service then moves
    /// the view's LOD offset to the finest level the renderer samples there
    /// (`clipmap::clip::offset_for_footprint` of `height` x `pixel_angle`), and holds and reads
    /// nothing finer for the view (docs/VIEWS.md, "Virtual views"). `false` when the request was
    /// not made: bad numbers (each must be finite and above 0, the angle below pi), no request
    /// mapping, or a lock word held too long.
    pub fn request_lod(&self, height: f64, pixel_angle: f64, effective: u32) -> bool {
        let ok = height.is_finite() && height > 0.0 && pixel_angle.is_finite() && pixel_angle > 0.0;
        if !ok || pixel_angle >= std::f64::consts::PI {
            return false;
        }
        let lod = |i: usize| Fields::Lod { at: v::lod(i), height, pixel_angle, effective };
        match &self.view {
            Some(b) if b.record < v::MAX_REQUEST_RECORDS => {
                self.request_at(v::request(b.record), Some(b.incarnation), lod(1 + b.record))
            }
            Some(_) => false,
            None => self.request_at(layout::request::SEQ, None, lod(0)),
        }
    }
}
