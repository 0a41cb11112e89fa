//! Continuous grid indices of many direction pairs at once, for `Table::eval_batch`.
//!
//! The generic path (`Grid::coords_of` → `HalfDiff::from_dirs`) takes three atan2 and four
//! sin_cos per pair. Here the half-frame rotation uses the half vector's own components
//! (cos φh = h.x/r, sin θh = r/|h| ..., with one division for both 1/r and 1/|h|), the angles
//! come from a branch-free atan ([`crate::math::atan::atan2_first_quadrant`], one division for the ratio),
//! the index maps multiply by a precomputed 1/span, and the loop over a block of pairs has no
//! calls or branches, so it vectorizes. Results agree with the generic path to ~1e-15 in angle;
//! `Table::eval_into` takes these angles too on the grids where they apply
//! ([`HalfdiffIndexer::index_one`]), so per-pair and batched lookups have the same bits.

use crate::geometry::Vec3;
use crate::grid::{Axis, Grid, GridKind, Warp};
use crate::math::PI;
use crate::math::atan::{atan2_first_quadrant, atan2_full};

/// An axis's angle → continuous index map, as `Axis::continuous_index`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct IndexMap {
    lo: f64,
    /// 1 / (hi − lo): a multiplication per pair instead of a division.
    inv_span: f64,
    sqrt: bool,
    n: f64,
    offset: f64,
}

impl IndexMap {
    fn new(a: &Axis) -> IndexMap {
        let (lo, hi) = a.range();
        IndexMap {
            lo,
            inv_span: 1.0 / (hi - lo),
            sqrt: a.warp == Warp::Sqrt,
            n: a.n as f64,
            // continuous_index(lo) = −(the placement's offset).
            offset: a.continuous_index(lo),
        }
    }

    /// `Axis::continuous_index` (to an ulp of the fraction), branch-free.
    #[inline(always)]
    fn index(&self, x: f64) -> f64 {
        let t = (x - self.lo) * self.inv_span;
        // The sqrt warp's inverse clamps below 0 like `Warp::inverse`.
        let u = if self.sqrt { t.max(0.0).sqrt() } else { t };
        u * self.n + self.offset
    }
}

/// Precomputed index maps of a half/difference grid without θ limit.
#[derive(Clone, Debug)]
pub(crate) struct HalfdiffIndexer {
    four: bool,
    maps: [IndexMap; 4],
    pub(crate) use_avx2: bool,
}

/// Pairs per block of the vectorized loop.
pub(crate) const BLOCK: usize = 64;

impl HalfdiffIndexer {
    /// `None` when the grid is not a half/difference grid or has a θ limit.
    pub(crate) fn new(grid: &Grid) -> Option<HalfdiffIndexer> {
        // The vectorized index maps know the linear and sqrt warps only.
        if grid.theta_max().is_some() || grid.axes().iter().any(|a| a.warp == Warp::Grazing) {
            return None;
        }
        let four = match grid.kind() {
            GridKind::Halfdiff3 => false,
            GridKind::Halfdiff4 => true,
            _ => return None,
        };
        let a = grid.axes();
        let m = |k: usize| IndexMap::new(&a[k.min(a.len() - 1)]);
        Some(HalfdiffIndexer {
            four,
            maps: [m(0), m(1), m(2), m(3)],
            use_avx2: crate::simd::avx2_fma(),
        })
    }

    /// Continuous indices (storage order) of each pair, and whether the pair is in the
    /// domain (both directions strictly above the horizon). At most [`BLOCK`] pairs.
    pub(crate) fn indices(&self, pairs: &[(Vec3, Vec3)], t: &mut [[f64; 4]], ok: &mut [bool]) {
        #[cfg(target_arch = "x86_64")]
        if self.use_avx2 {
            // SAFETY: `use_avx2` is only true when the CPU reports AVX2 and FMA.
            return unsafe { self.indices_avx2(pairs, t, ok) };
        }
        self.indices_impl(pairs, t, ok)
    }

    /// The continuous indices of one pair, as [`HalfdiffIndexer::indices`] gives them (the
    /// portable and AVX2 loops have the same bits); `None` below the horizon.
    #[inline]
    pub(crate) fn index_one(&self, wi: Vec3, wo: Vec3) -> Option<[f64; 4]> {
        let (mut t, mut ok) = ([[0f64; 4]], [false]);
        self.indices_impl(&[(wi, wo)], &mut t, &mut ok);
        ok[0].then_some(t[0])
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn indices_avx2(&self, pairs: &[(Vec3, Vec3)], t: &mut [[f64; 4]], ok: &mut [bool]) {
        self.indices_impl(pairs, t, ok)
    }

    #[inline(always)]
    fn indices_impl(&self, pairs: &[(Vec3, Vec3)], t: &mut [[f64; 4]], ok: &mut [bool]) {
        if self.four {
            self.indices_kind::<true>(pairs, t, ok)
        } else {
            self.indices_kind::<false>(pairs, t, ok)
        }
    }

    /// The loop for one grid kind (`FOUR`: halfdiff4), so that it has no branch inside.
    #[inline(always)]
    fn indices_kind<const FOUR: bool>(
        &self,
        pairs: &[(Vec3, Vec3)],
        t: &mut [[f64; 4]],
        ok: &mut [bool],
    ) {
        let [m0, m1, m2, m3] = self.maps;
        for ((&(wi, wo), tk), okk) in pairs.iter().zip(t.iter_mut()).zip(ok.iter_mut()) {
            // The half vector unnormalized: its angles do not depend on its length.
            let (hx, hy, hz) = (wi.x + wo.x, wi.y + wo.y, wi.z + wo.z);
            let r2 = hx * hx + hy * hy;
            let r = r2.sqrt();
            let len = (r2 + hz * hz).sqrt();
            let theta_h = atan2_first_quadrant(r, hz.max(0.0));
            // The half frame: cos φh = hx/r, sin φh = hy/r, cos θh = hz/len, sin θh = r/len,
            // from one reciprocal 1/(r·len). On the normal (r = 0) φh is undefined: take 0
            // (cos 1, sin 0) like atan2(0, 0).
            let rl = r * len;
            let inv = 1.0 / if rl > 0.0 { rl } else { 1.0 };
            let (inv_r, inv_len) = (len * inv, r * inv);
            let (cp, sp, ct, st) = if rl > 0.0 {
                (hx * inv_r, hy * inv_r, hz * inv_len, r * inv_len)
            } else {
                (1.0, 0.0, 1.0, 0.0)
            };
            // wi in the half frame: rotate by −φh about z, then by −θh about y.
            let x1 = cp * wi.x + sp * wi.y;
            let y1 = cp * wi.y - sp * wi.x;
            let x2 = ct * x1 - st * wi.z;
            let z2 = st * x1 + ct * wi.z;
            let theta_d = atan2_first_quadrant((x2 * x2 + y1 * y1).sqrt(), z2.max(0.0));
            let phi_d = atan2_full(y1, x2);
            if FOUR {
                let phi_h = atan2_full(hy, hx);
                let wrap = |a: f64| if a < 0.0 { a + 2.0 * PI } else { a };
                *tk = [
                    m0.index(theta_h),
                    m1.index(wrap(phi_h)),
                    m2.index(theta_d),
                    m3.index(wrap(phi_d)),
                ];
            } else {
                // MERL's fold: φd and φd + π are the same pair with wi and wo swapped.
                let pd = if phi_d < 0.0 { phi_d + PI } else { phi_d };
                *tk = [m0.index(theta_h), m1.index(theta_d), m2.index(pd), 0.0];
            }
            *okk = wi.z > 0.0 && wo.z > 0.0;
        }
    }
}
