//! The summary `cargo xtask dataset` prints ([`BuildSummary::report`]).

use super::{BuildSummary, Duplicates, SPLITS};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

impl BuildSummary {
    /// The summary `cargo xtask dataset` prints: counts, skipped files by
    /// reason, copies, warnings, splits, speed (`dir`: where the dataset went;
    /// `rss`: peak resident set size in KiB, if known).
    pub fn report(&self, dir: &Path, seconds: f64, threads: usize, rss: Option<u64>) -> String {
        let s = self;
        let mut out = String::new();
        files_and_takes(s, dir, &mut out);
        if s.duplicates.takes > 0 {
            duplicates(&s.duplicates, &mut out);
        }
        frames_and_splits(s, seconds, threads, rss, &mut out);
        // Duplicates that were simply not read and excluded files are routine;
        // list the files that failed.
        let failed: Vec<&str> = s
            .skipped
            .iter()
            .filter(|k| !matches!(k.code.as_str(), "duplicate_take" | "excluded"))
            .map(|k| k.message.as_str())
            .collect();
        if !s.warnings.is_empty() {
            let warnings: Vec<&str> = s.warnings.iter().map(|w| w.message.as_str()).collect();
            first_twenty(
                "warnings: files that end inside their motion, their complete frames kept \
             (all in manifest.json; --strict skips them):",
                &warnings,
                &mut out,
            );
        }
        if !failed.is_empty() {
            first_twenty(
                "files that failed (all skipped files are in skipped.json):",
                &failed,
                &mut out,
            );
        }
        out
    }
}

/// Where the dataset went, files found, takes written by skeleton, files
/// skipped by reason.
fn files_and_takes(s: &BuildSummary, dir: &Path, out: &mut String) {
    let _ = writeln!(out, "dataset written to {}", dir.display());
    let _ = writeln!(out, "  files found        {:>10}", s.files);
    let _ = writeln!(out, "  takes written      {:>10}", s.takes);
    for ((format, skeleton), n) in &s.takes_by_skeleton {
        let _ = writeln!(out, "    {format:<4} {skeleton:<33} {n:>6}");
    }
    let _ = writeln!(out, "  files skipped      {:>10}", s.skipped.len());
    let mut by_code: BTreeMap<&str, usize> = BTreeMap::new();
    for k in &s.skipped {
        *by_code.entry(k.code.as_str()).or_default() += 1;
    }
    for (code, n) in &by_code {
        let _ = writeln!(out, "    {code:<16} {n:>10}");
    }
}

/// The line on takes in several copies: which were kept and why others
/// were not.
fn duplicates(d: &Duplicates, out: &mut String) {
    let kept: Vec<String> = d
        .kept_by_format
        .iter()
        .map(|(f, n)| format!("{n} {f}"))
        .collect();
    let _ = writeln!(
        out,
        "  takes in several copies {:>5}   kept: {}; {} after the preferred copy failed; \
             {} retargeted (Daz) copies read but yielded to the subject's skeleton; \
             {} copies cut short yielded to another copy; {} copies not read",
        d.takes,
        if kept.is_empty() {
            "none".into()
        } else {
            kept.join(", ")
        },
        d.fell_back,
        d.superseded,
        d.truncated_yielded,
        d.unread
    );
}

/// Excluded files, frames in and out, short and cut takes, takes and
/// windows per split, and the speed.
fn frames_and_splits(
    s: &BuildSummary,
    seconds: f64,
    threads: usize,
    rss: Option<u64>,
    out: &mut String,
) {
    if s.excluded > 0 || !s.exclude_unmatched.is_empty() {
        let _ = writeln!(out, "  excluded files     {:>10}", s.excluded);
    }
    if !s.exclude_unmatched.is_empty() {
        let _ = writeln!(
            out,
            "  exclude-list ids matching no take: {}",
            s.exclude_unmatched.join(", ")
        );
    }
    let _ = writeln!(
        out,
        "  input frames       {:>10}   (native rate)",
        s.native_frames
    );
    let _ = writeln!(out, "  frames written     {:>10}   (30 fps)", s.frames);
    let _ = writeln!(out, "  takes < 1 window   {:>10}", s.short_takes);
    let _ = writeln!(
        out,
        "  takes cut short    {:>10}   (complete frames kept, see warnings)",
        s.warnings.len()
    );
    let _ = writeln!(out, "  {:<8} {:>8} {:>10}", "split", "takes", "windows");
    for (i, split) in SPLITS.iter().enumerate() {
        let _ = writeln!(
            out,
            "  {:<8} {:>8} {:>10}",
            split, s.takes_per_split[i], s.windows_per_split[i]
        );
    }
    let rss = rss.map_or("?".to_string(), |k| format!("{:.0} MiB", k as f64 / 1024.0));
    let _ = writeln!(
        out,
        "  {seconds:.2} s on {threads} threads, {:.0} input frames/s, peak RSS {rss}",
        s.native_frames as f64 / seconds
    );
}

/// A heading, then the first 20 messages indented, then how many more.
fn first_twenty(heading: &str, messages: &[&str], out: &mut String) {
    let _ = writeln!(out, "{heading}");
    for m in messages.iter().take(20) {
        let _ = writeln!(out, "  {m}");
    }
    if messages.len() > 20 {
        let _ = writeln!(out, "  … and {} more", messages.len() - 20);
    }
}
