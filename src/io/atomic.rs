//! Atomic file replacement shared by every writer in the crate
//! ([`crate::io::write_atomically`], [`crate::audio::write_wav`]).
//!
//! The file is written to a temporary `<dir>/.<name>.tmp.<pid>` in the same
//! directory, fsynced, and renamed over the final path. Rename within one
//! directory is atomic on POSIX, so readers see the old file or the complete
//! new one. The temporary is removed if writing it or anything after that
//! fails; after a successful rename the directory is fsynced (best effort) so
//! the rename itself survives a crash.

use std::fs;
use std::path::{Path, PathBuf};

/// How a module's error type reports the failures of [`replace_atomically`].
pub trait AtomicWriteError {
    /// A filesystem operation on `path` failed; `context` says which.
    fn fs(path: &Path, context: String, source: std::io::Error) -> Self;
    /// `path` has no file name, so no temporary can be named after it
    /// (nothing was written).
    fn no_file_name(path: &Path) -> Self;
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
            let _ = fs::remove_file(&tmp);
            Err(e)
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
