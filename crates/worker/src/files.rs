//! Writing a file so that it is never seen half-written: the scene cache, and the images the
//! command-line tools save.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::SystemTime;

/// Writes `bytes` to `path` atomically: into a temporary file in the same directory, synced to
/// disk, then renamed over `path`. A crash or a full disk leaves the previous file (or none), never
/// a truncated one, and the temporary file is removed on failure. An existing file's permissions
/// are kept; a symbolic link is written through (its target is replaced).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let path = resolve_link(path);
    write_via_temporary(&path, bytes, false, |f| {
        if let Ok(meta) = std::fs::metadata(&path) {
            f.set_permissions(meta.permissions())?;
        }
        Ok(())
    })
}

/// [`write_atomic`] for the scene cache: the file is its owner's alone (0600 on Unix, from the
/// moment the temporary file is created, so no other user can open it meanwhile), last modified at
/// `modified` (the cache's recency), and a symbolic link at `path` is replaced by the file, its
/// target left alone: the rename replaces the directory entry, whatever it is.
pub(crate) fn write_private(
    path: &Path,
    bytes: &[u8],
    modified: SystemTime,
) -> std::io::Result<()> {
    write_via_temporary(path, bytes, true, |f| {
        #[cfg(unix)]
        {
            // The umask may have taken bits from the mode asked for at creation: exactly 0600.
            use std::os::unix::fs::PermissionsExt;
            f.set_permissions(std::fs::Permissions::from_mode(0o600))?;
        }
        f.set_modified(modified)
    })
}

/// Writes `bytes` into a new temporary file beside `path` (readable by its owner only when
/// `private`), lets `finish` set its permissions and times, syncs it and renames it over `path`.
fn write_via_temporary(
    path: &Path,
    bytes: &[u8],
    private: bool,
    finish: impl FnOnce(&File) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path.file_name().ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{} is not a file name", path.display()),
        )
    })?;
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let tmp = dir.join(format!(
        ".{}.tmp-{}-{}",
        name.to_string_lossy(),
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ));
    let written = (|| {
        let mut options = std::fs::OpenOptions::new();
        // `create_new` (O_EXCL) does not follow a link left at the temporary name either.
        options.write(true).create_new(true);
        #[cfg(unix)]
        if private {
            use std::os::unix::fs::OpenOptionsExt;
            options.mode(0o600);
        }
        #[cfg(not(unix))]
        let _ = private;
        let mut f = options.open(&tmp)?;
        f.write_all(bytes)?;
        finish(&f)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    // The rename itself reaches the disk with the directory; best effort (not every platform or
    // file system can sync a directory).
    if let Ok(d) = std::fs::File::open(&dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Where a symbolic link points (so the link stays a link); anything else as it is.
fn resolve_link(path: &Path) -> PathBuf {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => {
            std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
        }
        _ => path.to_path_buf(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Dir(PathBuf);
    impl Dir {
        fn new(name: &str) -> Dir {
            let d = std::env::temp_dir().join(format!(
                "pathfarm-files-{name}-{}-{}",
                std::process::id(),
                std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_nanos())
            ));
            std::fs::create_dir_all(&d).unwrap();
            Dir(d)
        }
        fn entries(&self) -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(&self.0)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        }
    }
    impl Drop for Dir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    /// Over an existing file, a reader sees the old bytes or the new ones, whole, never a mix or
    /// a truncated file; no temporary file is left.
    #[test]
    fn writing_over_a_file_shows_the_old_or_the_new_bytes_and_leaves_no_temporary() {
        let dir = Dir::new("over");
        let path = dir.0.join("image.exr");
        let old = vec![1u8; 256 << 10];
        let new = vec![2u8; 128 << 10];
        std::fs::write(&path, &old).unwrap();
        let done = std::sync::atomic::AtomicBool::new(false);
        std::thread::scope(|s| {
            s.spawn(|| {
                let mut reads = 0;
                while !done.load(Ordering::SeqCst) || reads == 0 {
                    let got = std::fs::read(&path).unwrap();
                    assert!(got == old || got == new, "read {} mixed bytes", got.len());
                    reads += 1;
                }
            });
            for i in 0..40 {
                write_atomic(&path, if i % 2 == 0 { &new } else { &old }).unwrap();
            }
            done.store(true, Ordering::SeqCst);
        });
        assert_eq!(std::fs::read(&path).unwrap(), old);
        write_atomic(&path, &new).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), new);
        assert_eq!(dir.entries(), vec!["image.exr".to_string()]);
    }

    /// A failed write leaves what was there and no temporary file.
    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = Dir::new("fail");
        // Renaming a file over a non-empty directory fails after the temporary file was written.
        let target = dir.0.join("out.png");
        std::fs::create_dir(&target).unwrap();
        std::fs::write(target.join("keep"), b"old").unwrap();
        assert!(write_atomic(&target, b"new").is_err());
        assert_eq!(std::fs::read(target.join("keep")).unwrap(), b"old");
        assert_eq!(dir.entries(), vec!["out.png".to_string()]);
        // A missing directory: an error, nothing created.
        assert!(write_atomic(&dir.0.join("no/such/dir/x.exr"), b"new").is_err());
        assert_eq!(dir.entries(), vec!["out.png".to_string()]);
    }

    #[cfg(unix)]
    #[test]
    fn permissions_are_kept_and_links_written_through() {
        use std::os::unix::fs::PermissionsExt;
        let dir = Dir::new("perm");
        let path = dir.0.join("a.png");
        std::fs::write(&path, b"old").unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o640)).unwrap();
        let link = dir.0.join("link.png");
        std::os::unix::fs::symlink(&path, &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o640);
        assert_eq!(
            dir.entries(),
            vec!["a.png".to_string(), "link.png".to_string()]
        );
    }
}
