"""Experiments over many windows: the filling bench (:mod:`.bench`, ``evfuse bench``; its
surface families with a difficulty knob are :mod:`sim.scene.families`, which only writes scenes,
still importable as ``fusion.experiments.families``), and the paper's tables
(:mod:`.reproduce`, ``evfuse reproduce``)."""
