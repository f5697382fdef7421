// small test cube: gmsh cube.geo -3 -setnumber h 1 -format msh22 -o cube_h1.msh (also msh41, .mesh)
// second order: gmsh cube.geo -3 -setnumber h 1 -order 2 -format msh22 -o cube_order2.msh
SetFactory("OpenCASCADE");
DefineConstant[ h = 0.5 ];
Box(1) = {0, 0, 0, 1, 1, 1};
Mesh.MeshSizeMax = h;
Mesh.MeshSizeMin = h / 4;
Mesh.MeshSizeFromPoints = 0;
Mesh.MeshSizeFromCurvature = 0;
Mesh.MeshSizeExtendFromBoundary = 0;
