"""The geometry layer: every stage from the target surface to the deployment simulation, on
numpy, scipy, libigl and networkx alone (no CAD kernel).

Subpackages, each importing only those before it: ``core``, ``solve``, ``target``, ``flatten``,
``tiling``, ``assembled``, ``flat``, ``hinges``, ``route``, ``simulate``.
"""
