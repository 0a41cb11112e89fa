//! Codecs: how a table's samples become the payload of a file and back.
//!
//! A codec is a chain of stages, each a small type with its own encode/decode and tests:
//! (1) [`domain`] — which cells are coded (invalid cells cost no bytes: the mask is implied by
//! the grid or stored beside the data); (2) [`transform`] — an optional cosine weight, a curve
//! (linear or log(ε + x)) and an optional colour decorrelation; (3) [`quantize`] — f32 (lossless), f16 or k-bit uniform;
//! (4) [`predict`] — residuals from grid neighbours, byte-plane shuffle; (5) [`entropy`] —
//! zstd, or for DCT coefficients [`coefcode`], a context-adaptive range coder; (6) [`dct`] —
//! transform coding of the whole table with quantized coefficients; (6b) [`tucker`] — a
//! truncated Tucker (HOSVD) low-rank decomposition with quantized factors and core; (6c)
//! [`residual`] — optionally after either, the quantized difference between the table and
//! what the decoder reconstructs, which bounds every sample's error.
//!
//! A [`CodecSpec`] is the fully resolved chain (every data-derived parameter written out) and
//! is recorded in the file header, so any file decodes with no flags. A [`CodecRequest`] is
//! what a user asks for (`--codec dct:step=0.02`); [`CodecRequest::resolve`] turns it into a
//! spec for a given table. [`search`] picks the smallest spec meeting an error budget.

pub mod coefcode;
pub mod dct;
pub mod domain;
pub mod eigen;
pub mod entropy;
mod header;
mod idct;
pub mod predict;
pub mod quantize;
#[doc(hidden)]
pub mod reference;
pub mod residual;
mod simd;
pub mod tensor;
pub mod transform;
pub mod tucker;
mod unpredict;

use crate::grid::{Grid, GridKind};
use crate::table::Table;
use crate::{Error, Result};
use domain::Domain;
use entropy::Zstd;
use predict::{Predictor, Shape};
use quantize::Quantizer;
use serde::{Deserialize, Serialize};
use transform::{Colour, Curve, Transform, Weight};

mod planes;
mod request;
mod scratch;
mod spec;
#[cfg(test)]
mod tests;

pub use planes::*;
pub use request::*;
pub use scratch::*;
pub use spec::*;
