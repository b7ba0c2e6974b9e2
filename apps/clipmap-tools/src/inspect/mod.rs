//! Looking at a running service from outside, as any client does: `cliptex attach` (the live
//! view from the mapping plus the control socket's typed statistics) and `cliptex dump --attach`
//! (pictures of every published level).
//!
//! This is the top of the stack: it reads the mapping through [`clipmap::shm::Client`], asks the
//! control socket of [`clipmap_service`] and draws with [`clipmap::report`]. Nothing below it
//! depends on it; [`clipmap::report`] (formatting and drawing) sits below the service.

pub mod attach;
pub mod live_dump;
