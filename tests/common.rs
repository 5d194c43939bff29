//! Helpers shared by the integration tests: where the real CMU samples are.
//!
//! The samples live in `../shared/cmu/` beside the repository (override with
//! `CMU_SHARED_DIR`). They are read at run time and never copied into the
//! project. When they are missing the tests fail with a message saying what
//! they need.

use std::path::PathBuf;

/// The folder holding `cmu-bvh-sample.zip`, `cmu-asfamc-sample.zip` and `trials.csv`.
pub fn shared_cmu_dir() -> PathBuf {
    let dir = std::env::var_os("CMU_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/cmu"));
    assert!(
        dir.join("cmu-bvh-sample.zip").is_file() && dir.join("cmu-asfamc-sample.zip").is_file(),
        "these tests need the CMU samples: {}/cmu-bvh-sample.zip and cmu-asfamc-sample.zip \
         (set CMU_SHARED_DIR to the folder that holds them)",
        dir.display()
    );
    dir
}

/// Path of the BVH sample archive.
pub fn bvh_zip() -> PathBuf {
    shared_cmu_dir().join("cmu-bvh-sample.zip")
}

/// Path of the ASF/AMC sample archive.
pub fn asfamc_zip() -> PathBuf {
    shared_cmu_dir().join("cmu-asfamc-sample.zip")
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
