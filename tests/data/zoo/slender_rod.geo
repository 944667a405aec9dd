// Slender free rod: 300 mm long, 12 mm across (25:1), metres, linear tets (lifted to P2).
SetFactory("OpenCASCADE");
Cylinder(1) = {0, 0, 0, 0.3, 0, 0, 0.006};
Mesh.CharacteristicLengthMin = 0.004;
Mesh.CharacteristicLengthMax = 0.004;
Mesh.ElementOrder = 1;
