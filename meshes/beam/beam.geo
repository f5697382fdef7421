// a beam 1 m x 0.1 m x 0.1 m along x, starting at x = 0 (clamp the x = 0 face)
// gmsh beam.geo -3 -setnumber h 0.1 -format msh22 -o beam_l0.msh
SetFactory("OpenCASCADE");
DefineConstant[ h = 0.1 ];
Box(1) = {0, -0.05, -0.05, 1, 0.1, 0.1};
// size control shared by all shapes: a uniform target edge length h everywhere
Mesh.MeshSizeMax = h;
Mesh.MeshSizeMin = h / 4;
Mesh.MeshSizeFromPoints = 0;
Mesh.MeshSizeFromCurvature = 0;
Mesh.MeshSizeExtendFromBoundary = 0;
Mesh.Optimize = 1;
Mesh.Algorithm3D = 10;   // HXT: better dihedral angles than the default Delaunay here
General.NumThreads = 1;  // one thread (generate.sh also turns off address randomisation)
Mesh.SaveAll = 0;
// save only the tetrahedra
Physical Volume("body", 1) = Volume{:};
