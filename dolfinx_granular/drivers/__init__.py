"""What solves: the problem (forms, bcs, materials: :mod:`.problem`), the shared convergence test
(:mod:`.convergence`), the driver protocol (:mod:`.protocol`) and the drivers: Newton through
SNES (:mod:`.newton`), load stepping (:mod:`.loading`), arc length (:mod:`.arclength`,
:mod:`.pathrecords`), PETSc's SNESNEWTONAL (:mod:`.snes_al`), and one material point without a
mesh (:mod:`.material_point`)."""
