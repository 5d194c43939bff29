//! Download an archive once into a cache, with a progress bar.

use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use sha2::{Digest, Sha256};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The cached copy of `url` under `cache`: downloaded on first use (to a
/// `.part` file renamed when complete), reused afterwards.
pub fn cached(url: &str, cache: &Path, quiet: bool) -> Result<PathBuf> {
    let name = url
        .rsplit('/')
        .next()
        .filter(|n| !n.is_empty())
        .unwrap_or("download");
    let key: String = Sha256::digest(url.as_bytes())[..6]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    let path = cache.join(format!("{key}-{name}"));
    if path.is_file() {
        if !quiet {
            eprintln!("using cached {} (from {url})", path.display());
        }
        return Ok(path);
    }
    std::fs::create_dir_all(cache)
        .with_context(|| format!("creating cache {}", cache.display()))?;
    let part = path.with_extension("part");
    download(url, &part, quiet).with_context(|| {
        format!("downloading {url} (no network? download it yourself and pass --source PATH)")
    })?;
    std::fs::rename(&part, &path).with_context(|| format!("renaming {}", part.display()))?;
    Ok(path)
}

fn download(url: &str, to: &Path, quiet: bool) -> Result<()> {
    let mut resp = ureq::get(url).call()?;
    let len = resp
        .headers()
        .get("content-length")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(len.unwrap_or(0))
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} {bar:40} {bytes}/{total_bytes} {bytes_per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("downloading {url}"));
    let mut reader = resp.body_mut().as_reader();
    let mut file =
        std::fs::File::create(to).with_context(|| format!("creating {}", to.display()))?;
    let mut buf = vec![0u8; 1 << 16];
    let mut total = 0u64;
    loop {
        let n = reader.read(&mut buf)?;
        if n == 0 {
            break;
        }
        file.write_all(&buf[..n])?;
        total += n as u64;
        bar.set_position(total);
    }
    file.sync_all()?;
    bar.finish_and_clear();
    if let Some(l) = len {
        if l != total {
            bail!("connection closed after {total} of {l} bytes");
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::BufRead;
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
        let a = cached(&url, cache.path(), true).unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), body);
        assert!(a
            .file_name()
            .unwrap()
            .to_string_lossy()
            .ends_with("-sample.zip"));
        let b = cached(&url, cache.path(), true).unwrap();
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
        let err = cached("http://127.0.0.1:9/allasfamc.zip", cache.path(), true).unwrap_err();
        assert!(format!("{err:#}").contains("downloading http://127.0.0.1:9/allasfamc.zip"));
        assert!(!cache.path().join("allasfamc.zip").exists());
    }
}
