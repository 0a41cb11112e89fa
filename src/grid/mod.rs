//! Parameterizations of the 4D space of direction pairs: grids that know their axes.
//!
//! A [`Grid`] is one of four kinds ([`GridKind`]); each has a fixed list of angular
//! quantities ([`Quantity`]) in storage order (C order: the last axis is the fastest). Each axis
//! has a resolution, a warp from index space to angle ([`Warp`]) and a sample placement
//! ([`Placement`]). Storage order and conventions are documented in `docs/parameterizations.md`.

mod dirs;
mod spec;

use crate::geometry::{HalfDiff, Vec3};
use crate::math::{FRAC_PI_2, PI};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

pub use dirs::CellDirections;
pub use spec::parse_grid_spec;

/// The parameterization.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GridKind {
    /// (θi, φi, θo, φo): regular spherical, any BRDF.
    Spherical4,
    /// (θi, θo, Δφ): isotropic BRDFs; Δφ = |φo − φi| folded into [0, π] (assumes the mirror
    /// symmetry y → −y that isotropic, reciprocal BRDFs have).
    Spherical3,
    /// (θh, θd, φd): Rusinkiewicz (1998) for isotropic BRDFs; φd folded into [0, π) by
    /// reciprocity, as in MERL.
    Halfdiff3,
    /// (θh, φh, θd, φd): Rusinkiewicz for anisotropic BRDFs, φd over the full circle.
    Halfdiff4,
}

impl GridKind {
    pub fn name(self) -> &'static str {
        match self {
            GridKind::Spherical4 => "spherical4",
            GridKind::Spherical3 => "spherical3",
            GridKind::Halfdiff3 => "halfdiff3",
            GridKind::Halfdiff4 => "halfdiff4",
        }
    }

    /// The axis quantities in storage order (last fastest).
    pub fn quantities(self) -> &'static [Quantity] {
        use Quantity::*;
        match self {
            GridKind::Spherical4 => &[ThetaI, PhiI, ThetaO, PhiO],
            GridKind::Spherical3 => &[ThetaI, ThetaO, DeltaPhi],
            GridKind::Halfdiff3 => &[ThetaH, ThetaD, PhiD],
            GridKind::Halfdiff4 => &[ThetaH, PhiH, ThetaD, PhiD],
        }
    }

    /// True for the half/difference kinds (whose cells can lie below the horizon).
    pub fn is_half_diff(self) -> bool {
        matches!(self, GridKind::Halfdiff3 | GridKind::Halfdiff4)
    }

    /// True when the kind can only represent isotropic BRDFs.
    pub fn is_isotropic(self) -> bool {
        matches!(self, GridKind::Spherical3 | GridKind::Halfdiff3)
    }

    /// Angular range [lo, hi] of a quantity on this kind of grid and whether it is periodic.
    fn range(self, q: Quantity) -> (f64, f64, bool) {
        use Quantity::*;
        match q {
            ThetaI | ThetaO | ThetaH | ThetaD => (0.0, FRAC_PI_2, false),
            PhiI | PhiO | PhiH => (0.0, 2.0 * PI, true),
            // Mirror-symmetric about 0 and π: clamping at the ends is the reflection.
            DeltaPhi => (0.0, PI, false),
            // Reciprocity maps φd to φd + π, so the folded axis is periodic with period π.
            PhiD if self == GridKind::Halfdiff3 => (0.0, PI, true),
            PhiD => (0.0, 2.0 * PI, true),
        }
    }
}

/// An angular quantity that a grid axis samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Quantity {
    ThetaI,
    PhiI,
    ThetaO,
    PhiO,
    DeltaPhi,
    ThetaH,
    PhiH,
    ThetaD,
    PhiD,
}

impl Quantity {
    pub fn name(self) -> &'static str {
        match self {
            Quantity::ThetaI => "theta_i",
            Quantity::PhiI => "phi_i",
            Quantity::ThetaO => "theta_o",
            Quantity::PhiO => "phi_o",
            Quantity::DeltaPhi => "delta_phi",
            Quantity::ThetaH => "theta_h",
            Quantity::PhiH => "phi_h",
            Quantity::ThetaD => "theta_d",
            Quantity::PhiD => "phi_d",
        }
    }
    fn is_theta(self) -> bool {
        matches!(
            self,
            Quantity::ThetaI | Quantity::ThetaO | Quantity::ThetaH | Quantity::ThetaD
        )
    }
}

/// The map from normalized index space u ∈ [0, 1] to the axis range.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Warp {
    /// angle = lo + (hi − lo) u.
    Linear,
    /// angle = lo + (hi − lo) u², i.e. index ∝ sqrt(angle): dense near 0, as MERL's θh
    /// (Matusik et al. 2003) where specular peaks live.
    Sqrt,
    /// angle = lo + (hi − lo)(1 − (1 − u)²): dense near the upper end, the mirror of
    /// [`Warp::Sqrt`], for θ axes whose source changes fastest at the horizon (Fresnel and
    /// shadowing at grazing; measured files whose f·cos θ is finite there). The last
    /// centred sample of n sits 90°/(4n²) from the horizon instead of 90°/(2n).
    Grazing,
}

impl Warp {
    #[inline]
    fn forward(self, u: f64) -> f64 {
        match self {
            Warp::Linear => u,
            Warp::Sqrt => u * u,
            Warp::Grazing => {
                let v = 1.0 - u;
                1.0 - v * v
            }
        }
    }
    #[inline]
    fn inverse(self, t: f64) -> f64 {
        match self {
            Warp::Linear => t,
            Warp::Sqrt => t.max(0.0).sqrt(),
            Warp::Grazing => 1.0 - (1.0 - t).max(0.0).sqrt(),
        }
    }
    /// d(angle fraction)/du at u.
    #[inline]
    fn derivative(self, u: f64) -> f64 {
        match self {
            Warp::Linear => 1.0,
            Warp::Sqrt => 2.0 * u,
            Warp::Grazing => 2.0 * (1.0 - u),
        }
    }
}

/// Where in its index-space cell each sample sits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Placement {
    /// u = (i + ½)/n: cell centres (no sample on a boundary; the default).
    Center,
    /// u = i/n: lower cell edges, MERL's convention (θh = (i/90)² π/2 ...).
    LowerEdge,
}

impl Placement {
    #[inline]
    fn offset(self) -> f64 {
        match self {
            Placement::Center => 0.5,
            Placement::LowerEdge => 0.0,
        }
    }
}

/// One axis of a grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Axis {
    pub quantity: Quantity,
    pub n: usize,
    pub warp: Warp,
    pub placement: Placement,
    /// Angular range in radians (derived from kind, quantity and the grid's θ limit).
    #[serde(skip)]
    lo: f64,
    #[serde(skip)]
    hi: f64,
    #[serde(skip)]
    periodic: bool,
}

impl Axis {
    /// The angle of sample `i` (radians).
    #[inline]
    pub fn sample(&self, i: usize) -> f64 {
        let u = (i as f64 + self.placement.offset()) / self.n as f64;
        self.lo + (self.hi - self.lo) * self.warp.forward(u)
    }

    /// The continuous index of angle `x`: `sample(i) == x` ⇔ result = i.
    #[inline]
    pub fn continuous_index(&self, x: f64) -> f64 {
        let t = (x - self.lo) / (self.hi - self.lo);
        self.warp.inverse(t) * self.n as f64 - self.placement.offset()
    }

    pub fn range(&self) -> (f64, f64) {
        (self.lo, self.hi)
    }
    pub fn is_periodic(&self) -> bool {
        self.periodic
    }

    /// Width in radians of the cell of sample `i` (for measure weights).
    fn cell_width(&self, i: usize) -> f64 {
        let u = (i as f64 + 0.5) / self.n as f64;
        (self.hi - self.lo) * self.warp.derivative(u) / self.n as f64
    }
}

/// Largest number of cells a grid may have (keeps a hostile header from asking for
/// terabytes; 2^31 cells of RGB f32 is already 24 GiB).
pub const MAX_CELLS: usize = 1 << 31;
/// Largest resolution of one axis.
pub const MAX_AXIS_RESOLUTION: usize = 1 << 16;

/// What a table interpolates between its samples.
///
/// Plain: f itself. Cosine: f·cos θi·cos θo, divided by the query's cos θi·cos θo after the
/// sum. A source whose f grows like 1/cos θ at the horizon (RGL files: their f·cos θo stays
/// finite there, `docs/rgl.md`; Fresnel or shadowing-free microfacet lobes at grazing) is
/// smooth in the weighted quantity, while f itself changes faster than any bin can follow
/// in the last degree before the horizon. The values stored at the samples are f either
/// way; only what happens between them differs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InterpWeight {
    #[default]
    None,
    Cosine,
}

impl InterpWeight {
    pub fn is_none(&self) -> bool {
        *self == InterpWeight::None
    }
    /// The name in grid specs (`weight=cosine`).
    pub fn name(self) -> &'static str {
        match self {
            InterpWeight::None => "none",
            InterpWeight::Cosine => "cosine",
        }
    }
}

/// What a half/difference grid stores in the cells whose sample pair lies below the horizon.
///
/// Half/difference coordinates do not follow the horizon: near grazing, a query's cell has
/// corners whose (wi, wo) dips below it. `Cut` leaves those cells invalid, so a query beside
/// the horizon is interpolated from the valid corners alone: the value of cells up to a
/// θd step away, where a BRDF that grows or falls toward grazing (Fresnel, shadowing,
/// 1/cos θ) is far from the query's: the few percent of uniform queries with such a corner
/// carry most of a narrow peak's squared log error on the MERL grid. `Extend`
/// stores at each such cell the source's value at the nearest pair above the horizon (every
/// direction below cos θ = [`HORIZON_COS`] raised to it, azimuth kept) and interpolates from
/// it: the values beside the horizon are then held on both sides of it (a constant
/// continuation: no value the source does not take). Gold α 0.01 over a 0.002 body on the
/// MERL grid in log space, 10⁶ uniform pairs: log_rmse 2.2e-3 → 7.1e-4
/// (docs/parameterizations.md). Queries at or below the horizon still give 0.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Horizon {
    #[default]
    Cut,
    Extend,
}

impl Horizon {
    pub fn is_cut(&self) -> bool {
        *self == Horizon::Cut
    }
    /// The name in grid specs (`horizon=extend`).
    pub fn name(self) -> &'static str {
        match self {
            Horizon::Cut => "cut",
            Horizon::Extend => "extend",
        }
    }
    /// The cosine a direction below the horizon is raised to for its cell's value: 0 when
    /// cut (no pair there is in the domain), [`HORIZON_COS`] when extended.
    pub fn raised_cos(self) -> f64 {
        match self {
            Horizon::Cut => 0.0,
            Horizon::Extend => HORIZON_COS,
        }
    }
}

/// cos θ of the pair an [`Horizon::Extend`] cell below the horizon is given the value of:
/// 0.057° above the horizon. Any cosine well below the smallest θd step (1° on the MERL grid,
/// cos = 0.017) serves; at 1e-3 a bounded source has its limit value there to within its
/// change over 0.06°.
pub const HORIZON_COS: f64 = 1e-3;

/// `w` raised to cos θ = [`HORIZON_COS`] along its azimuth when it lies below that (azimuth
/// 0 for a direction straight down, which has none).
pub fn raised_to_horizon(w: Vec3) -> Vec3 {
    if w.z >= HORIZON_COS {
        return w;
    }
    let r = (w.x * w.x + w.y * w.y).sqrt();
    let s = (1.0 - HORIZON_COS * HORIZON_COS).sqrt();
    if r > 0.0 {
        Vec3::new(w.x / r * s, w.y / r * s, HORIZON_COS)
    } else {
        Vec3::new(s, 0.0, HORIZON_COS)
    }
}

/// The space the neighbours' values are combined in.
///
/// Linear: the weighted mean of the (possibly cosine-weighted) values. Log: the weighted mean
/// of asinh(v/s), mapped back by s·sinh — a geometric mean for values well above the scale s
/// and the linear mean well below it. A specular lobe is close to exp(−c·θh²) (Beckmann,
/// Ward) or a power of a quadratic (GGX), so its logarithm is smooth where the values
/// themselves fall by decades between two samples: linear interpolation of a narrow peak's
/// flank overestimates it by the ratio of neighbouring samples, log interpolation follows it.
/// The scale keeps values near zero (and of either sign) well defined; `pack` derives it
/// from the metrics' own floor (1e-3 × the mean value, spec/metrics.md). Nearest lookups
/// return the sample itself in either space.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InterpSpace {
    #[default]
    Linear,
    Log {
        /// s > 0, finite: below it the mean is close to linear.
        scale: f64,
    },
}

impl InterpSpace {
    pub fn is_linear(&self) -> bool {
        *self == InterpSpace::Linear
    }
    /// The name in grid descriptions (`log:1.234e-3`: four digits for a reader; headers keep
    /// the exact value).
    pub fn name(self) -> String {
        match self {
            InterpSpace::Linear => "linear".to_string(),
            InterpSpace::Log { scale } => format!("log:{scale:.3e}"),
        }
    }
    /// A log space of scale `scale`, checked.
    pub fn log(scale: f64) -> Result<InterpSpace> {
        if scale.is_finite() && scale > 0.0 && scale.recip().is_finite() {
            Ok(InterpSpace::Log { scale })
        } else {
            Err(Error::input(format!(
                "interpolation space log: scale {} is not a finite positive number",
                crate::model::params::fmt_num(scale)
            )))
        }
    }
}

/// A parameterization of direction pairs with a resolution, warp and placement per axis.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    kind: GridKind,
    axes: Vec<Axis>,
    /// Domain limit: cells (and queries) with θi or θo above it are outside the table.
    theta_max: Option<f64>,
    /// The limit in degrees as given, written to headers as is: rad → deg → rad does not
    /// always return the same f64, so a re-derived value could read back as another grid.
    theta_max_deg: Option<f64>,
    /// What is interpolated between samples.
    weight: InterpWeight,
    /// The space it is interpolated in.
    space: InterpSpace,
    /// What the cells below the horizon hold.
    horizon: Horizon,
}

/// Serialized form of a grid (what headers store): validated on the way in.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GridDesc {
    pub kind: GridKind,
    pub axes: Vec<AxisDesc>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_max_deg: Option<f64>,
    /// Absent for plain interpolation: headers of such grids are unchanged, byte for byte.
    #[serde(default, skip_serializing_if = "InterpWeight::is_none")]
    pub interp_weight: InterpWeight,
    /// Absent for linear interpolation (headers of such grids are unchanged).
    #[serde(default, skip_serializing_if = "InterpSpace::is_linear")]
    pub interp_space: InterpSpace,
    /// Absent for [`Horizon::Cut`] (headers of such grids are unchanged).
    #[serde(default, skip_serializing_if = "Horizon::is_cut")]
    pub horizon: Horizon,
}

/// Serialized form of an axis.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AxisDesc {
    pub quantity: Quantity,
    pub n: usize,
    pub warp: Warp,
    pub placement: Placement,
}

impl Grid {
    /// Builds a grid; `axes` are (n, warp, placement) in the kind's storage order.
    pub fn new(
        kind: GridKind,
        axes: &[(usize, Warp, Placement)],
        theta_max_deg: Option<f64>,
    ) -> Result<Grid> {
        let qs = kind.quantities();
        if axes.len() != qs.len() {
            return Err(Error::input(format!(
                "grid {}: {} axes given, expected {} ({})",
                kind.name(),
                axes.len(),
                qs.len(),
                qs.iter().map(|q| q.name()).collect::<Vec<_>>().join(", ")
            )));
        }
        let theta_max_deg = match theta_max_deg {
            None => None,
            Some(d) if d.is_finite() && d > 0.0 && d <= 90.0 => {
                if d == 90.0 {
                    None
                } else {
                    Some(d)
                }
            }
            Some(d) => {
                return Err(Error::input(format!(
                    "grid: theta-max = {} is out of range (0, 90] degrees",
                    crate::model::params::fmt_num(d)
                )));
            }
        };
        let theta_max = theta_max_deg.map(f64::to_radians);
        let mut out = Vec::with_capacity(qs.len());
        let mut cells: usize = 1;
        for (&q, &(n, warp, placement)) in qs.iter().zip(axes) {
            if n == 0 || n > MAX_AXIS_RESOLUTION {
                return Err(Error::input(format!(
                    "grid {}: axis {} resolution {n} is out of range [1, {MAX_AXIS_RESOLUTION}]",
                    kind.name(),
                    q.name()
                )));
            }
            cells = cells.saturating_mul(n);
            let (lo, mut hi, periodic) = kind.range(q);
            if periodic && warp != Warp::Linear {
                return Err(Error::input(format!(
                    "grid {}: axis {} is periodic and needs warp linear (got {:?})",
                    kind.name(),
                    q.name(),
                    warp
                )));
            }
            // Spherical grids spend their θ samples on the stored domain only.
            if let (Some(tm), true) = (theta_max, matches!(q, Quantity::ThetaI | Quantity::ThetaO))
            {
                hi = tm;
            }
            out.push(Axis {
                quantity: q,
                n,
                warp,
                placement,
                lo,
                hi,
                periodic,
            });
        }
        if cells > MAX_CELLS {
            return Err(Error::input(format!(
                "grid {}: {cells} cells exceed the limit of {MAX_CELLS}",
                kind.name()
            )));
        }
        Ok(Grid {
            kind,
            axes: out,
            theta_max,
            theta_max_deg,
            weight: InterpWeight::None,
            space: InterpSpace::Linear,
            horizon: Horizon::Cut,
        })
    }

    /// MERL's grid (Matusik et al. 2003): halfdiff3 90×90×180, sqrt θh, lower edges.
    pub fn merl() -> Grid {
        Grid::new(
            GridKind::Halfdiff3,
            &[
                (90, Warp::Sqrt, Placement::LowerEdge),
                (90, Warp::Linear, Placement::LowerEdge),
                (180, Warp::Linear, Placement::LowerEdge),
            ],
            None,
        )
        .expect("the MERL grid is valid")
    }

    pub fn from_desc(d: &GridDesc) -> Result<Grid> {
        let qs = d.kind.quantities();
        if d.axes.len() != qs.len() || d.axes.iter().zip(qs).any(|(a, q)| a.quantity != *q) {
            return Err(Error::input(format!(
                "grid {}: axes must be {}",
                d.kind.name(),
                qs.iter().map(|q| q.name()).collect::<Vec<_>>().join(", ")
            )));
        }
        let axes: Vec<_> = d.axes.iter().map(|a| (a.n, a.warp, a.placement)).collect();
        let space = match d.interp_space {
            InterpSpace::Linear => InterpSpace::Linear,
            InterpSpace::Log { scale } => InterpSpace::log(scale)?,
        };
        Grid::new(d.kind, &axes, d.theta_max_deg)?
            .with_weight(d.interp_weight)
            .with_space(space)
            .with_horizon(d.horizon)
    }

    /// The same samples with `weight` interpolated between them.
    pub fn with_weight(mut self, weight: InterpWeight) -> Grid {
        self.weight = weight;
        self
    }

    /// What is interpolated between samples.
    pub fn weight(&self) -> InterpWeight {
        self.weight
    }

    /// The same samples interpolated in `space` (a checked [`InterpSpace`]).
    pub fn with_space(mut self, space: InterpSpace) -> Grid {
        self.space = space;
        self
    }

    /// The space values are interpolated in.
    pub fn space(&self) -> InterpSpace {
        self.space
    }

    /// The same samples with `horizon` below the horizon; [`Horizon::Extend`] only on
    /// half/difference grids (a spherical grid's samples all lie above the horizon).
    pub fn with_horizon(mut self, horizon: Horizon) -> Result<Grid> {
        if horizon == Horizon::Extend && !self.kind.is_half_diff() {
            return Err(Error::input(format!(
                "grid {}: horizon=extend applies to halfdiff3 and halfdiff4 grids, whose cells \
                 can lie below the horizon (every {} sample lies above it)",
                self.kind.name(),
                self.kind.name()
            )));
        }
        self.horizon = horizon;
        Ok(self)
    }

    /// What the cells below the horizon hold.
    pub fn horizon(&self) -> Horizon {
        self.horizon
    }

    /// The pair whose value a cell with sample pair (`wi`, `wo`) holds, or `None` when the
    /// cell is outside the stored domain: the pair itself above the horizon, and on an
    /// [`Horizon::Extend`] grid a pair below it raised to the horizon ([`raised_to_horizon`]).
    #[inline]
    pub fn value_pair(&self, wi: Vec3, wo: Vec3) -> Option<(Vec3, Vec3)> {
        if wi.z > 0.0 && wo.z > 0.0 {
            return self.in_domain(wi, wo).then_some((wi, wo));
        }
        if self.horizon == Horizon::Extend {
            let (a, b) = (raised_to_horizon(wi), raised_to_horizon(wo));
            if self.in_domain(a, b) {
                return Some((a, b));
            }
        }
        None
    }

    pub fn desc(&self) -> GridDesc {
        GridDesc {
            kind: self.kind,
            axes: self
                .axes
                .iter()
                .map(|a| AxisDesc {
                    quantity: a.quantity,
                    n: a.n,
                    warp: a.warp,
                    placement: a.placement,
                })
                .collect(),
            theta_max_deg: self.theta_max_deg,
            interp_weight: self.weight,
            interp_space: self.space,
            horizon: self.horizon,
        }
    }

    pub fn kind(&self) -> GridKind {
        self.kind
    }
    pub fn axes(&self) -> &[Axis] {
        &self.axes
    }
    pub fn theta_max(&self) -> Option<f64> {
        self.theta_max
    }
    /// θmax in degrees as given (no round trip through radians).
    pub fn theta_max_deg(&self) -> Option<f64> {
        self.theta_max_deg
    }
    pub fn shape(&self) -> Vec<usize> {
        self.axes.iter().map(|a| a.n).collect()
    }
    pub fn cells(&self) -> usize {
        self.axes.iter().map(|a| a.n).product()
    }

    /// A compact human description, e.g. `halfdiff3 90x90x180 (sqrt,linear,linear; lower_edge)`.
    pub fn describe(&self) -> String {
        let dims: Vec<String> = self.axes.iter().map(|a| a.n.to_string()).collect();
        let warps: Vec<String> = self
            .axes
            .iter()
            .map(|a| format!("{:?}", a.warp).to_lowercase())
            .collect();
        let placements: Vec<&str> = self
            .axes
            .iter()
            .map(|a| match a.placement {
                Placement::Center => "center",
                Placement::LowerEdge => "edge",
            })
            .collect();
        let mut s = format!(
            "{} {} (warp {}; at {})",
            self.kind.name(),
            dims.join("x"),
            warps.join("/"),
            placements.join("/")
        );
        if let Some(d) = self.theta_max_deg {
            s.push_str(&format!("; theta-max {d}°"));
        }
        if !self.weight.is_none() {
            s.push_str(&format!("; weight {}", self.weight.name()));
        }
        if !self.space.is_linear() {
            s.push_str(&format!("; space {}", self.space.name()));
        }
        if !self.horizon.is_cut() {
            s.push_str(&format!("; horizon {}", self.horizon.name()));
        }
        s
    }

    /// Multi-index of flat cell `flat` (C order).
    pub fn unflatten(&self, mut flat: usize, idx: &mut [usize]) {
        for (k, a) in self.axes.iter().enumerate().rev() {
            idx[k] = flat % a.n;
            flat /= a.n;
        }
    }

    /// The axis angles of a cell's sample.
    pub fn sample_coords(&self, idx: &[usize]) -> [f64; 4] {
        let mut c = [0.0; 4];
        for (k, a) in self.axes.iter().enumerate() {
            c[k] = a.sample(idx[k]);
        }
        c
    }

    /// The direction pair at axis angles `c` (in storage order).
    pub fn dirs_from_coords(&self, c: &[f64; 4]) -> (Vec3, Vec3) {
        match self.kind {
            GridKind::Spherical4 => (
                Vec3::from_spherical(c[0], c[1]),
                Vec3::from_spherical(c[2], c[3]),
            ),
            GridKind::Spherical3 => (
                Vec3::from_spherical(c[0], 0.0),
                Vec3::from_spherical(c[1], c[2]),
            ),
            GridKind::Halfdiff3 => HalfDiff {
                theta_h: c[0],
                phi_h: 0.0,
                theta_d: c[1],
                phi_d: c[2],
            }
            .to_dirs(),
            GridKind::Halfdiff4 => HalfDiff {
                theta_h: c[0],
                phi_h: c[1],
                theta_d: c[2],
                phi_d: c[3],
            }
            .to_dirs(),
        }
    }

    /// The direction pair sampled by a cell.
    pub fn cell_dirs(&self, idx: &[usize]) -> (Vec3, Vec3) {
        self.dirs_from_coords(&self.sample_coords(idx))
    }

    /// The axis angles of a direction pair (storage order), folded into the grid's ranges.
    /// `None` when the pair has no coordinates here (wi = −wo on a half/difference grid).
    pub fn coords_of(&self, wi: Vec3, wo: Vec3) -> Option<[f64; 4]> {
        let wrap = |a: f64| if a < 0.0 { a + 2.0 * PI } else { a };
        match self.kind {
            GridKind::Spherical4 => Some([wi.theta(), wrap(wi.phi()), wo.theta(), wrap(wo.phi())]),
            GridKind::Spherical3 => {
                let mut d = (wo.phi() - wi.phi()).abs();
                if d > PI {
                    d = 2.0 * PI - d;
                }
                Some([wi.theta(), wo.theta(), d, 0.0])
            }
            GridKind::Halfdiff3 => {
                let hd = HalfDiff::from_dirs(wi, wo)?;
                // MERL's fold: φd and φd + π are the same pair with wi and wo swapped.
                let pd = if hd.phi_d < 0.0 {
                    hd.phi_d + PI
                } else {
                    hd.phi_d
                };
                Some([hd.theta_h, hd.theta_d, pd, 0.0])
            }
            GridKind::Halfdiff4 => {
                let hd = HalfDiff::from_dirs(wi, wo)?;
                Some([hd.theta_h, wrap(hd.phi_h), hd.theta_d, wrap(hd.phi_d)])
            }
        }
    }

    /// True when a direction pair lies in the stored domain (above the horizon, within θmax).
    #[inline]
    pub fn in_domain(&self, wi: Vec3, wo: Vec3) -> bool {
        self.in_domain_z(wi.z, wo.z)
    }

    /// Solid-angle measure dωi dωo of a cell (used to weight the `cells` sample set):
    /// sinθi sinθo dθi dφi dθo dφo on spherical grids (Δφ counted twice, for ±Δφ);
    /// 4 cosθd sinθh sinθd dθh dφh dθd dφd on half/difference grids (Rusinkiewicz 1998),
    /// with the integral over the missing azimuth (2π) and the φd fold (×2) on 3D kinds.
    pub fn cell_measure(&self, idx: &[usize]) -> f64 {
        idx.iter()
            .enumerate()
            .map(|(k, &i)| self.axis_measure(k, i))
            .product()
    }

    /// [`Grid::cell_measure`] as one factor per axis: the measure of cell (i₀, i₁, …) is the
    /// product of `factors[k][i_k]`. For weighting every cell of a large grid without
    /// per-cell trigonometry.
    pub fn cell_measure_factors(&self) -> Vec<Vec<f64>> {
        (0..self.axes.len())
            .map(|k| {
                (0..self.axes[k].n)
                    .map(|i| self.axis_measure(k, i))
                    .collect()
            })
            .collect()
    }

    /// Axis `k`'s factor of the measure of a cell with index `i` on it: every kind's
    /// measure separates into the cell's width on each axis, sin θ on each θ axis but θd,
    /// 4 cos θd sin θd on θd, and the 3D kinds' constants (on the first axis).
    fn axis_measure(&self, k: usize, i: usize) -> f64 {
        use Quantity::*;
        let a = &self.axes[k];
        let t = a.sample(i);
        let shape = match a.quantity {
            ThetaI | ThetaO | ThetaH => t.sin().abs(),
            ThetaD => 4.0 * t.cos() * t.sin().abs(),
            PhiI | PhiO | PhiH | PhiD | DeltaPhi => 1.0,
        };
        let constant = match (k, self.kind) {
            (0, GridKind::Spherical3 | GridKind::Halfdiff3) => 2.0 * PI * 2.0,
            _ => 1.0,
        };
        constant * shape * a.cell_width(i)
    }

    /// Validity of every cell implied by geometry alone: the sample pair is above the horizon
    /// and inside θmax.
    ///
    /// Built from per-axis tables, because the validity only needs cos θi and cos θo (the z
    /// components of [`Grid::cell_dirs`]): per-cell trigonometry was 60% of opening a small
    /// file. The z components are computed with the very operations, in the same order, that
    /// [`Vec3::from_spherical`], [`Vec3::rotate_y`] and [`Vec3::mirror`] use, so the mask is
    /// bit-for-bit the one the per-cell path gives (tested on every kind, with and without θmax).
    pub fn geometric_mask(&self) -> Vec<bool> {
        // cos θ as `Vec3::from_spherical` returns it: exactly 0 at π/2.
        let cos_theta = |t: f64| if t == FRAC_PI_2 { 0.0 } else { t.cos() };
        let table = |k: usize, f: &dyn Fn(f64) -> f64| -> Vec<f64> {
            let a = &self.axes[k];
            (0..a.n).map(|i| f(a.sample(i))).collect()
        };
        // An extended grid's cell below the horizon holds its pair raised to cos θ =
        // HORIZON_COS ([`Grid::value_pair`]): valid when that pair is in the domain.
        let floor = self.horizon.raised_cos();
        let inside = |zi: f64, zo: f64| {
            if zi > 0.0 && zo > 0.0 {
                self.in_domain_z(zi, zo)
            } else {
                self.in_domain_z(zi.max(floor), zo.max(floor))
            }
        };
        let n = |k: usize| self.axes[k].n;
        // Rows of the first axis in parallel (a MERL grid's 1.46 M flags were 7% of a whole
        // `eval` process): every flag is computed on its own, so the same bits.
        use rayon::prelude::*;
        let mut out = vec![false; self.cells()];
        let row = self.cells() / n(0);
        match self.kind {
            GridKind::Spherical4 | GridKind::Spherical3 => {
                // (θi, φi, θo, φo) or (θi, θo, Δφ): validity repeats along the φ axes.
                let (o, inner) = match self.kind {
                    GridKind::Spherical4 => (2, n(3)),
                    _ => (1, n(2)),
                };
                let zi = table(0, &cos_theta);
                let zo = table(o, &cos_theta);
                out.par_chunks_mut(row).zip(&zi).for_each(|(r, &a)| {
                    // Spherical4: n(1) blocks of φi, each θo × φo.
                    for (block, &b) in r.chunks_mut(inner).zip(zo.iter().cycle()) {
                        block.fill(inside(a, b));
                    }
                });
            }
            GridKind::Halfdiff3 | GridKind::Halfdiff4 => {
                // d = (sin θd cos φd, ·, cos θd), then rotate_y(θh): z' = −sin θh·d.x + cos θh·d.z
                // (for wo, d is mirrored: d.x → −d.x); φh turns about z and drops out.
                let d = match self.kind {
                    GridKind::Halfdiff4 => 2,
                    _ => 1,
                };
                let (sh, ch) = (table(0, &f64::sin), table(0, &f64::cos));
                let (sd, cd) = (table(d, &f64::sin), table(d, &cos_theta));
                let cp = table(d + 1, &f64::cos);
                out.par_chunks_mut(row).enumerate().for_each(|(h, r)| {
                    // Halfdiff4: n(1) blocks of φh, each θd × φd, all alike.
                    for block in r.chunks_mut(sd.len() * cp.len()) {
                        for (j, line) in block.chunks_mut(cp.len()).enumerate() {
                            let zc = ch[h] * cd[j];
                            for (o, &c) in line.iter_mut().zip(&cp) {
                                let x = sd[j] * c;
                                *o = inside(-sh[h] * x + zc, -sh[h] * -x + zc);
                            }
                        }
                    }
                });
            }
        }
        debug_assert_eq!(out.len(), self.cells());
        out
    }

    /// [`Grid::in_domain`] on the two cosines alone.
    #[inline]
    fn in_domain_z(&self, zi: f64, zo: f64) -> bool {
        // Compare cosines: θ ≤ θmax ⇔ cos θ ≥ cos θmax (with a little slack for rounding).
        if !(zi > 0.0 && zo > 0.0) {
            return false;
        }
        match self.theta_max {
            None => true,
            Some(t) => {
                let c = t.cos() - 1e-12;
                zi >= c && zo >= c
            }
        }
    }

    /// cos θi · cos θo of every cell's sample pair, in storage order, each cosine clamped at 0
    /// (a direction below the horizon weighs 0). From per-axis tables, a few multiplies per
    /// cell (a MERL grid in milliseconds, cheap enough for every decode): on half/difference
    /// grids cos θi, cos θo = cos θh cos θd ∓ sin θh sin θd cos φd (the z components of
    /// [`HalfDiff::to_dirs`]; φh turns about z and drops out), on spherical grids the θ axes
    /// give them directly. Tested against [`Grid::cell_dirs`] on every kind.
    pub fn cos_products(&self) -> Vec<f64> {
        let products = self.cell_cos_products();
        (0..self.cells()).map(|f| products.at(f)).collect()
    }

    /// [`Grid::cos_products`] without a per-cell array: each cell's product computed when
    /// read, from the per-axis tables of the axes it depends on (θi, θo on spherical grids;
    /// θh, θd, φd on half/difference ones). A per-cell f64 array is 134 MB on a 64⁴ grid,
    /// 33.5 MB on a 128×128×256 one.
    pub fn cell_cos_products(&self) -> CellCosProducts {
        let cos = |t: f64| if t == FRAC_PI_2 { 0.0 } else { t.cos() };
        let table = |k: usize, f: &dyn Fn(f64) -> f64| -> Vec<f64> {
            let a = &self.axes[k];
            (0..a.n).map(|i| f(a.sample(i))).collect()
        };
        let place = |k: usize| AxisPlace {
            stride: self.axes[k + 1..].iter().map(|a| a.n).product(),
            n: self.axes[k].n,
        };
        match self.kind {
            GridKind::Spherical4 | GridKind::Spherical3 => {
                let o = if self.kind == GridKind::Spherical4 {
                    2
                } else {
                    1
                };
                CellCosProducts::Spherical {
                    cos_i: table(0, &cos),
                    cos_o: table(o, &cos),
                    i: place(0),
                    o: place(o),
                }
            }
            GridKind::Halfdiff3 | GridKind::Halfdiff4 => {
                let d = if self.kind == GridKind::Halfdiff4 {
                    2
                } else {
                    1
                };
                CellCosProducts::HalfDiff {
                    floor: self.horizon.raised_cos(),
                    cos_h: table(0, &cos),
                    sin_h: table(0, &f64::sin),
                    cos_d: table(d, &cos),
                    sin_d: table(d, &f64::sin),
                    cos_phi_d: table(d + 1, &f64::cos),
                    h: place(0),
                    d: place(d),
                    phi_d: place(d + 1),
                }
            }
        }
    }

    /// True for θ axes (used by interpolation to clamp rather than wrap).
    pub fn axis_is_theta(&self, k: usize) -> bool {
        self.axes[k].quantity.is_theta()
    }
}

/// cos θi · cos θo of a grid's cells ([`Grid::cell_cos_products`]), computed by the cell's
/// flat index.
#[derive(Clone, Debug)]
pub enum CellCosProducts {
    /// (θi, [φi,] θo, φo | Δφ): cos θi · cos θo, each clamped at 0.
    Spherical {
        cos_i: Vec<f64>,
        cos_o: Vec<f64>,
        i: AxisPlace,
        o: AxisPlace,
    },
    /// (θh, [φh,] θd, φd): cos θi, cos θo = cos θh cos θd ∓ sin θh sin θd cos φd; below the
    /// horizon each clamped at `floor` (0, or [`HORIZON_COS`] on an extended grid, whose
    /// cells there hold the pair raised to it: [`Grid::value_pair`]).
    HalfDiff {
        floor: f64,
        cos_h: Vec<f64>,
        sin_h: Vec<f64>,
        cos_d: Vec<f64>,
        sin_d: Vec<f64>,
        cos_phi_d: Vec<f64>,
        h: AxisPlace,
        d: AxisPlace,
        phi_d: AxisPlace,
    },
}

/// Where an axis's index sits in a flat cell index.
#[derive(Clone, Copy, Debug)]
pub struct AxisPlace {
    stride: usize,
    n: usize,
}

impl AxisPlace {
    #[inline]
    fn of(self, cell: usize) -> usize {
        (cell / self.stride) % self.n
    }
}

impl CellCosProducts {
    /// The product of the cell at flat (storage-order) index `cell`.
    #[inline]
    pub fn at(&self, cell: usize) -> f64 {
        match self {
            CellCosProducts::Spherical { cos_i, cos_o, i, o } => {
                cos_i[i.of(cell)].max(0.0) * cos_o[o.of(cell)].max(0.0)
            }
            CellCosProducts::HalfDiff {
                floor,
                cos_h,
                sin_h,
                cos_d,
                sin_d,
                cos_phi_d,
                h,
                d,
                phi_d,
            } => {
                let (h, j) = (h.of(cell), d.of(cell));
                let a = cos_h[h] * cos_d[j];
                let b = sin_h[h] * sin_d[j];
                let t = b * cos_phi_d[phi_d.of(cell)];
                let (ci, co) = (a - t, a + t);
                if ci > 0.0 && co > 0.0 {
                    ci * co
                } else {
                    // Below the horizon: the pair the cell holds the value of.
                    ci.max(*floor) * co.max(*floor)
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cos_products_match_the_cell_directions_on_every_kind() {
        for spec in [
            "merl",
            "halfdiff3:7x5x9,warp=sqrt/linear/linear,at=center/edge/edge",
            "halfdiff4:5x6x7x8,warp=sqrt/linear/linear/linear,at=edge",
            "halfdiff4:4x3x5x6",
            "merl,horizon=extend",
            "halfdiff4:4x3x5x6,horizon=extend",
            "spherical3:6x7x5,warp=sqrt/linear/linear,theta-max=80",
            "spherical3:8x8x3,at=edge",
            "spherical4:8x3x8x4,warp=linear/linear/sqrt/linear,at=edge",
            "spherical4:4x3x4x5,theta-max=60",
        ] {
            let g = spec::parse_grid_spec(spec).unwrap();
            // An extended grid's cells below the horizon weigh the pair raised to it.
            let w = g.cos_products();
            assert_eq!(w.len(), g.cells(), "{spec}");
            let d = g.axes().len();
            let mut idx = [0usize; 4];
            // Every cell of the small grids; every 97th of MERL's 1.46 M.
            let stride = if g.cells() > 100_000 { 97 } else { 1 };
            let mut grazing = 0;
            for f in (0..g.cells()).step_by(stride) {
                g.unflatten(f, &mut idx[..d]);
                let (wi, wo) = g.cell_dirs(&idx[..d]);
                let want = match g.value_pair(wi, wo) {
                    Some((a, b)) if g.horizon() == Horizon::Extend => a.z * b.z,
                    _ => wi.z.max(0.0) * wo.z.max(0.0),
                };
                assert!(
                    (w[f] - want).abs() <= 1e-14,
                    "{spec}: cell {f} {:?}: {} vs {want}",
                    &idx[..d],
                    w[f]
                );
                grazing += usize::from(want < 0.1);
            }
            // The check must see grazing cells, where the weight matters (θmax = 80° keeps
            // the sqrt-warped spherical3 grid away from them).
            assert!(grazing > 0 || spec.contains("theta-max"), "{spec}");
        }
    }

    #[test]
    fn geometric_mask_is_the_per_cell_domain_test_bit_for_bit() {
        for spec in [
            "merl",
            "halfdiff3:7x5x9,warp=sqrt/linear/linear,at=center/edge/edge",
            "halfdiff3:9x9x16,at=edge,theta-max=60",
            "halfdiff4:5x6x7x8,warp=sqrt/linear/linear/linear,at=edge",
            "halfdiff4:6x4x6x8,at=edge,theta-max=45",
            "spherical3:6x7x5,warp=sqrt/linear/linear,theta-max=80",
            "spherical3:8x8x3,at=edge",
            "spherical4:8x3x8x4,warp=linear/linear/sqrt/linear,at=edge",
            "spherical4:4x3x4x5,theta-max=60",
            "merl,horizon=extend",
            "halfdiff4:5x6x7x8,warp=sqrt/linear/linear/linear,at=edge,horizon=extend",
            "halfdiff3:9x9x16,at=edge,theta-max=60,horizon=extend",
        ] {
            let g = spec::parse_grid_spec(spec).unwrap();
            let mask = g.geometric_mask();
            assert_eq!(mask.len(), g.cells(), "{spec}");
            let d = g.axes().len();
            let mut idx = [0usize; 4];
            let (mut valid, mut invalid, mut below) = (0, 0, 0);
            for (f, &m) in mask.iter().enumerate() {
                g.unflatten(f, &mut idx[..d]);
                let (wi, wo) = g.cell_dirs(&idx[..d]);
                // The tabulation's test (`Grid::value_pair`): the domain test itself on a
                // grid cut at the horizon.
                let held = g.value_pair(wi, wo).is_some();
                assert_eq!(m, held, "{spec}: cell {f} {:?}", &idx[..d]);
                if g.horizon() == Horizon::Cut {
                    assert_eq!(m, g.in_domain(wi, wo), "{spec}: cell {f}");
                }
                if m {
                    valid += 1;
                    below += usize::from(!(wi.z > 0.0 && wo.z > 0.0));
                } else {
                    invalid += 1;
                }
            }
            // Both outcomes must occur on half/difference grids, or the comparison proves
            // nothing about the boundary (spherical grids sample θ < 90° or within θmax, so
            // every cell of most of them is valid). An extended grid without θmax holds
            // every cell, those below the horizon included.
            assert!(valid > 0, "{spec}");
            let extended = g.horizon() == Horizon::Extend;
            if extended && g.theta_max().is_none() {
                assert!(
                    invalid == 0 && below > 0,
                    "{spec}: {invalid} invalid, {below} below"
                );
            } else {
                assert!(
                    invalid > 0 || spec.starts_with("spherical"),
                    "{spec}: no invalid cell"
                );
                assert_eq!(below, 0, "{spec}");
            }
        }
    }

    #[test]
    fn horizon_extend_parses_round_trips_and_is_refused_on_spherical_grids() {
        let g = spec::parse_grid_spec("halfdiff3:8x8x16,horizon=extend").unwrap();
        assert_eq!(g.horizon(), Horizon::Extend);
        let json = serde_json::to_string(&g.desc()).unwrap();
        assert!(json.contains(r#""horizon":"extend""#), "{json}");
        assert_eq!(
            Grid::from_desc(&serde_json::from_str(&json).unwrap()).unwrap(),
            g
        );
        // A grid cut at the horizon writes the header it always wrote.
        let plain = serde_json::to_string(&Grid::merl().desc()).unwrap();
        assert!(!plain.contains("horizon"), "{plain}");
        let m = spec::parse_grid_spec("merl,horizon=extend").unwrap();
        assert_eq!(m, Grid::merl().with_horizon(Horizon::Extend).unwrap());
        assert!(m.describe().ends_with("horizon extend"), "{}", m.describe());
        for bad in [
            "spherical3:8x8x16,horizon=extend",
            "spherical4:4,horizon=extend",
            "halfdiff3:8,horizon=below",
            "merl,horizon=yes",
        ] {
            let e = spec::parse_grid_spec(bad).unwrap_err().to_string();
            assert!(e.contains("horizon"), "{bad}: {e}");
        }
        let mut d = spec::parse_grid_spec("spherical3:8").unwrap().desc();
        d.horizon = Horizon::Extend;
        assert!(Grid::from_desc(&d).is_err());
    }

    #[test]
    fn raised_directions_keep_their_azimuth() {
        let w = Vec3::from_spherical(1.7, 0.6);
        let r = raised_to_horizon(w);
        assert_eq!(r.z, HORIZON_COS);
        assert!((r.length() - 1.0).abs() < 1e-15);
        assert!((r.y.atan2(r.x) - 0.6).abs() < 1e-12);
        // Above it, unchanged; straight down, azimuth 0.
        let up = Vec3::from_spherical(0.3, 2.0);
        assert_eq!(raised_to_horizon(up), up);
        let down = raised_to_horizon(Vec3::new(0.0, 0.0, -1.0));
        assert_eq!((down.y, down.z), (0.0, HORIZON_COS));
        assert!(down.x > 0.99);
    }

    #[test]
    fn merl_sample_positions_match_the_reference() {
        let g = Grid::merl();
        let th = &g.axes()[0];
        assert_eq!(th.sample(0), 0.0);
        let i = 45.0_f64;
        assert!((th.sample(45) - (i / 90.0).powi(2) * FRAC_PI_2).abs() < 1e-15);
        assert!((g.axes()[1].sample(1) - PI / 180.0).abs() < 1e-15);
        assert!((g.axes()[2].sample(179) - 179.0 * PI / 180.0).abs() < 1e-14);
        assert_eq!(g.cells(), 1_458_000);
    }

    #[test]
    fn continuous_index_inverts_sample() {
        for g in [
            Grid::merl(),
            parse_grid_spec("spherical4:8x16x8x16").unwrap(),
            parse_grid_spec("halfdiff4:8x16x8x16,warp=sqrt/linear/linear/linear").unwrap(),
        ] {
            for a in g.axes() {
                for i in 0..a.n {
                    let t = a.continuous_index(a.sample(i));
                    assert!((t - i as f64).abs() < 1e-9, "{:?} {i} {t}", a.quantity);
                }
            }
        }
    }

    #[test]
    fn cell_directions_round_trip_through_coords() {
        for spec in [
            "halfdiff3:16x16x32",
            "halfdiff4:8x16x8x16",
            "spherical4:8x16x8x16",
            "spherical3:8x8x16",
        ] {
            let g = parse_grid_spec(spec).unwrap();
            let mut idx = [0usize; 4];
            let d = g.axes().len();
            for f in 0..g.cells() {
                g.unflatten(f, &mut idx[..d]);
                let (wi, wo) = g.cell_dirs(&idx[..d]);
                if !g.in_domain(wi, wo) {
                    continue;
                }
                let c = g.coords_of(wi, wo).unwrap();
                let s = g.sample_coords(&idx[..d]);
                for k in 0..d {
                    let (lo, hi) = g.axes()[k].range();
                    let mut diff = (c[k] - s[k]).abs();
                    if g.axes()[k].is_periodic() {
                        diff = diff.min((hi - lo) - diff);
                    }
                    assert!(
                        diff < 1e-9,
                        "{spec} cell {f} axis {k}: {} vs {}",
                        c[k],
                        s[k]
                    );
                }
            }
        }
    }

    #[test]
    fn measure_sums_to_the_domain() {
        // ∫∫ dωi dωo over both hemispheres = (2π)².
        for spec in [
            "spherical4:32x32x32x32",
            "spherical3:64x64x64",
            "halfdiff3:128x128x64",
            "halfdiff4:48x32x48x32",
        ] {
            let g = parse_grid_spec(spec).unwrap();
            let d = g.axes().len();
            let mut idx = [0usize; 4];
            let mut total = 0.0;
            for f in 0..g.cells() {
                g.unflatten(f, &mut idx[..d]);
                let (wi, wo) = g.cell_dirs(&idx[..d]);
                if g.in_domain(wi, wo) {
                    total += g.cell_measure(&idx[..d]);
                }
            }
            let want = (2.0 * PI).powi(2);
            assert!(
                (total / want - 1.0).abs() < 0.02,
                "{spec}: {total} vs {want}"
            );
        }
    }

    #[test]
    fn bad_grids_are_refused() {
        assert!(
            Grid::new(
                GridKind::Halfdiff3,
                &[(0, Warp::Linear, Placement::Center); 3],
                None
            )
            .is_err()
        );
        assert!(
            Grid::new(
                GridKind::Halfdiff3,
                &[(4, Warp::Linear, Placement::Center); 2],
                None
            )
            .is_err()
        );
        assert!(
            Grid::new(
                GridKind::Halfdiff3,
                &[(4, Warp::Sqrt, Placement::Center); 3],
                None
            )
            .is_err()
        );
        assert!(
            Grid::new(
                GridKind::Spherical4,
                &[(65536, Warp::Linear, Placement::Center); 4],
                None
            )
            .is_err()
        );
    }
}
