# Reads a legacy VTK file with VTK's own reader (the one ParaView uses) and prints what it
# found: "points N cells N type T error E" and, per point array, "NAME COMPONENTS VALUES-OF-POINT-1".
# Used by the mesh unit tests: /usr/bin/python3 vtk_read.py FILE
import sys
import vtk

r = vtk.vtkUnstructuredGridReader()
r.SetFileName(sys.argv[1])
r.ReadAllVectorsOn()
r.ReadAllScalarsOn()
r.Update()
g = r.GetOutput()
print("points %d cells %d type %d error %d" % (g.GetNumberOfPoints(), g.GetNumberOfCells(),
      g.GetCellType(0) if g.GetNumberOfCells() else -1, r.GetErrorCode()))
pd = g.GetPointData()
for i in range(pd.GetNumberOfArrays()):
    a = pd.GetArray(i)
    print("%s %d %s" % (a.GetName(), a.GetNumberOfComponents(),
          " ".join("%.9g" % a.GetComponent(1, c) for c in range(a.GetNumberOfComponents()))))
