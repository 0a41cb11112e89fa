//! File formats and output handling.

pub mod atomic;
pub mod native;
