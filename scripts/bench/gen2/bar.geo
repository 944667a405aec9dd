// Generator 2 (independent): a steel-like bar 250 x 25 x 10 mm (a chime or glockenspiel bar,
// rectangular, so no two bending families share frequencies), metres, linear tets.
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 0.250, 0.025, 0.010};
Mesh.CharacteristicLengthMin = 0.005;
Mesh.CharacteristicLengthMax = 0.005;
Mesh.ElementOrder = 1;
