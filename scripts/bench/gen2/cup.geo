// Generator 2 (independent): a small porcelain-like bowl, a spherical shell of outer radius
// 70 mm and wall 4 mm cut 22 mm below its centre (rim at z = -0.022 ... open upwards after
// the flip below), metres, linear tets. Opening up: the cap below the plane z = -0.022 is the
// solid; the rim is at the top.
SetFactory("OpenCASCADE");
Sphere(1) = {0, 0, 0, 0.070};
Sphere(2) = {0, 0, 0, 0.066};
BooleanDifference(3) = { Volume{1}; Delete; }{ Volume{2}; Delete; };
Box(4) = {-0.1, -0.1, 0.012, 0.2, 0.2, 0.1};
BooleanDifference(5) = { Volume{3}; Delete; }{ Volume{4}; Delete; };
Mesh.CharacteristicLengthMin = 0.0075;
Mesh.CharacteristicLengthMax = 0.0075;
Mesh.ElementOrder = 1;
