//! Every cell's direction pair from per-axis sines and cosines.
//!
//! [`Grid::cell_dirs`] computes four `sin_cos` per cell, the largest cost of tabulating a
//! model without a structured kernel on a 64⁴ grid (16.8 M cells, 60 M `sin_cos`). The
//! angles of a cell are its axes' samples, so each `sin_cos` can be taken once per axis
//! sample; the directions are then made with the very operations, in the same order, that
//! [`Vec3::from_spherical`], [`Vec3::rotate_y`], [`Vec3::rotate_z`] and [`Vec3::mirror`]
//! perform: the same bits as [`Grid::cell_dirs`] (tested on every kind).

use super::{Grid, GridKind};
use crate::geometry::Vec3;
use crate::math::FRAC_PI_2;

/// sin and cos of every sample of one axis; `cos_polar` is the cosine as
/// [`Vec3::from_spherical`] takes it for a polar angle (exactly 0 at π/2).
struct AxisTrig {
    sin: Vec<f64>,
    cos: Vec<f64>,
    cos_polar: Vec<f64>,
}

impl AxisTrig {
    fn new(samples: impl Iterator<Item = f64>) -> AxisTrig {
        let mut t = AxisTrig {
            sin: Vec::new(),
            cos: Vec::new(),
            cos_polar: Vec::new(),
        };
        for a in samples {
            let (s, c) = a.sin_cos();
            t.sin.push(s);
            t.cos.push(c);
            t.cos_polar.push(if a == FRAC_PI_2 { 0.0 } else { c });
        }
        t
    }

    /// The axis fixed at angle 0 (φi of spherical3, φh of halfdiff3).
    fn zero() -> AxisTrig {
        AxisTrig::new(std::iter::once(0.0))
    }
}

/// A grid's cell directions ([`Grid::cell_directions`]).
pub struct CellDirections {
    kind: GridKind,
    /// Per storage axis, then the zero axis last.
    axes: Vec<AxisTrig>,
}

impl Grid {
    /// The per-axis tables of [`CellDirections`]: one `sin_cos` per axis sample.
    pub fn cell_directions(&self) -> CellDirections {
        let mut axes: Vec<AxisTrig> = self
            .axes
            .iter()
            .map(|a| AxisTrig::new((0..a.n).map(|i| a.sample(i))))
            .collect();
        axes.push(AxisTrig::zero());
        CellDirections {
            kind: self.kind,
            axes,
        }
    }
}

impl CellDirections {
    /// [`Vec3::from_spherical`] of sample `i` of polar axis `t` and sample `j` of azimuth
    /// axis `p`.
    #[inline]
    fn spherical(&self, t: usize, i: usize, p: usize, j: usize) -> Vec3 {
        let (st, ct) = (self.axes[t].sin[i], self.axes[t].cos_polar[i]);
        let (sp, cp) = (self.axes[p].sin[j], self.axes[p].cos[j]);
        Vec3::new(st * cp, st * sp, ct)
    }

    /// The direction pair of the cell with axis indices `idx` (storage order): the bits of
    /// [`Grid::cell_dirs`].
    #[inline]
    pub fn at(&self, idx: &[usize]) -> (Vec3, Vec3) {
        let zero = self.axes.len() - 1;
        match self.kind {
            GridKind::Spherical4 => (
                self.spherical(0, idx[0], 1, idx[1]),
                self.spherical(2, idx[2], 3, idx[3]),
            ),
            GridKind::Spherical3 => (
                self.spherical(0, idx[0], zero, 0),
                self.spherical(1, idx[1], 2, idx[2]),
            ),
            GridKind::Halfdiff3 => self.half_diff((0, idx[0]), (zero, 0), (1, idx[1]), (2, idx[2])),
            GridKind::Halfdiff4 => {
                self.half_diff((0, idx[0]), (1, idx[1]), (2, idx[2]), (3, idx[3]))
            }
        }
    }

    /// [`crate::geometry::HalfDiff::to_dirs`] of (θh, φh, θd, φd), each an (axis, sample).
    #[inline]
    fn half_diff(
        &self,
        th: (usize, usize),
        ph: (usize, usize),
        td: (usize, usize),
        pd: (usize, usize),
    ) -> (Vec3, Vec3) {
        let d = self.spherical(td.0, td.1, pd.0, pd.1);
        let (sy, cy) = (self.axes[th.0].sin[th.1], self.axes[th.0].cos[th.1]);
        let (sz, cz) = (self.axes[ph.0].sin[ph.1], self.axes[ph.0].cos[ph.1]);
        let back = |v: Vec3| {
            // rotate_y(θh), then rotate_z(φh).
            let y = Vec3::new(cy * v.x + sy * v.z, v.y, -sy * v.x + cy * v.z);
            Vec3::new(cz * y.x - sz * y.y, sz * y.x + cz * y.y, y.z)
        };
        (back(d), back(d.mirror()))
    }
}

#[cfg(test)]
mod tests {
    use crate::grid::parse_grid_spec;

    /// The per-axis directions are the per-cell ones, bit for bit, on every kind, with warps,
    /// edge placement (samples on the horizon) and θmax.
    #[test]
    fn the_per_axis_directions_are_cell_dirs() {
        for spec in [
            "spherical4:6x8x5x7",
            "spherical3:9x7x12,at=edge",
            "spherical3:8x8x16,warp=sqrt,theta-max=60",
            "halfdiff3:90x90x180,warp=sqrt/linear/linear,at=edge",
            "halfdiff3:7x9x10",
            "halfdiff4:9x8x7x10",
            "halfdiff4:6x6x6x6,at=edge",
        ] {
            let g = parse_grid_spec(spec).unwrap();
            let dirs = g.cell_directions();
            let d = g.axes().len();
            let mut idx = [0usize; 4];
            let bits = |v: crate::geometry::Vec3| v.to_array().map(f64::to_bits);
            for cell in 0..g.cells() {
                g.unflatten(cell, &mut idx[..d]);
                let (a, b) = g.cell_dirs(&idx[..d]);
                let (x, y) = dirs.at(&idx[..d]);
                assert!(
                    bits(a) == bits(x) && bits(b) == bits(y),
                    "{spec}: cell {cell} {idx:?}: {a:?} {b:?} against {x:?} {y:?}"
                );
            }
        }
    }
}
