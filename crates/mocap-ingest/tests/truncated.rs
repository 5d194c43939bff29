//! Files cut short (issue 23 §4): a take whose file ends inside (or before
//! the end of) its motion keeps its complete frames, with a warning in the
//! manifest; `strict` skips it as `truncated`, as format 2 did. Damage
//! anywhere else still fails the file, and so does a file without one
//! complete frame. Small synthetic ASF/AMC and BVH fixtures, no samples.

use mocap_ingest::asf::AsfOptions;
use mocap_ingest::dataset::{
    build_dataset, manifest_warnings, BuildSummary, DatasetOptions, NoProgress, Warning,
};
use mocap_ingest::source::Source;
use mocap_ingest::{clip_from_motion, read_amc, read_bvh, ErrorKind, Motion, Options, Truncation};
use std::path::{Path, PathBuf};

/// Raw frames of the fixtures (120 fps: 30 fps keeps frames 0, 4, 8).
const FRAMES: usize = 9;

/// A CMU-like ASF: the 18 bones the pipeline keeps, three rotation dofs
/// each, arms to the sides.
fn asf() -> String {
    let bones: [(&str, [f64; 3], f64); 18] = [
        ("lhipjoint", [1.0, 0.0, 0.0], 1.0),
        ("lfemur", [0.0, -1.0, 0.0], 4.0),
        ("ltibia", [0.0, -1.0, 0.0], 4.0),
        ("lfoot", [0.0, 0.0, 1.0], 1.0),
        ("rhipjoint", [-1.0, 0.0, 0.0], 1.0),
        ("rfemur", [0.0, -1.0, 0.0], 4.0),
        ("rtibia", [0.0, -1.0, 0.0], 4.0),
        ("rfoot", [0.0, 0.0, 1.0], 1.0),
        ("lowerback", [0.0, 1.0, 0.0], 2.0),
        ("upperback", [0.0, 1.0, 0.0], 2.0),
        ("lowerneck", [0.0, 1.0, 0.0], 1.0),
        ("upperneck", [0.0, 1.0, 0.0], 1.0),
        ("lclavicle", [1.0, 0.0, 0.0], 2.0),
        ("lhumerus", [1.0, 0.0, 0.0], 2.0),
        ("lradius", [1.0, 0.0, 0.0], 2.0),
        ("rclavicle", [-1.0, 0.0, 0.0], 2.0),
        ("rhumerus", [-1.0, 0.0, 0.0], 2.0),
        ("rradius", [-1.0, 0.0, 0.0], 2.0),
    ];
    let mut s = String::from(
        ":version 1.10\n:name test\n:units\n  mass 1.0\n  length 0.45\n  angle deg\n\
         :root\n   order TX TY TZ RX RY RZ\n   axis XYZ\n   position 0 0 0\n   orientation 0 0 0\n\
         :bonedata\n",
    );
    for (i, (name, d, len)) in bones.iter().enumerate() {
        s.push_str(&format!(
            "  begin\n     id {}\n     name {name}\n     direction {} {} {}\n     length {len}\n     \
             axis 0 0 0 XYZ\n    dof rx ry rz\n  end\n",
            i + 1,
            d[0],
            d[1],
            d[2]
        ));
    }
    s.push_str(
        ":hierarchy\n  begin\n    root lhipjoint rhipjoint lowerback\n    lhipjoint lfemur\n    \
         lfemur ltibia\n    ltibia lfoot\n    rhipjoint rfemur\n    rfemur rtibia\n    rtibia rfoot\n    \
         lowerback upperback\n    upperback lowerneck lclavicle rclavicle\n    lowerneck upperneck\n    \
         lclavicle lhumerus\n    lhumerus lradius\n    rclavicle rhumerus\n    rhumerus rradius\n  end\n",
    );
    s
}

const AMC_BONES: [&str; 18] = [
    "lowerback",
    "upperback",
    "lowerneck",
    "upperneck",
    "lclavicle",
    "lhumerus",
    "lradius",
    "rclavicle",
    "rhumerus",
    "rradius",
    "lhipjoint",
    "lfemur",
    "ltibia",
    "lfoot",
    "rhipjoint",
    "rfemur",
    "rtibia",
    "rfoot",
];

/// An AMC of `frames` frames: the root walks forward, every joint sways.
fn amc(frames: usize) -> String {
    let mut s = String::from("#!OML:ASF test.asf\n:FULLY-SPECIFIED\n:DEGREES\n");
    for f in 1..=frames {
        let a = f as f64 * 1.5;
        s.push_str(&format!(
            "{f}\nroot {:.4} 10.25 -0.5 1.25 {a:.4} -2.5\n",
            f as f64 * 0.25
        ));
        for (i, b) in AMC_BONES.iter().enumerate() {
            s.push_str(&format!("{b} {:.4} -{:.4} 0.75\n", a + i as f64, a * 0.5));
        }
    }
    s
}

/// A Motionbuilder-friendly (2010) BVH: a T-pose frame, then `frames`
/// frames of motion (`Frames:` counts both).
fn bvh(frames: usize) -> String {
    fn chain(s: &mut String, names: &[(&str, [f64; 3])], depth: usize) {
        let Some(((name, o), rest)) = names.split_first() else {
            let pad = " ".repeat(depth);
            s.push_str(&format!(
                "{pad}End Site\n{pad}{{\n{pad} OFFSET 0 0.5 0\n{pad}}}\n"
            ));
            return;
        };
        let pad = " ".repeat(depth);
        s.push_str(&format!(
            "{pad}JOINT {name}\n{pad}{{\n{pad} OFFSET {} {} {}\n{pad} CHANNELS 3 Zrotation Xrotation Yrotation\n",
            o[0], o[1], o[2]
        ));
        chain(s, rest, depth + 1);
        s.push_str(&format!("{pad}}}\n"));
    }
    let mut s = String::from(
        "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n",
    );
    let legs = |side: &str, x: f64| {
        [
            (format!("{side}UpLeg"), [x, 0.0, 0.0]),
            (format!("{side}Leg"), [0.0, -4.0, 0.0]),
            (format!("{side}Foot"), [0.0, -4.0, 0.0]),
            (format!("{side}ToeBase"), [0.0, 0.0, 1.0]),
        ]
    };
    let arms = |side: &str, x: f64| {
        [
            (format!("{side}Arm"), [x, 0.0, 0.0]),
            (format!("{side}ForeArm"), [x, 0.0, 0.0]),
            (format!("{side}Hand"), [x, 0.0, 0.0]),
            (format!("{side}HandIndex1"), [x / 4.0, 0.0, 0.0]),
        ]
    };
    fn as_str(v: &[(String, [f64; 3])]) -> Vec<(&str, [f64; 3])> {
        v.iter().map(|(n, o)| (n.as_str(), *o)).collect()
    }
    chain(&mut s, &as_str(&legs("Left", 1.0)), 1);
    chain(&mut s, &as_str(&legs("Right", -1.0)), 1);
    // Spine → Spine1 → (Neck1 → Head, LeftArm …, RightArm …).
    s.push_str(" JOINT Spine\n {\n  OFFSET 0 2 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n");
    s.push_str(
        "  JOINT Spine1\n  {\n   OFFSET 0 2 0\n   CHANNELS 3 Zrotation Xrotation Yrotation\n",
    );
    chain(
        &mut s,
        &[("Neck1", [0.0, 1.0, 0.0]), ("Head", [0.0, 1.0, 0.0])],
        3,
    );
    chain(&mut s, &as_str(&arms("Left", 2.0)), 3);
    chain(&mut s, &as_str(&arms("Right", -2.0)), 3);
    s.push_str("  }\n }\n}\n");
    let channels = 6 + 3 * 20;
    s.push_str(&format!(
        "MOTION\nFrames: {}\nFrame Time: 0.00833333\n",
        frames + 1
    ));
    s.push_str(&vec!["0"; channels].join(" "));
    s.push('\n');
    for f in 1..=frames {
        let a = f as f64 * 1.5;
        let mut v = vec![
            format!("{:.4}", f as f64 * 0.25),
            "10.25".into(),
            "-0.5".into(),
        ];
        for c in 3..channels {
            v.push(format!("{:.4}", a + (c % 7) as f64 - 3.0));
        }
        s.push_str(&v.join(" "));
        s.push('\n');
    }
    s
}

/// Byte offset of the start of the `n`-th line (1-based) of `text`.
fn line_start(text: &str, n: usize) -> usize {
    text.split_inclusive('\n').take(n - 1).map(str::len).sum()
}

/// Line number (1-based) of the first line equal to `line`.
fn line_no(text: &str, line: &str) -> usize {
    text.lines().position(|l| l == line).expect(line) + 1
}

fn read_amc_text(text: &str) -> Result<Motion, mocap_ingest::IngestError> {
    read_amc(
        "02_01.amc",
        text.as_bytes(),
        "02.asf",
        asf().as_bytes(),
        AsfOptions::default(),
    )
}

fn rows(m: &Motion) -> usize {
    clip_from_motion("f", "02_01", m, &Options::default())
        .unwrap_or_else(|e| panic!("{e}"))
        .features
        .len()
}

/// Every pose of `cut` equals the same frame of `whole`.
fn same_poses(cut: &Motion, whole: &Motion) {
    for i in 0..cut.num_frames() {
        assert_eq!(cut.pose(i), whole.pose(i), "frame {i}");
    }
}

#[test]
fn an_amc_cut_inside_its_last_frame_keeps_its_complete_frames() {
    let whole_text = amc(FRAMES);
    let whole = read_amc_text(&whole_text).unwrap();
    assert_eq!((whole.num_frames(), whole.truncation()), (FRAMES, None));
    assert_eq!(rows(&whole), 3, "frames 0, 4, 8 at 30 fps");

    let last = line_no(&whole_text, &FRAMES.to_string());
    let root = line_start(&whole_text, last + 1);
    let lfemur = line_start(&whole_text, last + 2 + 11);
    let cuts = [
        // After whole lines: the frame lacks its bones.
        ("missing lines", line_start(&whole_text, last + 3), last + 2),
        ("only the frame number", root, last),
        // Inside a line: values missing, a value cut, a bone name cut.
        ("short line", root + "root 2.2500 10.25".len(), last + 1),
        ("value cut", root + "root 2.2500 10.25 -".len(), last + 1),
        ("name cut", lfemur + "lfem".len(), last + 13),
    ];
    for (what, at, line) in cuts {
        let m = read_amc_text(&whole_text[..at]).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(m.num_frames(), FRAMES - 1, "{what}");
        let t = m
            .truncation()
            .unwrap_or_else(|| panic!("{what}: no truncation"));
        assert_eq!(
            t,
            Truncation {
                expected: FRAMES,
                found: FRAMES - 1,
                line,
                leading: 0
            },
            "{what}"
        );
        assert_eq!((t.frames_kept(), t.frames_expected()), (8, 9), "{what}");
        // 8 raw frames at 120 fps: frames 0 and 4 at 30 fps.
        assert_eq!(rows(&m), 2, "{what}");
        same_poses(&m, &whole);
    }

    // A frame number cut at the end: the frames before it are complete.
    let ten = amc(10);
    let cut = &ten[..line_start(&ten, line_no(&ten, "10")) + 1];
    let m = read_amc_text(cut).unwrap();
    assert_eq!(m.num_frames(), 9);
    assert_eq!(m.truncation().map(|t| (t.expected, t.found)), Some((10, 9)));
    // A complete file that simply has no final newline is not cut.
    let m = read_amc_text(whole_text.trim_end()).unwrap();
    assert_eq!((m.num_frames(), m.truncation()), (FRAMES, None));
}

#[test]
fn a_bvh_cut_short_keeps_its_complete_frames() {
    let whole_text = bvh(FRAMES);
    let whole = read_bvh("02_01.bvh", whole_text.as_bytes()).unwrap();
    assert_eq!((whole.num_frames(), whole.truncation()), (FRAMES, None));
    assert_eq!(rows(&whole), 3);

    let header = line_no(&whole_text, "Frame Time: 0.00833333");
    let last = header + 1 + FRAMES; // the last frame's line (T-pose first)
    let start = line_start(&whole_text, last);
    let last_line = &whole_text[start..whole_text.len() - 1];
    let cuts = [
        // `Frames:` promises a line that is not there.
        ("line missing", start, last - 1),
        ("short line", start + last_line.len() / 2, last),
        ("value cut", start + last_line.find(" -").unwrap() + 2, last),
    ];
    for (what, at, line) in cuts {
        let m = read_bvh("02_01.bvh", &whole_text.as_bytes()[..at])
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(m.num_frames(), FRAMES - 1, "{what}");
        // Counted as in the file (the T-pose included), and as the take counts.
        let t = m.truncation().unwrap();
        assert_eq!(
            t,
            Truncation {
                expected: FRAMES + 1,
                found: FRAMES,
                line,
                leading: 1
            },
            "{what}"
        );
        assert_eq!((t.frames_kept(), t.frames_expected()), (8, 9), "{what}");
        assert_eq!(rows(&m), 2, "{what}");
        same_poses(&m, &whole);
    }
    // A header that promises many more frames than the file holds.
    let more = whole_text.replace(
        &format!("Frames: {}", FRAMES + 1),
        &format!("Frames: {}", FRAMES + 100),
    );
    let m = read_bvh("02_01.bvh", more.as_bytes()).unwrap();
    assert_eq!(m.num_frames(), FRAMES);
    let t = m.truncation().unwrap();
    assert_eq!(
        (t.frames_kept(), t.frames_expected()),
        (FRAMES, FRAMES + 99)
    );
}

#[test]
fn damage_before_the_end_and_files_without_a_complete_frame_still_fail() {
    let a = amc(FRAMES);
    let kind = |r: Result<Motion, mocap_ingest::IngestError>| r.map(|_| ()).unwrap_err().kind;
    // A bad token mid-file, in a file that is also cut at the end.
    let bad = a.replacen("root 0.7500 10.25", "root ten 10.25", 1);
    let bad = &bad[..bad.len() - 10];
    assert!(matches!(
        kind(read_amc_text(bad)),
        ErrorKind::NonNumeric { .. }
    ));
    // A short line that is not the last one.
    let third = line_no(&a, "3") + 2;
    let short: String = a
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i + 1 == third {
                l.rsplit_once(' ').unwrap().0.to_string()
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    assert!(matches!(
        kind(read_amc_text(&short)),
        ErrorKind::ChannelCount { .. }
    ));
    // A last line with junk rather than a cut value, or one value too many.
    let junk = format!("{}x1", a.trim_end());
    assert!(matches!(
        kind(read_amc_text(&junk)),
        ErrorKind::NonNumeric { .. }
    ));
    let extra = format!("{} 1.0\n", a.trim_end());
    assert!(matches!(
        kind(read_amc_text(&extra)),
        ErrorKind::ChannelCount { .. }
    ));
    // A frame missing a line mid-file.
    let gap = a.replacen("rfoot 18.5000 -0.7500 0.75\n", "", 1);
    assert_ne!(gap, a);
    assert!(matches!(
        kind(read_amc_text(&gap)),
        ErrorKind::Syntax { .. }
    ));
    // No complete frame: truncated, as before.
    let first = &a[..line_start(&a, 4) + 8];
    match kind(read_amc_text(first)) {
        ErrorKind::Truncated {
            expected: 1,
            found: 0,
            ..
        } => {}
        k => panic!("{k}"),
    }

    let b = bvh(FRAMES);
    let bkind = |t: &str| {
        read_bvh("02_01.bvh", t.as_bytes())
            .map(|_| ())
            .unwrap_err()
            .kind
    };
    let header = line_no(&b, "Frame Time: 0.00833333");
    // A short line before the last.
    let start = line_start(&b, header + 3);
    let end = start + b[start..].find('\n').unwrap();
    let cut_mid = format!("{}{}", &b[..end - 8], &b[end..]);
    assert!(matches!(bkind(&cut_mid), ErrorKind::ChannelCount { .. }));
    // A bad token on the last line that is not a cut number.
    let junk = format!("{} abc", b.trim_end());
    assert!(matches!(bkind(&junk), ErrorKind::NonNumeric { .. }));
    // Only the T-pose frame is complete: no motion frame, truncated as before.
    let tpose_only = &b[..line_start(&b, header + 2) + 20];
    match bkind(tpose_only) {
        ErrorKind::Truncated {
            expected: 10,
            found: 1,
            ..
        } => {}
        k => panic!("{k}"),
    }
}

/// A fresh directory under the system's temporary folder, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let p = std::env::temp_dir().join(format!(
            "mocap-ingest-{name}-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn options(strict: bool) -> DatasetOptions {
    DatasetOptions {
        window: 2,
        stride: 1,
        fractions: [1.0, 0.0, 0.0],
        strict,
        ..Default::default()
    }
}

fn build(src: &Path, out: &Path, strict: bool) -> BuildSummary {
    let source = Source::open(src).unwrap();
    build_dataset(
        &[source],
        &["src".into()],
        out,
        &options(strict),
        &NoProgress,
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

fn manifest(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap()
}

/// The collection of the dataset test, written into `src`: a whole AMC,
/// an AMC and a BVH cut inside their last frame, an AMC damaged mid-file,
/// and one take as a cut AMC and a whole BVH. Returns the line counts of
/// the cut AMC and the cut BVH.
fn write_cut_collection(src: &Path) -> (usize, usize) {
    std::fs::create_dir_all(src).unwrap();
    let (a, b) = (amc(FRAMES), bvh(FRAMES));
    let cut_amc = &a[..a.len() - 20];
    let cut_bvh = &b[..b.len() - 20];
    let files: [(&str, &str); 7] = [
        ("02.asf", &asf()),
        // Whole.
        ("02_01.amc", &a),
        // Cut inside its last frame (AMC and BVH).
        ("02_02.amc", cut_amc),
        ("02_04.bvh", cut_bvh),
        // Damaged mid-file.
        (
            "02_03.amc",
            &a.replacen("root 0.7500 10.25", "root ten 10.25", 1),
        ),
        // Cut, and a complete copy of the same take: the complete one is kept.
        ("02_05.amc", cut_amc),
        ("02_05.bvh", &b),
    ];
    for (name, text) in files {
        std::fs::write(src.join(name), text).unwrap();
    }
    (cut_amc.lines().count(), cut_bvh.lines().count())
}

/// The warnings on the two files of [`write_cut_collection`] cut short,
/// given their line counts.
fn cut_warnings(amc_lines: usize, bvh_lines: usize) -> [Warning; 2] {
    [
        Warning {
            file: "src/02_02.amc".into(),
            take: "02_02".into(),
            kind: "truncated".into(),
            frames_kept: 8,
            frames_expected: 9,
            message: format!(
                "src/02_02.amc: the file ends inside its motion (line {amc_lines}): \
                 kept its 8 complete frames of 9"
            ),
        },
        Warning {
            file: "src/02_04.bvh".into(),
            take: "02_04".into(),
            kind: "truncated".into(),
            frames_kept: 8,
            frames_expected: 9,
            message: format!(
                "src/02_04.bvh: the file ends inside its motion (line {bvh_lines}): \
                 kept its 8 complete frames of 9"
            ),
        },
    ]
}

#[test]
fn a_dataset_keeps_takes_cut_short_with_a_warning_unless_strict() {
    let tmp = TempDir::new("truncated-dataset");
    let src = tmp.0.join("src");
    let (amc_lines, bvh_lines) = write_cut_collection(&src);

    let out = tmp.0.join("ds");
    let s = build(&src, &out, false);
    assert_eq!(s.files, 6);
    assert_eq!(s.takes, 4, "{:?}", s.skipped);
    // Whole: 9 + 9 raw frames (3 + 3 at 30 fps); cut: 8 + 8 (2 + 2).
    assert_eq!((s.native_frames, s.frames), (34, 10));
    let codes: Vec<(&str, &str)> = s
        .skipped
        .iter()
        .map(|k| (k.take.as_str(), k.code.as_str()))
        .collect();
    assert_eq!(
        codes,
        [("02_03", "non_numeric"), ("02_05", "duplicate_take")]
    );
    assert!(
        s.skipped[1].message.contains(
            "ends inside its motion (8 of 9 frames) and the copy src/02_05.bvh is complete"
        ),
        "{}",
        s.skipped[1].message
    );
    assert_eq!(s.duplicates.truncated_yielded, 1);
    let want = cut_warnings(amc_lines, bvh_lines);
    assert_eq!(s.warnings, want);
    // The summary `cargo xtask dataset` prints lists them.
    let text = s.report(&out, 1.0, 1, None);
    assert!(text.contains("takes cut short             2"), "{text}");
    for w in &want {
        assert!(text.contains(&w.message), "{text}");
    }
    // The manifest says the same, in take order, and records the option.
    let m = manifest(&out);
    assert_eq!(manifest_warnings(&m).unwrap(), want);
    assert_eq!(m["counts"]["warnings"], 2);
    assert_eq!(m["options"]["strict"], false);
    assert_eq!(m["format_version"], mocap_ingest::dataset::FORMAT_VERSION);
    // A manifest from before (no `warnings`) reads as no warnings.
    let mut old = m.clone();
    old.as_object_mut().unwrap().remove("warnings");
    assert_eq!(manifest_warnings(&old).unwrap(), Vec::<Warning>::new());
    // Rebuilt: the same bytes.
    let again = tmp.0.join("again");
    build(&src, &again, false);
    for f in mocap_ingest::dataset::FILES {
        assert!(
            std::fs::read(out.join(f)).unwrap() == std::fs::read(again.join(f)).unwrap(),
            "{f} differs"
        );
    }

    strict_skips_them(&src, &tmp.0.join("strict"), amc_lines);
}

/// Strict: the files of [`write_cut_collection`] (in `src`) cut short are
/// skipped as `truncated` (`amc_lines`: the cut AMC's line count).
fn strict_skips_them(src: &Path, strict: &Path, amc_lines: usize) {
    let s = build(src, strict, true);
    assert_eq!(s.takes, 2);
    assert_eq!((s.native_frames, s.frames), (18, 6));
    assert!(s.warnings.is_empty());
    let codes: Vec<(&str, &str)> = s
        .skipped
        .iter()
        .map(|k| (k.file.as_str(), k.code.as_str()))
        .collect();
    assert_eq!(
        codes,
        [
            ("src/02_02.amc", "truncated"),
            ("src/02_03.amc", "non_numeric"),
            ("src/02_04.bvh", "truncated"),
            ("src/02_05.amc", "truncated"),
        ]
    );
    assert!(
        s.skipped[0].message.contains(&format!(
            "truncated motion: expected 9 frames, file holds 8 complete frames (ends at line {amc_lines})"
        )),
        "{}",
        s.skipped[0].message
    );
    assert_eq!(s.duplicates.fell_back, 1);
    let m = manifest(strict);
    assert_eq!(m["warnings"], serde_json::json!([]));
    assert_eq!(m["options"]["strict"], true);
}
