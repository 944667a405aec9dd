// High-aspect and sliver tets: a 120 x 80 x 3 mm plate meshed as ONE extruded layer of prisms
// split into tets (in-plane size 20 mm against 3 mm through: aspect ratios near 10), left
// unoptimised so that flat slivers stay. Metres, linear tets (lifted to P2).
Point(1) = {0, 0, 0, 0.02};
Point(2) = {0.12, 0, 0, 0.02};
Point(3) = {0.12, 0.08, 0, 0.02};
Point(4) = {0, 0.08, 0, 0.02};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
Extrude {0, 0, 0.003} { Surface{1}; Layers{1}; }
Mesh.Optimize = 0;
Mesh.ElementOrder = 1;
