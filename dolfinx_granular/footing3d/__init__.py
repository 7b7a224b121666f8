"""The 3-D scene: a rectangular footing near the crest of a slope (the 2-D benchmark's cross-section
extruded), on hexahedra, with sphere RVEs at the Gauss points."""
