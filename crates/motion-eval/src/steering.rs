//! Steering (`cargo xtask steer`, `continue --path`, `eval --steer`):
//! motions asked, frame by frame, to follow a path, and how well they do,
//! beside what real walks of the data do.

use crate::run::{Asking, Run};
use crate::{create_dir, EvalError};
use mocap_ingest::category::Category;
use mocap_ingest::Pose;
use motion_metrics::{motion_stats, root_speed, turning_rate, MotionStats, Options};
use motion_steer::{heading_deg, parse_path, path_error, reach_seconds, turn_seconds, Path, FPS};
use motion_vrnn::generate::{self, Rollout};
use motion_vrnn::steer::{steer_windows, Steered};
use serde::{Deserialize, Serialize};
use std::path::{Path as FsPath, PathBuf};

/// Motions each path is followed by in `eval --steer`.
pub const STEER_MOTIONS: usize = 64;

/// The built-in paths `eval --steer` measures (`motion_steer::parse_path`).
pub const BUILT_IN: [&str; 4] = ["line:10", "circle:2", "zigzag:4", "stop-go"];

/// The end of a path counts as reached within this distance (metres).
pub const REACH_M: f64 = 0.5;

/// A turn counts as made once the facing is within this many degrees of
/// the new direction.
pub const TURN_TOLERANCE_DEG: f64 = 15.0;

/// A path's corners turn at least this much (degrees); a circle's polygon
/// has none.
pub const CORNER_DEG: f64 = 45.0;

/// Frames a motion following `path` is given: one and a half times the
/// asked time, plus two seconds, plus the first frame.
pub fn frames_for(path: &Path) -> usize {
    ((path.asked_seconds() * 1.5 + 2.0) * FPS).ceil() as usize + 1
}

/// What real walks of the training windows do: the reference of the
/// steering measures and of the speeds a path may ask.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Walks {
    /// Training windows of walking.
    pub windows: usize,
    /// Their mean root speed (m/s): the built-in paths' speed.
    pub speed_m_s: f64,
    /// The fastest mean root speed of any training window (m/s): the most
    /// a path may ask.
    pub fastest_m_s: f64,
    /// The 90th percentile of the walks' mean turning rate (°/s).
    pub turning_p90_deg_s: f64,
    /// The walks' measures (skating, contact, jerk, bones).
    pub stats: MotionStats,
}

/// `v`'s `q`-quantile (0 for none).
fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

impl Run {
    /// The real walks of the training windows ([`Walks`]).
    pub fn walks(&self) -> Result<Walks, EvalError> {
        let (train, categories) = self.labelled("train")?;
        let all = generate::windows_of(train);
        let poses: Vec<Vec<Pose>> = all.iter().map(|x| self.generated_poses(x)).collect();
        let walks: Vec<Vec<Pose>> = poses
            .iter()
            .zip(categories)
            .filter(|(_, c)| **c == Category::Walk)
            .map(|(p, _)| p.clone())
            .collect();
        if walks.is_empty() {
            return Err(EvalError::Invalid(format!(
                "{}: no training windows of walking to measure steering against",
                self.data.dir.display()
            )));
        }
        let o = Options::default();
        let speeds: Vec<f64> = walks.iter().map(|m| root_speed(m, 0, FPS)).collect();
        let mut turning: Vec<f64> = walks.iter().map(|m| turning_rate(m, FPS).abs()).collect();
        Ok(Walks {
            windows: walks.len(),
            speed_m_s: speeds.iter().sum::<f64>() / speeds.len() as f64,
            fastest_m_s: poses
                .iter()
                .map(|m| root_speed(m, 0, FPS))
                .fold(0.0, f64::max),
            turning_p90_deg_s: quantile(&mut turning, 0.9),
            stats: motion_stats(&walks, &o),
        })
    }

    /// `n` motions of `frames` frames following `path`, each continuing
    /// `context` frames of a training window drawn from `seed` (of the
    /// category asked, walking where none is), asked for that category.
    pub fn steer(
        &self,
        path: &Path,
        n: usize,
        frames: usize,
        context: usize,
        seed: u64,
    ) -> Result<Vec<Steered>, EvalError> {
        let train = self.split("train")?;
        let (category, ask) = match self.ask {
            Asking::One(c, a) => (c, Some(a)),
            _ => (Category::Walk, None),
        };
        let picks = self.training_picks(Some(category), n, seed)?;
        let o = Rollout {
            frames,
            context,
            seed,
            ask,
            pace_gain: 0.0,
            draws: 1,
        };
        let stats = &self.data.stats;
        Ok(steer_windows(
            &self.model.model,
            train,
            &picks,
            &o,
            path,
            stats,
            &self.device,
        )?)
    }
}

/// How motions followed one path.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PathScore {
    /// The path asked (`line:10`, a file, …).
    pub path: String,
    /// Its speed (m/s) and the time it asks for (s).
    pub speed_m_s: f64,
    pub asked_s: f64,
    /// Motions measured.
    pub motions: usize,
    /// Mean distance of the root from the path (m), mean and std over the
    /// motions.
    pub error_m: f64,
    pub error_std_m: f64,
    /// Motions whose root reached the end ([`REACH_M`]).
    pub reached: usize,
    /// Time to reach the end over the asked time, mean over those that did.
    pub time_ratio: Option<f64>,
    /// Seconds from a corner being asked (the control's farthest target
    /// passing it) to the facing being within [`TURN_TOLERANCE_DEG`] of the
    /// new direction, mean over corners and motions that turned; None
    /// where the path has no corner.
    pub turn_s: Option<f64>,
    /// Corners (of all motions) never turned.
    pub turns_missed: usize,
    /// The steered motions' measures.
    pub stats: MotionStats,
}

/// Seconds each corner of `path` took the motion with roots `roots` and
/// facings `forward` to turn (None: never), asked when the control's
/// farthest target (one second ahead at the path's speed) passed it.
pub fn corner_turns(path: &Path, roots: &[[f64; 2]], forward: &[[f64; 2]]) -> Vec<Option<f64>> {
    let points = path.points();
    let mut out = Vec::new();
    for i in 1..points.len().saturating_sub(1) {
        let (a, b) = (path.segment_tangent(i - 1), path.segment_tangent(i));
        if heading_deg(a, b).abs() < CORNER_DEG {
            continue;
        }
        let corner = path.arc_at_point(i);
        let mut s = 0.0;
        let asked = roots.iter().position(|&r| {
            s = path.project(r, s, motion_steer::follow::WINDOW_M);
            s + path.speed_at(s) >= corner
        });
        out.push(asked.and_then(|t| turn_seconds(forward, t, b, TURN_TOLERANCE_DEG)));
    }
    out
}

/// `path` followed by the motions `steered` (poses `poses`), measured.
pub fn score(name: &str, path: &Path, steered: &[Steered], poses: &[Vec<Pose>]) -> PathScore {
    let n = steered.len().max(1) as f64;
    let mut errors = Vec::new();
    let (mut times, mut turns, mut missed) = (Vec::new(), Vec::new(), 0);
    for s in steered {
        let roots: Vec<[f64; 2]> = s.track.iter().map(|f| f.pos).collect();
        let forward: Vec<[f64; 2]> = s.track.iter().map(|f| f.forward).collect();
        errors.push(path_error(path, &roots));
        if let Some(t) = reach_seconds(path, &roots, REACH_M) {
            times.push(t / path.asked_seconds());
        }
        for t in corner_turns(path, &roots, &forward) {
            match t {
                Some(t) => turns.push(t),
                None => missed += 1,
            }
        }
    }
    let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let error = mean(&errors).unwrap_or(f64::NAN);
    let var = errors.iter().map(|e| (e - error).powi(2)).sum::<f64>() / n;
    PathScore {
        path: name.to_string(),
        speed_m_s: path.speeds().first().copied().unwrap_or(0.0),
        asked_s: path.asked_seconds(),
        motions: steered.len(),
        error_m: error,
        error_std_m: var.sqrt(),
        reached: times.len(),
        time_ratio: mean(&times),
        turn_s: mean(&turns),
        turns_missed: missed,
        stats: motion_stats(poses, &Options::default()),
    }
}

/// The path `spec` ([`motion_steer::parse_path`]) at `speed` m/s, or at
/// the mean speed of the run's real walks, with those walks; refused above
/// the fastest training window's speed.
pub fn asked_path(run: &Run, spec: &str, speed: Option<f64>) -> Result<(Path, Walks), EvalError> {
    if !run.meta.config.model.parts.control {
        return Err(EvalError::Invalid(
            "this model was trained without the control, so it cannot follow a path; train one with `cargo xtask train` (the default, `--condition category+pace+control`)".into(),
        ));
    }
    let walks = run.walks()?;
    let path = parse_path(spec, speed.unwrap_or(walks.speed_m_s))?;
    path.check_speed(walks.fastest_m_s)?;
    Ok((path, walks))
}

/// What [`write_steered`] wrote, and how the motions followed the path.
pub struct Written {
    /// One BVH per motion.
    pub bvh: Vec<PathBuf>,
    /// The motions' Parquet and the picture from above.
    pub parquet: PathBuf,
    pub png: PathBuf,
    pub score: PathScore,
}

impl Written {
    /// The files written, one a line, then how the motions followed.
    pub fn summary(&self) -> String {
        let s = &self.score;
        let mut out: String = self
            .bvh
            .iter()
            .map(|f| format!("{}\n", f.display()))
            .collect();
        out += &format!(
            "{}\n{}\npath error {:.2} m (± {:.2}); reached the end: {} of {}",
            self.parquet.display(),
            self.png.display(),
            s.error_m,
            s.error_std_m,
            s.reached,
            s.motions
        );
        if let Some(t) = s.time_ratio {
            out += &format!(", in {t:.2}× the asked time");
        }
        out + "\n"
    }
}

/// `n` motions following `path` (named `spec`; [`Run::steer`] from
/// `context` frames and `seed`), written beside `out`: `out` itself (or
/// `OUT_k.bvh` for several), `OUT.parquet` and `OUT.png` (the path from
/// above, each root over it).
pub fn write_steered(
    run: &Run,
    (spec, path): (&str, &Path),
    n: usize,
    (context, seed): (usize, u64),
    out: &FsPath,
) -> Result<Written, EvalError> {
    let steered = run.steer(path, n.max(1), frames_for(path), context, seed)?;
    let motions: Vec<_> = steered
        .iter()
        .enumerate()
        .map(|(k, s)| run.motion(format!("steered_{k}"), &s.frames))
        .collect();
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        create_dir(dir)?;
    }
    let stem = out.with_extension("");
    let mut bvh = Vec::new();
    for (k, m) in motions.iter().enumerate() {
        let file = match motions.len() {
            1 => out.to_path_buf(),
            _ => PathBuf::from(format!("{}_{k}.bvh", stem.display())),
        };
        motion_render::bvh::write_bvh(&file, m)?;
        bvh.push(file);
    }
    let (parquet, png) = (stem.with_extension("parquet"), stem.with_extension("png"));
    motion_render::io::write_parquet(&parquet, &motions)?;
    picture(&png, spec, path, &steered)?;
    let poses: Vec<_> = motions.iter().map(|m| m.poses.clone()).collect();
    let score = score(spec, path, &steered, &poses);
    Ok(Written {
        bvh,
        parquet,
        png,
        score,
    })
}

/// `a / b`, a steered measure over the real walks' (`b` kept from 0).
fn ratio(a: f64, b: f64) -> f64 {
    a / b.max(1e-12)
}

/// `eval --steer`: the real walks, and each path measured.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SteerReport {
    pub walks: Walks,
    pub paths: Vec<PathScore>,
}

/// The picture of `path` from above with the roots of `steered` over it.
pub fn picture(
    file: &FsPath,
    title: &str,
    path: &Path,
    steered: &[Steered],
) -> Result<(), EvalError> {
    let roots: Vec<Vec<[f64; 2]>> = steered
        .iter()
        .map(|s| s.track.iter().map(|f| f.pos).collect())
        .collect();
    Ok(motion_render::top_down(file, title, path.points(), &roots)?)
}

/// `eval --steer`: every built-in path ([`BUILT_IN`]) at the real walks'
/// speed, followed by `motions` motions from training contexts (`context`
/// frames, drawn from `seed`), measured; with `pictures`, each path's
/// picture written there as `steer-PATH.png`.
pub fn evaluate(
    run: &Run,
    motions: usize,
    context: usize,
    seed: u64,
    pictures: Option<&FsPath>,
    log: &dyn Fn(&str),
) -> Result<SteerReport, EvalError> {
    let walks = run.walks()?;
    let mut paths = Vec::new();
    for spec in BUILT_IN {
        let path = parse_path(spec, walks.speed_m_s)?;
        let steered = run.steer(&path, motions, frames_for(&path), context, seed)?;
        let poses: Vec<_> = steered
            .iter()
            .map(|s| run.generated_poses(&s.frames))
            .collect();
        let s = score(spec, &path, &steered, &poses);
        if let Some(dir) = pictures {
            let name = format!("steer-{}.png", spec.replace(':', "-"));
            picture(&dir.join(name), spec, &path, &steered)?;
        }
        log(&format!(
            "{spec}: path error {:.2} m, reached {}/{}",
            s.error_m, s.reached, s.motions
        ));
        paths.push(s);
    }
    Ok(SteerReport { walks, paths })
}

/// The goals of steering, each with its test on a path's score (ratios to
/// the real walks'): the path error, the end in time, a 90° turn, and the
/// motion's feet, smoothness and bones.
pub fn goals(p: &PathScore, w: &Walks) -> [(&'static str, bool); 5] {
    let g = &p.stats;
    [
        ("path error ≤ 0.3 m", p.error_m <= 0.3),
        (
            "the end within 20 % of the asked time",
            p.reached == p.motions && p.time_ratio.is_some_and(|t| (0.8..=1.2).contains(&t)),
        ),
        (
            "a 90° turn within 1.5 s",
            p.turn_s.is_none_or(|t| t <= 1.5 && p.turns_missed == 0),
        ),
        (
            "skating ≤ 1.5×, contact 0.75–1.25×, jerk 0.67–1.5× real walks",
            ratio(g.skate_in_contact, w.stats.skate_in_contact) <= 1.5
                && (0.75..=1.25).contains(&ratio(g.contact_share, w.stats.contact_share))
                && (0.67..=1.5).contains(&ratio(g.jerk_m_s3, w.stats.jerk_m_s3)),
        ),
        ("bone cv ≤ 1 %", g.bone_cv <= 0.01),
    ]
}

/// The steering table over seeds: each path's measures as mean ± std over
/// `reports` (one per training seed), then each goal on the mean and seed
/// by seed.
pub fn seeds_markdown(reports: &[(u64, SteerReport)]) -> String {
    let Some((_, first)) = reports.first() else {
        return String::new();
    };
    // Mean ± std over the seeds, as every other table of the results page.
    let ms = |v: Vec<f64>, p: usize| {
        let (m, sd) = crate::mean_std(&v);
        format!("{m:.p$} ± {sd:.p$}")
    };
    let mut s = String::from("| path | path error m | reached | time / asked | 90° turn s | corners missed | skating × | contact × | jerk × | bone cv |\n|---|---|---|---|---|---|---|---|---|---|\n");
    for (k, p) in first.paths.iter().enumerate() {
        let each = |f: &dyn Fn(&PathScore, &Walks) -> f64| -> Vec<f64> {
            reports
                .iter()
                .map(|(_, r)| f(&r.paths[k], &r.walks))
                .collect()
        };
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            p.path,
            ms(each(&|p, _| p.error_m), 2),
            ms(each(&|p, _| p.reached as f64 / p.motions.max(1) as f64), 2),
            ms(each(&|p, _| p.time_ratio.unwrap_or(f64::NAN)), 2),
            match p.turn_s {
                Some(_) => ms(each(&|p, _| p.turn_s.unwrap_or(f64::NAN)), 2),
                None => "–".into(),
            },
            ms(each(&|p, _| p.turns_missed as f64), 1),
            ms(
                each(&|p, w| ratio(p.stats.skate_in_contact, w.stats.skate_in_contact)),
                2
            ),
            ms(
                each(&|p, w| ratio(p.stats.contact_share, w.stats.contact_share)),
                2
            ),
            ms(each(&|p, w| ratio(p.stats.jerk_m_s3, w.stats.jerk_m_s3)), 2),
            ms(each(&|p, _| p.stats.bone_cv), 4),
        ));
    }
    s.push_str("\nGoals, seed by seed (✓ met, ✗ missed):\n\n| path | ");
    let names = goals(&first.paths[0], &first.walks).map(|g| g.0);
    s.push_str(&names.join(" | "));
    s.push_str(" |\n|---|");
    s.push_str(&"---|".repeat(names.len()));
    s.push('\n');
    for (k, p) in first.paths.iter().enumerate() {
        s.push_str(&format!("| {} |", p.path));
        for g in 0..names.len() {
            let marks: Vec<String> = reports
                .iter()
                .map(|(seed, r)| {
                    let ok = goals(&r.paths[k], &r.walks)[g].1;
                    format!("{seed}{}", if ok { "✓" } else { "✗" })
                })
                .collect();
            s.push_str(&format!(" {} |", marks.join(" ")));
        }
        s.push('\n');
    }
    s
}

/// A Markdown table of `r`: each path's error, end, turns, and its
/// motions' measures as ratios to the real walks'.
pub fn markdown(r: &SteerReport) -> String {
    let w = &r.walks.stats;
    let mut s = format!(
        "Real walks: {} training windows, {:.2} m/s (fastest window {:.2} m/s), turning p90 {:.0}°/s; skating in contact {:.3}, contact {:.2}, jerk {:.1} m/s³, bone cv {:.4}.\n\n",
        r.walks.windows, r.walks.speed_m_s, r.walks.fastest_m_s, r.walks.turning_p90_deg_s,
        w.skate_in_contact, w.contact_share, w.jerk_m_s3, w.bone_cv
    );
    s.push_str("| path | m/s | asked s | path error m | reached | time / asked | 90° turn s (missed) | skating × | contact × | jerk × | bone cv |\n|---|---|---|---|---|---|---|---|---|---|---|\n");
    for p in &r.paths {
        let g = &p.stats;
        s.push_str(&format!(
            "| {} | {:.2} | {:.1} | {:.2} ± {:.2} | {}/{} | {} | {} | {:.2} | {:.2} | {:.2} | {:.4} |\n",
            p.path,
            p.speed_m_s,
            p.asked_s,
            p.error_m,
            p.error_std_m,
            p.reached,
            p.motions,
            p.time_ratio.map_or("–".into(), |t| format!("{t:.2}")),
            p.turn_s
                .map_or("–".into(), |t| format!("{t:.2} ({})", p.turns_missed)),
            ratio(g.skate_in_contact, w.skate_in_contact),
            ratio(g.contact_share, w.contact_share),
            ratio(g.jerk_m_s3, w.jerk_m_s3),
            g.bone_cv
        ));
    }
    s
}
