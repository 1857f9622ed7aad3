"""The CAD layer: exact B-rep tiles and hinge parts built with build123d (OpenCASCADE).

It reads plain arrays (tiles, hinges, route steps) and a profile's dimensions
(:class:`~drawstring.cad.dimensions.FeatureDimensions`), never the pipeline's records.
:mod:`.paths` (the string's centre lines and length) needs no kernel; the other modules load
it, so nothing is imported here.  Entry points: :func:`drawstring.cad.design.build_design_solids`
and the checks of :mod:`drawstring.cad.checks`.
"""
