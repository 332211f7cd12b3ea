"""Engines that run a scenario: the built-in numba engine, LIGGGHTS, and a user's command.

``base.py`` is the protocol and the registry (``get_engine``, ``run_scenario``), ``builtin.py``
the numba engine, ``liggghts.py`` the LIGGGHTS adapter, ``command.py`` the command engine."""
