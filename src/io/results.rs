//! HDF5 results of the fits: named f64 datasets (tables as one 1-D dataset per column) with
//! units, plus f64 and string attributes on groups, written in one go and atomically
//! ([`super::write_atomically`]): a reader sees the previous file or the complete new one.
//!
//! The layout of each fit's file is documented where the fit is (e.g. the `fit-material`
//! command); this module only knows groups, datasets and attributes. The root carries the
//! attributes `format` (string) and `format_version` (u64). Every dataset has a string attribute
//! `units` ("1" for dimensionless, "" for indices and labels coded as numbers).

use super::{
    create_nested, read_attr, read_str_attr, write_attr, write_dataset, write_str_attr, IoError,
};
use std::path::Path;

/// An attribute value.
#[derive(Clone, Debug, PartialEq)]
pub enum AttrValue {
    Number(f64),
    Text(String),
}

#[derive(Clone, Debug, PartialEq)]
struct Dataset {
    path: String,
    shape: Vec<usize>,
    data: Vec<f64>,
    units: String,
}

/// Collects what a results file holds, then writes it.
#[derive(Clone, Debug)]
pub struct ResultsFile {
    format: String,
    version: u64,
    datasets: Vec<Dataset>,
    /// (group path, key, value); "/" is the root.
    attributes: Vec<(String, String, AttrValue)>,
}

/// A path `/a/b/c` split into checked components: each non-empty `[A-Za-z0-9_.-]`, not `.`/`..`.
fn components(path: &str) -> Result<Vec<&str>, String> {
    if path == "/" {
        return Ok(Vec::new());
    }
    let rest = path
        .strip_prefix('/')
        .ok_or_else(|| format!("path {path:?} must start with '/'"))?;
    let parts: Vec<&str> = rest.split('/').collect();
    for p in &parts {
        if p.is_empty()
            || *p == "."
            || *p == ".."
            || !p
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_.-".contains(c))
        {
            return Err(format!(
                "path {path:?}: component {p:?} must be non-empty [A-Za-z0-9_.-]"
            ));
        }
    }
    Ok(parts)
}

impl ResultsFile {
    pub fn new(format: &str, version: u64) -> ResultsFile {
        ResultsFile {
            format: format.into(),
            version,
            datasets: Vec::new(),
            attributes: Vec::new(),
        }
    }

    /// A dataset of any shape (row-major `data`).
    pub fn dataset(
        &mut self,
        path: &str,
        shape: &[usize],
        data: Vec<f64>,
        units: &str,
    ) -> &mut Self {
        self.datasets.push(Dataset {
            path: path.into(),
            shape: shape.to_vec(),
            data,
            units: units.into(),
        });
        self
    }

    /// A 1-D dataset (e.g. one column of a table).
    pub fn column(&mut self, path: &str, data: Vec<f64>, units: &str) -> &mut Self {
        let n = data.len();
        self.dataset(path, &[n], data, units)
    }

    pub fn number(&mut self, group: &str, key: &str, value: f64) -> &mut Self {
        self.attributes
            .push((group.into(), key.into(), AttrValue::Number(value)));
        self
    }

    pub fn text(&mut self, group: &str, key: &str, value: &str) -> &mut Self {
        self.attributes
            .push((group.into(), key.into(), AttrValue::Text(value.into())));
        self
    }

    /// Checks paths, shapes and uniqueness; nothing touches the disk.
    fn validate(&self, path: &Path) -> Result<(), IoError> {
        let bad = |reason: String| IoError::InvalidInput {
            path: path.to_path_buf(),
            reason,
        };
        let mut seen = std::collections::BTreeSet::new();
        for d in &self.datasets {
            let parts = components(&d.path).map_err(bad)?;
            if parts.is_empty() {
                return Err(bad("a dataset cannot be the root".into()));
            }
            if d.shape.iter().product::<usize>() != d.data.len() {
                return Err(bad(format!(
                    "{}: shape {:?} does not hold {} values",
                    d.path,
                    d.shape,
                    d.data.len()
                )));
            }
            if !seen.insert(d.path.clone()) {
                return Err(bad(format!("{}: written twice", d.path)));
            }
        }
        // A dataset may not sit where another one's group is.
        for d in &self.datasets {
            let prefix = format!("{}/", d.path);
            if let Some(other) = self.datasets.iter().find(|o| o.path.starts_with(&prefix)) {
                return Err(bad(format!(
                    "{} is a dataset and also the group of {}",
                    d.path, other.path
                )));
            }
        }
        let mut keys = std::collections::BTreeSet::new();
        for (group, key, _) in &self.attributes {
            components(group).map_err(bad)?;
            if key.is_empty() || (group == "/" && (key == "format" || key == "format_version")) {
                return Err(bad(format!(
                    "attribute {key:?} on {group} is empty or reserved"
                )));
            }
            if self.datasets.iter().any(|d| &d.path == group) {
                return Err(bad(format!(
                    "attribute {key:?}: {group} is a dataset, not a group"
                )));
            }
            if !keys.insert((group.clone(), key.clone())) {
                return Err(bad(format!("attribute {key:?} on {group} written twice")));
            }
        }
        Ok(())
    }

    /// Writes the file atomically.
    pub fn write(&self, path: &Path) -> Result<(), IoError> {
        self.validate(path)?;
        super::write_atomically(path, |tmp| {
            let file = hdf5::File::create(tmp).map_err(IoError::hdf5(tmp, "creating HDF5 file"))?;
            self.fill(tmp, &file)?;
            file.close()
                .map_err(IoError::hdf5(tmp, "closing HDF5 file"))
        })
    }

    fn fill(&self, path: &Path, file: &hdf5::File) -> Result<(), IoError> {
        write_str_attr(path, file, "format", &self.format)?;
        write_attr(path, file, "format_version", &self.version)?;
        for d in &self.datasets {
            let parts = components(&d.path).expect("validated");
            let (name, groups) = parts.split_last().expect("validated: not the root");
            let group = create_nested(path, file, groups)?;
            let ds = write_dataset(path, &group, name, &d.shape, &d.data)?;
            write_str_attr(path, &ds, "units", &d.units)?;
        }
        for (group_path, key, value) in &self.attributes {
            let parts = components(group_path).expect("validated");
            let group = create_nested(path, file, &parts)?;
            match value {
                AttrValue::Number(v) => write_attr(path, &group, key, v)?,
                AttrValue::Text(s) => write_str_attr(path, &group, key, s)?,
            }
        }
        Ok(())
    }
}

/// Reads one dataset back: (values, shape).
pub fn read_dataset(path: &Path, dataset: &str) -> Result<(Vec<f64>, Vec<usize>), IoError> {
    let file = hdf5::File::open(path).map_err(IoError::hdf5(path, "opening HDF5 file"))?;
    let ds = file
        .dataset(dataset)
        .map_err(IoError::hdf5(path, format!("opening dataset {dataset}")))?;
    let shape = ds.shape();
    let data = if shape.iter().product::<usize>() == 0 {
        Vec::new()
    } else {
        ds.read_raw::<f64>()
            .map_err(IoError::hdf5(path, format!("reading dataset {dataset}")))?
    };
    Ok((data, shape))
}

/// Reads an attribute of a group ("/" for the root) back.
pub fn read_attribute(path: &Path, group: &str, key: &str) -> Result<AttrValue, IoError> {
    let file = hdf5::File::open(path).map_err(IoError::hdf5(path, "opening HDF5 file"))?;
    let loc = file
        .group(group)
        .map_err(IoError::hdf5(path, format!("opening group {group}")))?;
    match read_attr::<f64>(path, &loc, key) {
        Ok(v) => Ok(AttrValue::Number(v)),
        Err(_) => read_str_attr(path, &loc, key).map(AttrValue::Text),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_validation() {
        let dir = tempdir();
        let path = dir.join("r.h5");
        let mut f = ResultsFile::new("diffsound.test", 1);
        f.column("/fit/history/loss", vec![3.0, 2.0, 1.0], "1")
            .dataset("/fit/matrix", &[2, 2], vec![1.0, 2.0, 3.0, 4.0], "Pa")
            .number("/fit", "youngs_modulus", 5e10)
            .text("/", "mesh", "bowl.msh");
        f.write(&path).unwrap();
        assert_eq!(
            read_dataset(&path, "/fit/history/loss").unwrap(),
            (vec![3.0, 2.0, 1.0], vec![3])
        );
        assert_eq!(read_dataset(&path, "/fit/matrix").unwrap().1, vec![2, 2]);
        assert_eq!(
            read_attribute(&path, "/fit", "youngs_modulus").unwrap(),
            AttrValue::Number(5e10)
        );
        assert_eq!(
            read_attribute(&path, "/", "mesh").unwrap(),
            AttrValue::Text("bowl.msh".into())
        );
        assert_eq!(
            read_attribute(&path, "/", "format").unwrap(),
            AttrValue::Text("diffsound.test".into())
        );

        for broken in [
            ResultsFile::new("x", 1)
                .column("/a", vec![1.0], "")
                .column("/a", vec![1.0], "")
                .clone(),
            ResultsFile::new("x", 1)
                .dataset("/a", &[2], vec![1.0], "")
                .clone(),
            ResultsFile::new("x", 1)
                .column("/a", vec![1.0], "")
                .column("/a/b", vec![1.0], "")
                .clone(),
            ResultsFile::new("x", 1).column("a", vec![1.0], "").clone(),
            ResultsFile::new("x", 1)
                .column("/a b", vec![1.0], "")
                .clone(),
            ResultsFile::new("x", 1).number("/", "format", 1.0).clone(),
        ] {
            let p = dir.join("bad.h5");
            assert!(matches!(
                broken.write(&p),
                Err(IoError::InvalidInput { .. })
            ));
            assert!(!p.exists(), "nothing is written for invalid input");
        }
    }

    fn tempdir() -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("diffsound-results-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }
}
