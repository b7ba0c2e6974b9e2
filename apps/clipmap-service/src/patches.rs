//! Patch admission for a growing texture (docs/GROWING.md): `PATCH FILE` and `PATCH DATA` on the
//! control socket. A `PATCH DATA`'s announced bytes are admitted against the bounds first (its
//! size, the bytes all connections hold in flight), then read, decoded off the async workers,
//! handed to the grower, and answered once the patch is durable.

use super::protocol::Flow;
use super::ControlLimits;
use clipmap::growing::input::{self, InputError, Paths};
use clipmap::growing::serve::{GrowCommand, Grower, IN_FLIGHT_UNIT};
use std::path::PathBuf;
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio::sync::oneshot;

/// Why a patch was not taken: the text after `ERR`.
#[derive(Debug, thiserror::Error)]
pub enum PatchRefusal {
    /// The service's texture does not grow.
    #[error("PATCH: this service's texture does not grow (start clipmapd --growing DIR)")]
    NotGrowing,
    /// More bytes announced than one patch may have.
    #[error("PATCH DATA: {bytes} bytes announced; the most is {max} (--max-patch-bytes); closing")]
    TooBig {
        /// Bytes announced.
        bytes: u64,
        /// `--max-patch-bytes`.
        max: u64,
    },
    /// The bytes in flight, all connections together, stayed at their bound for the idle time.
    #[error("PATCH DATA: {bytes} bytes announced while the {max_in_flight} bytes of patches the service holds in flight at once (twice --max-patch-bytes) stayed taken for {idle_ms} ms; nothing was taken; try again later; closing")]
    InFlight {
        /// Bytes announced.
        bytes: u64,
        /// The bound on the bytes in flight.
        max_in_flight: u64,
        /// The idle time waited.
        idle_ms: u128,
    },
    /// The input ended before the announced bytes.
    #[error("PATCH DATA: {got} of {bytes} bytes arrived before the end of input; nothing was taken")]
    Short {
        /// Bytes that arrived.
        got: usize,
        /// Bytes announced.
        bytes: u64,
    },
    /// Reading the bytes failed.
    #[error("PATCH DATA: reading the bytes: {0}; nothing was taken")]
    Read(std::io::Error),
    /// The bytes did not arrive within the idle time.
    #[error("PATCH DATA: the bytes did not arrive within {idle_ms} ms; nothing was taken; closing")]
    Slow {
        /// The idle time.
        idle_ms: u128,
    },
    /// The patch (its sidecar, its image) is not usable.
    #[error("PATCH: {0}; nothing was taken")]
    Input(InputError),
    /// Decoding it stopped unexpectedly.
    #[error("PATCH: reading the patch failed unexpectedly; nothing was taken")]
    Decoding,
    /// The grower's queue is full, or it is gone.
    #[error("PATCH: the grower is busy or has stopped; try again")]
    GrowerBusy,
    /// The grower refused it (its message).
    #[error("PATCH: {0}; nothing was taken")]
    Grower(String),
    /// The grower stopped before answering.
    #[error("PATCH: the grower has stopped")]
    GrowerStopped,
    /// The grower did not answer in time.
    #[error("PATCH: the grower did not answer in time (the patch may still be taken)")]
    GrowerLate,
}

/// A patch as the socket brought it.
enum Patch {
    /// A sidecar file on the service's machine.
    File(PathBuf),
    /// A sidecar's text and the image's (or raw texels') bytes.
    Data(String, Vec<u8>),
}

/// `PATCH FILE <path>`: the patch id once it is durable. `grower` is the service's grower (none
/// when its texture does not grow); `limits` bound the wait for its answer.
pub(super) async fn file(grower: Option<&Grower>, limits: &ControlLimits, path: PathBuf) -> Result<u64, PatchRefusal> {
    let g = grower.ok_or(PatchRefusal::NotGrowing)?;
    take(g, limits, Patch::File(path)).await
}

/// `PATCH DATA <bytes> <json>`: admits the announced bytes, reads them from `rd` and takes the
/// patch. Every refusal before the bytes are read closes the connection (they are never read as
/// requests).
pub(super) async fn data(
    grower: Option<&Grower>,
    limits: &ControlLimits,
    rd: &mut (impl AsyncRead + Unpin),
    bytes: u64,
    json: String,
) -> (Result<u64, PatchRefusal>, Flow) {
    let Some(g) = grower else { return (Err(PatchRefusal::NotGrowing), Flow::Close) };
    if bytes > g.max_patch_bytes {
        return (Err(PatchRefusal::TooBig { bytes, max: g.max_patch_bytes }), Flow::Close);
    }
    let idle = limits.idle;
    // Every PATCH DATA in flight, all connections together, holds its share of the grower's
    // bound until its patch is decoded and handed over; one that cannot have it within the idle
    // time is refused. The buffer grows as bytes arrive, so an announced size that never comes
    // costs nothing.
    let share = bytes.div_ceil(IN_FLIGHT_UNIT) as u32;
    let Ok(Ok(permit)) = tokio::time::timeout(idle, g.in_flight.clone().acquire_many_owned(share)).await else {
        let refusal = PatchRefusal::InFlight { bytes, max_in_flight: g.max_in_flight_bytes, idle_ms: idle.as_millis() };
        return (Err(refusal), Flow::Close);
    };
    let mut data = Vec::with_capacity(bytes.min(64 << 10) as usize);
    let mut limited = rd.take(bytes);
    let read = limited.read_to_end(&mut data);
    match tokio::time::timeout(idle, read).await {
        Ok(Ok(n)) if n as u64 == bytes => {
            let taken = take(g, limits, Patch::Data(json, data)).await;
            drop(permit);
            (taken, Flow::Continue)
        }
        Ok(Ok(got)) => (Err(PatchRefusal::Short { got, bytes }), Flow::Close),
        Ok(Err(e)) => (Err(PatchRefusal::Read(e)), Flow::Close),
        Err(_) => (Err(PatchRefusal::Slow { idle_ms: idle.as_millis() }), Flow::Close),
    }
}

/// Reads and checks a patch (off the async workers: decoding is work), hands it to the grower and
/// waits for its answer: the patch's id once it is durable.
async fn take(g: &Grower, limits: &ControlLimits, p: Patch) -> Result<u64, PatchRefusal> {
    let decoding = g.clone();
    let new = tokio::task::spawn_blocking(move || decode(&decoding, p)).await.map_err(|_| PatchRefusal::Decoding)?;
    let new = new.map_err(PatchRefusal::Input)?;
    let (tx, rx) = oneshot::channel();
    if !g.send(GrowCommand::Add { patch: new, source: None, reply: tx }) {
        return Err(PatchRefusal::GrowerBusy);
    }
    // Keeping a patch syncs it to disk: allow longer than a tick command.
    match tokio::time::timeout(limits.reply_timeout * 6, rx).await {
        Ok(Ok(Ok(id))) => Ok(id),
        Ok(Ok(Err(e))) => Err(PatchRefusal::Grower(e)),
        Ok(Err(_)) => Err(PatchRefusal::GrowerStopped),
        Err(_) => Err(PatchRefusal::GrowerLate),
    }
}

/// A patch's sidecar and image read and checked against the grower's grid and bound.
fn decode(g: &Grower, p: Patch) -> Result<clipmap::growing::NewPatch, InputError> {
    let (grid, max) = (g.grid(), g.max_patch_bytes);
    match p {
        // The owner's own request: the sidecar's image may be anywhere it can read.
        Patch::File(path) => input::read_sidecar(&grid, &path, max, Paths::Anywhere),
        Patch::Data(json, bytes) => input::sidecar(json.as_bytes(), "the request")
            .and_then(|d| input::new_patch(&grid, &d, bytes, max, "the request")),
    }
}
