//! Names of output files derived from a user's path or prefix.

use std::path::{Path, PathBuf};

/// `prefix` with `suffix` appended as text (`out/bowl` + `_loss.png` → `out/bowl_loss.png`).
pub fn plot_path(prefix: &Path, suffix: &str) -> PathBuf {
    let mut s = prefix.as_os_str().to_owned();
    s.push(suffix);
    PathBuf::from(s)
}

/// `path` without its extension, with `suffix` appended (`out/a.h5` + `_map.png` → `out/a_map.png`).
pub fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let mut s = path.with_extension("").into_os_string();
    s.push(suffix);
    PathBuf::from(s)
}
