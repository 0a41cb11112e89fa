//! Round trips and invariants of the codec chain as a whole.

use super::*;
use crate::brdf::Channels;
use crate::grid::parse_grid_spec;
use crate::table::Provenance;

fn small_table() -> Table {
    let g = parse_grid_spec("halfdiff3:8x8x12").unwrap();
    let valid = g.geometric_mask();
    let n = g.cells();
    let data: Vec<f32> = (0..n * 3)
        .map(|i| {
            let f = i / 3;
            let (a, b, cc) = (f / 96, f / 12 % 8, f % 12);
            (0.1 + (a as f32 * 0.3).exp() * (1.0 + 0.1 * b as f32) + 0.01 * cc as f32)
                * (1.0 + 0.2 * (i % 3) as f32)
        })
        .collect();
    Table::new(
        g,
        Channels::default_for(3),
        Provenance::default(),
        data,
        valid,
    )
    .unwrap()
}

#[test]
fn a_reused_scratch_does_not_change_the_output() {
    // One scratch through tables of different sizes and specs (larger, then smaller, then
    // larger again): the arrays it hands out hold the previous decode's values, and none
    // may leak into the next.
    let small = small_table();
    let big = crate::tabulate::tabulate(
        &crate::testing::GgxConductor::new(0.3),
        &parse_grid_spec("halfdiff3:16x12x24").unwrap(),
        &crate::tabulate::TabulateOptions::default(),
    )
    .unwrap();
    let mut scratch = DecodeScratch::default();
    for (t, req) in [
        (&big, "dct:step=0.05"),
        (&small, "dct:step=0.05"),
        (&small, "dct:step=0.01,coding=zstd,level=3"),
        (&big, "dct:step=0.2,colour=none"),
        (&big, "dct:step=0.05"),
    ] {
        let spec = CodecRequest::parse(req).unwrap().resolve(t).unwrap();
        let payload = spec.encode(t).unwrap();
        let layout = Layout::of(t);
        let want = spec.decode(&payload, &layout).unwrap();
        let mut buf = vec![f32::NAN; want.len()];
        spec.decode_into_with(&payload, &layout, &mut buf, &mut scratch)
            .unwrap();
        assert!(
            buf.iter()
                .zip(&want)
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{req} on {:?}",
            t.grid().shape()
        );
    }
}

#[test]
fn decode_into_a_dirty_buffer_equals_decode() {
    // Every value must be written: a reused buffer full of NaN must not leak into the
    // result (invalid cells included).
    let t = small_table();
    assert!(t.valid().iter().any(|v| !v), "the grid has invalid cells");
    for req in [
        "zstd-f32",
        "lossless",
        "f16",
        "uniform:bits=10",
        "dct:step=0.05,coding=zstd,level=3",
        "dct:step=0.05",
        "dct:step=0.05,colour=none,curve=linear",
        "dct:step=0.05,residual=0.01",
        "dct:step=0.05,coding=zstd,residual=0.01",
        "tucker:ranks=4x4x6,residual=0.01",
    ] {
        let spec = CodecRequest::parse(req).unwrap().resolve(&t).unwrap();
        let payload = spec.encode(&t).unwrap();
        let layout = Layout::of(&t);
        let want = spec.decode(&payload, &layout).unwrap();
        let mut buf = vec![f32::NAN; want.len()];
        spec.decode_into(&payload, &layout, &mut buf).unwrap();
        assert_eq!(
            buf.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "{req}"
        );
        let mut short = vec![0f32; want.len() - 1];
        assert!(spec.decode_into(&payload, &layout, &mut short).is_err());
    }
}

#[test]
fn every_requested_codec_round_trips_through_its_header() {
    let t = small_table();
    for s in [
        "zstd-f32",
        "lossless",
        "lossless:predict=0.0.1,space=integer,cross=off,level=3",
        "f16",
        "f16:curve=linear",
        "uniform:bits=12",
        "uniform:bits=8,curve=linear,colour=none",
        "dct:step=0.001",
        "dct:step=0.01,curve=linear,colour=none",
        "dct:step=0.001,coding=zstd",
        "dct:step=0.01,coding=zstd,level=3,colour=none",
        "dct:step=0.002,deadzone=1.5,refine=3",
        "dct:step=0.01,coding=context,curve=linear,refine=1",
        "f16:weight=cosine",
        "uniform:bits=12,weight=cos",
        "dct:step=0.001,weight=cosine",
        "dct:step=0.001,weight=cosine,coding=zstd",
        "tucker:ranks=4x4x6,step=0.001",
        "tucker:ranks=8x8x12,step=0.01,curve=linear,colour=none,level=3",
        // Full rank: w·x is not as low-rank as x, so a truncation would say nothing of w.
        "tucker:ranks=8x8x12,step=0.001,weight=cosine",
        "dct:step=0.5,residual=0.01",
        "dct:step=0.5,coding=zstd,level=3,residual=0.02,curve=linear",
        "tucker:ranks=2x2x3,step=0.5,residual=0.01,colour=none",
        "dct:step=0.5,residual=0.005,weight=cosine",
    ] {
        let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
        let json = serde_json::to_string(&spec).unwrap();
        assert_eq!(
            json.contains(r#""curve":"cosine_"#),
            s.contains("weight"),
            "{s}"
        );
        let back: CodecSpec = serde_json::from_str(&json).unwrap();
        assert_eq!(back, spec, "{s}");
        let payload = spec.encode(&t).unwrap();
        let dec = back.decode(&payload, &Layout::of(&t)).unwrap();
        assert_eq!(dec.len(), t.data().len());
        for (cell, &ok) in t.valid().iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (dec[cell * 3 + k], t.data()[cell * 3 + k]);
                if !ok {
                    assert_eq!(a, 0.0, "{s}: invalid cell {cell} decodes to {a}");
                } else if spec.is_lossless() {
                    assert_eq!(a.to_bits(), b.to_bits(), "{s}");
                } else {
                    // Coarsest settings above: within 5% (uniform 8-bit linear on a
                    // range of ~15 is ±0.03 absolute). The weighted ones are fine
                    // settings of the log curve, whose errors stay relative down to ε/w.
                    assert!((a - b).abs() <= 0.05 * b + 0.04, "{s}: {a} vs {b}");
                }
            }
        }
    }
}

/// Decoded values of the fast decoders against `reference::decode`: bit for bit where
/// the chain is lossless, or quantized with the linear curve (no `exp`, same f64 maths);
/// else within 5e-5 relative to ε + x, i.e. a log-space error of 5e-5: the DCT's f32 sums
/// run in another order (rounding ≲ box terms × 2⁻²⁴ × the largest partial sum) and `exp`
/// is ≤ 1 ulp. That is 6× below the quantization noise of the finest step tested
/// (step/√12 = 2.9e-4 at step 1e-3).
fn assert_matches_reference(t: &Table, spec: &CodecSpec, what: &str) {
    let layout = Layout::of(t);
    let payload = spec.encode(t).unwrap();
    let fast = spec.decode(&payload, &layout).unwrap();
    let slow = reference::decode(spec, &payload, &layout).unwrap();
    assert_eq!(fast.len(), slow.len());
    let exact = spec.is_lossless();
    let curve = spec.transform().map(|t| &t.curve);
    let weights = spec
        .transform()
        .and_then(|t| t.cell_weights(layout.grid, layout.valid));
    let c = layout.channels;
    let scale = slow.iter().enumerate().fold(0f32, |m, (i, b)| {
        m.max(b.abs() * weights.as_ref().map_or(1.0, |w| w.at(i / c)) as f32)
    });
    for (i, (a, b)) in fast.iter().zip(&slow).enumerate() {
        // ε is in the units of the coded quantity w·x: ε/w in those of x.
        let w = weights.as_ref().map_or(1.0, |w| w.at(i / c)) as f32;
        let eps = match curve {
            Some(Curve::Log { eps } | Curve::SignedLog { eps }) => eps[i % c] as f32 / w,
            _ => 0.0,
        };
        let linear_quantized =
            matches!(curve, Some(Curve::Linear)) && matches!(spec, CodecSpec::Quantized { .. });
        if exact || (linear_quantized && weights.is_none()) {
            assert_eq!(a.to_bits(), b.to_bits(), "{what}: value {i}: {a} vs {b}");
        } else if linear_quantized {
            // 1/w: an f32 multiply by the rounded reciprocal against an f64 division,
            // after the f32 rounding of the dequantized value: ≤ 3 roundings of 2⁻²⁴.
            assert!(
                (a - b).abs() <= 2e-7 * b.abs() + f32::MIN_POSITIVE,
                "{what}: value {i}: {a} vs {b} (w {w})"
            );
        } else if weights.is_some() && matches!(curve, Some(Curve::Linear)) {
            // The DCT's f32 rounding is relative to the plane's largest values (as in
            // idct's tests, 1e-5 of the largest |w·x|), not to a small w·x at a grazing
            // cell; ÷ w in the units of x.
            assert!(
                (a - b).abs() <= 5e-5 * b.abs() + 1e-5 * scale / w + f32::MIN_POSITIVE,
                "{what}: value {i}: {a} vs {b} (w {w}, largest w·x {scale})"
            );
        } else {
            assert!(
                (a - b).abs() <= 5e-5 * (b.abs() + eps) + f32::MIN_POSITIVE,
                "{what}: value {i}: {a} vs {b} (ε {eps})"
            );
        }
    }
}

#[test]
fn fast_decoders_match_the_reference_decoder() {
    let t = small_table();
    for s in [
        "zstd-f32",
        "lossless",
        "lossless:predict=1.1.2,space=float,cross=on",
        "lossless:predict=0.0.1,space=integer,cross=off",
        "f16",
        "f16:curve=linear",
        "uniform:bits=12",
        "uniform:bits=10,curve=linear",
        "uniform:bits=10,curve=linear,colour=none",
        "dct:step=0.001",
        "dct:step=0.05",
        "dct:step=0.01,curve=linear,colour=none",
        "f16:weight=cosine",
        "f16:curve=linear,weight=cosine",
        "uniform:bits=12,weight=cosine",
        "uniform:bits=10,curve=linear,weight=cosine",
        "uniform:bits=10,curve=linear,colour=none,weight=cosine",
        "dct:step=0.001,weight=cosine",
        "dct:step=0.01,curve=linear,colour=none,weight=cosine,coding=zstd",
        "tucker:ranks=4x4x6,step=0.001",
        "tucker:ranks=8x8x12,step=0.05,curve=linear,colour=none",
        "dct:step=0.3,residual=0.003",
        "dct:step=0.3,coding=zstd,residual=0.003,weight=cosine",
        "dct:step=0.05,curve=linear,colour=none,residual=0.01",
        "tucker:ranks=2x2x3,step=0.3,residual=0.003",
    ] {
        let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
        assert_matches_reference(&t, &spec, s);
    }
}

/// [`small_table`] shifted down so that about a fifth of its valid values are negative,
/// as in a measured fit to noisy data.
fn signed_table() -> Table {
    let t = small_table();
    let data: Vec<f32> = t
        .data()
        .iter()
        .enumerate()
        .map(|(i, &v)| v - 2.5 + 0.3 * ((i * 7919 % 13) as f32 / 13.0))
        .collect();
    let valid = t.valid().to_vec();
    Table::new(
        t.grid().clone(),
        t.channels().clone(),
        t.provenance().clone(),
        data,
        valid,
    )
    .unwrap()
}

#[test]
fn the_signed_log_curve_keeps_negative_values() {
    let t = signed_table();
    let values: Vec<f32> = t
        .data()
        .chunks_exact(3)
        .zip(t.valid())
        .filter(|(_, ok)| **ok)
        .flat_map(|(v, _)| v.iter().copied())
        .collect();
    let negative = values.iter().filter(|&&v| v < 0.0).count();
    assert!(
        negative * 10 > values.len() && negative * 2 < values.len(),
        "{negative} of {} negative",
        values.len()
    );
    // Channel 0's mean |x| over valid cells: its ε is 1e-3 of that.
    let ch0: Vec<f64> = values.iter().step_by(3).map(|v| v.abs() as f64).collect();
    let mean_abs = ch0.iter().sum::<f64>() / ch0.len() as f64;
    for s in [
        "f16:curve=signed-log",
        "uniform:bits=12,curve=signed-log",
        "dct:step=0.002,curve=signed-log",
        "dct:step=0.002,curve=signed-log,coding=zstd,colour=none",
        "dct:step=0.002,curve=signed-log,weight=cosine",
        "tucker:ranks=8x8x12,step=0.002,curve=signed-log",
        "dct:step=0.3,curve=signed-log,residual=0.003",
    ] {
        let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
        let json = serde_json::to_string(&spec).unwrap();
        assert!(json.contains("signed_log"), "{s}: {json}");
        let back: CodecSpec = serde_json::from_str(&json).unwrap();
        assert_eq!(back, spec, "{s}");
        let text = CodecRequest::parse(s).unwrap().to_string();
        assert!(text.contains("curve=signed-log"), "{s}: {text}");
        let tr = spec.transform().unwrap();
        let eps = tr.curve.eps().unwrap()[0];
        // The curve's ε is in the units of w·x: ε/w in those of x.
        let w = tr.cell_weights(t.grid(), t.valid());
        if w.is_none() {
            // ε relative to the mean |x| (the default 1e-3), not to the mean x.
            assert!((eps / (1e-3 * mean_abs) - 1.0).abs() < 1e-6, "{s}: ε {eps}");
        }
        let payload = spec.encode(&t).unwrap();
        let dec = back.decode(&payload, &Layout::of(&t)).unwrap();
        let mut worst = 0f64;
        for (cell, &ok) in t.valid().iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (dec[cell * 3 + k] as f64, t.data()[cell * 3 + k] as f64);
                if !ok {
                    assert_eq!(a, 0.0, "{s}: invalid cell {cell}");
                    continue;
                }
                // Relative to |x| + ε on both sides of 0: the steps above are fine ones.
                let eps = eps / w.as_ref().map_or(1.0, |w| w.at(cell));
                let rel = (a - b).abs() / (b.abs() + eps);
                worst = worst.max(rel);
                assert!(rel <= 0.05, "{s}: cell {cell}: {a} vs {b} (ε {eps})");
                if b.abs() > 10.0 * eps {
                    assert_eq!(a < 0.0, b < 0.0, "{s}: cell {cell}: {a} vs {b}");
                }
            }
        }
        assert_matches_reference(&t, &spec, s);
        eprintln!("{s}: worst relative error {worst:.2e}");
    }
    // The log curve clamps them at 0: a relative error of 1 at every negative value.
    let spec = CodecRequest::parse("dct:step=0.002")
        .unwrap()
        .resolve(&t)
        .unwrap();
    let dec = spec
        .decode(&spec.encode(&t).unwrap(), &Layout::of(&t))
        .unwrap();
    assert!(dec.iter().all(|&v| v >= 0.0));
}

/// A random `halfdiff3:a×b×cc` table (1 or 3 channels): 5% zeros, the rest spread over
/// 18 e-folds, below-horizon cells invalid.
fn random_table(a: usize, b: usize, cc: usize, three: bool, seed: u64) -> Table {
    let g = parse_grid_spec(&format!("halfdiff3:{a}x{b}x{cc}")).unwrap();
    let valid = g.geometric_mask();
    let c = if three { 3 } else { 1 };
    let mut rng = crate::math::SplitMix64::new(seed);
    let data: Vec<f32> = (0..g.cells() * c)
        .map(|_| {
            let u = rng.next_f64();
            if u < 0.05 {
                0.0
            } else {
                (u * 18.0 - 9.0).exp() as f32
            }
        })
        .collect();
    Table::new(
        g,
        Channels::default_for(c),
        Provenance::default(),
        data,
        valid,
    )
    .unwrap()
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
    /// Random tables (grid sizes, 1 or 3 channels, magnitudes over 8 decades, zeros):
    /// every chain decodes like the reference.
    #[test]
    fn random_tables_decode_like_the_reference(
        a in 2usize..9, b in 2usize..9, cc in 2usize..13, three in proptest::bool::ANY,
        seed in proptest::prelude::any::<u64>(), which in 0usize..12,
    ) {
        let t = random_table(a, b, cc, three, seed);
        let s = [
            "lossless", "f16", "uniform:bits=14", "dct:step=0.003", "dct:step=0.1",
            "f16:weight=cosine", "uniform:bits=14,weight=cosine",
            "dct:step=0.003,weight=cosine",
            "tucker:ranks=2x2x2,step=0.003", "tucker:ranks=2x2x2,step=0.1,factor=4",
            "dct:step=0.3,residual=0.003", "tucker:ranks=1x1x1,step=0.3,residual=0.01",
        ][which];
        let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
        assert_matches_reference(&t, &spec, s);
    }
}

#[test]
fn uniform_meets_its_stated_max_error() {
    let t = small_table();
    let spec = CodecRequest::parse("uniform:bits=10")
        .unwrap()
        .resolve(&t)
        .unwrap();
    let bound = spec.max_transformed_error().unwrap();
    let dec = spec
        .decode(&spec.encode(&t).unwrap(), &Layout::of(&t))
        .unwrap();
    let CodecSpec::Quantized { transform, .. } = &spec else {
        panic!()
    };
    for (cell, &ok) in t.valid().iter().enumerate() {
        if ok {
            for k in 0..3 {
                let a = transform.curve.forward(dec[cell * 3 + k] as f64, k);
                let b = transform.curve.forward(t.data()[cell * 3 + k] as f64, k);
                // f32 storage of the decoded value adds ~1e-7 relative.
                assert!((a - b).abs() <= bound + 1e-6, "{a} {b} {bound}");
            }
        }
    }
}

/// The largest error of a decoded table against its source, per channel in the curve
/// space y = curve(w·x) (the space `max_transformed_error` speaks of), relative to the
/// stated bound plus the decoder's f32 rounding: the plane value and the sum Mᵀz in f32,
/// `exp_f32` (1 ulp) and the f32 x, × 1/w in f32. Each is a few 2⁻²⁴ of |y| or of the
/// cell's ‖z‖; 5e-7 × (2 + |y| + ‖z‖) covers them with a margin of about 2. The clamp at
/// x ≥ 0 only moves a decoded y towards the true one (y ≥ ln ε, resp. ≥ 0), never away.
/// Returns the largest error / bound over valid cells (invalid cells must decode to 0).
fn residual_error_ratio(t: &Table, spec: &CodecSpec, what: &str) -> f64 {
    let c = t.channels().len();
    let bound = spec.max_transformed_error().unwrap();
    let tr = spec.transform().unwrap();
    let dec = spec
        .decode(&spec.encode(t).unwrap(), &Layout::of(t))
        .unwrap();
    let curve_only = Transform {
        colour: None,
        ..tr.clone()
    };
    let ya = curve_only.forward_all(&dec, c, t.grid(), t.valid());
    let yb = curve_only.forward_all(t.data(), c, t.grid(), t.valid());
    let zb = tr.forward_all(t.data(), c, t.grid(), t.valid());
    let mut worst = 0f64;
    for (f, &ok) in t.valid().iter().enumerate() {
        let cell = f * c..(f + 1) * c;
        if !ok {
            assert!(
                dec[cell].iter().all(|&v| v == 0.0),
                "{what}: invalid cell {f}"
            );
            continue;
        }
        let norm = zb[cell.clone()].iter().map(|v| v * v).sum::<f64>().sqrt();
        for i in cell {
            assert!(dec[i].is_finite() && dec[i] >= 0.0, "{what}: value {i}");
            let err = (ya[i] - yb[i]).abs();
            let tol = bound * (1.0 + 1e-12) + 5e-7 * (2.0 + yb[i].abs() + norm);
            assert!(
                err <= tol,
                "{what}: value {i}: y {} decoded {} (error {err:e}, bound {bound:e})",
                yb[i],
                ya[i]
            );
            worst = worst.max(err / bound);
        }
    }
    worst
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(32))]
    /// Random tables (grid sizes, 1 or 3 channels, magnitudes over 8 decades, zeros),
    /// random residual steps, every chain that takes a residual, both curves, with and
    /// without colour and weight: every decoded valid value within the stated
    /// `max_transformed_error` (Σ_i |M_ik| S/2 per channel, S/2 without colour) plus the
    /// f32 rounding of [`residual_error_ratio`].
    #[test]
    fn residual_chains_meet_their_stated_bound_on_random_tables(
        a in 2usize..9, b in 2usize..9, cc in 2usize..13, three in proptest::bool::ANY,
        seed in proptest::prelude::any::<u64>(), which in 0usize..6,
        log_s in -3.0f64..-0.5, lossy_step in 0.05f64..2.0,
    ) {
        let t = random_table(a, b, cc, three, seed);
        let s = 10f64.powf(log_s);
        let req = [
            format!("dct:step={lossy_step},residual={s}"),
            format!("dct:step={lossy_step},coding=zstd,colour=none,residual={s}"),
            format!("dct:step={lossy_step},weight=cosine,residual={s}"),
            // Linear: values up to e^9 ≈ 8e3, the step scaled to that range.
            format!("dct:step={},curve=linear,residual={}", lossy_step * 100.0, s * 10.0),
            format!("tucker:ranks=2x1x2,step={lossy_step},residual={s}"),
            format!("tucker:ranks=1x2x2,step={lossy_step},colour=none,curve=linear,residual={}", s * 10.0),
        ][which].clone();
        let spec = CodecRequest::parse(&req).unwrap().resolve(&t).unwrap();
        residual_error_ratio(&t, &spec, &req);
    }
}

/// The bound is tight, not vacuous: on a table with many cells the largest error comes
/// close to S/2 without colour (and to a good part of Σ|M_ik| S/2 with it), while the DCT
/// alone at that step is far outside it.
#[test]
fn residual_bound_is_reached_and_the_dct_alone_misses_it() {
    let t = ggx_on("halfdiff3:12x10x16");
    for (s, at_least) in [
        ("dct:step=0.5,colour=none,residual=0.01", 0.9),
        ("dct:step=0.5,residual=0.01", 0.5),
        ("dct:step=0.5,coding=zstd,residual=0.002", 0.5),
        ("tucker:ranks=3x3x3,step=0.5,residual=0.01", 0.5),
    ] {
        let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
        let r = residual_error_ratio(&t, &spec, s);
        assert!(r >= at_least && r <= 1.0 + 1e-6, "{s}: error/bound {r}");
    }
    // Without the residual the same DCT is off by far more than S/2 = 0.005 somewhere.
    let plain = CodecRequest::parse("dct:step=0.5")
        .unwrap()
        .resolve(&t)
        .unwrap();
    let dec = plain
        .decode(&plain.encode(&t).unwrap(), &Layout::of(&t))
        .unwrap();
    let tr = plain.transform().unwrap();
    let ya = tr.forward_all(&dec, 3, t.grid(), t.valid());
    let yb = tr.forward_all(t.data(), 3, t.grid(), t.valid());
    let worst = (0..t.grid().cells())
        .filter(|&f| t.valid()[f])
        .flat_map(|f| (0..3).map(move |k| f * 3 + k))
        .map(|i| (ya[i] - yb[i]).abs())
        .fold(0f64, f64::max);
    assert!(worst > 0.05, "{worst}");
}

/// A residual file cut anywhere, with its section length or steps edited, or decoded with
/// the spec of the chain without the residual: an error, never a panic or a silent
/// partial decode.
#[test]
fn hostile_residual_payloads_and_headers_are_errors() {
    let t = small_table();
    let layout = Layout::of(&t);
    for s in [
        "dct:step=0.1,residual=0.01",
        "dct:step=0.1,coding=zstd,residual=0.01",
        "tucker:ranks=4x4x6,step=0.1,residual=0.01",
    ] {
        let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
        let payload = spec.encode(&t).unwrap();
        let (lossy, section) = residual::split(&payload).unwrap();
        assert!(!lossy.is_empty() && !section.is_empty(), "{s}");
        let mut cuts: Vec<usize> = (0..12).collect();
        cuts.extend([
            8 + lossy.len() - 1,
            8 + lossy.len(),
            8 + lossy.len() + 1,
            payload.len() / 2,
            payload.len() - 1,
        ]);
        for cut in cuts {
            let e = spec.decode(&payload[..cut], &layout);
            assert!(e.is_err(), "{s}: cut {cut} of {}", payload.len());
            assert!(reference::decode(&spec, &payload[..cut], &layout).is_err());
        }
        // The section length pointing past the end, or short by one byte.
        for len in [u64::MAX, payload.len() as u64, lossy.len() as u64 - 1] {
            let mut bad = payload.clone();
            bad[..8].copy_from_slice(&len.to_le_bytes());
            assert!(spec.decode(&bad, &layout).is_err(), "{s}: length {len}");
        }
        // Hostile residual stages in the header.
        let edits: [fn(&mut residual::ResidualStage); 4] = [
            |r| r.step = vec![0.01; 2],
            |r| r.step[1] = f64::NAN,
            |r| r.step[0] = -1.0,
            |r| r.predict.orders = vec![0, 0],
        ];
        for (i, edit) in edits.iter().enumerate() {
            let mut bad = spec.clone();
            edit(bad.residual_mut().expect("a residual spec"));
            let e = bad.decode(&payload, &layout).unwrap_err().to_string();
            assert!(e.contains("residual"), "{s} edit {i}: {e}");
            assert!(bad.encode(&t).is_err(), "{s} edit {i}");
        }
        // The plain chain given a residual payload (or the reverse) fails too.
        let mut plain = spec.clone();
        match &mut plain {
            CodecSpec::Dct { residual, .. }
            | CodecSpec::DctContext { residual, .. }
            | CodecSpec::Tucker { residual, .. } => *residual = None,
            _ => unreachable!(),
        }
        assert!(
            spec.decode(&plain.encode(&t).unwrap(), &layout).is_err(),
            "{s}"
        );
    }
    // A step too fine for the table: an error naming the step, not a wrap (at resolve,
    // which tries the residual predictors, and at encode).
    let req = CodecRequest::parse("dct:step=1,residual=1e-12").unwrap();
    let e = req.resolve(&t).unwrap_err().to_string();
    assert!(e.contains("residual step 1e-12 is too small"), "{e}");
    let mut spec = CodecRequest::parse("dct:step=1,residual=1")
        .unwrap()
        .resolve(&t)
        .unwrap();
    if let CodecSpec::DctContext {
        residual: Some(r), ..
    } = &mut spec
    {
        r.step = vec![1e-12; 3];
    }
    let e = spec.encode(&t).unwrap_err().to_string();
    assert!(e.contains("residual step 1e-12 is too small"), "{e}");
}

/// A GGX conductor (grazing Fresnel peaks) on `grid`, 3 channels.
fn ggx_on(grid: &str) -> Table {
    let g = parse_grid_spec(grid).unwrap();
    crate::tabulate::tabulate(
        &crate::testing::GgxConductor::new(0.15),
        &g,
        &crate::tabulate::TabulateOptions::default(),
    )
    .unwrap()
}

#[test]
fn the_f32_planes_made_together_are_each_plane_made_alone_rounded() {
    // The rate control's f32 planes (one pass over the cells, planes filled one by one)
    // against `filled_plane` of each component, with a weight, a colour matrix and invalid
    // cells to fill, on every grid kind.
    let mut filled = 0;
    for grid in [
        "halfdiff3:12x10x16,warp=sqrt/linear/linear,at=edge",
        "halfdiff4:8x6x8x10",
        "spherical3:12x12x10,theta-max=85",
        "spherical4:8x6x8x6,at=edge",
    ] {
        let t = ggx_on(grid);
        filled += t.valid().iter().any(|v| !v) as usize;
        let spec = CodecRequest::parse("dct:step=0.02,weight=cosine")
            .unwrap()
            .resolve(&t)
            .unwrap();
        let tr = spec.transform().unwrap();
        assert!(tr.colour.is_some(), "{grid}");
        let together = filled_planes_f32(&t, tr);
        assert_eq!(together.len(), 3);
        // Made in the samples' own memory: the same bits.
        let in_place = filled_planes_f32_in_place(&t, tr, t.data().to_vec());
        assert_eq!(in_place, together, "{grid}: made in the samples");
        for (k, p) in together.iter().enumerate() {
            let alone = filled_plane(&t, tr, k);
            for (f, (a, b)) in p.iter().zip(&alone).enumerate() {
                assert_eq!(
                    a.to_bits(),
                    (*b as f32).to_bits(),
                    "{grid} plane {k} cell {f}"
                );
            }
        }
    }
    assert!(filled >= 2, "grids with invalid cells to fill: {filled}");
    // One channel: the plane made in the samples is the plane made beside them.
    let t = crate::tabulate::tabulate(
        &crate::model::Model::parse("ggx:alpha=0.3").unwrap(),
        &parse_grid_spec("halfdiff4:8x6x8x10").unwrap(),
        &Default::default(),
    )
    .unwrap();
    let spec = CodecRequest::parse("dct:step=0.02,weight=cosine")
        .unwrap()
        .resolve(&t)
        .unwrap();
    let tr = spec.transform().unwrap();
    assert_eq!(
        filled_planes_f32_in_place(&t, tr, t.data().to_vec()),
        filled_planes_f32(&t, tr)
    );
}

/// Every grid kind (warps, placements, θmax), weighted chains: the decoded table meets the
/// quantizer's promise in the weighted transformed space, z = M curve(w·x). Uniform: every
/// valid component within step/2 (through the colour matrix: `max_transformed_error`); f16:
/// within `max_error` of its magnitude; DCT (orthonormal, Parseval): Σ over valid
/// components of Δz² ≤ Σ over all coefficients of their quantization error² ≤ cells ×
/// (r·step)², r = ½ for rounding (zstd coding), the dead zone 0.75 for context coding.
/// Each plus the f32 rounding of the decoded value (relative 2⁻²³ of w·x and of ε).
#[test]
fn weighted_chains_meet_their_bound_in_the_weighted_space_on_every_grid_kind() {
    for grid in [
        "halfdiff3:12x10x16,warp=sqrt/linear/linear,at=edge",
        "halfdiff4:8x6x8x10,warp=sqrt/linear/linear/linear",
        "spherical3:12x12x10,theta-max=85",
        "spherical4:8x6x8x6,at=edge",
    ] {
        let t = ggx_on(grid);
        let c = 3;
        for s in [
            "uniform:bits=12,weight=cosine",
            "uniform:bits=11,curve=linear,weight=cosine",
            "f16:weight=cosine",
            "f16:curve=linear,weight=cosine",
            "dct:step=0.02,weight=cosine",
            "dct:step=0.02,weight=cosine,coding=zstd",
            "dct:step=0.05,curve=linear,colour=none,weight=cosine",
        ] {
            let what = format!("{grid} {s}");
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            let tr = spec.transform().unwrap().clone();
            assert_eq!(tr.weight, Some(Weight::Cosine), "{what}");
            let dec = spec
                .decode(&spec.encode(&t).unwrap(), &Layout::of(&t))
                .unwrap();
            assert!(dec.iter().all(|v| v.is_finite() && *v >= 0.0), "{what}");
            let za = tr.forward_all(&dec, c, t.grid(), t.valid());
            let zb = tr.forward_all(t.data(), c, t.grid(), t.valid());
            let w = tr.cell_weights(t.grid(), t.valid()).unwrap();
            // f32 rounding in the decoder (of y = Mᵀz, |y| ≤ ‖z‖, before the inverse
            // curve; of the decoded x), seen in the transformed space: a few 2⁻²⁴.
            let norm = |f: usize| {
                zb[f * c..f * c + c]
                    .iter()
                    .map(|v| v * v)
                    .sum::<f64>()
                    .sqrt()
            };
            let rounding = |f: usize, k: usize| match &tr.curve {
                Curve::Linear => 4.8e-7 * (w.at(f) * t.data()[f * c + k].abs() as f64 + norm(f)),
                Curve::Log { .. } | Curve::SignedLog { .. } => 2.4e-7 * (2.0 + norm(f)),
            };
            let valid = |f: &usize| t.valid()[*f];
            let cells = t.grid().cells();
            let mut max_ratio = 0f64;
            match &spec {
                CodecSpec::Quantized { quantize, .. } => {
                    for f in (0..cells).filter(valid) {
                        // Component k of z is what was quantized, within max_error_k. The
                        // decoder's clamp (x ≥ 0, per channel after Mᵀ) projects onto a
                        // convex set holding the true value, so it can only shorten the
                        // error vector, but it may move it between components: bound the
                        // cell's Euclidean error (M is orthonormal).
                        let zs = f * c..f * c + c;
                        let err = za[zs.clone()]
                            .iter()
                            .zip(&zb[zs.clone()])
                            .map(|(a, b)| (a - b).powi(2))
                            .sum::<f64>()
                            .sqrt();
                        let bound = (0..c)
                            .map(|k| quantize.max_error(k, zb[f * c + k].abs()).powi(2))
                            .sum::<f64>()
                            .sqrt();
                        let r: f64 = (0..c).map(|j| rounding(f, j)).sum();
                        assert!(
                            err <= bound + r + 1e-12,
                            "{what}: cell {f} w {}: {:?} vs {:?} (bound {bound})",
                            w.at(f),
                            &za[zs.clone()],
                            &zb[zs]
                        );
                        max_ratio = max_ratio.max(err / bound);
                    }
                    // Not vacuous: some cell's error is a sizeable part of its bound.
                    assert!(max_ratio > 0.3, "{what}: largest error/bound {max_ratio}");
                }
                CodecSpec::Dct { dct, .. } | CodecSpec::DctContext { dct, .. } => {
                    let r = match &spec {
                        CodecSpec::Dct { .. } => 0.5,
                        _ => coefcode::DEFAULT_DEADZONE,
                    };
                    // z in component space: undo nothing, the colour matrix is orthonormal
                    // so Σ_k Δz_k² is the same before and after it.
                    let sse: f64 = (0..cells)
                        .filter(valid)
                        .flat_map(|f| (0..c).map(move |k| f * c + k))
                        .map(|i| (za[i] - zb[i]).powi(2))
                        .sum();
                    let fp: f64 = (0..cells)
                        .filter(valid)
                        .flat_map(|f| (0..c).map(move |k| (f, k)))
                        .map(|(f, k)| (rounding(f, k) + 2e-5).powi(2))
                        .sum();
                    let bound = (cells * c) as f64 * (r * dct.step[0]).powi(2);
                    assert!(
                        sse.sqrt() <= bound.sqrt() + fp.sqrt(),
                        "{what}: √SSE {} > √bound {}",
                        sse.sqrt(),
                        bound.sqrt()
                    );
                    // Not vacuous: the error is a sizeable part of the bound.
                    assert!(sse > 1e-4 * bound, "{what}: {sse} vs {bound}");
                }
                _ => unreachable!(),
            }
        }
    }
}

/// Cells at the weight floor (pairs below the horizon declared valid, as an explicit mask
/// may) holding values up to f32::MAX, and 0: every weighted chain decodes them finite
/// and ≥ 0, and invalid cells to 0.
#[test]
fn grazing_cells_decode_finite() {
    let g = parse_grid_spec("halfdiff3:6x6x8,at=edge").unwrap();
    let prod = g.cos_products();
    let mut valid = g.geometric_mask();
    // Below-horizon cells become valid, except every third (kept invalid).
    for (f, v) in valid.iter_mut().enumerate() {
        if prod[f] == 0.0 && f % 3 != 0 {
            *v = true;
        }
    }
    assert!(valid.iter().zip(&prod).any(|(&ok, &p)| ok && p == 0.0));
    let data: Vec<f32> = (0..g.cells() * 3)
        .map(|i| match (i / 3) % 4 {
            0 => f32::MAX,
            1 => 0.0,
            2 => 1e30,
            _ => 0.5,
        })
        .collect();
    let t = Table::new(
        g,
        Channels::default_for(3),
        Provenance::default(),
        data,
        valid.clone(),
    )
    .unwrap();
    for s in [
        "f16:curve=linear,weight=cosine",
        "f16:weight=cosine",
        "uniform:bits=16,curve=linear,weight=cosine",
        "uniform:bits=16,weight=cosine",
        "dct:step=0.01,weight=cosine",
        "dct:step=0.01,weight=cosine,coding=zstd",
        "dct:step=0.01,weight=cosine,residual=0.001",
    ] {
        let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
        let layout = Layout::of(&t);
        let payload = spec.encode(&t).unwrap();
        for dec in [
            spec.decode(&payload, &layout).unwrap(),
            reference::decode(&spec, &payload, &layout).unwrap(),
        ] {
            for (i, v) in dec.iter().enumerate() {
                assert!(v.is_finite() && *v >= 0.0, "{s}: value {i} = {v}");
                if !valid[i / 3] {
                    assert_eq!(*v, 0.0, "{s}: invalid value {i}");
                }
            }
            // The floor cells holding f32::MAX come back huge, not clamped to 0.
            let big = dec
                .chunks_exact(3)
                .zip(&valid)
                .zip(&prod)
                .filter(|((_, ok), p)| **ok && **p == 0.0)
                .map(|((v, _), _)| v[0])
                .fold(0f32, f32::max);
            assert!(big > 1e37, "{s}: {big}");
        }
    }
}

#[test]
fn bad_requests_name_the_option() {
    for (s, want) in [
        ("dct", "needs step"),
        ("dct:step=-1", "step"),
        ("uniform:bits=40", "bits"),
        ("lossless:level=99", "level"),
        ("f16:bogus=1", "bogus"),
        ("brotli", "unknown codec"),
        (
            "dct:step=0.1,level=3",
            "level applies to dct with coding=zstd",
        ),
        (
            "dct:step=0.1,coding=zstd,refine=2",
            "refine applies to dct with coding=context",
        ),
        ("dct:step=0.1,deadzone=0.2", "deadzone"),
        ("dct:step=0.1,refine=21", "refine"),
        ("dct:step=0.1,coding=huffman", "coding"),
        (
            "dct:step=0.1,weight=sine",
            "weight = \"sine\", expected cosine",
        ),
        (
            "lossless:weight=cosine",
            "weight applies to the lossy codecs (f16, uniform, dct, tucker) only: lossless keeps",
        ),
        (
            "zstd-f32:weight=cos",
            "zstd-f32 keeps every sample bit for bit",
        ),
        ("tucker", "needs ranks"),
        ("tucker:ranks=8x0x4", "ranks"),
        ("tucker:ranks=8xx4", "ranks"),
        ("tucker:ranks=8x8x8,step=0", "step"),
        ("tucker:ranks=8x8x8,factor=1e9", "factor"),
        ("tucker:ranks=8x8x8,deadzone=1", "deadzone"),
        (
            "dct:step=0.1,residual=0",
            "residual = \"0\", expected a positive step",
        ),
        ("dct:step=0.1,residual=inf", "residual"),
        (
            "uniform:bits=8,residual=0.1",
            "residual=0.1 applies to dct and tucker only",
        ),
        ("lossless:residual=0.1", "applies to dct and tucker only"),
    ] {
        let e = CodecRequest::parse(s).unwrap_err().to_string();
        assert!(e.contains(want), "{s}: {e}");
    }
}

#[test]
fn hostile_headers_and_payloads_are_errors_not_panics() {
    let t = small_table();
    let layout = Layout::of(&t);
    for s in ["dct:step=0.01", "dct:step=0.01,coding=zstd"] {
        let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
        let payload = spec.encode(&t).unwrap();
        for cut in [0, 1, payload.len() / 2, payload.len() - 1] {
            assert!(
                spec.decode(&payload[..cut], &layout).is_err(),
                "{s} cut {cut}"
            );
        }
        let mut bad = spec.clone();
        match &mut bad {
            CodecSpec::Dct { dct, .. } | CodecSpec::DctContext { dct, .. } => {
                dct.step = vec![0.0; 3]
            }
            _ => unreachable!(),
        }
        assert!(bad.decode(&payload, &layout).is_err(), "{s}");
        if let CodecSpec::DctContext { coding, domain, .. } = &spec {
            for (dz, it) in [(9.0, 0), (0.75, 1000)] {
                let mut bad = spec.clone();
                if let CodecSpec::DctContext {
                    coding: c,
                    domain: d,
                    ..
                } = &mut bad
                {
                    *c = coefcode::ContextCoding::new(dz);
                    *d = Domain::FillRefined { iterations: it };
                }
                assert!(bad.decode(&payload, &layout).is_err(), "{dz} {it}");
            }
            assert_eq!(*domain, Domain::FillInvalid);
            assert_eq!(coding.deadzone, coefcode::DEFAULT_DEADZONE);
        }
    }
    let spec = CodecRequest::parse("tucker:ranks=4x4x6,step=0.01")
        .unwrap()
        .resolve(&t)
        .unwrap();
    let payload = spec.encode(&t).unwrap();
    for cut in [0, 1, payload.len() / 2, payload.len() - 1] {
        assert!(
            spec.decode(&payload[..cut], &layout).is_err(),
            "tucker cut {cut}"
        );
    }
    let edits: [fn(&mut tucker::TuckerStage, &mut Domain); 6] = [
        |s, _| s.ranks = vec![4, 4],
        |s, _| s.ranks = vec![4, 9, 6],
        |s, _| s.ranks = vec![4, 0, 6],
        |s, _| s.step = vec![0.01, f64::INFINITY, 0.01],
        |s, _| s.factor_step = f64::NAN,
        |_, d| *d = Domain::DropInvalid,
    ];
    for (i, edit) in edits.iter().enumerate() {
        let mut bad = spec.clone();
        if let CodecSpec::Tucker { tucker, domain, .. } = &mut bad {
            edit(tucker, domain);
        }
        assert!(bad.decode(&payload, &layout).is_err(), "tucker edit {i}");
        assert!(bad.encode(&t).is_err(), "tucker edit {i}");
    }
    // Smaller ranks than the payload was written with: its extents exceed them.
    let mut small = spec.clone();
    if let CodecSpec::Tucker { tucker, .. } = &mut small {
        tucker.ranks = vec![1, 1, 1];
    }
    assert!(small.decode(&payload, &layout).is_err());
    let lossless = CodecRequest::parse("lossless")
        .unwrap()
        .resolve(&t)
        .unwrap();
    let p = lossless.encode(&t).unwrap();
    assert!(lossless.decode(&p[..p.len() - 1], &layout).is_err());
}

#[test]
fn the_refined_fill_from_the_kept_fill_is_the_refined_fill_of_the_plane() {
    // A pass changes only the invalid cells, so the coefficients plus the DCT of the change
    // are the DCT of the changed plane: the same coefficients as the pass that transforms
    // the plane back and forth, to the f32 rounding of those transforms, for one and two
    // passes and the relaxed and plain fill.
    let t = ggx_on("halfdiff3:16x12x24");
    assert!(t.valid().iter().any(|&v| !v), "the grid has invalid cells");
    let dims = t.grid().shape();
    let spec = CodecRequest::parse("dct:step=0.02")
        .unwrap()
        .resolve(&t)
        .unwrap();
    let plane = filled_plane(&t, spec.transform().unwrap(), 0);
    let fill = fill_of(&plane, t.valid());
    assert_eq!(fill.len(), t.valid().iter().filter(|&&v| !v).count());
    let coef: Vec<f32> = dct::forward(&plane, &dims)
        .iter()
        .map(|&c| c as f32)
        .collect();
    let largest = coef.iter().fold(0f32, |m, c| m.max(c.abs()));
    let step = 0.02 * largest as f64;
    for (passes, relaxation) in [(1, 1.0), (1, FILL_RELAXATION), (2, FILL_RELAXATION)] {
        let both_ways = refine_coefficients_f32(
            coef.clone(),
            &dims,
            t.valid(),
            step,
            0.75,
            passes,
            relaxation,
        );
        let from_fill = refine_coefficients_from_fill(
            coef.clone(),
            &dims,
            t.valid(),
            &fill,
            step,
            0.75,
            passes,
            relaxation,
        );
        let moved = both_ways
            .iter()
            .zip(&coef)
            .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        let apart = both_ways
            .iter()
            .zip(&from_fill)
            .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(moved > 1e-3 * largest, "{passes} passes moved {moved}");
        assert!(
            apart < 1e-5 * largest,
            "{passes} passes: {apart} of {largest}"
        );
    }
}
