// Unit cube [0,1]^3 for the mesh-reader tests (diffsound src/mesh).
// Regenerate every fixture with tests/data/mesh/make_fixtures.sh.
// Straight faces only, so in the 10-node version every mid-edge node is
// the exact midpoint of its edge: that is what pins down the node order.
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 1, 1, 1};
Mesh.CharacteristicLengthMin = 0.4;
Mesh.CharacteristicLengthMax = 0.4;
