//! Every integration test in one binary: linking is most of a clean test run, so the tests are
//! modules of this crate rather than a binary each (as ripgrep gathers its own). Run one group
//! with `cargo test --test it cli_roam::`, one test by its name.
//!
//! Each module drives the real binaries (`CARGO_BIN_EXE_*`) or the library from a temporary
//! directory; `common` holds the shared helpers.

mod common;

mod api;
mod bc_edges;
mod bc_formats;
mod bc_prepared;
mod bc_readers;
mod bc_strict;
mod bc_views;
mod cli_attach;
mod cli_check;
mod cli_config;
mod cli_dump;
mod cli_dump_heights;
mod cli_roam;
mod cli_snapshots;
mod clipbench_cog;
mod clipbench_formats;
mod clipbench_growing;
mod clipbench_perf;
mod clipbench_policies;
mod clipbench_tiles;
mod clipbench_views;
mod clipmapd;
mod clipprep;
mod cog;
mod cog_config;
mod cog_masks;
mod cog_read_once;
#[cfg(feature = "remote")]
mod cog_remote;
mod cog_samples;
mod config_build_errors;
mod config_errors;
mod config_fuzz_props;
mod config_hostile;
mod config_ic_errors;
mod config_lexical;
mod config_paths;
mod config_plan;
mod config_tokens;
mod elevation;
mod examples;
mod fuzz_regressions;
mod georef;
mod georef_extremes;
mod georef_growing;
mod georef_prepared;
mod georef_wrap;
mod growing;
mod growing_service;
mod height_cracks;
mod hostile;
mod house;
mod patch_fuzz_props;
#[cfg(feature = "remote")]
mod remote;
#[cfg(feature = "remote")]
mod remote_flight;
#[cfg(feature = "remote")]
mod remote_h2;
mod shm_readers;
mod shm_room;
mod sixteen_bit;
mod stability;
mod tiff_fuzz_props;
mod tiff_hardening;
mod tiles;
mod tiles_archives;
mod tiles_cache;
mod tiles_faults;
mod tools_cog_names;
mod views_own;
mod views_restart;
