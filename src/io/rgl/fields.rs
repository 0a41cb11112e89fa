//! An RGL `.bsdf` file as its fields (name, dtype, shape, bytes, in file order), and the two
//! fields that the others determine: the VNDF and the luminance (issue #19).
//!
//! The measured files of the RGL database hold, per (φi, θi) slice, a VNDF that is the
//! visible-normal density of their own NDF (Dupuy & Jakob 2018, §5, with the Jacobian of the
//! (u_θ, u_φ) square): vndf[y][x] = c_s · D(m) · max(0, wi·m) · sin θm · u_θ at the node
//! u_θ = x/(W − 1), u_φ = y/(H − 1), θm = u_θ²·π/2, φm = (2u_φ − 1)·π (relative to φi for an
//! isotropic file, absolute for an anisotropic one), D the `ndf` grid looked up as Mitsuba
//! looks it up, wi the slice's incident direction and c_s a per-slice constant that the warp's
//! normalisation divides out. Their `luminance` is the Rec. 709 luminance of `rgb`. A packed
//! file can therefore leave both out and rebuild them ([`derived_vndf`], [`luminance_of`]);
//! whether the derived VNDF is the file's is measured by whoever leaves it out (files
//! brdfpack's own writer makes hold another density).

use super::tensor::{Dtype, FieldData, TensorFile, encode};
use super::warp::Grid2;
use crate::geometry::Vec3;
use crate::math::{FRAC_PI_2, PI};
use crate::{Error, Result};

/// One field of a tensor file, owned.
#[derive(Clone, Debug, PartialEq)]
pub struct RawField {
    pub name: String,
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    /// Little-endian data, `shape.product() × dtype.size()` bytes.
    pub data: Vec<u8>,
}

impl RawField {
    /// A float32 field.
    pub fn f32(name: &str, shape: Vec<usize>, values: &[f32]) -> RawField {
        RawField {
            name: name.to_string(),
            dtype: Dtype::F32,
            shape,
            data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }

    /// The values of a float32 field (`None` for another dtype).
    pub fn f32_values(&self) -> Option<Vec<f32>> {
        (self.dtype == Dtype::F32).then(|| {
            self.data
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
                .collect()
        })
    }

    /// Elements the shape declares.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Every field of a tensor file, in file order.
#[derive(Clone, Debug, PartialEq)]
pub struct RglFields {
    pub fields: Vec<RawField>,
}

impl RglFields {
    /// The fields of a tensor file (not validated as an RGL BSDF: [`super::RglBsdf`] does that).
    pub fn parse(bytes: &[u8], name: &str) -> Result<RglFields> {
        let file = TensorFile::parse(bytes, name)?;
        Ok(RglFields {
            fields: file
                .fields()
                .iter()
                .map(|f| RawField {
                    name: f.name.clone(),
                    dtype: f.dtype,
                    shape: f.shape.clone(),
                    data: file.raw(f).to_vec(),
                })
                .collect(),
        })
    }

    /// The tensor file of these fields, in their order (Mitsuba's layout: 8-byte aligned
    /// blocks, version 1.0).
    pub fn to_tensor_bytes(&self) -> Vec<u8> {
        let fields: Vec<FieldData> = self
            .fields
            .iter()
            .map(|f| FieldData {
                name: &f.name,
                dtype: f.dtype,
                shape: f.shape.clone(),
                data: f.data.clone(),
            })
            .collect();
        encode(&fields)
    }

    pub fn get(&self, name: &str) -> Option<&RawField> {
        self.fields.iter().find(|f| f.name == name)
    }

    /// The field `name`, or an error naming it (`what` names the file).
    pub fn require(&self, name: &str, what: &str) -> Result<&RawField> {
        self.get(name)
            .ok_or_else(|| Error::invalid_file(what, format!("required field `{name}` is missing")))
    }

    /// The float32 values of `name`, or an error naming the field.
    pub fn f32_of(&self, name: &str, what: &str) -> Result<Vec<f32>> {
        let f = self.require(name, what)?;
        f.f32_values().ok_or_else(|| {
            Error::invalid_file(
                what,
                format!("field `{name}`: dtype {}, expected float32", f.dtype.name()),
            )
        })
    }

    /// Replaces the data of field `name` (same dtype and shape), or inserts the field at
    /// `position` (clamped to the end) when absent.
    pub fn put(&mut self, field: RawField, position: usize) {
        match self.fields.iter_mut().find(|f| f.name == field.name) {
            Some(f) => *f = field,
            None => {
                let at = position.min(self.fields.len());
                self.fields.insert(at, field);
            }
        }
    }

    /// Removes the field `name` and says where it was.
    pub fn take(&mut self, name: &str) -> Option<(usize, RawField)> {
        let at = self.fields.iter().position(|f| f.name == name)?;
        Some((at, self.fields.remove(at)))
    }
}

/// The VNDF of every slice as the measured files hold it, up to each slice's constant (module
/// doc): `[Nφ, Nθ, H, W]` from the slices' angles (radians; `phi_i` of one value for an
/// isotropic file, whose azimuths are relative to φi), the `ndf` grid (`ndf_values` row-major
/// `[rows][cols]`) and the VNDF's H × W. Computed in f64, stored in f32.
pub fn derived_vndf(
    phi_i: &[f32],
    theta_i: &[f32],
    ndf_values: &[f32],
    ndf_shape: [usize; 2],
    height: usize,
    width: usize,
) -> Vec<f32> {
    let [rows, cols] = ndf_shape;
    let ndf = Grid2::new(cols, rows, ndf_values.to_vec());
    let isotropic = phi_i.len() == 1;
    let mut out = Vec::with_capacity(phi_i.len() * theta_i.len() * height * width);
    for &phi in phi_i {
        // An isotropic file's azimuths are relative to φi: its slice sits at φi = 0.
        let phi = if isotropic { 0.0 } else { f64::from(phi) };
        for &theta in theta_i {
            let wi = Vec3::from_spherical(f64::from(theta), phi);
            for y in 0..height {
                let u_phi = y as f64 / (height - 1) as f64;
                let phi_m = (2.0 * u_phi - 1.0) * PI;
                for x in 0..width {
                    let u_theta = x as f64 / (width - 1) as f64;
                    let theta_m = u_theta * u_theta * FRAC_PI_2;
                    let m = Vec3::from_spherical(theta_m, phi_m);
                    let d = ndf.eval([u_theta, u_phi]);
                    let v = d * wi.dot(m).max(0.0) * theta_m.sin() * u_theta;
                    // A density: an ndf node below 0 (none in a valid file) gives 0, not a
                    // negative weight.
                    out.push(v.max(0.0) as f32);
                }
            }
        }
    }
    out
}

/// The projected area σ(wi) = ∫ D(m) max(0, wi·m) dm of an isotropic NDF (every row of the
/// `[rows][cols]` grid `ndf_values` the same), on a `sigma` grid of `sigma_shape`
/// `[rows, cols]` (node x at u_θ = x/(cols − 1), θ = u_θ²·π/2, as the NDF's): the measured
/// files' `sigma` up to one constant per file (their NDFs are normalised by another
/// quadrature: `sigma` is 0.991–0.992 of this on the four public files, constant to 1.5e-4
/// over θ). `None` for an anisotropic NDF.
///
/// The azimuth is integrated in closed form (∫₀^{2π} max(0, a cos φ + b) dφ =
/// 2(b φ₀ + a sin φ₀), cos φ₀ = −b/a, for |b| < a), θm by Simpson's rule, 16 intervals in
/// each NDF cell, over the NDF's linear interpolation in u_θ (dθ = π u_θ du_θ).
pub fn projected_area(
    ndf_values: &[f32],
    ndf_shape: [usize; 2],
    sigma_shape: [usize; 2],
) -> Option<Vec<f64>> {
    let [rows, cols] = ndf_shape;
    let [s_rows, s_cols] = sigma_shape;
    if rows == 0 || cols < 2 || s_rows == 0 || s_cols < 2 || ndf_values.len() != rows * cols {
        return None;
    }
    let first = &ndf_values[..cols];
    if ndf_values.chunks_exact(cols).any(|r| r != first) {
        return None;
    }
    const PER_CELL: usize = 16;
    let n = (cols - 1) * PER_CELL;
    // Nodes of θm: u, θm, its sine and cosine, D, Simpson weight × dθ/du.
    let nodes: Vec<(f64, f64, f64, f64)> = (0..=n)
        .map(|k| {
            let u = k as f64 / n as f64;
            let theta = u * u * FRAC_PI_2;
            let cell = (k / PER_CELL).min(cols - 2);
            let t = (u * (cols - 1) as f64 - cell as f64).clamp(0.0, 1.0);
            let d = f64::from(first[cell]) * (1.0 - t) + f64::from(first[cell + 1]) * t;
            let w = if k == 0 || k == n {
                1.0
            } else if k % 2 == 1 {
                4.0
            } else {
                2.0
            };
            let (sin, cos) = theta.sin_cos();
            (sin, cos, d, w / (3.0 * n as f64) * PI * u)
        })
        .collect();
    let per_column: Vec<f64> = (0..s_cols)
        .map(|x| {
            let u = x as f64 / (s_cols - 1) as f64;
            let (sin_i, cos_i) = (u * u * FRAC_PI_2).sin_cos();
            nodes
                .iter()
                .map(|&(sin_m, cos_m, d, w)| {
                    let a = sin_m * sin_i;
                    let b = cos_m * cos_i;
                    let azimuths = if b >= a {
                        2.0 * PI * b
                    } else if b <= -a {
                        0.0
                    } else {
                        let c = (-b / a).clamp(-1.0, 1.0);
                        2.0 * (b * c.acos() + a * (1.0 - c * c).sqrt())
                    };
                    d.max(0.0) * azimuths * sin_m * w
                })
                .sum()
        })
        .collect();
    Some(
        (0..s_rows)
            .flat_map(|_| per_column.iter().copied())
            .collect(),
    )
}

/// The `luminance` field of a `[Nφ, Nθ, 3, n, n]` `rgb` tensor: Rec. 709 luminance
/// 0.2126 R + 0.7152 G + 0.0722 B per node, `[Nφ, Nθ, n, n]`, at least 0 (Mitsuba samples
/// in proportion to it; the measured files hold no negative luminance).
pub fn luminance_of(rgb: &[f32], slices: usize, plane: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(slices * plane);
    for s in 0..slices {
        let at = |c: usize, p: usize| f64::from(rgb[(s * 3 + c) * plane + p]);
        for p in 0..plane {
            let y = 0.2126 * at(0, p) + 0.7152 * at(1, p) + 0.0722 * at(2, p);
            out.push(y.max(0.0) as f32);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_round_trip_through_the_tensor_container() {
        let bytes = std::fs::read(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/fixtures/rgl/tiny.bsdf"
        ))
        .unwrap();
        let f = RglFields::parse(&bytes, "tiny").unwrap();
        assert_eq!(f.to_tensor_bytes(), bytes);
        assert_eq!(f.f32_of("theta_i", "tiny").unwrap(), vec![0.0, 1.2]);
    }

    #[test]
    fn derived_vndf_is_the_visible_normal_density() {
        // A flat NDF D = 1: at the node u_θ = 0.5 (θm = π/8), φm = 0 (row 1 of 3), normal
        // incidence: 1 · cos(π/8) · sin(π/8) · 0.5.
        let v = derived_vndf(&[0.0], &[0.0], &[1.0; 4], [2, 2], 3, 3);
        let want = (PI / 8.0).cos() * (PI / 8.0).sin() * 0.5;
        assert!((f64::from(v[3 + 1]) - want).abs() < 1e-7, "{}", v[4]);
        // Column 0 (u_θ = 0) holds 0; every value is ≥ 0.
        assert_eq!(v[0], 0.0);
        assert!(v.iter().all(|&x| x >= 0.0));
        // Grazing incidence: m facing away from wi (φm = ±π at θi = 90°) gets 0.
        let g = derived_vndf(&[0.0], &[FRAC_PI_2 as f32], &[1.0; 4], [2, 2], 3, 3);
        assert_eq!(g[2], 0.0);
        assert!(g[3 + 2] > 0.0);
    }

    /// The projected area of a GGX NDF (normalised: ∫ D cos θm dm = 1) is Smith's
    /// cos θi (1 + Λ(θi)), Λ = (√(1 + α² tan² θi) − 1)/2 (Heitz 2014, "Understanding the
    /// masking-shadowing function"). The NDF is sampled on 256 nodes of u_θ and interpolated
    /// linearly there, which is the error measured (5.3e-5 at α 0.3 up to θi = 81°); an NDF whose
    /// rows differ (anisotropic) is not derived.
    #[test]
    fn the_projected_area_of_a_ggx_ndf_is_smiths() {
        for alpha in [0.3f64, 0.6] {
            let cols = 256;
            let d: Vec<f32> = (0..cols)
                .map(|x| {
                    let u = x as f64 / (cols - 1) as f64;
                    let t = (u * u * FRAC_PI_2).min(FRAC_PI_2 - 1e-6);
                    let (c, t2) = (t.cos(), t.tan().powi(2));
                    (alpha * alpha / (PI * c.powi(4) * (alpha * alpha + t2).powi(2))) as f32
                })
                .collect();
            let ndf: Vec<f32> = d.iter().chain(&d).copied().collect();
            let s = projected_area(&ndf, [2, cols], [2, 64]).unwrap();
            assert_eq!(s.len(), 128);
            assert_eq!(s[..64], s[64..]);
            let mut worst = 0f64;
            for (x, &got) in s[..58].iter().enumerate() {
                let u = x as f64 / 63.0;
                let t = u * u * FRAC_PI_2;
                let lambda = ((1.0 + alpha * alpha * t.tan().powi(2)).sqrt() - 1.0) / 2.0;
                let want = t.cos() * (1.0 + lambda);
                worst = worst.max((got / want - 1.0).abs());
            }
            assert!(worst < 2e-4, "α {alpha}: worst relative error {worst:e}");
        }
        let mut aniso = vec![1.0f32; 2 * 8];
        aniso[9] = 2.0;
        assert!(projected_area(&aniso, [2, 8], [2, 8]).is_none());
    }

    #[test]
    fn luminance_is_rec709() {
        let rgb = [1.0, 0.0, 0.0, 1.0, 0.0, 0.0];
        let l = luminance_of(&rgb, 1, 2);
        assert_eq!(l, vec![0.2126, 0.7152]);
    }
}
