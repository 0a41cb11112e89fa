//! Where the log error of an RGL file lies (docs/rgl.md, "The horizon between slices").
//!
//! `cargo run --release --example rgl_horizon_probe -- FILE SOURCE [N] [SEED] [ZMAX]`
//!
//! 1. `brdfpack check`'s uniform set (N pairs, SEED): log_rmse, its squared error binned by θo
//!    (and whether the file reads high or low), the 12 worst pairs (`LOWO=1`: of those with
//!    θo < 89°).
//! 2. An estimate of the expected log_rmse with little variance: 20·N pairs with wo.z uniform
//!    in [0, ZMAX] (default 0.02) give the band's share of the mean squared error, the uniform
//!    set the rest; the band's error binned by where wi lies between the θi (φi) slices and by
//!    θi. `SNAP=1` puts every wi of the band on its nearest slice (the slices' blend is then
//!    out of play).
use brdfpack::geometry::Vec3;
use brdfpack::io::rgl::RglBsdf;
use brdfpack::math::SplitMix64;
use rayon::prelude::*;

fn le2(file: &RglBsdf, src: &dyn brdfpack::brdf::Brdf, wi: Vec3, wo: Vec3) -> (f64, f64, f64) {
    use brdfpack::brdf::Brdf;
    let mut a = [0.0; 3];
    let mut b = [0.0; 3];
    file.eval(wi, wo, &mut a);
    src.eval(wi, wo, &mut b);
    let mut s = 0.0;
    for c in 0..3 {
        let e = brdfpack::check::log_error(b[c], a[c], wi.z);
        s += e * e;
    }
    (s / 3.0, a[1], b[1])
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let file = RglBsdf::open(&args[1]).unwrap();
    let src = brdfpack::source::open_brdf(&args[2]).unwrap();
    let n: usize = args.get(3).map(|s| s.parse().unwrap()).unwrap_or(100000);
    let seed: u64 = args.get(4).map(|s| s.parse().unwrap()).unwrap_or(1);
    let zmax: f64 = args.get(5).map(|s| s.parse().unwrap()).unwrap_or(0.02);
    let theta_i = file.info().theta_i.clone();
    let nphi = file.info().phi_slices;
    // 1. check's uniform set.
    let pairs: Vec<(Vec3, Vec3)> = brdfpack::check::uniform_pairs(seed).take(n).collect();
    let errs: Vec<(f64, f64, f64)> = pairs
        .par_iter()
        .map(|&(wi, wo)| le2(&file, &*src, wi, wo))
        .collect();
    let total: f64 = errs.iter().map(|e| e.0).sum();
    println!(
        "uniform n={n} seed={seed}: log_rmse {:.5}",
        (total / n as f64).sqrt()
    );
    let bins_o = [0.0, 80.0, 88.0, 89.0, 89.5, 89.7, 89.9, 89.97, 89.99, 90.0];
    let mut acc = vec![(0.0, 0usize, 0.0, 0.0); bins_o.len() - 1];
    for (&(_wi, wo), e) in pairs.iter().zip(&errs) {
        let t = wo.z.acos().to_degrees();
        let b = bins_o
            .windows(2)
            .position(|w| t >= w[0] && t < w[1])
            .unwrap_or(bins_o.len() - 2);
        acc[b].0 += e.0;
        acc[b].1 += 1;
        if e.1 > e.2 {
            acc[b].2 += e.0
        } else {
            acc[b].3 += e.0
        }
    }
    for (b, a) in acc.iter().enumerate() {
        println!(
            "  θo {:>6}-{:<6} n {:>6} share {:.3}  (high {:.3} low {:.3})",
            bins_o[b],
            bins_o[b + 1],
            a.1,
            a.0 / total,
            a.2 / total,
            a.3 / total
        );
    }
    // Top pairs.
    let mut idx: Vec<usize> = (0..n).collect();
    idx.sort_by(|&a, &b| errs[b].0.partial_cmp(&errs[a].0).unwrap());
    let pick: Vec<usize> = idx
        .iter()
        .copied()
        .filter(|&k| std::env::var_os("LOWO").is_none() || pairs[k].1.z > 0.0175)
        .take(12)
        .collect();
    for &k in pick.iter() {
        let (wi, wo) = pairs[k];
        println!(
            "  top: share {:.3} θi {:.2} φi {:.1} θo {:.4} φo {:.1}  read {:.4e} true {:.4e}",
            errs[k].0 / total,
            wi.z.acos().to_degrees(),
            wi.y.atan2(wi.x).to_degrees(),
            wo.z.acos().to_degrees(),
            wo.y.atan2(wo.x).to_degrees(),
            errs[k].1,
            errs[k].2
        );
    }
    // 2. Horizon band: wo.z uniform in [0, zmax], 20 n pairs, contribution to the mean.
    let m = 20 * n;
    let mut rng = SplitMix64::new(seed ^ 0xabcdef);
    let band: Vec<(Vec3, Vec3)> = (0..m)
        .map(|_| {
            let z = rng.next_f64();
            let p = 2.0 * std::f64::consts::PI * rng.next_f64();
            let r = (1.0 - z * z).sqrt();
            let mut wi = Vec3::new(r * p.cos(), r * p.sin(), z);
            if std::env::var_os("SNAP").is_some() {
                let t = z.acos();
                let ts = theta_i
                    .iter()
                    .cloned()
                    .min_by(|a, b| (a - t).abs().partial_cmp(&(b - t).abs()).unwrap())
                    .unwrap();
                let step = 2.0 * std::f64::consts::PI / (nphi.max(2) - 1) as f64;
                let ps = if nphi > 1 {
                    ((p + std::f64::consts::PI) / step).round() * step - std::f64::consts::PI
                } else {
                    p
                };
                let ps = (ps as f32) as f64;
                wi = Vec3::from_spherical(ts, ps + 1e-9);
            }
            let z = zmax * rng.next_f64();
            let p = 2.0 * std::f64::consts::PI * rng.next_f64();
            let r = (1.0 - z * z).sqrt();
            (wi, Vec3::new(r * p.cos(), r * p.sin(), z))
        })
        .collect();
    let be: Vec<(f64, f64, f64)> = band
        .par_iter()
        .map(|&(wi, wo)| le2(&file, &*src, wi, wo))
        .collect();
    let band_mean: f64 = be.iter().map(|e| e.0).sum::<f64>() / m as f64 * zmax;
    let rest: f64 = pairs
        .iter()
        .zip(&errs)
        .filter(|(p, _)| p.1.z >= zmax)
        .map(|(_, e)| e.0)
        .sum::<f64>()
        / n as f64;
    println!(
        "expected: band(z<{zmax}) {:.3e} + rest {:.3e} → log_rmse {:.5} (rest alone {:.5})",
        band_mean,
        rest,
        (band_mean + rest).sqrt(),
        rest.sqrt()
    );
    let (mut hi, mut lo) = (0.0, 0.0);
    for e in &be {
        if e.1 > e.2 { hi += e.0 } else { lo += e.0 }
    }
    println!(
        "  band: read high {:.3} low {:.3}",
        hi / (hi + lo),
        lo / (hi + lo)
    );
    // Binned by θi slice fraction and φi slice fraction (band only).
    let frac = |v: f64, axis: &[f64]| -> (usize, f64) {
        let k = axis
            .windows(2)
            .position(|w| v <= w[1])
            .unwrap_or(axis.len().saturating_sub(2));
        if axis.len() < 2 {
            return (0, 0.0);
        }
        (k, ((v - axis[k]) / (axis[k + 1] - axis[k])).clamp(0.0, 1.0))
    };
    let phis: Vec<f64> = (0..nphi.max(2))
        .map(|p| {
            -std::f64::consts::PI + 2.0 * std::f64::consts::PI * p as f64 / (nphi.max(2) - 1) as f64
        })
        .collect();
    let mut by_ti = [0.0; 10];
    let mut by_pf = [0.0; 10];
    let mut by_tdeg = [0.0; 9];
    let mut tot = 0.0;
    for (&(wi, _), e) in band.iter().zip(&be) {
        let t = wi.z.acos();
        let (_, ft) = frac(t, &theta_i);
        let (_, fp) = frac(wi.y.atan2(wi.x), &phis);
        by_ti[((ft * 10.0) as usize).min(9)] += e.0;
        by_pf[((fp * 10.0) as usize).min(9)] += e.0;
        by_tdeg[((t.to_degrees() / 10.0) as usize).min(8)] += e.0;
        tot += e.0;
    }
    let shares = |bins: &[f64]| {
        bins.iter()
            .map(|v| format!("{:.3}", v / tot))
            .collect::<Vec<_>>()
            .join(" ")
    };
    println!("  band by θi frac : {}", shares(&by_ti));
    println!("  band by φi frac : {}", shares(&by_pf));
    println!("  band by θi 10°  : {}", shares(&by_tdeg));
}
