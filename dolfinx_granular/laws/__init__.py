"""Material laws F -> (W, P, A) on plain arrays: the protocols (:mod:`.protocol`), the public
contact geometry every RVE builds on (:mod:`.contacts`), their shared helpers (:mod:`.tools`), the
Taylor RVE (:mod:`.taylor`, Numba kernel :mod:`.taylor_kernel`), the frictional one
(:mod:`.friction`, :mod:`.friction_kernel`), the cheaper model levels (:mod:`.levels`) and the
overlap validity measure (:mod:`.validity`). No DOLFINx here."""
