//! `cargo xtask audit`.

use anyhow::{bail, Context, Result};
use clap::Args;
use dataset_audit::{audit, Rebuild, Report, Thresholds};
use motion_render::chart::histogram;
use motion_render::write_file;
use std::fmt::Write as _;
use std::path::PathBuf;

#[derive(Args)]
pub struct AuditArgs {
    /// Dataset directory written by `cargo xtask dataset`.
    #[arg(long, default_value = "data/datasets/cmu")]
    data: PathBuf,
    /// Rebuild from these sources (as given to `dataset`) and prove the bytes match.
    #[arg(long = "source")]
    sources: Vec<PathBuf>,
    /// The --asf skeleton the dataset was built with (for the rebuild).
    #[arg(long)]
    asf: Option<PathBuf>,
    /// Where to write audit.md, audit.json, flagged.txt and the histograms (default: DATA-audit beside the dataset).
    #[arg(long)]
    report: Option<PathBuf>,
}

pub fn run(a: AuditArgs) -> Result<()> {
    let started = std::time::Instant::now();
    let rebuild = Rebuild {
        sources: a.sources.clone(),
        asf: a.asf.clone(),
    };
    let report = audit(&a.data, &rebuild, Thresholds::default())?;
    let out = a.report.clone().unwrap_or_else(|| {
        let mut p = a.data.clone().into_os_string();
        p.push("-audit");
        PathBuf::from(p)
    });
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let seconds = started.elapsed().as_secs_f64();
    let md = markdown(&report, seconds);
    write_file(&out.join("audit.md"), md.as_bytes())?;
    let json = serde_json::to_string_pretty(
        &serde_json::json!({ "ok": report.ok(), "seconds": seconds, "report": report }),
    )?;
    write_file(&out.join("audit.json"), (json + "\n").as_bytes())?;
    write_file(&out.join("flagged.txt"), flagged_list(&report).as_bytes())?;
    if !report.takes.is_empty() {
        let durations: Vec<f64> = report.takes.iter().map(|t| t.seconds).collect();
        let cv: Vec<f64> = report.takes.iter().map(|t| 100.0 * t.bone_cv).collect();
        histogram(
            &out.join("take_duration.png"),
            "take duration",
            "seconds",
            &durations,
            30,
        )?;
        histogram(
            &out.join("root_speed.png"),
            "horizontal root speed per frame",
            "m/s",
            &report.speeds,
            40,
        )?;
        histogram(
            &out.join("bone_length_variation.png"),
            "largest bone-length variation per take",
            "percent of length",
            &cv,
            30,
        )?;
        histogram(
            &out.join("foot_height.png"),
            "height of the lower toe per frame",
            "units above the floor",
            &report.toe_heights,
            40,
        )?;
    }
    print!("{md}");
    println!("\nreport: {}", out.display());
    if !report.ok() {
        bail!(
            "audit failed: {} of {} checks failed",
            report.checks.iter().filter(|c| !c.ok).count(),
            report.checks.len()
        );
    }
    Ok(())
}

/// The flagged takes as an exclude list for `cargo xtask dataset --exclude`:
/// one id per line, the reasons as `#` comments.
fn flagged_list(r: &Report) -> String {
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

fn markdown(r: &Report, seconds: f64) -> String {
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
    let flagged: Vec<_> = r.takes.iter().filter(|t| !t.flags.is_empty()).collect();
    let th = &r.thresholds;
    let _ = writeln!(
        s,
        "## Data quality\n\n{} takes, {} flagged (mean root speed > {} m/s, any frame > {} m/s, bone length std > {}% of its length, lowest toe > {} units).\n",
        r.takes.len(), flagged.len(), th.mean_speed, th.max_speed, 100.0 * th.bone_cv, th.min_toe
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
