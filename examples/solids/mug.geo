// Thick-walled mug with a handle, metres: outer radius 80 mm, height 180 mm, wall 12 mm,
// base 15 mm. The handle (half torus, centre-line radius 45 mm, tube radius 12 mm, its ends
// buried in the wall) breaks the axial symmetry, so the cup's bending pairs split.
SetFactory("OpenCASCADE");
Cylinder(1) = {0, 0, 0, 0, 0, 0.18, 0.080};
// Half torus in the xy plane (y >= 0), turned to x >= 0, then stood up into the xz plane.
Torus(2) = {0, 0, 0, 0.045, 0.012, Pi};
Rotate {{0, 0, 1}, {0, 0, 0}, -Pi/2} { Volume{2}; }
Rotate {{1, 0, 0}, {0, 0, 0}, Pi/2} { Volume{2}; }
Translate {0.072, 0, 0.095} { Volume{2}; }
Cylinder(3) = {0, 0, 0.015, 0, 0, 0.2, 0.068};
// Cup and handle fused, then the inside of the cup removed.
BooleanUnion(4) = { Volume{1}; Delete; }{ Volume{2}; Delete; };
BooleanDifference(5) = { Volume{4}; Delete; }{ Volume{3}; Delete; };
Mesh.CharacteristicLengthMin = 0.011;
Mesh.CharacteristicLengthMax = 0.011;
Mesh.ElementOrder = 1;
Mesh.Algorithm3D = 1;
Mesh.Optimize = 1;
Mesh.MshFileVersion = 2.2;
Mesh.Binary = 0;
