"""What an identification means: its accuracy (:mod:`.accuracy`), which parameters the data can
identify (:mod:`.identifiability`) and their uncertainty (:mod:`.uncertainty`). The public
functions are :func:`iwr.accuracy`, :func:`iwr.identifiability` and :func:`iwr.uncertainty`;
this package exports nothing, so that ``iwr.analysis.accuracy`` is always the module."""
