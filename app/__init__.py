"""What a person runs: the ``drawstring`` command line (:mod:`.cli`)."""
