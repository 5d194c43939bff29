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

use crate::solve::{euler, solve, Solved, NUM_BVH_JOINTS, SKELETON};
use crate::{Motion, RenderError};
use mocap_ingest::math::Axis;
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
        let rotations: Vec<&str> = s.orders[b]
            .iter()
            .map(|a| match a {
                Axis::X => "Xrotation",
                Axis::Y => "Yrotation",
                Axis::Z => "Zrotation",
            })
            .collect();
        let (kw, channels) = if j.parent.is_none() {
            (
                "ROOT",
                format!("6 Xposition Yposition Zposition {}", rotations.join(" ")),
            )
        } else {
            ("JOINT", format!("3 {}", rotations.join(" ")))
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
            let e = euler(r, s.orders[b], prev[b]);
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

/// Write every motion as `DIR/ID.bvh` and read each back ([`round_trip`]),
/// the motions on rayon's threads (each file its own; the round trips in
/// the motions' order).
pub fn write_all(dir: &Path, motions: &[Motion]) -> Result<Vec<RoundTrip>, RenderError> {
    use rayon::prelude::*;
    motions
        .par_iter()
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
            let text = to_bvh(m)?;
            crate::write_file(&dir.join(format!("{}.bvh", m.id)), text.as_bytes())?;
            round_trip(m, &text)
        })
        .collect()
}

/// A motions Parquet file ([`crate::io::read_parquet`]) exported with
/// [`write_all`] into `out`, or into a `bvh/` folder beside it where `out`
/// is None (created): the folder and the round trips.
pub fn export_parquet(
    file: &Path,
    out: Option<&Path>,
) -> Result<(std::path::PathBuf, Vec<RoundTrip>), RenderError> {
    let dir = out.map_or_else(
        || file.parent().unwrap_or(Path::new(".")).join("bvh"),
        Path::to_path_buf,
    );
    let motions = crate::io::read_parquet(file)?;
    std::fs::create_dir_all(&dir).map_err(|cause| RenderError::Io {
        path: dir.clone(),
        cause,
    })?;
    Ok((dir.clone(), write_all(&dir, &motions)?))
}

/// Read a BVH file back with `mocap_ingest` (every frame, no resampling) as
/// a motion named `id`.
pub fn read_motion(path: &Path, id: &str) -> Result<Motion, RenderError> {
    let bytes = std::fs::read(path).map_err(|cause| RenderError::Io {
        path: path.to_path_buf(),
        cause,
    })?;
    let m = mocap_ingest::read_bvh(&path.display().to_string(), &bytes).map_err(|e| {
        RenderError::Format {
            path: path.to_path_buf(),
            message: e.to_string(),
        }
    })?;
    Ok(Motion {
        id: id.to_string(),
        poses: (0..m.num_frames()).map(|f| m.pose(f)).collect(),
    })
}

/// How well a BVH file reproduces its motion, read back with
/// `mocap_ingest`'s reader. Distances in CMU units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RoundTrip {
    /// Frames read back.
    pub frames: usize,
    /// Largest and mean joint distance, read back vs the motion.
    pub max: f64,
    /// Mean joint distance over joints and frames.
    pub mean: f64,
    /// Largest and mean distance of the motion rebuilt with mean bone
    /// lengths ([`crate::solve::with_mean_bone_lengths`]) from the motion:
    /// the error bone-length variation alone explains.
    pub bone_max: f64,
    /// Mean of that distance.
    pub bone_mean: f64,
    /// Largest distance between what was read back and the mean-bone-length
    /// motion: the error not explained by bone lengths.
    pub residual_max: f64,
}

/// Every motions Parquet file of `files` exported ([`export_parquet`]):
/// a line per file exported and the round-trip table (what `export`
/// prints), and an error message per file that failed.
pub fn export_files(files: &[std::path::PathBuf], out: Option<&Path>) -> (String, Vec<String>) {
    let (mut printed, mut errors, mut sets) = (String::new(), Vec::new(), Vec::new());
    for f in files {
        match export_parquet(f, out) {
            Ok((dir, t)) => {
                printed += &format!(
                    "{} -> {}/ ({} motions)\n",
                    f.display(),
                    dir.display(),
                    t.len()
                );
                let name = f
                    .file_name()
                    .map_or(String::new(), |n| n.to_string_lossy().into_owned());
                sets.push((name, t));
            }
            Err(e) => errors.push(e.to_string()),
        }
    }
    let named: Vec<(&str, Vec<RoundTrip>)> =
        sets.iter().map(|(n, t)| (n.as_str(), t.clone())).collect();
    (printed + &round_trip_table(&named), errors)
}

/// The BVH round-trip table `sample` and `export` print: per set, the
/// worst and mean joint distance of the files read back, and the part
/// bone-length variation explains.
pub fn round_trip_table(sets: &[(&str, Vec<RoundTrip>)]) -> String {
    use std::fmt::Write;
    // Fixed above 0.01, else scientific.
    let dist = |v: f64| match v >= 0.01 {
        true => format!("{v:.3}"),
        false => format!("{v:.1e}"),
    };
    let mut out = format!(
        "BVH read back with mocap-ingest (joint distance to the motion, CMU units; x0.0564 = m):\n  {:<14} {:>7} {:>10} {:>10} {:>16} {:>16}\n",
        "set", "motions", "max", "mean", "bone-length max", "unexplained max"
    );
    for (name, t) in sets {
        let max = |f: fn(&RoundTrip) -> f64| t.iter().map(f).fold(0.0, f64::max);
        let mean = t.iter().map(|r| r.mean).sum::<f64>() / t.len().max(1) as f64;
        let _ = writeln!(
            out,
            "  {name:<14} {:>7} {:>10} {:>10} {:>16} {:>16}",
            t.len(),
            dist(max(|r| r.max)),
            dist(mean),
            dist(max(|r| r.bone_max)),
            dist(max(|r| r.residual_max))
        );
    }
    out
}

/// Read `text` (the BVH of `m`) back with `mocap_ingest` and compare.
pub fn round_trip(m: &Motion, text: &str) -> Result<RoundTrip, RenderError> {
    use mocap_ingest::math::{norm, sub};
    let err = |message: String| RenderError::Motion {
        id: m.id.clone(),
        message,
    };
    let back = mocap_ingest::read_bvh(&format!("{}.bvh", m.id), text.as_bytes())
        .map_err(|e| err(format!("reading the export back: {e}")))?;
    if back.skeleton() != mocap_ingest::SkeletonKind::Exported {
        return Err(err(format!("read back as {}", back.skeleton().name())));
    }
    if back.num_frames() != m.poses.len() {
        return Err(err(format!(
            "{} frames read back, {} written",
            back.num_frames(),
            m.poses.len()
        )));
    }
    let rigid = crate::solve::with_mean_bone_lengths(&m.poses);
    let mut r = RoundTrip {
        frames: m.poses.len(),
        ..RoundTrip::default()
    };
    let (mut sum, mut bone_sum, mut n) = (0.0, 0.0, 0usize);
    for (f, (pose, rig)) in m.poses.iter().zip(&rigid).enumerate() {
        let read = back.pose(f);
        for k in 0..pose.len() {
            let (e, b) = (norm(sub(read[k], pose[k])), norm(sub(rig[k], pose[k])));
            r.max = r.max.max(e);
            r.bone_max = r.bone_max.max(b);
            r.residual_max = r.residual_max.max(norm(sub(read[k], rig[k])));
            (sum, bone_sum, n) = (sum + e, bone_sum + b, n + 1);
        }
    }
    r.mean = sum / n.max(1) as f64;
    r.bone_mean = bone_sum / n.max(1) as f64;
    Ok(r)
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
