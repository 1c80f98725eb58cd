//! The scene cache on disk: blobs (scenes and environment images) kept by their SHA-256 between
//! runs, bounded in bytes, private, and never read or removed through a symbolic link.
//!
//! - Names: `{hash}.scene` and `{hash}.environment` (64 hex digits). Only such regular files are
//!   counted and evicted; anything else in the directory is left alone.
//! - Bound: after a blob is written, the least recently used files go until the directory's total
//!   is within `max_bytes` (the file just written stays). A blob larger than the bound is not
//!   written at all: the worker uses it from memory and fetches it again next time, and nothing
//!   else is evicted for it (so 0 keeps nothing on disk).
//! - Recency is the file's modification time: set when the file is written and on every hit, so
//!   the order survives a restart. The directory is scanned when the cache opens (learning the
//!   total and evicting down to the bound, which may have been lowered) and again after every
//!   write: several workers on one machine (`pathfarm up`'s) share the default directory, and the
//!   bound holds for the directory as a whole when they share it too.
//! - Privacy (Unix): the directory is created 0700, or made 0700 when it exists and belongs to
//!   this user (a directory of another user's is used as it is, with a warning); files are 0600
//!   from their creation.
//! - Links: an entry that is a symbolic link, or not a regular file, is a miss: it is removed (the
//!   link, never its target) and the blob fetched again; files are opened with O_NOFOLLOW and must
//!   be the file that was checked. A cache directory that is itself a link is refused: the worker
//!   runs without a disk cache. (Only the directory's last component is checked: where its parents
//!   lead is the user's layout.)
//!
//! The hash is checked on every read, so a damaged or planted file is never used: it is removed.

use sha2::{Digest, Sha256};
use std::fs::{File, Metadata};
use std::io::{ErrorKind, Read};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, SystemTime};

/// The kinds of blob kept: the suffixes of the cache's file names.
const KINDS: [&str; 2] = ["scene", "environment"];

/// A temporary file of a write that was interrupted (a killed worker) is removed when the cache
/// opens if it is older than this; a younger one may be another worker's write in progress.
const STALE_TEMPORARY: Duration = Duration::from_secs(3600);

#[derive(Debug, thiserror::Error)]
pub enum DiskError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: a symbolic link, not a directory: not used as a cache", path.display())]
    Link { path: PathBuf },
    #[error("{}: not a directory", path.display())]
    NotDirectory { path: PathBuf },
    #[error("{name}: not a name of the scene cache's")]
    Name { name: String },
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> DiskError + '_ {
    move |source| DiskError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// What became of a blob given to [`DiskCache::put`].
#[derive(Debug, PartialEq, Eq)]
pub enum Stored {
    /// Written; `evicted` older files were removed to stay within the bound.
    Kept { evicted: usize },
    /// Larger than the bound: not written.
    TooLarge,
}

/// A cache file found by a scan.
struct Entry {
    name: String,
    len: u64,
    modified: SystemTime,
}

struct State {
    /// The directory's total (the cache's files) at the last scan, less what was evicted since.
    total: u64,
    /// The last modification time given to a file: the next is later, so that files used one
    /// after the other are ordered even where the clock is coarse.
    last_stamp: SystemTime,
}

pub struct DiskCache {
    dir: PathBuf,
    max_bytes: u64,
    state: Mutex<State>,
}

/// Whether `name` is a cache file's: `{hash}.{kind}`.
fn is_entry_name(name: &str) -> bool {
    name.split_once('.').is_some_and(|(hash, kind)| {
        hash.len() == 64 && hash.bytes().all(|b| b.is_ascii_hexdigit()) && KINDS.contains(&kind)
    })
}

/// Whether `name` is a temporary file of [`crate::files::write_private`] writing a cache file:
/// `.{hash}.{kind}.tmp-{pid}-{n}`.
fn is_temporary_name(name: &str) -> bool {
    name.strip_prefix('.')
        .and_then(|n| n.split_once(".tmp-"))
        .is_some_and(|(entry, _)| is_entry_name(entry))
}

impl DiskCache {
    /// The cache in `dir` (created, private, if missing), holding at most `max_bytes` of blobs.
    /// `None`, with a warning logged, when `dir` is a symbolic link or not a directory: the worker
    /// then keeps scenes in memory only. A directory that cannot be created or read is only
    /// logged: each write tries again.
    pub fn open(dir: PathBuf, max_bytes: u64) -> Option<DiskCache> {
        match prepare_dir(&dir) {
            Err(e @ (DiskError::Link { .. } | DiskError::NotDirectory { .. })) => {
                tracing::warn!(error = %e, "no scene cache on disk");
                return None;
            }
            Err(e) => tracing::warn!(error = %e, "cannot create the scene cache's directory"),
            Ok(()) => make_private(&dir),
        }
        let cache = DiskCache {
            dir,
            max_bytes,
            state: Mutex::new(State {
                total: 0,
                last_stamp: SystemTime::UNIX_EPOCH,
            }),
        };
        let mut state = cache.lock();
        match cache.prune(&mut state, None, true) {
            Ok((files, evicted)) => tracing::info!(
                dir = %cache.dir.display(),
                files,
                bytes = state.total,
                max_bytes,
                evicted,
                "scene cache on disk"
            ),
            Err(e) => tracing::warn!(error = %e, "cannot read the scene cache"),
        }
        drop(state);
        Some(cache)
    }

    /// The cache's files' total in bytes, as of the last scan (at open and after each write)
    /// less what was evicted since.
    #[cfg(test)]
    pub fn total(&self) -> u64 {
        self.lock().total
    }

    pub fn path(&self, hash: &str, kind: &str) -> PathBuf {
        self.dir.join(format!("{hash}.{kind}"))
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // The state is two numbers, consistent whatever a panicking holder did.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A modification time for a file used now: now, or just after the last one given.
    fn stamp(&self) -> SystemTime {
        let mut state = self.lock();
        let now = SystemTime::now();
        let stamp = if now > state.last_stamp {
            now
        } else {
            state.last_stamp + Duration::from_nanos(1)
        };
        state.last_stamp = stamp;
        stamp
    }

    /// The blob `hash` of `kind` if the cache has it, whole and true to its hash; the file then
    /// becomes the most recently used. A miss otherwise: an entry that is a link or not a regular
    /// file, or whose bytes do not hash to `hash`, is removed (logged), so it is fetched again.
    pub fn get(&self, hash: &str, kind: &str) -> Option<Vec<u8>> {
        if !is_entry_name(&format!("{hash}.{kind}")) {
            return None;
        }
        let path = self.path(hash, kind);
        let checked = match std::fs::symlink_metadata(&path) {
            Ok(m) => m,
            Err(e) if e.kind() == ErrorKind::NotFound => return None,
            Err(e) => {
                tracing::warn!(path = %path.display(), error = %e, "cannot read a cached blob");
                return None;
            }
        };
        if !checked.is_file() {
            let removed = if checked.is_dir() {
                "left alone"
            } else {
                // `remove_file` unlinks the entry itself: a link's target is untouched.
                match std::fs::remove_file(&path) {
                    Ok(()) => "removed",
                    Err(_) => "not removable",
                }
            };
            tracing::warn!(
                path = %path.display(),
                file_type = ?checked.file_type(),
                removed,
                "a scene cache entry is a link or not a regular file: not read, fetched again"
            );
            return None;
        }
        let read = open_no_follow(&path).and_then(|mut f| {
            let opened = f.metadata()?;
            if !same_file(&checked, &opened) {
                return Err(std::io::Error::other("replaced while it was opened"));
            }
            let mut bytes = Vec::with_capacity(usize::try_from(opened.len()).unwrap_or(0));
            f.read_to_end(&mut bytes)?;
            Ok((f, bytes))
        });
        let (file, bytes) = match read {
            Ok(r) => r,
            Err(e) => {
                tracing::warn!(path = %path.display(), error = %e, "cannot read a cached blob");
                return None;
            }
        };
        if hex::encode(Sha256::digest(&bytes)) != hash {
            let _ = std::fs::remove_file(&path);
            tracing::warn!(path = %path.display(), "a cached blob fails its hash: removed");
            return None;
        }
        // A hit: the most recently used now. A file whose time cannot be set (not ours) is still
        // used; it only keeps its place in the order.
        if let Err(e) = file.set_modified(self.stamp()) {
            tracing::debug!(path = %path.display(), error = %e, "cannot mark a cached blob used");
        }
        Some(bytes)
    }

    /// Writes the blob `hash` of `kind` (private, atomically) as the most recently used file, then
    /// evicts the least recently used others until the cache is within its bound. A blob larger
    /// than the bound is not written ([`Stored::TooLarge`]).
    pub fn put(&self, hash: &str, kind: &str, bytes: &[u8]) -> Result<Stored, DiskError> {
        // Only names a scan counts: a file the bound would not see is never written.
        let name = format!("{hash}.{kind}");
        if !is_entry_name(&name) {
            return Err(DiskError::Name { name });
        }
        if bytes.len() as u64 > self.max_bytes {
            return Ok(Stored::TooLarge);
        }
        prepare_dir(&self.dir)?;
        let path = self.dir.join(&name);
        crate::files::write_private(&path, bytes, self.stamp()).map_err(io_error(&path))?;
        let mut state = self.lock();
        let (_, evicted) = self.prune(&mut state, Some(&name), false)?;
        tracing::debug!(
            file = name,
            bytes = bytes.len(),
            total = state.total,
            evicted,
            "cached on disk"
        );
        Ok(Stored::Kept { evicted })
    }

    /// Scans the directory and removes the least recently used files (not `keep`) until the total
    /// is within the bound; with `stale`, also interrupted writes' old temporary files. The number
    /// of cache files found and of those evicted.
    fn prune(
        &self,
        state: &mut State,
        keep: Option<&str>,
        stale: bool,
    ) -> Result<(usize, usize), DiskError> {
        let mut entries = self.scan(stale)?;
        let found = entries.len();
        let mut total = entries.iter().fold(0u64, |t, e| t.saturating_add(e.len));
        // Oldest first; equal times (a coarse file system) in name order, so the order is stable.
        entries.sort_by(|a, b| a.modified.cmp(&b.modified).then(a.name.cmp(&b.name)));
        let mut evicted = 0;
        for e in entries {
            if total <= self.max_bytes {
                break;
            }
            if keep == Some(e.name.as_str()) {
                continue;
            }
            match std::fs::remove_file(self.dir.join(&e.name)) {
                Ok(()) => {
                    evicted += 1;
                    total -= e.len;
                    tracing::debug!(file = e.name, bytes = e.len, "evicted from the scene cache");
                }
                // Another worker sharing the directory evicted it first.
                Err(err) if err.kind() == ErrorKind::NotFound => total -= e.len,
                Err(err) => tracing::warn!(
                    file = e.name,
                    error = %err,
                    "cannot evict a file from the scene cache"
                ),
            }
        }
        state.total = total;
        Ok((found, evicted))
    }

    /// The cache's files: regular files with its names. Links (their targets are elsewhere) and
    /// other files are skipped. With `stale`, old temporary files of interrupted writes go.
    fn scan(&self, stale: bool) -> Result<Vec<Entry>, DiskError> {
        // A directory replaced by a link since it was opened is not followed: its files are not
        // ours to evict.
        match std::fs::symlink_metadata(&self.dir) {
            Ok(m) if m.file_type().is_symlink() => {
                return Err(DiskError::Link {
                    path: self.dir.clone(),
                })
            }
            Err(e) if e.kind() == ErrorKind::NotFound => return Ok(Vec::new()),
            _ => {}
        }
        let now = SystemTime::now();
        let mut entries = Vec::new();
        for entry in std::fs::read_dir(&self.dir).map_err(io_error(&self.dir))? {
            let Ok(entry) = entry else { continue };
            let Ok(name) = entry.file_name().into_string() else {
                continue;
            };
            // `DirEntry::metadata` does not follow a link: a link is not a file here.
            let Ok(meta) = entry.metadata() else { continue };
            if !meta.is_file() {
                continue;
            }
            let modified = meta.modified().unwrap_or(SystemTime::UNIX_EPOCH);
            if is_entry_name(&name) {
                entries.push(Entry {
                    name,
                    len: meta.len(),
                    modified,
                });
            } else if stale
                && is_temporary_name(&name)
                && now.duration_since(modified).unwrap_or_default() > STALE_TEMPORARY
            {
                match std::fs::remove_file(entry.path()) {
                    Ok(()) => tracing::debug!(file = name, "removed an interrupted write"),
                    Err(e) => tracing::debug!(file = name, error = %e, "cannot remove a temporary"),
                }
            }
        }
        Ok(entries)
    }
}

/// Makes sure `dir` is a directory (not a link to one), creating it private if it is missing.
fn prepare_dir(dir: &Path) -> Result<(), DiskError> {
    let checked = |meta: std::io::Result<Metadata>| match meta {
        Ok(m) if m.file_type().is_symlink() => Err(DiskError::Link {
            path: dir.to_path_buf(),
        }),
        Ok(m) if !m.is_dir() => Err(DiskError::NotDirectory {
            path: dir.to_path_buf(),
        }),
        Ok(_) => Ok(()),
        Err(e) => Err(io_error(dir)(e)),
    };
    match std::fs::symlink_metadata(dir) {
        Err(e) if e.kind() == ErrorKind::NotFound => {
            let mut builder = std::fs::DirBuilder::new();
            builder.recursive(true);
            #[cfg(unix)]
            {
                // Missing parents too (~/.cache/pathfarm): 0700, as the XDG cache's should be.
                use std::os::unix::fs::DirBuilderExt;
                builder.mode(0o700);
            }
            builder.create(dir).map_err(io_error(dir))?;
            // Created meanwhile by someone else, as a link, `create` does not fail: look again.
            checked(std::fs::symlink_metadata(dir))
        }
        meta => checked(meta),
    }
}

/// Makes the directory `dir` 0700 if it belongs to this user; logs a warning if it does not. The
/// directory is opened without following a link and changed through that handle, so it is the
/// directory that was checked.
#[cfg(unix)]
fn make_private(dir: &Path) {
    use rustix::fs::OFlags;
    use std::os::unix::fs::{MetadataExt, OpenOptionsExt, PermissionsExt};
    let opened = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags((OFlags::NOFOLLOW | OFlags::DIRECTORY).bits() as i32)
        .open(dir)
        .and_then(|d| Ok((d.metadata()?, d)));
    let (meta, handle) = match opened {
        Ok(o) => o,
        Err(e) => {
            tracing::warn!(
                dir = %dir.display(),
                error = %e,
                "cannot check the scene cache's permissions"
            );
            return;
        }
    };
    let mode = meta.mode() & 0o777;
    if meta.uid() != rustix::process::geteuid().as_raw() {
        tracing::warn!(
            dir = %dir.display(),
            owner = meta.uid(),
            mode = format!("{mode:o}"),
            "the scene cache's directory belongs to another user: its permissions are left alone"
        );
    } else if mode != 0o700 {
        match handle.set_permissions(std::fs::Permissions::from_mode(0o700)) {
            Ok(()) => tracing::info!(
                dir = %dir.display(),
                was = format!("{mode:o}"),
                "made the scene cache's directory private (0700)"
            ),
            Err(e) => tracing::warn!(
                dir = %dir.display(),
                error = %e,
                "cannot make the scene cache's directory private"
            ),
        }
    }
}

#[cfg(not(unix))]
fn make_private(_dir: &Path) {}

/// Opens `path` for reading, failing (ELOOP) if it is a symbolic link. O_NONBLOCK: a FIFO put there
/// after the check does not block the open (it changes nothing for a regular file).
#[cfg(unix)]
fn open_no_follow(path: &Path) -> std::io::Result<File> {
    use rustix::fs::OFlags;
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .read(true)
        .custom_flags((OFlags::NOFOLLOW | OFlags::NONBLOCK).bits() as i32)
        .open(path)
}

/// Elsewhere there is no O_NOFOLLOW: the `symlink_metadata` check before the open is what keeps
/// links out.
#[cfg(not(unix))]
fn open_no_follow(path: &Path) -> std::io::Result<File> {
    File::open(path)
}

/// Whether the opened file is the regular file that was checked (not replaced in between).
#[cfg(unix)]
fn same_file(checked: &Metadata, opened: &Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    opened.is_file() && checked.dev() == opened.dev() && checked.ino() == opened.ino()
}

#[cfg(not(unix))]
fn same_file(_checked: &Metadata, opened: &Metadata) -> bool {
    opened.is_file()
}

#[cfg(test)]
mod tests;
