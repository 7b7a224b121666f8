"""Output: run files and restarts (:mod:`.runwriter`), derived fields and networks
(:mod:`.postprocess`), and figures (:mod:`.plotting`, :mod:`.shear_figures`)."""
