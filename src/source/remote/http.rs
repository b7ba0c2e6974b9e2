//! The HTTP(S) backend: ranged GETs (`Range: bytes=A-B`), HEAD and PUT with `reqwest`, every
//! answer checked before a byte of it is used.
//!
//! A `206` must carry the `Content-Range` asked for (or one that ends where the object ends)
//! and exactly that many body bytes; a `200` (a server that ignores ranges) is read up to the end
//! of the range and no further, and only for objects of at most [`MAX_WHOLE_OBJECT`] bytes; a
//! `416` means the object ends before the range starts. Anything else is a [`Failure`],
//! classified for the retry loop.

use super::fetch::{Backend, Failure, Got, Segments};
use super::location::Location;
use super::options::RemoteOptions;
use super::runtime::block;
use bytes::Bytes;
use reqwest::header::{CONTENT_LENGTH, CONTENT_RANGE, RANGE, RETRY_AFTER};
use reqwest::StatusCode;
use std::time::Duration;

/// Largest object read whole from a server that does not answer range requests.
pub const MAX_WHOLE_OBJECT: u64 = 256 << 20;

/// Ranged reads over HTTP(S).
pub struct Http {
    client: Result<reqwest::Client, String>,
    timeout: Duration,
}

impl Http {
    /// A client with the options' timeouts (connections are kept and reused per host).
    pub fn new(opts: &RemoteOptions) -> Http {
        super::runtime::install_crypto();
        let client = reqwest::Client::builder()
            .timeout(opts.timeout)
            .connect_timeout(opts.connect_timeout)
            .pool_max_idle_per_host(opts.in_flight.max(1))
            .tcp_nodelay(true)
            .no_proxy()
            .build()
            .map_err(|e| format!("cannot make an HTTP client: {e}"));
        Http { client, timeout: opts.timeout }
    }

    fn client(&self) -> Result<reqwest::Client, Failure> {
        self.client.clone().map_err(Failure::Fatal)
    }
}

/// The failure of a request that got no answer.
fn request_failure(e: reqwest::Error) -> Failure {
    let timed_out = e.is_timeout();
    // Without the URL: the location is named by the caller, and a URL is never logged twice.
    let why = if timed_out {
        "timed out".to_string()
    } else if e.is_connect() {
        format!("cannot connect: {}", root_cause(&e))
    } else {
        format!("the connection failed: {}", root_cause(&e))
    };
    Failure::Transient { why, retry_after: None, timed_out }
}

fn root_cause(e: &(dyn std::error::Error + 'static)) -> String {
    let mut cur = e;
    while let Some(next) = cur.source() {
        cur = next;
    }
    cur.to_string()
}

/// The failure of an answer that is not a success.
fn status_failure(status: StatusCode, headers: &reqwest::header::HeaderMap) -> Failure {
    let retry_after = headers
        .get(RETRY_AFTER)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok())
        .map(Duration::from_secs);
    match status.as_u16() {
        404 | 410 => Failure::NotFound,
        401 | 403 => Failure::Denied(format!("HTTP {status}")),
        408 | 429 | 500 | 502 | 503 | 504 => {
            Failure::Transient { why: format!("HTTP {status}"), retry_after, timed_out: false }
        }
        _ => Failure::Fatal(format!("HTTP {status}")),
    }
}

/// `bytes A-B/TOTAL` (TOTAL may be `*`).
fn content_range(headers: &reqwest::header::HeaderMap) -> Option<(u64, u64, Option<u64>)> {
    let v = headers.get(CONTENT_RANGE)?.to_str().ok()?.trim();
    let rest = v.strip_prefix("bytes ")?;
    let (range, total) = rest.split_once('/')?;
    let (a, b) = range.split_once('-')?;
    let total = if total == "*" { None } else { Some(total.parse().ok()?) };
    Some((a.parse().ok()?, b.parse().ok()?, total))
}

/// Reads the body, failing if it holds more than `max` bytes; stops reading at `stop` bytes. The
/// pieces are kept as they came (no copy).
async fn body(resp: &mut reqwest::Response, max: u64, stop: u64) -> Result<Segments, Failure> {
    let mut parts: Vec<Bytes> = Vec::new();
    let mut len = 0u64;
    while len < stop {
        match resp.chunk().await {
            Ok(Some(c)) => {
                if len + c.len() as u64 > max {
                    return Err(Failure::transient(format!("the body holds more than the {max} bytes announced")));
                }
                len += c.len() as u64;
                parts.push(c);
            }
            Ok(None) => break,
            Err(e) => {
                let timed_out = e.is_timeout();
                let why = format!("the body was cut after {len} bytes: {}", root_cause(&e));
                return Err(Failure::Transient { why, retry_after: None, timed_out });
            }
        }
    }
    Ok(Segments(parts))
}

async fn get(client: reqwest::Client, url: String, start: u64, len: u64) -> Result<Got, Failure> {
    let last = start + len - 1;
    let mut resp =
        client.get(&url).header(RANGE, format!("bytes={start}-{last}")).send().await.map_err(request_failure)?;
    let status = resp.status();
    let headers = resp.headers().clone();
    match status {
        StatusCode::PARTIAL_CONTENT => {
            let Some((a, b, total)) = content_range(&headers) else {
                return Err(Failure::transient("a partial answer without a usable Content-Range"));
            };
            let ends_object = total.is_some_and(|t| b + 1 == t && b < last);
            if a != start || (b != last && !ends_object) || b < a {
                return Err(Failure::transient(format!(
                    "Content-Range bytes {a}-{b} answers a request for bytes {start}-{last}"
                )));
            }
            let want = b - a + 1;
            if let Some(n) = headers.get(CONTENT_LENGTH).and_then(|v| v.to_str().ok()?.parse::<u64>().ok()) {
                if n != want {
                    return Err(Failure::transient(format!("Content-Length {n} for a range of {want} bytes")));
                }
            }
            let buf = body(&mut resp, want, want + 1).await?;
            if (buf.len() as u64) < want {
                return Err(Failure::transient(format!("the body ended after {} of {want} bytes", buf.len())));
            }
            Ok(Got { bytes: buf, object_len: total })
        }
        StatusCode::OK => {
            let announced = headers.get(CONTENT_LENGTH).and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
            if announced.is_some_and(|n| n > MAX_WHOLE_OBJECT) {
                return Err(Failure::Fatal(format!(
                    "the server ignores range requests and the object holds {} bytes, more than {MAX_WHOLE_OBJECT} read whole",
                    announced.unwrap_or(0)
                )));
            }
            let stop = start + len;
            let buf = body(&mut resp, announced.unwrap_or(MAX_WHOLE_OBJECT), stop).await?;
            let got = buf.len() as u64;
            if got < stop && announced.is_some_and(|n| got < n) {
                return Err(Failure::transient(format!(
                    "the body ended after {got} of {} bytes",
                    announced.unwrap_or(0)
                )));
            }
            let from = (start as usize).min(buf.len());
            let to = (stop as usize).min(buf.len());
            let object_len = if got < stop { Some(got) } else { announced };
            Ok(Got { bytes: buf.slice(from, to), object_len })
        }
        StatusCode::RANGE_NOT_SATISFIABLE => {
            let total = headers
                .get(CONTENT_RANGE)
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.trim().strip_prefix("bytes */")?.parse::<u64>().ok());
            Ok(Got { bytes: Segments::default(), object_len: total })
        }
        s if s.is_success() => Err(Failure::Fatal(format!("unexpected answer HTTP {s} to a range request"))),
        s => Err(status_failure(s, &headers)),
    }
}

impl Backend for Http {
    fn get(&self, loc: &Location, start: u64, len: u64) -> Result<Got, Failure> {
        if len == 0 {
            return Ok(Got { bytes: Segments::default(), object_len: None });
        }
        let client = self.client()?;
        let url = loc.target.clone();
        block(self.timeout, get(client, url, start, len))
    }

    fn head(&self, loc: &Location) -> Result<u64, Failure> {
        let client = self.client()?;
        let url = loc.target.clone();
        block(self.timeout, async move {
            let resp = client.head(&url).send().await.map_err(request_failure)?;
            let status = resp.status();
            if !status.is_success() {
                return Err(status_failure(status, resp.headers()));
            }
            resp.headers()
                .get(CONTENT_LENGTH)
                .and_then(|v| v.to_str().ok()?.parse::<u64>().ok())
                .ok_or_else(|| Failure::Fatal("the answer to HEAD has no Content-Length".into()))
        })
    }

    fn put(&self, loc: &Location, bytes: Bytes) -> Result<(), Failure> {
        let client = self.client()?;
        let url = loc.target.clone();
        block(self.timeout, async move {
            let resp = client.put(&url).body(bytes).send().await.map_err(request_failure)?;
            let status = resp.status();
            if status.is_success() {
                Ok(())
            } else {
                Err(status_failure(status, resp.headers()))
            }
        })
    }
}
