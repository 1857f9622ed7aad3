"""The design loop: options, stages in order, the tiling and co-optimization ladders, and the
measured design record.

:mod:`.record` (options, progress, the design record, the writer protocol) is the leaf every
other module imports; :func:`drawstring.pipeline.run.design` runs the stages.
"""
