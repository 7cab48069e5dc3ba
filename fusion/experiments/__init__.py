"""Experiments over many windows: the filling bench (:mod:`.bench`, ``evfuse bench``) and its
surface families with a difficulty knob (:mod:`.families`), and the paper's tables
(:mod:`.reproduce`, ``evfuse reproduce``)."""
