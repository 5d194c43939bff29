//! Charts drawn with `plotters` on the anti-aliased [`Canvas`]: line charts
//! (the training loss) and histograms (the dataset audit). Axes get
//! `plotters`' round tick values, a light grid, axis titles and a legend.

use crate::canvas::{save_png, Backend, Canvas, NoError, FONT_FAMILY};
use crate::RenderError;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;
use std::ops::Range;
use std::path::Path;

/// Chart size in pixels.
const SIZE: (u32, u32) = (900, 560);

/// One line of a chart.
pub struct Series<'a> {
    /// Legend text.
    pub name: &'a str,
    /// RGB colour.
    pub color: [u8; 3],
    /// `(x, y)` points; non-finite ones are skipped.
    pub points: Vec<(f64, f64)>,
}

pub(crate) fn style(rgb: [u8; 3], width: u32) -> ShapeStyle {
    ShapeStyle {
        color: RGBColor(rgb[0], rgb[1], rgb[2]).to_rgba(),
        filled: false,
        stroke_width: width,
    }
}

pub(crate) type DrawErr = DrawingAreaErrorKind<NoError>;

/// A tick label: integers without decimals, others with at most three
/// significant digits and no trailing zeros.
pub fn tick(v: &f64) -> String {
    let v = *v;
    if v == 0.0 || !v.is_finite() {
        return "0".into();
    }
    if (v - v.round()).abs() < 1e-9 * v.abs().max(1.0) && v.abs() < 1e7 {
        return format!("{v:.0}");
    }
    let decimals = (2 - v.abs().log10().floor() as i32).clamp(0, 8) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// Range `[lo, hi]` padded by 5% (or widened when empty).
fn padded(lo: f64, hi: f64) -> Range<f64> {
    if !(lo.is_finite() && hi.is_finite()) {
        return 0.0..1.0;
    }
    if hi <= lo {
        return lo - 0.5..lo + 0.5;
    }
    let pad = (hi - lo) * 0.05;
    lo - pad..hi + pad
}

/// The chart context every chart draws its data on.
pub(crate) type Chart<'a, 'b, X, Y> = ChartContext<
    'a,
    Backend<'b>,
    Cartesian2d<<X as AsRangedCoord>::CoordDescType, <Y as AsRangedCoord>::CoordDescType>,
>;

/// A chart on `canvas`: title, axes with round tick labels, a light grid,
/// the data drawn by `data` (which labels its series), a legend.
pub(crate) fn plot<X, Y>(
    canvas: &mut Canvas,
    (title, xlabel, ylabel): (&str, &str, &str),
    (x, y): (X, Y),
    data: impl FnOnce(&mut Chart<'_, '_, X, Y>) -> Result<(), DrawErr>,
) -> Result<(), DrawErr>
where
    X: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y: AsRangedCoord<Value = f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let root = canvas.backend().into_drawing_area();
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT_FAMILY, 22))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(80)
        .build_cartesian_2d(x, y)?;
    chart
        .configure_mesh()
        .x_desc(xlabel)
        .y_desc(ylabel)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .y_labels(12)
        .label_style((FONT_FAMILY, 14))
        .axis_desc_style((FONT_FAMILY, 16))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(RGBColor(244, 244, 244))
        .draw()?;
    data(&mut chart)?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FONT_FAMILY, 15))
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(180, 180, 180))
        .draw()?;
    root.present()
}

fn draw_lines<Y>(
    canvas: &mut Canvas,
    labels: (&str, &str, &str),
    series: &[Series],
    x: Range<f64>,
    y: Y,
) -> Result<(), DrawErr>
where
    Y: AsRangedCoord<Value = f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    plot(canvas, labels, (x, y), |chart| {
        for s in series {
            let st = style(s.color, 2);
            chart
                .draw_series(LineSeries::new(
                    s.points
                        .iter()
                        .copied()
                        .filter(|p| p.0.is_finite() && p.1.is_finite()),
                    st,
                ))?
                .label(s.name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], st));
        }
        Ok(())
    })
}

/// A line chart of `series` as a PNG. The y axis is logarithmic when every
/// value is positive and they span more than a factor of 20, else linear.
pub fn line_chart(
    path: &Path,
    title: &str,
    xlabel: &str,
    ylabel: &str,
    series: &[Series],
) -> Result<(), RenderError> {
    let pts = || {
        series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|p| p.0.is_finite() && p.1.is_finite())
    };
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts() {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    let x = if x1 > x0 { x0..x1 } else { padded(x0, x1) };
    let mut canvas = Canvas::new(SIZE.0, SIZE.1)?;
    let labels = (title, xlabel, ylabel);
    let r = if y0 > 0.0 && y1 / y0 > 20.0 {
        // Ticks at 1, 2 and 5 times the powers of ten in range.
        let (lo, hi) = (y0 / 1.2, y1 * 1.2);
        let ticks: Vec<f64> = (lo.log10().floor() as i32..=hi.log10().ceil() as i32)
            .flat_map(|e| [1.0, 2.0, 5.0].map(|m| m * 10f64.powi(e)))
            .filter(|v| (lo..=hi).contains(v))
            .collect();
        draw_lines(
            &mut canvas,
            labels,
            series,
            x,
            (lo..hi).log_scale().with_key_points(ticks),
        )
    } else {
        draw_lines(&mut canvas, labels, series, x, padded(y0, y1))
    };
    r.map_err(|e| RenderError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    save_png(&canvas, path)
}

/// A histogram of `values` (non-finite ones ignored) as a PNG: `bins` bars
/// from the minimum to the 99.5th percentile, so a few outliers do not
/// flatten the rest; values above go into the last bar and the legend.
pub fn histogram(
    path: &Path,
    title: &str,
    xlabel: &str,
    values: &[f64],
    bins: usize,
) -> Result<(), RenderError> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
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
    let label = if above > 0 {
        format!(
            "{} values; {above} above {} in the last bar",
            v.len(),
            tick(&hi)
        )
    } else {
        format!("{} values", v.len())
    };
    let top = counts.iter().copied().max().unwrap_or(0).max(1) as f64 * 1.08;
    let width = (hi - lo) / bins as f64;
    let mut canvas = Canvas::new(SIZE.0, SIZE.1)?;
    let fill = RGBColor(31, 119, 180).filled();
    let r = plot(
        &mut canvas,
        (title, xlabel, "count"),
        (lo..hi, 0.0..top),
        |chart| {
            chart
                .draw_series(counts.iter().enumerate().map(|(k, &c)| {
                    let x0 = lo + k as f64 * width;
                    Rectangle::new([(x0, 0.0), (x0 + width * 0.92, c as f64)], fill)
                }))?
                .label(label.as_str())
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 16, y + 5)], fill));
            Ok(())
        },
    );
    r.map_err(|e| RenderError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    save_png(&canvas, path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canvas::read_png;

    #[test]
    fn tick_labels_are_short() {
        let t = |v: f64| tick(&v);
        assert_eq!(
            [
                t(1000.0),
                t(20.0),
                t(0.5),
                t(12.6),
                t(0.00123),
                t(-3.0),
                t(2.25)
            ],
            ["1000", "20", "0.5", "12.6", "0.00123", "-3", "2.25"]
        );
    }

    #[test]
    fn charts_are_written_with_colour_and_grey_levels() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("loss.png");
        line_chart(
            &p,
            "loss",
            "epoch",
            "loss",
            &[
                Series {
                    name: "train",
                    color: [31, 119, 180],
                    points: (1..=50).map(|e| (e as f64, 1000.0 / e as f64)).collect(),
                },
                Series {
                    name: "kl",
                    color: [44, 160, 44],
                    points: (1..=50).map(|e| (e as f64, 10.0)).collect(),
                },
            ],
        )
        .unwrap();
        let (w, h, px) = read_png(&p);
        assert_eq!((w, h), SIZE);
        let blue = px.chunks(3).filter(|c| c == &[31, 119, 180]).count();
        assert!(blue > 100, "the train line is drawn ({blue} pixels)");
        let levels: std::collections::BTreeSet<u8> = px.chunks(3).map(|c| c[0]).collect();
        assert!(levels.len() > 50, "anti-aliasing gives many grey levels");

        let hp = tmp.path().join("h.png");
        let mut vals: Vec<f64> = (0..1000).map(|k| (k % 37) as f64).collect();
        vals.push(1e9);
        vals.push(f64::NAN);
        histogram(&hp, "values", "x", &vals, 20).unwrap();
        assert_eq!(read_png(&hp).0, SIZE.0);
    }
}
