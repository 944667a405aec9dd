// Generator 2 (independent): a glass-like tube, 280 mm long, outer radius 16 mm, wall 2.5 mm,
// axis along x, metres, linear tets.
SetFactory("OpenCASCADE");
Cylinder(1) = {0, 0, 0, 0.28, 0, 0, 0.016};
Cylinder(2) = {-0.01, 0, 0, 0.30, 0, 0, 0.0135};
BooleanDifference(3) = { Volume{1}; Delete; }{ Volume{2}; Delete; };
Mesh.CharacteristicLengthMin = 0.0055;
Mesh.CharacteristicLengthMax = 0.0055;
Mesh.ElementOrder = 1;
