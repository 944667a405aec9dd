// Thin free plate, 240 x 160 x 6 mm (thickness/length = 1/40), metres, second-order (10-node)
// tets straight from Gmsh: the mesh on which MUMPS ran out of workspace on 2 ranks (issue 37).
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 0.24, 0.16, 0.006};
Mesh.CharacteristicLengthMin = 0.012;
Mesh.CharacteristicLengthMax = 0.012;
Mesh.ElementOrder = 2;
