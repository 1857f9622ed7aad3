"""The fabrication layer: profiles and the files a maker prints or cuts.

:mod:`.profiles` loads and validates a profile;
:func:`drawstring.fabrication.exports.write_fabrication` writes a design's ``fabrication/`` folder
with one writer per process (:mod:`.processes`), through :mod:`.step` (STEP), :mod:`.mesh3mf`
and :mod:`.beds` (3MF print jobs), :mod:`.dxf`, :mod:`.panels` and :mod:`.parts` (flat parts,
plywood panels, rubber strips); :mod:`.measures` measures what is made.  The exports load the
CAD kernel, so nothing is imported here.
"""
