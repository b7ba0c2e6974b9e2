//! The S3 backend: `object_store`'s Amazon S3 client, one per bucket, configured from the usual
//! `AWS_*` environment variables (`AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`,
//! `AWS_SESSION_TOKEN`, `AWS_REGION` / `AWS_DEFAULT_REGION`, `AWS_ENDPOINT_URL` /
//! `AWS_ENDPOINT`, `AWS_ALLOW_HTTP`, ...). Credentials are handed to the client and never
//! printed or logged; an error names the location only.
//!
//! `object_store` retries what is worth retrying itself (with the options' backoff, which it
//! jitters; a body cut short is read on from where it stopped) and checks every answer to a
//! ranged GET: anything but a `206` is refused ("Received non-partial response when range
//! requested": a `200` with an error page is never read), and the `Content-Range` must be
//! exactly the range asked for (cut at the object's end); what fails after its retries is
//! final here. This backend checks the length of what arrives (a mismatch is retried by the
//! fetcher's loop), says where an object ends, and classifies what is left.

use super::fetch::{Backend, Failure, Got, Segments, Sink};
use super::location::Location;
use super::options::RemoteOptions;
use super::runtime::block;
use bytes::Bytes;
use object_store::aws::{AmazonS3, AmazonS3Builder, AmazonS3ConfigKey};
use object_store::path::Path as ObjectPath;
use object_store::{ClientOptions, GetOptions, GetRange, ObjectStore, ObjectStoreExt, PutPayload, RetryConfig};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Reads and writes objects of S3-compatible stores.
pub struct S3 {
    opts: RemoteOptions,
    /// The `AWS_*` variables, when not those of the process environment.
    vars: Option<Vec<(String, String)>>,
    stores: Mutex<HashMap<String, Arc<AmazonS3>>>,
}

impl S3 {
    /// A backend with the options' timeouts and retries (no store is made before it is used),
    /// configured from the process environment's `AWS_*` variables.
    pub fn new(opts: &RemoteOptions) -> S3 {
        S3 { opts: opts.clone(), vars: None, stores: Mutex::new(HashMap::new()) }
    }

    /// Like [`S3::new`], configured from `vars` (`AWS_*` names and values) instead of the
    /// process environment, which is left alone (tests, several stores in one process).
    pub fn with_vars(opts: &RemoteOptions, vars: Vec<(String, String)>) -> S3 {
        S3 { opts: opts.clone(), vars: Some(vars), stores: Mutex::new(HashMap::new()) }
    }

    fn var(&self, name: &str) -> Option<String> {
        match &self.vars {
            Some(vars) => vars.iter().find(|(k, _)| k == name).map(|(_, v)| v.clone()),
            None => std::env::var(name).ok(),
        }
    }

    fn builder(&self) -> AmazonS3Builder {
        let Some(vars) = &self.vars else { return AmazonS3Builder::from_env() };
        // What `from_env` does, over the given variables.
        let mut b = AmazonS3Builder::new();
        for (k, v) in vars {
            if let Ok(key) = k.to_ascii_lowercase().parse::<AmazonS3ConfigKey>() {
                b = b.with_config(key, v);
            }
        }
        b
    }

    fn store(&self, bucket: &str) -> Result<Arc<AmazonS3>, Failure> {
        let mut m = self.stores.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(s) = m.get(bucket) {
            return Ok(Arc::clone(s));
        }
        super::runtime::install_crypto();
        let mut b = self.builder().with_bucket_name(bucket);
        // AWS_ENDPOINT_URL is the name the AWS tools use; object_store reads AWS_ENDPOINT.
        let endpoint = self.var("AWS_ENDPOINT_URL").or_else(|| self.var("AWS_ENDPOINT"));
        if let Some(e) = &endpoint {
            b = b.with_endpoint(e.clone());
        }
        if self.var("AWS_REGION").is_none() {
            if let Some(r) = self.var("AWS_DEFAULT_REGION") {
                b = b.with_region(r);
            }
        }
        // A plain-HTTP endpoint that the environment names was chosen on purpose (a store on a
        // private network, a test server).
        let plain = endpoint.as_deref().is_some_and(|e| e.to_ascii_lowercase().starts_with("http://"));
        let mut client = ClientOptions::new()
            .with_timeout(self.opts.timeout)
            .with_connect_timeout(self.opts.connect_timeout)
            .with_allow_http(plain || self.var("AWS_ALLOW_HTTP").is_some_and(|v| v.eq_ignore_ascii_case("true")));
        if let Some(path) = &self.opts.ca_file {
            let pem = super::ca::read(path).map_err(Failure::Fatal)?;
            let certs = object_store::Certificate::from_pem_bundle(&pem).map_err(|e| {
                Failure::Fatal(format!("CLIPMAP_REMOTE_CA_FILE {}: cannot read its certificates: {e}", path.display()))
            })?;
            for c in certs {
                client = client.with_root_certificate(c);
            }
        }
        let retry = RetryConfig {
            backoff: object_store::BackoffConfig {
                init_backoff: self.opts.backoff.max(Duration::from_millis(1)),
                max_backoff: self.opts.backoff_max.max(Duration::from_millis(1)),
                base: 2.0,
            },
            max_retries: self.opts.retries as usize,
            retry_timeout: self.opts.timeout.saturating_mul(self.opts.retries + 1),
        };
        let store =
            b.with_client_options(client).with_retry(retry).build().map_err(|e| {
                Failure::Fatal(format!("cannot make the S3 client for bucket {bucket}: {}", sanitize(&e)))
            })?;
        let store = Arc::new(store);
        m.insert(bucket.to_string(), Arc::clone(&store));
        Ok(store)
    }

    fn limit(&self) -> Duration {
        // object_store retries inside one call.
        self.opts.timeout.saturating_mul(self.opts.retries + 1)
            + self.opts.backoff_max.saturating_mul(self.opts.retries)
    }
}

fn path(loc: &Location) -> Result<ObjectPath, Failure> {
    ObjectPath::parse(&loc.target).map_err(|e| Failure::Fatal(format!("not an object key: {e}")))
}

/// An `object_store` error in words, without anything but the error's own text (which names
/// the key and the status, never credentials).
fn sanitize(e: &object_store::Error) -> String {
    e.to_string()
}

fn failure(e: object_store::Error) -> Failure {
    match e {
        object_store::Error::NotFound { .. } => Failure::NotFound,
        object_store::Error::PermissionDenied { .. } | object_store::Error::Unauthenticated { .. } => {
            Failure::Denied(sanitize(&e))
        }
        other => {
            let text = sanitize(&other);
            if text.contains("416") || text.contains("Range Not Satisfiable") || text.contains("InvalidRange") {
                // The object ends before the range starts.
                return Failure::Fatal(format!("range not satisfiable: {text}"));
            }
            // object_store has retried already (the request and a body cut short alike).
            Failure::Fatal(text)
        }
    }
}

/// Bytes `[start, start + len)` (`len` > 0) of `p`, handed to `sink` as they arrive: the answer's
/// version first, then its body, checked against the range asked for. A range past the end of the
/// object hands nothing over but the object's size.
async fn get_into(
    store: Arc<AmazonS3>,
    p: ObjectPath,
    start: u64,
    len: u64,
    sink: &(dyn Fn(Head) -> Result<(), Failure> + Send + Sync),
    body: &(dyn Fn(Bytes) + Send + Sync),
) -> Result<(), Failure> {
    use futures_util::StreamExt;
    let options = GetOptions { range: Some(GetRange::Bounded(start..start + len)), ..Default::default() };
    let r = match store.get_opts(&p, options).await {
        Ok(r) => r,
        Err(e) => {
            let f = failure(e);
            if matches!(&f, Failure::Fatal(t) if t.starts_with("range not satisfiable")) {
                let size = store.head(&p).await.ok().map(|m| m.size);
                return sink(Head { object_len: size, validator: None });
            }
            return Err(f);
        }
    };
    let (range, size) = (r.range.clone(), r.meta.size);
    let validator = match &r.meta.e_tag {
        Some(tag) => Some(format!("ETag {tag}")),
        None => Some(format!("Last-Modified {}", r.meta.last_modified.to_rfc3339())),
    };
    if range.start != start || range.end < range.start || range.end > start + len {
        return Err(Failure::transient(format!(
            "asked for bytes {start}..{}, the answer holds bytes {}..{}",
            start + len,
            range.start,
            range.end
        )));
    }
    if range.end < start + len && range.end != size {
        return Err(Failure::transient(format!("the answer ends at byte {} of {size}", range.end)));
    }
    sink(Head { object_len: Some(size), validator })?;
    let want = range.end - range.start;
    let mut got = 0u64;
    let mut stream = r.into_stream();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(failure)?;
        if got + chunk.len() as u64 > want {
            return Err(Failure::transient(format!("the body holds more than the {want} bytes of its range")));
        }
        got += chunk.len() as u64;
        body(chunk);
    }
    if got < want {
        return Err(Failure::transient(format!("the body ended after {got} of {want} bytes")));
    }
    Ok(())
}

/// What an answer says of the object before its body.
struct Head {
    object_len: Option<u64>,
    validator: Option<String>,
}

impl Backend for S3 {
    fn get(&self, loc: &Location, start: u64, len: u64) -> Result<Got, Failure> {
        if len == 0 {
            return Ok(Got { bytes: Segments::default(), object_len: None, validator: None });
        }
        let store = self.store(&loc.bucket)?;
        let p = path(loc)?;
        block(self.limit(), async move {
            let head = Mutex::new(None);
            let parts = Mutex::new(Vec::new());
            let keep = |h: Head| {
                *head.lock().unwrap_or_else(|e| e.into_inner()) = Some(h);
                Ok(())
            };
            let add = |b: Bytes| parts.lock().unwrap_or_else(|e| e.into_inner()).push(b);
            get_into(store, p, start, len, &keep, &add).await?;
            let h = head.into_inner().unwrap_or_else(|e| e.into_inner());
            let (object_len, validator) = h.map_or((None, None), |h| (h.object_len, h.validator));
            Ok(Got { bytes: Segments(parts.into_inner().unwrap_or_else(|e| e.into_inner())), object_len, validator })
        })
    }

    fn get_streamed(&self, loc: &Location, start: u64, len: u64, sink: &Arc<dyn Sink>) -> Result<(), Failure> {
        if len == 0 {
            return Ok(());
        }
        let store = self.store(&loc.bucket)?;
        let p = path(loc)?;
        let sink = Arc::clone(sink);
        block(self.limit(), async move {
            let head = |h: Head| sink.head(h.object_len, h.validator.as_deref()).map_err(Failure::Fatal);
            let body = |b: Bytes| sink.bytes(b);
            get_into(store, p, start, len, &head, &body).await
        })
    }

    fn head(&self, loc: &Location) -> Result<u64, Failure> {
        let store = self.store(&loc.bucket)?;
        let p = path(loc)?;
        block(self.limit(), async move { store.head(&p).await.map(|m| m.size).map_err(failure) })
    }

    fn put(&self, loc: &Location, bytes: Bytes) -> Result<(), Failure> {
        let store = self.store(&loc.bucket)?;
        let p = path(loc)?;
        block(self.limit(), async move { store.put(&p, PutPayload::from(bytes)).await.map(|_| ()).map_err(failure) })
    }
}
