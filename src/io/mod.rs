//! File formats (native, RGL, ...) and output handling.

pub mod atomic;
pub mod native;
pub mod rgl;
