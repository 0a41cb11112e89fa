//! The props API on sources defined outside the crate: anisotropic incidence, a
//! discontinuous (table-like) source, a faulty source.

use brdfpack::brdf::{Brdf, Channels};
use brdfpack::geometry::Vec3;
use brdfpack::props::{
    PropsOptions, albedo_estimate, directional_albedo, directional_albedo_at, props,
};
use std::f64::consts::{FRAC_1_PI, PI};

/// A diffuse source whose reflectance depends on the incidence azimuth:
/// f = (0.5 + 0.3 cos²φi)/π, so a(θi, φi) = 0.5 + 0.3 cos²φi exactly.
struct AzimuthalDiffuse(Channels);

impl Brdf for AzimuthalDiffuse {
    fn channels(&self) -> &Channels {
        &self.0
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        out[0] = 0.0;
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return;
        }
        let s2 = wi.sin2_theta();
        // At the normal the azimuth is undefined; the x-axis value is used.
        let cos2_phi = if s2 > 0.0 { wi.x * wi.x / s2 } else { 1.0 };
        out[0] = (0.5 + 0.3 * cos2_phi) * FRAC_1_PI;
    }
    fn is_isotropic(&self) -> bool {
        false
    }
    fn is_reciprocal(&self) -> bool {
        // It depends on wi's azimuth only.
        false
    }
    fn describe(&self) -> String {
        "azimuthal diffuse".into()
    }
}

/// A piecewise-constant source like a nearest-neighbour table: ρ/π for θo < θc, else 0.
/// Its albedo is ρ sin²θc; the jump inside the domain is what tables present.
struct Cutoff {
    channels: Channels,
    cos_cut: f64,
}

impl Brdf for Cutoff {
    fn channels(&self) -> &Channels {
        &self.channels
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        out[0] = if wi.z > 0.0 && wo.z > self.cos_cut {
            FRAC_1_PI
        } else {
            0.0
        };
    }
    fn is_isotropic(&self) -> bool {
        true
    }
    fn describe(&self) -> String {
        "cutoff".into()
    }
}

/// Returns NaN on part of the domain (a broken source) to check nothing propagates.
struct Faulty(Channels);

impl Brdf for Faulty {
    fn channels(&self) -> &Channels {
        &self.0
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        out[0] = if wo.x > 0.5 {
            f64::NAN
        } else if wi.z > 0.0 && wo.z > 0.0 {
            FRAC_1_PI
        } else {
            0.0
        };
    }
    fn is_isotropic(&self) -> bool {
        true
    }
    fn describe(&self) -> String {
        "faulty".into()
    }
}

#[test]
fn albedo_follows_the_incidence_azimuth() {
    let b = AzimuthalDiffuse(Channels::default_for(1));
    for phi_deg in [0.0f64, 30.0, 90.0, 200.0] {
        let phi = phi_deg.to_radians();
        let a = directional_albedo_at(&b, 60f64.to_radians(), phi)[0];
        let want = 0.5 + 0.3 * phi.cos().powi(2);
        assert!((a - want).abs() < 1e-12, "φi {phi_deg}: {a} vs {want}");
    }
    // φi = 0 is the default.
    assert!((directional_albedo(&b, 0.5)[0] - 0.8).abs() < 1e-12);
    // Anisotropic sources are reported at φi = 0 and 90°; the max is 0.8.
    let r = props(
        &b,
        &PropsOptions {
            seed: 1,
            samples: 1000,
        },
    );
    assert_eq!(r.albedo.len(), 32);
    assert!(
        r.albedo
            .iter()
            .any(|row| row.phi_i_deg == 90.0 && (row.albedo[0] - 0.5).abs() < 1e-12)
    );
    assert!((r.energy.max_albedo - 0.8).abs() < 1e-12);
    assert!(!r.isotropy.holds && !r.isotropy.promised);
    assert!(r.failures.is_empty(), "{:?}", r.failures);
}

#[test]
fn discontinuous_source_error_is_covered_by_the_estimate() {
    // A jump inside the domain defeats any fixed rule: measured errors reach 9.5e-3 (θc 45°,
    // normal incidence). The promise is an honest estimate, not 1e-4.
    for theta_c_deg in [30.0f64, 45.0, 70.0] {
        let theta_c = theta_c_deg.to_radians();
        let b = Cutoff {
            channels: Channels::default_for(1),
            cos_cut: theta_c.cos(),
        };
        for theta_i_deg in [0.0f64, 40.0, 80.0] {
            let e = albedo_estimate(&b, theta_i_deg.to_radians(), 0.0);
            let err = (e.value[0] - theta_c.sin().powi(2)).abs();
            assert!(
                err <= e.error[0].max(1e-12) && err < 1e-2,
                "θc {theta_c_deg} θi {theta_i_deg}: {err:e} > {:e}",
                e.error[0]
            );
        }
    }
}

/// A table-like source: f(θo) linear between 10 nodes in θo (a continuous function with
/// kinks, like a linearly interpolated table).
struct LinearTable {
    channels: Channels,
    values: [f64; 10],
}

impl LinearTable {
    fn at(&self, theta_o: f64) -> f64 {
        let x = (theta_o / (PI / 2.0) * 9.0).clamp(0.0, 9.0);
        let k = (x as usize).min(8);
        let t = x - k as f64;
        self.values[k] * (1.0 - t) + self.values[k + 1] * t
    }
    /// 2π ∫ f(θo) cos θo sin θo dθo, Gauss–Legendre on each linear piece (exact to rounding:
    /// 20 nodes for a linear function times sin 2θo / 2 on a piece of 10°).
    fn albedo(&self) -> f64 {
        let (x, w): (Vec<f64>, Vec<f64>) = brdfpack_gl(20);
        let h = PI / 2.0 / 9.0;
        let mut sum = 0.0;
        for k in 0..9 {
            for (x, w) in x.iter().zip(&w) {
                let t = k as f64 * h + 0.5 * h * (x + 1.0);
                sum += w * 0.5 * h * self.at(t) * t.cos() * t.sin();
            }
        }
        2.0 * PI * sum
    }
}

/// Gauss–Legendre nodes by Newton's method (independent of the crate's, for the reference).
fn brdfpack_gl(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut xs = Vec::new();
    let mut ws = Vec::new();
    for i in 0..n {
        let mut z = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..50 {
            let (mut p0, mut p1) = (1.0, z);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            dp = n as f64 * (z * p1 - p0) / (z * z - 1.0);
            z -= p1 / dp;
        }
        xs.push(z);
        ws.push(2.0 / ((1.0 - z * z) * dp * dp));
    }
    (xs, ws)
}

impl Brdf for LinearTable {
    fn channels(&self) -> &Channels {
        &self.channels
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        out[0] = if wi.z > 0.0 && wo.z > 0.0 {
            self.at(wo.theta())
        } else {
            0.0
        };
    }
    fn is_isotropic(&self) -> bool {
        true
    }
    fn describe(&self) -> String {
        "linear table".into()
    }
}

#[test]
fn tabulated_smooth_source_meets_the_tolerance() {
    // A smooth function tabulated on 10 θo nodes (10° apart) and interpolated linearly:
    // kinks of the size a real table has. Measured worst error 1.1e-5 (docs/props.md). At
    // kinks the error estimate is an order of magnitude, not a bound (measured up to 1.2× low).
    let mut values = [0.0; 10];
    for (k, v) in values.iter_mut().enumerate() {
        let t = k as f64 * 10f64.to_radians();
        *v = 0.3 + 0.2 * (3.0 * t).cos();
    }
    let b = LinearTable {
        channels: Channels::default_for(1),
        values,
    };
    let want = b.albedo();
    for theta_i_deg in [0.0f64, 30.0, 60.0, 85.0] {
        let e = albedo_estimate(&b, theta_i_deg.to_radians(), 0.0);
        let err = (e.value[0] - want).abs();
        assert!(
            err < 1e-4,
            "θi {theta_i_deg}: {} vs {want} (est {:e})",
            e.value[0],
            e.error[0]
        );
        assert!(
            err <= 2.0 * e.error[0].max(1e-12),
            "θi {theta_i_deg}: {err:e} > est {:e}",
            e.error[0]
        );
    }
}

#[test]
fn harshly_kinked_source_error_is_covered_by_the_estimate() {
    // Random-looking values 10° apart: slope changes of 0.7 per node. Measured worst error
    // 1.4e-4 (θi 85°), above the 1e-4 of smooth sources; the estimate is within 5× of it
    // (4.6× low at θi 30°: both rules see the same kinks).
    let b = LinearTable {
        channels: Channels::default_for(1),
        values: [0.9, 0.2, 0.7, 0.1, 0.5, 0.05, 0.3, 0.6, 0.0, 0.4],
    };
    let want = b.albedo();
    for theta_i_deg in [0.0f64, 30.0, 60.0, 85.0] {
        let e = albedo_estimate(&b, theta_i_deg.to_radians(), 0.0);
        let err = (e.value[0] - want).abs();
        assert!(
            err <= 5.0 * e.error[0] && err < 2e-4,
            "θi {theta_i_deg}: {err:e}, est {:e}",
            e.error[0]
        );
    }
}

#[test]
fn faulty_source_is_reported_not_propagated() {
    let b = Faulty(Channels::default_for(1));
    let a = directional_albedo(&b, 0.3)[0];
    assert!(a.is_finite() && a > 0.0 && a < 1.0, "{a}");
    let r = props(
        &b,
        &PropsOptions {
            seed: 2,
            samples: 1000,
        },
    );
    assert!(r.positivity.nonfinite > 0);
    assert!(r.positivity.min_value.is_finite());
    assert!(!r.failures.is_empty());
    // The report serializes (no NaN reaches the JSON).
    let json = serde_json::to_string(&r).unwrap();
    assert!(!json.contains("NaN") && !json.contains("null"), "{json}");
    let _ = PI;
}

#[test]
#[ignore]
fn print_cutoff_errors() {
    let mut smooth = [0.0; 10];
    for (k, v) in smooth.iter_mut().enumerate() {
        *v = 0.3 + 0.2 * (3.0 * k as f64 * 10f64.to_radians()).cos();
    }
    let harsh = [0.9, 0.2, 0.7, 0.1, 0.5, 0.05, 0.3, 0.6, 0.0, 0.4];
    for (theta_i_deg, values) in [0.0f64, 30.0, 60.0, 85.0]
        .into_iter()
        .flat_map(|t| [(t, smooth), (t, harsh)])
    {
        let t = LinearTable {
            channels: Channels::default_for(1),
            values,
        };
        let e = albedo_estimate(&t, theta_i_deg.to_radians(), 0.0);
        println!(
            "table θi {theta_i_deg}: err {:.2e} est {:.2e} evals {}",
            e.value[0] - t.albedo(),
            e.error[0],
            e.evaluations
        );
    }
    for theta_c_deg in [30.0f64, 45.0, 70.0] {
        let theta_c = theta_c_deg.to_radians();
        let b = Cutoff {
            channels: Channels::default_for(1),
            cos_cut: theta_c.cos(),
        };
        for theta_i_deg in [0.0f64, 40.0, 80.0] {
            let e = albedo_estimate(&b, theta_i_deg.to_radians(), 0.0);
            let want = theta_c.sin().powi(2);
            println!(
                "θc {theta_c_deg} θi {theta_i_deg}: err {:.2e} est {:.2e} evals {}",
                e.value[0] - want,
                e.error[0],
                e.evaluations
            );
        }
    }
}
