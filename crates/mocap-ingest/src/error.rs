//! Typed errors. Every error names the file it comes from and what is wrong.

/// A failure to turn one input file into features.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {kind}")]
pub struct IngestError {
    /// The file (path on disk, or `archive.zip!/entry` for an archive entry).
    pub file: String,
    /// What is wrong with it.
    pub kind: ErrorKind,
}

impl IngestError {
    /// Build an error for `file`.
    pub fn new(file: impl Into<String>, kind: ErrorKind) -> Self {
        IngestError {
            file: file.into(),
            kind,
        }
    }

    /// A short machine-friendly name of the error kind (for reports).
    pub fn code(&self) -> &'static str {
        self.kind.code()
    }
}

/// What went wrong.
#[derive(Debug, thiserror::Error)]
pub enum ErrorKind {
    /// The file could not be read.
    #[error("cannot read file: {0}")]
    Io(#[from] std::io::Error),
    /// The file has no content.
    #[error("file is empty")]
    Empty,
    /// The file is not text (e.g. binary garbage).
    #[error("not a text file: byte 0x{byte:02x} at offset {offset}")]
    NotText {
        /// Byte offset of the first non-text byte.
        offset: usize,
        /// The byte.
        byte: u8,
    },
    /// The file's extension is not one this crate reads.
    #[error("unsupported file type (expected .bvh, .asf or .amc)")]
    UnsupportedFormat,
    /// A syntax error.
    #[error("{format} syntax error{}: {message}", at_line(*.line))]
    Syntax {
        /// `BVH`, `ASF` or `AMC`.
        format: &'static str,
        /// 1-based line number, where known.
        line: Option<usize>,
        /// What was expected or found.
        message: String,
    },
    /// A value that should be a number is not.
    #[error("non-numeric value {token:?} at line {line}")]
    NonNumeric {
        /// 1-based line number.
        line: usize,
        /// The offending token (truncated).
        token: String,
    },
    /// A motion line has the wrong number of values.
    #[error("channel count mismatch at line {line}: expected {expected} values, found {found}")]
    ChannelCount {
        /// 1-based line number.
        line: usize,
        /// Channels declared by the hierarchy.
        expected: usize,
        /// Values on the line.
        found: usize,
    },
    /// The motion section ends early.
    #[error("truncated motion: expected {expected} frames, file holds {found} complete frames (ends at line {line})")]
    Truncated {
        /// Frames declared.
        expected: usize,
        /// Complete frames present.
        found: usize,
        /// Last line of the file.
        line: usize,
    },
    /// The joint names match no known CMU skeleton.
    #[error("unknown skeleton: closest is {closest}, missing joints: {}", missing.join(", "))]
    UnknownSkeleton {
        /// The closest known skeleton.
        closest: &'static str,
        /// Joints that skeleton needs and the file lacks.
        missing: Vec<String>,
    },
    /// An AMC file whose ASF none of the rules found.
    #[error("missing skeleton file: no ASF found for this AMC; tried {tried}")]
    MissingAsf {
        /// Every rule tried, and why it failed.
        tried: String,
    },
    /// A NaN or infinite value.
    #[error("non-finite value in frame {frame} ({what})")]
    NonFinite {
        /// 0-based frame index (native rate).
        frame: usize,
        /// Which channel, joint or feature.
        what: String,
    },
    /// A pose whose local frame is undefined.
    #[error("degenerate pose in frame {frame}: {reason}")]
    Degenerate {
        /// 0-based frame index (30 fps after resampling).
        frame: usize,
        /// Why.
        reason: String,
    },
    /// A frame rate that cannot be resampled to the target.
    #[error("unsupported frame rate {source_fps} fps: cannot resample to {target_fps} fps (the rate must be an integer multiple of the target)")]
    UnsupportedFrameRate {
        /// The file's rate.
        source_fps: f64,
        /// The requested rate.
        target_fps: f64,
    },
    /// The file holds no motion frames.
    #[error("no motion frames")]
    NoFrames,
}

/// Where a file that ends inside its motion was cut, and what it still holds.
///
/// A file whose only damage is its end (it stops inside, or before the end
/// of, its motion: a BVH with fewer frame lines than `Frames:` says or a
/// short last line, an AMC whose last frame lacks lines or ends mid-line)
/// reads with its complete frames; this records the cut, so callers can warn
/// or, when strict, refuse the file with [`ErrorKind::Truncated`]
/// ([`Truncation::to_error`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Truncation {
    /// Frames the file was to hold, counted as in the file: a BVH's
    /// `Frames:` (a T-pose frame included), an AMC's number of the frame it
    /// ends in.
    pub expected: usize,
    /// Complete frames the file holds, counted the same way.
    pub found: usize,
    /// Last line of the file (1-based).
    pub line: usize,
    /// Leading frames of the file that are not motion (a BVH T-pose frame):
    /// `found - leading` motion frames are kept.
    pub leading: usize,
}

impl Truncation {
    /// The error a strict reader gives for this file.
    pub fn to_error(self) -> ErrorKind {
        ErrorKind::Truncated {
            expected: self.expected,
            found: self.found,
            line: self.line,
        }
    }

    /// Motion frames kept (as `native_frames` counts them: a BVH T-pose
    /// frame excluded).
    pub fn frames_kept(&self) -> usize {
        self.found.saturating_sub(self.leading)
    }

    /// Motion frames the file was to hold, counted like [`Self::frames_kept`].
    pub fn frames_expected(&self) -> usize {
        self.expected.saturating_sub(self.leading)
    }
}

/// Whether `token` could be the start of a decimal number cut short
/// (`-`, `12.`, `1e`, `1.5E-`): what is left of a value when a file ends
/// inside it.
pub(crate) fn is_number_prefix(token: &[u8]) -> bool {
    let t = token
        .strip_prefix(b"-")
        .or_else(|| token.strip_prefix(b"+"))
        .unwrap_or(token);
    let (mantissa, exponent) = match t.iter().position(|&b| b == b'e' || b == b'E') {
        Some(i) => (&t[..i], Some(&t[i + 1..])),
        None => (t, None),
    };
    let dots = mantissa.iter().filter(|&&b| b == b'.').count();
    let mantissa_ok = dots <= 1 && mantissa.iter().all(|&b| b == b'.' || b.is_ascii_digit());
    let exponent_ok = exponent.is_none_or(|e| {
        let e = e
            .strip_prefix(b"-")
            .or_else(|| e.strip_prefix(b"+"))
            .unwrap_or(e);
        mantissa.iter().any(u8::is_ascii_digit) && e.iter().all(u8::is_ascii_digit)
    });
    mantissa_ok && exponent_ok
}

/// Whether `part` (a slice of `whole`) runs to the end of `whole`: the file
/// ends inside it.
pub(crate) fn ends_at_end(whole: &[u8], part: &[u8]) -> bool {
    std::ptr::eq(part.as_ptr_range().end, whole.as_ptr_range().end)
}

fn at_line(line: Option<usize>) -> String {
    match line {
        Some(l) => format!(" at line {l}"),
        None => String::new(),
    }
}

impl ErrorKind {
    /// A short machine-friendly name of the kind.
    pub fn code(&self) -> &'static str {
        match self {
            ErrorKind::Io(_) => "io",
            ErrorKind::Empty => "empty",
            ErrorKind::NotText { .. } => "not_text",
            ErrorKind::UnsupportedFormat => "unsupported_format",
            ErrorKind::Syntax { .. } => "syntax",
            ErrorKind::NonNumeric { .. } => "non_numeric",
            ErrorKind::ChannelCount { .. } => "channel_count",
            ErrorKind::Truncated { .. } => "truncated",
            ErrorKind::UnknownSkeleton { .. } => "unknown_skeleton",
            ErrorKind::MissingAsf { .. } => "missing_asf",
            ErrorKind::NonFinite { .. } => "non_finite",
            ErrorKind::Degenerate { .. } => "degenerate",
            ErrorKind::UnsupportedFrameRate { .. } => "unsupported_frame_rate",
            ErrorKind::NoFrames => "no_frames",
        }
    }
}

/// Shorten a token for an error message.
pub(crate) fn snippet(token: &[u8]) -> String {
    let s = String::from_utf8_lossy(&token[..token.len().min(24)]).into_owned();
    if token.len() > 24 {
        format!("{s}…")
    } else {
        s
    }
}

/// Check that `bytes` looks like a text file; returns the kind of failure.
pub(crate) fn check_text(bytes: &[u8]) -> Result<(), ErrorKind> {
    if bytes.iter().all(|b| b.is_ascii_whitespace()) {
        return Err(ErrorKind::Empty);
    }
    // Text files here are ASCII (possibly with Latin-1 comments); control bytes
    // other than whitespace mean binary data.
    match bytes
        .iter()
        .position(|&b| b < 0x20 && !matches!(b, b'\n' | b'\r' | b'\t' | 0x0c))
    {
        Some(offset) => Err(ErrorKind::NotText {
            offset,
            byte: bytes[offset],
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn number_prefixes_are_what_is_left_of_a_cut_number() {
        for t in ["-", "+", ".", "-.", "12.", "1e", "1.5E-", "-0.25e+", "7"] {
            assert!(is_number_prefix(t.as_bytes()), "{t}");
        }
        for t in [
            "e", "-e5", "1.2.3", "1e5e", "1e-+", "abc", "nan", "1,5", "0x1F", "--1",
        ] {
            assert!(!is_number_prefix(t.as_bytes()), "{t}");
        }
    }

    #[test]
    fn a_part_ends_at_the_end_only_if_it_is_the_tail() {
        let text = b"1 2 3";
        assert!(ends_at_end(text, &text[4..]));
        assert!(!ends_at_end(text, &text[2..3]));
        assert!(!ends_at_end(text, b"3"));
    }
}
