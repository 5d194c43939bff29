//! A top-down plot of steering: the asked path (thick black) and the roots
//! that followed it (thin coloured lines, a dot at each first frame), in
//! metres, x to the right and z up the picture, on equal axis scales. Drawn
//! with [`crate::chart`]'s chart layout.

use crate::canvas::{save_png, Canvas};
use crate::chart::{plot, style, DrawErr};
use crate::RenderError;
use plotters::prelude::*;
use std::ops::Range;

/// Picture size in pixels (square).
const SIZE: u32 = 800;

/// Root colours, in turn (matplotlib's `tab10`).
const PALETTE: [[u8; 3]; 10] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
];

/// Roots beyond this many are drawn but left out of the legend.
const LEGEND_ROOTS: usize = 10;

fn finite(p: &&[f64; 2]) -> bool {
    p[0].is_finite() && p[1].is_finite()
}

fn xy(p: &[f64; 2]) -> (f64, f64) {
    (p[0], p[1])
}

/// The asked path and each root's path seen from above, as a PNG of about
/// 800×800 pixels: metres, x right, z up, equal scales. Non-finite points are
/// skipped.
pub fn top_down(
    path: &std::path::Path,
    title: &str,
    asked: &[[f64; 2]],
    roots: &[Vec<[f64; 2]>],
) -> Result<(), RenderError> {
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for p in asked.iter().chain(roots.iter().flatten()).filter(finite) {
        for k in 0..2 {
            (lo[k], hi[k]) = (lo[k].min(p[k]), hi[k].max(p[k]));
        }
    }
    let img = |e: DrawErr| RenderError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let labels = (title, "x (m, right)", "z (m, forward)");
    // The plotting area's size does not depend on the ranges: lay the chart
    // out once on a scratch canvas to read it.
    let mut dims = (1, 1);
    let mut scratch = Canvas::new(SIZE, SIZE)?;
    plot(&mut scratch, labels, (0.0..1.0, 0.0..1.0), |c| {
        dims = c.plotting_area().dim_in_pixel();
        Ok(())
    })
    .map_err(img)?;
    let ranges = equal_ranges(lo, hi, dims);
    let mut canvas = Canvas::new(SIZE, SIZE)?;
    plot(&mut canvas, labels, ranges, |chart| {
        let black = style([0, 0, 0], 4);
        chart
            .draw_series(LineSeries::new(asked.iter().filter(finite).map(xy), black))?
            .label("asked path")
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], black));
        for (i, root) in roots.iter().enumerate() {
            let rgb = PALETTE[i % PALETTE.len()];
            let thin = style(rgb, 1);
            let drawn =
                chart.draw_series(LineSeries::new(root.iter().filter(finite).map(xy), thin))?;
            if i < LEGEND_ROOTS {
                drawn
                    .label(format!("root {}", i + 1))
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], thin));
            }
            if let Some(first) = root.iter().find(finite) {
                let dot = Circle::new(xy(first), 5, style(rgb, 1).filled());
                chart.draw_series(std::iter::once(dot))?;
            }
        }
        Ok(())
    })
    .map_err(img)?;
    save_png(&canvas, path)
}

/// x and z ranges holding the box `lo..hi` (padded by 5 %, at least 1 m
/// wide) with the same metres per pixel on a plotting area of `dims` pixels.
fn equal_ranges(lo: [f64; 2], hi: [f64; 2], dims: (u32, u32)) -> (Range<f64>, Range<f64>) {
    let (lo, hi) = if lo[0] <= hi[0] {
        (lo, hi)
    } else {
        ([-1.0; 2], [1.0; 2])
    };
    let px = [dims.0.max(1) as f64, dims.1.max(1) as f64];
    let span = |k: usize| ((hi[k] - lo[k]) * 1.1).max(1.0);
    let per_px = (span(0) / px[0]).max(span(1) / px[1]);
    let range = |k: usize| {
        let (c, half) = ((lo[k] + hi[k]) / 2.0, per_px * px[k] / 2.0);
        c - half..c + half
    };
    (range(0), range(1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canvas::read_png;

    #[test]
    fn scales_are_equal() {
        // 10 m by 2 m on 600×300 pixels: x needs 11 m / 600 px, more than
        // z's 2.2 m / 300 px, so z gets 300 · 11/600 = 5.5 m around 1.
        let (x, z) = equal_ranges([0.0, 0.0], [10.0, 2.0], (600, 300));
        assert!((x.start + 0.5).abs() < 1e-12 && (x.end - 10.5).abs() < 1e-12);
        assert!((z.start + 1.75).abs() < 1e-12 && (z.end - 3.75).abs() < 1e-12);
        let (x, z) = equal_ranges([f64::MAX; 2], [f64::MIN; 2], (100, 100));
        assert_eq!((x, z), (-1.1..1.1, -1.1..1.1));
    }

    #[test]
    fn the_plot_is_written_the_same_twice() {
        let tmp = tempfile::tempdir().unwrap();
        let asked = [[0.0, 0.0], [0.0, 5.0], [-2.5, 5.0]];
        let roots = vec![
            (0..60).map(|t| [0.02 * t as f64, 0.1 * t as f64]).collect(),
            vec![[0.5, 0.0], [f64::NAN, 1.0], [0.5, 4.0], [-2.0, 5.5]],
        ];
        let (a, b) = (tmp.path().join("a.png"), tmp.path().join("b.png"));
        top_down(&a, "circle:2, 3 seeds", &asked, &roots).unwrap();
        top_down(&b, "circle:2, 3 seeds", &asked, &roots).unwrap();
        let bytes = std::fs::read(&a).unwrap();
        assert_eq!(bytes, std::fs::read(&b).unwrap());
        let (w, h, px) = read_png(&a);
        assert_eq!((w, h), (SIZE, SIZE));
        let black = px.chunks(3).filter(|c| c == &[0, 0, 0]).count();
        assert!(
            black > 500,
            "the asked path is thick ({black} black pixels)"
        );
        let blue = px.chunks(3).filter(|c| c == &PALETTE[0]).count();
        assert!(
            blue > 40,
            "the first root's start is marked ({blue} pixels)"
        );
        let orange = px.chunks(3).filter(|c| c == &PALETTE[1]).count();
        assert!(orange > 40, "the second root is drawn ({orange} pixels)");
    }
}
