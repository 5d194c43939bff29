//! Unit tests of the dataset stage: windows, splits, streaming moments.

use super::read::Moments;
use super::*;
use crate::features::NUM_FEATURES;

#[test]
fn windows_cover_whole_windows_only() {
    assert_eq!(window_starts(127, 128, 64), Vec::<usize>::new());
    assert_eq!(window_starts(128, 128, 64), vec![0]);
    assert_eq!(window_starts(320, 128, 64), vec![0, 64, 128, 192]);
}

#[test]
fn split_is_stable_and_roughly_proportional() {
    let f = [0.8, 0.1, 0.1];
    assert_eq!(split_of("02_01", 7, f), split_of("02_01", 7, f));
    let mut counts = [0; 3];
    for i in 0..10_000 {
        counts[split_of(&format!("{:02}_{:02}", i / 100, i % 100), 0, f)] += 1;
    }
    assert!((7700..8300).contains(&counts[0]), "{counts:?}");
    assert!((800..1200).contains(&counts[1]), "{counts:?}");
    let all_train = [1.0, 0.0, 0.0];
    assert_eq!(split_of("x", 1, all_train), 0);
}

#[test]
fn moments_match_two_pass_statistics() {
    let mut m = Moments::new();
    let xs = [1.0, 2.0, 4.0, 7.0];
    let ws = [1.0, 2.0, 0.0, 1.0];
    for (x, w) in xs.iter().zip(ws) {
        m.add(&[*x; NUM_FEATURES], w);
    }
    // Weighted: values 1, 2, 2, 7 → mean 3, variance (4+1+1+16)/4 = 5.5.
    assert!((m.mean[0] - 3.0).abs() < 1e-12);
    assert!((m.m2[0] / m.n - 5.5).abs() < 1e-12);
}
