//! Drawing a [`Figure`] into pixels and encoding them as PNG. Lines are stamped squares along
//! the segment, text uses a 3×5 pixel font (capitals; drawn at scale 2): no system fonts, no
//! anti-aliasing, so the bytes depend on nothing but the figure.

use super::figure::{Anchor, CHAR_ADVANCE, Figure, Item, RgbImage, TEXT_HEIGHT};
use crate::{Error, Result};

/// Renders a figure into an image of its size.
pub fn rasterize(fig: &Figure) -> RgbImage {
    let mut img = RgbImage::new(fig.width, fig.height, fig.background);
    for item in &fig.items {
        match item {
            Item::Fill { x, y, w, h, color } => fill(&mut img, *x, *y, *w, *h, *color),
            Item::Frame { x, y, w, h, color } => {
                if *w > 0 && *h > 0 {
                    fill(&mut img, *x, *y, *w, 1, *color);
                    fill(&mut img, *x, y + h - 1, *w, 1, *color);
                    fill(&mut img, *x, *y, 1, *h, *color);
                    fill(&mut img, x + w - 1, *y, 1, *h, *color);
                }
            }
            Item::Image { x, y, scale, image } => {
                for j in 0..image.height * scale {
                    for i in 0..image.width * scale {
                        let (px, py) = (x + i, y + j);
                        if px < img.width && py < img.height {
                            img.set(px, py, image.get(i / scale, j / scale));
                        }
                    }
                }
            }
            Item::Polyline {
                points,
                color,
                width,
                dashed,
            } => polyline(&mut img, points, *color, *width, *dashed),
            Item::Text {
                x,
                y,
                text,
                anchor,
                color,
            } => draw_text(&mut img, *x, *y, text, *anchor, *color),
        }
    }
    img
}

fn fill(img: &mut RgbImage, x: usize, y: usize, w: usize, h: usize, c: [u8; 3]) {
    for py in y..(y + h).min(img.height) {
        for px in x..(x + w).min(img.width) {
            img.set(px, py, c);
        }
    }
}

fn plot_square(img: &mut RgbImage, cx: f64, cy: f64, half: f64, c: [u8; 3]) {
    let x0 = (cx - half).round();
    let y0 = (cy - half).round();
    let n = (2.0 * half).round().max(1.0) as i64;
    for dy in 0..n {
        for dx in 0..n {
            let (px, py) = (x0 as i64 + dx, y0 as i64 + dy);
            if px >= 0 && py >= 0 && (px as usize) < img.width && (py as usize) < img.height {
                img.set(px as usize, py as usize, c);
            }
        }
    }
}

/// Dash pattern in pixels of arc length: on, off.
const DASH: (f64, f64) = (6.0, 4.0);

fn polyline(img: &mut RgbImage, pts: &[(f64, f64)], c: [u8; 3], width: f64, dashed: bool) {
    let half = width / 2.0;
    let mut arc = 0.0;
    for seg in pts.windows(2) {
        let (a, b) = (seg[0], seg[1]);
        if !(a.0.is_finite() && a.1.is_finite() && b.0.is_finite() && b.1.is_finite()) {
            continue;
        }
        let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
        // Quarter-pixel steps leave no gaps for any slope.
        let steps = (len * 4.0).ceil().max(1.0) as usize;
        for k in 0..=steps {
            let t = k as f64 / steps as f64;
            let s = arc + t * len;
            if dashed && s % (DASH.0 + DASH.1) >= DASH.0 {
                continue;
            }
            plot_square(img, a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1), half, c);
        }
        arc += len;
    }
}

/// Width in pixels of `text` as drawn by the raster font.
pub fn text_width(text: &str) -> f64 {
    text.chars().count() as f64 * CHAR_ADVANCE - 2.0
}

fn draw_text(img: &mut RgbImage, x: f64, y: f64, text: &str, anchor: Anchor, c: [u8; 3]) {
    const SCALE: usize = 2;
    let w = text_width(text);
    let left = match anchor {
        Anchor::Start => x,
        Anchor::Middle => x - w / 2.0,
        Anchor::End => x - w,
    };
    let top = (y - TEXT_HEIGHT).round() as i64;
    let mut pen = left.round() as i64;
    for ch in text.chars() {
        let rows = glyph(ch);
        for (r, bits) in rows.iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) != 0 {
                    for dy in 0..SCALE {
                        for dx in 0..SCALE {
                            let px = pen + (col * SCALE + dx) as i64;
                            let py = top + (r * SCALE + dy) as i64;
                            if px >= 0
                                && py >= 0
                                && (px as usize) < img.width
                                && (py as usize) < img.height
                            {
                                img.set(px as usize, py as usize, c);
                            }
                        }
                    }
                }
            }
        }
        pen += CHAR_ADVANCE as i64;
    }
}

/// The 3×5 glyph of a character: five rows, bit 4 = left column. Letters are drawn as
/// capitals; a character without a glyph is drawn as `?`.
fn glyph(c: char) -> [u8; 5] {
    match c.to_ascii_uppercase() {
        ' ' => [0, 0, 0, 0, 0],
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        'A' => [2, 5, 7, 5, 5],
        'B' => [6, 5, 6, 5, 6],
        'C' => [3, 4, 4, 4, 3],
        'D' => [6, 5, 5, 5, 6],
        'E' => [7, 4, 6, 4, 7],
        'F' => [7, 4, 6, 4, 4],
        'G' => [3, 4, 5, 5, 3],
        'H' => [5, 5, 7, 5, 5],
        'I' => [7, 2, 2, 2, 7],
        'J' => [1, 1, 1, 5, 2],
        'K' => [5, 5, 6, 5, 5],
        'L' => [4, 4, 4, 4, 7],
        'M' => [5, 7, 7, 5, 5],
        'N' => [6, 5, 5, 5, 5],
        'O' => [2, 5, 5, 5, 2],
        'P' => [6, 5, 6, 4, 4],
        'Q' => [2, 5, 5, 6, 3],
        'R' => [6, 5, 6, 5, 5],
        'S' => [3, 4, 2, 1, 6],
        'T' => [7, 2, 2, 2, 2],
        'U' => [5, 5, 5, 5, 7],
        'V' => [5, 5, 5, 5, 2],
        'W' => [5, 5, 7, 7, 5],
        'X' => [5, 5, 2, 5, 5],
        'Y' => [5, 5, 2, 2, 2],
        'Z' => [7, 1, 2, 4, 7],
        '.' => [0, 0, 0, 0, 2],
        ',' => [0, 0, 0, 2, 4],
        ':' => [0, 2, 0, 2, 0],
        ';' => [0, 2, 0, 2, 4],
        '-' => [0, 0, 7, 0, 0],
        '−' => [0, 0, 7, 0, 0],
        '+' => [0, 2, 7, 2, 0],
        '=' => [0, 7, 0, 7, 0],
        '/' => [1, 1, 2, 4, 4],
        '(' => [1, 2, 2, 2, 1],
        ')' => [4, 2, 2, 2, 4],
        '[' => [3, 2, 2, 2, 3],
        ']' => [6, 2, 2, 2, 6],
        '<' => [1, 2, 4, 2, 1],
        '>' => [4, 2, 1, 2, 4],
        '|' => [2, 2, 2, 2, 2],
        '_' => [0, 0, 0, 0, 7],
        '%' => [5, 1, 2, 4, 5],
        '*' | '·' => [0, 0, 2, 0, 0],
        '×' => [0, 5, 2, 5, 0],
        '\'' => [2, 2, 0, 0, 0],
        '°' => [2, 5, 2, 0, 0],
        '…' => [0, 0, 0, 0, 5],
        'θ' => [2, 5, 7, 5, 2],
        'φ' => [2, 7, 5, 7, 2],
        'α' => [0, 3, 5, 5, 3],
        'ε' => [3, 4, 6, 4, 3],
        'π' => [0, 7, 5, 5, 5],
        'ρ' => [0, 6, 5, 6, 4],
        'Δ' => [0, 2, 5, 5, 7],
        '≤' => [1, 2, 1, 0, 7],
        '∫' => [1, 2, 2, 2, 4],
        'ω' => [0, 5, 5, 7, 2],
        _ => [6, 1, 2, 0, 2],
    }
}

/// PNG bytes of an image (8-bit RGB, no metadata chunks: the same image gives the same bytes).
pub fn encode_png(img: &RgbImage) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, img.width as u32, img.height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::High);
        let mut writer = enc
            .write_header()
            .map_err(|e| Error::Failure(format!("PNG encoding: {e}")))?;
        let data: Vec<u8> = img.pixels.iter().flatten().copied().collect();
        writer
            .write_image_data(&data)
            .map_err(|e| Error::Failure(format!("PNG encoding: {e}")))?;
        writer
            .finish()
            .map_err(|e| Error::Failure(format!("PNG encoding: {e}")))?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plot::figure::{BLACK, Figure};

    #[test]
    fn a_horizontal_line_covers_its_pixels() {
        let mut f = Figure::new(20, 5);
        f.line((2.0, 2.0), (17.0, 2.0), BLACK, 1.0, false);
        let img = rasterize(&f);
        for x in 2..=17 {
            assert_eq!(img.get(x, 2), BLACK, "x = {x}");
        }
        assert_ne!(img.get(1, 2), BLACK);
        assert_ne!(img.get(10, 1), BLACK);
    }

    #[test]
    fn png_round_trips() {
        let mut img = RgbImage::new(3, 2, [1, 2, 3]);
        img.set(2, 1, [200, 100, 50]);
        let bytes = encode_png(&img).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (3, 2));
        assert_eq!(&buf[..3], &[1, 2, 3]);
        assert_eq!(&buf[15..18], &[200, 100, 50]);
    }
}
