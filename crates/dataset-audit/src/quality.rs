//! Per-take data quality: duration, root speed, bone lengths, foot height,
//! and the flags their thresholds raise.

use crate::{Report, TakeQuality, Thresholds, METRES_PER_UNIT};
use mocap_ingest::features::{feature_names, ANG_VEL_Y, VEL_X, VEL_Z};
use mocap_ingest::skeleton::{JOINT_NAMES, JOINT_PARENTS, NUM_JOINTS};
use polars::prelude::*;

/// Per-take data quality: duration, root speed, bone lengths, foot height.
pub(crate) fn quality(frames: &LazyFrame, fps: f64, r: &mut Report) -> PolarsResult<()> {
    let derived = derived_columns(frames)?;
    // Per-frame vectors for the histograms.
    let to_f = fps * METRES_PER_UNIT;
    let sp = derived.column("speed2")?.f64()?.clone();
    r.speeds = sp
        .iter()
        .map(|v| v.unwrap_or(f64::NAN).sqrt() * to_f)
        .collect();
    let tl = derived.column("toe_l")?.f64()?.clone();
    let tr = derived.column("toe_r")?.f64()?.clone();
    r.toe_heights = tl
        .iter()
        .zip(tr.iter())
        .map(|(a, b)| a.unwrap_or(f64::NAN).min(b.unwrap_or(f64::NAN)))
        .collect();
    let bones: Vec<usize> = (1..NUM_JOINTS)
        .filter(|j| JOINT_PARENTS[*j].is_some())
        .collect();
    let per = per_take(derived, &bones)?;
    let f = |c: &str, i: usize| {
        per.column(c)
            .ok()
            .and_then(|c| c.get(i).ok())
            .and_then(|v| v.extract::<f64>())
            .unwrap_or(f64::NAN)
    };
    let takes = per.column("take")?.str()?.clone();
    let th = r.thresholds.clone();
    for i in 0..per.height() {
        let bone_cv = bones
            .iter()
            .map(|j| f(&format!("b{j}_std"), i) / f(&format!("b{j}_mean"), i).max(1e-9))
            .fold(0.0, f64::max);
        let q = TakeQuality {
            take: takes.get(i).unwrap_or("?").to_string(),
            seconds: f("n", i) / fps,
            mean_speed: f("speed2_mean", i).sqrt() * to_f,
            max_speed: f("speed2_max", i).sqrt() * to_f,
            bone_cv,
            min_toe: f("toe_l_min", i).min(f("toe_r_min", i)),
            mean_toe: f("toe_low_mean", i),
            flags: Vec::new(),
        };
        let flags = flags(&q, &th);
        r.takes.push(TakeQuality { flags, ..q });
    }
    Ok(())
}

/// Per-frame columns derived with polars expressions: `take`, the squared
/// horizontal root speed (`speed2`, units per frame), the turning rate, both
/// toes' heights (`toe_l`, `toe_r`) and each bone's squared length
/// (`boneJ`: the local frame is rigid, so lengths are those of the global
/// pose).
fn derived_columns(frames: &LazyFrame) -> PolarsResult<DataFrame> {
    let names = feature_names();
    let joint_col = |j: usize, c: usize| names[1 + 3 * (j - 1) + c].clone();
    let pos = |j: usize, c: usize| -> Expr {
        if j == 0 {
            if c == 1 {
                col("root_y").cast(DataType::Float64)
            } else {
                lit(0.0)
            }
        } else {
            col(joint_col(j, c).as_str()).cast(DataType::Float64)
        }
    };
    let mut exprs = vec![
        col("take"),
        (col(names[VEL_X].as_str()).cast(DataType::Float64).pow(2)
            + col(names[VEL_Z].as_str()).cast(DataType::Float64).pow(2))
        .alias("speed2"),
        col(names[ANG_VEL_Y].as_str()),
    ];
    let toe_l = JOINT_NAMES
        .iter()
        .position(|n| *n == "LeftToeBase")
        .unwrap_or(4);
    let toe_r = JOINT_NAMES
        .iter()
        .position(|n| *n == "RightToeBase")
        .unwrap_or(8);
    exprs.push(pos(toe_l, 1).alias("toe_l"));
    exprs.push(pos(toe_r, 1).alias("toe_r"));
    for (j, parent) in JOINT_PARENTS.iter().enumerate() {
        if let Some(p) = *parent {
            let d2 = (0..3)
                .map(|c| (pos(j, c) - pos(p, c)).pow(2))
                .reduce(|a, b| a + b)
                .unwrap_or(lit(0.0));
            exprs.push(d2.alias(format!("bone{j}")));
        }
    }
    frames.clone().select(exprs).collect()
}

/// Aggregates per take with polars, sorted by take: frames (`n`), mean and
/// largest squared speed, lowest height of each toe, mean and std of each
/// of `bones`' lengths (`bJ_mean`, `bJ_std`), mean height of the lower toe.
fn per_take(derived: DataFrame, bones: &[usize]) -> PolarsResult<DataFrame> {
    let mut aggs = vec![
        len().alias("n"),
        col("speed2").mean().alias("speed2_mean"),
        col("speed2").max().alias("speed2_max"),
        col("toe_l").min().alias("toe_l_min"),
        col("toe_r").min().alias("toe_r_min"),
    ];
    for j in bones {
        let b = col(format!("bone{j}").as_str()).sqrt();
        aggs.push(b.clone().mean().alias(format!("b{j}_mean")));
        aggs.push(b.std(0).alias(format!("b{j}_std")));
    }
    let mut with_lower = derived.lazy().with_column(
        when(col("toe_l").lt(col("toe_r")))
            .then(col("toe_l"))
            .otherwise(col("toe_r"))
            .alias("toe_low"),
    );
    aggs.push(col("toe_low").mean().alias("toe_low_mean"));
    with_lower = with_lower
        .group_by([col("take")])
        .agg(aggs)
        .sort(["take"], Default::default());
    with_lower.collect()
}

/// What looks wrong with a take, by the thresholds.
fn flags(q: &TakeQuality, th: &Thresholds) -> Vec<String> {
    let mut flags = Vec::new();
    if q.mean_speed > th.mean_speed {
        flags.push(format!(
            "root speed {:.1} m/s on average: a wrong (too low) frame rate?",
            q.mean_speed
        ));
    }
    if q.max_speed > th.max_speed {
        flags.push(format!(
            "root jumps: {:.1} m/s at its fastest frame",
            q.max_speed
        ));
    }
    if q.bone_cv > th.bone_cv {
        flags.push(format!("bone lengths change by {:.1}%", 100.0 * q.bone_cv));
    }
    if q.min_toe > th.min_toe {
        flags.push(format!(
            "never touches the floor: lowest toe {:.1} units up",
            q.min_toe
        ));
    }
    if q.min_toe < th.sink_toe {
        flags.push(format!(
            "stands below its first frame's floor: lowest toe {:.1} units down \
             (the take starts raised, or the ground is uneven)",
            -q.min_toe
        ));
    }
    flags
}
