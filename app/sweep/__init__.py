"""``drawstring sweep``: the product of a few design options' values, designed on Dask.

:mod:`.command` is the command (its options and its run), :mod:`.variants` makes the variants
from the comma lists, :mod:`.task` designs one variant on a worker, :mod:`.table` writes
``sweep.csv`` and ``sweep.html``.
"""
