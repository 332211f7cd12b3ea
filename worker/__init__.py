"""Running simulations: the job function, the local process-pool executor (embedded default),
the RQ executor and the worker command. Needs Redis in service mode, never the database.
"""
