"""The fill stage: the frame's regions (:mod:`.segmentation`), the paper's region selection and
weighted filling (:mod:`.filling`), the map carried into the frame camera (:mod:`.projection`) and
``evfuse fill`` on a map folder (:mod:`.dense`). Filling methods other than the paper's are in
:mod:`fusion.methods`."""
