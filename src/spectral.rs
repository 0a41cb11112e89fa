//! Spectral channels: tabulated optical constants over wavelength (parsed from text; the
//! files are opened by `io`), and the conversion of spectral samples to linear sRGB (for
//! previews and for formats that hold RGB only; a whole table converts in
//! `table::spectral_to_rgb`, a layer above).
//!
//! Conventions (docs/spectral.md): wavelengths in nanometres; a spectrum given by samples
//! f(λ_j) is the piecewise-linear curve through them, held constant beyond the first and
//! last sample; RGB = M · XYZ with XYZ = Σ f(λ) I(λ) cmf(λ) / Σ I(λ) ȳ(λ) over the 5 nm
//! nodes 380–780 nm (CIE 015:2004 §7.1 summation), I = CIE illuminant D65, and M the linear
//! sRGB matrix (IEC 61966-2-1 primaries) built for the white of these same tables, so that a
//! spectrally flat BRDF f maps to R = G = B = f exactly.

use crate::brdf::Channels;
use crate::{Error, Result};
use std::path::Path;

/// First wavelength (nm) of [`CIE_1931_2DEG_D65`].
pub const CIE_START_NM: f64 = 380.0;
/// Spacing (nm) of [`CIE_1931_2DEG_D65`].
pub const CIE_STEP_NM: f64 = 5.0;

/// CIE 1931 2° colour-matching functions x̄, ȳ, z̄ and the relative spectral power of CIE
/// standard illuminant D65, at 5 nm from 380 to 780 nm (81 rows: [x̄, ȳ, z̄, D65]).
///
/// Sources: x̄ȳz̄ — CIE 015:2004 *Colorimetry*, Table T.4 (CIE 1931 standard colorimetric
/// observer), as distributed at 1 nm by the Colour & Vision Research Laboratory (CVRL,
/// file ciexyz31_1), whose 5 nm nodes are the CIE 5 nm values; D65 — CIE 015:2004 Table T.1
/// (also ISO 11664-2 / CIE S 014-2), normalised to 100 at 560 nm. Transcribed through the
/// datasets of colour-science 0.4.7 (`MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]`,
/// `SDS_ILLUMINANTS["D65"]`), rounded to 9 significant digits (every published digit kept).
#[rustfmt::skip]
pub const CIE_1931_2DEG_D65: [[f64; 4]; 81] = [
    [0.001368, 3.9e-05, 0.006450001, 49.9755], // 380
    [0.002236, 6.4e-05, 0.01054999, 52.3118], // 385
    [0.004243, 0.00012, 0.02005001, 54.6482], // 390
    [0.00765, 0.000217, 0.03621, 68.7015], // 395
    [0.01431, 0.000396, 0.06785001, 82.7549], // 400
    [0.02319, 0.00064, 0.1102, 87.1204], // 405
    [0.04351, 0.00121, 0.2074, 91.486], // 410
    [0.07763, 0.00218, 0.3713, 92.4589], // 415
    [0.13438, 0.004, 0.6456, 93.4318], // 420
    [0.21477, 0.0073, 1.0390501, 90.057], // 425
    [0.2839, 0.0116, 1.3856, 86.6823], // 430
    [0.3285, 0.01684, 1.62296, 95.7736], // 435
    [0.34828, 0.023, 1.74706, 104.865], // 440
    [0.34806, 0.0298, 1.7826, 110.936], // 445
    [0.3362, 0.038, 1.77211, 117.008], // 450
    [0.3187, 0.048, 1.7441, 117.41], // 455
    [0.2908, 0.06, 1.6692, 117.812], // 460
    [0.2511, 0.0739, 1.5281, 116.336], // 465
    [0.19536, 0.09098, 1.28764, 114.861], // 470
    [0.1421, 0.1126, 1.0419, 115.392], // 475
    [0.09564, 0.13902, 0.8129501, 115.923], // 480
    [0.05795001, 0.1693, 0.6162, 112.367], // 485
    [0.03201, 0.20802, 0.46518, 108.811], // 490
    [0.0147, 0.2586, 0.3533, 109.082], // 495
    [0.0049, 0.323, 0.272, 109.354], // 500
    [0.0024, 0.4073, 0.2123, 108.578], // 505
    [0.0093, 0.503, 0.1582, 107.802], // 510
    [0.0291, 0.6082, 0.1117, 106.296], // 515
    [0.06327, 0.71, 0.07824999, 104.79], // 520
    [0.1096, 0.7932, 0.05725001, 106.239], // 525
    [0.1655, 0.862, 0.04216, 107.689], // 530
    [0.2257499, 0.9148501, 0.02984, 106.047], // 535
    [0.2904, 0.954, 0.0203, 104.405], // 540
    [0.3597, 0.9803, 0.0134, 104.225], // 545
    [0.4334499, 0.9949501, 0.008749999, 104.046], // 550
    [0.5120501, 1.0, 0.005749999, 102.023], // 555
    [0.5945, 0.995, 0.0039, 100.0], // 560
    [0.6784, 0.9786, 0.002749999, 98.1671], // 565
    [0.7621, 0.952, 0.0021, 96.3342], // 570
    [0.8425, 0.9154, 0.0018, 96.0611], // 575
    [0.9163, 0.87, 0.001650001, 95.788], // 580
    [0.9786, 0.8163, 0.0014, 92.2368], // 585
    [1.0263, 0.757, 0.0011, 88.6856], // 590
    [1.0567, 0.6949, 0.001, 89.3459], // 595
    [1.0622, 0.631, 0.0008, 90.0062], // 600
    [1.0456, 0.5668, 0.0006, 89.8026], // 605
    [1.0026, 0.503, 0.00034, 89.5991], // 610
    [0.9384, 0.4412, 0.00024, 88.6489], // 615
    [0.8544499, 0.381, 0.00019, 87.6987], // 620
    [0.7514, 0.321, 0.0001, 85.4936], // 625
    [0.6424, 0.265, 4.999999e-05, 83.2886], // 630
    [0.5419, 0.217, 3e-05, 83.4939], // 635
    [0.4479, 0.175, 2e-05, 83.6992], // 640
    [0.3608, 0.1382, 1e-05, 81.863], // 645
    [0.2835, 0.107, -1.90582413e-21, 80.0268], // 650
    [0.2187, 0.0816, 0.0, 80.1207], // 655
    [0.1649, 0.061, 0.0, 80.2146], // 660
    [0.1212, 0.04458, 0.0, 81.2462], // 665
    [0.0874, 0.032, 0.0, 82.2778], // 670
    [0.0636, 0.0232, 0.0, 80.281], // 675
    [0.04677, 0.017, 0.0, 78.2842], // 680
    [0.0329, 0.01192, 0.0, 74.0027], // 685
    [0.0227, 0.00821, 0.0, 69.7213], // 690
    [0.01584, 0.005723, 0.0, 70.6652], // 695
    [0.01135916, 0.004102, 0.0, 71.6091], // 700
    [0.008110916, 0.002929, 0.0, 72.979], // 705
    [0.005790346, 0.002091, 0.0, 74.349], // 710
    [0.004109457, 0.001484, 0.0, 67.9765], // 715
    [0.002899327, 0.001047, 0.0, 61.604], // 720
    [0.00204919, 0.00074, 0.0, 65.7448], // 725
    [0.001439971, 0.00052, 0.0, 69.8856], // 730
    [0.0009999493, 0.0003611, 0.0, 72.4863], // 735
    [0.0006900786, 0.0002492, 0.0, 75.087], // 740
    [0.0004760213, 0.0001719, 0.0, 69.3398], // 745
    [0.0003323011, 0.00012, 0.0, 63.5927], // 750
    [0.0002348261, 8.48e-05, 0.0, 55.0054], // 755
    [0.0001661505, 6e-05, 0.0, 46.4182], // 760
    [0.000117413, 4.24e-05, 0.0, 56.6118], // 765
    [8.307527e-05, 3e-05, 0.0, 66.8054], // 770
    [5.870652e-05, 2.12e-05, 0.0, 65.0941], // 775
    [4.150994e-05, 1.499e-05, 0.0, 63.3828], // 780
];

/// The sRGB primaries' chromaticities (x, y) for R, G, B (IEC 61966-2-1:1999 / ITU-R BT.709).
pub const SRGB_PRIMARIES_XY: [[f64; 2]; 3] = [[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]];

/// Row limit of an optical-constants file.
const MAX_NK_ROWS: usize = 100_000;

/// Largest n or k an optical-constants file may give: the range of the parameters they
/// replace (`eta`, `k` of a conductor, `eta_re`, `eta_im` of HTSG). A file of n = k = 1e308
/// made the Fresnel term overflow: `eval` printed f = 1.7977e308 where 2.635 was due.
pub const MAX_NK: f64 = 1e6;

/// True when the channels are spectral samples (they carry wavelengths).
pub fn is_spectral(channels: &Channels) -> bool {
    channels.wavelengths_nm().is_some()
}

/// Ok when the channels are R, G, B (not spectral); `what` names the consumer in the error,
/// e.g. "MERL .binary". Formats that store RGB call this before writing.
pub fn require_rgb(channels: &Channels, what: &str) -> Result<()> {
    let names = channels.names();
    let is_rgb = !is_spectral(channels) && names.len() == 3 && names == ["R", "G", "B"];
    if is_rgb {
        return Ok(());
    }
    let hint = if is_spectral(channels) {
        "; convert it to RGB first (`--to-rgb` of tabulate and convert, or \
         `brdfpack::table::spectral_to_rgb`)"
    } else {
        ""
    };
    Err(Error::input(format!(
        "{what} holds R, G, B only; the table has {} channel(s) ({}){hint}",
        channels.len(),
        summarize_names(names)
    )))
}

/// `a, b, c` or `a, b, …, z (N)` for long lists.
pub(crate) fn summarize_names(names: &[String]) -> String {
    if names.len() <= 4 {
        names.join(", ")
    } else {
        format!("{}, {}, …, {}", names[0], names[1], names[names.len() - 1])
    }
}

/// A wavelength in µm as nanometres, rounded to 1e-6 nm so that labels read `645nm`
/// rather than `645.0000000000001nm` (0.645 · 1000 is not exact in binary).
pub fn nm_from_um(um: f64) -> f64 {
    (um * 1e9).round() / 1e6
}

/// Linear interpolation of the samples (xs strictly increasing) at `x`; None outside
/// [xs[0], xs[last]] (no extrapolation of measured data).
pub fn interp_linear(xs: &[f64], ys: &[f64], x: f64) -> Option<f64> {
    debug_assert_eq!(xs.len(), ys.len());
    let (&first, &last) = (xs.first()?, xs.last()?);
    if !(x >= first && x <= last) {
        return None;
    }
    // Index of the first sample > x, clamped so that [j − 1, j] is a valid interval.
    let j = xs
        .partition_point(|&v| v <= x)
        .clamp(1, xs.len().max(2) - 1);
    if xs.len() == 1 {
        return Some(ys[0]);
    }
    let (x0, x1) = (xs[j - 1], xs[j]);
    let t = (x - x0) / (x1 - x0);
    Some(ys[j - 1] + t * (ys[j] - ys[j - 1]))
}

/// Tabulated optical constants n(λ), k(λ) of a material (complex index n + ik), read from a
/// CSV file and interpolated linearly in λ (docs/spectral.md "Optical constants").
#[derive(Clone, Debug, PartialEq)]
pub struct OpticalConstants {
    pub wavelengths_nm: Vec<f64>,
    pub n: Vec<f64>,
    pub k: Vec<f64>,
    /// The file it came from, for messages.
    pub source: String,
}

impl OpticalConstants {
    /// Parses the text of an optical-constants CSV file (`path` only names it in messages).
    pub fn parse_csv(text: &str, path: &Path) -> Result<OpticalConstants> {
        let bad =
            |line: usize, msg: String| Error::invalid_file(path, format!("line {line}: {msg}"));
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
        let Some((hline, header)) = lines.next() else {
            return Err(Error::invalid_file(
                path,
                "empty; expected a header wavelength_nm,n,k and rows of numbers",
            ));
        };
        let cols = split_fields(header);
        let scale = match cols.as_slice() {
            [w, n, k] if n.eq_ignore_ascii_case("n") && k.eq_ignore_ascii_case("k") => {
                match w.to_ascii_lowercase().as_str() {
                    "wavelength_nm" | "lambda_nm" | "nm" => 1.0,
                    "wavelength_um" | "lambda_um" | "um" | "wavelength_µm" | "µm" => 1e3,
                    _ => {
                        return Err(bad(
                            hline,
                            format!(
                                "first column {w:?} does not state its unit; name it \
                                 wavelength_nm or wavelength_um"
                            ),
                        ));
                    }
                }
            }
            _ => {
                return Err(bad(
                    hline,
                    format!(
                        "header {header:?} is not wavelength_nm,n,k (or wavelength_um,n,k); \
                         the header is required so that the wavelength unit is never guessed"
                    ),
                ));
            }
        };
        let mut out = OpticalConstants {
            wavelengths_nm: Vec::new(),
            n: Vec::new(),
            k: Vec::new(),
            source: path.display().to_string(),
        };
        for (line, row) in lines {
            if out.n.len() >= MAX_NK_ROWS {
                return Err(bad(line, format!("more than {MAX_NK_ROWS} rows")));
            }
            let fields = split_fields(row);
            if fields.len() != 3 {
                return Err(bad(
                    line,
                    format!("{row:?} has {} fields; expected λ, n, k", fields.len()),
                ));
            }
            let mut v = [0.0; 3];
            for (slot, (f, name)) in v.iter_mut().zip(fields.iter().zip(["λ", "n", "k"])) {
                let x: f64 = f
                    .parse()
                    .map_err(|_| bad(line, format!("{name} = {f:?} is not a number")))?;
                // n and k may be 0 (an ideal lossless medium, a perfect conductor's n); λ not.
                let ok = x.is_finite()
                    && if name == "λ" {
                        x > 0.0
                    } else {
                        (0.0..=MAX_NK).contains(&x)
                    };
                if !ok {
                    return Err(bad(
                        line,
                        if name == "λ" {
                            format!("{name} = {f} is out of range; expected a finite value > 0")
                        } else {
                            format!("{name} = {f} is out of range; expected a value in [0, 1e6]")
                        },
                    ));
                }
                *slot = x;
            }
            let w = v[0] * scale;
            if let Some(&prev) = out.wavelengths_nm.last()
                && w <= prev
            {
                return Err(bad(
                    line,
                    format!(
                        "wavelength {} nm is not greater than the previous row's {prev} nm; \
                         rows must be strictly increasing in wavelength",
                        w
                    ),
                ));
            }
            out.wavelengths_nm.push(w);
            out.n.push(v[1]);
            out.k.push(v[2]);
        }
        if out.n.is_empty() {
            return Err(Error::invalid_file(
                path,
                "has a header but no rows of λ, n, k",
            ));
        }
        Ok(out)
    }

    /// n and k at each wavelength (nm) by linear interpolation; a wavelength outside the
    /// tabulated range is an error (measured constants are not extrapolated).
    pub fn at(&self, wavelengths_nm: &[f64]) -> Result<(Vec<f64>, Vec<f64>)> {
        let mut n = Vec::with_capacity(wavelengths_nm.len());
        let mut k = Vec::with_capacity(wavelengths_nm.len());
        for (i, &w) in wavelengths_nm.iter().enumerate() {
            let (Some(nv), Some(kv)) = (
                interp_linear(&self.wavelengths_nm, &self.n, w),
                interp_linear(&self.wavelengths_nm, &self.k, w),
            ) else {
                return Err(Error::input(format!(
                    "{}: wavelength[{i}] = {w} nm is outside the tabulated range [{}, {}] nm \
                     (optical constants are interpolated, never extrapolated)",
                    self.source,
                    self.wavelengths_nm[0],
                    self.wavelengths_nm[self.wavelengths_nm.len() - 1]
                )));
            };
            n.push(nv);
            k.push(kv);
        }
        Ok((n, k))
    }
}

/// The fields of a CSV row: comma-separated, or whitespace-separated when there is no comma.
fn split_fields(row: &str) -> Vec<&str> {
    if row.contains(',') {
        row.split(',').map(str::trim).collect()
    } else {
        row.split_whitespace().collect()
    }
}

/// 3×3 matrix inverse by the adjugate; None when singular.
fn invert3(m: [[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let cof =
        |r0: usize, r1: usize, c0: usize, c1: usize| m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0];
    let adj = [
        [cof(1, 2, 1, 2), -cof(0, 2, 1, 2), cof(0, 1, 1, 2)],
        [-cof(1, 2, 0, 2), cof(0, 2, 0, 2), -cof(0, 1, 0, 2)],
        [cof(1, 2, 0, 1), -cof(0, 2, 0, 1), cof(0, 1, 0, 1)],
    ];
    let det = m[0][0] * adj[0][0] + m[0][1] * adj[1][0] + m[0][2] * adj[2][0];
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    Some(adj.map(|row| row.map(|x| x / det)))
}

fn mat_vec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    m.map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2])
}

/// XYZ (Y = 1) of illuminant D65 under the 1931 observer, by the summation of the tables.
pub fn d65_white_xyz() -> [f64; 3] {
    let mut xyz = [0.0; 3];
    for row in &CIE_1931_2DEG_D65 {
        for c in 0..3 {
            xyz[c] += row[c] * row[3];
        }
    }
    let y = xyz[1];
    xyz.map(|v| v / y)
}

/// The XYZ → linear sRGB matrix for the sRGB primaries and `white` (XYZ, Y = 1): the
/// standard construction M⁻¹ with M = P·diag(P⁻¹ W) (e.g. Poynton, *Digital Video and HD*,
/// 2012, ch. 26; IEC 61966-2-1 gives it rounded to 4 digits for x, y = 0.3127, 0.3290).
pub fn xyz_to_linear_srgb_matrix(white: [f64; 3]) -> [[f64; 3]; 3] {
    // Columns of P: XYZ of each primary with Y = 1.
    let col = |[x, y]: [f64; 2]| [x / y, 1.0, (1.0 - x - y) / y];
    let (r, g, b) = (
        col(SRGB_PRIMARIES_XY[0]),
        col(SRGB_PRIMARIES_XY[1]),
        col(SRGB_PRIMARIES_XY[2]),
    );
    let p = [[r[0], g[0], b[0]], [r[1], g[1], b[1]], [r[2], g[2], b[2]]];
    // The primaries are linearly independent constants: P is invertible.
    let s = mat_vec(&invert3(p).expect("sRGB primaries are independent"), white);
    let rgb_to_xyz = p.map(|row| [row[0] * s[0], row[1] * s[1], row[2] * s[2]]);
    invert3(rgb_to_xyz).expect("sRGB matrix is invertible")
}

/// The linear map from N spectral samples to linear sRGB (see the module doc): one
/// (R, G, B) weight per channel, RGB = Σ_j weight_j · f_j.
#[derive(Clone, Debug, PartialEq)]
pub struct SpectrumToRgb {
    weights: Vec<[f64; 3]>,
}

impl SpectrumToRgb {
    /// The conversion for samples at `wavelengths_nm` (any order; distinct, finite, > 0).
    pub fn new(wavelengths_nm: &[f64]) -> Result<SpectrumToRgb> {
        if wavelengths_nm.is_empty() {
            return Err(Error::input(
                "spectral to RGB: no wavelengths (the channels are not spectral)",
            ));
        }
        for (i, &w) in wavelengths_nm.iter().enumerate() {
            if !(w.is_finite() && w > 0.0) {
                return Err(Error::input(format!(
                    "spectral to RGB: wavelength[{i}] = {w:?} nm; expected a finite value > 0"
                )));
            }
        }
        // Channel indices in increasing wavelength.
        let mut order: Vec<usize> = (0..wavelengths_nm.len()).collect();
        order.sort_by(|&a, &b| wavelengths_nm[a].total_cmp(&wavelengths_nm[b]));
        for pair in order.windows(2) {
            if wavelengths_nm[pair[0]] == wavelengths_nm[pair[1]] {
                return Err(Error::input(format!(
                    "spectral to RGB: channels {} and {} both have wavelength {} nm",
                    pair[0], pair[1], wavelengths_nm[pair[0]]
                )));
            }
        }
        let sorted: Vec<f64> = order.iter().map(|&i| wavelengths_nm[i]).collect();
        let mut xyz = vec![[0.0f64; 3]; wavelengths_nm.len()];
        let mut norm = 0.0;
        for (node, row) in CIE_1931_2DEG_D65.iter().enumerate() {
            let lambda = CIE_START_NM + CIE_STEP_NM * node as f64;
            norm += row[1] * row[3];
            // The hat functions of the piecewise-linear spectrum at λ, constant beyond the ends.
            let j = sorted.partition_point(|&w| w <= lambda);
            let hats: [(usize, f64); 2] = if j == 0 {
                [(order[0], 1.0), (order[0], 0.0)]
            } else if j == sorted.len() {
                [(order[j - 1], 1.0), (order[j - 1], 0.0)]
            } else {
                let t = (lambda - sorted[j - 1]) / (sorted[j] - sorted[j - 1]);
                [(order[j - 1], 1.0 - t), (order[j], t)]
            };
            for (ch, h) in hats {
                for c in 0..3 {
                    xyz[ch][c] += h * row[c] * row[3];
                }
            }
        }
        let m = xyz_to_linear_srgb_matrix(d65_white_xyz());
        let weights = xyz
            .into_iter()
            .map(|v| mat_vec(&m, v.map(|x| x / norm)))
            .collect();
        Ok(SpectrumToRgb { weights })
    }

    /// Linear sRGB of one spectrum (one value per channel, in channel order).
    pub fn convert(&self, spectrum: &[f64]) -> [f64; 3] {
        debug_assert_eq!(spectrum.len(), self.weights.len());
        let mut rgb = [0.0; 3];
        for (w, &f) in self.weights.iter().zip(spectrum) {
            for c in 0..3 {
                rgb[c] += w[c] * f;
            }
        }
        rgb
    }

    /// The (R, G, B) weight of each channel.
    pub fn weights(&self) -> &[[f64; 3]] {
        &self.weights
    }
}
