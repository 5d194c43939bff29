//! BVH export: a motion as CMU's Motionbuilder-style skeleton (without
//! fingers), rotations solved from the joint positions ([`crate::solve`]).
//!
//! - Joints: [`SKELETON`] (the 19 kept joints and six helpers at their
//!   parents' positions, as in CMU's files), names as in `docs/features.md`.
//! - Root: `Xposition Yposition Zposition Zrotation Yrotation Xrotation`;
//!   every other joint: `Zrotation Yrotation Xrotation` (`R = Rz·Ry·Rx`).
//! - 30 fps (`Frame Time: 0.0333333`); lengths in CMU units as the dataset
//!   (× 0.0564 = metres); y up, the motion's first frame facing +z.
//! - Offsets: the motion's mean bone lengths; no T-pose frame.
//!
//! `mocap_ingest` reads these files back (a Motionbuilder-named skeleton
//! without finger joints is recognised as this export, with no T-pose frame
//! to drop).

use crate::solve::{euler_zyx, solve, Solved, NUM_BVH_JOINTS, SKELETON};
use crate::{Motion, RenderError};
use std::fmt::Write as _;
use std::path::Path;

/// The `Frame Time` line's value (30 fps).
pub const FRAME_TIME: &str = "0.0333333";

/// A number with 6 decimals, without a negative zero.
fn num(v: f64) -> String {
    let s = format!("{v:.6}");
    if s.strip_prefix('-')
        .is_some_and(|r| r.bytes().all(|b| b == b'0' || b == b'.'))
    {
        s[1..].to_string()
    } else {
        s
    }
}

fn vec3(v: [f64; 3]) -> String {
    format!("{} {} {}", num(v[0]), num(v[1]), num(v[2]))
}

/// The hierarchy section of `s`'s skeleton.
fn hierarchy(s: &Solved) -> String {
    fn joint(out: &mut String, s: &Solved, b: usize, depth: usize) {
        let pad = "\t".repeat(depth);
        let j = &SKELETON[b];
        let (kw, channels) = if j.parent.is_none() {
            (
                "ROOT",
                "6 Xposition Yposition Zposition Zrotation Yrotation Xrotation",
            )
        } else {
            ("JOINT", "3 Zrotation Yrotation Xrotation")
        };
        let _ = writeln!(out, "{pad}{kw} {}\n{pad}{{", j.name);
        let _ = writeln!(out, "{pad}\tOFFSET {}", vec3(s.rest.offsets[b]));
        let _ = writeln!(out, "{pad}\tCHANNELS {channels}");
        let kids: Vec<usize> = (0..NUM_BVH_JOINTS)
            .filter(|&c| SKELETON[c].parent == Some(b))
            .collect();
        if kids.is_empty() {
            let _ = writeln!(
                out,
                "{pad}\tEnd Site\n{pad}\t{{\n{pad}\t\tOFFSET {}\n{pad}\t}}",
                vec3(s.rest.end_sites[b])
            );
        }
        for c in kids {
            joint(out, s, c, depth + 1);
        }
        let _ = writeln!(out, "{pad}}}");
    }
    let mut out = String::from("HIERARCHY\n");
    joint(&mut out, s, 0, 0);
    out
}

/// The motion's channel values, one line per frame, Euler angles continuous
/// over time.
fn motion_lines(s: &Solved, out: &mut String) {
    let mut prev: [Option<[f64; 3]>; NUM_BVH_JOINTS] = [None; NUM_BVH_JOINTS];
    for (f, local) in s.local.iter().enumerate() {
        let mut line = vec3(s.root[f]);
        for (b, r) in local.iter().enumerate() {
            let e = euler_zyx(r, prev[b]);
            prev[b] = Some(e);
            line.push(' ');
            line += &vec3(e);
        }
        out.push_str(&line);
        out.push('\n');
    }
}

/// The BVH text of a motion.
pub fn to_bvh(m: &Motion) -> Result<String, RenderError> {
    let s = solve(m)?;
    let mut out = hierarchy(&s);
    let _ = write!(
        out,
        "MOTION\nFrames: {}\nFrame Time: {FRAME_TIME}\n",
        s.local.len()
    );
    motion_lines(&s, &mut out);
    Ok(out)
}

/// Write a motion as a BVH file (atomically).
pub fn write_bvh(path: &Path, m: &Motion) -> Result<(), RenderError> {
    crate::write_file(path, to_bvh(m)?.as_bytes())
}

/// Write every motion as `DIR/ID.bvh`; returns the paths written.
pub fn write_all(dir: &Path, motions: &[Motion]) -> Result<Vec<std::path::PathBuf>, RenderError> {
    motions
        .iter()
        .map(|m| {
            let safe = !m.id.is_empty()
                && !m.id.starts_with('.')
                && m.id
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b"_-.".contains(&b));
            if !safe {
                return Err(RenderError::Motion {
                    id: m.id.clone(),
                    message: "the id cannot be a file name (letters, digits, `_`, `-`, `.` only)"
                        .into(),
                });
            }
            let p = dir.join(format!("{}.bvh", m.id));
            write_bvh(&p, m).map(|()| p)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_have_no_negative_zero() {
        assert_eq!(num(-0.0), "0.000000");
        assert_eq!(num(-1e-9), "0.000000");
        assert_eq!(num(-1.5), "-1.500000");
        assert_eq!(num(2.0), "2.000000");
    }
}
