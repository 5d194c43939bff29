//! How fast a run generates (`cargo xtask bench-sample`): the default
//! sampler (held to the pace, chosen among draws) beside the model alone
//! (one draw, the pace not held), both from the same training contexts.

use crate::run::Run;
use crate::EvalError;
use std::time::Instant;

/// One sampler timed.
#[derive(Clone, Debug, PartialEq)]
pub struct SampleTiming {
    /// What was timed: `default sampler` or `model alone`.
    pub sampler: &'static str,
    /// Samplings of the model per output frame
    /// ([`crate::horizon::samplings_per_frame`]).
    pub samplings_per_frame: usize,
    /// Motions generated at once.
    pub motions: usize,
    /// Frames per motion.
    pub frames: usize,
    /// The fastest of the repeats, seconds.
    pub seconds: f64,
}

impl SampleTiming {
    /// Output frames per second (every motion's frames).
    pub fn frames_per_s(&self) -> f64 {
        (self.motions * self.frames) as f64 / self.seconds.max(f64::MIN_POSITIVE)
    }
}

/// Time `m.sample` of `motions` motions of `frames` frames (continuing
/// `context` frames of training windows, sampling seed `seed`), the
/// fastest of `repeat` runs: with the run's sampler, then, where that
/// sampler holds the pace, with the model alone. `m`'s sampler is restored.
pub fn time_sampling(
    m: &mut Run,
    motions: usize,
    frames: usize,
    context: usize,
    seed: u64,
    repeat: usize,
) -> Result<Vec<SampleTiming>, EvalError> {
    let time = |m: &Run, sampler: &'static str| -> Result<SampleTiming, EvalError> {
        let mut best = f64::INFINITY;
        for _ in 0..repeat.max(1) {
            let start = Instant::now();
            m.sample(motions, frames, context, seed)?;
            best = best.min(start.elapsed().as_secs_f64());
        }
        Ok(SampleTiming {
            sampler,
            samplings_per_frame: crate::horizon::samplings_per_frame(m.held_pace().map(|h| h.1)),
            motions,
            frames,
            seconds: best,
        })
    };
    let mut out = vec![time(m, "default sampler")?];
    if m.held_pace().is_some() {
        out.push(m.alone(|m| time(m, "model alone"))?);
    }
    Ok(out)
}

/// The timings as a Markdown table.
pub fn markdown(t: &[SampleTiming]) -> String {
    let mut s = String::from(
        "| sampler | samplings per frame | motions × frames | seconds | frames/s |\n|---|---|---|---|---|\n",
    );
    for r in t {
        s += &format!(
            "| {} | {} | {} × {} | {:.2} | {:.0} |\n",
            r.sampler,
            r.samplings_per_frame,
            r.motions,
            r.frames,
            r.seconds,
            r.frames_per_s()
        );
    }
    s
}
