//! The root's track and the control signal of a recorded motion, from its
//! root-motion features `(vel_x, vel_z, ang_vel_y)` (`docs/features.md`,
//! "Root motion"): frame t+1's velocity is the translation from t to t+1
//! along frame t's axes, in dataset units per frame; its angle θ then turns
//! the axes, `ex' = cos θ·ex − sin θ·ez`, `ez' = sin θ·ex + cos θ·ez`
//! (positive θ turns right).

use crate::{Frame2, CONTROL, CONTROL_FRAMES, METRES_PER_UNIT};

/// The root's position (metres) and axes in the start frame at every frame,
/// integrating `root[t] = (vel_x, vel_z, ang_vel_y)` from frame 0 at the
/// origin facing +z (frame 0's values are ignored).
pub fn root_track(root: &[[f64; 3]]) -> Vec<Frame2> {
    let mut f = Frame2::START;
    let mut out = Vec::with_capacity(root.len());
    for (t, &r) in root.iter().enumerate() {
        if t > 0 {
            f = f.advanced(r);
        }
        out.push(f);
    }
    out
}

impl Frame2 {
    /// The root one frame later, moved by that frame's root motion
    /// `(vel_x, vel_z, ang_vel_y)`: the translation along these axes, then
    /// the axes turned (renormalised, so long motions keep unit axes).
    pub fn advanced(&self, [vx, vz, th]: [f64; 3]) -> Frame2 {
        let (ex, ez) = (self.right, self.forward);
        let mut pos = self.pos;
        for k in 0..2 {
            pos[k] += (ex[k] * vx + ez[k] * vz) * METRES_PER_UNIT;
        }
        let (s, c) = th.sin_cos();
        let nx = [c * ex[0] - s * ez[0], c * ex[1] - s * ez[1]];
        let nz = [s * ex[0] + c * ez[0], s * ex[1] + c * ez[1]];
        Frame2 {
            pos,
            right: unit(nx),
            forward: unit(nz),
        }
    }
}

fn unit(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]);
    if n > 0.0 {
        [v[0] / n, v[1] / n]
    } else {
        v
    }
}

/// The control row of every frame of a motion: for each offset k in
/// [`CONTROL_FRAMES`], the root's position and facing k frames ahead in frame
/// t's own axes, then the flag 1.0. Rows whose last offset runs past the
/// motion (t + 30 ≥ len) are all zeros (left free).
pub fn control_of_motion(root: &[[f64; 3]]) -> Vec<[f32; CONTROL]> {
    let track = root_track(root);
    let last = CONTROL_FRAMES[CONTROL_FRAMES.len() - 1];
    (0..track.len())
        .map(|t| {
            let mut row = [0f32; CONTROL];
            if t + last >= track.len() {
                return row;
            }
            let here = &track[t];
            for (i, &k) in CONTROL_FRAMES.iter().enumerate() {
                let there = &track[t + k];
                let p = here.local_point(there.pos);
                let d = here.local_dir(there.forward);
                row[4 * i..4 * i + 4].copy_from_slice(&[p[0], p[1], d[0], d[1]].map(|v| v as f32));
            }
            row[CONTROL - 1] = 1.0;
            row
        })
        .collect()
}

/// The root motion a control row asks for: the mean of each frame's
/// `(vel_x, vel_z, ang_vel_y)` (dataset units and radians a frame) over the
/// frames to its farthest target, were the root to walk there at a steady
/// speed and turn. The turn is the target's facing spread evenly over those
/// frames; the velocity is the chord to the target seen along the facing
/// halfway through the turn, lengthened to the arc it subtends. None for a
/// row left free.
pub fn asked_root_motion(row: &[f32; CONTROL]) -> Option<[f64; 3]> {
    if row[CONTROL - 1] == 0.0 {
        return None;
    }
    let i = 4 * (CONTROL_FRAMES.len() - 1);
    let frames = CONTROL_FRAMES[CONTROL_FRAMES.len() - 1] as f64;
    let [px, pz, fx, fz] = [row[i], row[i + 1], row[i + 2], row[i + 3]].map(f64::from);
    // Positive turns right: a facing turned by θ is (sin θ, cos θ) here.
    let turn = fx.atan2(fz);
    let half = turn / 2.0;
    let (s, c) = (-half).sin_cos();
    let arc = if half.abs() > 1e-9 {
        half / half.sin()
    } else {
        1.0
    };
    let scale = arc / (frames * METRES_PER_UNIT);
    Some([
        (c * px + s * pz) * scale,
        (c * pz - s * px) * scale,
        turn / frames,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Constant speed `v` (units per frame) straight ahead, turning `th`
    /// radians every frame.
    fn walk(v: f64, th: f64, n: usize) -> Vec<[f64; 3]> {
        vec![[0.0, v, th]; n]
    }

    #[test]
    fn a_straight_walk_goes_ahead() {
        let track = root_track(&walk(2.0, 0.0, 40));
        let m = 2.0 * METRES_PER_UNIT;
        assert!((track[39].pos[1] - 39.0 * m).abs() < 1e-12);
        assert_eq!(track[39].pos[0], 0.0);
        let rows = control_of_motion(&walk(2.0, 0.0, 40));
        assert_eq!(rows.len(), 40);
        let r = rows[3];
        for (i, k) in CONTROL_FRAMES.iter().enumerate() {
            let want = [0.0, (*k as f64 * m) as f32, 0.0, 1.0];
            assert_eq!(r[4 * i..4 * i + 4], want);
        }
        assert_eq!(r[12], 1.0);
    }

    #[test]
    fn rows_near_the_end_are_left_free() {
        let rows = control_of_motion(&walk(1.0, 0.1, 50));
        // 50 frames: rows 0..=19 given (t + 30 < 50), 20..50 free.
        assert!(rows[..20].iter().all(|r| r[12] == 1.0));
        assert!(rows[20..].iter().all(|r| r.iter().all(|&v| v == 0.0)));
        assert!(control_of_motion(&walk(1.0, 0.0, 30))
            .iter()
            .all(|r| r[12] == 0.0));
        assert!(control_of_motion(&[]).is_empty());
    }

    /// A circle at constant speed: the positions are the corners of a regular
    /// polygon with side v and exterior angle θ. After k frames the chord is
    /// 2R·sin(kθ/2), R = v / (2 sin(θ/2)), at (k−1)θ/2 to the right of the
    /// facing (the first side lies along the facing, half a corner before the
    /// circle's tangent), and the facing has turned kθ.
    #[test]
    fn a_circle_walk_has_chord_geometry() {
        for th in [0.05f64, -0.08] {
            let v = 1.5;
            let root = walk(v, th, 80);
            let rows = control_of_motion(&root);
            let radius = v * METRES_PER_UNIT / (2.0 * (th / 2.0).sin());
            let track = root_track(&root);
            for t in [0usize, 17, 49] {
                for (i, &k) in CONTROL_FRAMES.iter().enumerate() {
                    let k = k as f64;
                    let chord = 2.0 * radius * (k * th / 2.0).sin();
                    let bearing = (k - 1.0) * th / 2.0;
                    let want = [
                        chord * bearing.sin(),
                        chord * bearing.cos(),
                        (k * th).sin(),
                        (k * th).cos(),
                    ];
                    let here = &track[t];
                    let there = &track[t + k as usize];
                    let got_p = here.local_point(there.pos);
                    let got_d = here.local_dir(there.forward);
                    let got = [got_p[0], got_p[1], got_d[0], got_d[1]];
                    for j in 0..4 {
                        assert!(
                            (got[j] - want[j]).abs() < 1e-9,
                            "t {t} k {k}: {got:?} {want:?}"
                        );
                        assert!((rows[t][4 * i + j] as f64 - want[j]).abs() < 1e-6);
                    }
                }
            }
            // θ > 0 turns right: the walk bends towards +x.
            assert_eq!(rows[0][8] > 0.0, th > 0.0);
        }
    }

    /// A steady walk's rows ask for its own root motion: straight ahead,
    /// exactly; on a circle, the arc through the polygon's corners, within
    /// θ²/24 of its speed and half a corner to the side.
    #[test]
    fn a_row_asks_for_the_walk_it_was_read_from() {
        let rows = control_of_motion(&walk(2.0, 0.0, 40));
        let [vx, vz, th] = asked_root_motion(&rows[0]).unwrap();
        assert!(vx.abs() < 1e-6 && (vz - 2.0).abs() < 1e-5 && th == 0.0);
        for th in [0.05f64, -0.08] {
            let v = 1.5;
            let rows = control_of_motion(&walk(v, th, 80));
            let [ax, az, at] = asked_root_motion(&rows[5]).unwrap();
            assert!((at - th).abs() < 1e-6, "{at} {th}");
            assert!((az - v).abs() < v * th * th / 8.0 + 1e-5, "{az} {v}");
            assert!((ax + v * th / 2.0).abs() < 1e-3, "{ax}");
        }
        // Standing: the targets on the root, facing ahead.
        let mut stand = [0f32; CONTROL];
        for i in 0..CONTROL_FRAMES.len() {
            stand[4 * i + 3] = 1.0;
        }
        stand[CONTROL - 1] = 1.0;
        assert_eq!(asked_root_motion(&stand), Some([0.0, 0.0, 0.0]));
        assert_eq!(asked_root_motion(&[0.0; CONTROL]), None);
    }
}
