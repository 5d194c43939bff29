//! Helpers shared by the integration tests (here and in `xtask/tests`):
//! where the real CMU samples are, and what a test does without them.
//!
//! The samples live in `../shared/cmu/` beside the repository (override with
//! `CMU_SHARED_DIR`). They are read at run time and never copied into the
//! project. A test that needs them starts with [`require_samples!`]: when
//! they are missing it prints `skipped: … needs ../shared/cmu (set
//! CMU_SHARED_DIR)` and passes, unless `CMU_SAMPLES_REQUIRED=1` (set by
//! `.ci/run`), in which case it fails.

use mocap_ingest::dataset::DatasetOptions;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The sample files the real-data tests read.
pub const SAMPLE_FILES: [&str; 3] = [
    "cmu-bvh-sample.zip",
    "cmu-asfamc-sample.zip",
    "cmu-bvh-daz-sample.zip",
];

/// The environment variable that makes missing samples a failure.
pub const REQUIRED_VAR: &str = "CMU_SAMPLES_REQUIRED";

/// The folder that should hold the samples: `CMU_SHARED_DIR`, else
/// `../shared/cmu` beside the repository.
pub fn shared_cmu_dir() -> PathBuf {
    std::env::var_os("CMU_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/cmu"))
}

/// Whether the samples are there. If not: panics when `CMU_SAMPLES_REQUIRED`
/// is set (to anything but `0` or empty), else prints why the calling test
/// is skipped and returns `false`.
pub fn samples_present() -> bool {
    let dir = shared_cmu_dir();
    let missing: Vec<&str> = SAMPLE_FILES
        .iter()
        .copied()
        .filter(|f| !dir.join(f).is_file())
        .collect();
    if missing.is_empty() {
        return true;
    }
    let test = std::thread::current()
        .name()
        .unwrap_or("this test")
        .to_string();
    let why = format!(
        "{test} needs ../shared/cmu (set CMU_SHARED_DIR): {} missing in {}",
        missing.join(", "),
        dir.display()
    );
    let required = std::env::var(REQUIRED_VAR).is_ok_and(|v| !v.is_empty() && v != "0");
    assert!(!required, "{REQUIRED_VAR} is set but {why}");
    // Straight to the stderr handle: the test harness captures `eprintln!`
    // of passing tests, and this line must be seen. One `write_all` of the
    // whole line: `writeln!` writes its pieces one by one, and the harness's
    // own output (on stdout, into the same pipe under CI) could land
    // between them and break the line CI counts.
    use std::io::Write as _;
    let _ = std::io::stderr().write_all(format!("skipped: {why}\n").as_bytes());
    false
}

/// Return from the calling test (passing) when the CMU samples are absent;
/// see [`samples_present`].
#[macro_export]
macro_rules! require_samples {
    () => {
        if !$crate::samples_present() {
            return;
        }
    };
}

/// Path of a sample file (call [`require_samples!`] first).
pub fn sample(name: &str) -> PathBuf {
    shared_cmu_dir().join(name)
}

/// Path of the BVH sample archive.
pub fn bvh_zip() -> PathBuf {
    sample("cmu-bvh-sample.zip")
}

/// Path of the ASF/AMC sample archive.
pub fn asfamc_zip() -> PathBuf {
    sample("cmu-asfamc-sample.zip")
}

/// Path of the Daz-friendly BVH sample archive.
pub fn daz_zip() -> PathBuf {
    sample("cmu-bvh-daz-sample.zip")
}

/// Read one entry of a sample archive into memory.
pub fn read_entry(archive: &std::path::Path, name: &str) -> Vec<u8> {
    let source = mocap_ingest::source::Source::open(archive).expect("open archive");
    source
        .reader()
        .expect("reader")
        .read(name)
        .unwrap_or_else(|e| panic!("{}!/{name}: {e}", archive.display()))
}

/// Every file of a dataset directory.
pub use mocap_ingest::dataset::FILES as DATASET_FILES;

/// The bytes of every file of a dataset directory.
pub fn dataset_contents(dir: &Path) -> BTreeMap<&'static str, Vec<u8>> {
    DATASET_FILES
        .iter()
        .map(|f| (*f, std::fs::read(dir.join(f)).unwrap()))
        .collect()
}

/// Options for a handful of short takes (subject 02's are ~90 frames at
/// 30 fps): all in train and windows of 32 frames, so there are statistics.
pub fn short_takes_options() -> DatasetOptions {
    DatasetOptions {
        fractions: [1.0, 0.0, 0.0],
        window: 32,
        stride: 16,
        ..Default::default()
    }
}

/// A dataset in `dir/ds` from takes 02_01 … 02_06 (copied into `dir/src`):
/// windows of 32 frames (stride 16), split by `fractions` (train, val, test).
pub fn small_dataset(dir: &Path, fractions: [f64; 3]) -> PathBuf {
    let src = dir.join("src");
    std::fs::create_dir_all(&src).unwrap();
    for t in ["02_01", "02_02", "02_03", "02_04", "02_05", "02_06"] {
        let name = format!("cmu-bvh-motionbuilder/02/{t}.bvh");
        std::fs::write(src.join(format!("{t}.bvh")), read_entry(&bvh_zip(), &name)).unwrap();
    }
    let out = dir.join("ds");
    let opts = DatasetOptions {
        window: 32,
        stride: 16,
        fractions,
        ..Default::default()
    };
    let sources = [mocap_ingest::source::Source::open(&src).unwrap()];
    mocap_ingest::dataset::build_dataset(
        &sources,
        &["src".into()],
        &out,
        &opts,
        &mocap_ingest::dataset::NoProgress,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    out
}
