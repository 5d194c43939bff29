//! BVH reading through `bvh_anim`, with the validation `bvh_anim` lacks
//! (channel counts per line, truncation, frame-count sanity, NaN) and with its
//! panics contained.

use crate::error::{check_text, snippet, ErrorKind};
use crate::math::{add, Axis, Mat3, Vec3};
use crate::skeleton::{bvh_names, recognise_bvh, Pose, SkeletonKind, NUM_JOINTS};
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
    values: Vec<f32>,
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
fn forward_kinematics(joints: &[Joint], order: &[usize], v: &[f32]) -> Vec<Vec3> {
    let n = joints.len();
    let mut rot = vec![Mat3::IDENTITY; n];
    let mut pos = vec![[0.0; 3]; n];
    for &j in order {
        let joint = &joints[j];
        let mut local = joint.offset;
        for (axis, idx) in joint.position.iter().enumerate() {
            if let Some(i) = idx {
                local[axis] += v[*i] as f64;
            }
        }
        let mut r = Mat3::IDENTITY;
        for &(axis, i) in &joint.rotation {
            r = r.mul(&Mat3::rotation(axis, (v[i] as f64).to_radians()));
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
    values: Vec<f32>,
    channels: usize,
    frames: usize,
    /// Seconds per frame.
    frame_time: f64,
}

impl Tree {
    fn parse(bytes: &[u8]) -> Result<Tree, ErrorKind> {
        check_text(bytes)?;
        let layout = prescan(bytes)?;
        let bvh = match catch_unwind(AssertUnwindSafe(|| bvh_anim::from_bytes(bytes))) {
            Ok(Ok(bvh)) => bvh,
            Ok(Err(e)) => return Err(explain_parse_failure(bytes, &e.to_string())),
            Err(payload) => return Err(ErrorKind::Panic(panic_message(payload))),
        };
        let mut joints = Vec::new();
        let mut names = Vec::new();
        for j in bvh.joints() {
            let data = j.data();
            let o = data.offset();
            let mut position = [None; 3];
            let mut rotation = Vec::new();
            for c in data.channels() {
                let i = c.motion_index();
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
        let (channels, frames) = (layout.channels, layout.frames);
        let values: Vec<f32> = bvh
            .frames()
            .flat_map(|f| f.as_slice().iter().copied())
            .collect();
        if values.len() != frames * channels {
            return Err(ErrorKind::Syntax {
                format: "BVH",
                line: None,
                message: format!(
                    "{} motion values for {frames} frames of {channels} channels",
                    values.len()
                ),
            });
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            let (frame, ch) = (i / channels, i % channels);
            return Err(ErrorKind::NonFinite {
                frame,
                what: format!(
                    "channel {ch} ({}) at line {}",
                    channel_owner(&joints, &names, ch),
                    layout.first_data_line + frame
                ),
            });
        }
        let frame_time = bvh.frame_time().as_secs_f64();
        if !(frame_time > 0.0 && frame_time.is_finite()) {
            return Err(ErrorKind::Syntax {
                format: "BVH",
                line: None,
                message: format!("invalid Frame Time {frame_time}"),
            });
        }
        Ok(Tree {
            joints,
            names,
            values,
            channels,
            frames,
            frame_time,
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
                return Err(ErrorKind::Syntax {
                    format: "BVH",
                    line: None,
                    message: "cyclic joint hierarchy".into(),
                });
            }
        }
    }
    let order: Vec<usize> = (0..joints.len()).filter(|&i| mark[i]).collect();
    // bvh_anim stores joints depth-first, so a parent precedes its children.
    if order
        .iter()
        .any(|&i| joints[i].parent.is_some_and(|p| p >= i))
    {
        return Err(ErrorKind::Syntax {
            format: "BVH",
            line: None,
            message: "joint hierarchy is not in depth-first order".into(),
        });
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

/// What a cheap scan of the text says about the motion section.
struct Layout {
    channels: usize,
    frames: usize,
    first_data_line: usize,
}

/// Validate the structure `bvh_anim` trusts blindly: the declared channel
/// count, the frame count (so a huge `Frames:` cannot exhaust memory), and the
/// number of values on every motion line. Line numbers are 1-based.
fn prescan(bytes: &[u8]) -> Result<Layout, ErrorKind> {
    let syntax = |line: Option<usize>, message: String| ErrorKind::Syntax {
        format: "BVH",
        line,
        message,
    };
    let mut lines = bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .map(|(i, l)| (i + 1, l));
    let mut channels = 0usize;
    let mut saw_motion = false;
    for (n, line) in lines.by_ref() {
        let mut tok = tokens(line);
        match tok.next() {
            Some(b"CHANNELS") => {
                let count = tok.next().unwrap_or(b"");
                let c: usize = std::str::from_utf8(count)
                    .ok()
                    .and_then(|s| s.parse().ok())
                    .ok_or_else(|| ErrorKind::NonNumeric {
                        line: n,
                        token: snippet(count),
                    })?;
                let listed = tok.count();
                if listed != c {
                    return Err(syntax(
                        Some(n),
                        format!("CHANNELS declares {c} channels but lists {listed}"),
                    ));
                }
                channels += c;
            }
            Some(b"MOTION") => {
                saw_motion = true;
                break;
            }
            _ => {}
        }
    }
    if !saw_motion {
        return Err(syntax(None, "no MOTION section".into()));
    }
    let mut header = lines.by_ref().filter(|(_, l)| !l.trim_ascii().is_empty());
    let (n, frames_line) = header
        .next()
        .ok_or_else(|| syntax(None, "missing `Frames:` line after MOTION".into()))?;
    let frames_text = frames_line.trim_ascii();
    let frames: usize = frames_text
        .strip_prefix(b"Frames:")
        .map(|t| t.trim_ascii())
        .and_then(|t| std::str::from_utf8(t).ok())
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| {
            syntax(
                Some(n),
                format!("expected `Frames: N`, found {:?}", snippet(frames_text)),
            )
        })?;
    let (n, ft_line) = header
        .next()
        .ok_or_else(|| syntax(None, "missing `Frame Time:` line".into()))?;
    if !ft_line.trim_ascii().starts_with(b"Frame Time:") {
        return Err(syntax(Some(n), "expected `Frame Time: SECONDS`".into()));
    }
    let first_data_line = n + 1;
    let mut found = 0usize;
    let mut last_line = n;
    for (n, line) in lines {
        last_line = n;
        let count = tokens(line).count();
        if count == 0 {
            continue;
        }
        if count != channels {
            // A short final line is a truncated file, not a layout error.
            let rest = &bytes[(line.as_ptr() as usize - bytes.as_ptr() as usize) + line.len()..];
            if count < channels && rest.iter().all(u8::is_ascii_whitespace) {
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
    }
    if found < frames {
        return Err(ErrorKind::Truncated {
            expected: frames,
            found,
            line: last_line,
        });
    }
    if found > frames {
        return Err(syntax(
            None,
            format!("`Frames: {frames}` but the file holds {found} frames"),
        ));
    }
    Ok(Layout {
        channels,
        frames,
        first_data_line,
    })
}

/// Whitespace-separated tokens of a line.
fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| b.is_ascii_whitespace())
        .filter(|t| !t.is_empty())
}

/// After `bvh_anim` rejected a file that passed [`prescan`], find the first
/// motion value that is not a finite number, so the error can name its line.
fn explain_parse_failure(bytes: &[u8], parser_message: &str) -> ErrorKind {
    let motion = bytes
        .split(|&b| b == b'\n')
        .position(|l| l.trim_ascii() == b"MOTION");
    if let Some(m) = motion {
        // Data starts three lines after MOTION (Frames:, Frame Time:).
        for (i, line) in bytes.split(|&b| b == b'\n').enumerate().skip(m + 3) {
            for t in tokens(line) {
                let parsed = std::str::from_utf8(t)
                    .ok()
                    .and_then(|s| s.parse::<f32>().ok());
                match parsed {
                    Some(v) if v.is_finite() => {}
                    Some(_) => {
                        return ErrorKind::NonFinite {
                            frame: i - m - 3,
                            what: format!("value {:?} at line {}", snippet(t), i + 1),
                        }
                    }
                    None => {
                        return ErrorKind::NonNumeric {
                            line: i + 1,
                            token: snippet(t),
                        }
                    }
                }
            }
        }
    }
    ErrorKind::Syntax {
        format: "BVH",
        line: None,
        message: parser_message.to_string(),
    }
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
