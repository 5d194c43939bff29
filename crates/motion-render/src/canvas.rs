//! The one raster every picture is drawn on: an opaque RGB image
//! (a `tiny-skia` pixmap) with anti-aliased lines, circles and polygons, and
//! text in an embedded font (DejaVu Sans, so no system fonts are needed).
//! It is also a `plotters` drawing backend ([`Canvas::backend`]), so charts
//! and stick figures share the same anti-aliasing and font. PNG and animated
//! PNG files are written with the `png` crate.

use crate::RenderError;
use plotters::prelude::{DrawingBackend, IntoFont};
use plotters::style::{register_font, FontStyle, RGBColor};
use plotters_backend::{BackendColor, BackendCoord, BackendStyle, DrawingErrorKind};
use std::path::Path;
use tiny_skia::{FillRule, LineCap, Paint, PathBuilder, Pixmap, Rect, Stroke, Transform};

/// DejaVu Sans (Bitstream Vera licence, `assets/DejaVuSans.LICENSE`).
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// The font family every text is drawn in.
pub const FONT_FAMILY: &str = "sans-serif";

/// Register the embedded font with `plotters` (once per process).
pub fn register_embedded_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The font is a valid TrueType file (checked by a test).
        let _ = register_font(FONT_FAMILY, FontStyle::Normal, FONT);
    });
}

/// An opaque RGB raster, white to begin with.
pub struct Canvas {
    pixmap: Pixmap,
}

fn paint(rgb: [u8; 3]) -> Paint<'static> {
    let mut p = Paint::default();
    p.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
    p.anti_alias = true;
    p
}

impl Canvas {
    /// A white canvas of `w × h` pixels.
    pub fn new(w: u32, h: u32) -> Result<Canvas, RenderError> {
        let mut pixmap = Pixmap::new(w.max(1), h.max(1)).ok_or_else(|| RenderError::Image {
            path: Default::default(),
            message: format!("cannot allocate a {w}x{h} image"),
        })?;
        pixmap.fill(tiny_skia::Color::WHITE);
        register_embedded_font();
        Ok(Canvas { pixmap })
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.pixmap.width()
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.pixmap.height()
    }

    /// A polyline `width` pixels wide with round caps.
    pub fn polyline(&mut self, points: &[(f32, f32)], rgb: [u8; 3], width: f32) {
        let mut pb = PathBuilder::new();
        for (k, &(x, y)) in points.iter().enumerate() {
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            if k == 0 {
                pb.move_to(x, y);
            } else {
                pb.line_to(x, y);
            }
        }
        if let Some(path) = pb.finish() {
            let stroke = Stroke {
                width,
                line_cap: LineCap::Round,
                ..Stroke::default()
            };
            self.pixmap
                .stroke_path(&path, &paint(rgb), &stroke, Transform::identity(), None);
        }
    }

    /// A line segment.
    pub fn line(&mut self, a: (f32, f32), b: (f32, f32), rgb: [u8; 3], width: f32) {
        self.polyline(&[a, b], rgb, width);
    }

    /// A circle outline (`width > 0`) or disc (`width == 0`).
    pub fn circle(&mut self, c: (f32, f32), r: f32, rgb: [u8; 3], width: f32) {
        let Some(path) = PathBuilder::from_circle(c.0, c.1, r) else {
            return;
        };
        if width > 0.0 {
            let stroke = Stroke {
                width,
                ..Stroke::default()
            };
            self.pixmap
                .stroke_path(&path, &paint(rgb), &stroke, Transform::identity(), None);
        } else {
            self.pixmap.fill_path(
                &path,
                &paint(rgb),
                FillRule::Winding,
                Transform::identity(),
                None,
            );
        }
    }

    /// Text of `size` pixels with its top-left corner at `(x, y)`.
    pub fn text(&mut self, (x, y): (i32, i32), s: &str, size: f64, rgb: [u8; 3]) {
        let style = (FONT_FAMILY, size)
            .into_font()
            .color(&RGBColor(rgb[0], rgb[1], rgb[2]));
        // Text outside the canvas is clipped; a missing glyph draws nothing.
        let _ = self.backend().draw_text(s, &style, (x, y));
    }

    /// Width in pixels of `s` drawn by [`Canvas::text`] at `size` pixels (0
    /// if the font cannot lay it out).
    pub fn text_width(s: &str, size: f64) -> u32 {
        register_embedded_font();
        (FONT_FAMILY, size)
            .into_font()
            .box_size(s)
            .map_or(0, |(w, _)| w)
    }

    /// The pixels as RGB bytes, row by row.
    pub fn rgb(&self) -> Vec<u8> {
        // Opaque everywhere, so premultiplied RGBA is plain RGBA.
        self.pixmap
            .data()
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect()
    }

    /// Blend one pixel with `color` (its alpha is the coverage).
    fn blend(&mut self, (x, y): BackendCoord, color: BackendColor) {
        let (w, h) = (self.width() as i32, self.height() as i32);
        if x < 0 || y < 0 || x >= w || y >= h {
            return;
        }
        let a = color.alpha.clamp(0.0, 1.0);
        let i = (y as usize * w as usize + x as usize) * 4;
        let px = &mut self.pixmap.data_mut()[i..i + 3];
        for (p, c) in px.iter_mut().zip([color.rgb.0, color.rgb.1, color.rgb.2]) {
            *p = (*p as f64 * (1.0 - a) + c as f64 * a).round() as u8;
        }
    }

    /// This canvas as a `plotters` backend.
    pub fn backend(&mut self) -> Backend<'_> {
        Backend(self)
    }
}

/// A [`Canvas`] seen by `plotters`: shapes go through `tiny-skia`
/// (anti-aliased), text through `plotters`' own font rasteriser, whose
/// per-pixel coverage `draw_pixel` blends in.
pub struct Backend<'a>(&'a mut Canvas);

/// A `plotters` backend error (never produced: drawing cannot fail).
#[derive(Debug)]
pub struct NoError;

impl std::fmt::Display for NoError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("drawing error")
    }
}

impl std::error::Error for NoError {}

fn rgb_of(c: BackendColor) -> [u8; 3] {
    [c.rgb.0, c.rgb.1, c.rgb.2]
}

/// Pixel centre of a backend coordinate (so 1-pixel lines are crisp).
fn centre((x, y): BackendCoord) -> (f32, f32) {
    (x as f32 + 0.5, y as f32 + 0.5)
}

type DrawResult = Result<(), DrawingErrorKind<NoError>>;

impl DrawingBackend for Backend<'_> {
    type ErrorType = NoError;

    fn get_size(&self) -> (u32, u32) {
        (self.0.width(), self.0.height())
    }

    fn ensure_prepared(&mut self) -> DrawResult {
        Ok(())
    }

    fn present(&mut self) -> DrawResult {
        Ok(())
    }

    fn draw_pixel(&mut self, point: BackendCoord, color: BackendColor) -> DrawResult {
        self.0.blend(point, color);
        Ok(())
    }

    fn draw_line<S: BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> DrawResult {
        if style.color().alpha > 0.0 {
            let w = style.stroke_width().max(1) as f32;
            self.0
                .line(centre(from), centre(to), rgb_of(style.color()), w);
        }
        Ok(())
    }

    fn draw_rect<S: BackendStyle>(
        &mut self,
        ul: BackendCoord,
        br: BackendCoord,
        style: &S,
        fill: bool,
    ) -> DrawResult {
        if style.color().alpha == 0.0 {
            return Ok(());
        }
        let rgb = rgb_of(style.color());
        if fill {
            let (l, t) = (ul.0.min(br.0) as f32, ul.1.min(br.1) as f32);
            let (r, b) = (ul.0.max(br.0) as f32 + 1.0, ul.1.max(br.1) as f32 + 1.0);
            if let Some(rect) = Rect::from_ltrb(l, t, r, b) {
                self.0
                    .pixmap
                    .fill_rect(rect, &paint(rgb), Transform::identity(), None);
            }
        } else {
            let (a, b) = (centre(ul), centre(br));
            let w = style.stroke_width().max(1) as f32;
            self.0.polyline(&[a, (b.0, a.1), b, (a.0, b.1), a], rgb, w);
        }
        Ok(())
    }

    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> DrawResult {
        if style.color().alpha > 0.0 {
            let pts: Vec<(f32, f32)> = path.into_iter().map(centre).collect();
            let w = style.stroke_width().max(1) as f32;
            self.0.polyline(&pts, rgb_of(style.color()), w);
        }
        Ok(())
    }

    fn draw_circle<S: BackendStyle>(
        &mut self,
        c: BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> DrawResult {
        if style.color().alpha > 0.0 {
            let w = if fill {
                0.0
            } else {
                style.stroke_width().max(1) as f32
            };
            self.0
                .circle(centre(c), radius as f32, rgb_of(style.color()), w);
        }
        Ok(())
    }

    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> DrawResult {
        let mut pb = PathBuilder::new();
        for (k, p) in vert.into_iter().enumerate() {
            let (x, y) = centre(p);
            if k == 0 {
                pb.move_to(x, y);
            } else {
                pb.line_to(x, y);
            }
        }
        pb.close();
        if let (Some(path), true) = (pb.finish(), style.color().alpha > 0.0) {
            self.0.pixmap.fill_path(
                &path,
                &paint(rgb_of(style.color())),
                FillRule::Winding,
                Transform::identity(),
                None,
            );
        }
        Ok(())
    }
}

/// Write a canvas as a PNG (atomically).
pub fn save_png(canvas: &Canvas, path: &Path) -> Result<(), RenderError> {
    save_apng(std::slice::from_ref(canvas), 0, path)
}

/// Write canvases of one size as an animated PNG at `fps` frames per second,
/// looping (a single canvas gives a plain PNG). Atomic.
pub fn save_apng(frames: &[Canvas], fps: u16, path: &Path) -> Result<(), RenderError> {
    let err = |message: String| RenderError::Image {
        path: path.to_path_buf(),
        message,
    };
    let Some(first) = frames.first() else {
        return Err(err("no frames to write".into()));
    };
    if frames
        .iter()
        .any(|f| (f.width(), f.height()) != (first.width(), first.height()))
    {
        return Err(err("frames of different sizes".into()));
    }
    crate::write_atomically(path, |w| {
        let pe = |e: png::EncodingError| err(e.to_string());
        let mut enc = png::Encoder::new(w, first.width(), first.height());
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        if frames.len() > 1 {
            enc.set_animated(frames.len() as u32, 0).map_err(pe)?;
            enc.set_frame_delay(1, fps.max(1)).map_err(pe)?;
        }
        let mut wr = enc.write_header().map_err(pe)?;
        for f in frames {
            wr.write_image_data(&f.rgb()).map_err(pe)?;
        }
        wr.finish().map_err(pe)
    })
}

/// Width, height and pixels of a PNG file (tests only).
#[cfg(test)]
pub(crate) fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    (info.width, info.height, buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_anti_aliased_and_text_is_drawn() {
        let mut c = Canvas::new(40, 20).unwrap();
        c.line((2.0, 2.0), (37.0, 17.0), [0, 0, 0], 1.5);
        let px = c.rgb();
        let greys = px.chunks(3).filter(|p| p[0] > 20 && p[0] < 235).count();
        assert!(greys > 10, "no partial coverage: not anti-aliased");
        let mut t = Canvas::new(60, 20).unwrap();
        t.text((2, 2), "Hips 42", 14.0, [0, 0, 0]);
        let dark = t.rgb().chunks(3).filter(|p| p[0] < 128).count();
        assert!(dark > 20, "the embedded font drew {dark} dark pixels");
    }
}
