//! Where a named file lives: on a local disk or at a remote location.
//!
//! A configuration, or a user on the command line, names tile files by text; a name that starts
//! with `http://`, `https://` or `s3://` (any case) is a remote location, used exactly as
//! written, and any other name is a local path. That decision is made once, where a name enters
//! (the plan anchoring a name it renders, a tool reading its argument), by making a [`Place`];
//! everything downstream matches on the type instead of looking at the text again.
//!
//! A place gives back its exact original text (`Display`, and `Serialize` as a string), so error
//! messages and JSON reports read as the name was written. The remote stack (the `remote`
//! feature) parses a [`RemoteName`] further into endpoint and key; this room only tells the two
//! kinds apart, so it stands on the ground floor and every build has it.

use serde::{Serialize, Serializer};
use std::fmt;
use std::path::{Path, PathBuf};

/// The protocol a remote name is written with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum RemoteScheme {
    /// `http://`
    Http,
    /// `https://`
    Https,
    /// `s3://`: an S3-compatible object store.
    S3,
}

impl RemoteScheme {
    /// Every scheme.
    pub const ALL: [RemoteScheme; 3] = [RemoteScheme::Http, RemoteScheme::Https, RemoteScheme::S3];

    /// The prefix that introduces a name of this scheme, in lowercase (`http://`, ...).
    pub fn prefix(self) -> &'static str {
        match self {
            RemoteScheme::Http => "http://",
            RemoteScheme::Https => "https://",
            RemoteScheme::S3 => "s3://",
        }
    }

    /// The scheme `name` starts with (case-insensitive), if any.
    fn of(name: &str) -> Option<RemoteScheme> {
        RemoteScheme::ALL.into_iter().find(|s| {
            let p = s.prefix().as_bytes();
            name.len() >= p.len() && name.as_bytes()[..p.len()].eq_ignore_ascii_case(p)
        })
    }
}

/// A remote location's name, as written (`HTTP://Host/x` stays so), with its scheme.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RemoteName {
    scheme: RemoteScheme,
    text: String,
}

impl RemoteName {
    /// `name` as a remote name, when it starts with a remote scheme (case-insensitive).
    pub fn parse(name: &str) -> Option<RemoteName> {
        RemoteScheme::of(name).map(|scheme| RemoteName { scheme, text: name.to_string() })
    }

    /// The scheme.
    pub fn scheme(&self) -> RemoteScheme {
        self.scheme
    }

    /// The whole name, as written.
    pub fn as_str(&self) -> &str {
        &self.text
    }

    /// What follows the scheme's `://`.
    pub fn rest(&self) -> &str {
        &self.text[self.scheme.prefix().len()..]
    }

    /// The name's last `.`-suffix as a path would have it (`zst` for `.../r000.c000.raw.zst`),
    /// of its path alone: an http(s) URL's `?query` and `#fragment` are not part of it
    /// (`https://host/x.tif?sig=...` ends in `tif`); an S3 key is taken whole.
    pub fn extension(&self) -> Option<&str> {
        Path::new(self.path()).extension().and_then(|e| e.to_str())
    }

    /// The name without an http(s) URL's `?query` and `#fragment` (an S3 name whole: `?` and
    /// `#` are characters of a key).
    pub fn path(&self) -> &str {
        match self.scheme {
            RemoteScheme::S3 => &self.text,
            RemoteScheme::Http | RemoteScheme::Https => {
                let rest = self.rest();
                let end = rest.find(['?', '#']).map_or(self.text.len(), |i| self.scheme.prefix().len() + i);
                &self.text[..end]
            }
        }
    }
}

/// Query parameters whose values are secrets, by a word their name holds (case-insensitive):
/// `X-Amz-Signature`, `X-Amz-Credential`, `X-Amz-Security-Token`, `sig` (Azure SAS), `token`,
/// `access_token`, `api_key`, `password`, `secret`, `auth`.
const SECRET_PARAMETERS: [&str; 7] = ["sig", "token", "credential", "key", "password", "secret", "auth"];

/// What stands for a secret in a name as it is shown.
pub const REDACTED: &str = "***";

/// `text` as it may be shown (in errors, logs, statistics): every `http://` or `https://` URL in
/// it with the password of its user information replaced by [`REDACTED`] (the user kept), and
/// the value of every query parameter whose name holds a secret's word (`SECRET_PARAMETERS`:
/// a signature, a credential, a token, a key) replaced the same way. Everything else is kept as
/// written, so the shown name still says which object it is. Requests use the name itself.
pub fn redacted(text: &str) -> std::borrow::Cow<'_, str> {
    let lower = text.to_ascii_lowercase();
    if !lower.contains("http://") && !lower.contains("https://") {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = find_url(rest) {
        out.push_str(&rest[..at]);
        let url = &rest[at..];
        let end =
            url.find(|c: char| c.is_whitespace() || matches!(c, '`' | '\'' | '"' | '<' | '>')).unwrap_or(url.len());
        out.push_str(&redact_url(&url[..end]));
        rest = &url[end..];
    }
    out.push_str(rest);
    if out == text {
        std::borrow::Cow::Borrowed(text)
    } else {
        std::borrow::Cow::Owned(out)
    }
}

/// Where the next `http://` or `https://` (any case) starts in `text`.
fn find_url(text: &str) -> Option<usize> {
    let lower = text.to_ascii_lowercase();
    [lower.find("http://"), lower.find("https://")].into_iter().flatten().min()
}

/// One URL (no whitespace in it) with its secrets replaced.
fn redact_url(url: &str) -> String {
    let scheme_end = url.find("://").map_or(0, |i| i + 3);
    let after = &url[scheme_end..];
    let authority_end = after.find(['/', '?', '#']).unwrap_or(after.len());
    let authority = &after[..authority_end];
    let mut out = url[..scheme_end].to_string();
    match authority.rfind('@') {
        Some(at) => {
            let userinfo = &authority[..at];
            match userinfo.split_once(':') {
                Some((user, _password)) => out.push_str(&format!("{user}:{REDACTED}")),
                None => out.push_str(userinfo),
            }
            out.push_str(&authority[at..]);
        }
        None => out.push_str(authority),
    }
    let tail = &after[authority_end..];
    let (before_fragment, fragment) = match tail.find('#') {
        Some(i) => tail.split_at(i),
        None => (tail, ""),
    };
    match before_fragment.split_once('?') {
        Some((path, query)) => {
            out.push_str(path);
            out.push('?');
            let params: Vec<String> = query
                .split('&')
                .map(|p| match p.split_once('=') {
                    Some((name, value)) if !value.is_empty() && is_secret(name) => format!("{name}={REDACTED}"),
                    _ => p.to_string(),
                })
                .collect();
            out.push_str(&params.join("&"));
        }
        None => out.push_str(before_fragment),
    }
    out.push_str(fragment);
    out
}

fn is_secret(parameter: &str) -> bool {
    let p = parameter.to_ascii_lowercase();
    SECRET_PARAMETERS.iter().any(|w| p.contains(w))
}

impl fmt::Display for RemoteName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text)
    }
}

/// Where a named file lives: a local path, or a remote location.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Place {
    /// A file on a local disk.
    Local(PathBuf),
    /// An object at a remote location (`http://`, `https://`, `s3://`).
    Remote(RemoteName),
}

impl Place {
    /// The place `name` names: remote when it starts with a remote scheme, else a local path
    /// (used as given, relative or not).
    pub fn parse(name: &str) -> Place {
        match RemoteName::parse(name) {
            Some(r) => Place::Remote(r),
            None => Place::Local(PathBuf::from(name)),
        }
    }

    /// The place a path given as such names (a command-line argument, a path a caller built):
    /// remote when its text is a remote name, else that path.
    pub fn from_path(path: PathBuf) -> Place {
        match path.to_str().and_then(RemoteName::parse) {
            Some(r) => Place::Remote(r),
            None => Place::Local(path),
        }
    }

    /// The place `name` names, a relative local name joined to `dir` (the directory of the file
    /// that named it); absolute names and remote locations are kept as written.
    pub fn anchored(dir: &Path, name: &str) -> Place {
        match Place::parse(name) {
            Place::Local(p) if !name.starts_with('/') => Place::Local(dir.join(p)),
            place => place,
        }
    }

    /// The local path, when the place is local.
    pub fn as_local(&self) -> Option<&Path> {
        match self {
            Place::Local(p) => Some(p),
            Place::Remote(_) => None,
        }
    }

    /// The remote name, when the place is remote.
    pub fn remote(&self) -> Option<&RemoteName> {
        match self {
            Place::Local(_) => None,
            Place::Remote(r) => Some(r),
        }
    }

    /// The name's last `.`-suffix (`zst` for a compressed tile file), local or remote.
    pub fn extension(&self) -> Option<&str> {
        match self {
            Place::Local(p) => p.extension().and_then(|e| e.to_str()),
            Place::Remote(r) => r.extension(),
        }
    }

    /// The name as a path (a remote name's text unchanged): for records that keep the name of a
    /// file that is never read through the place, such as a `.ic` a `.ct`-only plan did not open.
    pub(crate) fn into_path_buf(self) -> PathBuf {
        match self {
            Place::Local(p) => p,
            Place::Remote(r) => PathBuf::from(r.text),
        }
    }
}

impl fmt::Display for Place {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Place::Local(p) => fmt::Display::fmt(&p.display(), f),
            Place::Remote(r) => f.write_str(&r.text),
        }
    }
}

/// As the name's text: a local path exactly as a `PathBuf` serializes, a remote name as written.
impl Serialize for Place {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Place::Local(p) => p.serialize(s),
            Place::Remote(r) => s.serialize_str(&r.text),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn local(p: &str) -> Place {
        Place::Local(PathBuf::from(p))
    }

    #[test]
    fn a_password_and_signatures_in_a_url_are_never_shown() {
        for (text, shown) in [
            ("http://user:hunter2@h:80/x.tif", "http://user:***@h:80/x.tif"),
            (
                "https://h/x.tif?X-Amz-Signature=abc&X-Amz-Date=2026&x-amz-credential=AK%2F1",
                "https://h/x.tif?X-Amz-Signature=***&X-Amz-Date=2026&x-amz-credential=***",
            ),
            ("cannot open `HTTPS://u:p@h/a?sig=zz&sv=1#f`: no", "cannot open `HTTPS://u:***@h/a?sig=***&sv=1#f`: no"),
            ("a https://h/x?token=t http://h/y?api_key=k", "a https://h/x?token=*** http://h/y?api_key=***"),
            ("http://user@h/x?page=2", "http://user@h/x?page=2"),
            ("/data/x.tif s3://b/k?token=t", "/data/x.tif s3://b/k?token=t"),
        ] {
            assert_eq!(redacted(text), shown, "{text}");
        }
    }

    #[test]
    fn a_url_with_a_query_ends_in_its_paths_extension() {
        for (name, ext, path) in [
            ("https://h/x.tif?sig=a/b.png&t=1", Some("tif"), "https://h/x.tif"),
            ("http://h:8/d/x.TIFF#part", Some("TIFF"), "http://h:8/d/x.TIFF"),
            ("https://h/x.raw.zst?X-Amz-Signature=00", Some("zst"), "https://h/x.raw.zst"),
            ("https://h/x?y.tif", None, "https://h/x"),
            ("s3://b/k.tif?v", Some("tif?v"), "s3://b/k.tif?v"),
        ] {
            let r = RemoteName::parse(name).unwrap();
            assert_eq!((r.extension(), r.path()), (ext, path), "{name}");
            assert_eq!(r.as_str(), name, "the name itself is kept whole");
        }
    }

    #[test]
    fn local_names_are_paths_as_given() {
        for name in [
            "/data/t/r000.c001.raw",
            "tiles/r000.c001.raw",
            "../up/x.raw",
            "./a/../b",
            "http:/one-slash",
            "s3:/x",
            "",
            "file://x",
            "httpx://h/p",
        ] {
            let p = Place::parse(name);
            assert_eq!(p, local(name), "{name}");
            assert_eq!(p.as_local(), Some(Path::new(name)));
            assert!(p.remote().is_none());
            assert_eq!(p.to_string(), name);
        }
    }

    #[test]
    fn remote_names_keep_their_text_and_scheme() {
        for (name, scheme, rest) in [
            ("http://h:8080/pyr/L00/r000.c001.raw", RemoteScheme::Http, "h:8080/pyr/L00/r000.c001.raw"),
            ("https://example.org/a/../b", RemoteScheme::Https, "example.org/a/../b"),
            ("s3://bucket/key/x.raw.zst", RemoteScheme::S3, "bucket/key/x.raw.zst"),
            ("HTTP://Host/X", RemoteScheme::Http, "Host/X"),
            ("hTtPs://h//double", RemoteScheme::Https, "h//double"),
            ("S3://B/k", RemoteScheme::S3, "B/k"),
            ("http://", RemoteScheme::Http, ""),
        ] {
            let p = Place::parse(name);
            let r = p.remote().unwrap_or_else(|| panic!("{name} is remote"));
            assert_eq!((r.scheme(), r.rest(), r.as_str()), (scheme, rest, name));
            assert_eq!(p.as_local(), None);
            assert_eq!(p.to_string(), name);
            assert_eq!(Place::from_path(PathBuf::from(name)), p);
        }
        assert_eq!(Place::parse("s3://b/k/t.raw.zst").extension(), Some("zst"));
        assert_eq!(Place::parse("http://h/t.raw").extension(), Some("raw"));
    }

    #[test]
    fn anchoring_joins_relative_local_names_only() {
        let dir = Path::new("/cfg/dir");
        assert_eq!(Place::anchored(dir, "t/r0.raw"), local("/cfg/dir/t/r0.raw"));
        assert_eq!(Place::anchored(dir, "../t/r0.raw"), local("/cfg/dir/../t/r0.raw"));
        assert_eq!(Place::anchored(dir, "/abs/r0.raw"), local("/abs/r0.raw"));
        assert_eq!(Place::anchored(dir, "Https://h/x").to_string(), "Https://h/x");
        assert!(Place::anchored(dir, "s3://b/k").remote().is_some());
        assert_eq!(Place::anchored(dir, "http:/x"), local("/cfg/dir/http:/x"));
    }

    #[test]
    fn serializes_as_the_text_a_path_would() {
        for name in ["/a/b c/r0.raw", "rel/x", "http://h/x%20y", "S3://b/k"] {
            let place = serde_json::to_string(&Place::parse(name)).unwrap();
            assert_eq!(place, serde_json::to_string(&PathBuf::from(name)).unwrap(), "{name}");
        }
    }

    proptest! {
        #[test]
        fn the_text_comes_back_and_the_kind_follows_the_prefix(
            prefix in prop::sample::select(vec!["", "/", "./", "../", "http://", "HTTPS://", "s3://", "S3:/", "http:"]),
            body in "[a-zA-Z0-9._/:%-]{0,24}",
        ) {
            let name = format!("{prefix}{body}");
            let place = Place::parse(&name);
            prop_assert_eq!(place.to_string(), name.clone());
            let lower = name.to_ascii_lowercase();
            let remote = ["http://", "https://", "s3://"].iter().any(|s| lower.starts_with(s));
            prop_assert_eq!(place.remote().is_some(), remote);
            prop_assert_eq!(Place::from_path(PathBuf::from(&name)), place);
        }
    }
}
