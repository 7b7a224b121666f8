"""Output: run files and restarts (:mod:`.runwriter`), the output-folder rule of every command
(:mod:`.outfolder`), derived fields and networks (:mod:`.postprocess`), and figures
(:mod:`.plotting`, :mod:`.shear_figures`)."""
