//! Filesystem helpers the store's modules share: the time, the host name, unique names,
//! sorted listings, permissions, removal, and reads that never open a special file.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// A name made once: the pid, a per-process counter and the clock's nanoseconds (for
/// temporary files and folders in the store).
pub(crate) fn unique_suffix() -> String {
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    format!("{}-{n}-{t:x}", std::process::id())
}

/// Seconds since the Unix epoch.
pub fn now_unix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// This machine's host name.
pub fn hostname() -> String {
    fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| fs::read_to_string("/etc/hostname"))
        .map(|s| s.trim().to_string())
        .or_else(|_| std::env::var("HOSTNAME"))
        .unwrap_or_else(|_| "unknown".into())
}

/// The entries of a folder, sorted (none if it cannot be read).
pub(crate) fn list_dir(p: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = fs::read_dir(p)
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    v.sort();
    v
}

/// A file's modification time in nanoseconds since the epoch (−1 when unknown): with its size
/// and inode, what the external inputs' hash cache compares.
pub(crate) fn mtime_ns(meta: &fs::Metadata) -> i128 {
    meta.modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_nanos() as i128)
        .unwrap_or(-1)
}

/// Sets or clears the write bits of a file or folder (best effort).
pub(crate) fn set_readonly(p: &Path, ro: bool) {
    if let Ok(m) = fs::metadata(p) {
        let mut perm = m.permissions();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = perm.mode();
            perm.set_mode(if ro { mode & !0o222 } else { mode | 0o200 });
        }
        #[cfg(not(unix))]
        perm.set_readonly(ro);
        let _ = fs::set_permissions(p, perm);
    }
}

/// The number of hard links to a file (1 where unknown).
pub(crate) fn link_count(p: &Path) -> u64 {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        fs::symlink_metadata(p).map(|m| m.nlink()).unwrap_or(1)
    }
    #[cfg(not(unix))]
    {
        let _ = p;
        1
    }
}

/// Clears the write bits of a folder tree (best effort).
pub(crate) fn set_tree_readonly(p: &Path) {
    if let Ok(rd) = fs::read_dir(p) {
        for e in rd.flatten() {
            if e.file_type().map(|t| t.is_dir()).unwrap_or(false) {
                set_tree_readonly(&e.path());
            }
        }
    }
    set_readonly(p, true);
}

/// Removes a file or folder tree, making read-only folders writable first. Errors are ignored
/// (a later `gc` retries).
pub fn remove_tree(p: &Path) {
    fn unlock(p: &Path) {
        set_readonly(p, false);
        if let Ok(rd) = fs::read_dir(p) {
            for e in rd.flatten() {
                if e.file_type().map(|t| t.is_dir()).unwrap_or(false) {
                    unlock(&e.path());
                }
            }
        }
    }
    if p.is_dir() {
        unlock(p);
        let _ = fs::remove_dir_all(p);
    } else {
        let _ = fs::remove_file(p);
    }
}

/// Reads a file that must be a plain file (never opens a FIFO, socket or device, which could
/// block forever).
pub(crate) fn read_plain(p: &Path) -> std::io::Result<Vec<u8>> {
    let meta = fs::symlink_metadata(p)?;
    if !meta.file_type().is_file() {
        return Err(std::io::Error::other(
            "not a plain file (a link, FIFO, socket or device)",
        ));
    }
    fs::read(p)
}

/// The inode of a file (0 where unknown): a file that shares a good blob's inode is that blob.
pub(crate) fn inode(meta: &fs::Metadata) -> u64 {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        meta.ino()
    }
    #[cfg(not(unix))]
    {
        let _ = meta;
        0
    }
}

/// A path's file name without its extension, as text (empty when it has none).
pub(crate) fn file_stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default()
}

/// A path's file name, as text (empty when it has none).
pub(crate) fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default()
}
