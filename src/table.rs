//! A tabulated BRDF: a grid, its channels, where it came from, f32 samples and validity.

use crate::brdf::{Brdf, Channels};
use crate::geometry::Vec3;
use crate::grid::{CellCosProducts, Grid, InterpSpace, InterpWeight};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

mod cells;
pub mod lookup;
mod to_rgb;

pub use cells::CellSet;
pub use to_rgb::spectral_to_rgb;

/// Where a table came from, recorded in every file written.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    /// The source: a canonical model spec (JSON) or a description of a measured file.
    pub source: String,
    /// The tool and version that wrote it (no timestamps or host data: outputs are reproducible).
    pub tool: String,
    /// Notes on choices that change meaning, e.g. an anisotropic model forced onto an
    /// isotropic grid.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
}

/// How a table is evaluated between its samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interp {
    /// The sample whose cell contains the query (rounded in warped index space).
    Nearest,
    /// Multilinear in warped index space: periodic φ, clamped θ ends, invalid neighbours
    /// dropped and the remaining weights renormalized.
    #[default]
    Linear,
}

/// The f64 numbers a source stored, kept beside the f32 samples when f32 storage would
/// lose them (a MERL `.binary` file holds f64), so a table read from such a file can be
/// written back byte for byte. Physical value = `raw[cell * channels + c] × scale[c]`;
/// for every valid cell `data == (raw × scale) as f32` (checked by [`Table::with_exact`]).
/// Invalid cells keep whatever the source stored there (e.g. MERL's −1 markers).
/// Any operation that computes new samples (tabulation, re-gridding) drops it.
#[derive(Clone, Debug, PartialEq)]
pub struct ExactValues {
    /// Per-channel factor from the stored numbers to 1/sr (MERL: 1/1500, 1.15/1500, 1.66/1500).
    pub scale: Vec<f64>,
    /// Cell-major, channel fastest, like [`Table::data`].
    pub raw: Vec<f64>,
}

/// A BRDF tabulated on a grid. Data are cell-major, channel fastest:
/// `data[cell * channels + c]`. Invalid cells (below the horizon, outside the stored
/// domain, or marked missing in a measured source) hold 0 and are never interpolated from.
#[derive(Clone, Debug, PartialEq)]
pub struct Table {
    grid: Grid,
    channels: Channels,
    provenance: Provenance,
    data: Vec<f32>,
    valid: Vec<bool>,
    /// The source's own f64 values when f32 would lose them (see [`ExactValues`]).
    exact: Option<ExactValues>,
    /// `valid` packed as bits for batched lookups, built on first use.
    bits: BitsCache,
    /// Every cell's cos θi · cos θo, built on the first lookup of a cosine-weighted grid.
    cos: CosCache,
    /// The vectorized angle maps of a half/difference grid, built on the first lookup.
    angles: AnglesCache,
    /// The index range of the valid cells on each axis, built on the first nearest-valid
    /// fallback.
    bounds: BoundsCache,
}

impl Table {
    /// The table behind `brdf` (a table source: `Brdf::as_any` of an [`InterpolatedTable`]
    /// is its table) when it lies on `grid` itself: its valid samples are then its values at
    /// the grid's nodes, which tabulation and `check`'s `cells` set read instead of
    /// interpolating at each node.
    pub fn behind<'a>(brdf: &'a dyn Brdf, grid: &Grid) -> Option<&'a Table> {
        brdf.as_any()
            .and_then(|a| a.downcast_ref::<Table>())
            .filter(|t| t.grid() == grid)
    }

    /// Builds a table, checking that the sizes agree and every valid value is finite.
    pub fn new(
        grid: Grid,
        channels: Channels,
        provenance: Provenance,
        mut data: Vec<f32>,
        valid: Vec<bool>,
    ) -> Result<Table> {
        let cells = grid.cells();
        let c = channels.len();
        if valid.len() != cells || data.len() != cells * c {
            return Err(Error::input(format!(
                "table: {} values and {} validity flags for {cells} cells × {c} channels",
                data.len(),
                valid.len()
            )));
        }
        for (cell, &ok) in valid.iter().enumerate() {
            let v = &mut data[cell * c..(cell + 1) * c];
            if ok {
                if let Some(x) = v.iter().find(|x| !x.is_finite()) {
                    return Err(Error::Failure(format!(
                        "table: cell {cell} holds the non-finite value {x}"
                    )));
                }
            } else {
                v.fill(0.0);
            }
        }
        Ok(Table {
            grid,
            channels,
            provenance,
            data,
            valid,
            exact: None,
            bits: BitsCache::default(),
            cos: CosCache::default(),
            angles: AnglesCache::default(),
            bounds: BoundsCache::default(),
        })
    }

    /// Attaches the source's exact f64 values, checking that they are finite, that the
    /// scales are finite and positive, and that every valid cell's f32 sample is their
    /// rounding (so the two can never disagree).
    pub fn with_exact(mut self, exact: ExactValues) -> Result<Table> {
        let c = self.channels.len();
        if exact.scale.len() != c || exact.raw.len() != self.data.len() {
            return Err(Error::input(format!(
                "exact values: {} scales and {} values for {c} channels × {} cells",
                exact.scale.len(),
                exact.raw.len(),
                self.valid.len()
            )));
        }
        if let Some(s) = exact.scale.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return Err(Error::input(format!(
                "exact values: scale {s} is not finite and positive"
            )));
        }
        for (i, &r) in exact.raw.iter().enumerate() {
            if !r.is_finite() {
                return Err(Error::input(format!(
                    "exact values: value {i} (cell {}, channel {}) is {r}",
                    i / c,
                    i % c
                )));
            }
            let cell = i / c;
            let want = (r * exact.scale[i % c]) as f32;
            if self.valid[cell] && want.to_bits() != self.data[i].to_bits() {
                return Err(Error::input(format!(
                    "exact values: cell {cell} channel {} holds {} but the exact value {r} × {} \
                     rounds to {want}",
                    i % c,
                    self.data[i],
                    exact.scale[i % c]
                )));
            }
        }
        self.exact = Some(exact);
        Ok(self)
    }

    /// The source's exact f64 values, when the table carries them.
    pub fn exact(&self) -> Option<&ExactValues> {
        self.exact.as_ref()
    }

    /// Drops the exact f64 values (e.g. before a lossy encoding).
    pub fn without_exact(mut self) -> Table {
        self.exact = None;
        self
    }

    /// A copy of the samples without the exact f64 values (a MERL file's are twice the size
    /// of its f32 samples) and without the lookup caches: what a working copy needs when
    /// only the samples are read.
    pub fn clone_samples(&self) -> Table {
        Table {
            grid: self.grid.clone(),
            channels: self.channels.clone(),
            provenance: self.provenance.clone(),
            data: self.data.clone(),
            valid: self.valid.clone(),
            exact: None,
            bits: BitsCache::default(),
            cos: CosCache::default(),
            angles: AnglesCache::default(),
            bounds: BoundsCache::default(),
        }
    }

    /// Sets what is interpolated between the samples ([`InterpWeight`]); the samples stay.
    pub fn set_interp_weight(&mut self, weight: InterpWeight) {
        if self.grid.weight() != weight {
            self.grid = self.grid.clone().with_weight(weight);
        }
    }

    /// Sets the space values are interpolated in ([`InterpSpace`]); the samples stay.
    pub fn set_interp_space(&mut self, space: InterpSpace) {
        if self.grid.space() != space {
            self.grid = self.grid.clone().with_space(space);
        }
    }

    /// An all-invalid table of `grid` × `channels` (zeroed memory, filled by tabulation).
    pub(crate) fn zeroed(grid: Grid, channels: Channels) -> Table {
        let cells = grid.cells();
        Table {
            data: vec![0.0; cells * channels.len()],
            valid: vec![false; cells],
            grid,
            channels,
            provenance: Provenance::default(),
            exact: None,
            bits: BitsCache::default(),
            cos: CosCache::default(),
            angles: AnglesCache::default(),
            bounds: BoundsCache::default(),
        }
    }

    /// Makes this table one of `grid` × `channels` with `provenance`, keeping the allocation
    /// when the sizes agree. The samples are left as they are: the caller overwrites every
    /// cell (value and validity) and keeps invalid cells at 0 and valid ones finite.
    pub(crate) fn reset(&mut self, grid: &Grid, channels: &Channels, provenance: Provenance) {
        let cells = grid.cells();
        let c = channels.len();
        if self.grid != *grid {
            self.grid = grid.clone();
            self.cos = CosCache::default();
            self.angles = AnglesCache::default();
        }
        if self.channels != *channels {
            self.channels = channels.clone();
        }
        self.provenance = provenance;
        // New samples: exact values of an earlier source no longer describe them.
        self.exact = None;
        self.data.resize(cells * c, 0.0);
        self.valid.resize(cells, false);
        self.bits = BitsCache::default();
        self.bounds = BoundsCache::default();
    }

    /// The samples, the table consumed (cell-major, channel fastest, as [`Table::data`]).
    pub fn into_samples(self) -> Vec<f32> {
        self.data
    }

    /// Moves the samples out for the rate control, which decodes its candidates into their
    /// memory instead of holding a second table-sized buffer (`plan::rate`). The table holds
    /// no samples until [`Table::give_back_samples`]; nothing else may read it meanwhile.
    pub(crate) fn lend_samples(&mut self) -> Vec<f32> {
        std::mem::take(&mut self.data)
    }

    /// Puts samples back after [`Table::lend_samples`]: resized to the table's size, invalid
    /// cells and any non-finite value set to 0, so the table's invariants hold whatever the
    /// buffer went through (on an error path it holds an unfinished decode).
    pub(crate) fn give_back_samples(&mut self, mut data: Vec<f32>) {
        let c = self.channels.len();
        data.resize(self.valid.len() * c, 0.0);
        for (v, &ok) in data.chunks_exact_mut(c.max(1)).zip(&self.valid) {
            for x in v {
                if !ok || !x.is_finite() {
                    *x = 0.0;
                }
            }
        }
        self.data = data;
    }

    /// The sample and validity buffers, for filling in place (see [`Table::reset`]).
    pub(crate) fn buffers_mut(&mut self) -> (&mut [f32], &mut [bool]) {
        // The caller may change validity: the packed copy is rebuilt on the next batch.
        self.bits = BitsCache::default();
        self.bounds = BoundsCache::default();
        (&mut self.data, &mut self.valid)
    }

    pub fn grid(&self) -> &Grid {
        &self.grid
    }
    pub fn channels(&self) -> &Channels {
        &self.channels
    }
    pub fn provenance(&self) -> &Provenance {
        &self.provenance
    }
    pub fn provenance_mut(&mut self) -> &mut Provenance {
        &mut self.provenance
    }
    pub fn data(&self) -> &[f32] {
        &self.data
    }
    pub fn valid(&self) -> &[bool] {
        &self.valid
    }
    pub fn valid_count(&self) -> usize {
        self.valid.iter().filter(|&&v| v).count()
    }
    /// The values of one cell.
    pub fn cell(&self, cell: usize) -> &[f32] {
        let c = self.channels.len();
        &self.data[cell * c..(cell + 1) * c]
    }

    /// Evaluates the table at a direction pair; 0 outside the stored domain's horizon.
    /// Queries beyond θmax return an error in [`Table::try_eval`]; here they give 0.
    pub fn eval_into(&self, wi: Vec3, wo: Vec3, interp: Interp, out: &mut [f64]) {
        out.fill(0.0);
        let Some(t) = self.continuous_indices(wi, wo) else {
            return;
        };
        let layout = Layout::new(&self.grid);
        if let Some(log) = self.log_space(interp) {
            match self.query_weight(wi, wo) {
                QueryWeight::Plain => {
                    self.interpolate_log(&t, &layout, &self.valid[..], out, log, |_| 1.0, 1.0)
                }
                QueryWeight::Cosine { cells, inv_q } => self.interpolate_log(
                    &t,
                    &layout,
                    &self.valid[..],
                    out,
                    log,
                    |flat| cells.at(flat) as f32 as f64,
                    inv_q,
                ),
                QueryWeight::Horizon => {}
            }
            return;
        }
        match self.query_weight(wi, wo) {
            QueryWeight::Plain => {
                self.interpolate_masked(&t, interp, &layout, &self.valid[..], out, |_, w| w)
            }
            QueryWeight::Cosine { cells, inv_q } => {
                self.interpolate_masked(&t, interp, &layout, &self.valid[..], out, |flat, w| {
                    cosine_weight(w, cells.at(flat) as f32, inv_q)
                })
            }
            QueryWeight::Horizon => {}
        }
    }

    /// The log space of this table's grid, when a lookup with `interp` combines in it
    /// (linear interpolation on a grid with [`InterpSpace::Log`]; a nearest lookup returns
    /// a sample, in any space).
    #[inline]
    fn log_space(&self, interp: Interp) -> Option<LogSpace> {
        match self.grid.space() {
            InterpSpace::Log { scale } if interp == Interp::Linear => Some(LogSpace::new(scale)),
            _ => None,
        }
    }

    /// How a query's neighbours are weighted on this table's grid ([`InterpWeight`]).
    #[inline]
    fn query_weight(&self, wi: Vec3, wo: Vec3) -> QueryWeight<'_> {
        match self.grid.weight() {
            InterpWeight::None => QueryWeight::Plain,
            InterpWeight::Cosine => {
                let q = wi.z.max(0.0) * wo.z.max(0.0);
                if q < MIN_COS_PRODUCT {
                    QueryWeight::Horizon
                } else {
                    QueryWeight::Cosine {
                        cells: self.cell_cos_products(),
                        inv_q: 1.0 / q,
                    }
                }
            }
        }
    }

    /// cos θi · cos θo of every cell's sample pair (read as f32: the weights need no more),
    /// from per-axis tables built once (a per-cell array was 67 MB on a 64⁴ grid, held for
    /// the table's life, and 134 MB more while built).
    fn cell_cos_products(&self) -> &CellCosProducts {
        self.cos.0.get_or_init(|| self.grid.cell_cos_products())
    }

    /// The pair's continuous index along every axis (storage order); `None` outside the
    /// stored domain, where [`Table::eval_into`] gives 0.
    fn continuous_indices(&self, wi: Vec3, wo: Vec3) -> Option<[f64; 4]> {
        if !self.grid.in_domain(wi, wo) {
            return None;
        }
        // Where the batched lookups take the vectorized angles, one pair takes them too:
        // `eval_into`, `eval_batch` and the stencils then agree bit for bit, so `brdfpack
        // eval` prints what the bindings' batched arrays hold.
        if let Some(ix) = self
            .angles
            .0
            .get_or_init(|| crate::table::lookup::HalfdiffIndexer::new(&self.grid))
        {
            return ix.index_one(wi, wo);
        }
        let coords = self.grid.coords_of(wi, wo)?;
        let mut t = [0f64; 4];
        for (tk, (a, &x)) in t.iter_mut().zip(self.grid.axes().iter().zip(&coords)) {
            *tk = a.continuous_index(x);
        }
        Some(t)
    }

    /// Interpolates at continuous indices `t_in` (storage order) into `out`, which the caller
    /// has zeroed, reading validity from `mask` (the table's own flags or a bitset of them
    /// that stays in cache).
    #[inline(always)]
    /// `weigh(flat, w)` turns a neighbour's interpolation weight into the factor its value
    /// enters the sum with (the identity, or the cosine weighting of [`InterpWeight`]).
    fn interpolate_masked<M: CellMask + ?Sized>(
        &self,
        t_in: &[f64; 4],
        interp: Interp,
        layout: &Layout,
        mask: &M,
        out: &mut [f64],
        weigh: impl Fn(usize, f64) -> f64,
    ) {
        let c = self.channels.len();
        let Corners { wsum, tcont, .. } =
            self.corners_masked(t_in, interp, layout, mask, |flat, w| {
                let w = weigh(flat, w);
                for (o, &v) in out.iter_mut().zip(&self.data[flat * c..(flat + 1) * c]) {
                    *o += w * v as f64;
                }
            });
        if wsum > 0.0 && wsum != 1.0 {
            // Some neighbours were invalid: the rest carry the whole weight.
            for o in out.iter_mut() {
                *o /= wsum;
            }
        } else if wsum == 0.0 {
            let d = layout.d;
            if let Some(flat) = self.nearest_valid(&tcont[..d], &layout.strides[..d]) {
                let w = weigh(flat, 1.0);
                for (o, &v) in out.iter_mut().zip(&self.data[flat * c..(flat + 1) * c]) {
                    *o = w * v as f64;
                }
            }
        }
    }

    /// [`Table::interpolate_masked`] in a log space: the weighted mean of asinh(m·v/s) over
    /// the valid neighbours (m = `pre(flat)`, the neighbour's cosine weight or 1), mapped
    /// back and multiplied by `post` (1/q of the query, or 1). When no neighbour is valid,
    /// the nearest valid sample's m·v·post, untransformed. [`Stencil::apply`] repeats these
    /// operations in this order, so the two agree bit for bit.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn interpolate_log<M: CellMask + ?Sized>(
        &self,
        t_in: &[f64; 4],
        layout: &Layout,
        mask: &M,
        out: &mut [f64],
        log: LogSpace,
        pre: impl Fn(usize) -> f64,
        post: f64,
    ) {
        let c = self.channels.len();
        let Corners { wsum, tcont, .. } =
            self.corners_masked(t_in, Interp::Linear, layout, mask, |flat, w| {
                let m = pre(flat);
                for (o, &v) in out.iter_mut().zip(&self.data[flat * c..(flat + 1) * c]) {
                    *o += w * log.to_log(m * v as f64);
                }
            });
        if wsum > 0.0 {
            for o in out.iter_mut() {
                *o = log.finish(*o, wsum, post);
            }
        } else {
            let d = layout.d;
            if let Some(flat) = self.nearest_valid(&tcont[..d], &layout.strides[..d]) {
                let m = pre(flat);
                for (o, &v) in out.iter_mut().zip(&self.data[flat * c..(flat + 1) * c]) {
                    *o = post * (m * v as f64);
                }
            }
        }
    }

    /// The valid neighbours of continuous indices `t_in` with nonzero weight, in corner order,
    /// each handed to `visit(flat, weight)`; returns the weight sum and the split's continuous
    /// indices (for the nearest-valid fallback).
    #[inline(always)]
    fn corners_masked<M: CellMask + ?Sized>(
        &self,
        t_in: &[f64; 4],
        interp: Interp,
        layout: &Layout,
        mask: &M,
        mut visit: impl FnMut(usize, f64),
    ) -> Corners {
        let d = layout.d;
        let strides = &layout.strides;
        let nearest = interp == Interp::Nearest;
        // Per axis: two neighbour indices and the weight of the upper one.
        let mut lo = [0usize; 4];
        let mut hi = [0usize; 4];
        let mut frac = [0f64; 4];
        let mut tcont = [0f64; 4];
        for k in 0..d {
            let a = &layout.split[k];
            let s = a.split(t_in[k], nearest);
            (lo[k], hi[k]) = (a.index_of(s.lo), a.index_of(s.hi));
            frac[k] = s.frac;
            tcont[k] = s.t;
        }
        let mut wsum = 0.0;
        let mut listed = 0u16;
        for corner in 0..(1usize << d) {
            let w = corner_weight(&frac[..d], corner);
            let mut flat = 0;
            for k in 0..d {
                flat += if corner >> k & 1 == 1 { hi[k] } else { lo[k] } * strides[k];
            }
            if w == 0.0 || !mask.is_valid(flat) {
                continue;
            }
            wsum += w;
            listed |= 1 << corner;
            visit(flat, w);
        }
        Corners {
            wsum,
            tcont,
            frac,
            listed,
        }
    }

    /// The interpolation stencil of every pair of `pairs`: which cells [`Table::eval_into`]
    /// reads, with which weights, and what it does after the sum. [`Stencil::apply`] then
    /// gives eval_into's values, bit for bit, for any data on the same grid and validity. The
    /// codec search scores dozens of candidate tables on the same sample set; the geometry
    /// (directions → grid coordinates, atan2 and all) is worked out once here.
    pub fn stencil(&self, pairs: &[(Vec3, Vec3)], interp: Interp) -> Stencil {
        use rayon::prelude::*;
        let layout = Layout::new(&self.grid);
        // Cells are stored as u32 (the field's comment); the grid's own limit keeps them there.
        assert!(
            self.grid.cells() <= u32::MAX as usize,
            "grid beyond MAX_CELLS"
        );
        let log = self.log_space(interp);
        // Each part sized for every pair's 2^d neighbours, then shrunk to what it holds.
        let neighbours = 1usize << layout.d;
        let cosine = self.grid.weight() == InterpWeight::Cosine;
        let parts: Vec<StencilPart> = pairs
            .par_chunks(STENCIL_PART)
            .map(|pairs| {
                let mut st = StencilPart::with_capacity(
                    pairs.len(),
                    neighbours,
                    layout.d,
                    log.is_some(),
                    cosine,
                );
                for &(wi, wo) in pairs {
                    if log.is_some() {
                        self.push_log_stencil(&mut st, wi, wo, &layout);
                        continue;
                    }
                    let mut after = After::None;
                    let weight = self.query_weight(wi, wo);
                    let weigh = |flat: usize, w: f64| match &weight {
                        QueryWeight::Cosine { cells, inv_q } => {
                            cosine_weight(w, cells.at(flat) as f32, *inv_q)
                        }
                        _ => w,
                    };
                    let t = match weight {
                        QueryWeight::Horizon => None,
                        _ => self.continuous_indices(wi, wo),
                    };
                    let mut listed = (0u16, [0.0; 4]);
                    if let Some(t) = t {
                        let Corners {
                            wsum,
                            tcont,
                            frac,
                            listed: corners,
                        } = self.corners_masked(&t, interp, &layout, &self.valid[..], |flat, w| {
                            st.cells.push(flat as u32);
                            if cosine {
                                st.weights.push(weigh(flat, w));
                            }
                        });
                        listed = (corners, frac);
                        if wsum > 0.0 && wsum != 1.0 {
                            after = After::Divide(wsum);
                        } else if wsum == 0.0 {
                            let d = layout.d;
                            match self.nearest_valid(&tcont[..d], &layout.strides[..d]) {
                                Some(f) if matches!(weight, QueryWeight::Plain) => {
                                    after = After::Hold(f)
                                }
                                // The held value, scaled: one neighbour with its weight
                                // (0 + w·v is w·v, as eval_into computes it); a
                                // cosine-weighted grid's, whose weights are listed.
                                Some(f) => {
                                    debug_assert!(cosine, "a query weight of a plain grid");
                                    st.cells.push(f as u32);
                                    st.weights.push(weigh(f, 1.0));
                                }
                                None => {}
                            }
                        }
                    }
                    if !cosine {
                        st.push_corners(listed.0, &listed.1[..layout.d]);
                    }
                    st.end_pair(after);
                }
                st.shrink_to_fit();
                st
            })
            .collect();
        Stencil {
            channels: self.channels.len(),
            cells_in_grid: self.grid.cells(),
            d: layout.d,
            pairs: pairs.len(),
            log,
            parts,
        }
    }

    /// One pair's stencil on a log-space grid: the neighbours with their interpolation
    /// weights and cosine factors, the query's factor after the sum, and the fallback of
    /// [`Table::interpolate_log`].
    fn push_log_stencil(&self, st: &mut StencilPart, wi: Vec3, wo: Vec3, layout: &Layout) {
        let weight = self.query_weight(wi, wo);
        let (pre, post): (Option<&CellCosProducts>, f64) = match &weight {
            QueryWeight::Cosine { cells, inv_q } => (Some(cells), *inv_q),
            _ => (None, 1.0),
        };
        // Only a cosine-weighted grid's neighbours have factors: on a plain grid every one
        // would be 1 (12 MB of ones for a 4-D grid's estimation and check sets).
        let push_pre = |st: &mut StencilPart, flat: usize| {
            if let Some(c) = pre {
                st.pre.push(c.at(flat) as f32);
            }
        };
        let mut after = After::None;
        let t = match weight {
            QueryWeight::Horizon => None,
            _ => self.continuous_indices(wi, wo),
        };
        let mut listed = (0u16, [0.0; 4]);
        if let Some(t) = t {
            let Corners {
                wsum,
                tcont,
                frac,
                listed: corners,
            } = self.corners_masked(&t, Interp::Linear, layout, &self.valid[..], |flat, _| {
                st.cells.push(flat as u32);
                push_pre(st, flat);
            });
            listed = (corners, frac);
            if wsum > 0.0 {
                after = After::Divide(wsum);
            } else {
                let d = layout.d;
                if let Some(f) = self.nearest_valid(&tcont[..d], &layout.strides[..d]) {
                    // Not a corner: `Hold` reads it alone.
                    st.cells.push(f as u32);
                    push_pre(st, f);
                    after = After::Hold(f);
                }
            }
        }
        st.push_corners(listed.0, &listed.1[..layout.d]);
        st.end_pair(after);
        st.post.push(post);
    }

    /// `valid` packed 64 cells to a word, built once per table (the MERL grid's 1.46 M flags
    /// take ~2 ms to pack, 3% of a 10⁶-pair batch).
    fn valid_bits(&self) -> &ValidBits {
        self.bits.0.get_or_init(|| ValidBits::new(&self.valid))
    }

    /// Evaluates the table at many direction pairs: `out[p·C + ch]` for pair `p` and channel
    /// `ch`, the values of [`Table::eval_into`], bit for bit (the same angles, corner order
    /// and fallbacks at invalid neighbours). Runs in parallel; the result does not depend on the number of
    /// threads or on the SIMD path. Half/difference grids without θ limit take a vectorized
    /// path for the angles (`crate::table::lookup`), and 3-D ones (halfdiff3, the MERL grid)
    /// a trilinear stencil path ([`Table::eval_blocks3`]).
    ///
    /// # Panics
    /// When `out.len() != pairs.len() × channels` (a caller bug, not an input error).
    pub fn eval_batch(&self, pairs: &[(Vec3, Vec3)], interp: Interp, out: &mut [f64]) {
        self.eval_batch_with(pairs, interp, out, true)
    }

    /// [`Table::eval_batch`] on the calling thread: for a caller that already works in
    /// parallel chunks (checking and normalizing its rows, then looking them up, with no array
    /// of pairs between the two). The same bits: every pair is looked up on its own.
    pub fn eval_batch_serial(&self, pairs: &[(Vec3, Vec3)], interp: Interp, out: &mut [f64]) {
        self.eval_batch_impl(pairs, interp, out, true, false)
    }

    /// [`Table::eval_batch`], with the AVX2 loops allowed (`simd`, when the CPU has them) or
    /// not (the portable loops, which tests compare against).
    pub(crate) fn eval_batch_with(
        &self,
        pairs: &[(Vec3, Vec3)],
        interp: Interp,
        out: &mut [f64],
        simd: bool,
    ) {
        self.eval_batch_impl(pairs, interp, out, simd, true)
    }

    fn eval_batch_impl(
        &self,
        pairs: &[(Vec3, Vec3)],
        interp: Interp,
        out: &mut [f64],
        simd: bool,
        parallel: bool,
    ) {
        use crate::table::lookup::HalfdiffIndexer;
        use rayon::prelude::*;
        let c = self.channels.len();
        assert_eq!(
            out.len(),
            pairs.len() * c,
            "eval_batch: output length for {} pairs × {c} channels",
            pairs.len()
        );
        /// Pairs per parallel work item.
        const CHUNK: usize = 4096;
        // Cosine-weighted grids take the per-pair path and log-space ones their own
        // ([`Table::eval_log_blocks`]): the batched loops interpolate f linearly.
        let batched = self.grid.weight().is_none() && self.log_space(interp).is_none();
        let indexer = HalfdiffIndexer::new(&self.grid)
            .filter(|_| batched)
            .map(|mut ix| {
                ix.use_avx2 &= simd;
                ix
            });
        let avx2 = simd && crate::simd::avx2();
        let layout = Layout::new(&self.grid);
        let bits = match &indexer {
            Some(_) => self.valid_bits(),
            None => &ValidBits(Vec::new()),
        };
        let log = self.log_space(interp);
        let chunk = |(out, pairs): (&mut [f64], &[(Vec3, Vec3)])| match &indexer {
            None if log.is_some() => {
                let log = log.expect("a log space");
                self.eval_log_blocks(pairs, log, &layout, avx2, out)
            }
            None => {
                for (o, &(wi, wo)) in out.chunks_exact_mut(c).zip(pairs) {
                    self.eval_into(wi, wo, interp, o);
                }
            }
            Some(ix) if layout.d == 3 => {
                self.eval_blocks3(ix, pairs, interp, &layout, bits, avx2, out)
            }
            Some(ix) => self.eval_blocks(ix, pairs, interp, &layout, bits, out),
        };
        if parallel {
            out.par_chunks_mut(CHUNK * c)
                .zip(pairs.par_chunks(CHUNK))
                .for_each(chunk);
        } else {
            out.chunks_mut(CHUNK * c)
                .zip(pairs.chunks(CHUNK))
                .for_each(chunk);
        }
    }

    /// Batched lookups on a 3-D grid, a block of pairs at a time: the angles
    /// ([`HalfdiffIndexer::indices`]), then every pair's stencil axis by axis in f64 lanes
    /// ([`Table::prepare3`]), then the 8 corners of each pair ([`Table::interpolate3`]).
    /// Much of a lookup's cost is computation (the angles, then 8 corners with wrap, clamp
    /// and validity rules), so the work is arranged for f64 lanes and without branches; the
    /// corner lines of the next block are prefetched for the part that is memory
    /// (docs/benchmarks.md, "Batched lookups").
    #[allow(clippy::too_many_arguments)]
    fn eval_blocks3(
        &self,
        ix: &crate::table::lookup::HalfdiffIndexer,
        pairs: &[(Vec3, Vec3)],
        interp: Interp,
        layout: &Layout,
        bits: &ValidBits,
        avx2: bool,
        out: &mut [f64],
    ) {
        use crate::table::lookup::BLOCK;
        let c = self.channels.len();
        let nearest = interp == Interp::Nearest;
        // Software pipeline: the stencils of block k + 1 are computed and their cache lines
        // prefetched before block k is interpolated, so that misses (a table larger than the
        // cache, or a cache shared with other processes) overlap the work.
        let prepare = |p: &[(Vec3, Vec3)], b: &mut Block3| {
            b.n = p.len();
            ix.indices(p, &mut b.t, &mut b.ok);
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: `avx2` is only true when the CPU reports AVX2.
                unsafe { prepare3_avx2(&b.t[..b.n], nearest, layout, &mut b.st) };
                self.prefetch3(b);
                return;
            }
            prepare3(&b.t[..b.n], nearest, layout, &mut b.st);
            self.prefetch3(b);
        };
        let mut cur = Box::<Block3>::default();
        let mut next = Box::<Block3>::default();
        let mut blocks = out
            .chunks_mut(BLOCK * c)
            .zip(pairs.chunks(BLOCK))
            .peekable();
        if let Some((_, p)) = blocks.peek() {
            prepare(p, &mut cur);
        }
        while let Some((out, _)) = blocks.next() {
            if let Some((_, p)) = blocks.peek() {
                prepare(p, &mut next);
            }
            let (t, ok, st) = (&cur.t[..cur.n], &cur.ok[..cur.n], &cur.st);
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: `avx2` is only true when the CPU reports AVX2.
                unsafe {
                    if c == 3 {
                        self.interpolate3_rgb_avx2(t, ok, st, interp, layout, bits, out);
                    } else {
                        self.interpolate3_avx2(t, ok, st, interp, layout, bits, out);
                    }
                }
                std::mem::swap(&mut cur, &mut next);
                continue;
            }
            self.interpolate3(t, ok, st, interp, layout, bits, out);
            std::mem::swap(&mut cur, &mut next);
        }
    }

    /// Lookups in a log space ([`InterpSpace::Log`], either weight), a block of pairs at a
    /// time: every pair's angles and valid neighbours as [`Table::eval_into`] finds them,
    /// then the asinh of every neighbour's every channel in one pass (four lanes at a time
    /// with `avx2`, [`crate::math::log::asinh_in_place_avx2`]: the bits of one asinh per
    /// value), then each pair's weighted sum in corner order and [`LogSpace::finish`]; the
    /// nearest-valid fallback of a pair without a valid neighbour as
    /// [`Table::interpolate_log`] takes it. The operations of [`Table::interpolate_log`] on
    /// the same values in the same order, so the same bits (test
    /// `eval_batch_equals_eval_into`): per pair, the transforms were most of a log-space
    /// lookup (an asinh per corner and channel, 24 a pair on a 3-D RGB grid).
    fn eval_log_blocks(
        &self,
        pairs: &[(Vec3, Vec3)],
        log: LogSpace,
        layout: &Layout,
        avx2: bool,
        out: &mut [f64],
    ) {
        /// Pairs per block: their neighbours' values (64 × 16 × C f64 at most) stay in cache.
        const LOG_BLOCK: usize = 64;
        let c = self.channels.len();
        let most = LOG_BLOCK << layout.d;
        let mut weights: Vec<f64> = Vec::with_capacity(most);
        let mut logs: Vec<f64> = Vec::with_capacity(most * c);
        // Per pair with a valid neighbour: (pair, its neighbours' range, weight sum, post).
        let mut sums: Vec<(usize, usize, usize, f64, f64)> = Vec::with_capacity(LOG_BLOCK);
        for (out, pairs) in out.chunks_mut(LOG_BLOCK * c).zip(pairs.chunks(LOG_BLOCK)) {
            out.fill(0.0);
            weights.clear();
            logs.clear();
            sums.clear();
            for (p, &(wi, wo)) in pairs.iter().enumerate() {
                let Some(t) = self.continuous_indices(wi, wo) else {
                    continue;
                };
                let (cells, post) = match self.query_weight(wi, wo) {
                    QueryWeight::Plain => (None, 1.0),
                    QueryWeight::Cosine { cells, inv_q } => (Some(cells), inv_q),
                    QueryWeight::Horizon => continue,
                };
                let pre = |flat: usize| cells.map_or(1.0, |cc| cc.at(flat) as f32 as f64);
                let start = weights.len();
                let Corners { wsum, tcont, .. } =
                    self.corners_masked(&t, Interp::Linear, layout, &self.valid[..], |flat, w| {
                        let m = pre(flat);
                        weights.push(w);
                        // `LogSpace::to_log`'s argument.
                        logs.extend(
                            self.data[flat * c..(flat + 1) * c]
                                .iter()
                                .map(|&v| (m * v as f64) * log.inv_scale),
                        );
                    });
                if wsum > 0.0 {
                    sums.push((p, start, weights.len(), wsum, post));
                } else {
                    let d = layout.d;
                    if let Some(flat) = self.nearest_valid(&tcont[..d], &layout.strides[..d]) {
                        let m = pre(flat);
                        let o = &mut out[p * c..(p + 1) * c];
                        for (o, &v) in o.iter_mut().zip(&self.data[flat * c..(flat + 1) * c]) {
                            *o = post * (m * v as f64);
                        }
                    }
                }
            }
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: `avx2` is only true when the CPU reports AVX2.
                unsafe { crate::math::log::asinh_in_place_avx2(&mut logs) };
            } else {
                crate::math::log::asinh_in_place(&mut logs);
            }
            #[cfg(not(target_arch = "x86_64"))]
            {
                let _ = avx2;
                crate::math::log::asinh_in_place(&mut logs);
            }
            for &(p, start, end, wsum, post) in &sums {
                let o = &mut out[p * c..(p + 1) * c];
                for (j, &w) in weights[start..end].iter().enumerate() {
                    let y = &logs[(start + j) * c..(start + j + 1) * c];
                    for (o, &y) in o.iter_mut().zip(y) {
                        *o += w * y;
                    }
                }
                for o in o.iter_mut() {
                    *o = log.finish(*o, wsum, post);
                }
            }
        }
    }

    /// Hints the cache lines of a block's corners: for the four corners on the two slow
    /// axes, the cell and its neighbour along the fastest axis (usually the same or the next
    /// line).
    #[inline]
    fn prefetch3(&self, b: &Block3) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            let c = self.channels.len();
            let ptr = self.data.as_ptr();
            for p in (0..b.n).filter(|&p| b.ok[p]) {
                let (flats, _) = b.st.corners(p);
                for pair in [0, 1, 2, 3] {
                    // Corners `pair` and `pair + 4` differ along the fastest axis only.
                    let (first, last) = (flats[pair] * c, flats[pair + 4] * c + c - 1);
                    // SAFETY: both are inside `data` (`Stencil3::corners`); a prefetch is a
                    // hint and never faults anyway.
                    unsafe {
                        _mm_prefetch::<_MM_HINT_T0>(ptr.add(first) as *const i8);
                        _mm_prefetch::<_MM_HINT_T0>(ptr.add(last) as *const i8);
                    }
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = b;
    }

    /// The trilinear interpolation of a block from its stencils: 8 corners, each weighted by
    /// the product of its axis weights and by its validity (0 or 1, a mask rather than a
    /// branch). The sums run in the corner order of [`Table::interpolate_masked`] and add
    /// only exact zeros for the corners it skips, so the result has the same bits; the
    /// division by the weight sum is skipped there when it is exactly 1, and x/1 = x here.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn interpolate3(
        &self,
        t: &[[f64; 4]],
        ok: &[bool],
        st: &Stencil3,
        interp: Interp,
        layout: &Layout,
        bits: &ValidBits,
        out: &mut [f64],
    ) {
        let c = self.channels.len();
        for (p, o) in out.chunks_exact_mut(c).enumerate().take(t.len()) {
            o.fill(0.0);
            if !ok[p] {
                continue;
            }
            let (flats, ws) = st.corners(p);
            let mut wsum = 0.0;
            for (&flat, &w) in flats.iter().zip(&ws) {
                // Invalid cells hold 0 (a `Table` invariant), so a 0 weight adds exact zeros.
                let w = if bits.is_valid(flat) { w } else { 0.0 };
                wsum += w;
                for (o, &v) in o.iter_mut().zip(&self.data[flat * c..(flat + 1) * c]) {
                    *o += w * v as f64;
                }
            }
            if wsum > 0.0 {
                for o in o.iter_mut() {
                    *o /= wsum;
                }
            } else {
                // No valid neighbour: the generic path's fallback (rare, near the horizon).
                self.interpolate_masked(&t[p], interp, layout, bits, o, |_, w| w);
            }
        }
    }

    /// [`Table::interpolate3`] compiled for AVX2 (any channel count).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn interpolate3_avx2(
        &self,
        t: &[[f64; 4]],
        ok: &[bool],
        st: &Stencil3,
        interp: Interp,
        layout: &Layout,
        bits: &ValidBits,
        out: &mut [f64],
    ) {
        self.interpolate3(t, ok, st, interp, layout, bits, out)
    }

    /// [`Table::interpolate3`] for 3 channels with AVX2: each corner's RGB is one masked
    /// 4-lane load (the 4th lane is not read), widened to f64 and accumulated in 4 lanes.
    /// Multiply then add, no FMA: the same operations in the same order as the portable
    /// loop, so the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn interpolate3_rgb_avx2(
        &self,
        t: &[[f64; 4]],
        ok: &[bool],
        st: &Stencil3,
        interp: Interp,
        layout: &Layout,
        bits: &ValidBits,
        out: &mut [f64],
    ) {
        use std::arch::x86_64::*;
        debug_assert_eq!(self.channels.len(), 3);
        let data = self.data.as_ptr();
        let load3 = _mm_set_epi32(0, -1, -1, -1);
        for (p, o) in out.chunks_exact_mut(3).enumerate().take(t.len()) {
            if !ok[p] {
                o.fill(0.0);
                continue;
            }
            let (flats, ws) = st.corners(p);
            let mut acc = _mm256_setzero_pd();
            let mut wsum = 0.0;
            for (&flat, &w) in flats.iter().zip(&ws) {
                let w = if bits.is_valid(flat) { w } else { 0.0 };
                wsum += w;
                // SAFETY: `flat` < cells (`Stencil3::corners`), so lanes 0..3 at flat·3 are
                // inside `data`; the masked lane 3 is never accessed.
                let v = unsafe { _mm256_cvtps_pd(_mm_maskload_ps(data.add(flat * 3), load3)) };
                acc = _mm256_add_pd(acc, _mm256_mul_pd(_mm256_set1_pd(w), v));
            }
            if wsum > 0.0 {
                let mut v = [0f64; 4];
                // SAFETY: `v` holds 4 f64.
                unsafe {
                    _mm256_storeu_pd(v.as_mut_ptr(), _mm256_div_pd(acc, _mm256_set1_pd(wsum)))
                };
                o.copy_from_slice(&v[..3]);
            } else {
                o.fill(0.0);
                self.interpolate_masked(&t[p], interp, layout, bits, o, |_, w| w);
            }
        }
    }

    /// Batched lookups on a 4-D grid: the angles of 64 pairs at a time, then the generic
    /// interpolation of each. Software pipeline: the angles and cache-line prefetches of
    /// block k + 1 are issued before block k is interpolated, so its misses overlap that work.
    fn eval_blocks(
        &self,
        ix: &crate::table::lookup::HalfdiffIndexer,
        pairs: &[(Vec3, Vec3)],
        interp: Interp,
        layout: &Layout,
        bits: &ValidBits,
        out: &mut [f64],
    ) {
        use crate::table::lookup::BLOCK;
        let c = self.channels.len();
        let strides = &layout.strides;
        let mut cur = ([[0f64; 4]; BLOCK], [false; BLOCK]);
        let mut next = cur;
        let blocks: Vec<_> = out.chunks_mut(BLOCK * c).zip(pairs.chunks(BLOCK)).collect();
        if let Some((_, p)) = blocks.first() {
            ix.indices(p, &mut cur.0, &mut cur.1);
            self.prefetch_corners(&cur.0[..p.len()], &cur.1, strides);
        }
        let n_blocks = blocks.len();
        let mut blocks = blocks.into_iter().peekable();
        for _ in 0..n_blocks {
            let Some((out, p)) = blocks.next() else {
                break;
            };
            if let Some((_, pn)) = blocks.peek() {
                ix.indices(pn, &mut next.0, &mut next.1);
                self.prefetch_corners(&next.0[..pn.len()], &next.1, strides);
            }
            let t = &cur.0[..p.len()];
            if ix.use_avx2 {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `use_avx2` is only true when the CPU reports AVX2 and FMA.
                unsafe {
                    self.interpolate_block_avx2(t, &cur.1, interp, layout, bits, out)
                };
            } else {
                self.interpolate_block(t, &cur.1, interp, layout, bits, out);
            }
            std::mem::swap(&mut cur, &mut next);
        }
    }

    #[inline(always)]
    fn interpolate_block(
        &self,
        t: &[[f64; 4]],
        ok: &[bool],
        interp: Interp,
        layout: &Layout,
        bits: &ValidBits,
        out: &mut [f64],
    ) {
        let c = self.channels.len();
        for ((o, tk), &okk) in out.chunks_exact_mut(c).zip(t).zip(ok) {
            o.fill(0.0);
            if okk {
                self.interpolate_masked(tk, interp, layout, bits, o, |_, w| w);
            }
        }
    }

    /// The same, compiled for AVX2 (floor and round become single instructions).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn interpolate_block_avx2(
        &self,
        t: &[[f64; 4]],
        ok: &[bool],
        interp: Interp,
        layout: &Layout,
        bits: &ValidBits,
        out: &mut [f64],
    ) {
        self.interpolate_block(t, ok, interp, layout, bits, out)
    }

    /// Hints the cache lines of the lower corner of every pair's cell along the two or
    /// three slow axes (the fastest axis's neighbour is adjacent in memory).
    #[inline]
    fn prefetch_corners(&self, t: &[[f64; 4]], ok: &[bool], strides: &[usize; 4]) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            let axes = self.grid.axes();
            let d = axes.len();
            let c = self.channels.len();
            let ptr = self.data.as_ptr();
            let len = self.data.len();
            for (tk, _) in t.iter().zip(ok).filter(|(_, o)| **o) {
                let mut base = 0usize;
                for k in 0..d {
                    let n = axes[k].n;
                    // Truncation of a value clamped to [0, n − 1]: never out of range.
                    let i = tk[k].clamp(0.0, (n - 1) as f64) as usize;
                    base += i * strides[k];
                }
                for corner in 0..(1usize << (d - 1)) {
                    let mut flat = base;
                    for (k, &stride) in strides.iter().enumerate().take(d - 1) {
                        if corner >> k & 1 == 1 {
                            flat += stride;
                        }
                    }
                    // The cell and its neighbour along the fastest axis (often the next line).
                    let first = (flat * c).min(len.saturating_sub(1));
                    let last = (flat * c + 2 * c - 1).min(len.saturating_sub(1));
                    // SAFETY: a prefetch is a hint and never faults; the addresses are inside
                    // `data` anyway.
                    unsafe {
                        _mm_prefetch::<_MM_HINT_T0>(ptr.add(first) as *const i8);
                        _mm_prefetch::<_MM_HINT_T0>(ptr.add(last) as *const i8);
                    }
                }
            }
        }
    }

    /// Search radius (in cells) of the nearest-valid fallback.
    const FALLBACK_RADIUS: i64 = 3;

    /// The valid cell nearest (in index space) to continuous indices `t`, within
    /// [`Self::FALLBACK_RADIUS`] cells; ties go to the lowest flat index (deterministic).
    ///
    /// The box of (2r + 2)^d candidates (4096 on a 4-D grid) is visited shell by shell: each
    /// axis's candidates sorted by their distance to `t`, shell m the cells whose largest
    /// rank is m. Every cell of shell m is at least as far as the nearest of its axes' m-th
    /// candidates, so once that bound exceeds the best found no later cell can win; the
    /// answer is the minimum over the whole box, as a plain scan gives it.
    ///
    /// A box that holds no valid cell on some axis (outside the range of the valid cells'
    /// indices there, [`Table::valid_bounds`]) is answered at once: a table with no valid cell,
    /// or only a few, was searched box by box for every lookup (`pack` of a MERL file with one
    /// valid bin: 15 s, docs/robustness.md).
    fn nearest_valid(&self, t: &[f64], strides: &[usize]) -> Option<usize> {
        const SPAN: usize = (2 * Table::FALLBACK_RADIUS + 2) as usize;
        let axes = self.grid.axes();
        let d = t.len();
        let bounds = self.valid_bounds()?;
        for k in 0..d {
            let first = t[k].floor() as i64 - Self::FALLBACK_RADIUS;
            let last = first + SPAN as i64 - 1;
            let (lo, hi) = (bounds[k].0 as i64, bounds[k].1 as i64);
            let reachable = if axes[k].is_periodic() {
                (first..=last).any(|i| (lo..=hi).contains(&i.rem_euclid(axes[k].n as i64)))
            } else {
                first <= hi && last >= lo
            };
            if !reachable {
                return None;
            }
        }
        // Per axis: (squared distance, unwrapped index) of each candidate, nearest first.
        let mut cand = [[(0.0f64, 0i64); SPAN]; 4];
        for k in 0..d {
            let first = t[k].floor() as i64 - Self::FALLBACK_RADIUS;
            for (o, c) in cand[k].iter_mut().enumerate() {
                let i = first + o as i64;
                *c = ((i as f64 - t[k]).powi(2), i);
            }
            cand[k].sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        }
        let nearest_sum: f64 = (0..d).map(|k| cand[k][0].0).sum();
        let mut best: Option<(f64, usize)> = None;
        for m in 0..SPAN {
            if let Some((bd, _)) = best {
                let bound = (0..d)
                    .map(|k| nearest_sum - cand[k][0].0 + cand[k][m].0)
                    .fold(f64::INFINITY, f64::min);
                // A margin for the bound's other summation order: a cell at the best
                // distance with a lower flat index must still be visited.
                if bound > bd + 1e-9 * (1.0 + bd) {
                    break;
                }
            }
            let mut rank = [0usize; 4];
            'shell: loop {
                if rank[..d].contains(&m) {
                    let mut flat = 0usize;
                    let mut dist = 0.0;
                    let mut inside = true;
                    for k in 0..d {
                        let a = &axes[k];
                        let (dk, i) = cand[k][rank[k]];
                        let idx = if a.is_periodic() {
                            i.rem_euclid(a.n as i64)
                        } else if i < 0 || i >= a.n as i64 {
                            inside = false;
                            0
                        } else {
                            i
                        };
                        dist += dk;
                        flat += idx as usize * strides[k];
                    }
                    if inside
                        && self.valid[flat]
                        && best.is_none_or(|(bd, bf)| dist < bd || (dist == bd && flat < bf))
                    {
                        best = Some((dist, flat));
                    }
                }
                // Next rank tuple in [0, m]^d.
                for r in rank.iter_mut().take(d) {
                    *r += 1;
                    if *r <= m {
                        continue 'shell;
                    }
                    *r = 0;
                }
                break;
            }
        }
        best.map(|(_, f)| f)
    }

    /// Per axis (storage order), the smallest and largest index of a valid cell; `None` when
    /// no cell is valid. Built once (a pass over the flags) and kept until validity changes.
    fn valid_bounds(&self) -> Option<[(usize, usize); 4]> {
        *self.bounds.0.get_or_init(|| {
            let axes = self.grid.axes();
            let d = axes.len();
            let mut bounds = [(usize::MAX, 0usize); 4];
            let mut any = false;
            // The multi-index of each flat index in C order (the last axis fastest).
            let mut idx = [0usize; 4];
            for &ok in &self.valid {
                if ok {
                    any = true;
                    for (b, &i) in bounds.iter_mut().zip(&idx).take(d) {
                        *b = (b.0.min(i), b.1.max(i));
                    }
                }
                for k in (0..d).rev() {
                    idx[k] += 1;
                    if idx[k] < axes[k].n {
                        break;
                    }
                    idx[k] = 0;
                }
            }
            any.then_some(bounds)
        })
    }

    /// Like [`Table::eval_into`] but refuses queries outside the stored domain (θ > θmax)
    /// instead of returning 0, since a silent 0 there would be an extrapolation.
    pub fn try_eval(&self, wi: Vec3, wo: Vec3, interp: Interp, out: &mut [f64]) -> Result<()> {
        if let Some(t) = self.grid.theta_max()
            && wi.z > 0.0
            && wo.z > 0.0
            && !self.grid.in_domain(wi, wo)
        {
            return Err(Error::input(format!(
                "direction pair ({:?}, {:?}) is outside the stored domain θ ≤ {}°",
                wi.to_array(),
                wo.to_array(),
                t.to_degrees()
            )));
        }
        self.eval_into(wi, wo, interp, out);
        Ok(())
    }
}

/// Validity of cells by flat index.
trait CellMask {
    fn is_valid(&self, flat: usize) -> bool;
}

impl CellMask for [bool] {
    #[inline(always)]
    fn is_valid(&self, flat: usize) -> bool {
        self[flat]
    }
}

/// Validity flags packed 64 to a word.
#[derive(Clone, Debug)]
struct ValidBits(Vec<u64>);

impl ValidBits {
    fn new(valid: &[bool]) -> ValidBits {
        ValidBits(
            valid
                .chunks(64)
                .map(|w| {
                    w.iter()
                        .enumerate()
                        .fold(0u64, |acc, (i, &v)| acc | (v as u64) << i)
                })
                .collect(),
        )
    }
}

impl CellMask for ValidBits {
    #[inline(always)]
    fn is_valid(&self, flat: usize) -> bool {
        self.0[flat >> 6] >> (flat & 63) & 1 == 1
    }
}

/// [`ValidBits`] of a table, built on the first batched lookup and dropped wherever the
/// validity flags can change (`Table::reset`, `Table::buffers_mut`). A cache, not part of
/// the table's value: any two compare equal, so `Table`'s `PartialEq` compares the data.
#[derive(Clone, Debug, Default)]
struct BitsCache(std::sync::OnceLock<ValidBits>);

impl PartialEq for BitsCache {
    fn eq(&self, _: &BitsCache) -> bool {
        true
    }
}

/// [`Table::valid_bounds`], built on first use; like [`BitsCache`], a cache that is not part
/// of the table's value.
#[derive(Clone, Debug, Default)]
struct BoundsCache(std::sync::OnceLock<Option<[(usize, usize); 4]>>);

impl PartialEq for BoundsCache {
    fn eq(&self, _: &BoundsCache) -> bool {
        true
    }
}

/// Per-cell cos θi · cos θo of a cosine-weighted grid, built on first use; like
/// [`BitsCache`], a cache that is not part of the table's value.
#[derive(Clone, Debug, Default)]
struct CosCache(std::sync::OnceLock<CellCosProducts>);

impl PartialEq for CosCache {
    fn eq(&self, _: &CosCache) -> bool {
        true
    }
}

/// The angle maps of [`crate::table::lookup::HalfdiffIndexer`] for the per-pair lookup, built
/// once per grid (they were rebuilt for every pair); like [`BitsCache`], a cache that is not
/// part of the table's value.
#[derive(Clone, Debug, Default)]
struct AnglesCache(std::sync::OnceLock<Option<crate::table::lookup::HalfdiffIndexer>>);

impl PartialEq for AnglesCache {
    fn eq(&self, _: &AnglesCache) -> bool {
        true
    }
}

/// Below this cos θi · cos θo a query on a cosine-weighted grid counts as on the horizon
/// (0, like a query below it): 1/q stays far from overflow, and a direction that close to
/// the horizon (both cosines ~1e-100) is not one a renderer asks about.
const MIN_COS_PRODUCT: f64 = 1e-200;

/// How one query weighs its neighbours ([`InterpWeight`]).
enum QueryWeight<'a> {
    Plain,
    /// f·cos θi·cos θo interpolated, divided by the query's own product (1/q = `inv_q`).
    Cosine {
        cells: &'a CellCosProducts,
        inv_q: f64,
    },
    /// A cosine-weighted grid queried on the horizon: 0.
    Horizon,
}

/// The maps of a log interpolation space ([`InterpSpace::Log`]) of scale s.
#[derive(Clone, Copy, Debug)]
struct LogSpace {
    scale: f64,
    inv_scale: f64,
}

impl LogSpace {
    fn new(scale: f64) -> LogSpace {
        LogSpace {
            scale,
            inv_scale: 1.0 / scale,
        }
    }
    /// asinh(u/s): ln(2u/s) above s, u/s below, odd. The inlined asinh of
    /// [`crate::math::log`]: libm's was a quarter of a `pack` on a log-space grid.
    #[inline(always)]
    fn to_log(self, u: f64) -> f64 {
        crate::math::log::asinh(u * self.inv_scale)
    }
    /// The value of a sum `y` of weighted logs whose weights sum to `wsum` > 0, times the
    /// query's factor `post`. The one expression every path uses.
    #[inline(always)]
    fn finish(self, y: f64, wsum: f64, post: f64) -> f64 {
        let y = if wsum != 1.0 { y / wsum } else { y };
        post * (self.scale * y.sinh())
    }
}

/// The factor of a neighbour of interpolation weight `w` whose sample has cos θi·cos θo =
/// `cell`, for a query of 1/(cos θi·cos θo) = `inv_q`; the one expression every path uses,
/// so that eval and stencils agree bit for bit.
#[inline(always)]
fn cosine_weight(w: f64, cell: f32, inv_q: f64) -> f64 {
    w * (cell as f64 * inv_q)
}

/// One axis's rule for splitting a continuous index into two neighbours and the weight of
/// the upper one ([`Interp`]): snap to a sample within 1e-9, wrap (periodic φ) or clamp
/// (θ ends), and for nearest keep one neighbour. In f64 and branch-free (selects only), so
/// the same function serves the per-query path and the lanes of [`prepare3`].
#[derive(Clone, Copy, Debug)]
struct AxisSplit {
    n: f64,
    inv_n: f64,
    /// n − 1, the last index.
    last: f64,
    last_index: usize,
    periodic: bool,
}

/// An index split by [`AxisSplit::split`]; `lo` and `hi` are integers in [0, n − 1].
#[derive(Clone, Copy, Debug)]
struct Split {
    lo: f64,
    hi: f64,
    /// The weight of `hi`.
    frac: f64,
    /// The index after snapping (for the nearest-valid fallback).
    t: f64,
}

impl AxisSplit {
    fn new(a: &crate::grid::Axis) -> AxisSplit {
        let n = a.n as f64;
        AxisSplit {
            n,
            inv_n: 1.0 / n,
            last: n - 1.0,
            last_index: a.n - 1,
            periodic: a.is_periodic(),
        }
    }

    #[inline(always)]
    fn split(&self, t: f64, nearest: bool) -> Split {
        // A query rebuilt from a sample position lands within rounding (~1e-13) of an
        // integer index; snap it so the sample is returned exactly rather than blended
        // with a neighbour that may be orders of magnitude larger (a specular peak).
        // (Ties to even: it differs from `round` only at x.5, which is never snapped.)
        let r = t.round_ties_even();
        let t = if (t - r).abs() < 1e-9 { r } else { t };
        let (lo, hi, frac) = if self.periodic {
            let f = t.floor();
            // f mod n in f64 (exact for integers this size); the quotient may round to one
            // off, which the two selects correct.
            let i = f - (f * self.inv_n).floor() * self.n;
            let i = if i < 0.0 { i + self.n } else { i };
            let i = if i >= self.n { i - self.n } else { i };
            let h = if i + 1.0 >= self.n { 0.0 } else { i + 1.0 };
            (i, h, t - f)
        } else {
            // Clamped θ ends: constant beyond the first and last samples. At the ends frac
            // is 0, so the upper neighbour (kept in range) has weight 0.
            let tc = t.max(0.0).min(self.last);
            let f = tc.floor();
            (f, (f + 1.0).min(self.last), tc - f)
        };
        if nearest {
            let i = if frac >= 0.5 { hi } else { lo };
            Split {
                lo: i,
                hi: i,
                frac: 0.0,
                t,
            }
        } else {
            Split { lo, hi, frac, t }
        }
    }

    /// A split index as `usize`, in [0, n − 1] whatever the float (NaN gives 0), so that
    /// flat indices built from it are always inside the table.
    #[inline(always)]
    fn index_of(&self, x: f64) -> usize {
        (x as usize).min(self.last_index)
    }
}

/// What [`Table::eval_into`] does after summing a pair's weighted neighbours.
#[derive(Clone, Copy, Debug)]
enum After {
    None,
    /// Some neighbours were invalid: divide by the weight of the others.
    Divide(f64),
    /// Every neighbour was invalid: hold this cell's value.
    Hold(usize),
}

/// What [`Table::corners_masked`] found: the weight sum of the listed neighbours, the
/// split's continuous indices (for the nearest-valid fallback), each axis's fraction and the
/// corners listed (bit `corner`).
struct Corners {
    wsum: f64,
    tcont: [f64; 4],
    frac: [f64; 4],
    listed: u16,
}

/// The interpolation weight of `corner` (bit k: the upper neighbour along axis k) from the
/// axes' fractions: the product in axis order, the same bits wherever it is made.
#[inline(always)]
fn corner_weight(frac: &[f64], corner: usize) -> f64 {
    let mut w = 1.0;
    for (k, &f) in frac.iter().enumerate() {
        w *= if corner >> k & 1 == 1 { f } else { 1.0 - f };
    }
    w
}

/// The interpolation stencils of a list of direction pairs on one grid and validity
/// ([`Table::stencil`]), in parts of [`STENCIL_PART`] pairs: made in parallel a part at a
/// time and kept as made (one array of every part's neighbours, made by concatenating them,
/// held both copies at once: 25 MB more at the 64⁴ packs' peak), and applied a part at a time.
#[derive(Clone, Debug, Default)]
pub struct Stencil {
    channels: usize,
    cells_in_grid: usize,
    /// Axes of the grid.
    d: usize,
    pairs: usize,
    /// Log-space grids ([`InterpSpace::Log`]): the space, each neighbour's factor inside the
    /// log (its cos θi·cos θo on cosine-weighted grids, else 1) and each pair's factor after
    /// it; `Hold` then holds the pair's one listed cell. `None` otherwise.
    log: Option<LogSpace>,
    parts: Vec<StencilPart>,
}

/// Pairs in each part of a [`Stencil`] but the last.
const STENCIL_PART: usize = 4096;

/// The stencils of up to [`STENCIL_PART`] consecutive pairs.
#[derive(Clone, Debug, Default)]
struct StencilPart {
    /// Pair p's neighbours are `cells[ends[p-1]..ends[p]]`, with `weights` alongside.
    ends: Vec<u32>,
    /// u32: a grid has at most [`crate::grid::MAX_CELLS`] (2³¹) cells, and the estimation
    /// sets hold millions of neighbours, so half the bytes of usize count.
    cells: Vec<u32>,
    /// Each neighbour's weight: cosine-weighted grids in the linear space only, where it
    /// depends on the neighbour's cell ([`InterpWeight::Cosine`]).
    weights: Vec<f64>,
    /// Otherwise each pair's d axis fractions and the corners it lists (bit `corner`, in
    /// corner order): a neighbour's weight is the product [`corner_weight`] makes again, the
    /// bits [`Table::corners_masked`] gave (d values a pair, not 2^d).
    fracs: Vec<f64>,
    corners: Vec<u16>,
    after: Vec<After>,
    /// Log-space grids: each neighbour's factor inside the log (empty on a grid without the
    /// cosine weight: every factor 1) and each pair's factor after it.
    pre: Vec<f32>,
    post: Vec<f64>,
}

impl StencilPart {
    /// A part for `pairs` pairs of up to `neighbours` neighbours each, sized once (grown by
    /// doubling, a 4-D grid's arrays reached twice their size).
    /// A part of a grid of `d` axes, with the cosine weight or not, in the log space or not.
    fn with_capacity(
        pairs: usize,
        neighbours: usize,
        d: usize,
        log: bool,
        cosine: bool,
    ) -> StencilPart {
        let listed = log || !cosine;
        StencilPart {
            ends: Vec::with_capacity(pairs),
            cells: Vec::with_capacity(pairs * neighbours),
            weights: Vec::with_capacity(if listed { 0 } else { pairs * neighbours }),
            fracs: Vec::with_capacity(if listed { pairs * d } else { 0 }),
            corners: Vec::with_capacity(if listed { pairs } else { 0 }),
            after: Vec::with_capacity(pairs),
            pre: Vec::with_capacity(if log && cosine { pairs * neighbours } else { 0 }),
            post: Vec::with_capacity(if log { pairs } else { 0 }),
        }
    }

    /// The current pair's corners listed and axis fractions (every pair of a part whose
    /// weights are products, listed or not).
    fn push_corners(&mut self, listed: u16, frac: &[f64]) {
        self.corners.push(listed);
        self.fracs.extend_from_slice(frac);
    }

    /// Each neighbour of local pair p on a grid of `d` axes: (its index in the part, its
    /// cell, its weight), in the order listed.
    #[inline(always)]
    fn for_each_neighbour(&self, d: usize, p: usize, mut f: impl FnMut(usize, u32, f64)) {
        let range = self.range(p);
        if self.corners.is_empty() {
            for k in range {
                f(k, self.cells[k], self.weights[k]);
            }
        } else {
            let frac = &self.fracs[p * d..(p + 1) * d];
            let mut rest = self.corners[p];
            for k in range {
                let corner = rest.trailing_zeros() as usize;
                rest &= rest.wrapping_sub(1);
                f(k, self.cells[k], corner_weight(frac, corner));
            }
        }
    }

    /// Ends the current pair (its neighbours pushed).
    fn end_pair(&mut self, after: After) {
        self.ends.push(self.cells.len() as u32);
        self.after.push(after);
    }

    fn shrink_to_fit(&mut self) {
        self.ends.shrink_to_fit();
        self.cells.shrink_to_fit();
        self.weights.shrink_to_fit();
        self.fracs.shrink_to_fit();
        self.corners.shrink_to_fit();
        self.after.shrink_to_fit();
        self.pre.shrink_to_fit();
        self.post.shrink_to_fit();
    }

    /// The neighbours of local pair p.
    #[inline]
    fn range(&self, p: usize) -> std::ops::Range<usize> {
        let start = if p == 0 { 0 } else { self.ends[p - 1] as usize };
        start..self.ends[p] as usize
    }

    /// Neighbour k's factor inside the log (1 when the grid has no cosine weight).
    #[inline]
    fn pre_at(&self, k: usize) -> f64 {
        if self.pre.is_empty() {
            1.0
        } else {
            self.pre[k] as f64
        }
    }
}

impl Stencil {
    /// Pairs covered.
    pub fn len(&self) -> usize {
        self.pairs
    }

    pub fn is_empty(&self) -> bool {
        self.pairs == 0
    }

    /// The first cell pair `p` reads (its lowest neighbour; the held cell when every
    /// neighbour is invalid; `usize::MAX` when it reads none): a sort key that puts pairs
    /// reading nearby cells next to each other.
    pub fn first_cell(&self, p: usize) -> usize {
        let part = &self.parts[p / STENCIL_PART];
        let p = p % STENCIL_PART;
        match part.after[p] {
            After::Hold(flat) => flat,
            _ => part.cells[part.range(p)]
                .iter()
                .map(|&f| f as usize)
                .min()
                .unwrap_or(usize::MAX),
        }
    }

    /// Every cell the stencils read (their neighbours and held cells), in no particular
    /// order and possibly repeated.
    pub fn cells_read(&self) -> impl Iterator<Item = u32> + '_ {
        self.parts.iter().flat_map(|part| {
            let held = part.after.iter().filter_map(|a| match a {
                After::Hold(flat) => Some(*flat as u32),
                _ => None,
            });
            part.cells.iter().copied().chain(held)
        })
    }

    /// The values of a table with these stencils' grid, validity and channel count holding
    /// `data` (cell-major): `out[p·C + ch]`, bit-identical to [`Table::eval_into`].
    ///
    /// # Panics
    /// When `data` or `out` has the wrong length (a caller bug).
    pub fn apply(&self, data: &[f32], out: &mut [f64]) {
        assert_eq!(
            data.len(),
            self.cells_in_grid * self.channels,
            "Stencil::apply: data length"
        );
        self.apply_with(data, out, |f| f);
    }

    /// [`Stencil::apply`] of a table given by the values of some of its cells alone (every
    /// cell these stencils read among them, [`Stencil::cells_read`]): `values[position(f)·C..]`
    /// holds cell f's. The same bits as `apply` on the whole table (the same values, summed in
    /// the same order): what lets a measurement decode only the cells it reads.
    ///
    /// # Panics
    /// When `position` gives a place outside `values` or `out` has the wrong length (a caller
    /// bug).
    pub fn apply_at_cells(
        &self,
        values: &[f32],
        out: &mut [f64],
        position: impl Fn(u32) -> u32 + Sync,
    ) {
        self.apply_with(values, out, position);
    }

    #[inline(always)]
    fn apply_with(&self, data: &[f32], out: &mut [f64], position: impl Fn(u32) -> u32 + Sync) {
        use rayon::prelude::*;
        let c = self.channels;
        assert_eq!(out.len(), self.len() * c, "Stencil::apply: output length");
        out.par_chunks_mut(STENCIL_PART * c)
            .zip(&self.parts)
            .for_each(|(out, part)| {
                for (p, o) in out.chunks_exact_mut(c).enumerate() {
                    let range = part.range(p);
                    if let Some(log) = self.log {
                        self.apply_log(log, part, p, range, data, o, &position);
                        continue;
                    }
                    o.fill(0.0);
                    part.for_each_neighbour(self.d, p, |_, flat, w| {
                        let flat = position(flat) as usize;
                        for (o, &v) in o.iter_mut().zip(&data[flat * c..(flat + 1) * c]) {
                            *o += w * v as f64;
                        }
                    });
                    match part.after[p] {
                        After::None => {}
                        After::Divide(wsum) => {
                            for o in o.iter_mut() {
                                *o /= wsum;
                            }
                        }
                        After::Hold(flat) => {
                            let flat = position(flat as u32) as usize;
                            for (o, &v) in o.iter_mut().zip(&data[flat * c..(flat + 1) * c]) {
                                *o = v as f64;
                            }
                        }
                    }
                }
            });
    }

    /// One pair of a log-space stencil: [`Table::interpolate_log`]'s operations in its order.
    #[allow(clippy::too_many_arguments)] // the pair, its part and the values.
    #[inline(always)]
    fn apply_log(
        &self,
        log: LogSpace,
        part: &StencilPart,
        p: usize,
        range: std::ops::Range<usize>,
        data: &[f32],
        o: &mut [f64],
        position: &impl Fn(u32) -> u32,
    ) {
        let c = self.channels;
        let post = part.post[p];
        o.fill(0.0);
        if let After::Hold(_) = part.after[p] {
            let (flat, m) = (
                position(part.cells[range.start]) as usize,
                part.pre_at(range.start),
            );
            for (o, &v) in o.iter_mut().zip(&data[flat * c..(flat + 1) * c]) {
                *o = post * (m * v as f64);
            }
            return;
        }
        part.for_each_neighbour(self.d, p, |k, flat, w| {
            let (flat, m) = (position(flat) as usize, part.pre_at(k));
            for (o, &v) in o.iter_mut().zip(&data[flat * c..(flat + 1) * c]) {
                *o += w * log.to_log(m * v as f64);
            }
        });
        if let After::Divide(wsum) = part.after[p] {
            for o in o.iter_mut() {
                *o = log.finish(*o, wsum, post);
            }
        }
    }
}

/// Per-axis constants of interpolation on a grid: the split rules and the flat strides.
#[derive(Clone, Copy, Debug)]
struct Layout {
    d: usize,
    split: [AxisSplit; 4],
    /// Flat-index strides of the axes (C order).
    strides: [usize; 4],
}

impl Layout {
    fn new(grid: &Grid) -> Layout {
        let axes = grid.axes();
        let d = axes.len();
        let mut strides = [0usize; 4];
        let mut s = 1;
        for k in (0..d).rev() {
            strides[k] = s;
            s *= axes[k].n;
        }
        let split = std::array::from_fn(|k| AxisSplit::new(&axes[k.min(d - 1)]));
        Layout { d, split, strides }
    }
}

/// The trilinear stencils of a block of pairs on a 3-D grid, axis-major so that
/// [`prepare3`] fills them in f64 lanes.
struct Stencil3 {
    /// Flat index of the lower corner (an exact integer).
    base: [f64; BLOCK],
    /// Flat offset from the lower to the upper neighbour per axis: 0 at a clamped end and
    /// for nearest, negative across the periodic wrap.
    step: [[f64; BLOCK]; 3],
    /// Weights of the lower and the upper neighbour per axis.
    w: [[[f64; BLOCK]; 2]; 3],
}

use crate::table::lookup::BLOCK;

/// One block of a batch on a 3-D grid: continuous indices, domain flags and stencils.
struct Block3 {
    n: usize,
    t: [[f64; 4]; BLOCK],
    ok: [bool; BLOCK],
    st: Stencil3,
}

impl Default for Block3 {
    fn default() -> Block3 {
        Block3 {
            n: 0,
            t: [[0.0; 4]; BLOCK],
            ok: [false; BLOCK],
            st: Stencil3::default(),
        }
    }
}

impl Default for Stencil3 {
    fn default() -> Stencil3 {
        Stencil3 {
            base: [0.0; BLOCK],
            step: [[0.0; BLOCK]; 3],
            w: [[[0.0; BLOCK]; 2]; 3],
        }
    }
}

impl Stencil3 {
    /// Flat indices and weights of pair `p`'s 8 corners, corner bit k = upper along axis k
    /// (the order of [`Table::interpolate_masked`]); the weight is the product over axes in
    /// axis order, as there.
    #[inline(always)]
    fn corners(&self, p: usize) -> ([usize; 8], [f64; 8]) {
        // Exact integers in range (see `prepare3`): the casts are exact.
        let base = self.base[p] as usize;
        let s = [
            self.step[0][p] as isize,
            self.step[1][p] as isize,
            self.step[2][p] as isize,
        ];
        let w = |k: usize, b: usize| self.w[k][b][p];
        let mut flats = [0usize; 8];
        let mut ws = [0f64; 8];
        for corner in 0..8 {
            let (b0, b1, b2) = (corner & 1, corner >> 1 & 1, corner >> 2 & 1);
            let off = s[0] * b0 as isize + s[1] * b1 as isize + s[2] * b2 as isize;
            flats[corner] = base.wrapping_add_signed(off);
            ws[corner] = w(0, b0) * w(1, b1) * w(2, b2);
        }
        (flats, ws)
    }
}

/// The stencils of a block of continuous indices (3-D grid), axis by axis so that each
/// loop runs in f64 lanes. Every index is clamped into [0, n − 1] (`AxisSplit::split` keeps
/// it there; `max`/`min` also map NaN, from pairs outside the domain, to 0), so the flat
/// indices of all corners are inside the table.
#[inline(always)]
fn prepare3(t: &[[f64; 4]], nearest: bool, layout: &Layout, st: &mut Stencil3) {
    let n = t.len();
    st.base[..n].fill(0.0);
    for k in 0..3 {
        let a = layout.split[k];
        let stride = layout.strides[k] as f64;
        let [w0, w1] = &mut st.w[k];
        let lanes = t
            .iter()
            .zip(&mut st.base[..n])
            .zip(&mut st.step[k][..n])
            .zip(w0[..n].iter_mut().zip(&mut w1[..n]));
        for (((tk, base), step), (w0, w1)) in lanes {
            let s = a.split(tk[k], nearest);
            let lo = s.lo.max(0.0).min(a.last);
            let hi = s.hi.max(0.0).min(a.last);
            *base += lo * stride;
            *step = (hi - lo) * stride;
            *w0 = 1.0 - s.frac;
            *w1 = s.frac;
        }
    }
}

/// [`prepare3`] compiled for AVX2 (floor and round are single instructions there). No FMA:
/// the same bits as the portable loop.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn prepare3_avx2(t: &[[f64; 4]], nearest: bool, layout: &Layout, st: &mut Stencil3) {
    prepare3(t, nearest, layout, st)
}

/// A table with an interpolation mode: a [`Brdf`] like any other. Owned, or borrowed
/// (`InterpolatedTable<&Table>`) where the table is large and its owner keeps it: the planner
/// measuring against a stored table would otherwise hold a second copy of it.
#[derive(Clone, Debug)]
pub struct InterpolatedTable<T = Table> {
    pub table: T,
    pub interp: Interp,
}

impl<T: std::borrow::Borrow<Table> + Send + Sync> InterpolatedTable<T> {
    fn t(&self) -> &Table {
        self.table.borrow()
    }
}

impl<T: std::borrow::Borrow<Table> + Send + Sync> Brdf for InterpolatedTable<T> {
    fn is_sampled(&self) -> bool {
        true
    }

    fn channels(&self) -> &Channels {
        self.t().channels()
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        self.t().eval_into(wi, wo, self.interp, out);
    }
    fn eval_pairs(&self, pairs: &[(Vec3, Vec3)], out: &mut [f64]) {
        self.t().eval_batch_serial(pairs, self.interp, out);
    }
    fn is_isotropic(&self) -> bool {
        self.t().grid().kind().is_isotropic()
    }
    fn is_reciprocal(&self) -> bool {
        // A folded half/difference table is reciprocal by construction; other grids store
        // whatever their source was, which the table does not promise.
        self.t().grid().kind() == crate::grid::GridKind::Halfdiff3
    }
    fn in_domain(&self, wi: Vec3, wo: Vec3) -> bool {
        self.t().grid().theta_max().is_none() || self.t().grid().in_domain(wi, wo)
    }
    fn theta_max_deg(&self) -> Option<f64> {
        self.t().grid().theta_max_deg()
    }
    fn describe(&self) -> String {
        format!(
            "table {} of {}",
            self.t().grid().describe(),
            self.t().provenance().source
        )
    }
    /// The table behind the lookup: tabulation on the table's own grid copies its samples
    /// instead of interpolating at every node.
    fn as_any(&self) -> Option<&dyn std::any::Any> {
        Some(self.t())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::parse_grid_spec;
    use crate::math::PI;
    use crate::tabulate::{TabulateOptions, tabulate};

    /// The shell-by-shell search finds the cell a scan of the whole box finds (nearest in
    /// index space, ties to the lowest flat index): 3-D and 4-D grids with a periodic axis
    /// shorter than the box, sparse and dense validity, points near the grid's edges and
    /// on exact half-integers (ties).
    #[test]
    fn the_nearest_valid_cell_is_the_scanned_one() {
        fn scan(t: &Table, c: &[f64], strides: &[usize]) -> Option<usize> {
            let r = Table::FALLBACK_RADIUS;
            let span = (2 * r + 2) as usize;
            let axes = t.grid.axes();
            let d = c.len();
            let mut best: Option<(f64, usize)> = None;
            let mut off = [0usize; 4];
            'outer: loop {
                let (mut flat, mut dist, mut inside) = (0usize, 0.0, true);
                for k in 0..d {
                    let a = &axes[k];
                    let i = c[k].floor() as i64 - r + off[k] as i64;
                    let idx = if a.is_periodic() {
                        i.rem_euclid(a.n as i64)
                    } else if i < 0 || i >= a.n as i64 {
                        inside = false;
                        0
                    } else {
                        i
                    };
                    dist += (i as f64 - c[k]).powi(2);
                    flat += idx as usize * strides[k];
                }
                if inside
                    && t.valid[flat]
                    && best.is_none_or(|(bd, bf)| dist < bd || (dist == bd && flat < bf))
                {
                    best = Some((dist, flat));
                }
                for o in off.iter_mut().take(d) {
                    *o += 1;
                    if *o < span {
                        continue 'outer;
                    }
                    *o = 0;
                }
                break;
            }
            best.map(|(_, f)| f)
        }
        let mut rng = crate::math::SplitMix64::new(41);
        for spec in [
            "halfdiff3:12x10x6",
            "halfdiff4:9x5x8x11",
            "spherical3:7x9x16",
        ] {
            let g = parse_grid_spec(spec).unwrap();
            let d = g.axes().len();
            let strides: Vec<usize> = (0..d)
                .map(|k| g.axes()[k + 1..].iter().map(|a| a.n).product())
                .collect();
            for density in [0.02, 0.3, 0.9] {
                let mut t = Table::zeroed(g.clone(), Channels::default_for(1));
                for v in t.valid.iter_mut() {
                    *v = rng.next_f64() < density;
                }
                let mut found = 0;
                for q in 0..3000 {
                    let c: Vec<f64> = g
                        .axes()
                        .iter()
                        .map(|a| {
                            let x = rng.next_f64() * (a.n as f64 + 2.0) - 1.0;
                            if q % 5 == 0 { x.floor() + 0.5 } else { x }
                        })
                        .collect();
                    let want = scan(&t, &c, &strides);
                    assert_eq!(
                        t.nearest_valid(&c, &strides),
                        want,
                        "{spec} {density} {c:?}"
                    );
                    found += want.is_some() as usize;
                }
                assert!(found > 100, "{spec} {density}: {found}");
            }
            // No valid cell, and one (in a corner, inside, next to a periodic seam): the
            // range test answers most queries; the answers are the scan's.
            let cells = g.cells();
            for one in [None, Some(0), Some(cells / 2 + 3), Some(cells - 1)] {
                let mut t = Table::zeroed(g.clone(), Channels::default_for(1));
                if let Some(f) = one {
                    t.valid[f] = true;
                }
                let mut found = 0;
                for _ in 0..3000 {
                    let c: Vec<f64> = g
                        .axes()
                        .iter()
                        .map(|a| rng.next_f64() * (a.n as f64 + 2.0) - 1.0)
                        .collect();
                    let want = scan(&t, &c, &strides);
                    assert_eq!(t.nearest_valid(&c, &strides), want, "{spec} {one:?} {c:?}");
                    found += want.is_some() as usize;
                }
                assert_eq!(t.valid_bounds().is_some(), one.is_some());
                assert!(one.is_none() || found > 0, "{spec} {one:?}");
            }
        }
    }

    #[test]
    fn the_stencils_of_pairs_in_another_order_are_the_same_stencils_in_that_order() {
        // The planner's estimators make the stencils of their pairs once in the set's order
        // (to find the order that walks the table in memory) and again in that order: a
        // pair's stencil must depend on that pair alone, for every interpolation the planner
        // measures (linear, cosine-weighted, log space) and across the chunks stencils are
        // made in (4096 pairs).
        let m = crate::model::Model::parse("lambert:albedo=0.2+ggx:alpha=0.1,fresnel=au").unwrap();
        let base = parse_grid_spec("halfdiff3:24x12x32,warp=sqrt/linear/linear").unwrap();
        let mut t = tabulate(&m, &base, &TabulateOptions::default()).unwrap();
        let pairs: Vec<(Vec3, Vec3)> = crate::check::uniform_pairs(7).take(10_000).collect();
        // A fixed permutation: every 7th pair first, then the rest reversed.
        let mut order: Vec<usize> = (0..pairs.len()).step_by(7).collect();
        order.extend((0..pairs.len()).rev().filter(|p| p % 7 != 0));
        let permuted: Vec<(Vec3, Vec3)> = order.iter().map(|&p| pairs[p]).collect();
        for setup in 0..3 {
            match setup {
                1 => t.set_interp_weight(crate::grid::InterpWeight::Cosine),
                2 => t.set_interp_space(crate::grid::InterpSpace::log(1e-3).unwrap()),
                _ => {}
            }
            let mut a = vec![0.0; pairs.len() * 3];
            t.stencil(&pairs, Interp::Linear).apply(t.data(), &mut a);
            let mut b = vec![0.0; pairs.len() * 3];
            t.stencil(&permuted, Interp::Linear).apply(t.data(), &mut b);
            for (k, &p) in order.iter().enumerate() {
                assert_eq!(
                    a[p * 3..p * 3 + 3]
                        .iter()
                        .map(|x| x.to_bits())
                        .collect::<Vec<_>>(),
                    b[k * 3..k * 3 + 3]
                        .iter()
                        .map(|x| x.to_bits())
                        .collect::<Vec<_>>(),
                    "setup {setup}, pair {p}"
                );
            }
        }
    }

    /// f = (1 + 0.5 wi·wo) / cos θo: finite f·cos θo at the horizon, as RGL files are
    /// (docs/rgl.md).
    struct HorizonGrowth(Channels);
    impl Brdf for HorizonGrowth {
        fn channels(&self) -> &Channels {
            &self.0
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            out[0] = if wi.z <= 0.0 || wo.z <= 0.0 {
                0.0
            } else {
                (1.0 + 0.5 * wi.dot(wo)) / wo.z
            };
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn describe(&self) -> String {
            "horizon growth".into()
        }
    }

    /// Interpolating f·cos θi·cos θo follows a 1/cos θo growth to the horizon, where f itself
    /// cannot: within the last bin (θo ≥ 89.5° on 90 bins) plain interpolation misses by far
    /// more than 50%, the weighted one stays within 1% (the rest is the bins' curvature).
    #[test]
    fn cosine_weight_follows_growth_at_the_horizon() {
        let src = HorizonGrowth(Channels::default_for(1));
        let plain = tabulate(
            &src,
            &parse_grid_spec("spherical3:90x90x180").unwrap(),
            &TabulateOptions::default(),
        )
        .unwrap();
        let mut weighted = plain.clone();
        weighted.set_interp_weight(InterpWeight::Cosine);
        assert_eq!(weighted.data(), plain.data(), "the samples stay");
        let (mut f, mut a, mut b) = ([0.0], [0.0], [0.0]);
        let (mut worst_plain, mut worst_weighted) = (0.0f64, 0.0f64);
        for k in 0..200 {
            let ti = (k as f64 * 0.4).to_radians();
            let to = (89.5 + 0.4999 * (k as f64 + 0.5) / 200.0).to_radians();
            let wi = Vec3::from_spherical(ti, 0.3);
            let wo = Vec3::from_spherical(to, 0.3 + 0.013 * k as f64);
            src.eval(wi, wo, &mut f);
            plain.eval_into(wi, wo, Interp::Linear, &mut a);
            weighted.eval_into(wi, wo, Interp::Linear, &mut b);
            assert!(b[0].is_finite());
            worst_plain = worst_plain.max((a[0] - f[0]).abs() / f[0]);
            worst_weighted = worst_weighted.max((b[0] - f[0]).abs() / f[0]);
        }
        assert!(worst_plain > 0.5, "plain {worst_plain}");
        assert!(worst_weighted < 0.01, "weighted {worst_weighted}");
        // On the horizon itself, 0 (one-sided), never a division by 0.
        weighted.eval_into(
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, 0.0),
            Interp::Linear,
            &mut b,
        );
        assert_eq!(b[0], 0.0);
    }

    /// The grazing warp puts the last centred sample of n at 90°/(4n²) from the horizon, and
    /// its continuous index inverts its samples.
    #[test]
    fn grazing_warp_is_dense_at_the_horizon() {
        let g = parse_grid_spec("spherical3:90x90x180,warp=grazing/grazing/linear").unwrap();
        let a = &g.axes()[0];
        let last = a.sample(89).to_degrees();
        assert!(
            (90.0 - last - 90.0 / (4.0 * 90.0 * 90.0)).abs() < 1e-9,
            "{last}"
        );
        for i in 0..90 {
            assert!((a.continuous_index(a.sample(i)) - i as f64).abs() < 1e-9);
        }
        // Spec and description carry the warp and the weight.
        let w = parse_grid_spec("halfdiff3:8,warp=sqrt/grazing/linear,weight=cosine").unwrap();
        assert!(
            w.describe().contains("sqrt/grazing/linear"),
            "{}",
            w.describe()
        );
        assert!(w.describe().contains("weight cosine"), "{}", w.describe());
        assert_eq!(Grid::from_desc(&w.desc()).unwrap(), w);
    }

    /// Smooth, reciprocal, anisotropic (via h.x²) test BRDF.
    struct Smooth(Channels, bool);
    impl Brdf for Smooth {
        fn channels(&self) -> &Channels {
            &self.0
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            if wi.z <= 0.0 || wo.z <= 0.0 {
                out.fill(0.0);
                return;
            }
            let h = (wi + wo).try_normalize().unwrap();
            let aniso = if self.1 { 0.5 * h.x * h.x } else { 0.0 };
            out[0] = 0.2 + h.z * h.z + 0.3 * wi.z * wo.z + 0.1 * wi.dot(wo) + aniso;
        }
        fn is_isotropic(&self) -> bool {
            !self.1
        }
        fn describe(&self) -> String {
            "smooth".into()
        }
    }

    /// Walks a path of queries and asserts no step jumps more than 4× the median step
    /// (plus a small floor): a seam would show as one outlier step.
    fn assert_continuous(t: &Table, path: impl Iterator<Item = (Vec3, Vec3)>, what: &str) {
        let mut v = [0.0];
        let vals: Vec<f64> = path
            .map(|(wi, wo)| {
                t.eval_into(wi, wo, Interp::Linear, &mut v);
                v[0]
            })
            .collect();
        let mut steps: Vec<f64> = vals.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
        let max = steps.iter().cloned().fold(0.0, f64::max);
        steps.sort_by(f64::total_cmp);
        let median = steps[steps.len() / 2];
        assert!(
            max <= 4.0 * median + 1e-6,
            "{what}: max step {max} vs median {median}"
        );
    }

    #[test]
    fn interpolation_is_continuous_across_the_phi_wrap() {
        let src = Smooth(Channels::default_for(1), true);
        for spec in ["spherical4:8x12x8x12", "halfdiff4:8x12x8x12"] {
            let t = tabulate(
                &src,
                &parse_grid_spec(spec).unwrap(),
                &TabulateOptions::default(),
            )
            .unwrap();
            // Rotate both directions together through φ = 0 ≡ 2π (moves φi, φo and φh).
            let path = (0..401).map(|k| {
                let a = -0.3 + 0.6 * k as f64 / 400.0;
                let wi = Vec3::from_spherical(0.6, 0.2).rotate_z(a);
                let wo = Vec3::from_spherical(0.5, 2.9).rotate_z(a);
                (wi, wo)
            });
            assert_continuous(&t, path, spec);
        }
    }

    /// Isotropic and reciprocal (period π in φd) but not mirror-symmetric: sin 2φd.
    struct Twisted(Channels);
    impl Brdf for Twisted {
        fn channels(&self) -> &Channels {
            &self.0
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            let hd = crate::geometry::HalfDiff::from_dirs(wi, wo).unwrap();
            out[0] = 0.5 + 0.3 * (2.0 * hd.phi_d).sin() * hd.theta_d.sin().powi(2);
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn describe(&self) -> String {
            "twisted".into()
        }
    }

    #[test]
    fn interpolation_is_continuous_across_the_phi_d_fold() {
        let src = Twisted(Channels::default_for(1));
        let g = parse_grid_spec("halfdiff3:16x16x12").unwrap();
        let t = tabulate(&src, &g, &TabulateOptions::default()).unwrap();
        // φd through π (folds to 0) and through 0 (from the negative side, folds to π).
        for centre in [PI, 0.0] {
            let path = (0..401).map(|k| {
                let pd = centre - 0.4 + 0.8 * k as f64 / 400.0;
                crate::geometry::HalfDiff {
                    theta_h: 0.3,
                    phi_h: 0.0,
                    theta_d: 0.5,
                    phi_d: pd,
                }
                .to_dirs()
            });
            assert_continuous(&t, path, "phi_d fold");
        }
    }

    #[test]
    fn nearest_returns_samples_and_linear_interpolates_between() {
        let src = Smooth(Channels::default_for(1), true);
        let g = parse_grid_spec("halfdiff4:8").unwrap();
        let t = tabulate(&src, &g, &TabulateOptions::default()).unwrap();
        let mut idx = [0usize; 4];
        let mut v = [0.0];
        for f in (0..g.cells()).step_by(7) {
            g.unflatten(f, &mut idx);
            let (wi, wo) = g.cell_dirs(&idx);
            if t.valid()[f] {
                t.eval_into(wi, wo, Interp::Nearest, &mut v);
                assert!((v[0] - t.cell(f)[0] as f64).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn queries_beyond_theta_max_are_refused() {
        let src = Smooth(Channels::default_for(1), false);
        let g = parse_grid_spec("spherical3:8,theta-max=60").unwrap();
        let t = tabulate(&src, &g, &TabulateOptions::default()).unwrap();
        let mut v = [0.0];
        let inside = Vec3::from_spherical(0.5, 0.0);
        let outside = Vec3::from_spherical(70f64.to_radians(), 0.0);
        assert!(t.try_eval(inside, inside, Interp::Linear, &mut v).is_ok());
        let e = t
            .try_eval(inside, outside, Interp::Linear, &mut v)
            .unwrap_err();
        assert!(e.to_string().contains("outside the stored domain"));
    }

    /// Random pairs (uniform, grazing, near-specular), exact cell positions (the snap rule)
    /// and pairs on the seams (φd fold, φh wrap, θh = 0, the normal, the horizon).
    fn lookup_test_pairs(g: &Grid) -> Vec<(Vec3, Vec3)> {
        use crate::check::SampleSet;
        let mut pairs = Vec::new();
        for set in [
            SampleSet::uniform(20_000, 5),
            SampleSet::grazing(5_000, 6),
            SampleSet::specular(5_000, 7),
        ] {
            pairs.extend(set.pairs);
        }
        let mut idx = [0usize; 4];
        let d = g.axes().len();
        for f in (0..g.cells()).step_by(g.cells() / 3000 + 1) {
            g.unflatten(f, &mut idx[..d]);
            pairs.push(g.cell_dirs(&idx[..d]));
        }
        let mut rng = crate::math::SplitMix64::new(9);
        for _ in 0..3000 {
            let th = rng.next_f64() * 0.8;
            let td = rng.next_f64() * 1.5;
            let eps = (rng.next_f64() - 0.5) * 1e-7;
            for (ph, pd) in [
                (0.0, eps),
                (eps, PI + eps),
                (2.0 * PI + eps, -eps),
                (eps, 0.5 * PI),
            ] {
                pairs.push(
                    crate::geometry::HalfDiff {
                        theta_h: th * eps.abs() * 1e3,
                        phi_h: ph,
                        theta_d: td,
                        phi_d: pd,
                    }
                    .to_dirs(),
                );
                pairs.push(
                    crate::geometry::HalfDiff {
                        theta_h: th,
                        phi_h: ph,
                        theta_d: td,
                        phi_d: pd,
                    }
                    .to_dirs(),
                );
            }
        }
        let n = Vec3::Z;
        let grazing = Vec3::new(1.0, 0.0, 1e-9).try_normalize().unwrap();
        pairs.extend([
            (n, n),
            (n, grazing),
            (grazing, grazing),
            (grazing, grazing.mirror()),
        ]);
        pairs.extend([
            (Vec3::new(1.0, 0.0, 0.0), n),
            (n, Vec3::new(0.0, 0.6, -0.8)),
        ]);
        // Below the horizon (one or both directions), and wi = −wo: 0 by definition.
        for set in [SampleSet::uniform(1000, 11), SampleSet::grazing(1000, 12)] {
            for (k, (wi, wo)) in set.pairs.into_iter().enumerate() {
                let flip = |v: Vec3| Vec3::new(v.x, v.y, -v.z);
                pairs.push(match k % 3 {
                    0 => (flip(wi), wo),
                    1 => (wi, flip(wo)),
                    _ => (flip(wi), flip(wo)),
                });
            }
        }
        pairs.push((Vec3::new(0.6, 0.0, 0.8), Vec3::new(-0.6, 0.0, -0.8)));
        pairs
    }

    /// `src` tabulated on `spec` with every 7th valid cell (and a run of 40 cells) marked
    /// invalid: lookups next to them drop those corners and renormalize, and some find no
    /// valid corner at all and take the nearest-valid fallback.
    fn with_holes(src: &dyn Brdf, spec: &str) -> Table {
        let t = tabulate(
            src,
            &parse_grid_spec(spec).unwrap(),
            &TabulateOptions::default(),
        )
        .unwrap();
        let mut valid = t.valid().to_vec();
        for (i, v) in valid.iter_mut().enumerate() {
            if i % 7 == 3 || (1000..1040).contains(&i) {
                *v = false;
            }
        }
        let holes = Table::new(
            t.grid().clone(),
            t.channels().clone(),
            t.provenance().clone(),
            t.data().to_vec(),
            valid,
        )
        .unwrap();
        assert!(holes.valid_count() < t.valid_count() * 7 / 8);
        holes
    }

    /// A narrow lobe's flanks fall by decades between samples: interpolating the logs (the
    /// log space) follows them, the values themselves are overestimated. Measured on pairs
    /// between the samples against the model, as `log_rmse` counts it; and a log-space table
    /// returns its samples where a query sits on one.
    #[test]
    fn log_space_follows_a_narrow_peak() {
        let m =
            crate::model::Model::parse("lambert:albedo=0.05+ggx:alpha=0.02,fresnel=au").unwrap();
        let linear = tabulate(
            &m,
            &parse_grid_spec("halfdiff3:48x48x64,warp=sqrt/linear/linear").unwrap(),
            &TabulateOptions::default(),
        )
        .unwrap();
        let mut log = linear.clone_samples();
        log.set_interp_space(crate::grid::InterpSpace::log(1e-4).unwrap());
        let pairs = crate::check::SampleSet::uniform(20_000, 3).pairs;
        let err = |t: &Table| {
            let mut sum = 0.0;
            let (mut g, mut f) = ([0.0; 3], [0.0; 3]);
            for &(wi, wo) in &pairs {
                t.eval_into(wi, wo, Interp::Linear, &mut g);
                m.eval(wi, wo, &mut f);
                for (gk, fk) in g.iter().zip(&f) {
                    let d = (1.0 + gk * wi.z).ln() - (1.0 + fk * wi.z).ln();
                    sum += d * d;
                }
            }
            (sum / (3 * pairs.len()) as f64).sqrt()
        };
        let (e_lin, e_log) = (err(&linear), err(&log));
        assert!(
            e_log < 0.6 * e_lin,
            "log space {e_log:.3e} not well below linear {e_lin:.3e}"
        );
        // At a sample (the centre of cell (5, 7, 9)) the log space gives the sample back.
        let idx = [5, 7, 9];
        let c = log.grid().sample_coords(&idx);
        let (wi, wo) = log.grid().dirs_from_coords(&c);
        let flat = (idx[0] * 48 + idx[1]) * 64 + idx[2];
        let mut g = [0.0; 3];
        log.eval_into(wi, wo, Interp::Linear, &mut g);
        for (gk, &v) in g.iter().zip(&log.data()[flat * 3..flat * 3 + 3]) {
            let v = v as f64;
            assert!((gk - v).abs() <= 1e-9 * v.abs(), "{gk} vs {v}");
        }
    }

    #[test]
    fn eval_batch_equals_eval_into() {
        let ggx = crate::model::Model::parse(
            "ggx:alpha=0.05,shadowing=smith-separable,fresnel=conductor,\
             eta=0.2004/0.924/1.1022,k=3.9129/2.4528/2.1421",
        )
        .unwrap();
        let aniso = crate::model::Model::parse("ggx:alpha_x=0.1,alpha_y=0.3,fresnel=au").unwrap();
        let smooth = Smooth(Channels::default_for(1), true);
        let cases: Vec<(Table, &str)> = vec![
            (
                tabulate(&ggx, &Grid::merl(), &TabulateOptions::default()).unwrap(),
                "merl",
            ),
            (
                tabulate(
                    &ggx,
                    &parse_grid_spec("halfdiff3:32x24x20").unwrap(),
                    &TabulateOptions::default(),
                )
                .unwrap(),
                "halfdiff3 centred",
            ),
            (
                tabulate(
                    &aniso,
                    &parse_grid_spec("halfdiff4:16x12x16x20,warp=sqrt/linear/linear/linear")
                        .unwrap(),
                    &TabulateOptions::default(),
                )
                .unwrap(),
                "halfdiff4",
            ),
            (
                tabulate(
                    &smooth,
                    &parse_grid_spec("spherical4:8x12x8x12").unwrap(),
                    &TabulateOptions::default(),
                )
                .unwrap(),
                "spherical4 (generic per pair)",
            ),
            (
                tabulate(
                    &Smooth(Channels::default_for(1), false),
                    &parse_grid_spec("halfdiff3:16x12x20,warp=sqrt/linear/linear").unwrap(),
                    &TabulateOptions::default(),
                )
                .unwrap(),
                "halfdiff3 1 channel",
            ),
            (
                with_holes(&ggx, "halfdiff3:24x16x32"),
                "halfdiff3 with invalid cells",
            ),
            (
                with_holes(&smooth, "halfdiff4:12x8x12x16"),
                "halfdiff4 with invalid cells",
            ),
            (
                tabulate(
                    &ggx,
                    &parse_grid_spec("spherical3:8,theta-max=60").unwrap(),
                    &TabulateOptions::default(),
                )
                .unwrap(),
                "spherical3 θ ≤ 60°",
            ),
            (
                with_holes(&ggx, "halfdiff3:24x16x32,weight=cosine"),
                "halfdiff3 cosine-weighted with invalid cells",
            ),
            (
                with_holes(&ggx, "halfdiff3:24x16x32,space=log:0.003"),
                "halfdiff3 log space with invalid cells",
            ),
            (
                with_holes(&ggx, "halfdiff3:24x16x32,weight=cosine,space=log:0.001"),
                "halfdiff3 cosine-weighted log space with invalid cells",
            ),
            (
                with_holes(&smooth, "halfdiff4:12x8x12x16,space=log:0.05"),
                "halfdiff4 log space with invalid cells",
            ),
            (
                with_holes(
                    &ggx,
                    "halfdiff3:16x12x20,warp=sqrt/grazing/linear,at=edge,horizon=extend,\
                     space=log:1e-6",
                ),
                "halfdiff3 grazing θd, extended, log space (pack's grid) with invalid cells",
            ),
            (
                tabulate(
                    &smooth,
                    &parse_grid_spec("spherical4:8x12x8x12,weight=cosine,space=log:0.3").unwrap(),
                    &TabulateOptions::default(),
                )
                .unwrap(),
                "spherical4 cosine-weighted log space",
            ),
            (
                tabulate(
                    &Smooth(Channels::default_for(1), false),
                    &parse_grid_spec(
                        "spherical3:12x10x16,warp=grazing/grazing/linear,weight=cosine",
                    )
                    .unwrap(),
                    &TabulateOptions::default(),
                )
                .unwrap(),
                "spherical3 grazing warp, cosine-weighted",
            ),
            (
                tabulate(
                    &ggx,
                    &parse_grid_spec("halfdiff3:16x12x20,warp=sqrt/grazing/linear").unwrap(),
                    &TabulateOptions::default(),
                )
                .unwrap(),
                "halfdiff3 grazing θd (generic per pair)",
            ),
        ];
        for (t, what) in &cases {
            let pairs = lookup_test_pairs(t.grid());
            let c = t.channels().len();
            for interp in [Interp::Linear, Interp::Nearest] {
                let mut batch = vec![f64::NAN; pairs.len() * c];
                t.eval_batch(&pairs, interp, &mut batch);
                // The portable loops and one thread give the same bits as the AVX2 loops on
                // the default pool.
                let mut portable = vec![f64::NAN; pairs.len() * c];
                t.eval_batch_with(&pairs, interp, &mut portable, false);
                let mut one_thread = vec![f64::NAN; pairs.len() * c];
                rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .build()
                    .unwrap()
                    .install(|| t.eval_batch(&pairs, interp, &mut one_thread));
                for (p, ((a, b), o)) in batch.iter().zip(&portable).zip(&one_thread).enumerate() {
                    assert!(
                        a.to_bits() == b.to_bits() && a.to_bits() == o.to_bits(),
                        "{what} {interp:?} value {p}: {a:e} (SIMD), {b:e} (portable), \
                         {o:e} (one thread)"
                    );
                }
                // The stencils give eval_into's bits, on the table's data and on other data.
                let stencil = t.stencil(&pairs, interp);
                let scaled: Vec<f32> = t.data().iter().map(|v| v * 0.7 + 0.1).collect();
                let mut via_stencil = vec![f64::NAN; pairs.len() * c];
                let mut one = vec![0.0; c];
                for data in [t.data(), &scaled[..]] {
                    stencil.apply(data, &mut via_stencil);
                    let other = Table::new(
                        t.grid().clone(),
                        t.channels().clone(),
                        t.provenance().clone(),
                        data.to_vec(),
                        t.valid().to_vec(),
                    )
                    .unwrap();
                    for (p, &(wi, wo)) in pairs.iter().enumerate() {
                        other.eval_into(wi, wo, interp, &mut one);
                        for ch in 0..c {
                            let (a, b) = (via_stencil[p * c + ch], one[ch]);
                            assert!(
                                a.to_bits() == b.to_bits(),
                                "{what} {interp:?} pair {p}: stencil {a:e} vs eval_into {b:e}"
                            );
                        }
                    }
                }
                // Batched and per-pair lookups take the same angles (`HalfdiffIndexer`
                // where the batch vectorizes them), so they agree bit for bit, ties of
                // `Interp::Nearest` at cell boundaries included.
                for (p, &(wi, wo)) in pairs.iter().enumerate() {
                    t.eval_into(wi, wo, interp, &mut one);
                    for ch in 0..c {
                        let (a, b) = (batch[p * c + ch], one[ch]);
                        assert!(
                            a.to_bits() == b.to_bits(),
                            "{what} {interp:?} pair {p} {wi:?} {wo:?}: batch {a:e} vs eval_into {b:e}"
                        );
                    }
                }
            }
        }
    }
}
