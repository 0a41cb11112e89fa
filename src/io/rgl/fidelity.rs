//! Whether a written RGL `.bsdf` still is its source: the directional albedo of the file
//! against the source's, by the same half-vector quadrature (`props::directional_albedo_at`,
//! accurate to 1e-4 on smooth sources).
//!
//! The file's NDF, VNDF warp and colour grid have a fixed resolution; a lobe narrower than
//! their nodes (GGX gold at α 1e-4: a half-width of 0.006°, far inside the first VNDF cell) is
//! written as a wider one with the peak's height, and the file reflects up to 6× the energy
//! the source does (albedo 6.15 at θi 85°, where gold's is 0.98). `convert` measured nothing
//! and wrote it with exit 0. The albedo is the quantity a renderer shows for any lobe, wide
//! or narrow, so it is the test: a file whose albedo differs from the source's by more than
//! [`ALBEDO_REFUSAL_SHARE`] of it (plus [`ALBEDO_REFUSAL_FLOOR`]) is not written.

use crate::brdf::Brdf;
use crate::io::rgl::RglBsdf;
use crate::props::{albedo_angle_pairs_deg, directional_albedo_at};
use crate::{Error, Result};
use rayon::prelude::*;
use serde::Serialize;

/// A file is refused when |a_file − a_source| exceeds this share of a_source (plus the floor)
/// at some incidence angle and channel: a gross failure, not a grade. At the default
/// resolutions the files of rough to glossy lobes stay far below it (GGX gold: 2e-3 at α 0.2
/// and 0.03, 0.013 at α 0.001, 0.038 at α 5e-4, about 4% of its albedo), and a coarse file
/// passes too (GGX gold at α 0.2 on 2 θi slices misses its albedo by 0.10 at θi 57°, 43% of
/// the threshold); GGX gold at α 3e-4 is off by 0.37 (38%) and at α 1e-4 by
/// 5.2 (docs/rgl.md).
pub const ALBEDO_REFUSAL_SHARE: f64 = 0.25;
/// Absolute part of the refusal threshold: a dark source (albedo 0.002) is not refused for
/// differences no render shows.
pub const ALBEDO_REFUSAL_FLOOR: f64 = 0.02;

/// The directional albedo of a written file against its source's, at the worst angle.
#[derive(Clone, Debug, Serialize)]
pub struct AlbedoFidelity {
    /// max over angles and channels of |a_file − a_source|.
    pub max_abs_diff: f64,
    /// Where it occurs (degrees) and in which channel (0 R, 1 G, 2 B).
    pub theta_i_deg: f64,
    pub phi_i_deg: f64,
    pub channel: usize,
    /// The two albedos there.
    pub source: f64,
    pub file: f64,
    /// The largest ratio of the difference to the refusal threshold
    /// (`ALBEDO_REFUSAL_SHARE · a_source + ALBEDO_REFUSAL_FLOOR`); above 1 the file is refused.
    pub threshold_share: f64,
}

/// The directional albedo of `file` against `source` at the 16 angles of
/// [`albedo_angle_pairs_deg`] (φi 0°, and 90° for an anisotropic source). A one-channel source is
/// compared with each of the file's grey channels.
pub fn albedo_fidelity(source: &dyn Brdf, file: &RglBsdf) -> AlbedoFidelity {
    let angles = albedo_angle_pairs_deg(source);
    let rows: Vec<AlbedoFidelity> = angles
        .par_iter()
        .map(|&(t, p)| {
            let (ti, pi) = (t.to_radians(), p.to_radians());
            let a = directional_albedo_at(source, ti, pi);
            let b = directional_albedo_at(file, ti, pi);
            let mut worst: Option<AlbedoFidelity> = None;
            for (k, &fb) in b.iter().enumerate() {
                let fa = if a.len() == b.len() { a[k] } else { a[0] };
                let diff = (fb - fa).abs();
                let share = diff / (ALBEDO_REFUSAL_SHARE * fa.abs() + ALBEDO_REFUSAL_FLOOR);
                // NaN counts as the worst of all (it is never written; see `refuse`).
                let share = if share.is_nan() { f64::INFINITY } else { share };
                if worst.as_ref().is_none_or(|w| share > w.threshold_share) {
                    worst = Some(AlbedoFidelity {
                        max_abs_diff: diff,
                        theta_i_deg: t,
                        phi_i_deg: p,
                        channel: k,
                        source: fa,
                        file: fb,
                        threshold_share: share,
                    });
                }
            }
            worst.expect("a file has three channels")
        })
        .collect();
    let max_abs = rows.iter().map(|r| r.max_abs_diff).fold(0.0, |m: f64, d| {
        if d.is_nan() { f64::INFINITY } else { m.max(d) }
    });
    // Rows in angle order: the first of equal shares is kept, whatever the thread count.
    let mut worst = rows
        .into_iter()
        .reduce(|w, r| {
            if r.threshold_share > w.threshold_share {
                r
            } else {
                w
            }
        })
        .expect("16 angles");
    worst.max_abs_diff = max_abs;
    worst
}

/// [`albedo_fidelity`] of the file `bytes` (as written) against `source`: an error when the
/// file is not a representation of the source (above the threshold), naming both albedos.
pub fn refuse_unrepresentable(
    source: &dyn Brdf,
    bytes: &[u8],
    output: &str,
) -> Result<AlbedoFidelity> {
    let file = RglBsdf::from_bytes(bytes, output)?;
    let f = albedo_fidelity(source, &file);
    if f.threshold_share > 1.0 {
        let channel = ["R", "G", "B"].get(f.channel).copied().unwrap_or("?");
        return Err(Error::input(format!(
            "{}: an RGL .bsdf cannot represent this source: the file's directional albedo at \
             θi {:.2}°, φi {:.0}° ({channel}) would be {:.4} against the source's {:.4} (more \
             than {:.0}% + {} apart): its lobe is narrower than the file's NDF, VNDF and \
             colour nodes hold, or its θi slices too few (raise the --rgl-* resolutions, or \
             keep it as a table: `brdfpack pack`); no file written",
            source.describe(),
            f.theta_i_deg,
            f.phi_i_deg,
            f.file,
            f.source,
            ALBEDO_REFUSAL_SHARE * 100.0,
            ALBEDO_REFUSAL_FLOOR,
        )));
    }
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::rgl::write::{RglWriteOptions, write_rgl};
    use crate::model::Model;

    /// Half the default θi slices (the rest as `convert` writes them).
    fn small() -> RglWriteOptions {
        RglWriteOptions {
            theta_slices: 16,
            ..RglWriteOptions::default()
        }
    }

    /// A rough lobe is written within a few thousandths of its albedo and accepted; a lobe
    /// far narrower than the file's nodes is refused, naming both albedos, at the
    /// resolution that cannot hold it.
    #[test]
    fn a_rough_lobe_is_kept_and_a_near_delta_one_is_refused() {
        let rough = Model::parse("ggx:alpha=0.3,fresnel=au").unwrap();
        let w = write_rgl(&rough, &small()).unwrap();
        let f = refuse_unrepresentable(&rough, &w.bytes, "rough.bsdf").unwrap();
        assert!(f.max_abs_diff < 0.02, "{f:?}");
        assert!(f.threshold_share < 0.2, "{f:?}");
        let narrow = Model::parse("ggx:alpha=0.0001,fresnel=au").unwrap();
        let w = write_rgl(&narrow, &small()).unwrap();
        let e = refuse_unrepresentable(&narrow, &w.bytes, "narrow.bsdf").unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("cannot represent") && msg.contains("no file written"),
            "{msg}"
        );
        // The file's albedo is not the source's (gold's is below 1 everywhere).
        let file = RglBsdf::from_bytes(&w.bytes, "narrow.bsdf").unwrap();
        let f = albedo_fidelity(&narrow, &file);
        assert!(f.source < 1.0 && f.file > 1.25 * f.source + 0.02, "{f:?}");
    }

    /// A grey one-channel source is compared with each of the file's grey channels: a
    /// Lambertian surface's file keeps its albedo ρ.
    #[test]
    fn a_grey_lambertian_file_keeps_its_albedo() {
        let lambert = Model::parse("lambert:albedo=0.5").unwrap();
        let w = write_rgl(&lambert, &small()).unwrap();
        let f = refuse_unrepresentable(&lambert, &w.bytes, "l.bsdf").unwrap();
        assert!((f.source - 0.5).abs() < 1e-3, "{f:?}");
        assert!(f.max_abs_diff < 0.01, "{f:?}");
    }
}
