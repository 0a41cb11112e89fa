//! Energy identities of the analytic models, through the props quadrature.

use brdfpack::model::Model;
use brdfpack::props::{albedo_angles_deg, directional_albedo};

#[test]
fn ggx_without_fresnel_never_reflects_more_than_it_receives() {
    // Fresnel `none` and correlated Smith G: the single-scattering albedo is ≤ 1 for every
    // roughness and incidence angle (the missing energy is multiple scattering).
    for alpha in [0.01, 0.03, 0.1, 0.3, 0.6, 1.0] {
        let m = Model::parse(&format!(
            "ggx:alpha={alpha},shadowing=smith-correlated,fresnel=none"
        ))
        .unwrap();
        let mut worst: f64 = 0.0;
        for deg in albedo_angles_deg() {
            let a = directional_albedo(&m, deg.to_radians())[0];
            assert!(a.is_finite() && a > 0.0, "α {alpha} θi {deg}: {a}");
            worst = worst.max(a);
        }
        // 1e-4 is the quadrature's accuracy target (docs/props.md).
        assert!(worst <= 1.0 + 1e-4, "α {alpha}: max albedo {worst}");
        // Smooth surfaces lose little to shadowing at normal incidence; rough ones lose more.
        let a0 = directional_albedo(&m, 0.0)[0];
        if alpha <= 0.1 {
            assert!(a0 > 0.98, "α {alpha}: albedo at normal incidence {a0}");
        }
    }
}

#[test]
fn lambert_albedo_is_rho_and_normalized_phong_stays_below_it() {
    let m = Model::parse("lambert:albedo=0.8/0.5/0.2").unwrap();
    for deg in albedo_angles_deg() {
        let a = directional_albedo(&m, deg.to_radians());
        for (got, rho) in a.iter().zip([0.8, 0.5, 0.2]) {
            assert!((got - rho).abs() < 1e-9, "θi {deg}: {got} vs {rho}");
        }
    }
    for n in [1.0, 10.0, 100.0, 1e4] {
        let m = Model::parse(&format!("phong:albedo=0.7,exponent={n},norm=energy")).unwrap();
        let a = directional_albedo(&m, 0.0)[0];
        assert!(a <= 0.7 + 1e-6, "n {n}: {a}");
        // At normal incidence no part of the lobe is cut by the horizon: exactly ρ.
        assert!((a - 0.7).abs() < 1e-4, "n {n}: {a}");
    }
}
