//! `cargo xtask audit`.

use anyhow::{bail, Context, Result};
use clap::Args;
use dataset_audit::markdown::{flagged_list, markdown};
use dataset_audit::{audit, Rebuild, Thresholds};
use motion_render::chart::histogram;
use motion_render::write_file;
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
