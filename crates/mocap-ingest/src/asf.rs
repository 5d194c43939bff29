//! CMU's original Acclaim format: ASF (skeleton) and AMC (motion), with forward
//! kinematics to the 19 kept joints.
//!
//! Conventions (those of CMU's own viewer and of the cgspeed BVH conversion):
//! - An `axis ax ay az XYZ` entry gives `C = Rz(az)·Ry(ay)·Rx(ax)` (rotations
//!   applied in the listed order); `dof rx ry rz` likewise gives
//!   `M = Rz·Ry·Rx` from the AMC values.
//! - A bone's global rotation is `R = R_parent · C · M · C⁻¹`; its end lies at
//!   `start + length · R · direction`, where `start` is the parent bone's end
//!   (the root position for bones hanging off the root).
//! - The root's AMC values follow `:root order`; its position is
//!   `position + (TX, TY, TZ)` and its rotation `C_root · M_root · C_root⁻¹`.
//! - Lengths stay in raw ASF units (no `:units length` scale), as in the BVH
//!   conversions.

use crate::error::{check_text, ends_at_end, is_number_prefix, snippet, ErrorKind, Truncation};
use crate::math::{add, scale, Axis, Mat3, Vec3};
use crate::skeleton::{Pose, ASF_BONES, NUM_JOINTS};
use crate::text::{parse_decimal, tokens};

/// How to build the skeleton from an ASF.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AsfOptions {
    /// Keep the `thorax` segment's length. By default it is set to zero, as in
    /// both cgspeed BVH releases, so that a take gives the same features from
    /// either format.
    pub full_skeleton: bool,
}

/// One channel of the root's AMC line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum RootDof {
    T(usize),
    R(Axis),
}

#[derive(Clone, Debug)]
struct Bone {
    name: String,
    /// Parent bone index, `None` when attached to the root.
    parent: Option<usize>,
    /// `length · direction`, in raw ASF units.
    vector: Vec3,
    c: Mat3,
    c_inv: Mat3,
    dofs: Vec<Axis>,
    /// Offset of this bone's values in a frame's value vector.
    value_offset: usize,
}

/// A parsed ASF skeleton.
#[derive(Clone, Debug)]
pub struct AsfSkeleton {
    degrees: bool,
    root_order: Vec<RootDof>,
    root_rot_axes: Vec<Axis>,
    root_position: Vec3,
    root_c: Mat3,
    bones: Vec<Bone>,
    /// Bones to evaluate, parents first.
    needed: Vec<usize>,
    /// Bone index of each kept joint except the root (index 0 unused).
    kept: [usize; NUM_JOINTS],
    values_per_frame: usize,
}

fn asf_err(line: usize, message: impl Into<String>) -> ErrorKind {
    ErrorKind::Syntax {
        format: "ASF",
        line: Some(line),
        message: message.into(),
    }
}

fn amc_err(line: usize, message: impl Into<String>) -> ErrorKind {
    ErrorKind::Syntax {
        format: "AMC",
        line: Some(line),
        message: message.into(),
    }
}

fn number(line: usize, tok: &str) -> Result<f64, ErrorKind> {
    number_bytes(line, tok.as_bytes())
}

fn number_bytes(line: usize, tok: &[u8]) -> Result<f64, ErrorKind> {
    match parse_decimal(tok) {
        Some(v) if v.is_finite() => Ok(v),
        Some(_) => Err(ErrorKind::NonFinite {
            frame: 0,
            what: format!("value {:?} at line {line}", String::from_utf8_lossy(tok)),
        }),
        None => Err(ErrorKind::NonNumeric {
            line,
            token: snippet(tok),
        }),
    }
}

fn axis_of(c: u8) -> Option<Axis> {
    match c.to_ascii_lowercase() {
        b'x' => Some(Axis::X),
        b'y' => Some(Axis::Y),
        b'z' => Some(Axis::Z),
        _ => None,
    }
}

fn axis_order(line: usize, s: &str) -> Result<Vec<Axis>, ErrorKind> {
    let axes: Option<Vec<Axis>> = s.bytes().map(axis_of).collect();
    match axes {
        Some(a) if a.len() == 3 => Ok(a),
        _ => Err(asf_err(line, format!("bad axis order {s:?}"))),
    }
}

fn three(line: usize, toks: &[&str]) -> Result<Vec3, ErrorKind> {
    if toks.len() < 3 {
        return Err(asf_err(line, "expected three numbers"));
    }
    Ok([
        number(line, toks[0])?,
        number(line, toks[1])?,
        number(line, toks[2])?,
    ])
}

/// Text lines with 1-based numbers, comments (`#`) removed, blank lines skipped.
fn text_lines(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.split('#').next().unwrap_or("");
        let toks: Vec<&str> = l.split_ascii_whitespace().collect();
        (!toks.is_empty()).then_some((i + 1, toks))
    })
}

struct BoneDraft {
    line: usize,
    name: Option<String>,
    direction: Option<Vec3>,
    length: Option<f64>,
    axis: Option<(Vec3, Vec<Axis>)>,
    dofs: Vec<Axis>,
}

impl AsfSkeleton {
    /// Parse an ASF file.
    pub fn parse(bytes: &[u8], options: AsfOptions) -> Result<AsfSkeleton, ErrorKind> {
        check_text(bytes)?;
        let text = String::from_utf8_lossy(bytes);
        let mut section = String::new();
        let mut degrees = true;
        let mut root_order: Vec<RootDof> = Vec::new();
        let mut root_axis: Option<Vec<Axis>> = None;
        let mut root_position = [0.0; 3];
        let mut root_orientation = [0.0; 3];
        let mut drafts: Vec<BoneDraft> = Vec::new();
        let mut current: Option<BoneDraft> = None;
        let mut hierarchy: Vec<(usize, Vec<String>)> = Vec::new();
        let mut last_line = 0;

        for (n, toks) in text_lines(&text) {
            last_line = n;
            if let Some(kw) = toks[0].strip_prefix(':') {
                section = kw.to_ascii_lowercase();
                continue;
            }
            let key = toks[0].to_ascii_lowercase();
            match section.as_str() {
                "units" if key == "angle" => {
                    degrees = match toks.get(1).map(|s| s.to_ascii_lowercase()) {
                        Some(u) if u.starts_with("deg") => true,
                        Some(u) if u.starts_with("rad") => false,
                        _ => return Err(asf_err(n, "angle unit must be deg or rad")),
                    };
                }
                "root" => match key.as_str() {
                    "order" => {
                        root_order = toks[1..]
                            .iter()
                            .map(|t| {
                                let t = t.to_ascii_lowercase();
                                let b = t.as_bytes();
                                match (b.first(), b.get(1).and_then(|&c| axis_of(c))) {
                                    (Some(b't'), Some(a)) if b.len() == 2 => {
                                        Ok(RootDof::T(a as usize))
                                    }
                                    (Some(b'r'), Some(a)) if b.len() == 2 => Ok(RootDof::R(a)),
                                    _ => Err(asf_err(n, format!("bad root channel {t:?}"))),
                                }
                            })
                            .collect::<Result<_, _>>()?;
                    }
                    "axis" => root_axis = Some(axis_order(n, toks.get(1).unwrap_or(&""))?),
                    "position" => root_position = three(n, &toks[1..])?,
                    "orientation" => root_orientation = three(n, &toks[1..])?,
                    _ => {}
                },
                "bonedata" => match key.as_str() {
                    "begin" => {
                        if current.is_some() {
                            return Err(asf_err(n, "`begin` inside a bone (missing `end`)"));
                        }
                        current = Some(BoneDraft {
                            line: n,
                            name: None,
                            direction: None,
                            length: None,
                            axis: None,
                            dofs: Vec::new(),
                        });
                    }
                    "end" => match current.take() {
                        Some(d) => drafts.push(d),
                        None => return Err(asf_err(n, "`end` without `begin`")),
                    },
                    _ => {
                        let Some(d) = current.as_mut() else {
                            return Err(asf_err(n, format!("{:?} outside begin/end", toks[0])));
                        };
                        match key.as_str() {
                            "name" => d.name = toks.get(1).map(|s| s.to_string()),
                            "direction" => d.direction = Some(three(n, &toks[1..])?),
                            "length" => d.length = Some(number(n, toks.get(1).unwrap_or(&""))?),
                            "axis" => {
                                let v = three(n, &toks[1..])?;
                                let order = axis_order(n, toks.get(4).unwrap_or(&""))?;
                                d.axis = Some((v, order));
                            }
                            "dof" => {
                                d.dofs = toks[1..]
                                    .iter()
                                    .map(|t| {
                                        let b = t.as_bytes();
                                        match (b, b.get(1).and_then(|&c| axis_of(c))) {
                                            ([b'r' | b'R', _], Some(a)) => Ok(a),
                                            _ => Err(asf_err(
                                                n,
                                                format!("unsupported dof {t:?} (only rx, ry, rz)"),
                                            )),
                                        }
                                    })
                                    .collect::<Result<_, _>>()?;
                            }
                            _ => {} // id, limits and their continuation lines, bodymass, …
                        }
                    }
                },
                "hierarchy" if key != "begin" && key != "end" => {
                    hierarchy.push((n, toks.iter().map(|s| s.to_string()).collect()));
                }
                _ => {}
            }
        }
        if current.is_some() {
            return Err(asf_err(
                last_line,
                "file ends inside a bone (missing `end`)",
            ));
        }
        if drafts.is_empty() {
            return Err(ErrorKind::Syntax {
                format: "ASF",
                line: None,
                message: "no :bonedata".into(),
            });
        }

        let rad = |v: f64| if degrees { v.to_radians() } else { v };
        let mut bones = Vec::with_capacity(drafts.len());
        let mut values_per_frame = root_order.len();
        for d in drafts {
            let name = d
                .name
                .ok_or_else(|| asf_err(d.line, "bone without a name"))?;
            let dir = d
                .direction
                .ok_or_else(|| asf_err(d.line, format!("bone {name} has no direction")))?;
            let mut length = d
                .length
                .ok_or_else(|| asf_err(d.line, format!("bone {name} has no length")))?;
            if name == "thorax" && !options.full_skeleton {
                length = 0.0;
            }
            let (axis_vals, order) = d
                .axis
                .unwrap_or(([0.0; 3], vec![Axis::X, Axis::Y, Axis::Z]));
            let c = Mat3::euler_applied(&order, &axis_vals.map(rad));
            let value_offset = values_per_frame;
            values_per_frame += d.dofs.len();
            bones.push(Bone {
                name,
                parent: None,
                vector: scale(dir, length),
                c,
                c_inv: c.transpose(),
                dofs: d.dofs,
                value_offset,
            });
        }
        // Hierarchy: "parent child child …"; "root" is the root.
        let index = |bones: &[Bone], n: &str| bones.iter().position(|b| b.name == n);
        let mut attached = vec![false; bones.len()];
        for (n, toks) in &hierarchy {
            let parent = if toks[0] == "root" {
                None
            } else {
                Some(index(&bones, &toks[0]).ok_or_else(|| {
                    asf_err(*n, format!("hierarchy names unknown bone {:?}", toks[0]))
                })?)
            };
            for child in &toks[1..] {
                let c = index(&bones, child).ok_or_else(|| {
                    asf_err(*n, format!("hierarchy names unknown bone {child:?}"))
                })?;
                bones[c].parent = parent;
                attached[c] = true;
            }
        }
        let mut kept = [0usize; NUM_JOINTS];
        let mut missing = Vec::new();
        for (k, want) in ASF_BONES.iter().enumerate().skip(1) {
            match index(&bones, want) {
                Some(i) if attached[i] => kept[k] = i,
                _ => missing.push(want.to_string()),
            }
        }
        if !missing.is_empty() {
            return Err(ErrorKind::UnknownSkeleton {
                closest: "CMU ASF",
                missing,
            });
        }
        let needed = topological_needed(&bones, &kept[1..])
            .ok_or_else(|| asf_err(last_line, "cyclic bone hierarchy"))?;
        let root_rot_axes: Vec<Axis> = root_order
            .iter()
            .filter_map(|d| match d {
                RootDof::R(a) => Some(*a),
                RootDof::T(_) => None,
            })
            .collect();
        let root_axis = root_axis.unwrap_or(vec![Axis::X, Axis::Y, Axis::Z]);
        Ok(AsfSkeleton {
            degrees,
            root_c: Mat3::euler_applied(&root_axis, &root_orientation.map(rad)),
            root_order,
            root_rot_axes,
            root_position,
            bones,
            needed,
            kept,
            values_per_frame,
        })
    }
}

/// The kept bones and their ancestors, ordered so that parents come first.
fn topological_needed(bones: &[Bone], kept: &[usize]) -> Option<Vec<usize>> {
    let mut depth = vec![usize::MAX; bones.len()];
    let mut mark = vec![false; bones.len()];
    for &k in kept {
        let mut j = Some(k);
        let mut steps = 0;
        while let Some(i) = j {
            mark[i] = true;
            j = bones[i].parent;
            steps += 1;
            if steps > bones.len() {
                return None;
            }
        }
    }
    for i in 0..bones.len() {
        if mark[i] {
            let mut d = 0;
            let mut j = bones[i].parent;
            while let Some(p) = j {
                d += 1;
                j = bones[p].parent;
            }
            depth[i] = d;
        }
    }
    let mut order: Vec<usize> = (0..bones.len()).filter(|&i| mark[i]).collect();
    order.sort_by_key(|&i| (depth[i], i));
    Some(order)
}

/// A parsed AMC motion bound to its skeleton.
#[derive(Clone, Debug)]
pub struct AmcMotion {
    skeleton: AsfSkeleton,
    /// `frames × values_per_frame` values, angles in radians.
    values: Vec<f64>,
    num_frames: usize,
    truncation: Option<Truncation>,
}

impl AmcMotion {
    /// Parse an AMC file against its subject's skeleton.
    ///
    /// A file that ends inside its last frame (lines of the frame missing,
    /// its last line short, or a bone name, value or frame number cut by
    /// the end of the file) reads with the complete frames before it
    /// ([`AmcMotion::truncation`]); without any complete frame it is
    /// [`ErrorKind::Truncated`]. Damage anywhere else is an error.
    pub fn parse(bytes: &[u8], skeleton: AsfSkeleton) -> Result<AmcMotion, ErrorKind> {
        check_text(bytes)?;
        let per_frame = skeleton.values_per_frame;
        let mut degrees = skeleton.degrees;
        let mut values: Vec<f64> = Vec::new();
        let mut frame: Option<usize> = None; // the current frame's number
        let mut seen = vec![false; skeleton.bones.len() + 1];
        let mut num_frames = 0usize;
        let mut last_line = 0;
        // Set when the file ends inside a frame: (that frame's number, line).
        let mut cut: Option<(usize, usize)> = None;

        let missing = |seen: &[bool]| -> Option<Option<String>> {
            if !(seen[0] || skeleton.root_order.is_empty()) {
                return Some(None);
            }
            skeleton
                .bones
                .iter()
                .enumerate()
                .find(|(i, b)| !b.dofs.is_empty() && !seen[i + 1])
                .map(|(_, b)| Some(b.name.clone()))
        };
        let finish = |seen: &[bool], frame: Option<usize>, at: usize| {
            let Some(num) = frame else {
                return Ok(());
            };
            match missing(seen) {
                None => Ok(()),
                Some(None) => Err(amc_err(at, format!("frame {num} has no root line"))),
                Some(Some(b)) => Err(amc_err(at, format!("frame {num} has no line for bone {b}"))),
            }
        };

        // Byte-level and allocation-free: this loop sees every line of every
        // AMC file. Lines of a frame come in the same order frame after
        // frame, so each position remembers its bone.
        let mut slot_at: Vec<usize> = Vec::new();
        let mut line_in_frame = 0usize;
        let mut next_line = 0usize; // byte offset of the next line
        for (n, raw) in (1..).zip(bytes.split(|&b| b == b'\n')) {
            next_line += raw.len() + 1;
            let line = match raw.iter().position(|&b| b == b'#') {
                Some(i) => &raw[..i],
                None => raw,
            };
            let mut toks = tokens(line);
            let Some(first) = toks.next() else {
                continue;
            };
            last_line = n;
            // Whether the file ends on this line (nothing but whitespace
            // after it, no comment on it): damage here may be the cut.
            let last = || {
                line.len() == raw.len()
                    && bytes
                        .get(next_line..)
                        .is_none_or(|rest| rest.iter().all(u8::is_ascii_whitespace))
            };
            let name = || String::from_utf8_lossy(first);
            if let Some(kw) = first.strip_prefix(b":") {
                if kw.eq_ignore_ascii_case(b"DEGREES") {
                    degrees = true;
                } else if kw.eq_ignore_ascii_case(b"RADIANS") {
                    degrees = false;
                }
                continue;
            }
            if first.iter().all(u8::is_ascii_digit) && toks.clone().next().is_none() {
                finish(&seen, frame, n - 1)?;
                let expected = num_frames + 1;
                let num: Option<usize> =
                    std::str::from_utf8(first).ok().and_then(|t| t.parse().ok());
                if num != Some(expected) {
                    // The next frame's number, cut by the end of the file.
                    if ends_at_end(bytes, first)
                        && expected.to_string().as_bytes().starts_with(first)
                    {
                        cut = Some((expected, n));
                        break;
                    }
                    let Some(num) = num else {
                        return Err(amc_err(n, format!("bad frame number {:?}", name())));
                    };
                    return Err(amc_err(
                        n,
                        format!("frame number {num} where {expected} was expected (frames are numbered from 1)"),
                    ));
                }
                num_frames += 1;
                values.resize(num_frames * per_frame, 0.0);
                seen.iter_mut().for_each(|s| *s = false);
                frame = Some(expected);
                line_in_frame = 0;
                continue;
            }
            if frame.is_none() {
                return Err(amc_err(
                    n,
                    format!("{:?} before the first frame number", name()),
                ));
            }
            let base = (num_frames - 1) * per_frame;
            let is_slot = |slot: usize| match slot {
                0 => first == b"root",
                i => skeleton.bones[i - 1].name.as_bytes() == first,
            };
            let slot = match slot_at.get(line_in_frame) {
                Some(&s) if is_slot(s) => s,
                _ => {
                    let s = if first == b"root" {
                        0
                    } else {
                        match skeleton
                            .bones
                            .iter()
                            .position(|b| b.name.as_bytes() == first)
                        {
                            Some(i) => i + 1,
                            None => {
                                // A bone name cut by the end of the file.
                                let cut_name = ends_at_end(bytes, first)
                                    && (b"root".starts_with(first)
                                        || skeleton
                                            .bones
                                            .iter()
                                            .any(|b| b.name.as_bytes().starts_with(first)));
                                if cut_name {
                                    cut = Some((num_frames, n));
                                    break;
                                }
                                return Err(amc_err(n, format!("unknown bone {:?}", name())));
                            }
                        }
                    };
                    if line_in_frame < slot_at.len() {
                        slot_at[line_in_frame] = s;
                    } else {
                        slot_at.push(s);
                    }
                    s
                }
            };
            line_in_frame += 1;
            let (offset, count) = match slot {
                0 => (0, skeleton.root_order.len()),
                i => (
                    skeleton.bones[i - 1].value_offset,
                    skeleton.bones[i - 1].dofs.len(),
                ),
            };
            let found = toks.clone().count();
            if found != count {
                // A short last line of numbers (the last one perhaps cut):
                // the file ends inside it.
                let cut_line = found < count
                    && last()
                    && toks.clone().all(|t| {
                        parse_decimal(t).is_some_and(f64::is_finite)
                            || (is_number_prefix(t) && ends_at_end(bytes, t))
                    });
                if cut_line {
                    cut = Some((num_frames, n));
                    break;
                }
                return Err(ErrorKind::ChannelCount {
                    line: n,
                    expected: count,
                    found,
                });
            }
            for (k, t) in toks.enumerate() {
                let v = match number_bytes(n, t) {
                    Ok(v) => v,
                    // A value cut by the end of the file.
                    Err(ErrorKind::NonNumeric { .. })
                        if is_number_prefix(t) && ends_at_end(bytes, t) =>
                    {
                        cut = Some((num_frames, n));
                        break;
                    }
                    Err(ErrorKind::NonFinite { what, .. }) => {
                        return Err(ErrorKind::NonFinite {
                            frame: num_frames - 1,
                            what: format!("bone {}, {what}", name()),
                        })
                    }
                    Err(e) => return Err(e),
                };
                let is_angle = slot != 0 || matches!(skeleton.root_order[k], RootDof::R(_));
                values[base + offset + k] = if is_angle && degrees {
                    v.to_radians()
                } else {
                    v
                };
            }
            if cut.is_some() {
                break;
            }
            seen[slot] = true;
        }
        // The file ends inside a frame: cut by the end of the file, or its
        // last frame lacks lines.
        let cut = cut.or_else(|| {
            frame
                .filter(|_| missing(&seen).is_some())
                .map(|num| (num, last_line))
        });
        let truncation = cut.map(|(num, line)| Truncation {
            expected: num,
            found: num - 1,
            line,
            leading: 0,
        });
        if let Some(t) = truncation {
            if t.found == 0 {
                return Err(t.to_error());
            }
            num_frames = t.found;
            values.truncate(num_frames * per_frame);
        }
        if num_frames == 0 {
            return Err(ErrorKind::NoFrames);
        }
        Ok(AmcMotion {
            skeleton,
            values,
            num_frames,
            truncation,
        })
    }

    /// Where the file was cut, if it ends inside its last frame (the
    /// complete frames before it are the motion).
    pub fn truncation(&self) -> Option<Truncation> {
        self.truncation
    }

    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.num_frames
    }

    /// Global positions of the kept joints at `frame` (0-based: AMC frame `frame + 1`).
    pub fn pose(&self, frame: usize) -> Pose {
        let s = &self.skeleton;
        let v = &self.values[frame * s.values_per_frame..(frame + 1) * s.values_per_frame];
        let mut root_pos = s.root_position;
        let mut root_angles = [0.0; 3];
        let mut r = 0;
        for (k, dof) in s.root_order.iter().enumerate() {
            match dof {
                RootDof::T(a) => root_pos[*a] += v[k],
                RootDof::R(_) => {
                    root_angles[r] = v[k];
                    r += 1;
                }
            }
        }
        let m_root = Mat3::euler_applied(&s.root_rot_axes, &root_angles[..r]);
        let root_rot = s.root_c.mul(&m_root).mul(&s.root_c.transpose());

        let n = s.bones.len();
        let mut rot = vec![Mat3::IDENTITY; n];
        let mut end = vec![[0.0; 3]; n];
        for &b in &s.needed {
            let bone = &s.bones[b];
            let (parent_rot, start) = match bone.parent {
                Some(p) => (rot[p], end[p]),
                None => (root_rot, root_pos),
            };
            let m = Mat3::euler_applied(
                &bone.dofs,
                &v[bone.value_offset..bone.value_offset + bone.dofs.len()],
            );
            rot[b] = parent_rot.mul(&bone.c).mul(&m).mul(&bone.c_inv);
            end[b] = add(start, rot[b].apply(bone.vector));
        }
        let mut pose = [[0.0; 3]; NUM_JOINTS];
        pose[0] = root_pos;
        for k in 1..NUM_JOINTS {
            pose[k] = end[s.kept[k]];
        }
        pose
    }
}
