// Thin curved shell: a hemispherical cap of outer radius 100 mm and wall 2.5 mm
// (thickness/radius = 1/40), metres, linear tets (lifted to P2).
SetFactory("OpenCASCADE");
Sphere(1) = {0, 0, 0, 0.1};
Sphere(2) = {0, 0, 0, 0.0975};
BooleanDifference(3) = { Volume{1}; Delete; }{ Volume{2}; Delete; };
Box(4) = {-0.2, -0.2, -0.2, 0.4, 0.4, 0.2};
BooleanDifference(5) = { Volume{3}; Delete; }{ Volume{4}; Delete; };
Mesh.CharacteristicLengthMin = 0.01;
Mesh.CharacteristicLengthMax = 0.01;
Mesh.ElementOrder = 1;
