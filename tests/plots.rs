//! Numerical tests on the pictures of `brdfpack plot` (docs/plots.md): the decoded pixels
//! and drawn curves are compared with what the physics says they must be.

mod common;

use assert_cmd::Command;
use brdfpack::geometry::Vec3;
use brdfpack::grid::Grid;
use brdfpack::plot::figure::{INVALID, Item, SPHERE_BACKGROUND, srgb_byte};
use brdfpack::plot::{
    Figure, ImageFormat, PlotOptions, Subject, View, encode, lobe_curves, plot, slice_cells,
};
use brdfpack::source::{Lookup, open_brdf};
use brdfpack::table::{Interp, InterpolatedTable, Table};
use brdfpack::tabulate::{TabulateOptions, tabulate};

/// Decodes an 8-bit RGB PNG into (width, height, bytes).
fn decode_png(bytes: &[u8]) -> (usize, usize, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .expect("PNG header");
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).expect("PNG data");
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    buf.truncate(info.buffer_size());
    (info.width as usize, info.height as usize, buf)
}

fn pixel(img: &(usize, usize, Vec<u8>), x: usize, y: usize) -> [u8; 3] {
    let k = 3 * (y * img.0 + x);
    [img.2[k], img.2[k + 1], img.2[k + 2]]
}

fn model(spec: &str) -> Subject {
    Subject::from_brdf(spec, open_brdf(spec).unwrap())
}

/// A Lambertian sphere lit by a directional light is ρ·max(0, n·l)·2^EV before the sRGB
/// curve (L = (ρ/π)·cos θi·E with E = π): every decoded pixel within 1/255 of that.
#[test]
fn lambert_sphere_follows_the_cosine_law_pixel_by_pixel() {
    for (exposure, light) in [
        (0.0, (45.0, 135.0)),
        (-1.0, (0.0, 0.0)),
        (0.5, (70.0, -20.0)),
    ] {
        let albedo = 0.8;
        let opts = PlotOptions {
            size: 96,
            exposure_ev: exposure,
            light_theta_deg: light.0,
            light_phi_deg: light.1,
            ..PlotOptions::default()
        };
        let fig = plot(View::Sphere, &model("lambert:albedo=0.8"), None, &opts).unwrap();
        let img = decode_png(&encode(&fig, ImageFormat::Png).unwrap());
        assert_eq!((img.0, img.1), (fig.width, fig.height));
        let panel = fig.panel("source").unwrap();
        assert_eq!((panel.width, panel.height), (96, 96));
        let l = Vec3::from_spherical(light.0.to_radians(), light.1.to_radians());
        let (mut lit, mut worst) = (0, 0i32);
        for j in 0..96 {
            for i in 0..96 {
                let x = 2.0 * (i as f64 + 0.5) / 96.0 - 1.0;
                let y = 1.0 - 2.0 * (j as f64 + 0.5) / 96.0;
                let got = pixel(&img, panel.x + i, panel.y + j);
                if x * x + y * y >= 1.0 {
                    assert_eq!(got, SPHERE_BACKGROUND, "pixel ({i}, {j}) is off the sphere");
                    continue;
                }
                let n = Vec3::new(x, y, (1.0 - x * x - y * y).sqrt());
                let radiance = albedo * n.dot(l).max(0.0) * 2f64.powf(exposure);
                let want = srgb_byte(radiance) as i32;
                lit += usize::from(want > 0);
                for c in got {
                    worst = worst.max((c as i32 - want).abs());
                }
            }
        }
        assert!(
            worst <= 1,
            "exposure {exposure} light {light:?}: off by {worst}/255"
        );
        assert!(lit > 1500, "only {lit} lit pixels");
    }
}

/// The lobe of a mirror-like GGX (α = 0.01) peaks at the mirror angle −θi within one plot
/// sample, both in the computed curve and in the polyline drawn.
#[test]
fn ggx_lobe_peaks_at_the_mirror_angle() {
    let subject = model("ggx:alpha=0.01");
    let opts = PlotOptions {
        lobe_theta_i_deg: vec![0.0, 30.0, 60.0, 75.0],
        ..PlotOptions::default()
    };
    let step = 180.0 / (opts.lobe_samples - 1) as f64;
    let curves = lobe_curves(
        subject.brdf.as_ref(),
        0.0,
        &opts.lobe_theta_i_deg,
        opts.lobe_samples,
    );
    for c in &curves {
        let k = (0..c.values.len())
            .max_by(|&a, &b| c.values[a].total_cmp(&c.values[b]))
            .unwrap();
        let peak = c.angles_deg[k];
        assert!(
            (peak + c.theta_i_deg).abs() <= step,
            "θi {}: peak at {peak}°, mirror at {}°",
            c.theta_i_deg,
            -c.theta_i_deg
        );
    }
    // The drawn curves: solid polylines with one point per sample; the ends (θo = ±90°, value
    // 0) sit at the plot's centre, and the farthest point is the peak.
    let fig = plot(View::Lobe, &subject, None, &opts).unwrap();
    let drawn: Vec<&Vec<(f64, f64)>> = fig
        .items
        .iter()
        .filter_map(|it| match it {
            Item::Polyline {
                points,
                dashed: false,
                ..
            } if points.len() == opts.lobe_samples => Some(points),
            _ => None,
        })
        .collect();
    assert_eq!(drawn.len(), 4);
    for (points, c) in drawn.iter().zip(&curves) {
        let centre = points[0];
        let r = |p: (f64, f64)| ((p.0 - centre.0).powi(2) + (p.1 - centre.1).powi(2)).sqrt();
        let k = (0..points.len())
            .max_by(|&a, &b| r(points[a]).total_cmp(&r(points[b])))
            .unwrap();
        let p = points[k];
        // Angle from the upward normal, positive towards the light (drawn on the right).
        let drawn_angle = (p.0 - centre.0).atan2(centre.1 - p.1).to_degrees();
        assert!(
            (drawn_angle + c.theta_i_deg).abs() <= step + 1e-9,
            "θi {}: drawn peak at {drawn_angle}°",
            c.theta_i_deg
        );
    }
}

/// A MERL-grid table whose validity is the geometric mask with extra holes punched in: the
/// slice shows the grey of invalid cells exactly at the cells the mask says, nowhere else.
#[test]
fn merl_slice_shows_invalid_cells_exactly_where_the_grid_says() {
    let grid = Grid::merl();
    let src = open_brdf("ggx:alpha=0.2,fresnel=au").unwrap();
    let t = tabulate(src.as_ref(), &grid, &TabulateOptions::default()).unwrap();
    // Holes: a diagonal pattern, plus a block, on top of the cells below the horizon.
    let mut valid = t.valid().to_vec();
    let mut idx = [0usize; 3];
    for (flat, v) in valid.iter_mut().enumerate() {
        grid.unflatten(flat, &mut idx);
        if (idx[0] + 2 * idx[1]) % 7 == 0 || (idx[0] / 10 == 4 && idx[1] / 10 == 2) {
            *v = false;
        }
    }
    let table = Table::new(
        grid.clone(),
        t.channels().clone(),
        t.provenance().clone(),
        t.data().to_vec(),
        valid,
    )
    .unwrap();
    assert_slice_matches_validity(&table, "self-made");

    if let Some(path) = common::shared_file("data/merl/gold-metallic-paint.binary") {
        let s = Subject::open(path.to_str().unwrap(), Lookup::Linear).unwrap();
        assert_slice_matches_validity(s.table.as_ref().unwrap(), "gold-metallic-paint");
    }
}

fn assert_slice_matches_validity(table: &Table, what: &str) {
    let subject = Subject {
        label: what.into(),
        brdf: Box::new(InterpolatedTable {
            table: table.clone(),
            interp: Interp::Linear,
        }),
        table: Some(table.clone()),
    };
    for phi_d in [90.0, 10.0] {
        let opts = PlotOptions {
            phi_d_deg: phi_d,
            ..PlotOptions::default()
        };
        let fig = plot(View::Slice, &subject, None, &opts).unwrap();
        let img = decode_png(&encode(&fig, ImageFormat::Png).unwrap());
        let p = fig.panel("source").unwrap();
        assert_eq!((p.width, p.height), (90 * p.scale, 90 * p.scale));
        // MERL's φd axis: 180 lower-edge samples of 1° from 0.
        let ip = phi_d as usize;
        assert_eq!(slice_cells(Some(table.grid()), phi_d).phi_d_deg, phi_d);
        let (mut invalid, mut checked) = (0, 0);
        for id in 0..90 {
            for ih in 0..90 {
                let flat = (ih * 90 + id) * 180 + ip;
                // Every pixel of the cell's block.
                for dy in 0..p.scale {
                    for dx in 0..p.scale {
                        let got = pixel(
                            &img,
                            p.x + ih * p.scale + dx,
                            p.y + (89 - id) * p.scale + dy,
                        );
                        assert_eq!(
                            got == INVALID,
                            !table.valid()[flat],
                            "{what} φd {phi_d}: cell θh #{ih} θd #{id}: pixel {got:?}"
                        );
                        checked += 1;
                    }
                }
                invalid += usize::from(!table.valid()[flat]);
            }
        }
        // The self-made mask has holes in every slice; a measured file may have none here.
        assert!(invalid < 8100, "{what}: every cell invalid");
        if what == "self-made" {
            assert!(
                invalid > 1000,
                "{what} φd {phi_d}: only {invalid} invalid cells"
            );
        }
        assert_eq!(checked, 8100 * p.scale * p.scale);
    }
}

/// Every view, with and without a reference, gives a PNG that decodes to the figure's size
/// and an SVG that a strict XML parser accepts, with an svg root of the same size; the same
/// figure gives the same bytes.
#[test]
fn every_view_encodes_to_a_decodable_png_and_well_formed_svg() {
    let src = model("ward:alpha_x=0.1,alpha_y=0.3");
    let reference = model("ward:alpha_x=0.12,alpha_y=0.3");
    let opts = PlotOptions {
        size: 48,
        ..PlotOptions::default()
    };
    for view in [
        View::Sphere,
        View::Lobe,
        View::Slice,
        View::Albedo,
        View::Report,
    ] {
        for r in [None, Some(&reference)] {
            let fig: Figure = plot(view, &src, r, &opts).unwrap();
            let png = encode(&fig, ImageFormat::Png).unwrap();
            let img = decode_png(&png);
            assert_eq!((img.0, img.1), (fig.width, fig.height), "{view:?}");
            let svg = encode(&fig, ImageFormat::Svg).unwrap();
            let text = String::from_utf8(svg.clone()).unwrap();
            let doc = roxmltree::Document::parse(&text)
                .unwrap_or_else(|e| panic!("{view:?}: SVG does not parse: {e}"));
            let root = doc.root_element();
            assert_eq!(root.tag_name().name(), "svg");
            assert_eq!(
                root.tag_name().namespace(),
                Some("http://www.w3.org/2000/svg")
            );
            assert_eq!(
                root.attribute("width"),
                Some(fig.width.to_string().as_str())
            );
            assert!(!text.contains("NaN") && !text.contains("inf"), "{view:?}");
            // Determinism.
            let again = plot(view, &src, r, &opts).unwrap();
            assert_eq!(encode(&again, ImageFormat::Png).unwrap(), png, "{view:?}");
            assert_eq!(encode(&again, ImageFormat::Svg).unwrap(), svg, "{view:?}");
        }
    }
}

/// A source compared with itself has zero error: the error panel is the ramp's bottom colour
/// on the whole sphere.
#[test]
fn a_source_against_itself_has_an_all_zero_error_map() {
    let a = model("ggx:alpha=0.3,fresnel=au");
    let b = model("ggx:alpha=0.3,fresnel=au");
    let opts = PlotOptions {
        size: 40,
        ..PlotOptions::default()
    };
    let fig = plot(View::Sphere, &a, Some(&b), &opts).unwrap();
    let img = decode_png(&encode(&fig, ImageFormat::Png).unwrap());
    let p = fig.panel("error").unwrap();
    let zero = brdfpack::plot::figure::ramp(0.0);
    let mut on_sphere = 0;
    for j in 0..40 {
        for i in 0..40 {
            let c = pixel(&img, p.x + i, p.y + j);
            assert!(c == zero || c == SPHERE_BACKGROUND, "({i}, {j}): {c:?}");
            on_sphere += usize::from(c == zero);
        }
    }
    assert!(on_sphere > 1000);
    // And a different source does show error.
    let c = model("ggx:alpha=0.35,fresnel=au");
    let fig = plot(View::Sphere, &c, Some(&b), &opts).unwrap();
    let img = decode_png(&encode(&fig, ImageFormat::Png).unwrap());
    let p = fig.panel("error").unwrap();
    let differing = (0..40 * 40)
        .filter(|k| {
            let px = pixel(&img, p.x + k % 40, p.y + k / 40);
            px != zero && px != SPHERE_BACKGROUND
        })
        .count();
    assert!(differing > 500, "{differing}");
}

#[test]
fn cli_plot_writes_the_named_format_and_rejects_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("a.svg");
    Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["plot", "lambert:albedo=0.5", "--view", "albedo", "-o"])
        .arg(&svg)
        .assert()
        .success();
    let text = std::fs::read_to_string(&svg).unwrap();
    roxmltree::Document::parse(&text).unwrap();

    let png = dir.path().join("a.png");
    let run = |threads: &str| {
        Command::cargo_bin("brdfpack")
            .unwrap()
            .env("RAYON_NUM_THREADS", threads)
            .args([
                "plot",
                "ggx:alpha=0.2,fresnel=au",
                "--against",
                "ggx:alpha=0.25,fresnel=au",
                "--size",
                "64",
                "-o",
            ])
            .arg(&png)
            .assert()
            .success();
        std::fs::read(&png).unwrap()
    };
    let one = run("1");
    decode_png(&one);
    assert_eq!(run("2"), one, "bytes depend on the thread count");

    for (args, needle) in [
        (vec!["plot", "lambert", "-o", "x.jpg"], "x.jpg"),
        (
            vec!["plot", "lambert", "-o", "x.png", "--size", "3"],
            "--size",
        ),
        (
            vec!["plot", "lambert", "-o", "x.png", "--light", "95,0"],
            "--light",
        ),
        (vec!["plot", "nosuchmodel", "-o", "x.png"], "nosuchmodel"),
    ] {
        let out = Command::cargo_bin("brdfpack")
            .unwrap()
            .current_dir(dir.path())
            .args(&args)
            .assert()
            .code(2);
        let err = String::from_utf8_lossy(&out.get_output().stderr).to_string();
        assert!(
            err.starts_with("brdfpack:") && err.contains(needle),
            "{args:?}: {err}"
        );
    }
}

#[test]
fn check_plot_writes_the_error_views_and_keeps_the_verdict() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("check.png");
    Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "check",
            "ggx:alpha=0.21",
            "--against",
            "ggx:alpha=0.2",
            "--samples",
            "4096",
            "--max-log-rmse",
            "1e-6",
            "--size",
            "48",
            "--plot",
        ])
        .arg(&out)
        .assert()
        .code(1);
    let img = decode_png(&std::fs::read(&out).unwrap());
    assert!(img.0 >= 400 && img.1 > 600, "{}x{}", img.0, img.1);
}

/// A browser on the PATH, if any (Debian's `chromium`).
fn browser() -> Option<&'static str> {
    ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|b| {
            std::process::Command::new(b)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        })
}

/// SVGs open in a real browser without errors: Chromium's XML parser, run headless, builds
/// the document without a `parsererror` element (it inserts one for any XML error; checked
/// below on a broken file). Skips with a reason when no browser is installed.
#[test]
fn svgs_load_in_a_headless_browser() {
    let Some(browser) = browser() else {
        println!("skipped: no chromium on the PATH (apt-get install chromium to run this test)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let load = |path: &std::path::Path| -> String {
        let out = std::process::Command::new(browser)
            .args(["--headless", "--no-sandbox", "--disable-gpu", "--dump-dom"])
            .arg(format!("file://{}", path.canonicalize().unwrap().display()))
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let broken = dir.path().join("broken.svg");
    std::fs::write(
        &broken,
        r#"<svg xmlns="http://www.w3.org/2000/svg"><text>a & b</text></svg>"#,
    )
    .unwrap();
    assert!(
        load(&broken).contains("parsererror"),
        "the check cannot see errors"
    );

    let opts = PlotOptions {
        size: 48,
        ..PlotOptions::default()
    };
    let fig = plot(
        View::Report,
        &model("ward:alpha_x=0.1,alpha_y=0.3"),
        Some(&model("ggx:alpha=0.2,fresnel=au")),
        &opts,
    )
    .unwrap();
    let report = dir.path().join("report.svg");
    std::fs::write(&report, encode(&fig, ImageFormat::Svg).unwrap()).unwrap();
    let mut files = vec![report];
    let images = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/images");
    let mut docs: Vec<_> = std::fs::read_dir(&images)
        .into_iter()
        .flatten()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "svg"))
        .collect();
    docs.sort();
    files.extend(docs);
    for f in &files {
        let dom = load(f);
        assert!(
            dom.starts_with("<svg"),
            "{}: {}",
            f.display(),
            &dom[..dom.len().min(300)]
        );
        assert!(!dom.contains("parsererror"), "{}", f.display());
    }
}

/// The figures in docs/images decode (PNG) and parse strictly (SVG).
#[test]
fn documented_images_decode_and_parse() {
    let images = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/images");
    let mut n = 0;
    for e in std::fs::read_dir(&images).unwrap() {
        let p = e.unwrap().path();
        match p.extension().and_then(|e| e.to_str()) {
            Some("png") => {
                let (w, h, _) = decode_png(&std::fs::read(&p).unwrap());
                assert!(w > 0 && h > 0, "{}", p.display());
            }
            Some("svg") => {
                let text = std::fs::read_to_string(&p).unwrap();
                roxmltree::Document::parse(&text)
                    .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            }
            _ => continue,
        }
        n += 1;
    }
    assert!(n >= 18, "{n} images");
}
