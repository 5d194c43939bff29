//! Atomic replacement of a whole directory.

use std::io;
use std::path::Path;

/// Put the complete directory `staging` at `out`. An existing `out` is
/// exchanged with `staging` atomically on Linux (`renameat2(RENAME_EXCHANGE)`)
/// and the old contents are then deleted, so readers see the old directory or
/// the new one, never a mixture or nothing. Elsewhere two renames are used.
pub fn replace_dir(staging: &Path, out: &Path) -> io::Result<()> {
    if out.exists() {
        exchange(staging, out)?;
        // `staging` now holds the previous contents.
        std::fs::remove_dir_all(staging)?;
    } else {
        std::fs::rename(staging, out)?;
    }
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty());
    if let Ok(d) = std::fs::File::open(parent.unwrap_or(Path::new("."))) {
        let _ = d.sync_all();
    }
    Ok(())
}

#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let ca = CString::new(a.as_os_str().as_bytes()).map_err(io::Error::other)?;
    let cb = CString::new(b.as_os_str().as_bytes()).map_err(io::Error::other)?;
    // SAFETY: both are valid NUL-terminated paths; renameat2 only reads them.
    let rc = unsafe {
        libc::renameat2(
            libc::AT_FDCWD,
            ca.as_ptr(),
            libc::AT_FDCWD,
            cb.as_ptr(),
            libc::RENAME_EXCHANGE,
        )
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn exchange(a: &Path, b: &Path) -> io::Result<()> {
    // Two renames: a crash in between leaves the old directory at `b.old`.
    let old = b.with_extension("old");
    std::fs::rename(b, &old)?;
    std::fs::rename(a, b)?;
    std::fs::rename(&old, a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_an_existing_directory_whole() {
        let tmp = std::env::temp_dir().join(format!("atomic-test-{}", std::process::id()));
        let (a, b) = (tmp.join("new"), tmp.join("out"));
        std::fs::create_dir_all(&a).unwrap();
        std::fs::create_dir_all(&b).unwrap();
        std::fs::write(a.join("x"), "new").unwrap();
        std::fs::write(b.join("x"), "old").unwrap();
        std::fs::write(b.join("only-old"), "old").unwrap();
        replace_dir(&a, &b).unwrap();
        assert_eq!(std::fs::read_to_string(b.join("x")).unwrap(), "new");
        assert!(!b.join("only-old").exists());
        assert!(!a.exists());
        std::fs::remove_dir_all(&tmp).unwrap();
    }
}
