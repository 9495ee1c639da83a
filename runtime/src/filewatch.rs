//! What a file watcher compares between polls: inode, device, length and modification/change
//! times. Editing in place changes the times and length; replacing by rename changes the inode.
//! Shared by the calibrator's calibration watcher and the estimator's model watcher.

use std::os::unix::fs::MetadataExt;
use std::path::Path;

/// A file's identity and state as of one poll.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FileSignature {
    ino: u64,
    dev: u64,
    len: u64,
    mtime_ns: i128,
    ctime_ns: i128,
}

impl FileSignature {
    /// The file's signature now, or None when it cannot be read (e.g. deleted).
    pub fn of(path: &Path) -> Option<FileSignature> {
        let m = std::fs::metadata(path).ok()?;
        Some(FileSignature {
            ino: m.ino(),
            dev: m.dev(),
            len: m.len(),
            mtime_ns: m.mtime() as i128 * 1_000_000_000 + m.mtime_nsec() as i128,
            ctime_ns: m.ctime() as i128 * 1_000_000_000 + m.ctime_nsec() as i128,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replacement_and_deletion_change_the_signature() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("f");
        std::fs::write(&p, "a").expect("write");
        let a = FileSignature::of(&p);
        assert!(a.is_some());
        assert_eq!(a, FileSignature::of(&p));
        let tmp = dir.path().join("g");
        std::fs::write(&tmp, "a").expect("write");
        std::fs::rename(&tmp, &p).expect("rename");
        assert_ne!(a, FileSignature::of(&p), "same content, new inode");
        std::fs::remove_file(&p).expect("remove");
        assert_eq!(FileSignature::of(&p), None);
    }
}
