//! Output paths checked before the work starts.
//!
//! A job that solves or fits for minutes and then cannot write its result has wasted the
//! minutes, and a failed write deep inside HDF5 names a hidden temp file. Every job therefore
//! checks each output path when it resolves its request, before any computation:
//!
//! * the path is not a directory and its folder exists;
//! * it is none of the job's inputs (a mesh, a recording, a fit), compared after resolving
//!   links, so `--out` equal to the mesh cannot overwrite the mesh;
//! * the folder takes a new file: a probe file `.<name>.probe.<pid>` is created and removed,
//!   and a failure says in one line which path and why (read-only file system, permission
//!   denied, disk full, or the system's own message).
//!
//! The probe writes one byte, so a disk with no block left fails here too.

use std::io::Write;
use std::path::{Path, PathBuf};

/// Why an output path cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("output {path} is a directory; give a file name")]
    IsDirectory { path: PathBuf },
    #[error("output directory {dir} does not exist (for {path})")]
    NoDirectory { path: PathBuf, dir: PathBuf },
    #[error(
        "output {path} is also an input of this job ({what}); writing it would destroy the input"
    )]
    IsInput { path: PathBuf, what: String },
    #[error("cannot write {path}: {reason}")]
    NotWritable { path: PathBuf, reason: String },
}

/// One line for an I/O error of a write: the common causes in words, else the system's text.
pub fn describe_write_error(e: &std::io::Error) -> String {
    match e.raw_os_error() {
        Some(30) => "read-only file system".into(),
        Some(28) => "no space left on the device (disk full)".into(),
        Some(13) | Some(1) => "permission denied".into(),
        Some(122) => "disk quota exceeded".into(),
        Some(27) => {
            "file too large for the process's file size limit (`ulimit -f`) or the file system"
                .into()
        }
        _ => e.to_string(),
    }
}

/// The path with its folder's links resolved (the file itself need not exist).
fn resolved(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = path.canonicalize() {
        return Some(p);
    }
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    Some(dir.canonicalize().ok()?.join(path.file_name()?))
}

/// Checks that `path` can take a job's output (module docs). `inputs` are the job's input
/// files, each with a word for the message (e.g. `("mesh", path)`).
pub fn check_output(path: &Path, inputs: &[(&str, &Path)]) -> Result<(), OutputError> {
    if path.is_dir() {
        return Err(OutputError::IsDirectory {
            path: path.to_path_buf(),
        });
    }
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        return Err(OutputError::NoDirectory {
            path: path.to_path_buf(),
            dir: dir.to_path_buf(),
        });
    }
    if let Some(out) = resolved(path) {
        for (what, input) in inputs {
            if resolved(input).is_some_and(|i| i == out) {
                return Err(OutputError::IsInput {
                    path: path.to_path_buf(),
                    what: what.to_string(),
                });
            }
        }
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let probe = dir.join(format!(".{name}.probe.{}", std::process::id()));
    let written = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .and_then(|mut f| {
            f.write_all(b"x")?;
            f.sync_all()
        });
    let _ = std::fs::remove_file(&probe);
    written.map_err(|e| OutputError::NotWritable {
        path: path.to_path_buf(),
        reason: describe_write_error(&e),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("diffsound_preflight_{name}_{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_writable_new_file_passes_and_leaves_nothing() {
        let d = scratch("ok");
        check_output(&d.join("a.h5"), &[]).unwrap();
        assert_eq!(
            std::fs::read_dir(&d).unwrap().count(),
            0,
            "the probe must be removed"
        );
    }

    #[test]
    fn directories_missing_folders_and_inputs_are_refused() {
        let d = scratch("bad");
        let mesh = d.join("m.msh");
        std::fs::write(&mesh, "x").unwrap();
        assert!(matches!(
            check_output(&d, &[]),
            Err(OutputError::IsDirectory { .. })
        ));
        assert!(matches!(
            check_output(&d.join("no/such/a.h5"), &[]),
            Err(OutputError::NoDirectory { .. })
        ));
        // The same file by another spelling is still the input.
        let other = d.join(".").join("m.msh");
        let e = check_output(&other, &[("mesh", &mesh)]).unwrap_err();
        assert!(
            e.to_string().contains("also an input of this job (mesh)"),
            "{e}"
        );
        assert_eq!(std::fs::read_to_string(&mesh).unwrap(), "x");
    }

    #[test]
    fn a_folder_that_takes_no_file_is_named_with_the_cause() {
        // /proc takes no new regular file, even for root.
        let e = check_output(Path::new("/proc/diffsound_out.h5"), &[]).unwrap_err();
        assert!(
            matches!(e, OutputError::NotWritable { .. })
                && e.to_string().contains("/proc/diffsound_out.h5"),
            "{e}"
        );
    }
}
