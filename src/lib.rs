//! brdfpack: turn BRDFs into compact tables and back.
//!
//! The pipeline: a [`brdf::Brdf`] source (an analytic [`model::Model`], a measured file or a
//! stored table) is sampled on a [`grid::Grid`] into a [`table::Table`], encoded by a codec,
//! written in one of the [`io`] formats, read back, evaluated anywhere by interpolation and
//! checked against its source with the metrics of [`check`].

pub mod bench;
pub mod brdf;
pub mod check;
pub mod codec;
pub mod error;
pub mod geometry;
pub mod grid;
pub mod io;
pub mod math;
pub mod memory;
pub mod model;
pub mod pairs;
pub mod plan;
pub mod plot;
pub mod props;
pub mod reads;
pub mod simd;
pub mod source;
pub mod spectral;
pub mod table;
pub mod tabulate;
#[doc(hidden)]
pub mod testing;
pub mod text;

pub use error::{Error, Result};

/// The tool's name and version, recorded in every file it writes.
pub const TOOL_VERSION: &str = concat!("brdfpack ", env!("CARGO_PKG_VERSION"));
