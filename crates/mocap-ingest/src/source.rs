//! Collections of CMU files: a directory tree or a `.zip` archive laid out
//! like CMU's downloads. Lists the takes (one per `.bvh` or `.amc`, each AMC
//! paired with its subject's `NN.asf` from the same folder) and reads them.

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

/// A failure to open or list a collection.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The path does not exist.
    #[error("{0}: no such file or directory")]
    NotFound(PathBuf),
    /// An I/O failure.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The archive cannot be read as a zip file.
    #[error("{path}: not a readable zip archive: {message}")]
    Zip {
        /// The archive.
        path: PathBuf,
        /// The cause.
        message: String,
    },
    /// A file that is neither a directory nor a `.zip`.
    #[error("{0}: expected a directory or a .zip archive")]
    Unsupported(PathBuf),
}

/// The motion formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Format {
    /// Biovision hierarchy.
    Bvh,
    /// Acclaim motion (with its ASF skeleton).
    Amc,
}

impl Format {
    /// The format of a file name, by extension (case-insensitive).
    pub fn of(name: &str) -> Option<Format> {
        let ext = name.rsplit_once('.')?.1.to_ascii_lowercase();
        match ext.as_str() {
            "bvh" => Some(Format::Bvh),
            "amc" => Some(Format::Amc),
            _ => None,
        }
    }

    /// Lower-case name (`bvh`, `amc`).
    pub fn as_str(self) -> &'static str {
        match self {
            Format::Bvh => "bvh",
            Format::Amc => "amc",
        }
    }
}

/// One file in a collection.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Entry {
    /// Path relative to the collection root, with `/` separators.
    pub name: String,
    /// Size in bytes (uncompressed).
    pub size: u64,
}

/// One take: a motion file and, for AMC, its skeleton file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TakeInput {
    /// Take id: the motion file's stem (e.g. `02_01`).
    pub take_id: String,
    /// The motion file's format.
    pub format: Format,
    /// The motion file.
    pub motion: Entry,
    /// The AMC's skeleton, if found.
    pub asf: Option<Entry>,
    /// Where the skeleton was looked for (for AMC).
    pub asf_expected: String,
}

/// The subject part of a take id (`02` of `02_01`); the whole id if it has no `_`.
pub fn subject_of(take_id: &str) -> &str {
    take_id.split_once('_').map_or(take_id, |(s, _)| s)
}

/// A directory tree or zip archive of motion files.
#[derive(Clone, Debug)]
pub struct Source {
    root: PathBuf,
    is_zip: bool,
}

impl Source {
    /// Open a directory or `.zip` archive.
    pub fn open(path: &Path) -> Result<Source, SourceError> {
        let meta = std::fs::metadata(path).map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => SourceError::NotFound(path.to_path_buf()),
            _ => SourceError::Io {
                path: path.to_path_buf(),
                source: e,
            },
        })?;
        let is_zip = if meta.is_dir() {
            false
        } else if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("zip"))
        {
            true
        } else {
            return Err(SourceError::Unsupported(path.to_path_buf()));
        };
        Ok(Source {
            root: path.to_path_buf(),
            is_zip,
        })
    }

    /// The collection's path.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Every file in the collection, sorted by name.
    pub fn entries(&self) -> Result<Vec<Entry>, SourceError> {
        let mut out = Vec::new();
        if self.is_zip {
            let mut zip = self.open_zip()?;
            for i in 0..zip.len() {
                let f = zip.by_index_raw(i).map_err(|e| SourceError::Zip {
                    path: self.root.clone(),
                    message: e.to_string(),
                })?;
                if f.is_file() {
                    let name = f.name().map_err(|e| SourceError::Zip {
                        path: self.root.clone(),
                        message: e.to_string(),
                    })?;
                    out.push(Entry {
                        name: name.into_owned(),
                        size: f.size(),
                    });
                }
            }
        } else {
            walk(&self.root, &self.root, &mut out)?;
        }
        out.sort();
        Ok(out)
    }

    /// The takes of the collection, sorted by path. Files other than `.bvh`,
    /// `.amc` and `.asf` are ignored.
    pub fn takes(&self) -> Result<Vec<TakeInput>, SourceError> {
        let entries = self.entries()?;
        let mut takes = Vec::new();
        for e in &entries {
            let Some(format) = Format::of(&e.name) else {
                continue;
            };
            let (dir, file) = e.name.rsplit_once('/').unwrap_or(("", &e.name));
            let take_id = file.rsplit_once('.').map_or(file, |(s, _)| s).to_string();
            let (asf, asf_expected) = match format {
                Format::Bvh => (None, String::new()),
                Format::Amc => {
                    let want = format!("{}.asf", subject_of(&take_id));
                    let path = if dir.is_empty() {
                        want
                    } else {
                        format!("{dir}/{want}")
                    };
                    let found = entries
                        .iter()
                        .find(|x| x.name.eq_ignore_ascii_case(&path))
                        .cloned();
                    (found, self.display_name(&path))
                }
            };
            takes.push(TakeInput {
                take_id,
                format,
                motion: e.clone(),
                asf,
                asf_expected,
            });
        }
        Ok(takes)
    }

    /// A reader for the collection's files (one per thread).
    pub fn reader(&self) -> Result<SourceReader, SourceError> {
        Ok(if self.is_zip {
            SourceReader::Zip(Box::new(self.open_zip()?))
        } else {
            SourceReader::Dir(self.root.clone())
        })
    }

    /// How errors and reports name a file of the collection:
    /// `dir/sub/file` or `archive.zip!/entry`.
    pub fn display_name(&self, name: &str) -> String {
        if self.is_zip {
            format!("{}!/{name}", self.root.display())
        } else {
            self.root.join(name).display().to_string()
        }
    }

    /// A name independent of where the collection lives:
    /// `archive.zip!/entry` or `folder/entry` (the collection's own name,
    /// then the entry). Datasets record these, so rebuilding from a copy
    /// elsewhere gives the same bytes.
    pub fn portable_name(&self, name: &str) -> String {
        let root = self
            .root
            .file_name()
            .map_or_else(|| ".".into(), |n| n.to_string_lossy().into_owned());
        if self.is_zip {
            format!("{root}!/{name}")
        } else {
            format!("{root}/{name}")
        }
    }

    fn open_zip(&self) -> Result<zip::ZipArchive<File>, SourceError> {
        let f = File::open(&self.root).map_err(|e| SourceError::Io {
            path: self.root.clone(),
            source: e,
        })?;
        zip::ZipArchive::new(f).map_err(|e| SourceError::Zip {
            path: self.root.clone(),
            message: e.to_string(),
        })
    }
}

fn walk(root: &Path, dir: &Path, out: &mut Vec<Entry>) -> Result<(), SourceError> {
    let io = |e| SourceError::Io {
        path: dir.to_path_buf(),
        source: e,
    };
    for item in std::fs::read_dir(dir).map_err(io)? {
        let item = item.map_err(io)?;
        let path = item.path();
        let meta = std::fs::metadata(&path).map_err(|e| SourceError::Io {
            path: path.clone(),
            source: e,
        })?;
        if meta.is_dir() {
            walk(root, &path, out)?;
        } else if let Ok(rel) = path.strip_prefix(root) {
            let name = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy())
                .collect::<Vec<_>>()
                .join("/");
            out.push(Entry {
                name,
                size: meta.len(),
            });
        }
    }
    Ok(())
}

/// Reads files of a [`Source`]. Not shared between threads: make one per thread.
pub enum SourceReader {
    /// Files under a directory.
    Dir(PathBuf),
    /// Entries of an open zip archive.
    Zip(Box<zip::ZipArchive<File>>),
}

impl SourceReader {
    /// Read a whole file.
    pub fn read(&mut self, name: &str) -> std::io::Result<Vec<u8>> {
        match self {
            SourceReader::Dir(root) => std::fs::read(root.join(name)),
            SourceReader::Zip(zip) => {
                let mut f = zip.by_name(name).map_err(std::io::Error::other)?;
                let mut buf = Vec::with_capacity(f.size().min(1 << 30) as usize);
                f.read_to_end(&mut buf)?;
                Ok(buf)
            }
        }
    }
}
