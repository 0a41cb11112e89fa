//! Stage (5), context entropy coding of quantized DCT coefficients (the `dct` codec's
//! `coding=context`): an adaptive binary range coder with contexts on the coefficient's
//! frequency band and its already-coded neighbours.
//!
//! The box of a component (C order, as [`dct::quantize`] stores it) is a set of lines along its
//! last axis. In the current model ([`ContextModel::LineEnds`]) each line, in C order, first
//! codes its end (1 + the position of its last nonzero, 0 when empty): an empty flag (context:
//! whether the lines one step back along the last-but-one axis and along the others are missing,
//! empty or not), then the end relative to the prediction p = the largest end of those lines
//! (p = 0: end − 1 in exp-Golomb; else a flag "end = p", a direction flag where both are
//! possible, |end − p| − 1 in exp-Golomb; contexts on ⌊log2 p⌋). Only the positions before
//! the end are coded, each as: a zero flag (implied nonzero at the last one); for a nonzero,
//! its sign and |q| in an exp-Golomb-like binarization (unary exponent with contexts, the
//! leading mantissa bit with a context, the rest at ½). Contexts: component (first, second,
//! rest), band = ⌊log2(1 + Σ frequency indices)⌋, and the magnitudes of the neighbours one step
//! back along every axis (coded before it in C order; those past their line's end are 0). The
//! first model ([`ContextModel::EveryPosition`], files written before line ends) codes every
//! position of the box this way, without ends; its stream starts with byte 0, the line-end
//! model's with 1. The current model ([`ContextModel::LineEndsWide`], `line_ends2`, byte 2) is
//! the line-end model with wider contexts and faster adaptation: zero flags also see the
//! magnitudes of the neighbours two steps back along every axis (four buckets), signs the
//! signs of left, back, up and left two steps back (81 contexts instead of 9), and each
//! context's estimators move 2^-3 and 2^-5 of the way instead of 2^-4 and 2^-7 (18.7% smaller
//! streams on the budget rows, 1–18% smaller `pack` files; docs/compression.md "Second
//! neighbours").
//!
//! The coder is the LZMA range coder (Pavlov, 7-Zip `LzmaEnc.c`) with 16-bit probabilities,
//! each context the average of a fast and a slow estimator: integer arithmetic only, so the
//! bytes are the same on every machine. Typical gain over varints + zstd on smooth BRDF tables:
//! 1.4–2× at the same coefficients (docs/compression.md); line ends save 0–17% more on the
//! budget tables (3.1% in all) and let the decoder skip the positions after them (it visits
//! 70,019 of gold-metallic-paint production's 1,586,962).

use super::DecodeScratch;
use super::dct::{self, Coefficients};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Parameters of context coding recorded in the header (the decoder needs none of them: they
/// say how the coefficients were chosen).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContextCoding {
    /// Dead zone in steps: coefficients with |c| < deadzone × step are coded as 0.
    pub deadzone: f64,
    /// How the stream is laid out. Headers written before the field existed lack it and are
    /// the first model ([`ContextModel::EveryPosition`]).
    #[serde(default, skip_serializing_if = "ContextModel::is_every_position")]
    pub model: ContextModel,
}

/// The layout of the range-coded stream (the contexts of the coded positions are the same in
/// both).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ContextModel {
    /// Every position of every box coded (files written before line ends).
    #[default]
    EveryPosition,
    /// Each line along the last axis first codes where it ends; positions after its last
    /// nonzero are not coded (they are zero), the last one's zero flag is implied.
    LineEnds,
    /// [`ContextModel::LineEnds`] with wider contexts and faster adaptation (files written
    /// since 2026-12-07): zero flags also see the neighbours two steps back along every axis,
    /// signs the signs of left, back, up and left two steps back, and the contexts adapt with
    /// the shifts [`FAST_WIDE`], [`SLOW_WIDE`] (module doc). Named `line_ends2` in headers:
    /// every byte counts in a preview file of 700 B.
    #[serde(rename = "line_ends2")]
    LineEndsWide,
}

impl ContextModel {
    /// The model new files are written in.
    pub const CURRENT: ContextModel = ContextModel::LineEndsWide;

    /// The old model is not written: a spec in it serializes to the very header the old
    /// binary wrote.
    fn is_every_position(&self) -> bool {
        *self == ContextModel::EveryPosition
    }

    /// The first byte of the range-coded stream. The range encoder always writes 0 there, so
    /// the byte is free to name the model: a reader that predates line ends refuses the
    /// stream ("bad range coder preamble") instead of decoding it with the wrong model.
    fn preamble(self) -> u8 {
        match self {
            ContextModel::EveryPosition => 0,
            ContextModel::LineEnds => 1,
            ContextModel::LineEndsWide => 2,
        }
    }

    /// The contexts' adaptation shifts (fast, slow).
    fn rates(self) -> (u32, u32) {
        match self {
            ContextModel::EveryPosition | ContextModel::LineEnds => (FAST, SLOW),
            ContextModel::LineEndsWide => (FAST_WIDE, SLOW_WIDE),
        }
    }

    /// Whether the zero flags' contexts hold the second neighbours.
    fn is_wide(self) -> bool {
        self == ContextModel::LineEndsWide
    }
}

/// Default dead zone (steps): a little more than rounding's 0.5 trades a small error for many
/// fewer nonzero coefficients (their zero flags are nearly free).
pub const DEFAULT_DEADZONE: f64 = 0.75;
/// Accepted dead-zone range (steps).
pub const DEADZONE_RANGE: (f64, f64) = (0.5, 4.0);

impl ContextCoding {
    /// Context coding with dead zone `deadzone` in the current model (what new files use).
    pub fn new(deadzone: f64) -> ContextCoding {
        ContextCoding {
            deadzone,
            model: ContextModel::CURRENT,
        }
    }

    pub fn validate(&self) -> Result<()> {
        let (lo, hi) = DEADZONE_RANGE;
        if !(lo..=hi).contains(&self.deadzone) {
            return Err(Error::input(format!(
                "dct dead zone {}: expected {lo}..={hi} steps",
                crate::model::params::fmt_num(self.deadzone)
            )));
        }
        Ok(())
    }
}

/// Probability precision (bits) and the two adaptation rates (shifts) of the first two
/// models.
const PROB_BITS: u32 = 16;
const PROB_ONE: u32 = 1 << PROB_BITS;
const FAST: u32 = 4;
const SLOW: u32 = 7;
/// The adaptation rates of [`ContextModel::LineEndsWide`]: faster. A box's statistics change
/// along the scan (low-frequency lines first), and its many contexts must be learned from
/// few symbols; measured (docs/compression.md, "Second neighbours").
const FAST_WIDE: u32 = 3;
const SLOW_WIDE: u32 = 5;
/// Renormalize when the range drops below 2^24 (one byte of headroom, as LZMA).
const TOP: u32 = 1 << 24;

/// One adaptive binary context: two estimates of P(bit = 0) in units of 2^-16.
#[derive(Clone, Copy, Debug)]
struct Ctx {
    fast: u16,
    slow: u16,
}

impl Default for Ctx {
    fn default() -> Self {
        Ctx {
            fast: (PROB_ONE / 2) as u16,
            slow: (PROB_ONE / 2) as u16,
        }
    }
}

impl Ctx {
    /// P(0), never 0 or 1: each estimate stays in [2^r − 1, 2^16 − 2^r + 1] (the update stalls
    /// there), so the average does too.
    #[inline]
    fn p0(&self) -> u32 {
        (self.fast as u32 + self.slow as u32) >> 1
    }
    /// Moves both estimates towards `bit`, by 2^-fast and 2^-slow of the way (shifts of at
    /// least 2: an estimate never reaches 0 or 2^16).
    #[inline]
    fn update(&mut self, bit: bool, (fast, slow): (u32, u32)) {
        let (f, s) = (self.fast as u32, self.slow as u32);
        if bit {
            self.fast = (f - (f >> fast)) as u16;
            self.slow = (s - (s >> slow)) as u16;
        } else {
            self.fast = (f + ((PROB_ONE - f) >> fast)) as u16;
            self.slow = (s + ((PROB_ONE - s) >> slow)) as u16;
        }
    }
}

/// LZMA-style range encoder (carry propagation through a cached byte and a run of 0xFF).
pub struct RangeEncoder {
    low: u64,
    range: u32,
    cache: u8,
    cache_size: u64,
    out: Vec<u8>,
    /// The contexts' adaptation shifts (fast, slow).
    rates: (u32, u32),
}

impl Default for RangeEncoder {
    fn default() -> Self {
        Self::new()
    }
}

impl RangeEncoder {
    pub fn new() -> RangeEncoder {
        RangeEncoder {
            low: 0,
            range: u32::MAX,
            cache: 0,
            cache_size: 1,
            out: Vec::new(),
            rates: (FAST, SLOW),
        }
    }

    /// An encoder whose contexts adapt as `model`'s do.
    fn for_model(model: ContextModel) -> RangeEncoder {
        RangeEncoder {
            rates: model.rates(),
            ..RangeEncoder::new()
        }
    }

    fn shift_low(&mut self) {
        if (self.low as u32) < 0xFF00_0000 || (self.low >> 32) != 0 {
            let carry = (self.low >> 32) as u8;
            let mut temp = self.cache;
            loop {
                self.out.push(temp.wrapping_add(carry));
                temp = 0xFF;
                self.cache_size -= 1;
                if self.cache_size == 0 {
                    break;
                }
            }
            self.cache = ((self.low as u32) >> 24) as u8;
        }
        self.cache_size += 1;
        self.low = ((self.low as u32) << 8) as u64;
    }

    #[inline]
    fn encode_p0(&mut self, p0: u32, bit: bool) {
        let bound = (self.range >> PROB_BITS) * p0;
        if bit {
            self.low += bound as u64;
            self.range -= bound;
        } else {
            self.range = bound;
        }
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    #[inline]
    fn encode(&mut self, ctx: &mut Ctx, bit: bool) {
        self.encode_p0(ctx.p0(), bit);
        ctx.update(bit, self.rates);
    }

    /// A bit at probability ½ (no context).
    #[inline]
    fn encode_direct(&mut self, bit: bool) {
        self.encode_p0(PROB_ONE / 2, bit);
    }

    pub fn finish(mut self) -> Vec<u8> {
        for _ in 0..5 {
            self.shift_low();
        }
        self.out
    }
}

/// The matching decoder. Reading past the end yields zero bytes (a truncated stream decodes to
/// something wrong, caught by the caller's end check, never to a panic).
pub struct RangeDecoder<'a> {
    code: u32,
    range: u32,
    input: &'a [u8],
    pos: usize,
    /// The contexts' adaptation shifts (fast, slow).
    rates: (u32, u32),
}

impl<'a> RangeDecoder<'a> {
    pub fn new(input: &'a [u8]) -> Result<RangeDecoder<'a>> {
        Self::with_preamble(input, ContextModel::EveryPosition)
    }

    /// A decoder of a stream in `model`: its first byte is the model's
    /// ([`ContextModel::preamble`]), its contexts adapt as the model's do.
    fn with_preamble(input: &'a [u8], model: ContextModel) -> Result<RangeDecoder<'a>> {
        let preamble = model.preamble();
        if input.len() < 5 || input[0] != preamble {
            return Err(Error::input(
                "context-coded DCT stream: missing or bad range coder preamble",
            ));
        }
        let code = u32::from_be_bytes([input[1], input[2], input[3], input[4]]);
        Ok(RangeDecoder {
            code,
            range: u32::MAX,
            input,
            pos: 5,
            rates: model.rates(),
        })
    }

    #[inline]
    fn next_byte(&mut self) -> u32 {
        let b = self.input.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        b as u32
    }

    #[inline]
    fn decode_p0(&mut self, p0: u32) -> bool {
        let bound = (self.range >> PROB_BITS) * p0;
        let bit = if self.code < bound {
            self.range = bound;
            false
        } else {
            self.code -= bound;
            self.range -= bound;
            true
        };
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | self.next_byte();
        }
        bit
    }

    #[inline]
    fn decode(&mut self, ctx: &mut Ctx) -> bool {
        let bit = self.decode_p0(ctx.p0());
        ctx.update(bit, self.rates);
        bit
    }

    #[inline]
    fn decode_direct(&mut self) -> bool {
        self.decode_p0(PROB_ONE / 2)
    }

    /// True when the decoder read no more than the stream holds (the encoder's 5 flush bytes
    /// cover every bit it wrote).
    pub fn within_input(&self) -> bool {
        self.pos <= self.input.len()
    }
}

/// Context-model sizes.
const COMP_CLASSES: usize = 3;
const BANDS: usize = 12;
const NBR_BUCKETS: usize = 9;
/// Buckets of the second neighbours' magnitude sum ([`ContextModel::LineEndsWide`]; the
/// other models use bucket 0 only).
const NB2_BUCKETS: usize = 4;
const UNARY_POS: usize = 16;
/// Largest exponent of |q| (dct::quantize clamps |q| to 2^30).
const MAX_EXP: u32 = 31;

/// Neighbour magnitude sum → bucket.
#[inline]
const fn nbr_bucket(m: u32) -> usize {
    match m {
        0 => 0,
        1 => 1,
        2 => 2,
        3..=4 => 3,
        5..=8 => 4,
        9..=16 => 5,
        17..=48 => 6,
        49..=256 => 7,
        _ => 8,
    }
}

/// Second-neighbour magnitude sum → bucket.
#[inline]
const fn nb2_bucket(m: u32) -> usize {
    match m {
        0 => 0,
        1 => 1,
        2..=3 => 2,
        _ => 3,
    }
}

/// Sign contexts of [`ContextModel::LineEndsWide`]: the signs of the neighbours one step back
/// along the last, the first and the last-but-one axis and two steps back along the last
/// (3⁴; the first two models use the first 9: the signs one step back along the last and the
/// first axis).
const WIDE_SIGN_CONTEXTS: usize = 81;

/// The sign context of [`ContextModel::LineEndsWide`] from the neighbours' signs + 1 (0, 1,
/// 2): left, back, up, and left two steps back. A smooth component's DCT coefficients keep
/// or alternate their signs along each axis (a ramp's are all of one sign at odd
/// frequencies), so a neighbour two steps back, of the same parity, predicts the sign well.
/// The second neighbours along the other axes too (3⁶ contexts) made files larger: the
/// coder learns 729 contexts too slowly (docs/compression.md, "Second neighbours").
#[inline]
fn wide_signs(s: [usize; 4]) -> usize {
    s.iter().fold(0, |acc, &x| acc * 3 + x)
}

/// All contexts of the model.
struct Model {
    zero: Vec<Ctx>,
    sign: Vec<Ctx>,
    unary: Vec<Ctx>,
    mantissa: Vec<Ctx>,
    line: LineModel,
}

impl Model {
    fn new() -> Model {
        Model {
            zero: vec![Ctx::default(); COMP_CLASSES * BANDS * NBR_BUCKETS * NB2_BUCKETS],
            sign: vec![Ctx::default(); COMP_CLASSES * WIDE_SIGN_CONTEXTS],
            unary: vec![Ctx::default(); COMP_CLASSES * NBR_BUCKETS * UNARY_POS],
            mantissa: vec![Ctx::default(); COMP_CLASSES * (MAX_EXP as usize + 1)],
            line: LineModel::new(),
        }
    }
}

/// Line-end model sizes: the states of the neighbouring lines (the one a step back along the
/// last-but-one axis, "up", and those a step back along the other axes, "back": each missing,
/// empty or not), the buckets of the predicted end, the unary positions of an end's exponent.
const LINE_STATES: usize = 9;
const END_BUCKETS: usize = 8;
const END_UNARY: usize = 16;
/// Largest exponent of an end difference's exp-Golomb code the decoder accepts: 2^40 is far
/// beyond any extent, and keeps the arithmetic in u64.
const MAX_END_EXP: u32 = 40;
/// The three exp-Golomb codes of a line end: no nonempty neighbour (end − 1), longer than the
/// prediction (end − pred − 1), shorter (pred − end − 1).
const FRESH: usize = 0;
const LONGER: usize = 1;
const SHORTER: usize = 2;

/// The contexts of the line ends.
struct LineModel {
    empty: Vec<Ctx>,
    same: Vec<Ctx>,
    longer: Vec<Ctx>,
    unary: Vec<Ctx>,
    mantissa: Vec<Ctx>,
}

impl LineModel {
    fn new() -> LineModel {
        LineModel {
            empty: vec![Ctx::default(); COMP_CLASSES * LINE_STATES],
            same: vec![Ctx::default(); COMP_CLASSES * END_BUCKETS],
            longer: vec![Ctx::default(); COMP_CLASSES * END_BUCKETS],
            unary: vec![Ctx::default(); COMP_CLASSES * 3 * END_UNARY],
            mantissa: vec![Ctx::default(); COMP_CLASSES * 3 * (MAX_END_EXP as usize + 1)],
        }
    }
}

/// What a line's end is coded with: the neighbour state (context of the empty flag) and the
/// prediction, the largest end of the neighbouring lines (0: none is nonempty).
#[derive(Clone, Copy, Debug)]
struct LineNbrs {
    state: usize,
    pred: usize,
}

impl LineNbrs {
    /// From the ends of the "up" and "back" neighbours (`None`: no such line).
    #[inline]
    fn new(up: Option<u32>, back: Option<u32>) -> LineNbrs {
        let st = |e: Option<u32>| e.map_or(0, |e| 1 + (e > 0) as usize);
        LineNbrs {
            state: st(up) * 3 + st(back),
            pred: up.unwrap_or(0).max(back.unwrap_or(0)) as usize,
        }
    }

    /// The neighbours of line `r` at outer index `outer` (the box's index without its last
    /// axis; `strides` in lines), from the ends of the lines before it.
    fn generic(outer: &[usize], strides: &[usize], r: usize, ends: &[u32]) -> LineNbrs {
        let k = outer.len();
        let up = (k >= 1 && outer[k - 1] > 0).then(|| ends[r - strides[k - 1]]);
        let back = (0..k.saturating_sub(1))
            .filter(|&a| outer[a] > 0)
            .map(|a| ends[r - strides[a]])
            .max();
        LineNbrs::new(up, back)
    }
}

/// ⌊log2 pred⌋ capped (pred ≥ 1).
#[inline]
fn end_bucket(pred: usize) -> usize {
    (pred.ilog2() as usize).min(END_BUCKETS - 1)
}

impl LineModel {
    /// `v` ≥ 0 as exp-Golomb (v + 1: unary exponent with contexts, the leading mantissa bit
    /// with a context, the rest at ½) in the code `kind` of component class `cc`.
    fn encode_eg(&mut self, rc: &mut RangeEncoder, cc: usize, kind: usize, v: u64) {
        let base = cc * 3 + kind;
        encode_golomb(
            rc,
            &mut self.unary[base * END_UNARY..(base + 1) * END_UNARY],
            &mut self.mantissa
                [base * (MAX_END_EXP as usize + 1)..(base + 1) * (MAX_END_EXP as usize + 1)],
            v + 1,
        );
    }

    fn decode_eg(&mut self, rc: &mut RangeDecoder, cc: usize, kind: usize) -> Result<u64> {
        let base = cc * 3 + kind;
        let v = decode_golomb(
            rc,
            &mut self.unary[base * END_UNARY..(base + 1) * END_UNARY],
            &mut self.mantissa
                [base * (MAX_END_EXP as usize + 1)..(base + 1) * (MAX_END_EXP as usize + 1)],
            MAX_END_EXP,
        )
        .ok_or_else(|| Error::input("context-coded DCT stream: line end beyond 2^40"))?;
        Ok(v - 1)
    }

    /// A line's end (1 + the position of its last nonzero, 0 for an empty line) of a line of
    /// `n` positions: an empty flag, then the end relative to the prediction.
    fn encode_end(&mut self, rc: &mut RangeEncoder, cc: usize, nb: LineNbrs, end: usize, n: usize) {
        rc.encode(&mut self.empty[cc * LINE_STATES + nb.state], end == 0);
        if end == 0 {
            return;
        }
        let p = nb.pred;
        if p == 0 {
            self.encode_eg(rc, cc, FRESH, (end - 1) as u64);
            return;
        }
        let pb = cc * END_BUCKETS + end_bucket(p);
        rc.encode(&mut self.same[pb], end != p);
        if end == p {
            return;
        }
        let longer = end > p;
        // Only one direction is possible at either side of the extent.
        if p > 1 && p < n {
            rc.encode(&mut self.longer[pb], longer);
        }
        if longer {
            self.encode_eg(rc, cc, LONGER, (end - p - 1) as u64);
        } else {
            self.encode_eg(rc, cc, SHORTER, (p - end - 1) as u64);
        }
    }

    /// Inverse of [`LineModel::encode_end`]; an end outside 0..=n is an error.
    #[inline]
    fn decode_end(
        &mut self,
        rc: &mut RangeDecoder,
        cc: usize,
        nb: LineNbrs,
        n: usize,
    ) -> Result<usize> {
        if rc.decode(&mut self.empty[cc * LINE_STATES + nb.state]) {
            return Ok(0);
        }
        let p = nb.pred as u64;
        let end = if p == 0 {
            self.decode_eg(rc, cc, FRESH)? + 1
        } else {
            let pb = cc * END_BUCKETS + end_bucket(nb.pred);
            if !rc.decode(&mut self.same[pb]) {
                p
            } else {
                let longer = if p > 1 && p < n as u64 {
                    rc.decode(&mut self.longer[pb])
                } else {
                    p == 1
                };
                if longer {
                    p + 1 + self.decode_eg(rc, cc, LONGER)?
                } else {
                    // 0 (out of range below) when the difference is too large.
                    p.saturating_sub(1 + self.decode_eg(rc, cc, SHORTER)?)
                }
            }
        };
        if end == 0 || end > n as u64 {
            return Err(Error::input(format!(
                "context-coded DCT stream: line end {end} outside 1..={n}"
            )));
        }
        Ok(end as usize)
    }
}

/// Walks a box in C order, giving for each coefficient its flat index and the context inputs
/// (band, neighbour magnitude sum, signs of the neighbours along the last and first axes).
struct BoxWalk {
    extent: Vec<usize>,
    strides: Vec<usize>,
    idx: Vec<usize>,
    /// Whether the context has the second neighbours ([`ContextModel::LineEndsWide`]).
    wide: bool,
}

impl BoxWalk {
    fn new(extent: &[usize], model: ContextModel) -> BoxWalk {
        BoxWalk {
            extent: extent.to_vec(),
            strides: dct::c_strides(extent),
            idx: vec![0; extent.len()],
            wide: model.is_wide(),
        }
    }

    /// Context inputs of the coefficient at the current index (flat `b`) from the codes
    /// already known (`codes[..b]`): band, neighbour bucket, second-neighbour bucket (0 unless
    /// wide), signs.
    #[inline]
    fn context(&self, codes: &[i32], b: usize) -> (usize, usize, usize, usize) {
        let d = self.idx.len();
        let mut sum_idx = 0usize;
        let mut m = 0u32;
        let mut m2 = 0u32;
        for a in 0..d {
            sum_idx += self.idx[a];
            if self.idx[a] > 0 {
                m = m.saturating_add(codes[b - self.strides[a]].unsigned_abs());
            }
            if self.wide && self.idx[a] > 1 {
                m2 = m2.saturating_add(codes[b - 2 * self.strides[a]].unsigned_abs());
            }
        }
        let band = ((usize::BITS - (sum_idx + 1).leading_zeros() - 1) as usize).min(BANDS - 1);
        // The sign of the neighbour `k` steps back along axis `a` (1: none, as signum 0).
        let sgn_at = |a: usize, k: usize| -> usize {
            if self.idx[a] >= k {
                (codes[b - k * self.strides[a]].signum() + 1) as usize
            } else {
                1
            }
        };
        let signs = if self.wide {
            // Left (the last axis), back (the first) and up (the last but one) one step back,
            // left two steps back; an axis a box lacks (or that would repeat one) reads as
            // "none".
            let back = (d >= 2).then_some(0);
            let up = (d >= 3).then(|| d - 2);
            let at = |a: Option<usize>, k: usize| a.map_or(1, |a| sgn_at(a, k));
            let left = d.checked_sub(1);
            wide_signs([at(left, 1), at(back, 1), at(up, 1), at(left, 2)])
        } else if d > 0 {
            sgn_at(d - 1, 1) * 3 + sgn_at(0, 1)
        } else {
            4
        };
        (band, nbr_bucket(m), nb2_bucket(m2), signs)
    }

    #[inline]
    fn advance(&mut self) {
        dct::advance(&mut self.idx, &self.extent);
    }
}

/// The zero-flag contexts of component class `cc` (every band and neighbour bucket).
fn zero_class(cc: usize) -> std::ops::Range<usize> {
    zero_index(cc, 0, 0, 0)..zero_index(cc + 1, 0, 0, 0)
}

/// The zero-flag context index of component class `cc`, band, neighbour bucket and
/// second-neighbour bucket.
#[inline]
fn zero_index(cc: usize, band: usize, nb: usize, nb2: usize) -> usize {
    ((cc * BANDS + band) * NBR_BUCKETS + nb) * NB2_BUCKETS + nb2
}

/// The sign and magnitude of a nonzero `q` (`decode_nonzero` reads them).
fn encode_nonzero(
    rc: &mut RangeEncoder,
    model: &mut Model,
    cc: usize,
    nb: usize,
    signs: usize,
    q: i32,
) {
    rc.encode(&mut model.sign[cc * WIDE_SIGN_CONTEXTS + signs], q < 0);
    let (unary, mantissa) = magnitude_contexts(model, cc, nb);
    encode_golomb(rc, unary, mantissa, q.unsigned_abs() as u64);
}

/// The contexts of |q|'s binarization: its unary exponent's (by component class and
/// neighbour bucket) and its first mantissa bit's (by component class).
#[inline]
fn magnitude_contexts(model: &mut Model, cc: usize, nb: usize) -> (&mut [Ctx], &mut [Ctx]) {
    let u = (cc * NBR_BUCKETS + nb) * UNARY_POS;
    let m = cc * (MAX_EXP as usize + 1);
    (
        &mut model.unary[u..u + UNARY_POS],
        &mut model.mantissa[m..m + MAX_EXP as usize + 1],
    )
}

/// v ≥ 1 in the exp-Golomb-like binarization of magnitudes and line ends: e = ⌊log2 v⌋ in
/// unary (bit i with context `unary[min(i, len − 1)]`), then the bit below the leading one
/// with context `mantissa[e]`, the e − 1 bits below it at ½.
fn encode_golomb(rc: &mut RangeEncoder, unary: &mut [Ctx], mantissa: &mut [Ctx], v: u64) {
    let e = v.ilog2();
    let last = unary.len() - 1;
    for i in 0..=e {
        rc.encode(&mut unary[(i as usize).min(last)], i < e);
    }
    if e > 0 {
        rc.encode(&mut mantissa[e as usize], (v >> (e - 1)) & 1 == 1);
        for k in (0..e - 1).rev() {
            rc.encode_direct((v >> k) & 1 == 1);
        }
    }
}

/// Inverse of [`encode_golomb`]; None when the exponent exceeds `max_e`.
#[inline]
fn decode_golomb(
    rc: &mut RangeDecoder,
    unary: &mut [Ctx],
    mantissa: &mut [Ctx],
    max_e: u32,
) -> Option<u64> {
    let last = unary.len() - 1;
    let mut e = 0u32;
    while rc.decode(&mut unary[(e as usize).min(last)]) {
        e += 1;
        if e > max_e {
            return None;
        }
    }
    let mut v: u64 = 1;
    if e > 0 {
        v = (v << 1) | rc.decode(&mut mantissa[e as usize]) as u64;
        for _ in 0..e - 1 {
            v = (v << 1) | rc.decode_direct() as u64;
        }
    }
    Some(v)
}

/// The first model: every position of the box.
fn encode_component(rc: &mut RangeEncoder, model: &mut Model, comp: usize, c: &Coefficients) {
    let cc = comp.min(COMP_CLASSES - 1);
    let mut walk = BoxWalk::new(&c.extent, ContextModel::EveryPosition);
    for (b, &q) in c.codes.iter().enumerate() {
        let (band, nb, nb2, signs) = walk.context(&c.codes, b);
        rc.encode(&mut model.zero[zero_index(cc, band, nb, nb2)], q != 0);
        if q != 0 {
            encode_nonzero(rc, model, cc, nb, signs, q);
        }
        walk.advance();
    }
}

/// The lines of a box along its last axis: their count, length and the strides (in lines) of
/// the other axes. A box without axes is one line of one position.
struct LineGrid {
    outer_extent: Vec<usize>,
    strides: Vec<usize>,
    count: usize,
    n: usize,
}

impl LineGrid {
    fn new(extent: &[usize], total: usize) -> LineGrid {
        let d = extent.len();
        let n = extent.last().copied().unwrap_or(1);
        let outer_extent = extent[..d.saturating_sub(1)].to_vec();
        LineGrid {
            strides: dct::c_strides(&outer_extent),
            outer_extent,
            count: if total == 0 { 0 } else { total / n },
            n,
        }
    }
}

/// The line-end models: per line (C order) its end, then the positions up to it.
fn encode_component_lines(
    rc: &mut RangeEncoder,
    model: &mut Model,
    comp: usize,
    c: &Coefficients,
    layout: ContextModel,
) {
    let cc = comp.min(COMP_CLASSES - 1);
    let grid = LineGrid::new(&c.extent, c.codes.len());
    let n = grid.n;
    let d = c.extent.len();
    let mut outer = vec![0usize; grid.outer_extent.len()];
    let mut ends = vec![0u32; grid.count];
    let mut walk = BoxWalk::new(&c.extent, layout);
    for r in 0..grid.count {
        let end = c.codes[r * n..(r + 1) * n]
            .iter()
            .rposition(|&q| q != 0)
            .map_or(0, |i| i + 1);
        let nbrs = LineNbrs::generic(&outer, &grid.strides, r, &ends);
        model.line.encode_end(rc, cc, nbrs, end, n);
        ends[r] = end as u32;
        walk.idx[..outer.len()].copy_from_slice(&outer);
        for i in 0..end {
            if d > 0 {
                walk.idx[d - 1] = i;
            }
            let b = r * n + i;
            let q = c.codes[b];
            let (band, nb, nb2, signs) = walk.context(&c.codes, b);
            // The last position's flag is implied: it ends the line, so it is nonzero.
            if i + 1 < end {
                rc.encode(&mut model.zero[zero_index(cc, band, nb, nb2)], q != 0);
            }
            if q != 0 {
                encode_nonzero(rc, model, cc, nb, signs, q);
            }
        }
        dct::advance(&mut outer, &grid.outer_extent);
    }
}

fn decode_component(
    rc: &mut RangeDecoder,
    model: &mut Model,
    comp: usize,
    extent: Vec<usize>,
    layout: ContextModel,
    scratch: &mut DecodeScratch,
) -> Result<Coefficients> {
    let cc = comp.min(COMP_CLASSES - 1);
    let total: usize = if extent.contains(&0) {
        0
    } else {
        extent.iter().product()
    };
    let mut codes = scratch.take_i32_zeroed(total);
    if extent.len() == 3 && total > 0 {
        let e = [extent[0], extent[1], extent[2]];
        match layout {
            ContextModel::LineEnds => decode_lines_3d::<false>(rc, model, cc, e, &mut codes)?,
            ContextModel::LineEndsWide => decode_lines_3d::<true>(rc, model, cc, e, &mut codes)?,
            ContextModel::EveryPosition => decode_box_3d(rc, model, cc, e, &mut codes)?,
        }
        return Ok(Coefficients { extent, codes });
    }
    let mut walk = BoxWalk::new(&extent, layout);
    if layout == ContextModel::EveryPosition {
        for b in 0..total {
            let (band, nb, nb2, signs) = walk.context(&codes, b);
            if rc.decode(&mut model.zero[zero_index(cc, band, nb, nb2)]) {
                codes[b] = decode_nonzero(rc, model, cc, nb, signs)?;
            }
            walk.advance();
        }
        return Ok(Coefficients { extent, codes });
    }
    let grid = LineGrid::new(&extent, total);
    let n = grid.n;
    let d = extent.len();
    let mut outer = vec![0usize; grid.outer_extent.len()];
    let mut ends = vec![0u32; grid.count];
    for r in 0..grid.count {
        let nbrs = LineNbrs::generic(&outer, &grid.strides, r, &ends);
        let end = model.line.decode_end(rc, cc, nbrs, n)?;
        ends[r] = end as u32;
        walk.idx[..outer.len()].copy_from_slice(&outer);
        for i in 0..end {
            if d > 0 {
                walk.idx[d - 1] = i;
            }
            let b = r * n + i;
            let (band, nb, nb2, signs) = walk.context(&codes, b);
            if i + 1 == end || rc.decode(&mut model.zero[zero_index(cc, band, nb, nb2)]) {
                codes[b] = decode_nonzero(rc, model, cc, nb, signs)?;
            }
        }
        dct::advance(&mut outer, &grid.outer_extent);
    }
    Ok(Coefficients { extent, codes })
}

/// The sign and magnitude of a coefficient known to be nonzero (see `encode_component`).
#[inline]
fn decode_nonzero(
    rc: &mut RangeDecoder,
    model: &mut Model,
    cc: usize,
    nb: usize,
    signs: usize,
) -> Result<i32> {
    let neg = rc.decode(&mut model.sign[cc * WIDE_SIGN_CONTEXTS + signs]);
    let (unary, mantissa) = magnitude_contexts(model, cc, nb);
    let v = decode_golomb(rc, unary, mantissa, 30)
        .ok_or_else(|| Error::input("context-coded DCT stream: coefficient exceeds 2^30"))?;
    let mag = v as i32; // v < 2^31 (e ≤ 30)
    Ok(if neg { -mag } else { mag })
}

/// [`nbr_bucket`] tabulated up to the start of the last bucket (the 3-D walk's lookup).
const NBR_LUT: [u8; 257] = {
    let mut t = [0u8; 257];
    let mut m = 0;
    while m < 257 {
        t[m] = nbr_bucket(m as u32) as u8;
        m += 1;
    }
    t
};

/// Offset of the zero-flag contexts of each band (within a component class), by the sum of
/// the frequency indices, for sums below `n`.
fn band_offsets(n: usize) -> Vec<usize> {
    (0..n)
        .map(|sum| ((usize::BITS - (sum + 1).leading_zeros() - 1) as usize).min(BANDS - 1))
        .map(|band| band * NBR_BUCKETS * NB2_BUCKETS)
        .collect()
}

/// The 3-D box (every MERL-grid table) with the contexts of [`BoxWalk`] computed
/// incrementally: the same model inputs in the same order, so the same stream decodes to the
/// same codes, at a fraction of the generic walk's cost (a DCT box is ~98% zeros, so the
/// per-coefficient context dominates decoding). The sign context is only formed for nonzero
/// coefficients, the only ones that use it.
fn decode_box_3d(
    rc: &mut RangeDecoder,
    model: &mut Model,
    cc: usize,
    [e0, e1, e2]: [usize; 3],
    codes: &mut [i32],
) -> Result<()> {
    let s0 = e1 * e2;
    // The zero-flag contexts of this component class, held apart so that `decode_nonzero`
    // can borrow the rest of the model.
    let zero_range = zero_class(cc);
    let mut zero_ctx = model.zero[zero_range.clone()].to_vec();
    let band_offset = band_offsets(e0 + e1 + e2);
    // Missing neighbours (index 0 along an axis) read as 0: the same magnitude sum (nothing
    // added) and sign context (signum 0 ↦ 1, the generic walk's "no neighbour") as `BoxWalk`.
    let zeros = vec![0i32; e2];
    for i0 in 0..e0 {
        for i1 in 0..e1 {
            let row = (i0 * e1 + i1) * e2;
            let (before, rest) = codes.split_at_mut(row);
            let cur = &mut rest[..e2];
            let up = if i1 > 0 {
                &before[row - e2..]
            } else {
                &zeros[..]
            };
            let back = if i0 > 0 {
                &before[row - s0..row - s0 + e2]
            } else {
                &zeros[..]
            };
            let offsets = &band_offset[i0 + i1..i0 + i1 + e2];
            let mut left = 0i32;
            for i2 in 0..e2 {
                // Three magnitudes below 2^31 each: no overflow in u64, and every sum from
                // 257 up (where `saturating_add` could have stopped) is bucket 8 either way.
                let m = left.unsigned_abs() as u64
                    + up[i2].unsigned_abs() as u64
                    + back[i2].unsigned_abs() as u64;
                let nb = if m < 257 {
                    NBR_LUT[m as usize] as usize
                } else {
                    8
                };
                if rc.decode(&mut zero_ctx[offsets[i2] + nb * NB2_BUCKETS]) {
                    let signs = (left.signum() + 1) as usize * 3 + (back[i2].signum() + 1) as usize;
                    cur[i2] = decode_nonzero(rc, model, cc, nb, signs)?;
                }
                left = cur[i2];
            }
        }
    }
    model.zero[zero_range].copy_from_slice(&zero_ctx);
    Ok(())
}

/// The line-end models' 3-D box: the incremental contexts of [`decode_box_3d`], visiting only
/// the positions up to each line's end (the rest of the box stays zero); `WIDE`: with the
/// second neighbours ([`ContextModel::LineEndsWide`]).
fn decode_lines_3d<const WIDE: bool>(
    rc: &mut RangeDecoder,
    model: &mut Model,
    cc: usize,
    [e0, e1, e2]: [usize; 3],
    codes: &mut [i32],
) -> Result<()> {
    let s0 = e1 * e2;
    let zero_range = zero_class(cc);
    let mut zero_ctx = model.zero[zero_range.clone()].to_vec();
    let band_offset = band_offsets(e0 + e1 + e2);
    let zeros = vec![0i32; e2];
    let mut ends = vec![0u32; e0 * e1];
    for i0 in 0..e0 {
        for i1 in 0..e1 {
            let r = i0 * e1 + i1;
            let nbrs = LineNbrs::new(
                (i1 > 0).then(|| ends[r - 1]),
                (i0 > 0).then(|| ends[r - e1]),
            );
            let end = model.line.decode_end(rc, cc, nbrs, e2)?;
            ends[r] = end as u32;
            if end == 0 {
                continue;
            }
            let row = r * e2;
            let (before, rest) = codes.split_at_mut(row);
            let cur = &mut rest[..end];
            // Neighbours past their own line's end read 0 from the zeroed array, as in the
            // encoder (they are zero).
            let up = if i1 > 0 {
                &before[row - e2..row - e2 + end]
            } else {
                &zeros[..end]
            };
            let back = if i0 > 0 {
                &before[row - s0..row - s0 + end]
            } else {
                &zeros[..end]
            };
            // The second neighbours (read only when WIDE).
            let up2 = if WIDE && i1 > 1 {
                &before[row - 2 * e2..row - 2 * e2 + end]
            } else {
                &zeros[..end]
            };
            let back2 = if WIDE && i0 > 1 {
                &before[row - 2 * s0..row - 2 * s0 + end]
            } else {
                &zeros[..end]
            };
            let offsets = &band_offset[i0 + i1..i0 + i1 + end];
            let (mut left, mut left2) = (0i32, 0i32);
            for i2 in 0..end {
                // As in `decode_box_3d`: no overflow in u64, sums from 257 up are bucket 8.
                let m = left.unsigned_abs() as u64
                    + up[i2].unsigned_abs() as u64
                    + back[i2].unsigned_abs() as u64;
                let nb = if m < 257 {
                    NBR_LUT[m as usize] as usize
                } else {
                    8
                };
                let at = if WIDE {
                    // Below 2^33: no overflow; every sum from 4 up is bucket 3.
                    let m2 = left2.unsigned_abs() as u64
                        + up2[i2].unsigned_abs() as u64
                        + back2[i2].unsigned_abs() as u64;
                    offsets[i2] + nb * NB2_BUCKETS + nb2_bucket(m2.min(4) as u32)
                } else {
                    offsets[i2] + nb * NB2_BUCKETS
                };
                // The line's last position is nonzero without a flag.
                if i2 + 1 == end || rc.decode(&mut zero_ctx[at]) {
                    let s = |q: i32| (q.signum() + 1) as usize;
                    let signs = if WIDE {
                        wide_signs([s(left), s(back[i2]), s(up[i2]), s(left2)])
                    } else {
                        s(left) * 3 + s(back[i2])
                    };
                    cur[i2] = decode_nonzero(rc, model, cc, nb, signs)?;
                }
                left2 = left;
                left = cur[i2];
            }
        }
    }
    model.zero[zero_range].copy_from_slice(&zero_ctx);
    Ok(())
}

/// The payload in the current model ([`ContextModel::CURRENT`]).
pub fn encode(comps: &[Coefficients]) -> Vec<u8> {
    encode_model(comps, ContextModel::CURRENT)
}

/// The smaller payload of the two line-end models and its model (the current one on a tie).
/// The second neighbours' contexts are four times as many: on a sparse box (a small file)
/// learning them can cost more than they save (up to 1% on the preview budget's files).
/// The two streams are coded on two threads: each coder is serial, and the rate control
/// codes every trial this way (on chrome-steel, an NBRDF fit whose files are 250–450 KB, the
/// second coding was 0.2 s of a 2.5 s `pack`).
pub fn encode_smaller(comps: &[Coefficients]) -> (ContextModel, Vec<u8>) {
    let (wide, plain) = rayon::join(
        || encode_model(comps, ContextModel::LineEndsWide),
        || encode_model(comps, ContextModel::LineEnds),
    );
    if plain.len() < wide.len() {
        (ContextModel::LineEnds, plain)
    } else {
        (ContextModel::LineEndsWide, wide)
    }
}

/// The payload: every component's box extents (varints), then one range-coded stream of every
/// component's codes in `model`, its first byte naming the model.
pub fn encode_model(comps: &[Coefficients], model: ContextModel) -> Vec<u8> {
    let mut out = Vec::new();
    for c in comps {
        for &e in &c.extent {
            dct::put_varint(&mut out, e as u64);
        }
    }
    let mut rc = RangeEncoder::for_model(model);
    let mut m = Model::new();
    for (k, c) in comps.iter().enumerate() {
        match model {
            ContextModel::EveryPosition => encode_component(&mut rc, &mut m, k, c),
            ContextModel::LineEnds | ContextModel::LineEndsWide => {
                encode_component_lines(&mut rc, &mut m, k, c, model)
            }
        }
    }
    let mut stream = rc.finish();
    // The encoder's interval never leaves [0, 1) of the initial range: its first byte is 0.
    debug_assert_eq!(stream[0], 0);
    stream[0] = model.preamble();
    out.extend(stream);
    out
}

/// Inverse of [`encode_model`], checking every extent against the grid `dims`.
pub fn decode(
    payload: &[u8],
    dims: &[usize],
    components: usize,
    model: ContextModel,
) -> Result<Vec<Coefficients>> {
    decode_with(
        payload,
        dims,
        components,
        model,
        &mut DecodeScratch::default(),
    )
}

/// [`decode`] with the code arrays taken from `scratch`.
pub(crate) fn decode_with(
    payload: &[u8],
    dims: &[usize],
    components: usize,
    model: ContextModel,
    scratch: &mut DecodeScratch,
) -> Result<Vec<Coefficients>> {
    let mut pos = 0;
    let extents = dct::read_extents(
        payload,
        &mut pos,
        dims,
        components,
        "context-coded DCT stream",
    )?;
    let mut rc = RangeDecoder::with_preamble(&payload[pos..], model)?;
    let mut m = Model::new();
    let mut out = Vec::with_capacity(components);
    for (k, extent) in extents.into_iter().enumerate() {
        out.push(decode_component(
            &mut rc, &mut m, k, extent, model, scratch,
        )?);
    }
    if !rc.within_input() {
        return Err(Error::input(
            "context-coded DCT stream: truncated (the decoder ran past its end)",
        ));
    }
    Ok(out)
}

/// Dead-zone quantization: coefficients with |c| < `deadzone` × step become 0, the others are
/// rounded as [`dct::quantize`] does (the decoder's reconstruction q × step is unchanged).
/// Zeroing the many small coefficients costs a little error and saves their bits.
pub fn quantize_deadzone<T: Copy + Into<f64>>(
    coef: &[T],
    dims: &[usize],
    step: f64,
    deadzone: f64,
) -> Coefficients {
    if deadzone <= 0.5 {
        return dct::quantize(coef, dims, step);
    }
    // Zeroing below the dead zone and quantizing in one pass: a zero quantizes to 0 anyway.
    dct::quantize_above(coef, dims, step, deadzone * step)
}

/// Every component quantized with its step and the dead zone (f64 coefficients, or the
/// planner's f32 ones: [`dct::quantize`]).
pub fn quantize_all<T: Copy + Into<f64>>(
    coefs: &[Vec<T>],
    dims: &[usize],
    steps: &[f64],
    deadzone: f64,
) -> Vec<Coefficients> {
    coefs
        .iter()
        .zip(steps)
        .map(|(p, &s)| quantize_deadzone(p, dims, s, deadzone))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn range_coder_round_trips_skewed_and_direct_bits() {
        let mut rng = crate::math::SplitMix64::new(7);
        let bits: Vec<(bool, bool)> = (0..20_000)
            .map(|i| (rng.next_f64() < 0.03, i % 3 == 0))
            .collect();
        let mut enc = RangeEncoder::new();
        let mut ctx = Ctx::default();
        for &(b, direct) in &bits {
            if direct {
                enc.encode_direct(b);
            } else {
                enc.encode(&mut ctx, b);
            }
        }
        let bytes = enc.finish();
        // ~13,333 adaptive bits at p = 0.03 (entropy 0.194 bit) + 6,667 direct bits ≈ 1.16 KB.
        assert!(bytes.len() < 1300, "{} bytes", bytes.len());
        assert!(bytes.len() > 1000, "{} bytes", bytes.len());
        let mut dec = RangeDecoder::new(&bytes).unwrap();
        let mut ctx = Ctx::default();
        for &(b, direct) in &bits {
            let got = if direct {
                dec.decode_direct()
            } else {
                dec.decode(&mut ctx)
            };
            assert_eq!(got, b);
        }
        assert!(dec.within_input());
    }

    #[test]
    fn carries_propagate_through_runs_of_ff() {
        // Long runs of the improbable symbol push `low` up and force carries.
        let mut enc = RangeEncoder::new();
        let mut ctx = Ctx::default();
        let pattern: Vec<bool> = (0..50_000).map(|i| i % 97 != 0).collect();
        for &b in &pattern {
            enc.encode(&mut ctx, b);
        }
        let bytes = enc.finish();
        let mut dec = RangeDecoder::new(&bytes).unwrap();
        let mut ctx = Ctx::default();
        for &b in &pattern {
            assert_eq!(dec.decode(&mut ctx), b);
        }
    }

    #[test]
    fn an_all_zero_box_costs_almost_nothing() {
        let c = Coefficients {
            extent: vec![40, 40, 40],
            codes: vec![0; 64_000],
        };
        let old = encode_model(std::slice::from_ref(&c), ContextModel::EveryPosition);
        // 64,000 zero flags in a few contexts: the probability saturates near 2^-11.
        assert!(old.len() < 120, "{} bytes", old.len());
        let dims = [40, 40, 40];
        let back = decode(&old, &dims, 1, ContextModel::EveryPosition).unwrap();
        assert_eq!(back, vec![c.clone()]);
        // With line ends: 1,600 empty-line flags (~12 B) after the extents and flush bytes.
        let bytes = encode(std::slice::from_ref(&c));
        assert!(bytes.len() <= 20, "{} bytes", bytes.len());
        assert_eq!(
            decode(&bytes, &dims, 1, ContextModel::CURRENT).unwrap(),
            vec![c]
        );
    }

    /// Codes with every kind of line: empty, ending at its last position, ending early, one
    /// nonzero, and magnitudes up to the 2^30 limit.
    fn varied_lines(extent: &[usize], seed: u64) -> Coefficients {
        let mut rng = crate::math::SplitMix64::new(seed);
        let n: usize = extent.iter().product();
        let len = extent.last().copied().unwrap_or(1);
        let mut codes = vec![0i32; n];
        for (r, line) in codes.chunks_mut(len).enumerate() {
            let end = match r % 5 {
                0 => 0,
                1 => len,
                2 => 1,
                _ => 1 + (rng.next_f64() * len as f64) as usize % len,
            };
            for (i, q) in line[..end].iter_mut().enumerate() {
                if i + 1 == end || rng.next_f64() < 0.3 {
                    let m = (rng.next_f64() * 31.0).exp2().min((1u64 << 30) as f64) as i32;
                    *q = if rng.next_f64() < 0.5 {
                        -m.max(1)
                    } else {
                        m.max(1)
                    };
                }
            }
        }
        Coefficients {
            extent: extent.to_vec(),
            codes,
        }
    }

    /// Files written before line ends (no `model` in the header) hold streams in the first
    /// model: they still decode, and such a header still reads and writes without the field
    /// (tests/codec_compat.rs decodes a file the old binary wrote).
    #[test]
    fn the_first_model_still_decodes() {
        let c = Coefficients {
            extent: vec![3, 4],
            codes: vec![5, -3, 0, 1, 0, 0, 2, 0, -1, 0, 0, 7],
        };
        let old = encode_model(std::slice::from_ref(&c), ContextModel::EveryPosition);
        assert_eq!(
            decode(&old, &[4, 4], 1, ContextModel::EveryPosition).unwrap(),
            vec![c.clone()]
        );
        // Each model refuses the others' streams by their first byte.
        let models = [
            ContextModel::EveryPosition,
            ContextModel::LineEnds,
            ContextModel::LineEndsWide,
        ];
        for written in models {
            let bytes = encode_model(std::slice::from_ref(&c), written);
            for read in models {
                assert_eq!(
                    decode(&bytes, &[4, 4], 1, read).is_ok(),
                    read == written,
                    "{written:?} read as {read:?}"
                );
            }
        }
        let json = r#"{"deadzone":0.75}"#;
        let coding: ContextCoding = serde_json::from_str(json).unwrap();
        assert_eq!(coding.model, ContextModel::EveryPosition);
        assert_eq!(serde_json::to_string(&coding).unwrap(), json);
        let coding = ContextCoding::new(0.75);
        assert_eq!(
            serde_json::to_string(&coding).unwrap(),
            r#"{"deadzone":0.75,"model":"line_ends2"}"#
        );
        // The line-end model's headers still read.
        let coding: ContextCoding =
            serde_json::from_str(r#"{"deadzone":0.75,"model":"line_ends"}"#).unwrap();
        assert_eq!(coding.model, ContextModel::LineEnds);
    }

    #[test]
    fn line_ends_round_trip_every_kind_of_line() {
        for extent in [
            vec![7],
            vec![5, 9],
            vec![4, 6, 11],
            vec![3, 4, 2, 5],
            vec![2, 3, 1],
        ] {
            for seed in 0..8 {
                let cs = vec![
                    varied_lines(&extent, seed),
                    varied_lines(&extent, seed + 100),
                    varied_lines(&extent, seed + 200),
                ];
                for model in [
                    ContextModel::EveryPosition,
                    ContextModel::LineEnds,
                    ContextModel::LineEndsWide,
                ] {
                    let bytes = encode_model(&cs, model);
                    let back = decode(&bytes, &extent, 3, model).unwrap();
                    assert_eq!(back, cs, "{extent:?} seed {seed} {model:?}");
                }
            }
        }
    }

    /// A stream whose first line claims to end past the box: an error naming the end, on the
    /// 3-D and on the generic path.
    #[test]
    fn a_line_end_beyond_the_extent_is_an_error() {
        for extent in [vec![3usize], vec![1, 1, 3], vec![1, 3]] {
            let mut out = Vec::new();
            for &e in &extent {
                dct::put_varint(&mut out, e as u64);
            }
            let mut rc = RangeEncoder::new();
            let mut m = Model::new();
            // Not empty, no neighbour: end − 1 = 5, end 6 in a line of 3.
            rc.encode(&mut m.line.empty[0], false);
            m.line.encode_eg(&mut rc, 0, FRESH, 5);
            let mut stream = rc.finish();
            stream[0] = ContextModel::LineEnds.preamble();
            out.extend(stream);
            let err = decode(&out, &extent, 1, ContextModel::LineEnds).unwrap_err();
            assert!(
                err.to_string().contains("line end 6 outside 1..=3"),
                "{err}"
            );
        }
    }

    #[test]
    fn deadzone_zeroes_small_coefficients_only() {
        let coef = [1.0, 0.7, -0.74, 0.76, -2.4, 0.3];
        let q = quantize_deadzone(&coef, &[6], 1.0, 0.75);
        assert_eq!(q.codes, vec![1, 0, 0, 1, -2]);
        let plain = quantize_deadzone(&coef, &[6], 1.0, 0.5);
        assert_eq!(plain.codes, vec![1, 1, -1, 1, -2]);
    }

    #[test]
    fn hostile_streams_are_errors() {
        for model in [
            ContextModel::EveryPosition,
            ContextModel::LineEnds,
            ContextModel::LineEndsWide,
        ] {
            let pre = model.preamble();
            for dims in [vec![4usize, 4], vec![4, 4, 4]] {
                let d = dims.len();
                assert!(decode(&[], &dims, 1, model).is_err());
                assert!(decode(&[9, 1, 0, 0, 0, 0, 0, 0], &dims, 1, model).is_err());
                // A preamble byte that the encoder never writes.
                let mut b = vec![2u8; d];
                b.extend([7, 0, 0, 0, 0]);
                assert!(decode(&b, &dims, 1, model).is_err());
                // Garbage after valid extents: decodes to something or errors, never panics.
                for seed in 0..200u64 {
                    let mut rng = crate::math::SplitMix64::new(seed);
                    let mut b = vec![4u8; d];
                    b.push(pre);
                    b.extend((0..12).map(|_| (rng.next_f64() * 256.0) as u8));
                    let _ = decode(&b, &dims, 1, model);
                }
                let extent: Vec<usize> = (0..d).map(|a| 3 + (a + 1) % 2).collect();
                let c = varied_lines(&extent, 3);
                let bytes = encode_model(std::slice::from_ref(&c), model);
                for cut in 0..bytes.len() - 1 {
                    if let Ok(v) = decode(&bytes[..cut], &dims, 1, model) {
                        // A cut inside the flush bytes may still decode, but only to the same
                        // codes.
                        assert_eq!(v, vec![c.clone()], "cut {cut}");
                    }
                }
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// 1-, 2- and 4-axis boxes take the generic context walk, 3-axis boxes the
        /// incremental one; both must read what the (generic) encoder wrote.
        #[test]
        fn boxes_of_any_dimension_round_trip(
            shape in proptest::collection::vec(1usize..6, 1..5), seed in any::<u64>(),
            sparsity in 0.0f64..1.0,
        ) {
            let mut rng = crate::math::SplitMix64::new(seed);
            let n: usize = shape.iter().product();
            let codes = (0..n).map(|_| {
                if rng.next_f64() < sparsity { 0 } else { (rng.next_f64() * 200.0 - 100.0) as i32 }
            }).collect();
            let cs = vec![Coefficients { extent: shape.clone(), codes }];
            for model in [
                    ContextModel::EveryPosition,
                    ContextModel::LineEnds,
                    ContextModel::LineEndsWide,
                ] {
                let back = decode(&encode_model(&cs, model), &shape, 1, model).unwrap();
                prop_assert_eq!(&back, &cs);
            }
        }

        /// Line ends on boxes of 1–4 axes (the 3-axis ones through the fast path), some
        /// empty, with all-zero lines, lines ending at their last position and magnitudes up
        /// to 2^30.
        #[test]
        fn line_ends_round_trip(
            shape in proptest::collection::vec(0usize..7, 1..5), comps in 1usize..4,
            seed in any::<u64>(), spread in 0.0f64..31.0, sparsity in 0.0f64..1.0,
            zero_lines in 0.0f64..1.0,
        ) {
            let mut rng = crate::math::SplitMix64::new(seed);
            let dims: Vec<usize> = shape.iter().map(|&e| e.max(1)).collect();
            let cs: Vec<Coefficients> = (0..comps).map(|k| {
                let extent = if k == 1 && seed % 3 == 0 { vec![0; shape.len()] } else { shape.clone() };
                let n: usize = if extent.contains(&0) { 0 } else { extent.iter().product() };
                let len = extent.last().copied().unwrap_or(1).max(1);
                let mut codes = vec![0i32; n];
                for line in codes.chunks_mut(len) {
                    if rng.next_f64() < zero_lines {
                        continue;
                    }
                    for q in line.iter_mut() {
                        if rng.next_f64() >= sparsity {
                            let m = (rng.next_f64() * spread).exp2().min((1u64 << 30) as f64) as i32;
                            *q = if rng.next_f64() < 0.5 { -m } else { m };
                        }
                    }
                }
                Coefficients { extent, codes }
            }).collect();
            for model in [ContextModel::LineEnds, ContextModel::LineEndsWide] {
                let bytes = encode_model(&cs, model);
                let back = decode(&bytes, &dims, comps, model).unwrap();
                prop_assert_eq!(&back, &cs);
            }
        }

        #[test]
        fn random_coefficient_arrays_round_trip(
            d0 in 0usize..7, d1 in 0usize..9, d2 in 0usize..11, comps in 1usize..5,
            seed in any::<u64>(), spread in 0.0f64..30.0, sparsity in 0.0f64..1.0,
        ) {
            let dims = [d0.max(1), d1.max(1), d2.max(1)];
            let mut rng = crate::math::SplitMix64::new(seed);
            let cs: Vec<Coefficients> = (0..comps).map(|k| {
                let extent = if k == 1 { vec![0, 0, 0] } else { vec![d0, d1, d2] };
                let n: usize = if extent.contains(&0) { 0 } else { extent.iter().product() };
                let codes = (0..n).map(|_| {
                    if rng.next_f64() < sparsity { return 0; }
                    // Heavy-tailed magnitudes up to the 2^30 limit.
                    let m = (rng.next_f64() * spread).exp2().min((1u64 << 30) as f64) as i32;
                    if rng.next_f64() < 0.5 { -m } else { m }
                }).collect();
                Coefficients { extent, codes }
            }).collect();
            for model in [
                    ContextModel::EveryPosition,
                    ContextModel::LineEnds,
                    ContextModel::LineEndsWide,
                ] {
                let bytes = encode_model(&cs, model);
                let back = decode(&bytes, &dims, comps, model).unwrap();
                prop_assert_eq!(&back, &cs);
            }
        }
    }
}
