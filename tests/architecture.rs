//! The architecture's rules that code can check (docs/ARCHITECTURE.md):
//! inside each library crate no two top-level modules import each other,
//! directly or through others, and `xtask/src` stays thin.

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
