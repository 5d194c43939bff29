//! Motions out of the project: every way a motion (global joint positions
//! at 30 fps) leaves it.
//!
//! - [`io`]: the motions Parquet and JSON formats (write, and read back);
//! - [`bvh`]: BVH export (CMU's Motionbuilder-style skeleton), with the
//!   rotations solved from joint positions by [`solve`];
//! - [`figure`]: stick figures (contact sheet, animated PNG) on the
//!   anti-aliased [`canvas`];
//! - [`chart`]: line charts and histograms with `plotters`;
//! - [`top_down()`]: asked paths and the roots that followed them, seen from
//!   above;
//! - [`feet`]: planted toes pinned in place, the legs bent to reach them;
//! - [`viewer`]: one self-contained HTML file with a 3-D viewer (three.js).
//!
//! The crate knows nothing of models or datasets: it takes [`Motion`]s and
//! numbers. Formats are documented in `docs/metrics.md` and `docs/export.md`.

pub mod bvh;
pub mod canvas;
pub mod chart;
pub mod feet;
pub mod figure;
pub mod io;
pub mod play;
pub mod solve;
pub mod top_down;
pub mod viewer;

pub use top_down::top_down;

use mocap_ingest::skeleton::Pose;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Frames per second of every motion (the dataset's rate).
pub const FPS: f64 = 30.0;

/// Metres per CMU length unit (the dataset's units; `docs/features.md`).
pub const METRES_PER_UNIT: f64 = 0.0564;

/// One motion in global coordinates (CMU units, y up, floor at y = 0, 30 fps).
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    /// Identifier (`sample_007`, `test_003`, `recon_003`); names its files.
    pub id: String,
    /// Joint positions per frame, in the order of `mocap_ingest::JOINT_NAMES`.
    pub poses: Vec<Pose>,
}

/// Why a motion could not be written, read or drawn.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// Reading or writing a file failed.
    #[error("{}: {cause}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        cause: std::io::Error,
    },
    /// A motions file is not in the documented format.
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A motion cannot be exported or drawn (empty, non-finite, degenerate).
    #[error("motion {id}: {message}")]
    Motion {
        /// The motion's id.
        id: String,
        /// What is wrong.
        message: String,
    },
    /// Drawing or encoding a picture failed.
    #[error("{}: {message}", path.display())]
    Image {
        /// The file.
        path: PathBuf,
        /// What failed.
        message: String,
    },
}

/// Write `path` atomically: `write` fills `NAME.tmp` beside it, which is then
/// renamed over `path`, so a crash never leaves a half-written file.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> Result<(), RenderError>,
) -> Result<(), RenderError> {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".tmp");
    let tmp = path.with_file_name(name);
    let io = |p: &Path| {
        let path = p.to_path_buf();
        move |cause| RenderError::Io { path, cause }
    };
    let file = std::fs::File::create(&tmp).map_err(io(&tmp))?;
    let mut w = std::io::BufWriter::new(file);
    write(&mut w)?;
    w.flush().map_err(io(&tmp))?;
    drop(w);
    std::fs::rename(&tmp, path).map_err(io(path))
}

/// Write `bytes` to `path` atomically.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), RenderError> {
    write_atomically(path, |w| {
        w.write_all(bytes).map_err(|cause| RenderError::Io {
            path: path.to_path_buf(),
            cause,
        })
    })
}
