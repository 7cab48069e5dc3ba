"""The event map: EMVS's disparity space image and semi-dense depth (:mod:`.emvs`), the depth range
it searches (:mod:`.dsi_range`, blind: from the scene's declaration or the data, never the
truth), and ``evfuse map`` on a sequence or a recording (:mod:`.mapping`)."""
