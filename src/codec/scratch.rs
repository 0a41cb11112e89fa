//! Working arrays the transform decoders reuse across decodes.

/// Working arrays of the transform decoders, reusable across decodes
/// ([`super::CodecSpec::decode_into_with`]); arrays grow to the largest size asked for and are kept.
#[derive(Debug, Default)]
pub struct DecodeScratch {
    f32s: Vec<Vec<f32>>,
    i32s: Vec<Vec<i32>>,
    /// Arrays given back are freed, not kept: for one decode, whose peak is then its
    /// largest step rather than every array it ever used (a 64⁴ RGB table: the three
    /// components' codes and each component's second intermediate, 400 MB, are gone
    /// before the next component is expanded).
    lean: bool,
}

impl DecodeScratch {
    /// A scratch for a single decode: nothing is kept for a next one.
    pub fn lean() -> DecodeScratch {
        DecodeScratch {
            lean: true,
            ..DecodeScratch::default()
        }
    }

    /// True for a [`DecodeScratch::lean`] one: the decoders then also work in place.
    pub(crate) fn is_lean(&self) -> bool {
        self.lean
    }

    /// At least `n` long, contents unspecified (every user writes what it reads).
    pub(crate) fn take_f32(&mut self, n: usize) -> Vec<f32> {
        let mut v = self.f32s.pop().unwrap_or_default();
        Self::grow(&mut v, n);
        v
    }

    pub(crate) fn give_f32(&mut self, v: Vec<f32>) {
        if !self.lean && v.capacity() > 0 {
            self.f32s.push(v);
        }
    }

    /// Exactly `n` zeros.
    pub(crate) fn take_i32_zeroed(&mut self, n: usize) -> Vec<i32> {
        match self.i32s.pop() {
            // As in `grow`: a fresh array comes zeroed from the allocator.
            None => vec![0; n],
            Some(mut v) => {
                v.clear();
                v.resize(n, 0);
                v
            }
        }
    }

    pub(crate) fn give_i32(&mut self, v: Vec<i32>) {
        if !self.lean && v.capacity() > 0 {
            self.i32s.push(v);
        }
    }

    /// `v` at least `n` long; it never shrinks, so a reused array is not written again.
    pub(crate) fn grow(v: &mut Vec<f32>, n: usize) {
        if v.capacity() == 0 {
            // A fresh array through the allocator's zeroed path: large ones are new pages,
            // already zero, where `resize` wrote every value (17 MB, ~2 ms, for the
            // intermediate of a MERL table decoded with a fresh scratch).
            *v = vec![0.0; n];
            crate::memory::advise_huge_pages(v);
        } else if v.len() < n {
            v.resize(n, 0.0);
        }
    }
}
