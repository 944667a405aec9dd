//! Atomic file replacement shared by every writer in the crate
//! ([`crate::io::write_atomically`], [`crate::audio::write_wav`]).
//!
//! The file is written to a temporary `<dir>/.<name>.tmp.<pid>` in the same
//! directory, fsynced, and renamed over the final path. Rename within one
//! directory is atomic on POSIX, so readers see the old file or the complete
//! new one. The temporary is removed if writing it or anything after that
//! fails; after a successful rename the directory is fsynced (best effort) so
//! the rename itself survives a crash.
//!
//! # A write that fails after the work
//!
//! A disk that fills during a long run (or a quota, a file size limit, a file system remounted
//! read-only) makes the write fail deep in HDF5 or the PNG encoder, whose text names the hidden
//! temporary. So when writing fails, the cause is looked for before the temporary is removed:
//! the OS error the failure carries ([`AtomicWriteError::os_error`]; HDF5 gives it only as
//! `errno = N` in its text, [`errno_in`]), else the process's file size limit
//! (`RLIMIT_FSIZE`, `ulimit -f`) if the temporary reached it, else a probe of 64 KiB written
//! beside it. A cause found becomes one line naming the final path
//! ([`AtomicWriteError::write_failed`], with [`crate::io::preflight::describe_write_error`]);
//! a failure with no such cause keeps its own error.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

/// How a module's error type reports the failures of [`replace_atomically`].
pub trait AtomicWriteError: Sized {
    /// A filesystem operation on `path` failed; `context` says which.
    fn fs(path: &Path, context: String, source: std::io::Error) -> Self;
    /// `path` has no file name, so no temporary can be named after it
    /// (nothing was written).
    fn no_file_name(path: &Path) -> Self;
    /// Writing `path` failed for `reason` (one line, the cause in words); nothing was written
    /// there.
    fn write_failed(path: &Path, reason: String) -> Self;
    /// The OS error underneath this failure, if it carries one.
    fn os_error(&self) -> Option<std::io::Error>;
}

/// The `errno = N` an HDF5 error text carries for a failed system call (its file driver
/// reports `file write failed: …, errno = 28, error message = 'No space left on device', …`).
pub fn errno_in(text: &str) -> Option<std::io::Error> {
    let (_, rest) = text.split_once("errno = ")?;
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    let code: i32 = digits.parse().ok()?;
    (code > 0).then(|| std::io::Error::from_raw_os_error(code))
}

/// Bytes the probe of a failed write writes (module docs): more than any file system's block,
/// so that a nearly full disk fails it as it failed the write.
const PROBE_BYTES: usize = 64 * 1024;

/// Why writing the temporary `tmp` failed (module docs): the OS error `e` carries, else the file
/// size limit reached, else the folder refusing a small write; `None` if none of these.
fn cause_of_failure<E: AtomicWriteError>(e: &E, tmp: &Path) -> Option<std::io::Error> {
    if let Some(io) = e.os_error() {
        return Some(io);
    }
    if let (Some(limit), Ok(meta)) = (file_size_limit(), fs::metadata(tmp)) {
        if meta.len().saturating_add(PROBE_BYTES as u64) >= limit {
            return Some(std::io::Error::from_raw_os_error(libc::EFBIG));
        }
    }
    let probe = tmp.with_extension(format!("probe.{}", std::process::id()));
    let written = fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .and_then(|mut f| {
            f.write_all(&[0u8; PROBE_BYTES])?;
            f.sync_all()
        });
    let _ = fs::remove_file(&probe);
    written.err()
}

/// The soft `RLIMIT_FSIZE` in bytes, `None` when unlimited.
fn file_size_limit() -> Option<u64> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit only writes the struct it is given.
    let ok = unsafe { libc::getrlimit(libc::RLIMIT_FSIZE, &mut lim) } == 0;
    (ok && lim.rlim_cur != libc::RLIM_INFINITY).then_some(lim.rlim_cur)
}

/// Writes `path` by calling `write` on the temporary `<dir>/.<name>.tmp.<pid>`
/// (see the module docs). `write` must create the file it is given.
pub fn replace_atomically<E, F>(path: &Path, write: F) -> Result<(), E>
where
    E: AtomicWriteError,
    F: FnOnce(&Path) -> Result<(), E>,
{
    let tmp = temp_path_for(path).ok_or_else(|| E::no_file_name(path))?;
    let result = write(&tmp).and_then(|()| {
        fs::File::open(&tmp)
            .and_then(|f| f.sync_all())
            .map_err(|source| E::fs(&tmp, "syncing temporary file".into(), source))?;
        fs::rename(&tmp, path).map_err(|source| {
            E::fs(
                path,
                format!("renaming {} into place", tmp.display()),
                source,
            )
        })
    });
    match result {
        Ok(()) => {
            // Persist the rename itself; failure here loses no data already
            // visible to readers, so it is not worth failing the whole write.
            if let Some(dir) = path.parent() {
                let dir = if dir.as_os_str().is_empty() {
                    Path::new(".")
                } else {
                    dir
                };
                if let Ok(d) = fs::File::open(dir) {
                    let _ = d.sync_all();
                }
            }
            Ok(())
        }
        Err(e) => {
            // The cause is looked for while the temporary still holds its bytes.
            let cause = cause_of_failure(&e, &tmp);
            let _ = fs::remove_file(&tmp);
            Err(match cause {
                Some(io) => E::write_failed(path, crate::io::preflight::describe_write_error(&io)),
                None => e,
            })
        }
    }
}

/// `<dir>/.<name>.tmp.<pid>` for `path`, or `None` if it has no file name.
pub fn temp_path_for(path: &Path) -> Option<PathBuf> {
    let name = path.file_name()?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp.{}", std::process::id()));
    Some(path.with_file_name(tmp_name))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::IoError;

    fn scratch(name: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("diffsound_atomic_{name}_{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn the_errno_of_an_hdf5_text_is_found() {
        let text = "unable to flush file: file write failed: time = Mon Dec  1 10:00:00 2025, filename = '/t/.a.h5.tmp.7', file descriptor = 5, errno = 28, error message = 'No space left on device', buf = 0x1";
        assert_eq!(errno_in(text).and_then(|e| e.raw_os_error()), Some(28));
        assert!(errno_in("can't write data").is_none());
        assert!(errno_in("errno = 0, fine").is_none());
    }

    /// A write failing with an OS error is reported on the final path with the cause in words,
    /// and leaves neither the file nor its temporary.
    #[test]
    fn a_failed_write_names_the_final_path_and_the_cause() {
        let d = scratch("full");
        let path = d.join("out.h5");
        let e = replace_atomically(&path, |tmp| {
            fs::write(tmp, b"partial").unwrap();
            Err(IoError::Hdf5 {
                path: tmp.to_path_buf(),
                context: "writing".into(),
                source: hdf5::Error::Internal(
                    "file write failed: filename = 'x', errno = 28, error message = 'No space left on device'".into(),
                ),
            })
        })
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "cannot write {}: no space left on the device (disk full)",
                path.display()
            )
        );
        assert_eq!(fs::read_dir(&d).unwrap().count(), 0, "nothing may be left");
        // A failure without an OS cause keeps its own message.
        let e = replace_atomically(&path, |tmp| {
            Err(IoError::InvalidInput {
                path: tmp.to_path_buf(),
                reason: "bad data".into(),
            })
        })
        .unwrap_err();
        assert!(e.to_string().contains("bad data"), "{e}");
        assert_eq!(fs::read_dir(&d).unwrap().count(), 0);
    }
}
