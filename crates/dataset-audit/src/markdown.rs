//! The audit as people read it: `audit.md`, and `flagged.txt` (an exclude
//! list for `cargo xtask dataset --exclude`).

use crate::Report;
use std::fmt::Write as _;

/// The flagged takes as an exclude list for `cargo xtask dataset --exclude`:
/// one id per line, the reasons as `#` comments.
pub fn flagged_list(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Takes flagged by `cargo xtask audit` of {} (data quality), one id per line.",
        r.dir
    );
    let _ = writeln!(
        s,
        "# Rebuild without them: cargo xtask dataset --exclude flagged.txt (same --source and options)."
    );
    for t in r.takes.iter().filter(|t| !t.flags.is_empty()) {
        let _ = writeln!(s, "{}  # {}", t.take, t.flags.join("; "));
    }
    s
}

/// `audit.md`: the checks, the floored features and the flagged takes.
pub fn markdown(r: &Report, seconds: f64) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Audit of `{}`\n", r.dir);
    let _ = writeln!(
        s,
        "{} ({} checks, {:.2} s)\n",
        if r.ok() { "**PASS**" } else { "**FAIL**" },
        r.checks.len(),
        seconds
    );
    let _ = writeln!(
        s,
        "| section | check | result | detail |\n|---|---|---|---|"
    );
    for c in &r.checks {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} |",
            c.section,
            c.name,
            if c.ok { "ok" } else { "**FAIL**" },
            c.detail.replace('|', "/")
        );
    }
    let _ = writeln!(
        s,
        "\nFeatures whose std hit the floor: {}\n",
        if r.floored_features.is_empty() {
            "none".into()
        } else {
            r.floored_features.join(", ")
        }
    );
    if !r.categories.is_empty() {
        let _ = writeln!(
            s,
            "## Categories\n\nWindows per category and split (`takes.parquet`'s `category`).\n\n| category | takes | train | val | test |\n|---|---|---|---|---|"
        );
        for c in &r.categories {
            let [tr, va, te] = c.windows;
            let _ = writeln!(s, "| {} | {} | {tr} | {va} | {te} |", c.category, c.takes);
        }
        let _ = writeln!(s);
    }
    for n in &r.notes {
        let _ = writeln!(s, "Note: {n}.\n");
    }
    let flagged: Vec<_> = r.takes.iter().filter(|t| !t.flags.is_empty()).collect();
    let th = &r.thresholds;
    let _ = writeln!(
        s,
        "## Data quality\n\n{} takes, {} flagged (mean root speed > {} m/s, any frame > {} m/s, bone length std > {}% of its length, lowest toe > {} or < {} units).\n",
        r.takes.len(), flagged.len(), th.mean_speed, th.max_speed, 100.0 * th.bone_cv, th.min_toe, th.sink_toe
    );
    let _ = writeln!(s, "| take | seconds | mean speed m/s | max speed m/s | bone var % | lowest toe | flags |\n|---|---|---|---|---|---|---|");
    for t in &flagged {
        let _ = writeln!(
            s,
            "| {} | {:.1} | {:.2} | {:.2} | {:.3} | {:.2} | {} |",
            t.take,
            t.seconds,
            t.mean_speed,
            t.max_speed,
            100.0 * t.bone_cv,
            t.min_toe,
            t.flags.join("; ")
        );
    }
    let _ = writeln!(
        s,
        "\nThe flagged ids are in flagged.txt: `cargo xtask dataset --exclude flagged.txt` rebuilds without them."
    );
    let _ = writeln!(s, "\nHistograms: take_duration.png, root_speed.png, bone_length_variation.png, foot_height.png");
    s
}
