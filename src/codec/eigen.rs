//! Eigendecomposition of a small real symmetric matrix (the Tucker stage's Gram matrices, at
//! most 180 × 180) by the cyclic Jacobi method.
//!
//! Hand-written rather than a linear-algebra crate so that the encoder's bytes are the same on
//! every CPU: plain scalar f64 (no run-time SIMD dispatch, no FMA contraction, no threads), a
//! fixed row-cyclic sweep order and a fixed stopping test make every result a pure function of
//! the input bits. Jacobi is also accurate (small eigenvalues to high relative accuracy) and
//! fast enough here: a 180 × 180 matrix takes well under a second.

#![allow(clippy::needless_range_loop)] // Rotations index two rows and two columns at once.

/// A pair is rotated only while |a_pq| > TOLERANCE·√|a_pp|·√|a_qq|; the sweeps stop at the
/// first sweep that rotates nothing. This relative test (Demmel & Veselić 1992, "Jacobi's
/// method is more accurate than QR") keeps the small eigenvalues of a positive definite
/// Gram matrix, and their vectors, to high relative accuracy, where a test against ‖A‖ would
/// leave the eigenvectors of eigenvalues below 1e-16·‖A‖ as rounding noise.
const TOLERANCE: f64 = f64::EPSILON;
/// Cyclic Jacobi converges quadratically, in about 6–10 sweeps at n = 180; a matrix still
/// not diagonal after this many is reported instead of returned half-done.
const MAX_SWEEPS: usize = 50;

/// A = V Λ Vᵀ with the eigenvalues in nonincreasing order (ties: the earlier diagonal position
/// after the sweeps first) and each column of V with its largest-|·| entry positive (the first
/// such entry on ties), so the vectors of distinct eigenvalues are unique.
#[derive(Debug, Clone, PartialEq)]
pub struct SymmetricEigen {
    n: usize,
    values: Vec<f64>,
    /// Column-major: column j (n values) is the eigenvector of `values[j]`.
    vectors: Vec<f64>,
}

impl SymmetricEigen {
    /// Decomposes the symmetric `a` (n × n, row-major; only symmetric input is meaningful, the
    /// upper and lower triangles are both read). `None` for non-finite entries, a wrong length
    /// or (never seen) no convergence within `MAX_SWEEPS` sweeps.
    pub fn new(a: &[f64], n: usize) -> Option<Self> {
        if a.len() != n.checked_mul(n)? || a.iter().any(|x| !x.is_finite()) {
            return None;
        }
        // Power-of-two scaling is exact and keeps the sums of squares below overflow.
        let scale = power_of_two_near_inverse(a.iter().fold(0.0, |m: f64, x| m.max(x.abs())));
        let mut m: Vec<f64> = a.iter().map(|x| x * scale).collect();
        let mut v = vec![0.0; n * n];
        for i in 0..n {
            v[i * n + i] = 1.0;
        }
        let mut sweeps = 0;
        loop {
            let mut rotated = false;
            for p in 0..n {
                for q in p + 1..n {
                    rotated |= rotate(&mut m, &mut v, n, p, q);
                }
            }
            if !rotated {
                break;
            }
            sweeps += 1;
            if sweeps == MAX_SWEEPS {
                return None;
            }
        }
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&i, &j| m[j * n + j].total_cmp(&m[i * n + i]).then(i.cmp(&j)));
        let values = order.iter().map(|&i| m[i * n + i] / scale).collect();
        let mut vectors = Vec::with_capacity(n * n);
        for &i in &order {
            let col = &v[i * n..(i + 1) * n];
            let mut big = 0;
            for (k, x) in col.iter().enumerate() {
                if x.abs() > col[big].abs() {
                    big = k;
                }
            }
            let sign = if col[big] < 0.0 { -1.0 } else { 1.0 };
            vectors.extend(col.iter().map(|x| sign * x));
        }
        Some(Self { n, values, vectors })
    }

    /// Eigenvalues, largest first.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Eigenvector `j` (of `values()[j]`), unit length.
    pub fn vector(&self, j: usize) -> &[f64] {
        &self.vectors[j * self.n..(j + 1) * self.n]
    }
}

/// 2^-e for the exponent e of `max` (1 for 0 or subnormal `max`), clamped far from the
/// limits of f64, so that `max` × the result is in [1, 2).
fn power_of_two_near_inverse(max: f64) -> f64 {
    let biased = ((max.to_bits() >> 52) & 0x7ff) as i64;
    if biased == 0 {
        return 1.0;
    }
    let e = (biased - 1023).clamp(-1000, 1000);
    f64::from_bits(((1023 - e) as u64) << 52)
}

/// One Jacobi rotation A ← JᵀAJ, V ← VJ zeroing a_pq (p < q), with J = [[c, s], [−s, c]] in
/// rows/columns p, q; false (nothing done) when a_pq is already negligible.
// Golub & Van Loan, Matrix Computations (4th ed.), §8.5 "Jacobi methods", sym.schur2.
fn rotate(m: &mut [f64], v: &mut [f64], n: usize, p: usize, q: usize) -> bool {
    let apq = m[p * n + q];
    let app = m[p * n + p];
    let aqq = m[q * n + q];
    if apq.abs() <= TOLERANCE * app.abs().sqrt() * aqq.abs().sqrt() || apq == 0.0 {
        return false;
    }
    let tau = (aqq - app) / (2.0 * apq);
    // t = tan θ, the smaller root of t² + 2τt − 1 = 0 (|θ| ≤ π/4); 1/(2τ) once τ² would overflow.
    let t = if tau.abs() > 1e150 {
        0.5 / tau
    } else {
        let sign = if tau >= 0.0 { 1.0 } else { -1.0 };
        sign / (tau.abs() + (1.0 + tau * tau).sqrt())
    };
    let c = 1.0 / (1.0 + t * t).sqrt();
    let s = t * c;
    m[p * n + p] = app - t * apq;
    m[q * n + q] = aqq + t * apq;
    m[p * n + q] = 0.0;
    m[q * n + p] = 0.0;
    for k in 0..n {
        if k == p || k == q {
            continue;
        }
        let akp = m[k * n + p];
        let akq = m[k * n + q];
        let new_p = c * akp - s * akq;
        let new_q = s * akp + c * akq;
        m[k * n + p] = new_p;
        m[p * n + k] = new_p;
        m[k * n + q] = new_q;
        m[q * n + k] = new_q;
    }
    let (vp, vq) = v.split_at_mut(q * n);
    let vp = &mut vp[p * n..(p + 1) * n];
    let vq = &mut vq[..n];
    for (x, y) in vp.iter_mut().zip(vq.iter_mut()) {
        let (a, b) = (*x, *y);
        *x = c * a - s * b;
        *y = s * a + c * b;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// ‖A − VΛVᵀ‖_F / ‖A‖_F and max |VᵀV − I|.
    fn errors(a: &[f64], n: usize, e: &SymmetricEigen) -> (f64, f64) {
        let mut res = 0.0;
        let mut norm = 0.0;
        for i in 0..n {
            for j in 0..n {
                let r: f64 = (0..n)
                    .map(|k| e.vector(k)[i] * e.values()[k] * e.vector(k)[j])
                    .sum();
                res += (a[i * n + j] - r) * (a[i * n + j] - r);
                norm += a[i * n + j] * a[i * n + j];
            }
        }
        let mut orth: f64 = 0.0;
        for i in 0..n {
            for j in 0..n {
                let d: f64 = e
                    .vector(i)
                    .iter()
                    .zip(e.vector(j))
                    .map(|(x, y)| x * y)
                    .sum();
                orth = orth.max((d - if i == j { 1.0 } else { 0.0 }).abs());
            }
        }
        let rel = if norm > 0.0 {
            (res / norm).sqrt()
        } else {
            res.sqrt()
        };
        (rel, orth)
    }

    fn symmetric(n: usize, seed: u64) -> Vec<f64> {
        // splitmix64: a fixed, dependency-free source of test matrices.
        let mut state = seed;
        let mut next = || {
            state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..=i {
                let x = next();
                a[i * n + j] = x;
                a[j * n + i] = x;
            }
        }
        a
    }

    proptest! {
        #[test]
        fn reconstructs_random_symmetric(n in 1usize..40, seed: u64, log_scale in -100i32..100) {
            let scale = 10f64.powi(log_scale);
            let a: Vec<f64> = symmetric(n, seed).iter().map(|x| x * scale).collect();
            let e = SymmetricEigen::new(&a, n).unwrap();
            let (rel, orth) = errors(&a, n, &e);
            prop_assert!(rel <= 1e-12, "n {} rel {:e}", n, rel);
            prop_assert!(orth <= 1e-12, "n {} orth {:e}", n, orth);
            prop_assert!(e.values().windows(2).all(|w| w[0] >= w[1]));
            for j in 0..n {
                let v = e.vector(j);
                let big = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
                let first = v.iter().find(|x| x.abs() == big).unwrap();
                prop_assert!(*first > 0.0);
            }
        }
    }

    #[test]
    fn diagonal_is_sorted_with_unit_vectors() {
        let a = [2.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 5.0];
        let e = SymmetricEigen::new(&a, 3).unwrap();
        assert_eq!(e.values(), &[5.0, 2.0, -1.0]);
        assert_eq!(e.vector(0), &[0.0, 0.0, 1.0]);
        assert_eq!(e.vector(1), &[1.0, 0.0, 0.0]);
        assert_eq!(e.vector(2), &[0.0, 1.0, 0.0]);
    }

    #[test]
    fn two_by_two_matches_closed_form() {
        // [[2, 1], [1, 2]]: eigenvalues 3 and 1, vectors (1, 1)/√2 and (1, −1)/√2 up to sign.
        let e = SymmetricEigen::new(&[2.0, 1.0, 1.0, 2.0], 2).unwrap();
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!((e.values()[0] - 3.0).abs() < 1e-15 && (e.values()[1] - 1.0).abs() < 1e-15);
        assert!(e.vector(0).iter().all(|x| (x - h).abs() < 1e-15));
        // Both entries of the second vector have |·| = 1/√2: the first is made positive.
        assert!((e.vector(1)[0] - h).abs() < 1e-15 && (e.vector(1)[1] + h).abs() < 1e-15);
        // [[a, b], [b, d]]: λ = (a + d)/2 ± √(((a − d)/2)² + b²).
        let (a, b, d) = (1.0, 3.0, -2.0);
        let e = SymmetricEigen::new(&[a, b, b, d], 2).unwrap();
        let r = (((a - d) / 2.0) * ((a - d) / 2.0) + b * b).sqrt();
        assert!((e.values()[0] - ((a + d) / 2.0 + r)).abs() < 1e-14);
        assert!((e.values()[1] - ((a + d) / 2.0 - r)).abs() < 1e-14);
    }

    #[test]
    fn repeated_eigenvalues() {
        // I + 𝟙𝟙ᵀ (4 × 4): eigenvalue 5 once (vector 𝟙/2) and 1 three times.
        let n = 4;
        let a: Vec<f64> = (0..n * n)
            .map(|k| if k / n == k % n { 2.0 } else { 1.0 })
            .collect();
        let e = SymmetricEigen::new(&a, n).unwrap();
        assert!((e.values()[0] - 5.0).abs() < 1e-14);
        assert!(e.values()[1..].iter().all(|x| (x - 1.0).abs() < 1e-14));
        assert!(e.vector(0).iter().all(|x| (x - 0.5).abs() < 1e-14));
        let (rel, orth) = errors(&a, n, &e);
        assert!(rel < 1e-14 && orth < 1e-14, "{rel:e} {orth:e}");
        // Zero and scalar matrices are already diagonal.
        let z = SymmetricEigen::new(&[0.0; 9], 3).unwrap();
        assert_eq!(z.values(), &[0.0; 3]);
        assert_eq!(z.vector(1), &[0.0, 1.0, 0.0]);
    }

    #[test]
    fn rejects_non_finite_and_wrong_length() {
        assert!(SymmetricEigen::new(&[1.0, f64::NAN, f64::NAN, 1.0], 2).is_none());
        assert!(SymmetricEigen::new(&[f64::INFINITY], 1).is_none());
        assert!(SymmetricEigen::new(&[1.0, 2.0, 3.0], 2).is_none());
        assert_eq!(SymmetricEigen::new(&[], 0).unwrap().values(), &[] as &[f64]);
    }

    /// The largest Gram matrix the Tucker stage builds (180 × 180, a MERL θh axis); it must
    /// finish (well under a second in release) and still be accurate at that size.
    #[test]
    fn largest_tucker_size() {
        let n = 180;
        let a = symmetric(n, 7);
        let e = SymmetricEigen::new(&a, n).unwrap();
        let (rel, orth) = errors(&a, n, &e);
        assert!(rel < 1e-12 && orth < 1e-12, "{rel:e} {orth:e}");
        // Same bits on a second run.
        assert_eq!(SymmetricEigen::new(&a, n).unwrap(), e);
    }
}
