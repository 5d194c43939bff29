//! Tests of paths, the follower and the measures, against hand-computed
//! values.

use crate::follow::LEAD_M;
use crate::path::PathError;
use crate::stick::{LEAD_M as STICK_LEAD_M, SETTLE_FRAMES};
use crate::*;

fn near(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

fn near2(a: [f64; 2], b: [f64; 2]) -> bool {
    near(a[0], b[0]) && near(a[1], b[1])
}

#[test]
fn built_in_paths_have_their_shapes() {
    let line = parse_path("line:10", 1.25).unwrap();
    assert_eq!(line.length(), 10.0);
    assert_eq!(line.asked_seconds(), 8.0);
    assert_eq!(line.point_at(3.0), [0.0, 3.0]);
    assert_eq!(line.point_at(12.0), [0.0, 10.0]);
    assert_eq!(line.tangent_at(3.0), [0.0, 1.0]);

    let circle = parse_path("circle:2", 1.0).unwrap();
    let n = circle.points().len() - 1;
    assert_eq!(n, 64);
    assert_eq!(circle.points()[0], [0.0, 0.0]);
    assert!(near2(circle.points()[n], [0.0, 0.0]));
    // A quarter round, turning left from +z: 2 m left, 2 m ahead.
    assert!(near2(circle.points()[16], [-2.0, 2.0]));
    let perimeter = 2.0 * 64.0 * 2.0 * (std::f64::consts::PI / 64.0).sin();
    assert!(near(circle.length(), perimeter));
    assert!(near2(
        circle.tangent_at(0.0),
        [
            -(std::f64::consts::PI / 64.0).sin(),
            (std::f64::consts::PI / 64.0).cos()
        ]
    ));

    let zig = parse_path("zigzag:2", 1.0).unwrap();
    assert_eq!(
        zig.points(),
        [[0.0, 0.0], [0.0, 2.5], [-2.5, 2.5], [-2.5, 5.0]]
    );
    assert_eq!(zig.length(), 7.5);

    let sg = parse_path("stop-go", 1.0).unwrap();
    assert_eq!(sg.points(), [[0.0, 0.0], [0.0, 5.0], [0.0, 10.0]]);
    assert_eq!(sg.waits(), [(1, 3.0)]);
    assert_eq!(sg.asked_seconds(), 13.0);
}

#[test]
fn projection_moves_forward_within_its_window() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("l.csv");
    std::fs::write(&f, "0,0\n0,4\n4,4\n").unwrap();
    let l = parse_path(f.to_str().unwrap(), 1.0).unwrap();
    // (1, 3.5): 1 m from the first leg at s = 3.5, 0.5 m from the second at
    // s = 4 + 1 = 5.
    assert_eq!(l.project([1.0, 3.5], 0.0, 1.5), 1.5);
    assert_eq!(l.project([1.0, 3.5], 3.0, 3.0), 5.0);
    assert_eq!(l.project([1.0, 3.5], 3.0, 1.5), 4.5);
    assert_eq!(l.project([1.0, 3.5], 4.5, 1.5), 5.0);
    assert_eq!(l.distance([1.0, 3.5]), 0.5);
    assert_eq!(l.distance([6.0, 7.0]), 13f64.sqrt());
    // A closed circle: the start does not project onto the end.
    let c = parse_path("circle:2", 1.0).unwrap();
    assert_eq!(c.project([0.0, 0.0], 0.0, 1.5), 0.0);
    assert!(near(
        c.project([0.0, 0.0], c.length() - 1.0, 1.5),
        c.length()
    ));
}

#[test]
fn csv_paths_read_headers_comments_and_speeds() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("p.csv");
    std::fs::write(&f, "# my path\nx,z,speed\n\n0,0\n0, 2, 0.5\n2,2\n").unwrap();
    let p = parse_path(f.to_str().unwrap(), 1.0).unwrap();
    assert_eq!(p.points(), [[0.0, 0.0], [0.0, 2.0], [2.0, 2.0]]);
    assert_eq!(p.speeds(), [0.5, 1.0]);
    assert_eq!(p.asked_seconds(), 6.0);
}

fn err(spec: &str, speed: f64) -> String {
    parse_path(spec, speed).unwrap_err().to_string()
}

#[test]
fn each_mistake_says_what_to_do() {
    let dir = tempfile::tempdir().unwrap();
    let file = |name: &str, text: &str| {
        let f = dir.path().join(name);
        std::fs::write(&f, text).unwrap();
        f.to_str().unwrap().to_string()
    };
    let missing = dir.path().join("none.csv");
    let e = err(missing.to_str().unwrap(), 1.0);
    assert!(
        e.starts_with(&format!("cannot read path file {}", missing.display())),
        "{e}"
    );
    assert!(e.contains("line:L"), "{e}");

    let bad = file("bad.csv", "0,0\n1;2\n");
    assert_eq!(
        err(&bad, 1.0),
        format!("{bad}:2: expected \"x,z\" or \"x,z,speed\" in metres and m/s, got \"1;2\"")
    );
    // A header is only skipped as the first line; NaN is not a coordinate.
    let late = file("late.csv", "0,0\nx,z\n");
    assert!(matches!(
        parse_path(&late, 1.0),
        Err(PathError::Line { line: 2, .. })
    ));
    let nan = file("nan.csv", "0,0\nnan,1\n");
    assert!(matches!(
        parse_path(&nan, 1.0),
        Err(PathError::Line { line: 2, .. })
    ));

    let one = file("one.csv", "x,z\n0,0\n");
    assert!(err(&one, 1.0).contains("has 1 point(s); give at least two"));
    let rep = file("rep.csv", "0,0\n1,1\n1,1\n");
    assert!(err(&rep, 1.0).contains("points 1 and 2 are both (1, 1); remove the repeated one"));
    let slow = file("slow.csv", "0,0\n1,1,0\n");
    assert!(err(&slow, 1.0).contains("speed 0 m/s is not a positive number"));
    assert!(err("line:3", -1.0).contains("speed -1 m/s"));
    assert!(err("line:3", f64::NAN).contains("speed NaN m/s"));

    for spec in ["line:abc", "circle:-1", "zigzag:1.5", "line:0", "spiral:3"] {
        let e = parse_path(spec, 1.0).unwrap_err();
        assert!(matches!(e, PathError::UnknownBuiltin { .. }), "{spec}: {e}");
        assert!(e
            .to_string()
            .starts_with(&format!("unknown path \"{spec}\"")));
    }

    let p = parse_path("line:3", 2.5).unwrap();
    assert!(p.check_speed(2.5).is_ok());
    assert_eq!(
        p.check_speed(2.0).unwrap_err().to_string(),
        "speed 2.5 m/s is above the fastest the data holds (2.00 m/s, its fastest training window); ask at most 2.00"
    );
}

/// A character at `pos` facing `forward` (right is forward turned 90°
/// clockwise).
fn at(pos: [f64; 2], forward: [f64; 2]) -> Frame2 {
    Frame2 {
        pos,
        right: [forward[1], -forward[0]],
        forward,
    }
}

fn targets(row: &[f32; CONTROL]) -> Vec<[f32; 4]> {
    assert_eq!(row[12], 1.0);
    (0..3)
        .map(|i| [row[4 * i], row[4 * i + 1], row[4 * i + 2], row[4 * i + 3]])
        .collect()
}

#[test]
fn a_character_on_a_line_is_led_ahead() {
    let mut f = Follower::new(parse_path("line:10", 1.2).unwrap());
    let ahead = |d: f64| [0.0, d as f32, 0.0, 1.0];
    let row = f.control(&at([0.0, 1.0], [0.0, 1.0]));
    assert_eq!(f.progress(), 1.0);
    assert_eq!(targets(&row), [ahead(0.4), ahead(0.8), ahead(1.2)]);
    // Facing +x, the line is on the character's left.
    let row = f.control(&at([0.0, 2.0], [1.0, 0.0]));
    let left = |d: f64| [-d as f32, 0.0, -1.0, 0.0];
    assert_eq!(targets(&row), [left(0.4), left(0.8), left(1.2)]);
    // Near the end the targets stop there.
    let mut s = 2.0;
    while s < 9.9 {
        s = (s + 1.0f64).min(9.9);
        f.control(&at([0.0, s], [0.0, 1.0]));
    }
    let row = f.control(&at([0.0, 9.9], [0.0, 1.0]));
    let t = targets(&row);
    assert!((t[0][1] - 0.1).abs() < 1e-6 && t[0] == t[2], "{t:?}");
    assert!(!f.done());
    f.control(&at([0.3, 9.96], [0.0, 1.0]));
    assert!(f.done());
}

#[test]
fn a_wait_holds_the_targets_then_releases_them() {
    let mut f = Follower::new(parse_path("stop-go", 1.0).unwrap());
    for z in [0.0, 1.5, 3.0, 4.5] {
        f.control(&at([0.0, z], [0.0, 1.0]));
    }
    // 0.3 m before the stop (not yet reached): every target is on it.
    let row = f.control(&at([0.0, 4.7], [0.0, 1.0]));
    let stop = [0.0, 0.3f32, 0.0, 1.0];
    assert_eq!(targets(&row), [stop; 3]);
    // 0.2 m before it the wait starts: held 3 s = 90 frames.
    let here = at([0.0, 4.8], [0.0, 1.0]);
    for call in 0..90 {
        let row = f.control(&here);
        assert_eq!(targets(&row), [[0.0, 0.2, 0.0, 1.0]; 3], "call {call}");
        assert!(!f.done());
    }
    // Released: progress moves on to the stop, the targets ahead of it
    // (asked faster by the schedule's one frame at 1 m/s, due since).
    let row = f.control(&here);
    let t = targets(&row);
    let due = 1.0 / 30.0;
    for (i, d) in [1.0 / 3.0, 2.0 / 3.0, 1.0].iter().enumerate() {
        let d = 0.2 + (1.0 + due) * d;
        assert!((t[i][1] as f64 - d).abs() < 1e-6, "{t:?}");
    }
    assert_eq!(f.progress(), 5.0);
}

/// A root that stands still behind the path's schedule is asked to catch
/// up: the speed asked rises by the distance it is behind, per second, at
/// most `LEAD_M`; the targets stay evenly spaced.
#[test]
fn a_root_behind_the_schedule_is_asked_to_catch_up() {
    let mut f = Follower::new(parse_path("line:10", 1.5).unwrap());
    let still = at([0.0, 0.0], [0.0, 1.0]);
    // After 6 calls at 1.5 m/s, 0.3 m is due: 1.8 m/s, targets 0.6, 1.2, 1.8.
    for _ in 0..5 {
        f.control(&still);
    }
    let t = targets(&f.control(&still));
    for (i, want) in [0.6, 1.2, 1.8].into_iter().enumerate() {
        assert!((t[i][1] - want).abs() < 1e-6, "{t:?}");
    }
    // Far behind, the rise stops at LEAD_M.
    for _ in 0..60 {
        f.control(&still);
    }
    let t = targets(&f.control(&still));
    assert!((t[2][1] as f64 - (LEAD_M + 1.5)).abs() < 1e-6, "{t:?}");
}

#[test]
fn path_error_is_the_mean_distance() {
    let p = parse_path("line:10", 1.0).unwrap();
    let e = path_error(&p, &[[1.0, 0.0], [0.0, 5.0], [-2.0, 12.0]]);
    assert!(near(e, (1.0 + 2.0 * 2f64.sqrt()) / 3.0));
    assert!(path_error(&p, &[]).is_nan());
}

#[test]
fn reaching_counts_only_past_most_of_the_path() {
    let p = parse_path("line:10", 1.0).unwrap();
    let roots: Vec<[f64; 2]> = (0..=120).map(|t| [0.0, 0.1 * t as f64]).collect();
    // Within 0.25 m of (0, 10) first at z = 9.8, frame 98.
    assert_eq!(reach_seconds(&p, &roots, 0.25), Some(98.0 / FPS));
    assert_eq!(reach_seconds(&p, &roots[..90], 0.25), None);
    // A circle starts at its end: only the return counts.
    let c = parse_path("circle:2", 1.0).unwrap();
    let round = c.points().to_vec();
    assert_eq!(reach_seconds(&c, &round, 0.1), Some(64.0 / FPS));
    assert_eq!(reach_seconds(&c, &round[..40], 0.1), None);
}

#[test]
fn turning_time_counts_from_the_asked_frame() {
    // Turning right 3° a frame from +z.
    let fwd: Vec<[f64; 2]> = (0..60)
        .map(|t| {
            let a = (3.0 * t as f64).to_radians();
            [a.sin(), a.cos()]
        })
        .collect();
    // Within 4.5° of +x from 85.5°: frame 29.
    assert_eq!(turn_seconds(&fwd, 5, [1.0, 0.0], 4.5), Some(24.0 / FPS));
    assert_eq!(turn_seconds(&fwd, 5, [0.0, 1.0], 1.0), None);
    assert_eq!(turn_seconds(&fwd, 0, [0.0, 1.0], 1.0), Some(0.0));
    assert_eq!(turn_seconds(&fwd, 5, [-1.0, 0.0], 10.0), None);
    assert_eq!(turn_seconds(&fwd, 99, [1.0, 0.0], 10.0), None);
}

#[test]
fn heading_is_positive_to_the_right() {
    assert!((heading_deg([0.0, 1.0], [1.0, 0.0]) - 90.0).abs() < 1e-12);
    assert!((heading_deg([0.0, 1.0], [-1.0, 0.0]) + 90.0).abs() < 1e-12);
    assert!((heading_deg([0.0, 1.0], [0.0, -2.0]) - 180.0).abs() < 1e-12);
    assert!((heading_deg([1.0, 1.0], [0.0, 3.0]) + 45.0).abs() < 1e-12);
    assert!(heading_deg([0.0, 0.0], [1.0, 0.0]).is_nan());
    assert_eq!(CONTROL, 13);
}

#[test]
fn local_coordinates_of_a_turned_frame() {
    // Facing +x (turned right): a point 2 m along +x is 2 m ahead, one at
    // -z is to its right.
    let f = Frame2 {
        pos: [1.0, 1.0],
        right: [0.0, -1.0],
        forward: [1.0, 0.0],
    };
    assert_eq!(f.local_point([3.0, 1.0]), [0.0, 2.0]);
    assert_eq!(f.local_point([1.0, 0.0]), [1.0, 0.0]);
}

#[test]
fn the_stick_turns_walks_runs_and_stops_as_the_keys_say() {
    let at = Frame2::START;
    let mut s = Stick::new(&at, 0.6, 1.5);
    // Walking straight ahead: targets 10/20/30 frames on at 0.6 m/s.
    let r = s.control(&at, Keys::default());
    for (i, k) in [10.0, 20.0, 30.0].iter().enumerate() {
        assert!(near(r[4 * i] as f64, 0.0));
        assert!((r[4 * i + 1] as f64 - 0.6 * k / 30.0).abs() < 1e-6);
        assert_eq!([r[4 * i + 2], r[4 * i + 3]], [0.0, 1.0]);
    }
    assert_eq!(r[CONTROL - 1], 1.0);
    // Right held for a second: the heading has turned 90° to +x.
    let right = Keys {
        turn: 1.0,
        ..Keys::default()
    };
    for _ in 0..30 {
        s.control(&at, right);
    }
    assert!(near2(s.heading(), [1.0, 0.0]));
    // The root has not moved for 31 frames: it is led the most, LEAD_M.
    let r = s.control(&at, Keys::default());
    assert!((r[8] as f64 - STICK_LEAD_M - 0.6).abs() < 1e-6 && (r[9] as f64).abs() < 1e-6);
    assert!((heading_deg([0.0, 1.0], s.heading()) - 90.0).abs() < 1e-6);
    // Run while held; stop stands (targets on the root, facing the
    // character's own way, not the heading asked before) until go.
    s.control(
        &at,
        Keys {
            run: true,
            ..Keys::default()
        },
    );
    assert_eq!(s.speed(), 1.5);
    let r = s.control(
        &at,
        Keys {
            stop: true,
            ..Keys::default()
        },
    );
    assert_eq!(s.speed(), 0.0);
    assert!(r[..2].iter().chain(&r[4..6]).all(|v| v.abs() < 1e-9));
    assert!(near2(s.heading(), at.forward));
    assert_eq!([r[2], r[3]], [0.0, 1.0]);
    s.control(&at, Keys::default());
    assert_eq!(s.speed(), 0.0, "stopped until go");
    // Settled (SETTLE_FRAMES stopped), the targets stay where the root
    // was: one that drifted 0.3 m right is asked back.
    for _ in 2..SETTLE_FRAMES {
        s.control(&at, Keys::default());
    }
    let drifted = Frame2 {
        pos: [0.3, 0.0],
        ..at
    };
    let r = s.control(&drifted, Keys::default());
    for i in 0..3 {
        assert!((r[4 * i] as f64 + 0.3).abs() < 1e-6 && (r[4 * i + 1] as f64).abs() < 1e-6);
    }
    let r = s.control(
        &drifted,
        Keys {
            go: true,
            ..Keys::default()
        },
    );
    assert_eq!(s.speed(), 0.6);
    assert!(near(r[0] as f64, 0.0), "going lets the settled place go");
}
