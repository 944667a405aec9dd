// Solid sphere of radius 0.5 m centred at the origin, for the analytic convergence test.
// The element size is set from the command line:
//   gmsh -3 -order 2 -clmin H -clmax H sphere.geo -o sphere.msh
// With -order 2 the mid-edge nodes on the boundary lie ON the sphere (curved, isoparametric).
SetFactory("OpenCASCADE");
Sphere(1) = {0, 0, 0, 0.5};
Mesh.Optimize = 1;
Physical Volume("solid") = {1};
