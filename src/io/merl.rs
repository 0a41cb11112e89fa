//! The MERL BRDF database `.binary` format (Matusik et al. 2003) and its reference lookup
//! (`BRDFRead.cpp`, 2005), as specified in `spec/formats.md` and `docs/format.md`.
//!
//! ```text
//! dims   3 × i32 LE   (90, 90, 180) = (θh bins, θd bins, φd bins over [0, π))
//! values 3 × n × f64 LE, n = product of dims: all red, then green, then blue; each channel
//!        C-order [θh][θd][φd]. Physical f_r (1/sr) = stored × scale[c]; negative = invalid.
//! ```
//! Exactness: the file's f64 values do not survive f32 storage, so a read keeps them in the
//! table's [`ExactValues`] (scale = the MERL scales, raw = the stored numbers), and a write
//! of a table that carries MERL-scaled exact values stores those numbers unchanged: read →
//! write reproduces the file byte for byte, also through the native and EXR f32 formats.

use crate::brdf::{Brdf, Channels};
use crate::geometry::Vec3;
use crate::grid::{Grid, GridKind, Placement, Warp};
use crate::math::{FRAC_PI_2, PI};
use crate::table::{ExactValues, Provenance, Table};
use crate::{Error, Result, TOOL_VERSION};
use std::path::Path;

/// Bytes of the dims header.
pub const HEADER_BYTES: usize = 12;
/// The standard dims (θh, θd, φd).
pub const STANDARD_DIMS: [usize; 3] = [90, 90, 180];
/// Size of a standard file: 12 + 3 × 1,458,000 × 8.
pub const STANDARD_FILE_BYTES: usize = 34_992_012;

/// `BRDFRead.cpp`: `#define RED_SCALE (1.0/1500.0)` etc. — one f64 division each, applied to
/// the stored value by one multiplication.
pub const SCALE: [f64; 3] = [1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0];

/// What a writer stores in cells without a valid value (the files here use −1.0).
pub const INVALID_RAW: f64 = -1.0;

/// A MERL file's content, exactly: its dims and the stored f64 values, channel-major as in
/// the file (`raw[c·n + (i·nd + j)·np + k]`).
#[derive(Clone, Debug, PartialEq)]
pub struct MerlTable {
    /// (θh, θd, φd) bin counts.
    pub dims: [usize; 3],
    pub raw: Vec<f64>,
}

impl MerlTable {
    /// Number of cells per channel.
    pub fn cells(&self) -> usize {
        self.dims.iter().product()
    }

    /// Parses a `.binary` file: the dims must be positive and their product must account for
    /// the file size exactly; every value must be finite.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<MerlTable> {
        let dims = parse_dims(bytes, path, 24)?;
        let n = dims.iter().product::<usize>();
        let mut raw = Vec::with_capacity(3 * n);
        for i in 0..3 * n {
            raw.push(stored_value(bytes, i, n, path)?);
        }
        Ok(MerlTable { dims, raw })
    }

    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(HEADER_BYTES + self.raw.len() * 8);
        for d in self.dims {
            out.extend_from_slice(&(d as i32).to_le_bytes());
        }
        for v in &self.raw {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    /// The grid of a MERL table with these dims: halfdiff3, sqrt θh, linear θd and φd, samples
    /// at the lower bin edges (MERL's sample positions).
    pub fn grid(dims: [usize; 3]) -> Result<Grid> {
        Grid::new(
            GridKind::Halfdiff3,
            &[
                (dims[0], Warp::Sqrt, Placement::LowerEdge),
                (dims[1], Warp::Linear, Placement::LowerEdge),
                (dims[2], Warp::Linear, Placement::LowerEdge),
            ],
            None,
        )
    }

    /// The table: f32 samples = stored × scale (rounded once), a cell is invalid when any of
    /// its stored values is negative, and the stored numbers are kept as exact values.
    pub fn to_table(&self, source: &str) -> Result<Table> {
        let n = self.cells();
        let mut data = vec![0f32; 3 * n];
        let mut exact = vec![0f64; 3 * n];
        let mut valid = vec![true; n];
        for c in 0..3 {
            for cell in 0..n {
                let r = self.raw[c * n + cell];
                exact[cell * 3 + c] = r;
                if r < 0.0 {
                    valid[cell] = false;
                }
                data[cell * 3 + c] = (r * SCALE[c]) as f32;
            }
        }
        table_of(self.dims, source, data, exact, valid)
    }

    /// The MERL content of a table on a MERL-shaped grid (see [`merl_dims`]) with 3 channels.
    /// Valid cells store value / scale[c]; invalid cells store −1.0. When the table carries
    /// exact values with the MERL scales, those stored numbers are used unchanged (so a file
    /// read and written again is identical), invalid cells included.
    pub fn from_table(table: &Table) -> Result<MerlTable> {
        let dims = merl_dims(table.grid()).ok_or_else(|| {
            Error::input(format!(
                "MERL .binary needs a halfdiff3 grid with warps sqrt/linear/linear at the lower \
                 bin edges (e.g. --grid merl); the table's grid is {}",
                table.grid().describe()
            ))
        })?;
        // A spectral table is not RGB even with 3 channels: refuse it, pointing to --to-rgb.
        if crate::spectral::is_spectral(table.channels()) {
            crate::spectral::require_rgb(table.channels(), "MERL .binary")?;
        }
        if table.channels().len() != 3 {
            return Err(Error::input(format!(
                "MERL .binary holds exactly 3 channels (red, green, blue); the table has {} ({})",
                table.channels().len(),
                table.channels().names().join(", ")
            )));
        }
        let n = table.grid().cells();
        let mut raw = vec![0f64; 3 * n];
        let same_scale = table.exact().filter(|e| {
            e.scale
                .iter()
                .zip(SCALE)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        });
        for cell in 0..n {
            for c in 0..3 {
                raw[c * n + cell] = if let Some(e) = same_scale {
                    e.raw[cell * 3 + c]
                } else if table.valid()[cell] {
                    // The writer's inverse of the reader's multiplication.
                    let v = match table.exact() {
                        Some(e) => e.raw[cell * 3 + c] * e.scale[c],
                        None => table.cell(cell)[c] as f64,
                    };
                    v / SCALE[c]
                } else {
                    INVALID_RAW
                };
            }
        }
        Ok(MerlTable { dims, raw })
    }
}

/// The dims of a grid that a MERL file can hold (halfdiff3, sqrt/linear/linear, lower edges,
/// no θ limit), or `None`.
pub fn merl_dims(grid: &Grid) -> Option<[usize; 3]> {
    let a = grid.axes();
    let shape_ok = grid.kind() == GridKind::Halfdiff3
        && grid.theta_max().is_none()
        && a.iter().all(|x| x.placement == Placement::LowerEdge)
        && a[0].warp == Warp::Sqrt
        && a[1].warp == Warp::Linear
        && a[2].warp == Warp::Linear;
    shape_ok.then(|| [a[0].n, a[1].n, a[2].n])
}

fn header_dims(bytes: &[u8]) -> [i32; 3] {
    let d = |k: usize| i32::from_le_bytes(bytes[4 * k..4 * k + 4].try_into().expect("4 bytes"));
    [d(0), d(1), d(2)]
}

/// Whether `bytes` start with MERL's standard dims (90, 90, 180), whatever their length: a
/// truncated or padded MERL file, which gets MERL's size error rather than "unknown format".
pub fn has_standard_dims(bytes: &[u8]) -> bool {
    bytes.len() >= HEADER_BYTES
        && header_dims(bytes)
            .iter()
            .zip(STANDARD_DIMS)
            .all(|(&d, s)| d as i64 == s as i64)
}

/// True when `bytes` look like a MERL file: positive dims whose product accounts for the
/// size exactly (the format has no magic).
pub fn looks_like_merl(bytes: &[u8]) -> bool {
    if bytes.len() < HEADER_BYTES {
        return false;
    }
    let d = header_dims(bytes);
    if d.iter().any(|&x| x <= 0) {
        return false;
    }
    let n = d.iter().map(|&x| x as u128).product::<u128>();
    bytes.len() as u128 == HEADER_BYTES as u128 + 24 * n
}

/// Reads a MERL file into a table.
///
/// The table is built from the bytes directly, without the channel-major copy a
/// [`MerlTable`] holds (35 MB of a standard file: at the input stage the bytes, the table's
/// f32 samples and its exact values are alive already, so that copy made the peak of every
/// command reading a MERL file, 124 MB instead of 89 MB); the values are those of
/// [`MerlTable::to_table`].
pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Table> {
    let dims = parse_dims(bytes, path, 0)?;
    let mut values = StoredValues::new(dims.iter().product());
    for i in 0..3 * values.n {
        values.put(i, stored_value(bytes, i, values.n, path)?);
    }
    values.into_table(dims, path)
}

/// A MERL file's values as they are read (channel-major, in file order) into a table's
/// cell-major f32 samples (stored × scale, rounded once), exact values and flags.
struct StoredValues {
    n: usize,
    data: Vec<f32>,
    exact: Vec<f64>,
    valid: Vec<bool>,
}

impl StoredValues {
    fn new(n: usize) -> StoredValues {
        StoredValues {
            n,
            data: vec![0f32; 3 * n],
            exact: vec![0f64; 3 * n],
            valid: vec![true; n],
        }
    }

    /// Stored value `i` (channel-major) is `r`: a negative one marks its cell invalid.
    #[inline]
    fn put(&mut self, i: usize, r: f64) {
        let (c, cell) = (i / self.n, i % self.n);
        self.exact[cell * 3 + c] = r;
        if r < 0.0 {
            self.valid[cell] = false;
        }
        self.data[cell * 3 + c] = (r * SCALE[c]) as f32;
    }

    /// The table of the file at `path` (`-`: stdin) of `dims`.
    fn into_table(self, dims: [usize; 3], path: &Path) -> Result<Table> {
        let name = path
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_else(|| "<stdin>".into());
        table_of(
            dims,
            &format!("MERL .binary file {name}"),
            self.data,
            self.exact,
            self.valid,
        )
        .map_err(|e| Error::invalid_file(path, e.to_string()))
    }
}

/// Reads the regular file `path` as a MERL file in chunks when its first bytes and size are
/// a MERL file's (and no other format's magic): `None` for anything else (the caller reads
/// and detects it whole). The same table as [`from_bytes`] of the whole file, without the
/// file's bytes in memory beside the table's samples and exact values: 35 MB less at the
/// peak of reading a standard file (87.5 MB), which `pack` does again for the samples of
/// a second curve.
pub fn read_regular_file(path: &Path) -> Result<Option<Table>> {
    use std::io::Read;
    let Ok(mut f) = std::fs::File::open(path) else {
        return Ok(None);
    };
    let Ok(meta) = f.metadata() else {
        return Ok(None);
    };
    if !meta.is_file() {
        return Ok(None);
    }
    let len = meta.len();
    let mut head = Vec::new();
    (&mut f)
        .take(64)
        .read_to_end(&mut head)
        .map_err(|e| Error::io(path, e))?;
    let other_magic = super::native::is_native(&head)
        || super::exr::is_exr(&head)
        || head.starts_with(b"tensor_file")
        || super::mbsdf::is_mbsdf(&head);
    let sized = head.len() >= HEADER_BYTES && {
        let d = header_dims(&head);
        d.iter().all(|&x| x > 0)
            && HEADER_BYTES as u128 + 24 * d.iter().map(|&x| x as u128).product::<u128>()
                == len as u128
    };
    if other_magic || !sized || len > super::atomic::MAX_INPUT_BYTES {
        return Ok(None);
    }
    let dims = parse_dims_of(&head, len, path, 0)?;
    let mut values = StoredValues::new(dims.iter().product());
    let total = 3 * values.n;
    // The values after the header, in chunks of whole values (channel-major, as stored).
    let mut rest = head.split_off(HEADER_BYTES);
    let mut chunk = vec![0u8; 1 << 20];
    let mut i = 0usize;
    while i < total {
        let want = ((total - i) * 8).min(chunk.len());
        let have = rest.len().min(want);
        chunk[..have].copy_from_slice(&rest[..have]);
        rest.drain(..have);
        f.read_exact(&mut chunk[have..want]).map_err(|e| {
            Error::invalid_file(path, format!("read failed at value {i} of {total}: {e}"))
        })?;
        for v in chunk[..want].chunks_exact(8) {
            let r = f64::from_le_bytes(v.try_into().expect("8 bytes"));
            values.put(i, finite_value(r, i, values.n, path)?);
            i += 1;
        }
    }
    values.into_table(dims, path).map(Some)
}

/// The dims of a `.binary` file's header, checked: positive, and their product accounts for
/// the file size exactly. The values' memory is checked against the budget: the f32 samples,
/// exact values and flags of the table and `extra` bytes a cell.
fn parse_dims(bytes: &[u8], path: &Path, extra: u64) -> Result<[usize; 3]> {
    parse_dims_of(bytes, bytes.len() as u64, path, extra)
}

/// [`parse_dims`] of a file of `len` bytes whose first bytes are `bytes` (at least the
/// header when `len` is).
fn parse_dims_of(bytes: &[u8], len: u64, path: &Path, extra: u64) -> Result<[usize; 3]> {
    let bad = |m: String| Error::invalid_file(path, m);
    if len < HEADER_BYTES as u64 || bytes.len() < HEADER_BYTES {
        return Err(bad(format!(
            "{len} bytes is too short for a MERL .binary file (a standard one is {} bytes)",
            STANDARD_FILE_BYTES
        )));
    }
    let mut dims = [0usize; 3];
    for (k, d) in dims.iter_mut().enumerate() {
        let v = i32::from_le_bytes(bytes[4 * k..4 * k + 4].try_into().expect("4 bytes"));
        // A dimension must be a positive bin count; the grid caps it further.
        if v <= 0 || v as usize > crate::grid::MAX_AXIS_RESOLUTION {
            return Err(bad(format!(
                "dims header {:?}: dimension {k} = {v} is not in [1, {}] (a standard file \
                 has 90 90 180)",
                header_dims(bytes),
                crate::grid::MAX_AXIS_RESOLUTION
            )));
        }
        *d = v as usize;
    }
    // At most 2^48 cells after the per-axis cap: the products below cannot overflow.
    let n = dims[0] * dims[1] * dims[2];
    let want = HEADER_BYTES as u128 + 3 * 8 * n as u128;
    if len as u128 != want {
        return Err(bad(format!(
            "size {len} bytes does not match dims {} {} {}, which need {want} bytes{}",
            dims[0],
            dims[1],
            dims[2],
            if len as u128 > want {
                " (trailing data?)"
            } else {
                " (truncated?)"
            }
        )));
    }
    // The table's f32 samples, exact f64 values and flags, and what the caller adds.
    crate::memory::require(
        &format!("MERL data of {} {} {} bins", dims[0], dims[1], dims[2]),
        (n as u64).saturating_mul(12 + 24 + 1 + extra),
    )
    .map_err(|e| bad(e.to_string()))?;
    Ok(dims)
}

/// Stored value `i` (channel-major) of a file of `n` cells a channel, which must be finite.
#[inline]
fn stored_value(bytes: &[u8], i: usize, n: usize, path: &Path) -> Result<f64> {
    let at = HEADER_BYTES + 8 * i;
    finite_value(
        f64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes")),
        i,
        n,
        path,
    )
}

/// `v`, stored value `i` (channel-major) of a file of `n` cells a channel, when finite.
#[inline]
fn finite_value(v: f64, i: usize, n: usize, path: &Path) -> Result<f64> {
    if !v.is_finite() {
        return Err(Error::invalid_file(
            path,
            format!(
                "value {i} (channel {}, cell {}) is {v}; MERL values must be finite",
                ["red", "green", "blue"][i / n],
                i % n
            ),
        ));
    }
    Ok(v)
}

/// The table of a MERL file from its f32 samples (stored × scale), exact stored values
/// (cell-major) and flags: the grid of `dims`, a note counting the invalid cells.
fn table_of(
    dims: [usize; 3],
    source: &str,
    data: Vec<f32>,
    exact: Vec<f64>,
    valid: Vec<bool>,
) -> Result<Table> {
    let grid = MerlTable::grid(dims)?;
    let negative = exact.iter().filter(|&&r| r < 0.0).count();
    let mut notes = Vec::new();
    if negative > 0 {
        notes.push(format!(
            "{negative} negative stored values mark {} invalid cells (MERL convention)",
            valid.iter().filter(|v| !**v).count()
        ));
    }
    let provenance = Provenance {
        source: source.to_string(),
        tool: TOOL_VERSION.to_string(),
        notes,
    };
    Table::new(grid, Channels::default_for(3), provenance, data, valid)?.with_exact(ExactValues {
        scale: SCALE.to_vec(),
        raw: exact,
    })
}

/// Writes a table (on a MERL-shaped grid, 3 channels) as MERL bytes.
pub fn to_bytes(table: &Table) -> Result<Vec<u8>> {
    Ok(MerlTable::from_table(table)?.to_bytes())
}

/// The reference lookup of `BRDFRead.cpp` (`--interp merl`): the nearest lower bin, no
/// interpolation, stored × scale returned unclamped (negative markers included).
#[derive(Clone, Debug)]
pub struct MerlLookup {
    table: MerlTable,
    channels: Channels,
}

impl MerlLookup {
    pub fn new(table: MerlTable) -> MerlLookup {
        MerlLookup {
            table,
            channels: Channels::default_for(3),
        }
    }

    /// From a table on a MERL-shaped grid (exact values are used when present).
    pub fn from_table(table: &Table) -> Result<MerlLookup> {
        Ok(MerlLookup::new(MerlTable::from_table(table)?))
    }

    pub fn merl(&self) -> &MerlTable {
        &self.table
    }

    /// The bin indices (θh, θd, φd) of a direction pair, step by step as `BRDFRead.cpp`.
    pub fn bins(&self, wi: Vec3, wo: Vec3) -> [usize; 3] {
        self.bins_of(wi, wo, wi)
    }

    /// The reference's steps: the half vector from the vectors as built (`in_h`, `out_h`),
    /// the difference vector from the normalized incoming one (`in_d`).
    fn bins_of(&self, in_h: Vec3, out_h: Vec3, in_d: Vec3) -> [usize; 3] {
        let [nh, nd, np] = self.table.dims;
        // std_coords_to_half_diff_coords: half = normalize((in + out) / 2).
        let half = normalize(Vec3::new(
            (in_h.x + out_h.x) / 2.0,
            (in_h.y + out_h.y) / 2.0,
            (in_h.z + out_h.z) / 2.0,
        ));
        let theta_half = half.z.acos();
        let phi_half = half.y.atan2(half.x);
        let bi_normal = Vec3::new(0.0, 1.0, 0.0);
        let normal = Vec3::new(0.0, 0.0, 1.0);
        let temp = rotate_vector(in_d, normal, -phi_half);
        let diff = rotate_vector(temp, bi_normal, -theta_half);
        let theta_diff = diff.z.acos();
        let mut phi_diff = diff.y.atan2(diff.x);

        // theta_half_index: 0 at or below 0, else ⌊sqrt(θh/(π/2)·n·n)⌋ — the sqrt warp.
        let ih = if theta_half <= 0.0 {
            0.0
        } else {
            ((theta_half / (PI / 2.0)) * nh as f64 * nh as f64).sqrt()
        };
        // theta_diff_index: ⌊θd/(π/2)·n⌋.
        let id = theta_diff / (PI * 0.5) * nd as f64;
        // phi_diff_index: reciprocity maps φd to φd + π; ⌊φd/π·n⌋ (the reference writes
        // `/ M_PI * 360 / 2`, which rounds identically since halving is exact).
        if phi_diff < 0.0 {
            phi_diff += PI;
        }
        let ip = phi_diff / PI * np as f64;
        [clamp_bin(ih, nh), clamp_bin(id, nd), clamp_bin(ip, np)]
    }

    /// The reference lookup at a direction pair (no horizon test, as the reference).
    pub fn lookup(&self, wi: Vec3, wo: Vec3) -> [f64; 3] {
        self.value_at(self.bins(wi, wo))
    }

    /// stored × scale of bin (θh, θd, φd), as the reference returns it.
    pub fn value_at(&self, [i, j, k]: [usize; 3]) -> [f64; 3] {
        let [_, nd, np] = self.table.dims;
        let n = self.table.cells();
        let ind = (i * nd + j) * np + k;
        [0, 1, 2].map(|c| self.table.raw[c * n + ind] * SCALE[c])
    }

    /// The reference lookup from spherical angles, building the vectors as the reference
    /// does: `(sinθ cosφ, sinθ sinφ, cosθ)`, the incoming one normalized for the rotation.
    pub fn lookup_angles(
        &self,
        theta_in: f64,
        phi_in: f64,
        theta_out: f64,
        phi_out: f64,
    ) -> [f64; 3] {
        let v = |t: f64, p: f64| {
            let s = t.sin();
            Vec3::new(s * p.cos(), s * p.sin(), t.cos())
        };
        let (vin, vout) = (v(theta_in, phi_in), v(theta_out, phi_out));
        self.value_at(self.bins_of(vin, vout, normalize(vin)))
    }
}

/// `(int)x` of a non-negative bin coordinate, clamped to [0, n − 1]; NaN → 0.
#[inline]
fn clamp_bin(x: f64, n: usize) -> usize {
    // `as usize` saturates: NaN and negatives → 0 (C's (int) is undefined there; the
    // reference's clamps give 0 for negatives), huge → usize::MAX, clamped below.
    (x as usize).min(n - 1)
}

/// `BRDFRead.cpp` normalize: each component divided by the length.
#[inline]
fn normalize(v: Vec3) -> Vec3 {
    let len = (v.x * v.x + v.y * v.y + v.z * v.z).sqrt();
    Vec3::new(v.x / len, v.y / len, v.z / len)
}

/// `BRDFRead.cpp` rotate_vector: Rodrigues' rotation of `v` about the unit `axis` by `angle`,
/// v cosα + axis (axis·v)(1 − cosα) + (axis × v) sinα, accumulated in the reference's order.
#[inline]
fn rotate_vector(v: Vec3, axis: Vec3, angle: f64) -> Vec3 {
    let cos_ang = angle.cos();
    let sin_ang = angle.sin();
    let mut out = Vec3::new(v.x * cos_ang, v.y * cos_ang, v.z * cos_ang);
    let temp = axis.x * v.x + axis.y * v.y + axis.z * v.z;
    let temp = temp * (1.0 - cos_ang);
    out.x += axis.x * temp;
    out.y += axis.y * temp;
    out.z += axis.z * temp;
    let cross = axis.cross(v);
    out.x += cross.x * sin_ang;
    out.y += cross.y * sin_ang;
    out.z += cross.z * sin_ang;
    out
}

impl Brdf for MerlLookup {
    fn is_sampled(&self) -> bool {
        true
    }

    fn channels(&self) -> &Channels {
        &self.channels
    }
    /// The reference lookup above the horizon (unclamped, negative markers included);
    /// 0 below it, as the [`Brdf`] contract asks.
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            out.fill(0.0);
            return;
        }
        let v = self.lookup(wi, wo);
        out.copy_from_slice(&v);
    }
    fn is_isotropic(&self) -> bool {
        true
    }
    fn is_reciprocal(&self) -> bool {
        // The φd fold makes the lookup symmetric only up to bin rounding.
        false
    }
    fn describe(&self) -> String {
        let [a, b, c] = self.table.dims;
        format!("MERL reference lookup (nearest lower bin) on {a}x{b}x{c}")
    }
}

/// θh of the lower edge of bin i (MERL's sample position), for tests and docs.
pub fn theta_h_edge(i: f64, n: usize) -> f64 {
    (i / n as f64).powi(2) * FRAC_PI_2
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::HalfDiff;

    fn small(dims: [usize; 3]) -> MerlTable {
        let n: usize = dims.iter().product();
        let raw = (0..3 * n)
            .map(|i| {
                if i % 7 == 3 {
                    -1.0
                } else {
                    i as f64 * 0.37 + 0.1
                }
            })
            .collect();
        MerlTable { dims, raw }
    }

    #[test]
    fn small_files_round_trip_through_tables() {
        let m = small([4, 5, 6]);
        let bytes = m.to_bytes();
        let back = MerlTable::from_bytes(&bytes, Path::new("x")).unwrap();
        assert_eq!(back, m);
        let t = back.to_table("x").unwrap();
        assert_eq!(t.grid().shape(), vec![4, 5, 6]);
        assert_eq!(to_bytes(&t).unwrap(), bytes);
        // Without the exact values, valid cells come back within f32 rounding and invalid
        // ones as −1.
        let m2 = MerlTable::from_table(&t.clone().without_exact()).unwrap();
        let n = m.cells();
        for i in 0..3 * n {
            let cell = i % n;
            if t.valid()[cell] {
                let rel = (m2.raw[i] - m.raw[i]).abs() / m.raw[i].abs().max(1e-30);
                assert!(rel < 1e-7, "{i}: {} vs {}", m2.raw[i], m.raw[i]);
            } else {
                assert_eq!(m2.raw[i], INVALID_RAW);
            }
        }
    }

    #[test]
    fn malformed_files_are_refused_with_reasons() {
        let bytes = small([4, 5, 6]).to_bytes();
        let p = Path::new("m.binary");
        let e = MerlTable::from_bytes(&bytes[..bytes.len() - 8], p).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("truncated"), "{e}");
        let mut wrong = bytes.clone();
        wrong[0..4].copy_from_slice(&5i32.to_le_bytes());
        let e = MerlTable::from_bytes(&wrong, p).unwrap_err().to_string();
        assert!(e.contains("does not match dims 5 5 6"), "{e}");
        wrong[0..4].copy_from_slice(&(-4i32).to_le_bytes());
        let e = MerlTable::from_bytes(&wrong, p).unwrap_err().to_string();
        assert!(e.contains("dimension 0 = -4"), "{e}");
        let mut nan = bytes.clone();
        nan[12 + 8 * 130..12 + 8 * 131].copy_from_slice(&f64::NAN.to_le_bytes());
        let e = MerlTable::from_bytes(&nan, p).unwrap_err().to_string();
        assert!(
            e.contains("value 130 (channel green, cell 10) is NaN"),
            "{e}"
        );
        assert!(MerlTable::from_bytes(&bytes[..5], p).is_err());
    }

    /// A regular file read in chunks ([`read_regular_file`]) is the table of its bytes
    /// ([`from_bytes`]) bit for bit, across chunk boundaries (192,000 values: one chunk holds
    /// 131,072), and refuses what it refuses; anything not sized as a MERL file, or with
    /// another format's magic, is left to the whole-file reader (which gives its errors).
    #[test]
    fn a_file_read_in_chunks_makes_the_table_of_its_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let mut m = small([40, 40, 40]);
        let n = m.cells();
        m.raw[131_071] = INVALID_RAW;
        m.raw[131_072] = 1e-300;
        let bytes = m.to_bytes();
        let p = dir.path().join("m.binary");
        std::fs::write(&p, &bytes).unwrap();
        let streamed = read_regular_file(&p).unwrap().expect("a MERL file");
        let whole = from_bytes(&bytes, &p).unwrap();
        let bits = |t: &Table| t.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&streamed), bits(&whole));
        assert_eq!(streamed.valid(), whole.valid());
        let raw = |t: &Table| {
            t.exact()
                .unwrap()
                .raw
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(raw(&streamed), raw(&whole));
        assert_eq!(streamed.provenance(), whole.provenance());
        // A non-finite value past the first chunk: the same error.
        let mut bad = bytes.clone();
        let i = 2 * n + 5;
        bad[12 + 8 * i..12 + 8 * (i + 1)].copy_from_slice(&f64::NAN.to_le_bytes());
        std::fs::write(&p, &bad).unwrap();
        let e = read_regular_file(&p).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert_eq!(e.to_string(), from_bytes(&bad, &p).unwrap_err().to_string());
        // Not sized as its header says, or another format's magic: not read here.
        std::fs::write(&p, &bytes[..bytes.len() - 8]).unwrap();
        assert!(read_regular_file(&p).unwrap().is_none());
        assert!(read_regular_file(dir.path()).unwrap().is_none());
        let native = dir.path().join("t.bpk");
        std::fs::write(&native, crate::io::native::MAGIC).unwrap();
        assert!(read_regular_file(&native).unwrap().is_none());
    }

    /// The table read straight from the bytes is the one of the parsed [`MerlTable`], bit for
    /// bit (samples, exact values, flags, notes), and refuses what the parser refuses.
    #[test]
    fn the_direct_reader_makes_the_parsed_table() {
        let mut m = small([6, 5, 8]);
        let n = m.cells();
        m.raw[3] = INVALID_RAW;
        m.raw[n + 17] = -0.25;
        m.raw[2 * n + 40] = 1e-300;
        let bytes = m.to_bytes();
        let p = Path::new("m.binary");
        let direct = from_bytes(&bytes, p).unwrap();
        let parsed = m.to_table("MERL .binary file m.binary").unwrap();
        let bits = |t: &Table| t.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&direct), bits(&parsed));
        assert_eq!(direct.valid(), parsed.valid());
        assert!(!direct.valid()[3] && !direct.valid()[17]);
        let raw = |t: &Table| {
            let e = t.exact().unwrap();
            (
                e.scale.clone(),
                e.raw.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            )
        };
        assert_eq!(raw(&direct), raw(&parsed));
        assert_eq!(direct.provenance(), parsed.provenance());
        let mut nan = bytes.clone();
        nan[12 + 8 * (n + 10)..12 + 8 * (n + 11)].copy_from_slice(&f64::INFINITY.to_le_bytes());
        let e = from_bytes(&nan, p).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(
            e.to_string().contains("(channel green, cell 10) is inf"),
            "{e}"
        );
        assert!(from_bytes(&bytes[..bytes.len() - 1], p).is_err());
    }

    #[test]
    fn bins_follow_the_reference_rules() {
        let l = MerlLookup::new(small([90, 90, 180]));
        // Midpoints of every θh bin map to themselves (and the sqrt rule, not linear).
        for i in 0..90 {
            for (j, k) in [(0, 0), (45, 90), (89, 179), (10, 17)] {
                let hd = HalfDiff {
                    theta_h: theta_h_edge(i as f64 + 0.5, 90),
                    phi_h: 0.7,
                    theta_d: (j as f64 + 0.5) * PI / 180.0,
                    phi_d: (k as f64 + 0.5) * PI / 180.0,
                };
                let (wi, wo) = hd.to_dirs();
                assert_eq!(l.bins(wi, wo), [i, j, k]);
                // Swapping the directions is φd + π: the same bin.
                assert_eq!(l.bins(wo, wi), [i, j, k]);
            }
        }
        // Degenerate pairs give finite bins (NaN → 0), never a panic.
        let z = Vec3::new(0.0, 0.0, 1.0);
        assert_eq!(l.bins(z, z), [0, 0, 0]);
        let b = l.bins(Vec3::new(1.0, 0.0, 0.0), Vec3::new(-1.0, 0.0, 0.0));
        assert!(b[0] < 90 && b[1] < 90 && b[2] < 180);
    }
}
