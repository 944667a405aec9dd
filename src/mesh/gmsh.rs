//! Gmsh MSH reader: versions 2.2 and 4.1, ASCII and binary.
//!
//! The whole file is read into memory and parsed with a cursor. Positions are
//! kept as byte offsets; an error in an ASCII file is reported by line number
//! (counted only when the error happens, so the hot loops stay cheap), an
//! error in a binary file by byte offset. Every count read from the file is
//! treated as untrusted: no allocation is sized from it beyond what the
//! remaining bytes could hold, and all arithmetic on it is checked, so corrupt
//! input yields an error, never a panic or a huge allocation.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use super::validate::finish;
use super::{ElementOrder, Location, MeshError, MeshRead, ReadOptions};

/// Reads a Gmsh mesh file (see the module docs for formats and checks).
pub fn read_mesh(path: &Path, opts: &ReadOptions) -> Result<MeshRead, MeshError> {
    let data = std::fs::read(path).map_err(|source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read_mesh_from_bytes(&data, path, opts)
}

/// Like [`read_mesh`] on file contents already in memory; `path` is only used
/// to name the source in errors.
pub fn read_mesh_from_bytes(
    data: &[u8],
    path: &Path,
    opts: &ReadOptions,
) -> Result<MeshRead, MeshError> {
    if !(opts.unit_scale.is_finite() && opts.unit_scale > 0.0) {
        return Err(MeshError::BadOption {
            path: path.to_path_buf(),
            message: format!(
                "unit_scale must be a positive finite number, got {}",
                opts.unit_scale
            ),
        });
    }
    let raw = parse_msh(data, path)?;
    finish(raw, path, opts)
}

/// The tets of a file as parsed, before unused nodes are dropped and before
/// any geometric check.
pub(super) struct RawMesh {
    /// Coordinates of every node in `$Nodes`, in file order, in mesh units.
    pub coords: Vec<[f64; 3]>,
    pub order: ElementOrder,
    /// Indices into `coords`, `order.nodes_per_tet()` per tet.
    pub connectivity: Vec<usize>,
    /// Element tag in the file of each tet, for messages.
    pub element_tags: Vec<u64>,
    /// Gmsh element type -> number of elements of that type that were skipped.
    pub ignored: BTreeMap<i64, usize>,
    /// Where the file ends, for errors about the file as a whole.
    pub end_location: Location,
}

const TYPE_TET4: i64 = 4;
const TYPE_TET10: i64 = 11;

/// Nodes per element and a plural name for the Gmsh element types a file may
/// contain besides tets. Binary files can only be skipped through element
/// types listed here, because their records carry no length.
fn element_type_info(element_type: i64) -> Option<(usize, &'static str)> {
    Some(match element_type {
        1 => (2, "lines"),
        2 => (3, "triangles"),
        3 => (4, "quadrangles"),
        4 => (4, "4-node tetrahedra"),
        5 => (8, "hexahedra"),
        6 => (6, "prisms"),
        7 => (5, "pyramids"),
        8 => (3, "3-node lines"),
        9 => (6, "6-node triangles"),
        10 => (9, "9-node quadrangles"),
        11 => (10, "10-node tetrahedra"),
        12 => (27, "27-node hexahedra"),
        13 => (18, "18-node prisms"),
        14 => (14, "14-node pyramids"),
        15 => (1, "points"),
        16 => (8, "8-node quadrangles"),
        17 => (20, "20-node hexahedra"),
        18 => (15, "15-node prisms"),
        19 => (13, "13-node pyramids"),
        20 => (9, "9-node triangles"),
        21 => (10, "10-node triangles"),
        22 => (12, "12-node triangles"),
        23 => (15, "15-node triangles"),
        24 => (15, "15-node incomplete triangles"),
        25 => (21, "21-node triangles"),
        26 => (4, "4-node lines"),
        27 => (5, "5-node lines"),
        28 => (6, "6-node lines"),
        29 => (20, "20-node tetrahedra"),
        30 => (35, "35-node tetrahedra"),
        31 => (56, "56-node tetrahedra"),
        92 => (64, "64-node hexahedra"),
        93 => (125, "125-node hexahedra"),
        _ => return None,
    })
}

/// `ignored 1234 elements of other types (2: 1200 triangles, 15: 34 points)`.
pub(super) fn ignored_summary(ignored: &BTreeMap<i64, usize>) -> Option<String> {
    let total: usize = ignored.values().sum();
    if total == 0 {
        return None;
    }
    let parts: Vec<String> = ignored
        .iter()
        .map(|(&ty, &count)| {
            let name = element_type_info(ty).map_or("elements of unknown type", |(_, name)| name);
            format!("{ty}: {count} {name}")
        })
        .collect();
    Some(format!(
        "ignored {total} elements of other types ({})",
        parts.join(", ")
    ))
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Version {
    /// MSH 2.x (2.0, 2.1, 2.2 share the layout read here).
    V2,
    V41,
}

/// Maps node tags from the file to indices into the node arrays.
enum TagMap {
    /// Indexed by tag; `usize::MAX` marks an unused tag. Used when tags are
    /// dense enough that the table stays small.
    Dense(Vec<usize>),
    Sparse(HashMap<u64, usize>),
}

impl TagMap {
    /// Builds the map, or returns the position in `tags` of the first tag
    /// that repeats an earlier one.
    fn build(tags: &[u64]) -> Result<TagMap, usize> {
        let max_tag = tags.iter().copied().max().unwrap_or(0);
        let dense_limit = 2 * tags.len() as u64 + 1024;
        if max_tag <= dense_limit {
            let mut table = vec![usize::MAX; max_tag as usize + 1];
            for (index, &tag) in tags.iter().enumerate() {
                let slot = &mut table[tag as usize];
                if *slot != usize::MAX {
                    return Err(index);
                }
                *slot = index;
            }
            Ok(TagMap::Dense(table))
        } else {
            let mut map = HashMap::with_capacity(tags.len());
            for (index, &tag) in tags.iter().enumerate() {
                if map.insert(tag, index).is_some() {
                    return Err(index);
                }
            }
            Ok(TagMap::Sparse(map))
        }
    }

    fn get(&self, tag: u64) -> Option<usize> {
        match self {
            TagMap::Dense(table) => {
                let index = *table.get(usize::try_from(tag).ok()?)?;
                (index != usize::MAX).then_some(index)
            }
            TagMap::Sparse(map) => map.get(&tag).copied(),
        }
    }
}

/// Collects the tets while `$Elements` is parsed.
struct TetCollector<'m> {
    tag_map: &'m TagMap,
    /// Order of the tets kept; fixed by the first tet seen.
    order: Option<ElementOrder>,
    connectivity: Vec<usize>,
    element_tags: Vec<u64>,
    n_tet4: usize,
    n_tet10: usize,
    first_tet4: u64,
    first_tet10: u64,
    ignored: BTreeMap<i64, usize>,
}

impl<'m> TetCollector<'m> {
    fn new(tag_map: &'m TagMap) -> Self {
        TetCollector {
            tag_map,
            order: None,
            connectivity: Vec::new(),
            element_tags: Vec::new(),
            n_tet4: 0,
            n_tet10: 0,
            first_tet4: 0,
            first_tet10: 0,
            ignored: BTreeMap::new(),
        }
    }

    fn finish(self) -> ParsedElements {
        ParsedElements {
            order: self.order,
            connectivity: self.connectivity,
            element_tags: self.element_tags,
            ignored: self.ignored,
            n_tet4: self.n_tet4,
            n_tet10: self.n_tet10,
            first_tet4: self.first_tet4,
            first_tet10: self.first_tet10,
        }
    }

    fn ignore(&mut self, element_type: i64, count: usize) {
        *self.ignored.entry(element_type).or_insert(0) += count;
    }

    /// Whether a tet of this type is stored (the first order seen wins; the
    /// other is only counted, and reported as an error at the end).
    fn start_tet(&mut self, element_type: i64, element_tag: u64) -> bool {
        let order = if element_type == TYPE_TET4 {
            if self.n_tet4 == 0 {
                self.first_tet4 = element_tag;
            }
            self.n_tet4 += 1;
            ElementOrder::Linear
        } else {
            if self.n_tet10 == 0 {
                self.first_tet10 = element_tag;
            }
            self.n_tet10 += 1;
            ElementOrder::Quadratic
        };
        let kept = *self.order.get_or_insert(order);
        if kept == order {
            self.element_tags.push(element_tag);
            true
        } else {
            false
        }
    }
}

/// What [`TetCollector`] gathered, without the borrow of the tag map.
struct ParsedElements {
    order: Option<ElementOrder>,
    connectivity: Vec<usize>,
    element_tags: Vec<u64>,
    ignored: BTreeMap<i64, usize>,
    n_tet4: usize,
    n_tet10: usize,
    first_tet4: u64,
    first_tet10: u64,
}

struct Parser<'a> {
    data: &'a [u8],
    pos: usize,
    path: &'a Path,
    /// Errors are located by byte offset in binary files, by line otherwise.
    binary: bool,
    /// The binary data is big-endian.
    big_endian: bool,
}

fn is_space(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | b'\n')
}

fn is_inline_space(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r')
}

fn show(token: &[u8]) -> String {
    let text = String::from_utf8_lossy(&token[..token.len().min(40)]).into_owned();
    if token.len() > 40 {
        format!("{text}...")
    } else {
        text
    }
}

fn parse_u64_digits(token: &[u8]) -> Option<u64> {
    let digits = token.strip_prefix(b"+").unwrap_or(token);
    if digits.is_empty() {
        return None;
    }
    let mut value: u64 = 0;
    for &b in digits {
        if !b.is_ascii_digit() {
            return None;
        }
        value = value.checked_mul(10)?.checked_add(u64::from(b - b'0'))?;
    }
    Some(value)
}

fn parse_i64_digits(token: &[u8]) -> Option<i64> {
    match token.strip_prefix(b"-") {
        Some(rest) => {
            let magnitude = parse_u64_digits(rest)?;
            0i64.checked_sub_unsigned(magnitude)
        }
        None => i64::try_from(parse_u64_digits(token)?).ok(),
    }
}

impl<'a> Parser<'a> {
    fn location(&self, at: usize) -> Location {
        if self.binary {
            Location::ByteOffset(at)
        } else {
            let before = &self.data[..at.min(self.data.len())];
            Location::Line(1 + before.iter().filter(|&&b| b == b'\n').count())
        }
    }

    fn syntax(&self, at: usize, message: String) -> MeshError {
        MeshError::Syntax {
            path: self.path.to_path_buf(),
            location: self.location(at),
            message,
        }
    }

    fn truncated(&self, what: &str) -> MeshError {
        MeshError::Truncated {
            path: self.path.to_path_buf(),
            location: self.location(self.data.len()),
            what: what.to_string(),
        }
    }

    fn at_end(&self) -> bool {
        self.pos >= self.data.len()
    }

    fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    fn skip_space(&mut self) {
        while self.pos < self.data.len() && is_space(self.data[self.pos]) {
            self.pos += 1;
        }
    }

    /// Next whitespace-separated token, possibly on a later line; returns its
    /// start offset too.
    fn token(&mut self, what: &str) -> Result<(usize, &'a [u8]), MeshError> {
        self.skip_space();
        let start = self.pos;
        while self.pos < self.data.len() && !is_space(self.data[self.pos]) {
            self.pos += 1;
        }
        if start == self.pos {
            return Err(self.truncated(what));
        }
        Ok((start, &self.data[start..self.pos]))
    }

    /// Next token on the current line; element and node records are one line
    /// each, so a record with too few values is caught on its own line rather
    /// than silently swallowing the next one.
    fn line_token(&mut self, what: &str) -> Result<(usize, &'a [u8]), MeshError> {
        while self.pos < self.data.len() && is_inline_space(self.data[self.pos]) {
            self.pos += 1;
        }
        if self.at_end() {
            return Err(self.truncated(what));
        }
        if self.data[self.pos] == b'\n' {
            return Err(self.syntax(self.pos, format!("line ends before {what}")));
        }
        let start = self.pos;
        while self.pos < self.data.len() && !is_space(self.data[self.pos]) {
            self.pos += 1;
        }
        Ok((start, &self.data[start..self.pos]))
    }

    /// Requires the rest of the line to be blank and moves past it.
    fn end_of_line(&mut self, record: &str) -> Result<(), MeshError> {
        while self.pos < self.data.len() && is_inline_space(self.data[self.pos]) {
            self.pos += 1;
        }
        match self.data.get(self.pos) {
            None => Ok(()),
            Some(b'\n') => {
                self.pos += 1;
                Ok(())
            }
            Some(_) => {
                let start = self.pos;
                let end = self.data[start..]
                    .iter()
                    .position(|&b| is_space(b))
                    .map_or(self.data.len(), |n| start + n);
                Err(self.syntax(
                    start,
                    format!(
                        "unexpected extra value '{}' after {record}",
                        show(&self.data[start..end])
                    ),
                ))
            }
        }
    }

    fn skip_line(&mut self) {
        match self.data[self.pos.min(self.data.len())..]
            .iter()
            .position(|&b| b == b'\n')
        {
            Some(n) => self.pos += n + 1,
            None => self.pos = self.data.len(),
        }
    }

    /// In binary files a count line is followed by raw data right after its
    /// newline; consume exactly up to and including that newline, because
    /// the data may itself start with bytes that look like whitespace.
    fn end_count_line(&mut self) -> Result<(), MeshError> {
        while self.pos < self.data.len() && is_inline_space(self.data[self.pos]) {
            self.pos += 1;
        }
        match self.data.get(self.pos) {
            None => Err(self.truncated("binary data")),
            Some(b'\n') => {
                self.pos += 1;
                Ok(())
            }
            Some(_) => Err(self.syntax(
                self.pos,
                "expected the end of the line before binary data".to_string(),
            )),
        }
    }

    fn u64_token(&mut self, what: &str, in_line: bool) -> Result<u64, MeshError> {
        let (at, token) = if in_line {
            self.line_token(what)?
        } else {
            self.token(what)?
        };
        parse_u64_digits(token).ok_or_else(|| {
            self.syntax(
                at,
                format!(
                    "expected a non-negative integer for {what}, found '{}'",
                    show(token)
                ),
            )
        })
    }

    fn i64_token(&mut self, what: &str, in_line: bool) -> Result<i64, MeshError> {
        let (at, token) = if in_line {
            self.line_token(what)?
        } else {
            self.token(what)?
        };
        parse_i64_digits(token).ok_or_else(|| {
            self.syntax(
                at,
                format!("expected an integer for {what}, found '{}'", show(token)),
            )
        })
    }

    fn f64_token(&mut self, what: &str, in_line: bool) -> Result<f64, MeshError> {
        let (at, token) = if in_line {
            self.line_token(what)?
        } else {
            self.token(what)?
        };
        std::str::from_utf8(token)
            .ok()
            .and_then(|text| text.parse::<f64>().ok())
            .ok_or_else(|| {
                self.syntax(
                    at,
                    format!("expected a number for {what}, found '{}'", show(token)),
                )
            })
    }

    /// A count that must fit in usize.
    fn count_token(&mut self, what: &str) -> Result<usize, MeshError> {
        self.skip_space();
        let at = self.pos;
        let value = self.u64_token(what, false)?;
        usize::try_from(value).map_err(|_| self.syntax(at, format!("{what} {value} is too large")))
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], MeshError> {
        if self.remaining() < n {
            return Err(self.truncated(what));
        }
        let bytes = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(bytes)
    }

    fn decode_i32(&self, bytes: &[u8]) -> i32 {
        let raw = [bytes[0], bytes[1], bytes[2], bytes[3]];
        if self.big_endian {
            i32::from_be_bytes(raw)
        } else {
            i32::from_le_bytes(raw)
        }
    }

    fn decode_u64(&self, bytes: &[u8]) -> u64 {
        let mut raw = [0u8; 8];
        raw.copy_from_slice(&bytes[..8]);
        if self.big_endian {
            u64::from_be_bytes(raw)
        } else {
            u64::from_le_bytes(raw)
        }
    }

    fn decode_f64(&self, bytes: &[u8]) -> f64 {
        f64::from_bits(self.decode_u64(bytes))
    }

    fn bin_i32(&mut self, what: &str) -> Result<i32, MeshError> {
        let bytes = self.take(4, what)?;
        Ok(self.decode_i32(bytes))
    }

    fn bin_u64(&mut self, what: &str) -> Result<u64, MeshError> {
        let bytes = self.take(8, what)?;
        Ok(self.decode_u64(bytes))
    }

    /// A binary size_t count that must fit in usize.
    fn bin_count(&mut self, what: &str) -> Result<usize, MeshError> {
        let at = self.pos;
        let value = self.bin_u64(what)?;
        usize::try_from(value).map_err(|_| self.syntax(at, format!("{what} {value} is too large")))
    }

    /// A binary int that must be >= 0.
    fn bin_nonneg_i32(&mut self, what: &str) -> Result<usize, MeshError> {
        let at = self.pos;
        let value = self.bin_i32(what)?;
        usize::try_from(value).map_err(|_| self.syntax(at, format!("{what} is negative ({value})")))
    }

    /// Capacity to reserve for `count` records of at least `min_bytes` each:
    /// never more than the rest of the file could hold.
    fn capacity_for(&self, count: usize, min_bytes: usize) -> usize {
        count.min(self.remaining() / min_bytes.max(1) + 1)
    }

    fn skip_space_if_ascii(&mut self) {
        if !self.binary {
            self.skip_space();
        }
    }

    fn unknown_node(&self, at: usize, element_tag: u64, node_tag: u64) -> MeshError {
        MeshError::UnknownNode {
            path: self.path.to_path_buf(),
            location: self.location(at),
            element_tag,
            node_tag,
        }
    }

    fn skip_inline_space(&mut self) {
        while self.pos < self.data.len() && is_inline_space(self.data[self.pos]) {
            self.pos += 1;
        }
    }

    /// Skips `count` one-line ASCII records (elements of a type not kept).
    fn skip_records(&mut self, count: usize, what: &str) -> Result<(), MeshError> {
        for _ in 0..count {
            self.skip_space();
            if self.at_end() {
                return Err(self.truncated(what));
            }
            self.skip_line();
        }
        Ok(())
    }

    /// Reads the next `$Name` header line. `None` at the end of the file.
    fn section_header(&mut self) -> Result<Option<(usize, String)>, MeshError> {
        self.skip_space();
        if self.at_end() {
            return Ok(None);
        }
        let start = self.pos;
        if self.data[start] != b'$' {
            let end = self.data[start..]
                .iter()
                .position(|&b| is_space(b))
                .map_or(self.data.len(), |n| start + n);
            return Err(self.syntax(
                start,
                format!(
                    "expected a section header such as $Nodes, found '{}'",
                    show(&self.data[start..end])
                ),
            ));
        }
        self.skip_line();
        let name = String::from_utf8_lossy(&self.data[start + 1..self.pos])
            .trim()
            .to_string();
        Ok(Some((start, name)))
    }

    /// Requires `$End<name>` next (after whitespace) and moves past its line.
    fn section_end(&mut self, name: &str) -> Result<(), MeshError> {
        self.skip_space();
        if self.at_end() {
            return Err(self.truncated(&format!("${name} (no $End{name})")));
        }
        let closing = format!("$End{name}");
        if !self.data[self.pos..].starts_with(closing.as_bytes()) {
            let start = self.pos;
            let end = (start + 40).min(self.data.len());
            let found = if self.binary {
                "binary data".to_string()
            } else {
                format!(
                    "'{}'",
                    show(&self.data[start..end]).lines().next().unwrap_or("")
                )
            };
            return Err(self.syntax(
                start,
                format!("expected {closing}, found {found} (wrong count in ${name}?)"),
            ));
        }
        self.skip_line();
        Ok(())
    }

    /// Skips a section by searching for its `$End<name>` followed by the end
    /// of a line; this works for ASCII and binary sections alike. The closing
    /// tag need not start a line: some writers (e.g. of binary
    /// `$ElementData`) put it straight after the binary data.
    fn skip_section(&mut self, name: &str) -> Result<(), MeshError> {
        let closing = format!("$End{name}");
        let closing = closing.as_bytes();
        let mut search = self.pos;
        while let Some(n) = self.data[search..].iter().position(|&b| b == b'$') {
            let at = search + n;
            let ends_line = self
                .data
                .get(at + closing.len())
                .is_none_or(|&b| is_space(b));
            if ends_line && self.data[at..].starts_with(closing) {
                self.pos = at;
                self.skip_line();
                return Ok(());
            }
            search = at + 1;
        }
        Err(self.truncated(&format!(
            "${name} (no {})",
            String::from_utf8_lossy(closing)
        )))
    }
}

/// Parses the file structure and returns every tet with node indices.
fn parse_msh(data: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    let mut p = Parser {
        data,
        pos: 0,
        path,
        binary: false,
        big_endian: false,
    };

    let first = p.section_header().map_err(|err| match err {
        MeshError::Syntax { path, location, .. } => MeshError::MissingSection {
            path,
            location,
            section: "MeshFormat",
        },
        other => other,
    })?;
    let Some((header_at, name)) = first else {
        return Err(MeshError::MissingSection {
            path: path.to_path_buf(),
            location: p.location(0),
            section: "MeshFormat",
        });
    };
    if name != "MeshFormat" {
        return Err(MeshError::MissingSection {
            path: path.to_path_buf(),
            location: p.location(header_at),
            section: "MeshFormat",
        });
    }
    let version = parse_mesh_format(&mut p)?;

    let mut nodes: Option<(Vec<[f64; 3]>, TagMap)> = None;
    let mut elements: Option<ParsedElements> = None;
    while let Some((header_at, name)) = p.section_header()? {
        match name.as_str() {
            "MeshFormat" => {
                return Err(p.syntax(header_at, "second $MeshFormat section".to_string()))
            }
            "Nodes" => {
                if nodes.is_some() {
                    return Err(p.syntax(
                        header_at,
                        "second $Nodes section (only one is supported)".to_string(),
                    ));
                }
                let (tags, coords, record_at) = match version {
                    Version::V2 => parse_nodes_v2(&mut p)?,
                    Version::V41 => parse_nodes_v41(&mut p)?,
                };
                p.section_end("Nodes")?;
                let tag_map = TagMap::build(&tags).map_err(|index| MeshError::DuplicateNode {
                    path: path.to_path_buf(),
                    location: p.location(record_at[index]),
                    node_tag: tags[index],
                })?;
                nodes = Some((coords, tag_map));
            }
            "Elements" => {
                if elements.is_some() {
                    return Err(p.syntax(
                        header_at,
                        "second $Elements section (only one is supported)".to_string(),
                    ));
                }
                let Some((_, tag_map)) = nodes.as_ref() else {
                    return Err(p.syntax(header_at, "$Elements comes before $Nodes".to_string()));
                };
                let mut collector = TetCollector::new(tag_map);
                match version {
                    Version::V2 => parse_elements_v2(&mut p, &mut collector)?,
                    Version::V41 => parse_elements_v41(&mut p, &mut collector)?,
                }
                p.section_end("Elements")?;
                elements = Some(collector.finish());
            }
            "Entities" if p.binary && version == Version::V41 => skip_entities_binary(&mut p)?,
            other => {
                let other = other.to_string();
                p.skip_section(&other)?;
            }
        }
    }

    let end_location = p.location(data.len());
    let Some((coords, _)) = nodes else {
        return Err(MeshError::MissingSection {
            path: path.to_path_buf(),
            location: end_location,
            section: "Nodes",
        });
    };
    let Some(elements) = elements else {
        return Err(MeshError::MissingSection {
            path: path.to_path_buf(),
            location: end_location,
            section: "Elements",
        });
    };
    let ParsedElements {
        order,
        connectivity,
        element_tags,
        ignored,
        n_tet4,
        n_tet10,
        first_tet4,
        first_tet10,
    } = elements;
    if n_tet4 > 0 && n_tet10 > 0 {
        return Err(MeshError::MixedOrder {
            path: path.to_path_buf(),
            n_tet4,
            first_tet4,
            n_tet10,
            first_tet10,
        });
    }
    Ok(RawMesh {
        coords,
        order: order.unwrap_or(ElementOrder::Linear),
        connectivity,
        element_tags,
        ignored,
        end_location,
    })
}

/// `$MeshFormat`: version, file type (0 ASCII, 1 binary), data size (8), and
/// for binary files the integer 1 written natively, which gives the byte order.
fn parse_mesh_format(p: &mut Parser) -> Result<Version, MeshError> {
    let (version_at, version_token) = p.token("the format version")?;
    let version_text = String::from_utf8_lossy(version_token).into_owned();
    let version = match version_text.parse::<f64>() {
        Ok(v) if (2.0..3.0).contains(&v) => Version::V2,
        Ok(v) if (v - 4.1).abs() < 1e-9 => Version::V41,
        _ => {
            return Err(MeshError::UnsupportedVersion {
                path: p.path.to_path_buf(),
                location: p.location(version_at),
                version: show(version_token),
            })
        }
    };
    p.skip_space();
    let file_type_at = p.pos;
    let file_type = p.u64_token("the file type", false)?;
    p.skip_space();
    let data_size_at = p.pos;
    let data_size = p.u64_token("the data size", false)?;
    match file_type {
        0 => {}
        1 => {
            p.end_count_line()?;
            let one_at = p.pos;
            let bytes = p.take(4, "the binary endianness marker")?;
            let raw = [bytes[0], bytes[1], bytes[2], bytes[3]];
            p.big_endian = if i32::from_le_bytes(raw) == 1 {
                false
            } else if i32::from_be_bytes(raw) == 1 {
                true
            } else {
                return Err(p.syntax(
                    one_at,
                    "binary endianness marker is not the integer 1".to_string(),
                ));
            };
            p.binary = true;
        }
        _ => {
            return Err(p.syntax(
                file_type_at,
                format!("file type must be 0 (ASCII) or 1 (binary), found {file_type}"),
            ))
        }
    }
    if data_size != 8 {
        return Err(p.syntax(
            data_size_at,
            format!("data size must be 8, found {data_size}"),
        ));
    }
    p.section_end("MeshFormat")?;
    Ok(version)
}

fn check_finite(p: &Parser, xyz: [f64; 3], tag: u64, at: usize) -> Result<(), MeshError> {
    if xyz.iter().all(|c| c.is_finite()) {
        Ok(())
    } else {
        Err(MeshError::NonFiniteCoordinate {
            path: p.path.to_path_buf(),
            location: p.location(at),
            node_tag: tag,
        })
    }
}

type NodeBlock = (Vec<u64>, Vec<[f64; 3]>, Vec<usize>);

/// MSH 2 `$Nodes`: count, then `tag x y z` per node (ASCII lines, or binary
/// int + 3 doubles).
fn parse_nodes_v2(p: &mut Parser) -> Result<NodeBlock, MeshError> {
    let count = p.count_token("the number of nodes")?;
    let record_bytes = if p.binary { 4 + 24 } else { 8 };
    let capacity = p.capacity_for(count, record_bytes);
    let (mut tags, mut coords, mut record_at) = (
        Vec::with_capacity(capacity),
        Vec::with_capacity(capacity),
        Vec::with_capacity(capacity),
    );
    if p.binary {
        p.end_count_line()?;
        for _ in 0..count {
            let at = p.pos;
            let record = p.take(record_bytes, "a binary node record")?;
            let tag = p.decode_i32(&record[0..4]);
            let tag =
                u64::try_from(tag).map_err(|_| p.syntax(at, format!("negative node tag {tag}")))?;
            let xyz = [
                p.decode_f64(&record[4..12]),
                p.decode_f64(&record[12..20]),
                p.decode_f64(&record[20..28]),
            ];
            check_finite(p, xyz, tag, at)?;
            tags.push(tag);
            coords.push(xyz);
            record_at.push(at);
        }
    } else {
        p.end_of_line("the number of nodes")?;
        for _ in 0..count {
            p.skip_space();
            let at = p.pos;
            let tag = p.u64_token("a node tag", true)?;
            let xyz = [
                p.f64_token("the x coordinate", true)?,
                p.f64_token("the y coordinate", true)?,
                p.f64_token("the z coordinate", true)?,
            ];
            p.end_of_line("a node record")?;
            check_finite(p, xyz, tag, at)?;
            tags.push(tag);
            coords.push(xyz);
            record_at.push(at);
        }
    }
    Ok((tags, coords, record_at))
}

/// MSH 4.1 `$Nodes`: header (numEntityBlocks numNodes minNodeTag maxNodeTag),
/// then per entity block (entityDim entityTag parametric numNodesInBlock) the
/// block's node tags followed by its coordinates (x y z, plus entityDim
/// parametric coordinates when `parametric` is 1).
fn parse_nodes_v41(p: &mut Parser) -> Result<NodeBlock, MeshError> {
    let header_at = p.pos;
    let (n_blocks, n_nodes) = if p.binary {
        let n_blocks = p.bin_count("the number of node blocks")?;
        let n_nodes = p.bin_count("the number of nodes")?;
        p.bin_u64("the minimum node tag")?;
        p.bin_u64("the maximum node tag")?;
        (n_blocks, n_nodes)
    } else {
        let n_blocks = p.count_token("the number of node blocks")?;
        let n_nodes = p.count_token("the number of nodes")?;
        p.u64_token("the minimum node tag", false)?;
        p.u64_token("the maximum node tag", false)?;
        (n_blocks, n_nodes)
    };
    let capacity = p.capacity_for(n_nodes, if p.binary { 32 } else { 8 });
    let (mut tags, mut coords, mut record_at) = (
        Vec::with_capacity(capacity),
        Vec::with_capacity(capacity),
        Vec::with_capacity(capacity),
    );
    for _ in 0..n_blocks {
        p.skip_space_if_ascii();
        let block_at = p.pos;
        let (entity_dim, parametric, in_block) = if p.binary {
            let dim = p.bin_i32("a node block's entity dimension")?;
            p.bin_i32("a node block's entity tag")?;
            let parametric = p.bin_i32("a node block's parametric flag")?;
            (
                i64::from(dim),
                i64::from(parametric),
                p.bin_count("the number of nodes in a block")?,
            )
        } else {
            let dim = p.i64_token("a node block's entity dimension", false)?;
            p.i64_token("a node block's entity tag", false)?;
            let parametric = p.i64_token("a node block's parametric flag", false)?;
            (
                dim,
                parametric,
                p.count_token("the number of nodes in a block")?,
            )
        };
        if !(0..=3).contains(&entity_dim) || !(0..=1).contains(&parametric) {
            return Err(p.syntax(
                block_at,
                format!("bad node block header (entity dimension {entity_dim}, parametric flag {parametric})"),
            ));
        }
        let extra_values = if parametric == 1 {
            entity_dim as usize
        } else {
            0
        };
        let first = tags.len();
        for _ in 0..in_block {
            p.skip_space_if_ascii();
            record_at.push(p.pos);
            let tag = if p.binary {
                p.bin_u64("a node tag")?
            } else {
                p.u64_token("a node tag", false)?
            };
            tags.push(tag);
        }
        for i in 0..in_block {
            p.skip_space_if_ascii();
            let at = p.pos;
            let mut xyz = [0.0; 3];
            if p.binary {
                let record = p.take(8 * (3 + extra_values), "binary node coordinates")?;
                for (k, c) in xyz.iter_mut().enumerate() {
                    *c = p.decode_f64(&record[8 * k..8 * k + 8]);
                }
            } else {
                for c in xyz.iter_mut() {
                    *c = p.f64_token("a node coordinate", false)?;
                }
                for _ in 0..extra_values {
                    p.f64_token("a parametric node coordinate", false)?;
                }
            }
            check_finite(p, xyz, tags[first + i], at)?;
            coords.push(xyz);
        }
    }
    if tags.len() != n_nodes {
        return Err(p.syntax(
            header_at,
            format!(
                "$Nodes announces {n_nodes} nodes but its blocks hold {}",
                tags.len()
            ),
        ));
    }
    Ok((tags, coords, record_at))
}

/// MSH 2 `$Elements`. ASCII: one line per element, `tag type numTags tags...
/// nodes...`. Binary: blocks, each a header (type, numElementsInBlock,
/// numTags) followed by that many records `tag tags... nodes...` of ints.
fn parse_elements_v2(p: &mut Parser, tets: &mut TetCollector) -> Result<(), MeshError> {
    let count = p.count_token("the number of elements")?;
    if p.binary {
        p.end_count_line()?;
        let mut done = 0usize;
        while done < count {
            let header_at = p.pos;
            let element_type = i64::from(p.bin_i32("an element block's type")?);
            let in_block = p.bin_nonneg_i32("the number of elements in a block")?;
            let n_tags = p.bin_nonneg_i32("the number of element tags")?;
            if in_block == 0 || in_block > count - done {
                return Err(p.syntax(
                    header_at,
                    format!(
                        "element block of {in_block} elements does not fit the {} still announced",
                        count - done
                    ),
                ));
            }
            let Some((n_nodes, _)) = element_type_info(element_type) else {
                return Err(p.syntax(header_at, format!("unknown element type {element_type} (its size is unknown, so it cannot be skipped)")));
            };
            let ints_per_record = 1 + n_tags + n_nodes;
            let record_bytes = 4 * ints_per_record;
            let block_bytes = record_bytes
                .checked_mul(in_block)
                .filter(|&b| b <= p.remaining());
            if block_bytes.is_none() {
                return Err(p.truncated("a binary element block"));
            }
            if element_type == TYPE_TET4 || element_type == TYPE_TET10 {
                tets.connectivity.reserve(in_block * n_nodes);
                for _ in 0..in_block {
                    let at = p.pos;
                    let record = p.take(record_bytes, "a binary element record")?;
                    let element_tag = p.decode_i32(&record[0..4]);
                    let element_tag = u64::try_from(element_tag)
                        .map_err(|_| p.syntax(at, format!("negative element tag {element_tag}")))?;
                    if tets.start_tet(element_type, element_tag) {
                        for k in 0..n_nodes {
                            let offset = 4 * (1 + n_tags + k);
                            let node_tag = p.decode_i32(&record[offset..offset + 4]);
                            let index = u64::try_from(node_tag)
                                .ok()
                                .and_then(|t| tets.tag_map.get(t));
                            let index = index.ok_or_else(|| {
                                p.unknown_node(at + offset, element_tag, node_tag as u64)
                            })?;
                            tets.connectivity.push(index);
                        }
                    }
                }
            } else {
                p.take(record_bytes * in_block, "a binary element block")?;
                tets.ignore(element_type, in_block);
            }
            done += in_block;
        }
    } else {
        p.end_of_line("the number of elements")?;
        let mut node_tags = [0u64; 10];
        for _ in 0..count {
            p.skip_space();
            let element_tag = p.u64_token("an element tag", true)?;
            let element_type = p.i64_token("an element type", true)?;
            if element_type != TYPE_TET4 && element_type != TYPE_TET10 {
                tets.ignore(element_type, 1);
                p.skip_line();
                continue;
            }
            let n_tags = p.u64_token("the number of element tags", true)?;
            for _ in 0..n_tags {
                p.i64_token("an element tag value", true)?;
            }
            let n_nodes = if element_type == TYPE_TET4 { 4 } else { 10 };
            let mut node_at = [0usize; 10];
            for k in 0..n_nodes {
                p.skip_inline_space();
                node_at[k] = p.pos;
                node_tags[k] = p.u64_token("an element node tag", true)?;
            }
            p.end_of_line("an element record")?;
            if tets.start_tet(element_type, element_tag) {
                for k in 0..n_nodes {
                    let index = tets
                        .tag_map
                        .get(node_tags[k])
                        .ok_or_else(|| p.unknown_node(node_at[k], element_tag, node_tags[k]))?;
                    tets.connectivity.push(index);
                }
            }
        }
    }
    Ok(())
}

/// MSH 4.1 `$Elements`: header (numEntityBlocks numElements minTag maxTag),
/// then per block (entityDim entityTag elementType numElementsInBlock) the
/// records `tag node...` (ASCII lines, or binary size_t values).
fn parse_elements_v41(p: &mut Parser, tets: &mut TetCollector) -> Result<(), MeshError> {
    let header_at = p.pos;
    let (n_blocks, n_elements) = if p.binary {
        let n_blocks = p.bin_count("the number of element blocks")?;
        let n_elements = p.bin_count("the number of elements")?;
        p.bin_u64("the minimum element tag")?;
        p.bin_u64("the maximum element tag")?;
        (n_blocks, n_elements)
    } else {
        let n_blocks = p.count_token("the number of element blocks")?;
        let n_elements = p.count_token("the number of elements")?;
        p.u64_token("the minimum element tag", false)?;
        p.u64_token("the maximum element tag", false)?;
        (n_blocks, n_elements)
    };
    let mut seen = 0usize;
    for _ in 0..n_blocks {
        p.skip_space_if_ascii();
        let block_at = p.pos;
        let (element_type, in_block) = if p.binary {
            p.bin_i32("an element block's entity dimension")?;
            p.bin_i32("an element block's entity tag")?;
            let element_type = i64::from(p.bin_i32("an element block's type")?);
            (
                element_type,
                p.bin_count("the number of elements in a block")?,
            )
        } else {
            p.i64_token("an element block's entity dimension", false)?;
            p.i64_token("an element block's entity tag", false)?;
            let element_type = p.i64_token("an element block's type", false)?;
            (
                element_type,
                p.count_token("the number of elements in a block")?,
            )
        };
        seen = seen.saturating_add(in_block);
        let is_tet = element_type == TYPE_TET4 || element_type == TYPE_TET10;
        let n_nodes = match element_type_info(element_type) {
            Some((n, _)) => n,
            None if !p.binary => {
                // ASCII records are lines, so even an unknown type can be skipped.
                p.skip_records(in_block, "an element record")?;
                tets.ignore(element_type, in_block);
                continue;
            }
            None => {
                return Err(p.syntax(block_at, format!("unknown element type {element_type} (its size is unknown, so it cannot be skipped)")));
            }
        };
        if p.binary {
            let record_bytes = 8 * (1 + n_nodes);
            if record_bytes
                .checked_mul(in_block)
                .is_none_or(|b| b > p.remaining())
            {
                return Err(p.truncated("a binary element block"));
            }
            if !is_tet {
                p.take(record_bytes * in_block, "a binary element block")?;
                tets.ignore(element_type, in_block);
                continue;
            }
            tets.connectivity.reserve(in_block * n_nodes);
            for _ in 0..in_block {
                let at = p.pos;
                let record = p.take(record_bytes, "a binary element record")?;
                let element_tag = p.decode_u64(&record[0..8]);
                if tets.start_tet(element_type, element_tag) {
                    for k in 0..n_nodes {
                        let offset = 8 * (1 + k);
                        let node_tag = p.decode_u64(&record[offset..offset + 8]);
                        let index = tets
                            .tag_map
                            .get(node_tag)
                            .ok_or_else(|| p.unknown_node(at + offset, element_tag, node_tag))?;
                        tets.connectivity.push(index);
                    }
                }
            }
        } else {
            if !is_tet {
                p.skip_records(in_block, "an element record")?;
                tets.ignore(element_type, in_block);
                continue;
            }
            let mut node_tags = [0u64; 10];
            let mut node_at = [0usize; 10];
            for _ in 0..in_block {
                p.skip_space();
                let element_tag = p.u64_token("an element tag", true)?;
                for k in 0..n_nodes {
                    p.skip_inline_space();
                    node_at[k] = p.pos;
                    node_tags[k] = p.u64_token("an element node tag", true)?;
                }
                p.end_of_line("an element record")?;
                if tets.start_tet(element_type, element_tag) {
                    for k in 0..n_nodes {
                        let index = tets
                            .tag_map
                            .get(node_tags[k])
                            .ok_or_else(|| p.unknown_node(node_at[k], element_tag, node_tags[k]))?;
                        tets.connectivity.push(index);
                    }
                }
            }
        }
    }
    if seen != n_elements {
        return Err(p.syntax(
            header_at,
            format!("$Elements announces {n_elements} elements but its blocks hold {seen}"),
        ));
    }
    Ok(())
}

/// Binary MSH 4.1 `$Entities`: walks the records (points, curves, surfaces,
/// volumes with their physical and bounding tags) so that no byte of binary
/// data is mistaken for the closing line. If the walk does not land on
/// `$EndEntities`, falls back to searching for it.
fn skip_entities_binary(p: &mut Parser) -> Result<(), MeshError> {
    let start = p.pos;
    let walked = walk_entities_binary(p).is_ok() && p.section_end("Entities").is_ok();
    if !walked {
        p.pos = start;
        p.skip_section("Entities")?;
    }
    Ok(())
}

fn walk_entities_binary(p: &mut Parser) -> Result<(), MeshError> {
    let counts = [
        p.bin_count("the number of points")?,
        p.bin_count("the number of curves")?,
        p.bin_count("the number of surfaces")?,
        p.bin_count("the number of volumes")?,
    ];
    for (dim, &count) in counts.iter().enumerate() {
        for _ in 0..count {
            p.take(4, "an entity tag")?;
            // A point stores its position, higher entities their bounding box.
            p.take(if dim == 0 { 24 } else { 48 }, "entity coordinates")?;
            let n_physical = p.bin_count("the number of physical tags")?;
            p.take(
                n_physical
                    .checked_mul(4)
                    .ok_or_else(|| p.truncated("physical tags"))?,
                "physical tags",
            )?;
            if dim > 0 {
                let n_bounding = p.bin_count("the number of bounding entities")?;
                p.take(
                    n_bounding
                        .checked_mul(4)
                        .ok_or_else(|| p.truncated("bounding tags"))?,
                    "bounding tags",
                )?;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
