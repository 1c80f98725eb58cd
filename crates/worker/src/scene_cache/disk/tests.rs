//! The disk cache on real files in a temporary directory.

use super::*;

/// A directory of its own under the system's temporary directory, removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let d = std::env::temp_dir().join(format!(
            "pathfarm-scene-cache-{name}-{}-{}",
            std::process::id(),
            SystemTime::now()
                .duration_since(SystemTime::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos())
        ));
        std::fs::create_dir_all(&d).unwrap();
        TempDir(d)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A blob of `len` bytes (`fill`ed) and its hash.
fn blob(fill: u8, len: usize) -> (String, Vec<u8>) {
    let bytes = vec![fill; len];
    (hex::encode(Sha256::digest(&bytes)), bytes)
}

fn exists(cache: &DiskCache, hash: &str) -> bool {
    cache.path(hash, "scene").exists()
}

/// The sizes of the cache's files (regular files with its names) as they are on disk.
fn on_disk(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap())
        .filter(|e| is_entry_name(&e.file_name().to_string_lossy()))
        .map(|e| e.metadata().unwrap())
        .filter(|m| m.is_file())
        .map(|m| m.len())
        .sum()
}

fn modified(path: &Path) -> SystemTime {
    std::fs::metadata(path).unwrap().modified().unwrap()
}

fn set_modified(path: &Path, t: SystemTime) {
    let f = std::fs::File::options().write(true).open(path).unwrap();
    f.set_modified(t).unwrap();
}

#[test]
fn least_recently_used_files_go_first_and_the_total_stays_within_the_bound() {
    let dir = TempDir::new("lru");
    let cache = DiskCache::open(dir.0.clone(), 250).unwrap();
    let blobs: Vec<_> = (1..=4).map(|i| blob(i, 100)).collect();
    assert_eq!(
        cache.put(&blobs[0].0, "scene", &blobs[0].1).unwrap(),
        Stored::Kept { evicted: 0 }
    );
    assert_eq!(
        cache.put(&blobs[1].0, "scene", &blobs[1].1).unwrap(),
        Stored::Kept { evicted: 0 }
    );
    assert_eq!(cache.total(), 200);
    // The third does not fit beside the first two: the oldest goes.
    assert_eq!(
        cache.put(&blobs[2].0, "scene", &blobs[2].1).unwrap(),
        Stored::Kept { evicted: 1 }
    );
    assert!(!exists(&cache, &blobs[0].0));
    assert!(exists(&cache, &blobs[1].0) && exists(&cache, &blobs[2].0));
    assert_eq!((cache.total(), on_disk(&dir.0)), (200, 200));
    cache.put(&blobs[3].0, "scene", &blobs[3].1).unwrap();
    assert!(!exists(&cache, &blobs[1].0));
    assert!(exists(&cache, &blobs[2].0) && exists(&cache, &blobs[3].0));
    assert_eq!((cache.total(), on_disk(&dir.0)), (200, 200));
    // What is left reads back.
    assert_eq!(cache.get(&blobs[3].0, "scene"), Some(blobs[3].1.clone()));
    assert_eq!(cache.get(&blobs[0].0, "scene"), None);
}

#[test]
fn the_file_just_written_stays_even_when_it_alone_fills_the_bound() {
    let dir = TempDir::new("keep");
    let cache = DiskCache::open(dir.0.clone(), 100).unwrap();
    let (small, big) = (blob(1, 40), blob(2, 100));
    cache.put(&small.0, "scene", &small.1).unwrap();
    assert_eq!(
        cache.put(&big.0, "environment", &big.1).unwrap(),
        Stored::Kept { evicted: 1 }
    );
    assert!(cache.path(&big.0, "environment").exists());
    assert!(!exists(&cache, &small.0));
    assert_eq!(cache.total(), 100);
}

#[test]
fn a_blob_larger_than_the_bound_is_not_kept_and_evicts_nothing() {
    let dir = TempDir::new("large");
    let cache = DiskCache::open(dir.0.clone(), 150).unwrap();
    let (kept, large) = (blob(1, 100), blob(2, 151));
    cache.put(&kept.0, "scene", &kept.1).unwrap();
    assert_eq!(
        cache.put(&large.0, "scene", &large.1).unwrap(),
        Stored::TooLarge
    );
    assert!(!exists(&cache, &large.0));
    assert!(exists(&cache, &kept.0));
    assert_eq!((cache.total(), on_disk(&dir.0)), (100, 100));
}

#[test]
fn a_hit_makes_a_file_the_most_recently_used() {
    let dir = TempDir::new("hit");
    let cache = DiskCache::open(dir.0.clone(), 250).unwrap();
    let (a, b, c) = (blob(1, 100), blob(2, 100), blob(3, 100));
    cache.put(&a.0, "scene", &a.1).unwrap();
    cache.put(&b.0, "scene", &b.1).unwrap();
    assert!(modified(&cache.path(&a.0, "scene")) < modified(&cache.path(&b.0, "scene")));
    assert_eq!(cache.get(&a.0, "scene"), Some(a.1.clone()));
    assert!(modified(&cache.path(&a.0, "scene")) > modified(&cache.path(&b.0, "scene")));
    // `b` is now the least recently used: it goes, not `a`.
    cache.put(&c.0, "scene", &c.1).unwrap();
    assert!(exists(&cache, &a.0) && exists(&cache, &c.0));
    assert!(!exists(&cache, &b.0));
}

#[test]
fn recency_survives_a_restart() {
    let dir = TempDir::new("restart");
    let (a, b, c) = (blob(1, 100), blob(2, 100), blob(3, 100));
    {
        let cache = DiskCache::open(dir.0.clone(), 250).unwrap();
        cache.put(&a.0, "scene", &a.1).unwrap();
        cache.put(&b.0, "scene", &b.1).unwrap();
        assert_eq!(cache.get(&a.0, "scene"), Some(a.1.clone()));
    }
    let cache = DiskCache::open(dir.0.clone(), 250).unwrap();
    assert_eq!(cache.total(), 200);
    cache.put(&c.0, "scene", &c.1).unwrap();
    assert!(exists(&cache, &a.0) && exists(&cache, &c.0));
    assert!(!exists(&cache, &b.0));
}

#[test]
fn the_start_up_scan_counts_only_the_cache_files_and_evicts_down_to_the_bound() {
    let dir = TempDir::new("scan");
    let t0 = SystemTime::now() - Duration::from_secs(600);
    let files = [(blob(1, 100), 0), (blob(2, 50), 10), (blob(3, 80), 20)];
    for (i, ((hash, bytes), age)) in files.iter().enumerate() {
        let kind = if i == 1 { "environment" } else { "scene" };
        let path = dir.0.join(format!("{hash}.{kind}"));
        std::fs::write(&path, bytes).unwrap();
        set_modified(&path, t0 + Duration::from_secs(*age));
    }
    // Not the cache's: other names, a cache name on a directory.
    let hash = &files[0].0 .0;
    let others = [
        "notes.txt".to_string(),
        hash.clone(),
        format!("{hash}.png"),
        format!("{}.scene", &hash[..63]),
    ];
    for name in &others {
        std::fs::write(dir.0.join(name), vec![0u8; 1000]).unwrap();
    }
    let (dir_hash, _) = blob(9, 1);
    std::fs::create_dir(dir.0.join(format!("{dir_hash}.scene"))).unwrap();

    let cache = DiskCache::open(dir.0.clone(), 10_000).unwrap();
    assert_eq!(cache.total(), 230);
    drop(cache);
    // A lower bound: the oldest goes at start, nothing else.
    let cache = DiskCache::open(dir.0.clone(), 150).unwrap();
    assert_eq!(cache.total(), 130);
    assert!(!exists(&cache, &files[0].0 .0));
    assert!(cache.path(&files[1].0 .0, "environment").exists());
    assert!(exists(&cache, &files[2].0 .0));
    for name in &others {
        assert_eq!(
            std::fs::read(dir.0.join(name)).unwrap().len(),
            1000,
            "{name}"
        );
    }
    // A directory with a cache name is neither read nor removed.
    assert_eq!(cache.get(&dir_hash, "scene"), None);
    assert!(dir.0.join(format!("{dir_hash}.scene")).is_dir());
    // A bound of 0 keeps nothing.
    drop(cache);
    let cache = DiskCache::open(dir.0.clone(), 0).unwrap();
    assert_eq!((cache.total(), on_disk(&dir.0)), (0, 0));
    assert_eq!(
        cache.put(&files[0].0 .0, "scene", &files[0].0 .1).unwrap(),
        Stored::TooLarge
    );
    assert!(dir.0.join("notes.txt").exists());
}

#[test]
fn a_damaged_file_is_a_miss_and_removed() {
    let dir = TempDir::new("damaged");
    let cache = DiskCache::open(dir.0.clone(), 1000).unwrap();
    let (hash, bytes) = blob(1, 100);
    std::fs::write(cache.path(&hash, "scene"), b"not the scene").unwrap();
    assert_eq!(cache.get(&hash, "scene"), None);
    assert!(!exists(&cache, &hash));
    cache.put(&hash, "scene", &bytes).unwrap();
    assert_eq!(cache.get(&hash, "scene"), Some(bytes));
    // Names that are not a hash are refused either way.
    assert_eq!(cache.get("../../etc/passwd", "scene"), None);
    assert!(matches!(
        cache.put("../escape", "scene", b"x"),
        Err(DiskError::Name { .. })
    ));
    assert!(!dir.0.parent().unwrap().join("escape.scene").exists());
}

#[test]
fn old_temporary_files_of_interrupted_writes_are_removed_at_start() {
    let dir = TempDir::new("temporary");
    let (hash, _) = blob(1, 10);
    let old = dir.0.join(format!(".{hash}.scene.tmp-1-0"));
    let young = dir.0.join(format!(".{hash}.scene.tmp-1-1"));
    let other = dir.0.join(".notes.txt.tmp-1-0");
    for p in [&old, &young, &other] {
        std::fs::write(p, b"partial").unwrap();
    }
    let long_ago = SystemTime::now() - Duration::from_secs(2 * 3600);
    set_modified(&old, long_ago);
    set_modified(&other, long_ago);
    let cache = DiskCache::open(dir.0.clone(), 1000).unwrap();
    assert!(!old.exists());
    assert!(young.exists() && other.exists());
    assert_eq!(cache.total(), 0);
}

#[cfg(unix)]
mod unix {
    use super::*;
    use std::os::unix::fs::{symlink, PermissionsExt};

    fn mode(path: &Path) -> u32 {
        std::fs::symlink_metadata(path)
            .unwrap()
            .permissions()
            .mode()
            & 0o777
    }

    #[test]
    fn an_entry_that_is_a_link_is_not_followed_and_its_target_is_kept() {
        let dir = TempDir::new("link");
        let elsewhere = TempDir::new("link-target");
        let cache = DiskCache::open(dir.0.clone(), 1000).unwrap();
        let (hash, bytes) = blob(1, 100);
        // A link to other content, and a link to the very bytes of the blob: neither is read.
        let other = elsewhere.0.join("secret");
        std::fs::write(&other, b"other content").unwrap();
        let same = elsewhere.0.join("copy");
        std::fs::write(&same, &bytes).unwrap();
        for target in [&other, &same] {
            let link = cache.path(&hash, "scene");
            symlink(target, &link).unwrap();
            assert_eq!(cache.get(&hash, "scene"), None);
            // The link is gone, its target is not.
            assert!(std::fs::symlink_metadata(&link).is_err());
            assert!(target.exists());
        }
        assert_eq!(std::fs::read(&other).unwrap(), b"other content");
        assert_eq!(std::fs::read(&same).unwrap(), bytes);
        // Writing over a link replaces the link, never its target.
        symlink(&other, cache.path(&hash, "scene")).unwrap();
        cache.put(&hash, "scene", &bytes).unwrap();
        let meta = std::fs::symlink_metadata(cache.path(&hash, "scene")).unwrap();
        assert!(meta.file_type().is_file());
        assert_eq!(std::fs::read(&other).unwrap(), b"other content");
        assert_eq!(cache.get(&hash, "scene"), Some(bytes));
    }

    #[test]
    fn links_are_neither_counted_nor_evicted() {
        let dir = TempDir::new("link-evict");
        let elsewhere = TempDir::new("link-evict-target");
        let (linked, linked_bytes) = blob(9, 500);
        let target = elsewhere.0.join(format!("{linked}.scene"));
        std::fs::write(&target, &linked_bytes).unwrap();
        symlink(&target, dir.0.join(format!("{linked}.scene"))).unwrap();
        let cache = DiskCache::open(dir.0.clone(), 150).unwrap();
        assert_eq!(cache.total(), 0);
        let (a, b) = (blob(1, 100), blob(2, 100));
        cache.put(&a.0, "scene", &a.1).unwrap();
        cache.put(&b.0, "scene", &b.1).unwrap();
        assert!(!exists(&cache, &a.0) && exists(&cache, &b.0));
        assert_eq!(cache.total(), 100);
        assert!(std::fs::symlink_metadata(dir.0.join(format!("{linked}.scene"))).is_ok());
        assert_eq!(std::fs::read(&target).unwrap(), linked_bytes);
    }

    #[test]
    fn a_cache_directory_that_is_a_link_is_refused() {
        let root = TempDir::new("link-dir");
        let real = root.0.join("real");
        std::fs::create_dir(&real).unwrap();
        let (hash, bytes) = blob(1, 100);
        std::fs::write(real.join(format!("{hash}.scene")), &bytes).unwrap();
        std::fs::set_permissions(&real, std::fs::Permissions::from_mode(0o755)).unwrap();
        let link = root.0.join("scenes");
        symlink(&real, &link).unwrap();
        // Even a bound of 0 evicts nothing there: the cache is not used at all.
        assert!(DiskCache::open(link.clone(), 0).is_none());
        assert_eq!(
            std::fs::read(real.join(format!("{hash}.scene"))).unwrap(),
            bytes
        );
        assert_eq!(mode(&real), 0o755);
        // A regular file where the directory should be is refused too.
        let file = root.0.join("file");
        std::fs::write(&file, b"x").unwrap();
        assert!(DiskCache::open(file.clone(), 1000).is_none());
        assert_eq!(std::fs::read(&file).unwrap(), b"x");
    }

    #[test]
    fn the_directory_is_0700_and_the_files_0600() {
        let root = TempDir::new("perm");
        // Created (with a missing parent) private.
        let dir = root.0.join("cache").join("scenes");
        let cache = DiskCache::open(dir.clone(), 1000).unwrap();
        assert_eq!(mode(&dir), 0o700);
        let (hash, bytes) = blob(1, 100);
        cache.put(&hash, "scene", &bytes).unwrap();
        assert_eq!(mode(&cache.path(&hash, "scene")), 0o600);
        // An existing file with wider permissions is replaced by a private one.
        let (other, other_bytes) = blob(2, 100);
        std::fs::write(cache.path(&other, "scene"), b"old").unwrap();
        std::fs::set_permissions(
            cache.path(&other, "scene"),
            std::fs::Permissions::from_mode(0o644),
        )
        .unwrap();
        cache.put(&other, "scene", &other_bytes).unwrap();
        assert_eq!(mode(&cache.path(&other, "scene")), 0o600);
        // An existing directory of ours is made private when the cache opens.
        drop(cache);
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
        let cache = DiskCache::open(dir.clone(), 1000).unwrap();
        assert_eq!(mode(&dir), 0o700);
        assert_eq!(cache.get(&hash, "scene"), Some(bytes));
    }
}
