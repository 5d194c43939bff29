//! A training run killed with SIGKILL and resumed ends exactly where an
//! uninterrupted run with the same seed ends.

mod common;

use common::{six_takes, small_dataset, xtask};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

const EPOCHS: &str = "15";

fn dataset(tmp: &Path) -> PathBuf {
    let ds = tmp.join("ds");
    small_dataset(&six_takes(tmp), &ds);
    ds
}

fn train_cmd(ds: &Path, out: &Path) -> Command {
    train_for(EPOCHS, ds, out)
}

fn train_for(epochs: &str, ds: &Path, out: &Path) -> Command {
    let mut c = train_budget(ds, out);
    c.args(["--epochs", epochs]);
    c
}

/// `train` as the other commands, the epochs left to the preset's budget.
fn train_budget(ds: &Path, out: &Path) -> Command {
    let mut c = xtask();
    c.args([
        "train",
        "--quiet",
        "--batch",
        "8",
        "--early-stopping",
        "0",
        "--seed",
        "11",
        "--data",
    ])
    .arg(ds)
    .arg("--out")
    .arg(out);
    c
}

/// `last/checkpoint.json` of `run` (None before its first checkpoint).
fn last_meta(run: &Path) -> Option<serde_json::Value> {
    std::fs::read_to_string(run.join("last/checkpoint.json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
}

fn epoch_of(run: &Path) -> usize {
    last_meta(run)
        .and_then(|v| v["epoch"].as_u64())
        .unwrap_or(0) as usize
}

/// Metrics without the timing fields.
fn metrics(run: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            let o = v.as_object_mut().unwrap();
            o.remove("seconds");
            o.remove("windows_per_s");
            v
        })
        .collect()
}

#[test]
fn sigkill_and_resume_reaches_the_uninterrupted_result() {
    integration_tests::require_samples!();
    kill_and_resume(&[], &train_cmd);
}

/// The default's budget set to 15 times the small dataset's training
/// windows: 15 epochs, each count of epochs × 15/600 (the last 8 through
/// the rollout: 300 × 15/600 = 7.5, rounded; the judge every epoch from
/// epoch 7, where the feed ramp ends; 1 epoch per initialisation; the KL
/// warmed up in 1). The uninterrupted run on 1 thread and the run killed
/// before the late epochs and resumed across them on 3 end with the same
/// bytes, and the checkpoint holds the scaled schedule.
#[test]
fn a_budget_scales_the_schedule_and_resumes_exactly_across_the_late_epochs() {
    integration_tests::require_samples!();
    let budget = |ds: &Path, out: &Path| {
        let manifest = std::fs::read_to_string(ds.join("manifest.json")).unwrap();
        let m: serde_json::Value = serde_json::from_str(&manifest).unwrap();
        let windows = m["counts"]["windows_per_split"]["train"].as_u64().unwrap();
        assert!(windows > 0);
        let threads = if out.ends_with("a") { "1" } else { "3" };
        let mut c = train_budget(ds, out);
        c.env("RAYON_NUM_THREADS", threads);
        c.args(["--budget", &(15 * windows).to_string()]);
        c
    };
    let (tmp, _, m) = kill_and_resume(&[], &budget);
    assert!(m[..6].iter().all(|e| e["generated"].is_null()));
    assert!(m[6..].iter().all(|e| !e["generated"].is_null()));
    let meta = last_meta(&tmp.path().join("a")).unwrap();
    let c = &meta["config"];
    assert_eq!(c["epochs"], 15, "{c}");
    assert_eq!(c["rollout_last"], 8, "{c}");
    assert_eq!(c["kl_warmup_epochs"], 1, "{c}");
    assert_eq!(c["select"]["generation"]["every"], 1, "{c}");
    assert_eq!(c["inits"]["epochs"], 1, "{c}");
    assert!(c["budget"].as_u64().is_some_and(|b| b % 15 == 0), "{c}");
}

/// `--rollout-last 8` trains the first 7 epochs as the plain run
/// (`--rollout-last 0`) does and the last 8 otherwise (the gradient through
/// the fed frames, the fed speed loss and the preset's root weight), and a
/// run killed on either side of the switch resumes exactly. (Without the
/// option every one of these 15 epochs is a late one: the preset's 200.)
#[test]
fn the_late_rollout_starts_on_time_and_resumes_exactly() {
    integration_tests::require_samples!();
    // One initialisation: the probes of several would run late epochs too.
    let (tmp, ds, late) = kill_and_resume(&["--rollout-last", "8", "--inits", "1"], &train_cmd);
    let plain = tmp.path().join("plain");
    let mut c = train_cmd(&ds, &plain);
    let off = ["--inits", "1", "--rollout-last", "0"];
    assert!(c.args(off).status().unwrap().success());
    let plain = metrics(&plain);
    assert_eq!(
        late[..7],
        plain[..7],
        "the first 7 epochs are the plain run's"
    );
    for e in 7..15 {
        assert_ne!(
            late[e]["train_recon"],
            plain[e]["train_recon"],
            "epoch {}",
            e + 1
        );
    }
    let meta = last_meta(&tmp.path().join("a")).unwrap();
    assert_eq!(meta["config"]["rollout_last"], 8, "{meta}");
}

/// Train `cmd` (15 epochs) with `extra` options once through (`a`) and
/// once killed after epoch 3 and resumed (`b`): the same metrics and bytes.
/// Returns the directory, the dataset and the metrics.
fn kill_and_resume(
    extra: &[&str],
    train_cmd: &dyn Fn(&Path, &Path) -> Command,
) -> (tempfile::TempDir, PathBuf, Vec<serde_json::Value>) {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path());
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    assert!(train_cmd(&ds, &a).args(extra).status().unwrap().success());

    let mut child = train_cmd(&ds, &b).args(extra).spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    while epoch_of(&b) < 3 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let killed_at = epoch_of(&b);
    assert!((3..15).contains(&killed_at), "killed at epoch {killed_at}");

    let mut resume = train_cmd(&ds, &b);
    resume.args(extra).arg("--resume");
    assert!(resume.status().unwrap().success());

    assert_eq!(epoch_of(&b), 15);
    assert_eq!(metrics(&a), metrics(&b), "metrics differ");
    for f in [
        "last/model.safetensors",
        "last/optimizer.safetensors",
        "best/model.safetensors",
    ] {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{f} differs after resume"
        );
    }
    assert!(b.join("loss.png").is_file());
    let m = metrics(&a);
    (tmp, ds, m)
}

#[test]
fn resume_without_a_checkpoint_starts_from_scratch_and_says_so() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path());
    // A run killed in its first epoch: metrics started, no `last/` yet.
    let run = tmp.path().join("killed");
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(run.join("metrics.jsonl"), "").unwrap();
    let out = train_for("2", &ds, &run).arg("--resume").output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("no checkpoint to resume from yet")
            && stderr.contains("starting from scratch"),
        "{stderr}"
    );
    assert_eq!(epoch_of(&run), 2);
    assert_eq!(metrics(&run).len(), 2);

    // A directory that does not exist is a mistake, not a fresh start.
    let missing = tmp.path().join("no-such-run");
    let out = train_cmd(&ds, &missing).arg("--resume").output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("nothing to resume"), "{stderr}");
    assert!(!missing.exists());
}

#[test]
fn the_best_of_several_initialisations_is_kept_and_trained_on_as_probed() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path());
    let run = tmp.path().join("inits");
    let out = train_for("4", &ds, &run)
        .args(["--inits", "3"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("kept initialisation"), "{stderr}");
    let meta = last_meta(&run).expect("a checkpoint");
    let losses: Vec<f64> = meta["init"]["val_losses"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(losses.len(), 3);
    // The kept candidate has the lowest loss, and its weights come from
    // seed + k·2³².
    let kept = (0..3).fold(0, |b, k| if losses[k] < losses[b] { k } else { b });
    assert_eq!(
        meta["init"]["seed"].as_u64(),
        Some(11 + ((kept as u64) << 32))
    );
    // The probe ran the run's own first 4 epochs from that candidate: the
    // run's loss at epoch 4 is the probe's, to the bit.
    let m = metrics(&run);
    let last = &m[3];
    let loss = last["val_recon"].as_f64().unwrap() + last["val_kl"].as_f64().unwrap();
    assert_eq!(loss, losses[kept]);
    // Candidates differ (else the test shows nothing).
    assert!(losses.iter().any(|l| *l != losses[0]), "{losses:?}");
}

/// Each `(options, message)`: training 2 epochs with the options fails
/// and says the message.
fn refused(cases: &[(&[&str], &str)]) {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path());
    for (args, says) in cases {
        let out = train_for("2", &ds, &tmp.path().join("run"))
            .args(*args)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?} trained");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(says), "{args:?}: {err}");
    }
}

#[test]
fn the_late_root_weight_needs_the_late_epochs_and_a_positive_weight() {
    integration_tests::require_samples!();
    refused(&[
        (
            &["--rollout-last", "0", "--late-root-weight", "4"],
            "--late-root-weight weighs the root in the last epochs: it needs --rollout-last N",
        ),
        (
            &["--rollout-last", "1", "--late-root-weight=-1"],
            "root weight must be positive, got -1",
        ),
    ]);
}
