//! The runtime remote requests run on: two worker threads of their own, so that a read blocks
//! only its calling thread (an engine read thread, a tool's thread) and never needs to be
//! called from inside some other runtime.

use super::fetch::Failure;
use std::future::Future;
use std::sync::OnceLock;
use std::time::Duration;

fn runtime() -> Result<&'static tokio::runtime::Runtime, Failure> {
    static RT: OnceLock<Result<tokio::runtime::Runtime, String>> = OnceLock::new();
    RT.get_or_init(|| {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("clipmap-remote")
            .enable_all()
            .build()
            .map_err(|e| format!("cannot start the runtime of remote reads: {e}"))
    })
    .as_ref()
    .map_err(|e| Failure::Fatal(e.clone()))
}

/// Runs `fut` on the remote runtime and waits for it, at most `limit` (plus a second of grace:
/// the request's own timeout should end it first).
pub fn block<T: Send + 'static>(
    limit: Duration,
    fut: impl Future<Output = Result<T, Failure>> + Send + 'static,
) -> Result<T, Failure> {
    let rt = runtime()?;
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    let bounded = limit.saturating_add(Duration::from_secs(1));
    rt.spawn(async move {
        let r = match tokio::time::timeout(bounded, fut).await {
            Ok(r) => r,
            Err(_) => Err(Failure::Transient { why: "timed out".into(), retry_after: None, timed_out: true }),
        };
        let _ = tx.send(r);
    });
    rx.recv().unwrap_or_else(|_| Err(Failure::Fatal("the request's task ended without an answer".into())))
}

/// Installs the process's TLS provider (ring) once, for `https://` and the S3 client.
pub(crate) fn install_crypto() {
    static DONE: OnceLock<()> = OnceLock::new();
    DONE.get_or_init(|| {
        // Another part of the process may have installed one already: that one is kept.
        let _ = rustls::crypto::ring::default_provider().install_default();
    });
}
