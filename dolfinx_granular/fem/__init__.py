"""The DOLFINx glue: quadrature data for F, P and A (:mod:`.quadrature`), materials on cells
(:mod:`.material`, :mod:`.linear`), wiring checks (:mod:`.diagnose`), stress fields and probes
(:mod:`.fields`, :mod:`.probing`), and every difference between DOLFINx releases
(:mod:`.compat`)."""
