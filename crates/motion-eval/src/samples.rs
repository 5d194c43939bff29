//! What `cargo xtask sample` writes: generated motions (and reconstructed
//! real windows) as Parquet, JSON and BVH, a contact sheet, animated PNGs
//! and the 3-D viewer.

use crate::run::{Run, RunSpec};
use crate::{create_dir, EvalError};
use motion_render::bvh::RoundTrip;
use motion_render::figure::{animation, contact_sheet, SHEET_MOTIONS_PER_ROW};
use motion_render::io::write_motions;
use motion_render::viewer::{write_viewer, MotionSet};
use motion_render::Motion;
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
    let motions: Vec<Motion> = m
        .sample(o.n, o.frames, spec.context, spec.seed)?
        .iter()
        .enumerate()
        .map(|(k, x)| m.motion(format!("sample_{k:03}"), x))
        .collect();
    let seconds = started.elapsed().as_secs_f64();
    write_motions(out, "samples", &motions)?;
    contact_sheet(&out.join("contact_sheet.png"), &motions, o.sheet_columns)?;
    let anim = out.join("anim");
    create_dir(&anim)?;
    for mo in &motions {
        animation(&anim.join(format!("{}.png", mo.id)), &[mo])?;
    }
    let bvh = out.join("bvh");
    create_dir(&bvh)?;
    let mut round_trips = vec![("generated", motion_render::bvh::write_all(&bvh, &motions)?)];
    // The first generated motions beside their BVH files read back: what a
    // rigid skeleton makes of the model's stretching bones.
    let mut read_back = Vec::new();
    for mo in motions.iter().take(4) {
        read_back.push(mo.clone());
        read_back.push(motion_render::bvh::read_motion(
            &bvh.join(format!("{}.bvh", mo.id)),
            &format!("{}_bvh", mo.id),
        )?);
    }
    let mut sets = vec![MotionSet {
        name: "samples",
        group: 1,
        motions: &motions,
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
    let category_sheet = match m.ask {
        crate::run::Asking::Nothing | crate::run::Asking::Own(_)
            if !m.model.model.config().categories.is_empty() =>
        {
            category_sheet(
                &m,
                spec,
                o.frames,
                o.sheet_columns,
                &out.join("category_sheet.png"),
            )?
        }
        _ => Vec::new(),
    };
    Ok(Written {
        category_sheet,
        reconstructed: pairs.len() / 2,
        epoch: m.meta.epoch,
        seconds,
        round_trips,
        warnings: m.warnings,
        motions,
    })
}
