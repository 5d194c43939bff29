//! Download an archive once into a cache (`mocap-fetch`), with a progress bar.

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

/// The cached copy of `url` under `cache`, downloaded with a progress bar on first use.
pub fn cached(url: &str, cache: &Path, quiet: bool) -> Result<PathBuf> {
    let hit = mocap_fetch::cache_path(url, cache);
    if !quiet && hit.is_file() {
        eprintln!("using cached {} (from {url})", hit.display());
    }
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(0)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} {bar:40} {bytes}/{total_bytes} {bytes_per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("downloading {url}"));
    let path = mocap_fetch::cached(url, cache, &|done, total| {
        if let Some(t) = total {
            bar.set_length(t);
        }
        bar.set_position(done);
    });
    bar.finish_and_clear();
    Ok(path?)
}
