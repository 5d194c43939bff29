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
use std::ops::ControlFlow;

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

/// A bone as the ASF's `:bonedata` describes it, before it is built.
struct BoneDraft {
    line: usize,
    name: Option<String>,
    direction: Option<Vec3>,
    length: Option<f64>,
    axis: Option<(Vec3, Vec<Axis>)>,
    dofs: Vec<Axis>,
}

impl BoneDraft {
    /// A bone opened by `begin` at `line`.
    fn new(line: usize) -> BoneDraft {
        BoneDraft {
            line,
            name: None,
            direction: None,
            length: None,
            axis: None,
            dofs: Vec::new(),
        }
    }

    /// Take one line of the bone's body (`key` lower-cased): its name,
    /// direction, length, axis or degrees of freedom; other keys (`id`,
    /// `limits` and their continuation lines, `bodymass`, …) are ignored.
    fn set(&mut self, n: usize, key: &str, toks: &[&str]) -> Result<(), ErrorKind> {
        match key {
            "name" => self.name = toks.get(1).map(|s| s.to_string()),
            "direction" => self.direction = Some(three(n, &toks[1..])?),
            "length" => self.length = Some(number(n, toks.get(1).unwrap_or(&""))?),
            "axis" => {
                let v = three(n, &toks[1..])?;
                let order = axis_order(n, toks.get(4).unwrap_or(&""))?;
                self.axis = Some((v, order));
            }
            "dof" => self.dofs = bone_dofs(n, &toks[1..])?,
            _ => {}
        }
        Ok(())
    }
}

/// The channels of the root's AMC line (`order TX TY TZ RX RY RZ`).
fn root_order(n: usize, toks: &[&str]) -> Result<Vec<RootDof>, ErrorKind> {
    toks.iter()
        .map(|t| {
            let t = t.to_ascii_lowercase();
            let b = t.as_bytes();
            match (b.first(), b.get(1).and_then(|&c| axis_of(c))) {
                (Some(b't'), Some(a)) if b.len() == 2 => Ok(RootDof::T(a as usize)),
                (Some(b'r'), Some(a)) if b.len() == 2 => Ok(RootDof::R(a)),
                _ => Err(asf_err(n, format!("bad root channel {t:?}"))),
            }
        })
        .collect()
}

/// A bone's degrees of freedom (`dof rx ry rz`, rotations only).
fn bone_dofs(n: usize, toks: &[&str]) -> Result<Vec<Axis>, ErrorKind> {
    toks.iter()
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
        .collect()
}

/// What an ASF's sections say, line by line, before the bones are built.
struct AsfSections {
    degrees: bool,
    root_order: Vec<RootDof>,
    root_axis: Option<Vec<Axis>>,
    root_position: Vec3,
    root_orientation: Vec3,
    drafts: Vec<BoneDraft>,
    /// The bone being read (after its `begin`).
    current: Option<BoneDraft>,
    /// `:hierarchy` lines: line number and tokens.
    hierarchy: Vec<(usize, Vec<String>)>,
    last_line: usize,
}

impl AsfSections {
    /// Read an ASF's text: `:units` (the angle unit), `:root`, `:bonedata`
    /// and `:hierarchy`; a bone left open or no bone at all is an error.
    fn read(text: &str) -> Result<AsfSections, ErrorKind> {
        let mut s = AsfSections {
            degrees: true,
            root_order: Vec::new(),
            root_axis: None,
            root_position: [0.0; 3],
            root_orientation: [0.0; 3],
            drafts: Vec::new(),
            current: None,
            hierarchy: Vec::new(),
            last_line: 0,
        };
        let mut section = String::new();
        for (n, toks) in text_lines(text) {
            s.last_line = n;
            if let Some(kw) = toks[0].strip_prefix(':') {
                section = kw.to_ascii_lowercase();
                continue;
            }
            let key = toks[0].to_ascii_lowercase();
            match section.as_str() {
                "units" if key == "angle" => {
                    s.degrees = match toks.get(1).map(|u| u.to_ascii_lowercase()) {
                        Some(u) if u.starts_with("deg") => true,
                        Some(u) if u.starts_with("rad") => false,
                        _ => return Err(asf_err(n, "angle unit must be deg or rad")),
                    };
                }
                "root" => s.root_line(n, &key, &toks)?,
                "bonedata" => s.bone_line(n, &key, &toks)?,
                "hierarchy" if key != "begin" && key != "end" => {
                    s.hierarchy
                        .push((n, toks.iter().map(|t| t.to_string()).collect()));
                }
                _ => {}
            }
        }
        if s.current.is_some() {
            return Err(asf_err(
                s.last_line,
                "file ends inside a bone (missing `end`)",
            ));
        }
        if s.drafts.is_empty() {
            return Err(ErrorKind::Syntax {
                format: "ASF",
                line: None,
                message: "no :bonedata".into(),
            });
        }
        Ok(s)
    }

    /// A line of `:root`: `order`, `axis`, `position` or `orientation`.
    fn root_line(&mut self, n: usize, key: &str, toks: &[&str]) -> Result<(), ErrorKind> {
        match key {
            "order" => self.root_order = root_order(n, &toks[1..])?,
            "axis" => self.root_axis = Some(axis_order(n, toks.get(1).unwrap_or(&""))?),
            "position" => self.root_position = three(n, &toks[1..])?,
            "orientation" => self.root_orientation = three(n, &toks[1..])?,
            _ => {}
        }
        Ok(())
    }

    /// A line of `:bonedata`: `begin`, `end`, or a line of the open bone.
    fn bone_line(&mut self, n: usize, key: &str, toks: &[&str]) -> Result<(), ErrorKind> {
        match key {
            "begin" => {
                if self.current.is_some() {
                    return Err(asf_err(n, "`begin` inside a bone (missing `end`)"));
                }
                self.current = Some(BoneDraft::new(n));
            }
            "end" => match self.current.take() {
                Some(d) => self.drafts.push(d),
                None => return Err(asf_err(n, "`end` without `begin`")),
            },
            _ => {
                let Some(d) = self.current.as_mut() else {
                    return Err(asf_err(n, format!("{:?} outside begin/end", toks[0])));
                };
                d.set(n, key, toks)?;
            }
        }
        Ok(())
    }
}

/// The bones of the drafts, in file order, not yet attached, and the values
/// per AMC frame (the root's `root_values` first, then each bone's dofs).
/// The `thorax` is given length 0 unless `options.full_skeleton`.
fn build_bones(
    drafts: Vec<BoneDraft>,
    degrees: bool,
    options: AsfOptions,
    root_values: usize,
) -> Result<(Vec<Bone>, usize), ErrorKind> {
    let rad = |v: f64| if degrees { v.to_radians() } else { v };
    let mut bones = Vec::with_capacity(drafts.len());
    let mut values_per_frame = root_values;
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
    Ok((bones, values_per_frame))
}

/// The index of the bone named `n`.
fn bone_index(bones: &[Bone], n: &str) -> Option<usize> {
    bones.iter().position(|b| b.name == n)
}

/// Attach the bones as the `:hierarchy` lines say ("parent child child …";
/// `root` is the root); which bones were attached.
fn attach(bones: &mut [Bone], hierarchy: &[(usize, Vec<String>)]) -> Result<Vec<bool>, ErrorKind> {
    let mut attached = vec![false; bones.len()];
    for (n, toks) in hierarchy {
        let parent = if toks[0] == "root" {
            None
        } else {
            Some(bone_index(bones, &toks[0]).ok_or_else(|| {
                asf_err(*n, format!("hierarchy names unknown bone {:?}", toks[0]))
            })?)
        };
        for child in &toks[1..] {
            let c = bone_index(bones, child)
                .ok_or_else(|| asf_err(*n, format!("hierarchy names unknown bone {child:?}")))?;
            bones[c].parent = parent;
            attached[c] = true;
        }
    }
    Ok(attached)
}

/// The bone ending at each kept joint (index 0, the root, unused); a kept
/// bone missing or not attached is an unknown skeleton.
fn kept_bones(bones: &[Bone], attached: &[bool]) -> Result<[usize; NUM_JOINTS], ErrorKind> {
    let mut kept = [0usize; NUM_JOINTS];
    let mut missing = Vec::new();
    for (k, want) in ASF_BONES.iter().enumerate().skip(1) {
        match bone_index(bones, want) {
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
    Ok(kept)
}

impl AsfSkeleton {
    /// Parse an ASF file.
    pub fn parse(bytes: &[u8], options: AsfOptions) -> Result<AsfSkeleton, ErrorKind> {
        check_text(bytes)?;
        let text = String::from_utf8_lossy(bytes);
        let s = AsfSections::read(&text)?;
        let (mut bones, values_per_frame) =
            build_bones(s.drafts, s.degrees, options, s.root_order.len())?;
        let attached = attach(&mut bones, &s.hierarchy)?;
        let kept = kept_bones(&bones, &attached)?;
        let needed = topological_needed(&bones, &kept[1..])
            .ok_or_else(|| asf_err(s.last_line, "cyclic bone hierarchy"))?;
        let root_rot_axes: Vec<Axis> = s
            .root_order
            .iter()
            .filter_map(|d| match d {
                RootDof::R(a) => Some(*a),
                RootDof::T(_) => None,
            })
            .collect();
        let root_axis = s.root_axis.unwrap_or(vec![Axis::X, Axis::Y, Axis::Z]);
        let rad = |v: f64| if s.degrees { v.to_radians() } else { v };
        Ok(AsfSkeleton {
            degrees: s.degrees,
            root_c: Mat3::euler_applied(&root_axis, &s.root_orientation.map(rad)),
            root_order: s.root_order,
            root_rot_axes,
            root_position: s.root_position,
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

/// Where an AMC file ends inside a frame: that frame's number and the line.
type Cut = (usize, usize);

/// One non-blank line of an AMC file.
struct AmcLine<'b> {
    /// 1-based line number.
    n: usize,
    /// The line as in the file.
    raw: &'b [u8],
    /// The line without its comment.
    text: &'b [u8],
    /// Byte offset of the next line.
    next: usize,
}

impl AmcLine<'_> {
    /// Whether the file ends on this line (nothing but whitespace after it,
    /// no comment on it): damage here may be the cut.
    fn is_last(&self, bytes: &[u8]) -> bool {
        self.text.len() == self.raw.len()
            && bytes
                .get(self.next..)
                .is_none_or(|rest| rest.iter().all(u8::is_ascii_whitespace))
    }
}

/// An AMC file being read against its skeleton: the values of the frames so
/// far, and which lines of the current frame have come.
struct AmcReader<'a> {
    skeleton: &'a AsfSkeleton,
    bytes: &'a [u8],
    degrees: bool,
    /// `num_frames × values_per_frame` values, angles in radians.
    values: Vec<f64>,
    /// The current frame's number.
    frame: Option<usize>,
    num_frames: usize,
    /// Lines of the current frame seen: the root's (slot 0), bone `i`'s
    /// (slot `i + 1`).
    seen: Vec<bool>,
    /// The slot of each line of a frame: lines come in the same order frame
    /// after frame, so each position remembers its bone.
    slot_at: Vec<usize>,
    line_in_frame: usize,
}

impl<'a> AmcReader<'a> {
    /// Nothing read yet; angles in the skeleton's unit.
    fn new(bytes: &'a [u8], skeleton: &'a AsfSkeleton) -> Self {
        AmcReader {
            skeleton,
            bytes,
            degrees: skeleton.degrees,
            values: Vec::new(),
            frame: None,
            num_frames: 0,
            seen: vec![false; skeleton.bones.len() + 1],
            slot_at: Vec::new(),
            line_in_frame: 0,
        }
    }

    /// A `:KEYWORD` line: `:DEGREES` and `:RADIANS` set the angle unit; the
    /// others (`:FULLY-SPECIFIED`) change nothing.
    fn keyword(&mut self, kw: &[u8]) {
        if kw.eq_ignore_ascii_case(b"DEGREES") {
            self.degrees = true;
        } else if kw.eq_ignore_ascii_case(b"RADIANS") {
            self.degrees = false;
        }
    }

    /// The line missing from the current frame, if any: `Some(None)` for the
    /// root's, `Some(Some(bone))` for a bone's.
    fn missing(&self) -> Option<Option<String>> {
        if !(self.seen[0] || self.skeleton.root_order.is_empty()) {
            return Some(None);
        }
        self.skeleton
            .bones
            .iter()
            .enumerate()
            .find(|(i, b)| !b.dofs.is_empty() && !self.seen[i + 1])
            .map(|(_, b)| Some(b.name.clone()))
    }

    /// An error if the current frame (if any) lacks a line, reported at line
    /// `at`.
    fn finish_frame(&self, at: usize) -> Result<(), ErrorKind> {
        let Some(num) = self.frame else {
            return Ok(());
        };
        match self.missing() {
            None => Ok(()),
            Some(None) => Err(amc_err(at, format!("frame {num} has no root line"))),
            Some(Some(b)) => Err(amc_err(at, format!("frame {num} has no line for bone {b}"))),
        }
    }

    /// A frame number at line `n`: the current frame must be complete and
    /// the number the next one; a number cut by the end of the file is the
    /// cut.
    fn frame_number(&mut self, n: usize, first: &[u8]) -> Result<Option<Cut>, ErrorKind> {
        self.finish_frame(n - 1)?;
        let expected = self.num_frames + 1;
        let num: Option<usize> = std::str::from_utf8(first).ok().and_then(|t| t.parse().ok());
        if num != Some(expected) {
            // The next frame's number, cut by the end of the file.
            if ends_at_end(self.bytes, first) && expected.to_string().as_bytes().starts_with(first)
            {
                return Ok(Some((expected, n)));
            }
            let Some(num) = num else {
                return Err(amc_err(
                    n,
                    format!("bad frame number {:?}", String::from_utf8_lossy(first)),
                ));
            };
            return Err(amc_err(
                n,
                format!(
                    "frame number {num} where {expected} was expected (frames are numbered from 1)"
                ),
            ));
        }
        self.num_frames += 1;
        self.values
            .resize(self.num_frames * self.skeleton.values_per_frame, 0.0);
        self.seen.iter_mut().for_each(|s| *s = false);
        self.frame = Some(expected);
        self.line_in_frame = 0;
        Ok(None)
    }

    /// A line of the current frame (`first`: the root or a bone, then its
    /// values): the values stored, angles in radians; a line cut by the end
    /// of the file is the cut.
    fn bone_line<'b>(
        &mut self,
        line: &AmcLine,
        first: &[u8],
        toks: impl Iterator<Item = &'b [u8]> + Clone,
    ) -> Result<Option<Cut>, ErrorKind> {
        if self.frame.is_none() {
            return Err(amc_err(
                line.n,
                format!(
                    "{:?} before the first frame number",
                    String::from_utf8_lossy(first)
                ),
            ));
        }
        let slot = match self.slot(line.n, first)? {
            ControlFlow::Continue(slot) => slot,
            ControlFlow::Break(cut) => return Ok(Some(cut)),
        };
        self.line_in_frame += 1;
        if let Some(cut) = self.store(line, first, toks, slot)? {
            return Ok(Some(cut));
        }
        self.seen[slot] = true;
        Ok(None)
    }

    /// The slot of a line starting with `first` (0: the root, `i + 1`: bone
    /// `i`), remembered for its position in the frame; a bone name cut by
    /// the end of the file is the cut.
    fn slot(&mut self, n: usize, first: &[u8]) -> Result<ControlFlow<Cut, usize>, ErrorKind> {
        let bones = &self.skeleton.bones;
        let is_slot = |slot: usize| match slot {
            0 => first == b"root",
            i => bones[i - 1].name.as_bytes() == first,
        };
        if let Some(&s) = self.slot_at.get(self.line_in_frame) {
            if is_slot(s) {
                return Ok(ControlFlow::Continue(s));
            }
        }
        let s = if first == b"root" {
            0
        } else {
            match bones.iter().position(|b| b.name.as_bytes() == first) {
                Some(i) => i + 1,
                None => {
                    // A bone name cut by the end of the file.
                    let cut_name = ends_at_end(self.bytes, first)
                        && (b"root".starts_with(first)
                            || bones.iter().any(|b| b.name.as_bytes().starts_with(first)));
                    if cut_name {
                        return Ok(ControlFlow::Break((self.num_frames, n)));
                    }
                    return Err(amc_err(
                        n,
                        format!("unknown bone {:?}", String::from_utf8_lossy(first)),
                    ));
                }
            }
        };
        if self.line_in_frame < self.slot_at.len() {
            self.slot_at[self.line_in_frame] = s;
        } else {
            self.slot_at.push(s);
        }
        Ok(ControlFlow::Continue(s))
    }

    /// Store the values of `slot`'s line (`toks`, after the name): as many
    /// as it has channels, angles in radians; a short last line or a value
    /// cut by the end of the file is the cut.
    fn store<'b>(
        &mut self,
        line: &AmcLine,
        first: &[u8],
        toks: impl Iterator<Item = &'b [u8]> + Clone,
        slot: usize,
    ) -> Result<Option<Cut>, ErrorKind> {
        let (skeleton, bytes, n) = (self.skeleton, self.bytes, line.n);
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
                && line.is_last(bytes)
                && toks.clone().all(|t| {
                    parse_decimal(t).is_some_and(f64::is_finite)
                        || (is_number_prefix(t) && ends_at_end(bytes, t))
                });
            if cut_line {
                return Ok(Some((self.num_frames, n)));
            }
            return Err(ErrorKind::ChannelCount {
                line: n,
                expected: count,
                found,
            });
        }
        let base = (self.num_frames - 1) * skeleton.values_per_frame;
        for (k, t) in toks.enumerate() {
            let v = match number_bytes(n, t) {
                Ok(v) => v,
                // A value cut by the end of the file.
                Err(ErrorKind::NonNumeric { .. })
                    if is_number_prefix(t) && ends_at_end(bytes, t) =>
                {
                    return Ok(Some((self.num_frames, n)));
                }
                Err(ErrorKind::NonFinite { what, .. }) => {
                    return Err(ErrorKind::NonFinite {
                        frame: self.num_frames - 1,
                        what: format!("bone {}, {what}", String::from_utf8_lossy(first)),
                    })
                }
                Err(e) => return Err(e),
            };
            let is_angle = slot != 0 || matches!(skeleton.root_order[k], RootDof::R(_));
            self.values[base + offset + k] = if is_angle && self.degrees {
                v.to_radians()
            } else {
                v
            };
        }
        Ok(None)
    }
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
        let mut r = AmcReader::new(bytes, &skeleton);
        let mut last_line = 0;
        // Set when the file ends inside a frame: (that frame's number, line).
        let mut cut: Option<Cut> = None;
        // Byte-level and allocation-free: this loop sees every line of every
        // AMC file.
        let mut next_line = 0usize; // byte offset of the next line
        for (n, raw) in (1..).zip(bytes.split(|&b| b == b'\n')) {
            next_line += raw.len() + 1;
            let text = match raw.iter().position(|&b| b == b'#') {
                Some(i) => &raw[..i],
                None => raw,
            };
            let mut toks = tokens(text);
            let Some(first) = toks.next() else {
                continue;
            };
            last_line = n;
            let line = AmcLine {
                n,
                raw,
                text,
                next: next_line,
            };
            if let Some(kw) = first.strip_prefix(b":") {
                r.keyword(kw);
                continue;
            }
            let step = if first.iter().all(u8::is_ascii_digit) && toks.clone().next().is_none() {
                r.frame_number(n, first)?
            } else {
                r.bone_line(&line, first, toks)?
            };
            if step.is_some() {
                cut = step;
                break;
            }
        }
        // The file ends inside a frame: cut by the end of the file, or its
        // last frame lacks lines.
        let cut = cut.or_else(|| {
            r.frame
                .filter(|_| r.missing().is_some())
                .map(|num| (num, last_line))
        });
        let (mut values, mut num_frames) = (r.values, r.num_frames);
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
            values.truncate(num_frames * skeleton.values_per_frame);
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
