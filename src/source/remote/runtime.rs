//! Remote requests run on the process's runtime ([`crate::runtime`]): a read blocks only its
//! calling thread (an engine read thread, a tool's thread) while its request runs there.

use super::fetch::Failure;
use std::future::Future;
use std::sync::OnceLock;
use std::time::Duration;

/// Runs `fut` on the process's runtime and waits for it, at most `limit` (plus a second of
/// grace: the request's own timeout should end it first). Called from async code (a runtime's
/// worker thread), it hands that worker's other tasks over first ([`crate::runtime::wait`]), so
/// the wait never starves the runtime it waits for.
pub fn block<T: Send + 'static>(
    limit: Duration,
    fut: impl Future<Output = Result<T, Failure>> + Send + 'static,
) -> Result<T, Failure> {
    let rt = crate::runtime::shared().map_err(|e| Failure::Fatal(format!("remote reads: {e}")))?;
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    let bounded = limit.saturating_add(Duration::from_secs(1));
    rt.spawn(async move {
        let r = match tokio::time::timeout(bounded, fut).await {
            Ok(r) => r,
            Err(_) => Err(Failure::Transient { why: "timed out".into(), retry_after: None, timed_out: true }),
        };
        let _ = tx.send(r);
    });
    crate::runtime::wait(|| rx.recv())
        .unwrap_or_else(|_| Err(Failure::Fatal("the request's task ended without an answer".into())))
}

/// Installs the process's TLS provider (ring) once, for `https://` and the S3 client.
pub(crate) fn install_crypto() {
    static DONE: OnceLock<()> = OnceLock::new();
    DONE.get_or_init(|| {
        // Another part of the process may have installed one already: that one is kept.
        let _ = rustls::crypto::ring::default_provider().install_default();
    });
}
