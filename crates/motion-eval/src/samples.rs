//! What `cargo xtask sample` writes: generated motions (and reconstructed
//! real windows) as Parquet, JSON and BVH, a contact sheet, animated PNGs
//! and the 3-D viewer.

use crate::run::{pin_feet, Run, RunSpec};
use crate::{create_dir, EvalError};
use motion_metrics::{foot_skating, FootFrames, Options};
use motion_render::bvh::RoundTrip;
use motion_render::feet::Pinned;
use motion_render::figure::{animation, contact_sheet, SHEET_MOTIONS_PER_ROW};
use motion_render::io::write_motions;
use motion_render::viewer::{write_viewer, MotionSet};
use motion_render::{Motion, METRES_PER_UNIT};
use motion_vrnn::generate::Ask;
use motion_vrnn::MotionModel;
use std::path::Path;

/// How many motions, how long, and what else to write.
#[derive(Clone, Debug)]
pub struct SampleOptions {
    /// Motions to generate.
    pub n: usize,
    /// Frames per motion (30 fps).
    pub frames: usize,
    /// Windows of the spec's split to reconstruct beside the real ones.
    pub reconstruct: usize,
    /// Columns of the contact sheet, spread over the whole motion.
    pub sheet_columns: usize,
}

/// What pinning the planted toes of generated motions did
/// ([`motion_render::feet::pin_feet`]), measured as `docs/metrics.md`
/// measures feet, before and after.
#[derive(Clone, Copy, Debug)]
pub struct FeetPinned {
    /// Foot-frames held, out of reach, the largest shift.
    pub pinned: Pinned,
    /// The creep of planted toes (m/s), before and after.
    pub creep_m_s: (f64, f64),
    /// The share of foot-frames in contact that skate, before and after.
    pub skate_in_contact: (f64, f64),
}

impl std::fmt::Display for FeetPinned {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "feet pinned: {} planted foot-frames held ({} out of the leg's reach), largest shift {:.3} m; creep of planted toes {:.3} -> {:.3} m/s, skating in contact {:.3} -> {:.3}",
            self.pinned.planted,
            self.pinned.out_of_reach,
            self.pinned.max_shift * METRES_PER_UNIT,
            self.creep_m_s.0,
            self.creep_m_s.1,
            self.skate_in_contact.0,
            self.skate_in_contact.1
        )
    }
}

/// Pins the planted toes of `motions` from frame `from` on (the frames
/// before it, a user's clip, are left as they are) and measures the feet of
/// those frames before and after.
pub fn pin_generated(motions: &mut [Motion], from: usize) -> FeetPinned {
    let feet = |motions: &[Motion]| {
        let mut n = FootFrames::default();
        for m in motions {
            n += foot_skating(m.poses.get(from..).unwrap_or(&[]), &Options::default());
        }
        n
    };
    let before = feet(motions);
    let mut pinned = Pinned::default();
    for m in motions.iter_mut() {
        if let Some(p) = m.poses.get_mut(from..) {
            pinned += pin_feet(p);
        }
    }
    let after = feet(motions);
    FeetPinned {
        pinned,
        creep_m_s: (before.creep_m_s(), after.creep_m_s()),
        skate_in_contact: (before.skate_in_contact(), after.skate_in_contact()),
    }
}

/// What [`write_samples`] wrote.
pub struct Written {
    /// The generated motions.
    pub motions: Vec<Motion>,
    /// Epoch of the checkpoint they come from.
    pub epoch: usize,
    /// Seconds spent generating.
    pub seconds: f64,
    /// Real windows reconstructed (pairs of real and reconstruction).
    pub reconstructed: usize,
    /// BVH round trips per set: generated, and real and reconstructed
    /// when there are reconstructions.
    pub round_trips: Vec<(&'static str, Vec<RoundTrip>)>,
    /// What the user should know.
    pub warnings: Vec<String>,
    /// A conditioned model not asked for one category: the categories
    /// drawn in `category_sheet.png` ([`category_sheet`]), one row each.
    pub category_sheet: Vec<String>,
    /// Seconds spent generating the category sheet's motions.
    pub category_seconds: f64,
    /// With [`RunSpec::pin_feet`]: what pinning the feet did.
    pub pinned: Option<FeetPinned>,
}

impl Written {
    /// What `cargo xtask sample` prints of it: the files written to `out`
    /// (reconstructions of `split`), and what pinning the feet did.
    pub fn listing(&self, out: &Path, split: &str, o: &SampleOptions) -> String {
        let mut s = format!("wrote {}:\n", out.display());
        let mut line = |file: &str, what: String| s += &format!("  {file:<32}{what}\n");
        line(
            "samples.parquet, samples.json",
            "motions (motion, frame, joint, x, y, z; CMU units)".into(),
        );
        if self.reconstructed > 0 {
            let n = self.reconstructed;
            line(
                "reconstructions.parquet/.json",
                format!("{n} real {split} windows and their reconstructions"),
            );
        }
        line(
            "bvh/ID.bvh",
            "every motion as BVH (CMU Motionbuilder skeleton, 30 fps)".into(),
        );
        let c = o.sheet_columns;
        line(
            "contact_sheet.png",
            format!("stick figures, {c} columns over the whole motion (labelled in seconds)"),
        );
        line(
            "anim/*.png",
            format!(
                "animated PNG of the first {PREVIEW_MOTIONS} motions' first {PREVIEW_FRAMES} frames (and real vs reconstruction)"
            ),
        );
        line(
            "viewer.html",
            format!("open in a browser: the first {PREVIEW_MOTIONS} motions in 3-D, orbit/pan/zoom, play/pause, speed, frame slider"),
        );
        if !self.category_sheet.is_empty() {
            let c = self.category_sheet.join(", ");
            line(
                "category_sheet.png",
                format!(
                    "one row per category asked for, its first {PREVIEW_FRAMES} frames (generated in {:.1} s): {c}",
                    self.category_seconds
                ),
            );
        }
        if let Some(p) = &self.pinned {
            s += &format!("{p}\n");
        }
        s
    }
}

/// The contact sheet of a conditioned model: one row per category of the
/// model, [`SHEET_MOTIONS_PER_ROW`] motions asked for it (each continuing a
/// training window of it), named `category_k`. Returns the categories.
pub fn category_sheet(
    m: &Run,
    spec: &RunSpec,
    frames: usize,
    columns: usize,
    path: &Path,
) -> Result<Vec<String>, EvalError> {
    let config = m.model.model.config();
    let mut motions = Vec::new();
    for (row, name) in config.categories.iter().enumerate() {
        let category = name.parse().map_err(EvalError::Invalid)?;
        let ask = Ask {
            row: row + 1,
            guidance: spec.guidance,
        };
        let n = SHEET_MOTIONS_PER_ROW;
        for (k, x) in m
            .sample_asked(
                crate::run::Asking::One(category, ask),
                n,
                frames,
                spec.context,
                spec.seed,
            )?
            .iter()
            .enumerate()
        {
            motions.push(m.motion(format!("{name}_{k}"), x));
        }
    }
    contact_sheet(path, &motions, columns)?;
    Ok(config.categories.clone())
}

/// Generate `o.n` motions from the run of `spec` (each continuing
/// `spec.context` frames of a random training window) and write them, with
/// Motions previewed as animations and in the 3-D viewer (every motion is
/// in the Parquet, JSON, BVH and the contact sheet).
pub const PREVIEW_MOTIONS: usize = 12;

/// Frames of each motion's animated preview (10 s at 30 fps).
pub const PREVIEW_FRAMES: usize = 300;

/// The first [`PREVIEW_FRAMES`] frames of `m`.
fn preview(m: &Motion) -> Motion {
    Motion {
        id: m.id.clone(),
        poses: m.poses.iter().take(PREVIEW_FRAMES).cloned().collect(),
    }
}

/// The generated `motions`' files in `out`: every motion in
/// `samples.parquet` and `bvh/` (with the BVH round trips), the previews
/// in `samples.json` and `anim/`, the contact sheet; and the first four
/// motions beside their BVH files read back (what a rigid skeleton makes
/// of the model's stretching bones).
fn write_generated(
    out: &Path,
    motions: &[Motion],
    columns: usize,
) -> Result<(Vec<RoundTrip>, Vec<Motion>), EvalError> {
    use rayon::prelude::*;
    motion_render::io::write_parquet(&out.join("samples.parquet"), motions)?;
    let shown = &motions[..motions.len().min(PREVIEW_MOTIONS)];
    let previews: Vec<Motion> = shown.iter().map(preview).collect();
    let json = motion_render::io::motions_json(&previews);
    motion_render::write_file(&out.join("samples.json"), json.as_bytes())?;
    contact_sheet(&out.join("contact_sheet.png"), motions, columns)?;
    let anim = out.join("anim");
    create_dir(&anim)?;
    previews
        .par_iter()
        .try_for_each(|mo| animation(&anim.join(format!("{}.png", mo.id)), &[mo]))?;
    let bvh = out.join("bvh");
    create_dir(&bvh)?;
    let round_trips = motion_render::bvh::write_all(&bvh, motions)?;
    let mut read_back = Vec::new();
    for mo in motions.iter().take(4) {
        read_back.push(mo.clone());
        read_back.push(motion_render::bvh::read_motion(
            &bvh.join(format!("{}.bvh", mo.id)),
            &format!("{}_bvh", mo.id),
        )?);
    }
    Ok((round_trips, read_back))
}

/// `cargo xtask sample`: `o.n` motions of `o.frames` frames from the run
/// of `spec` with their files and previews, the viewer, the category sheet, and
/// `o.reconstruct` reconstructed windows of `spec.split`, into `out`.
pub fn write_samples(spec: &RunSpec, o: &SampleOptions, out: &Path) -> Result<Written, EvalError> {
    if o.n == 0 || o.frames == 0 {
        return Err(EvalError::Invalid(
            "--n and --frames must be positive".into(),
        ));
    }
    let m = Run::load(spec, &["train", &spec.split])?;
    create_dir(out)?;
    let started = std::time::Instant::now();
    let mut motions: Vec<Motion> = m
        .sample(o.n, o.frames, spec.context, spec.seed)?
        .iter()
        .enumerate()
        .map(|(k, x)| m.motion(format!("sample_{k:03}"), x))
        .collect();
    let pinned = m.pin_feet.then(|| pin_generated(&mut motions, 0));
    let seconds = started.elapsed().as_secs_f64();
    let anim = out.join("anim");
    let bvh = out.join("bvh");
    let (generated, read_back) = write_generated(out, &motions, o.sheet_columns)?;
    let mut round_trips = vec![("generated", generated)];
    let shown = &motions[..motions.len().min(PREVIEW_MOTIONS)];
    let mut sets = vec![MotionSet {
        name: "samples",
        group: 1,
        motions: shown,
    }];
    let mut pairs = Vec::new();
    if o.reconstruct > 0 {
        let w = m.split(&spec.split)?;
        let idx: Vec<usize> = (0..w.n.min(o.reconstruct)).collect();
        let (real, rec) = m.reconstruct(&spec.split, &idx)?;
        for (k, (r, x)) in real.iter().zip(&rec).enumerate() {
            pairs.push(m.motion(format!("{}_{k:03}", spec.split), r));
            pairs.push(m.motion(format!("recon_{k:03}"), x));
        }
        write_motions(out, "reconstructions", &pairs)?;
        for pair in pairs.chunks(2) {
            animation(
                &anim.join(format!("{}_vs_{}.png", pair[0].id, pair[1].id)),
                &[&pair[0], &pair[1]],
            )?;
        }
        let t = motion_render::bvh::write_all(&bvh, &pairs)?;
        let (r, c): (Vec<_>, Vec<_>) = t.iter().enumerate().partition(|(k, _)| k % 2 == 0);
        round_trips.push(("real", r.into_iter().map(|(_, t)| *t).collect()));
        round_trips.push(("reconstructed", c.into_iter().map(|(_, t)| *t).collect()));
        sets.push(MotionSet {
            name: "real vs reconstruction",
            group: 2,
            motions: &pairs,
        });
    }
    sets.push(MotionSet {
        name: "generated vs its BVH read back",
        group: 2,
        motions: &read_back,
    });
    write_viewer(&out.join("viewer.html"), &sets)?;
    let category_started = std::time::Instant::now();
    let category_sheet = match m.ask {
        crate::run::Asking::Nothing | crate::run::Asking::Own(_)
            if !m.model.model.config().categories.is_empty() =>
        {
            category_sheet(
                &m,
                spec,
                o.frames.min(PREVIEW_FRAMES),
                o.sheet_columns,
                &out.join("category_sheet.png"),
            )?
        }
        _ => Vec::new(),
    };
    Ok(Written {
        pinned,
        category_sheet,
        category_seconds: category_started.elapsed().as_secs_f64(),
        reconstructed: pairs.len() / 2,
        epoch: m.meta.epoch,
        seconds,
        round_trips,
        warnings: m.warnings,
        motions,
    })
}
