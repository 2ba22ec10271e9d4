"""Scenes with exact answers, shared by the tests, the benchmarks and the examples: not the
core API, and nothing in the core imports them.

- `shapes`: exact reference surfaces (sphere, cylinder, torus, saddle, ...) with faceted
  meshes, exact closest points, normals and signed distances (pure numpy);
- `element_scenes`: targets and penetrating contactors for the contact element's checks;
- `gmsh_scenes`: meshes written by gmsh's OpenCASCADE kernel (second-order cells, volumes,
  parts with features); `feature_scenes`: those parts with their exact signed distance.
  Both need gmsh (``pip install 'diffsurf[test]'``), imported when a scene is meshed.
"""
