//! Tile services and tile trees named by a template ([`TemplateArchive`]): an `http(s)://` URL
//! or a local path with placeholders for the tile's zoom, column and row.
//!
//! Placeholders: `{z}` the zoom; `{x}` the column from the west; `{y}` the row from the north
//! (XYZ, as OpenStreetMap and `gdal2tiles.py --xyz` count); `{-y}` the row from the south (TMS,
//! `gdal2tiles.py`'s default); `{quadkey}` the Bing Maps quadkey; `{s}` a subdomain, chosen
//! from the configured list by the tile's column and row so that neighbouring tiles spread
//! across them; WMTS REST's `{TileMatrix}` (the zoom), `{TileRow}` (from the north) and
//! `{TileCol}`. Any other `{...}` is refused, naming it.
//!
//! Over HTTP(S) each tile is one plain GET through the remote stack ([`Fetcher::object`](crate::source::remote::Fetcher::object)): at
//! most `CLIPMAP_REMOTE_IN_FLIGHT` requests in flight to each host, transient failures retried
//! with backoff, `429` and `503` retried after the server's `Retry-After` (bounded by
//! `CLIPMAP_REMOTE_BACKOFF_MAX_MS`). A `404`, `410`, `204` or an empty body is a missing tile. A
//! configured User-Agent and extra headers go with every request and never into a message. An
//! answer's `Content-Type` (an image type or none) and size are checked before the bytes are
//! handed on; the pyramid source then checks their magic number and decoded size. With a disk
//! cache (`CLIPMAP_REMOTE_CACHE_DIR`) a tile is looked up there by its URL first, and a tile
//! fetched is kept there when it is an image (its magic number says PNG, JPEG or WebP): a
//! missing tile, an error or a page answered for a tile is never cached.

use super::{ArchiveError, Fetched, PyramidInfo, TileAddr, TileArchive, TileEncoding, MAX_ZOOM};
use crate::source::FaultKind;
use std::path::PathBuf;

/// The most bytes one tile's answer may hold.
pub const MAX_TILE_ANSWER: u64 = 32 << 20;

/// The subdomains `{s}` takes when none are configured (as Leaflet's default).
pub const DEFAULT_SUBDOMAINS: [&str; 3] = ["a", "b", "c"];

/// One piece of a template.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Piece {
    Text(String),
    Zoom,
    Col,
    Row,
    TmsRow,
    Quadkey,
    Subdomain,
}

/// A parsed template.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Template {
    pieces: Vec<Piece>,
    subdomains: Vec<String>,
}

impl Template {
    /// Parses `text`; `subdomains` are what `{s}` takes (empty: `DEFAULT_SUBDOMAINS`).
    pub fn parse(text: &str, subdomains: &[String]) -> Result<Template, String> {
        let mut pieces = Vec::new();
        let mut rest = text;
        while let Some(open) = rest.find('{') {
            if open > 0 {
                pieces.push(Piece::Text(rest[..open].to_string()));
            }
            let close = rest[open..]
                .find('}')
                .ok_or_else(|| format!("`{{` at byte {} is never closed", text.len() - rest.len() + open))?;
            let name = &rest[open + 1..open + close];
            pieces.push(match name {
                "z" | "TileMatrix" => Piece::Zoom,
                "x" | "TileCol" => Piece::Col,
                "y" | "TileRow" => Piece::Row,
                "-y" => Piece::TmsRow,
                "quadkey" => Piece::Quadkey,
                "s" => Piece::Subdomain,
                other => {
                    return Err(format!(
                        "unknown placeholder {{{other}}}: expected {{z}}, {{x}}, {{y}}, {{-y}}, {{quadkey}}, {{s}}, {{TileMatrix}}, {{TileRow}} or {{TileCol}}"
                    ))
                }
            });
            rest = &rest[open + close + 1..];
        }
        if !rest.is_empty() {
            pieces.push(Piece::Text(rest.to_string()));
        }
        let has = |p: &Piece| pieces.contains(p);
        let addressed = has(&Piece::Quadkey)
            || (has(&Piece::Zoom) && has(&Piece::Col) && (has(&Piece::Row) || has(&Piece::TmsRow)));
        if !addressed {
            return Err("the template does not name every tile: expected {z}, {x} and {y} (or {-y}), their WMTS names {TileMatrix}, {TileCol} and {TileRow}, or {quadkey}".into());
        }
        let subdomains = if subdomains.is_empty() {
            DEFAULT_SUBDOMAINS.iter().map(|s| s.to_string()).collect()
        } else {
            subdomains.to_vec()
        };
        Ok(Template { pieces, subdomains })
    }

    /// The URL or path of tile `at`.
    pub fn expand(&self, at: TileAddr) -> String {
        let mut out = String::new();
        for p in &self.pieces {
            match p {
                Piece::Text(t) => out.push_str(t),
                Piece::Zoom => out.push_str(&at.z.to_string()),
                Piece::Col => out.push_str(&at.x.to_string()),
                Piece::Row => out.push_str(&at.y.to_string()),
                Piece::TmsRow => out.push_str(&at.tms_y().to_string()),
                Piece::Quadkey => out.push_str(&at.quadkey()),
                Piece::Subdomain => {
                    let i = (u64::from(at.x) + u64::from(at.y)) % self.subdomains.len() as u64;
                    out.push_str(&self.subdomains[i as usize]);
                }
            }
        }
        out
    }

    /// The text before the first placeholder.
    fn prefix(&self) -> &str {
        match self.pieces.first() {
            Some(Piece::Text(t)) => t,
            _ => "",
        }
    }

    /// Whether the first placeholder is the zoom, right after a `/` (a tree of zoom
    /// directories, as gdal2tiles.py writes).
    fn zoom_directories(&self) -> bool {
        matches!(self.pieces.get(1), Some(Piece::Zoom)) && self.prefix().ends_with('/')
    }

    /// The encoding the template's extension names (`.png`, `.jpg`, `.jpeg`, `.webp`).
    pub fn encoding(&self) -> Option<TileEncoding> {
        let Some(Piece::Text(last)) = self.pieces.last() else { return None };
        let path = last.split(['?', '#']).next().unwrap_or_default().to_ascii_lowercase();
        if path.ends_with(".png") {
            Some(TileEncoding::Png)
        } else if path.ends_with(".jpg") || path.ends_with(".jpeg") {
            Some(TileEncoding::Jpeg)
        } else if path.ends_with(".webp") {
            Some(TileEncoding::Webp)
        } else {
            None
        }
    }
}

/// How a template is served.
#[derive(Clone, Debug, Default)]
pub struct TemplateOptions {
    /// The zooms that have tiles, `[min, max]`; `None`: read from a local tree's zoom
    /// directories, else 0..18.
    pub zooms: Option<[u8; 2]>,
    /// The area the tiles cover (west, south, east, north, degrees).
    pub bounds: Option<[f64; 4]>,
    /// Tile width and height; `None` for 256.
    pub tile_size: Option<u32>,
    /// What `{s}` takes.
    pub subdomains: Vec<String>,
    /// The User-Agent sent; `None` for `clipmap/VERSION`.
    pub user_agent: Option<String>,
    /// Extra headers sent with every request (`Name: value`), never written to messages.
    pub headers: Vec<(String, String)>,
    /// The remote stack's options; `None` for the `CLIPMAP_REMOTE_*` variables'.
    #[cfg(feature = "remote")]
    pub remote: Option<crate::source::remote::RemoteOptions>,
}

enum Reader {
    Local,
    #[cfg(feature = "remote")]
    Http {
        remote: Box<crate::source::remote::Remote>,
        request: crate::source::remote::ObjectRequest,
    },
}

/// A tile service or tree named by a template.
pub struct TemplateArchive {
    place: String,
    template: Template,
    info: PyramidInfo,
    reader: Reader,
}

fn is_http(text: &str) -> bool {
    let lower = text.to_ascii_lowercase();
    lower.starts_with("http://") || lower.starts_with("https://")
}

/// Whether `value` is a content type a tile may come with: an image type, a generic binary
/// type, or none.
#[cfg_attr(not(feature = "remote"), allow(dead_code))]
fn tile_content_type(value: &str) -> bool {
    let v = value.split(';').next().unwrap_or_default().trim().to_ascii_lowercase();
    v.starts_with("image/") || v == "application/octet-stream" || v == "binary/octet-stream" || v.is_empty()
}

impl TemplateArchive {
    /// Opens the service or tree `text` names.
    pub fn open(text: &str, opts: &TemplateOptions) -> Result<TemplateArchive, ArchiveError> {
        let place = crate::place::redacted(text).into_owned();
        let bad =
            |problem: String| ArchiveError { place: place.clone(), at: None, kind: FaultKind::BadRequest, problem };
        let template = Template::parse(text, &opts.subdomains).map_err(bad)?;
        let lower = text.to_ascii_lowercase();
        let reader = if is_http(text) {
            #[cfg(feature = "remote")]
            {
                let ropts = match &opts.remote {
                    Some(o) => o.clone(),
                    None => crate::source::remote::RemoteOptions::from_env().map_err(|e| bad(e.to_string()))?,
                };
                // With the disk cache the options name, if any: tiles are kept there by URL.
                let remote = crate::source::remote::Remote::new(ropts).map_err(|e| {
                    bad(format!("the remote disk cache (CLIPMAP_REMOTE_CACHE_DIR) cannot be used: {e}"))
                })?;
                let ua = opts.user_agent.clone().unwrap_or_else(|| format!("clipmap/{}", env!("CARGO_PKG_VERSION")));
                let mut headers = vec![("User-Agent".to_string(), ua)];
                for (name, value) in &opts.headers {
                    let ok_name =
                        !name.is_empty() && name.bytes().all(|b| b.is_ascii_alphanumeric() || b"-_".contains(&b));
                    if !ok_name || value.bytes().any(|b| b == b'\r' || b == b'\n') {
                        return Err(bad(format!(
                            "header {name:?}: expected a name of letters, digits, `-` and `_`, and a value on one line"
                        )));
                    }
                    headers.retain(|(n, _)| !n.eq_ignore_ascii_case(name));
                    headers.push((name.clone(), value.clone()));
                }
                Reader::Http {
                    remote: Box::new(remote),
                    request: crate::source::remote::ObjectRequest { headers, max_bytes: MAX_TILE_ANSWER },
                }
            }
            #[cfg(not(feature = "remote"))]
            return Err(bad("this build cannot read http:// or https:// (build with the `remote` feature)".into()));
        } else if lower.contains("://") {
            return Err(bad(
                "expected an http:// or https:// URL or a local path (for a bucket, give its https:// URL)".into(),
            ));
        } else {
            Reader::Local
        };
        let zooms = match opts.zooms {
            Some(z) => z,
            None if matches!(reader, Reader::Local) && template.zoom_directories() => {
                local_zooms(template.prefix()).map_err(bad)?
            }
            None => [0, 18],
        };
        if zooms[0] > zooms[1] || zooms[1] > MAX_ZOOM {
            return Err(bad(format!(
                "zooms {}..{}: expected MIN..MAX with MIN <= MAX <= {MAX_ZOOM}",
                zooms[0], zooms[1]
            )));
        }
        let info = PyramidInfo {
            min_zoom: zooms[0],
            max_zoom: zooms[1],
            tile_size: opts.tile_size.unwrap_or(256),
            bounds: opts.bounds,
            encoding: template.encoding(),
        };
        Ok(TemplateArchive { place, template, info, reader })
    }

    /// The template.
    pub fn template(&self) -> &Template {
        &self.template
    }

    fn error(&self, at: TileAddr, kind: FaultKind, problem: String) -> ArchiveError {
        ArchiveError { place: self.place.clone(), at: Some(at), kind, problem }
    }

    fn fetch_local(&self, at: TileAddr) -> Result<Fetched, ArchiveError> {
        let path = PathBuf::from(self.template.expand(at));
        let file = match std::fs::File::open(&path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Fetched::Missing),
            Err(e) => {
                let kind = if e.kind() == std::io::ErrorKind::PermissionDenied {
                    FaultKind::PermissionDenied
                } else {
                    FaultKind::Io
                };
                return Err(self.error(at, kind, format!("{}: {e}", path.display())));
            }
        };
        let len = file.metadata().map(|m| m.len()).unwrap_or(0);
        if len > MAX_TILE_ANSWER {
            return Err(self.error(
                at,
                FaultKind::Corrupt,
                format!("{} holds {len} bytes, more than the {MAX_TILE_ANSWER} a tile may", path.display()),
            ));
        }
        let mut bytes = Vec::with_capacity(len as usize);
        use std::io::Read;
        file.take(MAX_TILE_ANSWER + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| self.error(at, FaultKind::Io, format!("{}: {e}", path.display())))?;
        Ok(if bytes.is_empty() { Fetched::Missing } else { Fetched::Tile(bytes) })
    }
}

/// The zooms of a local tree: its numeric directories under `root`.
fn local_zooms(root: &str) -> Result<[u8; 2], String> {
    let dir = std::fs::read_dir(root)
        .map_err(|e| format!("cannot list {root} for its zoom directories: {e}; give the zooms (--zooms MIN..MAX)"))?;
    let zooms: Vec<u8> = dir
        .filter_map(|e| e.ok())
        .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
        .filter_map(|e| e.file_name().to_str()?.parse::<u8>().ok())
        .filter(|&z| z <= MAX_ZOOM)
        .collect();
    match (zooms.iter().min(), zooms.iter().max()) {
        (Some(&a), Some(&b)) => Ok([a, b]),
        _ => Err(format!("{root} has no zoom directories (0, 1, ...): give the zooms (--zooms MIN..MAX)")),
    }
}

impl TileArchive for TemplateArchive {
    fn place(&self) -> &str {
        &self.place
    }

    fn info(&self) -> &PyramidInfo {
        &self.info
    }

    fn fetch(&self, at: TileAddr) -> Result<Fetched, ArchiveError> {
        if !at.is_valid() {
            return Err(self.error(at, FaultKind::BadRequest, "not a tile of its zoom".into()));
        }
        match &self.reader {
            Reader::Local => self.fetch_local(at),
            #[cfg(feature = "remote")]
            Reader::Http { remote, request } => {
                use crate::source::remote::{Location, ReadError};
                let url = self.template.expand(at);
                let key = crate::source::remote::disk::object_key(&url);
                if let Some(bytes) = remote.cached_object(&key, MAX_TILE_ANSWER) {
                    return Ok(Fetched::Tile(bytes));
                }
                let loc = Location::parse(&url).map_err(|e| self.error(at, FaultKind::BadRequest, e.to_string()))?;
                match remote.fetcher().object(&loc, request) {
                    Ok(o) if o.bytes.is_empty() => Ok(Fetched::Missing),
                    Ok(o) => {
                        if let Some(ct) = o.content_type.as_deref().filter(|ct| !tile_content_type(ct)) {
                            return Err(self.error(
                                at,
                                FaultKind::Corrupt,
                                format!(
                                    "{loc}: the answer is Content-Type {ct} ({} bytes): expected an image",
                                    o.bytes.len()
                                ),
                            ));
                        }
                        // Kept only when it is an image: never a page, an error or a missing tile.
                        if super::TileEncoding::sniff(&o.bytes).is_some() {
                            remote.keep_object(&key, &o.bytes);
                        }
                        Ok(Fetched::Tile(o.bytes.to_vec()))
                    }
                    Err(ReadError::NotFound { .. }) => Ok(Fetched::Missing),
                    Err(e @ ReadError::Denied { .. }) => {
                        Err(self.error(at, FaultKind::PermissionDenied, e.to_string()))
                    }
                    Err(e) => Err(self.error(at, FaultKind::Io, e.to_string())),
                }
            }
        }
    }

    fn locate(&self, at: TileAddr) -> Option<String> {
        Some(crate::place::redacted(&self.template.expand(at)).into_owned())
    }

    #[cfg(feature = "remote")]
    fn remote_stats(&self) -> Option<crate::source::remote::RemoteStats> {
        match &self.reader {
            Reader::Local => None,
            Reader::Http { remote, .. } => Some(remote.stats()),
        }
    }

    #[cfg(feature = "remote")]
    fn is_cached(&self, at: TileAddr) -> bool {
        match &self.reader {
            Reader::Local => false,
            Reader::Http { remote, .. } => remote
                .cache()
                .is_some_and(|c| c.holds(&crate::source::remote::disk::object_key(&self.template.expand(at)))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(text: &str) -> Template {
        Template::parse(text, &[]).unwrap()
    }

    #[test]
    fn xyz_tms_and_wmts_placeholders_expand_to_hand_computed_urls() {
        let at = TileAddr { z: 3, x: 5, y: 2 };
        assert_eq!(t("https://tile.example.org/{z}/{x}/{y}.png").expand(at), "https://tile.example.org/3/5/2.png");
        // TMS: 2^3 - 1 - 2 = 5.
        assert_eq!(t("tiles/{z}/{x}/{-y}.png").expand(at), "tiles/3/5/5.png");
        assert_eq!(
            t("https://w.example.org/wmts/layer/default/GoogleMapsCompatible/{TileMatrix}/{TileRow}/{TileCol}.jpg")
                .expand(at),
            "https://w.example.org/wmts/layer/default/GoogleMapsCompatible/3/2/5.jpg"
        );
    }

    #[test]
    fn quadkeys_and_subdomains_expand_and_spread_across_tiles() {
        // Bing Maps' example: tile x 3, y 5 at level 3 is quadkey 213.
        let q = t("https://ecn.t{s}.example.net/tiles/a{quadkey}.jpeg?g=1");
        let s = |x, y| {
            Template::parse("https://{s}.example.org/{z}/{x}/{y}.png", &["t0".into(), "t1".into()])
                .unwrap()
                .expand(TileAddr { z: 4, x, y })
        };
        assert_eq!(q.expand(TileAddr { z: 3, x: 3, y: 5 }), "https://ecn.tc.example.net/tiles/a213.jpeg?g=1");
        assert_eq!(s(0, 0), "https://t0.example.org/4/0/0.png");
        assert_eq!(s(1, 0), "https://t1.example.org/4/1/0.png");
        assert_eq!(s(1, 1), "https://t0.example.org/4/1/1.png");
        assert_eq!(q.encoding(), Some(TileEncoding::Jpeg));
        assert_eq!(t("x/{z}/{x}/{y}").encoding(), None);
        assert_eq!(t("x/{z}/{x}/{y}.webp").encoding(), Some(TileEncoding::Webp));
    }

    #[test]
    fn templates_that_do_not_name_every_tile_are_refused_naming_what_is_wrong() {
        let e = Template::parse("https://a/{z}/{x}/{row}.png", &[]).unwrap_err();
        assert!(e.contains("unknown placeholder {row}"), "{e}");
        let e = Template::parse("https://a/{z}/{x}.png", &[]).unwrap_err();
        assert!(e.contains("does not name every tile"), "{e}");
        let e = Template::parse("https://a/{z/{x}/{y}", &[]).unwrap_err();
        assert!(e.contains("unknown placeholder {z/{x}"), "{e}");
        let e = Template::parse("https://a/{z}/{x}/{y", &[]).unwrap_err();
        assert!(e.contains("never closed"), "{e}");
    }

    #[test]
    fn a_local_tree_reads_its_zooms_from_its_directories_and_missing_or_empty_files_are_missing() {
        let dir = tempfile::tempdir().unwrap();
        for z in [2, 3, 5] {
            std::fs::create_dir_all(dir.path().join(format!("{z}/0"))).unwrap();
        }
        std::fs::write(dir.path().join("3/0/1.png"), b"\x89PNG\r\n\x1a\nrest").unwrap();
        std::fs::write(dir.path().join("3/0/2.png"), b"").unwrap();
        let text = format!("{}/{{z}}/{{x}}/{{y}}.png", dir.path().display());
        let a = TemplateArchive::open(&text, &TemplateOptions::default()).unwrap();
        assert_eq!((a.info().min_zoom, a.info().max_zoom, a.info().encoding), (2, 5, Some(TileEncoding::Png)));
        assert!(matches!(a.fetch(TileAddr { z: 3, x: 0, y: 1 }).unwrap(), Fetched::Tile(b) if b.len() == 12));
        assert_eq!(a.fetch(TileAddr { z: 3, x: 0, y: 2 }).unwrap(), Fetched::Missing);
        assert_eq!(a.fetch(TileAddr { z: 3, x: 0, y: 3 }).unwrap(), Fetched::Missing);
        let e = TemplateArchive::open("s3://bucket/{z}/{x}/{y}.png", &TemplateOptions::default())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("expected an http:// or https:// URL or a local path"), "{e}");
    }

    #[test]
    fn content_types_of_tiles_are_images_or_binary() {
        assert!(tile_content_type("image/png"));
        assert!(tile_content_type("image/jpeg; charset=binary"));
        assert!(tile_content_type("application/octet-stream"));
        assert!(!tile_content_type("text/html; charset=utf-8"));
        assert!(!tile_content_type("application/json"));
    }
}
