//! Asked paths: a polyline in the start frame (metres) with a speed per
//! segment (m/s) and waits at some points; built-ins (`line:L`, `circle:R`,
//! `zigzag:N`, `stop-go`) and CSV files of `x,z[,speed]` lines.

use crate::{dist, dot};
use std::path::PathBuf;

/// Legs of the `zigzag:N` built-in, metres.
pub const ZIGZAG_LEG_M: f64 = 2.5;

/// Why a path could not be read or is not usable.
#[derive(Debug, thiserror::Error)]
pub enum PathError {
    /// The CSV file could not be read.
    #[error("cannot read path file {}: {cause}; give a CSV file of \"x,z\" lines or a built-in path (line:L, circle:R, zigzag:N, stop-go)", file.display())]
    Read {
        /// The file.
        file: PathBuf,
        /// The cause.
        cause: std::io::Error,
    },
    /// A CSV line is not `x,z` or `x,z,speed`.
    #[error("{}:{line}: expected \"x,z\" or \"x,z,speed\" in metres and m/s, got \"{text}\"", file.display())]
    Line {
        /// The file.
        file: PathBuf,
        /// Line number, from 1.
        line: usize,
        /// The line.
        text: String,
    },
    /// Fewer than two points.
    #[error("path {what} has {count} point(s); give at least two")]
    TooFewPoints {
        /// The path (file or built-in).
        what: String,
        /// How many points it has.
        count: usize,
    },
    /// Two consecutive points are the same.
    #[error("path {what}: points {index} and {} are both ({x}, {z}); remove the repeated one", index + 1)]
    RepeatedPoint {
        /// The path (file or built-in).
        what: String,
        /// Index of the first of the two points, from 0.
        index: usize,
        /// Its x, metres.
        x: f64,
        /// Its z, metres.
        z: f64,
    },
    /// A speed is not a positive finite number.
    #[error("path {what}: speed {speed} m/s is not a positive number; give a speed above 0")]
    BadSpeed {
        /// The path (file or built-in).
        what: String,
        /// The speed.
        speed: f64,
    },
    /// A `name:argument` that is not one of the built-ins.
    #[error("unknown path \"{spec}\": the built-ins are line:L (metres > 0), circle:R (radius in metres > 0), zigzag:N (N ≥ 0 turns) and stop-go; anything else is read as a CSV file")]
    UnknownBuiltin {
        /// What was given.
        spec: String,
    },
    /// Points, speeds and waits that do not fit together (a caller's
    /// mistake, not a user's: built-ins and files never give them).
    #[error("path {what}: {message}")]
    Malformed {
        /// The path.
        what: String,
        /// What is wrong.
        message: String,
    },
    /// A speed faster than the training data holds.
    #[error(
        "speed {speed} m/s is above the fastest the data holds ({max:.2} m/s, its fastest training window); ask at most {max:.2}"
    )]
    TooFast {
        /// The fastest speed asked, m/s.
        speed: f64,
        /// The fastest the data holds, m/s.
        max: f64,
    },
}

/// A polyline to follow, in metres in the start frame, with the speed of each
/// segment (m/s) and waits (seconds standing at a point).
#[derive(Clone, Debug, PartialEq)]
pub struct Path {
    points: Vec<[f64; 2]>,
    speeds: Vec<f64>,
    waits: Vec<(usize, f64)>,
    /// Arc length at each point.
    cum: Vec<f64>,
}

impl Path {
    /// A path through `points` (at least two, no two consecutive equal, all
    /// finite) at `speeds[i]` m/s on segment i (one per segment, each > 0),
    /// standing `waits[j].1` seconds at point `waits[j].0`. `what` names it in
    /// errors.
    pub fn new(
        what: &str,
        points: Vec<[f64; 2]>,
        speeds: Vec<f64>,
        mut waits: Vec<(usize, f64)>,
    ) -> Result<Path, PathError> {
        let what = what.to_string();
        if points.len() < 2 {
            let count = points.len();
            return Err(PathError::TooFewPoints { what, count });
        }
        if let Some(index) = points.windows(2).position(|w| w[0] == w[1]) {
            let [x, z] = points[index];
            return Err(PathError::RepeatedPoint { what, index, x, z });
        }
        if let Some(&speed) = speeds.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return Err(PathError::BadSpeed { what, speed });
        }
        let message = if speeds.len() != points.len() - 1 {
            "give one speed per segment"
        } else if points.iter().flatten().any(|v| !v.is_finite()) {
            "a coordinate is not a finite number"
        } else if waits
            .iter()
            .any(|&(i, s)| i >= points.len() || !(s.is_finite() && s >= 0.0))
        {
            "a wait is at no point or is not a duration ≥ 0 s"
        } else {
            ""
        };
        if !message.is_empty() {
            let message = message.to_string();
            return Err(PathError::Malformed { what, message });
        }
        waits.sort_by_key(|w| w.0);
        let mut cum = vec![0.0];
        for w in points.windows(2) {
            cum.push(cum[cum.len() - 1] + dist(w[0], w[1]));
        }
        Ok(Path {
            points,
            speeds,
            waits,
            cum,
        })
    }

    /// The points, metres.
    pub fn points(&self) -> &[[f64; 2]] {
        &self.points
    }

    /// The speed of each segment, m/s.
    pub fn speeds(&self) -> &[f64] {
        &self.speeds
    }

    /// The waits: (point index, seconds), by point index.
    pub fn waits(&self) -> &[(usize, f64)] {
        &self.waits
    }

    /// Arc length of point `i`, metres (the length for an index past the end).
    pub fn arc_at_point(&self, i: usize) -> f64 {
        self.cum.get(i).copied().unwrap_or(self.length())
    }

    /// Total length, metres.
    pub fn length(&self) -> f64 {
        self.cum[self.cum.len() - 1]
    }

    /// Seconds the path asks for: each segment's length over its speed, plus
    /// the waits.
    pub fn asked_seconds(&self) -> f64 {
        let walk: f64 = (0..self.speeds.len())
            .map(|i| (self.cum[i + 1] - self.cum[i]) / self.speeds[i])
            .sum();
        walk + self.waits.iter().map(|w| w.1).sum::<f64>()
    }

    /// The segment holding arc length `s`: `i` with `cum[i] ≤ s < cum[i + 1]`, the
    /// last one from the end on, the first one before the start.
    pub fn segment_at(&self, s: f64) -> usize {
        let i = self.cum.partition_point(|&c| c <= s);
        i.clamp(1, self.speeds.len()) - 1
    }

    /// The point at arc length `s` (clamped to the path).
    pub fn point_at(&self, s: f64) -> [f64; 2] {
        let s = s.clamp(0.0, self.length());
        let i = self.segment_at(s);
        let (a, b) = (self.points[i], self.points[i + 1]);
        let u = (s - self.cum[i]) / (self.cum[i + 1] - self.cum[i]);
        [a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])]
    }

    /// The unit direction of segment `i`.
    pub fn segment_tangent(&self, i: usize) -> [f64; 2] {
        let i = i.min(self.speeds.len() - 1);
        let (a, b) = (self.points[i], self.points[i + 1]);
        let l = self.cum[i + 1] - self.cum[i];
        [(b[0] - a[0]) / l, (b[1] - a[1]) / l]
    }

    /// The unit tangent at arc length `s` (at a corner, the outgoing one; at
    /// the end, the last segment's).
    pub fn tangent_at(&self, s: f64) -> [f64; 2] {
        self.segment_tangent(self.segment_at(s))
    }

    /// The speed at arc length `s`, m/s (at a corner, the outgoing one).
    pub fn speed_at(&self, s: f64) -> f64 {
        self.speeds[self.segment_at(s)]
    }

    /// Arc length of the point closest to `p` among those with arc length in
    /// `[from_s, from_s + window_m]` (the first on ties), so progress never
    /// goes back and a path that crosses itself is followed in order.
    pub fn project(&self, p: [f64; 2], from_s: f64, window_m: f64) -> f64 {
        let lo = from_s.clamp(0.0, self.length());
        let hi = (lo + window_m.max(0.0)).min(self.length());
        let mut best = (f64::INFINITY, lo);
        for i in self.segment_at(lo)..self.speeds.len() {
            if self.cum[i] > hi {
                break;
            }
            let s = self.closest_on_segment(i, p).clamp(lo, hi);
            let d = dist(self.point_at(s), p);
            if d < best.0 {
                best = (d, s);
            }
        }
        best.1
    }

    /// Distance from `p` to the nearest point of the whole path, metres.
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        (0..self.speeds.len())
            .map(|i| dist(self.point_at(self.closest_on_segment(i, p)), p))
            .fold(f64::INFINITY, f64::min)
    }

    /// Arc length of the point of segment `i` closest to `p`.
    fn closest_on_segment(&self, i: usize, p: [f64; 2]) -> f64 {
        let a = self.points[i];
        let l = self.cum[i + 1] - self.cum[i];
        let u = dot([p[0] - a[0], p[1] - a[1]], self.segment_tangent(i));
        self.cum[i] + u.clamp(0.0, l)
    }

    /// Fails when any segment asks for more than `max` m/s.
    pub fn check_speed(&self, max: f64) -> Result<(), PathError> {
        let speed = self.speeds.iter().copied().fold(0.0, f64::max);
        if speed > max {
            return Err(PathError::TooFast { speed, max });
        }
        Ok(())
    }
}

/// The path `spec` asks for at `speed` m/s: a built-in (`line:L`, `circle:R`,
/// `zigzag:N`, `stop-go`, all from (0, 0) heading +z) or a CSV file of
/// `x,z` or `x,z,speed` lines (metres, m/s; a point's speed is that of the
/// segment leading to it, `speed` where missing). In the file, blank lines
/// and `#` comments are skipped, and so is a first line whose fields are not
/// numbers (a header).
pub fn parse_path(spec: &str, speed: f64) -> Result<Path, PathError> {
    if !(speed.is_finite() && speed > 0.0) {
        let what = spec.to_string();
        return Err(PathError::BadSpeed { what, speed });
    }
    if let Some(points) = builtin(spec)? {
        let speeds = vec![speed; points.len() - 1];
        let waits = if spec == "stop-go" {
            vec![(1, 3.0)]
        } else {
            vec![]
        };
        return Path::new(spec, points, speeds, waits);
    }
    let file = PathBuf::from(spec);
    let text = std::fs::read_to_string(&file).map_err(|cause| {
        if looks_builtin(spec) && cause.kind() == std::io::ErrorKind::NotFound {
            PathError::UnknownBuiltin { spec: spec.into() }
        } else {
            PathError::Read {
                file: file.clone(),
                cause,
            }
        }
    })?;
    let (points, speeds) = parse_csv(&file, &text, speed)?;
    Path::new(spec, points, speeds, vec![])
}

/// `name:argument` with a lower-case name: meant as a built-in.
fn looks_builtin(spec: &str) -> bool {
    spec.split_once(':').is_some_and(|(name, _)| {
        name.len() > 1 && name.chars().all(|c| c.is_ascii_lowercase() || c == '-')
    })
}

/// The points of a built-in path, `None` when `spec` names none.
fn builtin(spec: &str) -> Result<Option<Vec<[f64; 2]>>, PathError> {
    let bad = || PathError::UnknownBuiltin { spec: spec.into() };
    if spec == "stop-go" {
        return Ok(Some(vec![[0.0, 0.0], [0.0, 5.0], [0.0, 10.0]]));
    }
    let Some((name, arg)) = spec.split_once(':') else {
        return Ok(None);
    };
    let metres = || {
        arg.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0 && *v <= 1e6)
            .ok_or_else(bad)
    };
    let points = match name {
        "line" => vec![[0.0, 0.0], [0.0, metres()?]],
        "circle" => {
            let r = metres()?;
            // At least 64 sides, none longer than 0.25 m up to 4096 sides.
            let n = ((std::f64::consts::TAU * r / 0.25).ceil() as usize).clamp(64, 4096);
            (0..=n)
                .map(|i| {
                    let a = std::f64::consts::TAU * i as f64 / n as f64;
                    // Centre at (−r, 0): a left turn from facing +z.
                    [r * (a.cos() - 1.0), r * a.sin()]
                })
                .collect()
        }
        "zigzag" => {
            let n: usize = arg
                .trim()
                .parse()
                .ok()
                .filter(|&n| n <= 1000)
                .ok_or_else(bad)?;
            zigzag(n)
        }
        _ if looks_builtin(spec) && !std::path::Path::new(spec).exists() => return Err(bad()),
        _ => return Ok(None),
    };
    Ok(Some(points))
}

/// `n` right-angle turns alternating left and right (first left), `n + 1`
/// legs of [`ZIGZAG_LEG_M`].
fn zigzag(n: usize) -> Vec<[f64; 2]> {
    let mut p = [0.0, 0.0];
    let mut dir = [0.0, 1.0];
    let mut out = vec![p];
    for leg in 0..=n {
        p = [p[0] + ZIGZAG_LEG_M * dir[0], p[1] + ZIGZAG_LEG_M * dir[1]];
        out.push(p);
        // Left of (x, z) is (−z, x); right is (z, −x).
        dir = if leg % 2 == 0 {
            [-dir[1], dir[0]]
        } else {
            [dir[1], -dir[0]]
        };
    }
    out
}

type Points = (Vec<[f64; 2]>, Vec<f64>);

/// Points and segment speeds of a CSV path file's text.
fn parse_csv(file: &std::path::Path, text: &str, speed: f64) -> Result<Points, PathError> {
    let (mut points, mut speeds) = (Vec::new(), Vec::new());
    let mut first = true;
    for (n, raw) in text.lines().enumerate() {
        let line = raw.trim().trim_start_matches('\u{feff}');
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let nums: Vec<Option<f64>> = fields.iter().map(|f| f.parse::<f64>().ok()).collect();
        if std::mem::take(&mut first) && nums.iter().all(Option::is_none) {
            continue;
        }
        let values: Option<Vec<f64>> = nums.into_iter().collect();
        let (x, z, v) = match values.as_deref() {
            Some(&[x, z]) => (x, z, speed),
            Some(&[x, z, v]) => (x, z, v),
            _ => (f64::NAN, f64::NAN, speed),
        };
        if !(x.is_finite() && z.is_finite()) {
            return Err(PathError::Line {
                file: file.to_path_buf(),
                line: n + 1,
                text: raw.to_string(),
            });
        }
        if !(v.is_finite() && v > 0.0) {
            let what = format!("{}:{}", file.display(), n + 1);
            return Err(PathError::BadSpeed { what, speed: v });
        }
        if !points.is_empty() {
            speeds.push(v);
        }
        points.push([x, z]);
    }
    Ok((points, speeds))
}
