//! Read CMU motion capture and turn it into the per-frame features of
//! *Human Motion Generative Model using Variational Recurrent Neural Network*
//! (Murakami & Ikuzawa).
//!
//! The pipeline for one take is: read the file ([`bvh`] or [`asf`]) →
//! forward kinematics to the 19 kept joints ([`skeleton::JOINT_NAMES`]) →
//! resample to 30 fps ([`fps`]) → 58 local-frame features ([`features`]).
//! [`process_take`] runs it; [`source`] lists and reads whole collections.
//! Formats, units and the feature layout are documented in `docs/features.md`.

pub mod asf;
#[cfg(feature = "io")]
pub mod atomic;
#[cfg(feature = "io")]
pub mod bench;
pub mod bvh;
pub mod category;
#[cfg(feature = "io")]
pub mod dataset;
pub mod error;
pub mod features;
pub mod fps;
pub mod math;
pub mod skeleton;
#[cfg(feature = "io")]
pub mod source;
mod text;

pub use error::{ErrorKind, IngestError, Truncation};
pub use features::{FeatureVec, NUM_FEATURES};
pub use skeleton::{Pose, SkeletonKind, JOINT_NAMES, NUM_JOINTS};

use asf::{AmcMotion, AsfOptions, AsfSkeleton};
use bvh::BvhMotion;
use fps::FrameRateTable;
#[cfg(feature = "io")]
use source::{FileRef, Format, Source, SourceError, SourceReader, TakeInput};
#[cfg(feature = "io")]
use std::path::{Path, PathBuf};

/// A parsed motion at its native frame rate.
#[derive(Clone, Debug)]
pub enum Motion {
    /// From a BVH file.
    Bvh(BvhMotion),
    /// From an AMC file and its ASF.
    Amc(AmcMotion),
}

impl Motion {
    /// The skeleton the file uses.
    pub fn skeleton(&self) -> SkeletonKind {
        match self {
            Motion::Bvh(b) => b.skeleton,
            Motion::Amc(_) => SkeletonKind::AsfAmc,
        }
    }

    /// The frame rate the file states (BVH only; cgspeed files all say 120).
    pub fn declared_fps(&self) -> Option<f64> {
        match self {
            Motion::Bvh(b) => Some(b.declared_fps),
            Motion::Amc(_) => None,
        }
    }

    /// Number of motion frames (a BVH T-pose frame is not counted).
    pub fn num_frames(&self) -> usize {
        match self {
            Motion::Bvh(b) => b.num_frames(),
            Motion::Amc(a) => a.num_frames(),
        }
    }

    /// Where the file was cut, if it ends inside its motion: the motion is
    /// then its complete frames (see [`Truncation`]).
    pub fn truncation(&self) -> Option<Truncation> {
        match self {
            Motion::Bvh(b) => b.truncation(),
            Motion::Amc(a) => a.truncation(),
        }
    }

    /// Global positions of the 19 kept joints at a native-rate frame.
    pub fn pose(&self, frame: usize) -> Pose {
        match self {
            Motion::Bvh(b) => b.pose(frame),
            Motion::Amc(a) => a.pose(frame),
        }
    }
}

/// Read a BVH file's bytes. `file` names it in errors.
pub fn read_bvh(file: &str, bytes: &[u8]) -> Result<Motion, IngestError> {
    BvhMotion::parse(bytes)
        .map(Motion::Bvh)
        .map_err(|k| IngestError::new(file, k))
}

/// Read an AMC file's bytes with its subject's ASF.
pub fn read_amc(
    amc_file: &str,
    amc: &[u8],
    asf_file: &str,
    asf: &[u8],
    options: AsfOptions,
) -> Result<Motion, IngestError> {
    let skeleton = AsfSkeleton::parse(asf, options).map_err(|k| IngestError::new(asf_file, k))?;
    AmcMotion::parse(amc, skeleton)
        .map(Motion::Amc)
        .map_err(|k| IngestError::new(amc_file, k))
}

/// Options of the per-take pipeline.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// Output frame rate (the paper: 30).
    pub target_fps: f64,
    /// Source frame rates by take id.
    pub frame_rates: FrameRateTable,
    /// How ASF skeletons are built.
    pub asf: AsfOptions,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            target_fps: 30.0,
            frame_rates: FrameRateTable::default(),
            asf: AsfOptions::default(),
        }
    }
}

/// One take turned into features.
#[derive(Clone, Debug)]
pub struct Clip {
    /// Take id (file stem).
    pub take_id: String,
    /// Skeleton of the source file.
    pub skeleton: SkeletonKind,
    /// The source frame rate used.
    pub source_fps: f64,
    /// Frames in the source file at its native rate.
    pub native_frames: usize,
    /// Features at the target rate.
    pub features: Vec<FeatureVec>,
    /// Set when the file ends inside its motion: the take is its complete
    /// frames (`native_frames` of [`Truncation::frames_expected`]). Callers
    /// warn about it, or refuse the file ([`Truncation::to_error`]).
    pub truncation: Option<Truncation>,
}

/// Resample a motion to `options.target_fps` and compute its features.
/// A motion cut short that fails here fails as [`ErrorKind::Truncated`]: the
/// cut is what is wrong with its file.
pub fn clip_from_motion(
    file: &str,
    take_id: &str,
    motion: &Motion,
    options: &Options,
) -> Result<Clip, IngestError> {
    let truncation = motion.truncation();
    let err = |k| IngestError::new(file, truncation.map_or(k, Truncation::to_error));
    let source_fps = options.frame_rates.resolve(take_id, motion.declared_fps());
    let idx =
        fps::resample_indices(motion.num_frames(), source_fps, options.target_fps).map_err(err)?;
    let poses: Vec<Pose> = idx.iter().map(|&i| motion.pose(i)).collect();
    let features = features::compute_features(&poses).map_err(err)?;
    Ok(Clip {
        take_id: take_id.to_string(),
        skeleton: motion.skeleton(),
        source_fps,
        native_frames: motion.num_frames(),
        features,
        truncation,
    })
}

#[cfg(feature = "io")]
/// Read one take of `source` and compute its features.
pub fn process_take(
    source: &Source,
    reader: &mut SourceReader,
    take: &TakeInput,
    options: &Options,
) -> Result<Clip, IngestError> {
    process_take_with(
        take,
        |f| source.display_file(f),
        |f| reader.read_file(f),
        options,
    )
}

#[cfg(feature = "io")]
/// [`process_take`] with the file reading supplied by the caller (`read`
/// gets each file the take needs: the motion file, then, for AMC, its ASF);
/// `display` names files in errors.
pub fn process_take_with(
    take: &TakeInput,
    display: impl Fn(&FileRef) -> String,
    mut read: impl FnMut(&FileRef) -> std::io::Result<Vec<u8>>,
    options: &Options,
) -> Result<Clip, IngestError> {
    let motion = FileRef::Entry(take.motion.clone());
    let file = display(&motion);
    let bytes = read(&motion).map_err(|e| IngestError::new(&file, ErrorKind::Io(e)))?;
    let motion = match take.format {
        Format::Bvh => read_bvh(&file, &bytes)?,
        Format::Amc => {
            let Some(asf) = &take.asf else {
                return Err(IngestError::new(
                    &file,
                    ErrorKind::MissingAsf {
                        tried: take.asf_search.clone(),
                    },
                ));
            };
            let asf_file = display(asf);
            let asf_bytes = read(asf).map_err(|e| IngestError::new(&asf_file, ErrorKind::Io(e)))?;
            read_amc(&file, &bytes, &asf_file, &asf_bytes, options.asf)?
        }
    };
    clip_from_motion(&file, &take.take_id, &motion, options)
}

#[cfg(feature = "io")]
/// Why one motion file could not be turned into features ([`clip_of_file`]).
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// The file or its directory cannot be listed.
    #[error(transparent)]
    Source(#[from] SourceError),
    /// The path is not a `.bvh` or `.amc` file.
    #[error("{}: not a .bvh or .amc file", .0.display())]
    NotMotion(PathBuf),
    /// The file (or its ASF) cannot be read or turned into features.
    #[error(transparent)]
    Ingest(#[from] IngestError),
}

#[cfg(feature = "io")]
/// One motion file (a `.bvh`, or an `.amc` with its ASF found as
/// [`Source::takes`] finds it, else `asf`) read and turned into features the
/// way `cargo xtask dataset` turns a take; with the collection (its
/// directory) and the take it is.
pub fn clip_of_file(
    file: &Path,
    asf: Option<PathBuf>,
    options: &Options,
) -> Result<(Source, TakeInput, Clip), FileError> {
    if !file.is_file() {
        return Err(SourceError::NotFound(file.to_path_buf()).into());
    }
    let not_motion = || FileError::NotMotion(file.to_path_buf());
    let dir = match file.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = file.file_name().ok_or_else(not_motion)?.to_string_lossy();
    let source = Source::open(dir)?.with_fallback_asf(asf);
    let take = source
        .takes()?
        .into_iter()
        .find(|t| t.motion.name == name)
        .ok_or_else(not_motion)?;
    let mut reader = source.reader()?;
    let clip = process_take(&source, &mut reader, &take, options)?;
    Ok((source, take, clip))
}

#[cfg(feature = "io")]
/// What `cargo xtask inspect` prints about one motion file: the take, its
/// ASF, skeleton, frames before and after resampling, and the range of every
/// feature ([`clip_of_file`]).
pub fn describe_file(
    file: &Path,
    asf: Option<PathBuf>,
    options: &Options,
) -> Result<String, FileError> {
    use std::fmt::Write;
    let (source, take, clip) = clip_of_file(file, asf, options)?;
    let mut out = format!("file:          {}\n", file.display());
    let _ = writeln!(
        out,
        "take:          {} (subject {})",
        clip.take_id, take.subject
    );
    if let Some(asf) = &take.asf {
        let _ = writeln!(
            out,
            "asf:           {} ({})",
            source.display_file(asf),
            take.asf_search
        );
    }
    let _ = writeln!(out, "skeleton:      {}", clip.skeleton.name());
    let _ = writeln!(
        out,
        "frames:        {} at {} fps → {} at {} fps",
        clip.native_frames,
        clip.source_fps,
        clip.features.len(),
        options.target_fps
    );
    out.push_str("feature                 min       mean        max\n");
    for (n, [lo, mean, hi]) in features::feature_names()
        .iter()
        .zip(features::ranges(&clip.features))
    {
        let _ = writeln!(out, "{n:<16} {lo:>10.4} {mean:>10.4} {hi:>10.4}");
    }
    Ok(out)
}
