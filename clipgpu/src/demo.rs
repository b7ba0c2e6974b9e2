//! `clipgpu --demo`: starts a service of its own (the library's, in this process) on the
//! reference flight's procedural texture in a private directory, flies the flight against it
//! through the shared mapping exactly as against any `clipmapd`, and stops the service.

use crate::flight::{fly, FlightOptions, FlightReport};
use crate::gpu::Gpu;
use anyhow::{anyhow, Context, Result};
use std::os::unix::fs::DirBuilderExt;
use std::time::Duration;

/// Runs the demo flight; the service lives only as long as the flight.
pub fn demo(gpu: &Gpu, o: &FlightOptions) -> Result<FlightReport> {
    let source = clipmap::accuracy::study::source(&o.case).map_err(|e| anyhow!("the demo texture: {e}"))?;
    let dir = std::env::temp_dir().join(format!("clipgpu-demo-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::DirBuilder::new().mode(0o700).create(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let name = "clipgpu-demo";
    let mut options = clipmap::service::Options::new(name);
    options.shm_dir = dir.clone();
    options.socket = clipmap::service::default_socket(&dir, name);
    options.tick_hz = 120.0;
    options.budget_ms = None;
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let service = std::thread::spawn(move || -> Result<()> {
        clipmap::runtime::block_on(clipmap::service::run(
            source,
            options,
            async {
                let _ = stop_rx.await;
            },
            move |_| {
                let _ = ready_tx.send(());
            },
        ))
        .context("starting the demo service's runtime")?
        .map_err(|e| anyhow!("the demo service: {e}"))?;
        Ok(())
    });
    let result = match ready_rx.recv_timeout(Duration::from_secs(60)) {
        Ok(()) => fly(gpu, &dir, name, o),
        Err(_) => Err(anyhow!("the demo service did not start within 60 s")),
    };
    let _ = stop_tx.send(());
    let stopped = service.join().map_err(|_| anyhow!("the demo service panicked"))?;
    let _ = std::fs::remove_dir_all(&dir);
    let report = result?;
    stopped?;
    Ok(report)
}
