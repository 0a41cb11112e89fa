//! The four views, each drawn into a [`Figure`].

use super::figure::{
    AXIS, Anchor, CHAR_ADVANCE, Figure, GUIDE, INVALID, Item, Rgb, RgbImage, SPHERE_BACKGROUND,
    TEXT, label_number, line_color, ramp, shorten, srgb_byte,
};
use super::{Display, PlotOptions, RadiusScale, Subject};
use crate::brdf::Brdf;
use crate::geometry::{HalfDiff, Vec3};
use crate::grid::{Grid, GridKind, Placement};
use crate::math::PI;
use rayon::prelude::*;

const MARGIN: usize = 10;
/// Top of the panels: room for a title and a subtitle.
const TOP: usize = 40;
/// Width reserved for a colour bar and its labels.
const BAR_SPACE: usize = 78;
const BAR_WIDTH: usize = 12;
/// Gap between panels.
const GAP: usize = 10;
/// Characters of a source name shown in captions.
const LABEL_CHARS: usize = 34;

/// Relative error of a value against a reference value: |s − r| / (r + ε).
fn rel_err(s: f64, r: f64, eps: f64) -> f64 {
    let e = (s - r).abs() / (r.abs() + eps);
    if e.is_finite() { e } else { 0.0 }
}

/// The error colour scale: log10 of the relative error from 1e-4 (0) to 1 (1).
const ERR_DECADES: (f64, f64) = (-4.0, 0.0);

fn err_color(e: f64) -> Rgb {
    if e <= 0.0 {
        return ramp(0.0);
    }
    ramp((e.log10() - ERR_DECADES.0) / (ERR_DECADES.1 - ERR_DECADES.0))
}

/// p-th percentile (0..=1) by nearest rank of finite values; 0 for none.
fn percentile(mut v: Vec<f64>, p: f64) -> f64 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let k = ((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    v[k]
}

/// A vertical colour bar at (x, y) of height `h`, ramp from bottom (lo) to top (hi), with a
/// label per whole decade.
fn colour_bar(fig: &mut Figure, x: usize, y: usize, h: usize, lo: f64, hi: f64, title: &str) {
    let mut img = RgbImage::new(BAR_WIDTH, h, [0, 0, 0]);
    for j in 0..h {
        let t = 1.0 - (j as f64 + 0.5) / h as f64;
        for i in 0..BAR_WIDTH {
            img.set(i, j, ramp(t));
        }
    }
    fig.items.push(Item::Image {
        x,
        y,
        scale: 1,
        image: img,
    });
    fig.items.push(Item::Frame {
        x,
        y,
        w: BAR_WIDTH,
        h,
        color: AXIS,
    });
    let decades = (hi - lo).round().max(1.0) as i32;
    // At most ~8 labels.
    let step = ((decades as f64) / 8.0).ceil().max(1.0) as i32;
    let mut d = 0;
    while d <= decades {
        let v = lo + d as f64;
        let py = y as f64 + h as f64 * (1.0 - d as f64 / (hi - lo));
        fig.line(
            ((x + BAR_WIDTH) as f64, py),
            ((x + BAR_WIDTH + 3) as f64, py),
            AXIS,
            1.0,
            false,
        );
        fig.text(
            (x + BAR_WIDTH + 6) as f64,
            py + 5.0,
            label_number(10f64.powf(v)),
            Anchor::Start,
        );
        d += step;
    }
    fig.text(x as f64, y as f64 - 8.0, title, Anchor::Start);
}

/// The two title lines; the figure widens to hold them.
fn titles(fig: &mut Figure, title: &str, subtitle: &str) {
    let chars = title.chars().count().max(subtitle.chars().count());
    fig.width = fig.width.max(2 * MARGIN + chars * CHAR_ADVANCE as usize);
    fig.text(MARGIN as f64, 16.0, title, Anchor::Start);
    fig.text(MARGIN as f64, 31.0, subtitle, Anchor::Start);
}

fn caption(fig: &mut Figure, x: usize, w: usize, y: usize, text: &str) {
    fig.text(
        x as f64 + w as f64 / 2.0,
        y as f64,
        shorten(text, (w / 8).max(4)),
        Anchor::Middle,
    );
}

// ---------------------------------------------------------------------------------------
// sphere

/// Light direction in the camera frame.
fn light_dir(opts: &PlotOptions) -> Vec3 {
    Vec3::from_spherical(
        opts.light_theta_deg.to_radians(),
        opts.light_phi_deg.to_radians(),
    )
}

/// The outgoing radiance (linear RGB, before exposure) of each pixel of an `opts.size`²
/// orthographic view of a unit sphere, row-major from the top; `None` outside the sphere.
/// Pixel (i, j) looks at x = 2(i + ½)/N − 1, y = 1 − 2(j + ½)/N; the surface normal there is
/// n = (x, y, √(1 − x² − y²)), the tangent is the camera's x axis made orthogonal to n (so an
/// anisotropic source's x axis runs left–right), and L = f_r(wi, wo) · cos θi · E.
pub fn sphere_radiance(brdf: &dyn Brdf, opts: &PlotOptions) -> Vec<Option<[f64; 3]>> {
    let n = opts.size;
    let display = Display::for_brdf(brdf);
    let light = light_dir(opts);
    let view = Vec3::Z;
    let nc = brdf.channels().len();
    (0..n * n)
        .into_par_iter()
        .map_init(
            || vec![0.0; nc],
            |f, p| {
                let (i, j) = (p % n, p / n);
                let x = 2.0 * (i as f64 + 0.5) / n as f64 - 1.0;
                let y = 1.0 - 2.0 * (j as f64 + 0.5) / n as f64;
                let r2 = x * x + y * y;
                if r2 >= 1.0 {
                    return None;
                }
                let normal = Vec3::new(x, y, (1.0 - r2).sqrt());
                let tangent = (Vec3::new(1.0, 0.0, 0.0) - normal * normal.x)
                    .try_normalize()
                    .unwrap_or(Vec3::new(0.0, 1.0, 0.0));
                let bitangent = normal.cross(tangent);
                let local = |w: Vec3| Vec3::new(w.dot(tangent), w.dot(bitangent), w.dot(normal));
                let (wi, wo) = (local(light), local(view));
                let cos_i = wi.z;
                if cos_i <= 0.0 {
                    return Some([0.0; 3]);
                }
                brdf.eval(wi, wo, f);
                let rgb = display.rgb(f);
                Some(rgb.map(|c| {
                    let l = c * cos_i * opts.irradiance;
                    if l.is_finite() { l } else { 0.0 }
                }))
            },
        )
        .collect()
}

fn tone_map(radiance: &[Option<[f64; 3]>], n: usize, opts: &PlotOptions) -> RgbImage {
    let k = 2f64.powf(opts.exposure_ev);
    RgbImage {
        width: n,
        height: n,
        pixels: radiance
            .iter()
            .map(|p| match p {
                None => SPHERE_BACKGROUND,
                Some(rgb) => rgb.map(|c| srgb_byte(c * k)),
            })
            .collect(),
    }
}

/// The sphere view: one panel, or reference / source / error with a colour bar.
pub fn sphere_view(source: &Subject, reference: Option<&Subject>, opts: &PlotOptions) -> Figure {
    let n = opts.size;
    let panels = if reference.is_some() { 3 } else { 1 };
    let width = (2 * MARGIN
        + panels * n
        + (panels - 1) * GAP
        + if reference.is_some() { BAR_SPACE } else { 0 })
    .max(420);
    let height = TOP + n + 26;
    let mut fig = Figure::new(width, height);
    titles(
        &mut fig,
        "sphere: orthographic camera, directional light",
        &format!(
            "light θ={}° φ={}° (camera frame), E={}, L = f·cosθi·E, exposure {:+} EV, clip at 1, sRGB",
            label_number(opts.light_theta_deg),
            label_number(opts.light_phi_deg),
            if (opts.irradiance - PI).abs() < 1e-12 {
                "π".to_string()
            } else {
                label_number(opts.irradiance)
            },
            opts.exposure_ev
        ),
    );
    let src = sphere_radiance(source.brdf.as_ref(), opts);
    let cap_y = TOP + n + 16;
    match reference {
        None => {
            fig.image("source", MARGIN, TOP, 1, tone_map(&src, n, opts));
            caption(&mut fig, MARGIN, n, cap_y, &source.label);
        }
        Some(r) => {
            let rf = sphere_radiance(r.brdf.as_ref(), opts);
            let x1 = MARGIN + n + GAP;
            let x2 = x1 + n + GAP;
            fig.image("reference", MARGIN, TOP, 1, tone_map(&rf, n, opts));
            fig.image("source", x1, TOP, 1, tone_map(&src, n, opts));
            caption(&mut fig, MARGIN, n, cap_y, &format!("ref: {}", r.label));
            caption(&mut fig, x1, n, cap_y, &source.label);
            // ε: a thousandth of the brightest reference radiance.
            let peak = rf
                .iter()
                .flatten()
                .flat_map(|c| c.iter().copied())
                .fold(0.0, f64::max);
            let eps = (1e-3 * peak).max(1e-12);
            let errs: Vec<Option<f64>> = src
                .iter()
                .zip(&rf)
                .map(|(s, r)| match (s, r) {
                    (Some(s), Some(r)) => {
                        Some((0..3).map(|c| rel_err(s[c], r[c], eps)).fold(0.0, f64::max))
                    }
                    _ => None,
                })
                .collect();
            let img = RgbImage {
                width: n,
                height: n,
                pixels: errs
                    .iter()
                    .map(|e| e.map_or(SPHERE_BACKGROUND, err_color))
                    .collect(),
            };
            fig.image("error", x2, TOP, 1, img);
            let all: Vec<f64> = errs.iter().flatten().copied().collect();
            caption(
                &mut fig,
                x2,
                n,
                cap_y,
                &format!(
                    "p50 {} p99 {}",
                    label_number(percentile(all.clone(), 0.5)),
                    label_number(percentile(all, 0.99))
                ),
            );
            colour_bar(
                &mut fig,
                x2 + n + 8,
                TOP + 14,
                n - 14,
                ERR_DECADES.0,
                ERR_DECADES.1,
                "rel. err",
            );
        }
    }
    fig
}

// ---------------------------------------------------------------------------------------
// lobe

/// One curve of a lobe plot: f_r·cos θo (luminance) at signed angles θo in one plane.
#[derive(Clone, Debug, PartialEq)]
pub struct LobeCurve {
    /// Azimuth of the plane of incidence, degrees (0: the xz plane).
    pub plane_phi_deg: f64,
    pub theta_i_deg: f64,
    /// Signed outgoing angles in degrees, −90 … 90; negative is the mirror side (wo on the
    /// other side of the normal from wi), so the mirror direction is at −θi.
    pub angles_deg: Vec<f64>,
    pub values: Vec<f64>,
}

/// The lobe curves of `brdf` in the plane at azimuth `plane_phi_deg`, for each θi.
pub fn lobe_curves(
    brdf: &dyn Brdf,
    plane_phi_deg: f64,
    theta_i_deg: &[f64],
    samples: usize,
) -> Vec<LobeCurve> {
    let display = Display::for_brdf(brdf);
    let nc = brdf.channels().len();
    let phi = plane_phi_deg.to_radians();
    let angles: Vec<f64> = (0..samples)
        .map(|k| -90.0 + 180.0 * k as f64 / (samples - 1) as f64)
        .collect();
    theta_i_deg
        .iter()
        .map(|&ti| {
            let wi = Vec3::from_spherical(ti.to_radians(), phi);
            let values = angles
                .par_iter()
                .map_init(
                    || vec![0.0; nc],
                    |f, &t| {
                        let t = t.to_radians();
                        let (s, c) = t.sin_cos();
                        let wo = Vec3::new(s * phi.cos(), s * phi.sin(), c);
                        if wo.z <= 0.0 {
                            return 0.0;
                        }
                        brdf.eval(wi, wo, f);
                        let v = display.luminance(f) * wo.z;
                        if v.is_finite() { v } else { 0.0 }
                    },
                )
                .collect();
            LobeCurve {
                plane_phi_deg,
                theta_i_deg: ti,
                angles_deg: angles.clone(),
                values,
            }
        })
        .collect()
}

const LOBE_R: f64 = 150.0;

/// The lobe view: a polar plot per plane (xz; and yz for anisotropic sources), the source
/// solid, the reference dashed.
pub fn lobe_view(source: &Subject, reference: Option<&Subject>, opts: &PlotOptions) -> Figure {
    let aniso = !source.brdf.is_isotropic() || reference.is_some_and(|r| !r.brdf.is_isotropic());
    let planes: &[f64] = if aniso { &[0.0, 90.0] } else { &[0.0] };
    let pw = (2.0 * LOBE_R) as usize + 60;
    let width = (2 * MARGIN + planes.len() * pw).max(420);
    let height = TOP + LOBE_R as usize + 90;
    let mut fig = Figure::new(width, height);
    let scale = match opts.lobe_radius {
        RadiusScale::Linear => "linear radius".to_string(),
        RadiusScale::Log => format!("log radius, {} decades", label_number(opts.lobe_decades)),
    };
    titles(
        &mut fig,
        "lobe: f·cosθo (luminance) in the plane of incidence, light from the right",
        &format!(
            "{scale}; solid {}{}",
            shorten(&source.label, LABEL_CHARS),
            reference
                .map(|r| format!(", dashed ref {}", shorten(&r.label, LABEL_CHARS)))
                .unwrap_or_default()
        ),
    );
    for (pi, &plane) in planes.iter().enumerate() {
        let src = lobe_curves(
            source.brdf.as_ref(),
            plane,
            &opts.lobe_theta_i_deg,
            opts.lobe_samples,
        );
        let rf = reference.map(|r| {
            lobe_curves(
                r.brdf.as_ref(),
                plane,
                &opts.lobe_theta_i_deg,
                opts.lobe_samples,
            )
        });
        let vmax = src
            .iter()
            .chain(rf.iter().flatten())
            .flat_map(|c| c.values.iter().copied())
            .fold(0.0, f64::max);
        let vmax = if vmax > 0.0 { vmax } else { 1.0 };
        let radius = |v: f64| -> f64 {
            match opts.lobe_radius {
                RadiusScale::Linear => (v / vmax).max(0.0) * LOBE_R,
                RadiusScale::Log => {
                    let lo = vmax.log10() - opts.lobe_decades;
                    if v <= 0.0 {
                        0.0
                    } else {
                        ((v.log10() - lo) / opts.lobe_decades).clamp(0.0, 1.0) * LOBE_R
                    }
                }
            }
        };
        let cx = (MARGIN + pi * pw + pw / 2) as f64;
        // Room above the outer ring for the 0° label.
        let cy = TOP as f64 + LOBE_R + 30.0;
        let at = |r: f64, t_deg: f64| {
            let t = t_deg.to_radians();
            (cx + r * t.sin(), cy - r * t.cos())
        };
        // Guides: rings and radial lines every 30°.
        let rings: Vec<(f64, String)> = match opts.lobe_radius {
            RadiusScale::Linear => (1..=4)
                .map(|k| {
                    let f = k as f64 / 4.0;
                    (f * LOBE_R, label_number(f * vmax))
                })
                .collect(),
            RadiusScale::Log => {
                let d = opts.lobe_decades.floor().max(1.0) as i32;
                (0..d)
                    .map(|k| {
                        let v = vmax / 10f64.powi(k);
                        (radius(v), label_number(v))
                    })
                    .collect()
            }
        };
        for (r, label) in &rings {
            let pts = (0..=90).map(|k| at(*r, -90.0 + 2.0 * k as f64)).collect();
            // Ring labels on the light's side of the baseline.
            fig.items.push(Item::Polyline {
                points: pts,
                color: GUIDE,
                width: 1.0,
                dashed: false,
            });
            fig.text(cx + r, cy + 12.0, label.clone(), Anchor::Middle);
        }
        for k in 0..=6 {
            let t = -90.0 + 30.0 * k as f64;
            fig.line((cx, cy), at(LOBE_R, t), GUIDE, 1.0, false);
            let (lx, ly) = at(LOBE_R + 20.0, t);
            fig.text(lx, ly + 4.0, format!("{}°", t.abs()), Anchor::Middle);
        }
        fig.line((cx - LOBE_R, cy), (cx + LOBE_R, cy), AXIS, 1.0, false);
        for (k, c) in src.iter().enumerate() {
            let color = line_color(k);
            // Incidence: a tick outside the plot on the light's side.
            fig.line(
                at(LOBE_R + 2.0, c.theta_i_deg),
                at(LOBE_R + 8.0, c.theta_i_deg),
                color,
                2.0,
                false,
            );
            if let Some(rf) = &rf {
                fig.items.push(Item::Polyline {
                    points: rf[k]
                        .angles_deg
                        .iter()
                        .zip(&rf[k].values)
                        .map(|(&t, &v)| at(radius(v), t))
                        .collect(),
                    color,
                    width: 1.5,
                    dashed: true,
                });
            }
            fig.items.push(Item::Polyline {
                points: c
                    .angles_deg
                    .iter()
                    .zip(&c.values)
                    .map(|(&t, &v)| at(radius(v), t))
                    .collect(),
                color,
                width: 1.5,
                dashed: false,
            });
            let lx = MARGIN + pi * pw + 8 + k * 70;
            fig.items.push(Item::Text {
                x: lx as f64,
                y: cy + 44.0,
                text: format!("θi={}°", label_number(c.theta_i_deg)),
                anchor: Anchor::Start,
                color,
            });
        }
        fig.text(
            cx,
            cy + 28.0,
            format!(
                "plane φ={}°, max {}",
                label_number(plane),
                label_number(vmax)
            ),
            Anchor::Middle,
        );
    }
    fig
}

// ---------------------------------------------------------------------------------------
// slice

/// Resolution (θh × θd) of a slice of a source that is not a half/difference table.
pub const SLICE_DEFAULT_RESOLUTION: usize = 90;

/// The cells of a θh × θd slice: where they come from and the direction pair of each.
pub struct SliceCells {
    /// The table grid the cells are (None: the default MERL-like sampling of a model).
    pub grid: Option<Grid>,
    pub n_theta_h: usize,
    pub n_theta_d: usize,
    /// The φd actually shown (a table's nearest stored value), degrees.
    pub phi_d_deg: f64,
    /// Per cell (index `id * n_theta_h + ih`): the flat index into the table, when a grid.
    pub table_cell: Vec<usize>,
    /// Per cell: the sample's direction pair.
    pub pairs: Vec<(Vec3, Vec3)>,
    /// Position in cells (0 = low edge of the first) of a θh and of a θd in degrees, for
    /// axis labels (the axes may be warped).
    pub theta_h_pos: Box<dyn Fn(f64) -> f64 + Send + Sync>,
    pub theta_d_pos: Box<dyn Fn(f64) -> f64 + Send + Sync>,
}

/// Position (in cells, 0 = low edge of the first cell) of angle `deg` on a table axis.
fn axis_pos(grid: &Grid, k: usize, deg: f64) -> f64 {
    let a = &grid.axes()[k];
    let off = match a.placement {
        Placement::Center => 0.5,
        Placement::LowerEdge => 0.0,
    };
    a.continuous_index(deg.to_radians()) + off
}

/// The slice cells for a table `grid` on a half/difference grid, or the default sampling.
pub fn slice_cells(grid: Option<&Grid>, phi_d_deg: f64) -> SliceCells {
    if let Some(g) = grid
        && matches!(g.kind(), GridKind::Halfdiff3 | GridKind::Halfdiff4)
    {
        let hd4 = g.kind() == GridKind::Halfdiff4;
        let (kh, kd, kp) = if hd4 { (0, 2, 3) } else { (0, 1, 2) };
        let axes = g.axes();
        let nearest = |k: usize, rad: f64| -> usize {
            let a = &axes[k];
            let mut best = 0;
            for i in 0..a.n {
                let dist = |j: usize| {
                    let d = (a.sample(j) - rad).rem_euclid(2.0 * PI);
                    d.min(2.0 * PI - d)
                };
                if dist(i) < dist(best) {
                    best = i;
                }
            }
            best
        };
        // halfdiff3 folds φd into [0, π): φd and φd + π are the same pair swapped.
        let phi = if hd4 {
            phi_d_deg.to_radians()
        } else {
            phi_d_deg.to_radians().rem_euclid(PI)
        };
        let ip = nearest(kp, phi);
        let iph = if hd4 { nearest(1, 0.0) } else { 0 };
        let (nh, nd) = (axes[kh].n, axes[kd].n);
        let shape = g.shape();
        let mut table_cell = Vec::with_capacity(nh * nd);
        let mut pairs = Vec::with_capacity(nh * nd);
        for id in 0..nd {
            for ih in 0..nh {
                let idx: Vec<usize> = if hd4 {
                    vec![ih, iph, id, ip]
                } else {
                    vec![ih, id, ip]
                };
                let flat = idx.iter().zip(&shape).fold(0, |acc, (&i, &n)| acc * n + i);
                table_cell.push(flat);
                pairs.push(g.cell_dirs(&idx));
            }
        }
        let gh = g.clone();
        let gd = g.clone();
        return SliceCells {
            grid: Some(g.clone()),
            n_theta_h: nh,
            n_theta_d: nd,
            phi_d_deg: axes[kp].sample(ip).to_degrees(),
            table_cell,
            pairs,
            theta_h_pos: Box::new(move |deg| axis_pos(&gh, kh, deg)),
            theta_d_pos: Box::new(move |deg| axis_pos(&gd, kd, deg)),
        };
    }
    // MERL's layout: θh warped by a square root, θd linear, at cell centres.
    let n = SLICE_DEFAULT_RESOLUTION;
    let half_pi = PI / 2.0;
    let mut pairs = Vec::with_capacity(n * n);
    for id in 0..n {
        for ih in 0..n {
            let u = (ih as f64 + 0.5) / n as f64;
            pairs.push(
                HalfDiff {
                    theta_h: half_pi * u * u,
                    phi_h: 0.0,
                    theta_d: half_pi * (id as f64 + 0.5) / n as f64,
                    phi_d: phi_d_deg.to_radians(),
                }
                .to_dirs(),
            );
        }
    }
    SliceCells {
        grid: None,
        n_theta_h: n,
        n_theta_d: n,
        phi_d_deg,
        table_cell: Vec::new(),
        pairs,
        theta_h_pos: Box::new(move |deg| (deg / 90.0).max(0.0).sqrt() * n as f64),
        theta_d_pos: Box::new(move |deg| deg / 90.0 * n as f64),
    }
}

/// Luminance and validity of each slice cell for one subject: a table on the slice's grid
/// gives its stored cells and validity mask; anything else is evaluated at the cells' pairs
/// (valid where both directions are above the horizon).
fn slice_values(subject: &Subject, cells: &SliceCells) -> (Vec<f64>, Vec<bool>) {
    let display = Display::for_brdf(subject.brdf.as_ref());
    if let (Some(t), Some(g)) = (&subject.table, &cells.grid)
        && t.grid() == g
    {
        let valid = t.valid();
        return cells
            .table_cell
            .iter()
            .zip(&cells.pairs)
            .map(|(&flat, &(wi, wo))| {
                let v: Vec<f64> = t.cell(flat).iter().map(|&x| f64::from(x)).collect();
                let y = display.luminance(&v);
                // A valid cell below the horizon (an extended grid's) is no BRDF value.
                let shown = valid[flat] && wi.z > 0.0 && wo.z > 0.0;
                (if y.is_finite() { y } else { 0.0 }, shown)
            })
            .unzip();
    }
    let nc = subject.brdf.channels().len();
    cells
        .pairs
        .par_iter()
        .map_init(
            || vec![0.0; nc],
            |f, &(wi, wo)| {
                if !(wi.z > 0.0 && wo.z > 0.0) {
                    return (0.0, false);
                }
                subject.brdf.eval(wi, wo, f);
                let y = display.luminance(f);
                (if y.is_finite() { y } else { 0.0 }, true)
            },
        )
        .unzip()
}

fn slice_image(cells: &SliceCells, color: impl Fn(usize) -> Rgb) -> RgbImage {
    let (nh, nd) = (cells.n_theta_h, cells.n_theta_d);
    let mut img = RgbImage::new(nh, nd, INVALID);
    for id in 0..nd {
        for ih in 0..nh {
            // θd = 0 at the bottom.
            img.set(ih, nd - 1 - id, color(id * nh + ih));
        }
    }
    img
}

/// Axis ticks of a slice panel at (x, y) of size w × h (scale px per cell).
fn slice_axes(fig: &mut Figure, cells: &SliceCells, x: usize, y: usize, scale: usize) {
    let (w, h) = (cells.n_theta_h * scale, cells.n_theta_d * scale);
    let bottom = (y + h) as f64;
    let mut last = f64::NEG_INFINITY;
    for deg in [0.0, 1.0, 5.0, 10.0, 20.0, 30.0, 45.0, 60.0, 75.0, 90.0] {
        let px = x as f64 + (cells.theta_h_pos)(deg) * scale as f64;
        if !(px >= x as f64 - 0.5 && px <= (x + w) as f64 + 0.5) || px - last < 22.0 {
            continue;
        }
        last = px;
        fig.line((px, bottom + 1.0), (px, bottom + 5.0), AXIS, 1.0, false);
        fig.text(px, bottom + 15.0, label_number(deg), Anchor::Middle);
    }
    let mut last = f64::INFINITY;
    for deg in [0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0] {
        let py = bottom - (cells.theta_d_pos)(deg) * scale as f64;
        if !(py >= y as f64 - 0.5 && py <= bottom + 0.5) || last - py < 14.0 {
            continue;
        }
        last = py;
        fig.line((x as f64 - 5.0, py), (x as f64 - 1.0, py), AXIS, 1.0, false);
        fig.text(x as f64 - 6.0, py + 5.0, label_number(deg), Anchor::End);
    }
}

/// Left margin of slice panels (θd tick labels).
const SLICE_LEFT: usize = 34;

/// The slice view: θh (x, MERL's warp for models) × θd (y, up) at one φd, log10 of the
/// luminance; table cells as stored, invalid cells grey; with a reference, three panels.
pub fn slice_view(source: &Subject, reference: Option<&Subject>, opts: &PlotOptions) -> Figure {
    let grid = source
        .table
        .as_ref()
        .map(|t| t.grid())
        .filter(|g| matches!(g.kind(), GridKind::Halfdiff3 | GridKind::Halfdiff4))
        .or_else(|| {
            reference
                .and_then(|r| r.table.as_ref())
                .map(|t| t.grid())
                .filter(|g| matches!(g.kind(), GridKind::Halfdiff3 | GridKind::Halfdiff4))
        });
    let cells = slice_cells(grid, opts.phi_d_deg);
    let (nh, nd) = (cells.n_theta_h, cells.n_theta_d);
    let scale = (270 / nh.max(nd)).max(1);
    let (pw, ph) = (nh * scale, nd * scale);
    let (sv, sok) = slice_values(source, &cells);
    let rv = reference.map(|r| slice_values(r, &cells));

    let vmax = sv
        .iter()
        .zip(&sok)
        .chain(rv.iter().flat_map(|(v, ok)| v.iter().zip(ok)))
        .filter(|(_, ok)| **ok)
        .map(|(v, _)| *v)
        .fold(0.0, f64::max);
    let hi = if vmax > 0.0 { vmax.log10().ceil() } else { 0.0 };
    let lo = hi - opts.slice_decades;
    let value_color = |v: f64| -> Rgb {
        if v <= 0.0 {
            ramp(0.0)
        } else {
            ramp((v.log10() - lo) / (hi - lo))
        }
    };

    let n_value = if reference.is_some() { 2 } else { 1 };
    let slot = SLICE_LEFT + pw + GAP;
    let width = (MARGIN
        + n_value * slot
        + BAR_SPACE
        + if reference.is_some() {
            slot + BAR_SPACE
        } else {
            0
        })
    .max(420);
    let top = TOP + 8;
    let height = top + ph + 42;
    let mut fig = Figure::new(width, height);
    let where_from = match &cells.grid {
        Some(g) => format!("table cells as stored, {}", g.describe()),
        None => format!("evaluated at {nh}x{nd} (θh sqrt-warped as MERL), grey: below the horizon"),
    };
    titles(
        &mut fig,
        &format!(
            "slice: log10 f (luminance), θh (x) × θd (y) at φd={}°, grey = invalid",
            label_number(cells.phi_d_deg)
        ),
        &where_from,
    );
    let cap_y = top + ph + 34;
    let mut x = MARGIN + SLICE_LEFT;
    let mut value_panel = |fig: &mut Figure, name: &str, label: &str, v: &[f64], ok: &[bool]| {
        let img = slice_image(&cells, |k| if ok[k] { value_color(v[k]) } else { INVALID });
        fig.image(name, x, top, scale, img);
        slice_axes(fig, &cells, x, top, scale);
        caption(fig, x, pw, cap_y, label);
        x += slot;
    };
    if let (Some(r), Some((v, ok))) = (reference, &rv) {
        value_panel(&mut fig, "reference", &format!("ref: {}", r.label), v, ok);
    }
    value_panel(&mut fig, "source", &source.label, &sv, &sok);
    let bar_x = x - SLICE_LEFT;
    colour_bar(&mut fig, bar_x, top + 14, ph - 14, lo, hi, "f, 1/sr");
    if let Some((rvals, rok)) = &rv {
        let x = bar_x + BAR_SPACE + SLICE_LEFT;
        let peak = rvals
            .iter()
            .zip(rok)
            .filter(|(_, ok)| **ok)
            .map(|(v, _)| *v)
            .fold(0.0, f64::max);
        let eps = (1e-3 * peak).max(1e-12);
        let both = |k: usize| sok[k] && rok[k];
        let img = slice_image(&cells, |k| {
            if both(k) {
                err_color(rel_err(sv[k], rvals[k], eps))
            } else {
                INVALID
            }
        });
        fig.image("error", x, top, scale, img);
        slice_axes(&mut fig, &cells, x, top, scale);
        let errs: Vec<f64> = (0..sv.len())
            .filter(|&k| both(k))
            .map(|k| rel_err(sv[k], rvals[k], eps))
            .collect();
        caption(
            &mut fig,
            x,
            pw,
            cap_y,
            &format!(
                "p50 {} p99 {}",
                label_number(percentile(errs.clone(), 0.5)),
                label_number(percentile(errs, 0.99))
            ),
        );
        colour_bar(
            &mut fig,
            x + pw + 8,
            top + 14,
            ph - 14,
            ERR_DECADES.0,
            ERR_DECADES.1,
            "rel. err",
        );
    }
    fig
}

// ---------------------------------------------------------------------------------------
// albedo

/// Incidence angles of the albedo view, degrees: 0, 5, …, 85.
fn albedo_angles() -> Vec<f64> {
    (0..18).map(|k| 5.0 * k as f64).collect()
}

/// Directional albedo per display channel (RGB, or one grey value) at each angle.
fn albedo_curves(brdf: &dyn Brdf, angles: &[f64]) -> (Vec<Vec<f64>>, bool) {
    let display = Display::for_brdf(brdf);
    let per_angle: Vec<[f64; 3]> = angles
        .iter()
        .map(|&deg| display.rgb(&crate::props::directional_albedo(brdf, deg.to_radians())))
        .collect();
    let grey = display.is_grey();
    let n = if grey { 1 } else { 3 };
    (
        (0..n)
            .map(|c| {
                per_angle
                    .iter()
                    .map(|v| if v[c].is_finite() { v[c] } else { 0.0 })
                    .collect()
            })
            .collect(),
        grey,
    )
}

/// The albedo view: a(θi) = ∫ f_r cos θo dωo per channel against θi (the props quadrature);
/// the reference dashed.
pub fn albedo_view(source: &Subject, reference: Option<&Subject>) -> Figure {
    let angles = albedo_angles();
    let (src, grey) = albedo_curves(source.brdf.as_ref(), &angles);
    let rf = reference.map(|r| albedo_curves(r.brdf.as_ref(), &angles));
    let amax = src
        .iter()
        .chain(rf.iter().flat_map(|(c, _)| c.iter()))
        .flatten()
        .copied()
        .fold(0.0, f64::max);
    // The y range: up to the next tenth above the largest value (at least 0.1).
    let ymax = ((amax * 1.02 * 10.0).ceil() / 10.0).max(0.1);
    let (pw, ph) = (360.0, 200.0);
    let left = (MARGIN + 44) as f64;
    let top = TOP as f64 + 6.0;
    let width = (left + pw + 20.0) as usize;
    let height = (top + ph + 50.0) as usize;
    let mut fig = Figure::new(width.max(420), height);
    titles(
        &mut fig,
        "albedo: a(θi) = ∫ f·cosθo dωo (props quadrature), φi = 0",
        &format!(
            "solid {}{}",
            shorten(&source.label, LABEL_CHARS),
            reference
                .map(|r| format!(", dashed ref {}", shorten(&r.label, LABEL_CHARS)))
                .unwrap_or_default()
        ),
    );
    let px = |deg: f64| left + deg / 90.0 * pw;
    let py = |a: f64| top + ph - a / ymax * ph;
    // Grid and labels: θi every 15°, a every tenth (or fifth when the range is large).
    for k in 0..=6 {
        let deg = 15.0 * k as f64;
        fig.line((px(deg), top), (px(deg), top + ph), GUIDE, 1.0, false);
        fig.text(px(deg), top + ph + 14.0, format!("{deg}°"), Anchor::Middle);
    }
    let tenths = (ymax * 10.0).round() as usize;
    let step = tenths.div_ceil(10).max(1);
    for k in (0..=tenths).step_by(step) {
        let a = k as f64 / 10.0;
        fig.line((left, py(a)), (left + pw, py(a)), GUIDE, 1.0, false);
        fig.text(left - 6.0, py(a) + 5.0, label_number(a), Anchor::End);
    }
    fig.items.push(Item::Frame {
        x: left as usize,
        y: top as usize,
        w: pw as usize + 1,
        h: ph as usize + 1,
        color: AXIS,
    });
    fig.text(left + pw / 2.0, top + ph + 30.0, "θi", Anchor::Middle);
    let channel_color = |c: usize, grey: bool| -> Rgb {
        if grey {
            TEXT
        } else {
            [[214, 39, 40], [44, 160, 44], [31, 119, 180]][c]
        }
    };
    let mut draw = |curves: &[Vec<f64>], grey: bool, dashed: bool| {
        for (c, curve) in curves.iter().enumerate() {
            fig.items.push(Item::Polyline {
                points: angles
                    .iter()
                    .zip(curve)
                    .map(|(&d, &a)| (px(d), py(a)))
                    .collect(),
                color: channel_color(c, grey),
                width: 1.5,
                dashed,
            });
        }
    };
    if let Some((c, g)) = &rf {
        draw(c, *g, true);
    }
    draw(&src, grey, false);
    let legend = if grey { "grey: Y" } else { "R G B channels" };
    fig.text(left + pw, top + ph + 30.0, legend, Anchor::End);
    fig
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::parse_grid_spec;

    #[test]
    fn halfdiff4_slice_takes_phi_h_zero_and_the_nearest_phi_d() {
        let g = parse_grid_spec("halfdiff4:8").unwrap();
        let axes = g.axes();
        let c = slice_cells(Some(&g), 100.0);
        assert_eq!((c.n_theta_h, c.n_theta_d), (axes[0].n, axes[2].n));
        // The φd shown is the stored sample nearest 100°.
        let best = (0..axes[3].n)
            .map(|i| axes[3].sample(i).to_degrees())
            .min_by(|a, b| (a - 100.0).abs().total_cmp(&(b - 100.0).abs()))
            .unwrap();
        assert_eq!(c.phi_d_deg, best);
        // Each cell's flat index is the C-order index of (ih, iφh, id, iφd) with the same pair.
        let mut idx = [0usize; 4];
        for (k, &flat) in c.table_cell.iter().enumerate() {
            g.unflatten(flat, &mut idx);
            assert_eq!((idx[0], idx[2]), (k % c.n_theta_h, k / c.n_theta_h));
            assert_eq!(axes[3].sample(idx[3]).to_degrees(), best);
            assert!(axes[1].sample(idx[1]).abs() <= PI / axes[1].n as f64 + 1e-12);
            assert_eq!(g.cell_dirs(&idx), c.pairs[k]);
        }
    }

    #[test]
    fn default_slice_is_merl_warped_and_its_pairs_have_the_asked_angles() {
        let c = slice_cells(None, 90.0);
        assert_eq!((c.n_theta_h, c.n_theta_d), (90, 90));
        for &(ih, id) in &[(0usize, 0usize), (45, 10), (89, 89)] {
            let (wi, wo) = c.pairs[id * 90 + ih];
            let hd = HalfDiff::from_dirs(wi, wo).unwrap();
            let u = (ih as f64 + 0.5) / 90.0;
            assert!((hd.theta_h - PI / 2.0 * u * u).abs() < 1e-12);
            assert!((hd.theta_d - PI / 2.0 * (id as f64 + 0.5) / 90.0).abs() < 1e-12);
        }
        // Tick positions follow the warp: 22.5° of θh is halfway along the axis.
        assert!(((c.theta_h_pos)(22.5) - 45.0).abs() < 1e-12);
        assert!(((c.theta_d_pos)(45.0) - 45.0).abs() < 1e-12);
    }

    #[test]
    fn percentile_is_nearest_rank() {
        assert_eq!(percentile(vec![3.0, 1.0, 2.0, f64::NAN], 0.5), 2.0);
        assert_eq!(percentile(vec![], 0.99), 0.0);
        assert_eq!(rel_err(1.1, 1.0, 0.0), 0.10000000000000009);
    }
}
