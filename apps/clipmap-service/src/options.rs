//! The service's run-time options (what the command line resolved to) and the control socket's
//! bounds, checked once before anything starts.
//!
//! Owns defaults and validation only; reading a command line is the binary's business.

use super::ServiceError;
use clipmap::limits::{MAX_CONNECTIONS, MAX_IDLE_MS, MIN_BUDGET_MS};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Bounds of the control socket: every resource a client can make the service hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ControlLimits {
    /// Longest request line in bytes (without its newline); a longer one closes the connection.
    pub max_line: usize,
    /// Most connections open at once; more are answered `ERR` and closed.
    pub max_connections: usize,
    /// A connection that sends no complete line for this long is closed.
    pub idle: Duration,
    /// Longest wait for the tick loop to answer a command.
    pub reply_timeout: Duration,
}

impl Default for ControlLimits {
    fn default() -> Self {
        ControlLimits {
            max_line: 4096,
            max_connections: 64,
            idle: Duration::from_secs(30),
            reply_timeout: Duration::from_secs(5),
        }
    }
}

/// How to run one service.
#[derive(Clone, Debug)]
pub struct Options {
    /// Publication name (the mapping is `clipmap-<name>.map` in `shm_dir`).
    pub name: String,
    /// Directory of the mapping and its lock file.
    pub shm_dir: PathBuf,
    /// Path of the control socket.
    pub socket: PathBuf,
    /// Permission bits of the mapping (0o600: owner only).
    pub shm_mode: u32,
    /// Permission bits of the request mapping (`None`: the same as `shm_mode`).
    pub request_mode: Option<u32>,
    /// Copy budget per tick in milliseconds (`None`: unlimited).
    pub budget_ms: Option<f64>,
    /// Update ticks per second.
    pub tick_hz: f64,
    /// Invalid border to start with (`None`: the texture's).
    pub invalid_border: Option<u64>,
    /// Level centres aligned to multiples of this many level texels (1: texel-exact; see
    /// [`clipmap::clip::Settings::centre_alignment`]).
    pub centre_alignment: u64,
    /// Paging policies, the second-level pool's budget and the centre clamp.
    pub paging: clipmap::paging::PagingOptions,
    /// Control socket bounds.
    pub control: ControlLimits,
    /// A growing texture's grower (docs/GROWING.md): the service then replaces rebuilt tiles in
    /// their slots, publishes the growth block, and takes patches on the control socket.
    pub growing: Option<clipmap::growing::serve::Grower>,
    /// Further views to start with (docs/VIEWS.md).
    pub views: Vec<ViewOption>,
    /// Level-0 texels by which views may lie apart and all be held whole by the shared grids
    /// ([`clipmap::clip::Settings::view_spread`]; 0: grids for one view).
    pub view_spread: u64,
    /// Levels every view addresses at once, from its LOD offset (Performer's effective levels;
    /// `None`: all). A `.ct` that writes `effective_levels` below its level count gives it.
    pub effective_levels: Option<u32>,
}

/// The default control socket of a name: `clipmap-<name>.sock` beside the mapping.
pub fn default_socket(shm_dir: &Path, name: &str) -> PathBuf {
    shm_dir.join(format!("clipmap-{name}.sock"))
}

impl Options {
    /// Defaults for `name`: mapping in [`clipmap::shm::default_dir`], socket beside it, owner-only,
    /// 6 ms budget, 60 ticks per second.
    pub fn new(name: &str) -> Options {
        let shm_dir = clipmap::shm::default_dir();
        Options {
            name: name.to_string(),
            socket: default_socket(&shm_dir, name),
            shm_dir,
            shm_mode: 0o600,
            request_mode: None,
            budget_ms: Some(6.0),
            tick_hz: 60.0,
            invalid_border: None,
            centre_alignment: 1,
            paging: clipmap::paging::PagingOptions::default(),
            control: ControlLimits::default(),
            growing: None,
            views: Vec::new(),
            view_spread: 0,
            effective_levels: None,
        }
    }

    /// Checks every value; the error says which option and what was expected.
    pub fn check(&self) -> Result<(), ServiceError> {
        let bad = |m: String| Err(ServiceError::BadOption(m));
        clipmap::shm::check_name(&self.name).map_err(|e| ServiceError::BadOption(e.to_string()))?;
        if self.name.contains('@') {
            return bad(format!(
                "--name {}: `@` is kept for the mappings of views with grids of their own (NAME@VIEW, docs/SHM.md); choose a name without it",
                self.name
            ));
        }
        for (i, ViewOption { name, weight, .. }) in self.views.iter().enumerate() {
            clipmap::shm::layout::views::check_name(name)
                .map_err(|e| ServiceError::BadOption(format!("--view {name}: {e}")))?;
            if !(weight.is_finite() && *weight > 0.0) {
                return bad(format!("--view {name}:{weight}: expected a positive finite weight such as 1 or 3"));
            }
            if self.views[..i].iter().any(|v| &v.name == name) {
                return bad(format!("--view {name} given twice: each view needs its own name"));
            }
        }
        if self.views.len() >= clipmap::limits::MAX_VIEWS {
            return bad(format!(
                "{} --view options: at most {} views besides main",
                self.views.len(),
                clipmap::limits::MAX_VIEWS - 1
            ));
        }
        if self.view_spread > clipmap::limits::MAX_TEXTURE_SIZE {
            return bad(format!(
                "--view-spread {}: expected 0 to {} level-0 texels",
                self.view_spread,
                clipmap::limits::MAX_TEXTURE_SIZE
            ));
        }
        if !(self.tick_hz.is_finite() && self.tick_hz >= 1.0 && self.tick_hz <= 1000.0) {
            return bad(format!("--tick-hz {}: expected 1 to 1000 ticks per second", self.tick_hz));
        }
        if !(1..=clipmap::clip::MAX_CENTRE_ALIGNMENT).contains(&self.centre_alignment) {
            return bad(format!(
                "--centre-alignment {}: expected 1 (texel-exact centres) to {} level texels",
                self.centre_alignment,
                clipmap::clip::MAX_CENTRE_ALIGNMENT
            ));
        }
        if let Some(ms) = self.budget_ms {
            if !((MIN_BUDGET_MS..=super::protocol::MAX_BUDGET_MS).contains(&ms)) {
                return bad(format!(
                    "--budget-ms {ms}: expected at least {MIN_BUDGET_MS} (MIN_BUDGET_MS; less rounds to no work) and at most {} milliseconds, or `off`",
                    super::protocol::MAX_BUDGET_MS
                ));
            }
        }
        if self.shm_mode & !0o666 != 0 || self.shm_mode & 0o600 != 0o600 {
            return bad(format!(
                "--shm-mode {:o}: expected read-write for the owner and no execute bits (e.g. 600, 640, 660)",
                self.shm_mode
            ));
        }
        if let Some(m) = self.request_mode {
            if m & !0o666 != 0 || m & 0o600 != 0o600 {
                return bad(format!(
                    "--request-mode {m:o}: expected read-write for the owner and no execute bits (e.g. 600, 660)"
                ));
            }
        }
        // sockaddr_un holds 108 bytes including the terminating NUL.
        if self.socket.as_os_str().len() > 100 {
            return bad(format!("--socket {}: paths longer than 100 bytes cannot be bound", self.socket.display()));
        }
        if !self.shm_dir.is_dir() {
            return bad(format!("--shm-dir {}: not a directory", self.shm_dir.display()));
        }
        if self.growing.is_some() && self.paging.pool_bytes > 0 {
            return bad(format!(
                "--pool-bytes {}: a growing texture's tiles change as patches arrive, and a pool would serve old ones; leave the pool off",
                self.paging.pool_bytes
            ));
        }
        let c = &self.control;
        if c.max_connections == 0 || c.max_connections > MAX_CONNECTIONS {
            return bad(format!(
                "--max-connections {}: expected 1 to {MAX_CONNECTIONS} (MAX_CONNECTIONS)",
                c.max_connections
            ));
        }
        if c.idle.is_zero() || c.idle.as_millis() > MAX_IDLE_MS as u128 {
            return bad(format!(
                "--idle-ms {}: expected 1 to {MAX_IDLE_MS} (MAX_IDLE_MS, one day)",
                c.idle.as_millis()
            ));
        }
        if c.max_line < 16 || c.max_line > 1 << 20 || c.reply_timeout.is_zero() {
            return bad(format!(
                "control limits {c:?}: expected a line limit of 16 bytes to 1 MiB and a reply timeout"
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clipmap::paging::{PagingOptions, PrefetchKind};

    /// `clipmapd` and the GPU client's demo service (`clipgpu --demo`) start from these
    /// defaults: both page adaptively unless told otherwise.
    #[test]
    fn the_default_service_pages_adaptively() {
        let o = Options::new("x");
        assert_eq!(o.paging, PagingOptions::default());
        assert_eq!(o.paging.prefetch, PrefetchKind::Adaptive);
        let settings = clipmap::clip::Settings::default().with_paging(&o.paging);
        assert_eq!(settings.prefetch, PrefetchKind::Adaptive);
        assert_eq!(settings.grid_budget, None, "the default budget");
    }
}

/// A view to start with (`--view NAME[:WEIGHT][:own]`, docs/VIEWS.md).
#[derive(Clone, Debug, PartialEq)]
pub struct ViewOption {
    /// Its name.
    pub name: String,
    /// Its weight.
    pub weight: f64,
    /// Whether it has grids of its own, in a mapping of its own (docs/VIEWS.md, "Views far
    /// apart"), rather than a share of the primary's.
    pub own: bool,
}
