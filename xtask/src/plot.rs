//! A small line-plot renderer for loss curves: no system fonts, no C
//! dependencies. Lines, axes with ticks, a legend, and a 5×7 bitmap font.

use anyhow::Result;
use std::path::Path;

/// One line of the plot.
pub struct Series<'a> {
    /// Legend text.
    pub name: &'a str,
    /// RGB colour.
    pub color: [u8; 3],
    /// (x, y) points.
    pub points: Vec<(f64, f64)>,
}

/// An RGB raster.
pub(crate) struct Canvas {
    pub(crate) w: usize,
    pub(crate) h: usize,
    pub(crate) px: Vec<u8>,
}

impl Canvas {
    /// A white canvas.
    pub(crate) fn new(w: usize, h: usize) -> Canvas {
        Canvas {
            w,
            h,
            px: vec![255; w * h * 3],
        }
    }

    pub(crate) fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let i = (y as usize * self.w + x as usize) * 3;
            self.px[i..i + 3].copy_from_slice(&c);
        }
    }

    /// A line `thick` pixels wide.
    pub(crate) fn line(
        &mut self,
        (x0, y0): (f64, f64),
        (x1, y1): (f64, f64),
        c: [u8; 3],
        thick: i64,
    ) {
        let n = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as i64).max(1);
        for i in 0..=n {
            let t = i as f64 / n as f64;
            let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
            for dx in 0..thick {
                for dy in 0..thick {
                    self.set(
                        x.round() as i64 + dx - thick / 2,
                        y.round() as i64 + dy - thick / 2,
                        c,
                    );
                }
            }
        }
    }

    /// Text in the 5×7 font, top-left at `(x, y)`.
    pub(crate) fn text(&mut self, x: i64, y: i64, s: &str, c: [u8; 3]) {
        for (k, ch) in s.chars().enumerate() {
            let g = glyph(ch);
            for (row, bits) in g.iter().enumerate() {
                for col in 0..5 {
                    if bits & (0x10 >> col) != 0 {
                        self.set(x + k as i64 * 6 + col, y + row as i64, c);
                    }
                }
            }
        }
    }
}

/// 5×7 glyphs for the characters labels use (others draw as a box).
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_lowercase() {
        '0' => [14, 17, 19, 21, 25, 17, 14],
        '1' => [4, 12, 4, 4, 4, 4, 14],
        '2' => [14, 17, 1, 2, 4, 8, 31],
        '3' => [31, 2, 4, 2, 1, 17, 14],
        '4' => [2, 6, 10, 18, 31, 2, 2],
        '5' => [31, 16, 30, 1, 1, 17, 14],
        '6' => [6, 8, 16, 30, 17, 17, 14],
        '7' => [31, 1, 2, 4, 8, 8, 8],
        '8' => [14, 17, 17, 14, 17, 17, 14],
        '9' => [14, 17, 17, 15, 1, 2, 12],
        '.' => [0, 0, 0, 0, 0, 12, 12],
        ',' => [0, 0, 0, 0, 12, 4, 8],
        '%' => [24, 25, 2, 4, 8, 19, 3],
        '-' => [0, 0, 0, 31, 0, 0, 0],
        '+' => [0, 4, 4, 31, 4, 4, 0],
        ' ' => [0; 7],
        '(' => [2, 4, 8, 8, 8, 4, 2],
        ')' => [8, 4, 2, 2, 2, 4, 8],
        '/' => [0, 1, 2, 4, 8, 16, 0],
        ':' => [0, 12, 12, 0, 12, 12, 0],
        'a' => [0, 0, 14, 1, 15, 17, 15],
        'b' => [16, 16, 22, 25, 17, 17, 30],
        'c' => [0, 0, 14, 16, 16, 17, 14],
        'd' => [1, 1, 13, 19, 17, 17, 15],
        'e' => [0, 0, 14, 17, 31, 16, 14],
        'f' => [6, 9, 8, 28, 8, 8, 8],
        'g' => [0, 15, 17, 17, 15, 1, 14],
        'h' => [16, 16, 22, 25, 17, 17, 17],
        'i' => [4, 0, 12, 4, 4, 4, 14],
        'k' => [16, 16, 18, 20, 24, 20, 18],
        'l' => [12, 4, 4, 4, 4, 4, 14],
        'm' => [0, 0, 26, 21, 21, 17, 17],
        'n' => [0, 0, 22, 25, 17, 17, 17],
        'o' => [0, 0, 14, 17, 17, 17, 14],
        'p' => [0, 0, 30, 17, 30, 16, 16],
        'r' => [0, 0, 22, 25, 16, 16, 16],
        's' => [0, 0, 14, 16, 14, 1, 30],
        't' => [8, 8, 28, 8, 8, 9, 6],
        'u' => [0, 0, 17, 17, 17, 19, 13],
        'v' => [0, 0, 17, 17, 17, 10, 4],
        'w' => [0, 0, 17, 17, 21, 21, 10],
        'x' => [0, 0, 17, 10, 4, 10, 17],
        'y' => [0, 0, 17, 17, 15, 1, 14],
        'z' => [0, 0, 31, 2, 4, 8, 31],
        _ => [31, 17, 17, 17, 17, 17, 31],
    }
}

fn tick_label(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(0.01..10000.0).contains(&a) {
        format!("{v:.1e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.2}")
    }
}

/// Render `series` into a PNG at `path`.
pub fn line_plot(
    path: &Path,
    title: &str,
    xlabel: &str,
    ylabel: &str,
    series: &[Series],
) -> Result<()> {
    let (w, h) = (900usize, 560usize);
    let (left, right, top, bottom) = (80.0, 20.0, 40.0, 60.0);
    let mut cv = Canvas::new(w, h);
    let pts = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|p| p.0.is_finite() && p.1.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !x0.is_finite() {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    if y1 <= y0 {
        y1 = y0 + 1.0;
    }
    let pad = (y1 - y0) * 0.05;
    let (y0, y1) = (y0 - pad, y1 + pad);
    let (pw, ph) = (w as f64 - left - right, h as f64 - top - bottom);
    let sx = |x: f64| left + (x - x0) / (x1 - x0) * pw;
    let sy = |y: f64| top + (1.0 - (y - y0) / (y1 - y0)) * ph;
    let grey = [200, 200, 200];
    let black = [0, 0, 0];
    for i in 0..=5 {
        let fy = y0 + (y1 - y0) * i as f64 / 5.0;
        cv.line((left, sy(fy)), (left + pw, sy(fy)), grey, 1);
        cv.text(4, sy(fy) as i64 - 3, &tick_label(fy), black);
        let fx = x0 + (x1 - x0) * i as f64 / 5.0;
        cv.line((sx(fx), top), (sx(fx), top + ph), grey, 1);
        let label = tick_label(fx);
        cv.text(
            sx(fx) as i64 - 3 * label.len() as i64,
            (top + ph) as i64 + 8,
            &label,
            black,
        );
    }
    cv.line((left, top), (left, top + ph), black, 2);
    cv.line((left, top + ph), (left + pw, top + ph), black, 2);
    for s in series {
        for p in s.points.windows(2) {
            if p.iter().all(|q| q.0.is_finite() && q.1.is_finite()) {
                cv.line(
                    (sx(p[0].0), sy(p[0].1)),
                    (sx(p[1].0), sy(p[1].1)),
                    s.color,
                    2,
                );
            }
        }
    }
    cv.text(left as i64, 14, title, black);
    cv.text(
        (left + pw / 2.0) as i64 - 3 * xlabel.len() as i64,
        h as i64 - 20,
        xlabel,
        black,
    );
    cv.text(4, 24, ylabel, black);
    for (i, s) in series.iter().enumerate() {
        let y = top as i64 + 10 + 14 * i as i64;
        let x = (left + pw) as i64 - 26 - 6 * s.name.len() as i64 - 10;
        cv.line(
            (x as f64, y as f64 + 3.0),
            (x as f64 + 20.0, y as f64 + 3.0),
            s.color,
            3,
        );
        cv.text(x + 26, y, s.name, black);
    }
    save_png(&cv, path)
}

/// Write a canvas as a PNG (write, then rename).
pub(crate) fn save_png(cv: &Canvas, path: &Path) -> Result<()> {
    save_apng(std::slice::from_ref(cv), 0, path)
}

/// Write canvases of one size as an animated PNG at `fps` frames per
/// second, looping (a single canvas gives a plain PNG).
pub(crate) fn save_apng(frames: &[Canvas], fps: u16, path: &Path) -> Result<()> {
    let Some(first) = frames.first() else {
        anyhow::bail!("{}: no frames to write", path.display());
    };
    crate::write_atomically(path, |file| {
        let mut enc = png::Encoder::new(
            std::io::BufWriter::new(file),
            first.w as u32,
            first.h as u32,
        );
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        if frames.len() > 1 {
            enc.set_animated(frames.len() as u32, 0)?;
            enc.set_frame_delay(1, fps.max(1))?;
        }
        let mut wr = enc.write_header()?;
        for f in frames {
            wr.write_image_data(&f.px)?;
        }
        wr.finish()?;
        Ok(())
    })
}

/// Render a histogram of `values` (non-finite ones are ignored) into a PNG.
pub fn histogram(
    path: &Path,
    title: &str,
    xlabel: &str,
    values: &[f64],
    bins: usize,
) -> Result<()> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    // Range: minimum to the 99.5th percentile, so a few outliers do not
    // flatten the rest; values above go into the last bin (and the legend).
    let lo = v.first().copied().unwrap_or(0.0);
    let hi = v
        .get((v.len() as f64 * 0.995) as usize)
        .or(v.last())
        .copied()
        .unwrap_or(1.0);
    let (lo, hi) = if hi > lo { (lo, hi) } else { (lo, lo + 1.0) };
    let above = v.iter().filter(|&&x| x > hi).count();
    let bins = bins.max(1);
    let mut counts = vec![0usize; bins];
    for x in &v {
        let k = (((x - lo) / (hi - lo)) * bins as f64) as usize;
        counts[k.min(bins - 1)] += 1;
    }
    // Draw each bin as a step outline: left edge, top, right edge.
    let width = (hi - lo) / bins as f64;
    let mut points = vec![(lo, 0.0)];
    for (k, &c) in counts.iter().enumerate() {
        let x0 = lo + k as f64 * width;
        points.push((x0, c as f64));
        points.push((x0 + width, c as f64));
    }
    points.push((hi, 0.0));
    let label = if above > 0 {
        format!(
            "{} values, {above} above {} in last bin",
            v.len(),
            tick_label(hi)
        )
    } else {
        format!("{} values", v.len())
    };
    line_plot(
        path,
        title,
        xlabel,
        "count",
        &[Series {
            name: &label,
            color: [31, 119, 180],
            points,
        }],
    )
}
