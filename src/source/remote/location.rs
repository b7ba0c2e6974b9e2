//! Remote locations: `http(s)://HOST[:PORT]/PATH` and `s3://BUCKET/KEY`, parsed once per read
//! from the [`RemoteName`] a plan renders (which already carries its scheme: the one place a
//! name's kind is recognised is [`crate::place`]).

use crate::place::{RemoteName, RemoteScheme};
use std::fmt;

/// Which protocol reads a location.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum Scheme {
    /// `http://` or `https://`: ranged GETs to the URL.
    Http,
    /// `s3://`: an S3-compatible store (endpoint and credentials from the `AWS_*` variables).
    S3,
}

/// A parsed remote location.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Location {
    /// The protocol.
    pub scheme: Scheme,
    /// The endpoint reads are queued and bounded by: `http://host:port` (the URL's scheme, host
    /// and port) or `s3://bucket`.
    pub endpoint: String,
    /// The whole URL (HTTP) or the object key (S3, without the bucket).
    pub target: String,
    /// The bucket (S3 only; empty for HTTP).
    pub bucket: String,
}

/// Why a name is not a remote location that can be read.
/// Its message shows the name with its secrets replaced ([`crate::place::redacted`]).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("`{shown}` is not a usable remote location: {problem}; expected http://HOST[:PORT]/PATH, https://HOST[:PORT]/PATH or s3://BUCKET/KEY", shown = crate::place::redacted(name))]
pub struct LocationError {
    /// The name.
    pub name: String,
    /// What is wrong.
    pub problem: String,
}

impl Location {
    /// Parses `name` (a URL a plan rendered).
    pub fn parse(name: &str) -> Result<Location, LocationError> {
        match RemoteName::parse(name) {
            Some(remote) => Location::of(&remote),
            None => Err(LocationError {
                name: name.to_string(),
                problem: "the scheme is neither http, https nor s3".to_string(),
            }),
        }
    }

    /// Parses a remote name (its scheme already told apart, [`crate::place`]) into endpoint
    /// and target.
    pub fn of(remote: &RemoteName) -> Result<Location, LocationError> {
        let name = remote.as_str();
        let bad = |problem: &str| LocationError { name: name.to_string(), problem: problem.to_string() };
        if remote.scheme() == RemoteScheme::S3 {
            let rest = remote.rest();
            let (bucket, key) = rest.split_once('/').ok_or_else(|| bad("no object key after the bucket"))?;
            if bucket.is_empty() {
                return Err(bad("the bucket name is empty"));
            }
            if key.is_empty() || key.ends_with('/') {
                return Err(bad("the object key is empty or ends with `/`"));
            }
            if key.split('/').any(|seg| seg.is_empty() || seg == "." || seg == "..") {
                return Err(bad("the object key has an empty, `.` or `..` segment"));
            }
            return Ok(Location {
                scheme: Scheme::S3,
                endpoint: format!("s3://{bucket}"),
                target: key.to_string(),
                bucket: bucket.to_string(),
            });
        }
        let url = reqwest::Url::parse(name).map_err(|e| bad(&e.to_string()))?;
        let host = url.host_str().filter(|h| !h.is_empty()).ok_or_else(|| bad("no host"))?;
        if !url.username().is_empty() || url.password().is_some() {
            return Err(bad(
                "credentials in the URL are refused (a password in a URL ends up in logs and process lists); serve the object without them, or through a URL signed with a query",
            ));
        }
        let port = url.port_or_known_default().unwrap_or(80);
        let endpoint = format!("{}://{host}:{port}", url.scheme());
        Ok(Location { scheme: Scheme::Http, endpoint, target: url.to_string(), bucket: String::new() })
    }
}

/// The location as it may be shown in errors and logs: an HTTP URL with its secrets replaced
/// ([`crate::place::redacted`]); requests use [`Location::target`].
impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.scheme {
            Scheme::Http => f.write_str(&crate::place::redacted(&self.target)),
            Scheme::S3 => write!(f, "s3://{}/{}", self.bucket, self.target),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_are_scheme_host_and_port_or_the_bucket() {
        let h = Location::parse("http://127.0.0.1:8080/pyr/L00/r000.c001.raw").unwrap();
        assert_eq!((h.scheme.clone(), h.endpoint.as_str()), (Scheme::Http, "http://127.0.0.1:8080"));
        assert_eq!(Location::parse("https://example.org/a").unwrap().endpoint, "https://example.org:443");
        let s = Location::parse("s3://tiles/pyr/L00/r000.c001.raw").unwrap();
        assert_eq!(
            (s.endpoint.as_str(), s.bucket.as_str(), s.target.as_str()),
            ("s3://tiles", "tiles", "pyr/L00/r000.c001.raw")
        );
        assert_eq!(s.to_string(), "s3://tiles/pyr/L00/r000.c001.raw");
    }

    #[test]
    fn a_remote_name_parses_as_its_text_does() {
        for name in ["HTTP://h:1/x", "s3://b/k", "S3://b/k/", "https://h/a/../b", "http://"] {
            let r = RemoteName::parse(name).unwrap();
            assert_eq!(Location::of(&r), Location::parse(name), "{name}");
        }
        assert_eq!(Location::of(&RemoteName::parse("S3://B/k").unwrap()).unwrap().endpoint, "s3://B");
        assert!(Location::parse("/local/x").unwrap_err().problem.contains("scheme"));
    }

    #[test]
    fn unusable_names_say_what_is_wrong() {
        for (name, word) in [
            ("s3://bucket", "no object key"),
            ("s3:///key", "bucket name is empty"),
            ("s3://b/a//c", "empty"),
            ("http://user:pw@host/x", "credentials"),
            ("ftp://host/x", "scheme"),
        ] {
            let e = Location::parse(name).unwrap_err().to_string();
            assert!(e.contains(word) && e.contains("expected"), "{name}: {e}");
        }
    }
}
