//! Stage (5), entropy: zstd at a recorded level.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Largest decoded stream accepted (a MERL RGB table is 17.5 MB; 4D grids may be larger).
pub const MAX_STREAM: usize = 1 << 34;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub struct Zstd {
    pub level: i32,
}

impl Zstd {
    pub fn compress(&self, b: &[u8]) -> Result<Vec<u8>> {
        if !(1..=22).contains(&self.level) {
            return Err(Error::input(format!(
                "zstd level {} is out of range [1, 22]",
                self.level
            )));
        }
        zstd::bulk::compress(b, self.level)
            .map_err(|e| Error::Failure(format!("zstd compression failed: {e}")))
    }

    /// Decompresses exactly `want` bytes (a hostile payload cannot ask for more).
    pub fn decompress(&self, b: &[u8], want: usize) -> Result<Vec<u8>> {
        if want > MAX_STREAM {
            return Err(Error::input(format!("stream of {want} bytes is too large")));
        }
        let raw = zstd::bulk::decompress(b, want)
            .map_err(|e| Error::input(format!("zstd payload: {e}")))?;
        if raw.len() != want {
            return Err(Error::input(format!(
                "payload decodes to {} bytes, expected {want}",
                raw.len()
            )));
        }
        Ok(raw)
    }

    /// Decompresses a stream of unknown length up to `cap` bytes.
    pub fn decompress_capped(&self, b: &[u8], cap: usize) -> Result<Vec<u8>> {
        zstd::bulk::decompress(b, cap.min(MAX_STREAM))
            .map_err(|e| Error::input(format!("zstd payload: {e}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_refuses_wrong_lengths() {
        let z = Zstd { level: 3 };
        let b: Vec<u8> = (0..1000u32).map(|i| (i % 7) as u8).collect();
        let c = z.compress(&b).unwrap();
        assert!(c.len() < 100);
        assert_eq!(z.decompress(&c, 1000).unwrap(), b);
        assert!(z.decompress(&c, 999).is_err());
        assert!(z.decompress(&c, 1001).is_err());
        assert!(Zstd { level: 0 }.compress(&b).is_err());
    }
}
