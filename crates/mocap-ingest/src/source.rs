//! Collections of CMU files: a directory tree or a `.zip` archive, laid out
//! like CMU's downloads or however their owners keep them. Lists the takes
//! (one per `.bvh` or `.amc`, with its id, subject and, for an AMC, the ASF
//! found by the rules of [`Source::takes`]) and reads them.

use std::collections::BTreeMap;
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
    #[error("{path}: {cause}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        cause: std::io::Error,
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

/// A file a take reads: an entry of its collection, or a file outside it
/// (the `--asf` fallback skeleton).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FileRef {
    /// An entry of the collection.
    Entry(Entry),
    /// A file on disk outside the collection.
    External(PathBuf),
}

/// One take: a motion file and, for AMC, its skeleton file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TakeInput {
    /// Take id: the CMU trial id the file name starts with (`02_01` for
    /// `02_01.bvh` or `02_01-walk.amc`); else the file's path inside the
    /// collection without its extension (`salsa/04`). See [`take_identity`].
    pub take_id: String,
    /// Subject: the CMU subject number (`02`); else the file's folder
    /// (`salsa`), or the collection's name for a file at its top.
    pub subject: String,
    /// Whether the id is a CMU trial id (two files with the same CMU trial id
    /// are copies of one take).
    pub cmu_trial: bool,
    /// The motion file's format.
    pub format: Format,
    /// The motion file.
    pub motion: Entry,
    /// The AMC's skeleton, if one was found.
    pub asf: Option<FileRef>,
    /// For AMC: which rule found the ASF, or every rule tried and why it
    /// failed (the `missing_asf` message).
    pub asf_search: String,
}

/// The CMU trial id a file stem starts with: `NN_MM`, two or three digits
/// on each side, followed by the end of the stem or a non-digit
/// (`07_05-walk` → `07_05`, `131_14` → `131_14`; `walk`, `2_1` → none).
pub fn cmu_trial_id(stem: &str) -> Option<&str> {
    let b = stem.as_bytes();
    let digits = |from: usize| b[from..].iter().take_while(|c| c.is_ascii_digit()).count();
    let s = digits(0);
    if !(2..=3).contains(&s) || b.get(s) != Some(&b'_') {
        return None;
    }
    let t = digits(s + 1);
    if !(2..=3).contains(&t) {
        return None;
    }
    Some(&stem[..s + 1 + t])
}

/// Take id, subject and whether the id is a CMU trial id, for a motion file
/// `name` (its path inside the collection, `/`-separated) of a collection
/// called `collection`: see [`TakeInput::take_id`] and [`TakeInput::subject`].
pub fn take_identity(name: &str, collection: &str) -> (String, String, bool) {
    let (dir, file) = name.rsplit_once('/').unwrap_or(("", name));
    let stem = file.rsplit_once('.').map_or(file, |(s, _)| s);
    if let Some(id) = cmu_trial_id(stem) {
        let subject = id.split_once('_').map_or(id, |(s, _)| s);
        return (id.to_string(), subject.to_string(), true);
    }
    let id = match dir {
        "" => stem.to_string(),
        d => format!("{d}/{stem}"),
    };
    let subject = dir.rsplit('/').next().filter(|d| !d.is_empty());
    (id, subject.unwrap_or(collection).to_string(), false)
}

/// The subject number of a CMU take id (`02` of `02_01`), if it is one.
fn subject_number(take_id: &str) -> Option<&str> {
    cmu_trial_id(take_id).and_then(|id| id.split_once('_').map(|(s, _)| s))
}

/// A directory tree or zip archive of motion files.
#[derive(Clone, Debug)]
pub struct Source {
    root: PathBuf,
    is_zip: bool,
    fallback_asf: Option<PathBuf>,
}

impl Source {
    /// Open a directory or `.zip` archive.
    pub fn open(path: &Path) -> Result<Source, SourceError> {
        let meta = std::fs::metadata(path).map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => SourceError::NotFound(path.to_path_buf()),
            _ => SourceError::Io {
                path: path.to_path_buf(),
                cause: e,
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
            fallback_asf: None,
        })
    }

    /// Use `asf` (a file outside the collection) for every AMC whose own
    /// skeleton is not found by the first three rules of [`Source::takes`].
    pub fn with_fallback_asf(mut self, asf: Option<PathBuf>) -> Source {
        self.fallback_asf = asf;
        self
    }

    /// The fallback skeleton, if any.
    pub fn fallback_asf(&self) -> Option<&Path> {
        self.fallback_asf.as_deref()
    }

    /// The collection's own name: its folder's name, or the archive's without `.zip`.
    pub fn collection_name(&self) -> String {
        let name = self
            .root
            .file_name()
            .map_or_else(|| ".".into(), |n| n.to_string_lossy().into_owned());
        match name.len().checked_sub(4) {
            Some(cut) if self.is_zip && name.is_char_boundary(cut) => name[..cut].to_string(),
            _ => name,
        }
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
    ///
    /// An AMC's skeleton is, in this order: `NN.asf` beside it (`NN` the
    /// subject number of its CMU trial id); else the only `.asf` in its
    /// folder; else the one `.asf` in its folder whose name starts with the
    /// subject number (`07-walk.asf` for `07_05-walk.amc`); else the
    /// fallback given with [`Source::with_fallback_asf`]. Names compare
    /// case-insensitively.
    pub fn takes(&self) -> Result<Vec<TakeInput>, SourceError> {
        let entries = self.entries()?;
        let collection = self.collection_name();
        let mut asfs: BTreeMap<&str, Vec<&Entry>> = BTreeMap::new();
        for e in &entries {
            if e.name.to_ascii_lowercase().ends_with(".asf") {
                asfs.entry(parent_dir(&e.name)).or_default().push(e);
            }
        }
        let mut takes = Vec::new();
        for e in &entries {
            let Some(format) = Format::of(&e.name) else {
                continue;
            };
            let (take_id, subject, cmu_trial) = take_identity(&e.name, &collection);
            let (asf, asf_search) = match format {
                Format::Bvh => (None, String::new()),
                Format::Amc => {
                    let dir = parent_dir(&e.name);
                    let in_dir = asfs.get(dir).map_or(&[][..], Vec::as_slice);
                    self.find_asf(dir, in_dir, subject_number(&take_id))
                }
            };
            takes.push(TakeInput {
                take_id,
                subject,
                cmu_trial,
                format,
                motion: e.clone(),
                asf,
                asf_search,
            });
        }
        Ok(takes)
    }

    /// The skeleton of an AMC in folder `dir` whose folder holds the `.asf`
    /// files `in_dir`, and which rule found it (or all that were tried).
    fn find_asf(
        &self,
        dir: &str,
        in_dir: &[&Entry],
        subject: Option<&str>,
    ) -> (Option<FileRef>, String) {
        let file_of = |e: &Entry| e.name.rsplit('/').next().unwrap_or(&e.name).to_string();
        let listing = |v: &[&Entry]| -> String {
            match v.len() {
                0 => "none".into(),
                n => format!(
                    "{n}: {}",
                    v.iter().map(|e| file_of(e)).collect::<Vec<_>>().join(", ")
                ),
            }
        };
        let folder = self.display_name(if dir.is_empty() { "" } else { dir });
        let mut tried = Vec::new();
        let found = |e: &Entry, rule: &str| (Some(FileRef::Entry(e.clone())), rule.to_string());
        if let Some(nn) = subject {
            let want = format!("{nn}.asf");
            if let Some(e) = in_dir
                .iter()
                .find(|e| file_of(e).eq_ignore_ascii_case(&want))
            {
                return found(e, "NN.asf beside it");
            }
            tried.push(format!("{want} beside it (absent)"));
        } else {
            tried.push("NN.asf beside it (the name has no CMU subject number)".into());
        }
        if let [only] = in_dir {
            return found(only, "the only .asf in its folder");
        }
        tried.push(format!(
            "the only .asf in {folder} (found {})",
            listing(in_dir)
        ));
        if let Some(nn) = subject {
            let starts: Vec<&Entry> = in_dir
                .iter()
                .copied()
                .filter(|e| {
                    let f = file_of(e);
                    f.starts_with(nn) && !f[nn.len()..].starts_with(|c: char| c.is_ascii_digit())
                })
                .collect();
            if let [only] = starts[..] {
                return found(only, "the .asf starting with its subject number");
            }
            tried.push(format!(
                "one .asf starting with {nn} (found {})",
                listing(&starts)
            ));
        }
        match &self.fallback_asf {
            Some(p) => (Some(FileRef::External(p.clone())), "--asf".into()),
            None => {
                tried.push("--asf (not given)".into());
                (None, tried.join("; "))
            }
        }
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

    /// How errors and reports name a file a take reads.
    pub fn display_file(&self, f: &FileRef) -> String {
        match f {
            FileRef::Entry(e) => self.display_name(&e.name),
            FileRef::External(p) => p.display().to_string(),
        }
    }

    /// [`Source::portable_name`] of a file a take reads; a file outside
    /// the collection is named by its file name.
    pub fn portable_file(&self, f: &FileRef) -> String {
        match f {
            FileRef::Entry(e) => self.portable_name(&e.name),
            FileRef::External(p) => p.file_name().map_or_else(
                || p.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            ),
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
            cause: e,
        })?;
        zip::ZipArchive::new(f).map_err(|e| SourceError::Zip {
            path: self.root.clone(),
            message: e.to_string(),
        })
    }
}

/// The folder part of an entry name (`""` at the top).
fn parent_dir(name: &str) -> &str {
    name.rsplit_once('/').map_or("", |(d, _)| d)
}

fn walk(root: &Path, dir: &Path, out: &mut Vec<Entry>) -> Result<(), SourceError> {
    let io = |e| SourceError::Io {
        path: dir.to_path_buf(),
        cause: e,
    };
    for item in std::fs::read_dir(dir).map_err(io)? {
        let item = item.map_err(io)?;
        let path = item.path();
        let meta = std::fs::metadata(&path).map_err(|e| SourceError::Io {
            path: path.clone(),
            cause: e,
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
    /// Read a file a take needs (an entry, or a file outside the collection).
    pub fn read_file(&mut self, f: &FileRef) -> std::io::Result<Vec<u8>> {
        match f {
            FileRef::Entry(e) => self.read(&e.name),
            FileRef::External(p) => std::fs::read(p),
        }
    }

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
