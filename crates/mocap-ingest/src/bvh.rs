//! BVH reading, all our own code: the hierarchy by a small validating parser
//! (every malformed construct is an error with its line, never a panic), the
//! motion table in one validating pass (values per line, frame count,
//! non-finite values, line numbers; `Frames:` is never trusted for memory).

use crate::error::{check_text, ends_at_end, is_number_prefix, snippet, ErrorKind, Truncation};
use crate::math::{add, norm, scale, Axis, Mat3, Vec3};
use crate::skeleton::{
    bvh_joints, recognise_bvh, BvhJoint, Pose, SkeletonKind, CMU_REFERENCE_LEG,
    CMU_ROOT_FROM_HIP_JOINTS, HIPS, LEFT_FOOT, LEFT_LEG, LEFT_UP_LEG, NUM_JOINTS, RIGHT_FOOT,
    RIGHT_LEG, RIGHT_UP_LEG,
};
use crate::text::{parse_decimal, parse_numbers, tokens};

/// One BVH joint (or End Site), reduced to what forward kinematics needs.
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
/// motion frame (the synthetic T-pose or rest pose already dropped).
#[derive(Clone, Debug)]
pub struct BvhMotion {
    /// The recognised skeleton.
    pub skeleton: SkeletonKind,
    /// Frame rate stated by the file's `Frame Time`.
    pub declared_fps: f64,
    /// Factor from the file's length unit to CMU units (1 except for the
    /// Daz-friendly release, see [`SkeletonKind::Daz`]).
    pub unit_scale: f64,
    joints: Vec<Joint>,
    /// Joints to evaluate, in an order where parents come first.
    needed: Vec<usize>,
    /// For each kept joint, its index in `joints`.
    kept: [usize; NUM_JOINTS],
    values: Vec<f64>,
    num_channels: usize,
    first_frame: usize,
    num_frames: usize,
    truncation: Option<Truncation>,
}

impl BvhMotion {
    /// Parse and validate a BVH file. A file that ends inside its motion
    /// reads with its complete frames ([`BvhMotion::truncation`]); if it has
    /// no complete motion frame, or fails any later check, the error is
    /// [`ErrorKind::Truncated`], as its cut is what is wrong with it.
    pub fn parse(bytes: &[u8]) -> Result<BvhMotion, ErrorKind> {
        let tree = Tree::parse(bytes)?;
        let truncation = tree.truncation;
        let fail = |k: ErrorKind| truncation.map_or(k, Truncation::to_error);
        let name_refs: Vec<&str> = tree.names.iter().flatten().map(String::as_str).collect();
        let skeleton = recognise_bvh(&name_refs)
            .map_err(|(closest, missing)| fail(ErrorKind::UnknownSkeleton { closest, missing }))?;
        let mut kept = [0usize; NUM_JOINTS];
        for (k, want) in bvh_joints(skeleton).iter().enumerate() {
            kept[k] = find_joint(&tree, *want).map_err(fail)?;
        }
        let mut joints = tree.joints;
        let unit_scale = match skeleton {
            SkeletonKind::Daz => daz_hips(&mut joints, &mut kept).map_err(fail)?,
            _ => 1.0,
        };
        let needed = ancestors_closure(&joints, &kept).map_err(fail)?;
        let first_frame = usize::from(skeleton.has_tpose_frame());
        if tree.frames <= first_frame {
            return Err(fail(ErrorKind::NoFrames));
        }
        Ok(BvhMotion {
            skeleton,
            declared_fps: 1.0 / tree.frame_time,
            unit_scale,
            joints,
            needed,
            kept,
            values: tree.values,
            num_channels: tree.channels,
            first_frame,
            num_frames: tree.frames - first_frame,
            truncation: truncation.map(|t| Truncation {
                leading: first_frame,
                ..t
            }),
        })
    }

    /// Number of motion frames (T-pose excluded).
    pub fn num_frames(&self) -> usize {
        self.num_frames
    }

    /// Where the file was cut, if it ends inside its motion (the complete
    /// frames before the cut are the motion).
    pub fn truncation(&self) -> Option<Truncation> {
        self.truncation
    }

    /// Global positions of the kept joints at `frame` (0-based, T-pose
    /// excluded), in CMU units.
    pub fn pose(&self, frame: usize) -> Pose {
        let start = (frame + self.first_frame) * self.num_channels;
        let pos = forward_kinematics(
            &self.joints,
            &self.needed,
            &self.values[start..start + self.num_channels],
        );
        if self.unit_scale == 1.0 {
            self.kept.map(|j| pos[j])
        } else {
            self.kept.map(|j| scale(pos[j], self.unit_scale))
        }
    }
}

/// The index of a kept joint's BVH joint (or End Site); a name that occurs
/// twice is ambiguous and refused.
fn find_joint(tree: &Tree, want: BvhJoint) -> Result<usize, ErrorKind> {
    let name = want.name();
    let mut hits = tree
        .names
        .iter()
        .enumerate()
        .filter(|(_, n)| n.as_deref() == Some(name))
        .map(|(i, _)| i);
    let (Some(j), None) = (hits.next(), hits.next()) else {
        return Err(syntax(
            None,
            format!("joint name {name} occurs more than once"),
        ));
    };
    match want {
        BvhJoint::Named(_) => Ok(j),
        BvhJoint::EndSiteOf(_) => tree
            .joints
            .iter()
            .zip(&tree.names)
            .position(|(c, n)| n.is_none() && c.parent == Some(j))
            .ok_or_else(|| syntax(None, format!("joint {name} has no End Site"))),
    }
}

/// Adapt a Daz figure: returns its unit scale (a fixed CMU leg length,
/// hip joint to ankle, [`CMU_REFERENCE_LEG`], over the file's own: the mean
/// of both legs' thigh + shin offsets) and makes `Hips` the point where a
/// CMU root sits relative to its hip joints ([`CMU_ROOT_FROM_HIP_JOINTS`]),
/// fixed in the frame of the figure's `hip` (which lies elsewhere in the
/// pelvis), as a new channel-less joint.
fn daz_hips(joints: &mut Vec<Joint>, kept: &mut [usize; NUM_JOINTS]) -> Result<f64, ErrorKind> {
    let leg = [LEFT_LEG, LEFT_FOOT, RIGHT_LEG, RIGHT_FOOT]
        .iter()
        .map(|&k| norm(joints[kept[k]].offset))
        .sum::<f64>()
        / 2.0;
    if !(leg.is_finite() && leg > 1e-6) {
        return Err(ErrorKind::Degenerate {
            frame: 0,
            reason: format!("the Daz figure's legs have length {leg}"),
        });
    }
    let unit_scale = CMU_REFERENCE_LEG / leg;
    // Each hip joint's rest position in the hip's frame: the offsets from
    // `hip` down to the thigh (through `lButtock`).
    let hip = kept[HIPS];
    let rest = |mut j: usize| {
        let mut p = [0.0; 3];
        while j != hip {
            p = add(p, joints[j].offset);
            match joints[j].parent {
                Some(q) => j = q,
                None => return None,
            }
        }
        Some(p)
    };
    let (Some(l), Some(r)) = (rest(kept[LEFT_UP_LEG]), rest(kept[RIGHT_UP_LEG])) else {
        return Err(syntax(None, "the thighs do not hang from `hip`".into()));
    };
    let offset = add(
        scale(add(l, r), 0.5),
        scale(CMU_ROOT_FROM_HIP_JOINTS, 1.0 / unit_scale),
    );
    joints.push(Joint {
        parent: Some(hip),
        offset,
        position: [None; 3],
        rotation: Vec::new(),
    });
    kept[HIPS] = joints.len() - 1;
    Ok(unit_scale)
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
    /// Joint names; `None` for an End Site.
    names: Vec<Option<String>>,
    values: Vec<f64>,
    channels: usize,
    /// Complete frames (all of `Frames:` unless the file is cut short).
    frames: usize,
    /// Seconds per frame.
    frame_time: f64,
    /// Set when the file ends inside its motion.
    truncation: Option<Truncation>,
}

impl Tree {
    fn parse(bytes: &[u8]) -> Result<Tree, ErrorKind> {
        check_text(bytes)?;
        let (header_end, motion) = split_motion(bytes)?;
        let h = parse_hierarchy(&bytes[..header_end])?;
        let table = parse_motion(bytes, motion, h.channels, |ch| {
            channel_owner(&h.joints, &h.names, ch)
        })?;
        Ok(Tree {
            joints: h.joints,
            names: h.names,
            values: table.values,
            channels: h.channels,
            frames: table.frames,
            frame_time: table.frame_time,
            truncation: table.truncation,
        })
    }
}

/// The parsed `HIERARCHY` section.
struct Hierarchy {
    /// Joints and End Sites in file order (depth-first, parents first).
    joints: Vec<Joint>,
    /// Joint names; `None` for an End Site.
    names: Vec<Option<String>>,
    /// Number of channels (values per motion line).
    channels: usize,
}

/// A node being read: which line opened it, whether it has its `{`, OFFSET
/// and CHANNELS yet.
struct Open {
    node: usize,
    line: usize,
    has_offset: bool,
    has_channels: bool,
}

/// Parse the `HIERARCHY` section (everything before the `MOTION` line).
///
/// Our own parser, checking the whole grammar with line numbers:
/// `HIERARCHY`, one `ROOT name { … }` whose body holds one `OFFSET x y z`,
/// at most one `CHANNELS n c1 … cn` (the `n` names on the same line), and
/// nested `JOINT name { … }` or `End Site { OFFSET x y z }` blocks. End Sites
/// become channel-less nodes without a name. A malformed hierarchy is an
/// error here, never a panic.
fn parse_hierarchy(header: &[u8]) -> Result<Hierarchy, ErrorKind> {
    let mut h = HierarchyReader {
        joints: Vec::new(),
        names: Vec::new(),
        stack: Vec::new(),
        pending: None,
        started: false,
        finished: false,
        channels: 0,
    };
    let mut last_line = 0;
    for (ln, line) in (1..).zip(header.split(|&b| b == b'\n')) {
        let toks: Vec<&[u8]> = tokens(line).collect();
        if !toks.is_empty() {
            last_line = ln;
        }
        let mut i = 0;
        while i < toks.len() {
            i = h.token(ln, &toks, i)?;
        }
    }
    h.finish(last_line)
}

/// The `HIERARCHY` section being read: the nodes so far and the blocks open.
struct HierarchyReader {
    /// Joints and End Sites in file order.
    joints: Vec<Joint>,
    /// Joint names; `None` for an End Site.
    names: Vec<Option<String>>,
    /// The blocks open, outermost first.
    stack: Vec<Open>,
    /// A node declared (ROOT/JOINT/End Site) whose `{` has not come yet.
    pending: Option<Open>,
    /// Whether `HIERARCHY` has come.
    started: bool,
    /// Whether the ROOT's block has closed.
    finished: bool,
    /// Channels declared so far.
    channels: usize,
}

impl HierarchyReader {
    /// `joint NAME` or `End Site`, for messages.
    fn node_name(&self, i: usize) -> String {
        match &self.names[i] {
            Some(n) => format!("joint {n}"),
            None => "End Site".into(),
        }
    }

    /// Read the token `toks[i]` of line `ln`, with the tokens its keyword
    /// takes after it; the index of the next token.
    fn token(&mut self, ln: usize, toks: &[&[u8]], i: usize) -> Result<usize, ErrorKind> {
        let t = toks[i];
        let rest = &toks[i + 1..];
        let err = |m: String| Err(syntax(Some(ln), m));
        if let Some(p) = &self.pending {
            if t != b"{" {
                return err(format!(
                    "expected `{{` to open the {} declared at line {}, found {:?}",
                    self.node_name(p.node),
                    p.line,
                    snippet(t)
                ));
            }
        }
        if !self.started {
            if t != b"HIERARCHY" {
                return err(format!("expected HIERARCHY, found {:?}", snippet(t)));
            }
            self.started = true;
            return Ok(i + 1);
        }
        if self.finished {
            return err(format!(
                "unexpected {:?} after the ROOT's closing brace",
                snippet(t)
            ));
        }
        let used = match t {
            b"ROOT" | b"JOINT" => self.joint(ln, t == b"ROOT", rest)?,
            b"End" => self.end_site(ln, rest)?,
            b"{" => self.open_block(ln)?,
            b"}" => self.close_block(ln)?,
            b"OFFSET" => self.offset(ln, rest)?,
            b"CHANNELS" => self.channel_list(ln, rest)?,
            _ => return err(format!("unexpected {:?} in HIERARCHY", snippet(t))),
        };
        Ok(i + 1 + used)
    }

    /// `ROOT name` or `JOINT name` (`rest`: the tokens after the keyword):
    /// a node declared, its `{` to come; the tokens used (the name).
    fn joint(&mut self, ln: usize, root: bool, rest: &[&[u8]]) -> Result<usize, ErrorKind> {
        let err = |m: String| Err(syntax(Some(ln), m));
        if root && !self.joints.is_empty() {
            return err("a second ROOT (one skeleton per file is supported)".into());
        }
        if !root && self.stack.is_empty() {
            return err("JOINT outside the ROOT".into());
        }
        let parent = self.stack.last().map(|o| o.node);
        if parent.is_some_and(|p| self.names[p].is_none()) {
            return err("JOINT inside an End Site".into());
        }
        let kw = if root { "ROOT" } else { "JOINT" };
        let name = match rest.first() {
            Some(n) if *n != b"{" && *n != b"}" => *n,
            _ => return err(format!("{kw} without a name")),
        };
        if let Some(extra) = rest.get(1).filter(|x| **x != b"{") {
            return err(format!(
                "{kw} {}: unexpected {:?} after the name",
                String::from_utf8_lossy(name),
                snippet(extra)
            ));
        }
        self.joints.push(Joint::new(parent));
        self.names
            .push(Some(String::from_utf8_lossy(name).into_owned()));
        self.pending = Some(Open::new(self.joints.len() - 1, ln));
        Ok(1)
    }

    /// `End Site` (`rest`: the tokens after `End`): a channel-less node
    /// declared, its `{` to come; the tokens used (`Site`).
    fn end_site(&mut self, ln: usize, rest: &[&[u8]]) -> Result<usize, ErrorKind> {
        let err = |m: String| Err(syntax(Some(ln), m));
        if rest.first() != Some(&&b"Site"[..]) {
            return err("`End` must be followed by `Site`".into());
        }
        let Some(parent) = self.stack.last().map(|o| o.node) else {
            return err("End Site outside a joint".into());
        };
        if self.names[parent].is_none() {
            return err("End Site inside an End Site".into());
        }
        self.joints.push(Joint::new(Some(parent)));
        self.names.push(None);
        self.pending = Some(Open::new(self.joints.len() - 1, ln));
        Ok(1)
    }

    /// `{`: the declared node's block opens; no tokens used.
    fn open_block(&mut self, ln: usize) -> Result<usize, ErrorKind> {
        match self.pending.take() {
            Some(p) => self.stack.push(p),
            None => {
                return Err(syntax(
                    Some(ln),
                    "unexpected `{` (no ROOT, JOINT or End Site before it)".into(),
                ))
            }
        }
        Ok(0)
    }

    /// `}`: the innermost block closes (it must have had its OFFSET); the
    /// hierarchy is finished when the ROOT's does. No tokens used.
    fn close_block(&mut self, ln: usize) -> Result<usize, ErrorKind> {
        let err = |m: String| Err(syntax(Some(ln), m));
        let Some(open) = self.stack.pop() else {
            return err("unexpected `}` (nothing is open)".into());
        };
        if !open.has_offset {
            return err(format!(
                "the {} opened at line {} has no OFFSET",
                self.node_name(open.node),
                open.line
            ));
        }
        self.finished = self.stack.is_empty();
        Ok(0)
    }

    /// `OFFSET x y z` of the open node (`rest`: the numbers); uses the rest
    /// of the line.
    fn offset(&mut self, ln: usize, rest: &[&[u8]]) -> Result<usize, ErrorKind> {
        let err = |m: String| Err(syntax(Some(ln), m));
        let Some(open) = self.stack.last_mut() else {
            return err("OFFSET outside a joint".into());
        };
        if open.has_offset {
            let node = open.node;
            return err(format!("a second OFFSET in the {}", self.node_name(node)));
        }
        if rest.len() != 3 {
            return err(format!("OFFSET needs 3 numbers, found {}", rest.len()));
        }
        let mut o = [0.0; 3];
        for (v, tok) in o.iter_mut().zip(rest) {
            *v = parse_decimal(tok)
                .filter(|v| v.is_finite())
                .ok_or_else(|| ErrorKind::NonNumeric {
                    line: ln,
                    token: snippet(tok),
                })?;
        }
        open.has_offset = true;
        self.joints[open.node].offset = o;
        Ok(rest.len())
    }

    /// `CHANNELS n c1 … cn` of the open joint (`rest`: the count and the
    /// names), each channel numbered in file order; uses the rest of the
    /// line.
    fn channel_list(&mut self, ln: usize, rest: &[&[u8]]) -> Result<usize, ErrorKind> {
        let err = |m: String| Err(syntax(Some(ln), m));
        let Some(open) = self.stack.last_mut() else {
            return err("CHANNELS outside a joint".into());
        };
        if self.names[open.node].is_none() {
            return err("CHANNELS in an End Site".into());
        }
        if open.has_channels {
            let node = open.node;
            return err(format!("a second CHANNELS in the {}", self.node_name(node)));
        }
        let count_tok = rest.first().copied().unwrap_or(b"");
        let count: usize = std::str::from_utf8(count_tok)
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| ErrorKind::NonNumeric {
                line: ln,
                token: snippet(count_tok),
            })?;
        let listed = &rest[1.min(rest.len())..];
        if listed.len() != count {
            return err(format!(
                "CHANNELS declares {count} channels but lists {}",
                listed.len()
            ));
        }
        let joint = &mut self.joints[open.node];
        for c in listed {
            let (axis, position) = channel_type(c)
                .ok_or_else(|| syntax(Some(ln), format!("unknown channel {:?}", snippet(c))))?;
            let twice = if position {
                joint.position[axis as usize].is_some()
            } else {
                joint.rotation.iter().any(|r| r.0 == axis)
            };
            if twice {
                return err(format!("channel {:?} listed twice", snippet(c)));
            }
            if position {
                joint.position[axis as usize] = Some(self.channels);
            } else {
                joint.rotation.push((axis, self.channels));
            }
            self.channels += 1;
        }
        open.has_channels = true;
        Ok(rest.len())
    }

    /// The hierarchy read, if it is complete (`last_line`: the section's last
    /// non-blank line, for messages).
    fn finish(self, last_line: usize) -> Result<Hierarchy, ErrorKind> {
        let end = |m: String| Err(syntax(Some(last_line.max(1)), m));
        if !self.started {
            return end("no HIERARCHY".into());
        }
        if let Some(p) = &self.pending {
            return end(format!(
                "the {} declared at line {} has no body",
                self.node_name(p.node),
                p.line
            ));
        }
        if let Some(open) = self.stack.last() {
            return end(format!(
                "the hierarchy ends inside the {} opened at line {} (a `}}` is missing)",
                self.node_name(open.node),
                open.line
            ));
        }
        if self.joints.is_empty() {
            return end("no ROOT".into());
        }
        Ok(Hierarchy {
            joints: self.joints,
            names: self.names,
            channels: self.channels,
        })
    }
}

impl Joint {
    fn new(parent: Option<usize>) -> Joint {
        Joint {
            parent,
            offset: [0.0; 3],
            position: [None; 3],
            rotation: Vec::new(),
        }
    }
}

impl Open {
    fn new(node: usize, line: usize) -> Open {
        Open {
            node,
            line,
            has_offset: false,
            has_channels: false,
        }
    }
}

/// `Xposition` → (X, true), `Zrotation` → (Z, false); case-insensitive.
fn channel_type(t: &[u8]) -> Option<(Axis, bool)> {
    let (a, rest) = t.split_first()?;
    let axis = match a.to_ascii_lowercase() {
        b'x' => Axis::X,
        b'y' => Axis::Y,
        b'z' => Axis::Z,
        _ => return None,
    };
    if rest.eq_ignore_ascii_case(b"position") {
        Some((axis, true))
    } else if rest.eq_ignore_ascii_case(b"rotation") {
        Some((axis, false))
    } else {
        None
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
    // The parser stores joints depth-first, so a parent precedes its children.
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

fn channel_owner(joints: &[Joint], names: &[Option<String>], ch: usize) -> String {
    joints
        .iter()
        .zip(names)
        .find(|(j, _)| j.position.contains(&Some(ch)) || j.rotation.iter().any(|r| r.1 == ch))
        .and_then(|(_, n)| n.clone())
        .unwrap_or_else(|| "?".into())
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

struct MotionTable {
    values: Vec<f64>,
    /// Complete frames read (`Frames:` unless the file is cut short).
    frames: usize,
    frame_time: f64,
    /// Set when the file ends before its last frame is complete.
    truncation: Option<Truncation>,
}

/// The `Frames: N` and `Frame Time: S` lines that open the motion section
/// (`lines`: its non-blank lines with their numbers, after `MOTION`): the
/// frame count, the seconds per frame, and the second line's number.
fn motion_header<'b>(
    lines: &mut impl Iterator<Item = (usize, &'b [u8])>,
) -> Result<(usize, f64, usize), ErrorKind> {
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
    Ok((frames, frame_time, n))
}

/// Parse the motion section starting at 1-based line `motion_line`
/// (`MOTION`, `Frames: N`, `Frame Time: S`, then N lines of `channels` values),
/// checking every line. A file cut short (fewer lines than `Frames:` says, a
/// short last line, or a last value cut at the very end of the file) keeps
/// its complete frames and says so in `truncation`; damage anywhere else is
/// an error.
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
    let (frames, frame_time, n) = motion_header(&mut lines)?;
    // Never trust `Frames:` for memory: each value takes at least two bytes.
    let mut values = Vec::with_capacity((frames * channels).min(bytes.len() / 2));
    let mut found = 0usize;
    let mut last_line = n;
    // The table of the `found` complete frames, the file cut at `line`.
    let cut = |mut values: Vec<f64>, found: usize, line: usize| {
        values.truncate(found * channels);
        Ok(MotionTable {
            values,
            frames: found,
            frame_time,
            truncation: Some(Truncation {
                expected: frames,
                found,
                line,
                leading: 0,
            }),
        })
    };
    while let Some((n, line)) = lines.next() {
        last_line = n;
        let before = values.len();
        let parsed = parse_numbers(line, &mut values);
        if let Some(ch) = values[before..].iter().position(|v| !v.is_finite()) {
            return Err(ErrorKind::NonFinite {
                frame: found,
                what: format!("channel {ch} ({}) at line {n}", owner(ch)),
            });
        }
        if let Err(t) = parsed {
            // A number cut by the end of the file ends the motion there.
            if values.len() - before < channels && is_number_prefix(t) && ends_at_end(bytes, t) {
                return cut(values, found, n);
            }
            return Err(ErrorKind::NonNumeric {
                line: n,
                token: snippet(t),
            });
        }
        let count = values.len() - before;
        if count != channels {
            // A short final line is a truncated file, not a layout error.
            if count < channels && lines.next().is_none() {
                return cut(values, found, n);
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
        return cut(values, found, last_line);
    }
    Ok(MotionTable {
        values,
        frames: found,
        frame_time,
        truncation: None,
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
