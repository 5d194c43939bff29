//! The architecture's rules that code can check (docs/ARCHITECTURE.md):
//! inside each library crate no two top-level modules import each other,
//! directly or through others; `xtask/src` stays thin; no source file over
//! 1,000 lines and no function over 100; the README and the training
//! reference stay short enough to read.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The top-level module a file of `src` belongs to (`lib` for lib.rs).
fn module_of(src: &Path, file: &Path) -> String {
    let rel = file.strip_prefix(src).unwrap();
    let first = rel
        .components()
        .next()
        .unwrap()
        .as_os_str()
        .to_string_lossy();
    first.trim_end_matches(".rs").to_string()
}

/// Code of a file without its test module and comments.
fn code(text: &str) -> String {
    let text = text.split("#[cfg(test)]").next().unwrap_or("");
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Top-level module → the top-level modules of its crate it names
/// (`crate::m`, or `super::m` one level down).
fn imports(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let modules: BTreeSet<String> = files.iter().map(|f| module_of(src, f)).collect();
    let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for f in &files {
        let m = module_of(src, f);
        let nested = f.parent() != Some(src);
        let text = code(&std::fs::read_to_string(f).unwrap());
        for (prefix, allowed) in [
            ("crate::", true),
            ("super::", !nested || f.ends_with("mod.rs")),
        ] {
            if !allowed {
                continue;
            }
            for part in text.split(prefix).skip(1) {
                let name: String = part
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                if name != m && modules.contains(&name) {
                    g.entry(m.clone()).or_default().insert(name);
                }
            }
        }
    }
    g
}

/// A cycle through `start`, if any.
fn cycle(g: &BTreeMap<String, BTreeSet<String>>, start: &str) -> Option<Vec<String>> {
    let mut stack = vec![vec![start.to_string()]];
    let mut seen = BTreeSet::new();
    while let Some(path) = stack.pop() {
        let last = path.last().unwrap();
        for next in g.get(last).into_iter().flatten() {
            if next == start {
                let mut c = path.clone();
                c.push(next.clone());
                return Some(c);
            }
            if seen.insert(next.clone()) {
                let mut p = path.clone();
                p.push(next.clone());
                stack.push(p);
            }
        }
    }
    None
}

#[test]
fn no_import_circle_inside_a_crate() {
    let crates = workspace().join("crates");
    let mut circles = Vec::new();
    let mut checked = 0;
    for e in std::fs::read_dir(&crates).unwrap().flatten() {
        let src = e.path().join("src");
        if !src.is_dir() {
            continue;
        }
        let g = imports(&src);
        checked += 1;
        for m in g.keys() {
            if let Some(c) = cycle(&g, m) {
                circles.push(format!(
                    "{}: {}",
                    e.file_name().to_string_lossy(),
                    c.join(" → ")
                ));
            }
        }
    }
    assert!(
        checked >= 6,
        "only {checked} crates found under {}",
        crates.display()
    );
    assert!(
        circles.is_empty(),
        "import circles:\n{}",
        circles.join("\n")
    );
}

#[test]
fn the_checker_sees_a_circle() {
    let g: BTreeMap<String, BTreeSet<String>> = [
        ("train", &["generate", "model"][..]),
        ("generate", &["train"][..]),
        ("model", &["blocks"][..]),
        ("blocks", &[][..]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.iter().map(|s| s.to_string()).collect()))
    .collect();
    assert_eq!(
        cycle(&g, "generate"),
        Some(vec!["generate".into(), "train".into(), "generate".into()])
    );
    assert_eq!(cycle(&g, "model"), None);
}

#[test]
fn xtask_stays_thin() {
    let mut files = Vec::new();
    rust_files(&workspace().join("xtask/src"), &mut files);
    let lines: usize = files
        .iter()
        .map(|f| std::fs::read_to_string(f).unwrap().lines().count())
        .sum();
    assert!(
        lines < 1500,
        "xtask/src has {lines} lines: move the work into a library crate (docs/ARCHITECTURE.md)"
    );
}

/// Every `.rs` file of the library crates' `src` and of `xtask/src`.
fn source_files() -> Vec<PathBuf> {
    let mut files = Vec::new();
    for e in std::fs::read_dir(workspace().join("crates"))
        .unwrap()
        .flatten()
    {
        rust_files(&e.path().join("src"), &mut files);
    }
    rust_files(&workspace().join("xtask/src"), &mut files);
    files.sort();
    files
}

/// The functions of `text` longer than `limit` lines (from the `fn` line to
/// the brace that closes it at the same indentation): name and length.
fn long_functions(text: &str, limit: usize) -> Vec<(String, usize)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let line = lines[i];
        let body = line.trim_start();
        let indent = line.len() - body.len();
        let name = [
            "pub fn ",
            "fn ",
            "pub(crate) fn ",
            "pub(super) fn ",
            "unsafe fn ",
        ]
        .iter()
        .find_map(|p| body.strip_prefix(p))
        .map(|rest| rest.split(['(', '<']).next().unwrap_or("").to_string());
        match name {
            Some(name) if !body.trim_end().ends_with(';') => {
                let end = (i + 1..lines.len()).find(|&j| {
                    let l = lines[j].as_bytes();
                    l.len() > indent && l[..indent].iter().all(|&b| b == b' ') && l[indent] == b'}'
                });
                let end = end.unwrap_or(lines.len() - 1);
                if end - i + 1 > limit {
                    out.push((name, end - i + 1));
                }
                i = end + 1;
            }
            _ => i += 1,
        }
    }
    out
}

#[test]
fn the_function_checker_counts_from_fn_to_its_brace() {
    let text =
        "fn short() {\n    1\n}\n\n    pub fn long() -> u8 {\n        a();\n        b();\n    }\n";
    assert_eq!(long_functions(text, 3), [("long".to_string(), 4)]);
    assert!(long_functions(text, 4).is_empty());
}

#[test]
fn no_source_file_over_1000_lines_and_no_function_over_100() {
    let mut bad = Vec::new();
    for f in source_files() {
        let text = std::fs::read_to_string(&f).unwrap();
        let rel = f
            .strip_prefix(workspace())
            .unwrap_or(&f)
            .display()
            .to_string();
        let n = text.lines().count();
        if n > 1000 {
            bad.push(format!("{rel}: {n} lines"));
        }
        for (name, len) in long_functions(&text, 100) {
            bad.push(format!("{rel}: fn {name} is {len} lines"));
        }
    }
    assert!(
        bad.is_empty(),
        "split these (at most 1,000 lines a file, 100 a function):\n{}",
        bad.join("\n")
    );
}

#[test]
fn the_readme_and_the_training_reference_stay_short() {
    let read = |p: &str| std::fs::read_to_string(workspace().join(p)).unwrap();
    let words = read("README.md").split_whitespace().count();
    assert!(words <= 1200, "README.md has {words} words (at most 1,200)");
    let lines = read("docs/training.md").lines().count();
    assert!(
        lines <= 800,
        "docs/training.md has {lines} lines (at most 800)"
    );
}
