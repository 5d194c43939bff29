//! The dataset's files as written: the Parquet tables (Zstandard or
//! Snappy, floats byte-stream-split or plain), JSON, and the manifest;
//! every output hashed (SHA-256) while it is written.

use super::{BuildSummary, DatasetError, DatasetOptions, Encoding, FORMAT_VERSION, SPLITS};
use crate::features::{feature_names, NUM_FEATURES};
use crate::{Clip, Options};
use arrow_array::{ArrayRef, Float32Array, RecordBatch, StringArray, UInt32Array};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::WriterProperties;
use parquet::schema::types::ColumnPath;
use serde::Serialize;
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::sync::Arc;

/// A file read, as the manifest lists it.
#[derive(Serialize)]
pub(super) struct InputFile {
    pub(super) path: String,
    pub(super) size: u64,
    pub(super) sha256: String,
}

/// A file written, as the manifest lists it.
#[derive(Serialize)]
pub(super) struct OutputFile {
    path: String,
    size: u64,
    sha256: String,
}

/// The build's error for a failed write of `path`.
pub(super) fn write_err(path: &Path, e: impl std::fmt::Display) -> DatasetError {
    DatasetError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// A Parquet writer of `schema` into `path` with `encoding`: dictionaries
/// only for the id columns, row groups of 64 Ki rows.
pub(super) fn parquet_writer(
    path: &Path,
    schema: SchemaRef,
    encoding: Encoding,
) -> Result<ArrowWriter<OutWriter>, DatasetError> {
    let file = create_out(path)?;
    let (compression, split_floats) = match encoding {
        Encoding::Snappy => (Compression::SNAPPY, false),
        Encoding::SnappyByteStreamSplit => (Compression::SNAPPY, true),
        Encoding::Zstd => (Compression::ZSTD(ZstdLevel::default()), false),
        Encoding::ZstdByteStreamSplit => (Compression::ZSTD(ZstdLevel::default()), true),
    };
    // Dictionaries only for the repeated id strings; for float features they
    // cost time (interning every value) and save nothing.
    let mut props = WriterProperties::builder()
        .set_compression(compression)
        .set_dictionary_enabled(false)
        .set_column_dictionary_enabled(ColumnPath::from("take"), true)
        .set_column_dictionary_enabled(ColumnPath::from("subject"), true)
        .set_column_dictionary_enabled(ColumnPath::from("split"), true)
        .set_max_row_group_row_count(Some(64 * 1024))
        .set_created_by(format!("mocap-ingest {}", env!("CARGO_PKG_VERSION")));
    if split_floats {
        for f in schema.fields() {
            if f.data_type() == &DataType::Float32 {
                props = props.set_column_encoding(
                    ColumnPath::from(f.name().as_str()),
                    parquet::basic::Encoding::BYTE_STREAM_SPLIT,
                );
            }
        }
    }
    let props = props.build();
    ArrowWriter::try_new(file, schema, Some(props)).map_err(|e| write_err(path, e))
}

/// The columns of `frames.parquet`: take, subject, frame, the 58 features.
pub(super) fn frames_schema() -> SchemaRef {
    let mut fields = vec![
        Field::new("take", DataType::Utf8, false),
        Field::new("subject", DataType::Utf8, false),
        Field::new("frame", DataType::UInt32, false),
    ];
    for n in feature_names() {
        fields.push(Field::new(n, DataType::Float32, false));
    }
    Arc::new(Schema::new(fields))
}

/// The rows of `frames.parquet` for some takes (clip and subject), in order.
pub(super) fn frames_batch(
    schema: &SchemaRef,
    clips: &[(&Clip, &str)],
) -> Result<RecordBatch, arrow_schema::ArrowError> {
    let rows: usize = clips.iter().map(|c| c.0.features.len()).sum();
    let mut take = Vec::with_capacity(rows);
    let mut subject = Vec::with_capacity(rows);
    let mut frame = Vec::with_capacity(rows);
    let mut cols: Vec<Vec<f32>> = (0..NUM_FEATURES)
        .map(|_| Vec::with_capacity(rows))
        .collect();
    for (c, subj) in clips {
        for (t, f) in c.features.iter().enumerate() {
            take.push(c.take_id.as_str());
            subject.push(*subj);
            frame.push(t as u32);
            for (i, col) in cols.iter_mut().enumerate() {
                col.push(f[i] as f32);
            }
        }
    }
    let mut arrays: Vec<ArrayRef> = vec![
        Arc::new(StringArray::from(take)),
        Arc::new(StringArray::from(subject)),
        Arc::new(UInt32Array::from(frame)),
    ];
    arrays.extend(
        cols.into_iter()
            .map(|c| Arc::new(Float32Array::from(c)) as ArrayRef),
    );
    RecordBatch::try_new(schema.clone(), arrays)
}

/// `manifest.json`: the tool and format version, the sources, the options,
/// the counts, the warnings, and every file read and written with its size
/// and SHA-256.
pub(super) fn manifest(
    opts: &DatasetOptions,
    asf: Option<String>,
    source_labels: &[String],
    summary: &BuildSummary,
    inputs: &BTreeMap<String, InputFile>,
    outputs: &[OutputFile],
) -> serde_json::Value {
    let categories: BTreeMap<&str, &str> = (opts.categories.iter())
        .map(|(t, c)| (t.as_str(), c.name()))
        .collect();
    serde_json::json!({
        "tool": "mocap-ingest",
        "tool_version": env!("CARGO_PKG_VERSION"),
        "format_version": FORMAT_VERSION,
        "sources": source_labels,
        "options": {
            "fps": opts.ingest.target_fps,
            "window": opts.window,
            "stride": opts.stride,
            "split_fractions": opts.fractions,
            "seed": opts.seed,
            "split_by": opts.split_by,
            "std_floor": opts.std_floor,
            "full_asf_skeleton": opts.ingest.asf.full_skeleton,
            "frame_rate_overrides": frame_rate_overrides(&opts.ingest),
            "exclude": opts.exclude,
            "categories": categories,
            "asf": asf,
            "encoding": opts.encoding.name(),
            "strict": opts.strict,
        },
        "counts": {
            "files": summary.files,
            "takes": summary.takes,
            "skipped": summary.skipped.len(),
            "excluded": summary.excluded,
            "short_takes": summary.short_takes,
            "native_frames": summary.native_frames,
            "frames": summary.frames,
            "takes_per_split": split_map(summary.takes_per_split),
            "windows_per_split": split_map(summary.windows_per_split),
            "warnings": summary.warnings.len(),
        },
        "warnings": summary.warnings,
        "inputs": inputs.values().collect::<Vec<_>>(),
        "outputs": outputs,
    })
}

/// The frame rates of `o` that differ from the built-in table.
fn frame_rate_overrides(o: &Options) -> BTreeMap<String, f64> {
    let builtin = crate::fps::FrameRateTable::default();
    o.frame_rates
        .entries()
        .filter(|(k, v)| builtin.get(k) != Some(*v))
        .map(|(k, v)| (k.to_string(), v))
        .collect()
}

/// Counts per split as a JSON object.
fn split_map(v: [usize; 3]) -> serde_json::Value {
    serde_json::json!({ "train": v[0], "val": v[1], "test": v[2] })
}

/// A writer that hashes (SHA-256) and counts what goes through it, so an
/// output's manifest entry needs no second read of the file.
pub(super) struct Hashing<W> {
    inner: W,
    hasher: Sha256,
    len: u64,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hasher.update(&buf[..n]);
        self.len += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// An output file being written: buffered, hashed.
pub(super) type OutWriter = Hashing<BufWriter<File>>;

/// Create `path` for writing, buffered and hashed.
fn create_out(path: &Path) -> Result<OutWriter, DatasetError> {
    let file = File::create(path).map_err(|e| write_err(path, e))?;
    Ok(Hashing {
        inner: BufWriter::new(file),
        hasher: Sha256::new(),
        len: 0,
    })
}

/// Flush and sync an output; its manifest entry.
pub(super) fn finish_file(w: OutWriter, path: &Path) -> Result<OutputFile, DatasetError> {
    let f = w
        .inner
        .into_inner()
        .map_err(|e| write_err(path, e.error()))?;
    f.sync_all().map_err(|e| write_err(path, e))?;
    Ok(OutputFile {
        path: path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
        size: w.len,
        sha256: w
            .hasher
            .finalize()
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect(),
    })
}

/// Write `value` as pretty JSON (and a newline); its manifest entry.
pub(super) fn write_json(path: &Path, value: &impl Serialize) -> Result<OutputFile, DatasetError> {
    let mut text = serde_json::to_string_pretty(value).map_err(|e| write_err(path, e))?;
    text.push('\n');
    let mut w = create_out(path)?;
    w.write_all(text.as_bytes())
        .map_err(|e| write_err(path, e))?;
    finish_file(w, path)
}

/// One row of `takes.parquet`.
pub(super) struct TakeRow {
    pub(super) take: String,
    pub(super) subject: String,
    pub(super) file: String,
    pub(super) format: &'static str,
    pub(super) skeleton: &'static str,
    pub(super) source_fps: f64,
    pub(super) native_frames: u32,
    pub(super) frames: u32,
    pub(super) split: usize,
    pub(super) category: &'static str,
    pub(super) description: Option<String>,
}

/// Write `takes.parquet`; its manifest entry.
pub(super) fn write_takes(
    path: &Path,
    rows: &[TakeRow],
    encoding: Encoding,
) -> Result<OutputFile, DatasetError> {
    let schema = Arc::new(Schema::new(vec![
        Field::new("take", DataType::Utf8, false),
        Field::new("subject", DataType::Utf8, false),
        Field::new("file", DataType::Utf8, false),
        Field::new("format", DataType::Utf8, false),
        Field::new("skeleton", DataType::Utf8, false),
        Field::new("source_fps", DataType::Float32, false),
        Field::new("native_frames", DataType::UInt32, false),
        Field::new("frames", DataType::UInt32, false),
        Field::new("split", DataType::Utf8, false),
        Field::new("category", DataType::Utf8, false),
        Field::new("description", DataType::Utf8, true),
    ]));
    let strings = |f: fn(&TakeRow) -> &str| -> ArrayRef {
        Arc::new(StringArray::from_iter_values(rows.iter().map(f)))
    };
    let counts = |f: fn(&TakeRow) -> u32| -> ArrayRef {
        Arc::new(UInt32Array::from_iter_values(rows.iter().map(f)))
    };
    let cols: Vec<ArrayRef> = vec![
        strings(|r| &r.take),
        strings(|r| &r.subject),
        strings(|r| &r.file),
        strings(|r| r.format),
        strings(|r| r.skeleton),
        Arc::new(Float32Array::from_iter_values(
            rows.iter().map(|r| r.source_fps as f32),
        )),
        counts(|r| r.native_frames),
        counts(|r| r.frames),
        strings(|r| SPLITS[r.split]),
        strings(|r| r.category),
        Arc::new(StringArray::from_iter(
            rows.iter().map(|r| r.description.as_deref()),
        )),
    ];
    write_table(path, schema, cols, encoding)
}

/// Write `windows.parquet` (take, start, length, split); its manifest entry.
pub(super) fn write_windows(
    path: &Path,
    rows: &[(String, u32, usize)],
    window: usize,
    encoding: Encoding,
) -> Result<OutputFile, DatasetError> {
    let schema = Arc::new(Schema::new(vec![
        Field::new("take", DataType::Utf8, false),
        Field::new("start", DataType::UInt32, false),
        Field::new("length", DataType::UInt32, false),
        Field::new("split", DataType::Utf8, false),
    ]));
    let cols: Vec<ArrayRef> = vec![
        Arc::new(StringArray::from_iter_values(
            rows.iter().map(|r| r.0.as_str()),
        )),
        Arc::new(UInt32Array::from_iter_values(rows.iter().map(|r| r.1))),
        Arc::new(UInt32Array::from_iter_values(
            rows.iter().map(|_| window as u32),
        )),
        Arc::new(StringArray::from_iter_values(
            rows.iter().map(|r| SPLITS[r.2]),
        )),
    ];
    write_table(path, schema, cols, encoding)
}

/// Write one record batch of `cols` as a Parquet file; its manifest entry.
fn write_table(
    path: &Path,
    schema: SchemaRef,
    cols: Vec<ArrayRef>,
    encoding: Encoding,
) -> Result<OutputFile, DatasetError> {
    let batch = RecordBatch::try_new(schema.clone(), cols).map_err(|e| write_err(path, e))?;
    let mut w = parquet_writer(path, schema, encoding)?;
    w.write(&batch).map_err(|e| write_err(path, e))?;
    let f = w.into_inner().map_err(|e| write_err(path, e))?;
    finish_file(f, path)
}
