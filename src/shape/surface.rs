//! Triangle surfaces: the input of the signed distance field ([`super::sdf`]).
//!
//! A [`TriangleSurface`] is a list of vertices (3-vectors, in the unit of the file or the mesh)
//! and of triangles (three 0-based vertex indices). Triangles are expected to be ordered
//! counter-clockwise seen from outside, i.e. with the right-hand normal
//! n = (b − a) × (c − a) pointing out of the body, as OBJ exporters and
//! [`TetMesh::boundary_faces`] do. Nothing here requires the surface to be closed or
//! consistently oriented; the signed distance copes with small holes and flipped triangles.
//!
//! # Sources
//!
//! * [`read_obj`] / [`parse_obj`]: Wavefront OBJ. `v x y z [w]` lines give vertices (any
//!   further numbers, such as a w weight or vertex colours, are ignored); `f` lines give
//!   polygons whose corners are written `v`, `v/vt`, `v//vn` or `v/vt/vn`, with 1-based
//!   indices or negative ones counting back from the last vertex defined so far (−1 is the
//!   latest). A polygon of k ≥ 3 corners is fan-triangulated from its first corner into
//!   k − 2 triangles (0, i, i+1). A line ending in `\` continues on the next line. All other
//!   statements (`vt`, `vn`, `g`, `o`, `s`, `usemtl`, `mtllib`, `l`, `p`, comments, …) are
//!   skipped. Triangles that repeat a vertex index (from degenerate polygons) are dropped
//!   and counted in the warnings.
//! * [`TriangleSurface::from_mesh_boundary`]: the boundary faces of a tet mesh (corner
//!   nodes only, outward order), with the vertices renumbered compactly.
//!
//! Every error names the file and the 1-based line.

use std::fmt;
use std::path::{Path, PathBuf};

use crate::mesh::{bounding_box_of, cross, dot, sub, TetMesh};

/// A triangle soup with shared vertices.
#[derive(Clone, Debug, PartialEq)]
pub struct TriangleSurface {
    /// Vertex coordinates.
    pub vertices: Vec<[f64; 3]>,
    /// Three 0-based vertex indices per triangle, counter-clockwise seen from outside.
    pub triangles: Vec<[usize; 3]>,
}

/// A surface read from a file plus what is worth telling about it.
#[derive(Clone, Debug)]
pub struct SurfaceRead {
    pub surface: TriangleSurface,
    /// One line per issue that did not prevent reading (dropped degenerate triangles).
    pub warnings: Vec<String>,
}

/// Everything that can go wrong reading or building a triangle surface.
#[derive(thiserror::Error, Debug)]
pub enum SurfaceError {
    #[error("{}: cannot read file: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: line {line}: {message}", path.display())]
    Syntax {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error(
        "{}: line {line}: vertex index {index} is out of range ({n_vertices} vertices defined so far)",
        path.display()
    )]
    IndexOutOfRange {
        path: PathBuf,
        line: usize,
        index: i64,
        n_vertices: usize,
    },
    #[error("{}: no triangles (no `f` line with at least 3 distinct vertices)", path.display())]
    NoTriangles { path: PathBuf },
    #[error("triangle {triangle} uses vertex {vertex}, but the surface has {n_vertices} vertices")]
    BadTriangle {
        triangle: usize,
        vertex: usize,
        n_vertices: usize,
    },
    #[error("none of the {n_triangles} triangles has a positive area")]
    NoArea { n_triangles: usize },
    #[error("vertex {vertex} has a non-finite coordinate {coordinates:?}")]
    NonFiniteVertex {
        vertex: usize,
        coordinates: [f64; 3],
    },
}

impl TriangleSurface {
    /// A closed ellipsoid of semi-axes `axes` [m] centred on the origin: a vertex at each pole
    /// and `rings − 1` rings of `2·rings` vertices at evenly spaced polar angles, triangles
    /// counter-clockwise seen from outside (`rings` ≥ 2). For checks that need a smooth,
    /// unsymmetric solid with a known signed distance's behaviour.
    pub fn ellipsoid(axes: [f64; 3], rings: usize) -> TriangleSurface {
        let rings = rings.max(2);
        let segments = 2 * rings;
        let mut vertices = vec![[0.0, 0.0, axes[2]]];
        for i in 1..rings {
            let theta = std::f64::consts::PI * i as f64 / rings as f64;
            for j in 0..segments {
                let phi = 2.0 * std::f64::consts::PI * j as f64 / segments as f64;
                vertices.push([
                    axes[0] * theta.sin() * phi.cos(),
                    axes[1] * theta.sin() * phi.sin(),
                    axes[2] * theta.cos(),
                ]);
            }
        }
        vertices.push([0.0, 0.0, -axes[2]]);
        let south = vertices.len() - 1;
        let ring = |i: usize, j: usize| 1 + (i - 1) * segments + j % segments;
        let mut triangles = Vec::new();
        for j in 0..segments {
            triangles.push([0, ring(1, j), ring(1, j + 1)]);
            triangles.push([south, ring(rings - 1, j + 1), ring(rings - 1, j)]);
        }
        for i in 1..rings - 1 {
            for j in 0..segments {
                triangles.push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
                triangles.push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
            }
        }
        TriangleSurface {
            vertices,
            triangles,
        }
    }

    /// Checks that every index is in range and every coordinate finite.
    pub fn new(vertices: Vec<[f64; 3]>, triangles: Vec<[usize; 3]>) -> Result<Self, SurfaceError> {
        if let Some((vertex, &coordinates)) = vertices
            .iter()
            .enumerate()
            .find(|(_, v)| v.iter().any(|c| !c.is_finite()))
        {
            return Err(SurfaceError::NonFiniteVertex {
                vertex,
                coordinates,
            });
        }
        for (triangle, t) in triangles.iter().enumerate() {
            if let Some(&vertex) = t.iter().find(|&&v| v >= vertices.len()) {
                return Err(SurfaceError::BadTriangle {
                    triangle,
                    vertex,
                    n_vertices: vertices.len(),
                });
            }
        }
        Ok(TriangleSurface {
            vertices,
            triangles,
        })
    }

    /// The boundary of a tet mesh: its faces owned by exactly one tet
    /// ([`TetMesh::boundary_faces`], corners only, right-hand normal outward), on the corner
    /// nodes they use, renumbered compactly in increasing node order.
    pub fn from_mesh_boundary(mesh: &TetMesh) -> Self {
        let faces = mesh.boundary_faces();
        let mut new_index = vec![usize::MAX; mesh.n_nodes()];
        for &n in faces.iter().flatten() {
            new_index[n] = 0;
        }
        let mut vertices = Vec::new();
        for (old, slot) in new_index.iter_mut().enumerate() {
            if *slot == 0 {
                *slot = vertices.len();
                vertices.push(mesh.nodes[old]);
            }
        }
        let triangles = faces.iter().map(|f| f.map(|n| new_index[n])).collect();
        TriangleSurface {
            vertices,
            triangles,
        }
    }

    pub fn n_triangles(&self) -> usize {
        self.triangles.len()
    }

    /// Corner coordinates of triangle `t`.
    pub fn triangle_coords(&self, t: usize) -> [[f64; 3]; 3] {
        self.triangles[t].map(|v| self.vertices[v])
    }

    /// Axis-aligned bounding box `(min, max)` of the vertices that triangles use; `([0;3],
    /// [0;3])` for a surface without triangles.
    pub fn bounding_box(&self) -> ([f64; 3], [f64; 3]) {
        let used: Vec<[f64; 3]> = self
            .triangles
            .iter()
            .flatten()
            .map(|&v| self.vertices[v])
            .collect();
        bounding_box_of(&used)
    }

    /// Total area Σ ½|(b − a) × (c − a)|.
    pub fn area(&self) -> f64 {
        (0..self.n_triangles())
            .map(|t| {
                let [a, b, c] = self.triangle_coords(t);
                0.5 * dot(cross(sub(b, a), sub(c, a)), cross(sub(b, a), sub(c, a))).sqrt()
            })
            .sum()
    }

    /// Signed enclosed volume by the divergence theorem, V = Σ a·(b × c) / 6: the volume of
    /// a closed surface with outward normals, negative when all normals point inward.
    pub fn signed_volume(&self) -> f64 {
        (0..self.n_triangles())
            .map(|t| {
                let [a, b, c] = self.triangle_coords(t);
                dot(a, cross(b, c)) / 6.0
            })
            .sum()
    }

    /// Reverses every triangle (swaps its last two corners), turning the normals around.
    pub fn flip(&mut self) {
        for t in &mut self.triangles {
            t.swap(1, 2);
        }
    }
}

/// Reads a Wavefront OBJ file (format in the module docs).
pub fn read_obj(path: &Path) -> Result<SurfaceRead, SurfaceError> {
    let text = std::fs::read(path).map_err(|source| SurfaceError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_obj(&String::from_utf8_lossy(&text), path)
}

/// Parses OBJ text; `path` only names the source in errors and warnings.
pub fn parse_obj(text: &str, path: &Path) -> Result<SurfaceRead, SurfaceError> {
    let syntax = |line: usize, message: String| SurfaceError::Syntax {
        path: path.to_path_buf(),
        line,
        message,
    };
    let mut vertices: Vec<[f64; 3]> = Vec::new();
    let mut triangles: Vec<[usize; 3]> = Vec::new();
    let mut degenerate = 0usize;
    let mut first_degenerate_line = 0usize;
    let mut corners: Vec<usize> = Vec::new();
    // A statement may span several physical lines ending in `\`; errors name its first line.
    let mut statement = String::new();
    let mut statement_line = 0usize;
    for (i, raw) in text.lines().enumerate() {
        let line_no = i + 1;
        if statement.is_empty() {
            statement_line = line_no;
        }
        if let Some(head) = raw.strip_suffix('\\') {
            statement.push_str(head);
            statement.push(' ');
            continue;
        }
        statement.push_str(raw);
        let content = match statement.find('#') {
            Some(hash) => &statement[..hash],
            None => &statement[..],
        };
        let mut tokens = content.split_whitespace();
        match tokens.next() {
            Some("v") => {
                let mut xyz = [0.0; 3];
                for (k, c) in xyz.iter_mut().enumerate() {
                    let token = tokens.next().ok_or_else(|| {
                        syntax(
                            statement_line,
                            format!("vertex needs 3 coordinates, found {k}"),
                        )
                    })?;
                    *c = token.parse::<f64>().map_err(|_| {
                        syntax(statement_line, format!("bad vertex coordinate {token:?}"))
                    })?;
                    if !c.is_finite() {
                        return Err(syntax(
                            statement_line,
                            format!("non-finite vertex coordinate {token:?}"),
                        ));
                    }
                }
                vertices.push(xyz);
            }
            Some("f") => {
                corners.clear();
                for token in tokens {
                    let index_text = token.split('/').next().unwrap_or("");
                    let index: i64 = index_text.parse().map_err(|_| {
                        syntax(statement_line, format!("bad face corner {token:?}"))
                    })?;
                    let resolved = match index {
                        i if i > 0 && (i as u64) <= vertices.len() as u64 => i as usize - 1,
                        i if i < 0 && i.unsigned_abs() <= vertices.len() as u64 => {
                            vertices.len() - i.unsigned_abs() as usize
                        }
                        _ => {
                            return Err(SurfaceError::IndexOutOfRange {
                                path: path.to_path_buf(),
                                line: statement_line,
                                index,
                                n_vertices: vertices.len(),
                            })
                        }
                    };
                    corners.push(resolved);
                }
                if corners.len() < 3 {
                    return Err(syntax(
                        statement_line,
                        format!("a face needs at least 3 corners, found {}", corners.len()),
                    ));
                }
                for k in 1..corners.len() - 1 {
                    let t = [corners[0], corners[k], corners[k + 1]];
                    if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                        if degenerate == 0 {
                            first_degenerate_line = statement_line;
                        }
                        degenerate += 1;
                    } else {
                        triangles.push(t);
                    }
                }
            }
            _ => {}
        }
        statement.clear();
    }
    if triangles.is_empty() {
        return Err(SurfaceError::NoTriangles {
            path: path.to_path_buf(),
        });
    }
    let mut warnings = Vec::new();
    if degenerate > 0 {
        warnings.push(format!(
            "{}: dropped {degenerate} triangles that repeat a vertex (first on line {first_degenerate_line})",
            path.display()
        ));
    }
    Ok(SurfaceRead {
        surface: TriangleSurface {
            vertices,
            triangles,
        },
        warnings,
    })
}

impl fmt::Display for TriangleSurface {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} vertices, {} triangles",
            self.vertices.len(),
            self.triangles.len()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::box_mesh;

    fn parse(text: &str) -> Result<SurfaceRead, SurfaceError> {
        parse_obj(text, Path::new("inline.obj"))
    }

    #[test]
    fn obj_forms_fans_and_negative_indices() {
        let text = "# a unit square and a triangle\n\
                    mtllib x.mtl\n\
                    v 0 0 0\nv 1 0 0 1.0\nv 1 1 0 0.5 0.5 0.5\nv 0 1 0\n\
                    vt 0 0\nvn 0 0 1\n\
                    g square\ns off\n\
                    f 1/1/1 2/1/1 3//1 4/1\n\
                    v 0 0 1\n\
                    f -5 -4 \\\n  -1   # continued line and comment\n";
        let read = parse(text).unwrap();
        let s = read.surface;
        assert_eq!(s.vertices.len(), 5);
        assert_eq!(s.vertices[1], [1.0, 0.0, 0.0]);
        assert_eq!(s.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 4]]);
        assert!(read.warnings.is_empty());
        assert!((s.area() - 1.5).abs() < 1e-15);
    }

    #[test]
    fn obj_errors_name_file_and_line() {
        let e = parse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n").unwrap_err();
        assert!(
            matches!(
                e,
                SurfaceError::IndexOutOfRange {
                    line: 4,
                    index: 4,
                    n_vertices: 3,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().starts_with("inline.obj: line 4:"), "{e}");
        let e = parse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 -4 2\n").unwrap_err();
        assert!(
            matches!(
                e,
                SurfaceError::IndexOutOfRange {
                    line: 4,
                    index: -4,
                    ..
                }
            ),
            "{e}"
        );
        let e = parse("v 0 0\n").unwrap_err();
        assert!(
            e.to_string()
                .contains("line 1: vertex needs 3 coordinates, found 2"),
            "{e}"
        );
        let e = parse("v 0 0 zero\n").unwrap_err();
        assert!(
            e.to_string()
                .contains("line 1: bad vertex coordinate \"zero\""),
            "{e}"
        );
        let e = parse("v 0 0 nan\n").unwrap_err();
        assert!(e.to_string().contains("non-finite"), "{e}");
        let e = parse("v 0 0 0\nv 1 0 0\n\nf 1 2\n").unwrap_err();
        assert!(
            e.to_string()
                .contains("line 4: a face needs at least 3 corners, found 2"),
            "{e}"
        );
        let e = parse("v 0 0 0\nf a/1 1 1\n").unwrap_err();
        assert!(
            e.to_string().contains("line 2: bad face corner \"a/1\""),
            "{e}"
        );
        let e = parse("v 0 0 0\nv 1 0 0\n").unwrap_err();
        assert!(matches!(e, SurfaceError::NoTriangles { .. }), "{e}");
        let e = read_obj(Path::new("/nonexistent/x.obj")).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("/nonexistent/x.obj: cannot read file"),
            "{e}"
        );
    }

    #[test]
    fn obj_degenerate_triangles_are_dropped_and_reported() {
        let read = parse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 2\nf 1 2 3\n").unwrap();
        assert_eq!(read.surface.triangles, vec![[0, 1, 2]]);
        assert_eq!(read.warnings.len(), 1);
        assert!(
            read.warnings[0].contains("dropped 1 triangles") && read.warnings[0].contains("line 4")
        );
    }

    #[test]
    fn new_checks_indices_and_coordinates() {
        let e = TriangleSurface::new(vec![[0.0; 3]; 2], vec![[0, 1, 2]]).unwrap_err();
        assert!(matches!(
            e,
            SurfaceError::BadTriangle {
                triangle: 0,
                vertex: 2,
                n_vertices: 2
            }
        ));
        let e = TriangleSurface::new(vec![[0.0, f64::INFINITY, 0.0]], vec![]).unwrap_err();
        assert!(matches!(e, SurfaceError::NonFiniteVertex { vertex: 0, .. }));
    }

    #[test]
    fn mesh_boundary_is_closed_and_outward() {
        let mesh = box_mesh([2, 3, 1], [1.0, 2.0, 0.5]);
        let mut s = TriangleSurface::from_mesh_boundary(&mesh);
        // Only surface nodes are kept: the 2x3x1 box has no interior node.
        assert_eq!(s.vertices.len(), mesh.surface_vertices().len());
        assert_eq!(s.n_triangles(), 2 * 2 * (2 * 3 + 3 + 2));
        assert!(
            (s.signed_volume() - 1.0).abs() < 1e-14,
            "{}",
            s.signed_volume()
        );
        assert!((s.area() - 2.0 * (2.0 + 0.5 + 1.0)).abs() < 1e-14);
        assert_eq!(s.bounding_box(), ([0.0; 3], [1.0, 2.0, 0.5]));
        s.flip();
        assert!((s.signed_volume() + 1.0).abs() < 1e-14);
    }
}
