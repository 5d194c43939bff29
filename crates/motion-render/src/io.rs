//! The motions formats (`docs/metrics.md`): Parquet, one row per motion,
//! frame and joint (`motion`, `frame`, `joint`, `x`, `y`, `z`), and the
//! viewer's JSON. Both are written atomically; the Parquet is read back by
//! [`read_parquet`] (for `cargo xtask export`).

use crate::{Motion, RenderError, FPS};
use mocap_ingest::skeleton::{JOINT_NAMES, JOINT_PARENTS, NUM_JOINTS};
use polars::prelude::*;
use std::collections::HashMap;
use std::path::Path;

/// Write `NAME.parquet` and `NAME.json` into `dir`.
pub fn write_motions(dir: &Path, name: &str, motions: &[Motion]) -> Result<(), RenderError> {
    write_parquet(&dir.join(format!("{name}.parquet")), motions)?;
    crate::write_file(
        &dir.join(format!("{name}.json")),
        motions_json(motions).as_bytes(),
    )
}

/// Write motions as Parquet (`motion` str, `frame` u32, `joint` str, `x`,
/// `y`, `z` f32).
pub fn write_parquet(path: &Path, motions: &[Motion]) -> Result<(), RenderError> {
    let rows = motions.iter().map(|m| m.poses.len() * NUM_JOINTS).sum();
    let (mut id, mut frame, mut joint) = (
        Vec::with_capacity(rows),
        Vec::with_capacity(rows),
        Vec::with_capacity(rows),
    );
    let mut xyz = [(); 3].map(|()| Vec::with_capacity(rows));
    for m in motions {
        for (f, pose) in m.poses.iter().enumerate() {
            for (j, p) in pose.iter().enumerate() {
                id.push(m.id.as_str());
                frame.push(f as u32);
                joint.push(JOINT_NAMES[j]);
                for (c, v) in xyz.iter_mut().zip(p) {
                    c.push(*v as f32);
                }
            }
        }
    }
    let [x, y, z] = xyz;
    let polars_err = |e: PolarsError| RenderError::Format {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let mut df = DataFrame::new_infer_height(vec![
        Column::from(Series::new("motion".into(), id)),
        Column::from(Series::new("frame".into(), frame)),
        Column::from(Series::new("joint".into(), joint)),
        Column::from(Series::new("x".into(), x)),
        Column::from(Series::new("y".into(), y)),
        Column::from(Series::new("z".into(), z)),
    ])
    .map_err(polars_err)?;
    crate::write_atomically(path, |w| {
        ParquetWriter::new(w)
            .finish(&mut df)
            .map(|_| ())
            .map_err(polars_err)
    })
}

/// `{"fps", "units", "joints", "parents", "motions": [{"id", "frames":
/// [[x, y, z] × joints] × frames}]}`, positions rounded to 0.001 unit.
pub fn motions_json(motions: &[Motion]) -> String {
    let names: Vec<String> = JOINT_NAMES.iter().map(|n| format!("\"{n}\"")).collect();
    let parents: Vec<String> = JOINT_PARENTS
        .iter()
        .map(|p| p.map_or(-1, |v| v as i64).to_string())
        .collect();
    let mut s = format!(
        "{{\"fps\":{FPS},\"units\":\"CMU units (x{} = metres), y up, floor at y = 0\",\"joints\":[{}],\"parents\":[{}],\"motions\":[",
        crate::METRES_PER_UNIT,
        names.join(","),
        parents.join(",")
    );
    for (k, m) in motions.iter().enumerate() {
        if k > 0 {
            s += ",";
        }
        s += &format!(
            "{{\"id\":{},\"frames\":[",
            serde_json::Value::from(m.id.as_str())
        );
        for (f, pose) in m.poses.iter().enumerate() {
            if f > 0 {
                s += ",";
            }
            let joints: Vec<String> = pose
                .iter()
                .map(|p| format!("[{:.3},{:.3},{:.3}]", p[0], p[1], p[2]))
                .collect();
            s += "[";
            s += &joints.join(",");
            s += "]";
        }
        s += "]}";
    }
    s += "]}";
    s
}

/// Read a motions Parquet written by [`write_parquet`] (any row order):
/// motions in order of first appearance, every frame `0..n` of each with all
/// 19 joints exactly once.
pub fn read_parquet(path: &Path) -> Result<Vec<Motion>, RenderError> {
    let fail = |message: String| RenderError::Format {
        path: path.to_path_buf(),
        message,
    };
    let pe = |e: PolarsError| fail(e.to_string());
    let file = std::fs::File::open(path).map_err(|cause| RenderError::Io {
        path: path.to_path_buf(),
        cause,
    })?;
    let df = ParquetReader::new(file).finish().map_err(pe)?;
    let col = |name: &str| {
        df.column(name).map_err(|_| {
            fail(format!(
                "no `{name}` column (expected motion, frame, joint, x, y, z)"
            ))
        })
    };
    let ids = col("motion")?.str().map_err(pe)?.clone();
    let frames = col("frame")?.cast(&DataType::UInt32).map_err(pe)?;
    let frames = frames.u32().map_err(pe)?.clone();
    let joints = col("joint")?.str().map_err(pe)?.clone();
    let mut xyz = Vec::new();
    for c in ["x", "y", "z"] {
        let v = col(c)?.cast(&DataType::Float64).map_err(pe)?;
        xyz.push(v.f64().map_err(pe)?.clone());
    }
    let joint_index: HashMap<&str, usize> = JOINT_NAMES
        .iter()
        .enumerate()
        .map(|(k, n)| (*n, k))
        .collect();
    let mut order: Vec<String> = Vec::new();
    let mut by_id: HashMap<String, Vec<Option<[f64; 3]>>> = HashMap::new();
    for r in 0..df.height() {
        let (Some(id), Some(f), Some(jn)) = (ids.get(r), frames.get(r), joints.get(r)) else {
            return Err(fail(format!("row {r}: missing motion, frame or joint")));
        };
        let j = *joint_index
            .get(jn)
            .ok_or_else(|| fail(format!("row {r}: unknown joint {jn:?}")))?;
        let p = [0, 1, 2].map(|c| xyz[c].get(r).unwrap_or(f64::NAN));
        if p.iter().any(|v| !v.is_finite()) {
            return Err(fail(format!(
                "row {r}: motion {id} frame {f} joint {jn}: missing or non-finite position"
            )));
        }
        let slots = by_id.entry(id.to_string()).or_insert_with(|| {
            order.push(id.to_string());
            Vec::new()
        });
        let k = f as usize * NUM_JOINTS + j;
        if k >= slots.len() {
            // Frames may be sparse only until proven otherwise; never trust
            // a huge frame number for memory.
            if f as usize > df.height() {
                return Err(fail(format!(
                    "row {r}: frame {f} of motion {id} is beyond the rows"
                )));
            }
            slots.resize(k + 1, None);
        }
        if slots[k].replace(p).is_some() {
            return Err(fail(format!(
                "motion {id} frame {f} joint {jn} appears twice"
            )));
        }
    }
    order
        .into_iter()
        .map(|id| {
            let mut slots = by_id.remove(&id).unwrap_or_default();
            slots.resize(slots.len().div_ceil(NUM_JOINTS) * NUM_JOINTS, None);
            let poses = slots
                .chunks(NUM_JOINTS)
                .enumerate()
                .map(|(f, c)| {
                    let mut pose = [[0.0; 3]; NUM_JOINTS];
                    for (j, v) in c.iter().enumerate() {
                        pose[j] = v.ok_or_else(|| {
                            fail(format!("motion {id}: frame {f} has no {}", JOINT_NAMES[j]))
                        })?;
                    }
                    Ok(pose)
                })
                .collect::<Result<Vec<_>, RenderError>>()?;
            Ok(Motion { id, poses })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn motion(id: &str, frames: usize) -> Motion {
        Motion {
            id: id.into(),
            poses: (0..frames)
                .map(|f| {
                    let mut p = [[0.0; 3]; NUM_JOINTS];
                    for (j, v) in p.iter_mut().enumerate() {
                        *v = [j as f64, f as f64, 0.5];
                    }
                    p
                })
                .collect(),
        }
    }

    #[test]
    fn motions_json_layout() {
        let m = Motion {
            id: "sample_000".into(),
            poses: vec![[[1.0, 2.0, 3.0]; NUM_JOINTS]; 2],
        };
        let v: serde_json::Value = serde_json::from_str(&motions_json(&[m])).unwrap();
        assert_eq!(v["fps"], 30.0);
        assert_eq!(v["joints"].as_array().unwrap().len(), NUM_JOINTS);
        assert_eq!(v["parents"][0], -1);
        assert_eq!(v["motions"][0]["frames"].as_array().unwrap().len(), 2);
        assert_eq!(
            v["motions"][0]["frames"][1][18],
            serde_json::json!([1.0, 2.0, 3.0])
        );
    }

    #[test]
    fn parquet_round_trip_and_bad_files() {
        let tmp = tempfile::tempdir().unwrap();
        let ms = vec![motion("b", 3), motion("a", 2)];
        write_motions(tmp.path(), "m", &ms).unwrap();
        assert_eq!(read_parquet(&tmp.path().join("m.parquet")).unwrap(), ms);

        // A motion with a frame missing a joint is an error naming it.
        let mut df = ParquetReader::new(std::fs::File::open(tmp.path().join("m.parquet")).unwrap())
            .finish()
            .unwrap();
        df = df.slice(0, 3 * NUM_JOINTS - 1);
        let bad = tmp.path().join("bad.parquet");
        ParquetWriter::new(std::fs::File::create(&bad).unwrap())
            .finish(&mut df)
            .unwrap();
        let e = read_parquet(&bad).unwrap_err().to_string();
        assert!(
            e.contains("bad.parquet") && e.contains("frame 2 has no RightHand"),
            "{e}"
        );
        let e = read_parquet(&tmp.path().join("none.parquet")).unwrap_err();
        assert!(e.to_string().contains("none.parquet"));
    }
}
