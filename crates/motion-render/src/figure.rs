//! Stick figures: the paper's figure 6 (a contact sheet of motions, each at a
//! few times spread from its first to its last frame) and animated PNGs.
//! Orthographic, seen at three quarters (50° from the front of a character
//! facing +z), centred on the hips; floor ticks every 10 units move with the
//! character so travel shows. Left limbs blue, right limbs red, anti-aliased
//! ([`Canvas`]).

use crate::canvas::{save_apng, save_png, Canvas};
use crate::{Motion, RenderError, FPS};
use mocap_ingest::skeleton::{Pose, JOINT_PARENTS};
use std::path::Path;

/// Side colours: left limbs blue, right limbs red, spine dark grey.
pub fn bone_color(j: usize) -> [u8; 3] {
    match j {
        1..=4 | 13..=15 => [40, 90, 200],
        5..=8 | 16..=18 => [200, 50, 40],
        _ => [60, 60, 60],
    }
}

const FLOOR: [u8; 3] = [170, 170, 170];
const LABEL: [u8; 3] = [80, 80, 80];
const TIME: [u8; 3] = [120, 120, 120];

/// Horizontal screen coordinate of a point seen at three quarters, relative
/// to `centre`.
fn project(p: [f64; 3], centre: [f64; 3]) -> f64 {
    let (s, c) = 50f64.to_radians().sin_cos();
    (p[0] - centre[0]) * c + (p[2] - centre[2]) * s
}

/// The part of the segment `a`–`b` inside the rectangle `[x0, x1] × [y0,
/// y1]` (Liang–Barsky), or None when none of it is.
fn clip_segment(
    a: (f32, f32),
    b: (f32, f32),
    [x0, y0, x1, y1]: [f32; 4],
) -> Option<((f32, f32), (f32, f32))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f32, 1.0f32);
    for (p, q) in [
        (-dx, a.0 - x0),
        (dx, x1 - a.0),
        (-dy, a.1 - y0),
        (dy, y1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 <= t1).then(|| {
        let at = |t: f32| (a.0 + t * dx, a.1 + t * dy);
        (at(t0), at(t1))
    })
}

/// Draw one pose into the box `(x0, y0, w, h)`: feet at the bottom margin,
/// `scale` pixels per unit, horizontally centred on the hips. Nothing is
/// drawn outside the box widened by `above` pixels at the top and 4 at the
/// bottom (a figure sunk below the floor or thrown far above it is cut at
/// its cell, not drawn over the next row).
fn draw_pose(
    cv: &mut Canvas,
    pose: &Pose,
    (x0, y0, w, h): (f64, f64, f64, f64),
    scale: f64,
    above: f64,
) {
    let floor_y = y0 + h - 8.0;
    let cx = x0 + w / 2.0;
    let centre = pose[0];
    let f = |x: f64, y: f64| (x as f32, y as f32);
    cv.line(f(x0 + 4.0, floor_y), f(x0 + w - 4.0, floor_y), FLOOR, 1.0);
    for k in -20i64..=20 {
        let d = k as f64 * 10.0 - (centre[0] + centre[2]).rem_euclid(10.0);
        let sx = cx + d * scale * 0.7;
        if sx > x0 + 4.0 && sx < x0 + w - 4.0 {
            cv.line(f(sx, floor_y), f(sx, floor_y + 3.0), FLOOR, 1.0);
        }
    }
    let pt = |p: [f64; 3]| f(cx + project(p, centre) * scale, floor_y - p[1] * scale);
    // The box, less the lines' half width; the head also keeps its radius
    // inside it.
    let cell = [x0 + 1.0, y0 - above + 1.0, x0 + w - 1.0, y0 + h + 3.0].map(|v| v as f32);
    for (j, parent) in JOINT_PARENTS.iter().enumerate() {
        if let Some(pj) = *parent {
            if let Some((a, b)) = clip_segment(pt(pose[pj]), pt(pose[j]), cell) {
                cv.line(a, b, bone_color(j), 2.0);
            }
        }
    }
    let head = pt(pose[12]);
    if head.0 >= cell[0] + 3.0
        && head.0 <= cell[2] - 3.0
        && head.1 >= cell[1] + 3.0
        && head.1 <= cell[3] - 3.0
    {
        cv.circle(head, 3.0, bone_color(12), 1.2);
    }
}

/// Pixels per unit so a 40-unit (about 2.3 m) column fits a box `h` high.
fn scale_for(h: f64) -> f64 {
    (h - 14.0) / 40.0
}

/// Width of one stick-figure cell of the contact sheet, in pixels.
pub const CELL_WIDTH: u32 = 64;
/// Height of one stick-figure cell of the contact sheet, in pixels.
const CELL_HEIGHT: u32 = 110;
/// Motions per row of the contact sheet.
pub const SHEET_MOTIONS_PER_ROW: usize = 4;

/// The frames a contact sheet shows of a motion of `len` frames in
/// `columns` columns: evenly spaced from frame 0 to the last frame
/// `len - 1`, column `i` at `i · (len − 1) / (columns − 1)` rounded to the
/// nearest frame (halves up, in integer arithmetic, so deterministic).
/// Increasing; duplicates are dropped, so a motion of fewer than `columns`
/// frames gives each of its frames once. One column gives frame 0; an empty
/// motion or no columns give no frames.
///
/// `sheet_frames(128, 5)` is `[0, 32, 64, 95, 127]`,
/// `sheet_frames(1800, 5)` is `[0, 450, 900, 1349, 1799]`.
pub fn sheet_frames(len: usize, columns: usize) -> Vec<usize> {
    match (len, columns) {
        (0, _) | (_, 0) => Vec::new(),
        (_, 1) => vec![0],
        _ => {
            let (last, gaps) = ((len - 1) as u128, (columns - 1) as u128);
            let mut frames: Vec<usize> = (0..columns as u128)
                .map(|i| ((2 * i * last + gaps) / (2 * gaps)) as usize)
                .collect();
            frames.dedup();
            frames
        }
    }
}

/// The label of a contact-sheet column: the frame's time in seconds at
/// [`FPS`] (30), rounded to the nearest 0.1 s, with no decimal when it is a
/// whole number of seconds: frame 0 → `"0 s"`, 15 → `"0.5 s"`, 95 → `"3.2 s"`,
/// 900 → `"30 s"`, 1799 (the last of a 60 s motion) → `"60 s"`.
pub fn column_label(frame: usize) -> String {
    // frame · 10 / 30 is never exactly half-way between tenths.
    let tenths = (frame as f64 * 10.0 / FPS).round() as u64;
    match tenths % 10 {
        0 => format!("{} s", tenths / 10),
        d => format!("{}.{d} s", tenths / 10),
    }
}

/// Width and height in pixels of a contact sheet of `motions` motions with
/// `columns` columns each: rows of four motions, each `columns` cells of
/// [`CELL_WIDTH`] plus a 16-pixel gap, an 8-pixel margin, a 30-pixel title.
pub fn sheet_size(motions: usize, columns: usize) -> (u32, u32) {
    let block_w = CELL_WIDTH as usize * columns + 16;
    let block_h = CELL_HEIGHT as usize + 14;
    let rows = motions.div_ceil(SHEET_MOTIONS_PER_ROW);
    (
        (block_w * SHEET_MOTIONS_PER_ROW + 8) as u32,
        (block_h * rows + 30) as u32,
    )
}

/// The paper's figure 6: a grid of motions, four per row, each a row of
/// `columns` stick figures spread over the whole motion (its frames are
/// [`sheet_frames`] of its own length, so every motion is shown from its
/// first to its last frame), each labelled above with its time
/// ([`column_label`]); one scale for all, floor line in each panel. A motion
/// shorter than `columns` frames leaves its last cells empty. The picture is
/// [`sheet_size`] pixels.
pub fn contact_sheet(path: &Path, motions: &[Motion], columns: usize) -> Result<(), RenderError> {
    let (pw, ph) = (CELL_WIDTH as f64, CELL_HEIGHT as f64);
    let cols = SHEET_MOTIONS_PER_ROW;
    let block_w = pw * columns as f64 + 16.0;
    let block_h = ph + 14.0;
    let (w, h) = sheet_size(motions.len(), columns);
    let mut cv = Canvas::new(w, h)?;
    cv.text(
        (8, 6),
        &format!(
            "{} motions, each at {columns} evenly spaced times from first to last frame (30 fps)",
            motions.len()
        ),
        13.0,
        [0, 0, 0],
    );
    for (k, m) in motions.iter().enumerate() {
        let bx = 8.0 + (k % cols) as f64 * block_w;
        let by = 26.0 + (k / cols) as f64 * block_h;
        cv.text((bx as i32, by as i32 - 2), &m.id, 11.0, LABEL);
        for (i, t) in sheet_frames(m.poses.len(), columns).into_iter().enumerate() {
            let x0 = bx + i as f64 * pw;
            // The time above the figure, centred in its cell (drawn first:
            // a high jump's head may cover it).
            let label = column_label(t);
            let tw = Canvas::text_width(&label, 10.0) as f64;
            cv.text(
                ((x0 + (pw - tw) / 2.0).round() as i32, by as i32 + 10),
                &label,
                10.0,
                TIME,
            );
            draw_pose(
                &mut cv,
                &m.poses[t],
                (x0, by + 10.0, pw, ph),
                scale_for(ph),
                10.0,
            );
        }
    }
    save_png(&cv, path)
}

/// An animated PNG of motions side by side, 30 fps, labelled, looping.
pub fn animation(path: &Path, motions: &[&Motion]) -> Result<(), RenderError> {
    let (pw, ph) = (150.0, 190.0);
    let frames = motions.iter().map(|m| m.poses.len()).max().unwrap_or(0);
    let mut out = Vec::with_capacity(frames);
    for f in 0..frames {
        let mut cv = Canvas::new((pw * motions.len() as f64) as u32, ph as u32 + 14)?;
        for (k, m) in motions.iter().enumerate() {
            let x0 = k as f64 * pw;
            cv.text((x0 as i32 + 4, 2), &m.id, 11.0, LABEL);
            if let Some(pose) = m.poses.get(f).or(m.poses.last()) {
                draw_pose(&mut cv, pose, (x0, 14.0, pw, ph), scale_for(ph), 14.0);
            }
        }
        cv.text((4, ph as i32 - 1), &f.to_string(), 11.0, [150, 150, 150]);
        out.push(cv);
    }
    save_apng(&out, 30, path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canvas::read_png;

    /// A person of about 1.7 m (30 units) standing, facing +z, `dx` along x.
    fn standing(dx: f64) -> Pose {
        let p = [
            [0.0, 17.0, 0.0],
            [1.7, 16.5, 0.0],
            [1.8, 9.0, 0.3],
            [1.8, 1.5, 0.0],
            [1.8, 0.5, 2.0],
            [-1.7, 16.5, 0.0],
            [-1.8, 9.0, 0.3],
            [-1.8, 1.5, 0.0],
            [-1.8, 0.5, 2.0],
            [0.0, 19.5, 0.0],
            [0.0, 22.5, 0.0],
            [0.0, 26.0, 0.0],
            [0.0, 28.5, 0.3],
            [3.0, 25.0, 0.0],
            [4.0, 20.0, 0.0],
            [4.5, 15.0, 0.5],
            [-3.0, 25.0, 0.0],
            [-4.0, 20.0, 0.0],
            [-4.5, 15.0, 0.5],
        ];
        p.map(|[x, y, z]| [x + dx, y, z])
    }

    fn walk(id: &str, frames: usize) -> Motion {
        Motion {
            id: id.into(),
            poses: (0..frames).map(|f| standing(f as f64 * 0.5)).collect(),
        }
    }

    #[test]
    fn segments_are_clipped_to_the_cell() {
        let r = [0.0, 0.0, 10.0, 10.0];
        // Inside: unchanged; outside: nothing.
        assert_eq!(
            clip_segment((1.0, 1.0), (9.0, 5.0), r),
            Some(((1.0, 1.0), (9.0, 5.0)))
        );
        assert_eq!(clip_segment((1.0, 12.0), (9.0, 15.0), r), None);
        assert_eq!(clip_segment((-5.0, -1.0), (-1.0, 20.0), r), None);
        // Crossing the bottom edge at y = 10: x = 2 + (10 − 6) / 8 · 4 = 4.
        assert_eq!(
            clip_segment((2.0, 6.0), (6.0, 14.0), r),
            Some(((2.0, 6.0), (4.0, 10.0)))
        );
        // Through both sides.
        assert_eq!(
            clip_segment((-10.0, 5.0), (20.0, 5.0), r),
            Some(((0.0, 5.0), (10.0, 5.0)))
        );
    }

    #[test]
    fn a_figure_below_the_floor_stays_in_its_row() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("sheet.png");
        // Row 1: a figure 25 units under the floor; row 2: nothing drawn
        // (a motion with no frames).
        let sunk = Motion {
            id: "sunk".into(),
            poses: vec![standing(0.0).map(|[x, y, z]| [x, y - 25.0, z]); 5],
        };
        let mut motions = vec![sunk; 4];
        motions.push(Motion {
            id: String::new(),
            poses: Vec::new(),
        });
        contact_sheet(&p, &motions, 5).unwrap();
        let (w, h, px) = read_png(&p);
        let block_h = CELL_HEIGHT + 14;
        let ink_rows = (26 + block_h..h)
            .filter(|&y| (0..w).any(|x| px[((y * w + x) * 3) as usize] < 200))
            .count();
        assert_eq!(
            ink_rows, 0,
            "the sunk figures were drawn into the second row"
        );
        // They are drawn, cut at their cell.
        let ink_first = (26..26 + block_h)
            .filter(|&y| (0..w).any(|x| px[((y * w + x) * 3) as usize] < 120))
            .count();
        assert!(ink_first > 20);
    }

    #[test]
    fn columns_spread_from_first_to_last_frame() {
        // i · (len − 1) / 4 rounded, halves up: 127/4 = 31.75, 63.5, 95.25.
        assert_eq!(sheet_frames(128, 5), [0, 32, 64, 95, 127]);
        // 1799/4 = 449.75, 899.5, 1349.25: a 60 s motion to its last frame.
        assert_eq!(sheet_frames(1800, 5), [0, 450, 900, 1349, 1799]);
        // 149/4 = 37.25, 74.5, 111.75.
        assert_eq!(sheet_frames(150, 5), [0, 37, 75, 112, 149]);
        assert_eq!(sheet_frames(1800, 3), [0, 900, 1799]);
        assert_eq!(sheet_frames(1800, 2), [0, 1799]);
        assert_eq!(sheet_frames(1800, 1), [0]);
    }

    #[test]
    fn short_motions_give_each_frame_once() {
        assert_eq!(sheet_frames(1, 5), [0]);
        assert_eq!(sheet_frames(2, 5), [0, 1]);
        assert_eq!(sheet_frames(3, 5), [0, 1, 2]);
        assert_eq!(sheet_frames(5, 5), [0, 1, 2, 3, 4]);
        assert_eq!(sheet_frames(6, 5), [0, 1, 3, 4, 5]);
        assert_eq!(sheet_frames(0, 5), Vec::<usize>::new());
        assert_eq!(sheet_frames(10, 0), Vec::<usize>::new());
        for len in 1..200 {
            for columns in 1..12 {
                let f = sheet_frames(len, columns);
                assert_eq!(f.len(), len.min(columns), "{len} frames, {columns} columns");
                assert!(f.windows(2).all(|w| w[0] < w[1]));
                assert_eq!(f[0], 0);
                if columns > 1 {
                    assert_eq!(*f.last().unwrap(), len - 1);
                }
            }
        }
    }

    #[test]
    fn labels_are_seconds_to_a_tenth() {
        let labels: Vec<String> = sheet_frames(128, 5).into_iter().map(column_label).collect();
        assert_eq!(labels, ["0 s", "1.1 s", "2.1 s", "3.2 s", "4.2 s"]);
        let labels: Vec<String> = sheet_frames(1800, 5)
            .into_iter()
            .map(column_label)
            .collect();
        assert_eq!(labels, ["0 s", "15 s", "30 s", "45 s", "60 s"]);
        assert_eq!(column_label(15), "0.5 s");
        assert_eq!(column_label(30), "1 s");
        assert_eq!(column_label(3), "0.1 s");
        assert_eq!(column_label(1), "0 s");
        assert_eq!(column_label(2), "0.1 s");
        assert_eq!(column_label(1800), "60 s");
        assert_eq!(column_label(36_000), "1200 s");
    }

    #[test]
    fn contact_sheet_is_columns_cells_wide_with_labelled_columns() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("sheet.png");
        let motions = [
            walk("sample_000", 1800),
            walk("sample_001", 1800),
            walk("short", 3),
        ];
        contact_sheet(&p, &motions, 5).unwrap();
        let (w, h, px) = read_png(&p);
        // Four motions a row, each 5 cells of 64 pixels and a 16-pixel gap.
        assert_eq!((w, h), (4 * (5 * CELL_WIDTH + 16) + 8, 154));
        assert_eq!((w, h), sheet_size(3, 5));
        let ink = |x0: u32, x1: u32, y0: u32, y1: u32| {
            (y0..y1)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .filter(|&(x, y)| px[((y * w + x) * 3) as usize] < 200)
                .count()
        };
        // Motion `k`, cell `i`: the label strip and the figure below it.
        let cell = |k: u32, i: u32| 8 + k * (5 * CELL_WIDTH + 16) + i * CELL_WIDTH;
        for i in 0..5 {
            let x = cell(1, i);
            assert!(ink(x, x + CELL_WIDTH, 36, 46) > 5, "label of column {i}");
            assert!(ink(x, x + CELL_WIDTH, 46, 146) > 50, "figure of column {i}");
        }
        // Three frames: three cells drawn, two left empty.
        for i in 0..5 {
            let x = cell(2, i);
            let n = ink(x, x + CELL_WIDTH, 36, 146);
            assert_eq!(n > 0, i < 3, "column {i} of a 3-frame motion: {n}");
        }

        let p7 = tmp.path().join("sheet7.png");
        let many: Vec<Motion> = (0..5).map(|k| walk(&format!("m{k}"), 128)).collect();
        contact_sheet(&p7, &many, 7).unwrap();
        let (w7, h7, _) = read_png(&p7);
        assert_eq!((w7, h7), (4 * (7 * CELL_WIDTH + 16) + 8, 2 * 124 + 30));
        assert_eq!((w7, h7), sheet_size(5, 7));

        // Deterministic: the same picture twice.
        let again = tmp.path().join("again.png");
        contact_sheet(&again, &motions, 5).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), std::fs::read(&again).unwrap());
    }
}
