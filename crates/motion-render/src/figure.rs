//! Stick figures: the paper's figure 6 (a contact sheet of motions at a few
//! frames) and animated PNGs. Orthographic, seen at three quarters (50° from
//! the front of a character facing +z), centred on the hips; floor ticks
//! every 10 units move with the character so travel shows. Left limbs blue,
//! right limbs red, anti-aliased ([`Canvas`]).

use crate::canvas::{save_apng, save_png, Canvas};
use crate::{Motion, RenderError};
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

/// Horizontal screen coordinate of a point seen at three quarters, relative
/// to `centre`.
fn project(p: [f64; 3], centre: [f64; 3]) -> f64 {
    let (s, c) = 50f64.to_radians().sin_cos();
    (p[0] - centre[0]) * c + (p[2] - centre[2]) * s
}

/// Draw one pose into the box `(x0, y0, w, h)`: feet at the bottom margin,
/// `scale` pixels per unit, horizontally centred on the hips.
fn draw_pose(cv: &mut Canvas, pose: &Pose, (x0, y0, w, h): (f64, f64, f64, f64), scale: f64) {
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
    for (j, parent) in JOINT_PARENTS.iter().enumerate() {
        if let Some(pj) = *parent {
            cv.line(pt(pose[pj]), pt(pose[j]), bone_color(j), 2.0);
        }
    }
    cv.circle(pt(pose[12]), 3.0, bone_color(12), 1.2);
}

/// Pixels per unit so a 40-unit (about 2.3 m) column fits a box `h` high.
fn scale_for(h: f64) -> f64 {
    (h - 14.0) / 40.0
}

/// The paper's figure 6: a grid of motions, four per row, each a row of stick
/// figures at the given frames, one scale for all, floor line in each panel.
pub fn contact_sheet(path: &Path, motions: &[Motion], times: &[usize]) -> Result<(), RenderError> {
    let (pw, ph) = (64.0, 110.0);
    let cols = 4usize;
    let rows = motions.len().div_ceil(cols);
    let block_w = pw * times.len() as f64 + 16.0;
    let block_h = ph + 14.0;
    let mut cv = Canvas::new(
        (block_w * cols as f64) as u32 + 8,
        (block_h * rows as f64) as u32 + 30,
    )?;
    let frames: Vec<String> = times.iter().map(usize::to_string).collect();
    cv.text(
        (8, 6),
        &format!(
            "{} motions, frames {} at 30 fps",
            motions.len(),
            frames.join(", ")
        ),
        13.0,
        [0, 0, 0],
    );
    for (k, m) in motions.iter().enumerate() {
        let bx = 8.0 + (k % cols) as f64 * block_w;
        let by = 26.0 + (k / cols) as f64 * block_h;
        cv.text((bx as i32, by as i32 - 2), &m.id, 11.0, LABEL);
        for (i, &t) in times.iter().enumerate() {
            let Some(pose) = m.poses.get(t) else { continue };
            draw_pose(
                &mut cv,
                pose,
                (bx + i as f64 * pw, by + 10.0, pw, ph),
                scale_for(ph),
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
                draw_pose(&mut cv, pose, (x0, 14.0, pw, ph), scale_for(ph));
            }
        }
        cv.text((4, ph as i32 - 1), &f.to_string(), 11.0, [150, 150, 150]);
        out.push(cv);
    }
    save_apng(&out, 30, path)
}
