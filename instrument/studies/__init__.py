"""Studies of the model: reproducing the paper's figures (:mod:`.reproduce`, :mod:`.figures`),
what accuracy costs (:mod:`.accuracy`) and the synthetic validation of the inversion
(:mod:`.validate`).

They may import :mod:`..inference`, :mod:`..tables`, :mod:`..plotting` and the physics; never
the service or the command line.
"""
