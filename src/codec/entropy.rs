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

    /// Compresses the `len` bytes `write` writes, without holding them: zstd's streaming
    /// encoder with the size pledged, so that the frame names its content size as
    /// [`Zstd::compress`]'s does and [`Zstd::decompress`] reads it the same way.
    pub fn compress_streamed(
        &self,
        len: usize,
        write: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
    ) -> Result<Vec<u8>> {
        if !(1..=22).contains(&self.level) {
            return Err(Error::input(format!(
                "zstd level {} is out of range [1, 22]",
                self.level
            )));
        }
        let failed = |e: std::io::Error| Error::Failure(format!("zstd compression failed: {e}"));
        let mut enc = zstd::stream::write::Encoder::new(Vec::new(), self.level).map_err(failed)?;
        enc.set_pledged_src_size(Some(len as u64)).map_err(failed)?;
        enc.include_contentsize(true).map_err(failed)?;
        // Level 19 is the one level whose binary-tree match finder gets a chain log (24)
        // above its window log (23): 64 MB of tree for inputs over 8 MB. Capped at the
        // window log it takes 32 MB, and the lossless streams of a 52 MB table, a MERL file
        // and a narrow-peak material come out 20–130 bytes smaller, not larger
        // (docs/benchmarks.md, "Lossless encode memory").
        if self.level == 19 {
            enc.set_parameter(zstd::zstd_safe::CParameter::ChainLog(23))
                .map_err(failed)?;
        }
        write(&mut enc).map_err(failed)?;
        enc.finish().map_err(failed)
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

    /// Decompresses exactly `out.len()` little-endian f32 values into `out`, through a
    /// 64 KiB buffer: no byte copy of the table's size is held beside the table (the peak
    /// memory of reading a `zstd_f32` file was file + bytes + values, 3.3× the table).
    pub fn decompress_f32_into(&self, b: &[u8], out: &mut [f32]) -> Result<()> {
        use std::io::Read;
        let want = out.len().saturating_mul(4);
        if want > MAX_STREAM {
            return Err(Error::input(format!("stream of {want} bytes is too large")));
        }
        let zstd_error = |e: std::io::Error| Error::input(format!("zstd payload: {e}"));
        let mut decoder = zstd::stream::read::Decoder::with_buffer(b).map_err(zstd_error)?;
        let mut buf = vec![0u8; 1 << 16];
        let mut done = 0usize;
        for chunk in out.chunks_mut(buf.len() / 4) {
            let bytes = &mut buf[..chunk.len() * 4];
            let mut filled = 0;
            while filled < bytes.len() {
                match decoder.read(&mut bytes[filled..]).map_err(zstd_error)? {
                    0 => {
                        return Err(Error::input(format!(
                            "payload decodes to {} bytes, expected {want}",
                            done + filled
                        )));
                    }
                    n => filled += n,
                }
            }
            done += filled;
            for (o, q) in chunk.iter_mut().zip(bytes.chunks_exact(4)) {
                *o = f32::from_le_bytes([q[0], q[1], q[2], q[3]]);
            }
        }
        if decoder.read(&mut buf[..1]).map_err(zstd_error)? != 0 {
            return Err(Error::input(format!(
                "payload decodes to more than the {want} bytes expected"
            )));
        }
        Ok(())
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

    #[test]
    fn f32_values_decode_in_place_and_wrong_lengths_are_refused() {
        let z = Zstd { level: 3 };
        let v: Vec<f32> = (0..40_000).map(|i| (i as f32).sqrt() - 50.0).collect();
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        let c = z.compress(&bytes).unwrap();
        let mut out = vec![0f32; v.len()];
        z.decompress_f32_into(&c, &mut out).unwrap();
        assert_eq!(out, v);
        let mut short = vec![0f32; v.len() - 1];
        assert!(z.decompress_f32_into(&c, &mut short).is_err());
        let mut long = vec![0f32; v.len() + 1];
        assert!(z.decompress_f32_into(&c, &mut long).is_err());
        let mut junk = c.clone();
        junk.extend_from_slice(b"junk");
        assert!(z.decompress_f32_into(&junk, &mut out).is_err());
    }
}
