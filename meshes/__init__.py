"""gmsh geometries of the benchmarks (imported lazily: gmsh and DOLFINx are needed only here)."""
