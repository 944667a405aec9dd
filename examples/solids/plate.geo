// Free rectangular plate with an off-centre hole: 260 x 150 x 20 mm, metres.
// The hole breaks the plate's mirror symmetries, so its spectrum has no degenerate pairs.
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 0.26, 0.15, 0.02};
Cylinder(2) = {0.075, 0.055, -0.01, 0, 0, 0.04, 0.025};
BooleanDifference(3) = { Volume{1}; Delete; }{ Volume{2}; Delete; };
Mesh.CharacteristicLengthMin = 0.0085;
Mesh.CharacteristicLengthMax = 0.0085;
Mesh.ElementOrder = 1;
Mesh.Algorithm3D = 1;
Mesh.Optimize = 1;
Mesh.MshFileVersion = 2.2;
Mesh.Binary = 0;
