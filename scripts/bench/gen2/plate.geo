// Generator 2 (independent): a free aluminium-like plate 210 x 148 x 5 mm (an A5 sheet),
// metres, linear tets (diffsound lifts them to P2).
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 0.210, 0.148, 0.005};
Mesh.CharacteristicLengthMin = 0.011;
Mesh.CharacteristicLengthMax = 0.011;
Mesh.ElementOrder = 1;
