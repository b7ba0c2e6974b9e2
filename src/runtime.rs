//! The process's one tokio runtime: the read queues' runners, remote requests, the `clipmapd`
//! service (control socket, tick-loop hand-offs) and the tools' signal watchers all run on it.
//!
//! One runtime rather than one per user: every read queue, the remote reads and each binary used
//! to build their own, so a process serving several textures held several sets of worker threads
//! and blocking pools that knew nothing of each other. Built on first use ([`shared`]) and kept
//! for the life of the process (it is never shut down: each user stops its own tasks).
//!
//! Threads (named `clipmap-rt`):
//! - workers: as many as the cores available, at least 2 and at most 4 ([`WORKERS`]). Nothing blocks on
//!   them: tile reads run on blocking threads, and a wait for the runtime from a worker goes
//!   through [`wait`], which moves the worker's other tasks to another thread first. Two at
//!   least, so that one busy task never holds up everything else.
//! - at most [`MAX_BLOCKING_THREADS`] blocking threads (started on demand, ended after 10 s
//!   idle): every read queue's reads (at most `streams × max_in_flight_reads` per texture, which
//!   each queue's runner bounds itself), the service's blocking hand-offs, and whatever the
//!   libraries underneath put there (a host name's lookup). Work beyond the bound waits for a
//!   thread; it does not fail.

use std::future::Future;
use std::sync::OnceLock;
use std::time::Duration;
use tokio::runtime::{Handle, Runtime, RuntimeFlavor};

/// Worker threads, fewest and most: as many as the cores available within these (the workers
/// only route commands, completions and network bytes; reads run on blocking threads).
pub const WORKERS: (usize, usize) = (2, 4);

/// Blocking threads at most, over the whole process: room for four textures each with the most
/// stream servers ([`crate::limits::Limits::max_streams`], 64) reading the default
/// [`crate::limits::Limits::max_in_flight_reads`] (4) at once.
pub const MAX_BLOCKING_THREADS: usize = 1024;

/// How long an idle blocking thread is kept for the next piece of blocking work.
const KEEP_ALIVE: Duration = Duration::from_secs(10);

/// The process's runtime, built on the first call. An error (the operating system refused the
/// threads) is returned to every caller, each with a fresh copy of it.
pub fn shared() -> Result<&'static Runtime, std::io::Error> {
    static RT: OnceLock<Result<Runtime, (std::io::ErrorKind, String)>> = OnceLock::new();
    RT.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(WORKERS.0, |n| n.get());
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(cores.clamp(WORKERS.0, WORKERS.1))
            .max_blocking_threads(MAX_BLOCKING_THREADS)
            .thread_keep_alive(KEEP_ALIVE)
            .thread_name("clipmap-rt")
            .enable_all()
            .build()
            .map_err(|e| (e.kind(), e.to_string()))
    })
    .as_ref()
    .map_err(|(kind, why)| std::io::Error::new(*kind, format!("cannot start the runtime: {why}")))
}

/// Runs `fut` to its end on the calling thread, with the shared runtime's timers, sockets and
/// spawned tasks: how the binaries run their async code. Not from inside a runtime's task.
pub fn block_on<F: Future>(fut: F) -> Result<F::Output, std::io::Error> {
    Ok(shared()?.block_on(fut))
}

/// Runs `f`, which blocks its thread until something on the shared runtime answers. On a worker
/// thread of a multi-thread runtime (async code that called a blocking function) the worker's
/// other tasks are handed to another thread first (`block_in_place`), so that no caller can
/// starve the runtime it waits for; on any other thread (a read thread, a tool's thread) `f`
/// simply runs.
pub fn wait<R>(f: impl FnOnce() -> R) -> R {
    match Handle::try_current() {
        Ok(h) if h.runtime_flavor() == RuntimeFlavor::MultiThread => tokio::task::block_in_place(f),
        // A current-thread runtime's thread: it cannot hand its tasks over, and the answer comes
        // from the shared runtime's own workers, so waiting here delays only that runtime.
        _ => f(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    #[test]
    fn one_runtime_for_every_caller() {
        let a = shared().unwrap() as *const Runtime;
        let b = std::thread::spawn(|| shared().unwrap() as *const Runtime as usize).join().unwrap();
        assert_eq!(a as usize, b);
        let name = block_on(async { tokio::spawn(async { std::thread::current().name().map(str::to_string) }).await })
            .unwrap()
            .unwrap();
        assert_eq!(name.as_deref(), Some("clipmap-rt"));
    }

    /// More tasks than workers each block, through `wait`, on an answer that only another task
    /// on the same runtime gives: without the hand-off every worker would be stuck and no answer
    /// could come.
    #[test]
    fn waiting_from_every_worker_at_once_does_not_starve_the_runtime() {
        let rt = shared().unwrap();
        let n = WORKERS.1 * 2;
        let (done_tx, done_rx) = mpsc::channel();
        for _ in 0..n {
            let done = done_tx.clone();
            rt.spawn(async move {
                let (tx, rx) = mpsc::sync_channel(1);
                wait(|| {
                    tokio::spawn(async move {
                        tokio::time::sleep(Duration::from_millis(20)).await;
                        let _ = tx.send(());
                    });
                    rx.recv_timeout(Duration::from_secs(20)).expect("answered");
                });
                let _ = done.send(());
            });
        }
        for i in 0..n {
            done_rx.recv_timeout(Duration::from_secs(30)).unwrap_or_else(|_| panic!("task {i} of {n} never ended"));
        }
    }
}
