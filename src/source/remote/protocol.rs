//! Which HTTP version answered: the HTTP backend counts its answers by version, so `STATS`
//! shows whether a server speaks HTTP/2 (many requests multiplexed on few connections) or
//! HTTP/1.1 (one request at a time on each connection). It leaves choosing the version to the
//! client: ALPN over TLS, or prior knowledge (h2c) where the options ask for it
//! ([`super::RemoteOptions::h2c`]).

use std::sync::atomic::{AtomicU64, Ordering};

/// Answers counted by the HTTP version they came in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AnswerVersions {
    /// Answers over HTTP/1.0 or HTTP/1.1.
    pub http1: u64,
    /// Answers over HTTP/2.
    pub http2: u64,
}

impl AnswerVersions {
    /// The versions that answered, for the statistics: `HTTP/1.1`, `HTTP/2`, both
    /// (`HTTP/1.1 and HTTP/2`: servers of two kinds), or empty before any answer.
    pub fn summary(self) -> &'static str {
        match (self.http1 > 0, self.http2 > 0) {
            (false, false) => "",
            (true, false) => "HTTP/1.1",
            (false, true) => "HTTP/2",
            (true, true) => "HTTP/1.1 and HTTP/2",
        }
    }

    /// The sum of two counts (two backends').
    pub fn plus(self, other: AnswerVersions) -> AnswerVersions {
        AnswerVersions { http1: self.http1 + other.http1, http2: self.http2 + other.http2 }
    }
}

/// The counters behind [`AnswerVersions`], shared by a backend's requests.
#[derive(Debug, Default)]
pub(crate) struct VersionCounters {
    http1: AtomicU64,
    http2: AtomicU64,
}

impl VersionCounters {
    /// Counts one answer of `version` (HTTP/3 and HTTP/0.9 are not spoken: not counted).
    pub(crate) fn note(&self, version: reqwest::Version) {
        let counter = match version {
            reqwest::Version::HTTP_10 | reqwest::Version::HTTP_11 => &self.http1,
            reqwest::Version::HTTP_2 => &self.http2,
            _ => return,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// The counts so far.
    pub(crate) fn get(&self) -> AnswerVersions {
        AnswerVersions { http1: self.http1.load(Ordering::Relaxed), http2: self.http2.load(Ordering::Relaxed) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_are_counted_by_version_and_summed_up() {
        let c = VersionCounters::default();
        assert_eq!(c.get().summary(), "", "no answer yet");
        c.note(reqwest::Version::HTTP_11);
        c.note(reqwest::Version::HTTP_10);
        assert_eq!((c.get(), c.get().summary()), (AnswerVersions { http1: 2, http2: 0 }, "HTTP/1.1"));
        c.note(reqwest::Version::HTTP_2);
        assert_eq!(c.get().summary(), "HTTP/1.1 and HTTP/2");
        c.note(reqwest::Version::HTTP_3);
        assert_eq!(c.get(), AnswerVersions { http1: 2, http2: 1 }, "HTTP/3 is not counted");
        let h2 = AnswerVersions { http1: 0, http2: 5 };
        assert_eq!(h2.summary(), "HTTP/2");
        assert_eq!(h2.plus(c.get()), AnswerVersions { http1: 2, http2: 6 });
    }
}
