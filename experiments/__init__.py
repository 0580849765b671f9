"""Training experiments: the measurements behind the README's results, not library code.

Each module is one experiment (a configuration dataclass and a ``run``) that trains and evaluates
with the library (:mod:`demo.imitation`, :mod:`demo.rl`, :mod:`demo.evaluation`) and writes JSON and
figures; ``demo bench <name>`` runs it. Nothing in the library imports from here.

- :mod:`.compounding`: BC against the DAgger family as the horizon grows (``demo bench compounding``).
- :mod:`.policies`: every policy class on the same data and seeds (``demo bench policies``).
- :mod:`.multimodal`: which policies keep both modes of a bimodal task (``demo bench multimodal``).
- :mod:`.crossrobot`: one ee7 policy across arms (``demo bench crossrobot``).
- :mod:`.peer_gail`: our GAIL against the ``imitation`` library's (``demo bench peer-gail``).
"""
