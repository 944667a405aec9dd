// Sphere of radius 0.5 centred at the origin, coarse, for the reader tests.
// Curved boundary: in the 10-node version the surface mid-edge nodes sit on
// the sphere, not at the straight midpoints.
SetFactory("OpenCASCADE");
Sphere(1) = {0, 0, 0, 0.5};
Mesh.CharacteristicLengthMin = 0.3;
Mesh.CharacteristicLengthMax = 0.3;
// Physical groups make gmsh write a $PhysicalNames section (which the reader
// must skip) and save only the tagged volume and surface elements.
Physical Volume("solid") = {1};
Physical Surface("skin") = {1};
