"""The fill stage: the frame's regions (:mod:`.segmentation`), the paper's region selection and
weighted filling (:mod:`.filling`), the map carried into the frame camera (:mod:`.projection`) and
``evfuse fill`` on a map folder (:mod:`.dense`), whose records (:class:`~.records.DenseParams`,
:class:`~.records.FillInputs`, :class:`~.records.DenseResult`) are :mod:`.records`, below it.
Filling methods other than the paper's are in :mod:`fusion.methods`.

This ``__init__`` imports nothing: :mod:`fusion.io`, :mod:`fusion.scoring`, :mod:`fusion.figures`
and :mod:`fusion.methods` import :mod:`.records` (and :mod:`.segmentation`, :mod:`.filling`)
while :mod:`.dense` imports them, which re-exporting :mod:`.dense` here would turn into a loop."""
