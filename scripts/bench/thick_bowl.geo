// Thick hemispherical bowl with a foot ring: a solid of the same size as the
// shared bowl (about 0.116 m across, 0.06 m tall), used to generate benchmark
// meshes of any size with `gmsh -3 -clmax H thick_bowl.geo`. Units: metres.
SetFactory("OpenCASCADE");

R = 0.058;      // outer radius of the shell
t = 0.005;      // wall thickness
zc = 0.030;     // centre of the spheres (rim plane)
rf_out = 0.026; // foot ring outer radius
rf_in = 0.020;  // foot ring inner radius
hf = 0.004;     // foot ring height below the shell

Sphere(1) = {0, 0, zc, R};
Sphere(2) = {0, 0, zc, R - t};
Box(3) = {-1, -1, zc, 2, 2, 1};             // everything above the rim plane
shell() = BooleanDifference{ Volume{1}; Delete; }{ Volume{2, 3}; Delete; };

// Foot ring: reaches into the shell wall so that the union is one solid.
zb = zc - R;                                // lowest point of the outer sphere
Cylinder(4) = {0, 0, zb - hf, 0, 0, hf + 0.006, rf_out};
Cylinder(5) = {0, 0, zb - hf - 0.001, 0, 0, hf + 0.008, rf_in};
ring() = BooleanDifference{ Volume{4}; Delete; }{ Volume{5}; Delete; };
Sphere(6) = {0, 0, zc, R - t};              // keep the ring out of the cavity
ring2() = BooleanDifference{ Volume{ring()}; Delete; }{ Volume{6}; Delete; };
BooleanUnion{ Volume{shell()}; Delete; }{ Volume{ring2()}; Delete; }

// Only the tetrahedra are written (elements of physical groups only).
Physical Volume("solid", 1) = Volume{:};

Mesh.ElementOrder = 1;
Mesh.Algorithm3D = 10;   // HXT: fast, multithreaded 3D Delaunay
Mesh.Optimize = 1;
