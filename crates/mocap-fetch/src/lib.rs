//! Download an archive once into a cache: `cargo xtask dataset` without
//! `--source` fetches CMU's `allasfamc.zip` this way. The download goes to
//! a `.part` file renamed when complete, so the cache never holds half a
//! file under the final name; progress is reported to the caller.

use sha2::{Digest, Sha256};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Why a download failed.
#[derive(Debug, thiserror::Error)]
pub enum FetchError {
    /// The request or the transfer failed.
    #[error(
        "downloading {url}: {message} (no network? download it yourself and pass --source PATH)"
    )]
    Download {
        /// What was asked for.
        url: String,
        /// What went wrong.
        message: String,
    },
    /// The cache could not be written.
    #[error("{}: {cause}", path.display())]
    Cache {
        /// The file or directory.
        path: PathBuf,
        /// The cause.
        cause: std::io::Error,
    },
}

/// Bytes received so far and the total when the server says it.
pub type Progress<'a> = &'a dyn Fn(u64, Option<u64>);

/// The path of `url`'s copy under `cache` (whether or not it is there):
/// the URL's last segment behind 12 hex digits of its SHA-256.
pub fn cache_path(url: &str, cache: &Path) -> PathBuf {
    let name = url
        .rsplit('/')
        .next()
        .filter(|n| !n.is_empty())
        .unwrap_or("download");
    let key: String = Sha256::digest(url.as_bytes())[..6]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    cache.join(format!("{key}-{name}"))
}

/// The cached copy of `url` under `cache`: downloaded on first use,
/// reused afterwards ([`cache_path`] says whether it is there).
pub fn cached(url: &str, cache: &Path, progress: Progress) -> Result<PathBuf, FetchError> {
    let path = cache_path(url, cache);
    if path.is_file() {
        return Ok(path);
    }
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |cause| FetchError::Cache { path, cause }
    };
    std::fs::create_dir_all(cache).map_err(io(cache))?;
    let part = path.with_extension("part");
    download(url, &part, progress).map_err(|message| FetchError::Download {
        url: url.to_string(),
        message,
    })?;
    std::fs::rename(&part, &path).map_err(io(&part))?;
    Ok(path)
}

fn download(url: &str, to: &Path, progress: Progress) -> Result<(), String> {
    let mut resp = ureq::get(url).call().map_err(|e| e.to_string())?;
    let len = resp
        .headers()
        .get("content-length")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    let mut reader = resp.body_mut().as_reader();
    let fail = |e: std::io::Error| format!("{}: {e}", to.display());
    let mut file = std::fs::File::create(to).map_err(fail)?;
    let mut buf = vec![0u8; 1 << 16];
    let mut total = 0u64;
    loop {
        let n = reader.read(&mut buf).map_err(|e| e.to_string())?;
        if n == 0 {
            break;
        }
        file.write_all(&buf[..n]).map_err(fail)?;
        total += n as u64;
        progress(total, len);
    }
    file.sync_all().map_err(fail)?;
    match len {
        Some(l) if l != total => Err(format!("connection closed after {total} of {l} bytes")),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{BufRead, Write};
    use std::net::TcpListener;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;

    /// A one-file HTTP server on 127.0.0.1 that counts its requests.
    fn serve(body: Vec<u8>, max_requests: usize) -> (String, Arc<AtomicUsize>) {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let hits = Arc::new(AtomicUsize::new(0));
        let h = hits.clone();
        std::thread::spawn(move || {
            for stream in listener.incoming().take(max_requests) {
                let Ok(mut s) = stream else { continue };
                let mut r = std::io::BufReader::new(s.try_clone().unwrap());
                let mut line = String::new();
                while r.read_line(&mut line).is_ok_and(|n| n > 2) {
                    line.clear();
                }
                h.fetch_add(1, Ordering::SeqCst);
                let head = format!(
                    "HTTP/1.1 200 OK\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
                    body.len()
                );
                let _ = s.write_all(head.as_bytes());
                let _ = s.write_all(&body);
            }
        });
        (format!("http://{addr}/sub/sample.zip"), hits)
    }

    #[test]
    fn downloads_once_then_uses_the_cache() {
        let body: Vec<u8> = (0..300_000u32).map(|i| (i % 251) as u8).collect();
        let (url, hits) = serve(body.clone(), 4);
        let cache = tempfile::tempdir().unwrap();
        let a = cached(&url, cache.path(), &|_, _| {}).unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), body);
        assert!(a
            .file_name()
            .unwrap()
            .to_string_lossy()
            .ends_with("-sample.zip"));
        let b = cached(&url, cache.path(), &|_, _| {}).unwrap();
        assert_eq!(a, b);
        assert_eq!(
            hits.load(Ordering::SeqCst),
            1,
            "second call must not download"
        );
    }

    #[test]
    fn unreachable_url_is_a_clear_error() {
        let cache = tempfile::tempdir().unwrap();
        // Port 9 (discard) on loopback: nothing listens there.
        let err = cached("http://127.0.0.1:9/allasfamc.zip", cache.path(), &|_, _| {}).unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("downloading http://127.0.0.1:9/allasfamc.zip"),
            "{text}"
        );
        assert!(text.contains("--source"), "{text}");
        assert!(!cache.path().join("allasfamc.zip").exists());
    }
}
