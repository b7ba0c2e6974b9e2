//! The hostile-input suite: every way in from the outside world (names in shared directories,
//! files a configuration names, input images, numbers, writes, exit codes) tried the way a
//! hostile or careless local user would, against the real binaries. Each case is named after
//! what it attacks and asserts the exact outcome: the error text and exit code, the counted
//! fault, the untouched victim file, the running service still published. Every program run is
//! bounded (`common::exec_bounded`), so a regression to a hang fails instead of hanging.
//!
//! docs/RELIABILITY.md lists what is promised for each class; `bench/attack.sh` replays the
//! classes against the release binaries.

mod exits;
mod files;
mod growing;
mod images;
mod names;
mod numbers;
mod service;
mod writes;
