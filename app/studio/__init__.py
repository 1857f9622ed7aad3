"""drawstring studio: the local web app (``drawstring studio``).

- :mod:`.serve`: the command's options and the server's start;
- :mod:`.server`: the HTTP API and the page (FastAPI);
- :mod:`.service`: designs, jobs and uploads in the data folder (:class:`~.service.Studio`);
- :mod:`.executor`: where jobs run (child processes; the :class:`~.executor.Executor`
  interface for other executors);
- :mod:`.job`: one design job as its process runs it;
- :mod:`.options`: the design options described, parsed and estimated;
- :mod:`.store`: the SQLite records; :mod:`.files`: uploads, previews, zips, key numbers;
- ``static/``: the page (plain JavaScript modules, the 3D views on the report's three.js).
"""
