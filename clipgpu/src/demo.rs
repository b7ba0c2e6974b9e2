//! `clipgpu --demo`: starts a service of its own (the library's, in this process) on the
//! reference flight's procedural texture (or the height verification texture) in a private
//! directory, flies the flight against it through the shared mapping exactly as against any
//! `clipmapd`, and stops the service.

use crate::flight::{fly, FlightOptions, FlightReport};
use crate::gpu::Gpu;
use anyhow::{anyhow, Context, Result};
use clipmap::height::HeightFormat;
use clipmap::source::{HeightSource, TextureDesc, TileSource};
use std::os::unix::fs::DirBuilderExt;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

/// Runs the demo flight; the service lives only as long as the flight. `heights`: serve the
/// height verification texture (docs/ELEVATION.md) in this format, in the shape of the case's
/// texture, instead of the case's colour texture.
pub fn demo(gpu: &Gpu, o: &FlightOptions, heights: Option<HeightFormat>) -> Result<FlightReport> {
    let c = &o.case;
    let source: Arc<dyn TileSource> = match heights {
        Some(f) => {
            let desc = TextureDesc::new([c.size, c.size], c.clip_size, c.format, [c.tile, c.tile])
                .and_then(|d| d.with_invalid_border(c.invalid_border))
                .map_err(|e| anyhow!("the demo texture: {e}"))?;
            Arc::new(HeightSource::new(desc, f))
        }
        None => clipmap::accuracy::study::source(c).map_err(|e| anyhow!("the demo texture: {e}"))?,
    };
    with_service(source, "clipgpu-demo", |dir, name| fly(gpu, dir, name, o))
}

/// Serves `source` as the service `name` (the library's service, in this process, in a private
/// directory) while `f(directory, name)` runs, then stops it.
pub fn with_service<T>(source: Arc<dyn TileSource>, name: &str, f: impl FnOnce(&Path, &str) -> Result<T>) -> Result<T> {
    let dir = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::DirBuilder::new().mode(0o700).create(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut options = clipmap_service::Options::new(name);
    options.shm_dir = dir.clone();
    options.socket = clipmap_service::default_socket(&dir, name);
    options.tick_hz = 120.0;
    options.budget_ms = None;
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let thread_name = name.to_string();
    let service = std::thread::spawn(move || -> Result<()> {
        let name = thread_name;
        clipmap::runtime::block_on(clipmap_service::run(
            source,
            options,
            async {
                let _ = stop_rx.await;
            },
            move |_| {
                let _ = ready_tx.send(());
            },
        ))
        .with_context(|| format!("starting the service {name}'s runtime"))?
        .map_err(|e| anyhow!("the service {name}: {e}"))?;
        Ok(())
    });
    let result = match ready_rx.recv_timeout(Duration::from_secs(60)) {
        Ok(()) => f(&dir, name),
        Err(_) => Err(anyhow!("the service {name} did not start within 60 s")),
    };
    let _ = stop_tx.send(());
    let stopped = service.join().map_err(|_| anyhow!("the service {name} panicked"))?;
    let _ = std::fs::remove_dir_all(&dir);
    let report = result?;
    stopped?;
    Ok(report)
}
