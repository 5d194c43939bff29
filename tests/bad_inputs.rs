//! A corpus of broken files, made from real CMU files and by hand: each gives
//! its specific error naming the file, none panics, and good files beside them
//! still go through. A file whose only damage is that it ends inside its
//! motion keeps its complete frames and says where it was cut.

use integration_tests::{asfamc_zip, bvh_zip, read_entry};
use mocap_ingest::source::Source;
use mocap_ingest::{process_take, Clip, ErrorKind, IngestError, Options};
use std::path::Path;

fn good_bvh() -> String {
    String::from_utf8(read_entry(&bvh_zip(), "cmu-bvh-motionbuilder/02/02_01.bvh")).unwrap()
}
fn good_amc() -> String {
    String::from_utf8(read_entry(
        &asfamc_zip(),
        "all_asfamc/subjects/02/02_01.amc",
    ))
    .unwrap()
}
fn good_asf() -> String {
    String::from_utf8(read_entry(&asfamc_zip(), "all_asfamc/subjects/02/02.asf")).unwrap()
}

/// Replace the `n`-th line (1-based) of `text`.
fn with_line(text: &str, n: usize, f: impl Fn(&str) -> String) -> String {
    text.lines()
        .enumerate()
        .map(|(i, l)| if i + 1 == n { f(l) } else { l.to_string() })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Replace the `k`-th whitespace-separated token of a line.
fn set_token(line: &str, k: usize, with: &str) -> String {
    let mut t: Vec<&str> = line.split_whitespace().collect();
    t[k] = with;
    t.join(" ")
}

/// Byte offset of the start of the `n`-th line (1-based) of `text`.
fn line_start(text: &str, n: usize) -> usize {
    text.split_inclusive('\n').take(n - 1).map(str::len).sum()
}

fn line_of(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).unwrap() + 1
}

/// Write `files` into a fresh directory, process every take, and return the
/// result per take id.
fn run(files: &[(&str, Vec<u8>)]) -> Vec<(String, Result<Clip, IngestError>)> {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in files {
        let path = dir.path().join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, bytes).unwrap();
    }
    let source = Source::open(dir.path()).unwrap();
    let mut reader = source.reader().unwrap();
    let opts = Options::default();
    source
        .takes()
        .unwrap()
        .iter()
        .map(|t| {
            (
                t.take_id.clone(),
                process_take(&source, &mut reader, t, &opts),
            )
        })
        .collect()
}

fn expect_err<'a>(
    results: &'a [(String, Result<Clip, IngestError>)],
    take: &str,
) -> &'a IngestError {
    let (_, r) = results.iter().find(|(t, _)| t == take).unwrap();
    let e = r.as_ref().expect_err(take);
    let msg = e.to_string();
    eprintln!("{take}: {msg}");
    assert!(
        msg.contains(&format!("{take}.")),
        "error does not name the file: {msg}"
    );
    e
}

/// The take read from a file cut short: its complete frames, and the cut.
fn expect_cut<'a>(
    results: &'a [(String, Result<Clip, IngestError>)],
    take: &str,
) -> (&'a Clip, mocap_ingest::Truncation) {
    let (_, r) = results.iter().find(|(t, _)| t == take).unwrap();
    let clip = r.as_ref().unwrap_or_else(|e| panic!("{take}: {e}"));
    let t = clip
        .truncation
        .unwrap_or_else(|| panic!("{take}: the cut is not recorded"));
    eprintln!(
        "{take}: kept {} of {} frames",
        t.frames_kept(),
        t.frames_expected()
    );
    // The complete frames are the take (a BVH T-pose frame not counted),
    // every 4th at 30 fps; strict readers get the error of format 2.
    assert_eq!(clip.native_frames, t.frames_kept());
    assert_eq!(clip.native_frames, t.found - t.leading);
    assert_eq!(clip.features.len(), clip.native_frames.div_ceil(4));
    assert!(matches!(t.to_error(), ErrorKind::Truncated { .. }));
    (clip, t)
}

#[test]
fn broken_bvh_files_each_give_their_error() {
    integration_tests::require_samples!();
    let good = good_bvh();
    let motion_line = line_of(&good, "Frame Time") + 10;
    let cut = good.len() * 3 / 5;
    let files = vec![
        ("01_ok.bvh", good.clone().into_bytes()),
        ("02_empty.bvh", Vec::new()),
        (
            "03_garbage.bvh",
            (0..4096u32)
                .map(|i| ((i * 2654435761u32) >> 13) as u8)
                .collect(),
        ),
        ("04_truncated.bvh", good.as_bytes()[..cut].to_vec()),
        (
            "04b_no_frame.bvh",
            good.as_bytes()[..line_start(&good, motion_line - 8) + 5].to_vec(),
        ),
        (
            "05_channels.bvh",
            with_line(&good, motion_line, |l| {
                l.rsplit_once(' ').unwrap().0.to_string()
            })
            .into_bytes(),
        ),
        (
            "06_nan.bvh",
            with_line(&good, motion_line, |l| set_token(l, 5, "nan")).into_bytes(),
        ),
        (
            "07_text.bvh",
            with_line(&good, motion_line, |l| set_token(l, 5, "1.2.3")).into_bytes(),
        ),
        (
            "08_joints.bvh",
            good.replace("LeftForeArm", "LeftLowerArm").into_bytes(),
        ),
        (
            "09_frames.bvh",
            good.replace("Frames: 344", "Frames: 99999999999")
                .into_bytes(),
        ),
        ("10_braces.bvh", good.replacen("{", "", 3).into_bytes()),
        (
            "11_nomotion.bvh",
            good.as_bytes()[..good.find("MOTION").unwrap()].to_vec(),
        ),
        (
            "12_declared.bvh",
            good.replacen(
                "CHANNELS 3 Zrotation Yrotation Xrotation",
                "CHANNELS 4 Zrotation Yrotation Xrotation",
                1,
            )
            .into_bytes(),
        ),
        (
            "13_inf.bvh",
            with_line(&good, motion_line, |l| set_token(l, 7, "inf")).into_bytes(),
        ),
        (
            "14_extra_brace.bvh",
            good.replacen("}", "}\n}\n}", 1).into_bytes(),
        ),
        // Both made bvh_anim panic ("Missing joint name!", "Unexpected root").
        (
            "15_joint_without_name.bvh",
            good.replacen("JOINT LeftUpLeg", "JOINT", 1).into_bytes(),
        ),
        (
            "16_root_first.bvh",
            good.replacen("HIERARCHY", "", 1).into_bytes(),
        ),
    ];
    let results = run(&files);
    assert_eq!(results.len(), files.len());
    assert_eq!(
        results[0].1.as_ref().unwrap().features.len(),
        86,
        "the good file still goes through"
    );

    assert!(matches!(
        expect_err(&results, "02_empty").kind,
        ErrorKind::Empty
    ));
    assert!(matches!(
        expect_err(&results, "03_garbage").kind,
        ErrorKind::NotText { .. }
    ));
    let (_, t) = expect_cut(&results, "04_truncated");
    assert_eq!(t.expected, 344);
    assert!(
        t.found > 1 && t.found < 344 && t.line > motion_line - 10,
        "{t:?}"
    );
    // Cut inside the first frame line (after the T-pose): no motion frame.
    match &expect_err(&results, "04b_no_frame").kind {
        ErrorKind::Truncated {
            expected: 344,
            found: 1,
            line,
        } => assert_eq!(*line, motion_line - 8),
        k => panic!("{k}"),
    }
    match &expect_err(&results, "05_channels").kind {
        ErrorKind::ChannelCount {
            line,
            expected: 96,
            found: 95,
        } => assert_eq!(*line, motion_line),
        k => panic!("{k}"),
    }
    match &expect_err(&results, "06_nan").kind {
        ErrorKind::NonFinite { frame, what } => {
            assert_eq!(*frame, motion_line - line_of(&good, "Frame Time") - 1);
            assert!(what.contains(&format!("line {motion_line}")), "{what}");
        }
        k => panic!("{k}"),
    }
    match &expect_err(&results, "07_text").kind {
        ErrorKind::NonNumeric { line, token } => {
            assert_eq!(*line, motion_line);
            assert_eq!(token, "1.2.3");
        }
        k => panic!("{k}"),
    }
    match &expect_err(&results, "08_joints").kind {
        ErrorKind::UnknownSkeleton { missing, .. } => assert_eq!(missing, &["LeftForeArm"]),
        k => panic!("{k}"),
    }
    // `Frames:` promises more lines than the file holds: the same rule.
    let (_, t) = expect_cut(&results, "09_frames");
    assert_eq!((t.expected, t.found), (99999999999, 344));
    expect_err(&results, "10_braces");
    assert!(matches!(
        expect_err(&results, "11_nomotion").kind,
        ErrorKind::Syntax { .. }
    ));
    assert!(matches!(
        expect_err(&results, "12_declared").kind,
        ErrorKind::Syntax { line: Some(_), .. }
    ));
    assert!(matches!(
        expect_err(&results, "13_inf").kind,
        ErrorKind::NonFinite { .. }
    ));
    expect_err(&results, "14_extra_brace");
    let joint_line = line_of(&good, "JOINT LeftUpLeg");
    match &expect_err(&results, "15_joint_without_name").kind {
        ErrorKind::Syntax {
            line: Some(l),
            message,
            ..
        } => assert_eq!((*l, message.as_str()), (joint_line, "JOINT without a name")),
        k => panic!("{k}"),
    }
    match &expect_err(&results, "16_root_first").kind {
        ErrorKind::Syntax {
            line: Some(2),
            message,
            ..
        } => assert_eq!(message, "expected HIERARCHY, found \"ROOT\""),
        k => panic!("{k}"),
    }
}

#[test]
fn broken_asf_amc_files_each_give_their_error() {
    integration_tests::require_samples!();
    let (amc, asf) = (good_amc(), good_asf());
    let root2 = line_of(&amc, "root 10.4117");
    let files = vec![
        ("02/02.asf", asf.clone().into_bytes()),
        ("02/02_01.amc", amc.clone().into_bytes()),
        ("02/02_02.amc", amc.as_bytes()[..amc.len() / 2].to_vec()),
        // Damaged mid-file and cut at the end: the damage is the error.
        (
            "02/02_08.amc",
            with_line(&amc, root2, |l| l.replace("10.4117", "ten")).into_bytes()[..amc.len() / 2]
                .to_vec(),
        ),
        (
            "02/02_03.amc",
            with_line(&amc, root2, |l| l.rsplit_once(' ').unwrap().0.to_string()).into_bytes(),
        ),
        (
            "02/02_04.amc",
            amc.replacen("lowerback 7.44596", "lowerback nan", 1)
                .into_bytes(),
        ),
        (
            "02/02_05.amc",
            with_line(&amc, root2 + 1, |l| l.replace("lowerback", "lowerbackk")).into_bytes(),
        ),
        (
            "02/02_06.amc",
            with_line(&amc, root2 - 1, |_| "3".into()).into_bytes(),
        ),
        (
            "02/02_07.amc",
            with_line(&amc, root2, |l| l.replace("10.4117", "ten")).into_bytes(),
        ),
        ("09/09_01.amc", amc.clone().into_bytes()),
        ("17/17.asf", asf.replace("lfemur", "lthigh").into_bytes()),
        ("17/17_01.amc", amc.clone().into_bytes()),
        ("29/29.asf", vec![0u8, 159, 146, 150, 1, 2, 3]),
        ("29/29_01.amc", amc.clone().into_bytes()),
    ];
    let results = run(&files);
    assert_eq!(results.len(), 11);
    assert_eq!(
        results[0].1.as_ref().unwrap().features.len(),
        86,
        "the good file still goes through"
    );
    // Cut in the middle: the frames before the one it ends in are kept.
    let (_, t) = expect_cut(&results, "02_02");
    assert_eq!(t.found + 1, t.expected);
    assert!(t.found > 100 && t.found < 300, "{t:?}");
    match &expect_err(&results, "02_08").kind {
        ErrorKind::NonNumeric { line, token } => {
            assert_eq!((*line, token.as_str()), (root2, "ten"))
        }
        k => panic!("{k}"),
    }
    match &expect_err(&results, "02_03").kind {
        ErrorKind::ChannelCount {
            line,
            expected: 6,
            found: 5,
        } => assert_eq!(*line, root2),
        k => panic!("{k}"),
    }
    assert!(matches!(
        expect_err(&results, "02_04").kind,
        ErrorKind::NonFinite { frame: 1, .. }
    ));
    assert!(matches!(
        expect_err(&results, "02_05").kind,
        ErrorKind::Syntax { format: "AMC", .. }
    ));
    assert!(matches!(
        expect_err(&results, "02_06").kind,
        ErrorKind::Syntax { format: "AMC", .. }
    ));
    match &expect_err(&results, "02_07").kind {
        ErrorKind::NonNumeric { line, token } => {
            assert_eq!((*line, token.as_str()), (root2, "ten"))
        }
        k => panic!("{k}"),
    }
    match &expect_err(&results, "09_01").kind {
        ErrorKind::MissingAsf { tried } => {
            assert!(tried.starts_with("09.asf beside it (absent)"), "{tried}")
        }
        k => panic!("{k}"),
    }
    // Skeleton errors name the ASF.
    let (_, r) = results.iter().find(|(t, _)| t == "17_01").unwrap();
    let e = r.as_ref().unwrap_err();
    assert!(e.file.ends_with("17.asf"), "{e}");
    assert!(
        matches!(&e.kind, ErrorKind::UnknownSkeleton { missing, .. } if missing == &["lfemur"])
    );
    let (_, r) = results.iter().find(|(t, _)| t == "29_01").unwrap();
    assert!(matches!(
        r.as_ref().unwrap_err().kind,
        ErrorKind::NotText { .. }
    ));
}

#[test]
fn missing_collection_is_a_clear_error() {
    let e = Source::open(Path::new("/no/such/cmu")).unwrap_err();
    assert_eq!(e.to_string(), "/no/such/cmu: no such file or directory");
}
