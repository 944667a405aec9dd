//! Tetrahedral meshes: reading Gmsh files, checking them, lifting, straightening,
//! locating points on them, writing and generating them, and the geometric queries
//! the FEM and audio stages need. Meshes built from implicit shapes (signed distances,
//! marching tetrahedra) are made in [`crate::shape`].
//!
//! # Formats
//! [`read_mesh`] reads Gmsh MSH files in version **2.2** (2.0 and 2.1 share its
//! layout and are accepted too) and **4.1**, each in ASCII and binary form
//! (either endianness, data size 8). The version and form come from the
//! `$MeshFormat` section. Only 4-node (Gmsh type 4) and 10-node (type 11)
//! tetrahedra are kept; every other element type is ignored with one summary
//! warning, and a file that mixes 4- and 10-node tets is rejected. Sections the
//! reader does not need (`$PhysicalNames`, `$Entities`, `$Periodic`,
//! `$NodeData`, ...) are skipped. Node tags may be sparse; they are mapped to
//! compact 0-based indices in file order, and nodes that no tetrahedron uses
//! are dropped (with a warning) so that the FEM never sees a free node.
//!
//! # Node ordering
//! Everything in this module uses Gmsh's tetrahedron node order: corners
//! 0, 1, 2, 3, then the mid-edge nodes of the edges listed in [`TET10_EDGES`]:
//! 4:(0,1) 5:(1,2) 6:(0,2) 7:(0,3) 8:(2,3) 9:(1,3).
//! Sources: the Gmsh reference manual's high-order node ordering as explained
//! on the Gmsh mailing list (M. Vymazal, "Numbering of higher order
//! elements", 16 July 2014, <http://onelab.info/pipermail/gmsh/2014/009142.html>:
//! edges 0-1, 1-2, 2-0, 3-0, 3-2, 3-1) and the Kratos "Mesh Node Ordering"
//! page, which reproduces Gmsh's Tetrahedron10 diagram. The tests confirm it on
//! 10-node meshes written by gmsh 4.8.4 (straight-sided cube: every mid node is
//! the midpoint of the edge this table names).
//!
//! # Orientation and signs
//! A tet is *positively oriented* when its corners satisfy
//! `det[x1-x0, x2-x0, x3-x0] > 0`, i.e. corner 3 lies on the side of the
//! triangle (0,1,2) that its right-hand normal points to; this is the
//! orientation of Gmsh's reference tetrahedron. [`TetMesh::corner_volume`] is
//! that determinant divided by 6 (signed). Boundary faces are returned with
//! their corners ordered so that the right-hand normal points out of the body.
//!
//! # Zero-volume rule
//! With `D` the length of the bounding-box diagonal of the mesh, a tet whose
//! corner volume `V` satisfies `|V| <= 1e-12 * D^3` counts as zero-volume
//! (degenerate) and `V < -1e-12 * D^3` as inverted. The tolerance is relative
//! so that it does not depend on the unit; `1e-12` is far below the volume of
//! any tet a practical mesh of the box can contain (a regular tet of edge
//! `D/1000` has `V ~ 1e-10 D^3`) yet far above round-off of the determinant.
//! Both are errors when reading; inverted tets can instead be flipped with
//! [`ReadOptions::fix_inverted`]. Curved 10-node tets whose Jacobian becomes
//! non-positive inside the element are not detected by [`read_mesh`] (only
//! corners are checked): [`read_for_fem`], the reader of every job that
//! assembles a mesh, finds them ([`straighten`]) and refuses the file or, on
//! request, straightens them.
//!
//! # Errors and warnings
//! Every [`MeshError`] names the file and where: the line (ASCII), the byte
//! offset (binary) or the element tag. Problems that leave a usable mesh
//! (ignored element types, dropped nodes, several connected pieces, flipped
//! tets) are returned as one-line warnings in [`MeshRead::warnings`].

use std::fmt;
use std::path::PathBuf;

mod generate;
mod gmsh;
mod lift;
pub mod straighten;
mod validate;
mod write;

#[cfg(test)]
pub(crate) mod tests;

pub mod locate;
pub use generate::box_mesh;
pub(crate) use generate::KUHN_TETS;
pub use gmsh::{read_mesh, read_mesh_from_bytes};
pub use lift::{lift_to_quadratic, linear_node_gradient, to_linear, LiftError};
pub use locate::SurfacePoint;
pub use straighten::read_for_fem;
pub use validate::ZERO_VOLUME_RELATIVE_TOLERANCE;
pub use write::write_msh22_ascii;

/// The mid-edge nodes 4..=9 of a 10-node tet sit on these corner pairs, in
/// this order (Gmsh order, see the module docs).
pub const TET10_EDGES: [(usize, usize); 6] = [(0, 1), (1, 2), (0, 2), (0, 3), (2, 3), (1, 3)];

/// Corner triples of the four faces of a positively oriented tet, each ordered
/// so that its right-hand normal points out of the tet.
pub const TET_FACES_OUTWARD: [[usize; 3]; 4] = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];

/// Polynomial order of the tetrahedra of a mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ElementOrder {
    /// 4-node tets (Gmsh type 4).
    Linear,
    /// 10-node tets (Gmsh type 11).
    Quadratic,
}

impl ElementOrder {
    /// 4 for linear, 10 for quadratic tets.
    pub fn nodes_per_tet(self) -> usize {
        match self {
            ElementOrder::Linear => 4,
            ElementOrder::Quadratic => 10,
        }
    }
}

/// An unstructured mesh of tetrahedra of one order.
#[derive(Clone, Debug, PartialEq)]
pub struct TetMesh {
    /// Node coordinates in metres (after unit scaling).
    pub nodes: Vec<[f64; 3]>,
    /// `nodes_per_tet()` 0-based node indices per tet, in Gmsh node order.
    pub connectivity: Vec<usize>,
    pub order: ElementOrder,
}

impl TetMesh {
    /// 4 or 10.
    pub fn nodes_per_tet(&self) -> usize {
        self.order.nodes_per_tet()
    }

    pub fn n_tets(&self) -> usize {
        self.connectivity.len() / self.nodes_per_tet()
    }

    pub fn n_nodes(&self) -> usize {
        self.nodes.len()
    }

    /// Node indices of tet `e` (4 or 10 of them).
    pub fn tet(&self, e: usize) -> &[usize] {
        let npt = self.nodes_per_tet();
        &self.connectivity[e * npt..(e + 1) * npt]
    }

    /// Coordinates of all nodes of tet `e`, in element node order.
    pub fn tet_coords(&self, e: usize) -> Vec<[f64; 3]> {
        self.tet(e).iter().map(|&n| self.nodes[n]).collect()
    }

    /// Coordinates of the 4 corners of tet `e` (no allocation).
    pub fn corner_coords(&self, e: usize) -> [[f64; 3]; 4] {
        let t = self.tet(e);
        [
            self.nodes[t[0]],
            self.nodes[t[1]],
            self.nodes[t[2]],
            self.nodes[t[3]],
        ]
    }

    /// Signed volume of the straight tet on the 4 corners of tet `e`:
    /// positive for a positively oriented tet (see the module docs).
    pub fn corner_volume(&self, e: usize) -> f64 {
        let [a, b, c, d] = self.corner_coords(e);
        signed_tet_volume(a, b, c, d)
    }

    /// Sum of the signed corner volumes of all tets.
    pub fn volume(&self) -> f64 {
        (0..self.n_tets()).map(|e| self.corner_volume(e)).sum()
    }

    /// Centroid c \[m\] and second moment of volume about it, C = (1/V) ∫ (x − c)(x − c)ᵀ dV
    /// \[m²\], over the straight tets on the corners. Exact for them: a tet of volume V_e and
    /// corners x_i has ∫ x dV = V_e (Σ x_i)/4 and ∫ x xᵀ dV = V_e/20 (Σ x_i x_iᵀ + (Σ x_i)(Σ x_i)ᵀ).
    /// None for a mesh of no volume. A body of revolution has two equal eigenvalues of C, and
    /// its axis is the eigenvector of the third.
    pub fn volume_moments(&self) -> Option<([f64; 3], [[f64; 3]; 3])> {
        let mut volume = 0.0;
        let mut first = [0.0; 3];
        let mut second = [[0.0; 3]; 3];
        for e in 0..self.n_tets() {
            let corners = self.corner_coords(e);
            let v = signed_tet_volume(corners[0], corners[1], corners[2], corners[3]);
            let sum: [f64; 3] = std::array::from_fn(|r| corners.iter().map(|x| x[r]).sum::<f64>());
            volume += v;
            for r in 0..3 {
                first[r] += v * sum[r] / 4.0;
                for c in 0..3 {
                    let own: f64 = corners.iter().map(|x| x[r] * x[c]).sum();
                    second[r][c] += v / 20.0 * (own + sum[r] * sum[c]);
                }
            }
        }
        if !(volume.abs() > 0.0 && volume.is_finite()) {
            return None;
        }
        let centre: [f64; 3] = std::array::from_fn(|r| first[r] / volume);
        let moments = std::array::from_fn(|r| {
            std::array::from_fn(|c| second[r][c] / volume - centre[r] * centre[c])
        });
        Some((centre, moments))
    }

    /// Axis-aligned bounding box `(min, max)` of all nodes; `([0;3], [0;3])`
    /// for a mesh without nodes.
    pub fn bounding_box(&self) -> ([f64; 3], [f64; 3]) {
        bounding_box_of(&self.nodes)
    }

    /// Faces owned by exactly one tet, as corner-node triples ordered so the
    /// right-hand normal points out of the body. Sorted by their sorted node
    /// triple, so the result is deterministic. A tet with negative corner
    /// volume has its faces reversed, so the normals still point outward.
    pub fn boundary_faces(&self) -> Vec<[usize; 3]> {
        // (sorted key, outward-ordered face); a face shared by two tets shows
        // up twice with the same key and is interior.
        let mut faces: Vec<([usize; 3], [usize; 3])> = Vec::with_capacity(4 * self.n_tets());
        for e in 0..self.n_tets() {
            let t = self.tet(e);
            let reversed = self.corner_volume(e) < 0.0;
            for local in TET_FACES_OUTWARD {
                let mut face = [t[local[0]], t[local[1]], t[local[2]]];
                if reversed {
                    face.swap(1, 2);
                }
                let mut key = face;
                key.sort_unstable();
                faces.push((key, face));
            }
        }
        faces.sort_unstable_by_key(|&(key, _)| key);
        let mut boundary = Vec::new();
        let mut i = 0;
        while i < faces.len() {
            let mut j = i + 1;
            while j < faces.len() && faces[j].0 == faces[i].0 {
                j += 1;
            }
            if j - i == 1 {
                boundary.push(faces[i].1);
            }
            i = j;
        }
        boundary
    }

    /// Sorted, de-duplicated corner nodes lying on a boundary face.
    pub fn surface_vertices(&self) -> Vec<usize> {
        let mut vertices: Vec<usize> = self.boundary_faces().into_iter().flatten().collect();
        vertices.sort_unstable();
        vertices.dedup();
        vertices
    }

    /// Unit outward normal at every surface vertex, sorted by vertex index:
    /// the normalised sum of the normals of the boundary faces around the
    /// vertex, each weighted by its face area (the un-normalised cross
    /// product is exactly twice that).
    pub fn vertex_normals(&self) -> Vec<(usize, [f64; 3])> {
        let faces = self.boundary_faces();
        let mut vertices: Vec<usize> = faces.iter().flatten().copied().collect();
        vertices.sort_unstable();
        vertices.dedup();
        let mut sums = vec![[0.0f64; 3]; vertices.len()];
        for face in &faces {
            let [a, b, c] = face.map(|n| self.nodes[n]);
            let area_normal = cross(sub(b, a), sub(c, a));
            for n in face {
                // `vertices` holds every face node, so the search succeeds.
                if let Ok(slot) = vertices.binary_search(n) {
                    for k in 0..3 {
                        sums[slot][k] += area_normal[k];
                    }
                }
            }
        }
        vertices
            .into_iter()
            .zip(sums)
            .map(|(v, s)| {
                let len = norm(s);
                let unit = if len > 0.0 {
                    [s[0] / len, s[1] / len, s[2] / len]
                } else {
                    [0.0; 3]
                };
                (v, unit)
            })
            .collect()
    }

    /// Number of connected pieces, two tets being connected when they share
    /// a node. Nodes no tet uses are not counted.
    pub fn connected_components(&self) -> usize {
        if self.n_tets() == 0 {
            return 0;
        }
        let mut sets = DisjointSets::new(self.n_nodes());
        for e in 0..self.n_tets() {
            let t = self.tet(e);
            // Corners suffice: every mid node lies on an edge between corners.
            for &n in &t[1..4] {
                sets.union(t[0], n);
            }
        }
        let mut roots: Vec<usize> = (0..self.n_tets())
            .map(|e| sets.find(self.tet(e)[0]))
            .collect();
        roots.sort_unstable();
        roots.dedup();
        roots.len()
    }
}

/// Options of [`read_mesh`].
#[derive(Clone, Debug, PartialEq)]
pub struct ReadOptions {
    /// Metres per mesh unit (see [`parse_unit`]); coordinates are multiplied
    /// by it.
    pub unit_scale: f64,
    /// Flip inverted tets (swap corners 1 and 2 and the matching mid-edge
    /// nodes) instead of rejecting the file; each flip is reported as a
    /// warning.
    pub fix_inverted: bool,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions {
            unit_scale: 1.0,
            fix_inverted: false,
        }
    }
}

/// A mesh read from a file plus everything worth telling the user about it.
#[derive(Clone, Debug)]
pub struct MeshRead {
    pub mesh: TetMesh,
    /// The Gmsh element tag of each tet, in the order of `mesh`'s tets.
    pub element_tags: Vec<u64>,
    /// One line per issue that did not prevent reading (ignored element
    /// types, dropped nodes, several connected pieces, flipped tets).
    pub warnings: Vec<String>,
}

/// Where in a file something went wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Location {
    /// 1-based line of an ASCII file.
    Line(usize),
    /// 0-based byte offset in a binary file.
    ByteOffset(usize),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line(line) => write!(f, "line {line}"),
            Location::ByteOffset(offset) => write!(f, "byte offset {offset}"),
        }
    }
}

/// A tetrahedron that failed the volume check, named by its element tag in
/// the file.
#[derive(Clone, Debug, PartialEq)]
pub struct BadTet {
    pub element_tag: u64,
    /// Signed corner volume in cubic metres.
    pub volume: f64,
}

impl fmt::Display for BadTet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "element {} (V = {:.3e} m^3)",
            self.element_tag, self.volume
        )
    }
}

fn list_bad_tets(tets: &[BadTet]) -> String {
    tets.iter()
        .map(|t| t.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Everything that can go wrong reading a mesh. Each variant names the file
/// and where in it (line, byte offset or element tag) the problem is.
#[derive(thiserror::Error, Debug)]
pub enum MeshError {
    #[error("{}: cannot read file: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: {location}: unexpected end of file while reading {what}", path.display())]
    Truncated {
        path: PathBuf,
        location: Location,
        what: String,
    },
    #[error("{}: {location}: {message}", path.display())]
    Syntax {
        path: PathBuf,
        location: Location,
        message: String,
    },
    #[error("{}: {location}: missing ${section} section", path.display())]
    MissingSection {
        path: PathBuf,
        location: Location,
        section: &'static str,
    },
    #[error(
        "{}: {location}: unsupported MSH format version {version} \
         (supported: 2.2 and 4.1, ASCII or binary)",
        path.display()
    )]
    UnsupportedVersion {
        path: PathBuf,
        location: Location,
        version: String,
    },
    #[error("{}: {location}: node {node_tag} has a non-finite coordinate", path.display())]
    NonFiniteCoordinate {
        path: PathBuf,
        location: Location,
        node_tag: u64,
    },
    #[error("{}: {location}: node tag {node_tag} appears more than once", path.display())]
    DuplicateNode {
        path: PathBuf,
        location: Location,
        node_tag: u64,
    },
    #[error(
        "{}: {location}: element {element_tag} uses node {node_tag}, which is not in $Nodes",
        path.display()
    )]
    UnknownNode {
        path: PathBuf,
        location: Location,
        element_tag: u64,
        node_tag: u64,
    },
    #[error(
        "{}: mixes {n_tet4} 4-node tets (first: element {first_tet4}) and {n_tet10} \
         10-node tets (first: element {first_tet10}); a mesh must use one order",
        path.display()
    )]
    MixedOrder {
        path: PathBuf,
        n_tet4: usize,
        first_tet4: u64,
        n_tet10: usize,
        first_tet10: u64,
    },
    #[error("{}: {location}: no tetrahedra (element type 4 or 11) in the file{detail}", path.display())]
    NoTetrahedra {
        path: PathBuf,
        location: Location,
        detail: String,
    },
    #[error(
        "{}: {n_inverted} inverted and {n_degenerate} zero-volume tetrahedra \
         (|V| <= {tolerance:.3e} m^3 counts as zero); first: {}{}",
        path.display(),
        list_bad_tets(examples),
        if *n_inverted > 0 && *n_degenerate == 0 { " (ReadOptions::fix_inverted flips inverted ones)" } else { "" }
    )]
    BadVolume {
        path: PathBuf,
        n_inverted: usize,
        n_degenerate: usize,
        tolerance: f64,
        examples: Vec<BadTet>,
    },
    #[error("{}: invalid read option: {message}", path.display())]
    BadOption { path: PathBuf, message: String },
    /// Curved 10-node tets whose map folds over ([`straighten`]), refused by
    /// [`read_for_fem`] unless asked to straighten them.
    #[error("{}: {count} curved 10-node tetrahedra fold over (Jacobian determinant ≤ 0 inside the element; Gmsh element tags {tags}): rerun with --straighten-invalid to straighten their mid-edge nodes, or untangle the mesh with `gmsh -optimize_ho`", path.display())]
    FoldedTets {
        path: PathBuf,
        count: usize,
        /// The first Gmsh element tags, with an ellipsis when there are more.
        tags: String,
    },
    #[error("invalid length unit {input:?}: expected m, cm, mm, um, in, ft or a positive number of metres")]
    BadUnit { input: String },
}

/// Metres per unit for a unit name (`m`, `cm`, `mm`, `um`/`µm`, `in`, `ft`)
/// or a positive finite number of metres such as `"0.1"`.
pub fn parse_unit(s: &str) -> Result<f64, MeshError> {
    let trimmed = s.trim();
    let named = match trimmed {
        "m" => Some(1.0),
        "cm" => Some(0.01),
        "mm" => Some(1e-3),
        "um" | "µm" | "μm" => Some(1e-6),
        "in" => Some(0.0254),
        "ft" => Some(0.3048),
        _ => None,
    };
    if let Some(scale) = named {
        return Ok(scale);
    }
    match trimmed.parse::<f64>() {
        Ok(scale) if scale.is_finite() && scale > 0.0 => Ok(scale),
        _ => Err(MeshError::BadUnit {
            input: s.to_string(),
        }),
    }
}

// ---- small geometry helpers shared by the submodules ----

pub(crate) use crate::numerics::{cross, dot, norm, sub};

/// `det[b-a, c-a, d-a] / 6`.
pub(crate) fn signed_tet_volume(a: [f64; 3], b: [f64; 3], c: [f64; 3], d: [f64; 3]) -> f64 {
    dot(sub(b, a), cross(sub(c, a), sub(d, a))) / 6.0
}

pub(crate) fn bounding_box_of(points: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let Some(first) = points.first() else {
        return ([0.0; 3], [0.0; 3]);
    };
    let (mut lo, mut hi) = (*first, *first);
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// Union-find with path halving and union by size.
pub(crate) struct DisjointSets {
    parent: Vec<usize>,
    size: Vec<usize>,
}

impl DisjointSets {
    pub(crate) fn new(n: usize) -> Self {
        DisjointSets {
            parent: (0..n).collect(),
            size: vec![1; n],
        }
    }

    pub(crate) fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] != x {
            self.parent[x] = self.parent[self.parent[x]];
            x = self.parent[x];
        }
        x
    }

    pub(crate) fn union(&mut self, a: usize, b: usize) {
        let (mut ra, mut rb) = (self.find(a), self.find(b));
        if ra == rb {
            return;
        }
        if self.size[ra] < self.size[rb] {
            std::mem::swap(&mut ra, &mut rb);
        }
        self.parent[rb] = ra;
        self.size[ra] += self.size[rb];
    }
}
