"""Disk packings: the periodic cell (:mod:`.packing`), sieve curves (:mod:`.gsd`), the jammed
stress-free generator (:mod:`.generation`, with :mod:`.fire`, :mod:`.stress_free`, its sparse
Cholesky :mod:`.cholesky` and :mod:`.portable`, its CPU-independent arithmetic), the
candidate-pair search (:mod:`.neighbours`), contact fabric (:mod:`.fabric`), the shipped default
packing (:mod:`.reference_packing`) and the on-disk cache of generated packings (:mod:`.cache`).
No DOLFINx here."""
