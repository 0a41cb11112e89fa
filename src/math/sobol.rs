//! A four-dimensional Sobol sequence (Sobol 1967), Owen-scrambled by hashing (Burley 2020,
//! "Practical Hash-based Owen Scrambling"): points that give every region of the unit
//! hypercube its share. The first 2^m points of each dimension fill each of its 2^m
//! intervals of length 2^-m exactly once, scrambled or not.
//!
//! Why the planner uses it: a pseudo-random set of 131,072 direction pairs has no point in a
//! region holding 1e-5 of the pairs one time in four (Poisson, mean 1.3), and when a codec's
//! largest errors sit in such a region (beside the horizon, where f grows and uniform pairs
//! are rare) the variance the set shows is too small. A stratified set holds its share of
//! every such region.

/// Direction numbers m_k of dimensions 2–4 (Joe & Kuo 2008, `new-joe-kuo-6.21201`):
/// (degree s, coefficients a, initial m_1 … m_s). Dimension 1 is the van der Corput sequence.
const POLYNOMIALS: [(u32, u32, [u32; 3]); 3] =
    [(1, 0, [1, 0, 0]), (2, 1, [1, 3, 0]), (3, 1, [1, 3, 1])];

/// The 32 direction numbers v_k = m_k · 2^(32−k) of each dimension.
const fn directions() -> [[u32; 32]; 4] {
    let mut v = [[0u32; 32]; 4];
    let mut k = 0;
    while k < 32 {
        v[0][k] = 1 << (31 - k);
        k += 1;
    }
    let mut d = 0;
    while d < 3 {
        let (s, a, init) = POLYNOMIALS[d];
        let s = s as usize;
        // m_k for k = 1 … 32 (index k − 1), by the recurrence
        // m_k = 2a₁m_{k−1} ⊕ 2²a₂m_{k−2} ⊕ … ⊕ 2^s m_{k−s} ⊕ m_{k−s}.
        let mut m = [0u64; 32];
        let mut k = 0;
        while k < 32 {
            if k < s {
                m[k] = init[k] as u64;
            } else {
                let mut x = m[k - s] ^ (m[k - s] << s);
                let mut j = 1;
                while j < s {
                    if (a >> (s - 1 - j)) & 1 == 1 {
                        x ^= m[k - j] << j;
                    }
                    j += 1;
                }
                m[k] = x;
            }
            v[d + 1][k] = (m[k] << (31 - k)) as u32;
            k += 1;
        }
        d += 1;
    }
    v
}

const DIRECTIONS: [[u32; 32]; 4] = directions();

/// Burley's hash-based nested uniform scramble of the bits of `x` (most significant first).
fn owen_scramble(x: u32, seed: u32) -> u32 {
    let mut x = x.reverse_bits();
    // Laine–Karras permutation with Burley's constants: each bit is flipped by a hash of the
    // bits below it (above it, before the reversal).
    x = x.wrapping_add(seed);
    x ^= x.wrapping_mul(0x6c50_b47c);
    x ^= x.wrapping_mul(0xb82f_1e52);
    x ^= x.wrapping_mul(0xc7af_e638);
    x ^= x.wrapping_mul(0x8d22_f6e6);
    x.reverse_bits()
}

/// The scrambled Sobol points of one seed, point after point, each coordinate in [0, 1).
pub struct Sobol4 {
    index: u32,
    state: [u32; 4],
    seeds: [u32; 4],
    /// Low bits below the sequence's 32, so that coordinates are not confined to 2^-32 steps.
    jitter: crate::math::SplitMix64,
}

impl Sobol4 {
    pub fn new(seed: u64) -> Sobol4 {
        let mut rng = crate::math::SplitMix64::new(seed ^ 0x536f_626f_6c34);
        let seeds = std::array::from_fn(|_| (rng.next_u64() >> 32) as u32);
        Sobol4 {
            index: 0,
            state: [0; 4],
            seeds,
            jitter: rng,
        }
    }
}

impl Iterator for Sobol4 {
    type Item = [f64; 4];

    /// Point i in Gray-code order (the same set of the first 2^m points as in natural order);
    /// `None` after 2^32 points.
    fn next(&mut self) -> Option<[f64; 4]> {
        let i = self.index;
        if i == u32::MAX {
            return None;
        }
        let out = std::array::from_fn(|d| {
            let bits = owen_scramble(self.state[d], self.seeds[d]);
            (bits as f64 + self.jitter.next_f64()) * (1.0 / 4_294_967_296.0)
        });
        self.index += 1;
        let c = self.index.trailing_zeros() as usize;
        for (x, v) in self.state.iter_mut().zip(&DIRECTIONS) {
            *x ^= v[c.min(31)];
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_direction_numbers() {
        // m_k of dimension 2 are 1, 3, 5, 15, 17, 51 (x + 1); dimension 3's 1, 3, 3, 9, 29
        // (x² + x + 1, m 1, 3; Joe & Kuo's table).
        let m = |d: usize, k: usize| DIRECTIONS[d][k] >> (31 - k);
        assert_eq!(
            (0..6).map(|k| m(1, k)).collect::<Vec<_>>(),
            [1, 3, 5, 15, 17, 51]
        );
        assert_eq!(
            (0..5).map(|k| m(2, k)).collect::<Vec<_>>(),
            [1, 3, 3, 9, 29]
        );
        // Every m_k is odd and below 2^k (a valid direction number).
        for d in 0..4 {
            for k in 0..32 {
                let v = m(d, k) as u64;
                assert!(v % 2 == 1 && v < 1 << (k + 1), "dimension {d}, k {k}: {v}");
            }
        }
    }

    /// The first 2^m points fill each interval of 2^-m of every dimension once, and every
    /// cell of 2^-a × 2^-b of each pair of dimensions (a + b = m − t, t ≤ 2 for these
    /// dimensions) equally: the stratification the planner relies on.
    #[test]
    fn the_points_are_stratified() {
        let m = 12;
        let n = 1usize << m;
        let pts: Vec<[f64; 4]> = Sobol4::new(7).take(n).collect();
        for d in 0..4 {
            let mut seen = vec![0u32; n];
            for p in &pts {
                seen[(p[d] * n as f64) as usize] += 1;
            }
            assert!(seen.iter().all(|&c| c == 1), "dimension {d}");
        }
        for d0 in 0..4 {
            for d1 in d0 + 1..4 {
                let (a, b) = (5, 5);
                let mut seen = vec![0u32; 1 << (a + b)];
                for p in &pts {
                    let x = (p[d0] * (1 << a) as f64) as usize;
                    let y = (p[d1] * (1 << b) as f64) as usize;
                    seen[(x << b) | y] += 1;
                }
                let per = (n >> (a + b)) as u32;
                assert!(seen.iter().all(|&c| c == per), "dimensions {d0}, {d1}");
            }
        }
        // Another seed, other points.
        let other: Vec<[f64; 4]> = Sobol4::new(8).take(4).collect();
        assert_ne!(other[..], pts[..4]);
    }
}
