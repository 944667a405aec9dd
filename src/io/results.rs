//! HDF5 results of the fits: named datasets (tables as one 1-D dataset per column) with
//! units, plus attributes on groups, written in one go and atomically
//! ([`super::write_atomically`]): a reader sees the previous file or the complete new one.
//!
//! The layout of each fit's file is documented where the fit is (e.g. the `fit-material`
//! command); this module only knows groups, datasets and attributes. The root carries the
//! attributes `format` (string) and `format_version` (u64). Every dataset has a string attribute
//! `units` ("1" for dimensionless, "" for indices, flags and labels coded as numbers).
//!
//! Types, so that Python and other readers get what a value is:
//!
//! | kind | HDF5 type | written by |
//! |------|-----------|------------|
//! | measured or computed value | f64 | [`ResultsFile::dataset`], [`ResultsFile::column`], [`ResultsFile::number`], [`ResultsFile::numbers`] |
//! | index, count (vertex, mode, step) | u64 dataset, i64 attribute | [`ResultsFile::indices`], [`ResultsFile::integer`], [`ResultsFile::integers`] |
//! | index with −1 for "none" | i64 | [`ResultsFile::signed`] |
//! | flag | u8, 0 or 1 | [`ResultsFile::flags`], [`ResultsFile::flag`] |
//! | text, list of texts | variable-length UTF-8 string, 1-D array of them | [`ResultsFile::text`], [`ResultsFile::texts`] |
//!
//! A list is a 1-D array attribute (or a dataset), never a formatted string, and an enum is
//! a plain word (`fit_file`, `delta_bic_too_small`), never Rust's `Debug` text.

use super::{
    create_nested, read_attr, read_str_attr, write_attr, write_dataset, write_str_attr, IoError,
};
use hdf5::types::{TypeDescriptor, VarLenUnicode};
use std::path::Path;

/// An attribute value as [`read_attribute`] returns it. A flag reads back as an
/// `Integer` (0 or 1).
#[derive(Clone, Debug, PartialEq)]
pub enum AttrValue {
    Number(f64),
    Integer(i64),
    Text(String),
    Numbers(Vec<f64>),
    Integers(Vec<i64>),
    Texts(Vec<String>),
}

impl std::fmt::Display for AttrValue {
    /// The value as a reader would write it: `7`, `0.5`, `"text"`, `[0, 2]`, `["a", "b"]`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AttrValue::Number(v) => write!(f, "{v}"),
            AttrValue::Integer(i) => write!(f, "{i}"),
            AttrValue::Text(t) => write!(f, "{t:?}"),
            AttrValue::Numbers(v) => write!(f, "{v:?}"),
            AttrValue::Integers(v) => write!(f, "{v:?}"),
            AttrValue::Texts(v) => write!(f, "{v:?}"),
        }
    }
}

impl AttrValue {
    /// The value as an f64, for a number or an integer (what older files stored as f64).
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            AttrValue::Number(v) => Some(*v),
            AttrValue::Integer(i) => Some(*i as f64),
            _ => None,
        }
    }
}

/// An attribute as it is written.
#[derive(Clone, Debug, PartialEq)]
enum Stored {
    Value(AttrValue),
    Flag(bool),
}

/// A dataset's values, with the HDF5 type they are stored as.
#[derive(Clone, Debug, PartialEq)]
enum Values {
    Float(Vec<f64>),
    Index(Vec<u64>),
    Signed(Vec<i64>),
    Flag(Vec<u8>),
}

impl Values {
    fn len(&self) -> usize {
        match self {
            Values::Float(v) => v.len(),
            Values::Index(v) => v.len(),
            Values::Signed(v) => v.len(),
            Values::Flag(v) => v.len(),
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
struct Dataset {
    path: String,
    shape: Vec<usize>,
    data: Values,
    units: String,
}

/// Collects what a results file holds, then writes it.
#[derive(Clone, Debug)]
pub struct ResultsFile {
    format: String,
    version: u64,
    datasets: Vec<Dataset>,
    /// (group path, key, value); "/" is the root.
    attributes: Vec<(String, String, Stored)>,
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

    /// An f64 dataset of any shape (row-major `data`).
    pub fn dataset(
        &mut self,
        path: &str,
        shape: &[usize],
        data: Vec<f64>,
        units: &str,
    ) -> &mut Self {
        self.push(path, shape.to_vec(), Values::Float(data), units)
    }

    /// A 1-D f64 dataset (e.g. one column of a table).
    pub fn column(&mut self, path: &str, data: Vec<f64>, units: &str) -> &mut Self {
        let n = data.len();
        self.dataset(path, &[n], data, units)
    }

    /// A 1-D u64 dataset of indices or counts (units "").
    pub fn indices(&mut self, path: &str, data: Vec<usize>) -> &mut Self {
        let n = data.len();
        let data = data.into_iter().map(|i| i as u64).collect();
        self.push(path, vec![n], Values::Index(data), "")
    }

    /// A 1-D i64 dataset of indices where −1 means "none" (units "").
    pub fn signed(&mut self, path: &str, data: Vec<Option<usize>>) -> &mut Self {
        let n = data.len();
        let data = data
            .into_iter()
            .map(|i| i.map_or(-1, |i| i as i64))
            .collect();
        self.push(path, vec![n], Values::Signed(data), "")
    }

    /// A 1-D u8 dataset of flags, 0 or 1 (units "").
    pub fn flags(&mut self, path: &str, data: Vec<bool>) -> &mut Self {
        let n = data.len();
        let data = data.into_iter().map(u8::from).collect();
        self.push(path, vec![n], Values::Flag(data), "")
    }

    fn push(&mut self, path: &str, shape: Vec<usize>, data: Values, units: &str) -> &mut Self {
        self.datasets.push(Dataset {
            path: path.into(),
            shape,
            data,
            units: units.into(),
        });
        self
    }

    fn attr(&mut self, group: &str, key: &str, value: Stored) -> &mut Self {
        self.attributes.push((group.into(), key.into(), value));
        self
    }

    /// An f64 attribute.
    pub fn number(&mut self, group: &str, key: &str, value: f64) -> &mut Self {
        self.attr(group, key, Stored::Value(AttrValue::Number(value)))
    }

    /// An i64 attribute (an index or a count).
    pub fn integer(&mut self, group: &str, key: &str, value: i64) -> &mut Self {
        self.attr(group, key, Stored::Value(AttrValue::Integer(value)))
    }

    /// A u8 attribute, 0 or 1.
    pub fn flag(&mut self, group: &str, key: &str, value: bool) -> &mut Self {
        self.attr(group, key, Stored::Flag(value))
    }

    /// A string attribute.
    pub fn text(&mut self, group: &str, key: &str, value: &str) -> &mut Self {
        self.attr(group, key, Stored::Value(AttrValue::Text(value.into())))
    }

    /// A 1-D f64 array attribute.
    pub fn numbers(&mut self, group: &str, key: &str, values: Vec<f64>) -> &mut Self {
        self.attr(group, key, Stored::Value(AttrValue::Numbers(values)))
    }

    /// A 1-D i64 array attribute.
    pub fn integers(&mut self, group: &str, key: &str, values: Vec<i64>) -> &mut Self {
        self.attr(group, key, Stored::Value(AttrValue::Integers(values)))
    }

    /// A 1-D array attribute of strings.
    pub fn texts(&mut self, group: &str, key: &str, values: Vec<String>) -> &mut Self {
        self.attr(group, key, Stored::Value(AttrValue::Texts(values)))
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
            let ds = match &d.data {
                Values::Float(v) => write_dataset(path, &group, name, &d.shape, v)?,
                Values::Index(v) => write_dataset(path, &group, name, &d.shape, v)?,
                Values::Signed(v) => write_dataset(path, &group, name, &d.shape, v)?,
                Values::Flag(v) => write_dataset(path, &group, name, &d.shape, v)?,
            };
            write_str_attr(path, &ds, "units", &d.units)?;
        }
        for (group_path, key, value) in &self.attributes {
            let parts = components(group_path).expect("validated");
            let group = create_nested(path, file, &parts)?;
            match value {
                Stored::Flag(b) => write_attr(path, &group, key, &u8::from(*b))?,
                Stored::Value(AttrValue::Number(v)) => write_attr(path, &group, key, v)?,
                Stored::Value(AttrValue::Integer(v)) => write_attr(path, &group, key, v)?,
                Stored::Value(AttrValue::Text(s)) => write_str_attr(path, &group, key, s)?,
                Stored::Value(AttrValue::Numbers(v)) => write_array_attr(path, &group, key, v)?,
                Stored::Value(AttrValue::Integers(v)) => write_array_attr(path, &group, key, v)?,
                Stored::Value(AttrValue::Texts(v)) => {
                    let strings = v
                        .iter()
                        .map(|t| {
                            t.parse::<VarLenUnicode>()
                                .map_err(|e| IoError::InvalidInput {
                                    path: path.to_path_buf(),
                                    reason: format!(
                                        "attribute '{key}' on {group_path}: {t:?} cannot be stored: {e}"
                                    ),
                                })
                        })
                        .collect::<Result<Vec<_>, _>>()?;
                    write_array_attr(path, &group, key, &strings)?
                }
            }
        }
        Ok(())
    }
}

/// A 1-D array attribute (an empty one has shape `[0]`).
fn write_array_attr<T: hdf5::H5Type>(
    path: &Path,
    loc: &hdf5::Location,
    name: &str,
    values: &[T],
) -> Result<(), IoError> {
    let attr = loc
        .new_attr::<T>()
        .shape([values.len()])
        .create(name)
        .map_err(IoError::hdf5(
            path,
            format!("creating attribute '{name}' on {}", loc.name()),
        ))?;
    // hdf5-metno rejects writing an empty buffer; an empty array has nothing to write.
    if !values.is_empty() {
        attr.write_raw(values).map_err(IoError::hdf5(
            path,
            format!("writing attribute '{name}' on {}", loc.name()),
        ))?;
    }
    Ok(())
}

/// Reads one dataset back as f64 (integer and flag datasets are converted): (values, shape).
pub fn read_dataset(path: &Path, dataset: &str) -> Result<(Vec<f64>, Vec<usize>), IoError> {
    read_as::<f64>(path, dataset)
}

/// Reads an integer or flag dataset back as i64: (values, shape).
pub fn read_integers(path: &Path, dataset: &str) -> Result<(Vec<i64>, Vec<usize>), IoError> {
    read_as::<i64>(path, dataset)
}

/// One dataset read back as `T` (HDF5 converts the stored type): (values, shape).
fn read_as<T: hdf5::H5Type>(path: &Path, dataset: &str) -> Result<(Vec<T>, Vec<usize>), IoError> {
    let file = hdf5::File::open(path).map_err(IoError::hdf5(path, "opening HDF5 file"))?;
    let ds = file
        .dataset(dataset)
        .map_err(IoError::hdf5(path, format!("opening dataset {dataset}")))?;
    let shape = ds.shape();
    let data = if shape.iter().product::<usize>() == 0 {
        Vec::new()
    } else {
        ds.read_raw::<T>()
            .map_err(IoError::hdf5(path, format!("reading dataset {dataset}")))?
    };
    Ok((data, shape))
}

/// Reads an attribute of a group ("/" for the root) back, by its stored type: a float is a
/// `Number`, an integer or flag an `Integer`, a string `Text`, and a 1-D array the plural of
/// each.
pub fn read_attribute(path: &Path, group: &str, key: &str) -> Result<AttrValue, IoError> {
    let file = hdf5::File::open(path).map_err(IoError::hdf5(path, "opening HDF5 file"))?;
    let loc = file
        .group(group)
        .map_err(IoError::hdf5(path, format!("opening group {group}")))?;
    let context = || format!("reading attribute '{key}' on {group}");
    let attr = loc.attr(key).map_err(IoError::hdf5(path, context()))?;
    let descriptor = attr
        .dtype()
        .and_then(|t| t.to_descriptor())
        .map_err(IoError::hdf5(path, context()))?;
    let kind = match descriptor {
        TypeDescriptor::Float(_) => Kind::Float,
        TypeDescriptor::Integer(_) | TypeDescriptor::Unsigned(_) => Kind::Integer,
        _ => Kind::Text,
    };
    if attr.is_scalar() {
        return match kind {
            Kind::Float => read_attr::<f64>(path, &loc, key).map(AttrValue::Number),
            Kind::Integer => read_attr::<i64>(path, &loc, key).map(AttrValue::Integer),
            Kind::Text => read_str_attr(path, &loc, key).map(AttrValue::Text),
        };
    }
    let empty = attr.shape().iter().product::<usize>() == 0;
    let hdf5 = IoError::hdf5(path, context());
    Ok(match kind {
        Kind::Float if empty => AttrValue::Numbers(Vec::new()),
        Kind::Integer if empty => AttrValue::Integers(Vec::new()),
        Kind::Text if empty => AttrValue::Texts(Vec::new()),
        Kind::Float => AttrValue::Numbers(attr.read_raw::<f64>().map_err(hdf5)?),
        Kind::Integer => AttrValue::Integers(attr.read_raw::<i64>().map_err(hdf5)?),
        Kind::Text => AttrValue::Texts(
            attr.read_raw::<VarLenUnicode>()
                .map_err(hdf5)?
                .into_iter()
                .map(|s| s.as_str().to_owned())
                .collect(),
        ),
    })
}

enum Kind {
    Float,
    Integer,
    Text,
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

        // Typed values keep their types.
        let path = dir.join("typed.h5");
        let mut f = ResultsFile::new("diffsound.test", 2);
        f.indices("/map/vertex", vec![3, 0, 7])
            .signed("/poles/cluster", vec![Some(2), None])
            .flags("/clusters/heard", vec![true, false])
            .indices("/empty", Vec::new())
            .integer("/", "n_ranks", 2)
            .flag("/material", "learned", true)
            .integers("/", "fit_microphones", vec![0, 2, 4, 6])
            .numbers("/fit", "basis_samples", vec![0.15, 0.35])
            .texts("/", "recordings", vec!["a.wav".into(), "b ü.wav".into()])
            .texts("/", "none", Vec::new());
        f.write(&path).unwrap();
        let file = hdf5::File::open(&path).unwrap();
        let descriptor = |name: &str| {
            file.dataset(name)
                .unwrap()
                .dtype()
                .unwrap()
                .to_descriptor()
                .unwrap()
        };
        use hdf5::types::IntSize;
        assert_eq!(
            descriptor("/map/vertex"),
            TypeDescriptor::Unsigned(IntSize::U8)
        );
        assert_eq!(
            descriptor("/poles/cluster"),
            TypeDescriptor::Integer(IntSize::U8)
        );
        assert_eq!(
            descriptor("/clusters/heard"),
            TypeDescriptor::Unsigned(IntSize::U1)
        );
        drop(file);
        assert_eq!(
            read_integers(&path, "/map/vertex").unwrap(),
            (vec![3, 0, 7], vec![3])
        );
        assert_eq!(
            read_integers(&path, "/poles/cluster").unwrap().0,
            vec![2, -1]
        );
        assert_eq!(
            read_dataset(&path, "/clusters/heard").unwrap().0,
            vec![1.0, 0.0]
        );
        assert_eq!(read_dataset(&path, "/empty").unwrap(), (vec![], vec![0]));
        let attr = |g: &str, k: &str| read_attribute(&path, g, k).unwrap();
        assert_eq!(attr("/", "n_ranks"), AttrValue::Integer(2));
        assert_eq!(attr("/", "n_ranks").as_f64(), Some(2.0));
        assert_eq!(attr("/material", "learned"), AttrValue::Integer(1));
        assert_eq!(
            attr("/", "fit_microphones"),
            AttrValue::Integers(vec![0, 2, 4, 6])
        );
        assert_eq!(
            attr("/fit", "basis_samples"),
            AttrValue::Numbers(vec![0.15, 0.35])
        );
        assert_eq!(
            attr("/", "recordings"),
            AttrValue::Texts(vec!["a.wav".into(), "b ü.wav".into()])
        );
        assert_eq!(attr("/", "none"), AttrValue::Texts(Vec::new()));

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
