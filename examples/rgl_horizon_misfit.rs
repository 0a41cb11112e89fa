//! Where an RGL file's interpolant of f·cos θo reaches 0 next to the horizon (docs/rgl.md,
//! "The horizon tail").
//!
//! `cargo run --release --example rgl_horizon_misfit -- FILE SOURCE [N] [SEED]`
//!
//! For N queries (wi uniform over the hemisphere, the azimuth of wo uniform) the height z* of
//! wo at which Mitsuba's eval (f·cos θo, read by brdfpack's reader) reaches 0: z* < 0 when the
//! interpolant is still positive at the horizon (eval / wo.z then grows like 1/wo.z: the file
//! reads high without bound), z* > 0 when it is 0 already above the horizon (the file reads 0
//! there: a bounded error). Each query's expected squared log error over wo.z in [0, 0.02]
//! (the band of the uniform set, by quadrature in log wo.z) is summed by the sign of z* and by
//! θi; the expected number of pairs per 100,000 uniform pairs whose squared log error exceeds
//! 1, 4 and 9 is the tail that one sample set may or may not draw. `SNAP=1` puts wi on its
//! nearest θi slice.
use brdfpack::brdf::Brdf;
use brdfpack::geometry::Vec3;
use brdfpack::io::rgl::RglBsdf;
use brdfpack::math::SplitMix64;
use rayon::prelude::*;

const ZMAX: f64 = 0.02;

fn wo_at(phi: f64, z: f64) -> Vec3 {
    let r = (1.0 - z * z).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let file = RglBsdf::open(&args[1]).unwrap();
    let src = brdfpack::source::open_brdf(&args[2]).unwrap();
    let n: usize = args.get(3).map(|s| s.parse().unwrap()).unwrap_or(20000);
    let seed: u64 = args.get(4).map(|s| s.parse().unwrap()).unwrap_or(1);
    let theta_i = file.info().theta_i.clone();
    let snap = std::env::var_os("SNAP").is_some();
    let mut rng = SplitMix64::new(seed ^ 0x5eed);
    let queries: Vec<(Vec3, f64)> = (0..n)
        .map(|_| {
            let z = rng.next_f64();
            let p = 2.0 * std::f64::consts::PI * rng.next_f64();
            let mut wi = wo_at(p, z);
            if snap {
                let t = z.acos();
                let ts = theta_i
                    .iter()
                    .cloned()
                    .min_by(|a, b| (a - t).abs().partial_cmp(&(b - t).abs()).unwrap())
                    .unwrap();
                wi = Vec3::from_spherical((ts as f32) as f64, p);
            }
            let mut phi_o = 2.0 * std::f64::consts::PI * rng.next_f64();
            if std::env::var_os("ROWSNAP").is_some() {
                // wo on the horizon whose half vector lies on the nearest VNDF row (isotropic
                // files: rows over φm − φi, 128 of them over [−π, π]).
                let (t, pi) = (wi.z.acos(), wi.y.atan2(wi.x));
                let m0 = (wi + wo_at(phi_o, 0.0)).try_normalize().unwrap();
                let d = m0.y.atan2(m0.x) - pi;
                let step = 2.0 * std::f64::consts::PI / 127.0;
                let d = ((d + std::f64::consts::PI) / step).round() * step - std::f64::consts::PI;
                let two_tm = t.cos().atan2(-t.sin() * d.cos());
                let m = Vec3::from_spherical(0.5 * two_tm, pi + d);
                let wo = m * (2.0 * wi.dot(m)) - wi;
                phi_o = wo.y.atan2(wo.x);
            }
            (wi, phi_o)
        })
        .collect();
    // Log-spaced quadrature of wo.z over [1e-9, ZMAX] (trapezoids in ln z).
    let nq = 240;
    let zs: Vec<f64> = (0..nq)
        .map(|k| 1e-9 * (ZMAX / 1e-9f64).powf(k as f64 / (nq - 1) as f64))
        .collect();
    let thresholds = [1.0, 4.0, 9.0];
    let res: Vec<(f64, f64, [f64; 3], f64, f64)> = queries
        .par_iter()
        .map(|&(wi, phi)| {
            let mut a = [0.0; 3];
            let mut b = [0.0; 3];
            let err2 = |z: f64, a: &mut [f64; 3], b: &mut [f64; 3]| {
                let wo = wo_at(phi, z);
                file.eval(wi, wo, a);
                src.eval(wi, wo, b);
                (0..3)
                    .map(|c| brdfpack::check::log_error(b[c], a[c], wi.z).powi(2))
                    .sum::<f64>()
                    / 3.0
            };
            let e: Vec<f64> = zs.iter().map(|&z| err2(z, &mut a, &mut b)).collect();
            let mut loss = 0.0;
            let mut tail = [0.0; 3];
            for k in 1..nq {
                let dz = zs[k] - zs[k - 1];
                loss += 0.5 * (e[k] + e[k - 1]) * dz;
                for (t, th) in tail.iter_mut().zip(&thresholds) {
                    if e[k] > *th && e[k - 1] > *th {
                        *t += dz;
                    }
                }
            }
            // z*: the interpolant's zero.
            let mut c = [0.0; 3];
            file.eval_cosine(wi, wo_at(phi, 1e-9), &mut c);
            let g0 = c[1];
            file.eval_cosine(wi, wo_at(phi, 2e-3), &mut c);
            let g1 = c[1];
            let zstar = if g1 <= 0.0 {
                f64::NAN
            } else if g0 > 1e-12 * g1 {
                -g0 / ((g1 - g0) / 2e-3)
            } else {
                let (mut lo, mut hi) = (1e-9f64, 2e-3f64);
                for _ in 0..60 {
                    let mid = (lo * hi).sqrt();
                    file.eval_cosine(wi, wo_at(phi, mid), &mut c);
                    if c[1] > 1e-12 * g1 {
                        hi = mid
                    } else {
                        lo = mid
                    }
                }
                hi
            };
            let m = (wi + wo_at(phi, 0.0))
                .try_normalize()
                .unwrap_or(Vec3::new(0.0, 0.0, 1.0));
            let uq = (m.z.acos() / std::f64::consts::FRAC_PI_2).sqrt();
            (zstar, loss, tail, wi.z.acos().to_degrees(), uq)
        })
        .collect();
    let total: f64 = res.iter().map(|r| r.1).sum::<f64>() / n as f64;
    let (mut neg, mut pos) = (0.0, 0.0);
    let tb = [0.0, 60.0, 80.0, 85.0, 87.0, 88.0, 88.57, 89.5, 90.01];
    let mut by_t = [0.0; 8];
    let ub = [0.0, 0.5, 0.8, 0.9, 0.95, 0.98, 0.99213, 1.01];
    let mut by_u = [0.0; 7];
    let mut cnt_u = [0usize; 7];
    let mut tails = [0.0; 3];
    let mut zneg: Vec<f64> = Vec::new();
    let mut zpos: Vec<f64> = Vec::new();
    for r in &res {
        if r.0 < 0.0 {
            neg += r.1;
            zneg.push(-r.0);
        } else {
            pos += r.1;
            zpos.push(r.0);
        }
        by_t[tb
            .windows(2)
            .position(|w| r.3 >= w[0] && r.3 < w[1])
            .unwrap_or(7)] += r.1;
        let k = ub
            .windows(2)
            .position(|w| r.4 >= w[0] && r.4 < w[1])
            .unwrap_or(6);
        by_u[k] += r.1;
        cnt_u[k] += 1;
        for (t, v) in tails.iter_mut().zip(&r.2) {
            *t += v;
        }
    }
    let q = |v: &mut Vec<f64>, p: f64| -> f64 {
        if v.is_empty() {
            return 0.0;
        }
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        v[((v.len() - 1) as f64 * p) as usize]
    };
    println!(
        "band(z<{ZMAX}) mean sq log error {:.3e} (interpolant > 0 at the horizon: {:.3}, 0 above it: {:.3})",
        total,
        neg / n as f64 / total,
        pos / n as f64 / total
    );
    println!(
        "  z* < 0: {} queries, |z*| median {:.2e} p90 {:.2e} p99 {:.2e}; z* > 0: {}, median {:.2e} p90 {:.2e} p99 {:.2e}",
        zneg.len(),
        q(&mut zneg, 0.5),
        q(&mut zneg, 0.9),
        q(&mut zneg, 0.99),
        zpos.len(),
        q(&mut zpos, 0.5),
        q(&mut zpos, 0.9),
        q(&mut zpos, 0.99)
    );
    println!(
        "  pairs per 100k uniform with sq log error > 1 / 4 / 9: {:.2} / {:.2} / {:.2}",
        tails[0] / n as f64 * 1e5,
        tails[1] / n as f64 * 1e5,
        tails[2] / n as f64 * 1e5
    );
    println!(
        "  by θi 0/60/80/85/87/88/88.57/89.5/90: {}",
        by_t.iter()
            .map(|v| format!("{:.3}", v / n as f64 / total))
            .collect::<Vec<_>>()
            .join(" ")
    );
    for k in 0..7 {
        println!(
            "  u of the horizon half vector {:.3}-{:.3}: {} queries, share {:.3}",
            ub[k],
            ub[k + 1],
            cnt_u[k],
            by_u[k] / n as f64 / total
        );
    }
}
