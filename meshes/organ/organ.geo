// an organ-like shape for demos (liver-like): a large flattened lobe fused with a smaller
// lobe and a rounded tail, about 0.3 m x 0.2 m x 0.12 m, resting on z = 0
// gmsh organ.geo -3 -setnumber h 0.045 -format msh22 -o organ_l0.msh
SetFactory("OpenCASCADE");
DefineConstant[ h = 0.045 ];
// right lobe: ellipsoid radii 0.1 x 0.08 x 0.06
Sphere(1) = {0, 0, 0, 1};
Dilate {{0, 0, 0}, {0.1, 0.08, 0.06}} { Volume{1}; }
Translate {0.1, 0.1, 0.06} { Volume{1}; }
// left lobe: smaller and flatter, overlapping the right one
Sphere(2) = {0, 0, 0, 1};
Dilate {{0, 0, 0}, {0.085, 0.06, 0.04}} { Volume{2}; }
Translate {0.2, 0.09, 0.045} { Volume{2}; }
// tail towards -x
Sphere(3) = {0, 0, 0, 1};
Dilate {{0, 0, 0}, {0.06, 0.045, 0.035}} { Volume{3}; }
Rotate {{0, 0, 1}, {0, 0, 0}, 0.4} { Volume{3}; }
Translate {0.045, 0.06, 0.045} { Volume{3}; }
BooleanUnion{ Volume{1}; Delete; }{ Volume{2}; Volume{3}; Delete; }
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
