//! The HTTP(S) backend: ranged GETs (`Range: bytes=A-B`), HEAD and PUT with `reqwest`, every
//! answer checked before a byte of it is used.
//!
//! A `206` must carry the `Content-Range` asked for (or one that ends where the object ends)
//! and exactly that many body bytes. A `200` is an answer that ignores the range, and is used
//! only when it is the whole object: not an HTML page (`Content-Type: text/html`, what an error
//! page of a proxy or a misconfigured server is), at most `MAX_WHOLE_OBJECT` bytes, and of
//! exactly the object's size as a `HEAD` gives it (its `Content-Length`, if any, and its body
//! alike); the range is then cut out of it, and the answer is counted ([`Backend::ranges_ignored`],
//! `ranges_ignored` in the statistics) and said once an endpoint in the log: such a server makes
//! every read fetch the whole object. A `416` means the object ends before the range
//! starts. Anything else is a [`Failure`], classified for the retry loop.
//!
//! HTTP/2 where the server offers it: over TLS the client offers `h2` and `http/1.1` (ALPN) and
//! the server chooses; to `http://` endpoints it speaks HTTP/2 with prior knowledge (h2c) only
//! when the options say so ([`RemoteOptions::h2c`]). Over HTTP/2 every request to an endpoint
//! is a stream of one shared connection (as many at once as the server allows), instead of a
//! connection per request in flight. Answers are counted by version ([`Backend::versions`]).
//! Extra certificate authorities come from [`RemoteOptions::ca_file`].

use super::fetch::{Backend, Failure, Got, Hedge, Object, ObjectRequest, Segments, Sink};
use super::location::Location;
use super::options::RemoteOptions;
use super::protocol::{AnswerVersions, VersionCounters};
use super::runtime::block;
use bytes::Bytes;
use reqwest::header::{CONTENT_LENGTH, CONTENT_RANGE, CONTENT_TYPE, ETAG, LAST_MODIFIED, RANGE, RETRY_AFTER};
use reqwest::StatusCode;
use std::collections::HashSet;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Largest object read whole from a server that does not answer range requests.
pub(crate) const MAX_WHOLE_OBJECT: u64 = 256 << 20;

/// Ranged reads over HTTP(S).
pub struct Http {
    client: Result<reqwest::Client, String>,
    /// The client for `http://` URLs when they are spoken to in HTTP/2 with prior knowledge.
    h2c: Option<Result<reqwest::Client, String>>,
    timeout: Duration,
    ignored: Arc<IgnoredRanges>,
    versions: Arc<VersionCounters>,
}

/// Answers that ignored a range: a `200` with the whole object to a ranged GET, used (the
/// object checked and the range cut out of it) but each read then fetches the whole object,
/// tens of times slower than ranged reads. Counted, and said once an endpoint in the log.
#[derive(Debug, Default)]
struct IgnoredRanges {
    count: AtomicU64,
    warned: Mutex<HashSet<String>>,
}

impl IgnoredRanges {
    /// Counts one such answer from `endpoint` for an object of `size` bytes; the first from an
    /// endpoint is a warning in the log.
    fn note(&self, endpoint: &str, url: &str, size: u64) {
        self.count.fetch_add(1, Ordering::Relaxed);
        let first = self.warned.lock().unwrap_or_else(|e| e.into_inner()).insert(endpoint.to_string());
        if first {
            tracing::warn!(
                endpoint,
                object = %crate::place::redacted(url),
                "the server ignores range requests: it answered a ranged GET with the whole object (HTTP 200, {size} bytes), so every read fetches the whole object (29 to 46 times slower than ranged reads, measured); serve the files with a server that answers Range (nginx, S3; Python's http.server does not); counted in STATS as remote.ranges_ignored, said once an endpoint"
            );
        }
    }
}

impl Http {
    /// A client with the options' timeouts (connections are kept and reused per host), and
    /// one speaking h2c to `http://` URLs if the options ask for it.
    pub fn new(opts: &RemoteOptions) -> Http {
        super::runtime::install_crypto();
        let roots = opts.ca_file.as_deref().map(super::ca::read).transpose();
        let client = |h2c: bool| -> Result<reqwest::Client, String> {
            let mut b = reqwest::Client::builder()
                .timeout(opts.timeout)
                .connect_timeout(opts.connect_timeout)
                .pool_max_idle_per_host(opts.in_flight.max(1))
                .tcp_nodelay(true)
                .no_proxy();
            if let Some(pem) = roots.clone()? {
                let certs = reqwest::Certificate::from_pem_bundle(&pem).map_err(|e| {
                    format!(
                        "CLIPMAP_REMOTE_CA_FILE: cannot read its certificates: {}; expected CA certificates in PEM",
                        root_cause(&e)
                    )
                })?;
                b = b.tls_certs_merge(certs);
            }
            if h2c {
                b = b.http2_prior_knowledge();
            }
            b.build().map_err(|e| format!("cannot make an HTTP client: {}", root_cause(&e)))
        };
        Http {
            client: client(false),
            h2c: opts.h2c.then(|| client(true)),
            timeout: opts.timeout,
            ignored: Arc::default(),
            versions: Arc::default(),
        }
    }

    /// The client for `loc`: the h2c one for an `http://` URL when there is one.
    fn client(&self, loc: &Location) -> Result<reqwest::Client, Failure> {
        let plain = loc.target.get(..7).is_some_and(|s| s.eq_ignore_ascii_case("http://"));
        let client = match &self.h2c {
            Some(h2c) if plain => h2c,
            _ => &self.client,
        };
        client.clone().map_err(Failure::Fatal)
    }

    fn target(&self, loc: &Location) -> Target {
        Target {
            url: loc.target.clone(),
            endpoint: loc.endpoint.clone(),
            ignored: Arc::clone(&self.ignored),
            versions: Arc::clone(&self.versions),
        }
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
        .and_then(|v| super::retry_after::parse(v, std::time::SystemTime::now()));
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

/// The object's version an answer names: its `ETag`, else its `Last-Modified`.
fn validator(headers: &reqwest::header::HeaderMap) -> Option<String> {
    let text = |name| headers.get(name).and_then(|v: &reqwest::header::HeaderValue| v.to_str().ok());
    if let Some(tag) = text(ETAG) {
        return Some(format!("ETag {}", tag.trim()));
    }
    text(LAST_MODIFIED).map(|m| format!("Last-Modified {}", m.trim()))
}

/// Reads the body, handing each piece to `each` as it arrives (no copy), failing before a piece
/// that would take it past `max` bytes; stops reading at `stop` bytes. Returns the bytes read.
async fn body_each(
    resp: &mut reqwest::Response,
    max: u64,
    stop: u64,
    each: &mut (dyn FnMut(Bytes) + Send),
) -> Result<u64, Failure> {
    let mut len = 0u64;
    while len < stop {
        match resp.chunk().await {
            Ok(Some(c)) => {
                if len + c.len() as u64 > max {
                    return Err(Failure::transient(format!("the body holds more than the {max} bytes announced")));
                }
                len += c.len() as u64;
                each(c);
            }
            Ok(None) => break,
            Err(e) => {
                let timed_out = e.is_timeout();
                let why = format!("the body was cut after {len} bytes: {}", root_cause(&e));
                return Err(Failure::Transient { why, retry_after: None, timed_out });
            }
        }
    }
    Ok(len)
}

/// [`body_each`] keeping the pieces as they came.
async fn body(resp: &mut reqwest::Response, max: u64, stop: u64) -> Result<Segments, Failure> {
    let mut parts: Vec<Bytes> = Vec::new();
    body_each(resp, max, stop, &mut |c| parts.push(c)).await?;
    Ok(Segments(parts))
}

/// Sends the ranged GET of `[start, start + len)` (`len` > 0), counting its answer's version.
async fn send_range(client: &reqwest::Client, to: &Target, start: u64, len: u64) -> Result<reqwest::Response, Failure> {
    let last = start + len - 1;
    send(client.get(&to.url).header(RANGE, format!("bytes={start}-{last}")), &to.versions).await
}

/// Sends `req`, counting its answer's version.
async fn send(req: reqwest::RequestBuilder, versions: &VersionCounters) -> Result<reqwest::Response, Failure> {
    let resp = req.send().await.map_err(request_failure)?;
    versions.note(resp.version());
    Ok(resp)
}

/// Checks a `206`'s head against the range asked for (`[start, last]`): the object's length
/// (when the answer says) and the bytes its body is to hold.
fn partial_head(headers: &reqwest::header::HeaderMap, start: u64, last: u64) -> Result<(Option<u64>, u64), Failure> {
    let Some((a, b, total)) = content_range(headers) else {
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
    Ok((total, want))
}

/// Where a request goes and what counts its answers that ignored the range.
struct Target {
    url: String,
    endpoint: String,
    ignored: Arc<IgnoredRanges>,
    versions: Arc<VersionCounters>,
}

async fn get(client: reqwest::Client, to: Target, start: u64, len: u64) -> Result<Got, Failure> {
    let mut resp = send_range(&client, &to, start, len).await?;
    if resp.status() != StatusCode::PARTIAL_CONTENT {
        return not_partial(client, &to, start, len, resp).await;
    }
    let headers = resp.headers().clone();
    let (total, want) = partial_head(&headers, start, start + len - 1)?;
    let buf = body(&mut resp, want, want + 1).await?;
    if (buf.len() as u64) < want {
        return Err(Failure::transient(format!("the body ended after {} of {want} bytes", buf.len())));
    }
    Ok(Got { bytes: buf, object_len: total, validator: validator(&headers) })
}

/// [`get`], sent once more (a hedge: over HTTP/1.1 on another connection, the first one being
/// busy; over HTTP/2 another stream of the same connection) when no
/// answer came within `after`. The first successful answer is used whole, never pieces of two
/// (they may be of two versions of the object); the other request is dropped, which cancels it
/// and closes its connection. A failed answer waits for the other one. Returns whether a hedge
/// was sent.
async fn get_hedged(
    client: reqwest::Client,
    (first, second): (Target, Target),
    start: u64,
    len: u64,
    hedge: Hedge,
) -> Result<(Got, bool), Failure> {
    use futures_util::future::{select, Either};
    let sent = std::time::Instant::now();
    let mut one = Box::pin(get(client.clone(), first, start, len));
    // Until it is time to hedge and the budget has room for it (both asked again while not).
    loop {
        let mut wait = hedge.wait(sent.elapsed());
        if wait.is_zero() {
            if hedge.budget.take() {
                break;
            }
            wait = super::flight::HEDGE_RECHECK;
        }
        one = match select(one, Box::pin(tokio::time::sleep(wait))).await {
            Either::Left((r, _)) => return r.map(|g| (g, false)),
            Either::Right(((), one)) => one,
        };
    }
    let two = Box::pin(get(client, second, start, len));
    let (r, other) = match select(one, two).await {
        Either::Left((r, other)) | Either::Right((r, other)) => (r, other),
    };
    match r {
        Ok(g) => Ok((g, true)),
        Err(_) => other.await.map(|g| (g, true)),
    }
}

/// [`get`] handing the bytes of a `206` to `sink` as they arrive (any other answer whole).
async fn get_streamed(
    client: reqwest::Client,
    to: Target,
    start: u64,
    len: u64,
    sink: Arc<dyn Sink>,
) -> Result<(), Failure> {
    let mut resp = send_range(&client, &to, start, len).await?;
    if resp.status() != StatusCode::PARTIAL_CONTENT {
        let got = not_partial(client, &to, start, len, resp).await?;
        sink.head(got.object_len, got.validator.as_deref()).map_err(Failure::Fatal)?;
        for b in got.bytes.0 {
            sink.bytes(b);
        }
        return Ok(());
    }
    let (total, want) = partial_head(resp.headers(), start, start + len - 1)?;
    sink.head(total, validator(resp.headers()).as_deref()).map_err(Failure::Fatal)?;
    let got = body_each(&mut resp, want, want + 1, &mut |c| sink.bytes(c)).await?;
    if got < want {
        return Err(Failure::transient(format!("the body ended after {got} of {want} bytes")));
    }
    Ok(())
}

/// An answer to a range request other than `206`: the whole object (a `200`, checked, and
/// counted as a range ignored), the object's end (`416`), or a failure.
async fn not_partial(
    client: reqwest::Client,
    to: &Target,
    start: u64,
    len: u64,
    mut resp: reqwest::Response,
) -> Result<Got, Failure> {
    let url = &to.url;
    let status = resp.status();
    let headers = resp.headers().clone();
    match status {
        StatusCode::OK => {
            // The server ignored the range. Only the whole object will do: an error page sent
            // with 200 (a proxy's, a misconfigured server's) is never cut up into texels.
            let html = headers
                .get(CONTENT_TYPE)
                .and_then(|v| v.to_str().ok())
                .is_some_and(|v| v.trim().to_ascii_lowercase().starts_with("text/html"));
            if html {
                return Err(Failure::transient(
                    "HTTP 200 with an HTML page (Content-Type text/html) to a range request: an error page, not the object",
                ));
            }
            let announced = headers.get(CONTENT_LENGTH).and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
            if announced.is_some_and(|n| n > MAX_WHOLE_OBJECT) {
                return Err(Failure::Fatal(format!(
                    "the server ignores range requests and the object holds {} bytes, more than {MAX_WHOLE_OBJECT} read whole",
                    announced.unwrap_or(0)
                )));
            }
            let size = head(&client, url, &to.versions).await.map_err(|f| {
                let why = match f {
                    Failure::NotFound => "not found".to_string(),
                    Failure::Denied(w) | Failure::Fatal(w) | Failure::Transient { why: w, .. } => w,
                };
                Failure::transient(format!(
                    "HTTP 200 to a range request, and the object's size to check it against is unknown (HEAD: {why})"
                ))
            })?;
            if announced.is_some_and(|n| n != size) {
                return Err(Failure::transient(format!(
                    "HTTP 200 to a range request with Content-Length {}, but the object holds {size} bytes (HEAD): not the object",
                    announced.unwrap_or(0)
                )));
            }
            if size > MAX_WHOLE_OBJECT {
                return Err(Failure::Fatal(format!(
                    "the server ignores range requests and the object holds {size} bytes, more than {MAX_WHOLE_OBJECT} read whole"
                )));
            }
            let buf = body(&mut resp, size, size.saturating_add(1)).await?;
            let got = buf.len() as u64;
            if got != size {
                return Err(Failure::transient(format!(
                    "HTTP 200 to a range request with a body of {got} bytes, but the object holds {size} (HEAD)"
                )));
            }
            to.ignored.note(&to.endpoint, url, size);
            let from = start.min(size) as usize;
            let end = start.saturating_add(len).min(size) as usize;
            Ok(Got { bytes: buf.slice(from, end), object_len: Some(size), validator: validator(&headers) })
        }
        StatusCode::RANGE_NOT_SATISFIABLE => {
            let total = headers
                .get(CONTENT_RANGE)
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.trim().strip_prefix("bytes */")?.parse::<u64>().ok());
            Ok(Got { bytes: Segments::default(), object_len: total, validator: validator(&headers) })
        }
        s if s.is_success() => Err(Failure::Fatal(format!("unexpected answer HTTP {s} to a range request"))),
        s => Err(status_failure(s, &headers)),
    }
}

/// A plain GET of a whole object ([`Backend::get_object`]).
async fn get_object(
    client: reqwest::Client,
    url: String,
    req: ObjectRequest,
    versions: Arc<VersionCounters>,
) -> Result<Object, Failure> {
    let mut get = client.get(&url);
    for (name, value) in &req.headers {
        get = get.header(name.as_str(), value.as_str());
    }
    let mut resp = send(get, &versions).await?;
    let status = resp.status();
    let headers = resp.headers().clone();
    if status == StatusCode::NO_CONTENT {
        return Ok(Object::default());
    }
    if status != StatusCode::OK {
        return Err(status_failure(status, &headers));
    }
    let content_type = headers.get(CONTENT_TYPE).and_then(|v| v.to_str().ok()).map(|v| v.trim().to_string());
    let announced = headers.get(CONTENT_LENGTH).and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
    if let Some(n) = announced.filter(|&n| n > req.max_bytes) {
        return Err(Failure::Fatal(format!(
            "the answer holds {n} bytes, more than the {} expected at most",
            req.max_bytes
        )));
    }
    let mut buf = Vec::new();
    let got = body_each(&mut resp, req.max_bytes, req.max_bytes.saturating_add(1), &mut |c| buf.extend_from_slice(&c))
        .await
        .map_err(|f| match f {
            Failure::Transient { why, .. } if why.starts_with("the body holds more") => {
                Failure::Fatal(format!("the answer holds more than the {} bytes expected at most", req.max_bytes))
            }
            other => other,
        })?;
    if announced.is_some_and(|n| n != got) {
        return Err(Failure::transient(format!(
            "the body ended after {got} of the {} bytes its Content-Length announced",
            announced.unwrap_or(0)
        )));
    }
    Ok(Object { bytes: Bytes::from(buf), content_type })
}

/// The object's length, from the `Content-Length` of a `HEAD`.
async fn head(client: &reqwest::Client, url: &str, versions: &VersionCounters) -> Result<u64, Failure> {
    let resp = send(client.head(url), versions).await?;
    let status = resp.status();
    if !status.is_success() {
        return Err(status_failure(status, resp.headers()));
    }
    resp.headers()
        .get(CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok()?.parse::<u64>().ok())
        .ok_or_else(|| Failure::Fatal("the answer to HEAD has no Content-Length".into()))
}

impl Backend for Http {
    fn get(&self, loc: &Location, start: u64, len: u64) -> Result<Got, Failure> {
        if len == 0 {
            return Ok(Got { bytes: Segments::default(), object_len: None, validator: None });
        }
        let client = self.client(loc)?;
        block(self.timeout, get(client, self.target(loc), start, len))
    }

    fn get_hedged(&self, loc: &Location, start: u64, len: u64, hedge: Hedge) -> Result<(Got, bool), Failure> {
        if len == 0 {
            return Ok((Got { bytes: Segments::default(), object_len: None, validator: None }, false));
        }
        let client = self.client(loc)?;
        let targets = (self.target(loc), self.target(loc));
        block(self.timeout, get_hedged(client, targets, start, len, hedge))
    }

    fn get_streamed(&self, loc: &Location, start: u64, len: u64, sink: &Arc<dyn Sink>) -> Result<(), Failure> {
        if len == 0 {
            return Ok(());
        }
        let client = self.client(loc)?;
        block(self.timeout, get_streamed(client, self.target(loc), start, len, Arc::clone(sink)))
    }

    fn ranges_ignored(&self) -> u64 {
        self.ignored.count.load(Ordering::Relaxed)
    }

    fn versions(&self) -> AnswerVersions {
        self.versions.get()
    }

    fn head(&self, loc: &Location) -> Result<u64, Failure> {
        let client = self.client(loc)?;
        let url = loc.target.clone();
        let versions = Arc::clone(&self.versions);
        block(self.timeout, async move { head(&client, &url, &versions).await })
    }

    fn get_object(&self, loc: &Location, req: &ObjectRequest) -> Result<Object, Failure> {
        let client = self.client(loc)?;
        block(self.timeout, get_object(client, loc.target.clone(), req.clone(), Arc::clone(&self.versions)))
    }

    fn put(&self, loc: &Location, bytes: Bytes) -> Result<(), Failure> {
        let client = self.client(loc)?;
        let url = loc.target.clone();
        let versions = Arc::clone(&self.versions);
        block(self.timeout, async move {
            let resp = send(client.put(&url).body(bytes), &versions).await?;
            let status = resp.status();
            if status.is_success() {
                Ok(())
            } else {
                Err(status_failure(status, resp.headers()))
            }
        })
    }
}
