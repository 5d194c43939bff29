//! BVH reading. `bvh_anim` parses the hierarchy (its panics contained); the
//! motion table is parsed here in one validating pass, because `bvh_anim`
//! does not check the number of values per line, trusts `Frames:` for memory,
//! reads values as `f32` and gives no line numbers for bad values.

use crate::error::{check_text, snippet, ErrorKind};
use crate::math::{add, Axis, Mat3, Vec3};
use crate::skeleton::{bvh_names, recognise_bvh, Pose, SkeletonKind, NUM_JOINTS};
use crate::text::{parse_decimal, tokens};
use bvh_anim::ChannelType;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// One BVH joint, reduced to what forward kinematics needs.
#[derive(Clone, Debug)]
struct Joint {
    parent: Option<usize>,
    offset: Vec3,
    /// Frame-value index of the X/Y/Z position channels, if present.
    position: [Option<usize>; 3],
    /// Rotation channels in listed order: axis and frame-value index.
    rotation: Vec<(Axis, usize)>,
}

/// A parsed BVH motion: the kinematic tree and the channel values of every
/// motion frame (the synthetic T-pose already dropped).
#[derive(Clone, Debug)]
pub struct BvhMotion {
    /// The recognised skeleton.
    pub skeleton: SkeletonKind,
    /// Frame rate stated by the file's `Frame Time`.
    pub declared_fps: f64,
    joints: Vec<Joint>,
    /// Joints to evaluate, in an order where parents come first.
    needed: Vec<usize>,
    /// For each kept joint, its index in `joints`.
    kept: [usize; NUM_JOINTS],
    values: Vec<f64>,
    num_channels: usize,
    first_frame: usize,
    num_frames: usize,
}

impl BvhMotion {
    /// Parse and validate a BVH file.
    pub fn parse(bytes: &[u8]) -> Result<BvhMotion, ErrorKind> {
        let tree = Tree::parse(bytes)?;
        let name_refs: Vec<&str> = tree.names.iter().map(String::as_str).collect();
        let skeleton = recognise_bvh(&name_refs)
            .map_err(|(closest, missing)| ErrorKind::UnknownSkeleton { closest, missing })?;
        let mut kept = [0usize; NUM_JOINTS];
        for (k, want) in bvh_names(skeleton).iter().enumerate() {
            // recognise_bvh guarantees presence.
            kept[k] = name_refs.iter().position(|n| n == want).unwrap_or(0);
        }
        let needed = ancestors_closure(&tree.joints, &kept)?;
        let first_frame = usize::from(skeleton.has_tpose_frame());
        if tree.frames <= first_frame {
            return Err(ErrorKind::NoFrames);
        }
        Ok(BvhMotion {
            skeleton,
            declared_fps: 1.0 / tree.frame_time,
            joints: tree.joints,
            needed,
            kept,
            values: tree.values,
            num_channels: tree.channels,
            first_frame,
            num_frames: tree.frames - first_frame,
        })
    }

    /// Number of motion frames (T-pose excluded).
    pub fn num_frames(&self) -> usize {
        self.num_frames
    }

    /// Global positions of the kept joints at `frame` (0-based, T-pose excluded).
    pub fn pose(&self, frame: usize) -> Pose {
        let start = (frame + self.first_frame) * self.num_channels;
        let pos = forward_kinematics(
            &self.joints,
            &self.needed,
            &self.values[start..start + self.num_channels],
        );
        self.kept.map(|j| pos[j])
    }
}

/// Global joint positions for one frame's channel values, evaluating the
/// joints in `order` (parents first; others are left at the origin).
/// `pos(j) = pos(parent) + R(parent) · (offset + translation)`,
/// `R(j) = R(parent) · R(c1) · R(c2) · R(c3)` for rotation channels listed `c1 c2 c3`.
fn forward_kinematics(joints: &[Joint], order: &[usize], v: &[f64]) -> Vec<Vec3> {
    let n = joints.len();
    let mut rot = vec![Mat3::IDENTITY; n];
    let mut pos = vec![[0.0; 3]; n];
    for &j in order {
        let joint = &joints[j];
        let mut local = joint.offset;
        for (axis, idx) in joint.position.iter().enumerate() {
            if let Some(i) = idx {
                local[axis] += v[*i];
            }
        }
        let mut r = Mat3::IDENTITY;
        for &(axis, i) in &joint.rotation {
            r = r.mul(&Mat3::rotation(axis, v[i].to_radians()));
        }
        match joint.parent {
            Some(p) => {
                pos[j] = add(pos[p], rot[p].apply(local));
                rot[j] = rot[p].mul(&r);
            }
            None => {
                pos[j] = local;
                rot[j] = r;
            }
        }
    }
    pos
}

/// A BVH file's joint tree and motion values, validated but not yet recognised.
struct Tree {
    joints: Vec<Joint>,
    names: Vec<String>,
    values: Vec<f64>,
    channels: usize,
    frames: usize,
    /// Seconds per frame.
    frame_time: f64,
}

impl Tree {
    fn parse(bytes: &[u8]) -> Result<Tree, ErrorKind> {
        check_text(bytes)?;
        let (header_end, motion) = split_motion(bytes)?;
        let declared_channels = check_channel_lists(&bytes[..header_end])?;
        // bvh_anim reads the hierarchy; the motion table is ours (below).
        let mut header = bytes[..header_end].to_vec();
        header.extend_from_slice(b"\nMOTION\nFrames: 0\nFrame Time: 1\n");
        let bvh = match catch_unwind(AssertUnwindSafe(|| bvh_anim::from_bytes(&header))) {
            Ok(Ok(bvh)) => bvh,
            Ok(Err(e)) => {
                return Err(ErrorKind::Syntax {
                    format: "BVH",
                    line: None,
                    message: format!("in HIERARCHY: {e}"),
                })
            }
            Err(payload) => return Err(ErrorKind::Panic(panic_message(payload))),
        };
        let mut joints = Vec::new();
        let mut names = Vec::new();
        let mut channels = 0;
        for j in bvh.joints() {
            let data = j.data();
            let o = data.offset();
            let mut position = [None; 3];
            let mut rotation = Vec::new();
            for c in data.channels() {
                let i = c.motion_index();
                channels = channels.max(i + 1);
                match c.channel_type() {
                    ChannelType::PositionX => position[0] = Some(i),
                    ChannelType::PositionY => position[1] = Some(i),
                    ChannelType::PositionZ => position[2] = Some(i),
                    ChannelType::RotationX => rotation.push((Axis::X, i)),
                    ChannelType::RotationY => rotation.push((Axis::Y, i)),
                    ChannelType::RotationZ => rotation.push((Axis::Z, i)),
                }
            }
            joints.push(Joint {
                parent: data.parent_index(),
                offset: [o.x as f64, o.y as f64, o.z as f64],
                position,
                rotation,
            });
            names.push(String::from_utf8_lossy(data.name().as_ref()).into_owned());
        }
        if channels != declared_channels {
            return Err(ErrorKind::Syntax {
                format: "BVH",
                line: None,
                message: format!(
                    "hierarchy declares {declared_channels} channels but the parser found {channels}"
                ),
            });
        }
        let table = parse_motion(bytes, motion, channels, |ch| {
            channel_owner(&joints, &names, ch)
        })?;
        Ok(Tree {
            joints,
            names,
            values: table.values,
            channels,
            frames: table.frames,
            frame_time: table.frame_time,
        })
    }
}

/// The kept joints and all their ancestors, parents first.
fn ancestors_closure(joints: &[Joint], kept: &[usize]) -> Result<Vec<usize>, ErrorKind> {
    let mut mark = vec![false; joints.len()];
    for &k in kept {
        let mut j = Some(k);
        let mut steps = 0;
        while let Some(i) = j {
            if mark[i] {
                break;
            }
            mark[i] = true;
            j = joints[i].parent;
            steps += 1;
            if steps > joints.len() {
                return Err(syntax(None, "cyclic joint hierarchy".into()));
            }
        }
    }
    let order: Vec<usize> = (0..joints.len()).filter(|&i| mark[i]).collect();
    // bvh_anim stores joints depth-first, so a parent precedes its children.
    if order
        .iter()
        .any(|&i| joints[i].parent.is_some_and(|p| p >= i))
    {
        return Err(syntax(
            None,
            "joint hierarchy is not in depth-first order".into(),
        ));
    }
    Ok(order)
}

fn channel_owner(joints: &[Joint], names: &[String], ch: usize) -> String {
    joints
        .iter()
        .zip(names)
        .find(|(j, _)| j.position.contains(&Some(ch)) || j.rotation.iter().any(|r| r.1 == ch))
        .map(|(_, n)| n.clone())
        .unwrap_or_else(|| "?".into())
}

fn panic_message(payload: Box<dyn std::any::Any + Send>) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        s.to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic".into()
    }
}

fn syntax(line: Option<usize>, message: String) -> ErrorKind {
    ErrorKind::Syntax {
        format: "BVH",
        line,
        message,
    }
}

/// Where the `MOTION` line starts, and its 1-based line number.
fn split_motion(bytes: &[u8]) -> Result<(usize, usize), ErrorKind> {
    let mut start = 0;
    for (line, l) in (1..).zip(bytes.split(|&b| b == b'\n')) {
        if l.trim_ascii() == b"MOTION" {
            return Ok((start, line));
        }
        start += l.len() + 1;
    }
    Err(syntax(None, "no MOTION section".into()))
}

/// Check every `CHANNELS n …` line lists `n` channels; return their sum.
fn check_channel_lists(header: &[u8]) -> Result<usize, ErrorKind> {
    let mut total = 0;
    for (i, line) in header.split(|&b| b == b'\n').enumerate() {
        let mut tok = tokens(line);
        if tok.next() != Some(b"CHANNELS") {
            continue;
        }
        let count = tok.next().unwrap_or(b"");
        let c: usize = std::str::from_utf8(count)
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| ErrorKind::NonNumeric {
                line: i + 1,
                token: snippet(count),
            })?;
        let listed = tok.count();
        if listed != c {
            return Err(syntax(
                Some(i + 1),
                format!("CHANNELS declares {c} channels but lists {listed}"),
            ));
        }
        total += c;
    }
    Ok(total)
}

struct MotionTable {
    values: Vec<f64>,
    frames: usize,
    frame_time: f64,
}

/// Parse the motion section starting at 1-based line `motion_line`
/// (`MOTION`, `Frames: N`, `Frame Time: S`, then N lines of `channels` values),
/// checking every line.
fn parse_motion(
    bytes: &[u8],
    motion_line: usize,
    channels: usize,
    owner: impl Fn(usize) -> String,
) -> Result<MotionTable, ErrorKind> {
    let mut lines = bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .skip(motion_line)
        .map(|(i, l)| (i + 1, l))
        .filter(|(_, l)| !l.trim_ascii().is_empty());
    let (n, frames_line) = lines
        .next()
        .ok_or_else(|| syntax(None, "missing `Frames:` line after MOTION".into()))?;
    let frames_text = frames_line.trim_ascii();
    let frames: usize = frames_text
        .strip_prefix(b"Frames:")
        .and_then(|t| std::str::from_utf8(t.trim_ascii()).ok())
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| {
            syntax(
                Some(n),
                format!("expected `Frames: N`, found {:?}", snippet(frames_text)),
            )
        })?;
    let (n, ft_line) = lines
        .next()
        .ok_or_else(|| syntax(None, "missing `Frame Time:` line".into()))?;
    let frame_time = ft_line
        .trim_ascii()
        .strip_prefix(b"Frame Time:")
        .and_then(|t| std::str::from_utf8(t.trim_ascii()).ok())
        .and_then(|s| s.parse::<f64>().ok())
        .filter(|t| t.is_finite() && *t > 0.0)
        .ok_or_else(|| syntax(Some(n), "expected `Frame Time: SECONDS` (positive)".into()))?;

    // Never trust `Frames:` for memory: each value takes at least two bytes.
    let mut values = Vec::with_capacity((frames * channels).min(bytes.len() / 2));
    let mut found = 0usize;
    let mut last_line = n;
    while let Some((n, line)) = lines.next() {
        last_line = n;
        let before = values.len();
        for t in tokens(line) {
            let v = parse_decimal(t).ok_or_else(|| ErrorKind::NonNumeric {
                line: n,
                token: snippet(t),
            })?;
            if !v.is_finite() {
                let ch = values.len() - before;
                return Err(ErrorKind::NonFinite {
                    frame: found,
                    what: format!("channel {ch} ({}) at line {n}", owner(ch)),
                });
            }
            values.push(v);
        }
        let count = values.len() - before;
        if count != channels {
            // A short final line is a truncated file, not a layout error.
            if count < channels && lines.next().is_none() {
                return Err(ErrorKind::Truncated {
                    expected: frames,
                    found,
                    line: n,
                });
            }
            return Err(ErrorKind::ChannelCount {
                line: n,
                expected: channels,
                found: count,
            });
        }
        found += 1;
        if found > frames {
            return Err(syntax(
                Some(n),
                format!("`Frames: {frames}` but more frames follow"),
            ));
        }
    }
    if found < frames {
        return Err(ErrorKind::Truncated {
            expected: frames,
            found,
            line: last_line,
        });
    }
    Ok(MotionTable {
        values,
        frames,
        frame_time,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A root with position channels at (10, 20, 30) and three rotation
    /// channels listed in `order`, each 90°, and a child at offset (1, 2, 3).
    fn chain(order: &str) -> Vec3 {
        let channels: Vec<String> = order.chars().map(|c| format!("{c}rotation")).collect();
        let text = format!(
            "HIERARCHY\nROOT A\n{{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition {}\n \
             JOINT B\n {{\n  OFFSET 1 2 3\n  CHANNELS 3 Zrotation Yrotation Xrotation\n  \
             End Site\n  {{\n   OFFSET 0 0 1\n  }}\n }}\n}}\nMOTION\nFrames: 1\nFrame Time: 0.0083333\n\
             10 20 30 90 90 90 0 0 0\n",
            channels.join(" ")
        );
        let tree = Tree::parse(text.as_bytes()).unwrap();
        let pos = forward_kinematics(&tree.joints, &[0, 1], &tree.values);
        pos[1]
    }

    #[test]
    fn two_joint_chain_in_each_rotation_order() {
        // R = R(c1)·R(c2)·R(c3) applied to (1, 2, 3), worked by hand with
        // Rx90: (x,y,z)→(x,−z,y), Ry90: →(z,y,−x), Rz90: →(−y,x,z).
        let expected = [
            ("ZYX", [3.0, 2.0, -1.0]),
            ("ZXY", [-1.0, 3.0, 2.0]),
            ("XYZ", [3.0, -2.0, 1.0]),
            ("XZY", [-2.0, 1.0, 3.0]),
            ("YXZ", [1.0, -3.0, 2.0]),
            ("YZX", [2.0, 1.0, -3.0]),
        ];
        for (order, r) in expected {
            let p = chain(order);
            let want = [10.0 + r[0], 20.0 + r[1], 30.0 + r[2]];
            for k in 0..3 {
                assert!((p[k] - want[k]).abs() < 1e-9, "{order}: {p:?} != {want:?}");
            }
        }
    }

    #[test]
    fn crlf_line_endings_read_the_same() {
        let lf = "HIERARCHY\nROOT A\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n End Site\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\nFrames: 2\nFrame Time: 0.0083333\n1 2 3 10 20 30\n4 5 6 40 50 60\n";
        let crlf = lf.replace('\n', "\r\n");
        let a = Tree::parse(lf.as_bytes()).unwrap();
        let b = Tree::parse(crlf.as_bytes()).unwrap();
        assert_eq!(a.values, b.values);
        assert_eq!(a.values.len(), 12);
        assert_eq!(a.frames, 2);
    }
}
