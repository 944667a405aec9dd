//! Differentiable shape representation: implicit shapes and the meshes built from them.
//!
//! | module         | what it does |
//! |----------------|--------------|
//! | [`surface`]    | triangle surfaces (OBJ, or the boundary of a tet mesh) |
//! | [`sdf`]        | a surface's signed distance field (positive inside, sign from the generalised winding number) |
//! | [`distance`]   | distances between shapes: surface sampling, Hausdorff-type distances, volume IoU |
//! | [`marching`]   | marching tetrahedra on a background grid, with the record every gradient flows back through |
//! | [`refine`]     | longest-edge bisection of the background grid where the field asks for it |
//! | [`curve`]      | curving a P2 mesh's boundary onto the zero of a field |
//! | [`neural_sdf`] | a small MLP signed-distance field with positional encoding and hand-written backpropagation |
//! | [`field`]      | surfaces read and placed, their signed distance sampled on a grid, the reference depth |
//! | [`spectrum`]   | the forward chain: the spectrum of the body inside a field and its gradient to the field |
//!
//! # Shapes from signed distances
//!
//! For shape optimisation the crate builds its own meshes:
//! [`surface`] reads triangle surfaces (OBJ, or the boundary of a tet mesh),
//! [`sdf`] turns one into a signed distance field (positive inside, sign from
//! the generalised winding number), and [`marching`] meshes the region
//! {s > 0} of values on a background grid with marching tetrahedra, keeping
//! the record of every vertex (grid vertex or interpolated crossing) so that
//! gradients flow from node positions back to the values and grid offsets
//! ([`MarchedMesh::vjp`], and [`crate::mesh::linear_node_gradient`] from a lifted
//! P2 mesh). [`spectrum`] carries those gradients on to the eigenvalues; the fits
//! built on the chain (thickness, morph, geometry) are in [`crate::inverse`].
//! Reading, validating, lifting and writing tet meshes stays in [`crate::mesh`].

pub mod curve;
pub mod distance;
pub mod field;
pub mod marching;
pub mod neural_sdf;
pub mod refine;
pub mod sdf;
pub mod spectrum;
pub mod surface;

pub use curve::{curve_boundary, CurvedNode, CurvingReport, FieldGradient};
pub use distance::{
    compare_shapes, sample_surface, surface_distance, volume_iou, DistanceError, ShapeComparison,
    SurfaceDistance,
};
pub use field::{
    normalise_surface, read_surface, reference_depth, shifted_covering, union_box, SampledField,
};
pub use marching::{
    march, morph, morph_vjp, shell, shell_of_depth, BackgroundGrid, MarchedMesh, MarchingError,
    MarchingGradient, MarchingOptions, MarchingReport, MorphGradient, Shell, ShellGradient,
    VertexOrigin,
};
pub use sdf::SignedDistance;
pub use spectrum::{
    curved_body, curved_field_modes, curved_field_spectrum, curved_shell, curved_shell_spectrum,
    refine_crossings, shape_modes, shape_spectrum, CurvedBody, CurvedShell, ExactCrossing,
    FieldWeights, PointGradient, ShapeError, ShapeModes, ShapeSpectrum, StepTimings,
};
pub use surface::{parse_obj, read_obj, SurfaceError, SurfaceRead, TriangleSurface};
