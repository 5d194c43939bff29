//! Seeded random mutations of real BVH (Motionbuilder and Daz-friendly) and
//! ASF/AMC files — truncations, dropped or duplicated lines, junk tokens,
//! byte flips — built into one dataset beside good takes: every file is
//! accounted for (a file cut inside its motion as a take with a warning),
//! the good takes arrive, and nothing panics (a panic hook
//! counts panics anywhere in the process, caught or not).
//!
//! This binary holds a single test, so the hook sees only its own panics.

use integration_tests::{asfamc_zip, bvh_zip, daz_zip, read_entry};
use mocap_ingest::dataset::{build_dataset, NoProgress};
use mocap_ingest::source::Source;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// Mutants per kind of file (BVH Motionbuilder, BVH Daz, AMC, ASF).
const PER_KIND: usize = 100;
const SEED: u64 = 0x5eed_0012;

/// SplitMix64.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Tokens that confuse parsers: structure keywords of both formats, numbers
/// that are not, and plain junk.
const JUNK: [&str; 24] = [
    "{",
    "}",
    "ROOT",
    "JOINT",
    "End",
    "End Site",
    "OFFSET",
    "CHANNELS",
    "CHANNELS 99",
    "Xrotation",
    "MOTION",
    "Frames:",
    "HIERARCHY",
    "nan",
    "inf",
    "-",
    "1e999",
    "0x1F",
    ":root",
    ":bonedata",
    "begin",
    "end",
    "999999999999",
    "§junk§",
];

/// One random mutation of `text`; the header (the part before `split`, the
/// BVH hierarchy or the whole ASF) is hit more often than the motion table.
fn mutate(text: &[u8], split: usize, rng: &mut Rng) -> Vec<u8> {
    let lines: Vec<&[u8]> = text.split(|&b| b == b'\n').collect();
    let header_lines = text[..split].iter().filter(|&&b| b == b'\n').count().max(1);
    let pick_line = |rng: &mut Rng| {
        if rng.below(4) < 3 {
            rng.below(header_lines)
        } else {
            rng.below(lines.len())
        }
    };
    let join = |ls: Vec<Vec<u8>>| ls.join(&b'\n');
    match rng.below(6) {
        // Truncation, anywhere.
        0 => text[..rng.below(text.len())].to_vec(),
        // A dropped line.
        1 => {
            let k = pick_line(rng);
            join(
                (0..lines.len())
                    .filter(|&i| i != k)
                    .map(|i| lines[i].to_vec())
                    .collect(),
            )
        }
        // A duplicated line.
        2 => {
            let k = pick_line(rng);
            let mut v: Vec<Vec<u8>> = lines.iter().map(|l| l.to_vec()).collect();
            v.insert(k, lines[k].to_vec());
            join(v)
        }
        // A junk token inserted into a line, or replacing one of its tokens.
        3 | 4 => {
            let k = pick_line(rng);
            let junk = JUNK[rng.below(JUNK.len())];
            let mut toks: Vec<String> = String::from_utf8_lossy(lines[k])
                .split_whitespace()
                .map(String::from)
                .collect();
            let at = rng.below(toks.len() + 1);
            if rng.below(2) == 0 && at < toks.len() {
                toks[at] = junk.to_string();
            } else {
                toks.insert(at, junk.to_string());
            }
            let mut v: Vec<Vec<u8>> = lines.iter().map(|l| l.to_vec()).collect();
            v[k] = toks.join(" ").into_bytes();
            join(v)
        }
        // Byte flips: 1–4 random bytes set to random values.
        _ => {
            let mut t = text.to_vec();
            for _ in 0..1 + rng.below(4) {
                let at = if rng.below(4) < 3 {
                    rng.below(split)
                } else {
                    rng.below(t.len())
                };
                t[at] = rng.next() as u8;
            }
            t
        }
    }
}

fn motion_start(text: &[u8]) -> usize {
    text.windows(6)
        .position(|w| w == b"MOTION")
        .unwrap_or(text.len())
}

#[test]
fn hundreds_of_mutants_of_real_files_never_panic() {
    integration_tests::require_samples!();
    let panics = Arc::new(AtomicUsize::new(0));
    let seen = panics.clone();
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        seen.fetch_add(1, Ordering::SeqCst);
        default_hook(info);
    }));

    let mb = read_entry(&bvh_zip(), "cmu-bvh-motionbuilder/02/02_01.bvh");
    let daz = read_entry(&daz_zip(), "cmu-bvh-daz/02/02_02.bvh");
    let amc = read_entry(&asfamc_zip(), "all_asfamc/subjects/02/02_01.amc");
    let asf = read_entry(&asfamc_zip(), "all_asfamc/subjects/02/02.asf");
    // The AMC mutated in its first 100 lines (about 3 frames) mostly.
    let amc_head = amc
        .iter()
        .enumerate()
        .filter(|(_, &b)| b == b'\n')
        .nth(100)
        .map_or(amc.len(), |(i, _)| i);

    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("mutants");
    let write = |name: &str, bytes: &[u8]| {
        let p = root.join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    };
    // Good takes beside the mutants.
    write("good/02_01.bvh", &mb);
    write("good/02_02.bvh", &daz);
    write("good/amc/02.asf", &asf);
    write("good/amc/02_03.amc", &amc);
    let mut rng = Rng(SEED);
    for i in 0..PER_KIND {
        write(
            &format!("bvh/mb{i:03}.bvh"),
            &mutate(&mb, motion_start(&mb), &mut rng),
        );
        write(
            &format!("bvh/daz{i:03}.bvh"),
            &mutate(&daz, motion_start(&daz), &mut rng),
        );
        // Each AMC in its own folder with its ASF (found as the only .asf).
        write(&format!("amc/a{i:03}/skel.asf"), &asf);
        write(
            &format!("amc/a{i:03}/walk.amc"),
            &mutate(&amc, amc_head, &mut rng),
        );
        write(
            &format!("asf/s{i:03}/skel.asf"),
            &mutate(&asf, asf.len(), &mut rng),
        );
        write(&format!("asf/s{i:03}/walk.amc"), &amc);
    }

    let source = Source::open(&root).unwrap();
    let opts = integration_tests::short_takes_options();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let started = std::time::Instant::now();
    let s = pool
        .install(|| {
            build_dataset(
                &[source],
                &["mutants".into()],
                &tmp.path().join("ds"),
                &opts,
                &NoProgress,
            )
        })
        .unwrap_or_else(|e| panic!("{e}"));
    let seconds = started.elapsed().as_secs_f64();

    let mutants = 4 * PER_KIND;
    assert_eq!(s.files, mutants + 3);
    assert_eq!(
        s.takes + s.skipped.len(),
        s.files,
        "every file accounted for"
    );
    let mut by_code = std::collections::BTreeMap::<&str, usize>::new();
    for k in &s.skipped {
        *by_code.entry(k.code.as_str()).or_default() += 1;
        assert!(
            k.message.contains(k.file.rsplit('/').next().unwrap_or("?")),
            "the message names the file: {k:?}"
        );
    }
    eprintln!(
        "{mutants} mutants + 3 good takes in {seconds:.2} s: {} takes written ({} cut short, \
         kept with a warning), skipped by code {by_code:?}",
        s.takes,
        s.warnings.len()
    );
    // Mutants cut inside their motion are takes with a warning, in take order.
    assert!(s.warnings.len() < s.takes);
    for w in &s.warnings {
        assert_eq!(w.kind, "truncated");
        assert!(
            w.frames_kept > 0 && w.frames_kept < w.frames_expected,
            "{w:?}"
        );
    }
    assert!(s.warnings.windows(2).all(|p| p[0].take < p[1].take));
    assert!(!by_code.contains_key("panic"));
    assert_eq!(panics.load(Ordering::SeqCst), 0, "panics happened");
    // The good takes are in.
    let ok: Vec<&str> = s
        .skipped
        .iter()
        .map(|k| k.take.as_str())
        .filter(|t| t.starts_with("02_"))
        .collect();
    assert!(ok.is_empty(), "good takes skipped: {ok:?}");
    // Mutants are mostly broken, but not all (a duplicated blank line, a
    // flipped digit): at least a few read.
    assert!(s.takes > 3 && s.skipped.len() > mutants / 2, "{by_code:?}");
}
