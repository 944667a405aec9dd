// An L bracket in MILLIMETRES (run with --units mm): legs 80 x 40 mm and 50 x 40 mm, 5 mm thick,
// second-order tets.
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 80, 40, 5};
Box(2) = {0, 0, 0, 5, 40, 50};
BooleanUnion(3) = { Volume{1}; Delete; }{ Volume{2}; Delete; };
Mesh.CharacteristicLengthMin = 5;
Mesh.CharacteristicLengthMax = 5;
Mesh.ElementOrder = 2;
