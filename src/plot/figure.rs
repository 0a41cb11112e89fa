//! A figure as a list of drawing items in pixel coordinates (origin top left, y down), drawn
//! by either backend ([`super::raster`] for PNG, [`super::svg`] for SVG) so both formats show
//! the same picture from one description.

/// An 8-bit sRGB colour.
pub type Rgb = [u8; 3];

pub const WHITE: Rgb = [255, 255, 255];
pub const BLACK: Rgb = [0, 0, 0];
pub const TEXT: Rgb = [20, 20, 20];
pub const AXIS: Rgb = [120, 120, 120];
pub const GUIDE: Rgb = [215, 215, 215];
/// Behind a rendered sphere: dark enough that the lit sphere stands out, not black, so that
/// the unlit side of the sphere (black) stays visible.
pub const SPHERE_BACKGROUND: Rgb = [48, 48, 48];
/// Table cells that hold no value (the grid's validity mask says so). Grey never occurs in
/// [`ramp`] (tested), so an invalid cell can never be mistaken for a value.
pub const INVALID: Rgb = [128, 128, 128];

/// A raster image placed on the figure, each of its pixels drawn as a `scale` × `scale` block.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    /// Row-major, top row first.
    pub pixels: Vec<Rgb>,
}

impl RgbImage {
    pub fn new(width: usize, height: usize, fill: Rgb) -> RgbImage {
        RgbImage {
            width,
            height,
            pixels: vec![fill; width * height],
        }
    }
    pub fn get(&self, x: usize, y: usize) -> Rgb {
        self.pixels[y * self.width + x]
    }
    pub fn set(&mut self, x: usize, y: usize, c: Rgb) {
        self.pixels[y * self.width + x] = c;
    }
}

/// Horizontal alignment of a text at its anchor point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Anchor {
    Start,
    Middle,
    End,
}

/// One thing drawn on a figure.
#[derive(Clone, Debug, PartialEq)]
pub enum Item {
    /// A filled rectangle.
    Fill {
        x: usize,
        y: usize,
        w: usize,
        h: usize,
        color: Rgb,
    },
    /// A one-pixel outline just inside the rectangle.
    Frame {
        x: usize,
        y: usize,
        w: usize,
        h: usize,
        color: Rgb,
    },
    /// An image with its top-left corner at (x, y).
    Image {
        x: usize,
        y: usize,
        scale: usize,
        image: RgbImage,
    },
    /// A polyline (a curve of a plot) of stroke width `width` pixels.
    Polyline {
        points: Vec<(f64, f64)>,
        color: Rgb,
        width: f64,
        dashed: bool,
    },
    /// One line of text; (x, y) is the baseline point at the anchor.
    Text {
        x: f64,
        y: f64,
        text: String,
        anchor: Anchor,
        color: Rgb,
    },
}

/// Where a named image panel sits on a figure (tests read pixels through it).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Panel {
    pub name: String,
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
    /// Figure pixels per image pixel.
    pub scale: usize,
}

/// A complete picture.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    pub width: usize,
    pub height: usize,
    pub background: Rgb,
    pub items: Vec<Item>,
    pub panels: Vec<Panel>,
}

/// Height of a line of text, in figure pixels (the raster font is 5 rows at scale 2).
pub const TEXT_HEIGHT: f64 = 10.0;
/// Advance of one character, in figure pixels (raster font; SVG text is about as wide).
pub const CHAR_ADVANCE: f64 = 8.0;

impl Figure {
    pub fn new(width: usize, height: usize) -> Figure {
        Figure {
            width,
            height,
            background: WHITE,
            items: Vec::new(),
            panels: Vec::new(),
        }
    }

    pub fn text(&mut self, x: f64, y: f64, text: impl Into<String>, anchor: Anchor) {
        self.items.push(Item::Text {
            x,
            y,
            text: text.into(),
            anchor,
            color: TEXT,
        });
    }

    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), color: Rgb, width: f64, dashed: bool) {
        self.items.push(Item::Polyline {
            points: vec![a, b],
            color,
            width,
            dashed,
        });
    }

    /// Places an image panel and records where it is.
    pub fn image(&mut self, name: &str, x: usize, y: usize, scale: usize, image: RgbImage) {
        self.panels.push(Panel {
            name: name.to_string(),
            x,
            y,
            width: image.width * scale,
            height: image.height * scale,
            scale,
        });
        self.items.push(Item::Image { x, y, scale, image });
    }

    /// The panel called `name`.
    pub fn panel(&self, name: &str) -> Option<&Panel> {
        self.panels.iter().find(|p| p.name == name)
    }

    /// Figures one above the other (left-aligned), on a white background.
    pub fn stack(parts: Vec<Figure>) -> Figure {
        let width = parts.iter().map(|f| f.width).max().unwrap_or(1);
        let height = parts.iter().map(|f| f.height).sum::<usize>().max(1);
        let mut out = Figure::new(width, height);
        let mut y0 = 0;
        for part in parts {
            if part.background != out.background {
                out.items.push(Item::Fill {
                    x: 0,
                    y: y0,
                    w: part.width,
                    h: part.height,
                    color: part.background,
                });
            }
            let dy = y0 as f64;
            for item in part.items {
                out.items.push(match item {
                    Item::Fill { x, y, w, h, color } => Item::Fill {
                        x,
                        y: y + y0,
                        w,
                        h,
                        color,
                    },
                    Item::Frame { x, y, w, h, color } => Item::Frame {
                        x,
                        y: y + y0,
                        w,
                        h,
                        color,
                    },
                    Item::Image { x, y, scale, image } => Item::Image {
                        x,
                        y: y + y0,
                        scale,
                        image,
                    },
                    Item::Polyline {
                        points,
                        color,
                        width,
                        dashed,
                    } => Item::Polyline {
                        points: points.into_iter().map(|(x, y)| (x, y + dy)).collect(),
                        color,
                        width,
                        dashed,
                    },
                    Item::Text {
                        x,
                        y,
                        text,
                        anchor,
                        color,
                    } => Item::Text {
                        x,
                        y: y + dy,
                        text,
                        anchor,
                        color,
                    },
                });
            }
            for mut p in part.panels {
                p.y += y0;
                out.panels.push(p);
            }
            y0 += part.height;
        }
        out
    }
}

/// The colour ramp of heat maps and slices, t in [0, 1] (clamped): black → purple → red →
/// orange → pale yellow, monotonic in lightness like matplotlib's "inferno" (these stops are
/// our own approximation of it).
pub fn ramp(t: f64) -> Rgb {
    const STOPS: [[f64; 3]; 11] = [
        [0.0, 0.0, 4.0],
        [22.0, 11.0, 57.0],
        [66.0, 10.0, 104.0],
        [106.0, 23.0, 110.0],
        [147.0, 38.0, 103.0],
        [188.0, 55.0, 84.0],
        [221.0, 81.0, 58.0],
        [243.0, 120.0, 25.0],
        [252.0, 165.0, 10.0],
        [246.0, 215.0, 70.0],
        [252.0, 255.0, 164.0],
    ];
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let s = t * (STOPS.len() - 1) as f64;
    let i = (s.floor() as usize).min(STOPS.len() - 2);
    let f = s - i as f64;
    std::array::from_fn(|c| {
        let v = STOPS[i][c] + (STOPS[i + 1][c] - STOPS[i][c]) * f;
        v.round().clamp(0.0, 255.0) as u8
    })
}

/// A palette of well-separated line colours (one per incidence angle, or per channel).
pub fn line_color(i: usize) -> Rgb {
    const PALETTE: [Rgb; 6] = [
        [31, 119, 180],
        [214, 39, 40],
        [44, 160, 44],
        [148, 103, 189],
        [255, 127, 14],
        [23, 190, 207],
    ];
    PALETTE[i % PALETTE.len()]
}

/// sRGB transfer function (IEC 61966-2-1) of a linear value, clipped to [0, 1].
pub fn srgb_encode(linear: f64) -> f64 {
    let v = if linear.is_nan() {
        0.0
    } else {
        linear.clamp(0.0, 1.0)
    };
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// A linear value to an 8-bit sRGB code (clip at 1, transfer function, round).
pub fn srgb_byte(linear: f64) -> u8 {
    (srgb_encode(linear) * 255.0).round() as u8
}

/// A number for an axis label: fixed digits, no exponent below 1e4 and above 1e-3, else
/// `1e-5` style; never NaN (written as `-`).
pub fn label_number(v: f64) -> String {
    if !v.is_finite() {
        return "-".into();
    }
    if v == 0.0 {
        return "0".into();
    }
    let a = v.abs();
    if (1e-3..1e4).contains(&a) {
        let s = if a >= 100.0 {
            format!("{v:.0}")
        } else if a >= 1.0 {
            format!("{v:.2}")
        } else {
            format!("{v:.3}")
        };
        // 0.500 → 0.5, 2.00 → 2
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        let e = a.log10().floor() as i32;
        let m = v / 10f64.powi(e);
        if (m.abs() - 1.0).abs() < 1e-9 {
            format!("{}1e{e}", if v < 0.0 { "-" } else { "" })
        } else {
            format!("{m:.1}e{e}")
        }
    }
}

/// The last `max` characters of a label (a long path keeps its file name).
pub fn shorten(label: &str, max: usize) -> String {
    let n = label.chars().count();
    if n <= max {
        label.to_string()
    } else {
        let tail: String = label.chars().skip(n - (max - 1)).collect();
        format!("…{tail}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_never_produces_the_invalid_grey() {
        for k in 0..=100_000 {
            let c = ramp(k as f64 / 100_000.0);
            assert_ne!(c, INVALID, "t = {}", k as f64 / 1e5);
        }
        assert_eq!(ramp(0.0), [0, 0, 4]);
        assert_eq!(ramp(1.0), [252, 255, 164]);
        assert_eq!(ramp(f64::NAN), ramp(0.0));
    }

    #[test]
    fn srgb_transfer_matches_the_standard_points() {
        assert_eq!(srgb_byte(0.0), 0);
        assert_eq!(srgb_byte(1.0), 255);
        assert_eq!(srgb_byte(7.0), 255);
        // 18% grey encodes to 0.4613 → 118 (IEC 61966-2-1).
        assert_eq!(srgb_byte(0.18), 118);
        assert!((srgb_encode(0.5) - 0.735_356_983).abs() < 1e-8);
    }

    #[test]
    fn labels_are_short_and_fixed() {
        assert_eq!(label_number(0.5), "0.5");
        assert_eq!(label_number(2.0), "2");
        assert_eq!(label_number(150.0), "150");
        assert_eq!(label_number(1e-4), "1e-4");
        assert_eq!(label_number(2.5e-5), "2.5e-5");
        assert_eq!(label_number(f64::NAN), "-");
        assert_eq!(shorten("abcdef", 4), "…def");
    }
}
